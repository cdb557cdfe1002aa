//! A fixed workload per kernel path, for instruction counts under callgrind (repeatable, unlike
//! wall-clock time on a shared machine). One core: a one-thread rayon pool.
//!
//! Run, for MODE in none, eval, batch, grid, fit-setup, fit:
//! `cargo build --release --example kernel_counts &&
//!  valgrind --tool=callgrind --callgrind-out-file=/dev/null target/release/examples/kernel_counts MODE`
//! and subtract the set-up count (`none`; `fit-setup` for `fit`) from the others, then divide
//! by the work size:
//! eval and batch 200,000 points (cubic 32×32), grid 400 × 400 points, fit 10⁶ samples to a
//! cubic 64×64 grid.

use std::hint::black_box;

use nalgebra::Point3;
use splineface::bspline::{BSplineSurface, KnotVector, SurfaceFit};

fn main() -> anyhow::Result<()> {
    let mode = std::env::args().nth(1).unwrap_or_else(|| "none".into());
    let mut state = 1u64;
    let mut next = move || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    let k32 = KnotVector::clamped_uniform(3, 32, 0.0, 1.0)?;
    let grid = (0..32 * 32)
        .map(|i| Point3::new((i / 32) as f64, (i % 32) as f64, next()))
        .collect();
    let surface = BSplineSurface::new(k32.clone(), k32, 32, 32, grid)?;
    let params: Vec<[f64; 2]> = (0..200_000).map(|_| [next(), next()]).collect();
    let mut out = vec![Point3::origin(); params.len()];
    let lattice: Vec<f64> = (0..400).map(|i| i as f64 / 399.0).collect();
    let mut grid_out = vec![Point3::origin(); 400 * 400];
    let k64 = KnotVector::clamped_uniform(3, 64, 0.0, 1.0)?;
    let (fit_params, fit_points): (Vec<[f64; 2]>, Vec<Point3<f64>>) = if mode.starts_with("fit") {
        (0..1_000_000)
            .map(|_| {
                let (u, v) = (next(), next());
                ([u, v], Point3::new(u, v, u * v))
            })
            .unzip()
    } else {
        (Vec::new(), Vec::new())
    };
    match mode.as_str() {
        "none" | "fit-setup" => {}
        "eval" => {
            let mut acc = 0.0;
            for &[u, v] in &params {
                acc += surface.eval(u, v)?.z;
            }
            black_box(acc);
        }
        "batch" => pool.install(|| surface.eval_many_into(&params, &mut out))?,
        "grid" => pool.install(|| surface.eval_grid_into(&lattice, &lattice, &mut grid_out))?,
        "fit" => {
            black_box(
                pool.install(|| SurfaceFit::new(k64.clone(), k64.clone()).fit(&fit_params, &fit_points))?,
            );
        }
        other => anyhow::bail!("unknown mode {other:?}: use none, eval, batch, grid, fit-setup or fit"),
    }
    black_box((&out, &grid_out));
    Ok(())
}
