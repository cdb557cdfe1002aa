//! B-spline curves and a surface's iso-parametric curves: closed forms (Bernstein polynomials
//! and their derivatives), an independent Cox–de Boor oracle on random curves, the operations
//! leaving the curve unchanged to rounding, iso-curves that are the surface exactly, and the
//! images of parameter-space polylines that are the surface along them.

use nalgebra::{Point2, Point3, Vector3};
use proptest::prelude::*;
use splineface::Real;
use splineface::bspline::{BSplineCurve, BSplineError, BSplineSurface, Direction, KnotVector};

use super::common::{in_domain, knot_vector, naive_basis, random_points, surface};

fn random_curve(knots: KnotVector, seed: u64) -> BSplineCurve {
    let count = knots.num_control_points();
    BSplineCurve::new(knots, random_points(count, seed)).unwrap()
}

/// The largest distance between two curves over 33 parameters of `[lo, hi]`.
fn deviation(a: &BSplineCurve, b: &BSplineCurve, (lo, hi): (Real, Real)) -> Real {
    (0..=32)
        .map(|i| (lo + (hi - lo) * i as Real / 32.0).clamp(lo, hi))
        .map(|u| (a.eval(u).unwrap() - b.eval(u).unwrap()).norm())
        .fold(0.0, Real::max)
}

#[test]
fn a_cubic_bezier_curve_is_its_bernstein_form() {
    let knots = KnotVector::new(3, vec![0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0]).unwrap();
    let p = [
        Point3::new(0.0, 0.0, 0.0),
        Point3::new(1.0, 3.0, -1.0),
        Point3::new(4.0, -2.0, 2.0),
        Point3::new(5.0, 1.0, 0.5),
    ];
    let curve = BSplineCurve::new(knots, p.to_vec()).unwrap();
    for i in 0..=20 {
        let t = i as Real / 20.0;
        let s = 1.0 - t;
        let point = p[0].coords * s.powi(3)
            + p[1].coords * 3.0 * t * s * s
            + p[2].coords * 3.0 * t * t * s
            + p[3].coords * t.powi(3);
        let first = (p[1] - p[0]) * 3.0 * s * s + (p[2] - p[1]) * 6.0 * t * s + (p[3] - p[2]) * 3.0 * t * t;
        let second =
            (p[2] - p[1] * 2.0 + p[0].coords) * 6.0 * s + (p[3] - p[2] * 2.0 + p[1].coords) * 6.0 * t;
        let third = (p[3] - p[2] * 3.0 + p[1].coords * 3.0 - p[0].coords) * 6.0;
        let d = curve.derivatives(t, 4).unwrap();
        assert!((curve.eval(t).unwrap().coords - point).norm() < 1e-12, "{t}");
        assert!((d[0] - point).norm() < 1e-12);
        assert!((d[1] - first).norm() < 1e-11, "{t}: {} vs {first}", d[1]);
        assert!((d[2] - second).norm() < 1e-10, "{t}");
        assert!((d[3] - third).norm() < 1e-9, "{t}");
        assert_eq!(d[4], Vector3::zeros(), "above the degree");
    }
}

