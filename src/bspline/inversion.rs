//! Point inversion: the point of a surface closest to a point in space, with its parameters
//! (The NURBS Book §6.1, A6.4/A6.5 in spirit).
//!
//! [`ClosestPoints`] samples the surface once (`SAMPLES_PER_SPAN` points a knot span in each
//! direction, each with its first and second derivatives) into a k-d tree, and bounds each
//! knot-span pair by the box of its Bézier control points (the convex hull property) in a
//! bounding-volume tree. A query starts at a sample near it (one lookup in a grid of cubes
//! about the median sample cell's size, [`StartGrid`]; its nearest sample from the k-d tree
//! when its cube holds none), walks over the sample grid to the nearest sample (a neighbour
//! at a time while one comes nearer), and is moved to the closest point of that sample's
//! second-order expansion by two Newton steps on the expansion (no evaluation; each held
//! within a sample spacing and the piece). From there it runs a damped Newton iteration on
//! `½|F(u, v) − P|²` (the full Hessian
//! `FᵤᵀFᵤ + (F − P)·Fᵤᵤ, …`, falling back to Gauss-Newton where that is not positive
//! definite), each step projected onto the start's *piece* with the coordinates held on a
//! bound they would leave (so that points beyond an edge or a corner find the edge or the
//! corner). A piece is the domain cut along its creases, the knots of multiplicity ≥ the
//! degree where the surface is only C⁰: the distance has a kink there, so a minimum on a
//! crease is found as one on a piece's edge, with the piece's one-sided derivatives. Newton
//! stops when the step moves the surface point by less than `1e-12` of the surface's size, or
//! when the residual is perpendicular to the surface to `1e-12` (the book's two zero tests).
//! Then every other span whose box comes nearer the query than that answer is searched from
//! its own nearest sample (kept just inside the span, so that the search stays in the span's
//! own piece), and the nearest answer is kept: the answer is the global one across
//! spans, and a local one within a span (a span folded into two basins around the query can
//! hide the farther-from-the-start one; the property tests, on height fields with slopes up to
//! about ½, never saw it).
//!
//! Spans whose boxes could hold a nearer answer are found from per-cube lists of the boxes
//! within a cube's side of it, kept when they stay short (at most [`NEAR_PER_CUBE`] entries a
//! cube on average), else from the bounding-volume tree; both give the same spans.
//!
//! Speed (`cargo bench --bench bspline -- inversion`, one core, a 32 × 32 bicubic at 0.1% of
//! its size from it): 0.39–0.41 M queries/s at first; 0.98 M with a k-d tree of [`LEAF`]
//! points a leaf searched without recursion, Newton's derivatives in loops of compile-time
//! length for degrees 2 and 3, a batch's queries in [`crate::mesh`]'s Morton order (read one
//! by one, each missed the cache) and no allocation per query; 1.30 M with the first step
//! from stored tangents and the start by lookup. Then, against that code in the same runs
//! (criterion baselines): the start at the expansion's closest point after the walk (surface
//! evaluations a query 4.4 → 3.3, Newton's first move about 0.2 → 1e-4 of a sample cell)
//! 1.70 → 1.72 M; the per-cube box lists (the tree's search was a fifth of the time) 1.94 M;
//! Newton's tests on squares with one reciprocal a step 2.04 M; the Morton order's radix sort
//! 2.17 M. Then a query's functions (the search, the walk, Newton, the derivatives, the span
//! and piece lookups, the trees' searches) marked to be inlined into one loop: 1.77–2.01 →
//! 2.09–2.17 M in five pairs of alternating runs of the two builds (the same loop compiled for
//! AVX2 under `pulp`: 0–7% more, within the machine's drift, and dropped). On a 128 × 128
//! bicubic the changes before the inlining took 1.31 → 1.70 M; on 512 × 512, 0.98 M either
//! way (the queries' cache misses dominate). Left alone: the build, 3.0 ms for 32 × 32 and
//! 1.3 s for 512 × 512 (2.3 M samples with their derivatives). A last step taken from the
//! second-order expansion, without evaluating, was measured and dropped: where the tangents
//! are short, a step short in space is long in the parameters, and the property test found
//! the expansion's point and the stationarity off by more than their tolerances.

use std::borrow::Cow;

use nalgebra::{Point3, Vector3};

use super::basis::SpanPolynomials;
use super::{BSplineError, BSplineSurface, MAX_DEGREE};
use crate::Real;

/// Samples per knot span and direction for the starting points.
pub const SAMPLES_PER_SPAN: usize = 3;

/// The Newton steps on a sample's second-order expansion that give a query's start.
const MODEL_STEPS: usize = 2;

/// The most moves of [`ClosestPoints::descend`].
const WALK: usize = 8;

/// The most Newton steps a query takes.
const MAX_STEPS: usize = 30;

/// How far inside its span (a fraction of the span's width) a span's start is kept from the
/// span's upper edge (and where an answer on a piece's upper edge is looked up).
const INSIDE: Real = 1e-9;

/// `t`, moved below `hi` by [`INSIDE`] of `[lo, hi]`'s width when it is nearer `hi` than that,
/// so that it looks up the span or cell below `hi` rather than the one `hi` starts.
#[inline(always)]
fn short_of_upper(t: Real, (lo, hi): (Real, Real)) -> Real {
    t.min(hi - INSIDE * (hi - lo))
}

/// The closest point of a surface to a query point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClosestPoint {
    /// Its parameter `u`.
    pub u: Real,
    /// Its parameter `v`.
    pub v: Real,
    /// `F(u, v)`.
    pub point: Point3<Real>,
    /// `|F(u, v) − P|`.
    pub distance: Real,
}

/// The point, first and second derivatives at `(u, v)`: `[F, Fᵤ, F_v, Fᵤᵤ, Fᵤ_v, F_vv]`,
/// without allocating; on a piece's upper edge, the piece's own (one-sided) derivatives. The
/// basis functions come from `basis`' polynomials (`u`, `v`): Horner's rule, where A2.3
/// divides and clears tables (it was a quarter of the inversion's time).
#[inline(always)]
fn second_order(
    surface: &BSplineSurface,
    basis: [&SpanPolynomials; 2],
    u: Real,
    v: Real,
    piece: &Piece,
) -> [Vector3<Real>; 6] {
    // Equal low degrees with loops of known length (the general form's run-time bounds kept
    // the compiler from unrolling them: half the inversion's time on a bicubic); else tables
    // sized for the degrees (zeroing the largest degree's was measurable).
    match (surface.degree_u(), surface.degree_v()) {
        (3, 3) => return second_order_fixed::<4>(surface, basis, u, v, piece),
        (2, 2) => return second_order_fixed::<3>(surface, basis, u, v, piece),
        _ => {}
    }
    if surface.degree_u() <= 3 && surface.degree_v() <= 3 {
        second_order_in::<4>(surface, basis, u, v, piece)
    } else {
        second_order_in::<{ MAX_DEGREE + 1 }>(surface, basis, u, v, piece)
    }
}

