//! The points-only frontal structure: generalised affine Procrustes, in closed form.

use nalgebra::{Matrix2, Matrix2x3, OMatrix, Point2, SMatrix, U40, Vector2};

use super::{AlignError, FrontalMethod, FrontalStructure, PhotoPoints, apply_affine};
use crate::Real;
use crate::structure::{HALF_EYE_DISTANCE, LEFT_EYE_CENTRE, POINT_COUNT, RIGHT_EYE_CENTRE, unify_2d};

/// A `40 × 3` matrix, one row per structure point.
type Basis = SMatrix<Real, POINT_COUNT, 3>;

/// The frontal structure of a batch of photos from their points alone: generalised affine
/// Procrustes over the photos' point sets and their mirror images (the points-only path of the
/// paper's §2).
///
/// # The method
///
/// The goal is the structure `M` (`40 × 2`) and one affine map per point set such that the
/// mapped sets agree with `M` best in the least-squares sense. An affine map can carry `M` onto
/// any affine image of itself, so the answer is a *subspace* first: the columns `1, x, y` of an
/// affine consensus span the 3-dimensional subspace of `ℝ⁴⁰` closest to every set's own
/// span `{1, xₖ, yₖ}`, which is the top-3 eigenspace `U` of `Σₖ Qₖ Qₖᵀ` (`Qₖ` an orthonormal
/// basis of set `k`'s span). This is solved at once, with no iteration and no risk of the
/// collapse that alternating affine Procrustes suffers (each round shrinks the consensus toward
/// its dominant direction).
///
/// The subspace fixes `M` only up to an affine map, and a choice is needed: `M` is the member of
/// the subspace closest to the mean of the sets unified by similarities (eye centres at
/// `(±25, 0)`), `M = U Uᵀ M_sim`, so that the affine freedom is spent on nothing the photos do
/// not ask for. Each set is then fitted to `M` by an affine map, and the frontal structure is the
/// mean of the mapped sets (the paper's eq. 4), unified so that the eye centres are at
/// `(±25, 0)`.
///
/// Each photo's mirror image (`x ↦ −x`, partners swapped) joins the batch: for a yawed photo it
/// is a photo yawed the other way, which pulls the consensus toward frontal.
///
/// # Errors
/// [`AlignError::NoPhotos`] for an empty batch, [`AlignError::Points`] for a photo with bad
/// points, [`AlignError::Degenerate`] for a photo whose points lie on a line.
///
/// # Examples
///
/// ```
/// use nalgebra::Point2;
/// use splineface::align::{PhotoPoints, procrustes_frontal};
/// use splineface::reference::ReferenceFace;
///
/// // The reference structure seen from the front, 4 pixels a unit, `v` down.
/// let pixels: Vec<Point2<f64>> = ReferenceFace::embedded()
///     .structure()
///     .iter()
///     .map(|p| Point2::new(300.0 + 4.0 * p.x, 200.0 - 4.0 * p.y))
///     .collect();
/// let photo = PhotoPoints::new("front.jpg", pixels)?;
/// let frontal = procrustes_frontal(&[photo])?;
/// let nose_tip = frontal.points[28];
/// assert!(nose_tip.x.abs() < 1e-9 && (nose_tip.y + 23.31).abs() < 0.01);
/// # Ok::<(), splineface::align::AlignError>(())
/// ```
pub fn procrustes_frontal(photos: &[PhotoPoints]) -> Result<FrontalStructure, AlignError> {
    if photos.is_empty() {
        return Err(AlignError::NoPhotos);
    }
    let mut sets = Vec::with_capacity(2 * photos.len());
    for photo in photos {
        photo.validate()?;
        sets.push(photo.y_up());
        sets.push(photo.mirrored_y_up());
    }

    // Σₖ Qₖ Qₖᵀ and its top-3 eigenspace.
    let mut projector_sum = SMatrix::<Real, POINT_COUNT, POINT_COUNT>::zeros();
    for (k, set) in sets.iter().enumerate() {
        let basis = orthonormal_span(set).ok_or_else(|| AlignError::Degenerate {
            photo: photos[k / 2].name.clone(),
        })?;
        projector_sum += basis * basis.transpose();
    }
    let eigen = projector_sum.symmetric_eigen();
    let mut order: Vec<usize> = (0..POINT_COUNT).collect();
    order.sort_by(|&a, &b| eigen.eigenvalues[b].total_cmp(&eigen.eigenvalues[a]));
    let consensus = Basis::from_columns(&[
        eigen.eigenvectors.column(order[0]),
        eigen.eigenvectors.column(order[1]),
        eigen.eigenvectors.column(order[2]),
    ]);

    // The gauge: the member of the consensus subspace nearest the similarity-unified mean.
    let mut similarity_mean = SMatrix::<Real, POINT_COUNT, 2>::zeros();
    for (k, set) in sets.iter().enumerate() {
        let (_, unified) = unify_2d(set).map_err(|source| AlignError::Points {
            photo: photos[k / 2].name.clone(),
            source,
        })?;
        for (j, p) in unified.iter().enumerate() {
            similarity_mean[(j, 0)] += p.x / sets.len() as Real;
            similarity_mean[(j, 1)] += p.y / sets.len() as Real;
        }
    }
    let target = consensus * (consensus.transpose() * similarity_mean);

    // Each set fitted to the target; the frontal structure is the mean of the fitted sets.
    let mut warps = Vec::with_capacity(sets.len());
    for (k, set) in sets.iter().enumerate() {
        let warp = fit_affine(set, &target).ok_or_else(|| AlignError::Degenerate {
            photo: photos[k / 2].name.clone(),
        })?;
        warps.push(warp);
    }
    let mut mean = vec![Point2::origin(); POINT_COUNT];
    for (set, warp) in sets.iter().zip(&warps) {
        for (m, p) in mean.iter_mut().zip(set) {
            m.coords += apply_affine(warp, p).coords / sets.len() as Real;
        }
    }
    let (similarity, mut points) = unify_2d(&mean).map_err(|source| AlignError::Frontal {
        problem: format!("the mean of the aligned photos has no canonical frame: {source}"),
    })?;
    // Exactly where the frame puts them, not a rounding error away.
    points[RIGHT_EYE_CENTRE] = Point2::new(-HALF_EYE_DISTANCE, 0.0);
    points[LEFT_EYE_CENTRE] = Point2::new(HALF_EYE_DISTANCE, 0.0);
    let s = similarity.to_homogeneous().fixed_view::<2, 3>(0, 0).into_owned();
    let s_linear = s.fixed_view::<2, 2>(0, 0).into_owned();
    let warps: Vec<Matrix2x3<Real>> = warps
        .iter()
        .map(|w| {
            let mut composed = s_linear * w;
            composed[(0, 2)] += s[(0, 2)];
            composed[(1, 2)] += s[(1, 2)];
            composed
        })
        .collect();

    let mut squared = 0.0;
    for (set, warp) in sets.iter().zip(&warps) {
        for (f, p) in points.iter().zip(set) {
            squared += (apply_affine(warp, p) - f).norm_squared();
        }
    }
    let residual_rms = (squared / (sets.len() * POINT_COUNT) as Real).sqrt();

    let (warps, mirror_warps) = warps.chunks(2).map(|pair| (pair[0], pair[1])).unzip();
    Ok(FrontalStructure {
        points,
        warps,
        mirror_warps,
        residual_rms,
        method: FrontalMethod::Procrustes,
    })
}

