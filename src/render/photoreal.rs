//! Photo-realistic photos of a textured mesh: a perspective pinhole camera, a directional light
//! with soft shadows plus ambient light and a weak specular sheen, a gradient background, and
//! the blur and sensor noise of a real camera. The evaluation photographs known faces with it
//! and runs the whole photo path (detection, landmarks, reconstruction) on the pictures.
//!
//! # Conventions
//!
//! * **Camera** ([`Camera`]): OpenCV's. A world point `X` is seen at pixel `(u, v)` with
//!   `[u v 1]ᵀ ~ K (R X + t)`, `K = [[f, 0, cx], [0, f, cy], [0, 0, 1]]`; pixel centres are at
//!   integer coordinates, `v` grows downwards, the camera looks along its `+z`.
//! * **Light** ([`Lighting`]): its direction is given in the camera's *viewing* frame (`x`
//!   right, `y` up, `z` toward the camera), the frame photographers think in.
//! * **Shading**, in linear light: `albedo · (ambient + diffuse · max(0, n·l) · shadow) +
//!   specular · max(0, n·h)^shininess · shadow`, then the sRGB transfer curve. The albedo is the
//!   colour map read as sRGB and decoded to linear light.

use image::{Rgb, RgbImage};
use nalgebra::{Matrix3, Point2, Point3, Rotation3, UnitQuaternion, Vector3};
use rayon::prelude::*;

use super::RenderError;
use super::raster::rasterise;
use crate::Real;
use crate::mesh::TriangleMesh;

/// A perspective pinhole camera (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Focal length, pixels.
    pub focal: Real,
    /// The principal point, pixels.
    pub centre: Point2<Real>,
    /// Image width, pixels.
    pub width: usize,
    /// Image height, pixels.
    pub height: usize,
    /// `R`: world to camera.
    pub rotation: Rotation3<Real>,
    /// `t`: world to camera.
    pub translation: Vector3<Real>,
}

impl Camera {
    /// A `width × height` camera of focal length `focal` (pixels) looking at a head posed by
    /// `[yaw, pitch, roll]` (degrees, as [`crate::depth::Pose`] defines them for a face whose
    /// frame has `+y` up and `+z` toward a frontal viewer) from `distance` along its axis, with
    /// `target` (a point of the head's frame, say the middle of the face) on the optical axis:
    /// `R = diag(1, −1, −1) R_head`, `t = (0, 0, distance) − R · target`.
    pub fn looking_at_head(
        yaw_pitch_roll: [Real; 3],
        target: &Point3<Real>,
        distance: Real,
        focal: Real,
        (width, height): (usize, usize),
    ) -> Self {
        let [yaw, pitch, roll] = yaw_pitch_roll;
        let head = crate::depth::Pose::from_yaw_pitch_roll_degrees(yaw, pitch, roll, 1.0).rotation;
        let flip = Rotation3::from_matrix_unchecked(Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0)));
        let rotation = flip * head;
        Camera {
            focal,
            centre: Point2::new((width as Real - 1.0) / 2.0, (height as Real - 1.0) / 2.0),
            width,
            height,
            rotation,
            translation: Vector3::new(0.0, 0.0, distance) - rotation * target.coords,
        }
    }

    /// A world point in the camera's frame.
    pub fn to_camera(&self, p: &Point3<Real>) -> Point3<Real> {
        self.rotation * p + self.translation
    }

    /// Where the camera sees a world point, in pixels; `None` for points not in front of it.
    pub fn project(&self, p: &Point3<Real>) -> Option<Point2<Real>> {
        let q = self.to_camera(p);
        (q.z > 0.0).then(|| {
            Point2::new(
                self.centre.x + self.focal * q.x / q.z,
                self.centre.y + self.focal * q.y / q.z,
            )
        })
    }

    /// The camera's position in the world.
    pub fn position(&self) -> Point3<Real> {
        Point3::from(-(self.rotation.inverse() * self.translation))
    }

    /// The same camera with every pixel measure multiplied by `factor` (for supersampling).
    fn scaled(&self, factor: usize) -> Self {
        let f = factor as Real;
        Camera {
            focal: self.focal * f,
            centre: Point2::new((self.centre.x + 0.5) * f - 0.5, (self.centre.y + 0.5) * f - 0.5),
            width: self.width * factor,
            height: self.height * factor,
            ..*self
        }
    }
}

