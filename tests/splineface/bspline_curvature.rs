//! Curvatures against the closed forms of a height field `z = f(x, y)` that a bicubic holds
//! exactly, and the principal directions against their definition.

use nalgebra::{Point3, Vector3};
use splineface::Real;
use splineface::bspline::{BSplineSurface, KnotVector, SurfaceFit};

use super::common::Lcg;

/// `f`, its first and second derivatives: a cubic polynomial.
fn f(x: Real, y: Real) -> [Real; 6] {
    [
        0.3 * x * x - 0.2 * x * y + 0.1 * y * y + 0.05 * x * x * x - 0.04 * x * y * y,
        0.6 * x - 0.2 * y + 0.15 * x * x - 0.04 * y * y,
        -0.2 * x + 0.2 * y - 0.08 * x * y,
        0.6 + 0.3 * x,
        -0.2 - 0.08 * y,
        0.2 - 0.08 * x,
    ]
}

/// The height field as a bicubic Bézier patch over [0, 1]² with (x, y) = (u, v), by an exact
/// least-squares fit.
fn height_field() -> BSplineSurface {
    let mut params = Vec::new();
    let mut points = Vec::new();
    for i in 0..12 {
        for j in 0..12 {
            let (u, v) = (i as Real / 11.0, j as Real / 11.0);
            params.push([u, v]);
            points.push(Point3::new(u, v, f(u, v)[0]));
        }
    }
    let k = KnotVector::clamped_uniform(3, 4, 0.0, 1.0).unwrap();
    let fit = SurfaceFit::new(k.clone(), k).fit(&params, &points).unwrap();
    assert!(fit.report.max < 1e-12);
    fit.surface
}

#[test]
fn curvatures_match_the_closed_forms_of_a_height_field() {
    let s = height_field();
    let mut rng = Lcg(3);
    for _ in 0..200 {
        let (x, y) = (rng.next(), rng.next());
        let [_, fx, fy, fxx, fxy, fyy] = f(x, y);
        let w = 1.0 + fx * fx + fy * fy;
        let gaussian = (fxx * fyy - fxy * fxy) / (w * w);
        let mean =
            ((1.0 + fy * fy) * fxx - 2.0 * fx * fy * fxy + (1.0 + fx * fx) * fyy) / (2.0 * w.powf(1.5));
        let c = s.curvature(x, y).unwrap().unwrap();
        assert!(
            (c.gaussian - gaussian).abs() < 1e-10,
            "{} {}",
            c.gaussian,
            gaussian
        );
        assert!((c.mean - mean).abs() < 1e-10, "{} {}", c.mean, mean);
        let (k1, k2) = c.principal;
        assert!(k1 >= k2);
        assert!((k1 * k2 - gaussian).abs() < 1e-10 && (0.5 * (k1 + k2) - mean).abs() < 1e-10);
        let expected_normal = Vector3::new(-fx, -fy, 1.0) / w.sqrt();
        assert!((c.normal.into_inner() - expected_normal).norm() < 1e-12);
        // The directions: unit, tangent, orthogonal, and the normal curvature along each is
        // its principal curvature (κₙ(t) = II(t)/I(t), t = a F_u + b F_v).
        let d = s.derivatives(x, y, 2).unwrap();
        let (fu, fv) = (d.get(1, 0), d.get(0, 1));
        let normal_curvature = |t: &Vector3<Real>| {
            // Solve t = a F_u + b F_v in the tangent plane.
            let (e, ff, g) = (fu.dot(&fu), fu.dot(&fv), fv.dot(&fv));
            let (tu, tv) = (t.dot(&fu), t.dot(&fv));
            let det = e * g - ff * ff;
            let (a, b) = ((g * tu - ff * tv) / det, (e * tv - ff * tu) / det);
            let n = c.normal.into_inner();
            let second =
                a * a * d.get(2, 0).dot(&n) + 2.0 * a * b * d.get(1, 1).dot(&n) + b * b * d.get(0, 2).dot(&n);
            let first = a * a * e + 2.0 * a * b * ff + b * b * g;
            second / first
        };
        let (t1, t2) = (c.directions.0.into_inner(), c.directions.1.into_inner());
        assert!(t1.dot(&c.normal).abs() < 1e-12 && t2.dot(&c.normal).abs() < 1e-12);
        assert!(t1.dot(&t2).abs() < 1e-9);
        assert!((normal_curvature(&t1) - k1).abs() < 1e-9);
        assert!((normal_curvature(&t2) - k2).abs() < 1e-9);
    }
}

