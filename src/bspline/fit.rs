//! Least-squares fitting of a surface's control grid to scattered samples.

use nalgebra::Point3;
use rayon::prelude::*;

use super::BSplineError;
use super::band::SymmetricBand;
use super::basis::{basis_derivatives, width};
use super::knots::{KnotVector, MAX_DEGREE};
use super::surface::{BSplineSurface, check_parameter};
use crate::Real;

/// The largest banded normal matrix (in stored entries) a fit may build: 2²⁸ entries, 2 GiB.
/// A cubic 256 × 256 grid needs 5·10⁷.
const MAX_BAND_ENTRIES: usize = 1 << 28;

/// Least-squares fit of a B-spline surface's control grid to scattered 3D samples at given
/// parameters.
///
/// With samples `fₛ` at parameters `(uₛ, vₛ)` and weights `wₛ` (default 1), the control grid
/// `B` minimises
///
/// ```text
/// E(B) = (1/W) Σₛ wₛ ‖F(uₛ, vₛ) − fₛ‖²  +  λ · J(B),      W = Σₛ wₛ
/// ```
///
/// where `J` is the thin-plate energy `∬ F_uu² + 2F_uv² + F_vv²` over the domain mapped to the
/// unit square, discretised on the control net with divided differences at the Greville
/// abscissae (the P-spline idea of Eilers & Marx, made exact for planes). Choices and why:
///
/// * `J` vanishes exactly on affine functions of `(u, v)`, so a planar target stays exactly
///   planar whatever `λ`, and cells with no samples are filled by the smoothest continuation.
/// * `E` is invariant to the number of samples, to scaling the weights and to scaling the
///   geometry, so `λ` means the same on any data. `λ = 0` is pure least squares. Measured on
///   `z = u·v` sampled over the whole unit square (cubic, 10 × 10 grid), whose interior a thin
///   plate reproduces exactly, so that all the deviation is the plate's free-boundary layer:
///   `λ = 10⁻⁹` moves the fit by at most `4·10⁻⁵`, `10⁻⁶` by `3·10⁻³`, `10⁻³` by `7·10⁻²`.
///   Small values (`10⁻⁹`–`10⁻⁷`) are the ones that only define otherwise empty cells.
/// * The system is solved through its normal equations, whose conditioning grows with `λ`: a
///   plane is reproduced to `10⁻¹²` for `λ ≤ 10⁻³`, `10⁻⁹` at `λ = 1`, `3·10⁻⁷` at `λ = 10³`
///   (relative to the geometry). Values above 1 are rarely useful anyway.
///
/// How it is computed: the samples are sorted by knot cell; inside a cell every basis function
/// is a polynomial in the cell's local parameters `(t, s)`, written in the scaled Bernstein
/// basis where B-splines have non-negative coefficients, so each cell only accumulates the
/// moments `Σ w·tᵐ(1−t)²ᵖ⁻ᵐ·sⁿ(1−s)²q⁻ⁿ` (`(2p+1)(2q+1)` multiply-adds per sample, no basis
/// evaluation, no cancellation) and converts them to its block of the normal equations once.
/// The unknowns are numbered along the shorter grid dimension so the normal matrix is banded,
/// and a banded Cholesky factorisation solves it. The result is deterministic: the same input
/// gives the same bits on any number of threads.
///
/// # Examples
///
/// ```
/// use nalgebra::Point3;
/// use splineface::bspline::{KnotVector, SurfaceFit};
///
/// // Samples of the saddle z = x·y on a 30 × 30 grid of the unit square.
/// let mut params = Vec::new();
/// let mut points = Vec::new();
/// for i in 0..30 {
///     for j in 0..30 {
///         let (u, v) = (i as f64 / 29.0, j as f64 / 29.0);
///         params.push([u, v]);
///         points.push(Point3::new(u, v, u * v));
///     }
/// }
/// let knots = KnotVector::clamped_uniform(3, 8, 0.0, 1.0)?;
/// let fitted = SurfaceFit::new(knots.clone(), knots).fit(&params, &points)?;
/// // x·y is a bicubic polynomial, so the fit is exact to rounding.
/// assert!(fitted.report.max < 1e-12);
/// let p = fitted.surface.eval(0.3, 0.7)?;
/// assert!((p.z - 0.21).abs() < 1e-12);
/// # Ok::<(), splineface::bspline::BSplineError>(())
/// ```
#[derive(Debug, Clone)]
pub struct SurfaceFit<'a> {
    knots_u: KnotVector,
    knots_v: KnotVector,
    smoothness: Real,
    weights: Option<&'a [Real]>,
    keep_residuals: bool,
}

