//! Knot insertion and refinement, and what they make possible: clamping, restriction to a
//! sub-domain, splitting and Bézier extraction (The NURBS Book, §5.2–5.4). Each returns the
//! same surface over (part of) the same domain with a richer representation; the property tests
//! check that it evaluates the same to rounding.

use nalgebra::Point3;

use super::{BSplineError, BSplineSurface, Direction, KnotVector};
use crate::Real;

/// The NURBS Book A5.4 (`RefineKnotVectCurve`): the knot vector `knots` of a degree-`p` curve
/// with control points `points`, refined by the sorted values `x` (each in the domain): the new
/// knot vector and control points of the same curve.
fn refine_curve(
    knots: &[Real],
    p: usize,
    points: &[Point3<Real>],
    x: &[Real],
    span: impl Fn(Real) -> usize,
) -> (Vec<Real>, Vec<Point3<Real>>) {
    if x.is_empty() {
        return (knots.to_vec(), points.to_vec());
    }
    let n = points.len() - 1;
    let m = n + p + 1;
    let r = x.len() - 1;
    let a = span(x[0]);
    let b = span(x[r]) + 1;
    let mut q = vec![Point3::origin(); points.len() + x.len()];
    let mut u = vec![0.0; knots.len() + x.len()];
    q[..=a - p].copy_from_slice(&points[..=a - p]);
    for j in b - 1..=n {
        q[j + r + 1] = points[j];
    }
    u[..=a].copy_from_slice(&knots[..=a]);
    for j in b + p..=m {
        u[j + r + 1] = knots[j];
    }
    let (mut i, mut k) = (b + p - 1, b + p + r);
    for j in (0..=r).rev() {
        while x[j] <= knots[i] && i > a {
            q[k - p - 1] = points[i - p - 1];
            u[k] = knots[i];
            k -= 1;
            i -= 1;
        }
        q[k - p - 1] = q[k - p];
        for l in 1..=p {
            let index = k - p + l;
            let alpha = u[k + l] - x[j];
            if alpha == 0.0 {
                q[index - 1] = q[index];
            } else {
                let alpha = alpha / (u[k + l] - knots[i - p + l]);
                q[index - 1] = Point3::from(q[index - 1].coords * alpha + q[index].coords * (1.0 - alpha));
            }
        }
        u[k] = x[j];
        k -= 1;
    }
    (u, q)
}

/// How many times `value` appears in `knots`.
pub(super) fn multiplicity(knots: &[Real], value: Real) -> usize {
    knots.iter().filter(|&&k| k == value).count()
}

/// The basis functions of knots `u` (degree `p`) alive on `[lo, hi]`, two of its knots each
/// of multiplicity ≥ `p`, as `first..end`, and the clamped knots over it: `lo` and `hi`
/// `p + 1` times with the knots strictly between. `lo` occupies `u[s..s + m]`: the first
/// function alive on `[lo, lo + ε)` is `N_{s+m−1−p}`; `hi` starts at `u[e]`, the last one
/// alive on `(hi − ε, hi]` is `N_{e−1}`.
fn clamped_over(u: &[Real], p: usize, lo: Real, hi: Real) -> (usize, usize, Vec<Real>) {
    let above = u.partition_point(|&k| k <= lo);
    let end = u.partition_point(|&k| k < hi);
    let mut clamped = vec![lo; p + 1];
    clamped.extend_from_slice(&u[above..end]);
    clamped.extend(std::iter::repeat_n(hi, p + 1));
    (above - 1 - p, end, clamped)
}

impl BSplineSurface {
    fn knots_in(&self, direction: Direction) -> &KnotVector {
        match direction {
            Direction::U => self.knots_u(),
            Direction::V => self.knots_v(),
        }
    }

    /// The curves of the grid along `direction` (the columns for `u`, the rows for `v`).
    fn curves(&self, direction: Direction) -> Vec<Vec<Point3<Real>>> {
        let (rows, cols, grid) = (self.rows(), self.cols(), self.control_points());
        match direction {
            Direction::U => (0..cols)
                .map(|j| (0..rows).map(|i| grid[i * cols + j]).collect())
                .collect(),
            Direction::V => grid.chunks(cols).map(<[_]>::to_vec).collect(),
        }
    }

