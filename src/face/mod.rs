//! The face surface: the reference control grid deformed to an estimated 3D structure, and its
//! clipped triangle mesh (`../METHOD.md` §4, the paper's eq. 11–13).
//!
//! # The two deformations ([`Deformation`])
//!
//! * **Affine** (the paper's): `Tr_f = argmin ‖[T₀ | 1] Tr − T₁‖²` is the least-squares 3D
//!   affine map from the reference structure `T₀` to the estimated one `T₁`
//!   ([`structure_transform`]). B-splines are affine invariant, so mapping the control grid,
//!   `B₁ = [B₀ | 1] Tr_f`, maps the whole surface: `F₁ = Tr_f ∘ F₀`. The face keeps the
//!   reference's shape up to an affine change.
//! * **Local**: on top of the affine map, a smooth displacement field `D(u, v)` on the same
//!   knots, `F₁ = Tr_f ∘ F₀ + D`, so that each structure point moves where the estimate puts it.
//!   The point `k` sits at the parameters `pₖ` of its reference position (its frontal `x, y`
//!   through the reference frame); its residual displacement after the affine map is
//!   `dₖ = T₁ₖ − Tr_f(T₀ₖ)`, and `D` is the thin-plate-regularised least-squares fit of those 40
//!   vectors ([`SurfaceFit`] with smoothness `λ`). Fitting the *displacements*, not the points
//!   themselves, is deliberate: a landmark is not exactly on the reference surface (an eye
//!   centre lies a little in front of or behind the eyelid the grid was fitted to), and fitting
//!   positions would dent the surface by that offset at every landmark. The thin plate has the
//!   affine functions of `(u, v)` as its null space, so when `T₁` is an affine image of `T₀`
//!   every `dₖ` is zero and both modes give the same surface (a test checks it).
//!
//! Which is the default is set by measurement on ICT-FaceKit identities
//! (`cargo run --release --example surface_eval`): see [`Deformation::default`].

pub mod modes;
pub(crate) mod outline;
pub mod refine;
mod space;
mod tessellate;
pub mod texture;

use nalgebra::{Affine3, Matrix3, Matrix4, Point2, Point3, Vector3};

use crate::Real;
use crate::bspline::{BSplineError, BSplineSurface, SurfaceFit};
use crate::reference::{FrontalFrame, ReferenceFace};
use crate::structure::POINT_COUNT;

pub use outline::OUTLINE_POINTS;
pub use refine::{
    ConsistencyMap, Look, NORMALISATION_EYES, PHOTO_EXPRESSIONS_MAX, RefineOptions, RefineView,
    RefinedCamera, Refinement, SHIFTED_EXPRESSION_MIN, SHIFTED_EXPRESSIONS_MAX, TYPICAL_FOCAL, Window,
};
pub use space::{
    DenseFitOptions, ExpressionPrior, FaceSpace, LIP_WEIGHT, LipGaps, PLAUSIBLE_SIGMAS, PhotoFitOptions,
    PhotoSpaceFit, SpaceFit,
};
pub use tessellate::{ClippedMesh, MAX_VERTICES, MeshOptions};
pub use texture::{
    AUTOMATIC_COVERAGE, AUTOMATIC_MAX_SIDE, AUTOMATIC_MIN_SIDE, FaceTexture, NO_PHOTO, TexelSource,
    TextureOptions, TexturePhoto, automatic_atlas_side, bake_texture,
};

/// How the reference grid is deformed to an estimated structure (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Deformation {
    /// The paper's: the least-squares affine map `Tr_f` applied to the control grid.
    Affine,
    /// `Tr_f` plus a smooth displacement field through the 40 points' residual displacements,
    /// with thin-plate weight `smoothness` (`λ` of [`SurfaceFit::smoothness`]).
    Local {
        /// The thin-plate weight `λ > 0`.
        smoothness: Real,
    },
}

impl Deformation {
    /// The local mode's default thin-plate weight (see [`Deformation::default`]).
    pub const DEFAULT_SMOOTHNESS: Real = 1e-4;
}

