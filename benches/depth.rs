//! Speed of the depth stage on one core: 35 photos of a synthetic face (random poses within yaw
//! ±60°, pitch ±25°, roll ±15°, landmark noise 1% of the eye distance), the whole estimation
//! (points-only frontal structure, then depth). Target (issue 4): ≤ 20 ms. `paper (Fixed)` is
//! the paper's method (frontal `x, y` kept) as the baseline in the same run; `frontal only` is
//! the Procrustes part alone. `face space (60 identity, 53 expression modes)` is the default
//! shape's joint fit of the embedded reference's face space to the same photos, every photo with
//! its own expression (`FaceSpace::fit_photos`; target, issue 17: ≤ 30 ms), beside the depth
//! stage it follows; `face space, neutral` the same fit without expressions, and `with the
//! inner lips' gaps` with each photo's (`FaceSpace::fit_photos_with_lips`, off by default).
//! Measured: 20.5 ms, and 24.5 ms with the gaps.
//!
//! Run: `cargo bench --bench depth`.

use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::Point2;
use splineface::align::{PhotoPoints, procrustes_frontal};
use splineface::depth::{DepthOptions, FrontalFreedom, Pose, StructurePrior, estimate_depth};
use splineface::reference::ReferenceFace;
use std::hint::black_box;

use splineface::random::Lcg;

fn photos(count: usize) -> Vec<PhotoPoints> {
    let mut rng = Lcg(7);
    let reference = ReferenceFace::embedded();
    let face = reference.structure();
    let space = reference.face_space().expect("the default carries a face space");
    let modes = space.mode_count();
    let landmarks = space
        .landmarks(&vec![0.0; modes], &[])
        .unwrap()
        .expect("the default carries its landmarks");
    (0..count)
        .map(|k| {
            let pose = Pose::from_yaw_pitch_roll_degrees(
                rng.uniform(-60.0, 60.0),
                rng.uniform(-25.0, 25.0),
                rng.uniform(-15.0, 15.0),
                rng.uniform(2.0, 6.0),
            );
            // Uniform noise with the standard deviation of 1% of the eye distance.
            let sigma = 0.01 * 50.0 * pose.scale * 3f64.sqrt();
            let mut seen = |p: &nalgebra::Point3<f64>| {
                let q = pose.project(p);
                Point2::new(
                    320.0 + q.x + rng.uniform(-sigma, sigma),
                    240.0 - q.y + rng.uniform(-sigma, sigma),
                )
            };
            let pixels = face.iter().map(&mut seen).collect();
            let inner_lips = landmarks[60..68].iter().map(&mut seen).collect();
            PhotoPoints {
                inner_lips,
                ..PhotoPoints::new(format!("photo{k}"), pixels).unwrap()
            }
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let photos = photos(35);
    let prior = StructurePrior::from_reference(ReferenceFace::embedded());
    let mut group = c.benchmark_group("depth, 35 photos");
    group.bench_function("frontal only", |b| {
        b.iter(|| procrustes_frontal(black_box(&photos)).unwrap())
    });
    for (name, frontal) in [
        ("paper (Fixed)", FrontalFreedom::Fixed),
        ("Gauge", FrontalFreedom::Gauge),
        ("default (Free)", FrontalFreedom::Free),
    ] {
        let options = DepthOptions {
            frontal,
            ..DepthOptions::default()
        };
        group.bench_function(name, |b| {
            b.iter(|| {
                let structure = procrustes_frontal(black_box(&photos)).unwrap();
                estimate_depth(&photos, &structure, &prior, &options).unwrap()
            })
        });
    }
    let reference = ReferenceFace::embedded().as_seen_in_photos();
    let space = reference.face_space().expect("the default carries a face space");
    let views: Vec<Vec<Point2<f64>>> = photos.iter().map(PhotoPoints::y_up).collect();
    let lips: Vec<_> = photos.iter().map(PhotoPoints::lip_gaps_y_up).collect();
    let weights = splineface::structure::contour_weighted(DepthOptions::default().contour_weight);
    let expressive = Some(splineface::face::ExpressionPrior::DEFAULT);
    for (name, expressions, outline, with_lips) in [
        (
            "face space (60 identity, 53 expression modes)",
            expressive,
            true,
            false,
        ),
        ("face space with the inner lips' gaps", expressive, true, true),
        (
            "face space, each photo's expression on its own (the plain prior)",
            Some(splineface::face::ExpressionPrior::independent(
                splineface::face::ExpressionPrior::DEFAULT.sigma,
            )),
            true,
            false,
        ),
        (
            "face space, jaw points fixed (no outline)",
            expressive,
            false,
            false,
        ),
        ("face space, neutral (60 identity modes)", None, true, false),
    ] {
        let options = splineface::face::PhotoFitOptions {
            noise: splineface::pipeline::Shape::DEFAULT_NOISE,
            expressions,
            outline,
            lips: if with_lips {
                splineface::face::LIP_WEIGHT
            } else {
                0.0
            },
        };
        group.bench_function(name, |b| {
            b.iter(|| {
                space
                    .fit_photos_with_lips(black_box(&views), &lips, &weights, &options)
                    .unwrap()
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
