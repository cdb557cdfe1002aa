//! The evaluation harness (issue 8): the paper's Table 1 and Fig. 8(3) on faces with known
//! truth.
//!
//! Subjects are drawn from the ICT-FaceKit identity space (`../shared/data/ict-face`, weights
//! ~ N(0, 1)), photographed by the project's renderer ([`splineface::render::synthetic_photo`])
//! under random poses (yaw ±60°, pitch ±25°, roll ±15°), their 68 landmark vertices projected
//! with Gaussian noise (default 1% of the eye distance), reconstructed, and scored against the
//! subject's own mesh with [`splineface::compare::compare`] (aligned by the 40-point
//! structures). Baselines in the same run: the reference face unchanged, the paper's method
//! (RASL, frontal x,y fixed, SSIM constraint, affine grid deformation), the default with the
//! paper's affine deformation, without the SSIM constraint, and points-only. Then the error
//! against the number of photos (Fig. 8(3)), and neutral against expression photos (Table 2).
//!
//! Run: `cargo run --release --example eval -- [--quick] [--subjects N] [--photos N]
//! [--noise PERCENT] [--seed S] [--out DIR] [--ict DIR]`. Writes `DIR/evaluation.md` and
//! `DIR/error-vs-photos.png` (default DIR: `target/eval`).

#[path = "common/mod.rs"]
mod common;

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use common::{Ict, Lcg, Subject};
use nalgebra::Point3;
use splineface::Real;
use splineface::align::PhotoPoints;
use splineface::compare::{CompareOptions, CompareStats, InnerFaceOptions, compare, inner_face_score};
use splineface::depth::{DepthOptions, FrontalFreedom};
use splineface::face::{Deformation, MeshOptions, Units};
use splineface::pipeline::{Input, PhotoImage, PipelineOptions, Shape, reconstruct};
use splineface::reference::ReferenceFace;
use splineface::render::{TextStyle, View, draw_text, synthetic_photo, text_width};

struct Args {
    quick: bool,
    subjects: usize,
    photos: usize,
    noise: Real,
    seed: u64,
    out: PathBuf,
    ict: PathBuf,
}

fn parse_args() -> Result<Args> {
    let mut args = Args {
        quick: false,
        subjects: 10,
        photos: 12,
        noise: 1.0,
        seed: 8,
        out: PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/target/eval")),
        ict: Ict::default_dir(),
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = || it.next().with_context(|| format!("{flag} needs a value"));
        match flag.as_str() {
            "--quick" => args.quick = true,
            "--subjects" => args.subjects = value()?.parse()?,
            "--photos" => args.photos = value()?.parse()?,
            "--noise" => args.noise = value()?.parse()?,
            "--seed" => args.seed = value()?.parse()?,
            "--out" => args.out = value()?.into(),
            "--ict" => args.ict = value()?.into(),
            other => bail!("unknown argument {other}"),
        }
    }
    if args.quick {
        args.subjects = args.subjects.min(2);
        args.photos = args.photos.min(8);
    }
    if args.subjects == 0 || args.photos == 0 || args.noise < 0.0 || args.noise.is_nan() {
        bail!("--subjects and --photos must be positive, --noise non-negative");
    }
    Ok(args)
}

/// A way to make a face.
#[derive(Clone, Copy)]
struct Method {
    name: &'static str,
    /// `None`: the reference face unchanged. Else RASL or not, the frontal freedom, the SSIM
    /// constraint, and the shape (with the deformation of `Shape::Deformed`).
    run: Option<(bool, FrontalFreedom, bool, Shape, Deformation)>,
}

const LOCAL: Deformation = Deformation::Local {
    smoothness: Deformation::DEFAULT_SMOOTHNESS,
};
const SPACE: Shape = Shape::Space {
    noise: Shape::DEFAULT_NOISE,
    expressions: Some(splineface::face::ExpressionPrior::DEFAULT),
    outline: true,
    lips: 0.0,
};

