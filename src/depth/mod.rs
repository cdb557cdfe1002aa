//! Depth: from the frontal 2D structure and the photos' points to the 3D structure, by the
//! paper's Algorithm 1 (its §3): alternate each photo's pose and the 40 depths, minimising the
//! reprojection error divided by the multi-substructure similarity to a reference structure.
//!
//! # The problem
//!
//! The structure `T` (`3 × 40`, canonical frame) has its `x, y` from the frontal structure
//! ([`crate::align::FrontalStructure`]); only the depths `Z` are unknown. Each photo `i` has a
//! scaled orthographic pose (`sᵢ`, `Rᵢ`, see [`Pose`]) and the objective is
//!
//! ```text
//! f(poses, Z) = √( 1/(40N) · Σᵢ Σⱼ ‖S′ᵢ[:, j] − sᵢ P Rᵢ T[:, j]‖² ) / SIM(V_ref, V_T)
//! ```
//!
//! with `SIM` the multi-substructure similarity of the 3D edge lengths
//! ([`crate::structure::multi_substructure_similarity`]).
//!
//! # Choices the paper leaves open
//!
//! * **Anchoring.** Each photo's points are translated so that their eye midpoint is the origin,
//!   as the paper does; for that to match the structure, whose eye midpoint is the canonical
//!   origin, the two eye centres keep depth 0 (the canonical frame puts them at `(±25, 0, 0)`).
//!   The other 38 depths are free.
//! * **Units.** Each photo's points are also scaled, about that origin, so that their RMS radius
//!   equals the frontal structure's. Every photo then weighs the same whatever its resolution, the
//!   scales `sᵢ` are near 1, and the objective is in canonical units (50 between the eye
//!   centres), which gives the paper's stopping threshold `ε = 0.01` a meaning. Poses and RMS
//!   errors are reported back in each photo's pixels.
//! * **Pose step.** Each photo alone: a closed-form scaled orthographic Procrustes start (first
//!   iteration), then Levenberg–Marquardt over a rotation vector and the scale, warm-started from
//!   the previous iteration's pose afterwards (so a photo cannot jump to the depth-reversed twin
//!   pose that orthographic projection allows).
//! * **Depth step.** The reprojection term is a separable quadratic in `Z`; the objective
//!   `f² = E(Z)/SIM(Z)²` (same minimiser as `f`, smooth where `f` is not at `E = 0`) is minimised
//!   by L-BFGS with the exact gradient. Without the similarity constraint the step is closed-form.
//! * **Stopping.** When `f` changes by less than [`DepthOptions::tolerance`] between iterations,
//!   or after [`DepthOptions::max_iterations`].

mod lbfgs;
mod pose;

pub use pose::Pose;
pub(crate) use pose::{closed_form_pose, refine_pose};

use nalgebra::{Matrix3, Point2, Point3, Rotation3, Vector2, Vector3};

use crate::Real;
use crate::align::{AlignError, FrontalStructure, PhotoPoints};
use crate::reference::ReferenceFace;
use crate::structure::{
    Group, LEFT_EYE_CENTRE, POINT_COUNT, POINTS, RIGHT_EYE_CENTRE, edge_lengths,
    multi_substructure_similarity, multi_substructure_similarity_gradient, substructures,
};
use pose::reprojection_cost;

/// A photo whose RMS reprojection error exceeds this, in canonical units (5% of the eye
/// distance), and [`BAD_FIT_RATIO`] times the median over the photos (with three photos or
/// more), is reported as fitting badly: its points are not a view of the structure (wrong
/// landmarks, another face, strong perspective or expression). The ratio keeps one stranger,
/// which pulls every photo's error up a little, from getting the good photos flagged too.
pub const BAD_FIT_UNITS: Real = 2.5;

/// See [`BAD_FIT_UNITS`].
pub const BAD_FIT_RATIO: Real = 3.0;

/// Poses closer than this (degrees) count as one pose when deciding whether the photos see the
/// face from enough directions.
pub const DISTINCT_POSE_DEGREES: Real = 5.0;

/// The reference structure the depth is pulled toward: 40 points (canonical frame) and the
/// edges that the similarity compares.
#[derive(Debug, Clone, PartialEq)]
pub struct StructurePrior {
    points: Vec<Point3<Real>>,
    edges: Vec<[usize; 2]>,
}

