//! The tensor-product B-spline surface and its evaluation.

use nalgebra::{Affine3, DMatrix, Point3, Unit, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::basis::{RUNTIME, basis_derivatives, basis_fixed, width};
use super::knots::{KnotVector, MAX_DEGREE};
use super::{BSplineError, Direction};
use crate::Real;

/// A tensor-product B-spline surface
/// `F(u, v) = Σᵢ Σⱼ Nᵢ,ₚ(u) Nⱼ,q(v) bᵢⱼ` with a `rows × cols` grid of 3D control points.
///
/// `rows = knots_u.len() − p − 1` and `cols = knots_v.len() − q − 1`; the grid is flat and
/// row-major (`bᵢⱼ = control_points()[i·cols + j]`), row `i` along `u`. The domain is
/// `[u_p, u_rows] × [v_q, v_cols]`; evaluating outside it, or at NaN, is an error.
///
/// # Examples
///
/// ```
/// use nalgebra::Point3;
/// use splineface::bspline::{BSplineSurface, KnotVector};
///
/// // A bicubic patch over a 4 × 4 grid lying in the plane z = 0.
/// let ku = KnotVector::clamped_uniform(3, 4, 0.0, 1.0)?;
/// let kv = KnotVector::clamped_uniform(3, 4, 0.0, 1.0)?;
/// let grid = (0..16).map(|k| Point3::new((k / 4) as f64, (k % 4) as f64, 0.0)).collect();
/// let surface = BSplineSurface::new(ku, kv, 4, 4, grid)?;
/// let p = surface.eval(0.5, 0.25)?;
/// assert!((p - Point3::new(1.5, 0.75, 0.0)).norm() < 1e-12);
/// # Ok::<(), splineface::bspline::BSplineError>(())
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "RawSurface", into = "RawSurface")]
pub struct BSplineSurface {
    knots_u: KnotVector,
    knots_v: KnotVector,
    rows: usize,
    cols: usize,
    control_points: Vec<Point3<Real>>,
}

/// Parameters per parallel task in batch evaluation.
const BATCH: usize = 2048;

/// The JSON tag of a serialised surface.
const FORMAT: &str = "splineface/bspline-surface";
/// The version of the serialised form this build writes and reads.
const VERSION: u32 = 1;

/// The serialised form of a surface (documented on [`BSplineSurface::to_json`]).
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSurface {
    format: String,
    version: u32,
    knots_u: KnotVector,
    knots_v: KnotVector,
    rows: usize,
    cols: usize,
    control_points: Vec<Point3<Real>>,
}

impl TryFrom<RawSurface> for BSplineSurface {
    type Error = String;
    fn try_from(raw: RawSurface) -> Result<Self, String> {
        if raw.format != FORMAT {
            return Err(format!("format is {:?}, expected {FORMAT:?}", raw.format));
        }
        if raw.version != VERSION {
            return Err(format!(
                "format version {} is not supported (this build reads version {VERSION})",
                raw.version
            ));
        }
        BSplineSurface::new(raw.knots_u, raw.knots_v, raw.rows, raw.cols, raw.control_points)
            .map_err(|e| e.to_string())
    }
}

impl From<BSplineSurface> for RawSurface {
    fn from(s: BSplineSurface) -> Self {
        RawSurface {
            format: FORMAT.to_owned(),
            version: VERSION,
            knots_u: s.knots_u,
            knots_v: s.knots_v,
            rows: s.rows,
            cols: s.cols,
            control_points: s.control_points,
        }
    }
}

impl BSplineSurface {
    /// Builds a surface from its knot vectors (which carry the degrees) and a row-major
    /// `rows × cols` control grid.
    ///
    /// # Errors
    /// [`BSplineError::GridShapeMismatch`] when `rows` or `cols` disagree with the knots,
    /// [`BSplineError::ControlPointCount`] when `control_points.len() ≠ rows·cols`,
    /// [`BSplineError::NonFiniteControlPoint`] for a NaN or infinite coordinate.
    pub fn new(
        knots_u: KnotVector,
        knots_v: KnotVector,
        rows: usize,
        cols: usize,
        control_points: Vec<Point3<Real>>,
    ) -> Result<Self, BSplineError> {
        let (expected_rows, expected_cols) = (knots_u.num_control_points(), knots_v.num_control_points());
        if rows != expected_rows || cols != expected_cols {
            return Err(BSplineError::GridShapeMismatch {
                rows,
                cols,
                expected_rows,
                expected_cols,
            });
        }
        if control_points.len() != rows * cols {
            return Err(BSplineError::ControlPointCount {
                got: control_points.len(),
                rows,
                cols,
            });
        }
        if let Some(k) = control_points
            .iter()
            .position(|p| !p.coords.iter().all(|c| c.is_finite()))
        {
            return Err(BSplineError::NonFiniteControlPoint {
                row: k / cols,
                col: k % cols,
            });
        }
        Ok(BSplineSurface {
            knots_u,
            knots_v,
            rows,
            cols,
            control_points,
        })
    }