const METHODS: [Method; 7] = [
    Method {
        name: "mean face (reference unchanged)",
        run: None,
    },
    Method {
        name: "paper: RASL, frontal fixed, SSIM, affine",
        run: Some((
            true,
            FrontalFreedom::Fixed,
            true,
            Shape::Deformed,
            Deformation::Affine,
        )),
    },
    Method {
        name: "RASL, free, SSIM, affine",
        run: Some((
            true,
            FrontalFreedom::Free,
            true,
            Shape::Deformed,
            Deformation::Affine,
        )),
    },
    Method {
        name: "RASL, free, SSIM, local",
        run: Some((true, FrontalFreedom::Free, true, Shape::Deformed, LOCAL)),
    },
    Method {
        name: "**default**: RASL, free, SSIM, face space",
        run: Some((true, FrontalFreedom::Free, true, SPACE, LOCAL)),
    },
    Method {
        name: "points only, free, SSIM, face space",
        run: Some((false, FrontalFreedom::Free, true, SPACE, LOCAL)),
    },
    Method {
        name: "RASL, free, SSIM, face space, jaw points fixed (no outline)",
        run: Some((
            true,
            FrontalFreedom::Free,
            true,
            Shape::Space {
                noise: Shape::DEFAULT_NOISE,
                expressions: Some(splineface::face::ExpressionPrior::DEFAULT),
                outline: false,
                lips: 0.0,
            },
            LOCAL,
        )),
    },
];

const DEFAULT: usize = 4;
const JAW_FIXED: usize = 6;
const PAPER: usize = 1;

/// The modes of the face space the methods use: ICT's first 40. The subjects are drawn with
/// all 60, so the space has to generalise, not recall.
const SPACE_MODES: usize = 40;

/// The embedded reference with its face space cut to `SPACE_MODES` modes.
fn reference() -> &'static ReferenceFace {
    static REFERENCE: std::sync::OnceLock<ReferenceFace> = std::sync::OnceLock::new();
    REFERENCE.get_or_init(|| {
        let embedded = ReferenceFace::embedded();
        let modes = embedded.space_modes().map(|m| m.truncated(SPACE_MODES));
        embedded
            .clone()
            .with_space(modes)
            .expect("a cut space still fits the grid")
    })
}

/// Where a landmarker puts the structure's points off the contour, relative to the landmark
/// vertices: the default reference's photo structure less its vertex structure (see
/// `ReferenceFace::photo_structure`); zero on the contour, whose points are put on the outline
/// by `common::landmarks_in_view` instead.
fn landmarker_offsets() -> Vec<nalgebra::Vector3<Real>> {
    let reference = ReferenceFace::embedded();
    reference
        .photo_structure()
        .iter()
        .zip(reference.structure())
        .zip(splineface::structure::POINTS.iter())
        .map(|((a, b), def)| {
            if def.group == splineface::structure::Group::Contour {
                nalgebra::Vector3::zeros()
            } else {
                a - b
            }
        })
        .collect()
}

/// The subject's structure as a landmarker places it (`landmarker_offsets`).
fn seen_structure(subject: &Subject) -> Vec<Point3<Real>> {
    subject
        .structure
        .iter()
        .zip(landmarker_offsets())
        .map(|(p, d)| p + d)
        .collect()
}

