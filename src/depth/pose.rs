//! A photo's pose under the scaled orthographic camera, and its least-squares fit.

use nalgebra::{Matrix2x3, Matrix3, Matrix4, Point2, Point3, Rotation3, Vector3, Vector4};

use crate::Real;

/// The pose of a photo under a scaled orthographic camera: a structure point `X` (canonical
/// frame) is seen at `s · P · R · X`, `P` keeping the first two coordinates.
///
/// Angles ([`Pose::yaw_pitch_roll_degrees`]) follow `R = R_z(roll) · R_x(pitch) · R_y(yaw)`:
/// the face turns about its vertical axis first, then tips, then rolls in the picture plane.
/// Positive yaw turns the nose toward the image's right (the subject's left); positive pitch
/// tips the nose down (the face looks down); positive roll turns the face counter-clockwise as
/// the viewer sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// `R`, from the canonical frame to the camera's.
    pub rotation: Rotation3<Real>,
    /// `s`: image units per canonical unit.
    pub scale: Real,
}

impl Pose {
    /// The pose with the given angles (degrees, see the type's documentation) and scale.
    pub fn from_yaw_pitch_roll_degrees(yaw: Real, pitch: Real, roll: Real, scale: Real) -> Self {
        let rotation = Rotation3::from_axis_angle(&Vector3::z_axis(), roll.to_radians())
            * Rotation3::from_axis_angle(&Vector3::x_axis(), pitch.to_radians())
            * Rotation3::from_axis_angle(&Vector3::y_axis(), yaw.to_radians());
        Self { rotation, scale }
    }

    /// `[yaw, pitch, roll]` in degrees, pitch in `[−90, 90]`.
    pub fn yaw_pitch_roll_degrees(&self) -> [Real; 3] {
        let r = self.rotation.matrix();
        // Third row of R_z R_x R_y is (−cos p sin y, sin p, cos p cos y); R_z leaves it alone.
        let pitch = r[(2, 1)].clamp(-1.0, 1.0).asin();
        let yaw = (-r[(2, 0)]).atan2(r[(2, 2)]);
        // Column 1 of R_x R_y is (0, cos p, sin p); R_z turns its first two entries by roll.
        let roll = (-r[(0, 1)]).atan2(r[(1, 1)]);
        [yaw.to_degrees(), pitch.to_degrees(), roll.to_degrees()]
    }

    /// Where the pose sees a point: `s · P · R · X`.
    pub fn project(&self, point: &Point3<Real>) -> Point2<Real> {
        let q = self.rotation * point;
        Point2::new(self.scale * q.x, self.scale * q.y)
    }

    /// The angle of the rotation between two poses, in degrees (robust near 0, where the
    /// trace formula loses its accuracy).
    pub fn angle_to_degrees(&self, other: &Pose) -> Real {
        let q = nalgebra::UnitQuaternion::from_rotation_matrix(&(self.rotation.inverse() * other.rotation));
        (2.0 * q.imag().norm().atan2(q.w.abs())).to_degrees()
    }

    /// The angle between the camera's view direction and the face's forward axis (`+z`), in
    /// degrees: 0 for a frontal photo.
    pub fn view_angle_degrees(&self) -> Real {
        self.rotation[(2, 2)].clamp(-1.0, 1.0).acos().to_degrees()
    }
}

