//! The command line's arguments: every subcommand's flags, with the help text people read.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use splineface::pipeline::{Input, PipelineOptions};
use splineface::reference::ReferenceOptions;

/// Smooth 3D faces from uncalibrated photos: B-spline surfaces, meshes and depth maps.
#[derive(Parser)]
#[command(version, about)]
pub(crate) struct Cli {
    #[command(subcommand)]
    pub(crate) command: Command,
}

#[derive(Subcommand)]
pub(crate) enum Command {
    /// Validate a B-spline surface file (JSON) and print its shape, domain and extent.
    Inspect(InspectArgs),
    /// Fit a reference face (control grid, 40-point structure, clip region) to face scans.
    ///
    /// Give one `--landmarks` per `--mesh`, in the same order; several pairs give one reference
    /// from their mean.
    #[command(allow_negative_numbers = true)]
    FitReference(FitReferenceArgs),
    /// Reconstruct a face from photos and/or their landmark files.
    ///
    /// Landmark files (`.pts` with 68 iBUG or 40 structure points, or landmark JSON) are
    /// matched to photos by file stem in `--landmarks`; with landmarks and no photos the run is
    /// points-only (no RASL, no texture).
    #[command(allow_negative_numbers = true)]
    Reconstruct(ReconstructArgs),
    /// Reconstruct many subjects: one sub-folder of ROOT per subject (its photos and/or
    /// landmark files), each written to OUT/NAME as `reconstruct` writes it, subjects in
    /// parallel with the model loaded once. Resumable: a subject whose inputs and options are
    /// unchanged since its outputs were written is skipped. Writes OUT/summary.csv and
    /// OUT/summary.jsonl (one row per subject); a failed subject is a row, never the end of
    /// the batch (the exit status is 1 if any failed).
    Batch(BatchArgs),
    /// Detect the face in each photo and find its 68 landmarks: writes `NAME.pts` (iBUG,
    /// readable back by `reconstruct --landmarks DIR`), with `--json` also `NAME.json` (the
    /// project's landmark JSON), and `overlays/NAME.jpg` (the photo with the face box and the
    /// points, or why none were found).
    Landmarks(LandmarksArgs),
    /// Write dlib's landmark model in splineface's compact form, which loads in a fraction of
    /// the time (the same trees, bit for bit; `--landmark-model` takes either). An existing
    /// output made from the same `.dat` (by its recorded length and hash) is left as it is.
    CompactModel(CompactModelArgs),
    /// Run the whole pipeline on the embedded demo subject: render a dozen photos of it under
    /// varied poses, reconstruct the face and compare it with the truth.
    #[command(allow_negative_numbers = true)]
    Demo(DemoArgs),
    /// Render a mesh's orthographic depth map: EXR (float32 `Z` with a coverage channel `A`)
    /// or 16-bit PNG (0 = background), chosen by the output's extension.
    #[command(allow_negative_numbers = true)]
    RenderDepth(RenderDepthArgs),
    /// Compare a reconstruction with a ground-truth scan: align them, render both depth maps
    /// and write the |Δz| heatmap, the depth maps and stats.json (the paper's measures and
    /// millimetre errors) into a directory.
    #[command(allow_negative_numbers = true)]
    Compare(CompareArgs),
    /// Fit a B-spline surface to any scan that is a height field over some plane (a mesh's
    /// vertices or a point cloud): writes the surface (JSON or STEP), and beside it
    /// STEM.residuals.json (the fit's report) and STEM.residuals.png (each point's residual
    /// over the surface's parameters). With `--tolerance`, knots are inserted where the
    /// residual exceeds it until it holds or `--max-grid` is reached. A closed or folded scan
    /// is refused.
    #[command(allow_negative_numbers = true)]
    FitSurface(FitSurfaceArgs),
}

// The arguments of `splineface inspect`.
#[derive(clap::Args)]
pub(crate) struct InspectArgs {
    /// The surface file, as written by `BSplineSurface::to_json`.
    pub(crate) surface: PathBuf,
}