impl Default for Deformation {
    /// The local mode with `λ = 10⁻⁴`.
    ///
    /// Measured by `cargo run --release --example surface_eval` over 20 ICT-FaceKit identities:
    /// each subject's true structure, with Gaussian noise of σ units per coordinate standing in
    /// for a depth estimate's error, deforms the embedded reference; the figure is the mean
    /// height error `|Δz|` over the clipped face, canonical units (50 = eye distance).
    ///
    /// | deformation | σ = 0 | σ = 0.5 | σ = 1 |
    /// |---|---|---|---|
    /// | none (the reference itself) | 2.98 | 2.98 | 2.98 |
    /// | affine (the paper's) | 1.88 | 1.90 | 1.95 |
    /// | local, λ = 10⁻⁶ | 1.32 | 1.48 | 1.87 |
    /// | local, λ = 10⁻⁵ | 1.29 | 1.40 | 1.66 |
    /// | **local, λ = 10⁻⁴** | 1.38 | 1.43 | **1.58** |
    /// | local, λ = 10⁻³ | 1.65 | 1.69 | 1.76 |
    ///
    /// The local mode beats the affine one by 25–30%. Smaller `λ` follows the points more
    /// closely and wins on exact structures, but follows their noise too: the depth stage's
    /// estimates are off by 0.5–1 unit at 1–2% landmark noise, where `10⁻⁴` is within 3% of the
    /// best mean error and has the lowest 90th percentile (2.81 and 3.09 against 10⁻⁵'s 2.90
    /// and 3.38).
    fn default() -> Self {
        Deformation::Local {
            smoothness: Self::DEFAULT_SMOOTHNESS,
        }
    }
}

/// What can go wrong deforming the reference.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum FaceError {
    /// The estimated structure does not have 40 points.
    #[error("the structure has {0} points, expected 40")]
    PointCount(usize),
    /// A point is NaN or infinite.
    #[error("structure point {0} is not finite")]
    NonFinite(usize),
    /// The reference structure spans no volume, so no 3D affine map is determined.
    #[error("the reference structure is (nearly) flat or collinear: no 3D affine map is determined")]
    FlatReference,
    /// The least-squares map is singular or mirrors the face.
    #[error("the estimated structure is {0}: it is not a face seen from the front")]
    Degenerate(&'static str),
    /// An option is out of range.
    #[error("option {name} = {value} is out of range: {expected}")]
    Option {
        /// The option.
        name: &'static str,
        /// Its value.
        value: String,
        /// The range.
        expected: &'static str,
    },
    /// The kernel refused (should not happen with a valid reference).
    #[error("B-spline kernel: {0}")]
    Kernel(#[from] BSplineError),
    /// Triangulating the clip region failed.
    #[error("triangulating the face region: {0}")]
    Triangulation(String),
    /// A face space's inputs do not fit together (see [`FaceSpace::from_displacements`]).
    #[error("face space: {0}")]
    Space(String),
}

impl FaceError {
    /// `Err(`[`FaceError::Option`]`)`: the option `name` has `value`; `expected` says what it
    /// must be. The options' checks share it.
    pub(crate) fn option<T>(
        name: &'static str,
        value: impl std::fmt::Display,
        expected: &'static str,
    ) -> Result<T, Self> {
        Err(FaceError::Option {
            name,
            value: value.to_string(),
            expected,
        })
    }
}

/// How well a deformed surface follows the structure it was deformed to.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeformationReport {
    /// RMS over the 40 points of `‖F₁(pₖ) − (Tr_f(F₀(pₖ)) + dₖ)‖`: how far the surface is from
    /// carrying each reference surface point by the estimated displacement (canonical units).
    /// The affine mode's is the RMS of `dₖ` itself.
    pub displacement_rms: Real,
    /// The largest of the same.
    pub displacement_max: Real,
    /// RMS over the 40 points of `‖F₁(pₖ) − T₁ₖ‖`: how far the surface passes from each
    /// estimated point, including the reference's own landmark-to-surface offset.
    pub point_rms: Real,
}