impl StructurePrior {
    /// A prior from a structure and its edges.
    ///
    /// # Errors
    /// [`DepthError::Prior`] when there are not 40 finite points, an edge is out of range or has
    /// length 0, or there are no edges.
    pub fn new(points: Vec<Point3<Real>>, edges: Vec<[usize; 2]>) -> Result<Self, DepthError> {
        let fail = |problem: String| Err(DepthError::Prior { problem });
        if points.len() != POINT_COUNT {
            return fail(format!("{} points, expected {POINT_COUNT}", points.len()));
        }
        if let Some(k) = points.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
            return fail(format!("point {k} is not finite"));
        }
        if edges.is_empty() {
            return fail("no edges".to_owned());
        }
        for &[a, b] in &edges {
            if a >= POINT_COUNT || b >= POINT_COUNT || a == b {
                return fail(format!("edge [{a}, {b}] is not a pair of distinct points"));
            }
            if points[a] == points[b] {
                return fail(format!("edge [{a}, {b}] has length 0"));
            }
        }
        Ok(Self { points, edges })
    }

    /// The reference face's structure and edges.
    pub fn from_reference(reference: &ReferenceFace) -> Self {
        Self::new(reference.structure().to_vec(), reference.edges().to_vec())
            .expect("a validated reference has a valid structure")
    }

    /// The 40 points.
    pub fn points(&self) -> &[Point3<Real>] {
        &self.points
    }

    /// The edges.
    pub fn edges(&self) -> &[[usize; 2]] {
        &self.edges
    }
}

/// Settings of the depth estimation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthOptions {
    /// Divide by the multi-substructure similarity (the paper's method). `false` minimises the
    /// reprojection error alone (the paper's Fig. 9b ablation).
    pub similarity_constraint: bool,
    /// Stop when the objective changes by less than this between iterations (canonical units;
    /// the paper's `ε = 0.01`).
    pub tolerance: Real,
    /// The most pose/depth iterations.
    pub max_iterations: usize,
    /// What the depth step may change of the frontal structure's `x, y`.
    pub frontal: FrontalFreedom,
    /// The weight of the 9 contour (jaw) points against 1 for the others. A landmarker puts
    /// the jaw points of a turned face on its visible outline, which is not one fixed point of
    /// the face, so they fit no 3D structure well (see [`DepthOptions::default`]).
    pub contour_weight: Real,
}

/// What the depth step may change of the frontal structure's `x, y`.
///
/// Points alone fix the frontal structure only up to an affine map (and RASL's affine warps
/// likewise), and an affine consensus of photos that pitch is not exactly any view of the face:
/// both leave errors in `x, y` that the paper's method (`Fixed`) passes on to the depths. The
/// camera model fixes them: under scaled orthographic projection, the way each photo
/// foreshortens the face says what the frontal view is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrontalFreedom {
    /// `x, y` as given: the paper's method.
    Fixed,
    /// `x, y` up to the shear and vertical stretch that keep the eye centres in place
    /// ([`FrontalGauge`]): two more unknowns.
    Gauge,
    /// Every point's `x, y` is free too (orthographic bundle adjustment, with the similarity
    /// constraint still on the 3D edge lengths), the gauge's two unknowns kept as a short path
    /// for the global change. The frontal structure is then only the start; the rotation about
    /// the eye axis, which photos cannot fix, is the one that fits the prior structure best.
    Free,
}

impl Default for DepthOptions {
    /// The paper's similarity constraint and `ε = 0.01`, every frontal point free, and the
    /// contour at a tenth of the weight of the other points.
    ///
    /// The contour weight by measurement (`tools/photo_eval`: every set of 2 / 3 / 4 / 8 / 16
    /// photo-realistic photos of 7 subjects, dlib's landmarks, mean ratio of the inner-face error
    /// to the mean face's): weight 1 gave 1.55 / 1.57 / 1.25 / 1.27 / 1.23, weight 0.1 gave
    /// 1.33 / 1.45 / 1.14 / 1.13 / 1.12. With the surface's shrinkage on, 0, 0.1 and 0.3 gave
    /// 1.13 / 1.12 / 1.05 / 1.07 / 1.13, 1.04 / 1.08 / 0.96 / 0.95 / 0.94 and
    /// 1.07 / 1.10 / 0.97 / 0.97 / 0.94: the contour still says something about the face's
    /// width, but weighed like the other points it bends the structure toward its outline.
    fn default() -> Self {
        Self {
            similarity_constraint: true,
            tolerance: 0.01,
            max_iterations: 100,
            frontal: FrontalFreedom::Free,
            contour_weight: 0.1,
        }
    }
}

/// How one photo fits the estimated structure.
#[derive(Debug, Clone, PartialEq)]
pub struct PhotoFit {
    /// The photo's name.
    pub name: String,
    /// Its pose; the scale is in the photo's pixels per canonical unit.
    pub pose: Pose,
    /// RMS reprojection error over the 40 points, in the photo's pixels.
    pub rms_pixels: Real,
    /// The photo's eye midpoint in pixels (`y` down), where the structure's origin projects.
    pub eye_midpoint: Point2<Real>,
    /// The same in canonical units (50 between the eye centres).
    pub rms_units: Real,
    /// The RMS over the 31 points off the contour, canonical units.
    pub inner_rms_units: Real,
}

