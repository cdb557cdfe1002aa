//! Least-squares fitting.

use nalgebra::{Point3, Vector3};
use proptest::prelude::*;
use splineface::bspline::{BSplineError, BSplineSurface, KnotVector, SurfaceFit};

use crate::common::{Lcg, random_surface};

/// `count` random parameters over the unit square plus a regular `side × side` lattice, so that
/// every knot cell has samples.
fn covering_params(count: usize, side: usize, seed: u64) -> Vec<[f64; 2]> {
    let mut rng = Lcg(seed);
    let mut params: Vec<[f64; 2]> = (0..count).map(|_| [rng.next(), rng.next()]).collect();
    for i in 0..side {
        for j in 0..side {
            params.push([i as f64 / (side - 1) as f64, j as f64 / (side - 1) as f64]);
        }
    }
    params
}

/// Random interior knots on [0, 1], clamped.
fn random_clamped(degree: usize, n: usize, rng: &mut Lcg) -> KnotVector {
    let mut inner: Vec<f64> = (0..n - degree - 1).map(|_| rng.uniform(0.05, 0.95)).collect();
    inner.sort_by(|a, b| a.partial_cmp(b).unwrap());
    let mut knots = vec![0.0; degree + 1];
    knots.extend(inner);
    knots.extend(vec![1.0; degree + 1]);
    KnotVector::new(degree, knots).unwrap()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    /// Fitting a spline's own samples with the same knots returns its control grid.
    #[test]
    fn fitting_own_samples_recovers_the_control_grid(p in 1usize..=4, q in 1usize..=4, m in 0usize..6, n in 0usize..6, seed in any::<u64>()) {
        let mut rng = Lcg(seed);
        let ku = random_clamped(p, p + 1 + m, &mut rng);
        let kv = random_clamped(q, q + 1 + n, &mut rng);
        let truth = random_surface(ku.clone(), kv.clone(), seed ^ 0x9e37);
        // Dense enough that even narrow random knot cells hold samples.
        let params = covering_params(4000, 60, seed);
        let points = truth.eval_many(&params).unwrap();
        // The fit solves normal equations, which square the condition number: a knot span
        // a thousandth wide holding a handful of samples leaves its control points right to
        // about 1e-7 (found by this test: spans 0.5613–0.5624, 1.1e-7) while the samples are
        // still reproduced to 1e-12. So the grid is held to 1e-9 when every span is at least
        // 1% wide, to 1e-6 otherwise; the samples always to 1e-9.
        let narrowest = [&ku, &kv]
            .iter()
            .flat_map(|k| k.breakpoints().windows(2).map(|w| w[1] - w[0]).collect::<Vec<_>>())
            .fold(f64::INFINITY, f64::min);
        let tolerance = if narrowest >= 0.01 { 1e-9 } else { 1e-6 };
        let fitted = SurfaceFit::new(ku, kv).fit(&params, &points).unwrap();
        for (a, b) in fitted.surface.control_points().iter().zip(truth.control_points()) {
            prop_assert!((a - b).norm() < tolerance, "{a} vs {b} (narrowest span {narrowest})");
        }
        prop_assert!(fitted.report.max < 1e-9);
    }
}

#[test]
fn own_samples_recovered_on_a_rectangular_bicubic_grid() {
    let ku = KnotVector::clamped_uniform(3, 12, 0.0, 1.0).unwrap();
    let kv = KnotVector::clamped_uniform(3, 7, 0.0, 1.0).unwrap();
    let truth = random_surface(ku.clone(), kv.clone(), 11);
    let params = covering_params(5000, 40, 2);
    let points = truth.eval_many(&params).unwrap();
    let fitted = SurfaceFit::new(ku, kv).fit(&params, &points).unwrap();
    let worst = fitted
        .surface
        .control_points()
        .iter()
        .zip(truth.control_points())
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, f64::max);
    assert!(worst < 1e-9, "worst control point error {worst}");
    assert_eq!(fitted.report.samples, params.len());
}