/// A face surface: the deformed control grid over the reference's parameter domain, with the
/// frame and clip region it inherits and how it was made.
#[derive(Debug, Clone, PartialEq)]
pub struct FaceSurface {
    surface: BSplineSurface,
    frame: FrontalFrame,
    clip: Vec<Point2<Real>>,
    structure: Vec<Point3<Real>>,
    params: Vec<Point2<Real>>,
    transform: Affine3<Real>,
    deformation: Deformation,
    report: DeformationReport,
}

/// The parameters of the reference's structure points: their frontal positions through the
/// reference frame, clamped to the domain.
/// The RMS distance from `structure` to `surface` at the structure's parameters `params`
/// (a [`DeformationReport::point_rms`]).
fn point_rms(
    surface: &BSplineSurface,
    params: &[Point2<Real>],
    structure: &[Point3<Real>],
) -> Result<Real, FaceError> {
    let flat: Vec<[Real; 2]> = params.iter().map(|p| [p.x, p.y]).collect();
    let on_surface = surface.eval_many(&flat)?;
    Ok((on_surface
        .iter()
        .zip(structure)
        .map(|(a, b)| (a - b).norm_squared())
        .sum::<Real>()
        / structure.len().max(1) as Real)
        .sqrt())
}

fn structure_params(reference: &ReferenceFace) -> Vec<Point2<Real>> {
    let frame = reference.frame();
    reference
        .structure()
        .iter()
        .map(|p| {
            let q = frame.parameters(p.x, p.y);
            Point2::new(q.x.clamp(0.0, 1.0), q.y.clamp(0.0, 1.0))
        })
        .collect()
}

/// Checks an estimated structure: 40 finite points.
fn check_structure(points: &[Point3<Real>]) -> Result<(), FaceError> {
    if points.len() != POINT_COUNT {
        return Err(FaceError::PointCount(points.len()));
    }
    match points.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
        Some(k) => Err(FaceError::NonFinite(k)),
        None => Ok(()),
    }
}

/// The least-squares affine map `Tr_f` taking the points `from` onto `to` (the paper's eq. 11):
/// `argmin Σₖ ‖A·fromₖ + t − toₖ‖²`, solved through the centred 3 × 3 normal equations.
///
/// # Errors
/// [`FaceError::PointCount`] or [`FaceError::NonFinite`] for a bad structure,
/// [`FaceError::FlatReference`] when `from` spans no volume (the normal matrix's smallest
/// eigenvalue under 10⁻⁹ of its largest).
pub fn structure_transform(from: &[Point3<Real>], to: &[Point3<Real>]) -> Result<Affine3<Real>, FaceError> {
    check_structure(from)?;
    check_structure(to)?;
    let n = from.len() as Real;
    let centroid = |ps: &[Point3<Real>]| ps.iter().map(|p| p.coords).sum::<Vector3<Real>>() / n;
    let (c0, c1) = (centroid(from), centroid(to));
    let mut xx = Matrix3::zeros();
    let mut xy = Matrix3::zeros();
    for (a, b) in from.iter().zip(to) {
        let (x, y) = (a.coords - c0, b.coords - c1);
        xx += x * x.transpose();
        xy += x * y.transpose();
    }
    let eigen = xx.symmetric_eigenvalues();
    if eigen.min().partial_cmp(&(1e-9 * eigen.max())) != Some(std::cmp::Ordering::Greater) {
        return Err(FaceError::FlatReference);
    }
    // y = Mᵀ x with M = (XᵀX)⁻¹ XᵀY.
    let m = xx.cholesky().ok_or(FaceError::FlatReference)?.solve(&xy);
    let linear = m.transpose();
    let translation = c1 - linear * c0;
    let mut matrix = Matrix4::identity();
    matrix.fixed_view_mut::<3, 3>(0, 0).copy_from(&linear);
    matrix.fixed_view_mut::<3, 1>(0, 3).copy_from(&translation);
    Ok(Affine3::from_matrix_unchecked(matrix))
}