/// A fitted surface and how well it fits.
#[derive(Debug, Clone, PartialEq)]
pub struct FittedSurface {
    /// The surface whose control grid minimises the fitting objective.
    pub surface: BSplineSurface,
    /// Residuals of the samples.
    pub report: FitReport,
    /// Each sample's residual `‖F(uₛ, vₛ) − fₛ‖`, in the samples' order, when
    /// [`SurfaceFit::keep_residuals`] asked for them (the report's figures come from the same
    /// evaluation); empty otherwise.
    pub residuals: Vec<Real>,
}

/// Residuals of a fit, as distances `‖F(uₛ, vₛ) − fₛ‖` over all samples (weights ignored, so
/// the figures mean the same whatever the weighting).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FitReport {
    /// Samples fitted.
    pub samples: usize,
    /// Root mean square distance.
    pub rms: Real,
    /// Largest distance.
    pub max: Real,
    /// Index of the sample with the largest distance.
    pub max_index: usize,
    /// The smoothness weight `λ` used.
    pub smoothness: Real,
}

impl<'a> SurfaceFit<'a> {
    /// A fit onto the given knot vectors (which fix degrees and grid size), with no smoothing
    /// and unit weights.
    pub fn new(knots_u: KnotVector, knots_v: KnotVector) -> Self {
        SurfaceFit {
            knots_u,
            knots_v,
            smoothness: 0.0,
            weights: None,
            keep_residuals: false,
        }
    }

    /// Sets the smoothness weight `λ ≥ 0` (see the type's documentation). Validated by
    /// [`SurfaceFit::fit`].
    pub fn smoothness(mut self, lambda: Real) -> Self {
        self.smoothness = lambda;
        self
    }

    /// Keeps every sample's residual in [`FittedSurface::residuals`] (8 bytes a sample), for a
    /// caller that needs them one by one, without evaluating the surface again.
    pub fn keep_residuals(mut self) -> Self {
        self.keep_residuals = true;
        self
    }

    /// Sets one weight `wₛ ≥ 0` per sample. Validated by [`SurfaceFit::fit`].
    pub fn weights(mut self, weights: &'a [Real]) -> Self {
        self.weights = Some(weights);
        self
    }

    /// Fits the control grid to `points[s]` at `params[s] = [uₛ, vₛ]`.
    ///
    /// # Errors
    /// * [`BSplineError::NoSamples`], [`BSplineError::SampleCountMismatch`],
    ///   [`BSplineError::NonFiniteSample`], [`BSplineError::InvalidSampleParameter`],
    ///   [`BSplineError::InvalidWeight`], [`BSplineError::InvalidSmoothness`] for bad input;
    /// * [`BSplineError::Underdetermined`] when the samples leave a control point free (without
    ///   smoothing: some control point has no sample in its support, or too few);
    /// * [`BSplineError::SystemTooLarge`] for a grid whose banded system exceeds 2²⁸ entries.
    pub fn fit(&self, params: &[[Real; 2]], points: &[Point3<Real>]) -> Result<FittedSurface, BSplineError> {
        self.validate(params, points)?;
        let layout = Layout::new(&self.knots_u, &self.knots_v, self.smoothness > 0.0);
        let entries = SymmetricBand::entries(layout.unknowns(), layout.bandwidth);
        if entries > MAX_BAND_ENTRIES {
            return Err(BSplineError::SystemTooLarge {
                rows: layout.rows,
                cols: layout.cols,
                entries,
                limit: MAX_BAND_ENTRIES,
            });
        }

        let cells = self.accumulate(params, points)?;
        let (mut normal, mut rhs) = layout.assemble(&cells);
        let total_weight = self.weights.map_or(points.len() as Real, |w| w.iter().sum());
        if self.smoothness > 0.0 {
            let penalty = layout.thin_plate_penalty(&self.knots_u, &self.knots_v);
            normal.add_scaled(&penalty, self.smoothness * total_weight);
        }
        let hint = if self.smoothness > 0.0 {
            "; even with smoothing the samples must span more than a line"
        } else {
            "; add samples in its support or set a smoothness weight"
        };
        let factor = normal.cholesky().map_err(|unknown| {
            let (row, col) = layout.grid_position(unknown);
            BSplineError::Underdetermined { row, col, hint }
        })?;
        factor.solve_in_place(&mut rhs);

        let mut control = vec![Point3::origin(); layout.unknowns()];
        for (unknown, x) in rhs.iter().enumerate() {
            let (row, col) = layout.grid_position(unknown);
            control[row * layout.cols + col] = Point3::new(x[0], x[1], x[2]);
        }
        // The solve of a well-posed system cannot produce non-finite values, but a barely
        // posed one could overflow: `new` checks and reports it.
        let surface = BSplineSurface::new(
            self.knots_u.clone(),
            self.knots_v.clone(),
            layout.rows,
            layout.cols,
            control,
        )?;
        let mut kept = vec![0.0; if self.keep_residuals { points.len() } else { 0 }];
        let report = residuals(&surface, params, points, self.smoothness, &mut kept)?;
        Ok(FittedSurface {
            surface,
            report,
            residuals: kept,
        })
    }

