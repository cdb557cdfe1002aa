//! Photos (or their points) in, face out: the stages chained, and every output file.
//!
//! 0. **Agreement**: with images, photos whose landmarks mark other places of the face than the
//!    other photos' do are left out ([`crate::align::landmark_agreement`]).
//! 1. **Frontal structure**: RASL over the photos when images are given
//!    ([`crate::align::rasl_frontal`]), else points-only Procrustes
//!    ([`crate::align::procrustes_frontal`]).
//! 2. **Depth**: [`crate::depth::estimate_depth`].
//! 3. **Surface** ([`Shape`]): by default the reference's face space fitted jointly to the
//!    kept photos' points ([`crate::face::FaceSpace::fit_photos`]); otherwise, or when the
//!    reference has no space, the reference grid deformed to the estimated structure, followed
//!    as far as the evidence allows ([`StructureWeight`]; [`crate::face::shrunk_toward_reference`],
//!    [`crate::face::FaceSurface::deform`]). Then its clipped mesh, and, with images, a texture
//!    atlas in the surface's `(u, v)` baked from every photo whose points fit well
//!    ([`crate::face::bake_texture`]). With images and [`PipelineOptions::refine`], the
//!    face-space fit is refined by the photos' pixels ([`crate::face::FaceSpace::refine_photos`]:
//!    the photos are made to agree on what lies at each point of the face). The photo stages
//!    use the reference as the photo path sees it ([`ReferenceFace::as_seen_in_photos`]).
//! 4. **Outputs** ([`Reconstruction::files`]), in the chosen units: `face.obj` (+ `face.mtl`,
//!    and with images `face.png`, the atlas, `texture-confidence.png` and `turntable.png`),
//!    `face.glb`, `face.ply` (every mesh with its surface parameters as texture coordinates),
//!    `surface.json`, `surface.step`,
//!    `depth.exr`, `depth.png`, `preview.png`, `curvature.png` ([`files::CURVATURE_SIDE`]),
//!    `structure.json`, `report.json`, `aligned/*.png` after RASL, and
//!    `consistency.png` after the refinement. Each photo's camera and the face's points seen by
//!    it are kept ([`Reconstruction::photo_fits`]); [`PhotoSet::files`] draws them on the photos
//!    and adds the page ([`crate::report`]: `overlays/`, `landmarks/`, `report.html`).
//!
//! Everything is computed before anything is written, so a caller can write the files all or
//! nothing ([`crate::io::write_files_atomically`]).

pub mod files;
mod photos;
mod settings;

pub use photos::{
    IMAGE_EXTENSIONS, InputError, LANDMARK_EXTENSIONS, LandmarkedPhotos, PhotoRecord, PhotoSet, PhotoTiming,
    gather_inputs, landmark_photos, photo_index, photo_list,
};
pub(crate) use photos::{files_in, photo_files};
pub use settings::Settings;

use std::path::PathBuf;
use std::time::Instant;

use nalgebra::Point3;
use rayon::prelude::*;

use crate::Real;
use crate::align::{
    AlignError, Dropped, FrontalStructure, GreyImage, PhotoPoints, RaslOptions, RaslPhoto, RaslResult,
    disagreeing_photos, landmark_agreement, procrustes_frontal, rasl_frontal,
};
use crate::depth::{DepthError, DepthEstimate, DepthOptions, StructurePrior, estimate_depth};
use crate::face::{
    ClippedMesh, Deformation, ExpressionPrior, FaceError, FaceSurface, FaceTexture, MeshOptions,
    RefineOptions, RefineView, RefinedCamera, Refinement, TextureOptions, TexturePhoto, Units, bake_texture,
};
use crate::mesh::TriangleMesh;
use crate::reference::ReferenceFace;
use crate::render::{DepthMap, View};

/// A photo's image: grey for alignment, colour for the texture.
#[derive(Debug, Clone)]
pub struct PhotoImage {
    /// The grey image RASL aligns.
    pub grey: GreyImage,
    /// The colour image, for the texture.
    pub colour: image::RgbImage,
}

impl PhotoImage {
    /// Both forms of a decoded photo.
    ///
    /// # Errors
    /// As [`GreyImage::from_dynamic`].
    pub fn from_dynamic(image: &image::DynamicImage) -> Result<Self, crate::align::PhotoProblem> {
        Ok(PhotoImage {
            grey: GreyImage::from_dynamic(image)?,
            colour: image.to_rgb8(),
        })
    }
}

/// One photo handed to [`reconstruct`]: its points and, unless points-only, its image.
#[derive(Debug, Clone)]
pub struct Input {
    /// The 40 points, in the photo's pixels.
    pub points: PhotoPoints,
    /// The image, if any.
    pub image: Option<PhotoImage>,
}

/// How [`reconstruct`] runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PipelineOptions {
    /// The depth stage's options.
    pub depth: DepthOptions,
    /// How the reference grid is deformed.
    pub deformation: Deformation,
    /// The clipped mesh's resolution.
    pub mesh: MeshOptions,
    /// Output units.
    pub units: Units,
    /// RASL's options.
    pub rasl: RaslOptions,
    /// The depth map's larger side, pixels.
    pub depth_map_size: usize,
    /// The fewest usable photos a reconstruction accepts ([`MIN_PHOTOS`] by default).
    pub min_photos: usize,
    /// How far the surface follows the estimated structure beyond the similarity that best
    /// maps the reference's onto it ([`StructureWeight`]).
    pub structure_weight: StructureWeight,
    /// Leave out photos whose landmarks mark other places than the other photos' do
    /// ([`crate::align::landmark_agreement`]; needs images and three photos or more).
    pub drop_disagreeing: bool,
    /// Where the face's shape comes from.
    pub shape: Shape,
    /// Make the face with this photo's expression (its index among the inputs) instead of
    /// the neutral identity; needs [`Shape::Space`] with expressions fitted, and the photo
    /// kept ([`PipelineError::ExpressionOf`] otherwise).
    pub expression_of: Option<usize>,
    /// Refine the face-space fit with the photos' pixels ([`crate::face::FaceSpace::refine_photos`]):
    /// with images and [`Shape::Space`] only; `None` keeps the landmark fit. On by default
    /// (measured: [`RefineOptions::default`]).
    pub refine: Option<RefineOptions>,
    /// How the texture atlas is baked from the photos ([`crate::face::bake_texture`]; with
    /// images only).
    pub texture: TextureOptions,
}

