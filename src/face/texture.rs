//! A face texture from every photo, in the surface's own `(u, v)`.
//!
//! The B-spline surface's parameters are already a smooth, nearly isometric map of the face
//! (the reference's frontal plane scaled onto the unit square), so the texture needs no
//! unwrapping: texel `(c, r)` of an `n × n` atlas is the surface point at
//! `(u, v) = ((c + ½)/n, 1 − (r + ½)/n)`, and a mesh vertex's texture coordinates are its
//! surface parameters (`v` up, OBJ's convention).
//!
//! # What each texel takes from each photo
//!
//! Every texel inside the clip region is placed on the photo's own surface (the face with that
//! photo's expression, when one was fitted) and projected by the photo's fitted camera: the
//! surface is evaluated and projected at the nodes, every [`EVALUATION_STRIDE`] texels, and each
//! texel's projection, depth, normal cosine and resolution are bilinear between its four nodes
//! (so the cost per texel is an interpolation and, where the photo counts, a bilinear colour
//! sample; nothing per photo is held for the whole atlas but its weights). Its weight in photo
//! `i` is the product of
//!
//! * **visibility**: 0 unless the texel is the front-most surface where it lands: a depth
//!   buffer of the surface (a grid of quads every [`EVALUATION_STRIDE`] texels) rasterised in the
//!   photo, with a tolerance of [`DEPTH_TOLERANCE`] units plus two buffer cells' worth of
//!   depth; feathered to 0 over [`FEATHER`] of the atlas's side toward texels the photo does
//!   not see, so that an occlusion edge (the nose's side) leaves no seam;
//! * **foreshortening**: `r²` with `r = (cos θ − cos 80°)/(1 − cos 80°)` clamped to `[0, 1]`, `θ`
//!   between the surface's normal and the direction to the camera;
//! * **distance from the photo's border**: rising linearly over the outer 2% of the photo's
//!   smaller side;
//! * **resolution**: the photo's pixels per unit there against the median photo's, at most 1;
//! * **colour**: a greyscale photo among colour ones counts [`GREY_WEIGHT`] as much (it fills
//!   only what no colour photo sees).
//!
//! # Matching and blending
//!
//! Photos differ in exposure and white balance. Each photo gets a gain per channel, fitted in
//! the logarithm on the texels two photos share (weighted by both weights, Cauchy-reweighted
//! against shadows and highlights that differ between photos), normalised to a weighted
//! geometric mean of 1. Colours are blended in linear light as `Σ wᵢᵖ gᵢ cᵢ / Σ wᵢᵖ`, `p` the
//! [`TextureOptions::sharpness`]: the best view of each texel dominates while the weights
//! still fall smoothly to the next one.
//!
//! # Texels no photo sees
//!
//! Faces are nearly symmetric: a texel whose mirror image (`x ↦ −x` in the reference's frontal
//! plane) is seen takes that colour. The rest, and the atlas outside the clip region (padding
//! against bleeding when the texture is filtered), are filled by push-pull diffusion from the
//! texels around them. [`FaceTexture::sources`] says which texel came from where.
//!
//! A texel takes its look from the four nodes around it, and only nodes inside the clip
//! region are looked at, so the texels of the node cells the region's outline crosses (a band
//! of up to [`EVALUATION_STRIDE`] texels along it, about 1% of the face's texels) count as
//! unseen however well the photos show them, and are mirrored or diffused. Looking at the
//! nodes just outside the region as well makes them seen; on `lps-head`'s photo sets
//! (`tools/texture_eval`, over the same texels) that scored a little worse than the diffused
//! band (16.42 against 16.39 levels on photos-8, 14.60 against 14.57 on photos-3), so the band
//! stays diffused.

use image::{Rgb, RgbImage};
use nalgebra::{DMatrix, DVector, Point2, Point3, Vector3};
use rayon::prelude::*;

use super::{ClippedMesh, FaceError, FaceSurface, Look, RefinedCamera};
use crate::Real;
use crate::geometry::{edge_crossing, polygon_contains};

/// The depth test's tolerance, canonical units, beyond the buffer's own resolution.
pub const DEPTH_TOLERANCE: Real = 1.0;
/// The feathering's width toward texels a photo does not see, as a fraction of the atlas's side.
pub const FEATHER: Real = 1.0 / 128.0;
/// The weight of a greyscale photo among colour ones, relative to theirs.
pub const GREY_WEIGHT: f32 = 1e-3;
/// [`FaceTexture::dominant`] of a texel no photo sees.
pub const NO_PHOTO: u16 = u16::MAX;
/// `cos 80°`: views more oblique than this give nothing.
const GRAZING: Real = 0.173_648_177_666_930_35;

/// Options of [`bake_texture`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TextureOptions {
    /// The atlas's side in texels (16 to 8192), or `None` to take it from the photos
    /// ([`automatic_atlas_side`]: about one texel per pixel of the sharpest photo that sees
    /// each part of the face).
    pub size: Option<u32>,
    /// `p`, the power of the weights in the blend: 1 averages the photos by their weights,
    /// larger values let the best view of each texel dominate.
    pub sharpness: Real,
    /// Fit each photo's colour gains before blending.
    pub match_colours: bool,
    /// Fill texels no photo sees from their mirror images before diffusing.
    pub mirror: bool,
}

impl Default for TextureOptions {
    /// An atlas sized to the photos ([`automatic_atlas_side`]), `p = 1` (each texel the
    /// weighted mean of the photos that see it), colours matched, mirror filling on.
    ///
    /// Measured by `tools/texture_eval` (`lps-head`'s given photo sets through the whole photo
    /// path; every texel against the scan's own colour map after one gain per channel; sRGB
    /// levels): mean error / PSNR / colour steps across seams, photos-8 and photos-3:
    ///
    /// | `p` | photos-8 | photos-3 |
    /// |---|---|---|
    /// | 0.5 | 14.7 / 22.4 dB / 1.36 | 14.2 / 22.7 dB / 1.23 |
    /// | **1** | 16.4 / 21.7 dB / 1.37 | 14.5 / 22.5 dB / 1.25 |
    /// | 2 | 18.3 / 20.9 dB / 1.40 | 15.0 / 22.2 dB / 1.31 |
    /// | 4 | 20.3 / 19.9 dB / 1.47 | 15.5 / 21.9 dB / 1.42 |
    /// | 16 | 23.2 / 18.4 dB / 1.89 | 16.0 / 21.7 dB / 2.17 |
    /// | the most frontal photo alone (the texture before the atlas) | 34.2 / 16.0 dB | 19.9 / 19.4 dB |
    ///
    /// Averaging more views averages their lights away; sharper blends keep each photo's
    /// shading and show seams. `p = 0.5` measured better still on this one scan, but it gives
    /// grazing views, where a pose error moves the texture most, a larger say; `p = 1` is the
    /// weighted mean the weights were made for. Matching the photos' colours changed these
    /// figures by up to a level and a half (photos-8 14.9 unmatched against 16.4, photos-3
    /// 14.8 against 14.5): the renders share one exposure, so they cannot show what it is
    /// for; the tests show it bringing a photo exposed at 60% back within 2%. (These rows are
    /// of a 1024² atlas; the automatic size is measured in [`automatic_atlas_side`].)
    fn default() -> Self {
        TextureOptions {
            size: None,
            sharpness: 1.0,
            match_colours: true,
            mirror: true,
        }
    }
}

/// One photo for [`bake_texture`].
#[derive(Debug, Clone, Copy)]
pub struct TexturePhoto<'a> {
    /// The photo in colour (sRGB).
    pub image: &'a RgbImage,
    /// Its fitted camera, in the face's canonical frame.
    pub camera: RefinedCamera,
    /// The face as this photo shows it (its expression) when it differs from the face being
    /// textured; it must share the face's parameter domain.
    pub surface: Option<&'a FaceSurface>,
}

