//! Any scan to a spline: a B-spline surface fitted to a mesh's vertices or a point cloud that is
//! a height field over some plane.
//!
//! [`fit_scan`] finds the plane (the principal components of the points: the normal is the
//! direction of least variance; or a normal the caller gives), parametrises every point by its
//! position in the plane's bounding rectangle mapped to `[0, 1]²`, and fits a clamped surface
//! to the points at those parameters by the kernel's least-squares fit
//! ([`crate::bspline::SurfaceFit`], with a small thin-plate weight that defines the cells no
//! point reaches, such as the rectangle's corners beyond an oval scan). With a tolerance, it
//! starts from a coarse grid and inserts knots only where the residual asks for them: both spans
//! of every knot cell holding a point whose residual exceeds the tolerance (and
//! [`MIN_SPLIT_POINTS`] points or more) are halved, and the surface is fitted again, until every
//! residual is within the tolerance, no cell can be split, or the grid reaches its cap.
//!
//! The residual of a point is its distance to the surface point at its parameters,
//! `‖F(uₛ, vₛ) − pₛ‖`, which bounds its distance to the surface from above; the true distances
//! (closest points, by the kernel's point inversion) of up to [`DISTANCE_SAMPLES`] points are
//! measured too ([`ScanFit::distances`]).
//!
//! A scan that is not a height field over the plane (a closed head, a folded sheet) is refused
//! ([`ScanError::NotHeightField`]) rather than fitted into garbage: the plane's rectangle is cut
//! into cells about eight points each, and a cell whose heights leave a gap wider than three
//! cells (and 2% of the scan's size) holds two layers of surface; more than 5% of the points
//! in such cells refuse the scan. A height field with slopes below about 70° has no such gaps;
//! a face scan has a few (measured: 3.0% of ICT-FaceKit's neutral face, at its ears, eyelids,
//! nostrils and lips; 4.5% of the vertices of the Lee Perry-Smith scan's front cut out by a
//! box, under its chin and at its eyes), which are fitted through and show in the residuals
//! ([`ScanFit::layered`] says how many). The whole head has 51%, and the same front resampled
//! densely over its triangles 37% (its eyes and mouth have inner surfaces): both are refused.

use nalgebra::{Matrix3, Point3, SymmetricEigen, Vector3};
use rayon::prelude::*;
use std::path::{Path, PathBuf};

use crate::Real;
use crate::bspline::{BSplineError, BSplineSurface, KnotVector, SurfaceFit};
use crate::geometry::LengthUnit;

/// Options of [`fit_scan`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScanFitOptions {
    /// The degree in both directions (1 to 5).
    pub degree: usize,
    /// Control points per direction: the grid without a tolerance, the starting grid with one
    /// (`degree + 1` or more).
    pub grid: usize,
    /// The largest residual allowed (the scan's units); `None` fits the grid once.
    pub tolerance: Option<Real>,
    /// The most control points per direction knot insertion may reach.
    pub max_grid: usize,
    /// The thin-plate weight `λ` ([`SurfaceFit::smoothness`]).
    pub smoothness: Real,
    /// The plane's normal; `None`: the direction of least variance of the points.
    pub normal: Option<Vector3<Real>>,
}

impl Default for ScanFitOptions {
    /// Bicubic, a 16 × 16 grid, no tolerance, a cap of 128 control points per direction,
    /// `λ = 10⁻¹²`, the plane from the principal components.
    ///
    /// `λ` is there to define the rectangle's cells that no point reaches, but the thin plate
    /// acts on the whole surface, and it must stay below the squared residuals asked for.
    /// Measured on a Gaussian bump (height 0.3, deviation 0.16) on a paraboloid over the unit
    /// disc, 157k points, bicubic: with `λ = 10⁻⁷` the largest residual stayed at 0.0044 on
    /// uniform 32² and 64² grids; with `10⁻⁹`, a tolerance of 10⁻⁵ was not met by the
    /// 128² cap (the largest residual grew again from 1.2·10⁻⁴ as knots were added); with
    /// `10⁻¹²` it is met in 5 fits on a 47 × 48 grid (uniform 48² leaves 1.7·10⁻⁵), and
    /// `10⁻¹³` or `10⁻¹⁶` give the same. The empty corners' control points stay within the
    /// data's range of heights at every one of them.
    fn default() -> Self {
        ScanFitOptions {
            degree: 3,
            grid: 16,
            tolerance: None,
            max_grid: 128,
            smoothness: 1e-12,
            normal: None,
        }
    }
}

/// The plane a scan is a height field over: an origin (the points' centroid) and a
/// right-handed orthonormal frame whose third axis is the normal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScanPlane {
    /// The points' centroid.
    pub origin: Point3<Real>,
    /// The in-plane axes along which `u` and `v` run, and the normal.
    pub axes: [Vector3<Real>; 3],
    /// The points' range along the first two axes (`u` and `v` map them to `[0, 1]`).
    pub range: [(Real, Real); 2],
}

/// A fitted scan.
#[derive(Debug, Clone, PartialEq)]
pub struct ScanFit {
    /// The surface, in the scan's own coordinates.
    pub surface: BSplineSurface,
    /// The plane and the rectangle the parameters span.
    pub plane: ScanPlane,
    /// Each point's parameters `(u, v)`.
    pub params: Vec<[Real; 2]>,
    /// Each point's residual `‖F(uₛ, vₛ) − pₛ‖`.
    pub residuals: Vec<Real>,
    /// The residuals' root mean square and largest value.
    pub rms: Real,
    /// The largest residual.
    pub max: Real,
    /// Fits run (1 without a tolerance).
    pub rounds: usize,
    /// The tolerance asked for.
    pub tolerance: Option<Real>,
    /// The share of the points in cells with two layers along the normal (at most
    /// [`MAX_LAYERED`]; see the module documentation).
    pub layered: Real,
    /// Whether every residual is within the tolerance (`None` without one).
    pub within_tolerance: Option<bool>,
    /// The points' true distances to the surface, by point inversion
    /// ([`crate::bspline::ClosestPoints`]), over at most [`DISTANCE_SAMPLES`] of them.
    pub distances: DistanceSample,
}

