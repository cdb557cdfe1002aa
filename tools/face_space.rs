//! The statistical face space's ceilings: what the ICT-FaceKit identity modes, carried onto the
//! embedded reference's B-spline parametrisation (`splineface::face::FaceSpace`), can do for a
//! real face and for faces outside the space, with perfect data.
//!
//! * `lps-head` (a real scan, `../shared/data/lps-head`, CC BY 3.0): the space fitted to the
//!   scan's own 40 3D landmarks (MAP), and fitted densely to its whole surface (trimmed ICP),
//!   against the unchanged mean face and the local deformation by the true structure.
//! * Generalisation: the space built from ICT modes 0–(K−1), scored on identities drawn with
//!   all 60 modes (`w ~ N(0, 1)`), fitted to their true 3D landmarks.
//!
//! Every face is scored by `splineface::compare::inner_face_score` (truth → face over the
//! truth's inner face, after a similarity alignment), in millimetres, with the mean face scored
//! the same way.
//!
//! Run: `cargo run --release --example face_space -- [--ict DIR] [--data DIR] [--subjects N]
//! [--modes K]`; with `--write REFERENCE.json` it adds the 60 identity modes and the 53
//! expression blendshapes to that reference file (the ICT mean face's, as
//! `tools/build_reference.sh` makes it) instead.

#[path = "common/mod.rs"]
mod common;
#[allow(dead_code)]
#[path = "photo_eval/subjects.rs"]
mod subjects;

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use nalgebra::Point3;
use splineface::Real;
use splineface::compare::{InnerFaceOptions, inner_face_score};
use splineface::face::{Deformation, FaceSpace, FaceSurface, MeshOptions, SpaceFit, Units};
use splineface::mesh::TriangleMesh;
use splineface::reference::ReferenceFace;
use splineface::structure::{from_ibug68, unify};

use common::{Ict, Lcg};

struct Args {
    ict: PathBuf,
    data: PathBuf,
    subjects: usize,
    modes: usize,
    /// Add the 60-mode space to this reference file (which must be the ICT mean face's) and stop.
    write: Option<PathBuf>,
}

fn parse_args() -> Result<Args> {
    let mut args = Args {
        ict: Ict::default_dir(),
        data: PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data/lps-head")),
        subjects: 10,
        modes: 40,
        write: None,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = || it.next().with_context(|| format!("{flag} needs a value"));
        match flag.as_str() {
            "--ict" => args.ict = value()?.into(),
            "--data" => args.data = value()?.into(),
            "--subjects" => args.subjects = value()?.parse()?,
            "--modes" => args.modes = value()?.parse()?,
            "--write" => args.write = Some(value()?.into()),
            other => bail!("unknown argument {other}"),
        }
    }
    if args.subjects == 0 || args.modes == 0 {
        bail!("--subjects and --modes must be positive");
    }
    Ok(args)
}

/// Truth → face over the truth's inner face, mean distance in mm.
fn score(
    face: &TriangleMesh,
    structure: &[Point3<Real>],
    truth: &TriangleMesh,
    truth_structure: &[Point3<Real>],
) -> Result<Real> {
    Ok(inner_face_score(
        face,
        truth,
        (structure, truth_structure),
        &InnerFaceOptions::default(),
    )?
    .score
    .distance
    .mean)
}

/// A face surface's mesh and structure moved by `placement` (canonical → the truth's frame).
fn placed(
    face: &FaceSurface,
    placement: &nalgebra::Similarity3<Real>,
) -> Result<(TriangleMesh, Vec<Point3<Real>>)> {
    let affine = nalgebra::Affine3::from_matrix_unchecked(placement.to_homogeneous());
    let mesh = face.mesh(&MeshOptions::default())?.mesh.transformed(&affine);
    Ok((mesh, face.structure().iter().map(|p| placement * p).collect()))
}

/// The canonical → truth similarity of the mean face (its structure onto the truth's).
fn mean_placement(
    reference: &ReferenceFace,
    truth_structure: &[Point3<Real>],
) -> Result<nalgebra::Similarity3<Real>> {
    Ok(
        splineface::compare::fit_similarity(reference.structure(), truth_structure)
            .context("degenerate structure")?
            .0,
    )
}