/// Where a texel's colour came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TexelSource {
    /// Outside the clip region (padding, diffused).
    Outside,
    /// Seen by at least one photo.
    Seen,
    /// Unseen, its mirror image seen.
    Mirrored,
    /// Unseen, and so is its mirror image: diffused from around it.
    Filled,
}

/// [`FaceTexture::turntable`]'s five views of a mesh before an atlas colours them
/// ([`crate::render::PhotoGeometry`]): made while the atlas is baked, so that only the
/// colouring waits for it. The picture is the same to the bit.
pub(crate) struct Turntable {
    textured: crate::mesh::TriangleMesh,
    views: Vec<crate::render::PhotoGeometry>,
}

impl Turntable {
    const YAWS: [Real; 5] = [-60.0, -30.0, 0.0, 30.0, 60.0];
    const SIZE: (usize, usize) = (320, 400);

    /// The views of `mesh`, textured by its surface parameters.
    pub(crate) fn new(mesh: &ClippedMesh) -> Result<Self, FaceError> {
        use crate::render::{Camera, Lighting, PhotoGeometry, PhotoLook};
        let textured = mesh.parameter_textured();
        let (lo, hi) = crate::geometry::bounding_box(textured.positions()).expect("a mesh has vertices");
        let centre = nalgebra::center(&lo, &hi);
        let extent = (hi - lo).max().max(Real::MIN_POSITIVE);
        let distance = 6.0 * extent;
        let focal = 0.85 * Self::SIZE.1 as Real * distance / extent;
        let lighting = Lighting {
            direction: Vector3::new(0.2, 0.35, 1.0),
            diffuse: 0.5,
            ambient: 0.6,
            specular: 0.03,
            shininess: 30.0,
            shadow_softness: 0.02 * extent,
        };
        let look = PhotoLook {
            background_top: [0.32, 0.34, 0.36],
            background_bottom: [0.22, 0.23, 0.25],
            blur: 0.0,
            noise: 0.0,
            seed: 0,
            supersampling: 1,
        };
        let views = Self::YAWS
            .par_iter()
            .map(|&yaw| {
                let camera = Camera::looking_at_head([yaw, 0.0, 0.0], &centre, distance, focal, Self::SIZE);
                PhotoGeometry::new(&textured, &camera, &lighting, &look).map_err(|e| FaceError::Option {
                    name: "turntable view",
                    value: e.to_string(),
                    expected: "a mesh the renderer accepts",
                })
            })
            .collect::<Result<_, _>>()?;
        Ok(Turntable { textured, views })
    }

    /// The five views coloured by `atlas`, side by side.
    pub(crate) fn render(&self, atlas: &RgbImage) -> RgbImage {
        let map = crate::render::ColourMap::new(atlas);
        let views: Vec<RgbImage> = self
            .views
            .par_iter()
            .map(|view| view.render(&self.textured, &map))
            .collect();
        let (width, height) = Self::SIZE;
        let mut strip = RgbImage::new((width * views.len()) as u32, height as u32);
        for (k, view) in views.iter().enumerate() {
            image::imageops::replace(&mut strip, view, (k * width) as i64, 0);
        }
        strip
    }
}

/// A baked texture ([`bake_texture`]).
#[derive(Debug, Clone, PartialEq)]
pub struct FaceTexture {
    /// The atlas, `size × size`, sRGB; row 0 is `v = 1`.
    pub atlas: RgbImage,
    /// Per texel, row-major like the atlas: where its colour came from.
    pub sources: Vec<TexelSource>,
    /// Per texel: the largest weight any photo gave it (0 to 1), or its mirror image's for a
    /// mirrored texel; 0 elsewhere.
    pub confidence: Vec<f32>,
    /// Per texel: the photo that gave it the largest weight ([`NO_PHOTO`] where none did);
    /// where two neighbours differ, the blend passes from one photo to another (a seam).
    pub dominant: Vec<u16>,
    /// Per photo: its colour gains (linear light, red, green, blue).
    pub gains: Vec<[Real; 3]>,
    /// Per photo: its share of the blend over the seen texels (the shares sum to 1).
    pub shares: Vec<Real>,
}

impl FaceTexture {
    /// Texels by source: `[seen, mirrored, filled]` inside the clip region.
    pub fn counts(&self) -> [usize; 3] {
        let mut counts = [0; 3];
        for s in &self.sources {
            match s {
                TexelSource::Seen => counts[0] += 1,
                TexelSource::Mirrored => counts[1] += 1,
                TexelSource::Filled => counts[2] += 1,
                TexelSource::Outside => {}
            }
        }
        counts
    }

    /// The textured face from five views in one picture, left to right: yaw −60°, −30°, 0°,
    /// 30° and 60° (as [`crate::depth::Pose`] defines yaw), each `320 × 400` pixels, rendered by
    /// [`crate::render::render_photo`] under a soft light from above the camera.
    ///
    /// # Errors
    /// [`FaceError::Option`] if the renderer refuses (it should not for a face's mesh).
    pub fn turntable(&self, mesh: &ClippedMesh) -> Result<RgbImage, FaceError> {
        Ok(Turntable::new(mesh)?.render(&self.atlas))
    }

    /// The confidence map as a picture: seen texels green (brighter where the best photo's
    /// weight is larger), mirrored ones blue (by their mirror image's weight), diffused ones
    /// red, the outside of the clip region black.
    pub fn confidence_image(&self) -> RgbImage {
        let side = self.atlas.width();
        let level = |c: f32| (55.0 + 200.0 * c.clamp(0.0, 1.0)).round() as u8;
        RgbImage::from_fn(side, side, |x, y| {
            let k = (y * side + x) as usize;
            match self.sources[k] {
                TexelSource::Outside => Rgb([0, 0, 0]),
                TexelSource::Seen => Rgb([0, level(self.confidence[k]), 0]),
                TexelSource::Mirrored => Rgb([0, 0, level(self.confidence[k])]),
                TexelSource::Filled => Rgb([200, 0, 0]),
            }
        })
    }
}

/// The smallest side [`automatic_atlas_side`] chooses, texels.
pub const AUTOMATIC_MIN_SIDE: u32 = 256;
/// The largest side [`automatic_atlas_side`] chooses, texels (a larger atlas can be asked
/// for: each photo's weights take 4 bytes a texel while the atlas is baked).
pub const AUTOMATIC_MAX_SIDE: u32 = 2048;

/// The share of the face's texels that [`automatic_atlas_side`] gives at least a texel per
/// pixel of the sharpest photo that sees them.
pub const AUTOMATIC_COVERAGE: Real = 0.9;

