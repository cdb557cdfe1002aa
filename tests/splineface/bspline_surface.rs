//! Surface evaluation: closed forms, derivatives, normals, grids, the basis matrix, affine maps.

use nalgebra::{Affine3, Matrix4, Point3, Vector3};
use proptest::prelude::*;
use splineface::bspline::{BSplineError, BSplineSurface, Direction, KnotVector};

use crate::common::{Lcg, in_domain, knot_vector, random_surface, surface};

/// Parameters spread over the whole domain, corners and edges included.
fn sample_params(s: &BSplineSurface, count: usize) -> Vec<[f64; 2]> {
    let side = (count as f64).sqrt().ceil() as usize;
    let mut out = Vec::new();
    for i in 0..side {
        for j in 0..side {
            let t = |k: usize| k as f64 / (side - 1).max(1) as f64;
            out.push([in_domain(s.knots_u(), t(i)), in_domain(s.knots_v(), t(j))]);
        }
    }
    out
}

#[test]
fn bicubic_bezier_patch_matches_the_bernstein_formula() {
    let k = KnotVector::clamped_uniform(3, 4, 0.0, 1.0).unwrap();
    let s = random_surface(k.clone(), k, 7);
    let bern = |t: f64| {
        let r = 1.0 - t;
        [r * r * r, 3.0 * t * r * r, 3.0 * t * t * r, t * t * t]
    };
    let mut rng = Lcg(3);
    for _ in 0..200 {
        let (u, v) = (rng.next(), rng.next());
        let (bu, bv) = (bern(u), bern(v));
        let mut expected = Vector3::zeros();
        for i in 0..4 {
            for j in 0..4 {
                expected += s.control_point(i, j).coords * (bu[i] * bv[j]);
            }
        }
        assert!((s.eval(u, v).unwrap().coords - expected).norm() < 1e-12);
    }
}