/// The most points whose true distance [`fit_scan`] measures (every `k`-th point beyond).
pub const DISTANCE_SAMPLES: usize = 20_000;

/// Distances from a sample of a scan's points to its fitted surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DistanceSample {
    /// Points measured.
    pub count: usize,
    /// Root mean square distance.
    pub rms: Real,
    /// The 99th percentile.
    pub p99: Real,
    /// The largest.
    pub max: Real,
}

impl DistanceSample {
    /// The closest-point distances from every `k`-th of `points` to `surface`, so that at most
    /// [`DISTANCE_SAMPLES`] are measured.
    fn measure(surface: &BSplineSurface, points: &[Point3<Real>]) -> Result<Self, BSplineError> {
        let stride = points.len().div_ceil(DISTANCE_SAMPLES).max(1);
        let sample: Vec<Point3<Real>> = points.iter().step_by(stride).copied().collect();
        let closest = crate::bspline::ClosestPoints::new(surface).closest_many(&sample)?;
        let mut d: Vec<Real> = closest.iter().map(|c| c.distance).collect();
        d.sort_by(|a, b| a.total_cmp(b));
        Ok(DistanceSample {
            count: d.len(),
            rms: (d.iter().map(|x| x * x).sum::<Real>() / d.len().max(1) as Real).sqrt(),
            p99: percentile(&d, 0.99),
            max: d.last().copied().unwrap_or(0.0),
        })
    }
}

/// The `q`-quantile of ascending `sorted` (nearest rank; 0 for none).
fn percentile(sorted: &[Real], q: Real) -> Real {
    if sorted.is_empty() {
        return 0.0;
    }
    sorted[((sorted.len() - 1) as Real * q).round() as usize]
}

