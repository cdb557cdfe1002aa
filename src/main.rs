//! The `splineface` command line.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use nalgebra::{Affine3, Matrix4, Point3, Vector3};
use splineface::bspline::BSplineSurface;
use splineface::compare::CompareOptions;
use splineface::face::{Deformation, FaceSpace, Units};
use splineface::landmarks::{read_landmarks_json, read_vertex_indices};
use splineface::mesh::{TriangleMesh, read_mesh};
use splineface::pipeline::{
    Input, InputError, PhotoRecord, PipelineOptions, gather_inputs, has_extension, photo_files, photo_list,
    photo_stem, reconstruct,
};
use splineface::reference::ReferenceFace;
use splineface::reference::{ReferenceOptions, ReferenceScan, ReferenceSource, build_reference, fnv1a64};
use splineface::render::{
    DepthMap, MAX_SIDE, View, encode_depth_exr, encode_depth_png, frame_raster, heatmap_png, shaded_png,
};
use splineface::structure::{IBUG_POINT_COUNT, from_ibug68, unify};

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
            reconstruction,
            truth,
            out,
            landmarks: reconstruction_landmarks.zip(truth_landmarks),
            units: (reconstruction_units, truth_units),
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
    let encode_error = |e: splineface::render::DepthFileError| anyhow::anyhow!("{}: {e}", out.display());
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

/// Checks, before any work, that an output file can be written: its directory exists and a
/// file can be made in it, and the path itself is not a directory.
fn check_output_file(path: &Path) -> Result<()> {
    if path.is_dir() {
        bail!("{}: is a directory", path.display());
    }
    let directory = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    if !directory.exists() {
        bail!(
            "{}: the directory {} does not exist",
            path.display(),
            directory.display()
        );
    }
    if !directory.is_dir() {
        bail!("{}: {} is not a directory", path.display(), directory.display());
    }
    probe_writable(directory).with_context(|| format!("{}: cannot write there", path.display()))
}

/// Makes and removes an empty file in `directory`.
fn probe_writable(directory: &Path) -> Result<()> {
    splineface::io::probe_writable(directory)
        .with_context(|| format!("cannot create a file in {}", directory.display()))
}

fn write_files(files: &[(PathBuf, Vec<u8>)]) -> Result<()> {
    splineface::io::write_files_atomically(files)
        .map_err(|(path, e)| anyhow::anyhow!("cannot write {}: {e}", path.display()))
}

/// Millimetres per unit.
fn units_to_mm(text: &str, flag: &str) -> Result<f64> {
    match text.to_ascii_lowercase().as_str() {
        "mm" => Ok(1.0),
        "cm" => Ok(10.0),
        "m" => Ok(1000.0),
        _ => bail!("{flag} `{text}`: expected mm, cm or m"),
    }
}

/// A 40-point 3D structure from a landmark file: JSON with 3D points (68 or 40), or 68 vertex
/// indices into `mesh`.
fn read_structure(path: &Path, mesh: &TriangleMesh) -> Result<Vec<Point3<f64>>> {
    let is_json = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("json"));
    if is_json {
        return read_landmarks_json(path)?
            .structure_3d()
            .with_context(|| format!("{}: 3D landmarks are needed", path.display()));
    }
    let indices = read_vertex_indices(path, IBUG_POINT_COUNT, mesh.positions().len())?;
    let points: Vec<_> = indices.iter().map(|&i| mesh.positions()[i]).collect();
    from_ibug68(&points).with_context(|| format!("{}", path.display()))
}

struct CompareArgs {
    reconstruction: PathBuf,
    truth: PathBuf,
    out: PathBuf,
    landmarks: Option<(PathBuf, PathBuf)>,
    units: (String, String),
    options: CompareOptions,
}