/// Where the face's shape comes from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Shape {
    /// The paper's way: the reference surface deformed to the estimated 3D structure
    /// ([`PipelineOptions::deformation`], [`PipelineOptions::structure_weight`]).
    Deformed,
    /// The reference's face space ([`crate::face::FaceSpace`]) fitted jointly to the kept
    /// photos' points ([`crate::face::FaceSpace::fit_photos`], the contour points at the depth
    /// stage's weight) with noise `noise` per coordinate (canonical units); the depth stage
    /// still chooses the photos and reports their poses. A reference without a space falls
    /// back to [`Shape::Deformed`], and the report says so.
    Space {
        /// `ε`, canonical units.
        noise: Real,
        /// The prior of each photo's expression weights
        /// ([`crate::face::PhotoFitOptions::expressions`]), or `None` to take every photo as
        /// neutral.
        expressions: Option<ExpressionPrior>,
        /// Measure the jaw points off the chin against the face's outline as each photo
        /// sees it ([`crate::face::PhotoFitOptions::outline`]); `false` ties them to fixed
        /// places of the face.
        outline: bool,
        /// The weight of each photo's inner-lip gaps beside a point's
        /// ([`crate::face::PhotoFitOptions::lips`]; 0, the default, leaves them out: measured
        /// at [`crate::face::LIP_WEIGHT`]).
        lips: Real,
    },
}

/// How far the surface follows the estimated structure: the weight `α` of
/// [`crate::face::shrunk_toward_reference`] (1 follows the estimate fully, 0 keeps the
/// reference's shape where the estimate puts it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StructureWeight {
    /// As the evidence allows: `α = n / (n + SHRINKAGE · σ²)` for `n` photos whose points fit
    /// the structure with a median RMS error of `σ` units over the points off the contour
    /// ([`crate::depth::PhotoFit::inner_rms_units`]), the shrinkage of a mean measured `n` times
    /// with noise `σ` toward a prior (see [`SHRINKAGE`]); 0 when two photos' landmarks disagree
    /// ([`crate::align::landmark_agreement`] below its floor for both).
    Auto,
    /// This `α`, in `[0, 1]`.
    Fixed(Real),
}

impl Shape {
    /// The default [`Shape::Space`] noise, canonical units per coordinate (≈ 5 mm).
    pub const DEFAULT_NOISE: Real = 4.0;

    /// The default [`Shape::Space`] expression deviation `τ`.
    ///
    /// Measured by `tools/photo_eval --expressions` (six ICT-FaceKit identities wearing real
    /// skins, photographed neutral, smiling and with an open jaw in the same poses, the whole
    /// photo path, scored against the neutral identity): the error from expressive photos over
    /// the error from neutral ones, smile / open jaw, 3 and 8 photos:
    ///
    /// | τ | smile 3 | smile 8 | jaw 3 | jaw 8 | neutral photos 3 / 8 (ratio to the mean face) |
    /// |---|---|---|---|---|---|
    /// | none (every photo neutral) | 1.04 | 1.16 | 1.20 | 1.30 | 0.90 / 0.83 |
    /// | 0.25 | 1.02 | 1.11 | 1.02 | 1.09 | 0.92 / 0.84 |
    /// | **0.5** | 1.00 | 1.07 | 0.99 | 1.02 | 0.93 / 0.85 |
    /// | 1 | 0.99 | 1.03 | 0.98 | 0.99 | 0.92 / 0.86 |
    ///
    /// `τ = 1` is as good or a little better on these and on the real scan (0.86 against 0.88×
    /// its mean face's error with its 8 given photos), but fits the landmarks' noise into
    /// more than twice as many expression weights and takes twice the iterations (the bench's 35
    /// photos: 16 against 8); `0.5` keeps every expression within 7% of the neutral photos'
    /// error. (This table was measured with the plain, independent prior on an earlier
    /// evaluation; [`ExpressionPrior`] measures the shared expression and the rate added since.)
    pub const DEFAULT_EXPRESSION_SIGMA: Real = ExpressionPrior::DEFAULT.sigma;
}

impl Default for Shape {
    /// [`Shape::Space`] with `ε = 4` units.
    ///
    /// Measured by `tools/photo_eval` (107 sets of 2–16 photo-realistic photos of the
    /// Lee Perry-Smith scan and six ICT-FaceKit identities wearing real skins, the whole photo
    /// path; the space cut to ICT's first 40 modes, the identities drawn with all 60), mean
    /// ratio of the inner-face error to the mean face's for 2 / 3 / 4 / 8 / 16 photos:
    ///
    /// | shape | 2 | 3 | 4 | 8 | 16 | `lps-head` photos-8 / photos-3 |
    /// |---|---|---|---|---|---|---|
    /// | deformed (the structure stage's face) | 1.06 | 1.02 | 0.96 | 0.95 | 0.92 | 0.98 / 1.03 |
    /// | space, every photo neutral | 0.90 | 0.88 | 0.86 | 0.86 | 0.82 | 0.91 / 0.90 |
    /// | **space, an expression per photo (τ = 0.5)** | 0.94 | 0.90 | 0.88 | 0.87 | 0.82 | **0.88 / 0.88** |
    /// | space, τ = 1 | 0.94 | 0.90 | 0.88 | 0.87 | 0.83 | 0.86 / 0.87 |
    ///
    /// Per-photo expressions cost a little on neutral photos of faces the space describes well
    /// and keep the face when the photos show expressions ([`Shape::DEFAULT_EXPRESSION_SIGMA`]).
    /// (Measured with the plain prior on the expressions; [`ExpressionPrior::DEFAULT`]'s shared
    /// expression and rate since took the landmarks-only row of today's evaluation from
    /// 0.94 / 0.91 / 0.90 / 0.89 / 0.89 to 0.93 / 0.90 / 0.89 / 0.89 / 0.88 and the refined
    /// default's from 0.87 / 0.78 / 0.76 / 0.75 / 0.70 to 0.86 / 0.77 / 0.74 / 0.74 / 0.69,
    /// `tools/results/photos.md`.)
    /// `ε = 4` was chosen with the earlier, alternating fit (ε = 2 / 4 / 8: 0.89 / 0.90 / 0.94
    /// with two photos, 1.03 / 0.90 / 0.89 on the scan's 8 photos): smaller `ε` follows the
    /// landmarks more and wins on faces the space describes well, but fits the landmarker's
    /// errors into the shape of the real scan, which lies outside the space.
    fn default() -> Self {
        Shape::Space {
            noise: Self::DEFAULT_NOISE,
            expressions: Some(ExpressionPrior::DEFAULT),
            outline: true,
            lips: 0.0,
        }
    }
}

