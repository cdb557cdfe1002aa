//! The evaluation's subjects: a mesh to photograph (textured, millimetres, `+y` up, facing
//! `+z`) and the truth to score against (its surface and 40-point structure).
//!
//! * `lps`: Lee Perry-Smith's head scan (`../shared/data/lps-head`, CC BY 3.0), its own colour
//!   map, scored against `truth/mesh.obj` and `truth/landmarks68.txt`.
//! * `ict-N`: ICT-FaceKit identities (`../shared/data/ict-face`, MIT) wearing a real skin: a
//!   frontal photo projected onto the mean face through its landmarks (the identities share
//!   the mean face's texture coordinates), eye and mouth openings closed by fans.

use std::path::Path;

use anyhow::{Context, Result, bail};
use nalgebra::{DMatrix, Point2, Point3, Vector3};
use splineface::Real;
use splineface::compare::fit_similarity;
use splineface::landmarker::ShapePredictor;
use splineface::mesh::{TextureCoordinates, TriangleMesh, read_mesh};
use splineface::render::ColourMap;
use splineface::structure::from_ibug68;

use crate::common::{Ict, Lcg};

/// A face to photograph and score.
pub struct Subject {
    pub name: String,
    /// What the camera sees: millimetres, textured.
    pub mesh: TriangleMesh,
    pub colour: ColourMap,
    /// What a reconstruction is scored against (millimetres, same frame).
    pub truth: TriangleMesh,
    pub structure: Vec<Point3<Real>>,
    /// The 68 landmarks of the face the camera sees (millimetres; with an expression, the
    /// expressive face's).
    pub ibug: Vec<Point3<Real>>,
    /// The point cameras aim at (the middle of the face).
    pub target: Point3<Real>,
}

fn read_points(path: &Path) -> Result<Vec<Point3<Real>>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    text.lines()
        .filter(|l| !l.trim().is_empty() && !l.trim_start().starts_with('#'))
        .map(|l| {
            let v: Vec<Real> = l
                .split_whitespace()
                .map(str::parse)
                .collect::<Result<_, _>>()
                .with_context(|| format!("{}: `{l}`", path.display()))?;
            match v[..] {
                [x, y, z] => Ok(Point3::new(x, y, z)),
                _ => bail!("{}: `{l}` is not x y z", path.display()),
            }
        })
        .collect()
}

fn face_target(structure: &[Point3<Real>]) -> Point3<Real> {
    // Halfway between the eye centres and the mouth, on the face.
    let eyes = nalgebra::center(&structure[23], &structure[24]);
    let mouth = structure[32..40].iter().map(|p| p.coords).sum::<Vector3<Real>>() / 8.0;
    Point3::from((eyes.coords + mouth) / 2.0)
}

/// The Lee Perry-Smith scan, moved onto its truth (the two share their vertex order).
pub fn lps(dir: &Path) -> Result<Subject> {
    let glb = read_mesh(&dir.join("scan/LeePerrySmith.glb"))?;
    let truth = read_mesh(&dir.join("truth/mesh.obj"))?;
    if glb.positions().len() != truth.positions().len() {
        bail!("the scan and its truth differ in vertex count");
    }
    let (map, rms) = fit_similarity(glb.positions(), truth.positions()).context("degenerate scan")?;
    if rms > 1e-3 {
        bail!("the scan is not its truth moved ({rms} mm)");
    }
    let mesh = glb.transformed(&nalgebra::Affine3::from_matrix_unchecked(map.to_homogeneous()));
    // The file's texture coordinates were made for a map loaded with its rows flipped (as
    // three.js loads it: v = 0 is the image's bottom row); the glTF reader flips v once more.
    let mut texture = mesh
        .texture()
        .context("the scan has no texture coordinates")?
        .clone();
    for uv in &mut texture.uvs {
        uv.y = 1.0 - uv.y;
    }
    let mesh = mesh.with_texture(texture)?;
    let colour = ColourMap::new(&image::open(dir.join("scan/Map-COL.jpg"))?.to_rgb8());
    let ibug = read_points(&dir.join("truth/landmarks68.txt"))?;
    let structure = from_ibug68(&ibug)?;
    Ok(Subject {
        name: "lps".into(),
        target: face_target(&structure),
        mesh,
        colour,
        truth,
        structure,
        ibug,
    })
}

