//! Batch evaluation of bicubic surfaces in AVX2 registers (x86-64).
//!
//! [`crate::bspline::BSplineSurface::eval_many`] comes here for a bicubic surface when the CPU
//! has AVX2 and FMA, found at run time (`pulp`), so that a baseline x86-64 build still runs
//! everywhere; elsewhere it evaluates point by point. The results agree with
//! [`crate::bspline::BSplineSurface::eval`] to rounding: the sums run in another order, with
//! fused multiply-adds.
//!
//! Per point:
//! * its knot spans: for uniform knots by arithmetic alone (the comparisons with the stored
//!   knots that make [`crate::bspline::KnotVector::span`] exact at a knot were 30% of the
//!   time; near a knot the neighbouring span may be taken, whose polynomial agrees there to
//!   rounding), else by the knot vector's own lookup;
//! * the four basis functions in `u` in one register, from their polynomial on the span
//!   ([`CubicSpan::eval`]: three fused multiply-adds, where the Cox–de Boor recurrence is a
//!   chain of a dozen dependent products); the same in `v`;
//! * a row of four control points is 12 contiguous coordinates, three registers, so the rows'
//!   sums `sᵦ = Σₐ Nₐ(u) b_{a,β}` are three fused multiply-adds a row, rows 0–1 and 2–3 in
//!   two chains added at the end;
//! * then `F = Σᵦ N_β(v) sᵦ`: three products, the twelve lanes lined up into three sums by
//!   whole-register shuffles.
//!
//! Eight points are taken at a time in the loop ([`SIDE_BY_SIDE`]), their spans first, so
//! that their chains of dependent operations (about 60 cycles a point from the parameter's
//! load to the store) overlap.
//!
//! Measured against the scalar path (`cargo bench --bench bspline -- scattered`, one core, a
//! 32 × 32 grid, 10⁶ random parameters, the same run): `eval_many` 37.8 M points/s and
//! `eval_many_into` 36.0 M against `eval` one by one's 23.6 M at first. Then, against that
//! code's bench binary run alternately with this one's (the machine's speed drifts by a
//! fifth between runs): 48.1–52.8 M → 99.7–102.7 M points/s (`eval_many_into`, three pairs
//! of runs; `eval` one by one 33.8 M): spans by arithmetic 46.7 → 67.2 M, two chains of rows
//! +8%, two points side by side +3%, four +10%, eight +5–14% (sixteen no better). Variants measured and dropped: checking each chunk's parameters just
//! before evaluating it instead of all of them first (2–10% slower, though it reads them
//! once); the lanes summed one by one rather than by shuffles (the same speed); before the
//! spans by arithmetic, each 30–37 M points/s: the recurrence run for four points side by
//! side in registers (its knots gathered lane by lane), the grid held as coordinate planes
//! with four points' `v` sums formed across registers, and the 4 × 4 points of each patch
//! stored together (16 times the grid, read from L2).

use nalgebra::Point3;
use pulp::f64x4;
use pulp::x86::V3;
use std::arch::x86_64::__m256d;

use super::basis::SpanPolynomials;
use super::surface::BSplineSurface;
use crate::Real;