    /// The same knots with another control grid of the same shape.
    ///
    /// # Errors
    /// As [`BSplineSurface::new`].
    pub fn with_control_points(&self, control_points: Vec<Point3<Real>>) -> Result<Self, BSplineError> {
        Self::new(
            self.knots_u.clone(),
            self.knots_v.clone(),
            self.rows,
            self.cols,
            control_points,
        )
    }

    /// The degree `p` in `u`.
    #[inline]
    pub fn degree_u(&self) -> usize {
        self.knots_u.degree()
    }

    /// The degree `q` in `v`.
    #[inline]
    pub fn degree_v(&self) -> usize {
        self.knots_v.degree()
    }

    /// The knot vector in `u`.
    #[inline]
    pub fn knots_u(&self) -> &KnotVector {
        &self.knots_u
    }

    /// The knot vector in `v`.
    #[inline]
    pub fn knots_v(&self) -> &KnotVector {
        &self.knots_v
    }

    /// Grid rows (control points along `u`).
    #[inline]
    pub fn rows(&self) -> usize {
        self.rows
    }

    /// Grid columns (control points along `v`).
    #[inline]
    pub fn cols(&self) -> usize {
        self.cols
    }

    /// The control grid, `rows × cols`, row-major.
    #[inline]
    pub fn control_points(&self) -> &[Point3<Real>] {
        &self.control_points
    }

    /// The control point `bᵢⱼ`.
    ///
    /// # Panics
    /// If `i ≥ rows` or `j ≥ cols`.
    #[inline]
    pub fn control_point(&self, i: usize, j: usize) -> &Point3<Real> {
        assert!(
            i < self.rows && j < self.cols,
            "control point ({i}, {j}) outside the grid"
        );
        &self.control_points[i * self.cols + j]
    }

    /// The parameter domain in `u`.
    #[inline]
    pub fn domain_u(&self) -> (Real, Real) {
        self.knots_u.domain()
    }

    /// The parameter domain in `v`.
    #[inline]
    pub fn domain_v(&self) -> (Real, Real) {
        self.knots_v.domain()
    }

    /// Whether `(u, v)` lies in the domain, or the error that says why not.
    #[inline]
    fn check(&self, u: Real, v: Real) -> Result<(), BSplineError> {
        check_parameter(&self.knots_u, &self.knots_v, u, v)
    }

    /// The spans of `(u, v)`, or the error that says why there are none.
    #[inline]
    pub(super) fn locate(&self, u: Real, v: Real) -> Result<(usize, usize), BSplineError> {
        self.check(u, v)?;
        Ok((self.knots_u.span_in_domain(u), self.knots_v.span_in_domain(v)))
    }

    /// `F(u, v)` on the spans `(su, sv)`: `Σₐ Σ_b Nₐ(u)·N_b(v)·b_{su−p+a, sv−q+b}`.
    #[inline(always)]
    pub(crate) fn point_in_span<const NU: usize, const NV: usize>(
        &self,
        su: usize,
        sv: usize,
        u: Real,
        v: Real,
    ) -> Vector3<Real> {
        let (wu, wv) = (width::<NU>(self.degree_u()), width::<NV>(self.degree_v()));
        let nu = basis_fixed::<NU>(&self.knots_u, su, u);
        let nv = basis_fixed::<NV>(&self.knots_v, sv, v);
        let mut acc = Vector3::zeros();
        for (a, &weight_u) in nu[..wu].iter().enumerate() {
            let start = (su + 1 + a - wu) * self.cols + sv + 1 - wv;
            let row = &self.control_points[start..start + wv];
            let mut t = Vector3::zeros();
            for (pt, &weight_v) in row.iter().zip(&nv[..wv]) {
                t += pt.coords * weight_v;
            }
            acc += t * weight_u;
        }
        acc
    }