/// `structure` pulled toward the reference's: `S + α (T − S)`, where `T` is `structure` and `S`
/// the reference structure moved onto it by the least-squares similarity over the 31 points
/// off the contour. `α = 1` gives `structure` back; `α = 0` the reference's shape, placed as
/// the estimate is.
///
/// # Errors
/// [`FaceError::PointCount`], [`FaceError::NonFinite`] for a bad structure,
/// [`FaceError::Option`] for `α` outside `[0, 1]`, [`FaceError::FlatReference`] when no
/// similarity is determined.
pub fn shrunk_toward_reference(
    reference: &ReferenceFace,
    structure: &[Point3<Real>],
    alpha: Real,
) -> Result<Vec<Point3<Real>>, FaceError> {
    check_structure(structure)?;
    if !(0.0..=1.0).contains(&alpha) {
        return Err(FaceError::Option {
            name: "structure weight",
            value: alpha.to_string(),
            expected: "between 0 and 1",
        });
    }
    if alpha == 1.0 {
        return Ok(structure.to_vec());
    }
    let inner: Vec<usize> = (0..POINT_COUNT)
        .filter(|&k| crate::structure::POINTS[k].group != crate::structure::Group::Contour)
        .collect();
    let pick = |ps: &[Point3<Real>]| inner.iter().map(|&k| ps[k]).collect::<Vec<_>>();
    let (map, _) = crate::compare::fit_similarity(&pick(reference.structure()), &pick(structure))
        .ok_or(FaceError::FlatReference)?;
    Ok(reference
        .structure()
        .iter()
        .zip(structure)
        .map(|(r, t)| {
            let s = map * r;
            s + alpha * (t - s)
        })
        .collect())
}

impl FaceSurface {
    /// Deforms the reference's control grid to the estimated structure (canonical frame).
    ///
    /// # Errors
    /// [`FaceError::PointCount`], [`FaceError::NonFinite`] for a bad structure;
    /// [`FaceError::FlatReference`]; [`FaceError::Degenerate`] when `Tr_f` is singular or
    /// mirrors (its determinant is not positive, or under 10⁻⁶ of the scale cubed);
    /// [`FaceError::Option`] for a smoothness that is not positive and finite.
    ///
    /// # Examples
    /// ```
    /// use splineface::face::{Deformation, FaceSurface};
    /// use splineface::reference::ReferenceFace;
    ///
    /// let reference = ReferenceFace::embedded();
    /// // A face 10% wider than the reference: x scaled about the origin between the eyes.
    /// let wider: Vec<_> = reference.structure().iter().map(|p| nalgebra::Point3::new(1.1 * p.x, p.y, p.z)).collect();
    /// let face = FaceSurface::deform(reference, &wider, Deformation::Affine).unwrap();
    /// // The affine deformation is that scaling: every point of the surface moved with it.
    /// let (a, b) = (reference.surface().eval(0.4, 0.6).unwrap(), face.surface().eval(0.4, 0.6).unwrap());
    /// assert!((b.x - 1.1 * a.x).abs() < 1e-9 && (b.y - a.y).abs() < 1e-9);
    /// ```
    pub fn deform(
        reference: &ReferenceFace,
        structure: &[Point3<Real>],
        deformation: Deformation,
    ) -> Result<Self, FaceError> {
        let transform = structure_transform(reference.structure(), structure)?;
        let linear = transform.matrix().fixed_view::<3, 3>(0, 0).into_owned();
        let det = linear.determinant();
        let scale = linear.norm() / 3.0_f64.sqrt();
        if det <= 0.0 {
            return Err(FaceError::Degenerate("a mirror image of the reference"));
        }
        if det < 1e-6 * scale.powi(3) {
            return Err(FaceError::Degenerate("flat (the affine map to it is singular)"));
        }
        let frame = *reference.frame();
        let params = structure_params(reference);
        let flat: Vec<[Real; 2]> = params.iter().map(|p| [p.x, p.y]).collect();
        let affine = reference.surface().transformed(&transform);
        let displacements: Vec<Point3<Real>> = reference
            .structure()
            .iter()
            .zip(structure)
            .map(|(t0, t1)| Point3::from(t1 - transform * t0))
            .collect();
        let surface = match deformation {
            Deformation::Affine => affine,
            Deformation::Local { smoothness } => {
                if !(smoothness > 0.0 && smoothness.is_finite()) {
                    return Err(FaceError::Option {
                        name: "smoothness",
                        value: smoothness.to_string(),
                        expected: "positive and finite",
                    });
                }
                let field = SurfaceFit::new(affine.knots_u().clone(), affine.knots_v().clone())
                    .smoothness(smoothness)
                    .fit(&flat, &displacements)?;
                let grid = affine
                    .control_points()
                    .iter()
                    .zip(field.surface.control_points())
                    .map(|(b, d)| b + d.coords)
                    .collect();
                affine.with_control_points(grid)?
            }
        };
        let before = reference.surface().eval_many(&flat)?;
        let after = surface.eval_many(&flat)?;
        let mut report = DeformationReport {
            displacement_rms: 0.0,
            displacement_max: 0.0,
            point_rms: 0.0,
        };
        for k in 0..POINT_COUNT {
            let carried = transform * before[k] + displacements[k].coords;
            let off = (after[k] - carried).norm();
            report.displacement_rms += off * off;
            report.displacement_max = report.displacement_max.max(off);
            report.point_rms += (after[k] - structure[k]).norm_squared();
        }
        report.displacement_rms = (report.displacement_rms / POINT_COUNT as Real).sqrt();
        report.point_rms = (report.point_rms / POINT_COUNT as Real).sqrt();
        Ok(FaceSurface {
            surface,
            frame,
            clip: reference.clip().to_vec(),
            structure: structure.to_vec(),
            params,
            transform,
            deformation,
            report,
        })
    }