/// A bicubic surface made ready for [`Bicubic::eval_into`]: its basis as polynomials.
pub(crate) struct Bicubic<'a> {
    surface: &'a BSplineSurface,
    /// The basis functions of each span in `u` and in `v` as polynomials.
    basis_u: Vec<CubicSpan>,
    basis_v: Vec<CubicSpan>,
    /// [`crate::bspline::KnotVector::uniform_spans`] in `u` and in `v`, when both are uniform.
    uniform: Option<[(Real, Real, usize); 2]>,
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
            basis_u: CubicSpan::all(surface.knots_u()),
            basis_v: CubicSpan::all(surface.knots_v()),
            uniform: surface
                .knots_u()
                .uniform_spans()
                .zip(surface.knots_v().uniform_spans())
                .map(|(u, v)| [u, v]),
            simd,
        })
    }

    /// The surface at `params`, which must lie in its domain, into `out` (as long).
    pub(crate) fn eval_into(&self, params: &[[Real; 2]], out: &mut [Point3<Real>]) {
        match self.uniform {
            Some(uniform) => self.simd.vectorize(EvalInto {
                wide: self,
                params,
                out,
                spans: Uniform(uniform),
            }),
            None => self.simd.vectorize(EvalInto {
                wide: self,
                params,
                out,
                spans: Search(self.surface),
            }),
        }
    }

    /// One point: a row of four control points is 12 contiguous coordinates, three registers
    /// `[x₀ y₀ z₀ x₁ | y₁ z₁ x₂ y₂ | z₂ x₃ y₃ z₃]`, so the rows' sum `sᵦ = Σₐ Nₐ(u) b_{a,β}` is
    /// three fused multiply-adds a row; then `F = Σᵦ N_β(v) sᵦ`.
    #[inline(always)]
    fn point(&self, [su, sv]: [usize; 2], u: Real, v: Real) -> Point3<Real> {
        let simd = self.simd;
        let surface = self.surface;
        let nu = lanes(self.basis_u[su].eval(simd, u));
        let n = lanes(self.basis_v[sv].eval(simd, v));
        let cols = surface.cols();
        let first = (su - 3) * cols + sv - 3;
        // The 4 × 4 block's rows, bounds-checked once.
        let block: &[Real] = bytemuck::cast_slice(&surface.control_points()[first..first + 3 * cols + 4]);
        // Rows 0–1 and 2–3 summed apart, then added: two short chains of dependent
        // multiply-adds rather than one of four. Locals, not arrays updated in a loop (which
        // were kept in memory: a store and a reload per multiply-add).
        let row_stride = 3 * cols;
        let (w0, w1, w2, w3) = (
            simd.splat_f64x4(nu[0]),
            simd.splat_f64x4(nu[1]),
            simd.splat_f64x4(nu[2]),
            simd.splat_f64x4(nu[3]),
        );
        let [a0, a1, a2] = row(block, 0);
        let [b0, b1, b2] = row(block, row_stride);
        let [c0, c1, c2] = row(block, 2 * row_stride);
        let [d0, d1, d2] = row(block, 3 * row_stride);
        let (a0, a1, a2) = (
            simd.mul_add_f64x4(b0, w1, simd.mul_f64x4(a0, w0)),
            simd.mul_add_f64x4(b1, w1, simd.mul_f64x4(a1, w0)),
            simd.mul_add_f64x4(b2, w1, simd.mul_f64x4(a2, w0)),
        );
        let (c0, c1, c2) = (
            simd.mul_add_f64x4(d0, w3, simd.mul_f64x4(c0, w2)),
            simd.mul_add_f64x4(d1, w3, simd.mul_f64x4(c1, w2)),
            simd.mul_add_f64x4(d2, w3, simd.mul_f64x4(c2, w2)),
        );
        let (r0, r1, r2) = (
            simd.add_f64x4(a0, c0),
            simd.add_f64x4(a1, c1),
            simd.add_f64x4(a2, c2),
        );
        let r0 = simd.mul_f64x4(r0, f64x4(n[0], n[0], n[0], n[1]));
        let r1 = simd.mul_f64x4(r1, f64x4(n[1], n[1], n[2], n[2]));
        let r2 = simd.mul_f64x4(r2, f64x4(n[2], n[3], n[3], n[3]));
        // The twelve lanes to three sums, lined up by whole-register shuffles:
        // `[x y z x] + [x y z ·] + [x y z ·] + [x y z ·]` from
        // `r₀ = [x y z x]`, `r₁ = [y z x y]`, `r₂ = [z x y z]`.
        let (avx, avx2) = (simd.avx, simd.avx2);
        let (r0, r1, r2): (__m256d, __m256d, __m256d) =
            (bytemuck::cast(r0), bytemuck::cast(r1), bytemuck::cast(r2));
        // [r₀₂ r₀₃ r₁₀ r₁₁], then [r₀₃ r₁₀ r₁₁ r₁₂].
        let shifted = avx._mm256_permute2f128_pd::<0x21>(r0, r1);
        let second = avx._mm256_shuffle_pd::<0b0101>(shifted, r1);
        // [r₁₂ r₁₃ r₂₀ r₂₁] and [r₂₁ r₂₂ r₂₃ r₂₀].
        let third = avx._mm256_permute2f128_pd::<0x21>(r1, r2);
        let fourth = avx2._mm256_permute4x64_pd::<0b00_11_10_01>(r2);
        let sum: f64x4 = bytemuck::cast(
            avx._mm256_add_pd(avx._mm256_add_pd(r0, second), avx._mm256_add_pd(third, fourth)),
        );
        Point3::new(sum.0, sum.1, sum.2)
    }
}