/// Something the caller should know about an estimate.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum DepthWarning {
    /// A photo's points fit the structure badly (see [`BAD_FIT_UNITS`]).
    BadFit {
        /// The photo.
        photo: String,
        /// Its RMS error, canonical units.
        rms_units: Real,
    },
    /// Fewer than two distinct poses: depth is seen from too few directions and rests largely on
    /// the reference structure.
    FewPoses {
        /// Distinct poses found (at least [`DISTINCT_POSE_DEGREES`] apart).
        distinct: usize,
    },
    /// Every photo is (near) frontal, so the photos say nothing about depth: it is the
    /// reference's, reshaped only by the similarity constraint (or unchanged without it).
    DepthUnobservable {
        /// The largest angle between a view direction and frontal, degrees.
        largest_view_angle: Real,
    },
    /// The iteration cap was reached before the objective settled.
    NotConverged {
        /// Iterations run.
        iterations: usize,
    },
}

impl DepthEstimate {
    /// Whether photo `k`'s points fit the structure badly (a [`DepthWarning::BadFit`]).
    pub fn fits_badly(&self, k: usize) -> bool {
        self.warnings
            .iter()
            .any(|w| matches!(w, DepthWarning::BadFit { photo, .. } if *photo == self.photos[k].name))
    }

    /// The photo seen most nearly from the front (smallest [`Pose::view_angle_degrees`]) among
    /// those without a [`DepthWarning::BadFit`]; `None` when every photo fits badly.
    pub fn most_frontal_photo(&self) -> Option<usize> {
        self.photos
            .iter()
            .enumerate()
            .filter(|&(k, _)| !self.fits_badly(k))
            .min_by(|a, b| {
                a.1.pose
                    .view_angle_degrees()
                    .total_cmp(&b.1.pose.view_angle_degrees())
            })
            .map(|(k, _)| k)
    }
}

impl PhotoFit {
    /// Where the photo sees a point of the canonical frame, in its pixels (`y` down).
    pub fn pixel(&self, point: &Point3<Real>) -> Point2<Real> {
        let q = self.pose.project(point);
        Point2::new(self.eye_midpoint.x + q.x, self.eye_midpoint.y - q.y)
    }
}

impl std::fmt::Display for DepthWarning {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::BadFit { photo, rms_units } => write!(
                f,
                "photo {photo} fits the structure badly (RMS {rms_units:.2} units, {:.1}% of the eye distance)",
                2.0 * rms_units
            ),
            Self::FewPoses { distinct } => write!(
                f,
                "only {distinct} distinct pose(s): depth rests largely on the reference structure"
            ),
            Self::DepthUnobservable { largest_view_angle } => write!(
                f,
                "every photo is within {largest_view_angle:.1}° of frontal: the photos do not show depth"
            ),
            Self::NotConverged { iterations } => {
                write!(f, "the estimate had not settled after {iterations} iterations")
            }
        }
    }
}

/// The estimated 3D structure and how the photos fit it.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthEstimate {
    /// The 40 points in the canonical frame (eye centres at `(±25, 0, 0)`, `+z` toward the
    /// viewer).
    pub structure: Vec<Point3<Real>>,
    /// Per photo, in input order.
    pub photos: Vec<PhotoFit>,
    /// The objective `f` after each iteration; entry 0 is at the start (reference depths, fitted
    /// poses).
    pub objective: Vec<Real>,
    /// The multi-substructure similarity of the result to the prior.
    pub similarity: Real,
    /// The shear and stretch found for the frontal structure (identity when
    /// [`DepthOptions::frontal`] is [`FrontalFreedom::Fixed`]).
    pub gauge: FrontalGauge,
    /// Pose/depth iterations run.
    pub iterations: usize,
    /// Whether the objective settled within the tolerance.
    pub converged: bool,
    /// What the caller should know.
    pub warnings: Vec<DepthWarning>,
}

/// What can go wrong estimating depth.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum DepthError {
    /// Bad photos or frontal structure.
    #[error(transparent)]
    Align(#[from] AlignError),
    /// The number of photos and of frontal warps differ.
    #[error("{photos} photos but the frontal structure was made from {frontal}")]
    PhotoCountMismatch {
        /// Photos given.
        photos: usize,
        /// Photos the frontal structure has warps for.
        frontal: usize,
    },
    /// The prior structure is unusable.
    #[error("reference structure: {problem}")]
    Prior {
        /// What is wrong.
        problem: String,
    },
    /// An option is out of range.
    #[error("option {name} = {value} is out of range: {expected}")]
    Option {
        /// The option.
        name: &'static str,
        /// Its value.
        value: String,
        /// The range.
        expected: &'static str,
    },
    /// A photo's pose cannot be fitted (its points collapse under the structure).
    #[error("photo {photo}: no pose fits its points")]
    NoPose {
        /// The photo.
        photo: String,
    },
}

