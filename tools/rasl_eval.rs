//! Measures RASL's settings on synthetic batches with known truth:
//!
//! * **copies**: one frontal photo of the reference face warped by 12 known random affine maps
//!   (rotation ±8°, scales 0.92–1.08, shear ±0.06, shifts ±6 px), landmarks with 1.5 px noise,
//!   three copies occluded; the figure is the worst disagreement between copies, in window
//!   pixels, of where the true landmarks land after alignment (0 = perfect);
//! * **poses**: 35 photos under yaw ±30°, pitch ±15°, roll ±10°; the figure is the RMS distance
//!   (canonical units, 50 = eye distance) between the frontal structure and the true frontal
//!   `x, y` (the points-only Procrustes figure is printed for comparison), and the time.
//!
//! Run: `cargo run --release --example rasl_eval`; the default run's pictures go to
//! `target/rasl-eval/`.

#[path = "common/mod.rs"]
mod common;

use common::Lcg;
use nalgebra::{Matrix2x3, Point2};
use splineface::Real;
use splineface::align::{
    GreyImage, PhotoPoints, RaslOptions, RaslPhoto, apply_affine, procrustes_frontal, rasl_frontal,
};
use splineface::face::{Deformation, FaceSurface, MeshOptions};
use splineface::geometry::{affine, homogeneous};
use splineface::reference::ReferenceFace;
use splineface::render::{View, synthetic_photo};
use std::borrow::Cow;