/// The atlas side that gives [`AUTOMATIC_COVERAGE`] of the face's texels at least one texel
/// per pixel of the sharpest photo that sees them, rounded up to a multiple of 128 and held to
/// [`AUTOMATIC_MIN_SIDE`]`..=`[`AUTOMATIC_MAX_SIDE`].
///
/// Over a 33 × 33 grid of the clip region's `(u, v)`, each point needs `max |∂π/∂u|,
/// |∂π/∂v|` texels per unit of `u` and `v`: the pixel lengths of the surface's tangents in
/// the photo that shows them longest, among the photos that see the point at less than 80°
/// (`π` a photo's projection, its derivatives by central differences). Texels are uniform in
/// `(u, v)`, so the grid's points stand for equal shares of the atlas; the side is the
/// [`AUTOMATIC_COVERAGE`] quantile of their needs. The rest are where the surface turns away
/// from the front (the cheeks' sides), which the parametrisation over the frontal plane gives
/// few texels per millimetre; giving every one of them a texel per pixel takes 1,400–1,500
/// texels on `lps-head`'s photos (median 440, 90%: 640–710).
///
/// More texels than the photos have pixels hold nothing the photos saw. Measured by
/// `tools/texture_eval` on `lps-head` (each atlas sampled bilinearly at a 1024² atlas's
/// texels, as a renderer samples it; mean error in sRGB levels / PSNR / seam step, and the
/// bake's time on 2 cores; the rule gives 768 for both sets):
///
/// | side | photos-8 | photos-3 |
/// |---|---|---|
/// | 1024 (the former default) | 16.37 / 21.72 dB / 1.37, 720 ms | 14.52 / 22.45 dB / 1.25, 396 ms |
/// | **768** | 16.36 / 21.72 dB / 1.34, 467 ms | 14.49 / 22.47 dB / 1.18, 189 ms |
/// | 512 | 16.32 / 21.74 dB / 1.29, 227 ms | 14.46 / 22.50 dB / 1.17, 105 ms |
/// | 256 | 16.24 / 21.79 dB / 1.28, 94 ms | 14.36 / 22.57 dB / 1.12, 28 ms |
///
/// (`tools/results/texture.md`.) The comparison cannot see detail finer than the
/// reconstruction's registration to the scan (about a millimetre, two or three pixels), so it
/// rewards blur a little; the rule keeps the photos' own resolution rather than the smallest
/// atlas that scores as well.
///
/// # Errors
/// [`FaceError::Kernel`] if the surface cannot be evaluated over its unit domain.
pub fn automatic_atlas_side(face: &FaceSurface, photos: &[TexturePhoto<'_>]) -> Result<u32, FaceError> {
    let cameras: Vec<RefinedCamera> = photos.iter().map(|p| p.camera).collect();
    atlas_side(face.surface(), face.clip(), &cameras)
}

/// [`automatic_atlas_side`] of a surface over the unit square, clipped to `clip`.
fn atlas_side(
    surface: &crate::bspline::BSplineSurface,
    clip: &[Point2<Real>],
    cameras: &[RefinedCamera],
) -> Result<u32, FaceError> {
    const GRID: usize = 33;
    // A step of the central differences, in (u, v): some hundredths of a canonical unit.
    const STEP: Real = 1e-4;
    let mut needs = Vec::with_capacity(GRID * GRID);
    for r in 0..GRID {
        for c in 0..GRID {
            let (u, v) = (c as Real / (GRID - 1) as Real, r as Real / (GRID - 1) as Real);
            if !polygon_contains(clip, Point2::new(u, v)) {
                continue;
            }
            let d = surface.derivatives(u, v, 1)?;
            let (point, tangents) = (Point3::from(d.get(0, 0)), [d.get(1, 0), d.get(0, 1)]);
            let Some(normal) = tangents[0].cross(&tangents[1]).try_normalize(0.0) else {
                continue;
            };
            let mut need: Real = 0.0;
            for camera in cameras {
                if !camera.look(&point, &normal).is_some_and(|l| l.cos >= GRAZING) {
                    continue;
                }
                for t in tangents {
                    let ends = (
                        camera.pixel(&(point + t * STEP)),
                        camera.pixel(&(point - t * STEP)),
                    );
                    if let (Some(a), Some(b)) = ends {
                        need = need.max((a - b).norm() / (2.0 * STEP));
                    }
                }
            }
            if need > 0.0 {
                needs.push(need);
            }
        }
    }
    if needs.is_empty() {
        return Ok(AUTOMATIC_MIN_SIDE);
    }
    let k = ((needs.len() - 1) as Real * AUTOMATIC_COVERAGE).round() as usize;
    let (_, &mut need, _) = needs.select_nth_unstable_by(k, Real::total_cmp);
    let side = (need / 128.0).ceil() * 128.0;
    Ok(side.clamp(Real::from(AUTOMATIC_MIN_SIDE), Real::from(AUTOMATIC_MAX_SIDE)) as u32)
}

/// sRGB (0–255) to linear light.
fn linear_table() -> [f32; 256] {
    std::array::from_fn(|v| crate::render::srgb_to_linear(v as f32 / 255.0))
}

fn to_srgb(c: f32) -> u8 {
    crate::render::linear_to_srgb8(Real::from(c))
}

/// Bilinear colour (linear light) at pixel `p` (`y` down, centres at integers), clamped to
/// the image.
fn sample(image: &RgbImage, table: &[f32; 256], p: Point2<Real>) -> [f32; 3] {
    let (w, h) = (image.width() as usize, image.height() as usize);
    let (x, y) = (p.x.clamp(0.0, (w - 1) as Real), p.y.clamp(0.0, (h - 1) as Real));
    // Truncation is the floor here (x, y ≥ 0), and no call into libm on baseline x86-64.
    let (x0, y0) = (x as usize, y as usize);
    let (fx, fy) = ((x - x0 as Real) as f32, (y - y0 as Real) as f32);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let raw = image.as_raw();
    let at = |x: usize, y: usize| {
        let i = 3 * (y * w + x);
        [raw[i], raw[i + 1], raw[i + 2]]
    };
    let (a, b, c, d) = (at(x0, y0), at(x1, y0), at(x0, y1), at(x1, y1));
    std::array::from_fn(|k| {
        let top = table[a[k] as usize] * (1.0 - fx) + table[b[k] as usize] * fx;
        let bottom = table[c[k] as usize] * (1.0 - fx) + table[d[k] as usize] * fx;
        top * (1.0 - fy) + bottom * fy
    })
}

/// The atlas's texels: its side and whether each texel lies in the clip region.
struct Texels {
    side: usize,
    inside: Vec<bool>,
}

impl Texels {
    fn new(side: usize, clip: &[Point2<Real>]) -> Self {
        // Row by row: the even-odd rule of `polygon_contains`, each row's crossings found once.
        let inside = (0..side)
            .into_par_iter()
            .flat_map_iter(|r| {
                let v = texel_centre(side, r, true);
                let crossings: Vec<Real> = (0..clip.len())
                    .filter_map(|k| edge_crossing(clip[k], clip[(k + 1) % clip.len()], v))
                    .collect();
                (0..side).map(move |c| {
                    let u = texel_centre(side, c, false);
                    // Inside when an odd number of crossings lie beyond u.
                    crossings.iter().filter(|&&x| u < x).count() % 2 == 1
                })
            })
            .collect();
        Texels { side, inside }
    }

    /// The surface parameters `[u, v]` of texel `k` (row-major, row 0 at `v = 1`).
    fn param(&self, k: usize) -> [Real; 2] {
        [
            texel_centre(self.side, k % self.side, false),
            texel_centre(self.side, k / self.side, true),
        ]
    }
}

/// The parameter of the centre of column (or, with `row`, row) `k` of a `side`-texel atlas:
/// `(k + ½)/side` along `u`, `1 − (k + ½)/side` along `v`.
fn texel_centre(side: usize, k: usize, row: bool) -> Real {
    let t = (k as Real + 0.5) / side as Real;
    if row { 1.0 - t } else { t }
}

/// Surfaces are evaluated, and photos look at them, every this many texels along each side of
/// the atlas (and at the last texel); every other texel's look is bilinear between the four
/// nodes around it. Over a cell of 4 texels of a 1024² atlas (about 0.5 canonical units) a
/// face's cubic surface departs from the bilinear interpolant by some thousandths of a unit,
/// and its projection into a photo from the interpolated projection by less.
pub const EVALUATION_STRIDE: usize = 4;

/// The atlas's nodes ([`EVALUATION_STRIDE`]): `n × n` of them, row-major like the texels.
struct Nodes {
    side: usize,
    /// The texel (along a side) of each node.
    at: Vec<usize>,
    /// Per texel along a side: the node at or before it, and its fraction toward the next.
    bracket: Vec<(usize, Real)>,
}

impl Nodes {
    fn new(side: usize) -> Self {
        let mut at: Vec<usize> = (0..side).step_by(EVALUATION_STRIDE).collect();
        if at.last() != Some(&(side - 1)) {
            at.push(side - 1);
        }
        let n = at.len();
        let bracket = (0..side)
            .map(|t| {
                let i = (t / EVALUATION_STRIDE).min(n - 2);
                let (a, b) = (at[i], at[i + 1]);
                (i, (t - a) as Real / (b - a) as Real)
            })
            .collect();
        Nodes { side, at, bracket }
    }

    fn count(&self) -> usize {
        self.at.len()
    }

    /// The texel index of node `q`.
    fn texel(&self, q: usize) -> usize {
        let n = self.count();
        self.at[q / n] * self.side + self.at[q % n]
    }

    /// Texel `k`'s four nodes (row-major: `(i, j)`, `(i + 1, j)`, `(i, j + 1)`,
    /// `(i + 1, j + 1)`) and their bilinear weights.
    fn corners(&self, k: usize) -> ([usize; 4], [Real; 4]) {
        let n = self.count();
        let ((i, fx), (j, fy)) = (self.bracket[k % self.side], self.bracket[k / self.side]);
        let q = j * n + i;
        (
            [q, q + 1, q + n, q + n + 1],
            [(1.0 - fx) * (1.0 - fy), fx * (1.0 - fy), (1.0 - fx) * fy, fx * fy],
        )
    }
}

/// `Σ wᵢ xᵢ` over a texel's four corners, in their order.
fn mix(weights: [Real; 4], values: [Real; 4]) -> Real {
    weights[0] * values[0] + weights[1] * values[1] + weights[2] * values[2] + weights[3] * values[3]
}

/// A surface at the atlas's nodes: positions, and unit normals `F_u × F_v` (toward the
/// viewer) from central differences between neighbouring nodes (one-sided at the edges).
struct NodeSurface {
    positions: Vec<Point3<Real>>,
    normals: Vec<Vector3<Real>>,
}

impl NodeSurface {
    fn new(surface: &crate::bspline::BSplineSurface, nodes: &Nodes) -> Result<Self, FaceError> {
        let n = nodes.count();
        let params: Vec<[Real; 2]> = (0..n * n)
            .map(|q| {
                [
                    texel_centre(nodes.side, nodes.at[q % n], false),
                    texel_centre(nodes.side, nodes.at[q / n], true),
                ]
            })
            .collect();
        let positions = surface.eval_many(&params)?;
        let normals = (0..n * n)
            .into_par_iter()
            .map(|q| {
                let (i, j) = (q % n, q / n);
                let at = |i: usize, j: usize| positions[j * n + i];
                let du = at((i + 1).min(n - 1), j) - at(i.saturating_sub(1), j);
                // Node row j − 1 lies at larger v.
                let dv = at(i, j.saturating_sub(1)) - at(i, (j + 1).min(n - 1));
                du.cross(&dv).try_normalize(0.0).unwrap_or_else(Vector3::z)
            })
            .collect();
        Ok(NodeSurface { positions, normals })
    }

    /// How `camera` sees every node inside the clip region (`None` outside it or where the
    /// camera does not see it).
    fn looks(&self, camera: &RefinedCamera, nodes: &Nodes, texels: &Texels) -> Vec<Option<Look>> {
        (0..self.positions.len())
            .into_par_iter()
            .map(|q| {
                texels.inside[nodes.texel(q)]
                    .then(|| camera.look(&self.positions[q], &self.normals[q]))
                    .flatten()
            })
            .collect()
    }
}

/// Texel `k`'s look, bilinear between its nodes' (`None` unless all four have one).
fn texel_look(nodes: &Nodes, looks: &[Option<Look>], k: usize) -> Option<Look> {
    let (q, w) = nodes.corners(k);
    let [a, b, c, d] = q.map(|q| looks[q]);
    let (a, b, c, d) = (a?, b?, c?, d?);
    let field = |f: fn(&Look) -> Real| mix(w, [f(&a), f(&b), f(&c), f(&d)]);
    Some(Look {
        pixel: Point2::new(field(|l| l.pixel.x), field(|l| l.pixel.y)),
        key: field(|l| l.key),
        cos: field(|l| l.cos),
        resolution: field(|l| l.resolution),
    })
}

/// A texel's pixel from its corners' (NaN where a node has none): [`texel_look`]'s pixel, to
/// the last bit.
fn texel_pixel((q, w): ([usize; 4], [Real; 4]), pixels: &[Point2<Real>]) -> Point2<Real> {
    let [a, b, c, d] = q.map(|q| pixels[q]);
    Point2::new(mix(w, [a.x, b.x, c.x, d.x]), mix(w, [a.y, b.y, c.y, d.y]))
}

/// A depth buffer of a surface in one photo.
struct DepthBuffer {
    /// Image position of cell `(0, 0)`'s corner, pixels.
    origin: Point2<Real>,
    /// Pixels per cell.
    cell: Real,
    width: usize,
    height: usize,
    keys: Vec<Real>,
}

impl DepthBuffer {
    /// Rasterises the quads between the atlas's nodes whose four corners the camera sees in
    /// the clip region (`looks`: [`NodeSurface::looks`]).
    fn new(looks: &[Option<Look>], nodes: &Nodes, image: (u32, u32)) -> Option<Self> {
        let n = nodes.count();
        let (mut lo, mut hi) = (
            Point2::new(Real::INFINITY, Real::INFINITY),
            Point2::new(Real::NEG_INFINITY, Real::NEG_INFINITY),
        );
        for look in looks.iter().flatten() {
            lo = lo.inf(&look.pixel);
            hi = hi.sup(&look.pixel);
        }
        if lo.x > hi.x {
            return None;
        }
        // Keep to the photo, and at most 512 cells along the longer side (the depth test's
        // slack grows with the cells).
        lo = lo.sup(&Point2::new(-1.0, -1.0));
        hi = hi.inf(&Point2::new(Real::from(image.0), Real::from(image.1)));
        if lo.x >= hi.x || lo.y >= hi.y {
            return None;
        }
        let cell = ((hi.x - lo.x).max(hi.y - lo.y) / 512.0).max(1.0);
        let (width, height) = (
            ((hi.x - lo.x) / cell).ceil() as usize + 1,
            ((hi.y - lo.y) / cell).ceil() as usize + 1,
        );
        let mut pixels = Vec::with_capacity(n * n);
        let mut keys = Vec::with_capacity(n * n);
        for look in looks {
            match look {
                Some(look) => {
                    let p = look.pixel;
                    pixels.push([(p.x - lo.x) / cell, (p.y - lo.y) / cell]);
                    keys.push(look.key);
                }
                None => {
                    pixels.push([Real::NAN, Real::NAN]);
                    keys.push(Real::NEG_INFINITY);
                }
            }
        }
        let mut triangles = Vec::with_capacity(2 * n * n);
        for j in 0..n - 1 {
            for i in 0..n - 1 {
                let q = j * n + i;
                let quad = [q, q + 1, q + n + 1, q + n];
                if quad.iter().all(|&q| keys[q].is_finite()) {
                    let [a, b, c, d] = quad.map(|q| q as u32);
                    triangles.push([a, b, c]);
                    triangles.push([a, c, d]);
                }
            }
        }
        let (keys_out, _) = crate::render::raster::rasterise(&pixels, &keys, &triangles, width, height);
        Some(DepthBuffer {
            origin: lo,
            cell,
            width,
            height,
            keys: keys_out,
        })
    }

    /// The front-most key at image point `p` (NaN where nothing was drawn).
    fn front(&self, p: Point2<Real>) -> Real {
        // The nearest cell, halves rounded up (truncation of a non-negative value is its floor).
        let (x, y) = (
            (p.x - self.origin.x) / self.cell + 0.5,
            (p.y - self.origin.y) / self.cell + 0.5,
        );
        if !(x >= 0.0 && y >= 0.0) || x as usize >= self.width || y as usize >= self.height {
            return Real::NAN;
        }
        self.keys[y as usize * self.width + x as usize]
    }
}

/// One photo's view of the atlas: per texel its weight; per node the pixel it lands on (NaN
/// where the photo does not see it), from which a texel's colour is sampled when it is needed
/// ([`PhotoView::colour`]); and the colours on the colour-matching grid ([`GainGrid`]).
struct PhotoView {
    weights: Vec<f32>,
    pixels: Vec<Point2<Real>>,
    gain_colours: Vec<[f32; 3]>,
}

impl PhotoView {
    /// The colour (linear light) the photo gives the texel with these corners
    /// ([`Nodes::corners`]).
    fn colour(&self, corners: ([usize; 4], [Real; 4]), image: &RgbImage, table: &[f32; 256]) -> [f32; 3] {
        sample(image, table, texel_pixel(corners, &self.pixels))
    }
}

/// The texels the colour gains are fitted on: every `step = max(⌊side/128⌋, 1)`-th along each
/// side (128² to about 255² of them, `side²` for atlases under 256).
struct GainGrid {
    step: usize,
    count: usize,
}

impl GainGrid {
    fn new(side: usize) -> Self {
        let step = (side / 128).max(1);
        GainGrid {
            step,
            count: side.div_ceil(step),
        }
    }

    /// The grid's texels, row-major.
    fn texels(&self, side: usize) -> impl Iterator<Item = usize> + '_ {
        (0..self.count).flat_map(move |r| (0..self.count).map(move |c| r * self.step * side + c * self.step))
    }
}