fn compare(args: &CompareArgs) -> Result<()> {
    let scale_a = units_to_mm(&args.units.0, "--reconstruction-units")?;
    let scale_b = units_to_mm(&args.units.1, "--truth-units")?;
    if !(16..=MAX_SIDE).contains(&args.options.size) {
        bail!("--size {} must be between 16 and {MAX_SIDE}", args.options.size);
    }
    if let Some(max) = args.options.heatmap_max
        && !(max > 0.0 && max.is_finite())
    {
        bail!("--max {max} must be a positive number of millimetres");
    }
    check_output_dir(&args.out)?;
    let rec = read_mesh(&args.reconstruction)?;
    let truth = read_mesh(&args.truth)?;
    let structures = match &args.landmarks {
        Some((a, b)) => Some((read_structure(a, &rec)?, read_structure(b, &truth)?)),
        None => None,
    };
    let to_mm = |s: f64| Affine3::from_matrix_unchecked(Matrix4::new_nonuniform_scaling(&Vector3::repeat(s)));
    let rec = rec.transformed(&to_mm(scale_a));
    let truth = truth.transformed(&to_mm(scale_b));
    let structures = structures.map(|(a, b)| {
        (
            a.iter().map(|p| p * scale_a).collect::<Vec<_>>(),
            b.iter().map(|p| p * scale_b).collect::<Vec<_>>(),
        )
    });
    let start = std::time::Instant::now();
    let result = splineface::compare::compare(
        &rec,
        &truth,
        structures.as_ref().map(|(a, b)| (a.as_slice(), b.as_slice())),
        &args.options,
    )?;
    // The unchanged mean face (the embedded reference, 63 mm between its eye centres), scored
    // the same way: a reconstruction's figures mean little alone.
    let mean_face = match &structures {
        Some((_, truth_structure)) => {
            let reference = ReferenceFace::embedded();
            let units = splineface::face::Units::default();
            let mesh =
                splineface::face::FaceSurface::deform(reference, reference.structure(), Deformation::Affine)?
                    .mesh(&splineface::face::MeshOptions::default())?
                    .mesh
                    .transformed(&units.transform());
            let points: Vec<_> = reference
                .photo_structure()
                .iter()
                .map(|p| p * units.per_canonical_unit())
                .collect();
            Some(
                splineface::compare::inner_face_score(
                    &mesh,
                    &truth,
                    (&points, truth_structure),
                    &splineface::compare::InnerFaceOptions::default(),
                )?
                .score,
            )
        }
        None => None,
    };
    let elapsed = start.elapsed();
    let (w, h) = (
        result.reconstruction.raster.width,
        result.reconstruction.raster.height,
    );
    let encode =
        |r: Result<Vec<u8>, splineface::render::DepthFileError>| r.map_err(|e| anyhow::anyhow!("{e}"));
    std::fs::create_dir_all(&args.out).with_context(|| format!("cannot create {}", args.out.display()))?;
    let mut stats = serde_json::to_value(&result.stats)?;
    stats["reconstruction"] = args.reconstruction.display().to_string().into();
    stats["truth"] = args.truth.display().to_string().into();
    stats["units"] = "mm".into();
    stats["heatmap_max"] = result.heatmap_max.into();
    stats["inner_face_mean_face"] = serde_json::to_value(mean_face)?;
    let files = vec![
        (
            args.out.join("heatmap.png"),
            encode(heatmap_png(&result.abs_dz, w, h, result.heatmap_max, "mm"))?,
        ),
        (
            args.out.join("reconstruction-depth.exr"),
            encode(encode_depth_exr(&result.reconstruction))?,
        ),
        (
            args.out.join("truth-depth.exr"),
            encode(encode_depth_exr(&result.truth))?,
        ),
        (
            args.out.join("reconstruction.png"),
            encode(shaded_png(&result.reconstruction))?,
        ),
        (args.out.join("truth.png"), encode(shaded_png(&result.truth))?),
        (args.out.join("stats.json"), serde_json::to_vec_pretty(&stats)?),
    ];
    write_files(&files)?;
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
    let mut lo = surface.control_points()[0];
    let mut hi = lo;
    for p in surface.control_points() {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    println!(
        "  control box  [{:.6}, {:.6}] × [{:.6}, {:.6}] × [{:.6}, {:.6}]",
        lo.x, hi.x, lo.y, hi.y, lo.z, hi.z
    );
    Ok(())
}

fn file_name(path: &Path) -> String {
    path.file_name().map_or_else(
        || path.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}

/// `fit-reference`'s face-space inputs: displacement-field files of the scan.
struct ModeFiles {
    identity: PathBuf,
    /// The expression fields and their names.
    expressions: Option<(PathBuf, PathBuf)>,
    note: String,
}

/// Displacement fields `[mode][vertex][3]` (little-endian `f32`) of a scan of `vertices`
/// vertices, mapped into the canonical frame by `to_canonical` (its rotation and scale).
fn read_fields(
    path: &Path,
    vertices: usize,
    to_canonical: &nalgebra::Similarity3<f64>,
) -> Result<Vec<Vec<nalgebra::Vector3<f64>>>> {
    let bytes = splineface::io::read_input(path, splineface::io::MAX_LARGE_INPUT_BYTES)
        .with_context(|| format!("cannot read {}", path.display()))?;
    let per_mode = vertices * 12;
    if bytes.is_empty() || bytes.len() % per_mode != 0 {
        bail!(
            "{}: {} bytes is not a whole number of modes of {vertices} vertices × 3 float32 ({per_mode} bytes each)",
            path.display(),
            bytes.len()
        );
    }
    let mut fields = Vec::with_capacity(bytes.len() / per_mode);
    for (k, mode) in bytes.chunks_exact(per_mode).enumerate() {
        let mut field = Vec::with_capacity(vertices);
        for (v, d) in mode.chunks_exact(12).enumerate() {
            let c = |i: usize| f64::from(f32::from_le_bytes([d[i], d[i + 1], d[i + 2], d[i + 3]]));
            let vector = nalgebra::Vector3::new(c(0), c(4), c(8));
            if !vector.iter().all(|x| x.is_finite()) {
                bail!(
                    "{}: mode {k}, vertex {v}: the displacement is not finite",
                    path.display()
                );
            }
            field.push(to_canonical * vector);
        }
        fields.push(field);
    }
    Ok(fields)
}

/// The reference with a face space built from `modes`, displacement fields of its single
/// scan with 68 landmark vertex indices in `landmark_path`.
fn with_modes(
    reference: ReferenceFace,
    scan: &ReferenceScan,
    landmark_path: &Path,
    modes: &ModeFiles,
) -> Result<ReferenceFace> {
    let mesh = &scan.mesh;
    let vertices = mesh.positions().len();
    if has_extension(landmark_path, &["json"]) {
        bail!(
            "{}: the face space's modes need the landmarks as 68 vertex indices (to move them with the modes), not a JSON landmark file",
            landmark_path.display()
        );
    }
    // The indices again (the structure was read from them): the modes move those vertices.
    let landmarks = read_vertex_indices(landmark_path, IBUG_POINT_COUNT, vertices)?;
    let (to_canonical, _) = unify(&scan.structure)?;
    let scan = mesh.transformed(&nalgebra::convert(to_canonical));
    let identity = read_fields(&modes.identity, vertices, &to_canonical)?;
    let sigma = vec![1.0; identity.len()];
    let mut space = FaceSpace::from_displacements(&reference, &scan, &landmarks, &identity, &sigma)
        .with_context(|| format!("{}", modes.identity.display()))?;
    if let Some((fields_path, names_path)) = &modes.expressions {
        let fields = read_fields(fields_path, vertices, &to_canonical)?;
        let text = splineface::io::read_input_text(names_path, splineface::io::MAX_DATA_INPUT_BYTES)
            .with_context(|| format!("cannot read {}", names_path.display()))?;
        let names: Vec<String> = text
            .lines()
            .map(str::trim)
            .filter(|l| !l.is_empty() && !l.starts_with('#'))
            .map(str::to_owned)
            .collect();
        if names.len() != fields.len() {
            bail!(
                "{}: {} names for the {} expression modes of {}",
                names_path.display(),
                names.len(),
                fields.len(),
                fields_path.display()
            );
        }
        space = space
            .with_expression_displacements(&reference, &scan, &landmarks, &names, &fields, &modes.note)
            .with_context(|| format!("{}", fields_path.display()))?;
    }
    reference
        .with_space(Some(space.to_modes(&modes.note)))
        .map_err(anyhow::Error::msg)
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
    let mut scans = Vec::with_capacity(meshes.len());
    for (mesh_path, landmark_path) in meshes.iter().zip(landmarks) {
        let mesh = read_mesh(mesh_path)?;
        let bytes = splineface::io::read_input(mesh_path, splineface::io::MAX_LARGE_INPUT_BYTES)
            .with_context(|| format!("cannot read {}", mesh_path.display()))?;
        let structure = read_structure(landmark_path, &mesh)?;
        scans.push(ReferenceScan {
            source: ReferenceSource {
                mesh: file_name(mesh_path),
                mesh_fnv1a64: fnv1a64(&bytes),
                landmarks: file_name(landmark_path),
                vertices: mesh.positions().len(),
                triangles: mesh.triangles().len(),
            },
            mesh,
            structure,
        });
    }
    let start = std::time::Instant::now();
    let mut reference = if space_from_scans {
        splineface::reference::build_reference_with_space(&scans, options, note)?
    } else {
        build_reference(&scans, options, note)?
    };
    if let Some(modes) = modes {
        reference = with_modes(reference, &scans[0], &landmarks[0], modes)?;
    }
    let elapsed = start.elapsed();
    splineface::io::write_atomically(out, reference.to_json().as_bytes())
        .with_context(|| format!("cannot write {}", out.display()))?;
    let fit = reference.fit();
    let mm = 63.0 / 50.0;
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
    let options = output.options()?;
    if !(1..=200).contains(&photos) {
        bail!("--photos {photos}: between 1 and 200, please");
    }
    if !(noise >= 0.0 && noise.is_finite()) {
        bail!("--noise {noise}: must be a finite percentage, 0 or more");
    }
    check_output_dir(out)?;
    let start = std::time::Instant::now();
    progress(&format!(
        "photographing the demo subject: {photos} photos, landmark noise {noise}% of the eye distance"
    ));
    let scene = splineface::demo::scene(&splineface::demo::SceneOptions {
        photos,
        noise: noise / 100.0,
        seed,
        ..splineface::demo::SceneOptions::default()
    })
    .map_err(anyhow::Error::msg)?;
    let mut options = options;
    options.expression_of = output.expression_photo(&scene.inputs)?;
    let result = reconstruct(&scene.inputs, ReferenceFace::embedded(), &options, progress)?;
    progress("comparing with the truth");
    let to_units = options.units.transform();
    let scale = options.units.per_canonical_unit();
    let truth_mesh = scene.truth_mesh.transformed(&to_units);
    let truth_structure: Vec<_> = scene.truth_structure.iter().map(|p| p * scale).collect();
    let reconstruction = result.output_mesh();
    let comparison = splineface::compare::compare(
        &reconstruction,
        &truth_mesh,
        Some((&result.structure(), &truth_structure)),
        &CompareOptions::default(),
    )?;
    // The baseline: the reference face unchanged.
    let mean_face = splineface::face::FaceSurface::deform(
        ReferenceFace::embedded(),
        ReferenceFace::embedded().structure(),
        Deformation::Affine,
    )?
    .mesh(&options.mesh)?
    .mesh
    .transformed(&to_units);
    // Its landmarks as the photo path places them, like the reconstruction's and the truth's.
    let reference_structure: Vec<_> = ReferenceFace::embedded()
        .photo_structure()
        .iter()
        .map(|p| p * scale)
        .collect();
    let baseline = splineface::compare::compare(
        &mean_face,
        &truth_mesh,
        Some((&reference_structure, &truth_structure)),
        &CompareOptions::default(),
    )?;

    let mut files: Vec<(PathBuf, Vec<u8>)> = scene
        .files()
        .map_err(anyhow::Error::msg)?
        .into_iter()
        .map(|(p, b)| (Path::new("photos").join(p), b))
        .collect();
    let records: Vec<PhotoRecord> = scene
        .inputs
        .iter()
        .map(|input| PhotoRecord::given(&input.points.name, input.points.points.clone()))
        .collect();
    let mut warnings = Vec::new();
    let mut reconstruction_files = result.files()?;
    reconstruction_files.extend(photo_files(
        &records,
        Path::new("landmarks"),
        &scene.inputs,
        Some(&result),
        &mut warnings,
    ));
    for w in &warnings {
        progress(&format!("warning: {w}"));
    }
    files.extend(
        reconstruction_files
            .into_iter()
            .map(|(p, b)| (Path::new("reconstruction").join(p), b)),
    );
    let (w, h) = (
        comparison.reconstruction.raster.width,
        comparison.reconstruction.raster.height,
    );
    let encode =
        |r: Result<Vec<u8>, splineface::render::DepthFileError>| r.map_err(|e| anyhow::anyhow!("{e}"));
    let mut stats = serde_json::to_value(&comparison.stats)?;
    stats["baseline_mean_face"] = serde_json::to_value(&baseline.stats)?;
    stats["units"] = options.units.name().into();
    files.push((
        "compare/heatmap.png".into(),
        encode(heatmap_png(
            &comparison.abs_dz,
            w,
            h,
            comparison.heatmap_max,
            "mm",
        ))?,
    ));
    files.push(("compare/truth.png".into(), encode(shaded_png(&comparison.truth))?));
    files.push((
        "compare/reconstruction.png".into(),
        encode(shaded_png(&comparison.reconstruction))?,
    ));
    files.push(("compare/stats.json".into(), serde_json::to_vec_pretty(&stats)?));
    let page = splineface::report::report_page(
        &files,
        &splineface::report::PageOptions {
            title: format!("splineface demo: {photos} photos of the demo subject"),
            reconstruction: "reconstruction".into(),
            comparison: Some("compare".into()),
        },
    );
    files.push(("report.html".into(), page.into_bytes()));
    write_into(out, &files)?;

    let s = &comparison.stats;
    let b = &baseline.stats;
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
    use splineface::landmarker::{ModelSource, ShapePredictor};
    check_output_file(out)?;
    let dat = splineface::io::read_input(model, splineface::io::MAX_DATA_INPUT_BYTES)
        .with_context(|| format!("cannot read {}", model.display()))?;
    if dat.starts_with(splineface::landmarker::COMPACT_MAGIC) {
        bail!("{}: it is already in the compact form", model.display());
    }
    let source = ModelSource::of(&dat);
    if let Ok(file) = std::fs::File::open(out)
        && let Ok(length) = file.metadata().map(|m| m.len())
        && let Ok((_, recorded)) = ShapePredictor::read_compact(std::io::BufReader::new(file), length)
        && recorded == source
    {
        println!(
            "{} is up to date (made from this {})",
            out.display(),
            model.display()
        );
        return Ok(());
    }
    let predictor = ShapePredictor::parse(&dat).map_err(|problem| splineface::landmarker::ModelError {
        file: model.to_path_buf(),
        problem,
    })?;
    drop(dat);
    write_files(&[(out.to_path_buf(), predictor.to_compact(source))])?;
    println!("{}", out.display());
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
    let mut records: Vec<PhotoRecord> = Vec::new();
    let mut files: Vec<(PathBuf, Vec<u8>)> = Vec::new();
    let mut lines: Vec<String> = Vec::new();
    let mut found_any = false;
    // One photo a name; the photos decoded, detected and landmarked in parallel, gathered in
    // their order.
    let mut names = std::collections::BTreeSet::new();
    let mut unique: Vec<(&Path, String)> = Vec::new();
    for path in &paths {
        let stem = photo_stem(path);
        if names.insert(stem.clone()) {
            unique.push((path, stem));
        } else {
            lines.push(format!(
                "{}: skipped: another photo has the name `{stem}`",
                path.display()
            ));
        }
    }
    use rayon::prelude::*;
    type Landmarked = (String, Option<PhotoRecord>, Option<(PathBuf, Vec<u8>)>);
    let results: Vec<Landmarked> = unique
        .par_iter()
        .map(|(path, stem)| -> Result<Landmarked> {
            let decoded = match splineface::align::decode_photo(path) {
                Ok(d) => d,
                Err(e) => return Ok((format!("{}: skipped: {}", path.display(), e.problem), None, None)),
            };
            match splineface::pipeline::landmark_photo(&model, &decoded, stem) {
                Ok((_, found, _)) => {
                    let b = found.face.bbox;
                    let mut line = format!(
                        "{}: 68 points, face box {}×{} at ({}, {}), mirror disagreement {:.1}% of the eye width",
                        path.display(),
                        b.right - b.left + 1,
                        b.bottom - b.top + 1,
                        b.left,
                        b.top,
                        100.0 * found.disagreement
                    );
                    if let Some(note) = &found.note {
                        line.push_str(&format!("; {note}"));
                    }
                    let json_file = if json {
                        let landmarks = splineface::landmarks::Landmarks {
                            scheme: splineface::landmarks::Scheme::Ibug68,
                            points: splineface::landmarks::LandmarkPoints::Planar(found.ibug.clone()),
                        };
                        let text = splineface::landmarks::format_landmarks_json(&landmarks)
                            .with_context(|| format!("{}: its landmarks", path.display()))?;
                        Some((PathBuf::from(format!("{stem}.json")), text.into_bytes()))
                    } else {
                        None
                    };
                    let record = PhotoRecord {
                        image: Some(decoded.to_rgb8()),
                        ..PhotoRecord::from_detection(stem, &found)
                    };
                    Ok((line, Some(record), json_file))
                }
                Err(reason) => Ok((
                    format!("{}: skipped: {reason}", path.display()),
                    Some(PhotoRecord::skipped(stem, Some(decoded.to_rgb8()), reason)),
                    None,
                )),
            }
        })
        .collect::<Result<_>>()?;
    for (line, record, json_file) in results {
        lines.push(line);
        found_any |= record.as_ref().is_some_and(|r| r.detected);
        records.extend(record);
        files.extend(json_file);
    }
    if !found_any {
        bail!(
            "no photo gave landmarks:{}",
            lines.iter().map(|l| format!("\n  {l}")).collect::<String>()
        );
    }
    let mut warnings = Vec::new();
    // The `.pts` files at the top, so that `reconstruct --landmarks DIR` reads them.
    files.extend(photo_files(&records, Path::new(""), &[], None, &mut warnings));
    write_into(out, &files)?;
    println!("{}", out.display());
    for line in lines.iter().chain(&warnings) {
        println!("  {line}");
    }
    Ok(())
}