/// A skin from a frontal photo, in the ICT mean face's texture coordinates.
pub struct Skin {
    pub name: String,
    pub colour: ColourMap,
    pub image: image::RgbImage,
}

/// The ICT mesh's openings (eyes, mouth) closed by fans about a centre set back (an eye's by
/// [`EYE_DEPTH`], the mouth's by [`MOUTH_DEPTH`]), and the outer boundary left open.
struct Openings {
    /// Each opening: its boundary loop (vertex indices) and whether it is the mouth.
    loops: Vec<(Vec<u32>, bool)>,
}

/// How far back the centre of an eye's fan sits, cm.
const EYE_DEPTH: Real = 0.5;

/// How far back the centre of the mouth's fan sits, cm.
const MOUTH_DEPTH: Real = 1.0;

/// The side of the block of texels in a skin's top-left corner (outside the ICT mesh's
/// texture chart) that holds the inside of the mouth.
const MOUTH_TEXELS: u32 = 8;

/// The inside of the mouth, sRGB: dark and reddish, as a mouth's inside is in photos (its
/// cavity then shades it darker still). Before, the fan closing the mouth took the lips'
/// colours, so that an open jaw showed a lip-coloured funnel that no landmarker sees in real
/// photos.
const MOUTH_COLOUR: [u8; 3] = [52, 24, 24];

/// The teeth, sRGB (ivory), in the block of [`MOUTH_TEXELS`] texels beside the mouth's.
const TEETH_COLOUR: [u8; 3] = [222, 212, 192];

/// The teeth's bands ([`Openings::close`]), mm: how far behind the inner edge of a lip each
/// band's edge sits (and how far above the upper lip's edge, below the lower's), how far the
/// upper and the lower band reach into the mouth at most, and the fractions of the lips' gap
/// they take at most (the rest stays dark between them).
const TEETH_SETBACK: Real = 2.5;
const TEETH_TUCK: Real = 1.0;
const TEETH_REACH: [Real; 2] = [10.0, 7.0];
const TEETH_GAP_FRACTION: [Real; 2] = [0.4, 0.25];

fn boundary_loops(mesh: &TriangleMesh) -> Vec<Vec<u32>> {
    use std::collections::HashMap;
    let mut count: HashMap<(u32, u32), usize> = HashMap::new();
    let mut next: HashMap<u32, u32> = HashMap::new();
    for t in mesh.triangles() {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            *count.entry((a.min(b), a.max(b))).or_default() += 1;
        }
    }
    for t in mesh.triangles() {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            if count[&(a.min(b), a.max(b))] == 1 {
                // The opening runs against the triangle's own edge.
                next.insert(b, a);
            }
        }
    }
    let mut loops = Vec::new();
    let mut seen = std::collections::HashSet::new();
    let mut starts: Vec<u32> = next.keys().copied().collect();
    starts.sort_unstable();
    for start in starts {
        if seen.contains(&start) {
            continue;
        }
        let mut lp = vec![start];
        seen.insert(start);
        let mut at = next[&start];
        while at != start && seen.insert(at) {
            lp.push(at);
            match next.get(&at) {
                Some(&n) => at = n,
                None => break,
            }
        }
        loops.push(lp);
    }
    loops
}

impl Openings {
    fn of(neutral: &TriangleMesh) -> Self {
        let mut loops: Vec<Vec<u32>> = boundary_loops(neutral);
        // The longest loop is the mask's outer edge: it stays open.
        loops.sort_by_key(|l| std::cmp::Reverse(l.len()));
        let inner = loops.split_off(1);
        let loops = inner
            .into_iter()
            .map(|l| {
                let y = l.iter().map(|&v| neutral.positions()[v as usize].y).sum::<Real>() / l.len() as Real;
                // The eyes lie above the nose, the mouth below.
                (l, y <= 0.0)
            })
            .collect();
        Openings { loops }
    }