/// Photographs a subject: random poses, the 40 points as a landmarker places them (the jaw
/// points on the outline, the others moved by `landmarker_offsets`) projected with noise.
fn photograph(ict: &Ict, subject: &Subject, count: usize, noise: Real, rng: &mut Lcg) -> Result<Vec<Input>> {
    let offsets = landmarker_offsets();
    let mut inputs = Vec::with_capacity(count);
    for k in 0..count {
        let view = View::from_yaw_pitch_roll_degrees(
            rng.uniform(-60.0, 60.0),
            rng.uniform(-25.0, 25.0),
            rng.uniform(-15.0, 15.0),
        );
        let photo = synthetic_photo(&subject.mesh, &subject.structure, &view, 320, 384, 0.1)
            .map_err(anyhow::Error::msg)?;
        // Noise as a fraction of the frontal eye distance (50 units) in pixels.
        let sigma = noise / 100.0 * 50.0 / photo.raster.spacing;
        // The jaw points on the outline, as a landmarker puts them (1 unit ≈ 1.3 mm bands).
        let seen = common::landmarks_in_view(&subject.mesh, &ict.landmarks, &view, 1.0);
        let seen = splineface::structure::from_ibug68(&seen)?;
        let points: Vec<_> = seen
            .iter()
            .zip(&offsets)
            .map(|(q, d)| {
                let q = q + d;
                let p = photo.project(&q);
                nalgebra::Point2::new(
                    (p.x + sigma * rng.gaussian()).clamp(0.0, 319.0),
                    (p.y + sigma * rng.gaussian()).clamp(0.0, 383.0),
                )
            })
            .collect();
        let grey = photo.image;
        let colour = image::RgbImage::from_fn(320, 384, |x, y| {
            let v = (255.0 * grey.get(x as usize, y as usize)) as u8;
            image::Rgb([v, v, v])
        });
        inputs.push(Input {
            points: PhotoPoints::new(format!("p{k}"), points)?,
            image: Some(PhotoImage { grey, colour }),
        });
    }
    Ok(inputs)
}

/// Runs one method on the photos and scores it against the subject (millimetres).
fn score(method: &Method, inputs: &[Input], subject: &Subject) -> Result<(CompareStats, Real)> {
    let reference = reference();
    let units = Units::default();
    let mm = units.per_canonical_unit();
    let truth = subject.mesh.transformed(&units.transform());
    // Aligned through the landmarks as a landmarker places them, like the reconstruction's.
    let truth_structure: Vec<Point3<Real>> = seen_structure(subject).iter().map(|p| p * mm).collect();
    let (mesh, structure) = match method.run {
        None => {
            let mean = splineface::face::MeanFace::new(reference, units, &MeshOptions::default())?;
            (mean.mesh, mean.photo_structure)
        }
        Some((rasl, frontal, sim, shape, deformation)) => {
            let options = PipelineOptions {
                depth: DepthOptions {
                    frontal,
                    similarity_constraint: sim,
                    ..DepthOptions::default()
                },
                deformation,
                shape,
                // The error-against-photos sweep measures single photos too (it is where the
                // default minimum of two comes from).
                min_photos: 1,
                ..PipelineOptions::default()
            };
            let stripped: Vec<Input>;
            let inputs = if rasl {
                inputs
            } else {
                stripped = inputs
                    .iter()
                    .map(|i| Input {
                        points: i.points.clone(),
                        image: None,
                    })
                    .collect();
                &stripped
            };
            let result = reconstruct(inputs, reference, &options, |_| {})?;
            (result.output_mesh(), result.structure())
        }
    };
    let inner = inner_face_score(
        &mesh,
        &truth,
        (&structure, &truth_structure),
        &InnerFaceOptions::default(),
    )?
    .score
    .distance
    .mean;
    Ok((
        compare(
            &mesh,
            &truth,
            Some((&structure, &truth_structure)),
            &CompareOptions::default(),
        )?
        .stats,
        inner,
    ))
}

/// The figures a row reports.
fn figures((s, inner): &(CompareStats, Real)) -> [Real; 8] {
    [
        *inner,
        s.depth_error.mean,
        s.depth_error.p90,
        s.point_to_surface.mean,
        s.paper.mean_abs_dz_over_eye_distance,
        s.paper.structure_ssim.unwrap_or(Real::NAN),
        s.paper.depth_correlation.unwrap_or(Real::NAN),
        s.paper.percent_of_depth,
    ]
}

