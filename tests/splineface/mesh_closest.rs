//! Closest points on meshes against brute force and parry3d.

use nalgebra::{Point3, Vector3};
use parry3d::math::Vec3;
use parry3d::query::PointQuery;
use proptest::prelude::*;
use splineface::Real;
use splineface::mesh::{ClosestPoints, TriangleMesh, closest_on_triangle};

use crate::common::Lcg;

fn point() -> impl Strategy<Value = Point3<Real>> {
    (-10.0..10.0f64, -10.0..10.0f64, -10.0..10.0f64).prop_map(|(x, y, z)| Point3::new(x, y, z))
}

proptest! {
    /// No point of the triangle (on a fine barycentric grid) is nearer than the answer, and the
    /// answer lies in the triangle's plane, inside it.
    #[test]
    fn closest_on_triangle_is_the_minimum(p in point(), a in point(), b in point(), c in point()) {
        let q = closest_on_triangle(&p, &a, &b, &c);
        let d = (q - p).norm();
        let n = 40;
        for i in 0..=n {
            for j in 0..=n - i {
                let (u, v) = (i as Real / n as Real, j as Real / n as Real);
                let s = a + (b - a) * u + (c - a) * v;
                prop_assert!((s - p).norm() >= d - 1e-9);
            }
        }
        let normal = (b - a).cross(&(c - a));
        if normal.norm() > 1e-6 {
            prop_assert!(normal.normalize().dot(&(q - a)).abs() < 1e-9);
        }
    }
}

fn random_mesh(rng: &mut Lcg, n: usize) -> TriangleMesh {
    // A bumpy sheet plus scattered loose triangles: both near and far queries.
    let mut positions = Vec::new();
    let mut triangles = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            let (x, y) = (i as Real, j as Real);
            positions.push(Point3::new(x, y, (x / 3.0).sin() * 2.0 + rng.uniform(-0.2, 0.2)));
        }
    }
    let at = |i: usize, j: usize| (j * (n + 1) + i) as u32;
    for j in 0..n {
        for i in 0..n {
            triangles.push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
            triangles.push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
        }
    }
    for _ in 0..50 {
        let base = positions.len() as u32;
        let centre = Vector3::new(
            rng.uniform(0.0, n as Real),
            rng.uniform(0.0, n as Real),
            rng.uniform(-8.0, 8.0),
        );
        for _ in 0..3 {
            positions.push(Point3::from(
                centre
                    + Vector3::new(
                        rng.uniform(-1.0, 1.0),
                        rng.uniform(-1.0, 1.0),
                        rng.uniform(-1.0, 1.0),
                    ),
            ));
        }
        triangles.push([base, base + 1, base + 2]);
    }
    TriangleMesh::new(positions, triangles).unwrap()
}

#[test]
fn closest_points_agree_with_brute_force_and_parry() {
    let mut rng = Lcg(21);
    let mesh = random_mesh(&mut rng, 30);
    let index = ClosestPoints::new(&mesh);
    let queries: Vec<Point3<Real>> = (0..2000)
        .map(|_| rng.point_in([-5.0, -5.0, -12.0], [35.0, 35.0, 12.0]))
        .collect();
    let many = index.closest_many(&queries);
    let vertices: Vec<Vec3> = mesh
        .positions()
        .iter()
        .map(|p| Vec3::new(p.x as f32, p.y as f32, p.z as f32))
        .collect();
    let parry = parry3d::shape::TriMesh::new(vertices, mesh.triangles().to_vec()).unwrap();
    for (q, batch) in queries.iter().zip(&many) {
        let brute = (0..mesh.triangles().len())
            .map(|k| {
                let [a, b, c] = mesh.triangle(k);
                (closest_on_triangle(q, &a, &b, &c) - q).norm()
            })
            .fold(Real::INFINITY, Real::min);
        let single = index.closest(q);
        assert!(
            (single.distance - brute).abs() < 1e-12,
            "{q}: {} vs {brute}",
            single.distance
        );
        assert!((batch.distance - brute).abs() < 1e-12);
        assert!(((single.point - q).norm() - single.distance).abs() < 1e-12);
        // The reported triangle holds the point.
        let [a, b, c] = mesh.triangle(single.triangle);
        assert!((closest_on_triangle(q, &a, &b, &c) - single.point).norm() < 1e-9);
        let theirs = parry.distance_to_local_point(Vec3::new(q.x as f32, q.y as f32, q.z as f32), true);
        assert!((Real::from(theirs) - brute).abs() < 1e-4 * (1.0 + brute));
    }
}

/// Meshes of one to twelve triangles (a hierarchy of one leaf, of a root and two leaves, and a
/// little deeper: the query's stack at its smallest sizes) answer as brute force does, with
/// and without the previous query's hint.
#[test]
fn small_meshes_answer_as_brute_force() {
    let mut rng = Lcg(5);
    for n in 1..=12 {
        let positions: Vec<Point3<Real>> = (0..3 * n)
            .map(|_| rng.point_in([-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]))
            .collect();
        let triangles: Vec<[u32; 3]> = (0..n as u32).map(|k| [3 * k, 3 * k + 1, 3 * k + 2]).collect();
        let mesh = TriangleMesh::new(positions, triangles).unwrap();
        let index = ClosestPoints::new(&mesh);
        let queries: Vec<Point3<Real>> = (0..200)
            .map(|_| rng.point_in([-2.0, -2.0, -2.0], [2.0, 2.0, 2.0]))
            .collect();
        let many = index.closest_many(&queries);
        for (q, batch) in queries.iter().zip(&many) {
            let brute = (0..n)
                .map(|k| {
                    let [a, b, c] = mesh.triangle(k);
                    (closest_on_triangle(q, &a, &b, &c) - q).norm()
                })
                .fold(Real::INFINITY, Real::min);
            assert!(
                (index.closest(q).distance - brute).abs() < 1e-12,
                "{n} triangles, {q}"
            );
            assert!((batch.distance - brute).abs() < 1e-12, "{n} triangles, {q}");
        }
    }
}
