//! Dense refinement: the face-space fit carried past the landmarks by the photos' pixels.
//!
//! The landmark fit ([`FaceSpace::fit_photos`]) sees 40 points per photo; the shape between
//! them is the space's prior. [`FaceSpace::refine_photos`] adds what the photos themselves
//! say: the surface is sampled over the face region, every sample is projected into every
//! photo that sees it, and the identity weights and cameras move until the photos agree with
//! each other about what lies at each sample (photo-consistency), while the landmarks and the
//! prior still hold.
//!
//! # The objective
//!
//! ```text
//! E(w, cameras) = Σᵢⱼ ωⱼ ‖πᵢ(Sⱼ(w) + Eⱼ eᵢ) − xᵢⱼ‖² / (uᵢ ε)²                  landmarks
//!               + β Σₛ Σᵢ cᵢₛ ρ(Nᵢ(πᵢ(Fₛ(w) + Gₛ eᵢ)) − μₛ) / σ²                consistency
//!               + Σₖ wₖ² / σₖ²  +  Σᵢ κᵢ² / σ_κ²                               priors
//! ```
//!
//! * `πᵢ` is photo `i`'s camera: `x = o + s · (P R X) / (1 − κ (R X)_z)`, the scaled
//!   orthographic camera of the landmark fit with a perspective term `κ = 1/d` (`d` the
//!   camera's distance, canonical units): near cameras magnify the nose.
//! * `Nᵢ` is photo `i`'s grey image, **locally normalised** (its local mean removed and divided
//!   by its local deviation over a window of [`NORMALISATION_EYES`] eye distances): shading
//!   that varies smoothly across the face (light from another side in each photo) cancels;
//!   texture and edges (eyes, brows, nostrils, lips, skin detail) remain. This is the choice
//!   the method leaves open (normalised cross-correlation of patches, or colour after a gain
//!   and bias): it is the cross-correlation's per-pixel form, cheap and with an exact
//!   Jacobian (the normalised image's gradient). A per-photo gain and bias alone cannot
//!   follow a light that moves between photos.
//! * `μₛ` is the weighted mean over the views that see sample `s` (the unknown albedo,
//!   eliminated exactly: the Jacobian of each residual has the views' mean Jacobian taken
//!   off); `cᵢₛ` is how squarely photo `i` sees the sample (0 when it faces away or lies behind
//!   another part of the face: a depth test against the samples themselves in that view);
//!   `ρ` a Cauchy loss (shadows, highlights and hair disagree for reasons other than shape).
//! * `Fₛ(w)`, `Sⱼ(w)` are the space's surface at sample `s` and its structure point `j`;
//!   `Gₛ`, `Eⱼ` the photo's expression (fixed at the landmark fit's).
//!
//! Gauss-Newton with Levenberg–Marquardt damping, coarse to fine over image scales
//! ([`RefineOptions::levels`]): at each level the photos are cropped about the face and
//! resampled to the level's eye distance in pixels, so that the surface samples and the
//! pixels keep the same ratio whatever the photos' sizes.
//!
//! # When the photos do not agree
//!
//! The result is kept only when the photos agree better on the refined face than on the
//! landmark fit's (their disagreement at the finest level falls by
//! [`RefineOptions::min_gain`] or more) and the landmarks still fit (their RMS grows by at
//! most [`RefineOptions::landmark_slack`] units); otherwise the landmark result stands and
//! [`Refinement::accepted`] says why not.

use nalgebra::{DMatrix, DVector, Matrix2x3, Point2, Point3, Rotation3, Vector2, Vector3};
use rayon::prelude::*;

use super::FaceError;
use super::space::{FaceSpace, PhotoSpaceFit};
use crate::Real;
use crate::align::GreyImage;
use crate::bspline::SurfaceSpace;
use crate::reference::ReferenceFace;
use crate::structure::POINT_COUNT;

/// The local normalisation's window (Gaussian deviation), in eye distances.
pub const NORMALISATION_EYES: Real = 0.12;

/// Options of [`FaceSpace::refine_photos`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RefineOptions {
    /// The number of levels, coarse to fine; each halves the previous one's eye distance in
    /// pixels and doubles its samples' spacing.
    pub levels: usize,
    /// The finest level's eye distance in pixels (a photo with fewer is seen at its own size).
    pub eye_pixels: Real,
    /// The finest level's spacing of the surface samples, canonical units (50 between the eye
    /// centres).
    pub spacing: Real,
    /// Gauss-Newton iterations per level at most.
    pub iterations: usize,
    /// `σ`: the spread of a normalised intensity between photos that agree.
    pub sigma: Real,
    /// `β`: the weight of one consistency residual against one landmark coordinate (the
    /// samples are not independent: neighbours see overlapping pixels).
    pub beta: Real,
    /// `ε`, the landmarks' error per coordinate (canonical units), as in
    /// [`super::PhotoFitOptions::noise`].
    pub noise: Real,
    /// Refine each photo's perspective `κ` (else the cameras stay scaled orthographic).
    pub perspective: bool,
    /// The smallest relative fall of the disagreement for which the refinement is kept.
    pub min_gain: Real,
    /// How far the landmarks' weighted RMS may grow (canonical units) for the refinement to be
    /// kept.
    pub landmark_slack: Real,
}

