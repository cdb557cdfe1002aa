//! The kernel end to end: sample an analytic face-like height field, fit cubic control grids of
//! several sizes by least squares, and report residuals, timings, a normal and the JSON size.
//!
//! Run: `cargo run --release --example fit_surface`

use std::time::Instant;

use nalgebra::Point3;
use splineface::bspline::{BSplineSurface, KnotVector, SurfaceFit};

/// A smooth stand-in for a face in the canonical frame (eye centres at x = ±25): a Gaussian
/// dome with a nose ridge and two eye sockets, heights in the same units.
fn face(x: f64, y: f64) -> f64 {
    let cap = 45.0 * (-(x / 75.0).powi(2) - (y / 95.0).powi(2)).exp();
    let nose = 22.0 * (-(x / 9.0).powi(2) - ((y + 25.0) / 22.0).powi(2)).exp();
    let sockets = [-25.0, 25.0]
        .iter()
        .map(|c| -6.0 * (-((x - c) / 12.0).powi(2) - (y / 8.0).powi(2)).exp())
        .sum::<f64>();
    cap + nose + sockets
}

fn main() -> anyhow::Result<()> {
    // 10⁵ scattered samples over x ∈ [−70, 70], y ∈ [−85, 55], parametrised by frontal position.
    let mut state = 12345u64;
    let mut next = move || {
        state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let params: Vec<[f64; 2]> = (0..100_000).map(|_| [next(), next()]).collect();
    let to_xy = |[u, v]: [f64; 2]| (-70.0 + 140.0 * u, -85.0 + 140.0 * v);
    let points: Vec<Point3<f64>> = params
        .iter()
        .map(|&p| {
            let (x, y) = to_xy(p);
            Point3::new(x, y, face(x, y))
        })
        .collect();

    println!(
        "fitting {} samples of a face-like height field (units: eye distance = 50)",
        params.len()
    );
    println!("{:>7} {:>12} {:>12} {:>10}", "grid", "rms", "max", "time");
    let mut last: Option<BSplineSurface> = None;
    for n in [8, 16, 32, 64] {
        let knots = KnotVector::clamped_uniform(3, n, 0.0, 1.0)?;
        let start = Instant::now();
        let fitted = SurfaceFit::new(knots.clone(), knots)
            .smoothness(1e-9)
            .fit(&params, &points)?;
        let elapsed = start.elapsed();
        println!(
            "{:>7} {:>12.5} {:>12.5} {:>8.1} ms",
            format!("{n}×{n}"),
            fitted.report.rms,
            fitted.report.max,
            elapsed.as_secs_f64() * 1e3
        );
        last = Some(fitted.surface);
    }
    let surface = last.expect("fitted at least once");
    let tip = surface.eval(0.5, 60.0 / 140.0)?;
    println!(
        "F(0.5, 0.43) = ({:.3}, {:.3}, {:.3}), on the nose ridge",
        tip.x, tip.y, tip.z
    );
    match surface.normal(0.5, 60.0 / 140.0)? {
        Some(n) => println!("its unit normal: ({:.4}, {:.4}, {:.4})", n.x, n.y, n.z),
        None => println!("the surface is degenerate there"),
    }
    let json = surface.to_json();
    let back = BSplineSurface::from_json(&json)?;
    println!(
        "JSON: {} bytes, round trip exact: {}",
        json.len(),
        back == surface
    );
    Ok(())
}
