//! Measures the surface stage's two deformations on ICT-FaceKit identities with known truth:
//! each subject's true 40-point structure (optionally with Gaussian noise, as a depth estimate
//! would have) deforms the embedded reference, and the clipped result is compared with the
//! subject's own surface. Prints, per deformation, the mean over subjects of the mean, RMS and
//! 90th-percentile height error `|Δz|` over the clipped face (canonical units, 50 between the eye
//! centres; ×1.26 for millimetres) and the error at the 40 points.
//!
//! Run: `cargo run --release --example surface_eval [-- SUBJECTS [ICT_DIR]]` (default 20 and
//! `../shared/data/ict-face`).

#[path = "common/mod.rs"]
mod common;

use anyhow::Result;
use common::{Ict, Lcg};
use nalgebra::{Point2, Point3};
use splineface::Real;
use splineface::face::{Deformation, FaceSurface, MeshOptions};
use splineface::mesh::{Raster, front_heights};
use splineface::reference::ReferenceFace;

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let subjects: u64 = args.first().map(|a| a.parse()).transpose()?.unwrap_or(20);
    let dir = args.get(1).map_or_else(Ict::default_dir, Into::into);
    let ict = Ict::load(&dir)?;
    let reference = ReferenceFace::embedded();
    let modes: Vec<(String, Option<Deformation>)> =
        std::iter::once(("mean face (reference)".to_owned(), None))
            .chain(std::iter::once((
                "affine (paper)".to_owned(),
                Some(Deformation::Affine),
            )))
            .chain([1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2].into_iter().map(|s| {
                (
                    format!("local λ={s:e}"),
                    Some(Deformation::Local { smoothness: s }),
                )
            }))
            .collect();
    println!("{subjects} ICT identities (w ~ N(0,1)); |Δz| in canonical units (50 = eye distance)");
    for noise in [0.0, 0.5, 1.0] {
        println!("\nstructure noise σ = {noise} units per coordinate\n");
        println!("| deformation | mean |Δz| | RMS |Δz| | p90 |Δz| | point RMS |");
        println!("|---|---|---|---|---|");
        let mut sums = vec![[0.0; 4]; modes.len()];
        for seed in 0..subjects {
            let mut rng = Lcg(7000 + seed);
            let subject = ict.random_subject(&mut rng, 1.0)?;
            let noisy: Vec<Point3<Real>> = subject
                .structure
                .iter()
                .map(|p| p + noise * nalgebra::Vector3::from_fn(|_, _| rng.gaussian()))
                .collect();
            let raster = Raster {
                origin: Point2::new(-100.0, -140.0),
                spacing: 1.0,
                width: 201,
                height: 221,
            };
            let truth = front_heights(&subject.mesh, &raster);
            for (m, (_, mode)) in modes.iter().enumerate() {
                let face = match mode {
                    None => FaceSurface::deform(reference, reference.structure(), Deformation::Affine)?,
                    Some(mode) => FaceSurface::deform(reference, &noisy, *mode)?,
                };
                let mesh = face.mesh(&MeshOptions::default())?;
                let heights = front_heights(&mesh.mesh, &raster);
                let mut errors: Vec<Real> = heights
                    .iter()
                    .zip(&truth)
                    .filter(|(a, b)| a.is_finite() && b.is_finite())
                    .map(|(a, b)| (a - b).abs())
                    .collect();
                errors.sort_by(Real::total_cmp);
                let n = errors.len() as Real;
                let mean = errors.iter().sum::<Real>() / n;
                let rms = (errors.iter().map(|e| e * e).sum::<Real>() / n).sqrt();
                let p90 = errors[(0.9 * n) as usize];
                let params: Vec<[Real; 2]> = face.structure_params().iter().map(|p| [p.x, p.y]).collect();
                let on_surface = face.surface().eval_many(&params)?;
                let point_rms = (on_surface
                    .iter()
                    .zip(&subject.structure)
                    .map(|(a, b)| (a - b).norm_squared())
                    .sum::<Real>()
                    / 40.0)
                    .sqrt();
                for (s, v) in sums[m].iter_mut().zip([mean, rms, p90, point_rms]) {
                    *s += v / subjects as Real;
                }
            }
        }
        for ((name, _), s) in modes.iter().zip(&sums) {
            println!(
                "| {name} | {:.3} | {:.3} | {:.3} | {:.3} |",
                s[0], s[1], s[2], s[3]
            );
        }
    }
    Ok(())
}
