//! B-spline curves `C(u) = Σᵢ Nᵢ,ₚ(u) Pᵢ` in 3D, and the iso-parametric curves of a surface.
//!
//! A curve is held as a surface of one column whose `v` direction has degree 0 over `[0, 1]`
//! (`F(u, v) = C(u)` for every `v`): the surface's knot vectors, basis code, evaluation,
//! derivatives, knot insertion, refinement, degree elevation, restriction and splitting serve
//! the curve as they are, with the same guarantees and tests behind them.

use nalgebra::{DMatrix, Point2, Point3, Vector3};

use super::{BSplineError, BSplineSurface, Direction, KnotVector, MAX_DEGREE, basis_functions};
use crate::Real;

/// A B-spline curve in 3D: a knot vector of degree `p` and its `n` control points
/// (`n + p + 1` knots).
///
/// # Examples
/// ```
/// use nalgebra::Point3;
/// use splineface::bspline::{BSplineCurve, KnotVector};
///
/// // The quadratic Bézier curve through (0, 0, 0), bending toward (1, 2, 0), ending at (2, 0, 0).
/// let knots = KnotVector::new(2, vec![0.0, 0.0, 0.0, 1.0, 1.0, 1.0])?;
/// let points = vec![Point3::new(0.0, 0.0, 0.0), Point3::new(1.0, 2.0, 0.0), Point3::new(2.0, 0.0, 0.0)];
/// let curve = BSplineCurve::new(knots, points)?;
/// assert_eq!(curve.eval(0.5)?, Point3::new(1.0, 1.0, 0.0));
/// let d = curve.derivatives(0.5, 2)?; // C, C′, C″
/// assert_eq!((d[1].x, d[1].y, d[2].y), (2.0, 0.0, -8.0));
/// # Ok::<(), splineface::bspline::BSplineError>(())
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct BSplineCurve {
    /// One column: `rows` = the control points, `v` of degree 0 over `[0, 1]`.
    column: BSplineSurface,
}

/// The `v` knot vector of a curve's column: degree 0, one span over `[0, 1]`.
fn flat() -> KnotVector {
    KnotVector::new(0, vec![0.0, 1.0]).expect("a valid degree-0 knot vector")
}