/// The score of a fitted member of the space, placed where the fit put it.
fn score_fit(
    reference: &ReferenceFace,
    space: &FaceSpace,
    fit: &SpaceFit,
    truth: &TriangleMesh,
    truth_structure: &[Point3<Real>],
) -> Result<Real> {
    let face = space.face(reference, &fit.weights)?;
    let (mesh, structure) = placed(&face, &fit.placement)?;
    score(&mesh, &structure, truth, truth_structure)
}

/// The landmark fit's score over a grid of noise levels and contour weights.
fn sweep(
    reference: &ReferenceFace,
    space: &FaceSpace,
    truth: &TriangleMesh,
    truth_structure: &[Point3<Real>],
) -> Result<Vec<Real>> {
    let mut out = Vec::new();
    for contour in CONTOURS {
        for noise in NOISES {
            let fit = space.fit_structure(
                truth_structure,
                &splineface::structure::contour_weighted(contour),
                noise,
            )?;
            out.push(score_fit(reference, space, &fit, truth, truth_structure)?);
        }
    }
    Ok(out)
}

const NOISES: [Real; 6] = [0.5, 1.0, 2.0, 3.0, 4.0, 8.0];
const CONTOURS: [Real; 2] = [1.0, 0.0];

struct Row {
    name: String,
    mean_face: Real,
    local: Real,
    landmarks: Real,
    dense: Option<Real>,
}

fn ratio(a: Real, b: Real) -> String {
    format!("{a:.2} ({:.2}×)", a / b)
}

fn evaluate(
    reference: &ReferenceFace,
    space: &FaceSpace,
    truth: &TriangleMesh,
    truth_structure: &[Point3<Real>],
    dense: bool,
) -> Result<Row> {
    let mean = FaceSurface::deform(reference, reference.structure(), Deformation::Affine)?;
    let (mesh, structure) = placed(&mean, &mean_placement(reference, truth_structure)?)?;
    let mean_face = score(&mesh, &structure, truth, truth_structure)?;
    // The local deformation by the true structure (what the landmark path does today).
    let (to_canonical, canonical) = unify(truth_structure)?;
    let local = FaceSurface::deform(reference, &canonical, Deformation::default())?;
    let (mesh, structure) = placed(&local, &to_canonical.inverse())?;
    let local = score(&mesh, &structure, truth, truth_structure)?;
    // The space's MAP fit to the true 3D landmarks (`common::LANDMARK_NOISE`).
    let fit = common::space_fit_to_landmarks(space, truth_structure)?;
    let landmarks = score_fit(reference, space, &fit, truth, truth_structure)?;
    let dense = if dense {
        let fitted = common::space_fit_densely(space, reference, truth, &fit)?;
        Some(score_fit(reference, space, &fitted, truth, truth_structure)?)
    } else {
        None
    };
    Ok(Row {
        name: String::new(),
        mean_face,
        local,
        landmarks,
        dense,
    })
}