    /// The mesh with its openings closed: one centre vertex per opening (the loop's mean,
    /// moved back along `−z`), its texture coordinate the loop's mean; the mouth's fan takes
    /// the skin's mouth texels ([`MOUTH_TEXELS`]) instead, all over, and the mouth gets teeth
    /// ([`teeth`]).
    fn close(&self, mesh: &TriangleMesh, depth_scale: Real, skin_side: u32) -> Result<TriangleMesh> {
        let texture = mesh.texture().context("no texture coordinates")?;
        let mut positions = mesh.positions().to_vec();
        let mut triangles = mesh.triangles().to_vec();
        let mut uvs = texture.uvs.clone();
        let mut uv_triangles = texture.triangles.clone();
        // Each loop vertex's texture coordinate: from any triangle that uses it.
        let mut uv_of = vec![u32::MAX; positions.len()];
        for (t, u) in mesh.triangles().iter().zip(&texture.triangles) {
            for k in 0..3 {
                uv_of[t[k] as usize] = u[k];
            }
        }
        // The centre of the skins' mouth texels (`v` up from the image's bottom row).
        let mouth_uv = uvs.len() as u32;
        let corner = Real::from(MOUTH_TEXELS) / 2.0 / Real::from(skin_side);
        uvs.push(Point2::new(corner, 1.0 - corner));
        // The centre of the teeth's texels, beside the mouth's.
        let teeth_uv = uvs.len() as u32;
        uvs.push(Point2::new(3.0 * corner, 1.0 - corner));
        for (lp, mouth) in &self.loops {
            let depth = if *mouth { MOUTH_DEPTH } else { EYE_DEPTH };
            let n = lp.len() as Real;
            let centre = lp
                .iter()
                .map(|&v| positions[v as usize].coords)
                .sum::<Vector3<Real>>()
                / n;
            let c = positions.len() as u32;
            positions.push(Point3::from(centre - Vector3::z() * (depth * depth_scale)));
            // An eye's fan is textured by its loop, its centre by the loop's mean; the mouth's
            // takes the mouth's texels all over.
            let centre_uv = (!*mouth).then(|| {
                let mean = lp
                    .iter()
                    .map(|&v| uvs[uv_of[v as usize] as usize].coords)
                    .sum::<nalgebra::Vector2<Real>>()
                    / n;
                uvs.push(Point2::from(mean));
                uvs.len() as u32 - 1
            });
            for k in 0..lp.len() {
                let (a, b) = (lp[k], lp[(k + 1) % lp.len()]);
                triangles.push([a, b, c]);
                uv_triangles.push(match centre_uv {
                    Some(cu) => [uv_of[a as usize], uv_of[b as usize], cu],
                    None => [mouth_uv; 3],
                });
            }
            if *mouth {
                let loop_points: Vec<Point3<Real>> = lp.iter().map(|&v| positions[v as usize]).collect();
                for quad in teeth(&loop_points) {
                    let first = positions.len() as u32;
                    positions.extend(quad);
                    for t in [[0, 1, 2], [0, 2, 3]] {
                        triangles.push(t.map(|k| first + k));
                        uv_triangles.push([teeth_uv; 3]);
                    }
                }
            }
        }
        Ok(
            TriangleMesh::new(positions, triangles)?.with_texture(TextureCoordinates {
                uvs,
                triangles: uv_triangles,
            })?,
        )
    }
}