/// A directional light plus ambient light (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lighting {
    /// Toward the light, camera viewing frame (`x` right, `y` up, `z` toward the camera).
    pub direction: Vector3<Real>,
    /// The directional light's strength.
    pub diffuse: Real,
    /// The ambient light's strength.
    pub ambient: Real,
    /// The specular sheen's strength (white).
    pub specular: Real,
    /// The sheen's Blinn–Phong exponent.
    pub shininess: Real,
    /// The half-width of the shadows' soft edge, in the mesh's units; 0 for hard shadows.
    pub shadow_softness: Real,
}

impl Default for Lighting {
    /// A light above the camera, to the viewer's left.
    fn default() -> Self {
        Lighting {
            direction: Vector3::new(-0.3, 0.4, 1.0),
            diffuse: 0.75,
            ambient: 0.3,
            specular: 0.04,
            shininess: 30.0,
            shadow_softness: 2.0,
        }
    }
}

impl Lighting {
    /// A matte light: `diffuse` from `direction` (normalised here) plus `ambient`, no sheen,
    /// hard shadows. What a first-order spherical-harmonic lighting describes exactly (bar the
    /// shadows), as the refinement's tests and bench use it.
    pub fn matte(direction: Vector3<Real>, diffuse: Real, ambient: Real) -> Self {
        Lighting {
            direction: direction.normalize(),
            diffuse,
            ambient,
            specular: 0.0,
            shininess: 1.0,
            shadow_softness: 0.0,
        }
    }
}

/// What a photo looks like beyond its subject and light.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PhotoLook {
    /// The background's colour at the top of the image (sRGB, 0–1).
    pub background_top: [Real; 3],
    /// The background's colour at the bottom.
    pub background_bottom: [Real; 3],
    /// The lens blur: a Gaussian's standard deviation, pixels (0 for none).
    pub blur: Real,
    /// The sensor noise: a Gaussian's standard deviation on the 0–1 scale (0 for none).
    pub noise: Real,
    /// Seeds the noise.
    pub seed: u64,
    /// Samples per pixel along each side (antialiasing), 1 to 4.
    pub supersampling: usize,
}

impl Default for PhotoLook {
    fn default() -> Self {
        PhotoLook {
            background_top: [0.55, 0.6, 0.55],
            background_bottom: [0.35, 0.4, 0.38],
            blur: 0.6,
            noise: 0.01,
            seed: 1,
            supersampling: 2,
        }
    }
}

/// A colour map (sRGB) read as linear light.
#[derive(Debug, Clone)]
pub struct ColourMap {
    width: usize,
    height: usize,
    texels: Vec<[f32; 3]>,
}

/// An sRGB value (0–1) decoded to linear light (the standard's transfer curve).
pub fn srgb_to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// Linear light as an 8-bit sRGB value, `round(255 · linear_to_srgb(c))`, without a power:
/// a binary search of the 255 linear values at which the rounded value steps up (NaN gives
/// 0). Textures and renders encode millions of values; this is what they call.
pub(crate) fn linear_to_srgb8(c: Real) -> u8 {
    static STEPS: std::sync::OnceLock<[Real; 255]> = std::sync::OnceLock::new();
    let steps = STEPS.get_or_init(|| {
        std::array::from_fn(|v| {
            let s = (v as Real + 0.5) / 255.0;
            if s <= 0.04045 {
                s / 12.92
            } else {
                ((s + 0.055) / 1.055).powf(2.4)
            }
        })
    });
    steps.partition_point(|&t| t <= c) as u8
}

