//! Unification into the canonical frame: the similarity transform that puts the eye centres at
//! `O₁ = (−25, 0, 0)` and `O₂ = (25, 0, 0)`.

use nalgebra::{
    Point2, Point3, Rotation2, Rotation3, Similarity2, Similarity3, Translation2, Translation3,
    UnitQuaternion, Vector2, Vector3,
};

use super::{LEFT_EYE_CENTRE, POINT_COUNT, RIGHT_EYE_CENTRE, StructureError, check_points};
use crate::Real;

/// Half the distance between the eye centres in the canonical frame (the paper's 50 units).
pub const HALF_EYE_DISTANCE: Real = 25.0;

/// The similarity that maps a 3D structure into the canonical frame, and the mapped points.
///
/// Two points fix a 3D similarity only up to a rotation about the line through them. The
/// choice here is the *smallest* rotation that turns the eye axis onto `+x` (the shortest arc),
/// so a face already roughly in the canonical orientation (`+y` up, `+z` toward the viewer, as
/// scans and the depth stage deliver them) keeps its up and forward directions.
///
/// # Errors
/// The checks of [`super::from_ibug68`] for 40 points, and [`StructureError::CoincidentEyes`]
/// when the eye centres coincide.
pub fn unify(points: &[Point3<Real>]) -> Result<(Similarity3<Real>, Vec<Point3<Real>>), StructureError> {
    check_points(points, POINT_COUNT)?;
    let (right, left) = (points[RIGHT_EYE_CENTRE], points[LEFT_EYE_CENTRE]);
    let axis = left - right;
    let distance = axis.norm();
    if distance == 0.0 || !distance.is_finite() {
        return Err(StructureError::CoincidentEyes);
    }
    let rotation = UnitQuaternion::rotation_between(&axis, &Vector3::x()).unwrap_or_else(|| {
        // Anti-parallel: half a turn about y keeps y up.
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_axis_angle(
            &Vector3::y_axis(),
            std::f64::consts::PI,
        ))
    });
    let scale = 2.0 * HALF_EYE_DISTANCE / distance;
    let middle = nalgebra::center(&right, &left);
    let similarity = Similarity3::from_parts(
        Translation3::from(-(rotation * middle.coords) * scale),
        rotation,
        scale,
    );
    let mapped = points.iter().map(|p| similarity * p).collect();
    Ok((similarity, mapped))
}

/// [`unify`] for 2D points (a frontal structure in the plane); the similarity is fully fixed by
/// the two eye centres. The points are taken as given: an image's `v`-down coordinates must be
/// flipped by the caller first.
///
/// # Errors
/// As [`unify`].
pub fn unify_2d(points: &[Point2<Real>]) -> Result<(Similarity2<Real>, Vec<Point2<Real>>), StructureError> {
    check_points(points, POINT_COUNT)?;
    let (right, left) = (points[RIGHT_EYE_CENTRE], points[LEFT_EYE_CENTRE]);
    let axis: Vector2<Real> = left - right;
    let distance = axis.norm();
    if distance == 0.0 || !distance.is_finite() {
        return Err(StructureError::CoincidentEyes);
    }
    let rotation = Rotation2::new(-axis.y.atan2(axis.x));
    let scale = 2.0 * HALF_EYE_DISTANCE / distance;
    let middle = nalgebra::center(&right, &left);
    let similarity = Similarity2::from_parts(
        Translation2::from(-(rotation * middle.coords) * scale),
        nalgebra::UnitComplex::from_rotation_matrix(&rotation),
        scale,
    );
    let mapped = points.iter().map(|p| similarity * p).collect();
    Ok((similarity, mapped))
}