/// Why a scan could not be fitted.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ScanError {
    /// A setting out of range.
    #[error("{name} {value}: {expected}")]
    Option {
        /// The setting.
        name: &'static str,
        /// Its value.
        value: String,
        /// What it must be.
        expected: &'static str,
    },
    /// Fewer points than the grid has control points.
    #[error("{count} points: a {grid} × {grid} grid needs at least {needed}")]
    TooFewPoints {
        /// Points given.
        count: usize,
        /// Control points per direction.
        grid: usize,
        /// Points needed.
        needed: usize,
    },
    /// A coordinate is NaN or infinite.
    #[error("point {index} is not finite")]
    NonFinite {
        /// The point's index.
        index: usize,
    },
    /// The points span no plane (they lie on a line or a point).
    #[error("the points span no plane: they lie on a line or at one point")]
    Degenerate,
    /// The scan folds over itself along the plane's normal.
    #[error(
        "not a height field over any plane: {percent:.1}% of its points lie where the surface has two layers along the normal ({nx:.3}, {ny:.3}, {nz:.3}) (a closed or folded surface); fit an open part of it"
    )]
    NotHeightField {
        /// The share of the points in two-layer cells, percent.
        percent: Real,
        /// The normal's coordinates.
        nx: Real,
        /// See `nx`.
        ny: Real,
        /// See `nx`.
        nz: Real,
    },
    /// The kernel's fit failed.
    #[error(transparent)]
    Fit(#[from] BSplineError),
    /// The surface's mesh could not be made (a surface point not finite).
    #[error("the surface's mesh: {0}")]
    Mesh(#[from] crate::mesh::MeshProblem),
    /// An output could not be encoded.
    #[error(transparent)]
    Encode(#[from] crate::io::EncodeError),
}

/// The plane of `points`: the centroid and the principal axes (or `normal` and two axes
/// across it), with the points' range along the in-plane axes.
fn plane_of(points: &[Point3<Real>], normal: Option<Vector3<Real>>) -> Result<ScanPlane, ScanError> {
    let n = points.len() as Real;
    let centroid = points.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n;
    let covariance = points.iter().fold(Matrix3::zeros(), |a, p| {
        let d = p.coords - centroid;
        a + d * d.transpose()
    }) / n;
    let eigen = SymmetricEigen::new(covariance);
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eigen.eigenvalues[b].total_cmp(&eigen.eigenvalues[a]));
    let largest = eigen.eigenvalues[order[0]];
    // NaN-safe: a NaN or non-positive spread is degenerate too.
    if largest.is_nan() || largest <= 0.0 || eigen.eigenvalues[order[1]] <= 1e-12 * largest {
        return Err(ScanError::Degenerate);
    }
    let axes = match normal {
        Some(normal) => {
            let normal = normal.normalize();
            // The in-plane axis nearest the principal one.
            let first = eigen.eigenvectors.column(order[0]).into_owned();
            let mut a = first - normal * first.dot(&normal);
            if a.norm() < 1e-6 {
                a = eigen.eigenvectors.column(order[1]).into_owned();
                a -= normal * a.dot(&normal);
            }
            let a = a.normalize();
            [a, normal.cross(&a), normal]
        }
        None => {
            let a = eigen.eigenvectors.column(order[0]).into_owned();
            let b = eigen.eigenvectors.column(order[1]).into_owned();
            [a, b, a.cross(&b)]
        }
    };
    let mut range = [(Real::INFINITY, Real::NEG_INFINITY); 2];
    for p in points {
        let d = p.coords - centroid;
        for (k, r) in range.iter_mut().enumerate() {
            let t = d.dot(&axes[k]);
            *r = (r.0.min(t), r.1.max(t));
        }
    }
    if range.iter().any(|r| r.1 - r.0 <= 1e-12 * largest.sqrt()) {
        return Err(ScanError::Degenerate);
    }
    Ok(ScanPlane {
        origin: Point3::from(centroid),
        axes,
        range,
    })
}

impl ScanPlane {
    /// The parameters of `p`: its position in the plane's rectangle, in `[0, 1]²`.
    ///
    /// # Examples
    ///
    /// ```
    /// use nalgebra::Point3;
    /// use splineface::scan::{ScanFitOptions, fit_scan};
    ///
    /// // A 40 × 40 grid of samples of the bowl z = 0.2 (x² + y²) over [−1, 1]², fitted bicubic.
    /// let points: Vec<Point3<f64>> = (0..1600)
    ///     .map(|k| {
    ///         let (x, y) = ((k / 40) as f64 / 19.5 - 1.0, (k % 40) as f64 / 19.5 - 1.0);
    ///         Point3::new(x, y, 0.2 * (x * x + y * y))
    ///     })
    ///     .collect();
    /// let fit = fit_scan(&points, &ScanFitOptions { grid: 8, ..Default::default() })?;
    /// // The plane is z = 0 (the bowl's least-variance direction); the points span [−1, 1]².
    /// let plane = fit.plane;
    /// assert!(plane.axes[2].z.abs() > 0.999);
    /// let [u, v] = plane.params(&Point3::new(0.0, 0.0, 0.3));
    /// assert!((u - 0.5).abs() < 1e-9 && (v - 0.5).abs() < 1e-9);
    /// // Outside the rectangle: held to its edge.
    /// let [u, _] = plane.params(&Point3::new(9.0, 0.0, 0.0));
    /// assert!(u == 0.0 || u == 1.0);
    /// # Ok::<(), splineface::scan::ScanError>(())
    /// ```
    pub fn params(&self, p: &Point3<Real>) -> [Real; 2] {
        let d = p - self.origin;
        std::array::from_fn(|k| {
            let (lo, hi) = self.range[k];
            ((d.dot(&self.axes[k]) - lo) / (hi - lo)).clamp(0.0, 1.0)
        })
    }

    /// The height of `p` above the plane.
    ///
    /// # Examples
    ///
    /// ```
    /// use nalgebra::Point3;
    /// use splineface::scan::{ScanFitOptions, fit_scan};
    ///
    /// // A 40 × 40 grid of samples of the bowl z = 0.2 (x² + y²) over [−1, 1]², fitted bicubic.
    /// let points: Vec<Point3<f64>> = (0..1600)
    ///     .map(|k| {
    ///         let (x, y) = ((k / 40) as f64 / 19.5 - 1.0, (k % 40) as f64 / 19.5 - 1.0);
    ///         Point3::new(x, y, 0.2 * (x * x + y * y))
    ///     })
    ///     .collect();
    /// let fit = fit_scan(&points, &ScanFitOptions { grid: 8, ..Default::default() })?;
    /// // Heights above the bowl's plane (through the points' centroid) differ as the z's do.
    /// let (a, b) = (fit.plane.height(&points[0]), fit.plane.height(&points[820]));
    /// assert!(((a - b).abs() - (points[0].z - points[820].z).abs()).abs() < 1e-9);
    /// # Ok::<(), splineface::scan::ScanError>(())
    /// ```
    pub fn height(&self, p: &Point3<Real>) -> Real {
        (p - self.origin).dot(&self.axes[2])
    }
}

/// The cell of `t ∈ [0, 1]` among `n ≥ 1` equal cells (1 in the last).
fn cell_of(t: Real, n: usize) -> usize {
    ((t * n as Real) as usize).min(n - 1)
}

/// The footprint's grid for `points` scan points: about eight points a cell where they cover
/// the rectangle, from 2 to [`RESIDUAL_SIDE`] cells a side (a sparse cloud would leave gaps
/// between its points' cells at the heatmap's resolution).
fn footprint_side(points: usize) -> usize {
    ((points as Real / 8.0).sqrt() as usize).clamp(2, RESIDUAL_SIDE)
}

/// The cells of the largest 4-connected group of `cells` (an `n × n` grid, row `i` along `u`;
/// the first in scan order among equals).
fn largest_group(cells: &[bool], n: usize) -> Vec<bool> {
    let mut seen = vec![false; n * n];
    let mut largest: Vec<usize> = Vec::new();
    for seed in 0..n * n {
        if cells[seed] && !seen[seed] {
            let group = flood(n, vec![seed], |c| cells[c], &mut seen);
            if group.len() > largest.len() {
                largest = group;
            }
        }
    }
    let mut out = vec![false; n * n];
    for c in largest {
        out[c] = true;
    }
    out
}

/// The empty cells of `cells` joined to the grid's border through empty cells.
fn reachable_from_border(cells: &[bool], n: usize) -> Vec<bool> {
    let border: Vec<usize> = (0..n * n)
        .filter(|&c| {
            let (i, j) = (c / n, c % n);
            (i == 0 || j == 0 || i == n - 1 || j == n - 1) && !cells[c]
        })
        .collect();
    let mut reached = vec![false; n * n];
    flood(n, border, |c| !cells[c], &mut reached);
    reached
}

/// Marks in `reached` the cells of an `n × n` grid joined to `seeds` (passable themselves)
/// through 4-neighbours that are `passable` and not yet reached; returns the cells it marked.
fn flood(n: usize, seeds: Vec<usize>, passable: impl Fn(usize) -> bool, reached: &mut [bool]) -> Vec<usize> {
    for &c in &seeds {
        reached[c] = true;
    }
    let (mut queue, mut marked) = (seeds.clone(), seeds);
    while let Some(c) = queue.pop() {
        let (i, j) = (c / n, c % n);
        let around = [
            (i > 0).then(|| c - n),
            (i + 1 < n).then(|| c + n),
            (j > 0).then(|| c - 1),
            (j + 1 < n).then(|| c + 1),
        ];
        for next in around.into_iter().flatten() {
            if passable(next) && !reached[next] {
                reached[next] = true;
                queue.push(next);
                marked.push(next);
            }
        }
    }
    marked
}

/// The outline of a 4-connected, hole-free region of an `n × n` grid with no cells meeting at a
/// corner alone, counter-clockwise in `(u, v)`, collinear vertices left out; empty for an empty
/// region.
fn outline(region: &[bool], n: usize) -> Vec<nalgebra::Point2<Real>> {
    let inside = |i: isize, j: isize| {
        i >= 0 && j >= 0 && (i as usize) < n && (j as usize) < n && region[i as usize * n + j as usize]
    };
    // Each boundary edge between corner (i, j) points, with the region on its left; in such a
    // region every corner starts at most one.
    let mut next = std::collections::HashMap::new();
    for c in (0..n * n).filter(|&c| region[c]) {
        let (i, j) = ((c / n) as isize, (c % n) as isize);
        if !inside(i, j - 1) {
            next.insert((i, j), (i + 1, j));
        }
        if !inside(i + 1, j) {
            next.insert((i + 1, j), (i + 1, j + 1));
        }
        if !inside(i, j + 1) {
            next.insert((i + 1, j + 1), (i, j + 1));
        }
        if !inside(i - 1, j) {
            next.insert((i, j + 1), (i, j));
        }
    }
    let Some(&first) = next.keys().min() else {
        return Vec::new();
    };
    let mut corners = vec![first];
    let mut at = next[&first];
    while at != first {
        // One loop through every edge, by the region's making; were it not, no outline.
        let to = next.get(&at).filter(|_| corners.len() < next.len());
        let Some(&to) = to else {
            debug_assert!(false, "the boundary is not one loop");
            return Vec::new();
        };
        corners.push(at);
        at = to;
    }
    debug_assert_eq!(corners.len(), next.len(), "one loop");
    let m = corners.len();
    let turns = |k: usize| {
        let (a, b, c) = (corners[(k + m - 1) % m], corners[k], corners[(k + 1) % m]);
        (b.0 - a.0) * (c.1 - b.1) != (b.1 - a.1) * (c.0 - b.0)
    };
    (0..m)
        .filter(|&k| turns(k))
        .map(|k| nalgebra::Point2::new(corners[k].0 as Real / n as Real, corners[k].1 as Real / n as Real))
        .collect()
}

/// The share of `points` lying in cells of the plane's rectangle whose heights hold a gap (see
/// the module documentation).
fn layered_share(points: &[Point3<Real>], plane: &ScanPlane, params: &[[Real; 2]]) -> Real {
    let [(a0, a1), (b0, b1)] = plane.range;
    let size = (a1 - a0).max(b1 - b0);
    // About eight points a cell over the rectangle's area.
    let area = (a1 - a0) * (b1 - b0);
    let cell = (area * 8.0 / points.len() as Real).sqrt().max(size / 1024.0);
    let (columns, rows) = (
        (((a1 - a0) / cell).ceil() as usize).max(1),
        (((b1 - b0) / cell).ceil() as usize).max(1),
    );
    let mut cells: Vec<Vec<Real>> = vec![Vec::new(); columns * rows];
    for (p, uv) in points.iter().zip(params) {
        let (i, j) = (cell_of(uv[0], columns), cell_of(uv[1], rows));
        cells[j * columns + i].push(plane.height(p));
    }
    let gap = (3.0 * cell).max(0.02 * size);
    let layered: usize = cells
        .par_iter_mut()
        .map(|heights| {
            heights.sort_by(|a, b| a.total_cmp(b));
            if heights.windows(2).any(|w| w[1] - w[0] > gap) {
                heights.len()
            } else {
                0
            }
        })
        .sum();
    layered as Real / points.len() as Real
}

/// The largest share of a scan's points in two-layer cells that [`fit_scan`] fits through.
pub const MAX_LAYERED: Real = 0.05;

/// The fewest points a knot cell must hold for [`fit_scan`] to halve its spans (four for each
/// of the quarters it is cut into), so that a tolerance no grid can meet (noise, or a fold)
/// does not refine the grid past its data.
pub const MIN_SPLIT_POINTS: usize = 16;

impl ScanFitOptions {
    /// Checks the options (as [`fit_scan`] does first); a setting out of range is a
    /// [`ScanError::Option`] named like its command-line flag.
    ///
    /// # Errors
    /// The first setting out of range.
    ///
    /// # Examples
    ///
    /// ```
    /// use splineface::scan::ScanFitOptions;
    ///
    /// assert!(ScanFitOptions::default().validate().is_ok());
    /// let bad = ScanFitOptions { degree: 7, ..Default::default() };
    /// assert!(bad.validate().unwrap_err().to_string().contains("degree"));
    /// ```
    pub fn validate(&self) -> Result<(), ScanError> {
        let bad = |name: &'static str, value: String, expected: &'static str| {
            Err(ScanError::Option {
                name,
                value,
                expected,
            })
        };
        if !(1..=5).contains(&self.degree) {
            return bad("degree", self.degree.to_string(), "1 to 5");
        }
        if self.grid <= self.degree || self.grid > 1024 {
            return bad(
                "grid",
                self.grid.to_string(),
                "more than the degree, at most 1024",
            );
        }
        if self.max_grid < self.grid || self.max_grid > 1024 {
            return bad(
                "max-grid",
                self.max_grid.to_string(),
                "at least the grid, at most 1024",
            );
        }
        if let Some(t) = self.tolerance
            && !(t > 0.0 && t.is_finite())
        {
            return bad("tolerance", t.to_string(), "positive and finite");
        }
        if !(self.smoothness >= 0.0 && self.smoothness.is_finite()) {
            return bad("smoothness", self.smoothness.to_string(), "0 or more, finite");
        }
        if let Some(n) = self.normal
            && !(n.iter().all(|c| c.is_finite()) && n.norm() > 0.0)
        {
            return bad(
                "normal",
                format!("{},{},{}", n.x, n.y, n.z),
                "finite and not zero",
            );
        }
        Ok(())
    }
}

/// The knots of `knots` with every span in `marked` halved.
fn halved(knots: &KnotVector, marked: &[bool]) -> Result<KnotVector, BSplineError> {
    let mut out = knots.knots().to_vec();
    for (span, _) in marked.iter().enumerate().filter(|(_, m)| **m) {
        let (a, b) = (knots.knots()[span], knots.knots()[span + 1]);
        out.push(0.5 * (a + b));
    }
    out.sort_by(|a, b| a.total_cmp(b));
    KnotVector::new(knots.degree(), out)
}

/// Fits a B-spline surface to `points`, a height field over some plane (see the module
/// documentation).
///
/// # Errors
/// [`ScanError`]: options out of range, too few or non-finite points, points on a line, a scan
/// with two layers along the normal, or the kernel's fit failing.
///
/// # Examples
///
/// ```
/// use nalgebra::Point3;
/// use splineface::scan::{ScanFitOptions, fit_scan};
///
/// // A paraboloid cap sampled on a 60 × 60 grid, tilted: any plane will do.
/// let points: Vec<Point3<f64>> = (0..3600)
///     .map(|k| {
///         let (x, y) = ((k / 60) as f64 / 59.0 - 0.5, (k % 60) as f64 / 59.0 - 0.5);
///         let z = 0.3 * (x * x + y * y);
///         Point3::new(x, 0.8 * y + 0.6 * z, -0.6 * y + 0.8 * z)
///     })
///     .collect();
/// let options = ScanFitOptions { tolerance: Some(1e-4), grid: 4, ..Default::default() };
/// let fit = fit_scan(&points, &options)?;
/// assert!(fit.max <= 1e-4 && fit.within_tolerance == Some(true));
/// # Ok::<(), splineface::scan::ScanError>(())
/// ```
pub fn fit_scan(points: &[Point3<Real>], options: &ScanFitOptions) -> Result<ScanFit, ScanError> {
    options.validate()?;
    if let Some(index) = points
        .iter()
        .position(|p| !p.coords.iter().all(|c| c.is_finite()))
    {
        return Err(ScanError::NonFinite { index });
    }
    let needed = options.grid * options.grid;
    if points.len() < needed {
        return Err(ScanError::TooFewPoints {
            count: points.len(),
            grid: options.grid,
            needed,
        });
    }
    let plane = plane_of(points, options.normal)?;
    let params: Vec<[Real; 2]> = points.par_iter().map(|p| plane.params(p)).collect();
    let share = layered_share(points, &plane, &params);
    if share > MAX_LAYERED {
        let n = plane.axes[2];
        return Err(ScanError::NotHeightField {
            percent: 100.0 * share,
            nx: n.x,
            ny: n.y,
            nz: n.z,
        });
    }
    let mut knots = [
        KnotVector::clamped_uniform(options.degree, options.grid, 0.0, 1.0)?,
        KnotVector::clamped_uniform(options.degree, options.grid, 0.0, 1.0)?,
    ];
    let mut rounds = 0;
    loop {
        rounds += 1;
        let fitted = SurfaceFit::new(knots[0].clone(), knots[1].clone())
            .smoothness(options.smoothness)
            .keep_residuals()
            .fit(&params, points)?;
        let residuals = fitted.residuals;
        let max = residuals.iter().copied().fold(0.0, Real::max);
        let rms = (residuals.iter().map(|r| r * r).sum::<Real>() / residuals.len() as Real).sqrt();
        let within_tolerance = match options.tolerance {
            None => None,
            Some(tolerance) if max <= tolerance => Some(true),
            Some(tolerance) => {
                if split_knots(&mut knots, &params, &residuals, tolerance, options.max_grid)? {
                    continue;
                }
                Some(false)
            }
        };
        let surface = fitted.surface;
        return Ok(ScanFit {
            distances: DistanceSample::measure(&surface, points)?,
            surface,
            plane,
            params,
            residuals,
            rms,
            max,
            rounds,
            tolerance: options.tolerance,
            layered: share,
            within_tolerance,
        });
    }
}

/// Halves both spans of every knot cell that holds a point whose residual exceeds `tolerance`
/// and [`MIN_SPLIT_POINTS`] points or more, in each direction as far as `max_grid` control
/// points allow; whether any knot was inserted.
fn split_knots(
    knots: &mut [KnotVector; 2],
    params: &[[Real; 2]],
    residuals: &[Real],
    tolerance: Real,
    max_grid: usize,
) -> Result<bool, BSplineError> {
    let spans: Vec<[usize; 2]> = params
        .par_iter()
        .map(|uv| std::array::from_fn(|k| knots[k].span(uv[k]).expect("parameters lie in [0, 1]")))
        .collect();
    let width = knots[1].knots().len();
    let mut per_cell = vec![0usize; knots[0].knots().len() * width];
    for c in &spans {
        per_cell[c[0] * width + c[1]] += 1;
    }
    let mut grown = false;
    for (k, knot) in knots.iter_mut().enumerate() {
        let mut marked = vec![false; knot.knots().len()];
        for (c, r) in spans.iter().zip(residuals) {
            if *r > tolerance && per_cell[c[0] * width + c[1]] >= MIN_SPLIT_POINTS {
                marked[c[k]] = true;
            }
        }
        let room = max_grid - knot.num_control_points();
        let mut count = 0;
        for m in marked.iter_mut() {
            if *m {
                count += 1;
                *m = count <= room;
            }
        }
        if marked.iter().any(|m| *m) {
            *knot = halved(knot, &marked)?;
            grown = true;
        }
    }
    Ok(grown)
}

/// Reads a scan's points: the vertices of a mesh (OBJ, glTF or GLB, by
/// [`crate::mesh::read_mesh`]), of a PLY file with or without faces (a point cloud,
/// [`crate::mesh::parse_ply_points`]), or an XYZ text file (`.xyz` or `.txt`: one point a line, its
/// first three numbers separated by spaces, tabs or commas; blank lines and lines starting
/// with `#` or `//` skipped).
///
/// # Errors
/// A message naming the file and the problem (and the line, for XYZ).
///
/// # Examples
///
/// ```
/// use splineface::scan::read_scan_points;
///
/// let path = std::env::temp_dir().join(format!("splineface-doc-{}.xyz", std::process::id()));
/// std::fs::write(&path, "# x y z\n0 0 0\n1,0,0.5\n\n0\t1\t0.25\n")?;
/// let points = read_scan_points(&path)?;
/// assert_eq!(points.len(), 3);
/// assert_eq!(points[1], nalgebra::Point3::new(1.0, 0.0, 0.5));
/// std::fs::write(&path, "0 0 zero\n")?;
/// let error = read_scan_points(&path).unwrap_err();
/// assert!(error.to_string().contains("line 1"));
/// std::fs::remove_file(&path)?;
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub fn read_scan_points(path: &Path) -> Result<Vec<Point3<Real>>, ScanFileError> {
    let error = |message: String| ScanFileError {
        file: path.to_path_buf(),
        message,
    };
    let extension = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .unwrap_or_default();
    if extension == "ply" {
        // A point cloud, or a mesh's vertices.
        let bytes = crate::io::read_input(path, crate::io::MAX_LARGE_INPUT_BYTES)
            .map_err(|e| error(e.to_string()))?;
        return crate::mesh::parse_ply_points(&bytes).map_err(|e| error(e.to_string()));
    }
    if extension != "xyz" && extension != "txt" {
        let mesh = crate::mesh::read_mesh(path).map_err(|e| error(e.problem.to_string()))?;
        return Ok(mesh.positions().to_vec());
    }
    let text = crate::io::read_input_text(path, crate::io::MAX_LARGE_INPUT_BYTES)
        .map_err(|e| error(e.to_string()))?;
    let mut points = Vec::new();
    for (number, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') || line.starts_with("//") {
            continue;
        }
        let mut values = line
            .split(|c: char| c.is_whitespace() || c == ',')
            .filter(|s| !s.is_empty());
        let mut xyz = [0.0; 3];
        for c in &mut xyz {
            let field = values
                .next()
                .ok_or_else(|| error(format!("line {}: fewer than three numbers", number + 1)))?;
            *c = field
                .parse::<Real>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| error(format!("line {}: `{field}` is not a finite number", number + 1)))?;
        }
        points.push(Point3::from(xyz));
    }
    if points.is_empty() {
        return Err(error("no points".to_owned()));
    }
    Ok(points)
}