/// [`second_order`] for degrees `p = q = W − 1`, a compile-time constant: the same sums in
/// the same order as [`second_order_in`], so the same values.
#[inline(always)]
#[allow(clippy::needless_range_loop)] // r, s, k and c index several arrays at once
fn second_order_fixed<const W: usize>(
    surface: &BSplineSurface,
    [basis_u, basis_v]: [&SpanPolynomials; 2],
    u: Real,
    v: Real,
    piece: &Piece,
) -> [Vector3<Real>; 6] {
    let p = W - 1;
    let su = span_from_within(surface.knots_u(), u, piece.u);
    let sv = span_from_within(surface.knots_v(), v, piece.v);
    let nu = basis_u.derivatives_fixed::<W>(su, u);
    let nv = basis_v.derivatives_fixed::<W>(sv, v);
    let (cols, grid) = (surface.cols(), surface.control_points());
    // rows[k][s]: Σᵣ N⁽ᵏ⁾ᵣ(u) b_(su−p+r, sv−p+s), for k = 0, 1, 2.
    let mut rows = [[[0.0; 3]; W]; 3];
    for r in 0..W {
        let base = (su - p + r) * cols + sv - p;
        let row = &grid[base..base + W];
        for (s, b) in row.iter().enumerate() {
            for k in 0..3 {
                for c in 0..3 {
                    rows[k][s][c] += b[c] * nu[k][r];
                }
            }
        }
    }
    let mut out = [Vector3::zeros(); 6];
    for (slot, (k, l)) in [(0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2)]
        .into_iter()
        .enumerate()
    {
        let mut sum = [0.0; 3];
        for s in 0..W {
            for c in 0..3 {
                sum[c] += rows[k][s][c] * nv[l][s];
            }
        }
        out[slot] = Vector3::from(sum);
    }
    out
}

/// [`second_order`] with tables for degrees below `N`.
#[inline(always)]
fn second_order_in<const N: usize>(
    surface: &BSplineSurface,
    [basis_u, basis_v]: [&SpanPolynomials; 2],
    u: Real,
    v: Real,
    piece: &Piece,
) -> [Vector3<Real>; 6] {
    let (p, q) = (surface.degree_u(), surface.degree_v());
    let su = span_from_within(surface.knots_u(), u, piece.u);
    let sv = span_from_within(surface.knots_v(), v, piece.v);
    let (du, dv) = (2.min(p), 2.min(q));
    let mut nu = [[0.0; N]; 3];
    let mut nv = [[0.0; N]; 3];
    basis_u.derivatives(su, u, du, nu.as_flattened_mut());
    basis_v.derivatives(sv, v, dv, nv.as_flattened_mut());
    let (nu, nv) = (nu.as_flattened(), nv.as_flattened());
    let (cols, grid) = (surface.cols(), surface.control_points());
    // rows[k][s]: Σᵣ N⁽ᵏ⁾ᵣ(u) b_(su−p+r, sv−q+s), for k = 0, 1, 2.
    let mut rows = [[Vector3::zeros(); N]; 3];
    for r in 0..=p {
        let base = (su - p + r) * cols + sv - q;
        for s in 0..=q {
            let b = grid[base + s].coords;
            for k in 0..=du {
                rows[k][s] += b * nu[k * (p + 1) + r];
            }
        }
    }
    let along = |k: usize, l: usize| -> Vector3<Real> {
        if k > du || l > dv {
            return Vector3::zeros();
        }
        (0..=q).map(|s| rows[k][s] * nv[l * (q + 1) + s]).sum()
    };
    [
        along(0, 0),
        along(1, 0),
        along(0, 1),
        along(2, 0),
        along(1, 1),
        along(0, 2),
    ]
}

/// The step `−H⁻¹g` for the symmetric `H = [[a, b], [b, c]]`, when `H` is positive definite
/// beyond rounding (`det > 10⁻¹⁴ ac`): Newton's, or Gauss–Newton's for `H = JᵀJ`. One
/// division, its latency most of a step's.
#[inline(always)]
fn newton_step(g: [Real; 2], (a, b, c): (Real, Real, Real)) -> Option<[Real; 2]> {
    let det = a * c - b * b;
    (a > 0.0 && det > 1e-14 * a * c).then(|| {
        let inverse = det.recip();
        [-(c * g[0] - b * g[1]) * inverse, -(a * g[1] - b * g[0]) * inverse]
    })
}

/// The span of `knots` whose polynomial serves `t` in the piece `[lo, hi]`: the usual span,
/// except on the piece's upper edge `hi` inside the domain, which belongs to the next span
/// but is reached here from below.
#[inline(always)]
fn span_from_within(knots: &super::KnotVector, t: Real, (_, hi): (Real, Real)) -> usize {
    let mut span = knots.span_in_domain(t);
    if t >= hi && hi < knots.domain().1 {
        while span > knots.degree() && knots.knots()[span] >= t {
            span -= 1;
        }
    }
    span
}

/// A rectangle of the domain between creases (knots of multiplicity ≥ the degree, where the
/// surface is only C⁰) or the domain's edges, within which Newton runs: the distance has a
/// kink along a crease, and a minimum on one is found as a minimum on a piece's edge, with
/// that piece's one-sided derivatives.
#[derive(Debug, Clone, Copy)]
struct Piece {
    u: (Real, Real),
    v: (Real, Real),
}

/// The interior knots of `knots` with multiplicity at least the degree, ascending.
fn creases(knots: &super::KnotVector) -> Vec<Real> {
    let (t0, t1) = knots.domain();
    let mut out: Vec<Real> = knots
        .knots()
        .iter()
        .copied()
        .filter(|&k| k > t0 && k < t1)
        .filter(|&k| super::refine::multiplicity(knots.knots(), k) >= knots.degree())
        .collect();
    out.dedup();
    out
}

/// The piece `[lo, hi]` of `(t0, t1)` cut at `creases` that holds `t` (a crease starts the
/// piece above it).
#[inline(always)]
fn piece_of(creases: &[Real], (t0, t1): (Real, Real), t: Real) -> (Real, Real) {
    let k = creases.partition_point(|&c| c <= t);
    let lo = if k == 0 { t0 } else { creases[k - 1] };
    let hi = creases.get(k).copied().unwrap_or(t1);
    (lo, hi)
}

/// Points per leaf of a [`KdTree`] at most.
const LEAF: usize = 8;

/// A static k-d tree over points: median splits on the axis of the widest spread down to
/// leaves of at most [`LEAF`] points, whose coordinates are stored together (one plane per
/// axis) so that a leaf's distances are a short loop the compiler runs in SIMD registers.
#[derive(Debug, Clone)]
struct KdTree {
    /// The points in their given order (indices refer to it).
    points: Vec<Point3<Real>>,
    /// The points in leaf order, a plane per coordinate, and their given indices.
    planes: [Vec<Real>; 3],
    ids: Vec<u32>,
    nodes: Vec<KdNode>,
}

#[derive(Debug, Clone, Copy)]
enum KdNode {
    /// Split at `value` on `axis`: the first child follows this node, the second is at `above`.
    Split { axis: u8, value: Real, above: u32 },
    /// Points `[start, end)` in leaf order.
    Leaf { start: u32, end: u32 },
}

impl KdTree {
    fn new(points: Vec<Point3<Real>>) -> Self {
        let mut order: Vec<u32> = (0..points.len() as u32).collect();
        let mut nodes = Vec::with_capacity(2 * points.len() / LEAF + 1);
        Self::build(&points, &mut order, 0, &mut nodes);
        let planes = std::array::from_fn(|axis| order.iter().map(|&k| points[k as usize][axis]).collect());
        KdTree {
            points,
            planes,
            ids: order,
            nodes,
        }
    }