/// Teeth for a mouth whose inner lips run along `lips` (a closed loop, mm, `y` up, `z` to
/// the camera): quads (corners in order) of an upper band hanging from the upper lip and a
/// lower band rising from the lower one, each edge [`TEETH_SETBACK`] behind its lip's inner
/// edge and [`TEETH_TUCK`] beyond it (so the lip hides it), each reaching into the mouth
/// [`TEETH_GAP_FRACTION`] of the lips' gap at its place, [`TEETH_REACH`] at most. A closed
/// mouth (no gap) shows none: the bands stay behind the lips. A rough likeness of a mouth in a
/// photo (the upper teeth showing under the lip, the lower ones less), not of any anatomy.
fn teeth(lips: &[Point3<Real>]) -> Vec<[Point3<Real>; 4]> {
    let n = lips.len();
    if n < 4 {
        return Vec::new();
    }
    // The corners of the mouth: the loop's leftmost and rightmost points; the arc between them
    // that lies higher is the upper lip's.
    let by_x = |a: &usize, b: &usize| lips[*a].x.total_cmp(&lips[*b].x);
    let (Some(left), Some(right)) = ((0..n).min_by(by_x), (0..n).max_by(by_x)) else {
        return Vec::new();
    };
    let arc = |from: usize, to: usize| -> Vec<Point3<Real>> {
        let mut out = vec![lips[from]];
        let mut k = from;
        while k != to {
            k = (k + 1) % n;
            out.push(lips[k]);
        }
        out
    };
    let (one, other) = (arc(left, right), arc(right, left));
    let mean_y = |a: &[Point3<Real>]| a.iter().map(|p| p.y).sum::<Real>() / a.len() as Real;
    let (upper, lower) = if mean_y(&one) >= mean_y(&other) {
        (one, other)
    } else {
        (other, one)
    };
    // The height of an arc at `x`, linear between its points. Both arcs run from one corner to
    // the other, the loop's leftmost and rightmost points, so some segment spans every `x` of
    // the loop (the first point's height answers any other `x`).
    let height_at = |arc: &[Point3<Real>], x: Real| -> Real {
        arc.windows(2)
            .find_map(|w| {
                let (a, b) = (w[0], w[1]);
                let (lo, hi) = (a.x.min(b.x), a.x.max(b.x));
                (lo..=hi).contains(&x).then(|| {
                    let t = if hi > lo { (x - a.x) / (b.x - a.x) } else { 0.5 };
                    a.y + t * (b.y - a.y)
                })
            })
            .unwrap_or(arc[0].y)
    };
    let mut quads = Vec::new();
    for (band, (edge, facing)) in [(&upper, &lower), (&lower, &upper)].into_iter().enumerate() {
        // Into the mouth: down from the upper lip, up from the lower.
        let inward = if band == 0 { -1.0 } else { 1.0 };
        // Each point's band edge (top), tip and reach into the mouth.
        let strip: Vec<(Point3<Real>, Point3<Real>, Real)> = edge
            .iter()
            .map(|p| {
                let gap = (height_at(facing, p.x) - p.y).abs();
                let reach = (TEETH_GAP_FRACTION[band] * gap).min(TEETH_REACH[band]);
                let top = Point3::new(p.x, p.y - inward * TEETH_TUCK, p.z - TEETH_SETBACK);
                let tip = Point3::new(p.x, p.y + inward * reach, p.z - TEETH_SETBACK);
                (top, tip, reach)
            })
            .collect();
        // A quad whose two reaches sum to 0.2 mm or less is left out (a closed mouth's).
        for w in strip.windows(2) {
            let ((a, a_tip, a_reach), (b, b_tip, b_reach)) = (w[0], w[1]);
            if a_reach + b_reach > 0.2 {
                quads.push([a, b, b_tip, a_tip]);
            }
        }
    }
    quads
}

/// 2D thin-plate interpolation of offsets at `sites` (regularised by `lambda`).
struct ThinPlate2 {
    sites: Vec<Point2<Real>>,
    weights: DMatrix<Real>,
    affine: DMatrix<Real>,
}

impl ThinPlate2 {
    fn kernel(r2: Real) -> Real {
        if r2 <= 0.0 { 0.0 } else { 0.5 * r2 * r2.ln() }
    }