/// The constant of [`StructureWeight::Auto`], per square canonical unit.
///
/// Measured with `tools/photo_eval` (every set of 2–16 photos of 7 photo-realistic subjects,
/// dlib's landmarks, whose points fit with a median RMS of about 1.1 units): fixed weights gave
/// mean ratios to the mean face's error of 0.99 / 1.01 / 0.97 / 0.97 / 0.97 (α = 0.25),
/// 1.04 / 1.08 / 0.96 / 0.95 / 0.94 (α = 0.5) and 1.13 / 1.18 / 0.97 / 0.95 / 0.93 (α = 0.75)
/// for 2 / 3 / 4 / 8 / 16 photos: the best weight grows from about 0.25 at two photos to about
/// 0.75 at sixteen, as `n / (n + 6)` does; `6 ≈ 5 · 1.1²`. Landmarks projected without noise
/// fit to a few tenths of a unit, and the weight goes to 1.
pub const SHRINKAGE: Real = 5.0;

/// The default [`PipelineOptions::min_photos`]: two.
///
/// Measured (`tools/results/evaluation.md`, Fig. 8(3), 10 ICT-FaceKit subjects): from one photo
/// the default method's mean |Δz| is 4.84 ± 1.41 mm, *worse* than leaving the mean face
/// unchanged (3.57 ± 1.25 mm); two photos give 2.76 ± 1.20 mm and four or more about 1.9 mm. A
/// single photo is therefore refused unless the caller lowers the bar.
pub const MIN_PHOTOS: usize = 2;

impl Default for PipelineOptions {
    fn default() -> Self {
        PipelineOptions {
            depth: DepthOptions::default(),
            deformation: Deformation::default(),
            mesh: MeshOptions::default(),
            units: Units::default(),
            rasl: RaslOptions::default(),
            depth_map_size: 512,
            min_photos: MIN_PHOTOS,
            drop_disagreeing: true,
            structure_weight: StructureWeight::Auto,
            shape: Shape::default(),
            expression_of: None,
            refine: Some(RefineOptions::default()),
            texture: TextureOptions::default(),
        }
    }
}