    /// Appends the subtree of `order` (which starts at `offset` in leaf order) in depth-first
    /// order.
    fn build(points: &[Point3<Real>], order: &mut [u32], offset: usize, nodes: &mut Vec<KdNode>) {
        if order.len() <= LEAF {
            nodes.push(KdNode::Leaf {
                start: offset as u32,
                end: (offset + order.len()) as u32,
            });
            return;
        }
        let (lo, hi) = bounds(order.iter().map(|&k| points[k as usize]));
        let axis = (hi - lo).imax();
        let mid = order.len() / 2;
        order.select_nth_unstable_by(mid, |&a, &b| {
            points[a as usize][axis].total_cmp(&points[b as usize][axis])
        });
        let value = points[order[mid] as usize][axis];
        let at = nodes.len();
        nodes.push(KdNode::Leaf { start: 0, end: 0 });
        let (below, above) = order.split_at_mut(mid);
        Self::build(points, below, offset, nodes);
        let above_at = nodes.len() as u32;
        Self::build(points, above, offset + mid, nodes);
        nodes[at] = KdNode::Split {
            axis: axis as u8,
            value,
            above: above_at,
        };
    }

    /// The index of the point nearest `query` (the first in leaf order among equals).
    #[inline(always)]
    fn nearest(&self, query: &Point3<Real>) -> usize {
        let mut best = (Real::INFINITY, 0usize);
        // Subtrees still to visit with the squared distance from the query to their side of
        // the split (a lower bound of their points' distances); depth ≤ log₂(n / LEAF) + 1.
        let mut stack = [(0u32, 0.0); 64];
        let mut depth = 1;
        while depth > 0 {
            depth -= 1;
            let (mut node, bound) = stack[depth];
            if bound >= best.0 {
                continue;
            }
            loop {
                match self.nodes[node as usize] {
                    KdNode::Split { axis, value, above } => {
                        let delta = query[axis as usize] - value;
                        let (near, far) = if delta < 0.0 {
                            (node + 1, above)
                        } else {
                            (above, node + 1)
                        };
                        stack[depth] = (far, delta * delta);
                        depth += 1;
                        node = near;
                    }
                    KdNode::Leaf { start, end } => {
                        let (start, end) = (start as usize, end as usize);
                        let [x, y, z] = &self.planes;
                        for k in start..end {
                            let d = (x[k] - query.x).powi(2)
                                + (y[k] - query.y).powi(2)
                                + (z[k] - query.z).powi(2);
                            if d < best.0 {
                                best = (d, k);
                            }
                        }
                        break;
                    }
                }
            }
        }
        self.ids[best.1] as usize
    }
}

/// A uniform grid of cubes over the samples' box. Each cube holds the sample nearest its centre
/// among those inside it: a query's start in one lookup where the query lies in a cube that
/// holds a sample (the use: points near the surface), and the k-d tree's otherwise. Each cube
/// also lists the boxes (of knot-span pairs) that come within [`StartGrid::margin`] of it: a
/// query's boxes within a distance up to that margin are among its cube's, so that they are
/// found without the box tree.
#[derive(Debug, Clone)]
struct StartGrid {
    lo: Point3<Real>,
    /// `1 / side`.
    inverse: Real,
    dims: [usize; 3],
    /// Per cube (`x` fastest), its sample, or `u32::MAX` for none.
    cubes: Vec<u32>,
    /// The boxes near each cube: cube `c`'s are `near[offsets[c]..offsets[c + 1]]`, ascending.
    offsets: Vec<u32>,
    near: Vec<u32>,
    /// The distance within which a cube's list holds every box (0 where the lists were not
    /// made: they would have been too long).
    margin: Real,
}

/// Cubes per sample at most in a [`StartGrid`] (its memory, and its build time).
const CUBES_PER_SAMPLE: usize = 8;

/// Entries a cube at most, on average, in a [`StartGrid`]'s lists of near boxes (else it has
/// none, and queries use the box tree).
const NEAR_PER_CUBE: usize = 16;

impl StartGrid {
    /// Cubes of side `side` at least (made larger until there are at most
    /// [`CUBES_PER_SAMPLE`] a sample), with the `boxes` within a cube's side of each cube.
    fn new(points: &[Point3<Real>], side: Real, boxes: &[(Point3<Real>, Point3<Real>)]) -> Self {
        let (lo, hi) = bounds(points.iter().copied());
        let extent = hi - lo;
        let mut side = side.max(extent.max() * 1e-9).max(Real::MIN_POSITIVE);
        let dims = loop {
            let dims = [0, 1, 2].map(|a| (extent[a] / side).floor() as usize + 1);
            let cubes = dims.iter().try_fold(1usize, |n, &d| n.checked_mul(d));
            if cubes.is_some_and(|n| n <= CUBES_PER_SAMPLE * points.len().max(1)) {
                break dims;
            }
            side *= 1.25;
        };
        let inverse = 1.0 / side;
        let mut cubes = vec![u32::MAX; dims.iter().product()];
        let mut nearest = vec![Real::INFINITY; cubes.len()];
        for (k, p) in points.iter().enumerate() {
            let at = [0, 1, 2].map(|a| (((p[a] - lo[a]) * inverse) as usize).min(dims[a] - 1));
            let cube = (at[2] * dims[1] + at[1]) * dims[0] + at[0];
            let centre = lo + Vector3::from(at.map(|i| (i as Real + 0.5) * side));
            let d = (p - centre).norm_squared();
            if d < nearest[cube] {
                nearest[cube] = d;
                cubes[cube] = k as u32;
            }
        }
        let mut grid = StartGrid {
            lo,
            inverse,
            dims,
            cubes,
            offsets: Vec::new(),
            near: Vec::new(),
            margin: 0.0,
        };
        grid.list_near(boxes, side);
        grid
    }

    /// The cubes' lists of the boxes within `margin` of them, unless they would hold more
    /// than [`NEAR_PER_CUBE`] entries a cube.
    fn list_near(&mut self, boxes: &[(Point3<Real>, Point3<Real>)], margin: Real) {
        // Each box widened by a little more than the margin, so that rounding in the cube
        // indices cannot leave out a cube whose points lie within the margin.
        let widen = 1.01 * margin;
        let ranges: Vec<[(usize, usize); 3]> = boxes
            .iter()
            .map(|(lo, hi)| {
                [0, 1, 2].map(|a| {
                    let at = |t: Real| {
                        let c = ((t - self.lo[a]) * self.inverse).floor();
                        c.clamp(0.0, (self.dims[a] - 1) as Real) as usize
                    };
                    (at(lo[a] - widen), at(hi[a] + widen))
                })
            })
            .collect();
        let total = ranges.iter().try_fold(0usize, |n, r| {
            let count = r.iter().map(|&(a, b)| b - a + 1).product::<usize>();
            n.checked_add(count)
        });
        if !total.is_some_and(|n| n <= NEAR_PER_CUBE * self.cubes.len() && n < u32::MAX as usize) {
            return;
        }
        // Counting sort by cube: counts, offsets, then the boxes in ascending order.
        let cube = |x: usize, y: usize, z: usize| (z * self.dims[1] + y) * self.dims[0] + x;
        let each = |r: &[(usize, usize); 3], f: &mut dyn FnMut(usize)| {
            for z in r[2].0..=r[2].1 {
                for y in r[1].0..=r[1].1 {
                    for x in r[0].0..=r[0].1 {
                        f(cube(x, y, z));
                    }
                }
            }
        };
        let mut offsets = vec![0u32; self.cubes.len() + 1];
        for r in &ranges {
            each(r, &mut |c| offsets[c + 1] += 1);
        }
        for c in 0..self.cubes.len() {
            offsets[c + 1] += offsets[c];
        }
        let mut next = offsets.clone();
        let mut near = vec![0u32; offsets[self.cubes.len()] as usize];
        for (k, r) in ranges.iter().enumerate() {
            each(r, &mut |c| {
                near[next[c] as usize] = k as u32;
                next[c] += 1;
            });
        }
        (self.offsets, self.near, self.margin) = (offsets, near, margin);
    }