    fn validate(&self, params: &[[Real; 2]], points: &[Point3<Real>]) -> Result<(), BSplineError> {
        if params.is_empty() {
            return Err(BSplineError::NoSamples);
        }
        if params.len() != points.len() {
            return Err(BSplineError::SampleCountMismatch {
                params: params.len(),
                values: points.len(),
                what: "points",
            });
        }
        if !(self.smoothness >= 0.0 && self.smoothness.is_finite()) {
            return Err(BSplineError::InvalidSmoothness {
                value: self.smoothness,
            });
        }
        if let Some(w) = self.weights {
            if w.len() != params.len() {
                return Err(BSplineError::SampleCountMismatch {
                    params: params.len(),
                    values: w.len(),
                    what: "weights",
                });
            }
            if let Some((index, &value)) = w.iter().enumerate().find(|(_, w)| !(**w >= 0.0 && w.is_finite()))
            {
                return Err(BSplineError::InvalidWeight { index, value });
            }
        }
        if let Some(index) = points
            .iter()
            .position(|p| !p.coords.iter().all(|c| c.is_finite()))
        {
            return Err(BSplineError::NonFiniteSample { index });
        }
        Ok(())
    }

    /// The knot cell of every sample, `(su − p)·cells_v + (sv − q)`, or the error for the first
    /// sample whose parameter is invalid.
    fn locate(&self, params: &[[Real; 2]], shape: &CellShape) -> Result<Vec<u32>, BSplineError> {
        params
            .iter()
            .enumerate()
            .map(|(index, &[u, v])| {
                check_parameter(&self.knots_u, &self.knots_v, u, v).map_err(|source| {
                    BSplineError::InvalidSampleParameter {
                        index,
                        source: Box::new(source),
                    }
                })?;
                let (su, sv) = (self.knots_u.span_in_domain(u), self.knots_v.span_in_domain(v));
                // Fits in u32: the band-size limit caps the grid far below 2³² cells.
                Ok(((su - shape.p) * shape.cells_v + sv - shape.q) as u32)
            })
            .collect()
    }

    /// Per-cell sums of the normal-equation terms. The samples are counting-sorted by knot
    /// cell (stably), so that each cell's sums stay in cache while its samples are added, and
    /// the cells are summed in parallel into disjoint slots; each cell adds its samples in
    /// input order, so the sums are the same bits on any number of threads.
    fn accumulate(&self, params: &[[Real; 2]], points: &[Point3<Real>]) -> Result<CellSums, BSplineError> {
        let shape = CellShape::new(&self.knots_u, &self.knots_v);
        let cell_of = self.locate(params, &shape)?;
        let cells = shape.cells_u * shape.cells_v;
        let mut offsets = vec![0u32; cells + 1];
        for &c in &cell_of {
            offsets[c as usize + 1] += 1;
        }
        for c in 0..cells {
            offsets[c + 1] += offsets[c];
        }
        let mut order = vec![0u32; params.len()];
        let mut next = offsets.clone();
        for (s, &c) in cell_of.iter().enumerate() {
            order[next[c as usize] as usize] = s as u32;
            next[c as usize] += 1;
        }
        // Gathered copies in cell order: the random reads happen here, in a loop simple enough
        // for the processor to overlap them, instead of inside the arithmetic.
        let params: Vec<[Real; 2]> = order.iter().map(|&s| params[s as usize]).collect();
        let points: Vec<Point3<Real>> = order.iter().map(|&s| points[s as usize]).collect();
        let weights: Option<Vec<Real>> = self
            .weights
            .map(|w| order.iter().map(|&s| w[s as usize]).collect());
        let mut sums = CellSums::zeros(shape);
        let samples = Samples {
            params: &params,
            points: &points,
            weights: weights.as_deref(),
            offsets: &offsets,
        };
        let polynomials = (
            &SpanPolynomials::new(&self.knots_u),
            &SpanPolynomials::new(&self.knots_v),
        );
        with_widths!(shape.p, shape.q, sums.add_samples(polynomials, &samples));
        Ok(sums)
    }
}

/// The samples of a fit sorted by knot cell: cell `c`'s samples are `offsets[c]..offsets[c + 1]`.
struct Samples<'a> {
    params: &'a [[Real; 2]],
    points: &'a [Point3<Real>],
    weights: Option<&'a [Real]>,
    offsets: &'a [u32],
}

/// Sizes of the per-cell accumulators for degrees `(p, q)`.
#[derive(Debug, Clone, Copy)]
struct CellShape {
    p: usize,
    q: usize,
    cells_u: usize,
    cells_v: usize,
    /// Symmetric pairs `(a ≤ c)` of `u` basis functions: `(p+1)(p+2)/2`.
    pairs_u: usize,
    /// Same in `v`.
    pairs_v: usize,
}