proptest! {
    #[test]
    fn clamped_surfaces_interpolate_their_corner_control_points(ku in knot_vector(), kv in knot_vector(), seed in any::<u64>()) {
        prop_assume!(ku.is_clamped() && kv.is_clamped());
        let s = random_surface(ku, kv, seed);
        let (u0, u1) = s.domain_u();
        let (v0, v1) = s.domain_v();
        let (m, n) = (s.rows() - 1, s.cols() - 1);
        for (u, v, i, j) in [(u0, v0, 0, 0), (u0, v1, 0, n), (u1, v0, m, 0), (u1, v1, m, n)] {
            let p = s.eval(u, v).unwrap();
            prop_assert!((p - s.control_point(i, j)).norm() < 1e-12, "corner ({i}, {j})");
        }
    }

    /// Linear precision: control points affine in the Greville abscissae give exactly the
    /// affine surface a + b·u + c·v, on any knots.
    #[test]
    fn affine_control_grid_gives_the_exact_plane(ku in knot_vector(), kv in knot_vector(), t in prop::array::uniform4(0.0..=1.0f64)) {
        prop_assume!(ku.degree() >= 1 && kv.degree() >= 1);
        let (gu, gv) = (ku.greville(), kv.greville());
        let a = Vector3::new(1.0, -2.0, 0.5);
        let b = Vector3::new(3.0, 0.25, -1.0);
        let c = Vector3::new(-0.5, 2.0, 4.0);
        let f = |u: f64, v: f64| a + b * u + c * v;
        let grid = gu.iter().flat_map(|&u| gv.iter().map(move |&v| Point3::from(f(u, v)))).collect();
        let s = BSplineSurface::new(ku.clone(), kv.clone(), gu.len(), gv.len(), grid).unwrap();
        for (tu, tv) in [(t[0], t[1]), (t[2], t[3])] {
            let (u, v) = (in_domain(&ku, tu), in_domain(&kv, tv));
            let p = s.eval(u, v).unwrap();
            prop_assert!((p.coords - f(u, v)).norm() < 1e-11, "{p} vs {}", f(u, v));
        }
    }

    #[test]
    fn surface_derivatives_match_central_differences(s in surface(), tu in 0.05..0.95f64, tv in 0.05..0.95f64) {
        let (u, v) = (in_domain(s.knots_u(), tu), in_domain(s.knots_v(), tv));
        // Differences must not straddle a knot (the surface is only piecewise polynomial).
        let cell = |k: &KnotVector, x: f64| { let i = k.span(x).unwrap(); (k.knots()[i], k.knots()[i + 1]) };
        let ((ua, ub), (va, vb)) = (cell(s.knots_u(), u), cell(s.knots_v(), v));
        let (hu, hv) = (1e-4 * (ub - ua), 1e-4 * (vb - va));
        let (u, v) = (u.clamp(ua + 3.0 * hu, ub - 3.0 * hu), v.clamp(va + 3.0 * hv, vb - 3.0 * hv));
        let d = s.derivatives(u, v, 2).unwrap();
        let f = |du: f64, dv: f64| s.eval(u + du, v + dv).unwrap().coords;
        prop_assert!((d.point().coords - f(0.0, 0.0)).norm() < 1e-12);
        let scale = s.control_points().iter().map(|p| p.coords.amax()).fold(1.0, f64::max);
        let close = |a: Vector3<f64>, b: Vector3<f64>, tol: f64| (a - b).norm() <= tol * scale;
        let fu = (f(hu, 0.0) - f(-hu, 0.0)) / (2.0 * hu);
        let fv = (f(0.0, hv) - f(0.0, -hv)) / (2.0 * hv);
        prop_assert!(close(d.get(1, 0), fu, 1e-5 / (ub - ua)), "F_u {} vs {fu}", d.get(1, 0));
        prop_assert!(close(d.get(0, 1), fv, 1e-5 / (vb - va)), "F_v {} vs {fv}", d.get(0, 1));
        let fuu = (f(hu, 0.0) - 2.0 * f(0.0, 0.0) + f(-hu, 0.0)) / (hu * hu);
        let fvv = (f(0.0, hv) - 2.0 * f(0.0, 0.0) + f(0.0, -hv)) / (hv * hv);
        let fuv = (f(hu, hv) - f(hu, -hv) - f(-hu, hv) + f(-hu, -hv)) / (4.0 * hu * hv);
        prop_assert!(close(d.get(2, 0), fuu, 1e-2 / (ub - ua).powi(2)), "F_uu {} vs {fuu}", d.get(2, 0));
        prop_assert!(close(d.get(0, 2), fvv, 1e-2 / (vb - va).powi(2)), "F_vv {} vs {fvv}", d.get(0, 2));
        prop_assert!(close(d.get(1, 1), fuv, 1e-2 / ((ub - ua) * (vb - va))), "F_uv {} vs {fuv}", d.get(1, 1));
    }

    #[test]
    fn normals_are_unit_and_orthogonal_to_both_tangents(s in surface(), tu in 0.0..=1.0f64, tv in 0.0..=1.0f64) {
        let (u, v) = (in_domain(s.knots_u(), tu), in_domain(s.knots_v(), tv));
        let d = s.derivatives(u, v, 1).unwrap();
        match s.normal(u, v).unwrap() {
            Some(n) => {
                prop_assert!((n.norm() - 1.0).abs() < 1e-12);
                prop_assert!(n.dot(&d.get(1, 0)).abs() <= 1e-9 * d.get(1, 0).norm());
                prop_assert!(n.dot(&d.get(0, 1)).abs() <= 1e-9 * d.get(0, 1).norm());
                // Orientation: F_u, F_v, n is right-handed.
                prop_assert!(d.get(1, 0).cross(&d.get(0, 1)).dot(&n) > 0.0);
            }
            None => {
                let (fu, fv) = (d.get(1, 0), d.get(0, 1));
                prop_assert!(fu.cross(&fv).norm() <= 1e-12 * fu.norm() * fv.norm());
            }
        }
    }

    #[test]
    fn affine_invariance(s in surface(), m in prop::array::uniform12(-3.0..3.0f64), tu in 0.0..=1.0f64, tv in 0.0..=1.0f64) {
        let a = Affine3::from_matrix_unchecked(Matrix4::new(
            m[0], m[1], m[2], m[3], m[4], m[5], m[6], m[7], m[8], m[9], m[10], m[11], 0.0, 0.0, 0.0, 1.0,
        ));
        let (u, v) = (in_domain(s.knots_u(), tu), in_domain(s.knots_v(), tv));
        let lhs = s.transformed(&a).eval(u, v).unwrap();
        let rhs = a * s.eval(u, v).unwrap();
        prop_assert!((lhs - rhs).norm() < 1e-11 * (1.0 + rhs.coords.norm()));
    }

    #[test]
    fn dense_grid_and_batch_equal_pointwise_evaluation(s in surface()) {
        let us: Vec<f64> = (0..13).map(|i| in_domain(s.knots_u(), i as f64 / 12.0)).collect();
        let vs: Vec<f64> = (0..11).map(|i| in_domain(s.knots_v(), i as f64 / 10.0)).collect();
        let grid = s.eval_grid(&us, &vs).unwrap();
        let params: Vec<[f64; 2]> = us.iter().flat_map(|&u| vs.iter().map(move |&v| [u, v])).collect();
        let batch = s.eval_many(&params).unwrap();
        for (k, &[u, v]) in params.iter().enumerate() {
            let p = s.eval(u, v).unwrap();
            prop_assert!((grid[k] - p).norm() < 1e-12 * (1.0 + p.coords.norm()), "grid at ({u}, {v})");
            // A bicubic batch runs in SIMD registers, its sums in another order (issue 24:
            // the same to 1e-12); other degrees are evaluated exactly as `eval` does.
            if s.degree_u() == 3 && s.degree_v() == 3 {
                prop_assert!((batch[k] - p).norm() < 1e-12 * (1.0 + p.coords.norm()), "batch at ({u}, {v})");
            } else {
                prop_assert_eq!(batch[k], p);
            }
        }
    }

    #[test]
    fn basis_matrix_reproduces_evaluation(s in surface()) {
        let params = sample_params(&s, 30);
        let r = s.basis_matrix(&params).unwrap();
        prop_assert_eq!(r.nrows(), params.len());
        prop_assert_eq!(r.ncols(), s.rows() * s.cols());
        prop_assert_eq!(r.nnz_per_row(), (s.degree_u() + 1) * (s.degree_v() + 1));
        let via_r = r.mul(s.control_points());
        let dense = r.to_dense();
        for (k, &[u, v]) in params.iter().enumerate() {
            let p = s.eval(u, v).unwrap();
            prop_assert!((via_r[k] - p).norm() < 1e-12 * (1.0 + p.coords.norm()));
            let row_sum: f64 = dense.row(k).iter().sum();
            prop_assert!((row_sum - 1.0).abs() < 1e-13);
            let (cols, _) = r.row(k);
            prop_assert!(cols.windows(2).all(|w| w[0] < w[1]), "columns increase");
        }
    }
}

