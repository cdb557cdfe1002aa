//! The frontal 2D structure: one 40-point structure, in the canonical plane, that every photo's
//! points are an affine view of (the paper's §2, eq. 4).
//!
//! A [`FrontalStructure`] is what the depth stage needs from this stage. It has two sources:
//!
//! * [`procrustes_frontal`]: points only. Generalised affine Procrustes over the photos' point
//!   sets and their mirror images, in closed form (see its documentation). It is the fallback
//!   when there are no images, and the baseline the image-based path is measured against.
//! * [`rasl_frontal`] (the image-based path, Peng, Ganesh, Wright, Xu & Ma): low-rank batch
//!   alignment of the photos themselves; it produces the same [`FrontalStructure`], with
//!   [`FrontalMethod::Rasl`].
//!
//! Both take [`PhotoPoints`]: a photo's 40 structure points in image pixels (`v` down), named
//! so that errors can say which photo is wrong.

mod agreement;
mod image;
mod procrustes;
mod rasl;

pub use agreement::{
    AGREEMENT_FLOOR, AGREEMENT_RATIO, PATCH_SIDE, PATCH_STEP, disagreeing_photos, landmark_agreement,
};
pub(crate) use image::central_differences;
pub use image::{
    GreyImage, MAX_PIXELS, MIN_SIDE, PhotoError, PhotoProblem, decode_photo, decode_photo_bytes,
};
pub use procrustes::procrustes_frontal;
pub use rasl::{Dropped, RaslOptions, RaslPhoto, RaslResult, rasl_frontal, singular_value_threshold};

use nalgebra::{Matrix2x3, Point2, Vector2};

use crate::Real;
use crate::structure::{self, LEFT_EYE_CENTRE, POINT_COUNT, RIGHT_EYE_CENTRE, StructureError};

/// One photo's 40 structure points, in image pixels (`u` right, `v` down).
#[derive(Debug, Clone, PartialEq)]
pub struct PhotoPoints {
    /// A name for messages: usually the photo's or landmark file's name.
    pub name: String,
    /// The 40 points, in structure order.
    pub points: Vec<Point2<Real>>,
    /// The inner lips, iBUG points 60–67 in order, when the landmarker gave the 68 iBUG points;
    /// empty otherwise. They are not among the 40: the face-space fit reads an open mouth from
    /// them ([`PhotoPoints::lip_gaps_y_up`]).
    pub inner_lips: Vec<Point2<Real>>,
}

/// The first iBUG point of [`PhotoPoints::inner_lips`].
pub const FIRST_INNER_LIP: usize = 60;

/// How many points [`PhotoPoints::inner_lips`] holds when it holds any.
pub const INNER_LIP_COUNT: usize = 8;

impl PhotoPoints {
    /// A photo's points, checked: exactly 40 finite points with distinct eye centres.
    ///
    /// # Errors
    /// [`AlignError::Points`] naming the photo.
    pub fn new(name: impl Into<String>, points: Vec<Point2<Real>>) -> Result<Self, AlignError> {
        let photo = Self {
            name: name.into(),
            points,
            inner_lips: Vec::new(),
        };
        photo.validate()?;
        Ok(photo)
    }

    /// A photo's points from the 68 iBUG points (see [`structure::from_ibug68`]), with its
    /// inner lips.
    ///
    /// # Errors
    /// [`AlignError::Points`] naming the photo.
    pub fn from_ibug68(name: impl Into<String>, ibug: &[Point2<Real>]) -> Result<Self, AlignError> {
        let name = name.into();
        match structure::from_ibug68(ibug) {
            Ok(points) => {
                let photo = Self {
                    name,
                    points,
                    inner_lips: ibug[FIRST_INNER_LIP..FIRST_INNER_LIP + INNER_LIP_COUNT].to_vec(),
                };
                photo.validate()?;
                Ok(photo)
            }
            Err(source) => Err(AlignError::Points { photo: name, source }),
        }
    }

    /// The inner lips' gaps ([`structure::inner_lip_gaps`]) with `y` up, or `None` without
    /// [`PhotoPoints::inner_lips`].
    pub fn lip_gaps_y_up(&self) -> Option<[Vector2<Real>; 3]> {
        (self.inner_lips.len() == INNER_LIP_COUNT).then(|| {
            structure::inner_lip_gaps(|i| self.inner_lips[i - FIRST_INNER_LIP].coords)
                .map(|d| Vector2::new(d.x, -d.y))
        })
    }

    /// Checks what [`PhotoPoints::new`] checks (the fields are public, so callers that built
    /// the value by hand are checked again by every stage).
    ///
    /// # Errors
    /// [`AlignError::Points`] naming the photo.
    pub fn validate(&self) -> Result<(), AlignError> {
        let fail = |source| AlignError::Points {
            photo: self.name.clone(),
            source,
        };
        if self.points.len() != POINT_COUNT {
            return Err(fail(StructureError::WrongPointCount {
                got: self.points.len(),
                expected: POINT_COUNT,
            }));
        }
        if let Some(index) = self
            .points
            .iter()
            .position(|p| !(p.x.is_finite() && p.y.is_finite()))
        {
            return Err(fail(StructureError::NonFinitePoint { index }));
        }
        let eyes = self.points[LEFT_EYE_CENTRE] - self.points[RIGHT_EYE_CENTRE];
        if !(eyes.norm() > 0.0 && eyes.norm().is_finite()) {
            return Err(fail(StructureError::CoincidentEyes));
        }
        let lips = |problem: String| AlignError::InnerLips {
            photo: self.name.clone(),
            problem,
        };
        if !(self.inner_lips.is_empty() || self.inner_lips.len() == INNER_LIP_COUNT) {
            return Err(lips(format!(
                "{} points, expected none or {INNER_LIP_COUNT}",
                self.inner_lips.len()
            )));
        }
        if let Some(k) = self
            .inner_lips
            .iter()
            .position(|p| !(p.x.is_finite() && p.y.is_finite()))
        {
            return Err(lips(format!("point {} is not finite", FIRST_INNER_LIP + k)));
        }
        Ok(())
    }

