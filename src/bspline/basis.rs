//! B-spline basis functions and their derivatives (The NURBS Book, A2.2 and A2.3).
//!
//! Both functions write into a caller's slice and keep their scratch space on the stack, so a
//! hot loop evaluates them without allocating.

use super::knots::{KnotVector, MAX_DEGREE};
use crate::Real;

/// The `p + 1` basis functions `N_{i−p,p}(u), …, N_{i,p}(u)` that can be non-zero on span `i`
/// (The NURBS Book A2.2, the Cox–de Boor recursion in triangular form).
///
/// `span` must be the span of `u` ([`KnotVector::span`]); `out[r]` receives `N_{span−p+r,p}(u)`.
/// The values are non-negative and sum to 1 (partition of unity).
///
/// # Panics
/// If `out.len() < degree + 1`. A wrong `span` gives wrong values (checked in debug builds).
///
/// # Examples
///
/// ```
/// use splineface::bspline::{basis_functions, KnotVector};
///
/// let knots = KnotVector::clamped_uniform(2, 3, 0.0, 1.0)?; // one quadratic Bézier span
/// let u = 0.25;
/// let span = knots.span(u).unwrap();
/// let mut n = [0.0; 3];
/// basis_functions(&knots, span, u, &mut n);
/// // Bernstein polynomials: (1−u)², 2u(1−u), u².
/// assert_eq!(n, [0.5625, 0.375, 0.0625]);
/// # Ok::<(), splineface::bspline::BSplineError>(())
/// ```
pub fn basis_functions(knots: &KnotVector, span: usize, u: Real, out: &mut [Real]) {
    let p = knots.degree();
    out[..=p].copy_from_slice(&basis_fixed::<RUNTIME>(knots, span, u)[..=p]);
}

/// The const width that means "read the degree at run time": arrays of this size hold the
/// basis of any supported degree.
pub(crate) const RUNTIME: usize = MAX_DEGREE + 1;

/// The width `p + 1` of a basis evaluation: the constant `N` when the caller fixed it at
/// compile time, else (`N = RUNTIME`) read from the degree.
#[inline(always)]
pub(crate) fn width<const N: usize>(degree: usize) -> usize {
    if N == RUNTIME { degree + 1 } else { N }
}

/// [`basis_functions`] for the kernel's hot loops, returning `[Real; N]` with `N = p + 1` fixed
/// at compile time where the caller knows it (the loops then unroll and the values stay in
/// registers), or `N = RUNTIME` to read the degree at run time. Divisions are replaced by the
/// knot vector's cached reciprocals.
#[inline(always)]
pub(crate) fn basis_fixed<const N: usize>(knots: &KnotVector, span: usize, u: Real) -> [Real; N] {
    let p = width::<N>(knots.degree()) - 1;
    debug_assert_eq!(p, knots.degree());
    debug_assert!(span >= p && span < knots.num_control_points());
    debug_assert!({
        let k = knots.knots();
        k[span] <= u && (u < k[span + 1] || span + 1 == knots.num_control_points())
    });
    // k[p + d] is u_{span+d}, for d in −p..=p; one bounds check here instead of one per access.
    let k = &knots.knots()[span - p..span + p + 1];
    let inverse = &knots.inverse_denominators(span)[..p * (p + 1) / 2];
    let mut out = [0.0; N];
    let mut left = [0.0; N];
    let mut right = [0.0; N];
    out[0] = 1.0;
    let mut at = 0;
    // Exclusive ranges: LLVM unrolls `a..b` loops of constant trip count, not always `a..=b`.
    for j in 1..p + 1 {
        left[j] = u - k[p + 1 - j];
        right[j] = k[p + j] - u;
        let mut saved = 0.0;
        for r in 0..j {
            // out[r] / (u_{span+r+1} − u_{span+r+1−j}); the denominator is ≥ u_{span+1} − u_span > 0.
            let temp = out[r] * inverse[at + r];
            out[r] = saved + right[r + 1] * temp;
            saved = left[j - r] * temp;
        }
        at += j;
        out[j] = saved;
    }
    out
}