impl CellShape {
    fn new(knots_u: &KnotVector, knots_v: &KnotVector) -> Self {
        let (p, q) = (knots_u.degree(), knots_v.degree());
        CellShape {
            p,
            q,
            cells_u: knots_u.num_control_points() - p,
            cells_v: knots_v.num_control_points() - q,
            pairs_u: (p + 1) * (p + 2) / 2,
            pairs_v: (q + 1) * (q + 2) / 2,
        }
    }

    /// Values per cell: the Gram products, then the right-hand sides.
    fn per_cell(&self) -> usize {
        self.pairs_u * self.pairs_v + 3 * (self.p + 1) * (self.q + 1)
    }

    fn len(&self) -> usize {
        self.cells_u * self.cells_v * self.per_cell()
    }
}

/// For each knot cell `(su − p, sv − q)`: `Σ w·Nₐ(u)N_c(u)·N_b(v)N_d(v)` for `a ≤ c`, `b ≤ d`,
/// and `Σ w·Nₐ(u)N_b(v)·f`.
struct CellSums {
    shape: CellShape,
    data: Vec<Real>,
}

impl CellSums {
    fn zeros(shape: CellShape) -> Self {
        CellSums {
            shape,
            data: vec![0.0; shape.len()],
        }
    }

    fn add_samples<const NU: usize, const NV: usize>(
        &mut self,
        polynomials: (&SpanPolynomials, &SpanPolynomials),
        samples: &Samples<'_>,
    ) {
        let shape = self.shape;
        let (wu, wv) = (width::<NU>(shape.p), width::<NV>(shape.q));
        // Moments of degree 2p × 2q for the Gram entries, p × q for the right-hand sides.
        let (mu, mv) = (2 * wu - 1, 2 * wv - 1);
        let (pairs_u, pairs_v) = (wu * (wu + 1) / 2, wv * (wv + 1) / 2);
        let gram_len = pairs_u * pairs_v;
        let (poly_u, poly_v) = polynomials;
        self.data
            .par_chunks_mut(shape.per_cell())
            .enumerate()
            .for_each_init(
                || vec![0.0; pairs_u * mv],
                |half, (cell, acc)| {
                    let members = samples.offsets[cell] as usize..samples.offsets[cell + 1] as usize;
                    if members.is_empty() {
                        return;
                    }
                    let (cu, cv) = (cell / shape.cells_v, cell % shape.cells_v);
                    let (u0, iu) = (poly_u.starts[cu], poly_u.inverse_widths[cu]);
                    let (v0, iv) = (poly_v.starts[cv], poly_v.inverse_widths[cv]);
                    // Σ w·tᵐ(1−t)^(2p−m)·sⁿ(1−s)^(2q−n) and Σ w·f·tⁱ(1−t)^(p−i)·sʲ(1−s)^(q−j): all
                    // terms non-negative. Arrays sized from the const widths (4·NU·NV ≥ mu·mv).
                    let mut moments = [[[0.0; NV]; NU]; 4];
                    let moments = &mut moments.as_flattened_mut().as_flattened_mut()[..mu * mv];
                    let mut first = [[[0.0; NV]; NU]; 3];
                    let first = &mut first.as_flattened_mut().as_flattened_mut()[..3 * wu * wv];
                    for s in members {
                        let [u, v] = samples.params[s];
                        let w = samples.weights.map_or(1.0, |w| w[s]);
                        let t = ((u - u0) * iu).clamp(0.0, 1.0);
                        let r = ((v - v0) * iv).clamp(0.0, 1.0);
                        let bu = scaled_bernstein::<NU>(t, w, wu);
                        let bv = scaled_bernstein::<NV>(r, 1.0, wv);
                        for (row, &x) in moments.chunks_exact_mut(mv).zip(&bu.0.as_flattened()[..mu]) {
                            for (m, &y) in row.iter_mut().zip(&bv.0.as_flattened()[..mv]) {
                                *m += x * y;
                            }
                        }
                        let f = samples.points[s].coords;
                        for (row, &x) in first.chunks_exact_mut(3 * wv).zip(&bu.1[..wu]) {
                            for (m, &y) in row.chunks_exact_mut(3).zip(&bv.1[..wv]) {
                                let c = x * y;
                                m[0] += c * f.x;
                                m[1] += c * f.y;
                                m[2] += c * f.z;
                            }
                        }
                    }
                    // Gram: Σₘ Σₙ A[ac][m]·M[m][n]·B[bd][n], in two products.
                    let (gram, rhs) = acc.split_at_mut(gram_len);
                    let (pa, pb) = (poly_u.pair_coefficients(cu), poly_v.pair_coefficients(cv));
                    for (h, a) in half.chunks_exact_mut(mv).zip(pa.chunks_exact(mu)) {
                        for (n, hn) in h.iter_mut().enumerate() {
                            *hn = a
                                .iter()
                                .enumerate()
                                .map(|(m, &am)| am * moments[m * mv + n])
                                .sum();
                        }
                    }
                    for (g, h) in gram.chunks_exact_mut(pairs_v).zip(half.chunks_exact(mv)) {
                        for (gv, b) in g.iter_mut().zip(pb.chunks_exact(mv)) {
                            *gv = h.iter().zip(b).map(|(x, y)| x * y).sum();
                        }
                    }
                    // Right-hand sides: Σᵢ Σⱼ Du[a][i]·F[i][j]·Dv[b][j].
                    let (du, dv) = (poly_u.coefficients(cu), poly_v.coefficients(cv));
                    for a in 0..wu {
                        for b in 0..wv {
                            let mut sum = [0.0; 3];
                            for i in 0..wu {
                                for j in 0..wv {
                                    let c = du[a * wu + i] * dv[b * wv + j];
                                    let fij = &first[(i * wv + j) * 3..][..3];
                                    for k in 0..3 {
                                        sum[k] += c * fij[k];
                                    }
                                }
                            }
                            rhs[(a * wv + b) * 3..][..3].copy_from_slice(&sum);
                        }
                    }
                },
            );
    }
}

