//! Point inversion: closest points against a dense brute-force search, the optimality
//! conditions, exact answers on planes and beyond edges, and parameters recovered from points
//! just off the surface.

use nalgebra::{Point3, Vector3};
use proptest::prelude::*;
use splineface::Real;
use splineface::bspline::{BSplineError, BSplineSurface, ClosestPoints, KnotVector};

use super::common::{Lcg, knot_vector};

/// A height field over `[0, rows − 1] × [0, cols − 1]` on `ku × kv` with heights in `[-h, h]`.
fn height_field(ku: KnotVector, kv: KnotVector, h: Real, seed: u64) -> BSplineSurface {
    let (rows, cols) = (ku.num_control_points(), kv.num_control_points());
    let mut rng = Lcg(seed);
    let grid = (0..rows * cols)
        .map(|k| Point3::new((k / cols) as Real, (k % cols) as Real, rng.uniform(-h, h)))
        .collect();
    BSplineSurface::new(ku, kv, rows, cols, grid).unwrap()
}

/// The smallest distance from `query` to `side × side` samples of the surface.
fn brute_force(s: &BSplineSurface, query: &Point3<Real>, side: usize) -> Real {
    let ((u0, u1), (v0, v1)) = (s.domain_u(), s.domain_v());
    let us: Vec<Real> = (0..side)
        .map(|i| u0 + (u1 - u0) * i as Real / (side - 1) as Real)
        .collect();
    let vs: Vec<Real> = (0..side)
        .map(|i| v0 + (v1 - v0) * i as Real / (side - 1) as Real)
        .collect();
    s.eval_grid(&us, &vs)
        .unwrap()
        .iter()
        .map(|p| (p - query).norm())
        .fold(Real::INFINITY, Real::min)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]

    #[test]
    fn closest_points_are_no_farther_than_a_dense_search_and_are_stationary(
        ku in knot_vector(),
        kv in knot_vector(),
        seed in any::<u64>(),
    ) {
        prop_assume!(ku.degree() >= 2 && kv.degree() >= 2);
        check_closest_points(ku, kv, seed)?;
    }
}

#[test]
fn a_crease_next_to_the_start_does_not_hide_the_nearer_side() {
    // Found by the property test: a biquadratic with a double knot (a C⁰ crease) in v at
    // 0.8207. A query 0.03 from the surface had its nearest point just below the crease
    // (v ≈ 0.8191), but every start sat on the crease's sample, where the derivatives are the
    // upper piece's, so Newton found only the local minimum just above it (v = 0.82091).
    let ku = KnotVector::new(2, vec![-0.6, -0.3, 0.0, 1.0, 1.3, 1.6]).unwrap();
    let crease = 0.8207233719708763;
    let kv = KnotVector::new(2, vec![-0.6, -0.3, 0.0, crease, crease, 1.0, 1.3, 1.6]).unwrap();
    check_closest_points(ku, kv, 7324076834798080410).unwrap();
}

#[test]
fn a_minimum_on_a_crease_is_found_on_it() {
    // Found by the property test: a quartic × quadratic with a double knot (a C⁰ crease) in
    // v at 0.3722. Queries whose nearest point lies on the crease, where the distance has a
    // kink, once stopped 1e-6 off it with a residual far from normal (cosine 0.33).
    let ku = KnotVector::new(
        4,
        vec![
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
            0.5870757923148244,
            1.0,
            1.0,
            1.0,
            1.0,
            1.0,
        ],
    )
    .unwrap();
    let crease = 0.37220812539262854;
    let kv = KnotVector::new(
        2,
        vec![
            0.0,
            0.0,
            0.0,
            crease,
            crease,
            0.585929532948649,
            2.0 / 3.0,
            5.0 / 6.0,
            1.0,
            1.0,
            1.0,
        ],
    )
    .unwrap();
    for seed in 0..400 {
        check_closest_points(ku.clone(), kv.clone(), seed).unwrap();
    }
}