    /// The cube that holds `query`, if one does.
    #[inline(always)]
    fn cube(&self, query: &Point3<Real>) -> Option<usize> {
        let mut cube = 0;
        for a in (0..3).rev() {
            let t = (query[a] - self.lo[a]) * self.inverse;
            // Written so that NaN fails too (queries are finite; the box's is not checked).
            if !(t >= 0.0 && t < self.dims[a] as Real) {
                return None;
            }
            cube = cube * self.dims[a] + t as usize;
        }
        Some(cube)
    }

    /// The sample of the cube that holds `query`, if it holds one.
    #[cfg(test)]
    fn start(&self, query: &Point3<Real>) -> Option<usize> {
        self.cube(query).and_then(|c| self.sample_of(c))
    }

    /// The sample of cube `cube`, if it holds one.
    #[inline(always)]
    fn sample_of(&self, cube: usize) -> Option<usize> {
        let k = self.cubes[cube];
        (k != u32::MAX).then_some(k as usize)
    }

    /// The boxes within `distance` of a point in `cube`, among others, ascending; `None` where
    /// the distance exceeds the lists' margin.
    #[inline(always)]
    fn near(&self, cube: usize, distance: Real) -> Option<&[u32]> {
        (distance <= self.margin)
            .then(|| &self.near[self.offsets[cube] as usize..self.offsets[cube + 1] as usize])
    }
}

/// A bounding-volume hierarchy over boxes (median splits on the longest axis of the centres),
/// for the boxes within a distance of a point.
#[derive(Debug, Clone)]
struct BoxTree {
    /// Nodes: their box, and either two children or a leaf's box index.
    nodes: Vec<(Point3<Real>, Point3<Real>, Node)>,
}

#[derive(Debug, Clone, Copy)]
enum Node {
    Inner(u32, u32),
    Leaf(u32),
}

/// The corners of the axis-aligned box of `points` (infinite and inverted for none).
fn bounds(points: impl Iterator<Item = Point3<Real>>) -> (Point3<Real>, Point3<Real>) {
    points.fold(
        (
            Point3::from([Real::INFINITY; 3]),
            Point3::from([Real::NEG_INFINITY; 3]),
        ),
        |(lo, hi), p| (lo.inf(&p), hi.sup(&p)),
    )
}

#[inline(always)]
fn box_distance2(lo: &Point3<Real>, hi: &Point3<Real>, p: &Point3<Real>) -> Real {
    (lo - p).sup(&(p - hi)).sup(&Vector3::zeros()).norm_squared()
}

impl BoxTree {
    fn new(boxes: &[(Point3<Real>, Point3<Real>)]) -> Self {
        let mut tree = BoxTree {
            nodes: Vec::with_capacity(2 * boxes.len()),
        };
        let mut items: Vec<u32> = (0..boxes.len() as u32).collect();
        tree.build(boxes, &mut items);
        tree
    }

    fn build(&mut self, boxes: &[(Point3<Real>, Point3<Real>)], items: &mut [u32]) -> u32 {
        let (lo, hi) = bounds(
            items
                .iter()
                .flat_map(|&k| [boxes[k as usize].0, boxes[k as usize].1]),
        );
        let at = self.nodes.len() as u32;
        if items.len() == 1 {
            self.nodes.push((lo, hi, Node::Leaf(items[0])));
            return at;
        }
        self.nodes.push((lo, hi, Node::Leaf(0)));
        let centre = |k: u32| nalgebra::center(&boxes[k as usize].0, &boxes[k as usize].1);
        let extent = hi - lo;
        let axis = extent.imax();
        let mid = items.len() / 2;
        items.select_nth_unstable_by(mid, |&a, &b| centre(a)[axis].total_cmp(&centre(b)[axis]));
        let (left, right) = items.split_at_mut(mid);
        let l = self.build(boxes, left);
        let r = self.build(boxes, right);
        self.nodes[at as usize].2 = Node::Inner(l, r);
        at
    }

    /// Every box whose distance to `p` is below `sqrt(r2)`, appended to `out`.
    #[inline(always)]
    fn within(&self, p: &Point3<Real>, r2: Real, out: &mut Vec<usize>) {
        // Depth-first: at most one pending sibling a level, and median splits keep the depth
        // at ⌈log₂ boxes⌉ + 1.
        let mut stack = [0u32; 64];
        let mut depth = 1;
        while depth > 0 {
            depth -= 1;
            let (lo, hi, node) = &self.nodes[stack[depth] as usize];
            if box_distance2(lo, hi, p) >= r2 {
                continue;
            }
            match *node {
                Node::Leaf(k) => out.push(k as usize),
                Node::Inner(a, b) => {
                    stack[depth] = a;
                    stack[depth + 1] = b;
                    depth += 2;
                }
            }
        }
    }
}

/// The lists a query fills, kept from one query to the next to save their allocations.
#[derive(Debug, Default)]
struct Scratch {
    /// Knot-span pairs whose boxes come near the query.
    spans: Vec<usize>,
    /// Knot-span pairs a Newton search started or ended in.
    tried: Vec<usize>,
}

/// A surface made ready for closest-point queries (see the module documentation).
///
/// # Examples
///
/// ```
/// use nalgebra::Point3;
/// use splineface::bspline::{BSplineSurface, ClosestPoints, KnotVector};
///
/// // z = 0 over [0, 3]²: the closest point to (1, 2, 5) is (1, 2, 0), at distance 5.
/// let k = KnotVector::clamped_uniform(3, 4, 0.0, 1.0)?;
/// let grid = (0..16).map(|i| Point3::new((i / 4) as f64, (i % 4) as f64, 0.0)).collect();
/// let plane = BSplineSurface::new(k.clone(), k, 4, 4, grid)?;
/// let inverter = ClosestPoints::new(&plane);
/// let c = inverter.closest(&Point3::new(1.0, 2.0, 5.0))?;
/// assert!((c.u - 1.0 / 3.0).abs() < 1e-12 && (c.v - 2.0 / 3.0).abs() < 1e-12);
/// assert!((c.distance - 5.0).abs() < 1e-12);
/// # Ok::<(), splineface::bspline::BSplineError>(())
/// ```
#[derive(Debug, Clone)]
pub struct ClosestPoints<'a> {
    surface: Cow<'a, BSplineSurface>,
    /// The samples' parameters along `u` and `v` (the samples are their grid, row-major).
    us: Vec<Real>,
    vs: Vec<Real>,
    tree: KdTree,
    /// Starts by lookup for queries near the samples.
    grid: StartGrid,
    /// Each sample's derivatives `(Fᵤ, F_v, Fᵤᵤ, Fᵤ_v, F_vv)` (within the sample's piece), in
    /// the samples' order: Newton's start is taken from them without evaluating the surface.
    derivatives: Vec<[Vector3<Real>; 5]>,
    /// Every point of the surface lies within this of a sample (the largest cell diagonal).
    reach: Real,
    /// The boxes of the knot-span pairs' Bézier control points (row-major over `u` spans),
    /// each holding the surface over its spans (the convex hull property).
    boxes: BoxTree,
    /// The same boxes, by knot-span pair.
    span_boxes: Vec<(Point3<Real>, Point3<Real>)>,
    /// Knot spans along `v`.
    spans_v: usize,
    /// The creases along `u` and `v` (see [`Piece`]).
    creases_u: Vec<Real>,
    creases_v: Vec<Real>,
    /// Steps that move the surface point less than this have converged.
    tolerance: Real,
    /// The basis functions of each span in `u` and `v`, for Newton's derivatives.
    basis: [SpanPolynomials; 2],
}