/// The basis functions on span `span` and their derivatives up to `order` (The NURBS Book
/// A2.3).
///
/// `out` is `(order + 1) × (p + 1)`, row-major: `out[k·(p+1) + r]` receives the `k`-th
/// derivative `N⁽ᵏ⁾_{span−p+r,p}(u)`. Derivatives of order above `p` are zero.
///
/// # Panics
/// If `out.len() < (order + 1)·(degree + 1)`.
///
/// # Examples
///
/// ```
/// use splineface::bspline::{basis_derivatives, KnotVector};
///
/// let knots = KnotVector::clamped_uniform(2, 3, 0.0, 1.0)?;
/// let mut d = [0.0; 9];
/// basis_derivatives(&knots, knots.span(0.25).unwrap(), 0.25, 2, &mut d);
/// // d/du of (1−u)², 2u(1−u), u² at u = 1/4, then the second derivatives 2, −4, 2.
/// assert_eq!(&d[3..6], &[-1.5, 1.0, 0.5]);
/// assert_eq!(&d[6..9], &[2.0, -4.0, 2.0]);
/// # Ok::<(), splineface::bspline::BSplineError>(())
/// ```
pub fn basis_derivatives(knots: &KnotVector, span: usize, u: Real, order: usize, out: &mut [Real]) {
    // Tables sized for the degree: zeroing the largest degree's 16 × 16 table was a tenth of
    // point inversion's time on cubic surfaces. The arithmetic is the same whatever the size.
    if knots.degree() <= 3 {
        derivatives_in::<4>(knots, span, u, order, out);
    } else {
        derivatives_in::<{ MAX_DEGREE + 1 }>(knots, span, u, order, out);
    }
}

/// [`basis_derivatives`] with tables of side `N ≥ p + 1`.
#[inline(always)]
fn derivatives_in<const N: usize>(knots: &KnotVector, span: usize, u: Real, order: usize, out: &mut [Real]) {
    let p = knots.degree();
    let k = knots.knots();
    let w = p + 1;
    let out = &mut out[..(order + 1) * w];
    debug_assert!(p < N && span >= p && span < knots.num_control_points());

    // ndu: upper triangle holds basis functions of rising degree, lower triangle knot differences.
    let mut ndu = [[0.0; N]; N];
    let mut left = [0.0; N];
    let mut right = [0.0; N];
    ndu[0][0] = 1.0;
    for j in 1..=p {
        left[j] = u - k[span + 1 - j];
        right[j] = k[span + j] - u;
        let mut saved = 0.0;
        for r in 0..j {
            ndu[j][r] = right[r + 1] + left[j - r];
            let temp = ndu[r][j - 1] / ndu[j][r];
            ndu[r][j] = saved + right[r + 1] * temp;
            saved = left[j - r] * temp;
        }
        ndu[j][j] = saved;
    }
    for (j, o) in out[..w].iter_mut().enumerate() {
        *o = ndu[j][p];
    }
    out[w..].fill(0.0);
    let top = order.min(p);
    if top == 0 {
        return;
    }

    let p_i = p as isize;
    let mut a = [[0.0; N]; 2];
    for r in 0..=p {
        let r_i = r as isize;
        let (mut s1, mut s2) = (0usize, 1usize);
        a[0][0] = 1.0;
        for kk in 1..=top {
            let k_i = kk as isize;
            let mut d = 0.0;
            let rk = r_i - k_i;
            let pk = (p_i - k_i) as usize;
            if rk >= 0 {
                a[s2][0] = a[s1][0] / ndu[pk + 1][rk as usize];
                d = a[s2][0] * ndu[rk as usize][pk];
            }
            let j1 = if rk >= -1 { 1 } else { (-rk) as usize };
            let j2 = if r_i - 1 <= pk as isize { kk - 1 } else { p - r };
            for j in j1..=j2 {
                let idx = (rk + j as isize) as usize;
                a[s2][j] = (a[s1][j] - a[s1][j - 1]) / ndu[pk + 1][idx];
                d += a[s2][j] * ndu[idx][pk];
            }
            if r <= pk {
                a[s2][kk] = -a[s1][kk - 1] / ndu[pk + 1][r];
                d += a[s2][kk] * ndu[r][pk];
            }
            out[kk * w + r] = d;
            std::mem::swap(&mut s1, &mut s2);
        }
    }
    // Multiply by p!/(p−k)!.
    let mut factor = p as Real;
    for kk in 1..=top {
        for o in &mut out[kk * w..(kk + 1) * w] {
            *o *= factor;
        }
        factor *= (p - kk) as Real;
    }
}