#[test]
fn bad_parameters_are_errors_not_panics() {
    let k = KnotVector::clamped_uniform(3, 6, 0.0, 1.0).unwrap();
    let s = random_surface(k.clone(), k, 1);
    assert!(matches!(
        s.eval(f64::NAN, 0.5),
        Err(BSplineError::NonFiniteParameter { .. })
    ));
    assert!(matches!(
        s.eval(0.5, f64::INFINITY),
        Err(BSplineError::NonFiniteParameter { .. })
    ));
    assert!(matches!(
        s.eval(1.5, 0.5),
        Err(BSplineError::ParameterOutOfDomain {
            direction: Direction::U,
            ..
        })
    ));
    assert!(matches!(
        s.eval(0.5, -0.1),
        Err(BSplineError::ParameterOutOfDomain {
            direction: Direction::V,
            ..
        })
    ));
    assert!(s.derivatives(f64::NAN, 0.0, 2).is_err());
    assert!(s.normal(0.0, 2.0).is_err());
    assert!(s.eval_grid(&[0.0, 0.5], &[0.2, f64::NAN]).is_err());
    assert!(s.eval_grid(&[1.2], &[0.2]).is_err());
    assert!(s.eval_many(&[[0.1, 0.1], [0.2, -3.0]]).is_err());
    assert!(s.basis_matrix(&[[f64::NAN, 0.0]]).is_err());
    let msg = s.eval(1.5, 0.5).unwrap_err().to_string();
    assert!(msg.contains("u = 1.5") && msg.contains("[0, 1]"), "{msg}");
}

#[test]
fn bad_grids_are_errors_not_panics() {
    let k = KnotVector::clamped_uniform(2, 4, 0.0, 1.0).unwrap();
    let pts = |n: usize| vec![Point3::origin(); n];
    assert!(matches!(
        BSplineSurface::new(k.clone(), k.clone(), 4, 5, pts(20)),
        Err(BSplineError::GridShapeMismatch { expected_cols: 4, .. })
    ));
    assert!(matches!(
        BSplineSurface::new(k.clone(), k.clone(), 4, 4, pts(15)),
        Err(BSplineError::ControlPointCount { got: 15, .. })
    ));
    let mut bad = pts(16);
    bad[6] = Point3::new(0.0, f64::NAN, 0.0);
    assert!(matches!(
        BSplineSurface::new(k.clone(), k, 4, 4, bad),
        Err(BSplineError::NonFiniteControlPoint { row: 1, col: 2 })
    ));
}

#[test]
fn collapsed_edge_has_no_normal() {
    // All control points of row 0 coincide: F_v vanishes along u = 0.
    let k = KnotVector::clamped_uniform(2, 3, 0.0, 1.0).unwrap();
    let grid = (0..9)
        .map(|i| {
            if i < 3 {
                Point3::origin()
            } else {
                Point3::new((i / 3) as f64, (i % 3) as f64, 0.0)
            }
        })
        .collect();
    let s = BSplineSurface::new(k.clone(), k, 3, 3, grid).unwrap();
    assert_eq!(s.normal(0.0, 0.5).unwrap(), None);
    let inside = s.normal(0.5, 0.5).unwrap().expect("regular inside");
    assert!((inside.z.abs() - 1.0).abs() < 1e-12);
}

#[test]
fn empty_grid_evaluation_is_empty() {
    let k = KnotVector::clamped_uniform(1, 2, 0.0, 1.0).unwrap();
    let s = random_surface(k.clone(), k, 5);
    assert!(s.eval_grid(&[], &[0.5]).unwrap().is_empty());
    assert!(s.eval_many(&[]).unwrap().is_empty());
}
