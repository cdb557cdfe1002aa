//! The photo-realistic evaluation (issue 16): the whole photo path (detection, dlib's 68
//! points, RASL, depth, surface) on photos that behave like real ones, scored against the
//! truth over its inner face ([`splineface::compare::inner_face_score`]) beside the unchanged
//! mean face scored the same way in the same run.
//!
//! Run: `cargo run --release --example photo_eval -- [--model PATH] [--data DIR]`.

#[path = "common/mod.rs"]
mod common;

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use nalgebra::{Point2, Point3};
use splineface::Real;
use splineface::align::PhotoPoints;
use splineface::compare::{InnerFaceOptions, inner_face_score};
use splineface::face::{Deformation, FaceSurface, MeshOptions, Units};
use splineface::landmarker::ShapePredictor;
use splineface::mesh::{TriangleMesh, read_mesh};
use splineface::pipeline::{Input, PhotoImage, PipelineOptions, reconstruct};
use splineface::reference::ReferenceFace;
use splineface::structure::from_ibug68;

struct Truth {
    mesh: TriangleMesh,
    structure: Vec<Point3<Real>>,
}

fn read_truth(dir: &Path) -> Result<Truth> {
    let mesh = read_mesh(&dir.join("mesh.obj"))?;
    let text = std::fs::read_to_string(dir.join("landmarks68.txt"))?;
    let ibug: Vec<Point3<Real>> = text
        .lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let v: Vec<Real> = l.split_whitespace().map(|x| x.parse().unwrap()).collect();
            Point3::new(v[0], v[1], v[2])
        })
        .collect();
    Ok(Truth {
        mesh,
        structure: from_ibug68(&ibug)?,
    })
}

/// A photo with its detected points and the truth's projected points.
struct Photo {
    name: String,
    image: image::DynamicImage,
    detected: Option<Vec<Point2<Real>>>,
    projected: Vec<Point2<Real>>,
    ypr: [Real; 3],
}

fn read_set(dir: &Path, model: &ShapePredictor) -> Result<Vec<Photo>> {
    let camera: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("camera.json"))?)?;
    let mut photos = Vec::new();
    for p in camera["photos"].as_array().context("photos")? {
        let file = p["file"].as_str().context("file")?;
        let image = image::open(dir.join(file))?;
        let projected: Vec<Point2<Real>> = p["landmarks68_px"]
            .as_array()
            .context("landmarks68_px")?
            .iter()
            .map(|q| Point2::new(q[0].as_f64().unwrap(), q[1].as_f64().unwrap()))
            .collect();
        let found = splineface::detect::landmark_subject(model, &image).ok();
        if std::env::var("DUMP").is_ok() {
            let mut rgb = image.to_rgb8();
            let mut dot = |q: &Point2<Real>, c: [u8; 3]| {
                for dy in -2i64..=2 { for dx in -2i64..=2 {
                    let (x, y) = (q.x.round() as i64 + dx, q.y.round() as i64 + dy);
                    if x >= 0 && y >= 0 && (x as u32) < rgb.width() && (y as u32) < rgb.height() { rgb.put_pixel(x as u32, y as u32, image::Rgb(c)); }
                }}
            };
            for q in &projected { dot(q, [0, 255, 0]); }
            if let Some(f) = &found {
                for q in &f.ibug { dot(q, [255, 0, 0]); }
                let b = f.face.bbox;
                for x in b.left..=b.right { for y in [b.top, b.bottom] { if x >= 0 && y >= 0 && (x as u32) < rgb.width() && (y as u32) < rgb.height() { rgb.put_pixel(x as u32, y as u32, image::Rgb([0, 0, 255])); } } }
                for y in b.top..=b.bottom { for x in [b.left, b.right] { if x >= 0 && y >= 0 && (x as u32) < rgb.width() && (y as u32) < rgb.height() { rgb.put_pixel(x as u32, y as u32, image::Rgb([0, 0, 255])); } } }
            }
            std::fs::create_dir_all("/tmp/dump")?;
            rgb.save(format!("/tmp/dump/{}-{}", dir.file_name().unwrap().to_string_lossy(), file))?;
        }
        let detected = found.map(|f| f.ibug);
        let a = p["yaw_pitch_roll_deg"].as_array().context("ypr")?;
        let ypr = [a[0].as_f64().unwrap(), a[1].as_f64().unwrap(), a[2].as_f64().unwrap()];
        photos.push(Photo {
            ypr,
            name: file.trim_end_matches(".png").to_owned(),
            image,
            detected,
            projected,
        });
    }
    Ok(photos)
}

