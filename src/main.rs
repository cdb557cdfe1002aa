//! The `splineface` command line.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use splineface::bspline::BSplineSurface;

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