/// A scan file that could not be read.
#[derive(Debug, thiserror::Error)]
#[error("{}: {message}", file.display())]
pub struct ScanFileError {
    /// The file.
    pub file: PathBuf,
    /// What is wrong with it.
    pub message: String,
}

impl ScanFit {
    /// The residuals on a `side × side` grid over `(u, v)` (rows from `v = 0`): each cell's
    /// largest residual, NaN where no point falls (empty for a `side` of 0).
    ///
    /// # Examples
    ///
    /// ```
    /// use nalgebra::Point3;
    /// use splineface::scan::{ScanFitOptions, fit_scan};
    ///
    /// // A 40 × 40 grid of samples of the bowl z = 0.2 (x² + y²) over [−1, 1]², fitted bicubic.
    /// let points: Vec<Point3<f64>> = (0..1600)
    ///     .map(|k| {
    ///         let (x, y) = ((k / 40) as f64 / 19.5 - 1.0, (k % 40) as f64 / 19.5 - 1.0);
    ///         Point3::new(x, y, 0.2 * (x * x + y * y))
    ///     })
    ///     .collect();
    /// let fit = fit_scan(&points, &ScanFitOptions { grid: 8, ..Default::default() })?;
    /// // 4 × 4 cells over (u, v), each the largest residual of its points.
    /// let cells = fit.residual_grid(4);
    /// assert_eq!(cells.len(), 16);
    /// assert!(cells.iter().all(|r| *r >= 0.0 && *r <= fit.max));
    /// assert!(fit.residual_grid(0).is_empty());
    /// # Ok::<(), splineface::scan::ScanError>(())
    /// ```
    pub fn residual_grid(&self, side: usize) -> Vec<Real> {
        if side == 0 {
            return Vec::new();
        }
        let mut grid = vec![Real::NAN; side * side];
        for (uv, r) in self.params.iter().zip(&self.residuals) {
            let (i, j) = (cell_of(uv[0], side), cell_of(uv[1], side));
            let cell = &mut grid[j * side + i];
            *cell = if cell.is_nan() { *r } else { cell.max(*r) };
        }
        grid
    }
}