    fn fit(sites: &[Point2<Real>], offsets: &[nalgebra::Vector2<Real>], lambda: Real) -> Result<Self> {
        let n = sites.len();
        let mut a = DMatrix::<Real>::zeros(n + 3, n + 3);
        let mut b = DMatrix::<Real>::zeros(n + 3, 2);
        for i in 0..n {
            for j in 0..n {
                a[(i, j)] = Self::kernel((sites[i] - sites[j]).norm_squared());
            }
            a[(i, i)] += lambda;
            for (c, v) in [1.0, sites[i].x, sites[i].y].iter().enumerate() {
                a[(i, n + c)] = *v;
                a[(n + c, i)] = *v;
            }
            b[(i, 0)] = offsets[i].x;
            b[(i, 1)] = offsets[i].y;
        }
        let x = a.lu().solve(&b).context("thin plate: singular")?;
        Ok(ThinPlate2 {
            sites: sites.to_vec(),
            weights: x.rows(0, n).into_owned(),
            affine: x.rows(n, 3).into_owned(),
        })
    }

    fn at(&self, p: &Point2<Real>) -> nalgebra::Vector2<Real> {
        let mut out = nalgebra::Vector2::new(
            self.affine[(0, 0)] + self.affine[(1, 0)] * p.x + self.affine[(2, 0)] * p.y,
            self.affine[(0, 1)] + self.affine[(1, 1)] * p.x + self.affine[(2, 1)] * p.y,
        );
        for (k, s) in self.sites.iter().enumerate() {
            let u = Self::kernel((p - s).norm_squared());
            out.x += u * self.weights[(k, 0)];
            out.y += u * self.weights[(k, 1)];
        }
        out
    }
}