// The arguments of `splineface fit-reference`.
#[derive(clap::Args)]
pub(crate) struct FitReferenceArgs {
    /// A scan: OBJ, PLY, glTF or GLB.
    #[arg(long = "mesh", required = true)]
    pub(crate) meshes: Vec<PathBuf>,
    /// Its landmarks: 68 vertex indices (a text file, one a line, `#` comments) or a JSON
    /// landmark file with 3D points (68 iBUG or the 40 of the structure).
    #[arg(long = "landmarks", required = true)]
    pub(crate) landmarks: Vec<PathBuf>,
    /// The reference file to write (JSON).
    #[arg(long)]
    pub(crate) out: PathBuf,
    /// Control points along each side of the cubic grid.
    #[arg(long, default_value_t = ReferenceOptions::default().grid)]
    pub(crate) grid: usize,
    /// Thin-plate smoothness weight λ.
    #[arg(long, default_value_t = ReferenceOptions::default().smoothness)]
    pub(crate) smoothness: f64,
    /// Distance between frontal samples, canonical units (50 between the eye centres).
    #[arg(long, default_value_t = ReferenceOptions::default().sample_spacing)]
    pub(crate) sample_spacing: f64,
    /// Free text stored in the file's provenance (licence, origin).
    #[arg(long, default_value = "")]
    pub(crate) note: String,
    /// Identity modes of the face space: per-vertex displacement fields of the (single)
    /// scan, as little-endian float32 `[mode][vertex][x, y, z]` in the scan's own frame and
    /// units (the size must be a multiple of the scan's vertices × 12 bytes), each the
    /// displacement of one prior standard deviation (a plausible face is
    /// `scan + Σ wₖ·modeₖ` with `wₖ ~ N(0, 1)`). Needs the landmarks as vertex indices; the
    /// space stores how every mode moves those 68 vertices too (the photo fit reads an open
    /// mouth from the inner lips).
    #[arg(long, value_name = "FILE")]
    pub(crate) identity_modes: Option<PathBuf>,
    /// Expression modes (blendshapes) of the face space, laid out like `--identity-modes`,
    /// each the displacement of the full expression (weights in `[0, 1]`).
    #[arg(
        long,
        value_name = "FILE",
        requires = "expression_names",
        requires = "identity_modes"
    )]
    pub(crate) expression_modes: Option<PathBuf>,
    /// The expression modes' names, one a line (blank lines and `#` comments skipped).
    #[arg(long, value_name = "FILE", requires = "expression_modes")]
    pub(crate) expression_names: Option<PathBuf>,
    /// Where the modes came from (licence, origin), stored with them.
    #[arg(long, default_value = "")]
    pub(crate) modes_note: String,
    /// Learn a face space from the scans themselves (three or more): the principal
    /// components of their own fitted grids, each scan a sample of the faces it stands for.
    /// When every scan's landmark file gives the 68 iBUG points (vertex indices, or an
    /// `ibug68` JSON file), the space moves them too.
    #[arg(long, conflicts_with = "identity_modes")]
    pub(crate) space_from_scans: bool,
}

// The arguments of `splineface reconstruct`.
#[derive(clap::Args)]
pub(crate) struct ReconstructArgs {
    /// Photos (JPEG, PNG, BMP, TIFF, WebP).
    pub(crate) photos: Vec<PathBuf>,
    /// A directory of photos (every image file in it, by name).
    #[arg(long = "photos")]
    pub(crate) photo_dir: Option<PathBuf>,
    /// A directory of landmark files, one per photo, named like the photo.
    #[arg(long)]
    pub(crate) landmarks: Option<PathBuf>,
    /// The directory to write into (created if missing).
    #[arg(long)]
    pub(crate) out: PathBuf,
    #[command(flatten)]
    pub(crate) face: FaceArgs,
    #[command(flatten)]
    pub(crate) output: OutputArgs,
}

// The arguments of `splineface batch`.
#[derive(clap::Args)]
pub(crate) struct BatchArgs {
    /// The folder of subject folders.
    pub(crate) root: PathBuf,
    /// The directory to write into (created if missing; not inside ROOT).
    #[arg(long)]
    pub(crate) out: PathBuf,
    /// Reconstruct every subject, even those whose outputs are up to date.
    #[arg(long)]
    pub(crate) force: bool,
    #[command(flatten)]
    pub(crate) face: FaceArgs,
    #[command(flatten)]
    pub(crate) output: OutputArgs,
}

