//! Whether the photos' landmarks mark the same places of the face: a small patch of each photo
//! about each landmark, compared with the same landmark's patch in the other photos.
//!
//! A landmarker can fail without saying so: on a face turned by 35° or more, dlib's model
//! sometimes converges to a face turned the other way, its points a plausible face that lies
//! on the cheek and ear. Such points are a consistent view of *some* face, so the geometry of
//! the batch barely shows them (measured on rendered photos, `tools/photo_eval`: their
//! reprojection error left out of the fit was 3.5 units against 1.4–3.0 for good photos in the
//! same batch). Their pixels do: an eye corner looks like an eye corner from any side, and a
//! cheek does not. On the same photos the agreement defined here was 0.38–0.93 for every
//! photo whose points were right and −0.09–0.08 for every photo whose points were off by
//! more than 20% of the eye distance.

use nalgebra::{Point2, Vector2};

use super::{GreyImage, PhotoPoints};
use crate::Real;
use crate::structure::{Group, LEFT_EYE_CENTRE, POINT_COUNT, POINTS, RIGHT_EYE_CENTRE};

/// Samples along each side of a patch.
pub const PATCH_SIDE: usize = 9;

/// The distance between a patch's samples, as a fraction of the photo's eye distance (so a
/// patch spans a fifth of it, whatever the photo's resolution).
pub const PATCH_STEP: Real = 0.025;

/// A photo whose [`landmark_agreement`] is below this...
pub const AGREEMENT_FLOOR: Real = 0.25;

/// ...and below this fraction of the median of the other photos' disagrees with them
/// ([`disagreeing_photos`]).
pub const AGREEMENT_RATIO: Real = 0.5;

/// A patch about `centre`, its axes along and across the eye axis, normalised to zero mean and
/// unit norm (`None` when it is flat).
fn patch(image: &GreyImage, centre: Point2<Real>, axis: Vector2<Real>, step: Real) -> Option<Vec<Real>> {
    let across = Vector2::new(-axis.y, axis.x);
    let half = (PATCH_SIDE / 2) as i64;
    let mut values = Vec::with_capacity(PATCH_SIDE * PATCH_SIDE);
    for b in -half..=half {
        for a in -half..=half {
            let q = centre + axis * (a as Real * step) + across * (b as Real * step);
            values.push(Real::from(image.sample(image.data(), q.x, q.y)));
        }
    }
    let mean = values.iter().sum::<Real>() / values.len() as Real;
    values.iter_mut().for_each(|v| *v -= mean);
    let norm = values.iter().map(|v| v * v).sum::<Real>().sqrt();
    if norm.is_nan() || norm <= 1e-6 {
        return None;
    }
    values.iter_mut().for_each(|v| *v /= norm);
    Some(values)
}

/// The median of some values (`NaN` for none).
fn median(mut values: Vec<Real>) -> Real {
    if values.is_empty() {
        return Real::NAN;
    }
    values.sort_by(Real::total_cmp);
    let n = values.len();
    if n % 2 == 1 {
        values[n / 2]
    } else {
        (values[n / 2 - 1] + values[n / 2]) / 2.0
    }
}

/// How well each photo's landmarks agree with the others': for each of its 31 points off the
/// contour (jaw points sit on a turned face's outline, not on one place of it), the median
/// over the other photos of the normalised cross-correlation between the two photos' patches
/// about that point ([`PATCH_SIDE`]² samples, [`PATCH_STEP`] apart, turned with the eye
/// axis); the photo's agreement is the median over its points. 1 is perfect; unrelated patches
/// give about 0. `NaN` for a photo with no other to compare with.
pub fn landmark_agreement(photos: &[(&GreyImage, &PhotoPoints)]) -> Vec<Real> {
    let inner: Vec<usize> = (0..POINT_COUNT)
        .filter(|&k| POINTS[k].group != Group::Contour)
        .collect();
    let patches: Vec<Vec<Option<Vec<Real>>>> = photos
        .iter()
        .map(|(image, points)| {
            let p = &points.points;
            let eyes = p[LEFT_EYE_CENTRE] - p[RIGHT_EYE_CENTRE];
            let distance = eyes.norm();
            let axis = eyes / distance.max(Real::MIN_POSITIVE);
            inner
                .iter()
                .map(|&k| patch(image, p[k], axis, PATCH_STEP * distance))
                .collect()
        })
        .collect();
    (0..photos.len())
        .map(|i| {
            let per_point: Vec<Real> = (0..inner.len())
                .filter_map(|k| {
                    let mine = patches[i][k].as_ref()?;
                    let others: Vec<Real> = (0..photos.len())
                        .filter(|&j| j != i)
                        .filter_map(|j| patches[j][k].as_ref())
                        .map(|theirs| mine.iter().zip(theirs).map(|(a, b)| a * b).sum())
                        .collect();
                    (!others.is_empty()).then(|| median(others))
                })
                .collect();
            median(per_point)
        })
        .collect()
}

/// The photos (indices) whose [`landmark_agreement`] is below [`AGREEMENT_FLOOR`] and below
/// [`AGREEMENT_RATIO`] times the median of the others', with that median. With fewer than
/// three photos none is singled out: two that disagree cannot say which is wrong.
pub fn disagreeing_photos(agreement: &[Real]) -> Vec<(usize, Real)> {
    if agreement.len() < 3 {
        return Vec::new();
    }
    (0..agreement.len())
        .filter_map(|i| {
            let others = median(
                agreement
                    .iter()
                    .enumerate()
                    .filter(|&(j, a)| j != i && a.is_finite())
                    .map(|(_, &a)| a)
                    .collect(),
            );
            let a = agreement[i];
            (a < AGREEMENT_FLOOR && a < AGREEMENT_RATIO * others).then_some((i, others))
        })
        .collect()
}