/// [`Bicubic::eval_into`]'s loop, run by `pulp` with the features enabled. A struct rather
/// than a closure, and no closures inside (`map`, `from_fn`, helpers): code that is not
/// inlined into the function with the features is compiled without them, and every
/// intrinsic in it becomes a call (measured: ten times slower).
struct EvalInto<'b, 'a, S> {
    wide: &'b Bicubic<'a>,
    params: &'b [[Real; 2]],
    out: &'b mut [Point3<Real>],
    spans: S,
}

impl<S: Spans> pulp::NullaryFnOnce for EvalInto<'_, '_, S> {
    type Output = ();

    #[inline(always)]
    fn call(self) {
        // `SIDE_BY_SIDE` points' spans first, then their points: each point's chain of
        // dependent operations overlaps the others'.
        let (groups, rest) = self.params.as_chunks::<SIDE_BY_SIDE>();
        let (out_groups, out_rest) = self.out.as_chunks_mut::<SIDE_BY_SIDE>();
        for (out, params) in out_groups.iter_mut().zip(groups) {
            let mut spans = [[0; 2]; SIDE_BY_SIDE];
            for (s, &[u, v]) in spans.iter_mut().zip(params) {
                *s = self.spans.of(u, v);
            }
            for ((o, &s), &[u, v]) in out.iter_mut().zip(&spans).zip(params) {
                *o = self.wide.point(s, u, v);
            }
        }
        for (o, &[u, v]) in out_rest.iter_mut().zip(rest) {
            *o = self.wide.point(self.spans.of(u, v), u, v);
        }
    }
}

/// The points [`EvalInto`]'s loop takes at a time (see the module's docs for the measures).
const SIDE_BY_SIDE: usize = 8;

/// How a point's knot spans are found: a type for each way, so that [`EvalInto`]'s loop is
/// compiled for each without a branch inside.
trait Spans: Copy {
    /// The spans in `u` and `v` of a point in the domain.
    fn of(self, u: Real, v: Real) -> [usize; 2];
}

/// Uniform knots in both directions: the spans by arithmetic alone
/// ([`crate::bspline::KnotVector::uniform_spans`]), without the stored knots' comparisons that make
/// [`crate::bspline::KnotVector::span`] exact at a knot (they were 30% of the time: 46.7 → 67.2 M points/s
/// without them). Near a knot the neighbouring span may be chosen; its polynomial agrees there
/// to rounding.
#[derive(Clone, Copy)]
struct Uniform([(Real, Real, usize); 2]);

impl Spans for Uniform {
    #[inline(always)]
    fn of(self, u: Real, v: Real) -> [usize; 2] {
        let [(u0, inverse_u, last_u), (v0, inverse_v, last_v)] = self.0;
        [
            (3 + floor_or_below((u - u0) * inverse_u)).min(last_u),
            (3 + floor_or_below((v - v0) * inverse_v)).min(last_v),
        ]
    }
}