    /// The surface with the curves along `direction` replaced (all of one length) over `knots`.
    fn with_curves(
        &self,
        direction: Direction,
        knots: KnotVector,
        curves: &[Vec<Point3<Real>>],
    ) -> Result<Self, BSplineError> {
        let length = curves[0].len();
        match direction {
            Direction::U => {
                let cols = curves.len();
                let grid = (0..length * cols).map(|k| curves[k % cols][k / cols]).collect();
                BSplineSurface::new(knots, self.knots_v().clone(), length, cols, grid)
            }
            Direction::V => {
                let rows = curves.len();
                let grid = curves.iter().flatten().copied().collect();
                BSplineSurface::new(self.knots_u().clone(), knots, rows, length, grid)
            }
        }
    }

    /// The same surface with the knots `values` added along `direction` (The NURBS Book A5.5,
    /// refinement of a surface's knot vector, done by A5.4 on each row or column). `values`
    /// need not be sorted and may repeat; each must lie in the domain, and no knot may end up
    /// more than `degree` times (a surface stays continuous).
    ///
    /// # Errors
    /// [`BSplineError::ParameterOutOfDomain`] for a value outside the domain (or NaN),
    /// [`BSplineError::KnotMultiplicityTooHigh`] for a knot that would appear more than
    /// `degree` times.
    ///
    /// # Examples
    ///
    /// ```
    /// use nalgebra::Point3;
    /// use splineface::bspline::{BSplineSurface, Direction, KnotVector};
    ///
    /// let k = KnotVector::clamped_uniform(3, 5, 0.0, 1.0)?;
    /// let grid = (0..25).map(|i| Point3::new((i / 5) as f64, (i % 5) as f64, ((i * 7) % 3) as f64)).collect();
    /// let surface = BSplineSurface::new(k.clone(), k, 5, 5, grid)?;
    /// let finer = surface.refine_knots(Direction::U, &[0.2, 0.7, 0.7])?;
    /// assert_eq!(finer.rows(), 8);
    /// let (a, b) = (surface.eval(0.3, 0.6)?, finer.eval(0.3, 0.6)?);
    /// assert!((a - b).norm() < 1e-12);
    /// # Ok::<(), splineface::bspline::BSplineError>(())
    /// ```
    pub fn refine_knots(&self, direction: Direction, values: &[Real]) -> Result<Self, BSplineError> {
        let knots = self.knots_in(direction);
        for &value in values {
            knots.check_in_domain(direction, value)?;
        }
        let mut x = values.to_vec();
        x.sort_by(Real::total_cmp);
        let p = knots.degree();
        for run in x.chunk_by(|a, b| a == b) {
            let total = multiplicity(knots.knots(), run[0]) + run.len();
            if total > p {
                return Err(BSplineError::KnotMultiplicityTooHigh {
                    value: run[0],
                    multiplicity: total,
                    max: p,
                });
            }
        }
        if x.is_empty() {
            return Ok(self.clone());
        }
        let span = |u: Real| knots.span_in_domain(u);
        let mut refined_knots = Vec::new();
        let curves: Vec<Vec<Point3<Real>>> = self
            .curves(direction)
            .iter()
            .map(|curve| {
                let (u, q) = refine_curve(knots.knots(), p, curve, &x, span);
                refined_knots = u;
                q
            })
            .collect();
        self.with_curves(direction, KnotVector::new(p, refined_knots)?, &curves)
    }