    /// The point `F(u, v)`.
    ///
    /// # Errors
    /// [`BSplineError::NonFiniteParameter`] or [`BSplineError::ParameterOutOfDomain`].
    #[inline]
    pub fn eval(&self, u: Real, v: Real) -> Result<Point3<Real>, BSplineError> {
        let (su, sv) = self.locate(u, v)?;
        Ok(Point3::from(with_widths!(
            self.degree_u(),
            self.degree_v(),
            self.point_in_span(su, sv, u, v)
        )))
    }

    /// The partial derivatives `∂ᵏ⁺ˡF / ∂uᵏ ∂vˡ` for all `k + l ≤ order` (The NURBS Book A3.6).
    ///
    /// # Errors
    /// As [`BSplineSurface::eval`].
    ///
    /// # Examples
    ///
    /// ```
    /// use nalgebra::{Point3, Vector3};
    /// use splineface::bspline::{BSplineSurface, KnotVector};
    ///
    /// // The bilinear patch F(u, v) = (u, v, u·v).
    /// let k = KnotVector::clamped_uniform(1, 2, 0.0, 1.0)?;
    /// let grid = vec![
    ///     Point3::new(0.0, 0.0, 0.0), Point3::new(0.0, 1.0, 0.0),
    ///     Point3::new(1.0, 0.0, 0.0), Point3::new(1.0, 1.0, 1.0),
    /// ];
    /// let s = BSplineSurface::new(k.clone(), k, 2, 2, grid)?;
    /// let d = s.derivatives(0.5, 0.25, 2)?;
    /// assert_eq!(d.get(1, 0), Vector3::new(1.0, 0.0, 0.25)); // F_u = (1, 0, v)
    /// assert_eq!(d.get(0, 1), Vector3::new(0.0, 1.0, 0.5)); //  F_v = (0, 1, u)
    /// assert_eq!(d.get(1, 1), Vector3::new(0.0, 0.0, 1.0));
    /// assert_eq!(d.get(2, 0), Vector3::zeros());
    /// # Ok::<(), splineface::bspline::BSplineError>(())
    /// ```
    pub fn derivatives(&self, u: Real, v: Real, order: usize) -> Result<SurfaceDerivatives, BSplineError> {
        let (su, sv) = self.locate(u, v)?;
        let (p, q) = (self.degree_u(), self.degree_v());
        let (du, dv) = (order.min(p), order.min(q));
        let mut nu = [0.0; (MAX_DEGREE + 1) * (MAX_DEGREE + 1)];
        let mut nv = [0.0; (MAX_DEGREE + 1) * (MAX_DEGREE + 1)];
        basis_derivatives(&self.knots_u, su, u, du, &mut nu);
        basis_derivatives(&self.knots_v, sv, v, dv, &mut nv);
        let mut values = vec![Vector3::zeros(); (order + 1) * (order + 1)];
        let mut temp = [Vector3::zeros(); MAX_DEGREE + 1];
        for k in 0..=du {
            let nuk = &nu[k * (p + 1)..(k + 1) * (p + 1)];
            for (s, t) in temp[..=q].iter_mut().enumerate() {
                *t = Vector3::zeros();
                for (r, &w) in nuk.iter().enumerate() {
                    *t += self.control_points[(su - p + r) * self.cols + sv - q + s].coords * w;
                }
            }
            for l in 0..=dv.min(order - k) {
                let nvl = &nv[l * (q + 1)..(l + 1) * (q + 1)];
                values[k * (order + 1) + l] = temp[..=q].iter().zip(nvl).map(|(t, &w)| t * w).sum();
            }
        }
        Ok(SurfaceDerivatives { order, values })
    }

    /// The unit normal `(F_u × F_v) / |F_u × F_v|`, or `None` where the surface is degenerate
    /// (the two tangents are parallel or vanish, e.g. at a collapsed edge).
    ///
    /// The normal points to the side from which `u` turns to `v` counter-clockwise; for the
    /// face surfaces of this crate (`u` along x, `v` along y) that is `+z`, toward the viewer.
    ///
    /// # Errors
    /// As [`BSplineSurface::eval`].
    pub fn normal(&self, u: Real, v: Real) -> Result<Option<Unit<Vector3<Real>>>, BSplineError> {
        let d = self.derivatives(u, v, 1)?;
        Ok(unit_normal(&d.get(1, 0), &d.get(0, 1)))
    }

