//! Linear spaces of surfaces: members, modes, affine maps, mode and weight fitting.

use nalgebra::{Affine3, Matrix4, Point3, Vector3};
use proptest::prelude::*;
use splineface::bspline::{BSplineError, BSplineSurface, Direction, KnotVector, SurfaceSpace};

use crate::common::{Lcg, random_surface, surface};

/// `count` random displacement grids for `base`.
fn random_modes(base: &BSplineSurface, count: usize, seed: u64) -> Vec<Vec<Vector3<f64>>> {
    let mut rng = Lcg(seed);
    (0..count)
        .map(|_| {
            (0..base.rows() * base.cols())
                .map(|_| Vector3::new(rng.gaussian(), rng.gaussian(), rng.gaussian()))
                .collect()
        })
        .collect()
}

/// A lattice of parameters over `base`'s domain.
fn lattice(base: &BSplineSurface, side: usize) -> Vec<[f64; 2]> {
    let ((u0, u1), (v0, v1)) = (base.domain_u(), base.domain_v());
    let mut params = Vec::new();
    for i in 0..side {
        for j in 0..side {
            let (a, b) = (i as f64 / (side - 1) as f64, j as f64 / (side - 1) as f64);
            params.push([u0 + a * (u1 - u0), v0 + b * (v1 - v0)]);
        }
    }
    params
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(32))]

    /// `F_w = F₀ + Σₖ wₖ Dₖ` pointwise, with `Dₖ` each mode's own spline, for any knots.
    #[test]
    fn a_member_is_the_base_plus_the_weighted_modes(base in surface(), k in 0usize..4, seed in any::<u64>()) {
        let space = SurfaceSpace::new(base.clone(), random_modes(&base, k, seed)).unwrap();
        let mut rng = Lcg(seed ^ 7);
        let weights: Vec<f64> = (0..k).map(|_| rng.uniform(-2.0, 2.0)).collect();
        let member = space.surface(&weights).unwrap();
        let params = lattice(&base, 7);
        let samples = space.sample(&params).unwrap();
        for (s, &[u, v]) in params.iter().enumerate() {
            let mut expected = base.eval(u, v).unwrap();
            for (m, &w) in weights.iter().enumerate() {
                expected += space.mode_surface(m).eval(u, v).unwrap().coords * w;
            }
            let got = member.eval(u, v).unwrap();
            prop_assert!((got - expected).norm() < 1e-9 * (1.0 + expected.coords.norm()), "{got} vs {expected}");
            prop_assert!((samples.member(&weights)[s] - got).norm() < 1e-9 * (1.0 + got.coords.norm()));
        }
    }

    /// Affine invariance per mode: mapping the space maps every member, weights unchanged.
    #[test]
    fn mapping_the_space_maps_every_member(base in surface(), seed in any::<u64>()) {
        let space = SurfaceSpace::new(base.clone(), random_modes(&base, 3, seed)).unwrap();
        let mut rng = Lcg(seed);
        let mut m = Matrix4::identity();
        for r in 0..3 {
            for c in 0..4 {
                m[(r, c)] = rng.uniform(-2.0, 2.0);
            }
        }
        let a = Affine3::from_matrix_unchecked(m);
        let weights = [rng.gaussian(), rng.gaussian(), rng.gaussian()];
        let mapped = space.transformed(&a).surface(&weights).unwrap();
        let member = space.surface(&weights).unwrap();
        for [u, v] in lattice(&base, 5) {
            let lhs = mapped.eval(u, v).unwrap();
            let rhs = a * member.eval(u, v).unwrap();
            prop_assert!((lhs - rhs).norm() < 1e-9 * (1.0 + rhs.coords.norm()));
        }
    }

    /// Refining the space's knots refines every member: the same surface, more control
    /// points, for any knots, direction and weights.
    #[test]
    fn refining_the_space_refines_every_member(
        base in surface(),
        seed in any::<u64>(),
        along_u in any::<bool>(),
        at in proptest::collection::vec(0.0f64..1.0, 1..4),
    ) {
        let space = SurfaceSpace::new(base.clone(), random_modes(&base, 3, seed)).unwrap();
        let direction = if along_u { Direction::U } else { Direction::V };
        let (lo, hi) = if along_u { base.domain_u() } else { base.domain_v() };
        let values: Vec<f64> = at.iter().map(|a| lo + a * (hi - lo)).collect();
        // A value may meet a knot already there too often; the space refuses it as the
        // surface does.
        let finer = match (space.refine_knots(direction, &values), base.refine_knots(direction, &values)) {
            (Ok(finer), Ok(surface)) => {
                prop_assert_eq!(finer.base(), &surface);
                finer
            }
            (Err(a), Err(b)) => {
                prop_assert_eq!(a, b);
                return Ok(());
            }
            (a, b) => panic!("the space and its base disagree: {a:?} against {b:?}"),
        };
        let added = values.len();
        let (rows, cols) = if along_u { (base.rows() + added, base.cols()) } else { (base.rows(), base.cols() + added) };
        prop_assert_eq!((finer.base().rows(), finer.base().cols()), (rows, cols));
        prop_assert!(finer.modes().iter().all(|m| m.len() == rows * cols));
        let mut rng = Lcg(seed ^ 11);
        let weights = [rng.gaussian(), rng.gaussian(), rng.gaussian()];
        let (member, refined) = (space.surface(&weights).unwrap(), finer.surface(&weights).unwrap());
        for [u, v] in lattice(&base, 6) {
            let (a, b) = (member.eval(u, v).unwrap(), refined.eval(u, v).unwrap());
            prop_assert!((a - b).norm() < 1e-9 * (1.0 + a.coords.norm()), "{a} vs {b}");
        }
    }

    /// Noise-free samples of a member give its weights back.
    #[test]
    fn weights_of_a_member_are_recovered(seed in any::<u64>(), k in 1usize..6) {
        let knots = KnotVector::clamped_uniform(3, 7, 0.0, 1.0).unwrap();
        let base = random_surface(knots.clone(), knots, seed);
        let space = SurfaceSpace::new(base.clone(), random_modes(&base, k, seed ^ 3)).unwrap();
        let mut rng = Lcg(seed ^ 5);
        let truth: Vec<f64> = (0..k).map(|_| rng.uniform(-3.0, 3.0)).collect();
        let params = lattice(&base, 12);
        let targets = space.surface(&truth).unwrap().eval_many(&params).unwrap();
        let got = space.fit_weights(&params, &targets, &vec![0.0; k]).unwrap();
        for (g, t) in got.iter().zip(&truth) {
            prop_assert!((g - t).abs() < 1e-8, "{g} vs {t}");
        }
    }
}

