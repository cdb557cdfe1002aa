//! The jaw's points where a landmarker puts them: on the face's outline as each photo sees it.
//!
//! A 68-point landmarker puts the jaw points off the chin (iBUG 0–5 and 11–16, the
//! structure's contour points 0–2 and 6–8) on the face's visible outline at their height, not
//! on fixed places of the face: on the side a photo turns away from the camera the outline is
//! the occluding contour, which moves in toward the nose as the face turns (eos's contour
//! fitting models the same behaviour). A fit that ties those points to fixed places of the
//! face reads the turn as a narrower face; the depth stage gives them a tenth of the other
//! points' weight for that reason.
//!
//! [`Outline`] finds where a face space's mean face shows its outline to a camera: along the
//! surface's line through each such point at the point's height, from the point in to the
//! middle of the face, the place the camera sees farthest toward the point's side. On a
//! frontal view, or on the side turned toward the camera, that is the point's own place; on
//! the side turned away it moves in. [`FaceSpace::fit_photos`] then measures each photo's jaw
//! points against those places.

use nalgebra::{Matrix2x3, Point3, Vector2, Vector3};

use super::FaceError;
use super::space::FaceSpace;
use crate::Real;
use crate::structure::POINT_COUNT;

/// The structure's contour points that a landmarker puts on the outline (iBUG 0, 2, 4 and 12,
/// 14, 16); the three about the chin (iBUG 6, 8, 10) stay where the face puts them.
pub const OUTLINE_POINTS: [usize; 6] = [0, 1, 2, 6, 7, 8];

/// Samples a side of the lattice on which each point's place on the surface is found.
const LATTICE: usize = 128;

/// Samples along each point's line, from the point to the middle of the face (about half a
/// canonical unit apart on the reference: the jaw points lie 45–57 units out). Where the
/// outline is, the projection that picks it is stationary, so the place it gives is off by
/// far less than the spacing across the image (the synthetic test of `fit_photos` recovers
/// the weights to 0.002).
const LINE: usize = 96;

/// The candidate outline places of a face space's mean face: per point of
/// [`OUTLINE_POINTS`], the surface's samples along its line, the point's own place first.
#[derive(Debug, Clone)]
pub(crate) struct Outline {
    lines: Vec<Vec<Point3<Real>>>,
}

/// Where a face shows its outline to one camera: per point of [`OUTLINE_POINTS`], the
/// surface's point at the point's own place and the one on the outline.
pub(crate) type OutlinePlaces = [(Point3<Real>, Point3<Real>); OUTLINE_POINTS.len()];

impl Outline {
    /// The lines of `space`'s mean face: each point's place on the surface is the nearest
    /// sample of a [`LATTICE`]² lattice of its parameter square, and its line runs at that
    /// place's `v` from its `u` to the middle of the `u` range.
    ///
    /// # Errors
    /// [`FaceError::Space`] if the space's surface cannot be evaluated (it can: it was checked
    /// when the space was made).
    pub(crate) fn new(space: &FaceSpace) -> Result<Self, FaceError> {
        let base = space.surfaces().base();
        let (u0, u1) = base.domain_u();
        let (v0, v1) = base.domain_v();
        let last = (LATTICE - 1) as Real;
        let lattice: Vec<[Real; 2]> = (0..LATTICE * LATTICE)
            .map(|k| {
                let (i, j) = ((k % LATTICE) as Real, (k / LATTICE) as Real);
                [u0 + (u1 - u0) * i / last, v0 + (v1 - v0) * j / last]
            })
            .collect();
        let points = base.eval_many(&lattice).map_err(sampling)?;
        let structure = &space.structure_samples().base;
        let lines = OUTLINE_POINTS
            .iter()
            .map(|&j| {
                let nearest = points
                    .iter()
                    .map(|p| (p - structure[j]).norm_squared())
                    .enumerate()
                    .min_by(|a, b| a.1.total_cmp(&b.1))
                    .map_or(0, |(k, _)| k);
                let [u, v] = lattice[nearest];
                line(base, (u, v)).map_err(sampling)
            })
            .collect::<Result<_, _>>()?;
        Ok(Outline { lines })
    }