fn score(
    mesh: &TriangleMesh,
    structure: &[Point3<Real>],
    truth: &Truth,
) -> Result<splineface::compare::InnerFaceScore> {
    Ok(inner_face_score(mesh, &truth.mesh, (structure, &truth.structure), &InnerFaceOptions::default())?.score)
}

fn run(
    photos: &[&Photo],
    use_truth_points: bool,
    reference: &ReferenceFace,
    options: &PipelineOptions,
    truth: &Truth,
) -> Result<Option<splineface::compare::InnerFaceScore>> {
    let mut inputs = Vec::new();
    for p in photos {
        let ibug = if use_truth_points {
            p.projected.clone()
        } else {
            match &p.detected {
                Some(d) => d.clone(),
                None => continue,
            }
        };
        inputs.push(Input {
            points: PhotoPoints::from_ibug68(p.name.clone(), &ibug)?,
            image: Some(PhotoImage::from_dynamic(&p.image)?),
        });
    }
    let Ok(result) = reconstruct(&inputs, reference, options, |_| {}) else {
        return Ok(None);
    };
    if std::env::var("DIAG").is_ok() {
        for fit in &result.depth.photos {
            let p = photos.iter().find(|p| p.name == fit.name).unwrap();
            let [y, pi, r] = fit.pose.yaw_pitch_roll_degrees();
            let [ty, tp, tr] = p.ypr;
            let lm = match &p.detected { Some(d) => {
                let a = splineface::structure::from_ibug68(d)?; let b = splineface::structure::from_ibug68(&p.projected)?;
                let eye = (b[23]-b[24]).norm();
                let e = |r: std::ops::Range<usize>| (r.clone().map(|k| (a[k]-b[k]).norm_squared()).sum::<Real>() / r.len() as Real).sqrt() / eye * 100.0;
                format!("lm err contour {:.1}% inner {:.1}%", e(0..9), e(9..40)) }, None => "no det".into() };
            println!("  {} ypr est {:6.1} {:6.1} {:6.1} true {:6.1} {:6.1} {:6.1} rms {:.2}u {lm}", fit.name, y, pi, r, ty, tp, tr, fit.rms_units);
        }
        let est = result.structure();
        let inner: Vec<usize> = (9..40).collect();
        let (sim, _) = splineface::compare::fit_similarity(&inner.iter().map(|&k| est[k]).collect::<Vec<_>>(), &inner.iter().map(|&k| truth.structure[k]).collect::<Vec<_>>()).unwrap();
        let groups = [("contour", 0..9), ("brows", 9..15), ("eyes", 15..25), ("nose", 25..32), ("mouth", 32..40)];
        let mut line = String::from("  structure err (mm, xyz / z):");
        for (g, r) in groups { let n = r.len() as Real; let (mut e, mut ez) = (0.0, 0.0); for k in r { let d = sim * est[k] - truth.structure[k]; e += d.norm_squared(); ez += d.z * d.z; } line += &format!(" {g} {:.1}/{:.1}", (e/n).sqrt(), (ez/n).sqrt()); }
        println!("{line}");
    }
    Ok(Some(score(&result.output_mesh(), &result.structure(), truth)?))
}

