//! The paper's 40-point face structure: its points, groups and mirror partners, and its
//! derivation from the 68-point iBUG / 300-W annotation that common landmark detectors produce.
//!
//! The 40 points, in order (iBUG indices are 0-based; "mean" averages the listed points):
//!
//! | indices | group | iBUG-68 source |
//! |---|---|---|
//! | 0–8 | contour | 0, 2, 4, 6, 8, 10, 12, 14, 16 |
//! | 9–14 | brows | 17, 19, 21, 22, 24, 26 |
//! | 15–22 | eyes | 36, mean(37, 38), 39, mean(40, 41), 42, mean(43, 44), 45, mean(46, 47) |
//! | 23–24 | eye centres | mean(36..=41) (the subject's right eye), mean(42..=47) |
//! | 25–31 | nose | 27, 28, 29, 30, 31, 33, 35 |
//! | 32–39 | mouth | 48, 50, 51, 52, 54, 56, 57, 58 |
//!
//! Each point has a mirror partner (the point a left–right flip of the face puts in its
//! place); points on the symmetry axis are their own partners.
//!
//! Also here: [`unify`] / [`unify_2d`] (the canonical frame: eye centres at `(±25, 0, 0)`),
//! [`delaunay_edges`], the seven [`substructures`] of the paper's Fig. 3, [`edge_lengths`],
//! [`ssim`] and the multi-substructure similarity [`multi_substructure_similarity`].

mod frame;
mod similarity;

pub use frame::{HALF_EYE_DISTANCE, unify, unify_2d};
pub use similarity::{
    correlation, delaunay_edges, edge_lengths, multi_substructure_similarity,
    multi_substructure_similarity_gradient, ssim, substructures,
};

use nalgebra::{Point, Point3, SVector};

use crate::Real;

/// Number of points in the structure.
pub const POINT_COUNT: usize = 40;

/// Number of points in the iBUG / 300-W annotation.
pub const IBUG_POINT_COUNT: usize = 68;

/// The iBUG-68 point a left–right flip of the face puts in each point's place (its mirror
/// partner; points on the symmetry axis are their own).
pub const IBUG_MIRROR: [usize; IBUG_POINT_COUNT] = [
    16, 15, 14, 13, 12, 11, 10, 9, 8, 7, 6, 5, 4, 3, 2, 1, 0, 26, 25, 24, 23, 22, 21, 20, 19, 18, 17, 27, 28,
    29, 30, 35, 34, 33, 32, 31, 45, 44, 43, 42, 47, 46, 39, 38, 37, 36, 41, 40, 54, 53, 52, 51, 50, 49, 48,
    59, 58, 57, 56, 55, 64, 63, 62, 61, 60, 67, 66, 65,
];

/// The inner lips' facing pairs in the iBUG-68 annotation, `(upper, lower)`: 61–67, 62–66 and
/// 63–65. The 40 points hold the outer lips only, whose height a face's shape varies as
/// much as an open mouth does; the gap between the inner lips is the open mouth itself
/// (closed in a neutral face).
pub const INNER_LIP_PAIRS: [(usize, usize); 3] = [(61, 67), (62, 66), (63, 65)];

/// The inner lips' gaps: for each of [`INNER_LIP_PAIRS`], the lower point minus the upper
/// one, `at(i)` giving iBUG point `i` (a place, or a mode's displacement of it).
pub fn inner_lip_gaps<V: std::ops::Sub<Output = V>>(at: impl Fn(usize) -> V) -> [V; 3] {
    INNER_LIP_PAIRS.map(|(upper, lower)| at(lower) - at(upper))
}

/// Index of the subject's right eye centre (image left), `O₁ = (−25, 0, 0)` in the canonical
/// frame.
pub const RIGHT_EYE_CENTRE: usize = 23;

/// Index of the subject's left eye centre (image right), `O₂ = (25, 0, 0)`.
pub const LEFT_EYE_CENTRE: usize = 24;

/// The facial organ a structure point belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Group {
    /// The jaw line.
    Contour,
    /// The eyebrows.
    Brows,
    /// Eye corners and eyelid midpoints.
    Eyes,
    /// The two eye centres.
    EyeCentres,
    /// The nose bridge, tip and wings.
    Nose,
    /// Lip corners and lip midpoints.
    Mouth,
}

/// One point of the structure.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PointDefinition {
    /// A stable name, usable as a key in files.
    pub name: &'static str,
    /// Its organ.
    pub group: Group,
    /// The iBUG-68 points it is the mean of (one point for most).
    pub ibug_sources: &'static [usize],
    /// The index of its mirror partner in the structure.
    pub mirror: usize,
}

const fn def(
    name: &'static str,
    group: Group,
    ibug_sources: &'static [usize],
    mirror: usize,
) -> PointDefinition {
    PointDefinition {
        name,
        group,
        ibug_sources,
        mirror,
    }
}

use Group::*;