    /// Evaluates the surface on the grid `us × vs`, row-major: `out[i·vs.len() + k] = F(us[i], vs[k])`.
    ///
    /// Separable and parallel (rayon, over rows): for each `uᵢ` the intermediate curve
    /// `Cᵢ(v) = Σⱼ (Σₐ Nₐ,ₚ(uᵢ) bₐⱼ) Nⱼ,q(v)` has its control points computed once, and the `v`
    /// basis functions are computed once for the whole grid, so a point costs `(q + 1)` vector
    /// multiply-adds.
    ///
    /// # Errors
    /// As [`BSplineSurface::eval`], for the first bad parameter.
    pub fn eval_grid(&self, us: &[Real], vs: &[Real]) -> Result<Vec<Point3<Real>>, BSplineError> {
        let mut out = vec![Point3::origin(); us.len() * vs.len()];
        self.eval_grid_into(us, vs, &mut out)?;
        Ok(out)
    }

    /// [`BSplineSurface::eval_grid`] into a caller's buffer of `us.len() × vs.len()` points.
    ///
    /// # Errors
    /// As [`BSplineSurface::eval`]; `out` is unspecified after an error.
    ///
    /// # Panics
    /// If `out.len() ≠ us.len()·vs.len()`.
    pub fn eval_grid_into(
        &self,
        us: &[Real],
        vs: &[Real],
        out: &mut [Point3<Real>],
    ) -> Result<(), BSplineError> {
        assert_eq!(out.len(), us.len() * vs.len(), "output buffer has the wrong size");
        if us.is_empty() || vs.is_empty() {
            return Ok(());
        }
        let u_spans = us
            .iter()
            .map(|&u| self.locate(u, self.domain_v().0).map(|(su, _)| su))
            .collect::<Result<Vec<_>, _>>()?;
        let v_spans = vs
            .iter()
            .map(|&v| self.locate(self.domain_u().0, v).map(|(_, sv)| sv))
            .collect::<Result<Vec<_>, _>>()?;
        with_widths!(
            self.degree_u(),
            self.degree_v(),
            self.eval_grid_checked(us, vs, &u_spans, &v_spans, out)
        );
        Ok(())
    }

    /// [`BSplineSurface::eval_grid_into`] once every parameter's span is known.
    fn eval_grid_checked<const NU: usize, const NV: usize>(
        &self,
        us: &[Real],
        vs: &[Real],
        u_spans: &[usize],
        v_spans: &[usize],
        out: &mut [Point3<Real>],
    ) {
        let (wu, wv) = (width::<NU>(self.degree_u()), width::<NV>(self.degree_v()));
        // The v basis functions, once for the whole grid, and each one's first control column.
        let v_basis: Vec<[Real; NV]> = vs
            .iter()
            .zip(v_spans)
            .map(|(&v, &sv)| basis_fixed::<NV>(&self.knots_v, sv, v))
            .collect();
        let v_first: Vec<usize> = v_spans.iter().map(|&sv| sv + 1 - wv).collect();
        let cols = self.cols;
        out.par_chunks_mut(vs.len())
            .zip(us.par_iter().zip(u_spans))
            .for_each_init(
                || vec![Vector3::<Real>::zeros(); cols],
                |curve, (row_out, (&u, &su))| {
                    // The control points of the intermediate curve C(v) = F(u, v).
                    let nu = basis_fixed::<NU>(&self.knots_u, su, u);
                    curve.fill(Vector3::zeros());
                    for (a, &w) in nu[..wu].iter().enumerate() {
                        let first = (su + 1 + a - wu) * cols;
                        for (c, pt) in curve.iter_mut().zip(&self.control_points[first..first + cols]) {
                            *c += pt.coords * w;
                        }
                    }
                    for ((o, &first), nv) in row_out.iter_mut().zip(&v_first).zip(&v_basis) {
                        let mut acc = Vector3::zeros();
                        for (c, &w) in curve[first..first + wv].iter().zip(&nv[..wv]) {
                            acc += c * w;
                        }
                        *o = Point3::from(acc);
                    }
                },
            );
    }

    /// Evaluates the surface at every `[u, v]` of `params`, in parallel (rayon).
    ///
    /// A bicubic surface on an x86-64 CPU with AVX2 and FMA (found at run time) is evaluated
    /// in SIMD registers, its sums in another order than [`BSplineSurface::eval`]'s: each
    /// point agrees with `eval` to about 10⁻¹⁵ of the control points' size (tested to 10⁻¹²).
    /// Other surfaces and CPUs give `eval`'s values exactly.
    ///
    /// # Errors
    /// As [`BSplineSurface::eval`], for the first bad parameter in the list; then nothing is
    /// evaluated.
    pub fn eval_many(&self, params: &[[Real; 2]]) -> Result<Vec<Point3<Real>>, BSplineError> {
        let mut out = vec![Point3::origin(); params.len()];
        self.eval_many_into(params, &mut out)?;
        Ok(out)
    }