/// One mode: the ridge solution has the closed form `w = ⟨D, y − F₀⟩ / (⟨D, D⟩ + ρ)`.
#[test]
fn one_mode_ridge_weight_has_the_closed_form() {
    let knots = KnotVector::clamped_uniform(3, 6, 0.0, 1.0).unwrap();
    let base = random_surface(knots.clone(), knots, 21);
    let space = SurfaceSpace::new(base.clone(), random_modes(&base, 1, 4)).unwrap();
    let params = lattice(&base, 9);
    let mut rng = Lcg(8);
    let targets: Vec<Point3<f64>> = base
        .eval_many(&params)
        .unwrap()
        .into_iter()
        .map(|p| p + Vector3::new(rng.gaussian(), rng.gaussian(), rng.gaussian()))
        .collect();
    let mode = space.mode_surface(0).eval_many(&params).unwrap();
    let base_points = base.eval_many(&params).unwrap();
    let num: f64 = mode
        .iter()
        .zip(&targets)
        .zip(&base_points)
        .map(|((d, y), b)| d.coords.dot(&(y - b)))
        .sum();
    let den: f64 = mode.iter().map(|d| d.coords.norm_squared()).sum();
    for rho in [0.0, 1.0, 50.0, 1e6] {
        let w = space.fit_weights(&params, &targets, &[rho]).unwrap()[0];
        let expected = num / (den + rho);
        assert!(
            (w - expected).abs() < 1e-10 * (1.0 + expected.abs()),
            "ρ = {rho}: {w} vs {expected}"
        );
    }
}