/// `⌊x⌋` for `0 ≤ x < 2³¹`, or `x − 1` when `x` is a whole number: `x − ½` rounded to the
/// nearest by adding `1.5 · 2⁵²` (the integer is then the low bits of the sum), where a cast
/// (`as usize`, saturating and mapping NaN to 0) is a dozen instructions. Used for a knot
/// span, where `x − 1` for a whole `x` is the neighbouring span at a knot, as good there.
#[inline(always)]
fn floor_or_below(x: Real) -> usize {
    const ROUND: Real = 6_755_399_441_055_744.0;
    ((x - 0.5 + ROUND).to_bits() as u32) as usize
}

/// Any knots: [`crate::bspline::KnotVector::span`]'s own lookup.
#[derive(Clone, Copy)]
struct Search<'a>(&'a BSplineSurface);

impl Spans for Search<'_> {
    #[inline(always)]
    fn of(self, u: Real, v: Real) -> [usize; 2] {
        [
            self.0.knots_u().span_in_domain(u),
            self.0.knots_v().span_in_domain(v),
        ]
    }
}

/// The four control points from `block[offset..]`, 12 coordinates, in three registers.
#[inline(always)]
fn row(block: &[Real], offset: usize) -> [f64x4; 3] {
    let r: &[Real; 12] = block[offset..offset + 12].try_into().expect("four points");
    [
        f64x4(r[0], r[1], r[2], r[3]),
        f64x4(r[4], r[5], r[6], r[7]),
        f64x4(r[8], r[9], r[10], r[11]),
    ]
}

/// A register's four values.
#[inline(always)]
fn lanes(a: f64x4) -> [Real; 4] {
    [a.0, a.1, a.2, a.3]
}

/// A knot span's four cubic basis functions as polynomials in `t = (u − start)/h`: the span's
/// entries of [`SpanPolynomials`] in one record, so that a point's lookup is one bounds check
/// (reading them from `SpanPolynomials` itself was 2–5% slower, three pairs of alternating
/// runs).
#[derive(Clone, Copy)]
struct CubicSpan {
    start: Real,
    inverse: Real,
    /// `c₀ … c₃`, each the four functions' coefficients of `tᵏ`.
    c: [[Real; 4]; 4],
}

impl CubicSpan {
    /// Every span of `knots` (of degree 3), indexed by span.
    fn all(knots: &crate::bspline::KnotVector) -> Vec<CubicSpan> {
        let polynomials = SpanPolynomials::new(knots);
        (0..knots.num_control_points())
            .map(|span| {
                let [start, inverse] = polynomials.start(span);
                let c = polynomials.coefficients(span);
                CubicSpan {
                    start,
                    inverse,
                    c: [0, 1, 2, 3].map(|k| [c[4 * k], c[4 * k + 1], c[4 * k + 2], c[4 * k + 3]]),
                }
            })
            .collect()
    }