/// The closed-form start: the least-squares `2 × 3` map `M` from `structure` to `view`, then the
/// nearest scaled map with orthonormal rows (`M = U Σ Vᵀ` gives `s R₁₂ = mean(σ) · U Vᵀ`); the
/// third row of `R` is the cross product of the first two. `None` when the structure is
/// degenerate (all points on a line).
pub(crate) fn closed_form_pose(
    view: &[Point2<Real>],
    structure: &[Point3<Real>],
    weights: &[Real],
) -> Option<Pose> {
    let mut cross = Matrix2x3::zeros(); // Σ wⱼ xⱼ Xⱼᵀ
    let mut gram = Matrix3::zeros(); // Σ wⱼ Xⱼ Xⱼᵀ
    for ((x, p), w) in view.iter().zip(structure).zip(weights) {
        cross += *w * x.coords * p.coords.transpose();
        gram += *w * p.coords * p.coords.transpose();
    }
    // A planar structure (every depth equal) leaves the third column free: the pseudo-inverse
    // gives the map with no depth term, a rotation in the picture plane.
    let inverse = gram
        .try_inverse()
        .or_else(|| gram.pseudo_inverse(1e-12 * gram.norm()).ok())?;
    let map = cross * inverse;
    let svd = map.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let scale = (svd.singular_values[0] + svd.singular_values[1]) / 2.0;
    if !(scale > 0.0 && scale.is_finite()) {
        return None;
    }
    let rows = u * v_t;
    let r0 = Vector3::new(rows[(0, 0)], rows[(0, 1)], rows[(0, 2)]);
    let r1 = Vector3::new(rows[(1, 0)], rows[(1, 1)], rows[(1, 2)]);
    let r2 = r0.cross(&r1);
    let matrix = Matrix3::from_rows(&[r0.transpose(), r1.transpose(), r2.transpose()]);
    Some(Pose {
        // Re-orthonormalised against rounding.
        rotation: Rotation3::from_matrix(&matrix),
        scale,
    })
}

/// The weighted sum of squared reprojection errors of a pose.
pub(crate) fn reprojection_cost(
    pose: &Pose,
    view: &[Point2<Real>],
    structure: &[Point3<Real>],
    weights: &[Real],
) -> Real {
    view.iter()
        .zip(structure)
        .zip(weights)
        .map(|((x, p), w)| w * (x - pose.project(p)).norm_squared())
        .sum()
}

/// Levenberg–Marquardt refinement of a pose over its 4 parameters (a rotation vector applied
/// on the left, and the scale), from `start`. Never returns a pose worse than `start`.
pub(crate) fn refine_pose(
    start: Pose,
    view: &[Point2<Real>],
    structure: &[Point3<Real>],
    weights: &[Real],
) -> Pose {
    let mut pose = start;
    let mut cost = reprojection_cost(&pose, view, structure, weights);
    let mut damping = 1e-6;
    for _ in 0..50 {
        // Model mⱼ = s P exp([ω]×) R Xⱼ; at ω = 0: ∂m/∂ω = −s P [qⱼ]×, ∂m/∂s = P qⱼ, qⱼ = R Xⱼ.
        let mut normal = Matrix4::zeros();
        let mut rhs = Vector4::zeros();
        for ((x, p), &w) in view.iter().zip(structure).zip(weights) {
            let q = pose.rotation * p.coords;
            let s = pose.scale;
            // Rows of −s P [q]×: [q]× = [[0, −q_z, q_y], [q_z, 0, −q_x], [−q_y, q_x, 0]].
            let j0 = Vector4::new(0.0, s * q.z, -s * q.y, q.x);
            let j1 = Vector4::new(-s * q.z, 0.0, s * q.x, q.y);
            let r0 = x.x - s * q.x;
            let r1 = x.y - s * q.y;
            normal += w * (j0 * j0.transpose() + j1 * j1.transpose());
            rhs += w * (j0 * r0 + j1 * r1);
        }
        let mut improved = false;
        while damping < 1e12 {
            let mut damped = normal;
            for k in 0..4 {
                damped[(k, k)] += damping * normal[(k, k)].max(1e-12);
            }
            let Some(step) = damped.cholesky().map(|c| c.solve(&rhs)) else {
                damping *= 10.0;
                continue;
            };
            let candidate = Pose {
                rotation: Rotation3::new(Vector3::new(step[0], step[1], step[2])) * pose.rotation,
                scale: pose.scale + step[3],
            };
            let candidate_cost = reprojection_cost(&candidate, view, structure, weights);
            if candidate.scale > 0.0 && candidate_cost <= cost {
                let decrease = cost - candidate_cost;
                pose = candidate;
                cost = candidate_cost;
                damping = (damping / 10.0).max(1e-12);
                improved = decrease > 1e-14 * cost.max(Real::MIN_POSITIVE) && step.norm() > 1e-13;
                break;
            }
            damping *= 10.0;
        }
        if !improved {
            break;
        }
    }
    pose
}
