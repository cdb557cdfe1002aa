//! Speed of the surface stage's queries (issue 6):
//!
//! * a 1024 × 1024 depth map of a ~200k-triangle face mesh: the rasteriser on all cores and on
//!   one, against parry3d ray casting of the same pixels on one core (the baseline);
//!   target ≤ 50 ms;
//! * point-to-mesh distances for near-surface points (random surface points moved along the
//!   normal by up to ±0.2 mm, and by up to ±2 mm as `compare` asks them of a reconstruction
//!   that is off by millimetres) on one core: the crate's `ClosestPoints` against parry3d (the
//!   baseline); target ≥ 2 M queries/s.
//!
//! Run: `cargo bench --bench render`.

#[path = "../tools/common/mod.rs"]
mod common;

use std::hint::black_box;

use common::Lcg;
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use nalgebra::{Affine3, Matrix4, Point3, Vector3};
use parry3d::math::Vec3;
use parry3d::query::{PointQuery, Ray, RayCast};
use parry3d::shape::TriMesh;
use splineface::face::{Deformation, FaceSurface, MeshOptions};
use splineface::mesh::{ClosestPoints, TriangleMesh};
use splineface::reference::ReferenceFace;
use splineface::render::{DepthMap, View, frame_raster};

/// The reference face in millimetres, meshed to about 200k triangles.
fn face_mesh() -> TriangleMesh {
    let r = ReferenceFace::embedded();
    let face = FaceSurface::deform(r, r.structure(), Deformation::Affine).unwrap();
    let mesh = face.mesh(&MeshOptions { spacing: 0.36 }).unwrap().mesh;
    let mm = Affine3::from_matrix_unchecked(Matrix4::new_nonuniform_scaling(&Vector3::repeat(1.26)));
    mesh.transformed(&mm)
}

fn parry(mesh: &TriangleMesh) -> TriMesh {
    let vertices = mesh
        .positions()
        .iter()
        .map(|p| Vec3::new(p.x as f32, p.y as f32, p.z as f32))
        .collect();
    TriMesh::new(vertices, mesh.triangles().to_vec()).unwrap()
}

fn depth_maps(c: &mut Criterion) {
    let mesh = face_mesh();
    println!(
        "mesh: {} vertices, {} triangles",
        mesh.positions().len(),
        mesh.triangles().len()
    );
    let view = View::front();
    let raster = frame_raster(mesh.positions().iter().copied(), &view, 1024, 1024, 0.02).unwrap();
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    let mut group = c.benchmark_group("depth map 1024²");
    group.sample_size(20);
    group.bench_function("rasteriser, all cores", |b| {
        b.iter(|| black_box(DepthMap::render(&mesh, &view, &raster)))
    });
    group.bench_function("rasteriser, one core", |b| {
        b.iter(|| one.install(|| black_box(DepthMap::render(&mesh, &view, &raster))))
    });
    let tri = parry(&mesh);
    let top = mesh.positions().iter().map(|p| p.z).fold(f64::MIN, f64::max) as f32 + 1.0;
    group.sample_size(10);
    group.bench_function("parry3d ray casting, one core (baseline)", |b| {
        b.iter(|| {
            let mut covered = 0usize;
            for j in 0..raster.height {
                for i in 0..raster.width {
                    let p = raster.position(i, j);
                    let ray = Ray::new(Vec3::new(p.x as f32, p.y as f32, top), Vec3::new(0.0, 0.0, -1.0));
                    if tri.cast_local_ray(&ray, f32::MAX, true).is_some() {
                        covered += 1;
                    }
                }
            }
            black_box(covered)
        })
    });
    group.finish();
}

fn distances(c: &mut Criterion) {
    let mesh = face_mesh();
    let tri = parry(&mesh);
    let normals = mesh.normals().unwrap().to_vec();
    let index = ClosestPoints::new(&mesh);
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    // Random surface points moved along the normal by up to ±band mm.
    for band in [0.2, 2.0] {
        let mut rng = Lcg(11);
        let queries: Vec<Point3<f64>> = (0..100_000)
            .map(|_| {
                let k = (rng.next() * mesh.positions().len() as f64) as usize;
                mesh.positions()[k] + normals[k] * rng.uniform(-band, band)
            })
            .collect();
        let mut group = c.benchmark_group(format!("point-to-mesh distance, ±{band} mm"));
        group.throughput(Throughput::Elements(queries.len() as u64));
        group.sample_size(10);
        group.bench_function("parry3d, one core (baseline)", |b| {
            b.iter(|| {
                let mut sum = 0.0f32;
                for q in &queries {
                    sum += tri.distance_to_local_point(Vec3::new(q.x as f32, q.y as f32, q.z as f32), true);
                }
                black_box(sum)
            })
        });
        group.bench_function("ClosestPoints::closest, one core, random order", |b| {
            b.iter(|| {
                let mut sum = 0.0;
                for q in &queries {
                    sum += index.closest(q).distance;
                }
                black_box(sum)
            })
        });
        group.bench_function("ClosestPoints::closest_many, one core", |b| {
            b.iter(|| one.install(|| black_box(index.closest_many(&queries))))
        });
        group.bench_function("ClosestPoints::closest_many, all cores", |b| {
            b.iter(|| black_box(index.closest_many(&queries)))
        });
        group.finish();
    }
}

criterion_group!(benches, depth_maps, distances);
criterion_main!(benches);