#[test]
fn a_plane_is_flat_and_a_collapsed_edge_has_no_curvature() {
    let k = KnotVector::clamped_uniform(3, 4, 0.0, 1.0).unwrap();
    let plane: Vec<Point3<Real>> = (0..16)
        .map(|i| Point3::new((i / 4) as Real, (i % 4) as Real, 0.5 * (i / 4) as Real))
        .collect();
    let s = BSplineSurface::new(k.clone(), k.clone(), 4, 4, plane).unwrap();
    let c = s.curvature(0.3, 0.7).unwrap().unwrap();
    assert_eq!((c.gaussian, c.mean), (0.0, 0.0));
    assert_eq!(c.principal, (0.0, 0.0));
    // Every direction is principal on a plane: F_u's and its orthogonal one.
    assert!(c.directions.0.dot(&c.directions.1).abs() < 1e-12);
    // The row u = 0 collapsed to one point: no normal there, no curvature.
    let collapsed: Vec<Point3<Real>> = (0..16)
        .map(|i| {
            if i / 4 == 0 {
                Point3::origin()
            } else {
                Point3::new((i / 4) as Real, (i % 4) as Real, 0.0)
            }
        })
        .collect();
    let s = BSplineSurface::new(k.clone(), k, 4, 4, collapsed).unwrap();
    assert!(s.curvature(0.0, 0.5).unwrap().is_none());
    assert!(s.curvature(1.5, 0.5).is_err());
}

/// A surface of degrees `(p, q)` over `[0, 2]²` with random heights on a `rows × cols`
/// grid, its knots uneven (a double knot in `u` when there is room).
fn random_surface(p: usize, q: usize, rows: usize, cols: usize, seed: u64) -> BSplineSurface {
    let mut rng = Lcg(seed);
    let mut knots = |degree: usize, count: usize, double: bool| {
        let inner = count - degree - 1;
        let mut at: Vec<Real> = (1..=inner)
            .map(|i| 2.0 * (i as Real + 0.3 * rng.uniform(-1.0, 1.0)) / (inner + 1) as Real)
            .collect();
        if double && inner >= 2 {
            at[1] = at[0];
        }
        let mut all = vec![0.0; degree + 1];
        all.extend(at);
        all.extend(vec![2.0; degree + 1]);
        KnotVector::new(degree, all).unwrap()
    };
    let ku = knots(p, rows, true);
    let kv = knots(q, cols, false);
    let grid = (0..rows * cols)
        .map(|i| Point3::new((i / cols) as Real, (i % cols) as Real, rng.uniform(-1.0, 1.0)))
        .collect();
    BSplineSurface::new(ku, kv, rows, cols, grid).unwrap()
}

/// The grid's values are the pointwise ones to the last bit (normal, curvatures and
/// directions), for every degree from 1 to 5 either way, uneven and repeated knots, the
/// domain's ends, and where a collapsed edge leaves no normal; and the pointwise normal is
/// [`BSplineSurface::normal`]'s.
#[test]
fn a_curvature_grid_is_the_curvature_at_each_parameter() {
    let (us, vs) = (
        [0.0, 0.3, 0.61, 1.1, 1.37, 2.0],
        [0.0, 0.5, 1.0 / 3.0, 1.7, 1.9, 2.0],
    );
    for (p, q) in [(1, 1), (2, 3), (3, 3), (3, 2), (5, 4), (1, 5)] {
        for seed in 0..3 {
            let surface = random_surface(p, q, 8, 7, 10 * seed + p as u64);
            let map = surface.curvature_grid(&us, &vs).unwrap();
            assert_eq!(map.len(), us.len() * vs.len());
            for (i, &u) in us.iter().enumerate() {
                for (j, &v) in vs.iter().enumerate() {
                    let one = surface.curvature(u, v).unwrap();
                    assert_eq!(map[i * vs.len() + j], one, "degrees {p}, {q} at ({u}, {v})");
                    assert_eq!(
                        one.map(|c| c.normal),
                        surface.normal(u, v).unwrap(),
                        "degrees {p}, {q} at ({u}, {v})"
                    );
                }
            }
        }
    }
    // The row u = 0 collapsed to one point: no curvature along it, in the grid as alone.
    let k = KnotVector::clamped_uniform(3, 5, 0.0, 2.0).unwrap();
    let collapsed = (0..25)
        .map(|i| {
            if i / 5 == 0 {
                Point3::origin()
            } else {
                Point3::new((i / 5) as Real, (i % 5) as Real, 0.1 * (i % 3) as Real)
            }
        })
        .collect();
    let surface = BSplineSurface::new(k.clone(), k, 5, 5, collapsed).unwrap();
    let map = surface.curvature_grid(&[0.0, 1.0], &vs).unwrap();
    for (j, &v) in vs.iter().enumerate() {
        assert!(map[j].is_none());
        assert_eq!(map[vs.len() + j], surface.curvature(1.0, v).unwrap());
        assert!(map[vs.len() + j].is_some());
    }
    assert!(surface.curvature_grid(&[0.5], &[2.5]).is_err());
    assert!(surface.curvature_grid(&[-0.5], &[1.0]).is_err());
    assert!(surface.curvature_grid(&[], &vs).unwrap().is_empty());
}
