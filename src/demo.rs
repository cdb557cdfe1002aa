//! The embedded demo (`splineface demo`): a ground-truth face that ships with the library,
//! photographed by the project's own renderer under varied poses, for the whole pipeline to
//! reconstruct and be scored against.
//!
//! The subject (`reference/demo-subject.json`, made by `tools/build_demo_subject.rs`) is a
//! control grid the project fitted to an ICT-FaceKit identity with a mild smile and raised
//! brows; it is not the reference face the pipeline starts from (the ICT mean face).

use std::path::PathBuf;
use std::sync::OnceLock;

use nalgebra::{Point2, Point3};

use crate::Real;
use crate::align::{AlignError, PhotoPoints};
use crate::compare::{CompareError, CompareOptions, Comparison};
use crate::error::SettingError;
use crate::face::outline::outline_move;
use crate::face::{Deformation, FaceError, FaceSurface, MeanFace, MeshOptions, OUTLINE_POINTS};
use crate::io::EncodeError;
use crate::landmarks::format_pts;
use crate::mesh::TriangleMesh;
use crate::pipeline::{Input, PhotoImage, PhotoRecord, PipelineError, PipelineOptions, Reconstruction};
use crate::reference::ReferenceFace;
use crate::render::{RenderError, View, synthetic_photo};
use crate::structure::{LEFT_EYE_CENTRE, RIGHT_EYE_CENTRE};

const SUBJECT: &str = include_str!("../reference/demo-subject.json");

/// The demo's ground-truth face (parsed on first use).
pub fn subject() -> &'static ReferenceFace {
    static FACE: OnceLock<ReferenceFace> = OnceLock::new();
    FACE.get_or_init(|| {
        ReferenceFace::from_json(SUBJECT).expect("the embedded demo subject is valid (a test checks it)")
    })
}