#[test]
fn smoothing_keeps_a_plane_exact_whatever_the_weight() {
    // Up to λ = 1; beyond, the normal equations' conditioning (∝ λ) shows in the last digits,
    // as documented on `SurfaceFit`.
    let ku = KnotVector::clamped_uniform(3, 10, 0.0, 1.0).unwrap();
    let kv = KnotVector::clamped_uniform(3, 8, 0.0, 2.0).unwrap();
    let plane = |u: f64, v: f64| Point3::new(2.0 * u - 1.0, 0.5 * v + u, 3.0 - u + 0.25 * v);
    let mut rng = Lcg(5);
    // Samples only in part of the domain: the rest is filled by the smoothness term.
    let params: Vec<[f64; 2]> = (0..500)
        .map(|_| [rng.uniform(0.2, 0.6), rng.uniform(0.5, 1.5)])
        .collect();
    let points: Vec<_> = params.iter().map(|&[u, v]| plane(u, v)).collect();
    for lambda in [1e-8, 1e-3, 1.0] {
        let fitted = SurfaceFit::new(ku.clone(), kv.clone())
            .smoothness(lambda)
            .fit(&params, &points)
            .unwrap();
        for i in 0..=10 {
            for j in 0..=10 {
                let (u, v) = (i as f64 / 10.0, 2.0 * j as f64 / 10.0);
                let err = (fitted.surface.eval(u, v).unwrap() - plane(u, v)).norm();
                assert!(err < 1e-8, "λ = {lambda}: error {err} at ({u}, {v})");
            }
        }
    }
}

#[test]
fn smoothing_pulls_noise_toward_the_underlying_shape() {
    let k = KnotVector::clamped_uniform(3, 20, 0.0, 1.0).unwrap();
    let shape = |u: f64, v: f64| Point3::new(u, v, 0.3 * (3.0 * u).sin() * (2.0 * v).cos());
    let mut rng = Lcg(8);
    let params: Vec<[f64; 2]> = (0..3000).map(|_| [rng.next(), rng.next()]).collect();
    let points: Vec<_> = params
        .iter()
        .map(|&[u, v]| shape(u, v) + Vector3::new(0.0, 0.0, rng.uniform(-0.05, 0.05)))
        .collect();
    let error_to_truth = |s: &BSplineSurface| {
        let mut sum = 0.0;
        for i in 0..=40 {
            for j in 0..=40 {
                let (u, v) = (i as f64 / 40.0, j as f64 / 40.0);
                sum += (s.eval(u, v).unwrap() - shape(u, v)).norm_squared();
            }
        }
        (sum / 41.0 / 41.0).sqrt()
    };
    let raw = SurfaceFit::new(k.clone(), k.clone())
        .fit(&params, &points)
        .unwrap();
    let smooth = SurfaceFit::new(k.clone(), k.clone())
        .smoothness(1e-5)
        .fit(&params, &points)
        .unwrap();
    let (e_raw, e_smooth) = (error_to_truth(&raw.surface), error_to_truth(&smooth.surface));
    assert!(
        e_smooth < 0.8 * e_raw,
        "smoothing did not help: {e_smooth} vs {e_raw}"
    );
    // The residuals to the noisy samples grow instead, toward the noise level (0.05/√3 ≈ 0.029).
    assert!(smooth.report.rms > raw.report.rms);
    assert!(
        smooth.report.rms < 0.035,
        "over-smoothed: rms {}",
        smooth.report.rms
    );
}

#[test]
fn unsupported_control_points_are_an_error_without_smoothing() {
    let k = KnotVector::clamped_uniform(3, 10, 0.0, 1.0).unwrap();
    let mut rng = Lcg(1);
    // Samples only in the left half: the control points on the far right have no support.
    let params: Vec<[f64; 2]> = (0..2000).map(|_| [rng.uniform(0.0, 0.45), rng.next()]).collect();
    let points: Vec<_> = params.iter().map(|&[u, v]| Point3::new(u, v, u * v)).collect();
    let err = SurfaceFit::new(k.clone(), k.clone())
        .fit(&params, &points)
        .unwrap_err();
    match err {
        BSplineError::Underdetermined { row, .. } => assert!(row >= 5, "row {row} should be unsupported"),
        other => panic!("expected Underdetermined, got {other:?}"),
    }
    // With a little smoothing the same data give a well-defined surface.
    let fitted = SurfaceFit::new(k.clone(), k)
        .smoothness(1e-9)
        .fit(&params, &points)
        .unwrap();
    assert!(fitted.report.max < 1e-4, "max residual {}", fitted.report.max);
    assert!(
        fitted
            .surface
            .eval(1.0, 1.0)
            .unwrap()
            .coords
            .iter()
            .all(|c| c.is_finite())
    );
}