/// One photo's points made ready: `y` up, eye midpoint at the origin, scaled to the frontal
/// structure's RMS radius (`points = κ · (y_up − eye midpoint)`).
struct View {
    points: Vec<Point2<Real>>,
    kappa: Real,
    /// The eye midpoint, pixels, `y` down.
    middle: Point2<Real>,
    /// Each point's weight in the fit ([`DepthOptions::contour_weight`]).
    weights: Vec<Real>,
}

fn prepare_view(photo: &PhotoPoints, frontal_radius: Real, weights: &[Real]) -> Result<View, DepthError> {
    let up = photo.y_up();
    let middle = nalgebra::center(&up[RIGHT_EYE_CENTRE], &up[LEFT_EYE_CENTRE]);
    let centred: Vec<Vector2<Real>> = up.iter().map(|p| p - middle).collect();
    let radius = rms_radius(centred.iter());
    if !(radius > 0.0 && radius.is_finite()) {
        return Err(AlignError::Degenerate {
            photo: photo.name.clone(),
        }
        .into());
    }
    let kappa = frontal_radius / radius;
    Ok(View {
        points: centred.iter().map(|v| Point2::from(v * kappa)).collect(),
        kappa,
        middle: Point2::new(middle.x, -middle.y),
        weights: weights.to_vec(),
    })
}

fn rms_radius<'a>(vectors: impl Iterator<Item = &'a Vector2<Real>>) -> Real {
    let (sum, count) = vectors.fold((0.0, 0usize), |(s, n), v| (s + v.norm_squared(), n + 1));
    (sum / count as Real).sqrt()
}

/// The depth step's unknowns: the 40 depths; the frontal gauge (shear, stretch − 1), scaled by
/// the frontal structure's RMS `|y|` so that all unknowns have comparable curvature; then the
/// 40 `x` and the 40 `y` offsets from the gauged frontal structure.
const UNKNOWNS: usize = 3 * POINT_COUNT + 2;
const SHEAR: usize = POINT_COUNT;
const STRETCH: usize = POINT_COUNT + 1;
const DX: usize = POINT_COUNT + 2;
const DY: usize = 2 * POINT_COUNT + 2;
/// The pose unknowns of the joint step (after the structure's): each photo's rotation vector
/// and scale change, times this (a rotation of 1/50 radian moves a point 50 units from the
/// axis by 1 unit, so the unknowns have comparable curvature).
const POSE_SCALE: Real = 50.0;

/// The frontal gauge: the frontal structure's `x, y` become `(x + shear·y, stretch·y)`, the only
/// affine changes that keep the eye centres at `(±25, 0)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrontalGauge {
    /// `x` gains `shear · y`.
    pub shear: Real,
    /// `y` is multiplied by this.
    pub stretch: Real,
}

/// The depth step's objective `g(w) = E(w) / SIM(w)²` with its gradient: `E` is the mean
/// squared reprojection error with the poses fixed, `w` the depths and the scaled gauge.
struct DepthObjective<'a> {
    frontal: &'a [Point2<Real>],
    prior: &'a StructurePrior,
    groups: &'a [Vec<usize>; 7],
    reference_lengths: &'a [Real],
    views: &'a [View],
    options: &'a DepthOptions,
    /// The RMS of the frontal `y`, which scales the gauge unknowns.
    y_scale: Real,
}