/// What can stop the demo.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DemoError {
    /// A setting out of range.
    #[error(transparent)]
    Setting(#[from] SettingError),
    /// The subject's surface could not be made (it does not happen for the embedded subject).
    #[error("the demo subject: {0}")]
    Face(#[from] FaceError),
    /// A photo could not be rendered.
    #[error("a demo photo: {0}")]
    Render(#[from] RenderError),
    /// A photo's points are unusable (they are projected, so it does not happen).
    #[error("a demo photo's points: {0}")]
    Points(#[from] AlignError),
    /// The reconstruction.
    #[error(transparent)]
    Pipeline(#[from] PipelineError),
    /// The comparison with the truth.
    #[error("comparing with the truth: {0}")]
    Compare(#[from] CompareError),
    /// An output could not be encoded.
    #[error(transparent)]
    Encode(#[from] EncodeError),
}

/// How the demo's photos are taken.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneOptions {
    /// Photos (at least 1).
    pub photos: usize,
    /// Landmark noise, as a fraction of the eye distance (0.01 = 1%).
    pub noise: Real,
    /// The seed.
    pub seed: u64,
    /// Photo width and height, pixels.
    pub size: (usize, usize),
}

impl Default for SceneOptions {
    fn default() -> Self {
        SceneOptions {
            photos: 12,
            noise: 0.01,
            seed: 2016,
            size: (320, 384),
        }
    }
}

impl SceneOptions {
    /// Checks the options ([`scene`] does too).
    ///
    /// # Errors
    /// A [`SettingError`] for no photos or more than 200, a negative or non-finite noise
    /// (shown in percent, as the command line and the Python package take it), or a side
    /// outside 64 to 4096 pixels.
    pub fn validate(&self) -> Result<(), SettingError> {
        if self.photos == 0 || self.photos > 200 {
            return Err(SettingError::new(
                "photos",
                self.photos.to_string(),
                "between 1 and 200, please",
            ));
        }
        if !(self.noise >= 0.0 && self.noise.is_finite()) {
            return Err(SettingError::new(
                "noise",
                (100.0 * self.noise).to_string(),
                "must be a finite percentage, 0 or more",
            ));
        }
        let (width, height) = self.size;
        if width < 64 || height < 64 || width > 4096 || height > 4096 {
            return Err(SettingError::new(
                "size",
                format!("{width}x{height}"),
                "each side must be between 64 and 4096",
            ));
        }
        Ok(())
    }
}

/// The demo's photos with their points, and the truth.
#[derive(Debug, Clone)]
pub struct Scene {
    /// The photos and their (noisy) points, for [`crate::pipeline::reconstruct`].
    pub inputs: Vec<Input>,
    /// The poses they were taken from: `[yaw, pitch, roll]` in degrees.
    pub poses: Vec<[Real; 3]>,
    /// The subject's clipped surface mesh, canonical frame.
    pub truth_mesh: TriangleMesh,
    /// The subject's 40-point structure as a landmarker places it (see [`scene`]), canonical
    /// frame.
    pub truth_structure: Vec<Point3<Real>>,
}

/// Photographs the demo subject (see [`SceneOptions`]): poses spread over yaw ±40°, with pitch
/// ±15° and roll ±8° at random; each photo's points are the projected structure plus Gaussian
/// noise.
///
/// The structure is the subject's as a landmarker places it: its landmark vertices moved by
/// the offsets between the default reference's photo structure and its landmark vertices
/// ([`ReferenceFace::photo_structure`]), the same definitions the pipeline deforms from; in
/// each photo, the jaw points off the chin ([`crate::face::OUTLINE_POINTS`]) move further, along
/// the subject's surface onto its outline as the photo sees it, as a landmarker's do.
///
/// # Errors
/// [`DemoError::Setting`] as [`SceneOptions::validate`].
pub fn scene(options: &SceneOptions) -> Result<Scene, DemoError> {
    options.validate()?;
    let (width, height) = options.size;
    let subject = subject();
    let face = FaceSurface::deform(subject, subject.structure(), Deformation::Affine)?;
    let mesh = face.mesh(&MeshOptions { spacing: 0.75 })?.mesh;
    let reference = ReferenceFace::embedded();
    let seen: Vec<Point3<Real>> = subject
        .structure()
        .iter()
        .zip(reference.photo_structure().iter().zip(reference.structure()))
        .map(|(p, (a, b))| p + (a - b))
        .collect();
    let mut random = crate::random::Lcg(options.seed);
    let mut inputs = Vec::with_capacity(options.photos);
    let mut poses = Vec::with_capacity(options.photos);
    for k in 0..options.photos {
        let spread = if options.photos > 1 {
            -40.0 + 80.0 * k as Real / (options.photos - 1) as Real
        } else {
            0.0
        };
        let pose = [
            spread + random.uniform(-4.0, 4.0),
            random.uniform(-15.0, 15.0),
            random.uniform(-8.0, 8.0),
        ];
        let view = View::from_yaw_pitch_roll_degrees(pose[0], pose[1], pose[2]);
        // The jaw points off the chin on the face's outline in this view, where a landmarker
        // puts them.
        let rows = view.rotation.matrix().fixed_rows::<2>(0).into_owned();
        let mut in_view = seen.clone();
        for &j in &OUTLINE_POINTS {
            let p = subject.structure()[j];
            let place = subject.frame().parameters(p.x, p.y);
            in_view[j] +=
                outline_move(subject.surface(), (place.x, place.y), &rows).map_err(FaceError::from)?;
        }
        let photo = synthetic_photo(&mesh, &in_view, &view, width, height, 0.1)?;
        let eyes = (photo.points[LEFT_EYE_CENTRE] - photo.points[RIGHT_EYE_CENTRE])
            .norm()
            .max(1.0);
        // The noise is a fraction of the frontal eye distance in pixels (the projected one
        // shrinks with yaw).
        let frontal_eyes = eyes / (pose[0].to_radians().cos()).max(0.3);
        let sigma = options.noise * frontal_eyes;
        let points: Vec<Point2<Real>> = photo
            .points
            .iter()
            .map(|p| {
                Point2::new(
                    (p.x + sigma * random.gaussian()).clamp(0.0, (width - 1) as Real),
                    (p.y + sigma * random.gaussian()).clamp(0.0, (height - 1) as Real),
                )
            })
            .collect();
        let grey = photo.image;
        let colour = image::RgbImage::from_fn(width as u32, height as u32, |x, y| {
            let v = grey.get(x as usize, y as usize);
            // A skin tone, so the textured outputs look like a face.
            image::Rgb([
                (255.0 * (v * 1.0).min(1.0)) as u8,
                (255.0 * (v * 0.84).min(1.0)) as u8,
                (255.0 * (v * 0.72).min(1.0)) as u8,
            ])
        });
        inputs.push(Input {
            points: PhotoPoints::new(format!("photo{:02}", k + 1), points)?,
            image: Some(PhotoImage { grey, colour }),
        });
        poses.push(pose);
    }
    Ok(Scene {
        inputs,
        poses,
        truth_mesh: mesh,
        truth_structure: seen,
    })
}

impl Scene {
    /// The photos as PNG files and their points as iBUG-style `.pts` files with the 40
    /// structure points, `(relative path, bytes)`, so that `splineface reconstruct` can be run
    /// on them.
    ///
    /// # Errors
    /// An [`EncodeError`] (it does not happen for a scene that was made).
    pub fn files(&self) -> Result<Vec<(PathBuf, Vec<u8>)>, EncodeError> {
        let mut files = Vec::new();
        for input in &self.inputs {
            let name = &input.points.name;
            if let Some(image) = &input.image {
                files.push((
                    PathBuf::from(format!("{name}.png")),
                    crate::io::encode_png(&image.colour)?,
                ));
            }
            files.push((
                PathBuf::from(format!("{name}.pts")),
                format_pts(&input.points.points).into_bytes(),
            ));
        }
        Ok(files)
    }
}

/// A demo run: the scene reconstructed with the embedded reference, and the reconstruction and
/// the unchanged mean face each compared with the truth ([`crate::compare::compare`], in the
/// output units).
#[derive(Debug, Clone)]
pub struct Demo {
    /// The photos and the truth.
    pub scene: Scene,
    /// The reconstruction.
    pub reconstruction: Reconstruction,
    /// The reconstruction against the truth.
    pub comparison: Comparison,
    /// The mean face ([`MeanFace`]) against the truth: the baseline.
    pub baseline: Comparison,
}

impl Demo {
    /// Reconstructs `scene` with `options` and compares the result and the mean face with the
    /// truth, reporting each stage to `progress`.
    ///
    /// # Errors
    /// [`DemoError::Pipeline`] as [`crate::pipeline::reconstruct`] fails, [`DemoError::Face`] for
    /// a mesh spacing out of range, [`DemoError::Compare`] as the comparison fails.
    pub fn run(
        scene: Scene,
        options: &PipelineOptions,
        mut progress: impl FnMut(&str),
    ) -> Result<Self, DemoError> {
        let reference = ReferenceFace::embedded();
        let reconstruction = crate::pipeline::reconstruct(&scene.inputs, reference, options, &mut progress)?;
        progress("comparing with the truth");
        let units = options.units;
        let truth_mesh = scene.truth_mesh.transformed(&units.transform());
        let scale = units.per_canonical_unit();
        let truth_structure: Vec<_> = scene.truth_structure.iter().map(|p| p * scale).collect();
        let comparison = crate::compare::compare(
            &reconstruction.output_mesh(),
            &truth_mesh,
            Some((&reconstruction.structure(), &truth_structure)),
            &CompareOptions::default(),
        )?;
        // Its landmarks as the photo path places them, like the reconstruction's and the truth's.
        let mean = MeanFace::new(reference, units, &options.mesh)?;
        let baseline = crate::compare::compare(
            &mean.mesh,
            &truth_mesh,
            Some((&mean.photo_structure, &truth_structure)),
            &CompareOptions::default(),
        )?;
        Ok(Demo {
            scene,
            reconstruction,
            comparison,
            baseline,
        })
    }

    /// Every output file, `(path, bytes)`: the photos and their points in `photos/`, the
    /// reconstruction's files in `reconstruction/` (as `splineface reconstruct` writes them,
    /// with the landmark overlays), the comparison in `compare/` (its `stats.json` with the
    /// mean face's figures as `baseline_mean_face`), and `report.html`. Overlays that cannot be
    /// drawn are left out with a note in `warnings`.
    ///
    /// # Errors
    /// An [`EncodeError`] or [`PipelineError::Encode`] (neither happens for a finished run).
    pub fn files(&self, warnings: &mut Vec<String>) -> Result<Vec<(PathBuf, Vec<u8>)>, DemoError> {
        let in_folder = |folder: &str, files: Vec<(PathBuf, Vec<u8>)>| {
            files
                .into_iter()
                .map(move |(p, b)| (std::path::Path::new(folder).join(p), b))
                .collect::<Vec<_>>()
        };
        let mut files = in_folder("photos", self.scene.files()?);
        let records: Vec<PhotoRecord> = self
            .scene
            .inputs
            .iter()
            .map(|input| PhotoRecord::given(&input.points.name, input.points.points.clone()))
            .collect();
        let mut reconstruction = self.reconstruction.files()?;
        reconstruction.extend(crate::pipeline::photo_files(
            &records,
            std::path::Path::new("landmarks"),
            &self.scene.inputs,
            Some(&self.reconstruction),
            warnings,
        ));
        files.extend(in_folder("reconstruction", reconstruction));
        let mut extra = serde_json::Map::new();
        extra.insert(
            "baseline_mean_face".into(),
            serde_json::to_value(&self.baseline.stats).expect("the figures are finite or null"),
        );
        extra.insert("units".into(), self.reconstruction.options.units.name().into());
        files.extend(in_folder("compare", self.comparison.files(extra, false)?));
        let page = crate::report::report_page(
            &files,
            &crate::report::PageOptions {
                title: format!(
                    "splineface demo: {} photos of the demo subject",
                    self.scene.inputs.len()
                ),
                reconstruction: "reconstruction".into(),
                comparison: Some("compare".into()),
            },
        );
        files.push(("report.html".into(), page.into_bytes()));
        Ok(files)
    }
}