impl BSplineCurve {
    /// A curve from its knot vector and control points.
    ///
    /// # Errors
    /// [`BSplineError::CurvePointCount`] unless there are `knots.num_control_points()`
    /// points; [`BSplineError::NonFiniteCurvePoint`] for a point with a NaN or infinite
    /// coordinate.
    pub fn new(knots: KnotVector, points: Vec<Point3<Real>>) -> Result<Self, BSplineError> {
        let expected = knots.num_control_points();
        if points.len() != expected {
            return Err(BSplineError::CurvePointCount {
                got: points.len(),
                expected,
            });
        }
        if let Some(index) = points.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
            return Err(BSplineError::NonFiniteCurvePoint { index });
        }
        let rows = points.len();
        Ok(BSplineCurve {
            column: BSplineSurface::new(knots, flat(), rows, 1, points)?,
        })
    }

    fn from_column(column: BSplineSurface) -> Self {
        BSplineCurve { column }
    }

    /// The knot vector.
    pub fn knots(&self) -> &KnotVector {
        self.column.knots_u()
    }

    /// The degree.
    pub fn degree(&self) -> usize {
        self.column.degree_u()
    }

    /// The control points.
    pub fn control_points(&self) -> &[Point3<Real>] {
        self.column.control_points()
    }

    /// The parameter domain `[start, end]`.
    pub fn domain(&self) -> (Real, Real) {
        self.column.domain_u()
    }

    /// The point `C(u)`.
    ///
    /// # Errors
    /// [`BSplineError::ParameterOutOfDomain`] for `u` outside the domain (or NaN).
    ///
    /// # Examples
    /// ```
    /// use nalgebra::Point3;
    /// use splineface::bspline::{BSplineCurve, KnotVector};
    ///
    /// let knots = KnotVector::clamped_uniform(3, 5, 0.0, 1.0)?;
    /// let points = (0..5).map(|i| Point3::new(i as f64, ((i * 3) % 4) as f64, 0.5 * i as f64)).collect();
    /// let curve = BSplineCurve::new(knots, points)?;
    /// // Clamped: the curve starts and ends at its end control points.
    /// assert_eq!(curve.eval(0.0)?, Point3::new(0.0, 0.0, 0.0));
    /// assert_eq!(curve.eval(1.0)?, Point3::new(4.0, 0.0, 2.0));
    /// assert!(curve.eval(1.5).is_err());
    /// # Ok::<(), splineface::bspline::BSplineError>(())
    /// ```
    pub fn eval(&self, u: Real) -> Result<Point3<Real>, BSplineError> {
        self.knots().check_in_domain(Direction::U, u)?;
        self.column.eval(u, 0.0)
    }

    /// `C(u)` and its derivatives up to `order`, `[C, C′, C″, …]` (as vectors; those above the
    /// degree are zero). The NURBS Book A3.2, through the surface's A3.6.
    ///
    /// # Errors
    /// As [`BSplineCurve::eval`].
    ///
    /// # Examples
    /// ```
    /// use nalgebra::Point3;
    /// use splineface::bspline::{BSplineCurve, KnotVector};
    ///
    /// let knots = KnotVector::clamped_uniform(3, 5, 0.0, 1.0)?;
    /// let points = (0..5).map(|i| Point3::new(i as f64, ((i * 3) % 4) as f64, 0.5 * i as f64)).collect();
    /// let curve = BSplineCurve::new(knots, points)?;
    /// // [C, C′, C″, C‴, C⁗]: the fourth derivative of a cubic is zero.
    /// let d = curve.derivatives(0.4, 4)?;
    /// assert_eq!(d.len(), 5);
    /// assert_eq!(d[0], curve.eval(0.4)?.coords);
    /// assert_eq!(d[4].norm(), 0.0);
    /// // C′ against a central difference.
    /// let h = 1e-6;
    /// let difference = (curve.eval(0.4 + h)? - curve.eval(0.4 - h)?) / (2.0 * h);
    /// assert!((d[1] - difference).norm() < 1e-6);
    /// # Ok::<(), splineface::bspline::BSplineError>(())
    /// ```
    pub fn derivatives(&self, u: Real, order: usize) -> Result<Vec<Vector3<Real>>, BSplineError> {
        self.knots().check_in_domain(Direction::U, u)?;
        let d = self.column.derivatives(u, 0.0, order)?;
        Ok((0..=order).map(|k| d.get(k, 0)).collect())
    }

    /// The same curve with the knots `values` added (The NURBS Book A5.4); see
    /// [`BSplineSurface::refine_knots`] for the limits.
    ///
    /// # Errors
    /// As [`BSplineSurface::refine_knots`].
    ///
    /// # Examples
    /// ```
    /// use nalgebra::Point3;
    /// use splineface::bspline::{BSplineCurve, KnotVector};
    ///
    /// let knots = KnotVector::clamped_uniform(3, 5, 0.0, 1.0)?;
    /// let points = (0..5).map(|i| Point3::new(i as f64, ((i * 3) % 4) as f64, 0.5 * i as f64)).collect();
    /// let curve = BSplineCurve::new(knots, points)?;
    /// let finer = curve.refine_knots(&[0.1, 0.45, 0.9])?;
    /// assert_eq!(finer.control_points().len(), 8);
    /// assert!((finer.eval(0.6)? - curve.eval(0.6)?).norm() < 1e-12);
    /// # Ok::<(), splineface::bspline::BSplineError>(())
    /// ```
    pub fn refine_knots(&self, values: &[Real]) -> Result<Self, BSplineError> {
        Ok(Self::from_column(self.column.refine_knots(Direction::U, values)?))
    }

    /// The same curve with the knot `value` inserted `times` times (A5.1): `times` more control
    /// points, the same points in space.
    ///
    /// # Errors
    /// As [`BSplineSurface::refine_knots`].
    ///
    /// # Examples
    /// ```
    /// use nalgebra::Point3;
    /// use splineface::bspline::{BSplineCurve, KnotVector};
    ///
    /// let knots = KnotVector::clamped_uniform(3, 5, 0.0, 1.0)?;
    /// let points = (0..5).map(|i| Point3::new(i as f64, (i * i) as f64, 0.0)).collect();
    /// let curve = BSplineCurve::new(knots, points)?;
    /// let finer = curve.insert_knot(0.4, 2)?;
    /// assert_eq!(finer.control_points().len(), 7);
    /// assert!((finer.eval(0.7)? - curve.eval(0.7)?).norm() < 1e-12);
    /// # Ok::<(), splineface::bspline::BSplineError>(())
    /// ```
    pub fn insert_knot(&self, value: Real, times: usize) -> Result<Self, BSplineError> {
        Ok(Self::from_column(self.column.insert_knot(
            Direction::U,
            value,
            times,
        )?))
    }

    /// The same curve with its degree raised by `by` (A5.9), with clamped knots.
    ///
    /// # Errors
    /// As [`BSplineSurface::elevate_degree`].
    ///
    /// # Examples
    /// ```
    /// use nalgebra::Point3;
    /// use splineface::bspline::{BSplineCurve, KnotVector};
    ///
    /// // A straight segment of degree 1, raised to a cubic: three new points on the same line.
    /// let line = BSplineCurve::new(KnotVector::clamped_uniform(1, 2, 0.0, 1.0)?, vec![Point3::origin(), Point3::new(3.0, 0.0, 0.0)])?;
    /// let cubic = line.elevate_degree(2)?;
    /// assert_eq!((cubic.degree(), cubic.control_points().len()), (3, 4));
    /// assert!((cubic.control_points()[1].x - 1.0).abs() < 1e-12);
    /// # Ok::<(), splineface::bspline::BSplineError>(())
    /// ```
    pub fn elevate_degree(&self, by: usize) -> Result<Self, BSplineError> {
        Ok(Self::from_column(self.column.elevate_degree(Direction::U, by)?))
    }

    /// The part of the curve over `[lo, hi]`, clamped there.
    ///
    /// # Errors
    /// As [`BSplineSurface::restricted`].
    ///
    /// # Examples
    /// ```
    /// use nalgebra::Point3;
    /// use splineface::bspline::{BSplineCurve, KnotVector};
    ///
    /// let knots = KnotVector::clamped_uniform(3, 5, 0.0, 1.0)?;
    /// let points = (0..5).map(|i| Point3::new(i as f64, ((i * 3) % 4) as f64, 0.5 * i as f64)).collect();
    /// let curve = BSplineCurve::new(knots, points)?;
    /// let middle = curve.restricted(0.2, 0.7)?;
    /// assert_eq!(middle.domain(), (0.2, 0.7));
    /// assert!(middle.knots().is_clamped());
    /// assert!((middle.eval(0.2)? - curve.eval(0.2)?).norm() < 1e-12);
    /// assert_eq!(middle.control_points()[0], middle.eval(0.2)?);
    /// # Ok::<(), splineface::bspline::BSplineError>(())
    /// ```
    pub fn restricted(&self, lo: Real, hi: Real) -> Result<Self, BSplineError> {
        Ok(Self::from_column(self.column.restricted(Direction::U, lo, hi)?))
    }

    /// The curve cut in two at `at`, inside the domain: the parts over `[start, at]` and
    /// `[at, end]`, each clamped.
    ///
    /// # Errors
    /// As [`BSplineSurface::split`].
    ///
    /// # Examples
    /// ```
    /// use nalgebra::Point3;
    /// use splineface::bspline::{BSplineCurve, KnotVector};
    ///
    /// let knots = KnotVector::clamped_uniform(2, 4, 0.0, 1.0)?;
    /// let points = (0..4).map(|i| Point3::new(i as f64, (i % 2) as f64, 0.0)).collect();
    /// let curve = BSplineCurve::new(knots, points)?;
    /// let (left, right) = curve.split(0.3)?;
    /// assert_eq!((left.domain(), right.domain()), ((0.0, 0.3), (0.3, 1.0)));
    /// assert!((left.eval(0.3)? - right.eval(0.3)?).norm() < 1e-12);
    /// # Ok::<(), splineface::bspline::BSplineError>(())
    /// ```
    pub fn split(&self, at: Real) -> Result<(Self, Self), BSplineError> {
        let (a, b) = self.column.split(Direction::U, at)?;
        Ok((Self::from_column(a), Self::from_column(b)))
    }
}

