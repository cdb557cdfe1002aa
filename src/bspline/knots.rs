//! Knot vectors: validation, constructors and span lookup.

use serde::{Deserialize, Serialize};

use super::BSplineError;
use crate::Real;

/// The highest degree the kernel accepts.
///
/// Basis evaluation keeps its scratch space on the stack (The NURBS Book A2.2 and A2.3 need
/// `degree + 1` and `(degree + 1)²` values), so the degree is bounded. Faces use degree 3;
/// nothing in CAD practice goes near 15.
pub const MAX_DEGREE: usize = 15;

/// A validated, non-decreasing knot vector of a B-spline of a given degree.
///
/// A B-spline of degree `p` with `n` control points has `n + p + 1` knots
/// `U = (u₀ ≤ u₁ ≤ … ≤ u_{n+p})`, and its parameter domain is `[u_p, u_n]`. The vector always
/// stores *all* knots: there is no "order" and no dropped end knot (the OpenNURBS convention
/// that causes off-by-one bugs).
///
/// Invariants, checked by [`KnotVector::new`]:
/// * `0 ≤ degree ≤ MAX_DEGREE`,
/// * at least `2·(degree + 1)` knots, i.e. at least `degree + 1` control points,
/// * every knot finite, the sequence non-decreasing,
/// * no knot value repeated more than `degree + 1` times,
/// * a non-empty domain: `u_p < u_n`.
///
/// Span lookup ([`KnotVector::span`]) is O(1) when the knots inside the domain are equally
/// spaced (clamped or plain uniform vectors) and a binary search otherwise.
///
/// # Examples
///
/// ```
/// use splineface::bspline::KnotVector;
///
/// // Cubic, 6 control points, clamped on [0, 1]: 6 + 3 + 1 = 10 knots.
/// let knots = KnotVector::clamped_uniform(3, 6, 0.0, 1.0)?;
/// assert_eq!(knots.knots(), &[0.0, 0.0, 0.0, 0.0, 1.0 / 3.0, 2.0 / 3.0, 1.0, 1.0, 1.0, 1.0]);
/// assert_eq!(knots.num_control_points(), 6);
/// assert_eq!(knots.domain(), (0.0, 1.0));
/// assert_eq!(knots.span(0.5), Some(4));
/// assert_eq!(knots.span(1.0), Some(5)); // the right end belongs to the last span
/// assert_eq!(knots.span(1.5), None);
/// # Ok::<(), splineface::bspline::BSplineError>(())
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "RawKnotVector", into = "RawKnotVector")]
pub struct KnotVector {
    degree: usize,
    knots: Vec<Real>,
    // Derived from the two fields above, cached for the hot paths.
    /// `1 / h` when every span of the domain has the same width `h` (enables O(1) lookup).
    inverse_uniform_width: Option<Real>,
    /// The domain `[u_p, u_n]`.
    start: Real,
    end: Real,
    /// The last non-empty span of the domain (where its right end belongs).
    last_span: usize,
    /// Per span `i`, the reciprocals `1 / (u_{i+r+1} − u_{i+r+1−j})` of the Cox–de Boor
    /// denominators for `j = 1..=p`, `r = 0..j`: `p(p+1)/2` values, so that basis evaluation
    /// needs no division. Zero for empty spans (never read).
    inverse_denominators: Vec<Real>,
}

/// The serialised form: only what defines the vector; the lookup acceleration is rebuilt.
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawKnotVector {
    degree: usize,
    knots: Vec<Real>,
}

impl TryFrom<RawKnotVector> for KnotVector {
    type Error = BSplineError;
    fn try_from(raw: RawKnotVector) -> Result<Self, Self::Error> {
        KnotVector::new(raw.degree, raw.knots)
    }
}

impl From<KnotVector> for RawKnotVector {
    fn from(k: KnotVector) -> Self {
        RawKnotVector {
            degree: k.degree,
            knots: k.knots,
        }
    }
}