fn main() -> Result<()> {
    let mut data = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data/lps-head"));
    let mut model_path = PathBuf::from(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../shared/models/shape_predictor_68_face_landmarks.dat"
    ));
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        match flag.as_str() {
            "--data" => data = it.next().context("--data DIR")?.into(),
            "--model" => model_path = it.next().context("--model PATH")?.into(),
            other => bail!("unknown argument {other}"),
        }
    }
    let model = ShapePredictor::read(&model_path)?;
    let truth = read_truth(&data.join("truth"))?;
    let reference = ReferenceFace::embedded();
    let options = PipelineOptions::default();
    let units = Units::default();
    let mean = FaceSurface::deform(reference, reference.structure(), Deformation::Affine)?;
    let mean_mesh = mean.mesh(&MeshOptions::default())?.mesh.transformed(&units.transform());
    let mean_structure: Vec<Point3<Real>> =
        reference.structure().iter().map(|p| p * units.per_canonical_unit()).collect();
    let m = score(&mean_mesh, &mean_structure, &truth)?;
    let m0 = inner_face_score(&mean_mesh, &truth.mesh, (&mean_structure, &truth.structure), &InnerFaceOptions { iterations: 0, ..Default::default() })?.score;
    println!("mean face, landmark similarity only: mean {:.3} median {:.3}", m0.distance.mean, m0.distance.median);
    println!(
        "mean face: mean {:.3} median {:.3} p90 {:.3} coverage {:.3} scale {:.3}",
        m.distance.mean, m.distance.median, m.distance.p90, m.coverage, m.scale
    );
    // Experiments: the reference deformed to the truth's own structure.
    let per = units.per_canonical_unit();
    let canonical: Vec<Point3<Real>> = truth.structure.iter().map(|p| p / per).collect();
    for (label, deformation) in [("affine", Deformation::Affine), ("local", Deformation::default())] {
        for (inner_only, used) in [(false, (9..40).collect::<Vec<usize>>()), (true, (9..40).collect()), (true, (25..40).collect()), (true, (9..15).chain(25..40).collect()), (true, (15..40).collect())] {
            let mut target = canonical.clone();
            if inner_only {
                let affine0 = splineface::face::structure_transform(&(0..40).map(|k| reference.structure()[if used.contains(&k) {k} else {used[k % used.len()]}]).collect::<Vec<_>>(), &(0..40).map(|k| canonical[if used.contains(&k) {k} else {used[k % used.len()]}]).collect::<Vec<_>>())?;
                for k in 0..40 { if !used.contains(&k) { target[k] = affine0 * reference.structure()[k]; } }
            }
            if false {
                // Contour points: where the affine map of the inner points puts the reference's.
                let inner: Vec<usize> = (9..40).collect();
                let from: Vec<Point3<Real>> = inner.iter().map(|&k| reference.structure()[k]).collect();
                let to: Vec<Point3<Real>> = inner.iter().map(|&k| canonical[k]).collect();
                let mut f40 = reference.structure().to_vec();
                let mut t40 = canonical.clone();
                for k in 0..9 { f40[k] = from[k % from.len()]; t40[k] = to[k % to.len()]; }
                let affine = splineface::face::structure_transform(&f40, &t40)?;
                for k in 0..9 { target[k] = affine * reference.structure()[k]; }
            }
            let face = FaceSurface::deform(reference, &target, deformation)?;
            let mesh = face.mesh(&MeshOptions::default())?.mesh.transformed(&units.transform());
            let structure: Vec<Point3<Real>> = target.iter().map(|p| p * per).collect();
            let s = score(&mesh, &structure, &truth)?;
            println!("true structure, {label}, {:?}: mean {:.3} ({:.2}x)", if inner_only {format!("{}..{} ({})", used[0], used[used.len()-1], used.len())} else {"all".into()}, s.distance.mean, s.distance.mean / m.distance.mean);
        }
    }
    for set in ["photos-8", "photos-3"] {
        let photos = read_set(&data.join(set), &model)?;
        let all: Vec<&Photo> = photos.iter().collect();
        for (label, truth_points) in [("detected", false), ("projected truth", true)] {
            match run(&all, truth_points, reference, &options, &truth)? {
                Some(s) => println!(
                    "{set} {label}: mean {:.3} median {:.3} p90 {:.3} coverage {:.3} ({:.2}x mean face)",
                    s.distance.mean,
                    s.distance.median,
                    s.distance.p90,
                    s.coverage,
                    s.distance.mean / m.distance.mean
                ),
                None => println!("{set} {label}: failed"),
            }
        }
    }
    Ok(())
}