// The arguments of `splineface landmarks`.
#[derive(clap::Args)]
pub(crate) struct LandmarksArgs {
    /// Photos (JPEG, PNG, BMP, TIFF, WebP).
    pub(crate) photos: Vec<PathBuf>,
    /// A directory of photos (every image file in it, by name).
    #[arg(long = "photos")]
    pub(crate) photo_dir: Option<PathBuf>,
    /// dlib's 68-point model (`shape_predictor_68_face_landmarks.dat`; `tools/fetch-models`
    /// downloads it). Default: $SPLINEFACE_LANDMARK_MODEL.
    #[arg(long, env = "SPLINEFACE_LANDMARK_MODEL")]
    pub(crate) landmark_model: Option<PathBuf>,
    /// The directory to write into (created if missing).
    #[arg(long)]
    pub(crate) out: PathBuf,
    /// Also write each photo's landmarks as landmark JSON (`NAME.json`).
    #[arg(long)]
    pub(crate) json: bool,
}

// The arguments of `splineface compact-model`.
#[derive(clap::Args)]
pub(crate) struct CompactModelArgs {
    /// dlib's `shape_predictor_68_face_landmarks.dat`.
    pub(crate) model: PathBuf,
    /// The compact file to write (e.g. `shape_predictor_68_face_landmarks.sfsp`).
    #[arg(long)]
    pub(crate) out: PathBuf,
}

// The arguments of `splineface demo`.
#[derive(clap::Args)]
pub(crate) struct DemoArgs {
    /// The directory to write into (created if missing).
    #[arg(long, default_value = "splineface-demo")]
    pub(crate) out: PathBuf,
    /// How many photos to take.
    #[arg(long, default_value_t = 12)]
    pub(crate) photos: usize,
    /// Landmark noise, percent of the eye distance.
    #[arg(long, default_value_t = 1.0)]
    pub(crate) noise: f64,
    /// The random seed of the poses and the noise.
    #[arg(long, default_value_t = 2016)]
    pub(crate) seed: u64,
    #[command(flatten)]
    pub(crate) output: OutputArgs,
}

// The arguments of `splineface render-depth`.
#[derive(clap::Args)]
pub(crate) struct RenderDepthArgs {
    /// The mesh: OBJ, PLY, glTF or GLB.
    pub(crate) mesh: PathBuf,
    /// The depth map to write: `.exr` or `.png`.
    #[arg(long)]
    pub(crate) out: PathBuf,
    /// Pixels: `W` (square) or `WxH`.
    #[arg(long, default_value = "512")]
    pub(crate) size: String,
    /// `front`, or `YAW,PITCH,ROLL` in degrees (the pose convention of `structure.json`).
    #[arg(long, default_value = "front", allow_hyphen_values = true)]
    pub(crate) view: String,
    /// Also write a shaded preview (PNG).
    #[arg(long)]
    pub(crate) preview: Option<PathBuf>,
}

// The arguments of `splineface compare`.
#[derive(clap::Args)]
pub(crate) struct CompareArgs {
    /// The reconstructed face (OBJ, PLY, glTF or GLB).
    pub(crate) reconstruction: PathBuf,
    /// The ground-truth scan.
    pub(crate) truth: PathBuf,
    /// The directory to write into (created if missing).
    #[arg(long)]
    pub(crate) out: PathBuf,
    /// The reconstruction's landmarks (JSON with 3D points, or 68 vertex indices); with
    /// `--truth-landmarks`, the two are aligned by a similarity between their structures
    /// instead of rigid ICP.
    #[arg(long, requires = "truth_landmarks")]
    pub(crate) reconstruction_landmarks: Option<PathBuf>,
    /// The truth's landmarks (as above).
    #[arg(long, requires = "reconstruction_landmarks")]
    pub(crate) truth_landmarks: Option<PathBuf>,
    /// The reconstruction's exact surface (its `surface.json`, same frame and units): the inner
    /// face is also scored against it, by point inversion (needs the landmarks).
    #[arg(long, requires = "reconstruction_landmarks")]
    pub(crate) reconstruction_surface: Option<PathBuf>,
    /// Units of the reconstruction's coordinates: mm, cm or m.
    #[arg(long, default_value = "mm")]
    pub(crate) reconstruction_units: String,
    /// Units of the truth's coordinates: mm, cm or m.
    #[arg(long, default_value = "mm")]
    pub(crate) truth_units: String,
    /// Pixels along the depth maps' longer side.
    #[arg(long, default_value_t = 512)]
    pub(crate) size: usize,
    /// The heatmap's scale top in mm (default: the 99th percentile of |Δz|).
    #[arg(long)]
    pub(crate) max: Option<f64>,
}