/// The 3-4 chamfer distance (in texels, × 3) from every texel in `region` to the nearest
/// texel of `region` whose weight is 0, capped at `cap`.
fn distance_to_unset(weights: &[f32], region: &[bool], side: usize, cap: u16) -> Vec<u16> {
    let mut d: Vec<u16> = (0..side * side)
        .map(|k| if region[k] && weights[k] <= 0.0 { 0 } else { cap })
        .collect();
    let relax = |d: &mut Vec<u16>, k: usize, j: usize, cost: u16| {
        let through = d[j].saturating_add(cost);
        if through < d[k] {
            d[k] = through;
        }
    };
    for r in 0..side {
        for c in 0..side {
            let k = r * side + c;
            if c > 0 {
                relax(&mut d, k, k - 1, 3);
            }
            if r > 0 {
                relax(&mut d, k, k - side, 3);
                if c > 0 {
                    relax(&mut d, k, k - side - 1, 4);
                }
                if c + 1 < side {
                    relax(&mut d, k, k - side + 1, 4);
                }
            }
        }
    }
    for r in (0..side).rev() {
        for c in (0..side).rev() {
            let k = r * side + c;
            if c + 1 < side {
                relax(&mut d, k, k + 1, 3);
            }
            if r + 1 < side {
                relax(&mut d, k, k + side, 3);
                if c + 1 < side {
                    relax(&mut d, k, k + side + 1, 4);
                }
                if c > 0 {
                    relax(&mut d, k, k + side - 1, 4);
                }
            }
        }
    }
    d
}

