//! B-spline curves `C(u) = Σᵢ Nᵢ,ₚ(u) Pᵢ` in 3D, and the iso-parametric curves of a surface.
//!
//! A curve is held as a surface of one column whose `v` direction has degree 0 over `[0, 1]`
//! (`F(u, v) = C(u)` for every `v`): the surface's knot vectors, basis code, evaluation,
//! derivatives, knot insertion, refinement, degree elevation, restriction and splitting serve
//! the curve as they are, with the same guarantees and tests behind them.

use nalgebra::{Point3, Vector3};

use super::{BSplineError, BSplineSurface, Direction, KnotVector, basis_functions};
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
    pub fn eval(&self, u: Real) -> Result<Point3<Real>, BSplineError> {
        self.knots().check_in_domain(Direction::U, u)?;
        self.column.eval(u, 0.0)
    }

    /// `C(u)` and its derivatives up to `order`, `[C, C′, C″, …]` (as vectors; those above the
    /// degree are zero). The NURBS Book A3.2, through the surface's A3.6.
    ///
    /// # Errors
    /// As [`BSplineCurve::eval`].
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
    pub fn iso_v(&self, value: Real) -> Result<BSplineCurve, BSplineError> {
        self.iso(Direction::V, value)
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