/// `SAMPLES_PER_SPAN` parameters a non-empty span of `knots`, the domain's ends included.
fn sample_parameters(knots: &super::KnotVector) -> Vec<Real> {
    let breaks = knots.breakpoints();
    let mut out = Vec::new();
    for w in breaks.windows(2) {
        for s in 0..SAMPLES_PER_SPAN {
            out.push(w[0] + (w[1] - w[0]) * s as Real / SAMPLES_PER_SPAN as Real);
        }
    }
    out.push(knots.domain().1);
    out
}

impl<'a> ClosestPoints<'a> {
    /// Samples `surface` and builds the tree of its samples.
    pub fn new(surface: &'a BSplineSurface) -> Self {
        Self::build(Cow::Borrowed(surface))
    }

    /// As [`ClosestPoints::new`], owning its surface: an index that can be kept where a
    /// borrow cannot (a cache beside the surface, a handle in another language).
    ///
    /// ```
    /// use nalgebra::Point3;
    /// use splineface::bspline::{BSplineSurface, ClosestPoints, KnotVector};
    ///
    /// let knots = KnotVector::clamped_uniform(1, 2, 0.0, 1.0)?;
    /// let grid = vec![
    ///     Point3::new(0.0, 0.0, 0.0), Point3::new(0.0, 1.0, 0.0),
    ///     Point3::new(1.0, 0.0, 0.0), Point3::new(1.0, 1.0, 0.0),
    /// ];
    /// let index: ClosestPoints<'static> =
    ///     ClosestPoints::owning(BSplineSurface::new(knots.clone(), knots, 2, 2, grid)?);
    /// let found = index.closest(&Point3::new(0.25, 0.5, 2.0))?;
    /// assert!((found.u - 0.25).abs() < 1e-12 && (found.v - 0.5).abs() < 1e-12);
    /// assert!((found.distance - 2.0).abs() < 1e-12);
    /// # Ok::<(), splineface::bspline::BSplineError>(())
    /// ```
    pub fn owning(surface: BSplineSurface) -> ClosestPoints<'static> {
        ClosestPoints::build(Cow::Owned(surface))
    }

    fn build(surface: Cow<'a, BSplineSurface>) -> Self {
        let (us, vs) = (
            sample_parameters(surface.knots_u()),
            sample_parameters(surface.knots_v()),
        );
        let points = surface.eval_grid(&us, &vs).expect("samples lie in the domain");
        let nv = vs.len();
        // Each cell's longer diagonal.
        let mut diagonals: Vec<Real> = (0..us.len() - 1)
            .flat_map(|i| (0..nv - 1).map(move |j| (i, j)))
            .map(|(i, j)| {
                let at = |a: usize, b: usize| points[a * nv + b];
                (at(i + 1, j + 1) - at(i, j))
                    .norm()
                    .max((at(i + 1, j) - at(i, j + 1)).norm())
            })
            .collect();
        let reach = diagonals.iter().copied().fold(0.0, Real::max);
        // The start grid's cubes about a typical cell's size (the median's: a few steep cells
        // would make the largest's coarse everywhere).
        let middle = diagonals.len() / 2;
        let typical = *diagonals.select_nth_unstable_by(middle, Real::total_cmp).1;
        let (lo, hi) = bounds(points.iter().copied());
        let size = (hi - lo).norm().max(Real::MIN_POSITIVE);
        let boxes = surface
            .bezier_patches()
            .expect("a valid surface has Bézier patches")
            .iter()
            .map(|patch| bounds(patch.control_points().iter().copied()))
            .collect::<Vec<_>>();
        let grid = StartGrid::new(&points, typical, &boxes);
        let box_tree = BoxTree::new(&boxes);
        let spans_v = (vs.len() - 1) / SAMPLES_PER_SPAN;
        let (creases_u, creases_v) = (creases(surface.knots_u()), creases(surface.knots_v()));
        let basis = [
            SpanPolynomials::new(surface.knots_u()),
            SpanPolynomials::new(surface.knots_v()),
        ];
        let derivatives = us
            .iter()
            .flat_map(|&u| vs.iter().map(move |&v| (u, v)))
            .map(|(u, v)| {
                let piece = Piece {
                    u: piece_of(&creases_u, surface.domain_u(), u),
                    v: piece_of(&creases_v, surface.domain_v(), v),
                };
                let d = second_order(&surface, [&basis[0], &basis[1]], u, v, &piece);
                [d[1], d[2], d[3], d[4], d[5]]
            })
            .collect();
        ClosestPoints {
            surface,
            boxes: box_tree,
            span_boxes: boxes,
            spans_v,
            creases_u,
            creases_v,
            us,
            vs,
            grid,
            tree: KdTree::new(points),
            derivatives,
            // A cell bulges by little more than its diagonal's tenth for the spans sampled.
            reach: 1.1 * reach,
            tolerance: 1e-12 * size,
            basis,
        }
    }

    /// The closest point of the surface to `query`.
    ///
    /// # Errors
    /// [`BSplineError::NonFiniteSample`] (index 0) for a query with a NaN or infinite
    /// coordinate.
    pub fn closest(&self, query: &Point3<Real>) -> Result<ClosestPoint, BSplineError> {
        if !query.coords.iter().all(|c| c.is_finite()) {
            return Err(BSplineError::NonFiniteSample { index: 0 });
        }
        Ok(self.search(query, &mut Scratch::default()))
    }

    /// The sample `index`'s grid cell `(i, j)` and parameters.
    #[inline(always)]
    fn sample(&self, index: usize) -> ((usize, usize), [Real; 2]) {
        let (i, j) = (index / self.vs.len(), index % self.vs.len());
        ((i, j), [self.us[i], self.vs[j]])
    }

    /// The grid cell of parameters `(u, v)`.
    #[inline(always)]
    fn cell(&self, u: Real, v: Real) -> (usize, usize) {
        let at = |grid: &[Real], t: Real| grid.partition_point(|&g| g <= t).saturating_sub(1);
        (at(&self.us, u), at(&self.vs, v))
    }

    /// The piece that holds `(u, v)`.
    #[inline(always)]
    fn piece(&self, u: Real, v: Real) -> Piece {
        let s: &BSplineSurface = &self.surface;
        Piece {
            u: piece_of(&self.creases_u, s.domain_u(), u),
            v: piece_of(&self.creases_v, s.domain_v(), v),
        }
    }

    /// The knot-span pair of an answer found in `piece` (one on the piece's upper edge belongs
    /// to the span below it, the span of the piece).
    #[inline(always)]
    fn span_of_answer(&self, found: &ClosestPoint, piece: &Piece) -> usize {
        self.span_of(self.cell(short_of_upper(found.u, piece.u), short_of_upper(found.v, piece.v)))
    }

    /// The knot-span pair of sample cell `(i, j)` (the last samples belong to the last span).
    #[inline(always)]
    fn span_of(&self, (i, j): (usize, usize)) -> usize {
        let spans_u = (self.us.len() - 1) / SAMPLES_PER_SPAN;
        let a = (i / SAMPLES_PER_SPAN).min(spans_u - 1);
        let b = (j / SAMPLES_PER_SPAN).min(self.spans_v - 1);
        a * self.spans_v + b
    }

    /// Newton from the nearest sample; then from the nearest sample of every other knot span
    /// whose Bézier box comes nearer the query than the answer so far (and that no start or
    /// answer has been in), keeping the nearest answer.
    /// `scratch` holds lists between queries (their contents do not matter).
    ///
    /// It and the functions it calls are `#[inline(always)]`, so that a batch's loop is one
    /// function (16% more queries a second; see the module's docs).
    #[inline(always)]
    fn search(&self, query: &Point3<Real>, scratch: &mut Scratch) -> ClosestPoint {
        let cube = self.grid.cube(query);
        let nearest = match cube.and_then(|c| self.grid.sample_of(c)) {
            Some(k) => self.descend(query, k),
            None => self.tree.nearest(query),
        };
        let (cell, sample) = self.sample(nearest);
        let piece = self.piece(sample[0], sample[1]);
        let start = self.first_step(query, nearest, &piece);
        let mut best = self.newton(query, start, &piece);
        let Scratch { spans, tried } = scratch;
        spans.clear();
        let r2 = best.distance * best.distance;
        match cube.and_then(|c| self.grid.near(c, best.distance)) {
            Some(near) => spans.extend(
                near.iter()
                    .map(|&k| k as usize)
                    .filter(|&k| box_distance2(&self.span_boxes[k].0, &self.span_boxes[k].1, query) < r2),
            ),
            None => self.boxes.within(query, r2, spans),
        }
        tried.clear();
        tried.extend([
            self.span_of(cell),
            self.span_of(self.cell(
                short_of_upper(start[0], piece.u),
                short_of_upper(start[1], piece.v),
            )),
            self.span_of_answer(&best, &piece),
        ]);
        // In span order, so that the answer does not depend on the tree's traversal.
        spans.retain(|s| !tried.contains(s));
        spans.sort_unstable();
        for &span in spans.iter() {
            if tried.contains(&span) {
                continue;
            }
            // Start from the span's sample nearest the query.
            let (a, b) = (span / self.spans_v, span % self.spans_v);
            let mut start = ((a * SAMPLES_PER_SPAN, b * SAMPLES_PER_SPAN), Real::INFINITY);
            for i in a * SAMPLES_PER_SPAN..=(a + 1) * SAMPLES_PER_SPAN {
                for j in b * SAMPLES_PER_SPAN..=(b + 1) * SAMPLES_PER_SPAN {
                    let d = (self.tree.points[i * self.vs.len() + j] - query).norm_squared();
                    if d < start.1 {
                        start = ((i, j), d);
                    }
                }
            }
            let ((i, j), d2) = start;
            if d2.sqrt() - self.reach >= best.distance {
                // No point of the span comes nearer than its samples allow.
                continue;
            }
            // A sample on the span's far edge is also the next span's first, and would put
            // the search in the next span's piece. So start just inside the span.
            // (The span's samples lie in it, so only its upper edge needs keeping off.)
            let span_ends = |grid: &[Real], first: usize| (grid[first], grid[first + SAMPLES_PER_SPAN]);
            let start = [
                short_of_upper(self.us[i], span_ends(&self.us, a * SAMPLES_PER_SPAN)),
                short_of_upper(self.vs[j], span_ends(&self.vs, b * SAMPLES_PER_SPAN)),
            ];
            let piece = self.piece(start[0], start[1]);
            let found = self.newton(query, start, &piece);
            tried.push(span);
            tried.push(self.span_of_answer(&found, &piece));
            if found.distance < best.distance {
                best = found;
            }
        }
        best
    }

    /// From sample `index`, the sample grid's neighbours (the eight around) walked to while
    /// one comes nearer `query`: a sample where none does, at most [`WALK`] moves away.
    #[inline(always)]
    fn descend(&self, query: &Point3<Real>, index: usize) -> usize {
        let (nu, nv) = (self.us.len(), self.vs.len());
        let points = &self.tree.points;
        let (mut i, mut j) = (index / nv, index % nv);
        let mut best = (points[index] - query).norm_squared();
        for _ in 0..WALK {
            let mut next = None;
            for a in i.saturating_sub(1)..=(i + 1).min(nu - 1) {
                for b in j.saturating_sub(1)..=(j + 1).min(nv - 1) {
                    let d = (points[a * nv + b] - query).norm_squared();
                    if d < best {
                        best = d;
                        next = Some((a, b));
                    }
                }
            }
            let Some(at) = next else { break };
            (i, j) = at;
        }
        i * nv + j
    }

    /// Newton's start from sample `index` toward `query`: the closest point of the surface's
    /// second-order expansion about the sample (its stored derivatives, so no evaluation),
    /// found by up to [`MODEL_STEPS`] Newton steps on the expansion, held within a sample
    /// spacing of the sample and inside `piece`; the sample itself where the expansion does
    /// not determine a step.
    #[inline(always)]
    fn first_step(&self, query: &Point3<Real>, index: usize, piece: &Piece) -> [Real; 2] {
        let ((i, j), [u, v]) = self.sample(index);
        let [fu, fv, fuu, fuv, fvv] = self.derivatives[index];
        let r0 = self.tree.points[index] - query;
        let spacing = |grid: &[Real], k: usize| {
            let k = k.min(grid.len() - 2);
            grid[k + 1] - grid[k]
        };
        let (hu, hv) = (spacing(&self.us, i), spacing(&self.vs, j));
        // The step's bounds: a sample spacing, and the piece.
        let (lu, uu) = ((piece.u.0 - u).max(-hu), (piece.u.1 - u).min(hu));
        let (lv, uv) = ((piece.v.0 - v).max(-hv), (piece.v.1 - v).min(hv));
        let (mut du, mut dv) = (0.0, 0.0);
        for _ in 0..MODEL_STEPS {
            let r = r0 + fu * du + fv * dv + fuu * (0.5 * du * du) + fuv * (du * dv) + fvv * (0.5 * dv * dv);
            let (tu, tv) = (fu + fuu * du + fuv * dv, fv + fuv * du + fvv * dv);
            let g = [r.dot(&tu), r.dot(&tv)];
            let (a, b, c) = (tu.dot(&tu), tu.dot(&tv), tv.dot(&tv));
            let full = (a + r.dot(&fuu), b + r.dot(&fuv), c + r.dot(&fvv));
            let Some([su, sv]) = newton_step(g, full).or_else(|| newton_step(g, (a, b, c))) else {
                break;
            };
            (du, dv) = ((du + su).clamp(lu, uu), (dv + sv).clamp(lv, uv));
        }
        [u + du, v + dv]
    }

    /// [`ClosestPoints::closest`] for every query, in parallel (rayon).
    ///
    /// # Errors
    /// [`BSplineError::NonFiniteSample`] naming the first query that is not finite.
    ///
    /// # Examples
    ///
    /// ```
    /// use nalgebra::Point3;
    /// use splineface::bspline::{BSplineSurface, ClosestPoints, KnotVector};
    ///
    /// // The saddle z = (x − 1)(y − 1) over [0, 2]² (bilinear, so exact as a spline).
    /// let k = KnotVector::clamped_uniform(1, 2, 0.0, 1.0)?;
    /// let grid = vec![
    ///     Point3::new(0.0, 0.0, 1.0), Point3::new(0.0, 2.0, -1.0),
    ///     Point3::new(2.0, 0.0, -1.0), Point3::new(2.0, 2.0, 1.0),
    /// ];
    /// let saddle = BSplineSurface::new(k.clone(), k, 2, 2, grid)?;
    /// let inverter = ClosestPoints::new(&saddle);
    /// // One answer a query, in the queries' order; each a point on the surface whose
    /// // distance is the query's from it.
    /// let queries = [Point3::new(1.0, 1.0, 3.0), Point3::new(0.2, 1.9, -2.0), Point3::new(5.0, 5.0, 5.0)];
    /// let found = inverter.closest_many(&queries)?;
    /// assert_eq!(found.len(), 3);
    /// for (q, c) in queries.iter().zip(&found) {
    ///     assert!((saddle.eval(c.u, c.v)? - c.point).norm() < 1e-12);
    ///     assert!(((q - c.point).norm() - c.distance).abs() < 1e-12);
    /// }
    /// // Beyond the corner (2, 2, 1), the corner is nearest.
    /// assert_eq!((found[2].u, found[2].v), (1.0, 1.0));
    /// assert!(inverter.closest_many(&[Point3::new(f64::NAN, 0.0, 0.0)]).is_err());
    /// # Ok::<(), splineface::bspline::BSplineError>(())
    /// ```
    pub fn closest_many(&self, queries: &[Point3<Real>]) -> Result<Vec<ClosestPoint>, BSplineError> {
        if let Some(index) = queries
            .iter()
            .position(|q| !q.coords.iter().all(|c| c.is_finite()))
        {
            return Err(BSplineError::NonFiniteSample { index });
        }
        // In Morton (Z-order) order of the queries: neighbouring queries then walk the same
        // parts of the sample tree and the box tree. Each answer is the one `closest` gives
        // (nothing is carried from one query to the next).
        Ok(crate::mesh::in_morton_order(queries, 256, |chunk| {
            let mut scratch = Scratch::default();
            chunk.iter().map(|q| self.search(q, &mut scratch)).collect()
        }))
    }

    /// Damped Newton from `start` within `piece`, whose edges act as the domain's.
    #[inline(always)]
    fn newton(&self, query: &Point3<Real>, start: [Real; 2], piece: &Piece) -> ClosestPoint {
        let s: &BSplineSurface = &self.surface;
        let ((u0, u1), (v0, v1)) = (piece.u, piece.v);
        let [mut u, mut v] = start;
        let mut d = second_order(s, [&self.basis[0], &self.basis[1]], u, v, piece);
        let mut r = d[0] - query.coords;
        let mut f = r.norm_squared();
        let query_norm = query.coords.norm();
        for _ in 0..MAX_STEPS {
            let (fu, fv) = (d[1], d[2]);
            let g = [r.dot(&fu), r.dot(&fv)];
            // A coordinate on its bound whose descent (−g) leads out stays there (an active
            // set): the search goes on along the edge, or stops in a corner.
            let fixed_u = (u <= u0 && g[0] > 0.0) || (u >= u1 && g[0] < 0.0);
            let fixed_v = (v <= v0 && g[1] > 0.0) || (v >= v1 && g[1] < 0.0);
            // Zero cosine: the residual is perpendicular to the surface along every free
            // direction (or vanishes): `|r·Fᵤ| ≤ 10⁻¹² |r| |Fᵤ|`, compared squared.
            let (a, b, c) = (fu.dot(&fu), fu.dot(&fv), fv.dot(&fv));
            let flat_u = fixed_u || g[0] * g[0] <= 1e-24 * f * a;
            let flat_v = fixed_v || g[1] * g[1] <= 1e-24 * f * c;
            if flat_u && flat_v {
                break;
            }
            let full = (a + r.dot(&d[3]), b + r.dot(&d[4]), c + r.dot(&d[5]));
            let solve = |(a, b, c): (Real, Real, Real)| -> Option<[Real; 2]> {
                match (fixed_u, fixed_v) {
                    (true, false) => (c > 0.0).then(|| [0.0, -g[1] / c]),
                    (false, true) => (a > 0.0).then(|| [-g[0] / a, 0.0]),
                    _ => newton_step(g, (a, b, c)),
                }
            };
            let Some(mut step) = solve(full).or_else(|| solve((a, b, c))) else {
                break;
            };
            // Within rounding of no worse: near the answer `f` stops resolving the steps that
            // still straighten the residual to the normal (`r = F − P` carries the rounding of
            // coordinates of size `|P|`, `f = |r|²` twice `|r|` times that).
            let slack = 16.0 * Real::EPSILON * f.sqrt() * (query_norm + d[0].norm());
            // Damped: halve the step until it does not move away (at most 30 halvings).
            let mut accepted = false;
            for _ in 0..30 {
                let (nu, nv) = ((u + step[0]).clamp(u0, u1), (v + step[1]).clamp(v0, v1));
                let nd = second_order(s, [&self.basis[0], &self.basis[1]], nu, nv, piece);
                let nr = nd[0] - query.coords;
                let nf = nr.norm_squared();
                if nf <= f + slack {
                    let moved2 = (nd[0] - d[0]).norm_squared();
                    (u, v, d, r, f) = (nu, nv, nd, nr, nf);
                    accepted = moved2 > self.tolerance * self.tolerance;
                    break;
                }
                step = [0.5 * step[0], 0.5 * step[1]];
            }
            if !accepted {
                break;
            }
        }
        ClosestPoint {
            u,
            v,
            point: Point3::from(d[0]),
            distance: f.sqrt(),
        }
    }
}