/// What can stop a reconstruction.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PipelineError {
    /// Nothing to work with.
    #[error("no usable photos")]
    NoInputs,
    /// Fewer usable photos than [`PipelineOptions::min_photos`].
    #[error(
        "{usable} usable photo{}, at least {needed} needed{}",
        if *usable == 1 { "" } else { "s" },
        dropped.iter().map(|d| format!("; {} was dropped: {}", d.name, d.reason)).collect::<String>()
    )]
    TooFewPhotos {
        /// How many were usable.
        usable: usize,
        /// How many are needed.
        needed: usize,
        /// The photos left out by alignment, and why.
        dropped: Vec<Dropped>,
    },
    /// The frontal structure could not be found.
    #[error("frontal structure: {0}")]
    Align(#[from] AlignError),
    /// Depth estimation failed.
    #[error("depth: {0}")]
    Depth(#[from] DepthError),
    /// The surface could not be made.
    #[error("surface: {0}")]
    Face(#[from] FaceError),
    /// The face was asked for with a photo's expression ([`PipelineOptions::expression_of`])
    /// that the reconstruction does not know.
    #[error("the face with the expression of photo {photo} cannot be made: {reason}")]
    ExpressionOf {
        /// The photo's index among the inputs.
        photo: usize,
        /// Why.
        reason: String,
    },
    /// An output could not be encoded.
    #[error("encoding {file}: {message}")]
    Encode {
        /// The output.
        file: String,
        /// Why.
        message: String,
    },
}

/// How the face fits one of its photos: the photo's last fitted camera (the refinement's
/// when it ran, else the face-space fit's, else the depth stage's pose) and the face's 40
/// points, with the photo's own fitted expression, seen by it.
#[derive(Debug, Clone, PartialEq)]
pub struct PhotoFit {
    /// The photo's name.
    pub name: String,
    /// Its camera (for a points-only run, the scaled orthographic camera of a 1 × 1 image:
    /// the principal point does not matter without perspective).
    pub camera: RefinedCamera,
    /// The face's 40 points as the camera sees them, pixels with `y` down (`NaN` for a point
    /// behind the camera); the jaw points off the chin on the face's outline when the fit
    /// measured them there ([`crate::face::PhotoSpaceFit::outline_shifts`]).
    pub points: Vec<nalgebra::Point2<Real>>,
    /// The RMS distance from the photo's own 40 points, pixels.
    pub rms_pixels: Real,
}

/// A finished reconstruction (canonical frame; [`Reconstruction::files`] converts units).
#[derive(Debug, Clone)]
pub struct Reconstruction {
    /// The frontal structure used.
    pub frontal: FrontalStructure,
    /// RASL's result, when images were aligned.
    pub rasl: Option<RaslResult>,
    /// The 3D structure, poses and diagnostics.
    pub depth: DepthEstimate,
    /// The deformed surface.
    pub face: FaceSurface,
    /// Its clipped mesh.
    pub mesh: ClippedMesh,
    /// The texture atlas baked from every usable photo, when images were given (and one
    /// photo's pose was not flagged as bad).
    pub texture: Option<FaceTexture>,
    /// The photos that gave the texture (names, in the order of its gains and shares), or
    /// why there is none.
    pub texture_photos: Result<Vec<String>, String>,
    /// Photos left out, and why.
    pub dropped: Vec<Dropped>,
    /// Each photo's landmark agreement with the others ([`crate::align::landmark_agreement`]),
    /// by name, in input order; empty for a points-only run.
    pub agreement: Vec<(String, Real)>,
    /// The weight with which the surface follows the estimated structure
    /// ([`PipelineOptions::structure_weight`]), and why.
    pub structure_weight: (Real, String),
    /// How the face fits each photo it was made from, in the order of
    /// [`DepthEstimate::photos`].
    pub photo_fits: Vec<PhotoFit>,
    /// The face space's fit, when the shape came from it ([`Shape::Space`]).
    pub space: Option<crate::face::PhotoSpaceFit>,
    /// The refinement by the photos' pixels, when it ran ([`PipelineOptions::refine`]).
    pub refinement: Option<Refinement>,
    /// How the shape was made, in words (for the report).
    pub shape: String,
    /// Wall time per stage, seconds, in order.
    pub timings: Vec<(String, Real)>,
    /// The options used.
    pub options: PipelineOptions,
}

/// Runs the stages (see the module documentation) on the inputs, in their order. Photos with
/// images go through RASL when *every* input has an image; otherwise the run is points-only.
///
/// # Errors
/// [`PipelineError::NoInputs`] for an empty list, [`PipelineError::TooFewPhotos`] when fewer
/// than [`PipelineOptions::min_photos`] inputs are given or survive alignment, else the failing
/// stage's error.
///
/// # Examples
/// ```
/// use splineface::demo::{SceneOptions, scene};
/// use splineface::pipeline::{Input, PipelineOptions, reconstruct};
/// use splineface::reference::ReferenceFace;
///
/// // Four photos of the demo subject; their points alone (no images: no RASL, refinement or
/// // texture), which is quick.
/// let photos = scene(&SceneOptions { photos: 4, ..SceneOptions::default() }).unwrap();
/// let points: Vec<Input> = photos.inputs.iter().map(|i| Input { points: i.points.clone(), image: None }).collect();
/// let face = reconstruct(&points, ReferenceFace::embedded(), &PipelineOptions::default(), |stage| eprintln!("{stage}")).unwrap();
/// assert_eq!(face.depth.photos.len(), 4);
/// assert!(face.mesh.mesh.triangles().len() > 1000);
/// // Files as `splineface reconstruct` writes them.
/// let files = face.files().unwrap();
/// assert!(files.iter().any(|(path, _)| path.ends_with("face.glb")));
/// ```
pub fn reconstruct(
    inputs: &[Input],
    reference: &ReferenceFace,
    options: &PipelineOptions,
    progress: impl FnMut(&str),
) -> Result<Reconstruction, PipelineError> {
    Ok(run(inputs, reference, options, progress, false, |_| ())?.0)
}

/// Output files: `(path relative to the output directory, bytes)`.
pub type OutputFiles = Vec<(PathBuf, Vec<u8>)>;

/// [`reconstruct`], then [`Reconstruction::files`]: the same reconstruction and the same files,
/// sooner. The files that need no texture (the surface, depth maps, curvature, consistency
/// and RASL's pictures) are encoded while the texture is baked, on the cores the bake leaves
/// idle; the report's timings then list them beside the texture's.
///
/// # Errors
/// As [`reconstruct`] and [`Reconstruction::files`].
pub fn reconstruct_files(
    inputs: &[Input],
    reference: &ReferenceFace,
    options: &PipelineOptions,
    progress: impl FnMut(&str),
) -> Result<(Reconstruction, OutputFiles), PipelineError> {
    let (result, files, ()) = reconstruct_files_beside(inputs, reference, options, progress, |_| ())?;
    Ok((result, files))
}

/// [`reconstruct_files`] with `beside_texture`'s answer, made beside the texture's bake from
/// the reconstruction as it stands then (everything but the texture).
pub(crate) fn reconstruct_files_beside<T: Send>(
    inputs: &[Input],
    reference: &ReferenceFace,
    options: &PipelineOptions,
    progress: impl FnMut(&str),
    beside_texture: impl FnOnce(&Reconstruction) -> T + Send,
) -> Result<(Reconstruction, OutputFiles, T), PipelineError> {
    let (result, untextured, beside) = run(inputs, reference, options, progress, true, beside_texture)?;
    let files = match untextured {
        Some(untextured) => result.files_after(untextured)?,
        None => result.files()?,
    };
    Ok((result, files, beside))
}

/// [`reconstruct`]; with `encode`, also the files that need no texture, encoded beside the
/// texture's bake; and `beside_texture`'s answer, which it gives after them, beside the bake
/// (or after the stages when there is no texture to bake).
fn run<T: Send>(
    inputs: &[Input],
    reference: &ReferenceFace,
    options: &PipelineOptions,
    mut progress: impl FnMut(&str),
    encode: bool,
    beside_texture: impl FnOnce(&Reconstruction) -> T + Send,
) -> Result<(Reconstruction, Option<files::Untextured>, T), PipelineError> {
    let needed = check_request(inputs, options)?;
    // The structure to deform from is where the photo path puts landmarks on the reference.
    let reference: &ReferenceFace = &reference.as_seen_in_photos();
    let mut timings = Vec::new();
    let with_images = inputs.iter().all(|i| i.image.is_some());
    let start = Instant::now();
    let Agreement {
        scores: agreement,
        agreeing,
        mut dropped,
    } = agreement(inputs, options, with_images);
    if agreeing.len() < needed {
        return Err(PipelineError::TooFewPhotos {
            usable: agreeing.len(),
            needed,
            dropped,
        });
    }
    let names: Vec<String> = inputs.iter().map(|i| i.points.name.clone()).collect();
    let inputs: Vec<&Input> = agreeing.iter().map(|&k| &inputs[k]).collect();
    progress(&if with_images {
        format!("aligning {} photos and their mirror images (RASL)", inputs.len())
    } else {
        format!("frontal structure from the points of {} photos", inputs.len())
    });
    // The face space's fit and the refinement read the photos and their points, not the
    // frontal structure, and could run beside RASL. Measured (`tools/ab-bench`, 8 runs by
    // turns, `lps-head/photos-8`): no faster (wall 1.01 / 1.09 s best / median beside, 1.00 /
    // 1.09 s after; each stage already keeps both cores busy), 5% more CPU and a peak of 217–224
    // MB against 171–173. So they run after it, on the photos it kept.
    let (frontal, rasl, kept) = frontal_structure(&inputs, options, with_images)?;
    timings.push(("frontal structure".to_owned(), start.elapsed().as_secs_f64()));
    dropped.extend(rasl.as_ref().map(|r| r.dropped.clone()).unwrap_or_default());
    if kept.len() < needed {
        return Err(PipelineError::TooFewPhotos {
            usable: kept.len(),
            needed,
            dropped,
        });
    }

    progress("estimating depth and poses");
    let start = Instant::now();
    let points: Vec<PhotoPoints> = kept.iter().map(|&k| inputs[k].points.clone()).collect();
    let prior = StructurePrior::from_reference(reference);
    let depth = estimate_depth(&points, &frontal, &prior, &options.depth)?;
    timings.push(("depth".to_owned(), start.elapsed().as_secs_f64()));

    let start = Instant::now();
    let space = face_space(reference, options);
    let kept_agreement: Vec<Real> = kept.iter().map(|&k| agreement[agreeing[k]]).collect();
    let (structure_weight, weight_note) = structure_weight(options, &depth, &kept_agreement);
    let (face, space_fit, shape, refinement, surface_start) = match &space {
        Some((space, fit_options)) => {
            progress("fitting the face space to the photos' points and meshing the face");
            let photos = KeptPhotos {
                inputs: &inputs,
                kept: &kept,
                with_images,
            };
            let fitted = space_face(
                space,
                fit_options,
                reference,
                &photos,
                options,
                (&mut timings, start),
                &mut progress,
            )?;
            (
                fitted.face,
                Some(fitted.fit),
                fitted.shape,
                fitted.refinement,
                fitted.surface_start,
            )
        }
        None => {
            progress("deforming the reference surface and meshing the face");
            let (face, shape) = deformed_face(reference, &depth, structure_weight, options)?;
            (face, None, shape, None, start)
        }
    };
    let mesh = face.mesh(&options.mesh)?;
    timings.push(("surface".to_owned(), surface_start.elapsed().as_secs_f64()));
    let space_and_fit = space.as_ref().map(|(s, _)| s).zip(space_fit.as_ref());
    let fits = photo_fits(&inputs, &kept, &depth, space_and_fit, refinement.as_ref())?;
    let mut result = Reconstruction {
        frontal,
        rasl,
        depth,
        face,
        mesh,
        texture: None,
        texture_photos: Err("no images".to_owned()),
        dropped,
        structure_weight: (structure_weight, weight_note),
        photo_fits: fits,
        space: space_fit,
        refinement,
        shape,
        agreement: if with_images {
            names.into_iter().zip(agreement).collect()
        } else {
            Vec::new()
        },
        timings,
        options: *options,
    };
    let untextured = |r: &Reconstruction| encode.then(|| r.untextured_files(with_images));
    let (untextured, beside) = if with_images {
        progress(if encode {
            "baking the texture from the photos (and encoding the outputs that need none)"
        } else {
            "baking the texture from the photos"
        });
        let start = Instant::now();
        let r = &result;
        let space_and_fit = space.as_ref().map(|(s, _)| s).zip(r.space.as_ref());
        let (baked, (untextured, beside)) = rayon::join(
            || {
                texture_from_photos(
                    &r.face,
                    reference,
                    (&inputs, &kept, &r.photo_fits),
                    &r.depth,
                    space_and_fit,
                    r.refinement.as_ref(),
                    &options.texture,
                )
            },
            || (untextured(r), beside_texture(r)),
        );
        let baked = baked?;
        result
            .timings
            .push(("texture".to_owned(), start.elapsed().as_secs_f64()));
        match baked {
            Ok((texture, names)) => {
                result.texture = Some(texture);
                result.texture_photos = Ok(names);
            }
            Err(why) => result.texture_photos = Err(why),
        }
        (untextured, beside)
    } else {
        (untextured(&result), beside_texture(&result))
    };
    let untextured = match untextured {
        Some(files) => {
            let (files, seconds) = files?;
            result.timings.push((
                "outputs that need no texture (encoded beside the texture)".to_owned(),
                seconds,
            ));
            Some(files)
        }
        None => None,
    };
    Ok((result, untextured, beside))
}

/// The request's own checks, before any work: some inputs, at least the minimum of photos,
/// and a photo for [`PipelineOptions::expression_of`] that exists. Returns the minimum.
fn check_request(inputs: &[Input], options: &PipelineOptions) -> Result<usize, PipelineError> {
    if inputs.is_empty() {
        return Err(PipelineError::NoInputs);
    }
    let needed = options.min_photos.max(1);
    if inputs.len() < needed {
        return Err(PipelineError::TooFewPhotos {
            usable: inputs.len(),
            needed,
            dropped: Vec::new(),
        });
    }
    if let Some(photo) = options.expression_of
        && photo >= inputs.len()
    {
        return Err(PipelineError::ExpressionOf {
            photo,
            reason: format!("there are only {} photos", inputs.len()),
        });
    }
    Ok(needed)
}

/// Stage 0's answer: each photo's landmark agreement with the others (`NaN` without images),
/// the photos kept, and those left out with why.
struct Agreement {
    scores: Vec<Real>,
    agreeing: Vec<usize>,
    dropped: Vec<Dropped>,
}

/// Stage 0: photos whose landmarks mark other places of the face than the others' do are left
/// out (with images and [`PipelineOptions::drop_disagreeing`]).
fn agreement(inputs: &[Input], options: &PipelineOptions, with_images: bool) -> Agreement {
    let scores: Vec<Real> = if with_images {
        let pairs: Vec<(&GreyImage, &PhotoPoints)> = inputs
            .iter()
            .map(|i| (&i.image.as_ref().expect("checked above").grey, &i.points))
            .collect();
        landmark_agreement(&pairs)
    } else {
        vec![Real::NAN; inputs.len()]
    };
    let disagreeing = if options.drop_disagreeing {
        disagreeing_photos(&scores)
    } else {
        Vec::new()
    };
    let dropped = disagreeing
        .iter()
        .map(|&(k, others)| Dropped {
            name: inputs[k].points.name.clone(),
            reason: format!(
                "its landmarks do not mark the places the other photos' do (patch agreement {:.2}, the others' median {others:.2}): \
                 the landmarker probably failed on it",
                scores[k]
            ),
        })
        .collect();
    let agreeing = (0..inputs.len())
        .filter(|k| !disagreeing.iter().any(|(d, _)| d == k))
        .collect();
    Agreement {
        scores,
        agreeing,
        dropped,
    }
}

/// Stage 1: the frontal structure, by RASL over the photos with images, else from the points
/// alone; with the indices (into `inputs`) of the photos kept.
fn frontal_structure(
    inputs: &[&Input],
    options: &PipelineOptions,
    with_images: bool,
) -> Result<(FrontalStructure, Option<RaslResult>, Vec<usize>), PipelineError> {
    if with_images {
        let photos: Vec<RaslPhoto> = inputs
            .iter()
            .map(|i| RaslPhoto {
                image: std::borrow::Cow::Borrowed(&i.image.as_ref().expect("checked above").grey),
                points: i.points.clone(),
            })
            .collect();
        let result = rasl_frontal(&photos, &options.rasl)?;
        let kept: Vec<usize> = (0..inputs.len())
            .filter(|&k| result.kept.contains(&inputs[k].points.name))
            .collect();
        Ok((result.frontal.clone(), Some(result), kept))
    } else {
        let points: Vec<PhotoPoints> = inputs.iter().map(|i| i.points.clone()).collect();
        Ok((procrustes_frontal(&points)?, None, (0..inputs.len()).collect()))
    }
}

/// How far the deformed surface follows the estimated structure ([`StructureWeight`]), and
/// why; `agreement` is each kept photo's landmark agreement.
fn structure_weight(options: &PipelineOptions, depth: &DepthEstimate, agreement: &[Real]) -> (Real, String) {
    match options.structure_weight {
        StructureWeight::Fixed(alpha) => (alpha, "as asked".to_owned()),
        StructureWeight::Auto => {
            let mut errors: Vec<Real> = depth.photos.iter().map(|p| p.inner_rms_units).collect();
            errors.sort_by(Real::total_cmp);
            let sigma = errors[errors.len() / 2];
            let n = depth.photos.len() as Real;
            let disagree =
                depth.photos.len() == 2 && agreement.iter().all(|&a| a < crate::align::AGREEMENT_FLOOR);
            if disagree {
                (
                    0.0,
                    "the two photos' landmarks disagree (patch agreement below its floor): the face is the reference's"
                        .to_owned(),
                )
            } else {
                let alpha = n / (n + SHRINKAGE * sigma * sigma);
                (
                    alpha,
                    format!(
                        "{n} photos whose points fit with a median RMS of {sigma:.2} units off the contour"
                    ),
                )
            }
        }
    }
}

/// The photos the stages after alignment work with: `kept` indexes `inputs`.
struct KeptPhotos<'a> {
    inputs: &'a [&'a Input],
    kept: &'a [usize],
    with_images: bool,
}