impl BSplineSurface {
    /// The iso-parametric curve at `u = value`: `v ↦ F(value, v)`, exactly (its control points
    /// are the grid's columns blended by the `u` basis at `value`; its knots are `v`'s).
    ///
    /// # Errors
    /// [`BSplineError::ParameterOutOfDomain`] for `value` outside the `u` domain (or NaN).
    ///
    /// # Examples
    /// ```
    /// use nalgebra::Point3;
    /// use splineface::bspline::{BSplineSurface, KnotVector};
    ///
    /// let k = KnotVector::clamped_uniform(3, 6, 0.0, 1.0)?;
    /// let grid = (0..36).map(|i| Point3::new((i / 6) as f64, (i % 6) as f64, ((i * 7) % 5) as f64)).collect();
    /// let surface = BSplineSurface::new(k.clone(), k, 6, 6, grid)?;
    /// let curve = surface.iso_u(0.3)?;
    /// assert!((curve.eval(0.8)? - surface.eval(0.3, 0.8)?).norm() < 1e-12);
    /// # Ok::<(), splineface::bspline::BSplineError>(())
    /// ```
    pub fn iso_u(&self, value: Real) -> Result<BSplineCurve, BSplineError> {
        self.iso(Direction::U, value)
    }

    /// The iso-parametric curve at `v = value`: `u ↦ F(u, value)` (see
    /// [`BSplineSurface::iso_u`]).
    ///
    /// # Errors
    /// [`BSplineError::ParameterOutOfDomain`] for `value` outside the `v` domain (or NaN).
    ///
    /// # Examples
    /// ```
    /// use nalgebra::Point3;
    /// use splineface::bspline::{BSplineSurface, KnotVector};
    ///
    /// let ku = KnotVector::clamped_uniform(3, 6, 0.0, 1.0)?;
    /// let kv = KnotVector::clamped_uniform(2, 4, 0.0, 1.0)?;
    /// let grid = (0..24).map(|i| Point3::new((i / 4) as f64, (i % 4) as f64, ((i * 7) % 5) as f64)).collect();
    /// let surface = BSplineSurface::new(ku, kv, 6, 4, grid)?;
    /// // The curve u ↦ F(u, 0.25): the grid's rows blended by the v basis, u's knots.
    /// let curve = surface.iso_v(0.25)?;
    /// assert_eq!(curve.control_points().len(), surface.rows());
    /// assert!((curve.eval(0.6)? - surface.eval(0.6, 0.25)?).norm() < 1e-12);
    /// # Ok::<(), splineface::bspline::BSplineError>(())
    /// ```
    pub fn iso_v(&self, value: Real) -> Result<BSplineCurve, BSplineError> {
        self.iso(Direction::V, value)
    }

