//! The `splineface` command line.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use splineface::bspline::BSplineSurface;
use splineface::compare::{CompareOptions, FileComparison, LengthUnit, MeshFiles, compare_files};
use splineface::face::Units;
use splineface::face::modes::ModeFiles;
use splineface::mesh::read_mesh;
use splineface::pipeline::{Input, InputError, PipelineOptions, gather_inputs, photo_list, reconstruct};
use splineface::reference::{ReferenceFace, ReferenceOptions, ReferenceScan, build_reference};
use splineface::render::{
    DepthMap, MAX_SIDE, View, encode_depth_exr, encode_depth_png, frame_raster, shaded_png,
};

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
    /// Fit a reference face (control grid, 40-point structure, clip region) to face scans.
    ///
    /// Give one `--landmarks` per `--mesh`, in the same order; several pairs give one reference
    /// from their mean.
    #[command(allow_negative_numbers = true)]
    FitReference {
        /// A scan: OBJ, PLY, glTF or GLB.
        #[arg(long = "mesh", required = true)]
        meshes: Vec<PathBuf>,
        /// Its landmarks: 68 vertex indices (a text file, one a line, `#` comments) or a JSON
        /// landmark file with 3D points (68 iBUG or the 40 of the structure).
        #[arg(long = "landmarks", required = true)]
        landmarks: Vec<PathBuf>,
        /// The reference file to write (JSON).
        #[arg(long)]
        out: PathBuf,
        /// Control points along each side of the cubic grid.
        #[arg(long, default_value_t = ReferenceOptions::default().grid)]
        grid: usize,
        /// Thin-plate smoothness weight λ.
        #[arg(long, default_value_t = ReferenceOptions::default().smoothness)]
        smoothness: f64,
        /// Distance between frontal samples, canonical units (50 between the eye centres).
        #[arg(long, default_value_t = ReferenceOptions::default().sample_spacing)]
        sample_spacing: f64,
        /// Free text stored in the file's provenance (licence, origin).
        #[arg(long, default_value = "")]
        note: String,
        /// Identity modes of the face space: per-vertex displacement fields of the (single)
        /// scan, as little-endian float32 `[mode][vertex][x, y, z]` in the scan's own frame and
        /// units (the size must be a multiple of the scan's vertices × 12 bytes), each the
        /// displacement of one prior standard deviation (a plausible face is
        /// `scan + Σ wₖ·modeₖ` with `wₖ ~ N(0, 1)`). Needs the landmarks as vertex indices.
        #[arg(long, value_name = "FILE")]
        identity_modes: Option<PathBuf>,
        /// Expression modes (blendshapes) of the face space, laid out like `--identity-modes`,
        /// each the displacement of the full expression (weights in `[0, 1]`).
        #[arg(
            long,
            value_name = "FILE",
            requires = "expression_names",
            requires = "identity_modes"
        )]
        expression_modes: Option<PathBuf>,
        /// The expression modes' names, one a line (blank lines and `#` comments skipped).
        #[arg(long, value_name = "FILE", requires = "expression_modes")]
        expression_names: Option<PathBuf>,
        /// Where the modes came from (licence, origin), stored with them.
        #[arg(long, default_value = "")]
        modes_note: String,
        /// Learn a face space from the scans themselves (three or more): the principal
        /// components of their own fitted grids, each scan a sample of the faces it stands for.
        #[arg(long, conflicts_with = "identity_modes")]
        space_from_scans: bool,
    },
    /// Reconstruct a face from photos and/or their landmark files.
    ///
    /// Landmark files (`.pts` with 68 iBUG or 40 structure points, or landmark JSON) are
    /// matched to photos by file stem in `--landmarks`; with landmarks and no photos the run is
    /// points-only (no RASL, no texture).
    #[command(allow_negative_numbers = true)]
    Reconstruct {
        /// Photos (JPEG, PNG, BMP, TIFF, WebP).
        photos: Vec<PathBuf>,
        /// A directory of photos (every image file in it, by name).
        #[arg(long = "photos")]
        photo_dir: Option<PathBuf>,
        /// A directory of landmark files, one per photo, named like the photo.
        #[arg(long)]
        landmarks: Option<PathBuf>,
        /// The directory to write into (created if missing).
        #[arg(long)]
        out: PathBuf,
        #[command(flatten)]
        face: FaceArgs,
        #[command(flatten)]
        output: OutputArgs,
    },
    /// Reconstruct many subjects: one sub-folder of ROOT per subject (its photos and/or
    /// landmark files), each written to OUT/NAME as `reconstruct` writes it, subjects in
    /// parallel with the model loaded once. Resumable: a subject whose inputs and options are
    /// unchanged since its outputs were written is skipped. Writes OUT/summary.csv and
    /// OUT/summary.jsonl (one row per subject); a failed subject is a row, never the end of
    /// the batch (the exit status is 1 if any failed).
    Batch {
        /// The folder of subject folders.
        root: PathBuf,
        /// The directory to write into (created if missing; not inside ROOT).
        #[arg(long)]
        out: PathBuf,
        /// Reconstruct every subject, even those whose outputs are up to date.
        #[arg(long)]
        force: bool,
        #[command(flatten)]
        face: FaceArgs,
        #[command(flatten)]
        output: OutputArgs,
    },
    /// Detect the face in each photo and find its 68 landmarks: writes `NAME.pts` (iBUG,
    /// readable back by `reconstruct --landmarks DIR`), with `--json` also `NAME.json` (the
    /// project's landmark JSON), and `overlays/NAME.png` (the photo with the face box and the
    /// points, or why none were found).
    Landmarks {
        /// Photos (JPEG, PNG, BMP, TIFF, WebP).
        photos: Vec<PathBuf>,
        /// A directory of photos (every image file in it, by name).
        #[arg(long = "photos")]
        photo_dir: Option<PathBuf>,
        /// dlib's 68-point model (`shape_predictor_68_face_landmarks.dat`; `tools/fetch-models`
        /// downloads it). Default: $SPLINEFACE_LANDMARK_MODEL.
        #[arg(long, env = "SPLINEFACE_LANDMARK_MODEL")]
        landmark_model: Option<PathBuf>,
        /// The directory to write into (created if missing).
        #[arg(long)]
        out: PathBuf,
        /// Also write each photo's landmarks as landmark JSON (`NAME.json`).
        #[arg(long)]
        json: bool,
    },
    /// Write dlib's landmark model in splineface's compact form, which loads in a fraction of
    /// the time (the same trees, bit for bit; `--landmark-model` takes either). An existing
    /// output made from the same `.dat` (by its recorded length and hash) is left as it is.
    CompactModel {
        /// dlib's `shape_predictor_68_face_landmarks.dat`.
        model: PathBuf,
        /// The compact file to write (e.g. `shape_predictor_68_face_landmarks.sfsp`).
        #[arg(long)]
        out: PathBuf,
    },
    /// Run the whole pipeline on the embedded demo subject: render a dozen photos of it under
    /// varied poses, reconstruct the face and compare it with the truth.
    #[command(allow_negative_numbers = true)]
    Demo {
        /// The directory to write into (created if missing).
        #[arg(long, default_value = "splineface-demo")]
        out: PathBuf,
        /// How many photos to take.
        #[arg(long, default_value_t = 12)]
        photos: usize,
        /// Landmark noise, percent of the eye distance.
        #[arg(long, default_value_t = 1.0)]
        noise: f64,
        /// The random seed of the poses and the noise.
        #[arg(long, default_value_t = 2016)]
        seed: u64,
        #[command(flatten)]
        output: OutputArgs,
    },
    /// Render a mesh's orthographic depth map: EXR (float32 `Z` with a coverage channel `A`)
    /// or 16-bit PNG (0 = background), chosen by the output's extension.
    #[command(allow_negative_numbers = true)]
    RenderDepth {
        /// The mesh: OBJ, PLY, glTF or GLB.
        mesh: PathBuf,
        /// The depth map to write: `.exr` or `.png`.
        #[arg(long)]
        out: PathBuf,
        /// Pixels: `W` (square) or `WxH`.
        #[arg(long, default_value = "512")]
        size: String,
        /// `front`, or `YAW,PITCH,ROLL` in degrees (the pose convention of `structure.json`).
        #[arg(long, default_value = "front", allow_hyphen_values = true)]
        view: String,
        /// Also write a shaded preview (PNG).
        #[arg(long)]
        preview: Option<PathBuf>,
    },
    /// Compare a reconstruction with a ground-truth scan: align them, render both depth maps
    /// and write the |Δz| heatmap, the depth maps and stats.json (the paper's measures and
    /// millimetre errors) into a directory.
    #[command(allow_negative_numbers = true)]
    Compare {
        /// The reconstructed face (OBJ, PLY, glTF or GLB).
        reconstruction: PathBuf,
        /// The ground-truth scan.
        truth: PathBuf,
        /// The directory to write into (created if missing).
        #[arg(long)]
        out: PathBuf,
        /// The reconstruction's landmarks (JSON with 3D points, or 68 vertex indices); with
        /// `--truth-landmarks`, the two are aligned by a similarity between their structures
        /// instead of rigid ICP.
        #[arg(long, requires = "truth_landmarks")]
        reconstruction_landmarks: Option<PathBuf>,
        /// The truth's landmarks (as above).
        #[arg(long, requires = "reconstruction_landmarks")]
        truth_landmarks: Option<PathBuf>,
        /// Units of the reconstruction's coordinates: mm, cm or m.
        #[arg(long, default_value = "mm")]
        reconstruction_units: String,
        /// Units of the truth's coordinates: mm, cm or m.
        #[arg(long, default_value = "mm")]
        truth_units: String,
        /// Pixels along the depth maps' longer side.
        #[arg(long, default_value_t = 512)]
        size: usize,
        /// The heatmap's scale top in mm (default: the 99th percentile of |Δz|).
        #[arg(long)]
        max: Option<f64>,
    },
}