/// Stage 3 by the face space: its fit, the face, how it was made, the refinement when it ran,
/// and when the surface's own timing starts.
struct SpaceFace {
    face: FaceSurface,
    fit: crate::face::PhotoSpaceFit,
    shape: String,
    refinement: Option<Refinement>,
    surface_start: Instant,
}

/// The reference's face space and the fit's options, when [`PipelineOptions::shape`] asks
/// for it and the reference has one.
fn face_space(
    reference: &ReferenceFace,
    options: &PipelineOptions,
) -> Option<(crate::face::FaceSpace, crate::face::PhotoFitOptions)> {
    match options.shape {
        Shape::Space {
            noise,
            expressions,
            outline,
            lips,
        } => reference.face_space().map(|space| {
            (
                space,
                crate::face::PhotoFitOptions {
                    noise,
                    expressions,
                    outline,
                    lips,
                },
            )
        }),
        Shape::Deformed => None,
    }
}

/// Stage 3 by the face space: fitted to the kept photos' points, refined by their pixels (with
/// images and [`PipelineOptions::refine`]), shown neutral or with a photo's expression.
/// `timing` is the timings and when the stage started.
fn space_face(
    space: &crate::face::FaceSpace,
    fit_options: &crate::face::PhotoFitOptions,
    reference: &ReferenceFace,
    photos: &KeptPhotos<'_>,
    options: &PipelineOptions,
    timing: (&mut Vec<(String, Real)>, Instant),
    progress: &mut impl FnMut(&str),
) -> Result<SpaceFace, PipelineError> {
    let (timings, start) = timing;
    let KeptPhotos {
        inputs,
        kept,
        with_images,
    } = *photos;
    let views: Vec<Vec<nalgebra::Point2<Real>>> = kept.iter().map(|&k| inputs[k].points.y_up()).collect();
    let weights = crate::structure::contour_weighted(options.depth.contour_weight);
    let lips: Vec<Option<crate::face::LipGaps>> =
        kept.iter().map(|&k| inputs[k].points.lip_gaps_y_up()).collect();
    let mut fit = space.fit_photos_with_lips(&views, &lips, &weights, fit_options)?;
    // The refinement measures the jaw points against the outline the landmark fit found.
    let views: Vec<Vec<nalgebra::Point2<Real>>> = views
        .iter()
        .enumerate()
        .map(|(i, v)| fit.outline_points(i, v))
        .collect();
    timings.push(("face space".to_owned(), start.elapsed().as_secs_f64()));
    let mut refinement = None;
    if let (Some(refine), true) = (options.refine, with_images) {
        progress("refining the face with the photos' pixels");
        let start = Instant::now();
        let dense: Vec<RefineView> = kept
            .iter()
            .zip(&views)
            .map(|(&k, v)| RefineView {
                image: &inputs[k].image.as_ref().expect("checked above").grey,
                points: v,
            })
            .collect();
        let refined = space.refine_photos(reference, &fit, &dense, &weights, &refine)?;
        if refined.accepted {
            fit.weights = refined.weights.clone();
            fit.expressions = refined.expressions.clone();
        }
        timings.push(("refinement".to_owned(), start.elapsed().as_secs_f64()));
        refinement = Some(refined);
    }
    let surface_start = Instant::now();
    let mut shape = format!(
        "the reference's face space ({} modes) fitted to the points of {} photos, noise {} units",
        space.mode_count(),
        views.len(),
        fit_options.noise
    );
    let fitted_expressions = !fit.expression_names.is_empty();
    if fitted_expressions {
        let prior = fit_options.expressions.unwrap_or_default();
        shape.push_str(&format!(
            ", with each photo's expression ({} modes, deviation {}{}, rate {})",
            space.expressions().len(),
            prior.sigma,
            prior.shared_sigma.map_or(String::new(), |t| format!(
                " around an expression the photos share of deviation {t}"
            )),
            prior.rate
        ));
    }
    if fit_options.outline {
        shape.push_str(", the jaw's points measured on each photo's outline of the face");
    }
    let with_lips = lips.iter().filter(|l| l.is_some()).count();
    if fit_options.lips > 0.0 && space.carries_landmarks() && with_lips > 0 {
        shape.push_str(&format!(
            ", an open mouth read from the inner lips of {with_lips} photos (gap weight {})",
            fit_options.lips
        ));
    }
    let mut face = match options.expression_of {
        None => space.face(reference, &fit.weights)?,
        Some(photo) => {
            let Some(slot) = kept.iter().position(|&k| k == photo) else {
                return Err(PipelineError::ExpressionOf {
                    photo,
                    reason: "it was left out of the reconstruction".to_owned(),
                });
            };
            if !fitted_expressions {
                return Err(PipelineError::ExpressionOf {
                    photo,
                    reason:
                        "no expressions were fitted (the reference's space has none, or they were turned off)"
                            .to_owned(),
                });
            }
            shape.push_str(&format!(
                ", shown with the expression of {}",
                inputs[photo].points.name
            ));
            space.face_with_expression(reference, &fit.weights, &fit.expressions[slot])?
        }
    };
    if !fit.held.is_empty() {
        shape.push_str(&format!(
            "; modes {:?} left the prior's plausible range (±{} deviations) and were held at its edge",
            fit.held,
            crate::face::PLAUSIBLE_SIGMAS
        ));
    }
    if let Some(r) = &refinement {
        shape.push_str(&format!("; {}", r.note));
        if r.accepted && !r.displacement.is_empty() {
            face = face.displaced(&r.displacement)?;
            shape.push_str(", with a displacement of the control grid");
        }
    }
    Ok(SpaceFace {
        face,
        fit,
        shape,
        refinement,
        surface_start,
    })
}

