//! Builds `reference/demo-subject.json`, the ground-truth face of `splineface demo`: an
//! ICT-FaceKit identity (fixed seed, weights ~ N(0, 0.8²)) with a mild smile and raised brows,
//! fitted by the project's own reference builder (the same control grid, options and file format
//! as the default reference). Only the fitted control grid, the structure and the fit's figures
//! are stored; nothing of the ICT data itself.
//!
//! Run: `cargo run --release --example build_demo_subject [-- ICT_DIR]`.

#[path = "common/mod.rs"]
mod common;

use anyhow::Result;
use common::{Ict, Lcg};
use splineface::reference::{ReferenceOptions, ReferenceScan, ReferenceSource, build_reference};

const SEED: u64 = 2016;
const EXPRESSION: [(&str, f64); 4] = [
    ("mouthSmile_L", 0.35),
    ("mouthSmile_R", 0.3),
    ("browInnerUp_L", 0.2),
    ("browInnerUp_R", 0.2),
];

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let dir = args.first().map_or_else(Ict::default_dir, Into::into);
    let ict = Ict::load(&dir)?;
    let mut rng = Lcg(SEED);
    let weights: Vec<f64> = (0..ict.modes).map(|_| 0.8 * rng.gaussian()).collect();
    let subject = ict.subject_with_expression(&weights, &EXPRESSION)?;
    let scan = ReferenceScan {
        mesh: subject.mesh.clone(),
        structure: subject.structure.clone(),
        landmarks: None,
        source: ReferenceSource {
            mesh: format!(
                "ICT-FaceKit identity (seed {SEED}, w ~ N(0, 0.8^2)) + mild smile and raised brows"
            ),
            mesh_fnv1a64: splineface::io::fnv1a64_hex(splineface::mesh::format_obj(&subject.mesh).as_bytes()),
            landmarks: "landmarks68.txt".to_owned(),
            vertices: subject.mesh.positions().len(),
            triangles: subject.mesh.triangles().len(),
        },
    };
    let reference = build_reference(
        &[scan],
        &ReferenceOptions::default(),
        "The demo subject of `splineface demo`, made by tools/build_demo_subject.rs from the ICT-FaceKit \
         identity and expression spaces (Copyright (c) 2020 USC Institute for Creative Technologies, MIT \
         licence: see reference/README.md). Only the fitted grid, structure and figures are stored.",
    )?;
    let out = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("reference/demo-subject.json");
    splineface::io::write_atomically(&out, reference.to_json().as_bytes())?;
    let fit = reference.fit();
    println!(
        "{}: {} samples, RMS {:.4}, max {:.3} units",
        out.display(),
        fit.samples,
        fit.rms,
        fit.max
    );
    Ok(())
}