/// `(w·tᵐ(1−t)^(2p−m) for m ≤ 2p, w·tⁱ(1−t)^(p−i) for i ≤ p)` with `p = width − 1`, in arrays
/// sized from the const width `N` (`2N ≥ 2p + 1`).
#[inline(always)]
fn scaled_bernstein<const N: usize>(t: Real, w: Real, width: usize) -> ([[Real; N]; 2], [Real; N]) {
    let p = width - 1;
    let mut up = [[0.0; N]; 2];
    let mut down = [[0.0; N]; 2];
    let (up, down) = (up.as_flattened_mut(), down.as_flattened_mut());
    up[0] = 1.0;
    down[0] = 1.0;
    for k in 1..2 * p + 1 {
        up[k] = up[k - 1] * t;
        down[k] = down[k - 1] * (1.0 - t);
    }
    let mut twice = [[0.0; N]; 2];
    for (m, b) in twice.as_flattened_mut()[..2 * p + 1].iter_mut().enumerate() {
        *b = w * up[m] * down[2 * p - m];
    }
    let mut once = [0.0; N];
    for (i, b) in once[..p + 1].iter_mut().enumerate() {
        *b = w * up[i] * down[p - i];
    }
    (twice, once)
}

/// The basis functions of one direction on each knot span, as polynomials in the span's local
/// parameter `t = (u − u_i)/(u_{i+1} − u_i) ∈ [0, 1]`, in the scaled Bernstein basis
/// `tⁱ(1 − t)ᵖ⁻ⁱ`: `N_{span−p+a}(u) = Σᵢ D[a][i]·tⁱ(1 − t)ᵖ⁻ⁱ`. B-splines have non-negative
/// Bernstein coefficients on every span (Bézier extraction), so sums built from them do not
/// cancel.
struct SpanPolynomials {
    degree: usize,
    /// Per cell (span − p): `u_i` and `1/(u_{i+1} − u_i)` (zero for an empty span).
    starts: Vec<Real>,
    inverse_widths: Vec<Real>,
    /// Per cell, `(p + 1) × (p + 1)`: `D[a][i]`.
    coefficients: Vec<Real>,
    /// Per cell, `pairs × (2p + 1)`: the coefficients of `N_a·N_c` (`a ≤ c`, `pair_index`
    /// order) in the basis `tᵐ(1 − t)²ᵖ⁻ᵐ`, `Σ_{i+j=m} D[a][i]·D[c][j]`.
    pair_coefficients: Vec<Real>,
}