/// Stage 3 without a face space: the reference deformed to the estimated structure, shrunk
/// toward the reference's by `weight` ([`StructureWeight`]); and how it was made.
fn deformed_face(
    reference: &ReferenceFace,
    depth: &DepthEstimate,
    weight: Real,
    options: &PipelineOptions,
) -> Result<(FaceSurface, String), PipelineError> {
    if let Some(photo) = options.expression_of {
        return Err(PipelineError::ExpressionOf {
            photo,
            reason: "the face is the deformed reference (no face space was fitted), which has no expressions"
                .to_owned(),
        });
    }
    let target = crate::face::shrunk_toward_reference(reference, &depth.structure, weight)?;
    let shape = match options.shape {
        Shape::Space { .. } => {
            "the reference deformed to the estimated structure (the reference has no face space)".to_owned()
        }
        Shape::Deformed => "the reference deformed to the estimated structure".to_owned(),
    };
    Ok((
        FaceSurface::deform(reference, &target, options.deformation)?,
        shape,
    ))
}

/// How the face fits each kept photo ([`PhotoFit`]): its last fitted camera (the
/// refinement's when it ran, else the face-space fit's, else the depth stage's pose) and the
/// face's 40 points on the photo's own face (its fitted expression) seen by it.
fn photo_fits(
    inputs: &[&Input],
    kept: &[usize],
    depth: &DepthEstimate,
    space: Option<(&crate::face::FaceSpace, &crate::face::PhotoSpaceFit)>,
    refinement: Option<&Refinement>,
) -> Result<Vec<PhotoFit>, PipelineError> {
    let mut fits = Vec::with_capacity(kept.len());
    for (slot, &k) in kept.iter().enumerate() {
        let input = inputs[k];
        let size = input
            .image
            .as_ref()
            .map_or((1, 1), |i| (i.colour.width(), i.colour.height()));
        let camera = match (refinement, space) {
            (Some(r), _) => r.cameras[slot],
            (None, Some((_, fit))) => {
                let (pose, offset) = &fit.poses[slot];
                RefinedCamera::orthographic(pose, *offset, size)
            }
            (None, None) => {
                let photo = &depth.photos[slot];
                let middle = photo.eye_midpoint;
                RefinedCamera::orthographic(&photo.pose, nalgebra::Point2::new(middle.x, -middle.y), size)
            }
        };
        let structure = match space {
            Some((space, fit)) => {
                let expression = fit.expressions.get(slot).map_or(&[][..], Vec::as_slice);
                space.structure_with_expression(&fit.weights, expression)?
            }
            None => depth.structure.clone(),
        };
        // The jaw points off the chin where the fit measured them: on the face's outline.
        let shifts = space.and_then(|(_, fit)| fit.outline_shifts.get(slot));
        let points: Vec<nalgebra::Point2<Real>> = structure
            .iter()
            .enumerate()
            .map(|(j, x)| {
                let shift = shifts.map_or_else(nalgebra::Vector2::zeros, |s| s[j]);
                camera.pixel(x).map_or_else(
                    || nalgebra::Point2::new(Real::NAN, Real::NAN),
                    // The shifts are `y` up, the pixels `y` down.
                    |p| p - nalgebra::Vector2::new(shift.x, -shift.y),
                )
            })
            .collect();
        let squares: Vec<Real> = points
            .iter()
            .zip(&input.points.points)
            .map(|(p, q)| (p - q).norm_squared())
            .filter(|d| d.is_finite())
            .collect();
        let rms_pixels = (squares.iter().sum::<Real>() / squares.len().max(1) as Real).sqrt();
        fits.push(PhotoFit {
            name: input.points.name.clone(),
            camera,
            points,
            rms_pixels,
        });
    }
    Ok(fits)
}

