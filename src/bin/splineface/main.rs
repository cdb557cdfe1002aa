//! The `splineface` command line.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

mod args;

use anyhow::{Context, Result, bail};
use args::{
    BatchArgs, Cli, Command, CompareArgs, DemoArgs, FitReferenceArgs, FitSurfaceArgs, LandmarksArgs,
    ReconstructArgs, RenderDepthArgs,
};
use clap::Parser;
use splineface::bspline::BSplineSurface;
use splineface::compare::{CompareOptions, FileComparison, LengthUnit, MeshFiles, compare_files};
use splineface::face::Units;
use splineface::face::modes::ModeFiles;
use splineface::mesh::read_mesh;
use splineface::pipeline::{InputError, gather_inputs, photo_list};
use splineface::reference::{ReferenceFace, ReferenceOptions, ReferenceScan, build_reference};
use splineface::render::{DepthFormat, DepthMap, MAX_SIDE, View, shaded_png};

fn main() -> ExitCode {
    let result = run(Cli::parse());
    if let Some(Some(bar)) = BAR.get() {
        bar.finish_and_clear();
    }
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("error: {error:#}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Inspect(a) => inspect(&a.surface),
        Command::FitReference(a) => fit_reference(&a),
        Command::Reconstruct(a) => reconstruct_command(&a),
        Command::Batch(a) => batch_command(&a),
        Command::CompactModel(a) => compact_model(&a.model, &a.out),
        Command::Landmarks(a) => landmarks_command(&a),
        Command::Demo(a) => demo_command(&a),
        Command::RenderDepth(a) => render_depth(&a),
        Command::Compare(a) => compare(&a),
        Command::FitSurface(a) => fit_surface(&a),
    }
}

fn fit_surface(a: &FitSurfaceArgs) -> Result<()> {
    use splineface::scan::{ScanFitOptions, SurfaceFormat, fit_scan, read_scan_points, residual_paths};
    let normal = match &a.normal {
        None => None,
        Some(text) => {
            let values: Vec<f64> = text
                .split(',')
                .map(|t| t.trim().parse::<f64>())
                .collect::<Result<_, _>>()
                .ok()
                .filter(|v: &Vec<f64>| v.len() == 3)
                .with_context(|| format!("--normal {text}: expected X,Y,Z"))?;
            Some(nalgebra::Vector3::new(values[0], values[1], values[2]))
        }
    };
    let options = ScanFitOptions {
        degree: a.degree,
        grid: a.grid,
        tolerance: a.tolerance,
        max_grid: a.max_grid,
        smoothness: a.smoothness,
        normal,
    };
    options.validate().map_err(|e| anyhow::anyhow!("--{e}"))?;
    let unit = length_unit(&a.units, "--units")?;
    if SurfaceFormat::from_path(&a.out).is_none() {
        bail!("{}: the surface must be .json or .step", a.out.display());
    }
    if let Some(m) = &a.mesh
        && !matches!(
            splineface::mesh::MeshFormat::from_path(m),
            Some(splineface::mesh::MeshFormat::Obj | splineface::mesh::MeshFormat::Ply)
        )
    {
        bail!("{}: the mesh must be .obj or .ply", m.display());
    }
    let (report_path, heatmap_path) = residual_paths(&a.out);
    for path in [
        Some(a.out.as_path()),
        Some(&report_path),
        Some(&heatmap_path),
        a.mesh.as_deref(),
    ]
    .into_iter()
    .flatten()
    {
        check_output_file(path)?;
        let same = |x: &Path, y: &Path| {
            x.canonicalize()
                .ok()
                .is_some_and(|x| y.canonicalize().ok() == Some(x))
        };
        if same(path, &a.scan) {
            bail!("{}: an output would overwrite the scan", path.display());
        }
    }
    let points = read_scan_points(&a.scan)?;
    let start = std::time::Instant::now();
    let fit = fit_scan(&points, &options).map_err(|e| anyhow::anyhow!("{}: {e}", a.scan.display()))?;
    let seconds = start.elapsed().as_secs_f64();
    let report = fit.report_json(&a.scan.display().to_string(), &options, seconds);
    let files = fit.files(&a.out, a.mesh.as_deref(), &report, unit)?;
    write_files(&files)?;
    let s = &fit.surface;
    println!("{}", a.out.display());
    println!("  points      {}", points.len());
    println!(
        "  grid        {} × {} control points, degree {}",
        s.rows(),
        s.cols(),
        s.degree_u()
    );
    println!(
        "  residual    RMS {:.3e}, largest {:.3e} (scan units)",
        fit.rms, fit.max
    );
    let d = &fit.distances;
    println!(
        "  distance    RMS {:.3e}, 99% {:.3e}, largest {:.3e} (closest points of {} of the points)",
        d.rms, d.p99, d.max, d.count
    );
    if fit.layered > 0.0 {
        println!(
            "  folds       {:.1}% of the points lie where the scan has two layers; fitted through",
            100.0 * fit.layered
        );
    }
    match (fit.tolerance, fit.within_tolerance) {
        (Some(t), Some(true)) => println!("  tolerance   {t} met after {} fits", fit.rounds),
        (Some(t), _) => println!(
            "  tolerance   {t} NOT met after {} fits: no knot cell over it holds the {} points a split needs, or the grid reached --max-grid {}",
            fit.rounds,
            splineface::scan::MIN_SPLIT_POINTS,
            a.max_grid
        ),
        _ => {}
    }
    println!("  report      {}", report_path.display());
    println!("  heatmap     {}", heatmap_path.display());
    println!("  fit time    {:.1} ms", seconds * 1e3);
    if fit.within_tolerance == Some(false) {
        eprintln!("warning: the tolerance was not met (see the heatmap for where)");
    }
    Ok(())
}