#[test]
fn too_few_samples_are_an_error_even_when_every_cell_has_one() {
    // One sample per cell cannot pin 16 control points per cell.
    let k = KnotVector::clamped_uniform(3, 6, 0.0, 1.0).unwrap();
    let params: Vec<[f64; 2]> = (0..3)
        .flat_map(|i| (0..3).map(move |j| [(i as f64 + 0.5) / 3.0, (j as f64 + 0.5) / 3.0]))
        .collect();
    let points: Vec<_> = params.iter().map(|&[u, v]| Point3::new(u, v, 0.0)).collect();
    assert!(matches!(
        SurfaceFit::new(k.clone(), k).fit(&params, &points),
        Err(BSplineError::Underdetermined { .. })
    ));
}

#[test]
fn zero_weights_ignore_outliers() {
    let k = KnotVector::clamped_uniform(2, 5, 0.0, 1.0).unwrap();
    let mut params = covering_params(400, 10, 4);
    let mut points: Vec<_> = params
        .iter()
        .map(|&[u, v]| Point3::new(u, v, u * u - v))
        .collect();
    let mut weights = vec![1.0; params.len()];
    params.push([0.5, 0.5]);
    points.push(Point3::new(0.5, 0.5, 1e6));
    weights.push(0.0);
    let fitted = SurfaceFit::new(k.clone(), k)
        .weights(&weights)
        .fit(&params, &points)
        .unwrap();
    assert!((fitted.surface.eval(0.5, 0.5).unwrap().z - (0.25 - 0.5)).abs() < 1e-10);
    // The report counts every sample, weighted or not: the outlier is the worst.
    assert_eq!(fitted.report.max_index, params.len() - 1);
}

#[test]
fn residual_report_matches_a_direct_computation() {
    let k = KnotVector::clamped_uniform(3, 6, 0.0, 1.0).unwrap();
    let params = covering_params(20_000, 20, 6);
    let points: Vec<_> = params
        .iter()
        .map(|&[u, v]| Point3::new(u, v, (5.0 * u).sin() * v))
        .collect();
    let fitted = SurfaceFit::new(k.clone(), k).fit(&params, &points).unwrap();
    let d: Vec<f64> = params
        .iter()
        .zip(&points)
        .map(|(&[u, v], p)| (fitted.surface.eval(u, v).unwrap() - p).norm())
        .collect();
    let rms = (d.iter().map(|x| x * x).sum::<f64>() / d.len() as f64).sqrt();
    let (imax, max) = d
        .iter()
        .enumerate()
        .fold((0, 0.0), |a, (i, &x)| if x > a.1 { (i, x) } else { a });
    // The report evaluates in a batch, which for a bicubic surface sums in SIMD registers
    // in another order than `eval`: the same to rounding.
    assert!((fitted.report.rms - rms).abs() < 1e-12 * rms.max(1e-300));
    assert!((fitted.report.max - max).abs() < 1e-12 * max);
    assert!((d[fitted.report.max_index] - max).abs() < 1e-12 * max, "{imax}");
    assert!(
        rms > 1e-6,
        "the target is not a spline, so the residual is not zero"
    );
}

#[test]
fn scaling_the_geometry_scales_the_fit() {
    // λ is dimensionless: scaling the samples scales the smoothed fit by the same factor.
    let k = KnotVector::clamped_uniform(3, 12, 0.0, 1.0).unwrap();
    let mut rng = Lcg(12);
    let params: Vec<[f64; 2]> = (0..800).map(|_| [rng.uniform(0.0, 0.7), rng.next()]).collect();
    let points: Vec<_> = params
        .iter()
        .map(|&[u, v]| Point3::new(u, v, (4.0 * u).cos() + v * v))
        .collect();
    let scaled: Vec<_> = points.iter().map(|p| p * 1000.0).collect();
    let a = SurfaceFit::new(k.clone(), k.clone())
        .smoothness(1e-4)
        .fit(&params, &points)
        .unwrap();
    let b = SurfaceFit::new(k.clone(), k.clone())
        .smoothness(1e-4)
        .fit(&params, &scaled)
        .unwrap();
    for (x, y) in a.surface.control_points().iter().zip(b.surface.control_points()) {
        assert!((x * 1000.0 - y).norm() < 1e-6 * (1.0 + y.coords.norm()));
    }
    // And so does duplicating every sample (the objective is a mean).
    let params2: Vec<_> = params.iter().chain(&params).copied().collect();
    let points2: Vec<_> = points.iter().chain(&points).copied().collect();
    let c = SurfaceFit::new(k.clone(), k)
        .smoothness(1e-4)
        .fit(&params2, &points2)
        .unwrap();
    for (x, y) in a.surface.control_points().iter().zip(c.surface.control_points()) {
        assert!((x - y).norm() < 1e-9);
    }
}