const HEADER: &str = "| inner face mm | mean \\|Δz\\| mm | p90 \\|Δz\\| mm | point-to-surface mm | \\|Δz\\|/eye distance | structure SSIM | depth r | 100·\\|Δz\\|/z % |";

fn mean_std(values: &[Real]) -> (Real, Real) {
    let n = values.len() as Real;
    let mean = values.iter().sum::<Real>() / n;
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<Real>() / (n - 1.0).max(1.0);
    (mean, var.sqrt())
}

fn row(name: &str, runs: &[[Real; 8]]) -> String {
    let mut line = format!("| {name} |");
    for k in 0..8 {
        let (m, s) = mean_std(&runs.iter().map(|r| r[k]).collect::<Vec<_>>());
        let digits = if (4..=6).contains(&k) { 4 } else { 2 };
        line.push_str(&format!(" {m:.digits$} ± {s:.digits$} |"));
    }
    line
}

/// A plotted line: its `(x, y)` points and its colour.
type Series = (Vec<(Real, Real)>, [u8; 3]);

/// A line plot of `series` on a log₂ x axis, labelled with digits; colours as listed.
fn plot(series: &[Series], path: &std::path::Path) -> Result<()> {
    let (w, h) = (640u32, 400u32);
    let (left, right, top, bottom) = (70.0, 620.0, 20.0, 350.0);
    let mut image = image::RgbImage::from_pixel(w, h, image::Rgb([25, 25, 30]));
    let xs: Vec<Real> = series
        .iter()
        .flat_map(|(s, _)| s.iter().map(|p| p.0.log2()))
        .collect();
    let ys: Vec<Real> = series.iter().flat_map(|(s, _)| s.iter().map(|p| p.1)).collect();
    let (x0, x1) = (
        xs.iter().copied().fold(Real::INFINITY, Real::min),
        xs.iter().copied().fold(Real::NEG_INFINITY, Real::max),
    );
    let y1 = ys.iter().copied().fold(0.0, Real::max) * 1.1;
    let px = |x: Real| left + (x.log2() - x0) / (x1 - x0).max(1e-9) * (right - left);
    let py = |y: Real| bottom - y / y1.max(1e-9) * (bottom - top);
    let mut dot = |x: Real, y: Real, c: [u8; 3], r: i64| {
        for dx in -r..=r {
            for dy in -r..=r {
                let (u, v) = (x as i64 + dx, y as i64 + dy);
                if u >= 0 && v >= 0 && (u as u32) < w && (v as u32) < h {
                    image.put_pixel(u as u32, v as u32, image::Rgb(c));
                }
            }
        }
    };
    for k in 0..=400 {
        let t = k as Real / 400.0;
        dot(left + t * (right - left), bottom, [200, 200, 200], 0);
        dot(left, bottom - t * (bottom - top), [200, 200, 200], 0);
    }
    for (points, colour) in series {
        for pair in points.windows(2) {
            for k in 0..=200 {
                let t = k as Real / 200.0;
                let x = px(pair[0].0).mul_add(1.0 - t, px(pair[1].0) * t);
                let y = py(pair[0].1).mul_add(1.0 - t, py(pair[1].1) * t);
                dot(x, y, *colour, 1);
            }
        }
        for p in points {
            dot(px(p.0), py(p.1), *colour, 3);
        }
    }
    let style = TextStyle::white(15.0);
    for p in &series[0].0 {
        let label = format!("{}", p.0);
        let x = px(p.0) as f32 - text_width(&label, style.size) / 2.0;
        draw_text(&mut image, &label, x, bottom as f32 + 6.0, style);
    }
    for k in 0..=4 {
        let y = y1 * k as Real / 4.0;
        draw_text(&mut image, &format!("{y:.1}"), 8.0, py(y) as f32 - 9.0, style);
    }
    draw_text(&mut image, "mm", 8.0, 2.0, style);
    image.save(path)?;
    Ok(())
}