    /// The same surface with the knot `value` inserted `times` times along `direction` (The
    /// NURBS Book A5.3; see [`BSplineSurface::refine_knots`] for the limits).
    ///
    /// # Errors
    /// As [`BSplineSurface::refine_knots`].
    ///
    /// # Examples
    ///
    /// ```
    /// use nalgebra::Point3;
    /// use splineface::bspline::{BSplineSurface, Direction, KnotVector};
    ///
    /// let k = KnotVector::clamped_uniform(3, 5, 0.0, 1.0)?;
    /// let grid = (0..25).map(|i| Point3::new((i / 5) as f64, (i % 5) as f64, ((i * 7) % 3) as f64)).collect();
    /// let surface = BSplineSurface::new(k.clone(), k, 5, 5, grid)?;
    /// // A knot of multiplicity 2 in v: one control point more a row for each insertion.
    /// let more = surface.insert_knot(Direction::V, 0.4, 2)?;
    /// assert_eq!((more.rows(), more.cols()), (5, 7));
    /// assert!((surface.eval(0.8, 0.4)? - more.eval(0.8, 0.4)?).norm() < 1e-12);
    /// // A fourth copy would leave a cubic discontinuous.
    /// assert!(more.insert_knot(Direction::V, 0.4, 2).is_err());
    /// # Ok::<(), splineface::bspline::BSplineError>(())
    /// ```
    pub fn insert_knot(&self, direction: Direction, value: Real, times: usize) -> Result<Self, BSplineError> {
        self.refine_knots(direction, &vec![value; times])
    }

    /// The part of the surface over `[lo, hi]` along `direction` (the other direction whole),
    /// as a surface of its own with clamped knots there: `lo` and `hi` are inserted until they
    /// appear `degree` times (A5.4), and the knots and control points outside are dropped.
    ///
    /// # Errors
    /// [`BSplineError::ParameterOutOfDomain`] unless `start ≤ lo < hi ≤ end` of the domain
    /// ([`BSplineError::EmptyDomain`] when `lo ≥ hi`).
    ///
    /// # Examples
    ///
    /// ```
    /// use nalgebra::Point3;
    /// use splineface::bspline::{BSplineSurface, Direction, KnotVector};
    ///
    /// let k = KnotVector::clamped_uniform(3, 5, 0.0, 1.0)?;
    /// let grid = (0..25).map(|i| Point3::new((i / 5) as f64, (i % 5) as f64, ((i * 7) % 3) as f64)).collect();
    /// let surface = BSplineSurface::new(k.clone(), k, 5, 5, grid)?;
    /// // The strip u ∈ [0.25, 0.6]: its own surface, the same points there.
    /// let strip = surface.restricted(Direction::U, 0.25, 0.6)?;
    /// assert_eq!(strip.knots_u().domain(), (0.25, 0.6));
    /// assert_eq!(strip.cols(), surface.cols());
    /// assert!((strip.eval(0.4, 0.9)? - surface.eval(0.4, 0.9)?).norm() < 1e-12);
    /// # Ok::<(), splineface::bspline::BSplineError>(())
    /// ```
    pub fn restricted(&self, direction: Direction, lo: Real, hi: Real) -> Result<Self, BSplineError> {
        let knots = self.knots_in(direction);
        knots.check_in_domain(direction, lo)?;
        knots.check_in_domain(direction, hi)?;
        if lo >= hi {
            return Err(BSplineError::EmptyDomain { start: lo, end: hi });
        }
        let p = knots.degree();
        let missing = |v: Real| p.saturating_sub(multiplicity(knots.knots(), v));
        let inserts: Vec<Real> = std::iter::repeat_n(lo, missing(lo))
            .chain(std::iter::repeat_n(hi, missing(hi)))
            .collect();
        let refined = if inserts.is_empty() {
            std::borrow::Cow::Borrowed(self)
        } else {
            std::borrow::Cow::Owned(self.refine_knots(direction, &inserts)?)
        };
        let u = refined.knots_in(direction).knots();
        let (first, end, clamped) = clamped_over(u, p, lo, hi);
        let curves: Vec<Vec<Point3<Real>>> = refined
            .curves(direction)
            .into_iter()
            .map(|c| c[first..end].to_vec())
            .collect();
        refined.with_curves(direction, KnotVector::new(p, clamped)?, &curves)
    }