/// Where the face's landmarks and reference come from (`reconstruct`, `batch`).
#[derive(clap::Args)]
pub(crate) struct FaceArgs {
    /// A reference face file (default: the embedded ICT mean face).
    #[arg(long)]
    pub(crate) reference: Option<PathBuf>,
    /// dlib's 68-point model (`shape_predictor_68_face_landmarks.dat`; `tools/fetch-models`
    /// downloads it) for photos without a landmark file: faces are then detected and
    /// landmarked. Default: $SPLINEFACE_LANDMARK_MODEL.
    #[arg(long, env = "SPLINEFACE_LANDMARK_MODEL")]
    pub(crate) landmark_model: Option<PathBuf>,
}

/// Output options shared by `reconstruct`, `batch` and `demo`.
#[derive(clap::Args)]
pub(crate) struct OutputArgs {
    /// Output units: `mm` or `canonical` (the paper's: 50 between the eye centres).
    #[arg(long, default_value = "mm")]
    pub(crate) units: String,
    /// The distance between the eye centres in millimetres, for `--units mm`.
    #[arg(long, default_value_t = 63.0)]
    pub(crate) eye_distance: f64,
    /// Where the face's shape comes from: `space` (default, by measurement: the reference's
    /// face space fitted to the photos' points) or `deformed` (the reference deformed to the
    /// estimated structure, the paper's way; also used when the reference has no space).
    #[arg(long, default_value = "space")]
    pub(crate) shape: String,
    /// The face-space fit's landmark noise per coordinate, canonical units (larger keeps the
    /// face nearer the mean).
    #[arg(long, default_value_t = splineface::pipeline::Shape::DEFAULT_NOISE)]
    pub(crate) space_noise: f64,
    /// The prior deviation of each photo's expression weights in the face-space fit (larger
    /// lets the photos' points pull harder on the expression).
    #[arg(long, default_value_t = splineface::pipeline::Shape::DEFAULT_EXPRESSION_SIGMA)]
    pub(crate) expression_sigma: f64,
    /// Take every photo as neutral: fit no expressions.
    #[arg(long)]
    pub(crate) no_expressions: bool,
    /// Tie the jaw's landmarks to fixed places of the face rather than to its outline as each
    /// photo sees it (where a landmarker puts them; the outline is the default, by
    /// measurement).
    #[arg(long)]
    pub(crate) no_outline: bool,
    /// Read an open mouth from the gaps between the inner lips in the face-space fit, where the
    /// landmarks have the 68 iBUG points (off by default: on rendered photos it did not pay,
    /// see `splineface::face::LIP_WEIGHT`).
    #[arg(long)]
    pub(crate) lips: bool,
    /// Make the face with this photo's expression (its file stem, as the report names it)
    /// instead of the neutral identity.
    #[arg(long, value_name = "PHOTO")]
    pub(crate) expression_of: Option<String>,
    /// Keep the landmark fit: do not refine the face with the photos' pixels (the refinement
    /// makes the photos agree on what lies at each point of the face; it needs images and
    /// `--shape space`).
    #[arg(long)]
    pub(crate) no_refine: bool,
    /// Refine without the displacement of the control grid: the photos move the face space's
    /// weights and the cameras alone (the displacement carries the detail the space cannot, and
    /// costs about a fifth of a second for eight photos).
    #[arg(long)]
    pub(crate) no_displacement: bool,
    /// The surface deformation of `--shape deformed`: `local` (default, by measurement) or
    /// `affine` (the paper's).
    #[arg(long, default_value = "local")]
    pub(crate) deformation: String,
    /// Mesh vertex spacing, canonical units.
    #[arg(long, default_value_t = 1.0)]
    pub(crate) spacing: f64,
    /// The depth map's larger side, pixels.
    #[arg(long, default_value_t = 512)]
    pub(crate) depth_size: usize,
    /// The texture atlas's side (`face.png`), texels: 16 to 8192, or `auto` (about one texel
    /// per pixel of the sharpest photo over the face, 256 to 2048).
    #[arg(long, default_value = "auto")]
    pub(crate) texture_size: String,
    /// Stop with an error when fewer photos than this are usable (one photo measured worse
    /// than the unchanged mean face; see tools/results/evaluation.md).
    #[arg(long, default_value_t = splineface::pipeline::MIN_PHOTOS)]
    pub(crate) min_photos: usize,
}