    /// The surface, over the reference's parameter domain, in canonical units.
    pub fn surface(&self) -> &BSplineSurface {
        &self.surface
    }

    /// The reference frame the parameters come from.
    pub fn frame(&self) -> &FrontalFrame {
        &self.frame
    }

    /// The face-region clip polygon, in `(u, v)`.
    pub fn clip(&self) -> &[Point2<Real>] {
        &self.clip
    }

    /// The estimated structure the surface was deformed to.
    pub fn structure(&self) -> &[Point3<Real>] {
        &self.structure
    }

    /// The parameters `pₖ` of the 40 points on the surface.
    pub fn structure_params(&self) -> &[Point2<Real>] {
        &self.params
    }

    /// The structure transform `Tr_f`.
    pub fn transform(&self) -> &Affine3<Real> {
        &self.transform
    }

    /// The deformation used.
    pub fn deformation(&self) -> Deformation {
        self.deformation
    }

    /// How well the surface follows the structure.
    pub fn report(&self) -> &DeformationReport {
        &self.report
    }

    /// The surface with every control point moved by `displacement` (row-major), the same
    /// structure; its report's `point_rms` says how far the moved surface passes from it (as
    /// [`crate::face::FaceSpace::refine_photos`]'s displacement field is applied).
    ///
    /// # Errors
    /// [`FaceError::Option`] unless there is one displacement per control point;
    /// [`FaceError::Kernel`] for one that is not finite.
    pub fn displaced(&self, displacement: &[nalgebra::Vector3<Real>]) -> Result<Self, FaceError> {
        if displacement.len() != self.surface.control_points().len() {
            return Err(FaceError::Option {
                name: "displacement",
                value: displacement.len().to_string(),
                expected: "one per control point",
            });
        }
        let controls = self
            .surface
            .control_points()
            .iter()
            .zip(displacement)
            .map(|(c, d)| c + d)
            .collect();
        let surface = self.surface.with_control_points(controls)?;
        let point_rms = point_rms(&surface, &self.params, &self.structure)?;
        Ok(FaceSurface {
            surface,
            report: DeformationReport {
                point_rms,
                ..self.report
            },
            ..self.clone()
        })
    }

    /// The surface mapped by `transform` (for units and views), with its structure.
    pub fn transformed(&self, transform: &Affine3<Real>) -> Self {
        FaceSurface {
            surface: self.surface.transformed(transform),
            structure: self.structure.iter().map(|p| transform * p).collect(),
            ..self.clone()
        }
    }
}