/// The side of the residual heatmap and of the optional mesh's parameter grid.
pub const RESIDUAL_SIDE: usize = 256;

/// The surface file formats [`ScanFit::files`] writes, by extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SurfaceFormat {
    /// `.json`: [`BSplineSurface::to_json`].
    Json,
    /// `.step` or `.stp`: [`crate::bspline::encode_step`].
    Step,
}

impl SurfaceFormat {
    /// The format of `path` by its extension, if it names one.
    ///
    /// # Examples
    ///
    /// ```
    /// use std::path::Path;
    /// use splineface::scan::SurfaceFormat;
    ///
    /// assert_eq!(SurfaceFormat::from_path(Path::new("face.STP")), Some(SurfaceFormat::Step));
    /// assert_eq!(SurfaceFormat::from_path(Path::new("face.json")), Some(SurfaceFormat::Json));
    /// assert_eq!(SurfaceFormat::from_path(Path::new("face.obj")), None);
    /// ```
    pub fn from_path(path: &Path) -> Option<Self> {
        match path.extension()?.to_str()?.to_ascii_lowercase().as_str() {
            "json" => Some(SurfaceFormat::Json),
            "step" | "stp" => Some(SurfaceFormat::Step),
            _ => None,
        }
    }
}

/// The residual files beside a surface file `out`: `STEM.residuals.json` and
/// `STEM.residuals.png`.
///
/// # Examples
///
/// ```
/// use std::path::Path;
/// use splineface::scan::residual_paths;
///
/// let (report, heatmap) = residual_paths(Path::new("out/scan.step"));
/// assert_eq!(report, Path::new("out/scan.residuals.json"));
/// assert_eq!(heatmap, Path::new("out/scan.residuals.png"));
/// ```
pub fn residual_paths(out: &Path) -> (PathBuf, PathBuf) {
    let stem = out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let beside = |extension: &str| out.with_file_name(format!("{stem}.residuals.{extension}"));
    (beside("json"), beside("png"))
}