/// Projects a frontal photo onto the ICT mean face through their 68 landmarks: an affine
/// camera fitted to the landmarks off the jaw, then a thin-plate correction so that every
/// landmark lands on its photo point; the texture is drawn texel by texel in the mean face's
/// texture coordinates.
pub fn skin_from_photo(
    name: &str,
    photo: &image::RgbImage,
    photo_points: &[Point2<Real>],
    neutral: &TriangleMesh,
    landmarks: &[usize],
    size: u32,
) -> Result<Skin> {
    let x: Vec<Point3<Real>> = landmarks.iter().map(|&v| neutral.positions()[v]).collect();
    // Affine camera: u = A X + b over the points off the jaw.
    let used: Vec<usize> = (17..68).collect();
    let mut m = DMatrix::<Real>::zeros(used.len(), 4);
    let mut rhs = DMatrix::<Real>::zeros(used.len(), 2);
    for (r, &k) in used.iter().enumerate() {
        m[(r, 0)] = x[k].x;
        m[(r, 1)] = x[k].y;
        m[(r, 2)] = x[k].z;
        m[(r, 3)] = 1.0;
        rhs[(r, 0)] = photo_points[k].x;
        rhs[(r, 1)] = photo_points[k].y;
    }
    let camera = (m.transpose() * &m)
        .lu()
        .solve(&(m.transpose() * rhs))
        .context("affine camera")?;
    let project = |p: &Point3<Real>| {
        Point2::new(
            camera[(0, 0)] * p.x + camera[(1, 0)] * p.y + camera[(2, 0)] * p.z + camera[(3, 0)],
            camera[(0, 1)] * p.x + camera[(1, 1)] * p.y + camera[(2, 1)] * p.z + camera[(3, 1)],
        )
    };
    let sites: Vec<Point2<Real>> = x.iter().map(project).collect();
    let offsets: Vec<nalgebra::Vector2<Real>> = sites.iter().zip(photo_points).map(|(s, q)| q - s).collect();
    let scale = (sites[36] - sites[45]).norm();
    let warp = ThinPlate2::fit(
        &sites
            .iter()
            .map(|s| Point2::from(s.coords / scale))
            .collect::<Vec<_>>(),
        &offsets,
        1e-3,
    )?;
    let pixel_of: Vec<Point2<Real>> = neutral
        .positions()
        .iter()
        .map(|p| {
            let s = project(p);
            s + warp.at(&Point2::from(s.coords / scale))
        })
        .collect();
    let texture = neutral
        .texture()
        .context("the ICT mesh has no texture coordinates")?;
    let mut image = image::RgbImage::new(size, size);
    let mut filled = vec![false; (size * size) as usize];
    let s = size as Real;
    let sample = |q: Point2<Real>| -> [u8; 3] {
        let (w, h) = (photo.width() as Real, photo.height() as Real);
        let (x, y) = (q.x.clamp(0.0, w - 1.0), q.y.clamp(0.0, h - 1.0));
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let (xa, ya) = (x0 as u32, y0 as u32);
        let (xb, yb) = ((xa + 1).min(photo.width() - 1), (ya + 1).min(photo.height() - 1));
        let mut c = [0u8; 3];
        for (ch, o) in c.iter_mut().enumerate() {
            let v = |x: u32, y: u32| Real::from(photo.get_pixel(x, y)[ch]);
            let top = v(xa, ya) * (1.0 - fx) + v(xb, ya) * fx;
            let bottom = v(xa, yb) * (1.0 - fx) + v(xb, yb) * fx;
            *o = (top * (1.0 - fy) + bottom * fy).round().clamp(0.0, 255.0) as u8;
        }
        c
    };
    for (t, u) in neutral.triangles().iter().zip(&texture.triangles) {
        let corners = u.map(|k| {
            let uv = texture.uvs[k as usize];
            Point2::new(uv.x * s - 0.5, (1.0 - uv.y) * s - 0.5)
        });
        let pix = t.map(|v| pixel_of[v as usize]);
        // The texels the triangle's box covers, along one axis.
        let span = |axis: fn(&Point2<Real>) -> Real| {
            let lo = corners.iter().map(axis).fold(Real::INFINITY, Real::min);
            let hi = corners.iter().map(axis).fold(Real::NEG_INFINITY, Real::max);
            (lo.floor().max(0.0) as u32, hi.ceil().min(s - 1.0) as u32)
        };
        let (lo_x, hi_x) = span(|c| c.x);
        let (lo_y, hi_y) = span(|c| c.y);
        let [a, b, c] = corners;
        let area = (b.x - a.x) * (c.y - a.y) - (c.x - a.x) * (b.y - a.y);
        if area.abs() < 1e-12 {
            continue;
        }
        for ty in lo_y..=hi_y {
            for tx in lo_x..=hi_x {
                let p = Point2::new(tx as Real, ty as Real);
                let wa = ((b.x - p.x) * (c.y - p.y) - (c.x - p.x) * (b.y - p.y)) / area;
                let wb = ((c.x - p.x) * (a.y - p.y) - (a.x - p.x) * (c.y - p.y)) / area;
                let wc = 1.0 - wa - wb;
                // Half a texel of slack so that seams are covered.
                let slack = -1.0 / (area.abs().sqrt() + 1.0);
                if wa < slack || wb < slack || wc < slack {
                    continue;
                }
                let q = Point2::from(wa * pix[0].coords + wb * pix[1].coords + wc * pix[2].coords);
                image.put_pixel(tx, ty, image::Rgb(sample(q)));
                filled[(ty * size + tx) as usize] = true;
            }
        }
    }
    // Texels no triangle covers: the mean colour of those that are (they are seldom sampled).
    let (mut sum, mut n) = ([0u64; 3], 0u64);
    for (k, p) in image.pixels().enumerate() {
        if filled[k] {
            for c in 0..3 {
                sum[c] += u64::from(p[c]);
            }
            n += 1;
        }
    }
    let mean = image::Rgb(sum.map(|v| (v / n.max(1)) as u8));
    for (k, p) in image.pixels_mut().enumerate() {
        if !filled[k] {
            *p = mean;
        }
    }
    // The inside of the mouth and the teeth ([`Openings::close`]), in a corner no triangle
    // covers.
    for ty in 0..MOUTH_TEXELS {
        for tx in 0..2 * MOUTH_TEXELS {
            if filled[(ty * size + tx) as usize] {
                bail!("the skin's corner texels, kept for the inside of the mouth, are covered");
            }
            let colour = if tx < MOUTH_TEXELS {
                MOUTH_COLOUR
            } else {
                TEETH_COLOUR
            };
            image.put_pixel(tx, ty, image::Rgb(colour));
        }
    }
    Ok(Skin {
        name: name.to_owned(),
        colour: ColourMap::new(&image),
        image,
    })
}