/// Parses `W` or `WxH`.
fn parse_size(text: &str) -> Result<(usize, usize)> {
    let parse = |t: &str| {
        t.trim()
            .parse::<usize>()
            .ok()
            .filter(|&n| (1..=MAX_SIDE).contains(&n))
    };
    let size = match text.split_once(['x', 'X']) {
        Some((w, h)) => parse(w).zip(parse(h)),
        None => parse(text).map(|n| (n, n)),
    };
    size.with_context(|| format!("--size `{text}`: expected W or WxH, each between 1 and {MAX_SIDE}"))
}

fn render_depth(a: &RenderDepthArgs) -> Result<()> {
    let (mesh_path, out, size, view, preview) = (
        a.mesh.as_path(),
        a.out.as_path(),
        &a.size,
        &a.view,
        a.preview.as_deref(),
    );
    let (width, height) = parse_size(size)?;
    let view = View::parse(view).map_err(|e| anyhow::anyhow!("--view: {e}"))?;
    let format = DepthFormat::from_path(out)
        .with_context(|| format!("{}: the depth map must be .exr or .png", out.display()))?;
    if let Some(p) = preview
        && DepthFormat::from_path(p) != Some(DepthFormat::Png)
    {
        bail!("{}: the preview must be .png", p.display());
    }
    check_output_file(out)?;
    if let Some(p) = preview {
        check_output_file(p)?;
    }
    let mesh = read_mesh(mesh_path)?;
    let start = std::time::Instant::now();
    let map = DepthMap::framed(&mesh, &view, width, height)
        .map_err(|e| anyhow::anyhow!("{}: {e}", mesh_path.display()))?;
    let elapsed = start.elapsed();
    let encode_error = |e: splineface::io::EncodeError| anyhow::anyhow!("{}: {e}", out.display());
    let mut files = vec![(out.to_path_buf(), format.encode(&map).map_err(encode_error)?)];
    if let Some(p) = preview {
        files.push((p.to_path_buf(), shaded_png(&map).map_err(encode_error)?));
    }
    write_files(&files)?;
    let (lo, hi) = map.range().unwrap_or((0.0, 0.0));
    println!("{}", out.display());
    println!(
        "  pixels      {width} × {height}, {:.4} units each",
        map.raster.spacing
    );
    println!("  covered     {} pixels", map.covered());
    println!("  heights     {lo:.3} to {hi:.3}");
    println!(
        "  render time {:.1} ms ({} triangles)",
        elapsed.as_secs_f64() * 1e3,
        mesh.triangles().len()
    );
    Ok(())
}