/// Linear light (clamped to 0–1) encoded as an sRGB value (0–1).
pub fn linear_to_srgb(c: Real) -> Real {
    let c = c.clamp(0.0, 1.0);
    if c <= 0.0031308 {
        12.92 * c
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    }
}

impl ColourMap {
    /// A colour map from an sRGB image.
    pub fn new(image: &RgbImage) -> Self {
        let lookup: Vec<f32> = (0..256).map(|v| srgb_to_linear(v as f32 / 255.0)).collect();
        ColourMap {
            width: image.width() as usize,
            height: image.height() as usize,
            texels: image
                .pixels()
                .map(|p| {
                    [
                        lookup[p[0] as usize],
                        lookup[p[1] as usize],
                        lookup[p[2] as usize],
                    ]
                })
                .collect(),
        }
    }

    /// The linear colour at texture coordinates `(u, v)`, `v` up (`v = 0` is the image's
    /// bottom row), bilinear, repeating outside `[0, 1]`.
    pub fn sample(&self, u: Real, v: Real) -> [Real; 3] {
        // Coordinates inside the square, texels inside the image and non-negative ones are
        // the rule: each takes a comparison there rather than a library call (`rem_euclid`,
        // `floor` on the baseline x86-64 target) or an integer division, with the same result.
        let unit = |t: Real| {
            if (0.0..1.0).contains(&t) {
                t
            } else {
                t.rem_euclid(1.0)
            }
        };
        let floor = |t: Real| {
            let k = t as i64;
            if (k as Real) > t { k - 1 } else { k }
        };
        let x = unit(u) * self.width as Real - 0.5;
        let y = (1.0 - unit(v)) * self.height as Real - 0.5;
        let (x0, y0) = (floor(x), floor(y));
        let (fx, fy) = (x - x0 as Real, y - y0 as Real);
        let wrap = |a: i64, n: usize| {
            if (0..n as i64).contains(&a) {
                a as usize
            } else {
                a.rem_euclid(n as i64) as usize
            }
        };
        let (xa, xb) = (wrap(x0, self.width), wrap(x0 + 1, self.width));
        let (ya, yb) = (wrap(y0, self.height), wrap(y0 + 1, self.height));
        let at = |x: usize, y: usize| self.texels[y * self.width + x];
        let mut out = [0.0; 3];
        for (c, o) in out.iter_mut().enumerate() {
            let top = at(xa, ya)[c] as Real * (1.0 - fx) + at(xb, ya)[c] as Real * fx;
            let bottom = at(xa, yb)[c] as Real * (1.0 - fx) + at(xb, yb)[c] as Real * fx;
            *o = top * (1.0 - fy) + bottom * fy;
        }
        out
    }
}