    /// The same surface over the same domain with clamped knot vectors in both directions (the
    /// first and last knots repeated `degree + 1` times), which many file formats and CAD
    /// systems expect. A clamped surface comes back unchanged.
    ///
    /// # Errors
    /// None in practice (the domain is valid); as [`BSplineSurface::restricted`].
    ///
    /// # Examples
    ///
    /// ```
    /// use nalgebra::Point3;
    /// use splineface::bspline::{BSplineSurface, Direction, KnotVector};
    ///
    /// let k = KnotVector::clamped_uniform(3, 5, 0.0, 1.0)?;
    /// let grid = (0..25).map(|i| Point3::new((i / 5) as f64, (i % 5) as f64, ((i * 7) % 3) as f64)).collect();
    /// let surface = BSplineSurface::new(k.clone(), k, 5, 5, grid)?;
    /// // Already clamped: the same surface.
    /// assert_eq!(surface.clamped()?, surface);
    /// // A plain uniform knot vector's domain [3, 5] (degree 3, 6 control points).
    /// let open = KnotVector::new(3, (0..10).map(f64::from).collect())?;
    /// let grid = (0..30).map(|i| Point3::new((i / 5) as f64, (i % 5) as f64, (i % 4) as f64)).collect();
    /// let plain = BSplineSurface::new(open, surface.knots_v().clone(), 6, 5, grid)?;
    /// let clamped = plain.clamped()?;
    /// assert!(clamped.knots_u().is_clamped());
    /// assert!((clamped.eval(3.7, 0.2)? - plain.eval(3.7, 0.2)?).norm() < 1e-12);
    /// # Ok::<(), splineface::bspline::BSplineError>(())
    /// ```
    pub fn clamped(&self) -> Result<Self, BSplineError> {
        let mut surface = self.clone();
        for direction in [Direction::U, Direction::V] {
            let knots = surface.knots_in(direction);
            if !knots.is_clamped() {
                let (start, end) = knots.domain();
                surface = surface.restricted(direction, start, end)?;
            }
        }
        Ok(surface)
    }

    /// The surface split at `at` along `direction` into the parts below and above it, each
    /// clamped ([`BSplineSurface::restricted`]).
    ///
    /// # Errors
    /// [`BSplineError::ParameterOutOfDomain`] unless `at` lies strictly inside the domain.
    ///
    /// # Examples
    ///
    /// ```
    /// use nalgebra::Point3;
    /// use splineface::bspline::{BSplineSurface, Direction, KnotVector};
    ///
    /// let k = KnotVector::clamped_uniform(3, 5, 0.0, 1.0)?;
    /// let grid = (0..25).map(|i| Point3::new((i / 5) as f64, (i % 5) as f64, ((i * 7) % 3) as f64)).collect();
    /// let surface = BSplineSurface::new(k.clone(), k, 5, 5, grid)?;
    /// let (below, above) = surface.split(Direction::V, 0.3)?;
    /// assert_eq!((below.knots_v().domain(), above.knots_v().domain()), ((0.0, 0.3), (0.3, 1.0)));
    /// assert!((below.eval(0.5, 0.3)? - above.eval(0.5, 0.3)?).norm() < 1e-12);
    /// assert!(surface.split(Direction::V, 1.0).is_err()); // not inside the domain
    /// # Ok::<(), splineface::bspline::BSplineError>(())
    /// ```
    pub fn split(&self, direction: Direction, at: Real) -> Result<(Self, Self), BSplineError> {
        let (start, end) = self.knots_in(direction).domain();
        if !(at > start && at < end) {
            return Err(BSplineError::ParameterOutOfDomain {
                direction,
                value: at,
                start,
                end,
            });
        }
        Ok((
            self.restricted(direction, start, at)?,
            self.restricted(direction, at, end)?,
        ))
    }