/// [`splineface::io::check_output_dir`].
fn check_output_dir(out: &Path) -> Result<()> {
    Ok(splineface::io::check_output_dir(out)?)
}

/// [`splineface::io::check_output_file`].
fn check_output_file(path: &Path) -> Result<()> {
    Ok(splineface::io::check_output_file(path)?)
}

fn write_files(files: &[(PathBuf, Vec<u8>)]) -> Result<()> {
    splineface::io::write_files_atomically(files)
        .map_err(|(path, e)| anyhow::anyhow!("cannot write {}: {e}", path.display()))
}

/// `--reconstruction-units` and `--truth-units`.
fn length_unit(text: &str, flag: &str) -> Result<LengthUnit> {
    LengthUnit::parse(text).with_context(|| format!("{flag} `{text}`: expected mm, cm or m"))
}

fn compare(a: &CompareArgs) -> Result<()> {
    let files = MeshFiles {
        reconstruction: a.reconstruction.clone(),
        truth: a.truth.clone(),
        landmarks: a.reconstruction_landmarks.clone().zip(a.truth_landmarks.clone()),
        surface: a.reconstruction_surface.clone(),
        units: (
            length_unit(&a.reconstruction_units, "--reconstruction-units")?,
            length_unit(&a.truth_units, "--truth-units")?,
        ),
    };
    let options = CompareOptions {
        size: a.size,
        heatmap_max: a.max,
        ..CompareOptions::default()
    };
    options
        .validate()
        .map_err(|e| anyhow::anyhow!(e.flag_message()))?;
    check_output_dir(&a.out)?;
    let start = std::time::Instant::now();
    let FileComparison {
        comparison: result,
        mean_face,
        inner_face_surface,
    } = compare_files(&files, &options)?;
    let elapsed = start.elapsed();
    let mut extra = serde_json::Map::new();
    extra.insert(
        "reconstruction".into(),
        files.reconstruction.display().to_string().into(),
    );
    extra.insert("truth".into(), files.truth.display().to_string().into());
    extra.insert("units".into(), "mm".into());
    extra.insert("heatmap_max".into(), result.heatmap_max.into());
    extra.insert("inner_face_mean_face".into(), serde_json::to_value(mean_face)?);
    if let Some(path) = &files.surface {
        extra.insert("surface".into(), path.display().to_string().into());
        extra.insert(
            "inner_face_surface".into(),
            serde_json::to_value(inner_face_surface)?,
        );
    }
    write_into(&a.out, &result.files(extra, true)?)?;
    let s = &result.stats;
    println!("{}", a.out.display());
    println!(
        "  alignment      {} (scale {:.4}, RMS {:.3} mm)",
        s.alignment.method, s.alignment.scale, s.alignment.rms
    );
    println!(
        "  pixels         {} compared, {:.3} mm each",
        s.pixels_compared, s.pixel_size
    );
    println!(
        "  |Δz| mm        mean {:.3}, median {:.3}, 90% {:.3}, max {:.3}",
        s.depth_error.mean, s.depth_error.median, s.depth_error.p90, s.depth_error.max
    );
    println!(
        "  to surface mm  mean {:.3}, median {:.3}, 90% {:.3}",
        s.point_to_surface.mean, s.point_to_surface.median, s.point_to_surface.p90
    );
    println!(
        "  paper          |Δz|/eye distance {:.4}, {:.2}% of depth{}{}",
        s.paper.mean_abs_dz_over_eye_distance,
        s.paper.percent_of_depth,
        s.paper
            .structure_ssim
            .map_or(String::new(), |v| format!(", structure SSIM {v:.4}")),
        s.paper
            .depth_correlation
            .map_or(String::new(), |v| format!(", depth r {v:.4}")),
    );
    if let (Some(f), Some(m)) = (s.inner_face, mean_face) {
        println!(
            "  inner face mm  mean {:.3}, median {:.3}, 90% {:.3}, coverage {:.3}; the mean face: mean {:.3} ({:.2}× its error)",
            f.distance.mean,
            f.distance.median,
            f.distance.p90,
            f.coverage,
            m.distance.mean,
            f.distance.mean / m.distance.mean
        );
    }
    if let Some(f) = inner_face_surface {
        println!(
            "  exact surface  mean {:.3}, median {:.3}, 90% {:.3} (the inner face, to the spline)",
            f.distance.mean, f.distance.median, f.distance.p90
        );
    }
    println!("  time           {:.0} ms", elapsed.as_secs_f64() * 1e3);
    Ok(())
}

