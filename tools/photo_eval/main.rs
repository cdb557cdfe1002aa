//! The photo-realistic evaluation (issue 16): the whole photo path (SeetaFace detection,
//! dlib's 68 points, RASL, depth, surface) on photos that behave like real ones, scored against
//! the truth over its inner face ([`splineface::compare::inner_face_score`]) beside the
//! unchanged mean face scored the same way in the same run.
//!
//! Subjects ([`subjects`]): Lee Perry-Smith's textured head scan (`../shared/data/lps-head`,
//! CC BY 3.0), with its two photo sets as given and more rendered here, and ICT-FaceKit
//! identities (`../shared/data/ict-face`, MIT) wearing real skins projected from frontal
//! photos. Every subject gets a pool of rendered photos ([`photos::render_pool`]: perspective,
//! 0.4–2 m, varied light); sets of 2, 3, 4, 8 and 16 are drawn from it over several seeds, and
//! two disjoint halves of 16 photos test self-consistency.
//!
//! Run: `cargo run --release --example photo_eval -- [--quick] [--ict-subjects N] [--seeds N]
//! [--out DIR] [--model PATH]`; writes `DIR/photos.md` and pictures (default DIR
//! `target/photo-eval`; the committed page is `tools/results/photos.md`).

#[path = "../common/mod.rs"]
mod common;
mod photos;
mod subjects;

use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use nalgebra::{Point2, Point3};
use splineface::Real;
use splineface::align::PhotoPoints;
use splineface::compare::{InnerFaceOptions, InnerFaceScore, inner_face_score};
use splineface::face::{Deformation, FaceSurface, MeshOptions, Units};
use splineface::landmarker::ShapePredictor;
use splineface::mesh::TriangleMesh;
use splineface::pipeline::{Input, PhotoImage, PipelineOptions, Reconstruction, reconstruct};
use splineface::reference::ReferenceFace;

use common::{Ict, Lcg};
use photos::Photo;
use subjects::Subject;

struct Args {
    quick: bool,
    ict_subjects: usize,
    seeds: u64,
    counts: Vec<usize>,
    pool: usize,
    out: PathBuf,
    model: PathBuf,
    data: PathBuf,
    ict: PathBuf,
}

fn parse_args() -> Result<Args> {
    let shared = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../shared"));
    let mut args = Args {
        quick: false,
        ict_subjects: 6,
        seeds: 3,
        counts: vec![2, 3, 4, 8, 16],
        pool: 24,
        out: PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/target/photo-eval")),
        model: shared.join("models/shape_predictor_68_face_landmarks.dat"),
        data: shared.join("data/lps-head"),
        ict: shared.join("data/ict-face"),
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = || it.next().with_context(|| format!("{flag} needs a value"));
        match flag.as_str() {
            "--quick" => args.quick = true,
            "--ict-subjects" => args.ict_subjects = value()?.parse()?,
            "--seeds" => args.seeds = value()?.parse()?,
            "--counts" => {
                args.counts = value()?
                    .split(',')
                    .map(|c| c.trim().parse())
                    .collect::<Result<_, _>>()?
            }
            "--out" => args.out = value()?.into(),
            "--model" => args.model = value()?.into(),
            "--data" => args.data = value()?.into(),
            "--ict" => args.ict = value()?.into(),
            other => bail!("unknown argument {other}"),
        }
    }
    if args.quick {
        args.ict_subjects = args.ict_subjects.min(2);
        args.seeds = 1;
        args.counts = vec![3, 8];
    }
    if args.counts.iter().any(|&c| c == 0 || c > args.pool) {
        bail!("photo counts must be 1 to {}", args.pool);
    }
    Ok(args)
}

/// The mean face in millimetres: what every reconstruction is measured against.
struct MeanFace {
    mesh: TriangleMesh,
    structure: Vec<Point3<Real>>,
}

impl MeanFace {
    fn new(reference: &ReferenceFace) -> Result<Self> {
        let units = Units::default();
        let face = FaceSurface::deform(reference, reference.structure(), Deformation::Affine)?;
        Ok(MeanFace {
            mesh: face
                .mesh(&MeshOptions::default())?
                .mesh
                .transformed(&units.transform()),
            structure: reference
                .structure()
                .iter()
                .map(|p| p * units.per_canonical_unit())
                .collect(),
        })
    }
}

fn score(mesh: &TriangleMesh, structure: &[Point3<Real>], subject: &Subject) -> Result<InnerFaceScore> {
    Ok(inner_face_score(
        mesh,
        &subject.truth,
        (structure, &subject.structure),
        &InnerFaceOptions::default(),
    )?
    .score)
}

