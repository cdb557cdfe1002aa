//! Least-squares fitting of a surface's control grid to scattered samples.

use nalgebra::Point3;
use rayon::prelude::*;

use super::BSplineError;
use super::band::SymmetricBand;
use super::basis::{basis_fixed, width};
use super::knots::KnotVector;
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
/// The normal equations are accumulated per knot cell through the tensor-product structure
/// (`(p+1)(p+2)/2 · (q+1)(q+2)/2` products per sample instead of `((p+1)(q+1))²`), numbered
/// along the shorter grid dimension so they are banded, and solved by a banded Cholesky
/// factorisation. The result is deterministic: the same input gives the same bits on any
/// number of threads.
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
}

/// A fitted surface and how well it fits.
#[derive(Debug, Clone, PartialEq)]
pub struct FittedSurface {
    /// The surface whose control grid minimises the fitting objective.
    pub surface: BSplineSurface,
    /// Residuals of the samples.
    pub report: FitReport,
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
        }
    }

    /// Sets the smoothness weight `λ ≥ 0` (see the type's documentation). Validated by
    /// [`SurfaceFit::fit`].
    pub fn smoothness(mut self, lambda: Real) -> Self {
        self.smoothness = lambda;
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
        let report = residuals(&surface, params, points, self.smoothness)?;
        Ok(FittedSurface { surface, report })
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
        with_widths!(
            shape.p,
            shape.q,
            sums.add_samples(&self.knots_u, &self.knots_v, &samples)
        );
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
        knots_u: &KnotVector,
        knots_v: &KnotVector,
        samples: &Samples<'_>,
    ) {
        let shape = self.shape;
        let (wu, wv) = (width::<NU>(shape.p), width::<NV>(shape.q));
        let (pairs_u, pairs_v) = (wu * (wu + 1) / 2, wv * (wv + 1) / 2);
        let gram_len = pairs_u * pairs_v;
        self.data
            .par_chunks_mut(shape.per_cell())
            .enumerate()
            .for_each(|(cell, acc)| {
                let (gram, rhs) = acc.split_at_mut(gram_len);
                let members = samples.offsets[cell] as usize..samples.offsets[cell + 1] as usize;
                for s in members {
                    let [u, v] = samples.params[s];
                    let w = samples.weights.map_or(1.0, |w| w[s]);
                    let nu = basis_fixed::<NU>(knots_u, knots_u.span_in_domain(u), u);
                    let nv = basis_fixed::<NV>(knots_v, knots_v.span_in_domain(v), v);
                    // gram[pair(a, c)·pairs_v + pair(b, d)] += w·Nₐ N_c·N_b N_d: the pair
                    // products first (upper-triangle order, as `pair_index` numbers them), then
                    // one rectangular update, which unrolls and vectorises where nested
                    // triangular loops did not (4× fewer instructions, measured).
                    let mut pu = [[0.0; NU]; NU];
                    let mut pv = [[0.0; NV]; NV];
                    let pu = &mut pu.as_flattened_mut()[..pairs_u];
                    let pv = &mut pv.as_flattened_mut()[..pairs_v];
                    symmetric_products(&nu[..wu], w, pu);
                    symmetric_products(&nv[..wv], 1.0, pv);
                    for (row, &x) in gram.chunks_exact_mut(pairs_v).zip(pu.iter()) {
                        for (g, &y) in row.iter_mut().zip(pv.iter()) {
                            *g += x * y;
                        }
                    }
                    let wf = samples.points[s].coords * w;
                    let mut r = 0;
                    for &a in &nu[..wu] {
                        for &b in &nv[..wv] {
                            let ab = a * b;
                            rhs[r] += ab * wf.x;
                            rhs[r + 1] += ab * wf.y;
                            rhs[r + 2] += ab * wf.z;
                            r += 3;
                        }
                    }
                }
            });
    }
}

/// `out[pair(a, c)] = w·n[a]·n[c]` for `a ≤ c`, pairs numbered row by row of the upper triangle.
#[inline(always)]
fn symmetric_products(n: &[Real], w: Real, out: &mut [Real]) {
    let mut k = 0;
    for (a, &na) in n.iter().enumerate() {
        let wa = w * na;
        for &nc in &n[a..] {
            out[k] = wa * nc;
            k += 1;
        }
    }
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
/// the same on any number of threads.
fn residuals(
    surface: &BSplineSurface,
    params: &[[Real; 2]],
    points: &[Point3<Real>],
    smoothness: Real,
) -> Result<FitReport, BSplineError> {
    const CHUNK: usize = 8192;
    let partial = params
        .par_chunks(CHUNK)
        .zip(points.par_chunks(CHUNK))
        .enumerate()
        .map(|(c, (par, pts))| {
            let mut fitted = vec![Point3::origin(); par.len()];
            surface.eval_many_into(par, &mut fitted)?;
            let mut sum = 0.0;
            let mut max = (0.0, 0);
            for (k, (a, b)) in fitted.iter().zip(pts).enumerate() {
                let d2 = (a - b).norm_squared();
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

    #[test]
    fn divided_difference_is_exact_for_quadratics() {
        let (x0, x1, x2) = (0.1, 0.35, 0.9);
        let f = |x: Real| 3.0 * x * x - 2.0 * x + 7.0;
        let c = second_divided_difference(x0, x1, x2);
        let d2 = c[0] * f(x0) + c[1] * f(x1) + c[2] * f(x2);
        assert!((d2 - 6.0).abs() < 1e-12);
    }
}