fn inspect(path: &Path) -> Result<()> {
    let surface = BSplineSurface::read_json(path)?;
    let (u0, u1) = surface.domain_u();
    let (v0, v1) = surface.domain_v();
    println!("{}", path.display());
    println!("  degrees      {} × {}", surface.degree_u(), surface.degree_v());
    println!("  control grid {} × {}", surface.rows(), surface.cols());
    println!("  domain       u ∈ [{u0}, {u1}], v ∈ [{v0}, {v1}]");
    let (lo, hi) =
        splineface::geometry::bounding_box(surface.control_points()).context("no control points")?;
    println!(
        "  control box  [{:.6}, {:.6}] × [{:.6}, {:.6}] × [{:.6}, {:.6}]",
        lo.x, hi.x, lo.y, hi.y, lo.z, hi.z
    );
    Ok(())
}

fn fit_reference(a: &FitReferenceArgs) -> Result<()> {
    let (meshes, landmarks, out, note) = (&a.meshes, &a.landmarks, a.out.as_path(), a.note.as_str());
    let options = &ReferenceOptions {
        grid: a.grid,
        smoothness: a.smoothness,
        sample_spacing: a.sample_spacing,
        ..ReferenceOptions::default()
    };
    let modes = a.identity_modes.clone().map(|identity| ModeFiles {
        identity,
        expressions: a.expression_modes.clone().zip(a.expression_names.clone()),
        note: a.modes_note.clone(),
    });
    let modes = modes.as_ref();
    let space_from_scans = a.space_from_scans;
    if meshes.len() != landmarks.len() {
        bail!(
            "{} --mesh but {} --landmarks: give one landmark file per scan",
            meshes.len(),
            landmarks.len()
        );
    }
    if modes.is_some() && meshes.len() != 1 {
        bail!(
            "--identity-modes are displacement fields of one scan; {} scans were given",
            meshes.len()
        );
    }
    options.validate()?;
    check_output_file(out)?;
    let scans = meshes
        .iter()
        .zip(landmarks)
        .map(|(mesh, landmarks)| ReferenceScan::read(mesh, landmarks))
        .collect::<Result<Vec<_>, _>>()?;
    let start = std::time::Instant::now();
    let mut reference = if space_from_scans {
        splineface::reference::build_reference_with_space(&scans, options, note)?
    } else {
        build_reference(&scans, options, note)?
    };
    if let Some(modes) = modes {
        reference = modes.build(reference, &scans[0], &landmarks[0])?;
    }
    let elapsed = start.elapsed();
    splineface::io::write_atomically(out, reference.to_json().as_bytes())
        .with_context(|| format!("cannot write {}", out.display()))?;
    let fit = reference.fit();
    let mm = splineface::face::Units::default().per_canonical_unit();
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
    if let Some(space) = reference.space_modes() {
        println!(
            "  face space     {} identity and {} expression modes{}",
            space.sigma.len(),
            space.expressions.len(),
            if space.landmark_base.is_empty() {
                ""
            } else {
                ", moving the 68 landmarks"
            }
        );
    }
    println!("  time           {:.0} ms", elapsed.as_secs_f64() * 1e3);
    Ok(())
}