impl OutputArgs {
    /// The index of `--expression-of`'s photo among `inputs`.
    pub(crate) fn expression_photo(&self, inputs: &[Input]) -> Result<Option<usize>> {
        let Some(name) = &self.expression_of else {
            return Ok(None);
        };
        splineface::pipeline::photo_index(inputs, name)
            .map(Some)
            .with_context(|| format!("--expression-of {name}"))
    }

    /// The pipeline's options, checked by the library ([`splineface::pipeline::Settings`]).
    pub(crate) fn options(&self) -> Result<PipelineOptions> {
        let texture_size = match self.texture_size.as_str() {
            "auto" => None,
            text => Some(text.parse::<u32>().map_err(|_| {
                anyhow::anyhow!(
                    "--texture-size {text}: expected auto or a whole number of texels (16 to 8192)"
                )
            })?),
        };
        let settings = splineface::pipeline::Settings {
            units: self.units.clone(),
            eye_distance: self.eye_distance,
            shape: self.shape.clone(),
            space_noise: self.space_noise,
            expression_sigma: self.expression_sigma,
            expressions: !self.no_expressions,
            outline: !self.no_outline,
            lips: self.lips,
            refine: !self.no_refine,
            displacement: !self.no_displacement,
            deformation: self.deformation.clone(),
            spacing: self.spacing,
            depth_size: self.depth_size,
            texture_size,
            min_photos: self.min_photos,
        };
        settings
            .options()
            .map_err(|e| anyhow::anyhow!("--{} {}: {}", e.setting.replace('_', "-"), e.value, e.expected))
    }
}

// The arguments of `splineface fit-surface`.
#[derive(clap::Args)]
pub(crate) struct FitSurfaceArgs {
    /// The scan: a mesh (OBJ, PLY, glTF or GLB; its vertices are fitted) or XYZ text (`.xyz`
    /// or `.txt`, one `x y z` a line).
    pub(crate) scan: PathBuf,
    /// The surface to write: `.json` or `.step`.
    #[arg(long)]
    pub(crate) out: PathBuf,
    /// Control points per direction (the starting grid with `--tolerance`).
    #[arg(long, default_value_t = 16)]
    pub(crate) grid: usize,
    /// The largest residual allowed, in the scan's units: refine the knots until it holds.
    #[arg(long)]
    pub(crate) tolerance: Option<f64>,
    /// The most control points per direction `--tolerance` may reach.
    #[arg(long, default_value_t = 128)]
    pub(crate) max_grid: usize,
    /// The degree in both directions (1 to 5).
    #[arg(long, default_value_t = 3)]
    pub(crate) degree: usize,
    /// The thin-plate smoothness weight (0: pure least squares).
    #[arg(long, default_value_t = 1e-12)]
    pub(crate) smoothness: f64,
    /// The plane's normal `X,Y,Z` (default: the points' direction of least variance).
    #[arg(long)]
    pub(crate) normal: Option<String>,
    /// Also write the surface as a mesh over the scan's part of the plane: `.obj` or `.ply`.
    #[arg(long)]
    pub(crate) mesh: Option<PathBuf>,
    /// The scan's length unit, which a `.step` surface declares: `mm`, `cm` or `m` (the
    /// numbers are kept as they are).
    #[arg(long, default_value = "mm")]
    pub(crate) units: String,
}