/// Where the face's landmarks and reference come from (`reconstruct`, `batch`).
#[derive(clap::Args)]
struct FaceArgs {
    /// A reference face file (default: the embedded ICT mean face).
    #[arg(long)]
    reference: Option<PathBuf>,
    /// dlib's 68-point model (`shape_predictor_68_face_landmarks.dat`; `tools/fetch-models`
    /// downloads it) for photos without a landmark file: faces are then detected and
    /// landmarked. Default: $SPLINEFACE_LANDMARK_MODEL.
    #[arg(long, env = "SPLINEFACE_LANDMARK_MODEL")]
    landmark_model: Option<PathBuf>,
}

/// Output options shared by `reconstruct`, `batch` and `demo`.
#[derive(clap::Args)]
struct OutputArgs {
    /// Output units: `mm` or `canonical` (the paper's: 50 between the eye centres).
    #[arg(long, default_value = "mm")]
    units: String,
    /// The distance between the eye centres in millimetres, for `--units mm`.
    #[arg(long, default_value_t = 63.0)]
    eye_distance: f64,
    /// Where the face's shape comes from: `space` (default, by measurement: the reference's
    /// face space fitted to the photos' points) or `deformed` (the reference deformed to the
    /// estimated structure, the paper's way; also used when the reference has no space).
    #[arg(long, default_value = "space")]
    shape: String,
    /// The face-space fit's landmark noise per coordinate, canonical units (larger keeps the
    /// face nearer the mean).
    #[arg(long, default_value_t = splineface::pipeline::Shape::DEFAULT_NOISE)]
    space_noise: f64,
    /// The prior deviation of each photo's expression weights in the face-space fit (larger
    /// lets the photos' points pull harder on the expression).
    #[arg(long, default_value_t = splineface::pipeline::Shape::DEFAULT_EXPRESSION_SIGMA)]
    expression_sigma: f64,
    /// Take every photo as neutral: fit no expressions.
    #[arg(long)]
    no_expressions: bool,
    /// Make the face with this photo's expression (its file stem, as the report names it)
    /// instead of the neutral identity.
    #[arg(long, value_name = "PHOTO")]
    expression_of: Option<String>,
    /// Keep the landmark fit: do not refine the face with the photos' pixels (the refinement
    /// makes the photos agree on what lies at each point of the face; it needs images and
    /// `--shape space`).
    #[arg(long)]
    no_refine: bool,
    /// The surface deformation of `--shape deformed`: `local` (default, by measurement) or
    /// `affine` (the paper's).
    #[arg(long, default_value = "local")]
    deformation: String,
    /// Mesh vertex spacing, canonical units.
    #[arg(long, default_value_t = 1.0)]
    spacing: f64,
    /// The depth map's larger side, pixels.
    #[arg(long, default_value_t = 512)]
    depth_size: usize,
    /// The texture atlas's side (`face.png`), texels: 16 to 8192.
    #[arg(long, default_value_t = 1024)]
    texture_size: u32,
    /// Stop with an error when fewer photos than this are usable (one photo measured worse
    /// than the unchanged mean face; see tools/results/evaluation.md).
    #[arg(long, default_value_t = splineface::pipeline::MIN_PHOTOS)]
    min_photos: usize,
}