/// Photo `photo`'s view of the atlas (see the module documentation), seen on `surface` (the
/// face as the photo shows it), before its feathering ([`feather_view`]): its weights, and its
/// nodes' pixels.
fn photo_view(
    photo: &TexturePhoto<'_>,
    surface: &NodeSurface,
    (nodes, texels): (&Nodes, &Texels),
    reference_resolution: Real,
) -> PhotoView {
    let n = texels.side * texels.side;
    let (w, h) = (photo.image.width(), photo.image.height());
    let looks = surface.looks(&photo.camera, nodes, texels);
    let buffer = DepthBuffer::new(&looks, nodes, (w, h));
    let margin = 0.02 * Real::from(w.min(h));
    let mut weights = vec![0.0f32; n];
    weights.par_iter_mut().enumerate().for_each(|(k, weight)| {
        let Some(buffer) = &buffer else {
            return;
        };
        let Some(look) = texels.inside[k].then(|| texel_look(nodes, &looks, k)).flatten() else {
            return;
        };
        let (p, key, cos, resolution) = (look.pixel, look.key, look.cos, look.resolution);
        let facing = ((cos - GRAZING) / (1.0 - GRAZING)).clamp(0.0, 1.0);
        if facing <= 0.0 {
            return;
        }
        let border =
            p.x.min(p.y)
                .min(Real::from(w) - 1.0 - p.x)
                .min(Real::from(h) - 1.0 - p.y);
        if border <= 0.0 {
            return;
        }
        // The buffer's cell spans `cell / resolution` units; a surface seen at angle θ
        // changes depth by up to that much times tan θ across it.
        let slack = 2.0 * buffer.cell / resolution.max(Real::MIN_POSITIVE) / cos.max(0.2);
        let front = buffer.front(p);
        if front.is_finite() && key < front - DEPTH_TOLERANCE - slack {
            return;
        }
        let edge = (border / margin.max(1.0)).min(1.0);
        let sharpness = (resolution / reference_resolution).min(1.0);
        *weight = (facing * facing * edge * sharpness) as f32;
    });
    let pixels = looks
        .iter()
        .map(|look| look.map_or(Point2::new(Real::NAN, Real::NAN), |l| l.pixel))
        .collect();
    PhotoView {
        weights,
        pixels,
        gain_colours: Vec::new(),
    }
}

/// Feathers a view's weights toward the texels its photo does not see, and samples its colours
/// on the colour-matching grid. One core's work (the distance transform runs along the rows),
/// so that photos can be finished side by side.
fn feather_view(
    view: &mut PhotoView,
    image: &RgbImage,
    (nodes, texels, gain_grid): (&Nodes, &Texels, &GainGrid),
    table: &[f32; 256],
) {
    let reach = (FEATHER * texels.side as Real).max(1.0);
    // At most 3 × 64 for the largest atlas.
    let cap = (3.0 * reach).ceil() as u16;
    let distance = distance_to_unset(&view.weights, &texels.inside, texels.side, cap);
    view.weights.iter_mut().zip(&distance).for_each(|(w, &d)| {
        *w *= ((d as Real / 3.0) / reach).min(1.0) as f32;
    });
    view.gain_colours = gain_grid
        .texels(texels.side)
        .map(|k| {
            if view.weights[k] > 0.0 {
                view.colour(nodes.corners(k), image, table)
            } else {
                [0.0; 3]
            }
        })
        .collect();
}