/// The basis functions on each span of a knot vector as polynomials in the span's own
/// parameter `t = (u − uᵢ)/(uᵢ₊₁ − uᵢ) ∈ [0, 1]`: `N_{i−p+r}(u) = Σₖ cₖ[r] tᵏ`, the
/// coefficients from the functions' derivatives at the span's start (`cₖ = N⁽ᵏ⁾(uᵢ) hᵏ / k!`,
/// [`basis_derivatives`], The NURBS Book A2.3). Values and derivatives are then Horner's rule,
/// with no division and no table to clear; they agree with A2.3 to rounding. On a span's upper
/// end the polynomial is the span's own (derivatives from below).
#[derive(Debug, Clone)]
pub(crate) struct SpanPolynomials {
    degree: usize,
    /// Per span: `uᵢ` and `1/h` (zeros for an empty span, which no parameter falls in).
    starts: Vec<[Real; 2]>,
    /// Per span: `(p + 1)²` coefficients, `cₖ[r]` at `k·(p + 1) + r`.
    coefficients: Vec<Real>,
}

impl SpanPolynomials {
    pub(crate) fn new(knots: &KnotVector) -> Self {
        let p = knots.degree();
        let w = p + 1;
        let k = knots.knots();
        let spans = knots.num_control_points();
        let mut starts = vec![[0.0; 2]; spans];
        let mut coefficients = vec![0.0; spans * w * w];
        let mut derivatives = vec![0.0; w * w];
        for span in p..spans {
            let h = k[span + 1] - k[span];
            if h <= 0.0 {
                continue;
            }
            basis_derivatives(knots, span, k[span], p, &mut derivatives);
            let mut scale = 1.0;
            let c = &mut coefficients[span * w * w..(span + 1) * w * w];
            for order in 0..w {
                if order > 0 {
                    scale *= h / order as Real;
                }
                for r in 0..w {
                    c[order * w + r] = derivatives[order * w + r] * scale;
                }
            }
            starts[span] = [k[span], 1.0 / h];
        }
        SpanPolynomials {
            degree: p,
            starts,
            coefficients,
        }
    }

    /// Span `span`'s `uᵢ` and `1/h`.
    #[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))] // the AVX2 path's
    #[inline(always)]
    pub(crate) fn start(&self, span: usize) -> [Real; 2] {
        self.starts[span]
    }

    /// Span `span`'s coefficients, `cₖ[r]` at `k·(p + 1) + r`.
    #[inline(always)]
    pub(crate) fn coefficients(&self, span: usize) -> &[Real] {
        let w = self.degree + 1;
        &self.coefficients[span * w * w..(span + 1) * w * w]
    }

    /// [`SpanPolynomials::derivatives`] to order 2 for a degree known at compile time
    /// (`W = p + 1`): `[values, first, second]`, loops the compiler unrolls.
    #[inline(always)]
    #[allow(clippy::needless_range_loop)] // r indexes the three rows of `out`
    pub(crate) fn derivatives_fixed<const W: usize>(&self, span: usize, u: Real) -> [[Real; W]; 3] {
        debug_assert_eq!(self.degree + 1, W);
        let [start, inverse] = self.starts[span];
        let t = (u - start) * inverse;
        let c = &self.coefficients[span * W * W..(span + 1) * W * W];
        let mut out = [[0.0; W]; 3];
        for r in 0..W {
            let [value, first, second] = horner(c, W, r, t);
            out[0][r] = value;
            out[1][r] = first * inverse;
            out[2][r] = second * inverse * inverse;
        }
        out
    }