impl OutputArgs {
    /// The index of `--expression-of`'s photo among `inputs`.
    fn expression_photo(&self, inputs: &[Input]) -> Result<Option<usize>> {
        let Some(name) = &self.expression_of else {
            return Ok(None);
        };
        splineface::pipeline::photo_index(inputs, name)
            .map(Some)
            .with_context(|| format!("--expression-of {name}"))
    }

    /// The pipeline's options, checked by the library ([`splineface::pipeline::Settings`]).
    fn options(&self) -> Result<PipelineOptions> {
        let settings = splineface::pipeline::Settings {
            units: self.units.clone(),
            eye_distance: self.eye_distance,
            shape: self.shape.clone(),
            space_noise: self.space_noise,
            expression_sigma: self.expression_sigma,
            expressions: !self.no_expressions,
            refine: !self.no_refine,
            deformation: self.deformation.clone(),
            spacing: self.spacing,
            depth_size: self.depth_size,
            texture_size: self.texture_size,
            min_photos: self.min_photos,
        };
        settings
            .options()
            .map_err(|e| anyhow::anyhow!("--{} {}: {}", e.setting.replace('_', "-"), e.value, e.expected))
    }
}

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
        Command::Inspect { surface } => inspect(&surface),
        Command::FitReference {
            meshes,
            landmarks,
            out,
            grid,
            smoothness,
            sample_spacing,
            note,
            identity_modes,
            expression_modes,
            expression_names,
            modes_note,
            space_from_scans,
        } => {
            let options = ReferenceOptions {
                grid,
                smoothness,
                sample_spacing,
                ..ReferenceOptions::default()
            };
            let modes = identity_modes.map(|identity| ModeFiles {
                identity,
                expressions: expression_modes.zip(expression_names),
                note: modes_note,
            });
            fit_reference(
                &meshes,
                &landmarks,
                &out,
                &options,
                &note,
                modes.as_ref(),
                space_from_scans,
            )
        }
        Command::Reconstruct {
            photos,
            photo_dir,
            landmarks,
            out,
            face,
            output,
        } => reconstruct_command(
            &photos,
            photo_dir.as_deref(),
            landmarks.as_deref(),
            face.reference.as_deref(),
            face.landmark_model.as_deref(),
            &out,
            &output,
        ),
        Command::Batch {
            root,
            out,
            force,
            face,
            output,
        } => batch_command(
            &root,
            face.reference.as_deref(),
            face.landmark_model.as_deref(),
            &out,
            force,
            &output,
        ),
        Command::CompactModel { model, out } => compact_model(&model, &out),
        Command::Landmarks {
            photos,
            photo_dir,
            landmark_model,
            out,
            json,
        } => landmarks_command(
            &photos,
            photo_dir.as_deref(),
            landmark_model.as_deref(),
            &out,
            json,
        ),
        Command::Demo {
            out,
            photos,
            noise,
            seed,
            output,
        } => demo_command(&out, photos, noise, seed, &output),
        Command::RenderDepth {
            mesh,
            out,
            size,
            view,
            preview,
        } => render_depth(&mesh, &out, &size, &view, preview.as_deref()),
        Command::Compare {
            reconstruction,
            truth,
            out,
            reconstruction_landmarks,
            truth_landmarks,
            reconstruction_units,
            truth_units,
            size,
            max,
        } => compare(&CompareArgs {
            files: MeshFiles {
                reconstruction,
                truth,
                landmarks: reconstruction_landmarks.zip(truth_landmarks),
                units: (
                    length_unit(&reconstruction_units, "--reconstruction-units")?,
                    length_unit(&truth_units, "--truth-units")?,
                ),
            },
            out,
            options: CompareOptions {
                size,
                heatmap_max: max,
                ..CompareOptions::default()
            },
        }),
    }
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