fn write_into(out: &Path, files: &[(PathBuf, Vec<u8>)]) -> Result<()> {
    Ok(splineface::io::write_into(out, files)?)
}

/// The progress display: a spinner with the current stage when standard error is a terminal,
/// plain lines otherwise (logs, pipes, tests).
static BAR: std::sync::OnceLock<Option<indicatif::ProgressBar>> = std::sync::OnceLock::new();

fn progress_bar() -> Option<&'static indicatif::ProgressBar> {
    use std::io::IsTerminal;
    BAR.get_or_init(|| {
        std::io::stderr().is_terminal().then(|| {
            let bar = indicatif::ProgressBar::new_spinner();
            bar.set_style(
                indicatif::ProgressStyle::with_template("{spinner} [{elapsed}] {msg}")
                    .unwrap_or_else(|_| indicatif::ProgressStyle::default_spinner()),
            );
            bar.enable_steady_tick(std::time::Duration::from_millis(100));
            bar
        })
    })
    .as_ref()
}

fn progress(message: &str) {
    match progress_bar() {
        Some(bar) => {
            bar.println(format!("splineface: {message}"));
            bar.set_message(message.to_owned());
        }
        None => eprintln!("splineface: {message}"),
    }
}

fn reconstruct_command(a: &ReconstructArgs) -> Result<()> {
    let (photos, photo_dir, landmark_dir) = (&a.photos, a.photo_dir.as_deref(), a.landmarks.as_deref());
    let (reference_path, landmark_model) = (a.face.reference.as_deref(), a.face.landmark_model.as_deref());
    let (out, output) = (a.out.as_path(), &a.output);
    let start = std::time::Instant::now();
    let options = output.options()?;
    check_output_dir(out)?;
    let model_start = std::time::Instant::now();
    // Read before the photos, not beside them: read on a thread of its own while the photos
    // were decoded and their faces found, it made the whole no faster (`tools/ab-bench`,
    // `lps-head/photos-8`, 6 runs by turns: wall 1.07 / 1.15 s best / median against 1.07 /
    // 1.10; the photos' stage 185 → 229 ms best, as the read's page faults and copies take the
    // same cores) and the peak 171 → 183 MB.
    let predictor = landmark_model.map(read_model).transpose()?;
    let model_seconds = predictor.is_some().then(|| model_start.elapsed().as_secs_f64());
    let reference = read_reference(reference_path)?;
    let photo_paths = photo_list(photos, photo_dir)?;
    if !photo_paths.is_empty() {
        progress(&format!("reading {} photos", photo_paths.len()));
    }
    let set = gather_inputs(&photo_paths, landmark_dir, predictor.as_ref()).map_err(|e| match e {
        InputError::Nothing => anyhow::anyhow!(
            "nothing to reconstruct from: give photos (PHOTO... or --photos DIR) and/or --landmarks DIR"
        ),
        InputError::NoLandmarks => anyhow::anyhow!(
            "the photos need landmarks: give --landmarks DIR (a STEM.pts or STEM.json per photo) or \
             --landmark-model PATH (dlib's shape_predictor_68_face_landmarks.dat, see tools/fetch-models) \
             to detect and landmark the faces"
        ),
        e => e.into(),
    })?;
    if photo_paths.is_empty() {
        progress(&format!(
            "points only: {} landmark files",
            set.inputs.len() + set.skipped.len()
        ));
    }
    for note in &set.warnings {
        progress(note);
    }
    for s in &set.skipped {
        progress(&format!("skipped {s}"));
    }
    if let Err(InputError::TooFewPhotos {
        usable,
        needed,
        skipped,
    }) = set.check_count(options.min_photos)
    {
        bail!(
            "{usable} usable photo{}, at least {needed} needed (--min-photos){}{}",
            if usable == 1 { "" } else { "s" },
            skipped
                .iter()
                .map(|s| format!("\n  skipped {s}"))
                .collect::<String>(),
            if predictor.is_some() && !photo_paths.is_empty() {
                "\n  (`splineface landmarks PHOTO... --out DIR` draws what the detector found on each photo)"
            } else {
                ""
            }
        );
    }
    // The landmark model (67 MB in its compact form) is done with: let it go before the
    // stages whose buffers make the run's peak (RASL, the texture).
    drop(predictor);
    let mut options = options;
    options.expression_of = output.expression_photo(&set.inputs)?;
    let (result, files) = set.reconstruct_files(&reference, &options, progress, model_seconds)?;
    let writing = std::time::Instant::now();
    write_into(out, &files)?;
    let writing = writing.elapsed();
    for d in &result.dropped {
        progress(&format!("dropped {}: {}", d.name, d.reason));
    }
    for w in &result.depth.warnings {
        progress(&format!("warning: {w}"));
    }
    println!("{}", out.display());
    println!(
        "  photos     {} used{}",
        result.depth.photos.len(),
        if set.skipped.is_empty() {
            String::new()
        } else {
            format!(", {} skipped", set.skipped.len())
        }
    );
    println!(
        "  frontal    {:?} (residual {:.2} units)",
        result.frontal.method, result.frontal.residual_rms
    );
    println!(
        "  depth      SIM {:.4}, {} iterations",
        result.depth.similarity, result.depth.iterations
    );
    println!(
        "  mesh       {} vertices, {} triangles{}",
        result.mesh.mesh.positions().len(),
        result.mesh.mesh.triangles().len(),
        match &result.texture {
            Some(texture) => format!(", textured ({side} × {side} atlas)", side = texture.atlas.width()),
            None => String::new(),
        }
    );
    println!("  files      {}", files.len());
    println!("  time       {:.2} s", start.elapsed().as_secs_f64());
    // Every stage's time, as report.json has them.
    if let Some((_, bytes)) = files.iter().find(|(p, _)| p == Path::new("report.json"))
        && let Ok(report) = serde_json::from_slice::<serde_json::Value>(bytes)
    {
        for stage in report["timings"].as_array().into_iter().flatten() {
            if let (Some(name), Some(ms)) = (stage["stage"].as_str(), stage["ms"].as_f64()) {
                println!("    {ms:>8.0} ms  {name}");
            }
        }
    }
    println!("    {:>8.0} ms  writing the files", writing.as_secs_f64() * 1e3);
    Ok(())
}