/// The photos' landmarks, found once per photo.
struct Landmarks<'a> {
    model: &'a ShapePredictor,
    found: HashMap<String, Option<Vec<Point2<Real>>>>,
}

impl Landmarks<'_> {
    fn of(&mut self, key: &str, photo: &Photo) -> Option<Vec<Point2<Real>>> {
        self.found
            .entry(key.to_owned())
            .or_insert_with(|| {
                splineface::detect::landmark_subject(self.model, &photo.image)
                    .ok()
                    .map(|f| f.ibug)
            })
            .clone()
    }
}

/// One photo set of one subject.
struct Set<'a> {
    subject: usize,
    label: String,
    /// Photo keys (for the landmark cache) and photos.
    photos: Vec<(String, &'a Photo)>,
}

/// What a run of the pipeline on a set gave.
struct Outcome {
    score: Option<InnerFaceScore>,
    used: usize,
    undetected: usize,
    error: Option<String>,
}

fn run_set(
    set: &Set<'_>,
    subject: &Subject,
    landmarks: &mut Landmarks<'_>,
    reference: &ReferenceFace,
    options: &PipelineOptions,
) -> Result<(Outcome, Option<Reconstruction>)> {
    let mut inputs = Vec::new();
    let mut undetected = 0;
    for (key, photo) in &set.photos {
        let Some(ibug) = landmarks.of(key, photo) else {
            undetected += 1;
            continue;
        };
        inputs.push(Input {
            points: PhotoPoints::from_ibug68(photo.name.clone(), &ibug)?,
            image: Some(PhotoImage::from_dynamic(&photo.image)?),
        });
    }
    match reconstruct(&inputs, reference, options, |_| {}) {
        Ok(result) => {
            let s = score(&result.output_mesh(), &result.structure(), subject)?;
            Ok((
                Outcome {
                    score: Some(s),
                    used: result.depth.photos.len(),
                    undetected,
                    error: None,
                },
                Some(result),
            ))
        }
        Err(e) => Ok((
            Outcome {
                score: None,
                used: 0,
                undetected,
                error: Some(e.to_string()),
            },
            None,
        )),
    }
}

/// A seeded choice of `count` of `0..n`.
fn choose(n: usize, count: usize, seed: u64) -> Vec<usize> {
    let mut rng = Lcg(seed
        .wrapping_mul(0xD1B5_4A32_D192_ED03)
        .wrapping_add(count as u64));
    let mut order: Vec<usize> = (0..n).collect();
    for k in (1..n).rev() {
        let j = (rng.next() * (k + 1) as Real) as usize;
        order.swap(k, j.min(k));
    }
    order.truncate(count);
    order.sort_unstable();
    order
}

/// The skin sources: a frontal, evenly lit render of the scan, and the largest near-frontal
/// faces of dlib's `bald_guys.jpg` collage, each cropped with a margin.
fn skin_sources(
    lps: &Subject,
    shared: &Path,
    model: &ShapePredictor,
) -> Result<Vec<(String, image::RgbImage)>> {
    use splineface::render::{Camera, Lighting, PhotoLook, render_photo};
    let camera = Camera::looking_at_head(0.0, 0.0, 0.0, &lps.target, 650.0, 2200.0, 800, 1000);
    let even = Lighting {
        direction: nalgebra::Vector3::new(0.0, 0.2, 1.0),
        diffuse: 0.55,
        ambient: 0.45,
        specular: 0.02,
        shininess: 20.0,
        shadow_softness: 3.0,
    };
    let look = PhotoLook {
        blur: 0.0,
        noise: 0.0,
        ..PhotoLook::default()
    };
    let mut sources = vec![(
        "lps".to_owned(),
        render_photo(&lps.mesh, &lps.colour, &camera, &even, &look)?,
    )];
    let path = shared.join("data/dlib-faces/bald_guys.jpg");
    let collage = image::open(&path).with_context(|| format!("reading {}", path.display()))?;
    let grey = collage.to_luma8();
    let mut faces = splineface::detect::detect_faces(&grey);
    faces.sort_by_key(|f| std::cmp::Reverse(f.area()));
    let rgb = collage.to_rgb8();
    let intensity = splineface::landmarker::Intensity::from_rgb(&rgb);
    let mut taken = 0;
    for face in faces {
        if taken == 4 {
            break;
        }
        let points = model.predict(&intensity, splineface::detect::landmark_box(&face));
        // Near-frontal: the nose tip within 6% of the eye distance of the eyes' middle.
        let eyes = nalgebra::center(&points[36], &points[45]);
        let eye_distance = (points[45] - points[36]).norm();
        if (points[30].x - eyes.x).abs() > 0.06 * eye_distance || eye_distance < 60.0 {
            continue;
        }
        let b = face.bbox;
        let (w, h) = ((b.right - b.left) as f64, (b.bottom - b.top) as f64);
        let left = (b.left as f64 - 0.6 * w).max(0.0) as u32;
        let top = (b.top as f64 - 0.7 * h).max(0.0) as u32;
        let right = ((b.right as f64 + 0.6 * w) as u32).min(rgb.width() - 1);
        let bottom = ((b.bottom as f64 + 0.6 * h) as u32).min(rgb.height() - 1);
        let crop = image::imageops::crop_imm(&rgb, left, top, right - left, bottom - top).to_image();
        taken += 1;
        sources.push((format!("collage-{taken}"), crop));
    }
    Ok(sources)
}