fn render_depth(mesh_path: &Path, out: &Path, size: &str, view: &str, preview: Option<&Path>) -> Result<()> {
    let (width, height) = parse_size(size)?;
    let view = View::parse(view).map_err(|e| anyhow::anyhow!("--view: {e}"))?;
    let extension = out
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    let exr = match extension.as_deref() {
        Some("exr") => true,
        Some("png") => false,
        _ => bail!("{}: the depth map must be .exr or .png", out.display()),
    };
    if let Some(p) = preview
        && !p.extension().is_some_and(|e| e.eq_ignore_ascii_case("png"))
    {
        bail!("{}: the preview must be .png", p.display());
    }
    check_output_file(out)?;
    if let Some(p) = preview {
        check_output_file(p)?;
    }
    let mesh = read_mesh(mesh_path)?;
    let raster = frame_raster(mesh.positions().iter().copied(), &view, width, height, 0.02)
        .map_err(|e| anyhow::anyhow!("{}: {e}", mesh_path.display()))?;
    let start = std::time::Instant::now();
    let map = DepthMap::render(&mesh, &view, &raster);
    let elapsed = start.elapsed();
    let encode_error = |e: splineface::io::EncodeError| anyhow::anyhow!("{}: {e}", out.display());
    let bytes = if exr {
        encode_depth_exr(&map)
    } else {
        encode_depth_png(&map)
    }
    .map_err(encode_error)?;
    let mut files = vec![(out.to_path_buf(), bytes)];
    if let Some(p) = preview {
        files.push((p.to_path_buf(), shaded_png(&map).map_err(encode_error)?));
    }
    write_files(&files)?;
    let (lo, hi) = map.range().unwrap_or((0.0, 0.0));
    println!("{}", out.display());
    println!(
        "  pixels      {width} × {height}, {:.4} units each",
        raster.spacing
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

struct CompareArgs {
    files: MeshFiles,
    out: PathBuf,
    options: CompareOptions,
}

fn compare(args: &CompareArgs) -> Result<()> {
    args.options
        .validate()
        .map_err(|e| anyhow::anyhow!(e.flag_message()))?;
    check_output_dir(&args.out)?;
    let start = std::time::Instant::now();
    let FileComparison {
        comparison: result,
        mean_face,
    } = compare_files(&args.files, &args.options)?;
    let elapsed = start.elapsed();
    let mut extra = serde_json::Map::new();
    extra.insert(
        "reconstruction".into(),
        args.files.reconstruction.display().to_string().into(),
    );
    extra.insert("truth".into(), args.files.truth.display().to_string().into());
    extra.insert("units".into(), "mm".into());
    extra.insert("heatmap_max".into(), result.heatmap_max.into());
    extra.insert("inner_face_mean_face".into(), serde_json::to_value(mean_face)?);
    write_into(&args.out, &result.files(extra, true)?)?;
    let s = &result.stats;
    println!("{}", args.out.display());
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
    println!("  time           {:.0} ms", elapsed.as_secs_f64() * 1e3);
    Ok(())
}

fn inspect(path: &Path) -> Result<()> {
    let text = splineface::io::read_input_text(path, splineface::io::MAX_DATA_INPUT_BYTES)
        .with_context(|| format!("cannot read {}", path.display()))?;
    let surface = BSplineSurface::from_json(&text)
        .with_context(|| format!("{} is not a valid B-spline surface", path.display()))?;
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

fn fit_reference(
    meshes: &[PathBuf],
    landmarks: &[PathBuf],
    out: &Path,
    options: &ReferenceOptions,
    note: &str,
    modes: Option<&ModeFiles>,
    space_from_scans: bool,
) -> Result<()> {
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
            "  face space     {} identity and {} expression modes",
            space.sigma.len(),
            space.expressions.len()
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

fn reconstruct_command(
    photos: &[PathBuf],
    photo_dir: Option<&Path>,
    landmark_dir: Option<&Path>,
    reference_path: Option<&Path>,
    landmark_model: Option<&Path>,
    out: &Path,
    output: &OutputArgs,
) -> Result<()> {
    let start = std::time::Instant::now();
    let options = output.options()?;
    check_output_dir(out)?;
    let model_start = std::time::Instant::now();
    let predictor = match landmark_model {
        Some(path) => {
            progress(&format!("reading the landmark model {}", path.display()));
            Some(splineface::landmarker::ShapePredictor::read(path)?)
        }
        None => None,
    };
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
    let result = reconstruct(&set.inputs, &reference, &options, progress)?;
    progress("drawing the overlays and the report page");
    let files = set.files(&result, model_seconds)?;
    write_into(out, &files)?;
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
        if result.texture.is_some() {
            ", textured"
        } else {
            ""
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
    Ok(())
}

/// A reference face file ([`ReferenceFace::read`]), or the embedded one when `path` is `None`.
fn read_reference(path: Option<&Path>) -> Result<ReferenceFace> {
    match path {
        Some(path) => Ok(ReferenceFace::read(path)?),
        None => Ok(ReferenceFace::embedded().clone()),
    }
}

fn batch_command(
    root: &Path,
    reference_path: Option<&Path>,
    landmark_model: Option<&Path>,
    out: &Path,
    force: bool,
    output: &OutputArgs,
) -> Result<()> {
    use rayon::prelude::*;
    use splineface::batch::{
        BatchJob, Status, check_output, file_identity, run_subject, subjects, write_summary,
    };
    let options = output.options()?;
    if output.expression_of.is_some() {
        bail!("--expression-of names one photo; it has no meaning for a batch");
    }
    let subjects = subjects(root)?;
    check_output(root, out)?;
    let reference = read_reference(reference_path)?;
    let predictor = match landmark_model {
        Some(path) => {
            progress(&format!("reading the landmark model {}", path.display()));
            Some(splineface::landmarker::ShapePredictor::read(path)?)
        }
        None => None,
    };
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
    let finished = std::sync::atomic::AtomicUsize::new(0);
    // Subjects in parallel (each one's stages are parallel too; rayon shares the cores).
    let rows: Vec<_> = subjects
        .par_iter()
        .map(|subject| {
            let row = run_subject(subject, out, &job);
            let done = finished.fetch_add(1, std::sync::atomic::Ordering::SeqCst) + 1;
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
            row
        })
        .collect();
    if let Some(bar) = &bar {
        bar.finish_and_clear();
    }
    write_summary(out, &rows)?;
    let count = |s: Status| rows.iter().filter(|r| r.status == s).count();
    let (done, unchanged, failed) = (
        count(Status::Done),
        count(Status::Unchanged),
        count(Status::Failed),
    );
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

fn demo_command(out: &Path, photos: usize, noise: f64, seed: u64, output: &OutputArgs) -> Result<()> {
    let mut options = output.options()?;
    let scene_options = splineface::demo::SceneOptions {
        photos,
        noise: noise / 100.0,
        seed,
        ..splineface::demo::SceneOptions::default()
    };
    // The settings checked before any work: `scene` checks them again.
    if let Err(splineface::demo::DemoError::Setting(e)) = scene_options.validate() {
        bail!(e.flag_message());
    }
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

fn landmarks_command(
    photos: &[PathBuf],
    photo_dir: Option<&Path>,
    landmark_model: Option<&Path>,
    out: &Path,
    json: bool,
) -> Result<()> {
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
    progress(&format!("reading the landmark model {}", model_path.display()));
    let model = splineface::landmarker::ShapePredictor::read(model_path)?;
    let landmarked = splineface::pipeline::landmark_photos(&paths, &model, json)?;
    write_into(out, &landmarked.files)?;
    println!("{}", out.display());
    for line in &landmarked.lines {
        println!("  {line}");
    }
    Ok(())
}