/// A displacement field that is itself a spline on the base's knots is fitted exactly, and
/// fitting positions then subtracting the base's fit gives the same mode (linearity).
#[test]
fn a_spline_displacement_field_is_fitted_exactly() {
    let knots = KnotVector::clamped_uniform(3, 8, 0.0, 1.0).unwrap();
    let base = random_surface(knots.clone(), knots.clone(), 2);
    let field = random_surface(knots.clone(), knots, 9);
    let space = SurfaceSpace::new(base.clone(), Vec::new()).unwrap();
    let params = lattice(&base, 30);
    let displacements: Vec<Vector3<f64>> = field
        .eval_many(&params)
        .unwrap()
        .iter()
        .map(|p| p.coords)
        .collect();
    let (mode, report) = space.fit_displacement(&params, &displacements, 0.0).unwrap();
    assert!(report.max < 1e-9, "{}", report.max);
    for (d, c) in mode.iter().zip(field.control_points()) {
        assert!((d - c.coords).norm() < 1e-9);
    }
    let space = space.with_mode(mode).unwrap();
    let moved = space.surface(&[1.0]).unwrap();
    for (s, &[u, v]) in params.iter().enumerate() {
        let expected = base.eval(u, v).unwrap() + displacements[s];
        assert!((moved.eval(u, v).unwrap() - expected).norm() < 1e-9);
    }
}

#[test]
fn bad_modes_weights_and_samples_are_errors() {
    let knots = KnotVector::clamped_uniform(3, 5, 0.0, 1.0).unwrap();
    let base = random_surface(knots.clone(), knots, 1);
    let short = vec![Vector3::zeros(); 24];
    assert!(matches!(
        SurfaceSpace::new(base.clone(), vec![short]),
        Err(BSplineError::ModeSize {
            mode: 0,
            got: 24,
            expected: 25
        })
    ));
    let mut bad = vec![Vector3::zeros(); 25];
    bad[7].y = f64::NAN;
    assert!(matches!(
        SurfaceSpace::new(base.clone(), vec![vec![Vector3::zeros(); 25], bad]),
        Err(BSplineError::NonFiniteMode {
            mode: 1,
            row: 1,
            col: 2
        })
    ));
    let space = SurfaceSpace::new(base.clone(), random_modes(&base, 2, 3)).unwrap();
    assert!(matches!(
        space.surface(&[1.0]),
        Err(BSplineError::WeightCount { got: 1, expected: 2 })
    ));
    assert!(matches!(
        space.surface(&[1.0, f64::INFINITY]),
        Err(BSplineError::NonFiniteModeWeight { index: 1, .. })
    ));
    let params = lattice(&base, 4);
    let targets = base.eval_many(&params).unwrap();
    assert!(matches!(
        space.fit_weights(&params, &targets, &[0.0, -1.0]),
        Err(BSplineError::InvalidWeight { index: 1, .. })
    ));
    assert!(matches!(
        space.fit_weights(&params[..3], &targets, &[0.0, 0.0]),
        Err(BSplineError::SampleCountMismatch { .. })
    ));
    assert!(matches!(
        space.fit_weights(&[], &[], &[0.0, 0.0]),
        Err(BSplineError::NoSamples)
    ));
    let mut outside = params.clone();
    outside[2] = [1.5, 0.0];
    assert!(matches!(
        space.fit_weights(&outside, &targets, &[0.0, 0.0]),
        Err(BSplineError::InvalidSampleParameter { index: 2, .. })
    ));
    // Two equal modes: only their sum is determined, unless regularised.
    let twin = random_modes(&base, 1, 5).remove(0);
    let twins = SurfaceSpace::new(base.clone(), vec![twin.clone(), twin]).unwrap();
    assert!(matches!(
        twins.fit_weights(&params, &targets, &[0.0, 0.0]),
        Err(BSplineError::ModesUnderdetermined)
    ));
    let w = twins.fit_weights(&params, &targets, &[1.0, 1.0]).unwrap();
    assert!(w.iter().all(|w| w.abs() < 1e-12), "{w:?}");
}
