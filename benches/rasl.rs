//! Speed of RASL (issue 5): 35 photos (70 columns with their mirrors) of a synthetic face under
//! varied poses (yaw ±30°, pitch ±15°, roll ±10°), 240 × 280 pixels, landmarks with 1.5 px
//! noise, aligned in the default 100 × 120 window. Targets: the whole alignment ≤ 2 s and
//! ≤ 12 ms per inner iteration on this machine. Also the singular-value thresholding of one
//! 12,000 × 70 matrix through the Gram matrix against nalgebra's full SVD (the baseline).
//!
//! Run: `cargo bench --bench rasl`.

#[path = "../tools/common/mod.rs"]
mod common;

use std::borrow::Cow;
use std::hint::black_box;

use common::Lcg;
use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::{DMatrix, Point2};
use splineface::align::{PhotoPoints, RaslOptions, RaslPhoto, rasl_frontal, singular_value_threshold};
use splineface::face::{Deformation, FaceSurface, MeshOptions};
use splineface::reference::ReferenceFace;
use splineface::render::{View, synthetic_photo};

fn photos(count: usize) -> Vec<RaslPhoto<'static>> {
    let r = ReferenceFace::embedded();
    let face = FaceSurface::deform(r, r.structure(), Deformation::Affine).unwrap();
    let mesh = face.mesh(&MeshOptions { spacing: 1.0 }).unwrap().mesh;
    let mut rng = Lcg(17);
    (0..count)
        .map(|k| {
            let view = View::from_yaw_pitch_roll_degrees(
                rng.uniform(-30.0, 30.0),
                rng.uniform(-15.0, 15.0),
                rng.uniform(-10.0, 10.0),
            );
            let photo = synthetic_photo(&mesh, r.structure(), &view, 240, 280, 0.12).unwrap();
            let points: Vec<Point2<f64>> = photo
                .points
                .iter()
                .map(|p| p + nalgebra::Vector2::new(1.5 * rng.gaussian(), 1.5 * rng.gaussian()))
                .collect();
            RaslPhoto {
                image: Cow::Owned(photo.image),
                points: PhotoPoints::new(format!("p{k}"), points).unwrap(),
            }
        })
        .collect()
}

fn rasl(c: &mut Criterion) {
    let batch = photos(35);
    let options = RaslOptions::default();
    let once = rasl_frontal(&batch, &options).unwrap();
    println!(
        "35 photos: {:.2} s, {} outer and {} inner iterations, {:.2} ms per inner iteration",
        once.seconds,
        once.objective.len(),
        once.inner_iterations,
        1e3 * once.inner_seconds / once.inner_iterations as f64
    );
    let mut group = c.benchmark_group("rasl");
    group.sample_size(10);
    group.bench_function("35 photos, whole alignment", |b| {
        b.iter(|| black_box(rasl_frontal(&batch, &options).unwrap()))
    });
    // A batch of `reconstruct`'s usual size (7 photos, 14 columns), whose inner loop is more
    // about passes over memory than about products.
    let small = &batch[..7];
    group.bench_function("7 photos, whole alignment", |b| {
        b.iter(|| black_box(rasl_frontal(small, &options).unwrap()))
    });
    let mut rng = Lcg(3);
    let t = DMatrix::<f32>::from_fn(12_000, 70, |_, _| rng.gaussian() as f32);
    group.bench_function("singular-value thresholding 12000×70, Gram", |b| {
        b.iter(|| black_box(singular_value_threshold(&t, 30.0)))
    });
    let t64 = t.map(f64::from);
    group.bench_function("full SVD 12000×70, nalgebra (baseline)", |b| {
        b.iter(|| black_box(t64.clone().svd(true, true)))
    });
    group.finish();
}

criterion_group!(benches, rasl);
criterion_main!(benches);
