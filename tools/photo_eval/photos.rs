//! Photo sets: directories of photos with a `camera.json` in the `lps-head` layout (per photo:
//! `file`, `K`, `R`, `t_mm`, `yaw_pitch_roll_deg`, the light, and the truth's 68 landmarks
//! projected, `landmarks68_px`), read, or rendered here from a subject and cached.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use nalgebra::{Point2, Vector3};
use serde_json::json;
use splineface::Real;
use splineface::render::{Camera, Lighting, PhotoLook, render_photo};

use crate::common::Lcg;
use crate::subjects::Subject;

/// One photo of a set.
pub struct Photo {
    pub name: String,
    pub image: image::DynamicImage,
    /// The head's true yaw, pitch and roll, degrees.
    pub ypr: [Real; 3],
    /// The truth's 68 landmarks projected (no occlusion test).
    pub projected: Vec<Point2<Real>>,
}

/// Reads a set made in the `lps-head` layout.
pub fn read_set(dir: &Path) -> Result<Vec<Photo>> {
    let path = dir.join("camera.json");
    let camera: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?,
    )?;
    let number = |v: &serde_json::Value| v.as_f64().context("a number");
    let mut photos = Vec::new();
    for p in camera["photos"].as_array().context("photos")? {
        let file = p["file"].as_str().context("file")?;
        let image = image::open(dir.join(file)).with_context(|| format!("{}/{file}", dir.display()))?;
        let projected = p["landmarks68_px"]
            .as_array()
            .context("landmarks68_px")?
            .iter()
            .map(|q| Ok(Point2::new(number(&q[0])?, number(&q[1])?)))
            .collect::<Result<Vec<_>>>()?;
        let a = &p["yaw_pitch_roll_deg"];
        photos.push(Photo {
            name: Path::new(file)
                .file_stem()
                .context("name")?
                .to_string_lossy()
                .into_owned(),
            image,
            ypr: [number(&a[0])?, number(&a[1])?, number(&a[2])?],
            projected,
        });
    }
    Ok(photos)
}

/// The settings of one rendered photo, drawn at random.
struct Shot {
    ypr: [Real; 3],
    distance: Real,
    face_fraction: Real,
    lighting: Lighting,
    look: PhotoLook,
}

fn draw_shot(rng: &mut Lcg, max_yaw: Real, (near, far): (Real, Real), seed: u64) -> Shot {
    let ypr = [
        rng.uniform(-max_yaw, max_yaw),
        rng.uniform(-15.0, 15.0),
        rng.uniform(-8.0, 8.0),
    ];
    // Spread evenly in its logarithm.
    let distance = near.ln() + rng.next() * (far.ln() - near.ln());
    // From the front hemisphere, seldom from below (as photos are lit).
    let direction = loop {
        let d = Vector3::new(
            rng.uniform(-1.0, 1.0),
            rng.uniform(-0.25, 1.0),
            rng.uniform(0.25, 1.0),
        );
        if d.norm() <= 1.0 {
            break d.normalize();
        }
    };
    let grey = |rng: &mut Lcg| {
        let base = rng.uniform(0.25, 0.85);
        [0, 1, 2].map(|_| (base + rng.uniform(-0.1, 0.1)).clamp(0.0, 1.0))
    };
    Shot {
        ypr,
        distance: distance.exp(),
        face_fraction: rng.uniform(0.22, 0.45),
        lighting: Lighting {
            direction,
            diffuse: rng.uniform(0.5, 0.9),
            ambient: rng.uniform(0.18, 0.4),
            specular: rng.uniform(0.02, 0.06),
            shininess: rng.uniform(15.0, 40.0),
            shadow_softness: rng.uniform(1.0, 4.0),
        },
        look: PhotoLook {
            background_top: grey(rng),
            background_bottom: grey(rng),
            blur: rng.uniform(0.4, 0.9),
            noise: rng.uniform(0.004, 0.015),
            seed: seed ^ rng.0,
            supersampling: 2,
        },
    }
}

/// The version of the rendered pools: a cached pool made by another version is rendered
/// again.
const POOL_VERSION: u64 = 2;