/// The landmark model at `path` (dlib's `.dat` or its compact form), announced on the
/// progress display.
fn read_model(path: &Path) -> Result<splineface::landmarker::ShapePredictor> {
    progress(&format!("reading the landmark model {}", path.display()));
    Ok(splineface::landmarker::ShapePredictor::read(path)?)
}

/// A reference face file ([`ReferenceFace::read`]), or the embedded one when `path` is `None`.
fn read_reference(path: Option<&Path>) -> Result<ReferenceFace> {
    match path {
        Some(path) => Ok(ReferenceFace::read(path)?),
        None => Ok(ReferenceFace::embedded().clone()),
    }
}

fn batch_command(a: &BatchArgs) -> Result<()> {
    let (root, out, force, output) = (a.root.as_path(), a.out.as_path(), a.force, &a.output);
    let (reference_path, landmark_model) = (a.face.reference.as_deref(), a.face.landmark_model.as_deref());
    use splineface::batch::{
        BatchJob, Status, check_output, file_identity, run_subjects, status_counts, subjects, write_summary,
    };
    let options = output.options()?;
    if output.expression_of.is_some() {
        bail!("--expression-of names one photo; it has no meaning for a batch");
    }
    let subjects = subjects(root)?;
    check_output(root, out)?;
    let reference = read_reference(reference_path)?;
    let predictor = landmark_model.map(read_model).transpose()?;
    let job = BatchJob {
        model: predictor.as_ref(),
        model_identity: file_identity(landmark_model)?,
        reference: &reference,
        reference_identity: file_identity(reference_path)?,
        options,
        force,
    };
    let start = std::time::Instant::now();
    let total = subjects.len();
    let bar = {
        use std::io::IsTerminal;
        std::io::stderr().is_terminal().then(|| {
            let bar = indicatif::ProgressBar::new(total as u64);
            bar.set_style(
                indicatif::ProgressStyle::with_template(
                    "[{elapsed}] {bar:30} {pos}/{len} subjects, ETA {eta} {msg}",
                )
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
            );
            bar
        })
    };
    let rows = run_subjects(&subjects, out, &job, |row, done| {
        let line = format!(
            "{}: {}{} ({:.1} s)",
            row.subject,
            row.status.name(),
            if row.message.is_empty() {
                String::new()
            } else {
                format!(": {}", row.message)
            },
            row.seconds
        );
        match &bar {
            Some(bar) => {
                bar.println(line);
                bar.inc(1);
            }
            None => {
                let elapsed = start.elapsed().as_secs_f64();
                let eta = elapsed / done as f64 * (total - done) as f64;
                eprintln!("splineface: [{done}/{total}, ETA {eta:.0} s] {line}");
            }
        }
    });
    if let Some(bar) = &bar {
        bar.finish_and_clear();
    }
    write_summary(out, &rows)?;
    let [done, unchanged, failed] = status_counts(&rows);
    let seconds = start.elapsed().as_secs_f64();
    println!("{}", out.display());
    println!("  subjects   {total}: {done} done, {unchanged} unchanged, {failed} failed");
    println!(
        "  time       {seconds:.1} s ({:.1} subjects a minute)",
        if seconds > 0.0 {
            60.0 * (done + failed) as f64 / seconds
        } else {
            0.0
        }
    );
    println!("  summary    {}", out.join("summary.csv").display());
    if failed > 0 {
        bail!(
            "{failed} of {total} subjects failed (see {}):{}",
            out.join("summary.csv").display(),
            rows.iter()
                .filter(|r| r.status == Status::Failed)
                .map(|r| format!("\n  {}: {}", r.subject, r.message))
                .collect::<String>()
        );
    }
    Ok(())
}