impl Default for RefineOptions {
    fn default() -> Self {
        RefineOptions {
            levels: 3,
            eye_pixels: 80.0,
            spacing: 2.0,
            iterations: 8,
            sigma: 0.5,
            beta: 0.1,
            noise: 4.0,
            perspective: true,
            min_gain: 0.02,
            landmark_slack: 0.5,
        }
    }
}

/// One photo as [`FaceSpace::refine_photos`] takes it.
#[derive(Debug, Clone, Copy)]
pub struct RefineView<'a> {
    /// The grey image (`y` down).
    pub image: &'a GreyImage,
    /// Its 40 points, `y` up ([`crate::align::PhotoPoints::y_up`]).
    pub points: &'a [Point2<Real>],
}

/// A photo's camera after refinement: `x = offset + scale · (P R X) / (1 − κ (R X)_z)`, `y`
/// up, in the photo's pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RefinedCamera {
    /// `R`.
    pub rotation: Rotation3<Real>,
    /// `s`, pixels per canonical unit.
    pub scale: Real,
    /// `o`, pixels (`y` up).
    pub offset: Vector2<Real>,
    /// `κ`, per canonical unit: the inverse of the camera's distance (0: orthographic).
    pub perspective: Real,
}

impl RefinedCamera {
    /// Where the camera sees `x` (`y` up), with the derivative of that place in the camera
    /// frame's point `q = R x`; `None` behind the camera (or too near it).
    fn project(&self, x: &Point3<Real>) -> Option<(Vector3<Real>, Point2<Real>, Matrix2x3<Real>)> {
        let q = self.rotation * x.coords;
        let den = 1.0 - self.perspective * q.z;
        if den < 0.2 {
            return None;
        }
        let f = self.scale / den;
        let p = Point2::new(self.offset.x + f * q.x, self.offset.y + f * q.y);
        let g = f * self.perspective / den;
        let dq = Matrix2x3::new(f, 0.0, g * q.x, 0.0, f, g * q.y);
        Some((q, p, dq))
    }

    /// The camera moved by a step `[δ (3), log-scale, offset (2), κ]`.
    fn moved(&self, step: &[Real]) -> Self {
        RefinedCamera {
            rotation: Rotation3::new(Vector3::new(step[0], step[1], step[2])) * self.rotation,
            scale: self.scale * step[3].exp(),
            offset: self.offset + Vector2::new(step[4], step[5]),
            perspective: (self.perspective + step[6]).max(0.0),
        }
    }
}

/// Unknowns per photo: rotation (3), log-scale, offset (2), perspective.
const CAMERA: usize = 7;

/// What [`FaceSpace::refine_photos`] found.
#[derive(Debug, Clone, PartialEq)]
pub struct Refinement {
    /// The identity weights: the refined ones when [`Refinement::accepted`], else the landmark
    /// fit's.
    pub weights: Vec<Real>,
    /// The refined cameras, one per photo (the landmark fit's when not accepted).
    pub cameras: Vec<RefinedCamera>,
    /// The photos' disagreement (weighted RMS of the normalised intensities about each
    /// sample's mean) on the landmark fit's face and on the refined one, finest level.
    pub disagreement: (Real, Real),
    /// The landmarks' weighted RMS (canonical units) before and after.
    pub landmark_rms: (Real, Real),
    /// Per photo: the fraction of the face's samples it sees, finest level.
    pub coverage: Vec<Real>,
    /// Samples at the finest level, and those seen by two photos or more.
    pub samples: (usize, usize),
    /// Gauss-Newton iterations run over all levels.
    pub iterations: usize,
    /// Whether the refinement was kept.
    pub accepted: bool,
    /// Why, in words.
    pub note: String,
}

/// A photo at one level: the face's crop, resampled, locally normalised, with its gradient.
struct LevelImage {
    width: usize,
    height: usize,
    /// The crop's pixel `(c, r)` is the photo's pixel `origin + (c, r) / factor` (`y` down).
    origin: Vector2<Real>,
    factor: Real,
    normalised: Vec<f32>,
    gx: Vec<f32>,
    gy: Vec<f32>,
}