impl KnotVector {
    /// Validates `knots` as the knot vector of a degree-`degree` B-spline.
    ///
    /// # Errors
    /// [`BSplineError::DegreeTooHigh`], [`BSplineError::TooFewKnots`],
    /// [`BSplineError::NonFiniteKnot`], [`BSplineError::DecreasingKnots`],
    /// [`BSplineError::KnotMultiplicityTooHigh`] or [`BSplineError::EmptyDomain`], as listed on
    /// the type.
    pub fn new(degree: usize, knots: Vec<Real>) -> Result<Self, BSplineError> {
        if degree > MAX_DEGREE {
            return Err(BSplineError::DegreeTooHigh {
                degree,
                max: MAX_DEGREE,
            });
        }
        let need = 2 * (degree + 1);
        if knots.len() < need {
            return Err(BSplineError::TooFewKnots {
                got: knots.len(),
                need,
            });
        }
        if let Some((index, &value)) = knots.iter().enumerate().find(|(_, k)| !k.is_finite()) {
            return Err(BSplineError::NonFiniteKnot { index, value });
        }
        if let Some(index) = (1..knots.len()).find(|&i| knots[i] < knots[i - 1]) {
            return Err(BSplineError::DecreasingKnots {
                index,
                previous: knots[index - 1],
                value: knots[index],
            });
        }
        let mut run_start = 0;
        for i in 1..=knots.len() {
            if i == knots.len() || knots[i] != knots[run_start] {
                let multiplicity = i - run_start;
                if multiplicity > degree + 1 {
                    return Err(BSplineError::KnotMultiplicityTooHigh {
                        value: knots[run_start],
                        multiplicity,
                        max: degree + 1,
                    });
                }
                run_start = i;
            }
        }
        let n = knots.len() - degree - 1;
        let (start, end) = (knots[degree], knots[n]);
        if start >= end {
            return Err(BSplineError::EmptyDomain { start, end });
        }
        let inverse_uniform_width = uniform_inverse_width(&knots[degree..=n]);
        let last_span = (degree..n)
            .rev()
            .find(|&i| knots[i] < knots[i + 1])
            .expect("non-empty domain");
        let per_span = degree * (degree + 1) / 2;
        let mut inverse_denominators = vec![0.0; knots.len() * per_span];
        for span in degree..n {
            if knots[span] == knots[span + 1] {
                continue;
            }
            let mut at = span * per_span;
            for j in 1..=degree {
                for r in 0..j {
                    // ≥ u_{span+1} − u_span > 0 on a non-empty span.
                    inverse_denominators[at] = 1.0 / (knots[span + r + 1] - knots[span + r + 1 - j]);
                    at += 1;
                }
            }
        }
        Ok(KnotVector {
            degree,
            knots,
            inverse_uniform_width,
            start,
            end,
            last_span,
            inverse_denominators,
        })
    }

    /// The clamped (open) uniform knot vector: `degree + 1` knots at each end of
    /// `[start, end]` and `control_points − degree − 1` equally spaced interior knots.
    ///
    /// A clamped B-spline interpolates its first and last control points; this is the usual
    /// choice for surfaces and the one the face reference uses.
    ///
    /// # Errors
    /// [`BSplineError::DegreeTooHigh`], [`BSplineError::TooFewKnots`] when
    /// `control_points ≤ degree`, [`BSplineError::EmptyDomain`] when `start ≥ end` or either is
    /// not finite.
    pub fn clamped_uniform(
        degree: usize,
        control_points: usize,
        start: Real,
        end: Real,
    ) -> Result<Self, BSplineError> {
        check_constructor_args(degree, control_points, start, end)?;
        let spans = control_points - degree;
        let mut knots = Vec::with_capacity(control_points + degree + 1);
        knots.extend(std::iter::repeat_n(start, degree + 1));
        knots.extend((1..spans).map(|i| lerp(start, end, i, spans)));
        knots.extend(std::iter::repeat_n(end, degree + 1));
        Self::new(degree, knots)
    }

