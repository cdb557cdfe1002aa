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
use crate::align::PhotoPoints;
use crate::face::{Deformation, FaceSurface, MeshOptions};
use crate::landmarks::format_pts;
use crate::mesh::TriangleMesh;
use crate::pipeline::{Input, PhotoImage};
use crate::reference::ReferenceFace;
use crate::render::{View, synthetic_photo};
use crate::structure::{LEFT_EYE_CENTRE, RIGHT_EYE_CENTRE};

const SUBJECT: &str = include_str!("../reference/demo-subject.json");

/// The demo's ground-truth face (parsed on first use).
pub fn subject() -> &'static ReferenceFace {
    static FACE: OnceLock<ReferenceFace> = OnceLock::new();
    FACE.get_or_init(|| {
        ReferenceFace::from_json(SUBJECT).expect("the embedded demo subject is valid (a test checks it)")
    })
}

/// A small seeded generator (64-bit LCG, Knuth's MMIX constants): the same scene on every
/// machine.
struct Random(u64);

impl Random {
    fn next(&mut self) -> Real {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as Real / (1u64 << 53) as Real
    }

    fn uniform(&mut self, a: Real, b: Real) -> Real {
        a + (b - a) * self.next()
    }

    fn gaussian(&mut self) -> Real {
        let u = self.next().max(1e-300);
        (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * self.next()).cos()
    }
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
/// ([`ReferenceFace::photo_structure`]), the same definitions the pipeline deforms from.
///
/// # Errors
/// A message for zero photos, a negative or non-finite noise, or a size under 64 pixels.
pub fn scene(options: &SceneOptions) -> Result<Scene, String> {
    if options.photos == 0 || options.photos > 200 {
        return Err(format!("{} photos: between 1 and 200, please", options.photos));
    }
    if !(options.noise >= 0.0 && options.noise.is_finite()) {
        return Err(format!("noise {} must be non-negative", options.noise));
    }
    let (width, height) = options.size;
    if width < 64 || height < 64 || width > 4096 || height > 4096 {
        return Err(format!(
            "photos of {width}×{height}: each side must be between 64 and 4096"
        ));
    }
    let subject = subject();
    let face =
        FaceSurface::deform(subject, subject.structure(), Deformation::Affine).map_err(|e| e.to_string())?;
    let mesh = face
        .mesh(&MeshOptions { spacing: 0.75 })
        .map_err(|e| e.to_string())?
        .mesh;
    let reference = ReferenceFace::embedded();
    let seen: Vec<Point3<Real>> = subject
        .structure()
        .iter()
        .zip(reference.photo_structure().iter().zip(reference.structure()))
        .map(|(p, (a, b))| p + (a - b))
        .collect();
    let mut random = Random(options.seed);
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
        let photo = synthetic_photo(&mesh, &seen, &view, width, height, 0.1)?;
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
            points: PhotoPoints::new(format!("photo{:02}", k + 1), points).map_err(|e| e.to_string())?,
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
    /// The PNG encoder's message.
    pub fn files(&self) -> Result<Vec<(PathBuf, Vec<u8>)>, String> {
        let mut files = Vec::new();
        for input in &self.inputs {
            let name = &input.points.name;
            if let Some(image) = &input.image {
                files.push((
                    PathBuf::from(format!("{name}.png")),
                    crate::export::encode_png(&image.colour)?,
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