impl LevelImage {
    /// The photo's crop about `box_` (`[x0, y0, x1, y1]` in its pixels, `y` down) at `factor`
    /// crop pixels per photo pixel (at most 1), normalised over `window` crop pixels.
    fn new(image: &GreyImage, box_: [Real; 4], factor: Real, window: Real) -> Self {
        let origin = Vector2::new(box_[0], box_[1]);
        let width = (((box_[2] - box_[0]) * factor).ceil() as usize).max(8);
        let height = (((box_[3] - box_[1]) * factor).ceil() as usize).max(8);
        // Area sampling: the mean of k × k bilinear samples over each crop pixel's footprint.
        let k = (1.0 / factor).ceil().max(1.0) as usize;
        let values = image.data();
        let mut crop = vec![0.0f32; width * height];
        crop.par_chunks_mut(width).enumerate().for_each(|(r, row)| {
            for (c, out) in row.iter_mut().enumerate() {
                let mut sum = 0.0;
                for a in 0..k {
                    for b in 0..k {
                        let x = origin.x + (c as Real + (b as Real + 0.5) / k as Real - 0.5) / factor;
                        let y = origin.y + (r as Real + (a as Real + 0.5) / k as Real - 0.5) / factor;
                        sum += image.sample(values, x, y);
                    }
                }
                *out = sum / (k * k) as f32;
            }
        });
        let crop = blur(&crop, width, height, 0.7);
        let mean = blur(&crop, width, height, window);
        let centred: Vec<f32> = crop.iter().zip(&mean).map(|(v, m)| v - m).collect();
        let squares: Vec<f32> = centred.iter().map(|v| v * v).collect();
        let variance = blur(&squares, width, height, window);
        // A floor on the deviation: flat skin is not amplified into noise.
        let normalised: Vec<f32> = centred
            .iter()
            .zip(&variance)
            .map(|(v, s)| v / (s + 0.02f32 * 0.02).sqrt())
            .collect();
        let mut gx = vec![0.0f32; width * height];
        let mut gy = vec![0.0f32; width * height];
        for r in 0..height {
            for c in 0..width {
                let (c0, c1) = (c.saturating_sub(1), (c + 1).min(width - 1));
                let (r0, r1) = (r.saturating_sub(1), (r + 1).min(height - 1));
                gx[r * width + c] =
                    (normalised[r * width + c1] - normalised[r * width + c0]) / (c1 - c0).max(1) as f32;
                gy[r * width + c] =
                    (normalised[r1 * width + c] - normalised[r0 * width + c]) / (r1 - r0).max(1) as f32;
            }
        }
        LevelImage {
            width,
            height,
            origin,
            factor,
            normalised,
            gx,
            gy,
        }
    }

    /// The crop's coordinates of a photo point given `y` up.
    fn crop_of(&self, p: &Point2<Real>) -> Vector2<Real> {
        Vector2::new(
            (p.x - self.origin.x) * self.factor,
            (-p.y - self.origin.y) * self.factor,
        )
    }

    /// The normalised intensity and its gradient in the photo's `y`-up pixels at a crop place;
    /// `None` outside the crop.
    fn sample(&self, at: &Vector2<Real>) -> Option<(Real, Vector2<Real>)> {
        let (x, y) = (at.x, at.y);
        if !(x >= 0.0 && y >= 0.0 && x <= (self.width - 1) as Real && y <= (self.height - 1) as Real) {
            return None;
        }
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(self.width - 1), (y0 + 1).min(self.height - 1));
        let (fx, fy) = (x - x0 as Real, y - y0 as Real);
        let at = |v: &[f32]| {
            let w = self.width;
            let top = Real::from(v[y0 * w + x0]) * (1.0 - fx) + Real::from(v[y0 * w + x1]) * fx;
            let bottom = Real::from(v[y1 * w + x0]) * (1.0 - fx) + Real::from(v[y1 * w + x1]) * fx;
            top * (1.0 - fy) + bottom * fy
        };
        // d(crop)/d(photo, y up) = factor · diag(1, −1).
        let g = Vector2::new(at(&self.gx) * self.factor, -at(&self.gy) * self.factor);
        Some((at(&self.normalised), g))
    }
}

/// A separable Gaussian blur of deviation `sigma` pixels (borders clamped).
fn blur(values: &[f32], width: usize, height: usize, sigma: Real) -> Vec<f32> {
    let radius = (3.0 * sigma).ceil() as isize;
    let kernel: Vec<f32> = (-radius..=radius)
        .map(|d| (-(d * d) as Real / (2.0 * sigma * sigma)).exp() as f32)
        .collect();
    let total: f32 = kernel.iter().sum();
    let kernel: Vec<f32> = kernel.iter().map(|k| k / total).collect();
    let pass = |input: &[f32], along_rows: bool| {
        let mut out = vec![0.0f32; width * height];
        out.par_chunks_mut(width).enumerate().for_each(|(r, row)| {
            for (c, o) in row.iter_mut().enumerate() {
                let mut sum = 0.0;
                for (t, k) in kernel.iter().enumerate() {
                    let d = t as isize - radius;
                    let (cc, rr) = if along_rows {
                        ((c as isize + d).clamp(0, width as isize - 1) as usize, r)
                    } else {
                        (c, (r as isize + d).clamp(0, height as isize - 1) as usize)
                    };
                    sum += k * input[rr * width + cc];
                }
                *o = sum;
            }
        });
        out
    };
    pass(&pass(values, true), false)
}

/// The surface samples of one level: the identity space's points and modes there, each
/// photo's expression displacement, and the mean face's normals.
struct Samples {
    base: Vec<Point3<Real>>,
    /// `modes[s][k]`.
    modes: Vec<Vec<Vector3<Real>>>,
    /// `expression[i][s]`.
    expression: Vec<Vec<Vector3<Real>>>,
    normals: Vec<Vector3<Real>>,
    /// The samples' spacing, canonical units.
    spacing: Real,
}