/// The skins: each source photo's subject face (or, for a collage, the given box's face),
/// landmarked by dlib's model and projected onto the mean face.
///
/// The faces are found by the full search ([`splineface::detect::detect_faces`]), not the
/// reconstruction's coarse-first one: the subjects are the evaluation's fixed ground, and must
/// not change when the photo path under test does (they did once, with the coarse search).
pub fn skins(sources: &[(String, image::RgbImage)], model: &ShapePredictor, ict: &Ict) -> Result<Vec<Skin>> {
    sources
        .iter()
        .map(|(name, photo)| {
            let faces =
                splineface::detect::detect_faces(&image::DynamicImage::ImageRgb8(photo.clone()).to_luma8());
            let found = splineface::detect::subject_face(&faces)
                .map_err(|e| anyhow::Error::msg(e.to_string()))
                .and_then(|(face, _)| {
                    splineface::detect::landmark_face(model, photo, face).map_err(anyhow::Error::msg)
                })
                .with_context(|| format!("skin source {name}"))?;
            skin_from_photo(name, photo, &found.ibug, &ict.neutral, &ict.landmarks, 1024)
        })
        .collect()
}

/// An ICT identity (weights ~ N(0, 1) on every mode, seeded) in millimetres, wearing `skin`.
pub fn ict_subject(ict: &Ict, index: usize, seed: u64, skin: &Skin) -> Result<Subject> {
    ict_face(ict, format!("ict-{index}"), &ict_weights(ict, index, seed), skin)
}

/// The identity weights of [`ict_subject`] `index`.
pub fn ict_weights(ict: &Ict, index: usize, seed: u64) -> Vec<Real> {
    let mut rng = Lcg(seed.wrapping_mul(0x9E37_79B9).wrapping_add(index as u64 + 1));
    (0..ict.modes).map(|_| rng.gaussian()).collect()
}

/// The ICT face with identity weights `weights` in millimetres, wearing `skin`.
pub fn ict_face(ict: &Ict, name: String, weights: &[Real], skin: &Skin) -> Result<Subject> {
    ict_face_with_expression(ict, name, weights, &[], skin)
}

/// [`ict_subject`] `index` photographed with an expression (blendshape names and weights):
/// the camera sees the expression, the truth is the neutral identity.
pub fn ict_subject_with_expression(
    ict: &Ict,
    index: usize,
    seed: u64,
    expression: (&str, &[(&str, Real)]),
    skin: &Skin,
) -> Result<Subject> {
    let neutral = ict_subject(ict, index, seed, skin)?;
    let weights = ict_weights(ict, index, seed);
    let posed = ict_face_with_expression(
        ict,
        format!("ict-{index}-{}", expression.0),
        &weights,
        expression.1,
        skin,
    )?;
    // The truth is neutral; the 68 points (projected into the photos' records) are those of
    // the face the camera sees.
    Ok(Subject {
        truth: neutral.truth,
        structure: neutral.structure,
        ..posed
    })
}

/// The ICT face with identity weights `weights` and an expression in millimetres, wearing
/// `skin`.
fn ict_face_with_expression(
    ict: &Ict,
    name: String,
    weights: &[Real],
    expression: &[(&str, Real)],
    skin: &Skin,
) -> Result<Subject> {
    let positions: Vec<Point3<Real>> = ict
        .positions_with_expression(weights, expression)?
        .iter()
        .map(|p| p * 10.0)
        .collect();
    let truth = TriangleMesh::new(positions, ict.neutral.triangles().to_vec())?;
    let textured = truth
        .clone()
        .with_texture(ict.neutral.texture().context("ICT texture coordinates")?.clone())?;
    let mesh = Openings::of(&ict.neutral).close(&textured, 10.0, skin.image.width())?;
    let ibug: Vec<Point3<Real>> = ict.landmarks.iter().map(|&v| truth.positions()[v]).collect();
    let structure = from_ibug68(&ibug)?;
    Ok(Subject {
        name,
        target: face_target(&structure),
        mesh,
        colour: skin.colour.clone(),
        truth,
        structure,
        ibug,
    })
}