#[test]
fn fit_is_bitwise_identical_on_any_number_of_threads() {
    let k = KnotVector::clamped_uniform(3, 16, 0.0, 1.0).unwrap();
    let params = covering_params(200_000, 30, 77);
    let points: Vec<_> = params
        .iter()
        .map(|&[u, v]| Point3::new(u, v, (3.0 * u * v).sin()))
        .collect();
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            SurfaceFit::new(k.clone(), k.clone())
                .smoothness(1e-7)
                .fit(&params, &points)
                .unwrap()
        })
    };
    let (one, two, three) = (run(1), run(2), run(3));
    assert_eq!(one, two);
    assert_eq!(one, three);
}

#[test]
fn a_million_samples_fit() {
    let k = KnotVector::clamped_uniform(3, 64, 0.0, 1.0).unwrap();
    let params = covering_params(1_000_000, 2, 99);
    let truth = random_surface(k.clone(), k.clone(), 4);
    let points = truth.eval_many(&params).unwrap();
    let fitted = SurfaceFit::new(k.clone(), k).fit(&params, &points).unwrap();
    assert_eq!(fitted.report.samples, 1_000_004);
    assert!(fitted.report.max < 1e-8, "max residual {}", fitted.report.max);
}

#[test]
fn invalid_fit_input_is_an_error_not_a_panic() {
    let k = KnotVector::clamped_uniform(1, 3, 0.0, 1.0).unwrap();
    let fit = SurfaceFit::new(k.clone(), k.clone());
    let p = |x: f64| Point3::new(x, 0.0, 0.0);
    assert!(matches!(fit.fit(&[], &[]), Err(BSplineError::NoSamples)));
    assert!(matches!(
        fit.fit(&[[0.1, 0.1]], &[p(0.0), p(1.0)]),
        Err(BSplineError::SampleCountMismatch { what: "points", .. })
    ));
    assert!(matches!(
        fit.fit(&[[0.1, 0.1]], &[p(f64::NAN)]),
        Err(BSplineError::NonFiniteSample { index: 0 })
    ));
    assert!(matches!(
        fit.fit(&[[0.1, 0.1], [0.2, 1.5]], &[p(0.0), p(0.0)]),
        Err(BSplineError::InvalidSampleParameter { index: 1, .. })
    ));
    assert!(matches!(
        fit.fit(&[[f64::NAN, 0.1]], &[p(0.0)]),
        Err(BSplineError::InvalidSampleParameter { index: 0, .. })
    ));
    for bad in [-1.0, f64::NAN, f64::INFINITY] {
        assert!(matches!(
            fit.clone().smoothness(bad).fit(&[[0.1, 0.1]], &[p(0.0)]),
            Err(BSplineError::InvalidSmoothness { .. })
        ));
        assert!(matches!(
            fit.clone().weights(&[bad]).fit(&[[0.1, 0.1]], &[p(0.0)]),
            Err(BSplineError::InvalidWeight { index: 0, .. })
        ));
    }
    assert!(matches!(
        fit.clone().weights(&[1.0, 1.0]).fit(&[[0.1, 0.1]], &[p(0.0)]),
        Err(BSplineError::SampleCountMismatch { what: "weights", .. })
    ));
    let huge = KnotVector::clamped_uniform(3, 20_000, 0.0, 1.0).unwrap();
    assert!(matches!(
        SurfaceFit::new(huge.clone(), huge).fit(&[[0.1, 0.1]], &[p(0.0)]),
        Err(BSplineError::SystemTooLarge { .. })
    ));
    let msg = fit
        .fit(&[[0.1, 0.1], [0.2, 1.5]], &[p(0.0), p(0.0)])
        .unwrap_err()
        .to_string();
    assert!(msg.contains("sample 1") && msg.contains("v = 1.5"), "{msg}");
}