#[test]
fn bad_curves_and_parameters_are_refused() {
    let knots = KnotVector::clamped_uniform(2, 4, 0.0, 1.0).unwrap();
    let three = vec![Point3::origin(); 3];
    assert_eq!(
        BSplineCurve::new(knots.clone(), three).unwrap_err(),
        BSplineError::CurvePointCount { got: 3, expected: 4 }
    );
    let mut points = vec![Point3::origin(); 4];
    points[2].y = Real::NAN;
    assert_eq!(
        BSplineCurve::new(knots.clone(), points).unwrap_err(),
        BSplineError::NonFiniteCurvePoint { index: 2 }
    );
    let curve = BSplineCurve::new(knots, vec![Point3::origin(); 4]).unwrap();
    for u in [-0.1, 1.5, Real::NAN] {
        assert!(
            matches!(curve.eval(u), Err(BSplineError::ParameterOutOfDomain { .. })),
            "{u}"
        );
        assert!(curve.derivatives(u, 1).is_err(), "{u}");
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]

    /// Evaluation against the Cox–de Boor recursion written from its definition.
    #[test]
    fn curves_evaluate_as_the_definition(knots in knot_vector(), seed in any::<u64>(), t in 0.0..=1.0f64) {
        let curve = random_curve(knots.clone(), seed);
        let u = in_domain(&knots, t);
        let n = naive_basis(knots.knots(), knots.degree(), u);
        let expected: Vector3<Real> = curve.control_points().iter().zip(&n).map(|(p, w)| p.coords * *w).sum();
        prop_assert!((curve.eval(u).unwrap().coords - expected).norm() < 1e-9);
    }

    /// Insertion, refinement, elevation and splitting leave the curve where it was.
    #[test]
    fn the_operations_leave_the_curve_unchanged(knots in knot_vector(), seed in any::<u64>(), t in 0.05..0.95f64) {
        let curve = random_curve(knots.clone(), seed);
        let domain = curve.domain();
        let at = in_domain(&knots, t);
        let p = knots.degree();
        let existing = knots.knots().iter().filter(|&&k| k == at).count();
        if p >= 1 && existing < p {
            let inserted = curve.insert_knot(at, 1).unwrap();
            prop_assert_eq!(inserted.control_points().len(), curve.control_points().len() + 1);
            prop_assert!(deviation(&curve, &inserted, domain) < 1e-9);
        }
        if p <= 4 && knots.knots()[p + 1..knots.num_control_points()].chunk_by(|a, b| a == b).all(|r| r.len() <= p) {
            let elevated = curve.elevate_degree(1).unwrap();
            prop_assert_eq!(elevated.degree(), p + 1);
            prop_assert!(deviation(&curve, &elevated, domain) < 1e-9);
        }
        if at > domain.0 && at < domain.1 {
            let (left, right) = curve.split(at).unwrap();
            prop_assert_eq!((left.domain().1, right.domain().0), (at, at));
            prop_assert!(deviation(&curve, &left, left.domain()) < 1e-9);
            prop_assert!(deviation(&curve, &right, right.domain()) < 1e-9);
        }
    }

    /// A surface's iso-curves are the surface along them, value and derivatives.
    #[test]
    fn iso_curves_are_the_surface(surface in surface(), s in 0.0..=1.0f64, t in 0.0..=1.0f64) {
        let u = in_domain(surface.knots_u(), s);
        let v = in_domain(surface.knots_v(), t);
        let along_v = surface.iso_u(u).unwrap();
        let along_u = surface.iso_v(v).unwrap();
        let point = surface.eval(u, v).unwrap();
        prop_assert!((along_v.eval(v).unwrap() - point).norm() < 1e-9);
        prop_assert!((along_u.eval(u).unwrap() - point).norm() < 1e-9);
        let d = surface.derivatives(u, v, 1).unwrap();
        prop_assert!((along_u.derivatives(u, 1).unwrap()[1] - d.get(1, 0)).norm() < 1e-7 * (1.0 + d.get(1, 0).norm()));
        prop_assert!((along_v.derivatives(v, 1).unwrap()[1] - d.get(0, 1)).norm() < 1e-7 * (1.0 + d.get(0, 1).norm()));
        prop_assert!(surface.iso_u(surface.domain_u().1 + 1.0).is_err());
    }

    /// The image of a polyline in `(u, v)` is the surface along it: at every vertex, at the
    /// crossings of knot lines and between them, to rounding; of degree `p + q`, one unit of
    /// parameter a side. Where the surface jumps across a knot line it is refused instead.
    #[test]
    fn polyline_images_are_the_surface(
        surface in surface(),
        corners in prop::collection::vec((0.0..=1.0f64, 0.0..=1.0f64), 2..6),
        repeat in any::<bool>(),
    ) {
        let mut path: Vec<Point2<Real>> = corners
            .iter()
            .map(|&(s, t)| Point2::new(in_domain(surface.knots_u(), s), in_domain(surface.knots_v(), t)))
            .collect();
        if repeat {
            path.insert(1, path[0]);
        }
        let mut distinct = path.clone();
        distinct.dedup();
        let jumps = |k: &KnotVector| {
            let (a, b) = k.domain();
            k.knots().iter().any(|&x| x > a && x < b && k.knots().iter().filter(|&&y| y == x).count() > k.degree())
        };
        let image = surface.image_of_polyline(&path);
        if distinct.len() < 2 {
            prop_assert_eq!(image.unwrap_err(), BSplineError::PolylineTooShort { distinct: 1, needed: 2 });
            return Ok(());
        }
        if jumps(surface.knots_u()) || jumps(surface.knots_v()) {
            prop_assert!(matches!(image, Err(BSplineError::DiscontinuousSurface { .. })), "{image:?}");
            return Ok(());
        }
        let curve = image.unwrap();
        prop_assert_eq!(curve.degree(), surface.degree_u() + surface.degree_v());
        prop_assert_eq!(curve.domain(), (0.0, (distinct.len() - 1) as Real));
        for (k, pair) in distinct.windows(2).enumerate() {
            let (a, b) = (pair[0], pair[1]);
            // Evenly spaced points, and the points on the knot lines the side crosses.
            let mut along: Vec<Real> = (0..=16).map(|i| i as Real / 16.0).collect();
            for (knots, from, to) in [(surface.knots_u(), a.x, b.x), (surface.knots_v(), a.y, b.y)] {
                for &line in knots.knots() {
                    if (from - line) * (to - line) < 0.0 {
                        along.push((line - from) / (to - from));
                    }
                }
            }
            for s in along {
                let q = a + (b - a) * s;
                let (u0, u1) = surface.domain_u();
                let (v0, v1) = surface.domain_v();
                let expected = surface.eval(q.x.clamp(u0, u1), q.y.clamp(v0, v1)).unwrap();
                let got = curve.eval((k as Real + s).min(curve.domain().1)).unwrap();
                prop_assert!((got - expected).norm() < 1e-8, "side {k} at {s}: {} from the surface", (got - expected).norm());
            }
        }
    }
}