impl SpanPolynomials {
    fn new(knots: &KnotVector) -> Self {
        let p = knots.degree();
        let w = p + 1;
        let pairs = w * (w + 1) / 2;
        let k = knots.knots();
        let cells = knots.num_control_points() - p;
        let mut starts = vec![0.0; cells];
        let mut inverse_widths = vec![0.0; cells];
        let mut coefficients = vec![0.0; cells * w * w];
        let mut pair_coefficients = vec![0.0; cells * pairs * (2 * p + 1)];
        let mut derivatives = vec![0.0; w * w];
        for cell in 0..cells {
            let span = cell + p;
            let h = k[span + 1] - k[span];
            starts[cell] = k[span];
            if h == 0.0 {
                continue;
            }
            inverse_widths[cell] = 1.0 / h;
            // Power coefficients in t from the derivatives at the span's start, then the
            // power-to-Bernstein conversion cᵢ = Σ_{k≤i} C(i,k)/C(p,k)·aₖ, scaled by C(p,i).
            basis_derivatives(knots, span, k[span], p, &mut derivatives);
            let d = &mut coefficients[cell * w * w..(cell + 1) * w * w];
            for a in 0..w {
                let mut power = [0.0; MAX_DEGREE + 1];
                let mut scale = 1.0; // h^k / k!
                for (kk, c) in power[..w].iter_mut().enumerate() {
                    *c = derivatives[kk * w + a] * scale;
                    scale *= h / (kk + 1) as Real;
                }
                for i in 0..w {
                    let bernstein: Real = (0..=i)
                        .map(|kk| binomial(i, kk) / binomial(p, kk) * power[kk])
                        .sum();
                    d[a * w + i] = bernstein * binomial(p, i);
                }
            }
            let pc = &mut pair_coefficients[cell * pairs * (2 * p + 1)..(cell + 1) * pairs * (2 * p + 1)];
            for a in 0..w {
                for c in a..w {
                    let row = &mut pc[pair_index(a, c, p) * (2 * p + 1)..][..2 * p + 1];
                    for i in 0..w {
                        for j in 0..w {
                            row[i + j] += d[a * w + i] * d[c * w + j];
                        }
                    }
                }
            }
        }
        SpanPolynomials {
            degree: p,
            starts,
            inverse_widths,
            coefficients,
            pair_coefficients,
        }
    }

    fn coefficients(&self, cell: usize) -> &[Real] {
        let w = self.degree + 1;
        &self.coefficients[cell * w * w..(cell + 1) * w * w]
    }

    fn pair_coefficients(&self, cell: usize) -> &[Real] {
        let w = self.degree + 1;
        let len = w * (w + 1) / 2 * (2 * self.degree + 1);
        &self.pair_coefficients[cell * len..(cell + 1) * len]
    }
}

/// `C(n, k)` as a real (n ≤ 2·MAX_DEGREE, exact in f64).
fn binomial(n: usize, k: usize) -> Real {
    (0..k).fold(1.0, |acc, i| acc * (n - i) as Real / (i + 1) as Real)
}

/// Index of the pair `(min(a, c), max(a, c))` among the upper-triangle pairs of `0..=p`.
#[inline]
fn pair_index(a: usize, c: usize, p: usize) -> usize {
    let (a, c) = if a <= c { (a, c) } else { (c, a) };
    // Rows 0..a hold (p+1) + p + … + (p+2−a) pairs.
    a * (2 * p + 3 - a) / 2 + (c - a)
}

/// How control points are numbered as unknowns: along the shorter grid dimension, so the
/// normal matrix has the smaller bandwidth.
struct Layout {
    rows: usize,
    cols: usize,
    p: usize,
    q: usize,
    /// Unknown index of `(i, j)` is `i·stride_i + j·stride_j`.
    stride_i: usize,
    stride_j: usize,
    bandwidth: usize,
}

impl Layout {
    fn new(knots_u: &KnotVector, knots_v: &KnotVector, smoothing: bool) -> Self {
        let (rows, cols) = (knots_u.num_control_points(), knots_v.num_control_points());
        let (p, q) = (knots_u.degree(), knots_v.degree());
        // Half-bandwidth when `i` is the slow index with stride `cols` (the other case is
        // symmetric): data couple |Δi| ≤ p, |Δj| ≤ q; the penalty couples (±2, 0), (0, ±2)
        // and (±1, ±1).
        let width = |slow_deg: usize, fast_deg: usize, fast_len: usize| {
            let data = slow_deg * fast_len + fast_deg;
            if smoothing {
                data.max(2 * fast_len).max(fast_len + 1).max(2)
            } else {
                data
            }
        };
        let row_major = width(p, q, cols);
        let col_major = width(q, p, rows);
        let (stride_i, stride_j, bandwidth) = if row_major <= col_major {
            (cols, 1, row_major)
        } else {
            (1, rows, col_major)
        };
        Layout {
            rows,
            cols,
            p,
            q,
            stride_i,
            stride_j,
            bandwidth: bandwidth.min(rows * cols - 1),
        }
    }

    fn unknowns(&self) -> usize {
        self.rows * self.cols
    }

    #[inline(always)]
    fn unknown(&self, i: usize, j: usize) -> usize {
        i * self.stride_i + j * self.stride_j
    }

    fn grid_position(&self, unknown: usize) -> (usize, usize) {
        if self.stride_j == 1 {
            (unknown / self.cols, unknown % self.cols)
        } else {
            (unknown % self.rows, unknown / self.rows)
        }
    }

