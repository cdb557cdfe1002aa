//! The tensor-product B-spline kernel: knots, basis functions, surfaces, least-squares fitting.
//!
//! A surface of degrees `(p, q)` over knot vectors `U` (`m + p + 1` knots) and `V`
//! (`n + q + 1` knots) with an `m × n` grid of control points `bᵢⱼ` is
//!
//! ```text
//! F(u, v) = Σᵢ Σⱼ Nᵢ,ₚ(u) Nⱼ,q(v) bᵢⱼ,     (u, v) ∈ [u_p, u_m] × [v_q, v_n]
//! ```
//!
//! with `Nᵢ,ₚ` the Cox–de Boor basis functions. Cubic (`p = q = 3`) surfaces on simple knots
//! are C², which is what the face model uses. The pieces:
//!
//! * [`KnotVector`]: validated knots that own their degree; span lookup.
//! * [`basis_functions`], [`basis_derivatives`]: The NURBS Book A2.2 and A2.3, allocation-free.
//! * [`BSplineSurface`]: evaluation (point, derivatives, normal, dense grids, parameter lists),
//!   the sparse basis matrix [`BasisMatrix`], affine maps, JSON serialisation.
//! * [`SurfaceFit`]: least-squares control grids from scattered samples, with an optional
//!   thin-plate smoothness term, and a residual [`FitReport`].
//! * [`SurfaceSpace`]: a linear space of surfaces on one knot layout, `B₀ + Σₖ wₖ ΔBₖ` (a shape
//!   model's mean and modes), with mode fitting from displacement fields and regularised
//!   least-squares weights.
//!
//! Conventions: control grids are flat and row-major, `rows × cols`, row `i` along `u` and
//! column `j` along `v`, so `bᵢⱼ` is `control_points()[i·cols + j]`. Degrees, never orders.

/// Calls `$receiver.$method::<NU, NV>(args)` with the basis widths `NU = p + 1`, `NV = q + 1`
/// as compile-time constants for the common equal degrees 1–3, so that the hot loops unroll,
/// and with `RUNTIME` (degrees read at run time, see `basis::width`) for any other degrees.
macro_rules! with_widths {
    ($p:expr, $q:expr, $receiver:ident . $method:ident ( $($arg:expr),* )) => {
        match ($p, $q) {
            (3, 3) => $receiver.$method::<4, 4>($($arg),*),
            (2, 2) => $receiver.$method::<3, 3>($($arg),*),
            (1, 1) => $receiver.$method::<2, 2>($($arg),*),
            _ => $receiver.$method::<{ $crate::bspline::basis::RUNTIME }, { $crate::bspline::basis::RUNTIME }>($($arg),*),
        }
    };
}

pub(crate) mod band;
mod basis;
mod curvature;
mod curve;
mod fit;
mod inversion;
mod knots;
mod refine;
mod space;
mod step;
mod surface;
#[cfg(target_arch = "x86_64")]
mod wide;

pub use basis::{basis_derivatives, basis_functions};
pub use curvature::Curvature;
pub use curve::BSplineCurve;
pub use fit::{FitReport, FittedSurface, SurfaceFit};
pub use inversion::{ClosestPoint, ClosestPoints, SAMPLES_PER_SPAN};
pub use knots::{KnotVector, MAX_DEGREE};
pub use space::{SpaceSamples, SurfaceSpace};
pub use step::{StepOptions, encode_step};
pub use surface::{BSplineSurface, BasisMatrix, SurfaceDerivatives, SurfaceFileError};

use crate::Real;

/// A parameter direction of a surface.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Direction {
    /// The first parameter, along the grid's rows.
    U,
    /// The second parameter, along the grid's columns.
    V,
}

impl std::fmt::Display for Direction {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Direction::U => "u",
            Direction::V => "v",
        })
    }
}