    /// The plain (unclamped, periodic-style) uniform knot vector whose *domain* is
    /// `[start, end]`: all `control_points + degree + 1` knots are equally spaced, with `degree`
    /// of them before `start` and after `end`.
    ///
    /// # Errors
    /// As [`KnotVector::clamped_uniform`].
    pub fn uniform(
        degree: usize,
        control_points: usize,
        start: Real,
        end: Real,
    ) -> Result<Self, BSplineError> {
        check_constructor_args(degree, control_points, start, end)?;
        let spans = control_points - degree;
        let h = (end - start) / spans as Real;
        let total = control_points + degree + 1;
        let knots = (0..total)
            .map(|i| {
                let k = i as isize - degree as isize;
                // Exact at the domain ends whatever the rounding of `h`.
                if k >= 0 && k as usize <= spans {
                    lerp(start, end, k as usize, spans)
                } else {
                    start + k as Real * h
                }
            })
            .collect();
        Self::new(degree, knots)
    }

    /// The degree `p`.
    #[inline]
    pub fn degree(&self) -> usize {
        self.degree
    }

    /// All knots, `num_control_points() + degree() + 1` of them.
    #[inline]
    pub fn knots(&self) -> &[Real] {
        &self.knots
    }

    /// The number of control points `n = knots − degree − 1` a spline on these knots has.
    #[inline]
    pub fn num_control_points(&self) -> usize {
        self.knots.len() - self.degree - 1
    }

    /// The parameter domain `[u_p, u_n]`.
    #[inline]
    pub fn domain(&self) -> (Real, Real) {
        (self.start, self.end)
    }

    /// Whether every knot span of the domain has the same width (span lookup is then O(1)).
    #[inline]
    pub fn is_uniform(&self) -> bool {
        self.inverse_uniform_width.is_some()
    }

    /// For uniform knots, `(start, 1/h, last span)`: the span of a `u` in the domain is then
    /// `min(p + ⌊(u − start)/h⌋, last span)` by arithmetic alone. That agrees with
    /// [`KnotVector::span`] except for parameters within rounding of a knot, where it may give
    /// the neighbouring span; uniform knots are simple inside the domain, so the two spans'
    /// polynomials agree there in value and `p − 1` derivatives, and the points differ by
    /// rounding only. `None` for non-uniform knots.
    #[inline]
    pub(crate) fn uniform_spans(&self) -> Option<(Real, Real, usize)> {
        self.inverse_uniform_width
            .map(|inverse| (self.start, inverse, self.last_span))
    }

    /// Whether the spline interpolates its end control points: the first and last
    /// `degree + 1` knots are equal.
    pub fn is_clamped(&self) -> bool {
        let p = self.degree;
        let k = &self.knots;
        k[..=p].iter().all(|&x| x == k[0]) && k[k.len() - p - 1..].iter().all(|&x| x == k[k.len() - 1])
    }

    /// The knot span index `i` with `u_i ≤ u < u_{i+1}` and `p ≤ i < n`, the right end of the
    /// domain belonging to the last non-empty span (The NURBS Book A2.1). `None` when `u` is
    /// NaN or outside the domain.
    ///
    /// The basis functions that can be non-zero at `u` are `N_{i−p}, …, N_i`.
    #[inline]
    pub fn span(&self, u: Real) -> Option<usize> {
        // Written so that NaN fails the test.
        if !(u >= self.start && u <= self.end) {
            return None;
        }
        Some(self.span_in_domain(u))
    }

    /// [`KnotVector::span`] for a `u` already known to lie in the domain.
    #[inline(always)]
    pub(crate) fn span_in_domain(&self, u: Real) -> usize {
        let k = &self.knots;
        if u >= self.end {
            return self.last_span;
        }
        if let Some(inv_h) = self.inverse_uniform_width {
            // Guess by arithmetic (u − start ≥ 0, so the cast is a floor), then correct against
            // the stored knots so the answer is exactly the binary search's whatever the
            // rounding: uniform spans are equal to 10⁻⁹ of their width, so one step at most.
            let p = self.degree;
            let mut i = (p + ((u - self.start) * inv_h) as usize).min(self.last_span);
            while i > p && u < k[i] {
                i -= 1;
            }
            while i < self.last_span && u >= k[i + 1] {
                i += 1;
            }
            return i;
        }
        // First knot strictly greater than u, within [p + 1, n]; the span is the one before it.
        let (p, n) = (self.degree, self.num_control_points());
        p + k[p + 1..=n].partition_point(|&x| x <= u)
    }