fn demo_command(a: &DemoArgs) -> Result<()> {
    let (out, photos, noise, seed, output) = (a.out.as_path(), a.photos, a.noise, a.seed, &a.output);
    let mut options = output.options()?;
    let scene_options = splineface::demo::SceneOptions {
        photos,
        noise: noise / 100.0,
        seed,
        ..splineface::demo::SceneOptions::default()
    };
    // The settings checked before any work: `scene` checks them again.
    scene_options
        .validate()
        .map_err(|e| anyhow::anyhow!(e.flag_message()))?;
    check_output_dir(out)?;
    let start = std::time::Instant::now();
    progress(&format!(
        "photographing the demo subject: {photos} photos, landmark noise {noise}% of the eye distance"
    ));
    let scene = splineface::demo::scene(&scene_options)?;
    options.expression_of = output.expression_photo(&scene.inputs)?;
    let demo = splineface::demo::Demo::run(scene, &options, progress)?;
    let mut warnings = Vec::new();
    let files = demo.files(&mut warnings)?;
    for w in &warnings {
        progress(&format!("warning: {w}"));
    }
    write_into(out, &files)?;

    let s = &demo.comparison.stats;
    let b = &demo.baseline.stats;
    let unit = if matches!(options.units, Units::Canonical) {
        "units"
    } else {
        "mm"
    };
    println!(
        "splineface demo: {} photos of the demo subject, reconstructed and compared with the truth",
        photos
    );
    println!();
    let inner = |s: &splineface::compare::CompareStats| {
        s.inner_face
            .map_or_else(|| "-".to_owned(), |f| format!("{:.3}", f.distance.mean))
    };
    let rows: Vec<(String, String, String, &str)> = vec![
        (
            format!("inner face ({unit})"),
            inner(s),
            inner(b),
            "truth → surface, similarity-aligned",
        ),
        (
            format!("mean |Δz| ({unit})"),
            format!("{:.3}", s.depth_error.mean),
            format!("{:.3}", b.depth_error.mean),
            "",
        ),
        (
            format!("90th percentile |Δz| ({unit})"),
            format!("{:.3}", s.depth_error.p90),
            format!("{:.3}", b.depth_error.p90),
            "",
        ),
        (
            format!("point-to-surface ({unit})"),
            format!("{:.3}", s.point_to_surface.mean),
            format!("{:.3}", b.point_to_surface.mean),
            "",
        ),
        (
            "|Δz| / eye distance".into(),
            format!("{:.4}", s.paper.mean_abs_dz_over_eye_distance),
            format!("{:.4}", b.paper.mean_abs_dz_over_eye_distance),
            "paper: 0.1203 (Bosphorus)",
        ),
        (
            "structure SSIM".into(),
            format!("{:.4}", s.paper.structure_ssim.unwrap_or(0.0)),
            format!("{:.4}", b.paper.structure_ssim.unwrap_or(0.0)),
            "paper: 0.9312",
        ),
        (
            "depth correlation".into(),
            format!("{:.4}", s.paper.depth_correlation.unwrap_or(0.0)),
            format!("{:.4}", b.paper.depth_correlation.unwrap_or(0.0)),
            "paper: 0.9034",
        ),
        (
            "100·|Δz|/z (%)".into(),
            format!("{:.2}", s.paper.percent_of_depth),
            format!("{:.2}", b.paper.percent_of_depth),
            "",
        ),
    ];
    println!("  {:<30} {:>14} {:>12}", "", "reconstruction", "mean face");
    for (name, ours, base, note) in rows {
        println!(
            "{}",
            format!("  {name:<30} {ours:>14} {base:>12}   {note}").trim_end()
        );
    }
    println!();
    println!(
        "  outputs    {}/reconstruction (face.obj, face.glb, surface.step, depth.exr, ...)",
        out.display()
    );
    println!(
        "  photos     {}/photos (rerun: splineface reconstruct --photos {0}/photos --landmarks {0}/photos --out DIR)",
        out.display()
    );
    println!("  heatmap    {}/compare/heatmap.png", out.display());
    println!("  report     {}/report.html", out.display());
    println!("  time       {:.1} s", start.elapsed().as_secs_f64());
    Ok(())
}