/// Twenty queries against a random height field on `ku × kv`: global answers near the
/// surface, stationary ones off the creases.
fn check_closest_points(ku: KnotVector, kv: KnotVector, seed: u64) -> Result<(), TestCaseError> {
    let s = height_field(ku, kv, 0.25, seed);
    let inverter = ClosestPoints::new(&s);
    let mut rng = Lcg(seed ^ 0x9e37);
    let (rows, cols) = (s.rows() as Real, s.cols() as Real);
    for k in 0..20 {
        // Half the queries near the surface (the use: a scan against its fitted surface),
        // where the answer must be global; half anywhere around it, where a strongly
        // folded surface may hide a nearer basin from the starts and only a local
        // minimum is promised.
        let near = k % 2 == 0;
        let query = if near {
            let ((u0, u1), (v0, v1)) = (s.domain_u(), s.domain_v());
            let (u, v) = (rng.uniform(u0, u1), rng.uniform(v0, v1));
            let n = s.normal(u, v).unwrap().map_or(Vector3::z(), |n| n.into_inner());
            s.eval(u, v).unwrap() + n * rng.uniform(-0.05, 0.05)
        } else {
            rng.point_in([-1.0, -1.0, -2.0], [rows, cols, 2.0])
        };
        let c = inverter.closest(&query).unwrap();
        prop_assert!((c.point - s.eval(c.u, c.v).unwrap()).norm() < 1e-12);
        prop_assert!((c.distance - (c.point - query).norm()).abs() < 1e-12);
        // Samples 1/199 of the domain apart lie within a step of the true minimum.
        if near {
            let brute = brute_force(&s, &query, 200);
            prop_assert!(c.distance <= brute + 1e-9, "{} > {}", c.distance, brute);
        }
        // Inside the domain, and off the creases (knots of multiplicity ≥ the degree, where
        // the surface is only C⁰), the residual is normal to the surface.
        let ((u0, u1), (v0, v1)) = (s.domain_u(), s.domain_v());
        let crease = |k: &KnotVector, t: Real| {
            k.knots()
                .iter()
                .any(|&x| (x - t).abs() < 1e-6 && k.knots().iter().filter(|&&y| y == x).count() >= k.degree())
        };
        let smooth = !crease(s.knots_u(), c.u) && !crease(s.knots_v(), c.v);
        if smooth && c.u > u0 && c.u < u1 && c.v > v0 && c.v < v1 && c.distance > 1e-9 {
            let d = s.derivatives(c.u, c.v, 1).unwrap();
            let r = c.point - query;
            let (fu, fv) = (d.get(1, 0), d.get(0, 1));
            let (cu, cv) = (
                r.dot(&fu) / (r.norm() * fu.norm()),
                r.dot(&fv) / (r.norm() * fv.norm()),
            );
            // The residual's direction is known only to the rounding of the coordinates it is
            // the difference of, over its length: a query 10⁻⁷ from the surface cannot have
            // its cosines below about 10⁻⁹ (a case the property test found, before and after
            // the last step from the expansion).
            let bound =
                1e-9 + 64.0 * Real::EPSILON * (query.coords.norm() + c.point.coords.norm()) / r.norm();
            prop_assert!(
                cu.abs() <= bound && cv.abs() <= bound,
                "cosines {} {} at {:?}",
                cu,
                cv,
                c
            );
        }
    }
    Ok(())
}

#[test]
fn points_just_off_the_surface_give_back_their_parameters() {
    // A face-sized bicubic dome, 32 × 32; queries 0.1% of its size along the normal.
    let k = KnotVector::clamped_uniform(3, 32, 0.0, 1.0).unwrap();
    let grid = (0..32 * 32)
        .map(|i| {
            let (x, y) = ((i / 32) as Real / 31.0 - 0.5, (i % 32) as Real / 31.0 - 0.5);
            Point3::new(100.0 * x, 120.0 * y, 30.0 * (1.0 - 2.0 * (x * x + y * y)))
        })
        .collect();
    let s = BSplineSurface::new(k.clone(), k, 32, 32, grid).unwrap();
    let inverter = ClosestPoints::new(&s);
    let mut rng = Lcg(5);
    for _ in 0..2000 {
        let (u, v) = (rng.uniform(0.01, 0.99), rng.uniform(0.01, 0.99));
        let n = s.normal(u, v).unwrap().unwrap();
        let offset = rng.uniform(-0.15, 0.15); // 0.1% of the ~150-unit surface
        let query = s.eval(u, v).unwrap() + n.into_inner() * offset;
        let c = inverter.closest(&query).unwrap();
        assert!(
            (c.u - u).abs() < 1e-9 && (c.v - v).abs() < 1e-9,
            "({u}, {v}) → ({}, {})",
            c.u,
            c.v
        );
        assert!((c.distance - offset.abs()).abs() < 1e-9);
    }
    // The batch form gives the same answers.
    let queries: Vec<Point3<Real>> = (0..500)
        .map(|k| Point3::new(k as Real * 0.2 - 50.0, 30.0 - k as Real * 0.1, 10.0))
        .collect();
    let many = inverter.closest_many(&queries).unwrap();
    for (q, c) in queries.iter().zip(&many) {
        assert_eq!(*c, inverter.closest(q).unwrap());
    }
}

#[test]
fn beyond_an_edge_or_a_corner_the_closest_point_is_on_it() {
    let k = KnotVector::clamped_uniform(3, 4, 0.0, 1.0).unwrap();
    let grid = (0..16)
        .map(|i| Point3::new((i / 4) as Real, (i % 4) as Real, 0.0))
        .collect();
    let plane = BSplineSurface::new(k.clone(), k, 4, 4, grid).unwrap();
    let c = plane.closest_point(&Point3::new(5.0, 1.0, 2.0)).unwrap();
    assert!(
        (c.u - 1.0).abs() < 1e-12 && (c.v - 1.0 / 3.0).abs() < 1e-12,
        "{c:?}"
    );
    assert!((c.distance - 8.0_f64.sqrt()).abs() < 1e-12);
    let corner = plane.closest_point(&Point3::new(-1.0, -2.0, 0.5)).unwrap();
    assert_eq!((corner.u, corner.v), (0.0, 0.0));
    assert!((corner.point - Point3::origin()).norm() < 1e-12);
    assert!(matches!(
        plane.closest_point(&Point3::new(Real::NAN, 0.0, 0.0)),
        Err(BSplineError::NonFiniteSample { index: 0 })
    ));
    let inverter = ClosestPoints::new(&plane);
    let bad = [Point3::origin(), Point3::new(0.0, Real::INFINITY, 0.0)];
    assert!(matches!(
        inverter.closest_many(&bad),
        Err(BSplineError::NonFiniteSample { index: 1 })
    ));
    // A point on the plane is its own closest point.
    let on = inverter.closest(&Point3::new(1.5, 2.25, 0.0)).unwrap();
    assert!(on.distance < 1e-12);
}