impl BSplineSurface {
    /// The closest point of the surface to `query` (for many queries, build
    /// [`ClosestPoints`] once).
    ///
    /// # Errors
    /// As [`ClosestPoints::closest`].
    ///
    /// # Examples
    ///
    /// ```
    /// use nalgebra::Point3;
    /// use splineface::bspline::{BSplineSurface, KnotVector};
    ///
    /// // The plane z = 1 over [0, 1]²: straight down onto it.
    /// let k = KnotVector::clamped_uniform(1, 2, 0.0, 1.0)?;
    /// let grid = vec![
    ///     Point3::new(0.0, 0.0, 1.0), Point3::new(0.0, 1.0, 1.0),
    ///     Point3::new(1.0, 0.0, 1.0), Point3::new(1.0, 1.0, 1.0),
    /// ];
    /// let plane = BSplineSurface::new(k.clone(), k, 2, 2, grid)?;
    /// let c = plane.closest_point(&Point3::new(0.7, 0.1, -1.0))?;
    /// assert!((c.u - 0.7).abs() < 1e-12 && (c.v - 0.1).abs() < 1e-12 && (c.distance - 2.0).abs() < 1e-12);
    /// # Ok::<(), splineface::bspline::BSplineError>(())
    /// ```
    pub fn closest_point(&self, query: &Point3<Real>) -> Result<ClosestPoint, BSplineError> {
        ClosestPoints::new(self).closest(query)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::random::Lcg;

    /// The bucketed tree finds a point at the nearest distance (brute force), on random points
    /// with repeated and coplanar ones, for sizes around the leaf size.
    #[test]
    fn the_kd_tree_finds_the_nearest_point() {
        let mut rng = Lcg(5);
        for n in [1, 2, LEAF, LEAF + 1, 100, 1000] {
            let mut points: Vec<Point3<Real>> = (0..n)
                .map(|_| Point3::new(rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0), 0.0))
                .collect();
            if n > 4 {
                points[3] = points[1]; // a repeated point
            }
            let tree = KdTree::new(points.clone());
            for _ in 0..200 {
                let q = rng.point_in([-1.5, -1.5, -0.5], [1.5, 1.5, 0.5]);
                let found = (points[tree.nearest(&q)] - q).norm_squared();
                let nearest = points
                    .iter()
                    .map(|p| (p - q).norm_squared())
                    .fold(Real::INFINITY, Real::min);
                assert_eq!(found, nearest, "{n} points, query {q}");
            }
        }
    }