    /// The points with `y` up (`(u, v) ↦ (u, −v)`), the orientation of the canonical plane.
    pub fn y_up(&self) -> Vec<Point2<Real>> {
        self.points.iter().map(|p| Point2::new(p.x, -p.y)).collect()
    }

    /// The points of the mirror image of the photo, `y` up: `x ↦ −x` and mirror partners
    /// swapped, so that the mirror image of a face is labelled as a face.
    pub fn mirrored_y_up(&self) -> Vec<Point2<Real>> {
        structure::POINTS
            .iter()
            .map(|def| {
                let p = self.points[def.mirror];
                Point2::new(-p.x, -p.y)
            })
            .collect()
    }
}

/// Where a frontal structure came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrontalMethod {
    /// Generalised affine Procrustes over the points ([`procrustes_frontal`]).
    Procrustes,
    /// RASL batch alignment of the images.
    Rasl,
}

/// The frontal 2D structure and the warps that carry each photo's points onto it.
#[derive(Debug, Clone, PartialEq)]
pub struct FrontalStructure {
    /// The 40 frontal points in the canonical plane: eye centres at `(±25, 0)`, `y` up.
    pub points: Vec<Point2<Real>>,
    /// Per photo, in input order: the affine map `[A | t]` (`2 × 3`) from its `y`-up points
    /// ([`PhotoPoints::y_up`]) to the canonical plane.
    pub warps: Vec<Matrix2x3<Real>>,
    /// Per photo: the same for its mirror image ([`PhotoPoints::mirrored_y_up`]).
    pub mirror_warps: Vec<Matrix2x3<Real>>,
    /// The RMS distance between the warped points (photos and mirrors) and the frontal points,
    /// in canonical units: how far the photos are from being affine views of one structure.
    pub residual_rms: Real,
    /// How it was made.
    pub method: FrontalMethod,
}

impl FrontalStructure {
    /// The frontal points checked for use: 40 finite points, eye centres at `(±25, 0)`.
    ///
    /// # Errors
    /// [`AlignError::Frontal`] saying what is wrong.
    pub fn validate(&self) -> Result<(), AlignError> {
        if self.points.len() != POINT_COUNT {
            return Err(AlignError::Frontal {
                problem: format!("{} points, expected {POINT_COUNT}", self.points.len()),
            });
        }
        if let Some(k) = self
            .points
            .iter()
            .position(|p| !(p.x.is_finite() && p.y.is_finite()))
        {
            return Err(AlignError::Frontal {
                problem: format!("point {k} is not finite"),
            });
        }
        let right = self.points[RIGHT_EYE_CENTRE] - Point2::new(-structure::HALF_EYE_DISTANCE, 0.0);
        let left = self.points[LEFT_EYE_CENTRE] - Point2::new(structure::HALF_EYE_DISTANCE, 0.0);
        if right.norm() + left.norm() > 1e-6 {
            return Err(AlignError::Frontal {
                problem: "the eye centres are not at (±25, 0): the structure is not in the canonical plane"
                    .to_owned(),
            });
        }
        Ok(())
    }
}

/// Applies a `2 × 3` affine map `[A | t]` to a point.
pub fn apply_affine(warp: &Matrix2x3<Real>, p: &Point2<Real>) -> Point2<Real> {
    Point2::from(warp.fixed_view::<2, 2>(0, 0) * p.coords + Vector2::new(warp[(0, 2)], warp[(1, 2)]))
}

/// What can go wrong finding the frontal structure.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum AlignError {
    /// No photo was given.
    #[error("no photos: at least one is needed")]
    NoPhotos,
    /// A photo's points are unusable.
    #[error("photo {photo}: {source}")]
    Points {
        /// The photo's name.
        photo: String,
        /// What is wrong with its points.
        source: StructureError,
    },
    /// A photo's inner lips ([`PhotoPoints::inner_lips`]) are not 8 finite points.
    #[error("photo {photo}: the inner lips (iBUG 60–67): {problem}")]
    InnerLips {
        /// The photo's name.
        photo: String,
        /// What is wrong.
        problem: String,
    },
    /// A photo's points do not span the plane (all on one line, or all at one place), so no
    /// affine map can carry them onto a face.
    #[error("photo {photo}: the points lie on a line; they cannot be a face")]
    Degenerate {
        /// The photo's name.
        photo: String,
    },
    /// A frontal structure handed in is unusable.
    #[error("frontal structure: {problem}")]
    Frontal {
        /// What is wrong.
        problem: String,
    },
}