impl DepthObjective<'_> {
    fn gauge(&self, w: &[Real]) -> FrontalGauge {
        FrontalGauge {
            shear: w[SHEAR] / self.y_scale,
            stretch: 1.0 + w[STRETCH] / self.y_scale,
        }
    }

    /// The frontal structure after the gauge, without the per-point offsets.
    fn gauged_frontal(&self, w: &[Real]) -> Vec<Point2<Real>> {
        let gauge = self.gauge(w);
        self.frontal
            .iter()
            .map(|p| Point2::new(p.x + gauge.shear * p.y, gauge.stretch * p.y))
            .collect()
    }

    fn structure(&self, w: &[Real]) -> Vec<Point3<Real>> {
        self.gauged_frontal(w)
            .iter()
            .enumerate()
            .map(|(j, p)| Point3::new(p.x + w[DX + j], p.y + w[DY + j], w[j]))
            .collect()
    }

    /// Turns the structure about the eye axis (`x`) to fit the prior structure best, and writes
    /// it back into `w`: the one freedom that photos cannot fix once every point's `x, y` is
    /// free (turning the face and every camera by the same rotation changes no image), so the
    /// reference says which way is frontal. Returns the rotation applied.
    ///
    /// Closed form: with `q = R_x(φ) p`, `Σ q·t = cos φ Σ(y t_y + z t_z) + sin φ Σ(y t_z − z t_y)`
    /// is largest at `φ = atan2(Σ(y t_z − z t_y), Σ(y t_y + z t_z))`.
    fn fix_pitch(&self, w: &mut [Real]) -> Rotation3<Real> {
        let points = self.structure(w);
        let (mut along, mut across) = (0.0, 0.0);
        for (p, t) in points.iter().zip(&self.prior.points) {
            along += p.y * t.y + p.z * t.z;
            across += p.y * t.z - p.z * t.y;
        }
        let rotation = Rotation3::from_axis_angle(&Vector3::x_axis(), across.atan2(along));
        let target = self.gauged_frontal(w);
        for (j, (p, t)) in points.iter().zip(&target).enumerate() {
            let q = rotation * p;
            w[j] = q.z;
            w[DX + j] = q.x - t.x;
            w[DY + j] = q.y - t.y;
        }
        rotation
    }

    /// The poses the joint unknowns `w[UNKNOWNS..]` describe, relative to `base`.
    fn poses(&self, base: &[Pose], w: &[Real]) -> Vec<Pose> {
        base.iter()
            .zip(w[UNKNOWNS..].chunks_exact(4))
            .map(|(pose, p)| Pose {
                rotation: Rotation3::new(Vector3::new(p[0], p[1], p[2]) / POSE_SCALE) * pose.rotation,
                scale: pose.scale + p[3] / POSE_SCALE,
            })
            .collect()
    }

    fn value_and_gradient(&self, base: &[Pose], w: &[Real], gradient: &mut [Real]) -> Real {
        let points = self.structure(w);
        gradient.iter_mut().for_each(|g| *g = 0.0);
        let mut error = 0.0;
        let (mut d_shear, mut d_stretch) = (0.0, 0.0);
        let mut count = 0.0;
        for (i, (view, pose)) in self.views.iter().zip(self.poses(base, w)).enumerate() {
            let m = pose.rotation.matrix();
            let s = pose.scale;
            let c0 = Vector2::new(s * m[(0, 0)], s * m[(1, 0)]);
            let c1 = Vector2::new(s * m[(0, 1)], s * m[(1, 1)]);
            let c2 = Vector2::new(s * m[(0, 2)], s * m[(1, 2)]);
            // With r̃ⱼ = (rⱼ, 0) and Gᵢ = Σⱼ r̃ⱼ Xⱼᵀ: ∂E/∂ωₖ = −2s ⟨∂R/∂ωₖ · R₀, G⟩ and
            // ∂E/∂s = −2 ⟨R R₀, G⟩ (Frobenius products), where for R = exp([ω]×)
            // ∂R/∂ωₖ = (ωₖ [ω]× + [ω × (I − R) eₖ]×) R / |ω|² (Gallego & Yezzi 2015), [eₖ]× at 0.
            let mut outer = Matrix3::zeros();
            for (j, ((x, p), f)) in view.points.iter().zip(&points).zip(self.frontal).enumerate() {
                let weight = view.weights[j];
                count += weight;
                let residual = x.coords - c0 * p.x - c1 * p.y - c2 * p.z;
                let r = weight * residual;
                error += r.dot(&residual);
                let (rc0, rc1) = (r.dot(&c0), r.dot(&c1));
                gradient[j] -= 2.0 * r.dot(&c2);
                gradient[DX + j] -= 2.0 * rc0;
                gradient[DY + j] -= 2.0 * rc1;
                d_shear -= 2.0 * rc0 * f.y;
                d_stretch -= 2.0 * rc1 * f.y;
                for c in 0..3 {
                    outer[(0, c)] += r.x * p.coords[c];
                    outer[(1, c)] += r.y * p.coords[c];
                }
            }
            let at = UNKNOWNS + 4 * i;
            let omega = Vector3::new(w[at], w[at + 1], w[at + 2]) / POSE_SCALE;
            let omega_squared = omega.norm_squared();
            let base_rotation = base[i].rotation.matrix();
            let turn = Rotation3::new(omega);
            let mut d_pose = [0.0; 4];
            for (k, d) in d_pose.iter_mut().take(3).enumerate() {
                let e = Vector3::ith(k, 1.0);
                let derivative = if omega_squared > 1e-24 {
                    (omega.cross_matrix() * omega[k] + omega.cross(&(e - turn * e)).cross_matrix())
                        * turn.matrix()
                        / omega_squared
                } else {
                    e.cross_matrix()
                };
                *d = -2.0 * s * (derivative * base_rotation).dot(&outer);
            }
            d_pose[3] = -2.0 * m.dot(&outer);
            for (g, d) in gradient[at..at + 4].iter_mut().zip(d_pose) {
                *g = d / POSE_SCALE;
            }
        }
        let count = count.max(Real::MIN_POSITIVE);
        error /= count;
        gradient.iter_mut().for_each(|g| *g /= count);
        gradient[SHEAR] = d_shear / count / self.y_scale;
        gradient[STRETCH] = d_stretch / count / self.y_scale;

        let value = if self.options.similarity_constraint {
            let lengths = edge_lengths(&points, &self.prior.edges);
            let mut by_length = vec![0.0; lengths.len()];
            let sim = multi_substructure_similarity_gradient(
                self.reference_lengths,
                &lengths,
                self.groups,
                &mut by_length,
            );
            // ∇g = ∇E / SIM² − 2 E ∇SIM / SIM³, through ∂ℓ/∂(point) = (pₐ − p_b)/ℓ.
            let inverse = 1.0 / (sim * sim);
            gradient.iter_mut().for_each(|g| *g *= inverse);
            let factor = -2.0 * error * inverse / sim;
            for ((&[a, b], &length), &dsim) in self.prior.edges.iter().zip(&lengths).zip(&by_length) {
                let delta = points[a] - points[b];
                let frontal_dy = self.frontal[a].y - self.frontal[b].y;
                let weight = factor * dsim / length;
                gradient[a] += weight * delta.z;
                gradient[b] -= weight * delta.z;
                gradient[DX + a] += weight * delta.x;
                gradient[DX + b] -= weight * delta.x;
                gradient[DY + a] += weight * delta.y;
                gradient[DY + b] -= weight * delta.y;
                gradient[SHEAR] += weight * delta.x * frontal_dy / self.y_scale;
                gradient[STRETCH] += weight * delta.y * frontal_dy / self.y_scale;
            }
            error * inverse
        } else {
            error
        };
        for eye in [RIGHT_EYE_CENTRE, LEFT_EYE_CENTRE] {
            gradient[eye] = 0.0;
            gradient[DX + eye] = 0.0;
            gradient[DY + eye] = 0.0;
        }
        if self.options.frontal == FrontalFreedom::Fixed {
            gradient[SHEAR] = 0.0;
            gradient[STRETCH] = 0.0;
        }
        if self.options.frontal != FrontalFreedom::Free {
            gradient[DX..].iter_mut().for_each(|g| *g = 0.0);
        }
        value
    }

    /// The depth step: the minimiser of `g` over the structure and the poses together, from
    /// `w` and `poses` (both updated), by L-BFGS. The first step is the Newton step of the
    /// reprojection term in the depths, where it has curvature; with frontal photos only it has
    /// none, and the depths move only by the similarity.
    fn minimise(&self, poses: &mut Vec<Pose>, w: &mut Vec<Real>) {
        let curvature: Real = poses
            .iter()
            .map(|pose| {
                let m = pose.rotation.matrix();
                pose.scale * pose.scale * (m[(0, 2)] * m[(0, 2)] + m[(1, 2)] * m[(1, 2)])
            })
            .sum::<Real>()
            * 2.0
            / self.views.len() as Real
            / POINT_COUNT as Real;
        let first_step = if curvature > 1e-9 { 1.0 / curvature } else { 1.0 };
        let base = poses.clone();
        w.truncate(UNKNOWNS);
        w.resize(UNKNOWNS + 4 * poses.len(), 0.0);
        lbfgs::minimize(
            |w, g| self.value_and_gradient(&base, w, g),
            w,
            first_step,
            1e-8,
            500,
        );
        *poses = self.poses(&base, w);
        w.truncate(UNKNOWNS);
    }
}