fn compact_model(model: &Path, out: &Path) -> Result<()> {
    use splineface::landmarker::{Compacted, write_compact};
    match write_compact(model, out)? {
        Compacted::UpToDate => println!(
            "{} is up to date (made from this {})",
            out.display(),
            model.display()
        ),
        Compacted::Written => println!("{}", out.display()),
    }
    Ok(())
}

fn landmarks_command(a: &LandmarksArgs) -> Result<()> {
    let (photos, photo_dir, landmark_model) =
        (&a.photos, a.photo_dir.as_deref(), a.landmark_model.as_deref());
    let (out, json) = (a.out.as_path(), a.json);
    let paths = photo_list(photos, photo_dir)?;
    if paths.is_empty() {
        bail!("no photos: give PHOTO... or --photos DIR");
    }
    let Some(model_path) = landmark_model else {
        bail!(
            "--landmark-model PATH is needed (dlib's shape_predictor_68_face_landmarks.dat; tools/fetch-models \
             downloads it), or set SPLINEFACE_LANDMARK_MODEL"
        );
    };
    check_output_dir(out)?;
    let model = read_model(model_path)?;
    let landmarked = splineface::pipeline::landmark_photos(&paths, &model, json)?;
    write_into(out, &landmarked.files)?;
    println!("{}", out.display());
    for line in &landmarked.lines {
        println!("  {line}");
    }
    Ok(())
}