    /// [`BSplineSurface::eval_many`] into a caller's buffer of `params.len()` points (which
    /// spares a large allocation when it is reused).
    ///
    /// # Errors
    /// As [`BSplineSurface::eval_many`]; `out` is untouched after an error.
    ///
    /// # Panics
    /// If `out.len() ≠ params.len()`.
    pub fn eval_many_into(&self, params: &[[Real; 2]], out: &mut [Point3<Real>]) -> Result<(), BSplineError> {
        assert_eq!(out.len(), params.len(), "output buffer has the wrong size");
        self.check_all(params)?;
        with_widths!(
            self.degree_u(),
            self.degree_v(),
            self.eval_in_domain_into(params, out)
        );
        Ok(())
    }

    /// The error for the first parameter outside the domain, if any.
    fn check_all(&self, params: &[[Real; 2]]) -> Result<(), BSplineError> {
        // Each chunk by a fold of comparisons, without branches (the compiler runs it in SIMD
        // registers), which is `check` failing for none: a NaN fails every comparison, and an
        // infinity lies outside the finite domain. The error itself comes from `check`.
        let ((u0, u1), (v0, v1)) = (self.knots_u.domain(), self.knots_v.domain());
        let first_bad_chunk = params.par_chunks(BATCH).position_first(|chunk| {
            !chunk.iter().fold(true, |ok, &[u, v]| {
                ok & (u >= u0) & (u <= u1) & (v >= v0) & (v <= v1)
            })
        });
        match first_bad_chunk {
            Some(c) => params[c * BATCH..]
                .iter()
                .try_for_each(|&[u, v]| self.check(u, v)),
            None => Ok(()),
        }
    }

    /// `F(u, v)` for parameters already checked to lie in the domain.
    #[inline(always)]
    fn point_in_domain<const NU: usize, const NV: usize>(&self, u: Real, v: Real) -> Point3<Real> {
        let (su, sv) = (self.knots_u.span_in_domain(u), self.knots_v.span_in_domain(v));
        Point3::from(self.point_in_span::<NU, NV>(su, sv, u, v))
    }

    fn eval_in_domain_into<const NU: usize, const NV: usize>(
        &self,
        params: &[[Real; 2]],
        out: &mut [Point3<Real>],
    ) {
        // A bicubic surface on a CPU with AVX2 and FMA, for a batch at least as long as the
        // knot vectors (the wide path writes each span's basis as a polynomial first).
        #[cfg(target_arch = "x86_64")]
        if NU == 4
            && NV == 4
            && params.len() >= self.rows + self.cols
            && let Some(wide) = super::wide::Bicubic::new(self)
        {
            out.par_chunks_mut(BATCH)
                .zip(params.par_chunks(BATCH))
                .for_each(|(out, params)| wide.eval_into(params, out));
            return;
        }
        // Chunks with a plain loop inside, so that the evaluation inlines into the loop (a
        // per-point closure handed to rayon costs half as much again).
        out.par_chunks_mut(BATCH)
            .zip(params.par_chunks(BATCH))
            .for_each(|(out, params)| {
                for (o, &[u, v]) in out.iter_mut().zip(params) {
                    *o = self.point_in_domain::<NU, NV>(u, v);
                }
            });
    }

    /// The sparse basis matrix `R`: one row per `[u, v]` of `params`, one column per control
    /// point (row-major grid index `i·cols + j`), `(p + 1)(q + 1)` non-zeros per row, so that
    /// `F(params) = R·B` with `B` the control grid (`rows·cols × 3`).
    ///
    /// # Errors
    /// As [`BSplineSurface::eval`].
    pub fn basis_matrix(&self, params: &[[Real; 2]]) -> Result<BasisMatrix, BSplineError> {
        let (p, q) = (self.degree_u(), self.degree_v());
        self.assemble_basis(params, |su, sv, u, v, row_u, row_v| {
            row_u[..=p].copy_from_slice(&basis_fixed::<RUNTIME>(&self.knots_u, su, u)[..=p]);
            row_v[..=q].copy_from_slice(&basis_fixed::<RUNTIME>(&self.knots_v, sv, v)[..=q]);
        })
    }