/// Estimates the 3D structure from the photos' points and their frontal structure (the paper's
/// Algorithm 1; see the module documentation).
///
/// `photos` are the photos the frontal structure was made from, in the same order.
///
/// # Errors
/// [`DepthError::Align`] for bad photos or frontal structure, [`DepthError::PhotoCountMismatch`],
/// [`DepthError::Option`] for a tolerance that is not positive and finite or a zero iteration
/// cap, [`DepthError::NoPose`] when a photo's pose cannot be fitted.
///
/// # Examples
///
/// ```
/// use splineface::align::{PhotoPoints, procrustes_frontal};
/// use splineface::depth::{DepthOptions, Pose, StructurePrior, estimate_depth};
/// use splineface::reference::ReferenceFace;
///
/// // The reference structure seen from three directions, 3 pixels a unit.
/// let reference = ReferenceFace::embedded();
/// let photos: Vec<PhotoPoints> = [-30.0, 0.0, 25.0]
///     .iter()
///     .enumerate()
///     .map(|(k, &yaw)| {
///         let pose = Pose::from_yaw_pitch_roll_degrees(yaw, 5.0, 0.0, 3.0);
///         let pixels = reference
///             .structure()
///             .iter()
///             .map(|p| {
///                 let q = pose.project(p);
///                 nalgebra::Point2::new(320.0 + q.x, 240.0 - q.y)
///             })
///             .collect();
///         PhotoPoints::new(format!("photo{k}"), pixels)
///     })
///     .collect::<Result<_, _>>()?;
/// let frontal = procrustes_frontal(&photos)?;
/// let prior = StructurePrior::from_reference(reference);
/// let estimate = estimate_depth(&photos, &frontal, &prior, &DepthOptions::default())?;
/// let [yaw, ..] = estimate.photos[0].pose.yaw_pitch_roll_degrees();
/// assert!((yaw + 30.0).abs() < 1.0);
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn estimate_depth(
    photos: &[PhotoPoints],
    frontal: &FrontalStructure,
    prior: &StructurePrior,
    options: &DepthOptions,
) -> Result<DepthEstimate, DepthError> {
    if !(options.tolerance > 0.0 && options.tolerance.is_finite()) {
        return Err(DepthError::Option {
            name: "tolerance",
            value: options.tolerance.to_string(),
            expected: "a positive finite number",
        });
    }
    if options.max_iterations == 0 {
        return Err(DepthError::Option {
            name: "max_iterations",
            value: "0".to_owned(),
            expected: "at least 1",
        });
    }
    if photos.is_empty() {
        return Err(AlignError::NoPhotos.into());
    }
    if photos.len() != frontal.warps.len() {
        return Err(DepthError::PhotoCountMismatch {
            photos: photos.len(),
            frontal: frontal.warps.len(),
        });
    }
    frontal.validate()?;
    for photo in photos {
        photo.validate()?;
    }

    if !(options.contour_weight >= 0.0 && options.contour_weight <= 1.0) {
        return Err(DepthError::Option {
            name: "contour_weight",
            value: options.contour_weight.to_string(),
            expected: "between 0 and 1",
        });
    }
    let point_weights: Vec<Real> = crate::structure::contour_weighted(options.contour_weight).to_vec();
    let frontal_points = &frontal.points;
    let frontal_radius = rms_radius(frontal_points.iter().map(|p| &p.coords));
    let views = photos
        .iter()
        .map(|photo| prepare_view(photo, frontal_radius, &point_weights))
        .collect::<Result<Vec<_>, _>>()?;
    let groups = substructures(&prior.edges);
    let reference_lengths = edge_lengths(&prior.points, &prior.edges);

    // The depths start at the reference's, the eye centres at 0; the gauge at the identity.
    let y_scale = (frontal_points.iter().map(|p| p.y * p.y).sum::<Real>() / POINT_COUNT as Real).sqrt();
    let mut w = vec![0.0; UNKNOWNS];
    for (wj, p) in w.iter_mut().zip(&prior.points) {
        *wj = p.z;
    }
    w[RIGHT_EYE_CENTRE] = 0.0;
    w[LEFT_EYE_CENTRE] = 0.0;
    let problem = Problem {
        photos,
        frontal: frontal_points,
        prior,
        groups: &groups,
        reference_lengths: &reference_lengths,
        options,
        y_scale,
    };
    let fit = problem.solve(&views, &mut w)?;

    let Fit {
        structure,
        poses,
        objective,
        iterations,
        converged,
        gauge,
    } = fit;
    let photo_fits: Vec<PhotoFit> = photos
        .iter()
        .zip(&views)
        .zip(&poses)
        .map(|((photo, view), pose)| {
            let rms_units = (reprojection_cost(pose, &view.points, &structure, &view.weights)
                / view.weights.iter().sum::<Real>())
            .sqrt();
            PhotoFit {
                name: photo.name.clone(),
                pose: Pose {
                    rotation: pose.rotation,
                    scale: pose.scale / view.kappa,
                },
                rms_pixels: rms_units / view.kappa,
                eye_midpoint: view.middle,
                rms_units,
                inner_rms_units: inner_rms(view, pose, &structure),
            }
        })
        .collect();
    let similarity = multi_substructure_similarity(
        &reference_lengths,
        &edge_lengths(&structure, &prior.edges),
        &groups,
    );
    let warnings = warnings_for(&photo_fits, iterations, converged);
    Ok(DepthEstimate {
        structure,
        photos: photo_fits,
        objective,
        similarity,
        gauge,
        iterations,
        converged,
        warnings,
    })
}