impl Samples {
    fn new(
        space: &FaceSpace,
        reference: &ReferenceFace,
        expressions: &[Vec<Real>],
        spacing: Real,
    ) -> Result<Self, FaceError> {
        let frame = reference.frame();
        let mut params = Vec::new();
        let (x0, x1) = (frame.x[0].min(frame.x[1]), frame.x[0].max(frame.x[1]));
        let (y0, y1) = (frame.y[0].min(frame.y[1]), frame.y[0].max(frame.y[1]));
        let mut y = y0 + spacing / 2.0;
        while y < y1 {
            let mut x = x0 + spacing / 2.0;
            while x < x1 {
                let q = frame.parameters(x, y);
                if (0.0..=1.0).contains(&q.x)
                    && (0.0..=1.0).contains(&q.y)
                    && reference.in_face_region(q.x, q.y)
                {
                    params.push([q.x, q.y]);
                }
                x += spacing;
            }
            y += spacing;
        }
        let surfaces = space.surfaces();
        let sampled = surfaces.sample(&params)?;
        let modes = (0..params.len())
            .map(|s| sampled.modes.iter().map(|m| m[s]).collect())
            .collect();
        let expression_space = SurfaceSpace::new(surfaces.base().clone(), space.expressions().grid.clone())?;
        let expression_samples = expression_space.sample(&params)?;
        let expression = expressions
            .iter()
            .map(|e| {
                let mut d = vec![Vector3::zeros(); params.len()];
                for (weight, mode) in e.iter().zip(&expression_samples.modes) {
                    if *weight != 0.0 {
                        for (d, m) in d.iter_mut().zip(mode) {
                            *d += m * *weight;
                        }
                    }
                }
                d
            })
            .collect();
        let base_surface = surfaces.base();
        let normals = params
            .iter()
            .map(|&[u, v]| {
                Ok(base_surface
                    .normal(u, v)?
                    .map(|n| n.into_inner())
                    .unwrap_or_else(Vector3::z))
            })
            .collect::<Result<Vec<_>, FaceError>>()?;
        // The grid's normals point toward the viewer of the canonical frame (+z).
        let normals = normals
            .into_iter()
            .map(|n: Vector3<Real>| if n.z < 0.0 { -n } else { n })
            .collect();
        Ok(Samples {
            base: sampled.base,
            modes,
            expression,
            normals,
            spacing,
        })
    }

    fn len(&self) -> usize {
        self.base.len()
    }

    /// Sample `s` of photo `i` with identity `w`.
    fn point(&self, s: usize, i: usize, w: &[Real]) -> Point3<Real> {
        let mut p = self.base[s];
        for (d, wk) in self.modes[s].iter().zip(w) {
            p += d * *wk;
        }
        if let Some(e) = self.expression.get(i) {
            p += e[s];
        }
        p
    }
}

/// What the landmarks contribute: the space's structure modes and each photo's expression.
struct Landmarks<'a> {
    base: Vec<Point3<Real>>,
    /// `modes[j][k]`.
    modes: Vec<Vec<Vector3<Real>>>,
    expression: Vec<Vec<Vector3<Real>>>,
    views: &'a [RefineView<'a>],
    point_weights: &'a [Real; POINT_COUNT],
    /// Per photo: the fixed unit `uᵢ` (its starting scale).
    units: Vec<Real>,
}

/// The state the refinement moves.
#[derive(Clone)]
struct State {
    weights: Vec<Real>,
    cameras: Vec<RefinedCamera>,
}

/// One photo's view of one sample, linearised.
struct Seen {
    photo: usize,
    weight: Real,
    value: Real,
    /// `∂N/∂w` and `∂N/∂camera`.
    d_weights: Vec<Real>,
    d_camera: [Real; CAMERA],
}

/// The problem at one level.
struct Level<'a> {
    images: Vec<LevelImage>,
    samples: Samples,
    landmarks: &'a Landmarks<'a>,
    sigma_prior: &'a [Real],
    options: &'a RefineOptions,
}

/// Cauchy weight of a residual of scale `c`.
fn cauchy(r: Real, c: Real) -> Real {
    1.0 / (1.0 + (r / c) * (r / c))
}