    /// The surface as Bézier patches, one per non-empty knot span pair (The NURBS Book A5.7 in
    /// effect: every interior knot raised to multiplicity `degree`, then the grid cut), each a
    /// surface with knots `[a, …, a, b, …, b]` over its span. Row-major: the patch of `u` span
    /// `i` and `v` span `j` is at `i · (v spans) + j`.
    ///
    /// # Errors
    /// None in practice; as [`BSplineSurface::restricted`].
    ///
    /// # Examples
    ///
    /// ```
    /// use nalgebra::Point3;
    /// use splineface::bspline::{BSplineSurface, Direction, KnotVector};
    ///
    /// let k = KnotVector::clamped_uniform(3, 5, 0.0, 1.0)?;
    /// let grid = (0..25).map(|i| Point3::new((i / 5) as f64, (i % 5) as f64, ((i * 7) % 3) as f64)).collect();
    /// let surface = BSplineSurface::new(k.clone(), k, 5, 5, grid)?;
    /// // Two spans a direction: four bicubic patches of 4 × 4 control points each.
    /// let patches = surface.bezier_patches()?;
    /// assert_eq!(patches.len(), 4);
    /// assert!(patches.iter().all(|b| (b.rows(), b.cols()) == (4, 4)));
    /// // Patch (1, 0) covers u ∈ [0.5, 1], v ∈ [0, 0.5].
    /// assert_eq!(patches[2].knots_u().domain(), (0.5, 1.0));
    /// assert!((patches[2].eval(0.7, 0.2)? - surface.eval(0.7, 0.2)?).norm() < 1e-12);
    /// # Ok::<(), splineface::bspline::BSplineError>(())
    /// ```
    pub fn bezier_patches(&self) -> Result<Vec<BSplineSurface>, BSplineError> {
        let (us, vs) = (self.knots_u().breakpoints(), self.knots_v().breakpoints());
        // Every break at multiplicity `degree` once, so that each patch below is a slice.
        let mut full = self.clone();
        for (direction, values) in [(Direction::U, &us), (Direction::V, &vs)] {
            let knots = full.knots_in(direction);
            let p = knots.degree();
            let inserts: Vec<Real> = values
                .iter()
                .flat_map(|&v| std::iter::repeat_n(v, p.saturating_sub(multiplicity(knots.knots(), v))))
                .collect();
            full = full.refine_knots(direction, &inserts)?;
        }
        // Each span `[a, b]` now has both ends at multiplicity ≥ the degree, so its patch is
        // the `(p + 1)`-wide slice of the grid that [`BSplineSurface::restricted`] would keep
        // (`clamped_over`, with no knots between: the Bézier knots `[a, …, a, b, …, b]`),
        // taken directly, without restricting a copy of the grid for every span (cubic in the
        // grid's side).
        let slices =
            |direction: Direction, breaks: &[Real]| -> Result<Vec<(usize, KnotVector)>, BSplineError> {
                let knots = full.knots_in(direction);
                let (p, u) = (knots.degree(), knots.knots());
                breaks
                    .windows(2)
                    .map(|w| {
                        let (first, _, bezier) = clamped_over(u, p, w[0], w[1]);
                        Ok((first, KnotVector::new(p, bezier)?))
                    })
                    .collect()
            };
        let (rows, cols) = (slices(Direction::U, &us)?, slices(Direction::V, &vs)?);
        let (p, q) = (full.degree_u(), full.degree_v());
        let (grid, width) = (full.control_points(), full.cols());
        let mut patches = Vec::with_capacity(rows.len() * cols.len());
        for (i, ku) in &rows {
            for (j, kv) in &cols {
                let points = (0..=p)
                    .flat_map(|r| {
                        grid[(i + r) * width + j..=(i + r) * width + j + q]
                            .iter()
                            .copied()
                    })
                    .collect();
                patches.push(BSplineSurface::new(ku.clone(), kv.clone(), p + 1, q + 1, points)?);
            }
        }
        Ok(patches)
    }
}

/// `n choose k`, exactly for the small arguments of degree elevation.
fn binomial(n: usize, k: usize) -> Real {
    (0..k).fold(1.0, |acc, i| acc * (n - i) as Real / (i + 1) as Real)
}