/// A photo's RMS reprojection error over the 31 points off the contour, canonical units: the
/// points whose fit says whether the photo's landmarks are right.
fn inner_rms(view: &View, pose: &Pose, structure: &[Point3<Real>]) -> Real {
    let inner: Vec<Real> = POINTS
        .iter()
        .map(|p| if p.group == Group::Contour { 0.0 } else { 1.0 })
        .collect();
    (reprojection_cost(pose, &view.points, structure, &inner) / inner.iter().sum::<Real>()).sqrt()
}

/// What [`Problem::solve`] gives.
struct Fit {
    structure: Vec<Point3<Real>>,
    poses: Vec<Pose>,
    objective: Vec<Real>,
    iterations: usize,
    converged: bool,
    gauge: FrontalGauge,
}

/// Everything the alternation needs but the photos' views and the unknowns.
struct Problem<'a> {
    photos: &'a [PhotoPoints],
    frontal: &'a [Point2<Real>],
    prior: &'a StructurePrior,
    groups: &'a [Vec<usize>; 7],
    reference_lengths: &'a [Real],
    options: &'a DepthOptions,
    y_scale: Real,
}

impl Problem<'_> {
    /// The paper's alternation (see the module documentation) from the unknowns `w` (updated).
    fn solve(&self, views: &[View], w: &mut Vec<Real>) -> Result<Fit, DepthError> {
        let options = self.options;
        let depth = DepthObjective {
            frontal: self.frontal,
            prior: self.prior,
            groups: self.groups,
            reference_lengths: self.reference_lengths,
            views,
            options,
            y_scale: self.y_scale,
        };
        let pose_step =
            |structure: &[Point3<Real>], previous: Option<&[Pose]>| -> Result<Vec<Pose>, DepthError> {
                views
                    .iter()
                    .enumerate()
                    .map(|(i, view)| {
                        let start = match previous {
                            Some(poses) => Some(poses[i]),
                            None => closed_form_pose(&view.points, structure, &view.weights),
                        };
                        let start = start.ok_or_else(|| DepthError::NoPose {
                            photo: self.photos[i].name.clone(),
                        })?;
                        Ok(refine_pose(start, &view.points, structure, &view.weights))
                    })
                    .collect()
            };
        let objective_of = |structure: &[Point3<Real>], poses: &[Pose]| -> Real {
            let (mut sum, mut count) = (0.0, 0.0);
            for (view, pose) in views.iter().zip(poses) {
                sum += reprojection_cost(pose, &view.points, structure, &view.weights);
                count += view.weights.iter().sum::<Real>();
            }
            let rms = (sum / count.max(Real::MIN_POSITIVE)).sqrt();
            if options.similarity_constraint {
                let lengths = edge_lengths(structure, &self.prior.edges);
                rms / multi_substructure_similarity(self.reference_lengths, &lengths, self.groups)
            } else {
                rms
            }
        };

        let mut structure = depth.structure(w);
        let mut poses = pose_step(&structure, None)?;
        let mut objective = vec![objective_of(&structure, &poses)];
        let mut converged = false;
        let mut iterations = 0;
        while iterations < options.max_iterations {
            iterations += 1;
            depth.minimise(&mut poses, w);
            if options.frontal == FrontalFreedom::Free {
                let turn = depth.fix_pitch(w);
                for pose in &mut poses {
                    pose.rotation *= turn.inverse();
                }
            }
            structure = depth.structure(w);
            poses = pose_step(&structure, Some(&poses))?;
            let value = objective_of(&structure, &poses);
            let change = (value - objective[objective.len() - 1]).abs();
            objective.push(value);
            if change < options.tolerance {
                converged = true;
                break;
            }
        }
        Ok(Fit {
            structure,
            poses,
            objective,
            iterations,
            converged,
            gauge: depth.gauge(w),
        })
    }
}