    /// A sparse basis matrix from each parameter pair's `u`- and `v`-rows: `rows(su, sv, u, v,
    /// row_u, row_v)` fills the `p + 1` and `q + 1` values of the functions alive at spans
    /// `su`, `sv`; the matrix holds their products.
    fn assemble_basis(
        &self,
        params: &[[Real; 2]],
        rows: impl Fn(usize, usize, Real, Real, &mut [Real], &mut [Real]),
    ) -> Result<BasisMatrix, BSplineError> {
        let (p, q) = (self.degree_u(), self.degree_v());
        let nnz = (p + 1) * (q + 1);
        let mut columns = Vec::with_capacity(params.len() * nnz);
        let mut values = Vec::with_capacity(params.len() * nnz);
        let (mut row_u, mut row_v) = ([0.0; MAX_DEGREE + 1], [0.0; MAX_DEGREE + 1]);
        for &[u, v] in params {
            let (su, sv) = self.locate(u, v)?;
            rows(su, sv, u, v, &mut row_u, &mut row_v);
            for (a, &wu) in row_u[..=p].iter().enumerate() {
                for (b, &wv) in row_v[..=q].iter().enumerate() {
                    columns.push((su - p + a) * self.cols + sv - q + b);
                    values.push(wu * wv);
                }
            }
        }
        Ok(BasisMatrix {
            nrows: params.len(),
            ncols: self.rows * self.cols,
            nnz_per_row: nnz,
            columns,
            values,
        })
    }

    /// The sparse matrix of the basis functions' mixed partial derivatives
    /// `∂ᵏ⁺ˡ/∂uᵏ∂vˡ` at `params`, laid out as [`BSplineSurface::basis_matrix`]'s, so that
    /// `R_kl · B` is the surface's derivative of that order at every parameter pair (with `B`
    /// the control grid) and, applied to any other grid on the same knots (a displacement
    /// field, a mode of a [`super::SurfaceSpace`]), that grid's: one evaluation of the basis
    /// serves every grid. `(0, 0)` is the basis matrix itself; an order above a direction's
    /// degree gives zeros.
    ///
    /// ```
    /// use nalgebra::Point3;
    /// use splineface::bspline::{BSplineSurface, KnotVector};
    ///
    /// let k = KnotVector::clamped_uniform(3, 5, 0.0, 1.0)?;
    /// let grid = (0..25).map(|i| Point3::new((i / 5) as f64, (i % 5) as f64, ((i * 7) % 5) as f64)).collect();
    /// let s = BSplineSurface::new(k.clone(), k, 5, 5, grid)?;
    /// let d = s.derivatives(0.3, 0.7, 2)?;
    /// for (k, l) in [(0, 0), (1, 0), (0, 1), (1, 1), (2, 0)] {
    ///     let r = s.derivative_basis_matrix(&[[0.3, 0.7]], (k, l))?;
    ///     assert!((r.mul(s.control_points())[0].coords - d.get(k, l)).norm() < 1e-12);
    /// }
    /// # Ok::<(), splineface::bspline::BSplineError>(())
    /// ```
    ///
    /// # Errors
    /// As [`BSplineSurface::eval`].
    pub fn derivative_basis_matrix(
        &self,
        params: &[[Real; 2]],
        (k, l): (usize, usize),
    ) -> Result<BasisMatrix, BSplineError> {
        // One direction's row of order `order`: zeros above the degree.
        let row = |knots: &KnotVector, span: usize, t: Real, order: usize, out: &mut [Real]| {
            let degree = knots.degree();
            if order > degree {
                out[..=degree].fill(0.0);
                return;
            }
            let mut table = [0.0; (MAX_DEGREE + 1) * (MAX_DEGREE + 1)];
            basis_derivatives(knots, span, t, order, &mut table);
            out[..=degree].copy_from_slice(&table[order * (degree + 1)..(order + 1) * (degree + 1)]);
        };
        self.assemble_basis(params, |su, sv, u, v, row_u, row_v| {
            row(&self.knots_u, su, u, k, row_u);
            row(&self.knots_v, sv, v, l, row_v);
        })
    }