    /// The exact image on the surface of a polyline in its parameter domain: the curve
    /// `t ↦ F(q(t))`, where `q` runs linearly from vertex `k` to vertex `k + 1` as `t` runs from
    /// `k` to `k + 1` (so `t ∈ [0, n − 1]` for `n` vertices; repeated consecutive vertices count
    /// once). A closed outline is one whose last vertex repeats its first.
    ///
    /// Along a straight path in `(u, v)` a tensor-product patch of degrees `(p, q)` is a
    /// polynomial of degree `p + q` in `t`, so the curve has that degree and is exact: one
    /// Bézier piece between consecutive breakpoints (the vertices and the points where a segment
    /// crosses an interior knot line), joined with continuity C⁰ (knots of multiplicity
    /// `p + q`). Each piece's ends are the surface's points there; its inner control points
    /// solve the Bernstein collocation at the Chebyshev–Lobatto nodes of the piece, which
    /// reproduces a polynomial of the degree to rounding. This is what a CAD file needs beside
    /// a trimming polygon in `(u, v)`: the trimmed face's boundary edge in space, with the same
    /// parameter as its parameter-space curve.
    ///
    /// # Errors
    /// [`BSplineError::NonFiniteParameter`] or [`BSplineError::ParameterOutOfDomain`] for a
    /// vertex outside the domain; [`BSplineError::PolylineTooShort`] for fewer than two
    /// distinct vertices; [`BSplineError::DegreeTooHigh`] when `p + q` exceeds
    /// [`MAX_DEGREE`]; [`BSplineError::DiscontinuousSurface`] when the surface jumps across
    /// an interior knot line (degree 0 in a direction with interior knots, or a knot repeated
    /// `degree + 1` times), where no single curve is its image.
    ///
    /// # Examples
    /// ```
    /// use nalgebra::{Point2, Point3};
    /// use splineface::bspline::{BSplineSurface, KnotVector};
    ///
    /// let k = KnotVector::clamped_uniform(3, 6, 0.0, 1.0)?;
    /// let grid = (0..36).map(|i| Point3::new((i / 6) as f64, (i % 6) as f64, ((i * 7) % 5) as f64)).collect();
    /// let surface = BSplineSurface::new(k.clone(), k, 6, 6, grid)?;
    /// let triangle = [Point2::new(0.1, 0.2), Point2::new(0.9, 0.3), Point2::new(0.4, 0.8), Point2::new(0.1, 0.2)];
    /// let edge = surface.image_of_polyline(&triangle)?;
    /// assert_eq!((edge.degree(), edge.domain()), (6, (0.0, 3.0)));
    /// // Halfway along the second side.
    /// let on_surface = surface.eval(0.65, 0.55)?;
    /// assert!((edge.eval(1.5)? - on_surface).norm() < 1e-12);
    /// # Ok::<(), splineface::bspline::BSplineError>(())
    /// ```
    pub fn image_of_polyline(&self, vertices: &[Point2<Real>]) -> Result<BSplineCurve, BSplineError> {
        for v in vertices {
            super::surface::check_parameter(self.knots_u(), self.knots_v(), v.x, v.y)?;
        }
        let mut path: Vec<Point2<Real>> = Vec::with_capacity(vertices.len());
        for v in vertices {
            if path.last() != Some(v) {
                path.push(*v);
            }
        }
        if path.len() < 2 {
            return Err(BSplineError::PolylineTooShort {
                distinct: path.len(),
                needed: 2,
            });
        }
        let degree = self.degree_u() + self.degree_v();
        if degree > MAX_DEGREE {
            return Err(BSplineError::DegreeTooHigh {
                degree,
                max: MAX_DEGREE,
            });
        }
        let lines_u = interior_knot_lines(self.knots_u(), Direction::U)?;
        let lines_v = interior_knot_lines(self.knots_v(), Direction::V)?;
        let end = (path.len() - 1) as Real;
        if degree == 0 {
            // Degree 0 both ways with no interior knots: the surface is one point.
            let knots = KnotVector::new(0, vec![0.0, end])?;
            return BSplineCurve::new(knots, vec![self.eval(path[0].x, path[0].y)?]);
        }
        let collocation = BezierCollocation::new(degree);
        let ((u0, u1), (v0, v1)) = (self.domain_u(), self.domain_v());
        let at = |a: &Point2<Real>, b: &Point2<Real>, s: Real| {
            // A segment's ends exactly (a closed outline's image then closes exactly).
            let q = if s == 1.0 { *b } else { a + (b - a) * s };
            // The convex combination can round past the domain's end by an ulp.
            self.eval(q.x.clamp(u0, u1), q.y.clamp(v0, v1))
        };

        let mut knots = vec![0.0; degree + 1];
        let mut points = vec![self.eval(path[0].x, path[0].y)?];
        let mut cuts: Vec<Real> = Vec::new();
        let mut samples = vec![Point3::origin(); degree + 1];
        for (k, pair) in path.windows(2).enumerate() {
            let (a, b) = (&pair[0], &pair[1]);
            cuts.clear();
            cuts.push(0.0);
            for (lines, from, to) in [(&lines_u, a.x, b.x), (&lines_v, a.y, b.y)] {
                for &line in lines {
                    if (from - line) * (to - line) < 0.0 {
                        cuts.push((line - from) / (to - from));
                    }
                }
            }
            cuts.push(1.0);
            cuts.sort_by(Real::total_cmp);
            // Crossings closer than this (a path through a knot lines' intersection, crossing
            // both at once) are one breakpoint: the sliver between them would be a piece of no
            // length, and a CAD reader's knot tolerance would merge its knots anyway.
            const MERGE: Real = 1e-9;
            cuts.dedup_by(|later, kept| *later - *kept < MERGE);
            if let Some(last) = cuts.last_mut() {
                *last = 1.0;
            }
            for piece in cuts.windows(2) {
                let (s0, s1) = (piece[0], piece[1]);
                samples[0] = *points.last().expect("the path's first point");
                for (i, &node) in collocation.nodes.iter().enumerate().skip(1) {
                    samples[i] = at(a, b, s0 * (1.0 - node) + s1 * node)?;
                }
                points.extend(collocation.inner_points(&samples));
                points.push(samples[degree]);
                let t = if piece[1] == 1.0 {
                    (k + 1) as Real
                } else {
                    k as Real + s1
                };
                knots.extend(std::iter::repeat_n(t, degree));
            }
        }
        knots.push(*knots.last().expect("knots were pushed"));
        BSplineCurve::new(KnotVector::new(degree, knots)?, points)
    }