/// The NURBS Book A5.9 (`DegreeElevateCurve`): a curve of degree `p` on the clamped knot
/// vector `knots` (interior multiplicities at most `p`) raised to degree `p + t`: the new knot
/// vector (every distinct knot's multiplicity up by `t`) and control points. Written with the
/// book's indices so that it can be checked line by line against it.
#[allow(clippy::needless_range_loop, clippy::explicit_counter_loop)]
fn elevate_curve(
    knots: &[Real],
    p: usize,
    points: &[Point3<Real>],
    t: usize,
) -> (Vec<Real>, Vec<Point3<Real>>) {
    let n = points.len() - 1;
    if p == 0 {
        // A constant (one span: the caller refuses interior knots of degree 0, where the
        // curve breaks): its one point t + 1 times.
        let (start, end) = (knots[0], knots[knots.len() - 1]);
        let mut u = vec![start; t + 1];
        u.extend(std::iter::repeat_n(end, t + 1));
        return (u, vec![points[0]; t + 1]);
    }
    let m = n + p + 1;
    let ph = p + t;
    let ph2 = ph / 2;
    let zero = Point3::<Real>::origin();
    let blend = |a: Real, x: Point3<Real>, y: Point3<Real>| Point3::from(x.coords * a + y.coords * (1.0 - a));
    // Bézier degree-elevation coefficients.
    let mut bezalfs = vec![vec![0.0; p + 1]; ph + 1];
    bezalfs[0][0] = 1.0;
    bezalfs[ph][p] = 1.0;
    for i in 1..=ph2 {
        let inv = 1.0 / binomial(ph, i);
        for j in i.saturating_sub(t)..=p.min(i) {
            bezalfs[i][j] = inv * binomial(p, j) * binomial(t, i - j);
        }
    }
    for i in ph2 + 1..ph {
        for j in i.saturating_sub(t)..=p.min(i) {
            bezalfs[i][j] = bezalfs[ph - i][p - j];
        }
    }
    let distinct_interior = {
        let mut v: Vec<Real> = knots[p + 1..=n].to_vec();
        v.dedup();
        v.len()
    };
    let capacity = points.len() + t * (distinct_interior + 1);
    let mut qw = vec![zero; capacity];
    let mut uh = vec![0.0; capacity + ph + 1];
    let mut bpts = vec![zero; p + 1];
    let mut ebpts = vec![zero; ph + 1];
    let mut next_bpts = vec![zero; p.max(1)];
    let mut alfs = vec![0.0; p.max(1)];
    let mut mh = ph;
    let mut kind = ph + 1;
    let mut r: isize = -1;
    let mut a = p;
    let mut b = p + 1;
    let mut cind = 1;
    let mut ua = knots[0];
    qw[0] = points[0];
    uh[..=ph].fill(ua);
    bpts.copy_from_slice(&points[..=p]);
    while b < m {
        let i0 = b;
        while b < m && knots[b] == knots[b + 1] {
            b += 1;
        }
        let mul = b - i0 + 1;
        mh += mul + t;
        let ub = knots[b];
        let oldr = r;
        r = p as isize - mul as isize;
        let lbz = if oldr > 0 { ((oldr + 2) / 2) as usize } else { 1 };
        let rbz = if r > 0 { ph - ((r + 1) / 2) as usize } else { ph };
        if r > 0 {
            // Insert ub r times to make the Bézier segment.
            let numer = ub - ua;
            for k in (mul + 1..=p).rev() {
                alfs[k - mul - 1] = numer / (knots[a + k] - ua);
            }
            for j in 1..=r as usize {
                let save = r as usize - j;
                let s = mul + j;
                for k in (s..=p).rev() {
                    bpts[k] = blend(alfs[k - s], bpts[k], bpts[k - 1]);
                }
                next_bpts[save] = bpts[p];
            }
        }
        // Elevate the Bézier segment (only lbz..=ph are used below).
        for i in lbz..=ph {
            let mut sum = nalgebra::Vector3::zeros();
            for j in i.saturating_sub(t)..=p.min(i) {
                sum += bpts[j].coords * bezalfs[i][j];
            }
            ebpts[i] = Point3::from(sum);
        }
        if oldr > 1 {
            // Remove the knot ua oldr − 1 times.
            let mut first = kind - 2;
            let mut last = kind;
            let den = ub - ua;
            let bet = (ub - uh[kind - 1]) / den;
            for tr in 1..oldr as usize {
                let (mut i, mut j) = (first, last);
                let mut kj = j as isize - kind as isize + 1;
                while j - i > tr {
                    if i < cind {
                        let alf = (ub - uh[i]) / (ua - uh[i]);
                        qw[i] = blend(alf, qw[i], qw[i - 1]);
                    }
                    if j >= lbz {
                        let k = kj as usize;
                        if j - tr <= kind - ph + oldr as usize {
                            let gam = (ub - uh[j - tr]) / den;
                            ebpts[k] = blend(gam, ebpts[k], ebpts[k + 1]);
                        } else {
                            ebpts[k] = blend(bet, ebpts[k], ebpts[k + 1]);
                        }
                    }
                    i += 1;
                    j -= 1;
                    kj -= 1;
                }
                first -= 1;
                last += 1;
            }
        }
        if a != p {
            // Load the knot ua.
            for _ in 0..ph - oldr as usize {
                uh[kind] = ua;
                kind += 1;
            }
        }
        for j in lbz..=rbz {
            qw[cind] = ebpts[j];
            cind += 1;
        }
        if b < m {
            let r = r.max(0) as usize;
            bpts[..r].copy_from_slice(&next_bpts[..r]);
            for j in r..=p {
                bpts[j] = points[b - p + j];
            }
            a = b;
            b += 1;
            ua = ub;
        } else {
            for i in 0..=ph {
                uh[kind + i] = ub;
            }
        }
    }
    let nh = mh - ph - 1;
    qw.truncate(nh + 1);
    uh.truncate(nh + ph + 2);
    (uh, qw)
}

