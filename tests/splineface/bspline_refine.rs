//! Knot insertion and refinement, clamping, restriction, splitting and Bézier extraction: the
//! surface unchanged to rounding (property tests on random surfaces of degree 0–5, clamped or
//! not, with repeated knots), and the knot vectors the operations promise.

use proptest::prelude::*;
use splineface::Real;
use splineface::bspline::{BSplineError, BSplineSurface, Direction, KnotVector};

use super::common::{in_domain, random_surface, surface};

/// The largest distance between `a` and `b` over a 9 × 9 grid of `[u0, u1] × [v0, v1]`.
fn deviation(a: &BSplineSurface, b: &BSplineSurface, u: (Real, Real), v: (Real, Real)) -> Real {
    let mut worst: Real = 0.0;
    for i in 0..9 {
        for j in 0..9 {
            // Within the ends exactly, whatever the rounding.
            let s = (u.0 + (u.1 - u.0) * i as Real / 8.0).clamp(u.0, u.1);
            let t = (v.0 + (v.1 - v.0) * j as Real / 8.0).clamp(v.0, v.1);
            let at = |x: &BSplineSurface| {
                x.eval(s, t).unwrap_or_else(|e| {
                    panic!("{e} at ({s}, {t}), domains {:?} and {:?}", domain(a), domain(b))
                })
            };
            worst = worst.max((at(a) - at(b)).norm());
        }
    }
    worst
}

/// [`deviation`] a hair inside `[u0, u1] × [v0, v1]`: a surface whose knot has multiplicity
/// `degree + 1` is discontinuous there (it takes the right-hand limit at the knot, a part
/// ending there the left-hand one).
fn inner_deviation(a: &BSplineSurface, b: &BSplineSurface, u: (Real, Real), v: (Real, Real)) -> Real {
    let inset = |(lo, hi): (Real, Real)| (lo + 1e-9 * (hi - lo), hi - 1e-9 * (hi - lo));
    deviation(a, b, inset(u), inset(v))
}

fn domain(s: &BSplineSurface) -> ((Real, Real), (Real, Real)) {
    (s.domain_u(), s.domain_v())
}

fn knots_of(s: &BSplineSurface, direction: Direction) -> &KnotVector {
    match direction {
        Direction::U => s.knots_u(),
        Direction::V => s.knots_v(),
    }
}

/// Control points lie in [-10, 10]³; 1e-12 of that scale, with room for a few roundings.
const TOLERANCE: Real = 1e-11;