/// The texture atlas of `face` from the kept photos (see [`crate::face::texture`]), or why
/// there is none. Each photo is seen through its camera in `fits` and on its own face (the
/// fitted expression) when the photos were given expressions. Photos whose points fit badly
/// ([`crate::depth::DepthWarning::BadFit`]) give nothing.
fn texture_from_photos(
    face: &FaceSurface,
    reference: &ReferenceFace,
    (inputs, kept, fits): (&[&Input], &[usize], &[PhotoFit]),
    depth: &DepthEstimate,
    space: Option<(&crate::face::FaceSpace, &crate::face::PhotoSpaceFit)>,
    refinement: Option<&Refinement>,
    options: &TextureOptions,
) -> Result<Result<(FaceTexture, Vec<String>), String>, PipelineError> {
    let usable: Vec<usize> = (0..kept.len()).filter(|&slot| !depth.fits_badly(slot)).collect();
    if usable.is_empty() {
        return Ok(Err("every photo's points fit badly".to_owned()));
    }
    let displacement = refinement
        .filter(|r| r.accepted && !r.displacement.is_empty())
        .map(|r| r.displacement.as_slice());
    let images: Vec<&image::RgbImage> = usable
        .iter()
        .map(|&slot| {
            &inputs[kept[slot]]
                .image
                .as_ref()
                .expect("images were given")
                .colour
        })
        .collect();
    // Each photo's own face (its expression), side by side.
    let own_faces: Vec<Option<FaceSurface>> = usable
        .par_iter()
        .map(|&slot| -> Result<Option<FaceSurface>, PipelineError> {
            Ok(match space {
                Some((space, fit)) if !fit.expression_names.is_empty() => {
                    let own = space.face_with_expression(reference, &fit.weights, &fit.expressions[slot])?;
                    Some(match displacement {
                        Some(d) => own.displaced(d)?,
                        None => own,
                    })
                }
                _ => None,
            })
        })
        .collect::<Result<_, _>>()?;
    let photos: Vec<TexturePhoto<'_>> = usable
        .iter()
        .zip(&images)
        .zip(&own_faces)
        .map(|((&slot, image), own)| TexturePhoto {
            image,
            camera: fits[slot].camera,
            surface: own.as_ref(),
        })
        .collect();
    let texture = bake_texture(face, &photos, options)?;
    let names = usable
        .iter()
        .map(|&slot| inputs[kept[slot]].points.name.clone())
        .collect();
    Ok(Ok((texture, names)))
}