    /// The surface mapped by an affine transform: by the affine invariance of B-splines,
    /// `transformed(A).eval(u, v) = A(eval(u, v))`, and it is computed by mapping the control
    /// grid.
    ///
    /// ```
    /// use nalgebra::{Affine3, Matrix4, Point3};
    /// use splineface::bspline::{BSplineSurface, KnotVector};
    ///
    /// let k = KnotVector::clamped_uniform(2, 3, 0.0, 1.0)?;
    /// let grid = (0..9).map(|i| Point3::new((i / 3) as f64, (i % 3) as f64, (i * i) as f64)).collect();
    /// let s = BSplineSurface::new(k.clone(), k, 3, 3, grid)?;
    /// let a = Affine3::from_matrix_unchecked(Matrix4::new(
    ///     2.0, 0.5, 0.0, 1.0,
    ///     0.0, 1.0, 0.3, -2.0,
    ///     0.1, 0.0, 3.0, 0.5,
    ///     0.0, 0.0, 0.0, 1.0,
    /// ));
    /// let lhs = s.transformed(&a).eval(0.3, 0.6)?;
    /// let rhs = a * s.eval(0.3, 0.6)?;
    /// assert!((lhs - rhs).norm() < 1e-12);
    /// # Ok::<(), splineface::bspline::BSplineError>(())
    /// ```
    pub fn transformed(&self, affine: &Affine3<Real>) -> Self {
        BSplineSurface {
            control_points: self.control_points.iter().map(|p| affine * p).collect(),
            ..self.clone()
        }
    }

    /// The surface as JSON, in the documented, versioned form:
    ///
    /// ```json
    /// {
    ///   "format": "splineface/bspline-surface",
    ///   "version": 1,
    ///   "knots_u": { "degree": 3, "knots": [0, 0, 0, 0, 0.5, 1, 1, 1, 1] },
    ///   "knots_v": { "degree": 3, "knots": [0, 0, 0, 0, 0.5, 1, 1, 1, 1] },
    ///   "rows": 5,
    ///   "cols": 5,
    ///   "control_points": [[x, y, z], …]
    /// }
    /// ```
    ///
    /// Control points are row-major (`rows × cols`, row `i` along `u`). Numbers are written in
    /// the shortest form that reads back to the same `f64`, so the round trip
    /// [`BSplineSurface::from_json`] is exact.
    pub fn to_json(&self) -> String {
        serde_json::to_string(self).expect("a validated surface always serialises")
    }

    /// Reads a surface written by [`BSplineSurface::to_json`], validating everything.
    ///
    /// # Errors
    /// A `serde_json` error that says what is wrong: malformed JSON, a missing or unknown
    /// field, another format or version, or invalid knots or control points.
    pub fn from_json(json: &str) -> Result<Self, serde_json::Error> {
        serde_json::from_str(json)
    }

    /// Reads a surface file written by [`BSplineSurface::to_json`] (a reconstruction's
    /// `surface.json`), with an error that names the file.
    ///
    /// # Errors
    /// [`SurfaceFileError`] when the file cannot be read (or is larger than
    /// [`crate::io::MAX_DATA_INPUT_BYTES`]) or is not a valid surface.
    ///
    /// # Examples
    /// ```
    /// use splineface::bspline::{BSplineSurface, KnotVector};
    /// use nalgebra::Point3;
    ///
    /// let knots = KnotVector::clamped_uniform(1, 2, 0.0, 1.0).unwrap();
    /// let corners = [(0.0, 0.0), (0.0, 1.0), (1.0, 0.0), (1.0, 1.0)];
    /// let points = corners.iter().map(|&(u, v)| Point3::new(u, v, 0.0)).collect();
    /// let square = BSplineSurface::new(knots.clone(), knots, 2, 2, points).unwrap();
    /// let path = std::env::temp_dir().join("splineface-doc-square.json");
    /// std::fs::write(&path, square.to_json()).unwrap();
    /// assert_eq!(BSplineSurface::read_json(&path).unwrap(), square);
    /// std::fs::write(&path, "{}").unwrap();
    /// let error = BSplineSurface::read_json(&path).unwrap_err().to_string();
    /// assert!(error.contains("splineface-doc-square.json"), "{error}");
    /// ```
    pub fn read_json(path: &std::path::Path) -> Result<Self, SurfaceFileError> {
        let problem = |problem: String| SurfaceFileError {
            path: path.to_owned(),
            problem,
        };
        let text = crate::io::read_input_text(path, crate::io::MAX_DATA_INPUT_BYTES)
            .map_err(|e| problem(e.to_string()))?;
        Self::from_json(&text).map_err(|e| problem(format!("not a splineface surface: {e}")))
    }
}

/// A surface file that cannot be read ([`BSplineSurface::read_json`]).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{}: {problem}", path.display())]
pub struct SurfaceFileError {
    /// The file.
    pub path: std::path::PathBuf,
    /// What is wrong with it.
    pub problem: String,
}