fn direction() -> impl Strategy<Value = Direction> {
    prop_oneof![Just(Direction::U), Just(Direction::V)]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn refinement_keeps_the_surface_and_merges_the_knots(
        s in surface(),
        direction in direction(),
        ts in prop::collection::vec(0.0..=1.0f64, 1..6),
    ) {
        let knots = knots_of(&s, direction);
        prop_assume!(knots.degree() >= 1);
        let p = knots.degree();
        // Values in the domain, each kept within the multiplicity limit.
        let mut values: Vec<Real> = Vec::new();
        for t in ts {
            let x = in_domain(knots, t);
            let already = knots.knots().iter().chain(&values).filter(|&&k| k == x).count();
            if already < p {
                values.push(x);
            }
        }
        prop_assume!(!values.is_empty());
        let refined = s.refine_knots(direction, &values).unwrap();
        let (u, v) = domain(&s);
        prop_assert_eq!(domain(&refined), (u, v));
        prop_assert!(deviation(&s, &refined, u, v) < TOLERANCE, "{}", deviation(&s, &refined, u, v));
        let mut merged: Vec<Real> = knots.knots().iter().chain(&values).copied().collect();
        merged.sort_by(Real::total_cmp);
        prop_assert_eq!(knots_of(&refined, direction).knots(), merged.as_slice());
    }

    #[test]
    fn clamping_restricting_and_splitting_keep_the_surface(
        s in surface(),
        direction in direction(),
        a in 0.0..1.0f64,
        b in 0.0..1.0f64,
    ) {
        let (u, v) = domain(&s);
        let clamped = s.clamped().unwrap();
        prop_assert!(clamped.knots_u().is_clamped() && clamped.knots_v().is_clamped());
        prop_assert_eq!(domain(&clamped), (u, v));
        prop_assert!(deviation(&s, &clamped, u, v) < TOLERANCE);
        if s.knots_u().is_clamped() && s.knots_v().is_clamped() {
            prop_assert_eq!(&clamped, &s);
        }
        let knots = knots_of(&s, direction);
        prop_assume!(knots.degree() >= 1);
        let (lo, hi) = (in_domain(knots, a.min(b)), in_domain(knots, a.max(b)));
        prop_assume!(hi - lo > 1e-6);
        let part = s.restricted(direction, lo, hi).unwrap();
        let (pu, pv) = domain(&part);
        match direction {
            Direction::U => prop_assert_eq!((pu, pv), ((lo, hi), v)),
            Direction::V => prop_assert_eq!((pu, pv), (u, (lo, hi))),
        }
        prop_assert!(knots_of(&part, direction).is_clamped());
        prop_assert!(inner_deviation(&s, &part, pu, pv) < TOLERANCE);
        let (start, end) = knots.domain();
        let at = 0.5 * (start + end);
        let (below, above) = s.split(direction, at).unwrap();
        prop_assert!(inner_deviation(&s, &below, below.domain_u(), below.domain_v()) < TOLERANCE);
        prop_assert!(inner_deviation(&s, &above, above.domain_u(), above.domain_v()) < TOLERANCE);
        // The halves meet along the cut (unless the surface breaks there).
        let breaks = knots.knots().iter().filter(|&&k| k == at).count() > knots.degree();
        for k in (0..5).filter(|_| !breaks) {
            let t = k as Real / 4.0;
            let (x, y) = match direction {
                Direction::U => ((at, in_domain(s.knots_v(), t)), (at, in_domain(s.knots_v(), t))),
                Direction::V => ((in_domain(s.knots_u(), t), at), (in_domain(s.knots_u(), t), at)),
            };
            let gap = (below.eval(x.0, x.1).unwrap() - above.eval(y.0, y.1).unwrap()).norm();
            prop_assert!(gap < TOLERANCE);
        }
    }

    #[test]
    fn bezier_patches_tile_the_surface(s in surface()) {
        prop_assume!(s.degree_u() >= 1 && s.degree_v() >= 1);
        let patches = s.bezier_patches().unwrap();
        let (us, vs) = (s.knots_u().breakpoints(), s.knots_v().breakpoints());
        prop_assert_eq!(patches.len(), (us.len() - 1) * (vs.len() - 1));
        for (k, patch) in patches.iter().enumerate() {
            let (i, j) = (k / (vs.len() - 1), k % (vs.len() - 1));
            // A Bézier patch: degree + 1 control points a side, knots only at its corners.
            prop_assert_eq!((patch.rows(), patch.cols()), (s.degree_u() + 1, s.degree_v() + 1));
            prop_assert_eq!(patch.domain_u(), (us[i], us[i + 1]));
            prop_assert_eq!(patch.domain_v(), (vs[j], vs[j + 1]));
            prop_assert!(inner_deviation(&s, patch, patch.domain_u(), patch.domain_v()) < TOLERANCE);
        }
    }
}

#[test]
fn inserting_a_knot_p_times_makes_the_surface_at_it_one_row_of_control_points() {
    // The NURBS Book §5.2: with t inserted to multiplicity p, F(t, v) is the v-curve of the
    // single row of control points whose u basis function is 1 at t.
    let k = KnotVector::clamped_uniform(3, 6, 0.0, 1.0).unwrap();
    let s = random_surface(k.clone(), k, 7);
    let t = 0.37;
    let r = s.insert_knot(Direction::U, t, 3).unwrap();
    assert_eq!(r.rows(), 9);
    let first = r.knots_u().knots().iter().position(|&x| x == t).unwrap();
    let row = first - 1;
    let kv = r.knots_v();
    for v in [0.0, 0.2, 0.5, 0.93, 1.0] {
        let span = kv.span(v).unwrap();
        let mut n = [0.0; 4];
        splineface::bspline::basis_functions(kv, span, v, &mut n);
        let expected: nalgebra::Vector3<Real> = (0..4)
            .map(|l| r.control_point(row, span - 3 + l).coords * n[l])
            .sum();
        assert!((r.eval(t, v).unwrap().coords - expected).norm() < 1e-12);
        assert!((s.eval(t, v).unwrap().coords - expected).norm() < 1e-11);
    }
}