#[test]
fn polyline_images_refuse_what_is_not_a_curve_on_the_surface() {
    let k = KnotVector::clamped_uniform(3, 5, 0.0, 1.0).unwrap();
    let surface = BSplineSurface::new(k.clone(), k, 5, 5, random_points(25, 7)).unwrap();
    let a = Point2::new(0.2, 0.3);
    assert_eq!(
        surface.image_of_polyline(&[a, a]).unwrap_err(),
        BSplineError::PolylineTooShort {
            distinct: 1,
            needed: 2
        }
    );
    assert_eq!(
        surface.image_of_polyline(&[]).unwrap_err(),
        BSplineError::PolylineTooShort {
            distinct: 0,
            needed: 2
        }
    );
    assert!(matches!(
        surface.image_of_polyline(&[a, Point2::new(1.2, 0.3)]),
        Err(BSplineError::ParameterOutOfDomain {
            direction: Direction::U,
            ..
        })
    ));
    assert!(matches!(
        surface.image_of_polyline(&[a, Point2::new(0.5, Real::NAN)]),
        Err(BSplineError::NonFiniteParameter { .. })
    ));
    // A knot repeated degree + 1 times inside the domain: the surface tears along v = 0.5.
    let torn = KnotVector::new(1, vec![0.0, 0.0, 0.5, 0.5, 1.0, 1.0]).unwrap();
    let linear = KnotVector::clamped_uniform(1, 2, 0.0, 1.0).unwrap();
    let surface = BSplineSurface::new(linear, torn, 2, 4, random_points(8, 3)).unwrap();
    assert_eq!(
        surface
            .image_of_polyline(&[a, Point2::new(0.2, 0.9)])
            .unwrap_err(),
        BSplineError::DiscontinuousSurface {
            direction: Direction::V,
            value: 0.5,
            multiplicity: 2,
            degree: 1
        }
    );
}

/// A bilinear patch along its diagonal is the closed-form quadratic `F(t, t)`.
#[test]
fn a_bilinear_patch_along_its_diagonal_is_a_parabola() {
    let k = KnotVector::clamped_uniform(1, 2, 0.0, 1.0).unwrap();
    let corners = vec![
        Point3::new(0.0, 0.0, 0.0),
        Point3::new(0.0, 1.0, 0.0),
        Point3::new(1.0, 0.0, 0.0),
        Point3::new(1.0, 1.0, 1.0),
    ];
    let surface = BSplineSurface::new(k.clone(), k, 2, 2, corners).unwrap();
    let curve = surface
        .image_of_polyline(&[Point2::new(0.0, 0.0), Point2::new(1.0, 1.0)])
        .unwrap();
    // F(t, t) = (t, t, t²): the quadratic Bézier curve (0,0,0), (½,½,0), (1,1,1).
    assert_eq!(curve.degree(), 2);
    let expected = [
        Point3::new(0.0, 0.0, 0.0),
        Point3::new(0.5, 0.5, 0.0),
        Point3::new(1.0, 1.0, 1.0),
    ];
    for (got, want) in curve.control_points().iter().zip(&expected) {
        assert!((got - want).norm() < 1e-15, "{got} against {want}");
    }
    assert_eq!(curve.knots().knots(), &[0.0, 0.0, 0.0, 1.0, 1.0, 1.0]);
}