/// The shadow map's side, texels: twice the pixels the mesh spans in the (supersampled) image,
/// its longer side, rounded up to a multiple of 64 and held to 256..=[`SHADOW_MAP_MAX`], so
/// that a small view (the turntable's) does not pay for a map finer than it can show. The
/// evaluation's photos span more than 512 pixels and keep the largest map.
fn shadow_side(pixels: &[[Real; 2]], keys: &[Real]) -> usize {
    let (mut lo, mut hi) = ([Real::INFINITY; 2], [Real::NEG_INFINITY; 2]);
    for (p, k) in pixels.iter().zip(keys) {
        if k.is_finite() {
            for a in 0..2 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
    }
    let span = (hi[0] - lo[0]).max(hi[1] - lo[1]);
    if !span.is_finite() {
        return SHADOW_MAP_MAX;
    }
    let side = ((2.0 * span / 64.0).ceil() * 64.0).clamp(256.0, SHADOW_MAP_MAX as Real);
    side as usize
}

/// The largest shadow map's side, texels.
const SHADOW_MAP_MAX: usize = 1024;

/// The shadow map: the mesh's heights toward the light over a raster of the light's plane.
struct ShadowMap {
    turn: UnitQuaternion<Real>,
    raster: crate::mesh::Raster,
    heights: Vec<Real>,
    bias: Real,
    softness: Real,
}

impl ShadowMap {
    fn new(mesh: &TriangleMesh, towards_light: &Vector3<Real>, softness: Real, side: usize) -> Self {
        let turn = UnitQuaternion::rotation_between(towards_light, &Vector3::z())
            .unwrap_or_else(|| UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI));
        let turned: Vec<Point3<Real>> = mesh.positions().iter().map(|p| turn * p).collect();
        let (lo, hi) = crate::geometry::bounding_box(&turned).expect("a mesh has vertices");
        let spacing = ((hi.x - lo.x).max(hi.y - lo.y) / (side as Real - 2.0)).max(1e-9);
        let raster = crate::mesh::Raster {
            origin: Point2::new(lo.x - spacing, lo.y - spacing),
            spacing,
            width: side,
            height: side,
        };
        let heights = super::render_heights(&turned, mesh.triangles(), &raster);
        ShadowMap {
            turn,
            raster,
            heights,
            bias: 3.0 * spacing,
            softness,
        }
    }

    /// The fraction of the light that reaches `p` (percentage-closer filtering over a 5 × 5
    /// pattern of half-width `softness`).
    fn light(&self, p: &Point3<Real>) -> Real {
        let q = self.turn * p;
        let r = &self.raster;
        let steps = [-1.0, -0.5, 0.0, 0.5, 1.0];
        // A tap's column depends on its x step only and its row on its y step only: five of
        // each, rounded once, to the nearest cell by truncating half a cell on (`round` is a
        // library call on the baseline x86-64 target, a truncating conversion one instruction;
        // they differ only at exact halves).
        let cell = |c: Real, origin: Real, n: usize| {
            let k = (c - origin) / r.spacing + 0.5;
            (k >= 0.0 && k < n as Real).then_some(k as usize)
        };
        let columns = steps.map(|d| cell(q.x + d * self.softness, r.origin.x, r.width));
        let rows = steps.map(|d| cell(q.y + d * self.softness, r.origin.y, r.height));
        let mut lit = 0usize;
        for row in rows {
            for column in columns {
                let blocker = match (row, column) {
                    (Some(y), Some(x)) => self.heights[y * r.width + x],
                    _ => Real::NAN,
                };
                if blocker.is_nan() || blocker <= q.z + self.bias {
                    lit += 1;
                }
            }
        }
        lit as Real / 25.0
    }
}

/// Unit vertex normals: the area-weighted mean of the triangles' normals (`+z`-facing when a
/// vertex has none).
fn vertex_normals(mesh: &TriangleMesh) -> Vec<Vector3<Real>> {
    if let Some(normals) = mesh.normals() {
        return normals.to_vec();
    }
    let mut sums = vec![Vector3::zeros(); mesh.positions().len()];
    for (k, t) in mesh.triangles().iter().enumerate() {
        let [a, b, c] = mesh.triangle(k);
        let n = (b - a).cross(&(c - a));
        for &v in t {
            sums[v as usize] += n;
        }
    }
    sums.into_iter()
        .map(|n| n.try_normalize(0.0).unwrap_or_else(Vector3::z))
        .collect()
}

/// A small deterministic generator (SplitMix64) for the sensor noise.
struct SplitMix(u64);

impl SplitMix {
    fn next(&mut self) -> Real {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as Real / (1u64 << 53) as Real
    }

    fn gaussian(&mut self) -> Real {
        let u = self.next().max(1e-300);
        (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * self.next()).cos()
    }
}