/// An orthonormal basis of the span of `1, x, y` over the points, or `None` when the points lie
/// on a line (relative to their spread).
fn orthonormal_span(points: &[Point2<Real>]) -> Option<Basis> {
    let n = points.len() as Real;
    let centre = points
        .iter()
        .fold(nalgebra::Vector2::zeros(), |s, p| s + p.coords)
        / n;
    let centred = OMatrix::<Real, U40, nalgebra::U2>::from_fn(|j, c| points[j][c] - centre[c]);
    let svd = centred.svd(true, false);
    let u = svd.u?;
    let (s0, s1) = (svd.singular_values[0], svd.singular_values[1]);
    let (big, small) = (s0.max(s1), s0.min(s1));
    if !(big > 0.0 && small > 1e-9 * big) {
        return None;
    }
    let mut basis = Basis::from_element(1.0 / n.sqrt());
    basis.set_column(1, &u.column(0));
    basis.set_column(2, &u.column(1));
    Some(basis)
}

/// The affine map `[A | t]` that carries `from` onto `to` best in the least-squares sense, or
/// `None` when `from` lies on a line.
///
/// Solved on centred coordinates, `A = (Σ t̃ p̃ᵀ)(Σ p̃ p̃ᵀ)⁻¹`, `t = t̄ − A p̄`: a 2 × 2 system that
/// is well conditioned for any non-degenerate point set. (nalgebra's SVD solve of the 40 × 3
/// design `[x y 1]` returned a wrong answer for some sets: the regression test
/// `an_affine_change_of_one_photo_changes_the_result_by_an_affine_map_at_most` found it.)
fn fit_affine(from: &[Point2<Real>], to: &SMatrix<Real, POINT_COUNT, 2>) -> Option<Matrix2x3<Real>> {
    let n = from.len() as Real;
    let from_mean = from.iter().fold(Vector2::zeros(), |s, p| s + p.coords) / n;
    let to_mean = Vector2::new(to.column(0).sum(), to.column(1).sum()) / n;
    let (mut spread, mut cross) = (Matrix2::zeros(), Matrix2::zeros());
    for (j, p) in from.iter().enumerate() {
        let a = p.coords - from_mean;
        let b = Vector2::new(to[(j, 0)], to[(j, 1)]) - to_mean;
        spread += a * a.transpose();
        cross += b * a.transpose();
    }
    let linear = cross * spread.try_inverse()?;
    let translation = to_mean - linear * from_mean;
    Some(crate::geometry::affine(&linear, &translation))
}