    fn iso(&self, direction: Direction, value: Real) -> Result<BSplineCurve, BSplineError> {
        let (fixed, free) = match direction {
            Direction::U => (self.knots_u(), self.knots_v()),
            Direction::V => (self.knots_v(), self.knots_u()),
        };
        fixed.check_in_domain(direction, value)?;
        let p = fixed.degree();
        let span = fixed.span_in_domain(value);
        let mut basis = [0.0; super::MAX_DEGREE + 1];
        basis_functions(fixed, span, value, &mut basis);
        let (cols, grid) = (self.cols(), self.control_points());
        let at = |fixed_index: usize, free_index: usize| match direction {
            Direction::U => grid[fixed_index * cols + free_index],
            Direction::V => grid[free_index * cols + fixed_index],
        };
        let points = (0..free.num_control_points())
            .map(|j| {
                Point3::from(
                    (0..=p)
                        .map(|r| at(span - p + r, j).coords * basis[r])
                        .sum::<Vector3<Real>>(),
                )
            })
            .collect();
        BSplineCurve::new(free.clone(), points)
    }
}

/// The distinct knot values strictly inside the domain; an error where the spline jumps there.
fn interior_knot_lines(knots: &KnotVector, direction: Direction) -> Result<Vec<Real>, BSplineError> {
    if let Some((value, multiplicity)) = knots.jump() {
        return Err(BSplineError::DiscontinuousSurface {
            direction,
            value,
            multiplicity,
            degree: knots.degree(),
        });
    }
    let breaks = knots.breakpoints();
    Ok(breaks[1..breaks.len() - 1].to_vec())
}