/// Whether `(u, v)` lies in the domain of the knot vectors, or the error that says why not.
#[inline]
pub(crate) fn check_parameter(
    knots_u: &KnotVector,
    knots_v: &KnotVector,
    u: Real,
    v: Real,
) -> Result<(), BSplineError> {
    if !(u.is_finite() && v.is_finite()) {
        return Err(BSplineError::NonFiniteParameter { u, v });
    }
    for (knots, direction, value) in [(knots_u, Direction::U, u), (knots_v, Direction::V, v)] {
        knots.check_in_domain(direction, value)?;
    }
    Ok(())
}

/// `(F_u × F_v) / |F_u × F_v|` from the tangents, or `None` where they are parallel or
/// vanish ([`BSplineSurface::normal`]).
pub(super) fn unit_normal(fu: &Vector3<Real>, fv: &Vector3<Real>) -> Option<Unit<Vector3<Real>>> {
    let n = fu.cross(fv);
    let norm = n.norm();
    // Relative test: the sine of the angle between the tangents must not be rounding noise.
    (norm > 1e-12 * fu.norm() * fv.norm() && norm > 0.0).then(|| Unit::new_unchecked(n / norm))
}

/// The partial derivatives of a surface at one parameter, from
/// [`BSplineSurface::derivatives`].
#[derive(Debug, Clone, PartialEq)]
pub struct SurfaceDerivatives {
    order: usize,
    /// `(order + 1)²` vectors, `k`-major; entries with `k + l > order` are zero.
    values: Vec<Vector3<Real>>,
}

impl SurfaceDerivatives {
    /// The highest total order computed.
    pub fn order(&self) -> usize {
        self.order
    }

    /// `∂ᵏ⁺ˡF / ∂uᵏ ∂vˡ`; `get(0, 0)` is the point itself (as a vector).
    ///
    /// # Panics
    /// If `k + l > order()`.
    pub fn get(&self, k: usize, l: usize) -> Vector3<Real> {
        assert!(
            k + l <= self.order,
            "derivative ({k}, {l}) was not computed (order {})",
            self.order
        );
        self.values[k * (self.order + 1) + l]
    }

    /// The point `F(u, v)`.
    pub fn point(&self) -> Point3<Real> {
        Point3::from(self.values[0])
    }
}

/// The sparse basis matrix `R` of a surface at a list of parameters
/// ([`BSplineSurface::basis_matrix`]): `nrows × ncols`, every row with exactly
/// `(p + 1)(q + 1)` stored entries (some may be zero at knots).
#[derive(Debug, Clone, PartialEq)]
pub struct BasisMatrix {
    nrows: usize,
    ncols: usize,
    nnz_per_row: usize,
    columns: Vec<usize>,
    values: Vec<Real>,
}

impl BasisMatrix {
    /// Rows: one per parameter pair.
    pub fn nrows(&self) -> usize {
        self.nrows
    }

    /// Columns: one per control point.
    pub fn ncols(&self) -> usize {
        self.ncols
    }

    /// Stored entries per row, `(p + 1)(q + 1)`.
    pub fn nnz_per_row(&self) -> usize {
        self.nnz_per_row
    }

    /// Row `r` as `(column indices, values)`, columns increasing.
    ///
    /// # Panics
    /// If `r ≥ nrows()`.
    pub fn row(&self, r: usize) -> (&[usize], &[Real]) {
        let range = r * self.nnz_per_row..(r + 1) * self.nnz_per_row;
        (&self.columns[range.clone()], &self.values[range])
    }

    /// `R·B`: the surface points for a control grid `B` (`ncols` points).
    ///
    /// # Panics
    /// If `control_points.len() ≠ ncols()`.
    pub fn mul(&self, control_points: &[Point3<Real>]) -> Vec<Point3<Real>> {
        assert_eq!(
            control_points.len(),
            self.ncols,
            "control grid size does not match R"
        );
        (0..self.nrows)
            .map(|r| {
                let (c, v) = self.row(r);
                Point3::from(
                    c.iter()
                        .zip(v)
                        .map(|(&c, &w)| control_points[c].coords * w)
                        .sum::<Vector3<Real>>(),
                )
            })
            .collect()
    }

    /// The dense `nrows × ncols` matrix (for small problems and tests).
    pub fn to_dense(&self) -> DMatrix<Real> {
        let mut m = DMatrix::zeros(self.nrows, self.ncols);
        for r in 0..self.nrows {
            let (c, v) = self.row(r);
            for (&c, &v) in c.iter().zip(v) {
                m[(r, c)] += v;
            }
        }
        m
    }
}