impl ScanFit {
    /// The surface evaluated on a `side × side` cell grid over `(u, v)`, keeping the cells
    /// that hold a point of the scan (two triangles each), so that the rectangle's empty
    /// corners are left out.
    ///
    /// # Errors
    /// [`ScanError::Fit`] for a `side` of 0, [`ScanError::Mesh`] if the mesh cannot be made.
    ///
    /// # Examples
    ///
    /// ```
    /// use nalgebra::Point3;
    /// use splineface::scan::{ScanFitOptions, fit_scan};
    ///
    /// // A 40 × 40 grid of samples of the bowl z = 0.2 (x² + y²) over [−1, 1]², fitted bicubic.
    /// let points: Vec<Point3<f64>> = (0..1600)
    ///     .map(|k| {
    ///         let (x, y) = ((k / 40) as f64 / 19.5 - 1.0, (k % 40) as f64 / 19.5 - 1.0);
    ///         Point3::new(x, y, 0.2 * (x * x + y * y))
    ///     })
    ///     .collect();
    /// let fit = fit_scan(&points, &ScanFitOptions { grid: 8, ..Default::default() })?;
    /// // Every one of the 10 × 10 cells holds points: 11² vertices, two triangles a cell.
    /// let mesh = fit.mesh(10)?;
    /// assert_eq!((mesh.positions().len(), mesh.triangles().len()), (121, 200));
    /// # Ok::<(), splineface::scan::ScanError>(())
    /// ```
    pub fn mesh(&self, side: usize) -> Result<crate::mesh::TriangleMesh, ScanError> {
        let ts: Vec<Real> = (0..=side).map(|k| k as Real / side as Real).collect();
        let grid = self.surface.eval_grid(&ts, &ts)?;
        let mut occupied = vec![false; side * side];
        for uv in &self.params {
            let (i, j) = (cell_of(uv[0], side), cell_of(uv[1], side));
            occupied[i * side + j] = true;
        }
        let corner = |i: usize, j: usize| (i * (side + 1) + j) as u32;
        let mut triangles = Vec::new();
        for i in 0..side {
            for j in 0..side {
                if occupied[i * side + j] {
                    let (a, b, c, d) = (
                        corner(i, j),
                        corner(i + 1, j),
                        corner(i + 1, j + 1),
                        corner(i, j + 1),
                    );
                    triangles.push([a, b, c]);
                    triangles.push([a, c, d]);
                }
            }
        }
        Ok(crate::mesh::TriangleMesh::new(grid, triangles)?)
    }