fn main() -> Result<()> {
    let args = parse_args()?;
    let ict = Ict::load(&args.ict)?;
    std::fs::create_dir_all(&args.out)?;
    let start = std::time::Instant::now();
    let mut rng = Lcg(args.seed);
    let subjects: Vec<Subject> = (0..args.subjects)
        .map(|_| ict.random_subject(&mut rng, 1.0))
        .collect::<Result<_>>()?;

    // Table 1: every method on every subject.
    let mut results: Vec<Vec<[Real; 8]>> = vec![Vec::new(); METHODS.len()];
    let mut per_subject = String::new();
    for (s, subject) in subjects.iter().enumerate() {
        let inputs = photograph(&ict, subject, args.photos, args.noise, &mut rng)?;
        per_subject.push_str(&format!(
            "\n### Subject {}\n\n| method {HEADER}\n|---|---|---|---|---|---|---|---|---|\n",
            s + 1
        ));
        for (m, method) in METHODS.iter().enumerate() {
            let f = figures(&score(method, &inputs, subject)?);
            per_subject.push_str(
                &row(method.name, &[f])
                    .replace(" ± 0.00", "")
                    .replace(" ± 0.0000", ""),
            );
            per_subject.push('\n');
            results[m].push(f);
        }
        eprintln!(
            "subject {} of {} done ({:.0} s)",
            s + 1,
            args.subjects,
            start.elapsed().as_secs_f64()
        );
    }

    // Fig. 8(3): the error against the number of photos.
    let counts: Vec<usize> = if args.quick {
        vec![1, 2, 4, 8]
    } else {
        vec![1, 2, 4, 8, 16, 35]
    };
    let mut sweep: Vec<Vec<(Real, Real)>> = vec![Vec::new(); 2];
    let mut sweep_table = String::from(
        "| photos | default: mean \\|Δz\\| mm | paper: mean \\|Δz\\| mm | default: depth r | paper: depth r |\n|---|---|---|---|---|\n",
    );
    for &count in &counts {
        let mut errors = [Vec::new(), Vec::new()];
        let mut correlations = [Vec::new(), Vec::new()];
        for subject in &subjects {
            let inputs = photograph(&ict, subject, count, args.noise, &mut rng)?;
            for (k, m) in [DEFAULT, PAPER].into_iter().enumerate() {
                let f = figures(&score(&METHODS[m], &inputs, subject)?);
                errors[k].push(f[1]);
                correlations[k].push(f[6]);
            }
        }
        let (d, p) = (mean_std(&errors[0]), mean_std(&errors[1]));
        let (dr, pr) = (mean_std(&correlations[0]), mean_std(&correlations[1]));
        sweep[0].push((count as Real, d.0));
        sweep[1].push((count as Real, p.0));
        sweep_table.push_str(&format!(
            "| {count} | {:.2} ± {:.2} | {:.2} ± {:.2} | {:.4} | {:.4} |\n",
            d.0, d.1, p.0, p.1, dr.0, pr.0
        ));
        eprintln!("{count} photos done ({:.0} s)", start.elapsed().as_secs_f64());
    }
    plot(
        &[
            (sweep[0].clone(), [90, 170, 255]),
            (sweep[1].clone(), [255, 160, 60]),
        ],
        &args.out.join("error-vs-photos.png"),
    )?;

    // Table 2: neutral against expression photos of the same identities.
    let expressions: [&[(&str, Real)]; 3] = [
        &[("mouthSmile_L", 0.6), ("mouthSmile_R", 0.6)],
        &[("jawOpen", 0.4)],
        &[
            ("browInnerUp_L", 0.6),
            ("browInnerUp_R", 0.6),
            ("eyeWide_L", 0.4),
            ("eyeWide_R", 0.4),
        ],
    ];
    let mut neutral = Vec::new();
    let mut expressive = Vec::new();
    let mut identity_rng = Lcg(args.seed);
    for s in 0..args.subjects {
        let weights: Vec<Real> = (0..ict.modes).map(|_| identity_rng.gaussian()).collect();
        let plain = ict.subject(&weights)?;
        let inputs = photograph(&ict, &plain, args.photos, args.noise, &mut rng)?;
        neutral.push(figures(&score(&METHODS[DEFAULT], &inputs, &plain)?));
        // Photographed with an expression, scored against the neutral identity: the face the
        // default makes is the person's neutral face.
        let posed = ict.subject_with_expression(&weights, expressions[s % expressions.len()])?;
        let inputs = photograph(&ict, &posed, args.photos, args.noise, &mut rng)?;
        expressive.push(figures(&score(&METHODS[DEFAULT], &inputs, &plain)?));
    }

    let command = format!(
        "cargo run --release --example eval --{} --subjects {} --photos {} --noise {} --seed {}",
        if args.quick { " --quick" } else { "" },
        args.subjects,
        args.photos,
        args.noise,
        args.seed
    );
    let mut page = format!(
        "# Evaluation on ICT-FaceKit subjects\n\n\
         Made by `{command}` (tools/eval.rs) in {:.0} s on the development machine (2 cores). \
         {} subjects (identity weights ~ N(0, 1)), {} photos each (320 × 384, yaw ±60°, pitch ±25°, roll ±15°), \
         68 landmarks with noise σ = {}% of the eye distance; scored against each subject's own mesh, aligned by the \
         40-point structures; millimetres with 63 mm between the eye centres. Mean ± standard deviation over subjects.\n\n\
         ## Table 1: methods\n\n| method {HEADER}\n|---|---|---|---|---|---|---|---|---|\n",
        start.elapsed().as_secs_f64(),
        args.subjects,
        args.photos,
        args.noise
    );
    for (method, runs) in METHODS.iter().zip(&results) {
        page.push_str(&row(method.name, runs));
        page.push('\n');
    }
    let ratio_of = |method: usize| {
        let ratios: Vec<Real> = results[method]
            .iter()
            .zip(&results[0])
            .map(|(d, m)| d[0] / m[0])
            .collect();
        mean_std(&ratios)
    };
    let (ratio, spread) = ratio_of(DEFAULT);
    let (fixed, fixed_spread) = ratio_of(JAW_FIXED);
    page.push_str(&format!(
        "\nInner face (truth → surface over the truth's inner face after a similarity alignment, \
         `splineface::compare::inner_face_score`): the default is {ratio:.2} ± {spread:.2} times the mean face's error \
         ({fixed:.2} ± {fixed_spread:.2} with the jaw points tied to fixed places of the face).\n"
    ));
    eprintln!(
        "default / mean face, inner face: {ratio:.2} ± {spread:.2} (jaw fixed: {fixed:.2} ± {fixed_spread:.2})"
    );
    page.push_str(&format!(
        "\n## Fig. 8(3): error against the number of photos\n\n![error against photos](error-vs-photos.png)\n\n\
         Blue: the default; orange: the paper's method. Mean |Δz| in mm (y) against photos (x, log scale).\n\n{sweep_table}"
    ));
    page.push_str(&format!(
        "\n## Table 2: neutral against expression photos (the default method)\n\n| subjects {HEADER}\n|---|---|---|---|---|---|---|---|---|\n{}\n{}\n",
        row("neutral", &neutral),
        row(
            "with an expression (smile, open jaw, raised brows), scored against the neutral identity",
            &expressive
        )
    ));
    page.push_str(&format!("\n## Per subject\n{per_subject}"));
    let path = args.out.join("evaluation.md");
    std::fs::write(&path, page)?;
    println!(
        "wrote {} and error-vs-photos.png in {:.0} s",
        path.display(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}