/// The camera distances of [`render_pool`] by default, mm.
pub const DISTANCES: (Real, Real) = (400.0, 2000.0);

/// `count` photos of `subject` under random poses (yaw within ±`max_yaw`), distances (within
/// `distances`, mm), focal lengths (the face 22–45% of the width) and lights, rendered into
/// `dir` (reused when `dir` already holds this pool). With `flat` every photo is lit by ambient
/// light alone (no directional light, shading, shadows or sheen; the same poses, cameras,
/// backgrounds, blur and noise), a diagnostic of what the light does to the refinement
/// (`--flat-light`).
pub fn render_pool(
    subject: &Subject,
    count: usize,
    max_yaw: Real,
    distances: (Real, Real),
    seed: u64,
    dir: &Path,
    flat: bool,
) -> Result<PathBuf> {
    let mut stamp = format!("{POOL_VERSION} {} {count} {max_yaw} {seed}", subject.name);
    if distances != DISTANCES {
        stamp += &format!(" {}-{}", distances.0, distances.1);
    }
    if flat {
        stamp += " flat";
    }
    let stamp_path = dir.join("pool.txt");
    if std::fs::read_to_string(&stamp_path).ok().as_deref() == Some(stamp.as_str()) {
        return Ok(dir.to_path_buf());
    }
    std::fs::create_dir_all(dir)?;
    let (width, height) = (800usize, 1000usize);
    let face_width = (subject.structure[8] - subject.structure[0]).norm().max(1.0);
    let mut rng = Lcg(seed.wrapping_mul(0x2545_F491_4F6C_DD1D) ^ 0x5EED);
    let mut records = Vec::new();
    for k in 0..count {
        let mut shot = draw_shot(&mut rng, max_yaw, distances, seed.wrapping_add(k as u64));
        if flat {
            shot.lighting = Lighting {
                diffuse: 0.0,
                ambient: 1.0,
                specular: 0.0,
                ..shot.lighting
            };
        }
        let focal = shot.face_fraction * width as Real * shot.distance / face_width;
        let camera =
            Camera::looking_at_head(shot.ypr, &subject.target, shot.distance, focal, (width, height));
        let image = render_photo(
            &subject.mesh,
            &subject.colour,
            &camera,
            &shot.lighting,
            &shot.look,
        )?;
        let file = format!("img{k:02}.png");
        image.save(dir.join(&file))?;
        let landmarks: Vec<[Real; 2]> = subject
            .ibug
            .iter()
            .map(|p| camera.project(p).map_or([Real::NAN; 2], |q| [q.x, q.y]))
            .collect();
        let r = camera.rotation.matrix();
        records.push(json!({
            "file": file,
            "yaw_pitch_roll_deg": shot.ypr,
            "K": [[focal, 0.0, camera.centre.x], [0.0, focal, camera.centre.y], [0.0, 0.0, 1.0]],
            "R": [[r[(0, 0)], r[(0, 1)], r[(0, 2)]], [r[(1, 0)], r[(1, 1)], r[(1, 2)]], [r[(2, 0)], r[(2, 1)], r[(2, 2)]]],
            "t_mm": [camera.translation.x, camera.translation.y, camera.translation.z],
            "distance_mm": shot.distance,
            "focal_px": focal,
            "light_dir_camera": [shot.lighting.direction.x, shot.lighting.direction.y, shot.lighting.direction.z],
            "ambient": shot.lighting.ambient,
            "diffuse": shot.lighting.diffuse,
            "specular": shot.lighting.specular,
            "landmarks68_px": landmarks,
        }));
    }
    let camera_json = json!({
        "source": format!("rendered by tools/photo_eval from subject {}", subject.name),
        "conventions": "as ../shared/data/lps-head/photos-8/camera.json",
        "image_size": [width, height],
        "photos": records,
    });
    std::fs::write(dir.join("camera.json"), serde_json::to_vec_pretty(&camera_json)?)?;
    std::fs::write(&stamp_path, stamp)?;
    Ok(dir.to_path_buf())
}