/// The 40 points, in structure order (see the module documentation).
pub const POINTS: [PointDefinition; POINT_COUNT] = [
    def("contour_right_ear", Contour, &[0], 8),
    def("contour_right_upper", Contour, &[2], 7),
    def("contour_right_cheek", Contour, &[4], 6),
    def("contour_right_jaw", Contour, &[6], 5),
    def("contour_chin", Contour, &[8], 4),
    def("contour_left_jaw", Contour, &[10], 3),
    def("contour_left_cheek", Contour, &[12], 2),
    def("contour_left_upper", Contour, &[14], 1),
    def("contour_left_ear", Contour, &[16], 0),
    def("brow_right_outer", Brows, &[17], 14),
    def("brow_right_middle", Brows, &[19], 13),
    def("brow_right_inner", Brows, &[21], 12),
    def("brow_left_inner", Brows, &[22], 11),
    def("brow_left_middle", Brows, &[24], 10),
    def("brow_left_outer", Brows, &[26], 9),
    def("eye_right_outer", Eyes, &[36], 21),
    def("eye_right_upper", Eyes, &[37, 38], 20),
    def("eye_right_inner", Eyes, &[39], 19),
    def("eye_right_lower", Eyes, &[40, 41], 22),
    def("eye_left_inner", Eyes, &[42], 17),
    def("eye_left_upper", Eyes, &[43, 44], 16),
    def("eye_left_outer", Eyes, &[45], 15),
    def("eye_left_lower", Eyes, &[46, 47], 18),
    def("eye_right_centre", EyeCentres, &[36, 37, 38, 39, 40, 41], 24),
    def("eye_left_centre", EyeCentres, &[42, 43, 44, 45, 46, 47], 23),
    def("nose_bridge_top", Nose, &[27], 25),
    def("nose_bridge_upper", Nose, &[28], 26),
    def("nose_bridge_lower", Nose, &[29], 27),
    def("nose_tip", Nose, &[30], 28),
    def("nose_right_wing", Nose, &[31], 31),
    def("nose_base", Nose, &[33], 30),
    def("nose_left_wing", Nose, &[35], 29),
    def("mouth_right_corner", Mouth, &[48], 36),
    def("mouth_upper_right", Mouth, &[50], 35),
    def("mouth_upper_middle", Mouth, &[51], 34),
    def("mouth_upper_left", Mouth, &[52], 33),
    def("mouth_left_corner", Mouth, &[54], 32),
    def("mouth_lower_left", Mouth, &[56], 39),
    def("mouth_lower_middle", Mouth, &[57], 38),
    def("mouth_lower_right", Mouth, &[58], 37),
];

/// What can be wrong with points handed to the structure functions.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum StructureError {
    /// The wrong number of points.
    #[error("expected {expected} points, got {got}")]
    WrongPointCount {
        /// Points given.
        got: usize,
        /// Points needed.
        expected: usize,
    },
    /// A point has a NaN or infinite coordinate.
    #[error("point {index} is not finite")]
    NonFinitePoint {
        /// Its index in the input.
        index: usize,
    },
    /// Two points share a position where they must not.
    #[error("points {first} and {second} coincide")]
    DuplicatePoint {
        /// The first of them.
        first: usize,
        /// The second.
        second: usize,
    },
    /// The two eye centres coincide (or are too far apart for their distance to be
    /// represented), so no canonical frame exists.
    #[error("the eye centres coincide, or their distance overflows")]
    CoincidentEyes,
}

/// The 40 structure points from the 68 iBUG points, in 2D (image) or 3D.
///
/// # Errors
/// [`StructureError::WrongPointCount`] unless exactly 68 points are given,
/// [`StructureError::NonFinitePoint`] for a NaN or infinite coordinate.
///
/// # Examples
///
/// ```
/// use nalgebra::Point2;
/// use splineface::structure::{from_ibug68, RIGHT_EYE_CENTRE};
///
/// let ibug: Vec<Point2<f64>> = (0..68).map(|i| Point2::new(i as f64, 0.0)).collect();
/// let points = from_ibug68(&ibug)?;
/// assert_eq!(points.len(), 40);
/// assert_eq!(points[RIGHT_EYE_CENTRE].x, 38.5); // mean of 36..=41
/// # Ok::<(), splineface::structure::StructureError>(())
/// ```
pub fn from_ibug68<const D: usize>(ibug: &[Point<Real, D>]) -> Result<Vec<Point<Real, D>>, StructureError> {
    check_points(ibug, IBUG_POINT_COUNT)?;
    Ok(POINTS
        .iter()
        .map(|def| {
            let sum: SVector<Real, D> = def.ibug_sources.iter().map(|&i| ibug[i].coords).sum();
            Point::from(sum / def.ibug_sources.len() as Real)
        })
        .collect())
}

/// Per-point weights: `contour` on the 9 contour points, 1 elsewhere (the contour's points
/// are where a landmarker's jaw points land, the least reliable of the 40).
pub fn contour_weighted(contour: Real) -> [Real; POINT_COUNT] {
    std::array::from_fn(|k| {
        if POINTS[k].group == Group::Contour {
            contour
        } else {
            1.0
        }
    })
}

/// The structure with every point moved to its mirror partner's place (`out[k] =
/// points[mirror(k)]`): the labelling of the same points seen in a mirror. Applying it twice is
/// the identity.
///
/// # Errors
/// As [`from_ibug68`], for 40 points.
pub fn swap_partners<const D: usize>(
    points: &[Point<Real, D>],
) -> Result<Vec<Point<Real, D>>, StructureError> {
    check_points(points, POINT_COUNT)?;
    Ok(POINTS.iter().map(|def| points[def.mirror]).collect())
}

/// The mirror image of a structure in the canonical frame: `x ↦ −x` and partners swapped, so
/// that a symmetric face is its own mirror image.
///
/// # Errors
/// As [`swap_partners`].
pub fn mirrored_canonical(points: &[Point3<Real>]) -> Result<Vec<Point3<Real>>, StructureError> {
    Ok(swap_partners(points)?
        .into_iter()
        .map(|p| Point3::new(-p.x, p.y, p.z))
        .collect())
}

fn check_points<const D: usize>(points: &[Point<Real, D>], expected: usize) -> Result<(), StructureError> {
    if points.len() != expected {
        return Err(StructureError::WrongPointCount {
            got: points.len(),
            expected,
        });
    }
    match points
        .iter()
        .position(|p| !p.coords.iter().all(|c| c.is_finite()))
    {
        Some(index) => Err(StructureError::NonFinitePoint { index }),
        None => Ok(()),
    }
}