    /// Scatters the per-cell sums into the banded normal matrix and the right-hand sides.
    fn assemble(&self, cells: &CellSums) -> (SymmetricBand, Vec<[Real; 3]>) {
        let shape = cells.shape;
        let (p, q) = (self.p, self.q);
        let per_cell = shape.per_cell();
        let gram_len = shape.pairs_u * shape.pairs_v;
        let mut normal = SymmetricBand::zeros(self.unknowns(), self.bandwidth);
        let mut rhs = vec![[0.0; 3]; self.unknowns()];
        for ci in 0..shape.cells_u {
            for cj in 0..shape.cells_v {
                let cell = ci * shape.cells_v + cj;
                let acc = &cells.data[cell * per_cell..(cell + 1) * per_cell];
                if acc.iter().all(|&x| x == 0.0) {
                    continue;
                }
                let (gram, sums) = acc.split_at(gram_len);
                for a in 0..=p {
                    for b in 0..=q {
                        let g1 = self.unknown(ci + a, cj + b);
                        let r = 3 * (a * (q + 1) + b);
                        for d in 0..3 {
                            rhs[g1][d] += sums[r + d];
                        }
                        for c in 0..=p {
                            for e in 0..=q {
                                let g2 = self.unknown(ci + c, cj + e);
                                if g2 <= g1 {
                                    let value =
                                        gram[pair_index(a, c, p) * shape.pairs_v + pair_index(b, e, q)];
                                    normal.add(g1, g2, value);
                                }
                            }
                        }
                    }
                }
            }
        }
        (normal, rhs)
    }

    /// The discrete thin-plate energy `J` as a quadratic form on the control net (same for
    /// x, y and z): `Σ h_u h_v (D_uu² + 2 D_uv² + D_vv²)` with divided differences over the
    /// Greville abscissae of the domain mapped to `[0, 1]`.
    fn thin_plate_penalty(&self, knots_u: &KnotVector, knots_v: &KnotVector) -> SymmetricBand {
        let gu = unit_greville(knots_u);
        let gv = unit_greville(knots_v);
        let (rows, cols) = (self.rows, self.cols);
        let area = 1.0 / ((rows - 1).max(1) * (cols - 1).max(1)) as Real;
        let mut penalty = SymmetricBand::zeros(self.unknowns(), self.bandwidth);
        let mut add_term = |terms: &[(usize, Real)], weight: Real| {
            for &(g1, c1) in terms {
                for &(g2, c2) in terms {
                    if g2 <= g1 {
                        penalty.add(g1, g2, weight * c1 * c2);
                    }
                }
            }
        };
        // D_uu along each column, D_vv along each row.
        for (g, len, along_u) in [(&gu, rows, true), (&gv, cols, false)] {
            for k in 1..len.saturating_sub(1) {
                let c = second_divided_difference(g[k - 1], g[k], g[k + 1]);
                let others = if along_u { cols } else { rows };
                for o in 0..others {
                    let at = |kk: usize| {
                        if along_u {
                            self.unknown(kk, o)
                        } else {
                            self.unknown(o, kk)
                        }
                    };
                    add_term(&[(at(k - 1), c[0]), (at(k), c[1]), (at(k + 1), c[2])], area);
                }
            }
        }
        // D_uv on each grid quad.
        for i in 0..rows.saturating_sub(1) {
            for j in 0..cols.saturating_sub(1) {
                let c = 1.0 / ((gu[i + 1] - gu[i]) * (gv[j + 1] - gv[j]));
                add_term(
                    &[
                        (self.unknown(i, j), c),
                        (self.unknown(i + 1, j), -c),
                        (self.unknown(i, j + 1), -c),
                        (self.unknown(i + 1, j + 1), c),
                    ],
                    2.0 * area,
                );
            }
        }
        penalty
    }
}

/// Greville abscissae mapped to `[0, 1]`; equally spaced instead when they are not strictly
/// increasing (knots of multiplicity `p + 1` inside the domain), where divided differences
/// over them would be undefined.
fn unit_greville(knots: &KnotVector) -> Vec<Real> {
    let g = knots.greville();
    let n = g.len();
    let increasing = g.windows(2).all(|w| w[1] > w[0]);
    if n < 2 || !increasing {
        return (0..n).map(|i| i as Real / (n.max(2) - 1) as Real).collect();
    }
    let (lo, hi) = (g[0], g[n - 1]);
    g.iter().map(|x| (x - lo) / (hi - lo)).collect()
}

/// Coefficients of the second divided difference `f''` at `x1` from values at `x0 < x1 < x2`
/// (exact for quadratics).
fn second_divided_difference(x0: Real, x1: Real, x2: Real) -> [Real; 3] {
    let (h0, h1) = (x1 - x0, x2 - x1);
    let s = h0 + h1;
    [2.0 / (h0 * s), -2.0 / (h0 * h1), 2.0 / (h1 * s)]
}