fn main() -> Result<()> {
    let args = parse_args()?;
    let ict = Ict::load(&args.ict)?;
    if let Some(path) = &args.write {
        let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let reference = ReferenceFace::from_json(&text).with_context(|| format!("{}", path.display()))?;
        let space = ict.with_expressions(ict.face_space(&reference, ict.modes)?, &reference)?;
        let note = format!(
            "The {} identity modes of ICT-FaceKit (Copyright (c) 2020 USC Institute for Creative Technologies, MIT licence), \
             each a per-vertex displacement of the mean face carried to this grid by tools/face_space --write; deviation 1 \
             (the data's identities are w ~ N(0, 1)).",
            space.mode_count()
        );
        let with_space = reference
            .with_space(Some(space.to_modes(&note)))
            .map_err(anyhow::Error::msg)?;
        let json = with_space.to_json();
        let tmp = path.with_extension("json.tmp");
        std::fs::write(&tmp, &json)?;
        std::fs::rename(&tmp, path)?;
        eprintln!(
            "wrote {} ({} bytes, {} identity and {} expression modes)",
            path.display(),
            json.len(),
            space.mode_count(),
            space.expressions().len()
        );
        return Ok(());
    }
    let reference = ReferenceFace::embedded();
    let started = std::time::Instant::now();
    let full = ict.face_space(reference, ict.modes)?;
    eprintln!(
        "space of {} modes built in {:.1} s",
        full.mode_count(),
        started.elapsed().as_secs_f64()
    );

    println!(
        "# The face space's ceilings\n\nMade by `cargo run --release --example face_space -- --subjects {} --modes {}` \
         (tools/face_space.rs). Inner-face error in mm (truth → face over the truth's inner face, after a similarity \
         alignment), with the ratio to the unchanged mean face's. The lps-head scan is Lee Perry-Smith's (CC BY 3.0: \
         \"Infinite, 3D Head Scan by Lee Perry-Smith is licensed under a Creative Commons Attribution 3.0 Unported \
         License. Based on a work at www.triplegangers.com.\"); ICT-FaceKit: Copyright (c) 2020 USC Institute for \
         Creative Technologies, MIT licence.\n",
        args.subjects, args.modes
    );
    // The space carries ICT's own identities: its structure of w is ICT's, in the mean face's
    // canonical frame.
    let mut rng = Lcg(17);
    let w: Vec<Real> = (0..ict.modes).map(|_| rng.gaussian()).collect();
    let ibug: Vec<Point3<Real>> = ict
        .landmarks
        .iter()
        .map(|&i| ict.neutral.positions()[i])
        .collect();
    let (to_canonical, _) = unify(&from_ibug68(&ibug)?)?;
    let positions = ict.positions(&w);
    let direct: Vec<Point3<Real>> = from_ibug68(
        &ict.landmarks
            .iter()
            .map(|&i| to_canonical * positions[i])
            .collect::<Vec<_>>(),
    )?;
    let carried = full.structure(&w)?;
    let worst = direct
        .iter()
        .zip(&carried)
        .map(|(a, b)| (a - b).norm())
        .fold(0.0, Real::max);
    println!(
        "Structure carried by the space against ICT's own, a random identity: {worst:.2e} units at worst.\n"
    );

    println!(
        "| face | mean face | local deformation, true structure | space, MAP fit to the 3D landmarks | space, dense fit to the surface |"
    );
    println!("|---|---|---|---|---|");
    let lps = subjects::lps(&args.data)?;
    let mut lps_row = evaluate(reference, &full, &lps.truth, &lps.structure, true)?;
    lps_row.name = format!("lps-head, {} modes", full.mode_count());
    print_row(&lps_row);

    let sweep_lps = sweep(reference, &full, &lps.truth, &lps.structure)?;

    let space = full.truncated(args.modes);
    let mut rows = Vec::new();
    let mut sweeps = Vec::new();
    let mut rng = Lcg(2026);
    for s in 0..args.subjects {
        let weights: Vec<Real> = (0..ict.modes).map(|_| rng.gaussian()).collect();
        let subject = ict.subject(&weights)?;
        let units = Units::default();
        let truth = subject.mesh.transformed(&units.transform());
        let truth_structure: Vec<Point3<Real>> = subject
            .structure
            .iter()
            .map(|p| p * units.per_canonical_unit())
            .collect();
        let swept = sweep(reference, &space, &truth, &truth_structure)?;
        let mut row = evaluate(reference, &space, &truth, &truth_structure, s < 3)?;
        sweeps.push(swept.iter().map(|v| v / row.mean_face).collect::<Vec<_>>());
        row.name = format!("ICT identity {s} (60 modes), space of {}", space.mode_count());
        print_row(&row);
        rows.push(row);
    }
    let mean = |f: &dyn Fn(&Row) -> Real| rows.iter().map(f).sum::<Real>() / rows.len() as Real;
    println!(
        "| **ICT mean ratio to the mean face** | 1 | {:.2}× | {:.2}× | |",
        mean(&|r| r.local / r.mean_face),
        mean(&|r| r.landmarks / r.mean_face)
    );
    println!(
        "\n## The landmark fit's noise ε (mm per coordinate) and contour weight: ratio to the mean face\n\n| contour weight, ε | lps-head (60 modes) | ICT identities (mean, space of {}) |\n|---|---|---|",
        space.mode_count()
    );
    let mut at = 0;
    for contour in CONTOURS {
        for noise in NOISES {
            let ict = sweeps.iter().map(|s| s[at]).sum::<Real>() / sweeps.len() as Real;
            println!(
                "| {contour}, {noise} | {:.2}× | {ict:.2}× |",
                sweep_lps[at] / lps_row.mean_face
            );
            at += 1;
        }
    }
    eprintln!("done in {:.0} s", started.elapsed().as_secs_f64());
    Ok(())
}

fn print_row(row: &Row) {
    println!(
        "| {} | {:.2} | {} | {} | {} |",
        row.name,
        row.mean_face,
        ratio(row.local, row.mean_face),
        ratio(row.landmarks, row.mean_face),
        row.dense.map_or("".to_owned(), |d| ratio(d, row.mean_face))
    );
}
