//! The `splineface` command line.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use splineface::bspline::BSplineSurface;
use splineface::landmarks::{read_landmarks_json, read_vertex_indices};
use splineface::mesh::read_mesh;
use splineface::reference::{ReferenceOptions, ReferenceScan, ReferenceSource, build_reference, fnv1a64};
use splineface::structure::{IBUG_POINT_COUNT, from_ibug68};

/// Smooth 3D faces from uncalibrated photos: B-spline surfaces, meshes and depth maps.
#[derive(Parser)]
#[command(version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Validate a B-spline surface file (JSON) and print its shape, domain and extent.
    Inspect {
        /// The surface file, as written by `BSplineSurface::to_json`.
        surface: PathBuf,
    },
    /// Fit a reference face (control grid, 40-point structure, clip region) to face scans.
    ///
    /// Give one `--landmarks` per `--mesh`, in the same order; several pairs give one reference
    /// from their mean.
    FitReference {
        /// A scan: OBJ, PLY, glTF or GLB.
        #[arg(long = "mesh", required = true)]
        meshes: Vec<PathBuf>,
        /// Its landmarks: 68 vertex indices (a text file, one a line, `#` comments) or a JSON
        /// landmark file with 3D points (68 iBUG or the 40 of the structure).
        #[arg(long = "landmarks", required = true)]
        landmarks: Vec<PathBuf>,
        /// The reference file to write (JSON).
        #[arg(long)]
        out: PathBuf,
        /// Control points along each side of the cubic grid.
        #[arg(long, default_value_t = ReferenceOptions::default().grid)]
        grid: usize,
        /// Thin-plate smoothness weight λ.
        #[arg(long, default_value_t = ReferenceOptions::default().smoothness)]
        smoothness: f64,
        /// Distance between frontal samples, canonical units (50 between the eye centres).
        #[arg(long, default_value_t = ReferenceOptions::default().sample_spacing)]
        sample_spacing: f64,
        /// Free text stored in the file's provenance (licence, origin).
        #[arg(long, default_value = "")]
        note: String,
    },
}

fn main() -> ExitCode {
    match run(Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("error: {error:#}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Inspect { surface } => inspect(&surface),
        Command::FitReference {
            meshes,
            landmarks,
            out,
            grid,
            smoothness,
            sample_spacing,
            note,
        } => {
            let options = ReferenceOptions {
                grid,
                smoothness,
                sample_spacing,
                ..ReferenceOptions::default()
            };
            fit_reference(&meshes, &landmarks, &out, &options, &note)
        }
    }
}

fn inspect(path: &Path) -> Result<()> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let surface = BSplineSurface::from_json(&text)
        .with_context(|| format!("{} is not a valid B-spline surface", path.display()))?;
    let (u0, u1) = surface.domain_u();
    let (v0, v1) = surface.domain_v();
    println!("{}", path.display());
    println!("  degrees      {} × {}", surface.degree_u(), surface.degree_v());
    println!("  control grid {} × {}", surface.rows(), surface.cols());
    println!("  domain       u ∈ [{u0}, {u1}], v ∈ [{v0}, {v1}]");
    let mut lo = surface.control_points()[0];
    let mut hi = lo;
    for p in surface.control_points() {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    println!(
        "  control box  [{:.6}, {:.6}] × [{:.6}, {:.6}] × [{:.6}, {:.6}]",
        lo.x, hi.x, lo.y, hi.y, lo.z, hi.z
    );
    Ok(())
}

fn file_name(path: &Path) -> String {
    path.file_name().map_or_else(
        || path.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}

fn fit_reference(
    meshes: &[PathBuf],
    landmarks: &[PathBuf],
    out: &Path,
    options: &ReferenceOptions,
    note: &str,
) -> Result<()> {
    if meshes.len() != landmarks.len() {
        bail!(
            "{} --mesh but {} --landmarks: give one landmark file per scan",
            meshes.len(),
            landmarks.len()
        );
    }
    let mut scans = Vec::with_capacity(meshes.len());
    for (mesh_path, landmark_path) in meshes.iter().zip(landmarks) {
        let mesh = read_mesh(mesh_path)?;
        let bytes =
            std::fs::read(mesh_path).with_context(|| format!("cannot read {}", mesh_path.display()))?;
        let is_json = landmark_path
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("json"));
        let structure = if is_json {
            read_landmarks_json(landmark_path)?
                .structure_3d()
                .with_context(|| format!("{}: a reference needs 3D landmarks", landmark_path.display()))?
        } else {
            let indices = read_vertex_indices(landmark_path, IBUG_POINT_COUNT, mesh.positions().len())?;
            let points: Vec<_> = indices.iter().map(|&i| mesh.positions()[i]).collect();
            from_ibug68(&points).with_context(|| format!("{}", landmark_path.display()))?
        };
        scans.push(ReferenceScan {
            source: ReferenceSource {
                mesh: file_name(mesh_path),
                mesh_fnv1a64: fnv1a64(&bytes),
                landmarks: file_name(landmark_path),
                vertices: mesh.positions().len(),
                triangles: mesh.triangles().len(),
            },
            mesh,
            structure,
        });
    }
    let start = std::time::Instant::now();
    let reference = build_reference(&scans, options, note)?;
    let elapsed = start.elapsed();
    splineface::io::write_atomically(out, reference.to_json().as_bytes())
        .with_context(|| format!("cannot write {}", out.display()))?;
    let fit = reference.fit();
    let mm = 63.0 / 50.0;
    println!("{}", out.display());
    println!("  scans          {}", scans.len());
    println!(
        "  control grid   {0} × {0} cubic, λ = {1:e}",
        options.grid, options.smoothness
    );
    println!("  samples        {}", fit.samples);
    println!(
        "  residual       RMS {:.4}, median {:.4}, 95% {:.4}, max {:.3} units (RMS {:.3}, max {:.2} mm)",
        fit.rms,
        fit.median,
        fit.p95,
        fit.max,
        fit.rms * mm,
        fit.max * mm
    );
    println!(
        "  worst sample   ({:.1}, {:.1}, {:.1})",
        fit.max_at.x, fit.max_at.y, fit.max_at.z
    );
    println!("  time           {:.0} ms", elapsed.as_secs_f64() * 1e3);
    Ok(())
}