/// Per-photo gains (per channel, in the logarithm) that make the photos agree on the texels
/// they share: a weighted, Cauchy-reweighted least-squares fit normalised to a weighted
/// geometric mean of 1 (see the module documentation).
fn colour_gains(views: &[PhotoView], texels: &Texels, grid: &GainGrid) -> Vec<[Real; 3]> {
    let m = views.len();
    let mut gains = vec![[1.0; 3]; m];
    if m < 2 {
        return gains;
    }
    // Shared texels on the gain grid: (photo, weight, log colour) per view of each.
    let mut shared: Vec<(usize, Real, [Real; 3])> = Vec::new();
    let mut groups: Vec<std::ops::Range<usize>> = Vec::new();
    for (g, k) in grid.texels(texels.side).enumerate() {
        let begin = shared.len();
        for (i, view) in views.iter().enumerate() {
            let colour = view.gain_colours[g];
            if view.weights[k] > 0.0 && colour.iter().all(|&v| v > 1.0 / 255.0) {
                shared.push((i, view.weights[k] as Real, colour.map(|v| (v as Real).ln())));
            }
        }
        if shared.len() - begin >= 2 {
            groups.push(begin..shared.len());
        } else {
            shared.truncate(begin);
        }
    }
    if groups.is_empty() {
        return gains;
    }
    let totals: Vec<Real> = views
        .iter()
        .map(|v| v.weights.iter().map(|&w| w as Real).sum::<Real>())
        .collect();
    let total: Real = totals.iter().sum::<Real>().max(Real::MIN_POSITIVE);
    const SCALE: Real = 0.1; // the Cauchy scale of a log-colour difference: about 10%
    let mut x = vec![[0.0 as Real; 3]; m];
    for _round in 0..3 {
        let mut a = vec![DMatrix::<Real>::zeros(m, m); 3];
        let mut b = vec![DVector::<Real>::zeros(m); 3];
        for group in &groups {
            let seen = &shared[group.clone()];
            for (p, &(i, wi, ci)) in seen.iter().enumerate() {
                for &(j, wj, cj) in &seen[p + 1..] {
                    for ch in 0..3 {
                        // x_i − x_j ≈ log c_j − log c_i.
                        let d = cj[ch] - ci[ch];
                        let r = x[i][ch] - x[j][ch] - d;
                        let omega = wi * wj / (1.0 + (r / SCALE).powi(2));
                        a[ch][(i, i)] += omega;
                        a[ch][(j, j)] += omega;
                        a[ch][(i, j)] -= omega;
                        a[ch][(j, i)] -= omega;
                        b[ch][i] += omega * d;
                        b[ch][j] -= omega * d;
                    }
                }
            }
        }
        for (ch, (mut a, b)) in a.into_iter().zip(b).enumerate() {
            // A ridge keeps photos that share nothing with the others at a gain of 1.
            let ridge = 1e-6 * (a.trace() / m as Real).max(Real::MIN_POSITIVE);
            for i in 0..m {
                a[(i, i)] += ridge;
            }
            if let Some(solution) = a.cholesky().map(|c| c.solve(&b)) {
                for i in 0..m {
                    x[i][ch] = solution[i];
                }
            }
        }
    }
    for ch in 0..3 {
        let mean = (0..m).map(|i| x[i][ch] * totals[i]).sum::<Real>() / total;
        for i in 0..m {
            gains[i][ch] = (x[i][ch] - mean).exp();
        }
    }
    gains
}

/// One texel's blend: its colour (linear light), the largest weight a photo gave it, and
/// the sum of the powered weights (0 where no photo sees it).
#[derive(Debug, Clone, Copy, Default)]
struct Blended {
    colour: [f32; 3],
    best: f32,
    dominant: u16,
    total: f32,
}

/// `w^p`, by multiplication when `p` is a small whole number.
fn power(w: Real, p: Real) -> Real {
    if p == p.round() && (1.0..=16.0).contains(&p) {
        w.powi(p as i32)
    } else {
        w.powf(p)
    }
}

/// Push-pull diffusion: fills every texel whose weight is 0 from the weighted colours around
/// it (a pyramid of weighted 2 × 2 means, each level's holes filled bilinearly from the next
/// coarser one).
fn push_pull(colours: &mut [[f32; 3]], known: &[bool], side: usize) {
    if side <= 1 || known.iter().all(|&k| !k) {
        return;
    }
    let premultiplied: Vec<[f32; 4]> = colours
        .iter()
        .zip(known)
        .map(|(c, &k)| if k { [c[0], c[1], c[2], 1.0] } else { [0.0; 4] })
        .collect();
    let filled = fill_level(premultiplied, side);
    for (k, c) in colours.iter_mut().enumerate() {
        if !known[k] {
            let f = filled[k];
            *c = [f[0], f[1], f[2]];
        }
    }
}

/// One level of [`push_pull`]: `level` holds weight-premultiplied colours and weights; returns
/// plain colours everywhere.
fn fill_level(level: Vec<[f32; 4]>, side: usize) -> Vec<[f32; 4]> {
    let plain = |v: [f32; 4]| {
        if v[3] > 0.0 {
            [v[0] / v[3], v[1] / v[3], v[2] / v[3], 1.0]
        } else {
            [0.0; 4]
        }
    };
    if side == 1 {
        return vec![plain(level[0])];
    }
    let half = side.div_ceil(2);
    let mut coarse = vec![[0.0f32; 4]; half * half];
    for r in 0..side {
        for c in 0..side {
            let v = level[r * side + c];
            let o = &mut coarse[(r / 2) * half + c / 2];
            for k in 0..4 {
                o[k] += v[k];
            }
        }
    }
    for o in &mut coarse {
        // Weights saturate at 1 so that a well-covered coarse texel counts as fully known.
        if o[3] > 1.0 {
            let s = 1.0 / o[3];
            o.iter_mut().for_each(|v| *v *= s);
        }
    }
    let coarse = fill_level(coarse, half);
    (0..side * side)
        .into_par_iter()
        .map(|k| {
            let v = level[k];
            if v[3] >= 1.0 {
                return plain(v);
            }
            let (r, c) = (k / side, k % side);
            // Bilinear from the coarse level: texel centre c maps to (c + ½)/2 − ½ there.
            let (y, x) = ((r as f32 + 0.5) / 2.0 - 0.5, (c as f32 + 0.5) / 2.0 - 0.5);
            let (y0, x0) = (y.floor().max(0.0), x.floor().max(0.0));
            let (fy, fx) = ((y - y0).clamp(0.0, 1.0), (x - x0).clamp(0.0, 1.0));
            let (y0, x0) = (y0 as usize, x0 as usize);
            let (y1, x1) = ((y0 + 1).min(half - 1), (x0 + 1).min(half - 1));
            let at = |r: usize, c: usize| coarse[r * half + c];
            let up: [f32; 4] = std::array::from_fn(|k| {
                let top = at(y0, x0)[k] * (1.0 - fx) + at(y0, x1)[k] * fx;
                let bottom = at(y1, x0)[k] * (1.0 - fx) + at(y1, x1)[k] * fx;
                top * (1.0 - fy) + bottom * fy
            });
            // A partly known texel keeps its own colour in proportion to its weight.
            let w = v[3];
            let own = plain(v);
            [
                w * own[0] + (1.0 - w) * up[0],
                w * own[1] + (1.0 - w) * up[1],
                w * own[2] + (1.0 - w) * up[2],
                1.0,
            ]
        })
        .collect()
}

