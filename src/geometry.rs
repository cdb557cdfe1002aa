//! Small geometric helpers that several stages share: bounding boxes, planar polygons and 2D
//! affine maps.

use nalgebra::{Matrix2, Matrix2x3, Matrix3, Point, Point2, Vector2};

use crate::Real;

/// The smallest axis-aligned box holding `points`, as its lower and upper corners; `None` for
/// no points. Coordinates that are NaN are passed over (`f64::min` and `max` ignore them).
///
/// # Examples
/// ```
/// use nalgebra::Point2;
/// use splineface::geometry::bounding_box;
///
/// let points = [Point2::new(1.0, 5.0), Point2::new(-2.0, 3.0), Point2::new(0.5, 7.0)];
/// assert_eq!(bounding_box(&points), Some((Point2::new(-2.0, 3.0), Point2::new(1.0, 7.0))));
/// assert_eq!(bounding_box::<2>(&[]), None);
/// ```
pub fn bounding_box<'a, const D: usize>(
    points: impl IntoIterator<Item = &'a Point<Real, D>>,
) -> Option<(Point<Real, D>, Point<Real, D>)> {
    let mut points = points.into_iter();
    let first = *points.next()?;
    Some(points.fold((first, first), |(lo, hi), p| (lo.inf(p), hi.sup(p))))
}

/// Whether `p` lies inside `polygon` (even-odd rule; points on the boundary may go either way).
///
/// # Examples
/// ```
/// use nalgebra::Point2;
/// use splineface::geometry::polygon_contains;
///
/// let square = [Point2::new(0.0, 0.0), Point2::new(2.0, 0.0), Point2::new(2.0, 2.0), Point2::new(0.0, 2.0)];
/// assert!(polygon_contains(&square, Point2::new(1.0, 1.0)));
/// assert!(!polygon_contains(&square, Point2::new(3.0, 1.0)));
/// ```
pub fn polygon_contains(polygon: &[Point2<Real>], p: Point2<Real>) -> bool {
    let mut inside = false;
    for k in 0..polygon.len() {
        let (a, b) = (polygon[k], polygon[(k + 1) % polygon.len()]);
        if edge_crossing(a, b, p.y).is_some_and(|x| p.x < x) {
            inside = !inside;
        }
    }
    inside
}

/// The signed area of a closed polygon (the shoelace formula): positive when its vertices run
/// counter-clockwise (x right, y up), negative when clockwise; the last vertex joins the first.
///
/// # Examples
/// ```
/// use nalgebra::Point2;
/// use splineface::geometry::signed_area;
///
/// let mut square = vec![Point2::new(0.0, 0.0), Point2::new(2.0, 0.0), Point2::new(2.0, 2.0), Point2::new(0.0, 2.0)];
/// assert_eq!(signed_area(&square), 4.0);
/// square.reverse();
/// assert_eq!(signed_area(&square), -4.0);
/// ```
pub fn signed_area(polygon: &[Point2<Real>]) -> Real {
    let n = polygon.len();
    0.5 * (0..n)
        .map(|k| {
            let (a, b) = (polygon[k], polygon[(k + 1) % n]);
            a.x * b.y - a.y * b.x
        })
        .sum::<Real>()
}

/// Where the edge `ab` crosses the line at height `y`, under [`polygon_contains`]'s rule (an
/// edge counts when exactly one end lies above `y`); `None` when it does not cross.
pub(crate) fn edge_crossing(a: Point2<Real>, b: Point2<Real>, y: Real) -> Option<Real> {
    ((a.y > y) != (b.y > y)).then(|| a.x + (y - a.y) / (b.y - a.y) * (b.x - a.x))
}

/// The 3 × 3 homogeneous matrix of a 2D affine map `[A | t]` (a RASL warp), so that maps
/// compose by multiplication and invert with [`Matrix3::try_inverse`].
///
/// # Examples
/// ```
/// use nalgebra::{Matrix2x3, Point2};
/// use splineface::geometry::homogeneous;
///
/// let shift = Matrix2x3::new(1.0, 0.0, 5.0, 0.0, 1.0, -2.0);
/// let twice = homogeneous(&shift) * homogeneous(&shift);
/// assert_eq!(twice.transform_point(&Point2::new(0.0, 0.0)), Point2::new(10.0, -4.0));
/// ```
pub fn homogeneous(m: &Matrix2x3<Real>) -> Matrix3<Real> {
    Matrix3::new(
        m[(0, 0)],
        m[(0, 1)],
        m[(0, 2)],
        m[(1, 0)],
        m[(1, 1)],
        m[(1, 2)],
        0.0,
        0.0,
        1.0,
    )
}

/// The 2D affine map `x ↦ A x + t` as the 2 × 3 matrix `[A | t]` (a RASL warp).
///
/// # Examples
/// ```
/// use nalgebra::{Matrix2, Matrix2x3, Vector2};
/// use splineface::geometry::affine;
///
/// let m = affine(&Matrix2::new(1.0, 2.0, 3.0, 4.0), &Vector2::new(5.0, 6.0));
/// assert_eq!(m, Matrix2x3::new(1.0, 2.0, 5.0, 3.0, 4.0, 6.0));
/// ```
pub fn affine(linear: &Matrix2<Real>, shift: &Vector2<Real>) -> Matrix2x3<Real> {
    let mut m = Matrix2x3::zeros();
    m.fixed_view_mut::<2, 2>(0, 0).copy_from(linear);
    m.set_column(2, shift);
    m
}

/// A length unit of a file's coordinates (a mesh's, a surface's).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum LengthUnit {
    /// Millimetres.
    #[default]
    Millimetre,
    /// Centimetres.
    Centimetre,
    /// Metres.
    Metre,
}

impl LengthUnit {
    /// `mm`, `cm` or `m` (any case).
    pub fn parse(text: &str) -> Option<Self> {
        match text.to_ascii_lowercase().as_str() {
            "mm" => Some(LengthUnit::Millimetre),
            "cm" => Some(LengthUnit::Centimetre),
            "m" => Some(LengthUnit::Metre),
            _ => None,
        }
    }

    /// The unit's name in the plural: `millimetres`, `centimetres` or `metres`.
    pub fn plural(self) -> &'static str {
        match self {
            LengthUnit::Millimetre => "millimetres",
            LengthUnit::Centimetre => "centimetres",
            LengthUnit::Metre => "metres",
        }
    }

    /// Millimetres per unit.
    pub fn millimetres(self) -> Real {
        match self {
            LengthUnit::Millimetre => 1.0,
            LengthUnit::Centimetre => 10.0,
            LengthUnit::Metre => 1000.0,
        }
    }
}