/// Photographs a textured mesh (see the module documentation). The mesh's texture coordinates
/// index `colour_map`; its normals are used when it has them, else smooth vertex normals are
/// made. Triangles facing away from the camera are drawn too (a mask-like scan seen from the
/// side shows its inside, as a real one would).
///
/// # Errors
/// [`RenderError::NoTextureCoordinates`]; [`RenderError::Setting`] for an image side
/// outside 16–8192, a focal length that is not positive, supersampling outside 1–4, or a light
/// direction, blur or noise that is not finite (or negative).
pub fn render_photo(
    mesh: &TriangleMesh,
    colour_map: &ColourMap,
    camera: &Camera,
    lighting: &Lighting,
    look: &PhotoLook,
) -> Result<RgbImage, RenderError> {
    Ok(PhotoGeometry::new(mesh, camera, lighting, look)?.render(mesh, colour_map))
}

/// The half of [`render_photo`] that needs no colour map: which triangle each pixel shows, the
/// vertices' places and normals, the shadow map and the background, for one mesh, camera,
/// light and look. [`PhotoGeometry::render`] then colours it, the same picture to the bit, so
/// that the geometry can be made while the colour map is still being made.
pub(crate) struct PhotoGeometry {
    camera: Camera,
    big: Camera,
    lighting: Lighting,
    look: PhotoLook,
    pixels: Vec<[Real; 2]>,
    keys: Vec<Real>,
    ids: Vec<u32>,
    normals: Vec<Vector3<Real>>,
    towards_light: Vector3<Real>,
    shadows: ShadowMap,
    background: Vec<[Real; 3]>,
}

impl PhotoGeometry {
    /// The geometry of `mesh` seen by `camera` under `lighting` with `look` ([`render_photo`]'s
    /// checks and errors).
    pub(crate) fn new(
        mesh: &TriangleMesh,
        camera: &Camera,
        lighting: &Lighting,
        look: &PhotoLook,
    ) -> Result<Self, RenderError> {
        mesh.texture().ok_or(RenderError::NoTextureCoordinates)?;
        let setting = |ok: bool, message: String| {
            if ok {
                Ok(())
            } else {
                Err(RenderError::Setting { message })
            }
        };
        setting(
            (16..=8192).contains(&camera.width) && (16..=8192).contains(&camera.height),
            format!(
                "{}×{} pixels: each side must be 16 to 8192",
                camera.width, camera.height
            ),
        )?;
        setting(
            camera.focal > 0.0 && camera.focal.is_finite(),
            format!("focal length {} must be positive", camera.focal),
        )?;
        setting(
            (1..=4).contains(&look.supersampling),
            format!("supersampling {} must be 1 to 4", look.supersampling),
        )?;
        setting(
            lighting.direction.iter().all(|c| c.is_finite()) && lighting.direction.norm() > 0.0,
            "the light direction must be a finite, non-zero vector".to_owned(),
        )?;
        setting(
            look.blur >= 0.0 && look.blur.is_finite() && look.noise >= 0.0 && look.noise.is_finite(),
            "blur and noise must be finite and non-negative".to_owned(),
        )?;

        let factor = look.supersampling;
        let big = camera.scaled(factor);
        let (width, height) = (big.width, big.height);
        let in_camera: Vec<Point3<Real>> = mesh.positions().iter().map(|p| big.to_camera(p)).collect();
        // Points behind the camera get no key and so never win a pixel.
        let near = 1e-6;
        let pixels: Vec<[Real; 2]> = in_camera
            .iter()
            .map(|q| {
                let z = q.z.max(near);
                [
                    big.centre.x + big.focal * q.x / z,
                    big.centre.y + big.focal * q.y / z,
                ]
            })
            .collect();
        let keys: Vec<Real> = in_camera
            .iter()
            .map(|q| if q.z > near { 1.0 / q.z } else { Real::NEG_INFINITY })
            .collect();
        let (_, ids) = rasterise(&pixels, &keys, mesh.triangles(), width, height);

        let normals = vertex_normals(mesh);
        // The light toward the world: viewing frame → OpenCV camera frame → world.
        let viewing = lighting.direction.normalize();
        let towards_light = big.rotation.inverse() * Vector3::new(viewing.x, -viewing.y, -viewing.z);
        let shadows = ShadowMap::new(
            mesh,
            &towards_light,
            lighting.shadow_softness,
            shadow_side(&pixels, &keys),
        );
        // The background's gradient, row by row (linear light).
        let background: Vec<[Real; 3]> = (0..height)
            .map(|row| {
                let t = row as Real / (height.max(2) - 1) as Real;
                std::array::from_fn(|k| {
                    let top = srgb_to_linear(look.background_top[k] as f32) as Real;
                    let bottom = srgb_to_linear(look.background_bottom[k] as f32) as Real;
                    top * (1.0 - t) + bottom * t
                })
            })
            .collect();

        Ok(PhotoGeometry {
            camera: *camera,
            big,
            lighting: *lighting,
            look: *look,
            pixels,
            keys,
            ids,
            normals,
            towards_light,
            shadows,
            background,
        })
    }