impl BSplineSurface {
    /// The same surface with its degree along `direction` raised by `by` (The NURBS Book A5.9
    /// on every row or column): every distinct knot's multiplicity goes up by `by`, so the
    /// surface keeps its continuity. The result has clamped knots along `direction`
    /// ([`BSplineSurface::clamped`] first).
    ///
    /// # Errors
    /// [`BSplineError::DegreeTooHigh`] beyond [`super::MAX_DEGREE`];
    /// [`BSplineError::KnotMultiplicityTooHigh`] for a surface that breaks at an interior knot
    /// (multiplicity `degree + 1`): split it there first.
    ///
    /// # Examples
    ///
    /// ```
    /// use nalgebra::Point3;
    /// use splineface::bspline::{BSplineSurface, Direction, KnotVector};
    ///
    /// let k = KnotVector::clamped_uniform(2, 4, 0.0, 1.0)?;
    /// let grid = (0..16).map(|i| Point3::new((i / 4) as f64, (i % 4) as f64, ((i * 5) % 3) as f64)).collect();
    /// let surface = BSplineSurface::new(k.clone(), k, 4, 4, grid)?;
    /// let cubic = surface.elevate_degree(Direction::V, 1)?;
    /// assert_eq!((cubic.degree_v(), cubic.cols()), (3, 6));
    /// assert!((surface.eval(0.4, 0.8)? - cubic.eval(0.4, 0.8)?).norm() < 1e-12);
    /// # Ok::<(), splineface::bspline::BSplineError>(())
    /// ```
    pub fn elevate_degree(&self, direction: Direction, by: usize) -> Result<Self, BSplineError> {
        let p = self.knots_in(direction).degree();
        if by == 0 {
            return Ok(self.clone());
        }
        if p + by > super::MAX_DEGREE {
            return Err(BSplineError::DegreeTooHigh {
                degree: p + by,
                max: super::MAX_DEGREE,
            });
        }
        let clamped = self.clamped()?;
        let knots = clamped.knots_in(direction);
        let inner = &knots.knots()[p + 1..knots.num_control_points()];
        for run in inner.chunk_by(|a, b| a == b) {
            if run.len() > p {
                return Err(BSplineError::KnotMultiplicityTooHigh {
                    value: run[0],
                    multiplicity: run.len(),
                    max: p,
                });
            }
        }
        let mut elevated_knots = Vec::new();
        let curves: Vec<Vec<Point3<Real>>> = clamped
            .curves(direction)
            .iter()
            .map(|curve| {
                let (u, q) = elevate_curve(knots.knots(), p, curve, by);
                elevated_knots = u;
                q
            })
            .collect();
        clamped.with_curves(direction, KnotVector::new(p + by, elevated_knots)?, &curves)
    }
}