/// [`bake_texture`]'s checks of its inputs.
fn check_inputs(
    face: &FaceSurface,
    photos: &[TexturePhoto<'_>],
    options: &TextureOptions,
) -> Result<(), FaceError> {
    if let Some(size) = options.size.filter(|s| !(16..=8192).contains(s)) {
        return Err(FaceError::Option {
            name: "texture size",
            value: size.to_string(),
            expected: "16 to 8192 texels",
        });
    }
    if !(options.sharpness > 0.0 && options.sharpness.is_finite()) {
        return Err(FaceError::Option {
            name: "texture sharpness",
            value: options.sharpness.to_string(),
            expected: "positive and finite",
        });
    }
    if photos.is_empty()
        || photos.len() >= NO_PHOTO as usize
        || photos
            .iter()
            .any(|p| p.image.width() == 0 || p.image.height() == 0)
    {
        return Err(FaceError::Option {
            name: "texture photos",
            value: format!("{} photo(s)", photos.len()),
            expected: "1 to 65,534 photos, none of them empty",
        });
    }
    let domain = |s: &FaceSurface| (s.surface().domain_u(), s.surface().domain_v());
    if photos
        .iter()
        .filter_map(|p| p.surface)
        .any(|s| domain(s) != domain(face))
    {
        return Err(FaceError::Option {
            name: "texture photo surface",
            value: "a surface over another parameter domain".to_owned(),
            expected: "the face's own parameter domain",
        });
    }
    Ok(())
}

/// Each photo's view of the texels (what it sees of each and how well), taken at its own
/// surface when it has one; grey photos count a thousandth where a colour photo also sees.
fn photo_views(
    face: &NodeSurface,
    photos: &[TexturePhoto<'_>],
    grids: (&Nodes, &Texels, &GainGrid),
    reference_resolution: Real,
    table: &[f32; 256],
) -> Result<Vec<PhotoView>, FaceError> {
    // One photo after another, each over the texels in parallel: side by side measured 15–50
    // ms faster in the stage and 10–30 MB more at the peak. The feathering, one core's work
    // per photo, then runs for the photos side by side.
    let mut views = Vec::with_capacity(photos.len());
    for photo in photos {
        let own;
        let surface = match photo.surface {
            Some(s) => {
                own = NodeSurface::new(s.surface(), grids.0)?;
                &own
            }
            None => face,
        };
        views.push(photo_view(
            photo,
            surface,
            (grids.0, grids.1),
            reference_resolution,
        ));
    }
    views
        .par_iter_mut()
        .zip(photos)
        .for_each(|(view, photo)| feather_view(view, photo.image, grids, table));
    // A greyscale photo would take the colour out of every texel it shares: where a colour
    // photo sees a texel, it counts a thousandth as much.
    let grey: Vec<bool> = photos
        .par_iter()
        .map(|p| {
            p.image
                .as_raw()
                .par_chunks(3 * 4096)
                .all(|run| run.chunks_exact(3).all(|c| c[0] == c[1] && c[1] == c[2]))
        })
        .collect();
    if grey.iter().any(|&g| !g) {
        for (view, _) in views.iter_mut().zip(&grey).filter(|(_, g)| **g) {
            view.weights.iter_mut().for_each(|w| *w *= GREY_WEIGHT);
        }
    }
    Ok(views)
}

/// Every texel's colour, the weighted mean of the photos that see it (weights to the power
/// `p`, colours times their photo's gain), with its best weight and that photo. Each photo's
/// colour is sampled here, where its weight is positive, rather than held for the whole atlas.
///
/// The atlas is blended in bands of [`BLEND_ROWS`] rows, and each band photo by photo: a band
/// reads a small part of each photo, which stays in the cache while the band's texels take it,
/// where a texel after texel pass reads every photo at once (on `lps-head`'s photos-8, seven
/// photos of 2.7 MB: the blend took 1.6 times as long). Each texel still sums its photos in
/// their order, so the colours are the same to the last bit.
fn blend(
    views: &[PhotoView],
    (photos, nodes, table): (&[TexturePhoto<'_>], &Nodes, &[f32; 256]),
    gains: &[[Real; 3]],
    p: Real,
) -> Vec<Blended> {
    let side = nodes.side;
    let mut blended = vec![Blended::default(); side * side];
    blended
        .par_chunks_mut(BLEND_ROWS * side)
        .enumerate()
        .for_each(|(band, out)| {
            let first = band * BLEND_ROWS * side;
            let mut sums = vec![([0.0 as Real; 3], 0.0 as Real); out.len()];
            for (i, (view, photo)) in views.iter().zip(photos).enumerate() {
                let weights = &view.weights[first..first + out.len()];
                for (d, ((b, (sum, total)), &w)) in out.iter_mut().zip(&mut sums).zip(weights).enumerate() {
                    if w <= 0.0 {
                        continue;
                    }
                    if w > b.best {
                        b.best = w;
                        b.dominant = i as u16;
                    }
                    let wp = power(w as Real, p);
                    let c = view.colour(nodes.corners(first + d), photo.image, table);
                    for ch in 0..3 {
                        sum[ch] += wp * gains[i][ch] * c[ch] as Real;
                    }
                    *total += wp;
                }
            }
            for (b, (sum, total)) in out.iter_mut().zip(&sums) {
                if *total > 0.0 {
                    b.colour = sum.map(|s| (s / total) as f32);
                    b.total = *total as f32;
                } else {
                    *b = Blended {
                        dominant: NO_PHOTO,
                        ..Blended::default()
                    };
                }
            }
        });
    blended
}

/// The rows of the atlas blended together ([`blend`]).
const BLEND_ROWS: usize = 8;

/// Each photo's share of the blend, normalised to sum to 1 (0 each when nothing was seen).
fn photo_shares(views: &[PhotoView], blended: &[Blended], p: Real, m: usize) -> Vec<Real> {
    // Each photo's share, summed over fixed chunks in order (the same to the last bit
    // whatever the number of threads).
    let partial: Vec<Vec<Real>> = blended
        .par_chunks(4096)
        .enumerate()
        .map(|(c, chunk)| {
            let mut shares = vec![0.0; m];
            for (d, b) in chunk.iter().enumerate() {
                if b.total > 0.0 {
                    let k = c * 4096 + d;
                    for (i, view) in views.iter().enumerate() {
                        shares[i] += power(view.weights[k] as Real, p) / b.total as Real;
                    }
                }
            }
            shares
        })
        .collect();
    let mut shares = vec![0.0; m];
    for chunk in &partial {
        shares.iter_mut().zip(chunk).for_each(|(s, c)| *s += c);
    }
    let share_total: Real = shares.iter().sum();
    shares
        .into_iter()
        .map(|s| if share_total > 0.0 { s / share_total } else { 0.0 })
        .collect()
}

/// Fills texels no photo saw from their mirror image across the face's midline, where a photo
/// saw that. (Only unseen texels change, and only seen ones are read: each texel's mirror is
/// looked up independently, in parallel.)
fn fill_from_mirror(
    face: &FaceSurface,
    texels: &Texels,
    side: usize,
    (sources, colours, confidence): (&mut [TexelSource], &mut [[f32; 3]], &mut [f32]),
) {
    let frame = face.frame();
    let mirrors: Vec<Option<usize>> = (0..side * side)
        .into_par_iter()
        .map(|k| {
            if sources[k] != TexelSource::Filled {
                return None;
            }
            let [u, v] = texels.param(k);
            let q = frame.position(u, v);
            let m = frame.parameters(-q.x, q.y);
            let c = ((m.x * side as Real).floor() as i64).clamp(0, side as i64 - 1) as usize;
            let r = (((1.0 - m.y) * side as Real).floor() as i64).clamp(0, side as i64 - 1) as usize;
            let j = r * side + c;
            (sources[j] == TexelSource::Seen).then_some(j)
        })
        .collect();
    for (k, j) in mirrors.into_iter().enumerate() {
        if let Some(j) = j {
            sources[k] = TexelSource::Mirrored;
            colours[k] = colours[j];
            confidence[k] = confidence[j];
        }
    }
}

/// Bakes a texture atlas for `face` from `photos` (see the module documentation).
///
/// # Errors
/// [`FaceError::Option`] for a size outside 16–8192, a sharpness that is not positive and
/// finite, no photos, an empty photo, or a photo surface whose parameter domain is not the
/// face's; [`FaceError::Kernel`] if the surface cannot be evaluated.
pub fn bake_texture(
    face: &FaceSurface,
    photos: &[TexturePhoto<'_>],
    options: &TextureOptions,
) -> Result<FaceTexture, FaceError> {
    check_inputs(face, photos, options)?;
    let size = match options.size {
        Some(size) => size,
        None => automatic_atlas_side(face, photos)?,
    };
    let side = size as usize;
    let (texels, nodes, gain_grid) = (
        Texels::new(side, face.clip()),
        Nodes::new(side),
        GainGrid::new(side),
    );
    let surface = NodeSurface::new(face.surface(), &nodes)?;
    let table = linear_table();
    // The median photo's resolution over the face (at the atlas's centre).
    let centre = face.surface().eval(
        texel_centre(side, side / 2, false),
        texel_centre(side, side / 2, true),
    )?;
    let mut resolutions: Vec<Real> = photos
        .iter()
        .map(|p| p.camera.resolution(&centre).unwrap_or(0.0))
        .collect();
    resolutions.sort_by(Real::total_cmp);
    let reference_resolution = resolutions[resolutions.len() / 2].max(Real::MIN_POSITIVE);

    let grids = (&nodes, &texels, &gain_grid);
    let views = photo_views(&surface, photos, grids, reference_resolution, &table)?;
    let gains = if options.match_colours {
        colour_gains(&views, &texels, &gain_grid)
    } else {
        vec![[1.0; 3]; photos.len()]
    };

    let m = photos.len();
    let blended = blend(&views, (photos, &nodes, &table), &gains, options.sharpness);
    let shares = photo_shares(&views, &blended, options.sharpness, m);
    let mut colours: Vec<[f32; 3]> = blended.par_iter().map(|b| b.colour).collect();
    let mut confidence: Vec<f32> = blended
        .par_iter()
        .zip(&texels.inside)
        .map(|(b, &inside)| if inside { b.best } else { 0.0 })
        .collect();
    let mut sources: Vec<TexelSource> = blended
        .par_iter()
        .zip(&texels.inside)
        .map(|(b, &inside)| match (inside, b.total > 0.0) {
            (false, _) => TexelSource::Outside,
            (true, true) => TexelSource::Seen,
            (true, false) => TexelSource::Filled,
        })
        .collect();
    if options.mirror {
        fill_from_mirror(face, &texels, side, (&mut sources, &mut colours, &mut confidence));
    }
    let known: Vec<bool> = sources
        .iter()
        .map(|s| matches!(s, TexelSource::Seen | TexelSource::Mirrored))
        .collect();
    push_pull(&mut colours, &known, side);
    let mut atlas = RgbImage::new(size, size);
    atlas
        .par_chunks_mut(3)
        .zip(&colours)
        .for_each(|(texel, colour)| texel.copy_from_slice(&colour.map(to_srgb)));
    Ok(FaceTexture {
        atlas,
        sources,
        confidence,
        dominant: blended.iter().map(|b| b.dominant).collect(),
        gains,
        shares,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bspline::{BSplineSurface, KnotVector};
    use crate::depth::Pose;

    /// The flat parallelogram `F(u, v) = o + u a + v b` over the unit square (degree 1), with
    /// `a` and `b`.
    fn parallelogram() -> (BSplineSurface, Vector3<Real>, Vector3<Real>) {
        let knots = KnotVector::clamped_uniform(1, 2, 0.0, 1.0).unwrap();
        let (origin, a, b) = (
            Vector3::new(-30.0, -40.0, 5.0),
            Vector3::new(60.0, 0.0, 6.0),
            Vector3::new(3.0, 80.0, -4.0),
        );
        // Row i is u = i, column j is v = j.
        let corners = vec![
            Point3::from(origin),
            Point3::from(origin + b),
            Point3::from(origin + a),
            Point3::from(origin + a + b),
        ];
        (
            BSplineSurface::new(knots.clone(), knots, 2, 2, corners).unwrap(),
            a,
            b,
        )
    }

    /// A flat parallelogram `F = o + u a + v b` seen by an orthographic camera of scale `s`
    /// needs `s · max(|P R a|, |P R b|)` texels at every point: the side is that rounded up to
    /// a multiple of 128, held to 256..=2048; a camera that sees it edge-on or from behind
    /// asks for nothing.
    #[test]
    fn the_automatic_side_gives_a_texel_per_pixel_of_the_sharpest_camera() {
        let (surface, a, b) = parallelogram();
        let clip = [
            Point2::new(0.0, 0.0),
            Point2::new(1.0, 0.0),
            Point2::new(1.0, 1.0),
            Point2::new(0.0, 1.0),
        ];
        let camera = |scale: Real, yaw: Real, pitch: Real| {
            let pose = Pose::from_yaw_pitch_roll_degrees(yaw, pitch, 5.0, scale);
            RefinedCamera::orthographic(&pose, Point2::new(30.0, -20.0), (800, 1000))
        };
        // Texels per unit of scale: the longer of the two tangents' images.
        let per_scale = |yaw: Real, pitch: Real| {
            let c = camera(1.0, yaw, pitch);
            let lengths = [a, b].map(|t| (c.rotation * t).xy().norm());
            lengths[0].max(lengths[1])
        };
        // Scales that need 3% under a multiple of 128: a side that left out the
        // foreshortening (|a|, |b| = 60.3, 80.2) would round up past it.
        for (yaw, pitch) in [(20.0, -10.0), (20.0, -50.0), (60.0, 0.0)] {
            for side in [384, 640, 1024, 1536] {
                let scale = 0.97 * Real::from(side) / per_scale(yaw, pitch);
                let sharp = camera(scale, yaw, pitch);
                assert_eq!(
                    atlas_side(&surface, &clip, &[sharp]).unwrap(),
                    side,
                    "{yaw}, {pitch}"
                );
                // The sharper of two cameras decides.
                let blunt = camera(scale / 2.0, -yaw, pitch);
                assert_eq!(atlas_side(&surface, &clip, &[blunt, sharp]).unwrap(), side);
            }
        }
        let side =
            |scale: Real, yaw: Real| atlas_side(&surface, &clip, &[camera(scale, yaw, -10.0)]).unwrap();
        assert_eq!(side(0.5, 20.0), AUTOMATIC_MIN_SIDE);
        assert_eq!(side(100.0, 20.0), AUTOMATIC_MAX_SIDE);
        // Seen from behind (yaw 180°) or edge-on (85°), the camera asks for nothing.
        assert_eq!(side(12.0, 180.0), AUTOMATIC_MIN_SIDE);
        assert_eq!(side(12.0, 85.0), AUTOMATIC_MIN_SIDE);
    }

    /// On a flat parallelogram seen by an orthographic camera, a texel's projection, depth key,
    /// cosine and resolution are affine in `(u, v)`, so the nodes' bilinear interpolation must
    /// give every texel exactly what the camera gives its surface point; and a texel's pixel
    /// from the kept node pixels is its look's pixel to the last bit. The atlas's side (99)
    /// leaves a last node cell narrower than the others.
    #[test]
    fn texel_looks_interpolate_the_nodes_exactly_where_the_projection_is_affine() {
        let (surface, a, b) = parallelogram();
        let pose = Pose::from_yaw_pitch_roll_degrees(20.0, -10.0, 5.0, 7.0);
        let camera = RefinedCamera::orthographic(&pose, Point2::new(30.0, -20.0), (800, 1000));
        let side = 99;
        let clip = [
            Point2::new(-0.1, -0.1),
            Point2::new(1.1, -0.1),
            Point2::new(1.1, 1.1),
            Point2::new(-0.1, 1.1),
        ];
        let (texels, nodes) = (Texels::new(side, &clip), Nodes::new(side));
        assert_eq!(nodes.at[nodes.count() - 2..], [96, 98]);
        let at_nodes = NodeSurface::new(&surface, &nodes).unwrap();
        let looks = at_nodes.looks(&camera, &nodes, &texels);
        let pixels: Vec<Point2<Real>> = looks.iter().map(|l| l.unwrap().pixel).collect();
        let normal = a.cross(&b).normalize();
        for k in (0..side * side).step_by(7) {
            let [u, v] = texels.param(k);
            let truth = camera.look(&surface.eval(u, v).unwrap(), &normal).unwrap();
            let look = texel_look(&nodes, &looks, k).unwrap();
            assert!(
                (look.pixel - truth.pixel).norm() < 1e-9,
                "texel {k}: {look:?} against {truth:?}"
            );
            assert!((look.key - truth.key).abs() < 1e-9, "texel {k}");
            assert!((look.cos - truth.cos).abs() < 1e-12, "texel {k}");
            assert!((look.resolution - truth.resolution).abs() < 1e-12, "texel {k}");
            assert_eq!(texel_pixel(nodes.corners(k), &pixels), look.pixel, "texel {k}");
        }
    }
}