    /// The picture, its colours read from `colour_map` at `mesh`'s texture coordinates: `mesh`
    /// must be the one the geometry was made of.
    pub(crate) fn render(&self, mesh: &TriangleMesh, colour_map: &ColourMap) -> RgbImage {
        let PhotoGeometry {
            camera,
            big,
            lighting,
            look,
            pixels,
            keys,
            ids,
            normals,
            towards_light,
            shadows,
            background,
        } = self;
        let texture = mesh.texture().expect("checked when the geometry was made");
        let (width, height) = (big.width, big.height);
        let factor = look.supersampling;
        let eye = big.position();
        let mut linear = vec![[0.0 as Real; 3]; width * height];
        linear.par_chunks_mut(width).enumerate().for_each(|(row, out)| {
            for (col, o) in out.iter_mut().enumerate() {
                let id = ids[row * width + col];
                if id == u32::MAX {
                    *o = background[row];
                    continue;
                }
                let k = id as usize;
                let t = mesh.triangles()[k];
                // Perspective-correct barycentrics from the screen ones.
                let [a, b, c] = t.map(|v| pixels[v as usize]);
                let (x, y) = (col as Real, row as Real);
                let area = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]);
                let wa = ((b[0] - x) * (c[1] - y) - (c[0] - x) * (b[1] - y)) / area;
                let wb = ((c[0] - x) * (a[1] - y) - (a[0] - x) * (c[1] - y)) / area;
                let wc = 1.0 - wa - wb;
                let [ka, kb, kc] = t.map(|v| keys[v as usize]);
                let sum = wa * ka + wb * kb + wc * kc;
                let w = [wa * ka / sum, wb * kb / sum, wc * kc / sum];
                let corners = t.map(|v| mesh.positions()[v as usize]);
                let p = Point3::from(
                    w[0] * corners[0].coords + w[1] * corners[1].coords + w[2] * corners[2].coords,
                );
                let uv_index = texture.triangles[k];
                let uvs = uv_index.map(|v| texture.uvs[v as usize]);
                let uv = w[0] * uvs[0].coords + w[1] * uvs[1].coords + w[2] * uvs[2].coords;
                let albedo = colour_map.sample(uv.x, uv.y);
                let mut n = (w[0] * normals[t[0] as usize]
                    + w[1] * normals[t[1] as usize]
                    + w[2] * normals[t[2] as usize])
                    .try_normalize(0.0)
                    .unwrap_or_else(Vector3::z);
                let to_eye = (eye - p).try_normalize(0.0).unwrap_or_else(Vector3::z);
                if n.dot(&to_eye) < 0.0 {
                    n = -n; // the back of a surface: lit as its front would be
                }
                let lambert = n.dot(towards_light).max(0.0);
                let shadow = if lambert > 0.0 { shadows.light(&p) } else { 0.0 };
                let half = (towards_light + to_eye).try_normalize(0.0).unwrap_or(n);
                let sheen = lighting.specular * n.dot(&half).max(0.0).powf(lighting.shininess) * shadow;
                for ch in 0..3 {
                    o[ch] = albedo[ch] * (lighting.ambient + lighting.diffuse * lambert * shadow) + sheen;
                }
            }
        });

        // Down to the camera's size (box filter), then blur, the transfer curve and noise.
        let (w, h) = (camera.width, camera.height);
        let mut small = vec![[0.0 as Real; 3]; w * h];
        for (k, o) in small.iter_mut().enumerate() {
            let (col, row) = (k % w, k / w);
            for dy in 0..factor {
                for dx in 0..factor {
                    let s = linear[(row * factor + dy) * width + col * factor + dx];
                    for ch in 0..3 {
                        o[ch] += s[ch];
                    }
                }
            }
            for v in o.iter_mut() {
                *v /= (factor * factor) as Real;
            }
        }
        if look.blur > 0.0 {
            small = gaussian_blur(&small, w, h, look.blur);
        }
        let mut noise = SplitMix(look.seed);
        let mut image = RgbImage::new(w as u32, h as u32);
        for (k, p) in small.iter().enumerate() {
            let c = if look.noise == 0.0 {
                p.map(linear_to_srgb8)
            } else {
                p.map(|v| {
                    let v = linear_to_srgb(v) + look.noise * noise.gaussian();
                    (v.clamp(0.0, 1.0) * 255.0).round() as u8
                })
            };
            image.put_pixel((k % w) as u32, (k / w) as u32, Rgb(c));
        }
        image
    }
}

