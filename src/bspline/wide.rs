//! Batch evaluation of bicubic surfaces in AVX2 registers (x86-64).
//!
//! [`crate::bspline::BSplineSurface::eval_many`] comes here for a bicubic surface when the CPU
//! has AVX2 and FMA, found at run time (`pulp`), so that a baseline x86-64 build still runs
//! everywhere; elsewhere it evaluates point by point. The results agree with
//! [`crate::bspline::BSplineSurface::eval`] to rounding: the sums run in another order, with
//! fused multiply-adds.
//!
//! Per point:
//! * the four basis functions in `u` in one register, from their polynomial on the span
//!   ([`cubic_basis`]: three fused multiply-adds, where the Cox–de Boor recurrence is a
//!   chain of a dozen dependent products); the same in `v`;
//! * a row of four control points is 12 contiguous coordinates, three registers, so the rows'
//!   sums `sᵦ = Σₐ Nₐ(u) b_{a,β}` are three fused multiply-adds a row;
//! * then `F = Σᵦ N_β(v) sᵦ`: three products and nine additions.
//!
//! Measured against the scalar path (`cargo bench --bench bspline -- scattered`, one core, a
//! 32 × 32 grid, 10⁶ random parameters, the same run): `eval_many` 37.8 M points/s and
//! `eval_many_into` 36.0 M against `eval` one by one's 23.6 M (issue 24 asks for 80 M). About
//! a quarter of the time is `KnotVector::span_in_domain`. Variants measured and dropped, each
//! 30–37 M points/s before the domain check was made branch-free: the recurrence run for
//! four points side by side in registers (its knots gathered lane by lane), the grid held
//! as coordinate planes with four points' `v` sums formed across registers, and the 4 × 4
//! points of each patch stored together (16 times the grid, read from L2).

use nalgebra::Point3;
use pulp::f64x4;
use pulp::x86::V3;

use super::basis::SpanPolynomials;
use super::surface::BSplineSurface;
use crate::Real;

/// A bicubic surface made ready for [`Bicubic::eval_into`]: its basis as polynomials.
pub(crate) struct Bicubic<'a> {
    surface: &'a BSplineSurface,
    /// The basis functions of each span in `u` and in `v` as polynomials.
    basis_u: SpanPolynomials,
    basis_v: SpanPolynomials,
    simd: V3,
}

impl<'a> Bicubic<'a> {
    /// `None` when the CPU lacks AVX2 or FMA, or the surface is not bicubic.
    pub(crate) fn new(surface: &'a BSplineSurface) -> Option<Self> {
        let simd = V3::try_new()?;
        if surface.degree_u() != 3 || surface.degree_v() != 3 {
            return None;
        }
        Some(Bicubic {
            surface,
            basis_u: SpanPolynomials::new(surface.knots_u()),
            basis_v: SpanPolynomials::new(surface.knots_v()),
            simd,
        })
    }

    /// The surface at `params`, which must lie in its domain, into `out` (as long).
    pub(crate) fn eval_into(&self, params: &[[Real; 2]], out: &mut [Point3<Real>]) {
        self.simd.vectorize(EvalInto {
            wide: self,
            params,
            out,
        })
    }

    /// One point: a row of four control points is 12 contiguous coordinates, three registers
    /// `[x₀ y₀ z₀ x₁ | y₁ z₁ x₂ y₂ | z₂ x₃ y₃ z₃]`, so the rows' sum `sᵦ = Σₐ Nₐ(u) b_{a,β}` is
    /// three fused multiply-adds a row; then `F = Σᵦ N_β(v) sᵦ`.
    #[inline(always)]
    fn point(&self, u: Real, v: Real) -> Point3<Real> {
        let simd = self.simd;
        let surface = self.surface;
        let (su, sv) = (
            surface.knots_u().span_in_domain(u),
            surface.knots_v().span_in_domain(v),
        );
        let nu = lanes(cubic_basis(simd, &self.basis_u, su, u));
        let n = lanes(cubic_basis(simd, &self.basis_v, sv, v));
        let cols = surface.cols();
        let first = (su - 3) * cols + sv - 3;
        let points = surface.control_points();
        let zero = simd.splat_f64x4(0.0);
        // Locals, not an array updated in a loop (which was kept in memory: a store and a
        // reload per multiply-add).
        let (mut r0, mut r1, mut r2) = (zero, zero, zero);
        for (a, &weight) in nu.iter().enumerate() {
            let start = first + a * cols;
            let row: &[Real] = bytemuck::cast_slice(&points[start..start + 4]);
            let row: &[Real; 12] = row.try_into().expect("four points");
            let w = simd.splat_f64x4(weight);
            r0 = simd.mul_add_f64x4(f64x4(row[0], row[1], row[2], row[3]), w, r0);
            r1 = simd.mul_add_f64x4(f64x4(row[4], row[5], row[6], row[7]), w, r1);
            r2 = simd.mul_add_f64x4(f64x4(row[8], row[9], row[10], row[11]), w, r2);
        }
        let r0 = simd.mul_f64x4(r0, f64x4(n[0], n[0], n[0], n[1]));
        let r1 = simd.mul_f64x4(r1, f64x4(n[1], n[1], n[2], n[2]));
        let r2 = simd.mul_f64x4(r2, f64x4(n[2], n[3], n[3], n[3]));
        Point3::new(
            (r0.0 + r0.3) + (r1.2 + r2.1),
            (r0.1 + r1.0) + (r1.3 + r2.2),
            (r0.2 + r1.1) + (r2.0 + r2.3),
        )
    }
}

