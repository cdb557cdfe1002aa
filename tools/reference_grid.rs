//! Measures how well cubic control grids of several sizes and smoothness weights fit a real
//! face scan: the measurement behind the default reference (`ReferenceOptions::default()`,
//! `reference/README.md`).
//!
//! For every grid size and λ it builds the reference exactly as `splineface fit-reference`
//! does (`build_reference`) and reports, over the fitted face region's frontal samples:
//!
//! * the *parametric* residual `|F(u, v) − sample|` (what the least-squares fit minimises; at
//!   steep walls such as the nostrils it measures a vertical drop, not a distance),
//! * the *geometric* residual: the distance from each sample to the surface (tessellated at
//!   1/512 of the domain, parry3d closest-point queries),
//!
//! in canonical units and in millimetres (63 mm between the eye centres), and the fit time.
//!
//! Run: `cargo run --release --example reference_grid -- ../shared/data/ict-face`
//! (the directory holds `neutral_face.obj` and `landmarks68.txt`).

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use nalgebra::Point3;
use parry3d::math::Vec3;
use parry3d::query::PointQuery;
use parry3d::shape::TriMesh;
use splineface::geometry::polygon_contains;
use splineface::landmarks::read_vertex_indices;
use splineface::mesh::{Raster, front_heights, read_mesh};
use splineface::reference::{
    ReferenceFace, ReferenceOptions, ReferenceScan, ReferenceSource, build_reference, face_region,
};
use splineface::structure::{from_ibug68, unify};

/// Millimetres per canonical unit (63 mm between eye centres, 50 units).
const MM: f64 = splineface::face::DEFAULT_EYE_DISTANCE_MM / 50.0;

/// Tessellation of the surface over its whole domain.
fn tessellate(reference: &ReferenceFace, n: usize) -> Result<TriMesh> {
    let ts: Vec<f64> = (0..=n).map(|k| k as f64 / n as f64).collect();
    let grid = reference.surface().eval_grid(&ts, &ts)?;
    let vertices: Vec<Vec3> = grid
        .iter()
        .map(|p| Vec3::new(p.x as f32, p.y as f32, p.z as f32))
        .collect();
    let m = n as u32 + 1;
    let mut indices = Vec::with_capacity(2 * n * n);
    for i in 0..n as u32 {
        for j in 0..n as u32 {
            let a = i * m + j;
            indices.push([a, a + m, a + m + 1]);
            indices.push([a, a + m + 1, a + 1]);
        }
    }
    TriMesh::new(vertices, indices).context("tessellating the surface")
}

fn stats(mut d: Vec<f64>) -> (f64, f64, f64, f64) {
    d.sort_unstable_by(f64::total_cmp);
    let rms = (d.iter().map(|x| x * x).sum::<f64>() / d.len() as f64).sqrt();
    let at = |q: f64| d[((d.len() - 1) as f64 * q).round() as usize];
    (rms, at(0.5), at(0.95), d[d.len() - 1])
}

fn main() -> Result<()> {
    let dir: PathBuf = std::env::args()
        .nth(1)
        .context("usage: reference_grid DIR (with neutral_face.obj and landmarks68.txt)")?
        .into();
    let mesh = read_mesh(&dir.join("neutral_face.obj"))?;
    let indices = read_vertex_indices(&dir.join("landmarks68.txt"), 68, mesh.positions().len())?;
    let ibug: Vec<Point3<f64>> = indices.iter().map(|&i| mesh.positions()[i]).collect();
    let structure = from_ibug68(&ibug)?;
    let (similarity, _) = unify(&structure)?;
    let canonical = mesh.transformed(&nalgebra::convert(similarity));
    let scan = ReferenceScan {
        mesh,
        structure,
        landmarks: None,
        source: ReferenceSource {
            mesh: "neutral_face.obj".into(),
            mesh_fnv1a64: String::new(),
            landmarks: "landmarks68.txt".into(),
            vertices: 0,
            triangles: 0,
        },
    };
    println!(
        "| grid | λ | parametric RMS / median / 95% / max (units) | geometric RMS / median / 95% / max (units) | geometric RMS / 95% / max (mm) | fit time |"
    );
    println!("|---|---|---|---|---|---|");
    for grid in [8usize, 16, 32, 64] {
        for smoothness in [1e-10, 1e-7] {
            let options = ReferenceOptions {
                grid,
                smoothness,
                ..ReferenceOptions::default()
            };
            // Best of three: the wall clock of this VM is noisy.
            let mut best = f64::INFINITY;
            let mut reference = None;
            for _ in 0..3 {
                let start = Instant::now();
                reference = Some(build_reference(std::slice::from_ref(&scan), &options, "")?);
                best = best.min(start.elapsed().as_secs_f64());
            }
            let reference = reference.expect("built three times");
            // The fitted samples, as build_reference makes them.
            let frame = reference.frame();
            let raster = Raster {
                origin: nalgebra::Point2::new(frame.x[0], frame.y[0]),
                spacing: options.sample_spacing,
                width: ((frame.x[1] - frame.x[0]) / options.sample_spacing).floor() as usize + 1,
                height: ((frame.y[1] - frame.y[0]) / options.sample_spacing).floor() as usize + 1,
            };
            let region = face_region(reference.structure(), options.brow_lift, options.fit_margin);
            let heights = front_heights(&canonical, &raster);
            let surface = tessellate(&reference, 512)?;
            let mut parametric = Vec::new();
            let mut geometric = Vec::new();
            for j in 0..raster.height {
                for i in 0..raster.width {
                    let z = heights[j * raster.width + i];
                    let p = raster.position(i, j);
                    if z.is_nan() || !polygon_contains(&region, p) {
                        continue;
                    }
                    let uv = frame.parameters(p.x, p.y);
                    let e = reference
                        .surface()
                        .eval(uv.x.clamp(0.0, 1.0), uv.y.clamp(0.0, 1.0))?;
                    parametric.push((e - Point3::new(p.x, p.y, z)).norm());
                    geometric.push(f64::from(
                        surface.distance_to_local_point(Vec3::new(p.x as f32, p.y as f32, z as f32), false),
                    ));
                }
            }
            let fit = reference.fit();
            let (p_rms, p_med, p_95, p_max) = stats(parametric);
            assert!(
                (p_rms - fit.rms).abs() < 1e-6 * (1.0 + fit.rms),
                "the samples differ from the fit's"
            );
            let (g_rms, g_med, g_95, g_max) = stats(geometric);
            println!(
                "| {grid}×{grid} | {smoothness:e} | {p_rms:.3} / {p_med:.3} / {p_95:.3} / {p_max:.2} | {g_rms:.3} / {g_med:.3} / {g_95:.3} / {g_max:.2} | {:.3} / {:.3} / {:.2} | {:.0} ms |",
                g_rms * MM,
                g_95 * MM,
                g_max * MM,
                best * 1e3
            );
        }
    }
    Ok(())
}