/// A separable Gaussian blur of standard deviation `sigma` pixels (edges clamped).
fn gaussian_blur(values: &[[Real; 3]], width: usize, height: usize, sigma: Real) -> Vec<[Real; 3]> {
    let reach = (3.0 * sigma).ceil() as i64;
    let kernel: Vec<Real> = (-reach..=reach)
        .map(|d| (-(d * d) as Real / (2.0 * sigma * sigma)).exp())
        .collect();
    let total: Real = kernel.iter().sum();
    let pass = |input: &[[Real; 3]], horizontal: bool| -> Vec<[Real; 3]> {
        let mut out = vec![[0.0; 3]; input.len()];
        out.par_chunks_mut(width).enumerate().for_each(|(row, line)| {
            for (col, o) in line.iter_mut().enumerate() {
                for (k, weight) in kernel.iter().enumerate() {
                    let d = k as i64 - reach;
                    let (x, y) = if horizontal {
                        ((col as i64 + d).clamp(0, width as i64 - 1), row as i64)
                    } else {
                        (col as i64, (row as i64 + d).clamp(0, height as i64 - 1))
                    };
                    let s = input[y as usize * width + x as usize];
                    for ch in 0..3 {
                        o[ch] += weight * s[ch] / total;
                    }
                }
            }
        });
        out
    };
    pass(&pass(values, true), false)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The table's 8-bit encoding against the power law's, over a fine sweep of linear values
    /// beyond both ends: equal everywhere but within rounding of a step (none were there).
    #[test]
    fn srgb8_matches_the_power_law() {
        for i in -1000..=121_000 {
            let c = i as Real / 100_000.0;
            let exact = linear_to_srgb(c) * 255.0;
            let near_step = (exact - exact.floor() - 0.5).abs() < 1e-9;
            if !near_step {
                assert_eq!(linear_to_srgb8(c), exact.round() as u8, "linear {c}");
            }
        }
        assert_eq!(linear_to_srgb8(Real::NAN), 0);
        assert_eq!(linear_to_srgb8(Real::INFINITY), 255);
        assert_eq!(linear_to_srgb8(-1.0), 0);
    }
}