fn mean_of(values: impl Iterator<Item = Real>) -> Real {
    let (sum, n) = values.fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
    if n == 0 { Real::NAN } else { sum / n as Real }
}

fn main() -> Result<()> {
    let args = parse_args()?;
    let started = std::time::Instant::now();
    let shared = args.data.join("../..");
    let model = ShapePredictor::read(&args.model)?;
    let reference = ReferenceFace::embedded();
    let mean_face = MeanFace::new(reference)?;
    let options = PipelineOptions::default();
    std::fs::create_dir_all(&args.out)?;

    // Subjects and their pools.
    let mut subjects = vec![subjects::lps(&args.data)?];
    let ict = Ict::load(&args.ict)?;
    let skins = subjects::skins(&skin_sources(&subjects[0], &shared, &model)?, &model, &ict)?;
    for (k, skin) in skins.iter().enumerate() {
        skin.image
            .save(args.out.join(format!("skin-{}.png", skin.name)))?;
        let _ = k;
    }
    for k in 0..args.ict_subjects {
        subjects.push(subjects::ict_subject(&ict, k, 16, &skins[k % skins.len()])?);
    }
    let mut pools: Vec<Vec<Photo>> = Vec::new();
    for subject in &subjects {
        let max_yaw = if subject.name == "lps" { 60.0 } else { 45.0 };
        let dir = photos::render_pool(
            subject,
            args.pool,
            max_yaw,
            7,
            &args.out.join("pools").join(&subject.name),
        )?;
        pools.push(photos::read_set(&dir)?);
        eprintln!(
            "{}: pool of {} photos ({:.0} s)",
            subject.name,
            args.pool,
            started.elapsed().as_secs_f64()
        );
    }
    let given: Vec<(String, Vec<Photo>)> = ["photos-8", "photos-3"]
        .iter()
        .map(|s| Ok((s.to_string(), photos::read_set(&args.data.join(s))?)))
        .collect::<Result<_>>()?;

    // The sets.
    let mut sets: Vec<Set<'_>> = Vec::new();
    for (name, photos) in &given {
        sets.push(Set {
            subject: 0,
            label: format!("lps-head/{name} (given)"),
            photos: photos.iter().map(|p| (format!("{name}/{}", p.name), p)).collect(),
        });
    }
    for (s, subject) in subjects.iter().enumerate() {
        for &count in &args.counts {
            for seed in 0..args.seeds {
                let chosen = choose(args.pool, count, seed * 1000 + s as u64);
                sets.push(Set {
                    subject: s,
                    label: format!("{} {count} photos, seed {seed}", subject.name),
                    photos: chosen
                        .iter()
                        .map(|&k| (format!("{}/{}", subject.name, pools[s][k].name), &pools[s][k]))
                        .collect(),
                });
            }
        }
    }

    let mut landmarks = Landmarks {
        model: &model,
        found: HashMap::new(),
    };
    let baselines: Vec<InnerFaceScore> = subjects
        .iter()
        .map(|s| score(&mean_face.mesh, &mean_face.structure, s))
        .collect::<Result<_>>()?;
    let mut page = String::new();
    writeln!(page, "# Photo-realistic evaluation\n")?;
    writeln!(
        page,
        "Truth → surface distance over the truth's inner face (mm, after a similarity alignment: \
         landmarks, then ICP), the whole photo path; the mean face is scored the same way in the same run.\n"
    )?;
    writeln!(
        page,
        "| set | photos used | undetected | mean | median | p90 | coverage | mean face | ratio |"
    )?;
    writeln!(page, "|---|---|---|---|---|---|---|---|---|")?;
    let mut ratios: Vec<(usize, String, usize, Real)> = Vec::new();
    for set in &sets {
        let subject = &subjects[set.subject];
        let base = baselines[set.subject];
        let (outcome, _) = run_set(set, subject, &mut landmarks, reference, &options)?;
        let line = match (&outcome.score, &outcome.error) {
            (Some(s), _) => {
                let ratio = s.distance.mean / base.distance.mean;
                ratios.push((set.subject, set.label.clone(), set.photos.len(), ratio));
                format!(
                    "| {} | {} | {} | {:.2} | {:.2} | {:.2} | {:.3} | {:.2} | {:.2} |",
                    set.label,
                    outcome.used,
                    outcome.undetected,
                    s.distance.mean,
                    s.distance.median,
                    s.distance.p90,
                    s.coverage,
                    base.distance.mean,
                    ratio
                )
            }
            (None, error) => format!(
                "| {} | 0 | {} | failed: {} | | | | {:.2} | |",
                set.label,
                outcome.undetected,
                error.clone().unwrap_or_default(),
                base.distance.mean
            ),
        };
        eprintln!("{line}");
        writeln!(page, "{line}")?;
    }

    // Summary by photo count.
    writeln!(
        page,
        "\n## By photo count (ratio to the mean face; lower is better)\n"
    )?;
    writeln!(
        page,
        "| photos | sets | mean ratio | worst | sets worse than the mean face |"
    )?;
    writeln!(page, "|---|---|---|---|---|")?;
    let mut counts: Vec<usize> = ratios.iter().map(|r| r.2).collect();
    counts.sort_unstable();
    counts.dedup();
    for count in counts {
        let of: Vec<Real> = ratios.iter().filter(|r| r.2 == count).map(|r| r.3).collect();
        let line = format!(
            "| {count} | {} | {:.2} | {:.2} | {} |",
            of.len(),
            mean_of(of.iter().copied()),
            of.iter().copied().fold(0.0, Real::max),
            of.iter().filter(|&&r| r > 1.0).count()
        );
        eprintln!("{line}");
        writeln!(page, "{line}")?;
    }

    // Self-consistency: two disjoint halves of 16 photos.
    writeln!(page, "\n## Self-consistency: two disjoint halves of 16 photos\n")?;
    writeln!(
        page,
        "| subject | half A → B | half B → A | symmetric mean (mm) |"
    )?;
    writeln!(page, "|---|---|---|---|")?;
    for (s, subject) in subjects.iter().enumerate() {
        let chosen = choose(args.pool, 16.min(args.pool), 999 + s as u64);
        let halves: Vec<Set<'_>> = [&chosen[..chosen.len() / 2], &chosen[chosen.len() / 2..]]
            .iter()
            .map(|half| Set {
                subject: s,
                label: String::new(),
                photos: half
                    .iter()
                    .map(|&k| (format!("{}/{}", subject.name, pools[s][k].name), &pools[s][k]))
                    .collect(),
            })
            .collect();
        let a = run_set(&halves[0], subject, &mut landmarks, reference, &options)?.1;
        let b = run_set(&halves[1], subject, &mut landmarks, reference, &options)?.1;
        let line = match (a, b) {
            (Some(a), Some(b)) => {
                let one_way = |x: &Reconstruction, y: &Reconstruction| -> Result<Real> {
                    let as_truth = Subject {
                        name: String::new(),
                        mesh: x.output_mesh(),
                        colour: subject.colour.clone(),
                        truth: x.output_mesh(),
                        structure: x.structure(),
                        ibug: Vec::new(),
                        target: Point3::origin(),
                    };
                    Ok(score(&y.output_mesh(), &y.structure(), &as_truth)?.distance.mean)
                };
                let (ab, ba) = (one_way(&a, &b)?, one_way(&b, &a)?);
                format!(
                    "| {} | {ab:.2} | {ba:.2} | {:.2} |",
                    subject.name,
                    (ab + ba) / 2.0
                )
            }
            _ => format!("| {} | failed | failed | |", subject.name),
        };
        eprintln!("{line}");
        writeln!(page, "{line}")?;
    }
    writeln!(page, "\n{:.0} s in all.", started.elapsed().as_secs_f64())?;
    std::fs::write(args.out.join("photos.md"), &page)?;
    eprintln!("wrote {}", args.out.join("photos.md").display());
    Ok(())
}