    /// Where the mean face shows its outline to a camera whose image plane is spanned by the
    /// rows of `rows` (`P R`, any scale): per point, its own place and the sample of its line
    /// seen farthest toward its side.
    pub(crate) fn places(&self, rows: &Matrix2x3<Real>) -> OutlinePlaces {
        let axis = outward_axis(rows);
        std::array::from_fn(|n| farthest_out(&self.lines[n], &axis))
    }
}

/// [`LINE`] samples of `surface` along its line at `v`, from `u` to the middle of the `u`
/// range.
fn line(
    surface: &crate::bspline::BSplineSurface,
    (u, v): (Real, Real),
) -> Result<Vec<Point3<Real>>, crate::bspline::BSplineError> {
    let (u0, u1) = surface.domain_u();
    let middle = 0.5 * (u0 + u1);
    let params: Vec<[Real; 2]> = (0..LINE)
        .map(|s| [u + (middle - u) * s as Real / LINE as Real, v])
        .collect();
    Ok(surface.basis_matrix(&params)?.mul(surface.control_points()))
}

/// The face's x axis as a camera whose image plane is spanned by the rows of `rows` sees it:
/// outward is along it on the left side (x > 0) and against it on the right;
/// `(rows p) · (rows x̂) = p · (rowsᵀ rows x̂)`.
fn outward_axis(rows: &Matrix2x3<Real>) -> Vector3<Real> {
    rows.transpose() * (rows * Vector3::x())
}

/// The first of a line's points (a point's own place) and the one seen farthest toward its side
/// along `axis` ([`outward_axis`]).
fn farthest_out(line: &[Point3<Real>], axis: &Vector3<Real>) -> (Point3<Real>, Point3<Real>) {
    let own = line[0];
    let side = own.x.signum();
    let outward = |p: &Point3<Real>| side * axis.dot(&p.coords);
    let outline = line[1..].iter().fold(
        own,
        |best, &p| if outward(&p) > outward(&best) { p } else { best },
    );
    (own, outline)
}

/// How far a landmarker sees the point of `surface` at `(u, v)` moved onto the outline by a
/// camera whose image plane is spanned by the rows of `rows`: the outline's place along the
/// surface's line at `v` from `u` to the middle of the `u` range (the rule [`Outline`] fits
/// by), less the point's own place.
///
/// # Errors
/// As [`crate::bspline::BSplineSurface::basis_matrix`], for a parameter outside the domain.
pub(crate) fn outline_move(
    surface: &crate::bspline::BSplineSurface,
    (u, v): (Real, Real),
    rows: &Matrix2x3<Real>,
) -> Result<Vector3<Real>, crate::bspline::BSplineError> {
    let (own, outline) = farthest_out(&line(surface, (u, v))?, &outward_axis(rows));
    Ok(outline - own)
}

/// Per structure point, how far the outline moves it as a camera `rows` (`b P R`, the photo's
/// scale included) sees it: `rows (Pⱼ − Oⱼ)` for the points of [`OUTLINE_POINTS`] (`Pⱼ` the
/// surface's point at the point's own place, `Oⱼ` the outline's), zero for the others and
/// where the outline is the point's own place. Adding it to a photo's point makes the
/// point's residual against the structure the residual against where the outline moved it.
pub(crate) fn outline_shifts(places: &OutlinePlaces, rows: &Matrix2x3<Real>) -> [Vector2<Real>; POINT_COUNT] {
    let mut shifts = [Vector2::zeros(); POINT_COUNT];
    for (&j, (own, outline)) in OUTLINE_POINTS.iter().zip(places) {
        shifts[j] = rows * (own - outline);
    }
    shifts
}

fn sampling(e: crate::bspline::BSplineError) -> FaceError {
    FaceError::Space(format!("the outline's samples: {e}"))
}