#[test]
fn bad_knots_are_refused() {
    let k = KnotVector::clamped_uniform(2, 5, 0.0, 1.0).unwrap();
    let s = random_surface(k.clone(), k, 3);
    assert!(matches!(
        s.refine_knots(Direction::U, &[1.5]),
        Err(BSplineError::ParameterOutOfDomain { value, .. }) if value == 1.5
    ));
    assert!(matches!(
        s.refine_knots(Direction::V, &[Real::NAN]),
        Err(BSplineError::ParameterOutOfDomain { .. })
    ));
    // Degree 2: a knot may appear twice at most; the clamped ends already do three times.
    assert!(matches!(
        s.insert_knot(Direction::U, 0.4, 3),
        Err(BSplineError::KnotMultiplicityTooHigh {
            multiplicity: 3,
            max: 2,
            ..
        })
    ));
    assert!(matches!(
        s.insert_knot(Direction::U, 0.0, 1),
        Err(BSplineError::KnotMultiplicityTooHigh { .. })
    ));
    assert!(s.insert_knot(Direction::U, 0.4, 0).unwrap() == s);
    assert!(matches!(
        s.restricted(Direction::U, 0.6, 0.6),
        Err(BSplineError::EmptyDomain { .. })
    ));
    assert!(matches!(
        s.split(Direction::V, 1.0),
        Err(BSplineError::ParameterOutOfDomain { .. })
    ));
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn degree_elevation_keeps_the_surface_and_its_continuity(
        s in surface(),
        direction in direction(),
        by in 1usize..=3,
    ) {
        let knots = knots_of(&s, direction);
        let p = knots.degree();
        let (start, end) = knots.domain();
        let inner: Vec<Real> = knots.knots().iter().copied().filter(|&k| k > start && k < end).collect();
        let breaks = inner.chunk_by(|a, b| a == b).any(|run| run.len() > p);
        prop_assume!(p + by <= splineface::bspline::MAX_DEGREE);
        let elevated = s.elevate_degree(direction, by);
        if breaks {
            let refused = matches!(elevated, Err(BSplineError::KnotMultiplicityTooHigh { .. }));
            prop_assert!(refused);
            return Ok(());
        }
        let elevated = elevated.unwrap();
        let k = knots_of(&elevated, direction);
        prop_assert_eq!(k.degree(), p + by);
        prop_assert!(k.is_clamped());
        // Every distinct knot of the domain once more per degree added.
        let runs = |v: &[Real]| -> Vec<(Real, usize)> {
            v.chunk_by(|a, b| a == b).map(|r| (r[0], r.len())).collect()
        };
        let inner_after: Vec<Real> = k.knots().iter().copied().filter(|&x| x > start && x < end).collect();
        let before = runs(&inner);
        let after = runs(&inner_after);
        prop_assert_eq!(before.len(), after.len());
        for ((x, m), (y, n)) in before.iter().zip(&after) {
            prop_assert_eq!((x, m + by), (y, *n));
        }
        let (u, v) = domain(&s);
        prop_assert_eq!(domain(&elevated), (u, v));
        // Knot removal inside A5.9 divides by span widths: its rounding grows as the
        // narrowest span shrinks against the domain (the generator makes spans down to 10⁻⁴).
        let narrowest = k
            .knots()
            .windows(2)
            .map(|w| w[1] - w[0])
            .filter(|&w| w > 0.0)
            .fold(Real::INFINITY, Real::min);
        let condition = ((end - start) / narrowest).max(1.0);
        let error = deviation(&s, &elevated, u, v);
        prop_assert!(error < TOLERANCE * condition, "{} (condition {})", error, condition);
    }
}

#[test]
fn elevation_beyond_the_largest_degree_is_refused() {
    let k = KnotVector::clamped_uniform(3, 4, 0.0, 1.0).unwrap();
    let s = random_surface(k.clone(), k, 5);
    let max = splineface::bspline::MAX_DEGREE;
    assert!(matches!(
        s.elevate_degree(Direction::U, max),
        Err(BSplineError::DegreeTooHigh { .. })
    ));
    assert_eq!(s.elevate_degree(Direction::V, 0).unwrap(), s);
}

#[test]
fn a_large_uniform_surface_survives_every_operation_to_1e_12() {
    // The bar, on a well-conditioned surface: 64 × 64 bicubic, control points in
    // [-1, 1]³ (random_surface's [-10, 10] scaled), clamped uniform knots.
    let k = KnotVector::clamped_uniform(3, 64, 0.0, 1.0).unwrap();
    let big = random_surface(k.clone(), k, 11);
    let grid = big.control_points().iter().map(|p| p * 0.1).collect();
    let s = big.with_control_points(grid).unwrap();
    let inserted = s.insert_knot(Direction::U, 0.123_456, 2).unwrap();
    let refined = s
        .refine_knots(Direction::V, &[0.01, 0.25, 0.25, 0.5, 0.777, 0.999])
        .unwrap();
    let elevated = s
        .elevate_degree(Direction::U, 1)
        .unwrap()
        .elevate_degree(Direction::V, 2)
        .unwrap();
    assert_eq!((elevated.degree_u(), elevated.degree_v()), (4, 5));
    assert_eq!((elevated.rows(), elevated.cols()), (64 + 61, 64 + 2 * 61));
    let (u, v) = ((0.0, 1.0), (0.0, 1.0));
    for other in [&inserted, &refined, &elevated] {
        let error = deviation(&s, other, u, v);
        assert!(error < 1e-12, "{error}");
    }
    let patches = s.bezier_patches().unwrap();
    assert_eq!(patches.len(), 61 * 61);
    let worst = patches
        .iter()
        .step_by(97)
        .map(|p| deviation(&s, p, p.domain_u(), p.domain_v()))
        .fold(0.0, Real::max);
    assert!(worst < 1e-12, "{worst}");
}