/// [`Bicubic::eval_into`]'s loop, run by `pulp` with the features enabled. A struct rather
/// than a closure, and no closures inside (`map`, `from_fn`, helpers): code that is not
/// inlined into the function with the features is compiled without them, and every
/// intrinsic in it becomes a call (measured: ten times slower).
struct EvalInto<'b, 'a> {
    wide: &'b Bicubic<'a>,
    params: &'b [[Real; 2]],
    out: &'b mut [Point3<Real>],
}

impl pulp::NullaryFnOnce for EvalInto<'_, '_> {
    type Output = ();

    #[inline(always)]
    fn call(self) {
        for (o, &[u, v]) in self.out.iter_mut().zip(self.params) {
            *o = self.wide.point(u, v);
        }
    }
}

/// A register's four values.
#[inline(always)]
fn lanes(a: f64x4) -> [Real; 4] {
    [a.0, a.1, a.2, a.3]
}

/// The four cubic basis functions at `u` on `span`, in one register: Horner's rule over the
/// span's polynomial coefficients `c₀ … c₃` (each the four functions', contiguous: one load a
/// register), three fused multiply-adds where the Cox–de Boor recurrence is a chain of
/// dependent products.
#[inline(always)]
fn cubic_basis(simd: V3, polynomials: &SpanPolynomials, span: usize, u: Real) -> f64x4 {
    let [start, inverse] = polynomials.start(span);
    let t = simd.splat_f64x4((u - start) * inverse);
    let c: &[Real; 16] = polynomials.coefficients(span).try_into().expect("degree 3");
    // No closure (see `EvalInto`).
    let c0 = f64x4(c[0], c[1], c[2], c[3]);
    let c1 = f64x4(c[4], c[5], c[6], c[7]);
    let c2 = f64x4(c[8], c[9], c[10], c[11]);
    let c3 = f64x4(c[12], c[13], c[14], c[15]);
    simd.mul_add_f64x4(simd.mul_add_f64x4(simd.mul_add_f64x4(c3, t, c2), t, c1), t, c0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::random::Lcg;

    /// The wide path against the surface's own `eval`, on non-uniform knots and a count of
    /// parameters that leaves a remainder, at the domain's corners and edges too.
    #[test]
    fn the_wide_path_agrees_with_eval() {
        let Some(_) = V3::try_new() else {
            return; // nothing to compare on a CPU without AVX2
        };
        let mut rng = Lcg(5);
        let knots = |rng: &mut Lcg, n: usize| {
            crate::bspline::basis::clamped(3, (0..n - 4).map(|_| rng.uniform(0.0, 1.0)).collect())
        };
        let (rows, cols) = (9, 7);
        let grid = (0..rows * cols)
            .map(|_| {
                Point3::new(
                    rng.uniform(-5.0, 5.0),
                    rng.uniform(-5.0, 5.0),
                    rng.uniform(-5.0, 5.0),
                )
            })
            .collect();
        let surface =
            BSplineSurface::new(knots(&mut rng, rows), knots(&mut rng, cols), rows, cols, grid).unwrap();
        let wide = Bicubic::new(&surface).unwrap();
        let mut params: Vec<[Real; 2]> = (0..1001).map(|_| [rng.next(), rng.next()]).collect();
        params.extend([[0.0, 0.0], [1.0, 1.0], [0.0, 1.0], [1.0, 0.5], [0.5, 0.0]]);
        let mut out = vec![Point3::origin(); params.len()];
        wide.eval_into(&params, &mut out);
        for (p, &[u, v]) in out.iter().zip(&params) {
            let expected = surface.eval(u, v).unwrap();
            assert!(
                (p - expected).norm() <= 1e-12,
                "({u}, {v}): {p} against {expected}"
            );
        }
    }
}