fn encode_error<E: std::fmt::Display>(file: &str) -> impl Fn(E) -> PipelineError + '_ {
    move |error| PipelineError::Encode {
        file: file.to_owned(),
        message: error.to_string(),
    }
}

impl Reconstruction {
    /// The structure in output units.
    pub fn structure(&self) -> Vec<Point3<Real>> {
        let scale = self.options.units.per_canonical_unit();
        self.depth.structure.iter().map(|p| p * scale).collect()
    }

    /// The face mesh in output units, its texture coordinates the surface parameters (the
    /// texture atlas's coordinates, [`crate::face::texture`]).
    pub fn output_mesh(&self) -> TriangleMesh {
        self.mesh
            .parameter_textured()
            .transformed(&self.options.units.transform())
    }

    /// The depth map of `depth.exr`: the output mesh seen from the front, in the output units,
    /// over a raster whose larger side is [`PipelineOptions::depth_map_size`] pixels.
    ///
    /// # Errors
    /// [`PipelineError::Encode`] (for `depth.exr`) when no raster can be framed around the mesh.
    pub fn depth_map(&self) -> Result<DepthMap, PipelineError> {
        self.depth_map_of(&self.output_mesh())
    }

    fn depth_map_of(&self, mesh: &TriangleMesh) -> Result<DepthMap, PipelineError> {
        let size = self.options.depth_map_size;
        let view = View::front();
        let (lo, hi) =
            crate::geometry::bounding_box(mesh.positions()).unwrap_or((Point3::origin(), Point3::origin()));
        let aspect = (hi.y - lo.y) / (hi.x - lo.x).max(Real::MIN_POSITIVE);
        let (w, h) = if aspect >= 1.0 {
            (((size as Real) / aspect).round().max(1.0) as usize, size)
        } else {
            (size, ((size as Real) * aspect).round().max(1.0) as usize)
        };
        DepthMap::framed(mesh, &view, w, h).map_err(encode_error("depth.exr"))
    }
}