    /// The scan's footprint in `(u, v)` as a simple polygon, counter-clockwise: the outline of
    /// the cells of a `side × side` grid that hold scan points, keeping the largest 4-connected
    /// group of them, with its holes filled and its cells that touch only at a corner joined
    /// (so the outline is one simple loop); vertices on cell corners, collinear ones left
    /// out. Empty when no cell holds a point (`side` 0, or no points). The STEP file of
    /// `fit-surface` is trimmed to it, so that CAD shows the surface where the scan was, not
    /// the extrapolated corners of its rectangle.
    ///
    /// # Examples
    ///
    /// ```
    /// use nalgebra::Point3;
    /// use splineface::scan::{ScanFitOptions, fit_scan};
    ///
    /// // A 40 × 40 grid of samples of the bowl z = 0.2 (x² + y²) over [−1, 1]², fitted bicubic.
    /// let points: Vec<Point3<f64>> = (0..1600)
    ///     .map(|k| {
    ///         let (x, y) = ((k / 40) as f64 / 19.5 - 1.0, (k % 40) as f64 / 19.5 - 1.0);
    ///         Point3::new(x, y, 0.2 * (x * x + y * y))
    ///     })
    ///     .collect();
    /// let fit = fit_scan(&points, &ScanFitOptions { grid: 8, ..Default::default() })?;
    /// // The points fill the plane's rectangle: the footprint is its four corners.
    /// let outline = fit.footprint(16);
    /// assert_eq!(outline.len(), 4);
    /// assert!(outline.iter().all(|q| (q.x == 0.0 || q.x == 1.0) && (q.y == 0.0 || q.y == 1.0)));
    /// # Ok::<(), splineface::scan::ScanError>(())
    /// ```
    pub fn footprint(&self, side: usize) -> Vec<nalgebra::Point2<Real>> {
        let n = side;
        if n == 0 || self.params.is_empty() {
            return Vec::new();
        }
        let mut filled = vec![false; n * n];
        for uv in &self.params {
            filled[cell_of(uv[0], n) * n + cell_of(uv[1], n)] = true;
        }
        let mut region = largest_group(&filled, n);
        // Fill holes and join corner-only contacts until neither changes anything.
        loop {
            let outside = reachable_from_border(&region, n);
            for (cell, out) in region.iter_mut().zip(&outside) {
                *cell = !out;
            }
            let mut joined = false;
            for i in 1..n {
                for j in 1..n {
                    let [a, b, c, d] =
                        [(i - 1, j - 1), (i, j - 1), (i - 1, j), (i, j)].map(|(x, y)| x * n + y);
                    let diagonal = (region[a] && region[d] && !region[b] && !region[c])
                        || (region[b] && region[c] && !region[a] && !region[d]);
                    if diagonal {
                        for k in [a, b, c, d] {
                            region[k] = true;
                        }
                        joined = true;
                    }
                }
            }
            if !joined {
                break;
            }
        }
        outline(&region, n)
    }