fn warnings_for(photos: &[PhotoFit], iterations: usize, converged: bool) -> Vec<DepthWarning> {
    let mut errors: Vec<Real> = photos.iter().map(|p| p.rms_units).collect();
    errors.sort_by(Real::total_cmp);
    let floor = if photos.len() >= 3 {
        BAD_FIT_UNITS.max(BAD_FIT_RATIO * errors[errors.len() / 2])
    } else {
        BAD_FIT_UNITS
    };
    let mut warnings: Vec<DepthWarning> = photos
        .iter()
        .filter(|p| p.rms_units > floor)
        .map(|p| DepthWarning::BadFit {
            photo: p.name.clone(),
            rms_units: p.rms_units,
        })
        .collect();
    // Distinct poses: greedily, each pose at least DISTINCT_POSE_DEGREES from those kept.
    let mut distinct: Vec<&Pose> = Vec::new();
    for p in photos {
        if distinct
            .iter()
            .all(|q| q.angle_to_degrees(&p.pose) >= DISTINCT_POSE_DEGREES)
        {
            distinct.push(&p.pose);
        }
    }
    if distinct.len() < 2 {
        warnings.push(DepthWarning::FewPoses {
            distinct: distinct.len(),
        });
    }
    let largest_view_angle = photos
        .iter()
        .map(|p| p.pose.view_angle_degrees())
        .fold(0.0, Real::max);
    if largest_view_angle < DISTINCT_POSE_DEGREES {
        warnings.push(DepthWarning::DepthUnobservable { largest_view_angle });
    }
    if !converged {
        warnings.push(DepthWarning::NotConverged { iterations });
    }
    warnings
}
