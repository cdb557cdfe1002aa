//! Speed of the refinement by the photos' pixels (issue 18; target ≤ 3 s for 8 photos on the
//! machine's 2 cores): 8 photos (yaw −40° to 40°, 420 × 520 pixels, eye distance about 100
//! pixels, a light from another side in each) of a member of the embedded reference's face
//! space (60 identity modes), rendered by the project's renderer; `FaceSpace::refine_photos`
//! with the default options after the landmark fit, beside the landmark fit itself (the
//! stage it follows) in the same run.
//!
//! Run: `cargo bench --bench refine`.

use criterion::{Criterion, criterion_group, criterion_main};
use nalgebra::{Point2, Point3, Vector3};
use splineface::align::{GreyImage, PhotoPoints};
use splineface::face::{MeshOptions, PhotoFitOptions, RefineOptions, RefineView};
use splineface::mesh::{TextureCoordinates, TriangleMesh};
use splineface::reference::ReferenceFace;
use splineface::render::{Camera, ColourMap, Lighting, PhotoLook, render_photo};
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let reference = ReferenceFace::embedded().as_seen_in_photos().into_owned();
    let space = reference.face_space().expect("the default carries a face space");
    let truth: Vec<f64> = (0..space.mode_count())
        .map(|k| {
            if k < 10 {
                [1.0, -1.0][k % 2] * space.sigma()[k]
            } else {
                0.0
            }
        })
        .collect();
    let face = space.face(&reference, &truth).unwrap();
    let clipped = face.mesh(&MeshOptions::default()).unwrap();
    let triangles = clipped.mesh.triangles().to_vec();
    let mesh = TriangleMesh::new(clipped.mesh.positions().to_vec(), triangles.clone())
        .unwrap()
        .with_texture(TextureCoordinates {
            uvs: clipped.params.clone(),
            triangles,
        })
        .unwrap();
    // A texture with detail at several scales: stripes and checks in (u, v).
    let texture = image::RgbImage::from_fn(256, 256, |x, y| {
        let (u, v) = (x as f64 / 255.0, y as f64 / 255.0);
        let value = 0.55
            + 0.2 * (40.0 * u + 3.0 * (17.0 * v).sin()).sin()
            + 0.15 * (33.0 * v + 2.0 * (11.0 * u).cos()).sin();
        let c = (255.0 * value.clamp(0.05, 0.95)) as u8;
        image::Rgb([c, (0.8 * c as f64) as u8, (0.7 * c as f64) as u8])
    });
    let map = ColourMap::new(&texture);
    let structure = space.structure(&truth).unwrap();
    let mut images = Vec::new();
    let mut views = Vec::new();
    for k in 0..8 {
        let yaw = -40.0 + 80.0 * k as f64 / 7.0;
        let camera = Camera::looking_at_head(
            [yaw, 5.0, 0.0],
            &Point3::new(0.0, -20.0, 10.0),
            700.0,
            1400.0,
            (420, 520),
        );
        let lighting = Lighting::matte(Vector3::new((k as f64).sin(), 0.3, 1.0), 0.6, 0.4);
        let look = PhotoLook {
            background_top: [0.3; 3],
            background_bottom: [0.5; 3],
            blur: 0.5,
            seed: k,
            supersampling: 1,
            ..PhotoLook::default()
        };
        let photo = render_photo(&mesh, &map, &camera, &lighting, &look).unwrap();
        images.push(GreyImage::from_dynamic(&image::DynamicImage::ImageRgb8(photo)).unwrap());
        let points: Vec<Point2<f64>> = structure.iter().map(|p| camera.project(p).unwrap()).collect();
        views.push(PhotoPoints::new(format!("photo {k}"), points).unwrap().y_up());
    }
    let weights = splineface::structure::contour_weighted(0.1);
    let fit_options = PhotoFitOptions {
        noise: splineface::pipeline::Shape::DEFAULT_NOISE,
        expressions: None,
        outline: false,
        lips: splineface::face::LIP_WEIGHT,
    };
    let fit = space.fit_photos(&views, &weights, &fit_options).unwrap();
    let refine_views: Vec<RefineView> = images
        .iter()
        .zip(&views)
        .map(|(image, points)| RefineView { image, points })
        .collect();
    let options = RefineOptions::default();
    let mut group = c.benchmark_group("refinement, 8 photos");
    group.sample_size(10);
    group.bench_function("landmark fit (the stage before)", |b| {
        b.iter(|| {
            space
                .fit_photos(black_box(&views), &weights, &fit_options)
                .unwrap()
        })
    });
    group.bench_function("refine_photos (default options)", |b| {
        b.iter(|| {
            space
                .refine_photos(&reference, black_box(&fit), &refine_views, &weights, &options)
                .unwrap()
        })
    });
    let no_field = RefineOptions {
        field: false,
        ..RefineOptions::default()
    };
    group.bench_function("refine_photos (no displacement field)", |b| {
        b.iter(|| {
            space
                .refine_photos(&reference, black_box(&fit), &refine_views, &weights, &no_field)
                .unwrap()
        })
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