    /// The report of the fit as JSON: the scan's name, points, degree, grid, knots, rounds,
    /// tolerance, residuals (RMS, 99th percentile, largest), the plane and `seconds`.
    ///
    /// # Examples
    ///
    /// ```
    /// use nalgebra::Point3;
    /// use splineface::scan::{ScanFitOptions, fit_scan};
    ///
    /// // A 40 × 40 grid of samples of the bowl z = 0.2 (x² + y²) over [−1, 1]², fitted bicubic.
    /// let points: Vec<Point3<f64>> = (0..1600)
    ///     .map(|k| {
    ///         let (x, y) = ((k / 40) as f64 / 19.5 - 1.0, (k % 40) as f64 / 19.5 - 1.0);
    ///         Point3::new(x, y, 0.2 * (x * x + y * y))
    ///     })
    ///     .collect();
    /// let fit = fit_scan(&points, &ScanFitOptions { grid: 8, ..Default::default() })?;
    /// let report = fit.report_json("bowl.xyz", &ScanFitOptions::default(), 0.01);
    /// let value: serde_json::Value = serde_json::from_str(&report).expect("JSON");
    /// assert_eq!(value["points"], 1600);
    /// assert_eq!(value["grid"], serde_json::json!([8, 8]));
    /// # Ok::<(), splineface::scan::ScanError>(())
    /// ```
    pub fn report_json(&self, scan: &str, options: &ScanFitOptions, seconds: Real) -> String {
        let mut sorted = self.residuals.clone();
        sorted.sort_by(|a, b| a.total_cmp(b));
        let p99 = percentile(&sorted, 0.99);
        let d = &self.distances;
        let s = &self.surface;
        let v = |x: &Vector3<Real>| [x.x, x.y, x.z];
        let report = serde_json::json!({
            "scan": scan,
            "points": self.params.len(),
            "degree": [s.degree_u(), s.degree_v()],
            "grid": [s.rows(), s.cols()],
            "knots_u": s.knots_u().knots(),
            "knots_v": s.knots_v().knots(),
            "rounds": self.rounds,
            "tolerance": options.tolerance,
            "within_tolerance": self.within_tolerance,
            "smoothness": options.smoothness,
            "layered_share": self.layered,
            "residual": { "rms": self.rms, "p99": p99, "max": self.max },
            "distance": { "points": d.count, "rms": d.rms, "p99": d.p99, "max": d.max },
            "plane": {
                "origin": [self.plane.origin.x, self.plane.origin.y, self.plane.origin.z],
                "u_axis": v(&self.plane.axes[0]),
                "v_axis": v(&self.plane.axes[1]),
                "normal": v(&self.plane.axes[2]),
                "u_range": [self.plane.range[0].0, self.plane.range[0].1],
                "v_range": [self.plane.range[1].0, self.plane.range[1].1],
            },
            "seconds": seconds,
        });
        serde_json::to_string_pretty(&report).expect("a JSON value serialises") + "\n"
    }

    /// Every file of a fit written to `out` (the surface, in `out`'s format), beside it
    /// [`residual_paths`] (the report, and a heatmap of each cell's largest residual over
    /// `(u, v)`, scaled to the tolerance or else to the largest residual), and the mesh of
    /// [`ScanFit::mesh`] at `mesh` (`.obj` or `.ply`) when asked. A STEP file declares its
    /// numbers (the scan's, unscaled) to be in `unit`.
    ///
    /// # Errors
    /// [`ScanError::Option`] for an output whose extension names no format;
    /// [`ScanError::Encode`] if the heatmap cannot be encoded; [`ScanError::Fit`] if the STEP
    /// face cannot be trimmed to [`ScanFit::footprint`] (a surface that tears along a knot
    /// line; not one `fit_scan` makes).
    ///
    /// # Examples
    ///
    /// ```
    /// use nalgebra::Point3;
    /// use splineface::scan::{ScanFitOptions, fit_scan};
    ///
    /// // A 40 × 40 grid of samples of the bowl z = 0.2 (x² + y²) over [−1, 1]², fitted bicubic.
    /// let points: Vec<Point3<f64>> = (0..1600)
    ///     .map(|k| {
    ///         let (x, y) = ((k / 40) as f64 / 19.5 - 1.0, (k % 40) as f64 / 19.5 - 1.0);
    ///         Point3::new(x, y, 0.2 * (x * x + y * y))
    ///     })
    ///     .collect();
    /// let fit = fit_scan(&points, &ScanFitOptions { grid: 8, ..Default::default() })?;
    /// use std::path::Path;
    /// use splineface::geometry::LengthUnit;
    ///
    /// // Nothing is written: the files come back as paths and bytes.
    /// let files = fit.files(Path::new("out/bowl.step"), Some(Path::new("out/bowl.obj")), "{}", LengthUnit::Millimetre)?;
    /// let names: Vec<_> = files.iter().map(|(p, _)| p.file_name().unwrap().to_string_lossy().into_owned()).collect();
    /// assert_eq!(names, ["bowl.step", "bowl.residuals.json", "bowl.residuals.png", "bowl.obj"]);
    /// assert!(files[0].1.starts_with(b"ISO-10303-21;"));
    /// # Ok::<(), splineface::scan::ScanError>(())
    /// ```
    pub fn files(
        &self,
        out: &Path,
        mesh: Option<&Path>,
        report: &str,
        unit: LengthUnit,
    ) -> Result<Vec<(PathBuf, Vec<u8>)>, ScanError> {
        let bad = |name: &'static str, path: &Path, expected: &'static str| ScanError::Option {
            name,
            value: path.display().to_string(),
            expected,
        };
        let name = out
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let surface = match SurfaceFormat::from_path(out) {
            Some(SurfaceFormat::Json) => self.surface.to_json().into_bytes(),
            Some(SurfaceFormat::Step) => crate::bspline::encode_step(
                &self.surface,
                &crate::bspline::StepOptions {
                    name: &name,
                    description: &format!(
                        "a B-spline surface fitted to a scan by splineface fit-surface, in {}",
                        unit.plural()
                    ),
                    unit,
                    trim: &self.footprint(footprint_side(self.params.len())),
                },
            )
            .map_err(ScanError::Fit)?
            .into_bytes(),
            None => return Err(bad("out", out, "a .json or .step file")),
        };
        let (report_path, heatmap_path) = residual_paths(out);
        // Scaled to the tolerance (or the largest residual) in units of a power of ten, so that
        // the colour bar's three decimals read.
        let top = self.tolerance.unwrap_or(self.max).max(Real::MIN_POSITIVE);
        let exponent = top.log10().floor() as i32;
        let unit = 10.0_f64.powi(exponent);
        let values: Vec<Real> = self
            .residual_grid(RESIDUAL_SIDE)
            .iter()
            .map(|r| r / unit)
            .collect();
        let label = if exponent == 0 {
            String::new()
        } else {
            format!("×1e{exponent}")
        };
        let heatmap = crate::render::heatmap_png(&values, RESIDUAL_SIDE, RESIDUAL_SIDE, top / unit, &label)?;
        let mut files = vec![
            (out.to_path_buf(), surface),
            (report_path, report.as_bytes().to_vec()),
            (heatmap_path, heatmap),
        ];
        if let Some(path) = mesh {
            let triangles = self.mesh(RESIDUAL_SIDE)?;
            let bytes = crate::mesh::encode_mesh(path, &triangles)
                .ok_or_else(|| bad("mesh", path, "a .obj or .ply file"))?;
            files.push((path.to_path_buf(), bytes));
        }
        Ok(files)
    }
}