/// Everything that can go wrong in the B-spline kernel.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum BSplineError {
    /// The degree exceeds [`MAX_DEGREE`].
    #[error("degree {degree} is above the supported maximum {max}")]
    DegreeTooHigh {
        /// The degree asked for.
        degree: usize,
        /// [`MAX_DEGREE`].
        max: usize,
    },
    /// Fewer than `2·(degree + 1)` knots (fewer than `degree + 1` control points).
    #[error("too few knots: got {got}, need at least {need} (knots = control points + degree + 1)")]
    TooFewKnots {
        /// Knots given.
        got: usize,
        /// The minimum for the degree.
        need: usize,
    },
    /// A knot is NaN or infinite.
    #[error("knot {index} is not finite ({value})")]
    NonFiniteKnot {
        /// Its position in the vector.
        index: usize,
        /// Its value.
        value: Real,
    },
    /// The knots decrease somewhere.
    #[error("knots must not decrease: knot {index} is {value}, after {previous}")]
    DecreasingKnots {
        /// The first knot smaller than its predecessor.
        index: usize,
        /// The predecessor's value.
        previous: Real,
        /// The knot's value.
        value: Real,
    },
    /// A knot value is repeated more than `degree + 1` times.
    #[error("knot {value} is repeated {multiplicity} times; at most {max} (degree + 1) allowed")]
    KnotMultiplicityTooHigh {
        /// The repeated value.
        value: Real,
        /// How often it occurs.
        multiplicity: usize,
        /// `degree + 1`.
        max: usize,
    },
    /// The parameter domain `[u_p, u_n]` is empty (or its ends are not finite).
    #[error("empty parameter domain [{start}, {end}]")]
    EmptyDomain {
        /// `u_p`.
        start: Real,
        /// `u_n`.
        end: Real,
    },
    /// The control grid's shape does not match the knot vectors.
    #[error(
        "control grid is {rows} × {cols} but the knots need {expected_rows} × {expected_cols} \
         (control points = knots − degree − 1 in each direction)"
    )]
    GridShapeMismatch {
        /// Rows given.
        rows: usize,
        /// Columns given.
        cols: usize,
        /// Rows the `u` knots define.
        expected_rows: usize,
        /// Columns the `v` knots define.
        expected_cols: usize,
    },
    /// The number of control points is not `rows × cols`.
    #[error("{got} control points given for a {rows} × {cols} grid")]
    ControlPointCount {
        /// Points given.
        got: usize,
        /// Grid rows.
        rows: usize,
        /// Grid columns.
        cols: usize,
    },
    /// A curve's control points do not match its knot vector.
    #[error("{got} control points given for a curve whose knots need {expected}")]
    CurvePointCount {
        /// Points given.
        got: usize,
        /// Points the knot vector needs.
        expected: usize,
    },
    /// A polyline (2 distinct vertices at least) or a polygon (3) in a surface's parameter
    /// domain has too few distinct vertices.
    #[error("{distinct} distinct vertices given; at least {needed} are needed")]
    PolylineTooShort {
        /// Distinct consecutive vertices given.
        distinct: usize,
        /// The least number: 2 for a polyline, 3 for a polygon.
        needed: usize,
    },
    /// A trimming polygon encloses no area (its vertices lie on one line).
    #[error("the trim polygon encloses no area: its vertices lie on one line")]
    DegenerateTrim,
    /// The surface jumps across a knot line inside its domain (degree 0 there, or an interior
    /// knot of multiplicity `degree + 1`), so the image of a path across it is not one curve.
    #[error(
        "the surface is discontinuous at {direction} = {value} (knot multiplicity {multiplicity}, \
         degree {degree})"
    )]
    DiscontinuousSurface {
        /// `u` or `v`.
        direction: Direction,
        /// The knot's value.
        value: Real,
        /// Its multiplicity.
        multiplicity: usize,
        /// The direction's degree.
        degree: usize,
    },
    /// A curve's control point has a NaN or infinite coordinate.
    #[error("control point {index} is not finite")]
    NonFiniteCurvePoint {
        /// Its index.
        index: usize,
    },
    /// A control point has a NaN or infinite coordinate.
    #[error("control point ({row}, {col}) is not finite")]
    NonFiniteControlPoint {
        /// Its row.
        row: usize,
        /// Its column.
        col: usize,
    },
    /// A parameter pair has a NaN or infinite component.
    #[error("parameter ({u}, {v}) is not finite")]
    NonFiniteParameter {
        /// The `u` given.
        u: Real,
        /// The `v` given.
        v: Real,
    },
    /// A parameter lies outside the surface's domain.
    #[error("parameter {direction} = {value} is outside the domain [{start}, {end}]")]
    ParameterOutOfDomain {
        /// Which parameter.
        direction: Direction,
        /// Its value.
        value: Real,
        /// The domain's start.
        start: Real,
        /// The domain's end.
        end: Real,
    },
    /// Fitting was given no samples.
    #[error("no samples to fit")]
    NoSamples,
    /// Fitting was given different numbers of parameters, points or weights.
    #[error("{params} parameter pairs but {values} {what}")]
    SampleCountMismatch {
        /// Parameter pairs given.
        params: usize,
        /// Points or weights given.
        values: usize,
        /// `"points"` or `"weights"`.
        what: &'static str,
    },
    /// A sample point has a NaN or infinite coordinate.
    #[error("sample point {index} is not finite")]
    NonFiniteSample {
        /// The sample's index.
        index: usize,
    },
    /// A parameter of a sample is invalid (not finite or outside the domain).
    #[error("sample {index}: {source}")]
    InvalidSampleParameter {
        /// The sample's index.
        index: usize,
        /// What is wrong with it.
        source: Box<BSplineError>,
    },
    /// A sample weight is negative or not finite.
    #[error("weight {index} is {value}; weights must be finite and ≥ 0")]
    InvalidWeight {
        /// The weight's index.
        index: usize,
        /// Its value.
        value: Real,
    },
    /// The smoothness weight is negative or not finite.
    #[error("smoothness weight {value} must be finite and ≥ 0")]
    InvalidSmoothness {
        /// The value given.
        value: Real,
    },
    /// The samples do not determine the control grid: some control point has no (or only
    /// numerically dependent) support. Add samples there, or a smoothness weight.
    #[error(
        "the fit is underdetermined: control point ({row}, {col}) is not pinned down by the \
         samples{hint}"
    )]
    Underdetermined {
        /// Grid row of the first unconstrained control point found.
        row: usize,
        /// Its column.
        col: usize,
        /// Advice, depending on whether smoothing was on.
        hint: &'static str,
    },
    /// A mode's displacement grid does not have one vector per control point.
    #[error("mode {mode} has {got} displacements; the base's grid has {expected} control points")]
    ModeSize {
        /// The mode's index.
        mode: usize,
        /// Displacements given.
        got: usize,
        /// `rows·cols` of the base.
        expected: usize,
    },
    /// A mode's displacement has a NaN or infinite coordinate.
    #[error("mode {mode}: the displacement of control point ({row}, {col}) is not finite")]
    NonFiniteMode {
        /// The mode's index.
        mode: usize,
        /// Its row.
        row: usize,
        /// Its column.
        col: usize,
    },
    /// A list of per-mode values (weights, regularisers) has the wrong length.
    #[error("{got} values given for a space of {expected} modes")]
    WeightCount {
        /// Values given.
        got: usize,
        /// The number of modes.
        expected: usize,
    },
    /// A mode weight is NaN or infinite.
    #[error("mode weight {index} is not finite ({value})")]
    NonFiniteModeWeight {
        /// The weight's index.
        index: usize,
        /// Its value.
        value: Real,
    },
    /// The samples leave some combination of mode weights free (modes zero or dependent at
    /// the samples) and no regularisation fixes it.
    #[error("the samples do not determine the mode weights; add samples or a regularisation")]
    ModesUnderdetermined,
    /// The fitting system would need more memory than the kernel allows itself.
    #[error(
        "a {rows} × {cols} grid is too large to fit here: the banded normal matrix would hold \
         {entries} entries (limit {limit})"
    )]
    SystemTooLarge {
        /// Grid rows.
        rows: usize,
        /// Grid columns.
        cols: usize,
        /// Band entries needed.
        entries: usize,
        /// The limit.
        limit: usize,
    },
}