    /// As [`basis_derivatives`] for orders up to 2: `out[k·(p + 1) + r]` receives
    /// `N⁽ᵏ⁾_{span−p+r}(u)` for `k ≤ order`, zeros above the degree.
    #[inline]
    pub(crate) fn derivatives(&self, span: usize, u: Real, order: usize, out: &mut [Real]) {
        debug_assert!(order <= 2);
        let w = self.degree + 1;
        let [start, inverse] = self.starts[span];
        let t = (u - start) * inverse;
        let c = self.coefficients(span);
        for r in 0..w {
            let [value, first, second] = horner(c, w, r, t);
            out[r] = value;
            if order >= 1 {
                out[w + r] = first * inverse;
            }
            if order >= 2 {
                out[2 * w + r] = second * inverse * inverse;
            }
        }
    }
}

/// Basis function `r`'s value and first two derivatives in the span's own parameter `t`, by
/// Horner's rule over its coefficients (`cₖ[r]` at `k·w + r`, `w = p + 1`). Inlined, so that
/// a `w` known at compile time unrolls the loop.
#[inline(always)]
fn horner(c: &[Real], w: usize, r: usize, t: Real) -> [Real; 3] {
    let (mut value, mut first, mut second) = (c[(w - 1) * w + r], 0.0, 0.0);
    for k in (0..w - 1).rev() {
        second = second * t + 2.0 * first;
        first = first * t + value;
        value = value * t + c[k * w + r];
    }
    [value, first, second]
}

/// Knots of `degree` clamped to `[0, 1]` about the `inner` values (sorted here), for tests.
#[cfg(test)]
pub(crate) fn clamped(degree: usize, mut inner: Vec<Real>) -> KnotVector {
    inner.sort_by(Real::total_cmp);
    let knots: Vec<Real> = std::iter::repeat_n(0.0, degree + 1)
        .chain(inner)
        .chain(std::iter::repeat_n(1.0, degree + 1))
        .collect();
    KnotVector::new(degree, knots).expect("clamped knots in [0, 1]")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::random::Lcg;

    /// The span polynomials against A2.3 (`basis_derivatives`), orders 0 to 2, degrees 0 to 5,
    /// on random non-uniform knots with a repeated inner knot, at random parameters and at
    /// each span's two ends (its upper end from below, by its own polynomial).
    #[test]
    fn span_polynomials_agree_with_a2_3() {
        let mut rng = Lcg(11);
        for degree in 0..=5 {
            let n = degree + 7;
            let mut inner: Vec<Real> = (0..n - degree - 1).map(|_| rng.uniform(0.0, 1.0)).collect();
            if degree > 0 {
                inner.push(inner[0]); // a repeated knot: an empty span in between
            }
            let knots = clamped(degree, inner);
            let polynomials = SpanPolynomials::new(&knots);
            let k = knots.knots();
            let w = degree + 1;
            let (mut expected, mut got) = (vec![0.0; 3 * w], vec![0.0; 3 * w]);
            for span in degree..knots.num_control_points() {
                let (lo, hi) = (k[span], k[span + 1]);
                if hi <= lo {
                    continue;
                }
                for t in [0.0, 1.0, rng.next(), rng.next()] {
                    let u = lo + t * (hi - lo);
                    basis_derivatives(&knots, span, u, 2, &mut expected);
                    polynomials.derivatives(span, u, 2, &mut got);
                    for order in 0..3 {
                        // Derivatives grow like the span's inverse width to the order.
                        let size = (hi - lo).powi(-(order as i32)).max(1.0);
                        for r in 0..w {
                            let (e, g) = (expected[order * w + r], got[order * w + r]);
                            assert!(
                                (e - g).abs() <= 1e-11 * size,
                                "degree {degree}, span {span}, u {u}, order {order}, r {r}: {g} against {e}"
                            );
                        }
                    }
                }
            }
        }
    }
}