    /// The first step from a sample's tangents is exact on a flat, affinely parametrised
    /// surface (its Gauss–Newton model is the surface): from the nearest sample it lands on the
    /// foot of the perpendicular, unless that lies more than a sample spacing away or outside
    /// the domain, where it is held there.
    #[test]
    fn the_first_step_is_exact_on_an_affine_plane() {
        // F(u, v) = (3u, 2u + 4v, u − v) over [0, 1]², cubic in both directions.
        let k = crate::bspline::KnotVector::clamped_uniform(3, 6, 0.0, 1.0).unwrap();
        let at = |u: Real, v: Real| Point3::new(3.0 * u, 2.0 * u + 4.0 * v, u - v);
        // Greville abscissae: the control points of an affine map are its values there.
        let g = |i: usize| k.knots()[i + 1..i + 4].iter().sum::<Real>() / 3.0;
        let grid = (0..36).map(|i| at(g(i / 6), g(i % 6))).collect();
        let plane = BSplineSurface::new(k.clone(), k, 6, 6, grid).unwrap();
        let index = ClosestPoints::new(&plane);
        let normal = Vector3::new(3.0, 2.0, 1.0)
            .cross(&Vector3::new(0.0, 4.0, -1.0))
            .normalize();
        let mut rng = Lcg(3);
        let mut exact = 0;
        for _ in 0..500 {
            let (u, v) = (rng.uniform(-0.05, 1.05), rng.uniform(-0.05, 1.05));
            let query = at(u, v) + normal * rng.uniform(-2.0, 2.0);
            let nearest = index.tree.nearest(&query);
            let (_, sample) = index.sample(nearest);
            let piece = index.piece(sample[0], sample[1]);
            let [su, sv] = index.first_step(&query, nearest, &piece);
            let spacing = 1.0 / (3.0 * SAMPLES_PER_SPAN as Real);
            let held = |t: Real, s: Real| (t.clamp(s - spacing, s + spacing)).clamp(0.0, 1.0);
            let (eu, ev) = (held(u, sample[0]), held(v, sample[1]));
            assert!(
                (su - eu).abs() < 1e-12 && (sv - ev).abs() < 1e-12,
                "({u}, {v}): ({su}, {sv}) against ({eu}, {ev})"
            );
            exact += usize::from(eu == u && ev == v);
        }
        assert!(exact > 400, "{exact} of 500 steps landed on the foot");
    }