    /// The four functions at `u`, in one register: Horner's rule, three fused multiply-adds
    /// where the Cox–de Boor recurrence is a chain of dependent products.
    #[inline(always)]
    fn eval(&self, simd: V3, u: Real) -> f64x4 {
        let t = simd.splat_f64x4((u - self.start) * self.inverse);
        // No closure (see `EvalInto`).
        let [c0, c1, c2, c3] = self.c;
        let c0 = f64x4(c0[0], c0[1], c0[2], c0[3]);
        let c1 = f64x4(c1[0], c1[1], c1[2], c1[3]);
        let c2 = f64x4(c2[0], c2[1], c2[2], c2[3]);
        let c3 = f64x4(c3[0], c3[1], c3[2], c3[3]);
        simd.mul_add_f64x4(simd.mul_add_f64x4(simd.mul_add_f64x4(c3, t, c2), t, c1), t, c0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::random::Lcg;

    /// `n` control points with coordinates uniform in [−5, 5].
    fn random_grid(rng: &mut Lcg, n: usize) -> Vec<Point3<Real>> {
        (0..n)
            .map(|_| rng.point_in([-5.0, -5.0, -5.0], [5.0, 5.0, 5.0]))
            .collect()
    }

    /// `wide` at `params` against the surface's own `eval`, to 1e-12.
    fn agrees_with_eval(surface: &BSplineSurface, wide: &Bicubic, params: &[[Real; 2]]) {
        let mut out = vec![Point3::origin(); params.len()];
        wide.eval_into(params, &mut out);
        for (p, &[u, v]) in out.iter().zip(params) {
            let expected = surface.eval(u, v).unwrap();
            assert!(
                (p - expected).norm() <= 1e-12,
                "({u}, {v}): {p} against {expected}"
            );
        }
    }

    /// Uniform knots take the spans by arithmetic ([`Uniform`]): against `eval` at random
    /// parameters, at every knot, and one rounding step either side of every knot (where the
    /// arithmetic may pick the neighbouring span), on a domain that does not start at 0.
    #[test]
    fn the_uniform_path_agrees_with_eval_at_and_around_knots() {
        let Some(_) = V3::try_new() else {
            return;
        };
        let mut rng = Lcg(11);
        let (rows, cols) = (13, 10);
        let grid = random_grid(&mut rng, rows * cols);
        let knots_u = crate::bspline::KnotVector::clamped_uniform(3, rows, -0.3, 0.7).unwrap();
        let knots_v = crate::bspline::KnotVector::clamped_uniform(3, cols, 2.0, 9.0).unwrap();
        assert!(knots_u.is_uniform() && knots_v.is_uniform());
        let (du, dv) = (knots_u.breakpoints(), knots_v.breakpoints());
        let surface = BSplineSurface::new(knots_u, knots_v, rows, cols, grid).unwrap();
        let wide = Bicubic::new(&surface).unwrap();
        assert!(wide.uniform.is_some());
        let around = |t: Real, (lo, hi): (Real, Real)| {
            [t.next_down(), t, t.next_up()]
                .into_iter()
                .filter(move |x| (lo..=hi).contains(x))
        };
        let (domain_u, domain_v) = (surface.knots_u().domain(), surface.knots_v().domain());
        let mut params: Vec<[Real; 2]> = (0..2001)
            .map(|_| [rng.uniform(-0.3, 0.7), rng.uniform(2.0, 9.0)])
            .collect();
        for &u in &du {
            for &v in &dv {
                for u in around(u, domain_u) {
                    params.extend(around(v, domain_v).map(|v| [u, v]));
                }
            }
        }
        agrees_with_eval(&surface, &wide, &params);
    }

    /// `floor_or_below` is the floor off whole numbers and the floor or one less on them.
    #[test]
    fn floor_or_below_is_the_floor_or_one_less_at_whole_numbers() {
        for k in 0..2000u32 {
            let x = k as Real;
            let got = floor_or_below(x);
            assert!(got == k as usize || got + 1 == k as usize, "{x}: {got}");
            for y in [x.next_up(), x + 0.25, x + 0.5, x + 0.75, (x + 1.0).next_down()] {
                assert_eq!(floor_or_below(y), k as usize, "{y}");
            }
        }
    }

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
        let grid = random_grid(&mut rng, rows * cols);
        let surface =
            BSplineSurface::new(knots(&mut rng, rows), knots(&mut rng, cols), rows, cols, grid).unwrap();
        let wide = Bicubic::new(&surface).unwrap();
        let mut params: Vec<[Real; 2]> = (0..1001).map(|_| [rng.next(), rng.next()]).collect();
        params.extend([[0.0, 0.0], [1.0, 1.0], [0.0, 1.0], [1.0, 0.5], [0.5, 0.0]]);
        agrees_with_eval(&surface, &wide, &params);
    }
}
