//! Measures the depth stage on synthetic scenes with known truth: a face that is not the
//! reference (deeper, longer, slightly asymmetric) seen under random poses (yaw ±60°, pitch
//! ±25°, roll ±15°) with Gaussian landmark noise, for each `FrontalFreedom` mode, with and
//! without the similarity constraint. Prints depth RMS error (canonical units, 50 between the
//! eye centres), depth correlation, mean pose error, iterations and time per estimate.
//!
//! Run: `cargo run --release --example depth_eval [-- PHOTOS SCENES]` (defaults 12 and 20).

#[path = "common/mod.rs"]
mod common;

use std::time::Instant;

use common::Lcg;

use nalgebra::{Point2, Point3};
use splineface::Real;
use splineface::align::{PhotoPoints, procrustes_frontal};
use splineface::depth::{DepthOptions, FrontalFreedom, Pose, StructurePrior, estimate_depth};
use splineface::reference::ReferenceFace;
use splineface::structure::{LEFT_EYE_CENTRE, RIGHT_EYE_CENTRE, correlation};

fn truth() -> Vec<Point3<Real>> {
    ReferenceFace::embedded()
        .structure()
        .iter()
        .enumerate()
        .map(|(k, p)| {
            if k == RIGHT_EYE_CENTRE || k == LEFT_EYE_CENTRE {
                return *p;
            }
            let bump = 2.0 * (p.x / 15.0).sin() * (p.y / 30.0).cos();
            Point3::new(p.x, 1.08 * p.y, 1.25 * p.z + bump)
        })
        .collect()
}

fn free(points: &[Point3<Real>]) -> Vec<Real> {
    points
        .iter()
        .enumerate()
        .filter(|&(k, _)| k != RIGHT_EYE_CENTRE && k != LEFT_EYE_CENTRE)
        .map(|(_, p)| p.z)
        .collect()
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let photos: usize = args.first().map(|a| a.parse()).transpose()?.unwrap_or(12);
    let scenes: u64 = args.get(1).map(|a| a.parse()).transpose()?.unwrap_or(20);
    let truth = truth();
    let prior = StructurePrior::from_reference(ReferenceFace::embedded());
    println!("{photos} photos a scene, {scenes} scenes; depth RMS in canonical units (50 = eye distance)");
    println!(
        "| noise | frontal | SIM | depth RMS | xy RMS | correlation | pose error (°) | iterations | ms |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    for noise in [0.0, 0.01, 0.02] {
        for frontal_mode in [FrontalFreedom::Fixed, FrontalFreedom::Gauge, FrontalFreedom::Free] {
            for similarity_constraint in [true, false] {
                let options = DepthOptions {
                    frontal: frontal_mode,
                    similarity_constraint,
                    ..DepthOptions::default()
                };
                let (mut rms, mut xy, mut r, mut pose_error, mut iterations, mut seconds) =
                    (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
                for seed in 0..scenes {
                    let mut rng = Lcg(1000 + seed);
                    let poses: Vec<Pose> = (0..photos)
                        .map(|_| {
                            Pose::from_yaw_pitch_roll_degrees(
                                rng.uniform(-60.0, 60.0),
                                rng.uniform(-25.0, 25.0),
                                rng.uniform(-15.0, 15.0),
                                rng.uniform(2.0, 6.0),
                            )
                        })
                        .collect();
                    let views: Vec<PhotoPoints> = poses
                        .iter()
                        .enumerate()
                        .map(|(k, pose)| {
                            let sigma = noise * 50.0 * pose.scale;
                            let pixels = truth
                                .iter()
                                .map(|p| {
                                    let q = pose.project(p);
                                    Point2::new(
                                        320.0 + q.x + sigma * rng.gaussian(),
                                        240.0 - q.y + sigma * rng.gaussian(),
                                    )
                                })
                                .collect();
                            PhotoPoints::new(format!("p{k}"), pixels)
                        })
                        .collect::<Result<_, _>>()?;
                    let start = Instant::now();
                    let frontal = procrustes_frontal(&views)?;
                    let estimate = estimate_depth(&views, &frontal, &prior, &options)?;
                    seconds += start.elapsed().as_secs_f64();
                    let (a, b) = (free(&estimate.structure), free(&truth));
                    rms += (a.iter().zip(&b).map(|(x, y)| (x - y).powi(2)).sum::<Real>() / a.len() as Real)
                        .sqrt();
                    xy += (estimate
                        .structure
                        .iter()
                        .zip(&truth)
                        .map(|(p, q)| (p.x - q.x).powi(2) + (p.y - q.y).powi(2))
                        .sum::<Real>()
                        / 40.0)
                        .sqrt();
                    r += correlation(&a, &b).unwrap_or(0.0);
                    pose_error += estimate
                        .photos
                        .iter()
                        .zip(&poses)
                        .map(|(fit, pose)| fit.pose.angle_to_degrees(pose))
                        .sum::<Real>()
                        / photos as Real;
                    iterations += estimate.iterations as Real;
                }
                let n = scenes as Real;
                println!(
                    "| {:.1}% | {:?} | {} | {:.3} | {:.3} | {:.4} | {:.2} | {:.1} | {:.2} |",
                    noise * 100.0,
                    frontal_mode,
                    if similarity_constraint { "on" } else { "off" },
                    rms / n,
                    xy / n,
                    r / n,
                    pose_error / n,
                    iterations / n,
                    seconds / n * 1e3
                );
            }
        }
    }
    Ok(())
}