impl Level<'_> {
    /// Which photos see which samples under `state`: per photo, a weight per sample (how
    /// squarely it is seen, 0 when facing away or hidden).
    fn visibility(&self, state: &State) -> Vec<Vec<Real>> {
        state
            .cameras
            .par_iter()
            .enumerate()
            .map(|(i, camera)| {
                let image = &self.images[i];
                let n = self.samples.len();
                let mut seen = vec![0.0; n];
                let mut places = Vec::with_capacity(n);
                for (s, item) in seen.iter_mut().enumerate() {
                    let x = self.samples.point(s, i, &state.weights);
                    let Some((q, p, _)) = camera.project(&x) else {
                        places.push(None);
                        continue;
                    };
                    let normal = camera.rotation * self.samples.normals[s];
                    let towards = Vector3::new(
                        -camera.perspective * q.x,
                        -camera.perspective * q.y,
                        1.0 - camera.perspective * q.z,
                    )
                    .normalize();
                    let facing = normal.dot(&towards);
                    *item = ((facing - 0.15) / 0.35).clamp(0.0, 1.0);
                    places.push(Some((image.crop_of(&p), q.z)));
                }
                // The depth test: a grid of cells about twice the samples' spacing in the crop;
                // a sample more than two spacings behind the front-most in its cell is hidden.
                let cell = (2.0 * self.samples.spacing * camera.scale * image.factor).max(1.0);
                let (cw, ch) = (
                    (image.width as Real / cell).ceil() as usize + 1,
                    (image.height as Real / cell).ceil() as usize + 1,
                );
                let mut front = vec![Real::NEG_INFINITY; cw * ch];
                let index = |c: &Vector2<Real>| -> Option<usize> {
                    let (a, b) = ((c.x / cell).floor(), (c.y / cell).floor());
                    (a >= 0.0 && b >= 0.0 && (a as usize) < cw && (b as usize) < ch)
                        .then(|| b as usize * cw + a as usize)
                };
                for (place, w) in places.iter().zip(&seen) {
                    if let (Some((c, z)), true) = (place, *w > 0.0)
                        && let Some(k) = index(c)
                    {
                        front[k] = front[k].max(*z);
                    }
                }
                for (place, w) in places.iter().zip(seen.iter_mut()) {
                    match place {
                        Some((c, z)) => match index(c) {
                            Some(k) if *z >= front[k] - 2.0 * self.samples.spacing => {}
                            _ => *w = 0.0,
                        },
                        None => *w = 0.0,
                    }
                }
                seen
            })
            .collect()
    }

    /// Sample `s` seen by the photos with weights `visibility`, linearised (with derivatives
    /// when `derivatives`).
    fn seen(&self, state: &State, visibility: &[Vec<Real>], s: usize, derivatives: bool) -> Vec<Seen> {
        let k = state.weights.len();
        let mut out = Vec::new();
        for (i, camera) in state.cameras.iter().enumerate() {
            let c = visibility[i][s];
            if c <= 0.0 {
                continue;
            }
            let x = self.samples.point(s, i, &state.weights);
            let Some((q, p, dq)) = camera.project(&x) else {
                continue;
            };
            let image = &self.images[i];
            let Some((value, grad)) = image.sample(&image.crop_of(&p)) else {
                continue;
            };
            let mut d_weights = Vec::new();
            let mut d_camera = [0.0; CAMERA];
            if derivatives {
                // ∂N/∂q = ∇N · ∂p/∂q; ∂q/∂x = R.
                let dn_dq = dq.transpose() * grad;
                let dn_dx = camera.rotation.matrix().transpose() * dn_dq;
                d_weights = (0..k).map(|m| dn_dx.dot(&self.samples.modes[s][m])).collect();
                let rotation = q.cross(&dn_dq); // ∂q/∂δ = −[q]×: ∇·(−q × ·) = (q × ∇)
                let f = camera.scale / (1.0 - camera.perspective * q.z);
                let pq = Vector2::new(f * q.x, f * q.y);
                let d_kappa = Vector2::new(q.x, q.y) * (f * q.z / (1.0 - camera.perspective * q.z));
                d_camera = [
                    rotation.x,
                    rotation.y,
                    rotation.z,
                    grad.dot(&pq),
                    grad.x,
                    grad.y,
                    grad.dot(&d_kappa),
                ];
            }
            out.push(Seen {
                photo: i,
                weight: c,
                value,
                d_weights,
                d_camera,
            });
        }
        out
    }

    /// The consistency's weighted sum of squares (robust weights as given, or plain) and
    /// the summed weights.
    fn disagreement(&self, state: &State, visibility: &[Vec<Real>]) -> (Real, Real, usize) {
        let per: Vec<(Real, Real, usize)> = (0..self.samples.len())
            .into_par_iter()
            .map(|s| {
                let seen = self.seen(state, visibility, s, false);
                if seen.len() < 2 {
                    return (0.0, 0.0, 0);
                }
                let total: Real = seen.iter().map(|v| v.weight).sum();
                let mean = seen.iter().map(|v| v.weight * v.value).sum::<Real>() / total;
                let sum = seen
                    .iter()
                    .map(|v| v.weight * (v.value - mean).powi(2))
                    .sum::<Real>();
                (sum, total, 1)
            })
            .collect();
        per.iter()
            .fold((0.0, 0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1, a.2 + b.2))
    }

    /// The robust consistency cost.
    fn consistency_cost(&self, state: &State, visibility: &[Vec<Real>]) -> Real {
        let c = 2.0 * self.options.sigma;
        (0..self.samples.len())
            .into_par_iter()
            .map(|s| {
                let seen = self.seen(state, visibility, s, false);
                if seen.len() < 2 {
                    return 0.0;
                }
                let total: Real = seen.iter().map(|v| v.weight).sum();
                let mean = seen.iter().map(|v| v.weight * v.value).sum::<Real>() / total;
                seen.iter()
                    .map(|v| v.weight * c * c * (1.0 + ((v.value - mean) / c).powi(2)).ln())
                    .sum::<Real>()
            })
            .sum::<Real>()
            * self.options.beta
            / (self.options.sigma * self.options.sigma)
    }

    /// The whole cost.
    fn cost(&self, state: &State, visibility: &[Vec<Real>]) -> Real {
        self.consistency_cost(state, visibility)
            + self.landmarks.cost(state, self.options)
            + self.prior(state)
    }

    fn prior(&self, state: &State) -> Real {
        let identity: Real = state
            .weights
            .iter()
            .zip(self.sigma_prior)
            .map(|(w, s)| (w / s).powi(2))
            .sum();
        identity
            + state
                .cameras
                .iter()
                .map(|c| (c.perspective / KAPPA_SIGMA).powi(2))
                .sum::<Real>()
    }

    /// The Gauss-Newton normal equations `(H, g)` at `state` (cost's half-Hessian and half-
    /// gradient).
    fn normal_equations(&self, state: &State, visibility: &[Vec<Real>]) -> (DMatrix<Real>, DVector<Real>) {
        let k = state.weights.len();
        let n = k + CAMERA * state.cameras.len();
        let scale = self.options.beta / (self.options.sigma * self.options.sigma);
        let c = 2.0 * self.options.sigma;
        let (mut h, mut g) = (0..self.samples.len())
            .into_par_iter()
            .fold(
                || (DMatrix::<Real>::zeros(n, n), DVector::<Real>::zeros(n)),
                |(mut h, mut g), s| {
                    let seen = self.seen(state, visibility, s, true);
                    if seen.len() < 2 {
                        return (h, g);
                    }
                    let total: Real = seen.iter().map(|v| v.weight).sum();
                    let mean = seen.iter().map(|v| v.weight * v.value).sum::<Real>() / total;
                    // The views' mean Jacobian, taken off each view's (the albedo eliminated).
                    let mut mean_row = DVector::<Real>::zeros(n);
                    for v in &seen {
                        let a = v.weight / total;
                        for m in 0..k {
                            mean_row[m] += a * v.d_weights[m];
                        }
                        for (t, d) in v.d_camera.iter().enumerate() {
                            mean_row[k + CAMERA * v.photo + t] += a * d;
                        }
                    }
                    for v in &seen {
                        let r = v.value - mean;
                        let weight = scale * v.weight * cauchy(r, c);
                        let mut row = -mean_row.clone();
                        for m in 0..k {
                            row[m] += v.d_weights[m];
                        }
                        for (t, d) in v.d_camera.iter().enumerate() {
                            row[k + CAMERA * v.photo + t] += d;
                        }
                        h.ger(weight, &row, &row, 1.0);
                        g.axpy(weight * r, &row, 1.0);
                    }
                    (h, g)
                },
            )
            .reduce(
                || (DMatrix::<Real>::zeros(n, n), DVector::<Real>::zeros(n)),
                |(h1, g1), (h2, g2)| (h1 + h2, g1 + g2),
            );
        self.landmarks
            .normal_equations(state, self.options, &mut h, &mut g);
        for (m, s) in self.sigma_prior.iter().enumerate() {
            h[(m, m)] += 1.0 / (s * s);
            g[m] += state.weights[m] / (s * s);
        }
        for (i, camera) in state.cameras.iter().enumerate() {
            let t = k + CAMERA * i + 6;
            h[(t, t)] += 1.0 / (KAPPA_SIGMA * KAPPA_SIGMA);
            g[t] += camera.perspective / (KAPPA_SIGMA * KAPPA_SIGMA);
        }
        (h, g)
    }
}