/// Bernstein collocation of one degree at the Chebyshev–Lobatto nodes `sᵢ = (1 − cos(iπ/p))/2`
/// of `[0, 1]`: the inner Bézier control points of the polynomial taking given values there.
struct BezierCollocation {
    nodes: Vec<Real>,
    /// `(p − 1) × (p − 1)`: the inverse of the inner nodes' inner Bernstein values.
    inverse: DMatrix<Real>,
    /// `(p − 1) × 2`: the inner nodes' values of the end polynomials `B₀`, `Bₚ`.
    ends: DMatrix<Real>,
}

impl BezierCollocation {
    fn new(degree: usize) -> Self {
        let p = degree;
        let nodes: Vec<Real> = (0..=p)
            .map(|i| {
                if p == 0 || i == 0 {
                    0.0
                } else if i == p {
                    1.0
                } else {
                    0.5 * (1.0 - (std::f64::consts::PI * i as Real / p as Real).cos())
                }
            })
            .collect();
        let binomial =
            |n: usize, k: usize| -> Real { (0..k).fold(1.0, |c, j| c * (n - j) as Real / (j + 1) as Real) };
        let bernstein =
            |j: usize, s: Real| binomial(p, j) * s.powi(j as i32) * (1.0 - s).powi((p - j) as i32);
        let inner = p.saturating_sub(1);
        let matrix = DMatrix::from_fn(inner, inner, |i, j| bernstein(j + 1, nodes[i + 1]));
        let inverse = if inner == 0 {
            matrix
        } else {
            matrix
                .try_inverse()
                .expect("Bernstein collocation at distinct nodes is invertible")
        };
        let ends = DMatrix::from_fn(inner, 2, |i, e| bernstein(e * p, nodes[i + 1]));
        BezierCollocation { nodes, inverse, ends }
    }

    /// The inner control points `c₁ … c_{p−1}` of the polynomial whose values at the nodes
    /// are `samples` (whose ends are `c₀` and `cₚ`).
    fn inner_points(&self, samples: &[Point3<Real>]) -> impl Iterator<Item = Point3<Real>> + '_ {
        let p = samples.len() - 1;
        let (first, last) = (samples[0].coords, samples[p].coords);
        let rhs: Vec<Vector3<Real>> = (0..p.saturating_sub(1))
            .map(|i| samples[i + 1].coords - first * self.ends[(i, 0)] - last * self.ends[(i, 1)])
            .collect();
        (0..rhs.len()).map(move |r| {
            Point3::from(
                rhs.iter()
                    .enumerate()
                    .map(|(i, y)| y * self.inverse[(r, i)])
                    .sum::<Vector3<Real>>(),
            )
        })
    }
}