/// Distances between the fitted surface and the samples, summed in fixed chunks so the RMS is
/// the same on any number of threads; each sample's distance also written to `kept` unless it
/// is empty.
fn residuals(
    surface: &BSplineSurface,
    params: &[[Real; 2]],
    points: &[Point3<Real>],
    smoothness: Real,
    kept: &mut [Real],
) -> Result<FitReport, BSplineError> {
    const CHUNK: usize = 8192;
    // An empty `kept` gives empty chunks, one per sample chunk, to zip with.
    let kept_chunks: Vec<&mut [Real]> = if kept.is_empty() {
        (0..params.len().div_ceil(CHUNK))
            .map(|_| <&mut [Real]>::default())
            .collect()
    } else {
        kept.chunks_mut(CHUNK).collect()
    };
    let partial = params
        .par_chunks(CHUNK)
        .zip(points.par_chunks(CHUNK))
        .zip(kept_chunks)
        .enumerate()
        .map(|(c, ((par, pts), kept))| {
            let mut fitted = vec![Point3::origin(); par.len()];
            surface.eval_many_into(par, &mut fitted)?;
            let mut sum = 0.0;
            let mut max = (0.0, 0);
            for (k, (a, b)) in fitted.iter().zip(pts).enumerate() {
                let d2 = (a - b).norm_squared();
                if let Some(slot) = kept.get_mut(k) {
                    *slot = d2.sqrt();
                }
                sum += d2;
                if d2 > max.0 {
                    max = (d2, c * CHUNK + k);
                }
            }
            Ok((sum, max))
        })
        .collect::<Result<Vec<_>, BSplineError>>()?;
    let mut sum = 0.0;
    let mut max: (Real, usize) = (0.0, 0);
    for (s, m) in partial {
        sum += s;
        if m.0 > max.0 {
            max = m;
        }
    }
    Ok(FitReport {
        samples: params.len(),
        rms: (sum / params.len() as Real).sqrt(),
        max: max.0.sqrt(),
        max_index: max.1,
        smoothness,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pair_index_numbers_the_upper_triangle_in_order() {
        for p in 0..6 {
            let mut k = 0;
            for a in 0..=p {
                for c in a..=p {
                    assert_eq!(pair_index(a, c, p), k);
                    assert_eq!(pair_index(c, a, p), k);
                    k += 1;
                }
            }
            assert_eq!(k, (p + 1) * (p + 2) / 2);
        }
    }

    /// The Bernstein form of each span reproduces the basis functions, with non-negative
    /// coefficients (Bézier extraction), on non-uniform knots with a double knot.
    #[test]
    fn span_polynomials_reproduce_the_basis() {
        use crate::bspline::basis_functions;
        for degree in 0..=5 {
            let mut knots = vec![0.0; degree + 1];
            let interior: &[Real] = if degree == 0 {
                &[0.1, 0.25, 0.6]
            } else {
                &[0.1, 0.25, 0.25, 0.6, 0.9]
            };
            knots.extend(interior);
            knots.extend(vec![1.0; degree + 1]);
            let k = KnotVector::new(degree, knots).unwrap();
            let poly = SpanPolynomials::new(&k);
            let w = degree + 1;
            for cell in 0..k.num_control_points() - degree {
                let span = cell + degree;
                let (a, b) = (k.knots()[span], k.knots()[span + 1]);
                if a == b {
                    continue;
                }
                let d = poly.coefficients(cell);
                assert!(d.iter().all(|&x| x > -1e-14), "degree {degree}: {d:?}");
                // t < 1: the span's right end belongs to the next span.
                for step in 0..10 {
                    let t = step as Real / 10.0;
                    let u = a + (b - a) * t;
                    let mut n = vec![0.0; w];
                    basis_functions(&k, span, u, &mut n);
                    for (r, &expected) in n.iter().enumerate() {
                        let value: Real = (0..w)
                            .map(|i| d[r * w + i] * t.powi(i as i32) * (1.0 - t).powi((degree - i) as i32))
                            .sum();
                        assert!(
                            (value - expected).abs() < 1e-12,
                            "degree {degree} cell {cell} t {t}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn binomials_are_exact() {
        assert_eq!(binomial(6, 3), 20.0);
        assert_eq!(binomial(30, 15), 155_117_520.0);
        assert_eq!(binomial(4, 0), 1.0);
    }

    #[test]
    fn divided_difference_is_exact_for_quadratics() {
        let (x0, x1, x2) = (0.1, 0.35, 0.9);
        let f = |x: Real| 3.0 * x * x - 2.0 * x + 7.0;
        let c = second_divided_difference(x0, x1, x2);
        let d2 = c[0] * f(x0) + c[1] * f(x1) + c[2] * f(x2);
        assert!((d2 - 6.0).abs() < 1e-12);
    }
}