    /// `n` points uniform in the slab `[0, 4] × [−1, 1] × [0, depth]`.
    fn slab(rng: &mut Lcg, n: usize, depth: Real) -> Vec<Point3<Real>> {
        (0..n)
            .map(|_| rng.point_in([0.0, -1.0, 0.0], [4.0, 1.0, depth]))
            .collect()
    }

    /// The start grid gives, for a query in a cube, the sample of that cube nearest its centre
    /// (brute force over the samples), and nothing for an empty cube or outside the box.
    #[test]
    fn the_start_grid_holds_each_cubes_sample_nearest_its_centre() {
        let mut rng = Lcg(8);
        let points = slab(&mut rng, 300, 0.3);
        let grid = StartGrid::new(&points, 0.2, &[]);
        let side = 1.0 / grid.inverse;
        assert!(grid.cubes.len() <= CUBES_PER_SAMPLE * points.len());
        let cube_of = |p: &Point3<Real>| {
            [0, 1, 2].map(|a| (((p[a] - grid.lo[a]) / side) as usize).min(grid.dims[a] - 1))
        };
        for _ in 0..2000 {
            let q = rng.point_in([-0.5, -1.5, -0.2], [4.5, 1.5, 0.5]);
            let inside =
                (0..3).all(|a| q[a] >= grid.lo[a] && q[a] < grid.lo[a] + side * grid.dims[a] as Real);
            let expected = inside
                .then(|| {
                    let c = cube_of(&q);
                    let centre = grid.lo + Vector3::from(c.map(|i| (i as Real + 0.5) * side));
                    (0..points.len())
                        .filter(|&k| cube_of(&points[k]) == c)
                        .min_by(|&a, &b| {
                            (points[a] - centre)
                                .norm_squared()
                                .total_cmp(&(points[b] - centre).norm_squared())
                        })
                })
                .flatten();
            assert_eq!(grid.start(&q), expected, "query {q}");
        }
    }

    /// A cube's list of near boxes holds every box within the margin of any point in the
    /// cube (brute force over random boxes and queries, the distances up to the margin), in
    /// ascending order; and there is no list where the distance exceeds the margin.
    #[test]
    fn a_cubes_near_boxes_hold_every_box_within_the_margin() {
        let mut rng = Lcg(11);
        let points = slab(&mut rng, 400, 0.5);
        let boxes: Vec<(Point3<Real>, Point3<Real>)> = (0..60)
            .map(|_| {
                let lo = rng.point_in([-0.5, -1.5, -0.2], [4.0, 1.0, 0.5]);
                (
                    lo,
                    lo + Vector3::new(
                        rng.uniform(0.0, 0.6),
                        rng.uniform(0.0, 0.6),
                        rng.uniform(0.0, 0.2),
                    ),
                )
            })
            .collect();
        let grid = StartGrid::new(&points, 0.25, &boxes);
        assert!(grid.margin > 0.0, "the lists were made");
        let mut listed = 0;
        for _ in 0..3000 {
            let q = rng.point_in([-0.5, -1.5, -0.2], [4.5, 1.5, 0.7]);
            let Some(cube) = grid.cube(&q) else { continue };
            assert!(grid.near(cube, 1.001 * grid.margin).is_none());
            let r = rng.uniform(0.0, grid.margin);
            let near = grid.near(cube, r).unwrap();
            assert!(near.windows(2).all(|w| w[0] < w[1]));
            for (k, (lo, hi)) in boxes.iter().enumerate() {
                if box_distance2(lo, hi, &q) < r * r {
                    assert!(near.contains(&(k as u32)), "box {k} within {r} of {q}");
                    listed += 1;
                }
            }
        }
        assert!(listed > 300, "the queries came near boxes ({listed})");
    }

    /// The fixed-degree derivatives are the general form's, bit for bit (the same sums in the
    /// same order), for degrees 2 and 3 on non-uniform knots.
    #[test]
    fn fixed_degree_derivatives_equal_the_general_form() {
        let mut rng = Lcg(9);
        for degree in [2, 3] {
            let n = 9;
            let k = crate::bspline::basis::clamped(degree, (0..n - degree - 1).map(|_| rng.next()).collect());
            let grid = (0..n * n)
                .map(|_| Point3::new(rng.next(), rng.next(), rng.next()))
                .collect();
            let s = BSplineSurface::new(k.clone(), k, n, n, grid).unwrap();
            let basis = [
                SpanPolynomials::new(s.knots_u()),
                SpanPolynomials::new(s.knots_v()),
            ];
            let piece = Piece {
                u: s.domain_u(),
                v: s.domain_v(),
            };
            for _ in 0..100 {
                let (u, v) = (rng.next(), rng.next());
                let general = second_order_in::<4>(&s, [&basis[0], &basis[1]], u, v, &piece);
                let fixed = match degree {
                    2 => second_order_fixed::<3>(&s, [&basis[0], &basis[1]], u, v, &piece),
                    _ => second_order_fixed::<4>(&s, [&basis[0], &basis[1]], u, v, &piece),
                };
                assert_eq!(general, fixed, "degree {degree} at ({u}, {v})");
            }
        }
    }
}