/// The prior deviation of `κ`, per canonical unit: cameras nearer than about 150 units
/// (20 cm) are implausible.
const KAPPA_SIGMA: Real = 1.0 / 300.0;

impl Landmarks<'_> {
    fn residuals(
        &self,
        state: &State,
        i: usize,
    ) -> Vec<Option<(Vector2<Real>, Vector3<Real>, Matrix2x3<Real>)>> {
        let camera = &state.cameras[i];
        (0..POINT_COUNT)
            .map(|j| {
                let mut x = self.base[j];
                for (d, w) in self.modes[j].iter().zip(&state.weights) {
                    x += d * *w;
                }
                if let Some(e) = self.expression.get(i) {
                    x += e[j];
                }
                camera.project(&x).map(|(q, p, dq)| {
                    (
                        (p - self.views[i].points[j]) / self.units[i],
                        q,
                        dq / self.units[i],
                    )
                })
            })
            .collect()
    }

    fn cost(&self, state: &State, options: &RefineOptions) -> Real {
        let mut sum = 0.0;
        for i in 0..state.cameras.len() {
            for (r, w) in self.residuals(state, i).iter().zip(self.point_weights) {
                sum += w * r.map_or(1e6, |(r, _, _)| r.norm_squared());
            }
        }
        sum / (options.noise * options.noise)
    }

    /// Weighted RMS over all photos, canonical units.
    fn rms(&self, state: &State) -> Real {
        let total: Real = self.point_weights.iter().sum();
        let mut sum = 0.0;
        for i in 0..state.cameras.len() {
            for (r, w) in self.residuals(state, i).iter().zip(self.point_weights) {
                sum += w * r.map_or(0.0, |(r, _, _)| r.norm_squared());
            }
        }
        (sum / (total * state.cameras.len() as Real)).sqrt()
    }

    fn normal_equations(
        &self,
        state: &State,
        options: &RefineOptions,
        h: &mut DMatrix<Real>,
        g: &mut DVector<Real>,
    ) {
        let k = state.weights.len();
        let n = h.nrows();
        let inv = 1.0 / (options.noise * options.noise);
        for (i, camera) in state.cameras.iter().enumerate() {
            for (j, r) in self.residuals(state, i).into_iter().enumerate() {
                let Some((r, q, dq)) = r else { continue };
                let w = self.point_weights[j] * inv;
                let dx = dq * camera.rotation.matrix();
                for a in 0..2 {
                    let mut row = DVector::<Real>::zeros(n);
                    for m in 0..k {
                        row[m] = dx.row(a).dot(&self.modes[j][m].transpose());
                    }
                    let dqa: Vector3<Real> = dq.row(a).transpose();
                    let rotation = q.cross(&dqa);
                    let f = camera.scale / (1.0 - camera.perspective * q.z) / self.units[i];
                    let qa = if a == 0 { q.x } else { q.y };
                    let base = k + CAMERA * i;
                    row[base] = rotation.x;
                    row[base + 1] = rotation.y;
                    row[base + 2] = rotation.z;
                    row[base + 3] = f * qa;
                    row[base + 4 + a] = 1.0 / self.units[i];
                    row[base + 6] = f * qa * q.z / (1.0 - camera.perspective * q.z);
                    h.ger(w, &row, &row, 1.0);
                    g.axpy(w * r[a], &row, 1.0);
                }
            }
        }
    }
}