    /// The reciprocal Cox–de Boor denominators of span `span` (see the field's comment).
    #[inline(always)]
    pub(crate) fn inverse_denominators(&self, span: usize) -> &[Real] {
        let per_span = self.degree * (self.degree + 1) / 2;
        &self.inverse_denominators[span * per_span..(span + 1) * per_span]
    }

    /// The distinct knot values in the domain, ends included: the breakpoints between its
    /// non-empty spans.
    pub fn breakpoints(&self) -> Vec<Real> {
        let mut values: Vec<Real> = self
            .knots
            .iter()
            .copied()
            .filter(|&k| k >= self.start && k <= self.end)
            .collect();
        values.dedup();
        values
    }

    /// The first knot inside the domain repeated more than the degree, with its multiplicity:
    /// where a spline on these knots may jump (it is C⁻¹ there); `None` for a continuous one.
    pub(crate) fn jump(&self) -> Option<(Real, usize)> {
        let k = &self.knots;
        k.iter()
            .filter(|&&x| x > self.start && x < self.end)
            .map(|&x| (x, super::refine::multiplicity(k, x)))
            .find(|&(_, m)| m > self.degree)
    }

    /// `Ok` when `value` lies in the domain; else [`BSplineError::ParameterOutOfDomain`] for
    /// `direction` (NaN included).
    pub(crate) fn check_in_domain(
        &self,
        direction: super::Direction,
        value: Real,
    ) -> Result<(), BSplineError> {
        if value >= self.start && value <= self.end {
            Ok(())
        } else {
            Err(BSplineError::ParameterOutOfDomain {
                direction,
                value,
                start: self.start,
                end: self.end,
            })
        }
    }

    /// The Greville abscissae `ξᵢ = (u_{i+1} + … + u_{i+p}) / p`, one per control point (for
    /// degree 0, the span midpoints).
    ///
    /// A spline whose control values are `a + b·ξᵢ` is the linear function `a + b·u` (linear
    /// precision), which is why the fitting smoothness penalty is measured over these points.
    pub fn greville(&self) -> Vec<Real> {
        let p = self.degree;
        (0..self.num_control_points())
            .map(|i| {
                if p == 0 {
                    0.5 * (self.knots[i] + self.knots[i + 1])
                } else {
                    self.knots[i + 1..=i + p].iter().sum::<Real>() / p as Real
                }
            })
            .collect()
    }
}

fn check_constructor_args(
    degree: usize,
    control_points: usize,
    start: Real,
    end: Real,
) -> Result<(), BSplineError> {
    if degree > MAX_DEGREE {
        return Err(BSplineError::DegreeTooHigh {
            degree,
            max: MAX_DEGREE,
        });
    }
    if control_points <= degree {
        return Err(BSplineError::TooFewKnots {
            got: control_points + degree + 1,
            need: 2 * (degree + 1),
        });
    }
    if !(start.is_finite() && end.is_finite() && start < end) {
        return Err(BSplineError::EmptyDomain { start, end });
    }
    Ok(())
}

/// `start + (end − start)·i/n`, exact at `i = 0` and `i = n`.
fn lerp(start: Real, end: Real, i: usize, n: usize) -> Real {
    if i == n {
        end
    } else {
        let t = i as Real / n as Real;
        start + (end - start) * t
    }
}

/// `Some(1/h)` when all spans of `domain_knots` have width `h` to within rounding.
fn uniform_inverse_width(domain_knots: &[Real]) -> Option<Real> {
    let spans = domain_knots.len() - 1;
    let (start, end) = (domain_knots[0], domain_knots[spans]);
    let h = (end - start) / spans as Real;
    let tolerance = 1e-9 * h;
    let uniform = domain_knots
        .windows(2)
        .all(|w| ((w[1] - w[0]) - h).abs() <= tolerance);
    (uniform && h > 0.0).then(|| 1.0 / h)
}
