//! Measures how well cubic control grids of several sizes fit a real face scan: the measurement
//! behind the default reference grid size (issue 3).
//!
//! The scan is unified into the canonical frame by its 40-point structure (eye centres at
//! (±25, 0, 0)), parametrised by frontal position (u, v = x, y normalised over the bounding box),
//! and fitted by least squares with a tiny smoothness weight so that empty cells of the box
//! stay defined. Residuals are 3D distances at the scan's vertices, in canonical units and in
//! millimetres (63 mm between eye centres).
//!
//! Run: `cargo run --release --example reference_grid -- ../shared/data/ict-face`
//! (the directory holds `neutral_face.obj` and `landmarks68.txt`).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use nalgebra::Point3;
use splineface::bspline::{KnotVector, SurfaceFit};
use splineface::landmarks::read_vertex_indices;
use splineface::structure::{from_ibug68, unify};

/// Vertex positions of an OBJ file in file order (the order vertex-index landmark files refer
/// to; tobj renumbers vertices by first use in faces, so it cannot serve here).
fn obj_positions(path: &Path) -> Result<Vec<Point3<f64>>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    let mut positions = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let mut fields = line.split_whitespace();
        if fields.next() != Some("v") {
            continue;
        }
        let mut coordinate = || -> Result<f64> {
            let field = fields
                .next()
                .with_context(|| format!("{}: line {}: too few coordinates", path.display(), i + 1))?;
            let value: f64 = field
                .parse()
                .with_context(|| format!("{}: line {}: `{field}` is not a number", path.display(), i + 1))?;
            if !value.is_finite() {
                bail!("{}: line {}: coordinate is not finite", path.display(), i + 1);
            }
            Ok(value)
        };
        positions.push(Point3::new(coordinate()?, coordinate()?, coordinate()?));
    }
    Ok(positions)
}

fn main() -> Result<()> {
    let dir: PathBuf = std::env::args()
        .nth(1)
        .context("usage: reference_grid DIR (with neutral_face.obj and landmarks68.txt)")?
        .into();
    let vertices = obj_positions(&dir.join("neutral_face.obj"))?;
    let indices = read_vertex_indices(&dir.join("landmarks68.txt"), 68, vertices.len())?;
    let ibug: Vec<Point3<f64>> = indices.iter().map(|&i| vertices[i]).collect();
    let (similarity, _) = unify(&from_ibug68(&ibug)?)?;
    let all: Vec<Point3<f64>> = vertices.iter().map(|p| similarity * p).collect();
    // The face region: the jaw line (iBUG 0..=16) closed over the brows (26..=17) raised by
    // `brow_lift` units, grown by `margin` about its centroid. Outside it the scan wraps round
    // to the sides and the neck, where a frontal parametrisation is not single-valued.
    let brow_lift: f64 = std::env::args().nth(2).map_or(Ok(20.0), |s| s.parse())?;
    let margin: f64 = std::env::args().nth(3).map_or(Ok(1.1), |s| s.parse())?;
    let landmarks: Vec<Point3<f64>> = ibug.iter().map(|p| similarity * p).collect();
    let mut polygon: Vec<[f64; 2]> = (0..=16).map(|i| [landmarks[i].x, landmarks[i].y]).collect();
    polygon.extend(
        (17..=26)
            .rev()
            .map(|i| [landmarks[i].x, landmarks[i].y + brow_lift]),
    );
    let centroid = polygon
        .iter()
        .fold([0.0, 0.0], |a, p| [a[0] + p[0], a[1] + p[1]])
        .map(|c| c / polygon.len() as f64);
    let polygon: Vec<[f64; 2]> = polygon
        .iter()
        .map(|p| {
            [
                centroid[0] + margin * (p[0] - centroid[0]),
                centroid[1] + margin * (p[1] - centroid[1]),
            ]
        })
        .collect();
    let inside = |x: f64, y: f64| {
        // Even-odd rule.
        let mut inside = false;
        for k in 0..polygon.len() {
            let (a, b) = (polygon[k], polygon[(k + 1) % polygon.len()]);
            if (a[1] > y) != (b[1] > y) && x < a[0] + (y - a[1]) / (b[1] - a[1]) * (b[0] - a[0]) {
                inside = !inside;
            }
        }
        inside
    };
    // A crude stand-in for a front-view visibility test: drop vertices deeper than `min_z`
    // (the scan has interior geometry behind the face surface). To be replaced by keeping the
    // front-most surface of a frontal rasterisation.
    let min_z: f64 = std::env::args()
        .nth(4)
        .map_or(Ok(f64::NEG_INFINITY), |s| s.parse())?;
    let canonical: Vec<Point3<f64>> = all
        .into_iter()
        .filter(|p| inside(p.x, p.y) && p.z >= min_z)
        .collect();
    println!("face region: brow lift {brow_lift} units, margin ×{margin}, depth cut z ≥ {min_z}");
    let (mut lo, mut hi) = (canonical[0], canonical[0]);
    for p in &canonical {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    let params: Vec<[f64; 2]> = canonical
        .iter()
        .map(|p| [(p.x - lo.x) / (hi.x - lo.x), (p.y - lo.y) / (hi.y - lo.y)])
        .collect();
    let mm = 63.0 / 50.0;
    println!(
        "{} vertices; scale {:.4} canonical units per source unit; box x [{:.1}, {:.1}], y [{:.1}, {:.1}], z [{:.1}, {:.1}]",
        canonical.len(),
        similarity.scaling(),
        lo.x,
        hi.x,
        lo.y,
        hi.y,
        lo.z,
        hi.z
    );
    println!("| grid | λ | RMS (units) | max (units) | RMS (mm) | max (mm) | worst vertex | fit time |");
    println!("|---|---|---|---|---|---|---|---|");
    for n in [8usize, 16, 32, 64] {
        let knots = KnotVector::clamped_uniform(3, n, 0.0, 1.0)?;
        for lambda in [1e-9, 1e-7] {
            let start = Instant::now();
            let fit = SurfaceFit::new(knots.clone(), knots.clone())
                .smoothness(lambda)
                .fit(&params, &canonical)?;
            let elapsed = start.elapsed();
            let r = fit.report;
            let w = canonical[r.max_index];
            println!(
                "| {n}×{n} | {lambda:e} | {:.4} | {:.3} | {:.4} | {:.3} | {} at ({:.1}, {:.1}, {:.1}) | {:.1} ms |",
                r.rms,
                r.max,
                r.rms * mm,
                r.max * mm,
                r.max_index,
                w.x,
                w.y,
                w.z,
                elapsed.as_secs_f64() * 1e3
            );
        }
    }
    Ok(())
}