/// The distance between the eye centres that millimetre outputs assume unless told otherwise:
/// 63 mm, a typical adult's interpupillary distance. Photos do not fix a face's size; this
/// sets it.
pub const DEFAULT_EYE_DISTANCE_MM: Real = 63.0;

/// Output units (the canonical frame has 50 units between the eye centres).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Units {
    /// Millimetres, taking the distance between the eye centres as given (in mm).
    Millimetres {
        /// The eye distance in millimetres; [`DEFAULT_EYE_DISTANCE_MM`] by default.
        eye_distance: Real,
    },
    /// The paper's canonical units.
    Canonical,
}

impl Default for Units {
    /// Millimetres with [`DEFAULT_EYE_DISTANCE_MM`] between the eye centres.
    fn default() -> Self {
        Units::Millimetres {
            eye_distance: DEFAULT_EYE_DISTANCE_MM,
        }
    }
}

impl Units {
    /// Output units per canonical unit.
    pub fn per_canonical_unit(&self) -> Real {
        match self {
            Units::Millimetres { eye_distance } => eye_distance / (2.0 * crate::structure::HALF_EYE_DISTANCE),
            Units::Canonical => 1.0,
        }
    }

    /// The uniform scaling from canonical units to these.
    pub fn transform(&self) -> Affine3<Real> {
        Affine3::from_matrix_unchecked(Matrix4::new_nonuniform_scaling(&Vector3::repeat(
            self.per_canonical_unit(),
        )))
    }

    /// The unit's name as written in reports.
    pub fn name(&self) -> &'static str {
        match self {
            Units::Millimetres { .. } => "mm",
            Units::Canonical => "canonical (50 = eye distance)",
        }
    }
}

/// The unchanged mean face: the reference's own surface and structures in output units, the
/// baseline every reconstruction is scored beside (a reconstruction's error means little
/// alone; one that does not beat this face has learned nothing from the photos).
#[derive(Debug, Clone)]
pub struct MeanFace {
    /// The reference's clipped mesh, in the units asked for.
    pub mesh: crate::mesh::TriangleMesh,
    /// Its 40-point structure at its landmark vertices ([`ReferenceFace::structure`]).
    pub structure: Vec<Point3<Real>>,
    /// Its 40-point structure as the photo path places it ([`ReferenceFace::photo_structure`]):
    /// what aligns it to a truth whose landmarks a landmarker found, as a reconstruction's
    /// structure would be.
    pub photo_structure: Vec<Point3<Real>>,
}

impl MeanFace {
    /// `reference` unchanged, meshed with `mesh` and scaled to `units`.
    ///
    /// # Errors
    /// As [`FaceSurface::deform`] and [`FaceSurface::mesh`] (a reference that loaded does not
    /// fail; a spacing out of range does).
    ///
    /// # Examples
    /// ```
    /// use splineface::face::{MeanFace, MeshOptions, Units};
    /// use splineface::reference::ReferenceFace;
    ///
    /// let mean = MeanFace::new(ReferenceFace::embedded(), Units::default(), &MeshOptions::default()).unwrap();
    /// // 40 points, 63 mm between the eye centres.
    /// let eyes = mean.structure[splineface::structure::LEFT_EYE_CENTRE]
    ///     - mean.structure[splineface::structure::RIGHT_EYE_CENTRE];
    /// assert!((eyes.norm() - 63.0).abs() < 1e-9);
    /// assert!(mean.mesh.triangles().len() > 1000);
    /// ```
    pub fn new(reference: &ReferenceFace, units: Units, mesh: &MeshOptions) -> Result<Self, FaceError> {
        let scale = units.per_canonical_unit();
        let scaled = |points: &[Point3<Real>]| points.iter().map(|p| p * scale).collect::<Vec<_>>();
        Ok(MeanFace {
            mesh: FaceSurface::deform(reference, reference.structure(), Deformation::Affine)?
                .mesh(mesh)?
                .mesh
                .transformed(&units.transform()),
            structure: scaled(reference.structure()),
            photo_structure: scaled(reference.photo_structure()),
        })
    }
}