impl FaceSpace {
    /// Refines a landmark fit ([`FaceSpace::fit_photos`]) with the photos' pixels: see the
    /// [module documentation](self). `views` are the photos the landmark fit was given, in its
    /// order; `reference` the reference the space belongs to (its face region is where the
    /// surface is sampled).
    ///
    /// # Errors
    /// [`FaceError::Option`] when the views do not match the fit, or for options out of range
    /// (levels not 1 to 6; the eye pixels, spacing, `σ`, `β` or `ε` not positive and finite).
    pub fn refine_photos(
        &self,
        reference: &ReferenceFace,
        fit: &PhotoSpaceFit,
        views: &[RefineView<'_>],
        point_weights: &[Real; POINT_COUNT],
        options: &RefineOptions,
    ) -> Result<Refinement, FaceError> {
        let bad = |name: &'static str, value: String, expected: &'static str| {
            Err(FaceError::Option {
                name,
                value,
                expected,
            })
        };
        if views.len() != fit.poses.len() || views.iter().any(|v| v.points.len() != POINT_COUNT) {
            return bad(
                "views",
                views.len().to_string(),
                "one per photo of the fit, 40 points each",
            );
        }
        let positive = |v: Real| v > 0.0 && v.is_finite();
        if !(1..=6).contains(&options.levels) {
            return bad("levels", options.levels.to_string(), "1 to 6");
        }
        for (name, v) in [
            ("eye pixels", options.eye_pixels),
            ("spacing", options.spacing),
            ("sigma", options.sigma),
            ("beta", options.beta),
            ("noise", options.noise),
        ] {
            if !positive(v) {
                return bad(name, v.to_string(), "positive and finite");
            }
        }
        let start = State {
            weights: fit.weights.clone(),
            cameras: fit
                .poses
                .iter()
                .map(|(pose, offset)| RefinedCamera {
                    rotation: pose.rotation,
                    scale: pose.scale,
                    offset: offset.coords,
                    perspective: 0.0,
                })
                .collect(),
        };
        let expressions: Vec<Vec<Real>> = if fit
            .expressions
            .iter()
            .all(|e| e.len() == self.expressions().len())
        {
            fit.expressions.clone()
        } else {
            vec![Vec::new(); views.len()]
        };
        let structure = self.structure_samples();
        let landmarks = Landmarks {
            base: structure.base.clone(),
            modes: (0..POINT_COUNT)
                .map(|j| structure.modes.iter().map(|m| m[j]).collect())
                .collect(),
            expression: expressions
                .iter()
                .map(|e| {
                    let mut d = vec![Vector3::zeros(); POINT_COUNT];
                    for (w, mode) in e.iter().zip(&self.expressions().structure) {
                        for (d, m) in d.iter_mut().zip(mode) {
                            *d += m * *w;
                        }
                    }
                    d
                })
                .collect(),
            views,
            point_weights,
            units: start.cameras.iter().map(|c| c.scale).collect(),
        };
        // Each photo's face box: its landmarks' box grown by half its size (the forehead and
        // cheeks lie beyond the points), clamped to the image.
        let boxes: Vec<[Real; 4]> = views
            .iter()
            .map(|v| {
                let (mut x0, mut y0, mut x1, mut y1) = (Real::MAX, Real::MAX, Real::MIN, Real::MIN);
                for p in v.points {
                    (x0, x1) = (x0.min(p.x), x1.max(p.x));
                    (y0, y1) = (y0.min(-p.y), y1.max(-p.y));
                }
                let (mx, my) = (0.5 * (x1 - x0), 0.5 * (y1 - y0));
                [
                    (x0 - mx).max(0.0),
                    (y0 - my).max(0.0),
                    (x1 + mx).min(v.image.width() as Real - 1.0),
                    (y1 + my).min(v.image.height() as Real - 1.0),
                ]
            })
            .collect();
        let mut state = start.clone();
        let mut iterations = 0;
        let mut finest = None;
        for level_index in 0..options.levels {
            let coarser = (options.levels - 1 - level_index) as i32;
            let eye_pixels = options.eye_pixels / 2.0_f64.powi(coarser);
            let spacing = options.spacing * 2.0_f64.powi(coarser);
            let images: Vec<LevelImage> = views
                .iter()
                .zip(&boxes)
                .zip(&state.cameras)
                .map(|((v, b), camera)| {
                    let eye = 50.0 * camera.scale;
                    let factor = (eye_pixels / eye).min(1.0);
                    LevelImage::new(v.image, *b, factor, NORMALISATION_EYES * eye * factor)
                })
                .collect();
            let samples = Samples::new(self, reference, &expressions, spacing)?;
            let level = Level {
                images,
                samples,
                landmarks: &landmarks,
                sigma_prior: self.sigma(),
                options,
            };
            let mut damping = 1e-3;
            for _ in 0..options.iterations {
                iterations += 1;
                let visibility = level.visibility(&state);
                let cost = level.cost(&state, &visibility);
                let (h, g) = level.normal_equations(&state, &visibility);
                let mut improved = false;
                for _ in 0..8 {
                    let mut damped = h.clone();
                    for d in 0..damped.nrows() {
                        damped[(d, d)] += damping * h[(d, d)].max(1e-9);
                    }
                    let Some(chol) = damped.cholesky() else {
                        damping *= 10.0;
                        continue;
                    };
                    let step = -chol.solve(&g);
                    let k = state.weights.len();
                    let next = State {
                        weights: state
                            .weights
                            .iter()
                            .zip(step.iter())
                            .map(|(w, d)| w + d)
                            .collect(),
                        cameras: state
                            .cameras
                            .iter()
                            .enumerate()
                            .map(|(i, c)| c.moved(&step.as_slice()[k + CAMERA * i..k + CAMERA * (i + 1)]))
                            .collect(),
                    };
                    let next_cost = level.cost(&next, &visibility);
                    if next_cost.is_finite() && next_cost < cost {
                        let relative = (cost - next_cost) / cost.max(1e-12);
                        state = next;
                        damping = (damping / 3.0).max(1e-7);
                        improved = relative > 1e-5;
                        break;
                    }
                    damping *= 10.0;
                }
                if !improved {
                    break;
                }
            }
            if level_index + 1 == options.levels {
                finest = Some(level);
            }
        }
        let level = finest.expect("at least one level");
        let before_visibility = level.visibility(&start);
        let after_visibility = level.visibility(&state);
        let (b_sum, b_total, _) = level.disagreement(&start, &before_visibility);
        let (a_sum, a_total, seen_twice) = level.disagreement(&state, &after_visibility);
        let disagreement = (
            (b_sum / b_total.max(1e-12)).sqrt(),
            (a_sum / a_total.max(1e-12)).sqrt(),
        );
        let landmark_rms = (landmarks.rms(&start), landmarks.rms(&state));
        let coverage = after_visibility
            .iter()
            .map(|v| v.iter().filter(|&&c| c > 0.0).count() as Real / v.len().max(1) as Real)
            .collect();
        let gain = 1.0 - disagreement.1 / disagreement.0;
        let (accepted, note) = if !(gain >= options.min_gain) {
            (
                false,
                format!(
                    "the photos agree no better on the refined face (disagreement {:.3} → {:.3}): the landmark fit stands",
                    disagreement.0, disagreement.1
                ),
            )
        } else if landmark_rms.1 > landmark_rms.0 + options.landmark_slack {
            (
                false,
                format!(
                    "the refined face moved off the landmarks (RMS {:.2} → {:.2} units): the landmark fit stands",
                    landmark_rms.0, landmark_rms.1
                ),
            )
        } else {
            (
                true,
                format!(
                    "refined by the photos' agreement: disagreement {:.3} → {:.3}, landmark RMS {:.2} → {:.2} units",
                    disagreement.0, disagreement.1, landmark_rms.0, landmark_rms.1
                ),
            )
        };
        let kept = if accepted { state } else { start };
        Ok(Refinement {
            weights: kept.weights,
            cameras: kept.cameras,
            disagreement,
            landmark_rms,
            coverage,
            samples: (level.samples.len(), seen_twice),
            iterations,
            accepted,
            note,
        })
    }
}