fn main() -> anyhow::Result<()> {
    let r = ReferenceFace::embedded();
    let face = FaceSurface::deform(r, r.structure(), Deformation::Affine)?;
    let mesh = face.mesh(&MeshOptions { spacing: 1.0 })?.mesh;
    let base =
        synthetic_photo(&mesh, r.structure(), &View::front(), 200, 240, 0.12).map_err(anyhow::Error::msg)?;

    // The copies batch.
    let mut rng = Lcg(5);
    let mut copies = Vec::new();
    let mut maps = Vec::new();
    for i in 0..12 {
        let angle: Real = rng.uniform(-8.0, 8.0).to_radians();
        let (sx, sy, shear) = (
            rng.uniform(0.92, 1.08),
            rng.uniform(0.92, 1.08),
            rng.uniform(-0.06, 0.06),
        );
        let linear = nalgebra::Matrix2::new(angle.cos(), -angle.sin(), angle.sin(), angle.cos())
            * nalgebra::Matrix2::new(sx, shear, 0.0, sy);
        let centre = nalgebra::Vector2::new(100.0, 120.0);
        let t =
            centre + nalgebra::Vector2::new(rng.uniform(-6.0, 6.0), rng.uniform(-6.0, 6.0)) - linear * centre;
        let m = affine(&linear, &t);
        let mut data = Vec::with_capacity(200 * 240);
        for y in 0..240 {
            for x in 0..200 {
                let p = apply_affine(&m, &Point2::new(x as Real, y as Real));
                let mut v = base.image.sample(base.image.data(), p.x, p.y);
                if i % 4 == 1 && (120..144).contains(&x) && (110..134).contains(&y) {
                    v = if (x / 4 + y / 4) % 2 == 0 { 1.0 } else { 0.0 };
                }
                data.push(v);
            }
        }
        let inverse = homogeneous(&m)
            .try_inverse()
            .expect("invertible")
            .fixed_view::<2, 3>(0, 0)
            .into_owned();
        let points: Vec<Point2<Real>> = base
            .points
            .iter()
            .map(|p| {
                apply_affine(&inverse, p) + nalgebra::Vector2::new(1.5 * rng.gaussian(), 1.5 * rng.gaussian())
            })
            .collect();
        copies.push(RaslPhoto {
            image: Cow::Owned(GreyImage::new(200, 240, data)?),
            points: PhotoPoints::new(format!("copy{i}"), points)?,
        });
        maps.push(m);
    }
    // The poses batch.
    let mut poses = Vec::new();
    for k in 0..35 {
        let view = View::from_yaw_pitch_roll_degrees(
            rng.uniform(-30.0, 30.0),
            rng.uniform(-15.0, 15.0),
            rng.uniform(-10.0, 10.0),
        );
        let photo =
            synthetic_photo(&mesh, r.structure(), &view, 240, 280, 0.12).map_err(anyhow::Error::msg)?;
        let points = photo
            .points
            .iter()
            .map(|p| p + nalgebra::Vector2::new(1.5 * rng.gaussian(), 1.5 * rng.gaussian()))
            .collect();
        poses.push(RaslPhoto {
            image: Cow::Owned(photo.image),
            points: PhotoPoints::new(format!("p{k}"), points)?,
        });
    }
    let points_only: Vec<PhotoPoints> = poses.iter().map(|p| p.points.clone()).collect();
    let procrustes = procrustes_frontal(&points_only)?;
    let truth: Vec<Point2<Real>> = r.structure().iter().map(|p| Point2::new(p.x, p.y)).collect();
    let rms = |a: &[Point2<Real>], b: &[Point2<Real>]| {
        (a.iter().zip(b).map(|(p, q)| (p - q).norm_squared()).sum::<Real>() / a.len() as Real).sqrt()
    };
    println!(
        "poses batch: the points-only Procrustes frontal structure is {:.3} units RMS from the true frontal x, y",
        rms(&procrustes.points, &truth)
    );

    println!(
        "| ρ | inner tol | copies: worst px before → after | outer/inner | s | poses: from true frontal (units) | outer/inner | s | ms/inner |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    for (rho, tolerance) in [(1.25, 1e-7), (1.5, 1e-7), (2.0, 1e-7), (1.25, 1e-5)] {
        let options = RaslOptions {
            rho,
            inner_tolerance: tolerance,
            ..RaslOptions::default()
        };
        let result = rasl_frontal(&copies, &options)?;
        let spread = |warps: &[Matrix2x3<Real>]| -> Real {
            let mut worst: Real = 0.0;
            for k in 9..40 {
                let seen: Vec<Point2<Real>> = (0..copies.len())
                    .map(|i| {
                        let composed = homogeneous(&maps[i]) * homogeneous(&warps[2 * i]);
                        let inverse = composed
                            .try_inverse()
                            .expect("invertible")
                            .fixed_view::<2, 3>(0, 0)
                            .into_owned();
                        apply_affine(&inverse, &base.points[k])
                    })
                    .collect();
                for i in 0..seen.len() {
                    for j in 0..i {
                        worst = worst.max((seen[i] - seen[j]).norm());
                    }
                }
            }
            worst
        };
        if rho == RaslOptions::default().rho && tolerance == RaslOptions::default().inner_tolerance {
            // The pictures of the default run, for people to look at.
            let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("target/rasl-eval");
            std::fs::create_dir_all(&dir)?;
            for (name, bytes) in result.images().map_err(anyhow::Error::msg)? {
                std::fs::write(dir.join(format!("copies-{name}")), bytes)?;
            }
        }
        let pose_result = rasl_frontal(&poses, &options)?;
        if rho == RaslOptions::default().rho && tolerance == RaslOptions::default().inner_tolerance {
            let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("target/rasl-eval");
            for (name, bytes) in pose_result.images().map_err(anyhow::Error::msg)? {
                std::fs::write(dir.join(format!("poses-{name}")), bytes)?;
            }
        }
        let difference = rms(&pose_result.frontal.points, &truth);
        println!(
            "| {rho} | {tolerance:e} | {:.2} → {:.3} | {}/{} | {:.2} | {:.3} | {}/{} | {:.2} | {:.2} |",
            spread(&result.initial_warps),
            spread(&result.warps),
            result.objective.len(),
            result.inner_iterations,
            result.seconds,
            difference,
            pose_result.objective.len(),
            pose_result.inner_iterations,
            pose_result.seconds,
            1e3 * pose_result.inner_seconds / pose_result.inner_iterations as Real,
        );
    }
    Ok(())
}
