//! Closest points on a triangle mesh: a bounding-volume hierarchy over the triangles with a
//! nearest-first, pruned descent.

use nalgebra::{Point3, Vector3};

use super::TriangleMesh;
use crate::Real;

/// Triangles per leaf at most. Leaves of 2 and 8 answered 1.12 and 1.22 M near-surface queries
/// a second on one core against 1.20 M with 4 (`cargo bench --bench render -- "0.2
/// mm/ClosestPoints::closest_many, one core"`, one run each): the leaf size is not what holds
/// the queries back.
const LEAF: usize = 4;

/// A node of the hierarchy: 32 bytes, two to a cache line. Its box is stored in `f32`, rounded
/// outward ([`outward`]), so it still holds its triangles: it only prunes the search (the
/// triangles themselves are `f64`), and the answers are the same as with exact boxes.
#[derive(Debug, Clone, Copy)]
struct Node {
    lo: [f32; 3],
    hi: [f32; 3],
    /// Leaf: first triangle (in `order`); inner: index of the right child (the left child is
    /// the next node).
    start: u32,
    /// Leaf: triangle count (≥ 1); inner: 0.
    count: u32,
}

/// A mesh indexed for closest-point queries ([`ClosestPoints::closest`]).
///
/// The hierarchy splits triangles at the median of their centroids along the box's longest
/// side down to leaves of at most four. A query descends nearer child first, skips boxes
/// farther than the best triangle so far, and skips triangles whose plane is farther.
/// Everything is `f64`: answers are exact to rounding.
#[derive(Debug, Clone)]
pub struct ClosestPoints {
    nodes: Vec<Node>,
    /// Triangle corners in leaf order.
    corners: Vec<[Point3<Real>; 3]>,
    /// Each triangle's unit normal (zero if degenerate), in leaf order: the distance to its
    /// plane bounds the distance to it from below. (Kept with the corners, one array of
    /// triangles, it measured no faster: 1.01–1.09 against 1.09–1.19 M near-surface queries a
    /// second, three runs each by turns.)
    normals: Vec<Vector3<Real>>,
    /// The mesh's triangle index of each entry of `corners`.
    order: Vec<u32>,
    /// The most subtrees a query's stack holds: the nodes on the hierarchy's longest path
    /// from the root (each inner node's entry is taken before its two children go in).
    stack_size: usize,
}

/// A subtree waiting in a query's stack: its node, and its box's squared distance from the
/// query point.
type Waiting = (u32, Real);

/// The answer to a closest-point query.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Closest {
    /// The closest point on the mesh.
    pub point: Point3<Real>,
    /// Its distance from the query point.
    pub distance: Real,
    /// The triangle it lies on (the mesh's index).
    pub triangle: usize,
}

/// The point of triangle `abc` closest to `p` (Ericson, *Real-Time Collision Detection*, 5.1.5).
pub fn closest_on_triangle(
    p: &Point3<Real>,
    a: &Point3<Real>,
    b: &Point3<Real>,
    c: &Point3<Real>,
) -> Point3<Real> {
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(&ap);
    let d2 = ac.dot(&ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return *a;
    }
    let bp = p - b;
    let d3 = ab.dot(&bp);
    let d4 = ac.dot(&bp);
    if d3 >= 0.0 && d4 <= d3 {
        return *b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        let v = d1 / (d1 - d3);
        return a + ab * v;
    }
    let cp = p - c;
    let d5 = ab.dot(&cp);
    let d6 = ac.dot(&cp);
    if d6 >= 0.0 && d5 <= d6 {
        return *c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = d2 / (d2 - d6);
        return a + ac * w;
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        return b + (c - b) * w;
    }
    let denominator = va + vb + vc;
    if denominator == 0.0 || !denominator.is_finite() {
        // A degenerate triangle: the nearest of its edges' closest points.
        let segment = |s: &Point3<Real>, t: &Point3<Real>| {
            let d = t - s;
            let u = ((p - s).dot(&d) / d.norm_squared()).clamp(0.0, 1.0);
            if u.is_finite() { s + d * u } else { *s }
        };
        return [segment(a, b), segment(b, c), segment(c, a)]
            .into_iter()
            .min_by(|x, y| (x - p).norm_squared().total_cmp(&(y - p).norm_squared()))
            .expect("three candidates");
    }
    let v = vb / denominator;
    let w = vc / denominator;
    a + ab * v + ac * w
}

impl ClosestPoints {
    /// Indexes the mesh's triangles.
    pub fn new(mesh: &TriangleMesh) -> Self {
        let triangles: Vec<[Point3<Real>; 3]> =
            (0..mesh.triangles().len()).map(|k| mesh.triangle(k)).collect();
        let centroids: Vec<Vector3<Real>> = triangles
            .iter()
            .map(|t| (t[0].coords + t[1].coords + t[2].coords) / 3.0)
            .collect();
        let mut order: Vec<u32> = (0..triangles.len() as u32).collect();
        let mut nodes = Vec::with_capacity(2 * triangles.len() / LEAF + 1);
        build(&mut nodes, &mut order, 0, &triangles, &centroids);
        let corners = order.iter().map(|&k| triangles[k as usize]).collect();
        let normals = order
            .iter()
            .map(|&k| {
                let [a, b, c] = triangles[k as usize];
                (b - a)
                    .cross(&(c - a))
                    .try_normalize(0.0)
                    .unwrap_or_else(Vector3::zeros)
            })
            .collect();
        let stack_size = depth(&nodes, 0);
        ClosestPoints {
            nodes,
            corners,
            normals,
            order,
            stack_size,
        }
    }

    /// The closest point of the mesh to `p`.
    pub fn closest(&self, p: &Point3<Real>) -> Closest {
        self.closest_from(p, None, &mut self.stack()).0
    }

    /// The closest points of the mesh to many points, in their order.
    ///
    /// Queries run in Morton (Z-order) order of the points, in parallel chunks, each starting
    /// its search from the triangle that answered the previous query: neighbouring queries then
    /// touch the same parts of the hierarchy, which stay in cache, and the previous answer
    /// bounds the search from the start. On 200k triangles and random near-surface points this
    /// is many times faster than querying in random order, where nearly every node visited
    /// misses the cache (see `benches/render.rs`).
    pub fn closest_many(&self, points: &[Point3<Real>]) -> Vec<Closest> {
        in_morton_order(points, 4096, |chunk| {
            let mut stack = self.stack();
            let mut previous = None;
            chunk
                .iter()
                .map(|point| {
                    let (answer, entry) = self.closest_from(point, previous, &mut stack);
                    previous = Some(entry);
                    answer
                })
                .collect()
        })
    }

    /// Room for a query's stack.
    fn stack(&self) -> Vec<Waiting> {
        vec![(0, 0.0); self.stack_size]
    }

    /// The closest point to `p`, and the entry of `corners` of its triangle, searched from the
    /// triangle at entry `hint`: the previous query's, by its place in leaf order (looked up
    /// from the mesh's index it missed the cache: 8% of the search's own profile samples).
    ///
    /// `stack` is [`ClosestPoints::stack`]'s; its top is a local (pushed onto a `Vec`, each
    /// push and pop wrote the length back to memory). The two changes gave the same answers
    /// and 1.00–1.16× the queries a second: 100 000 queries on 197k triangles, one thread,
    /// `cargo bench --bench render -- "closest_many, one core"` by turns with the code before,
    /// 1.24–1.25 M → 1.25–1.32 M at ±0.2 mm from the surface, 0.68–0.70 M → 0.74–0.80 M at
    /// ±2 mm; five runs of each by turns of a timing loop, 1.03–1.12 M → 1.13–1.27 M.
    ///
    /// Measured and dropped: the hierarchy folded into four-wide nodes (each level's four
    /// boxes tested together lane by lane, 13 inner nodes visited a query instead of 24) runs 22%
    /// fewer instructions (4216 against 5296 a query under valgrind, the changes above in
    /// both) but took the same time (five runs each by turns: 1.16–1.27 M against
    /// 1.13–1.27 M): the queries wait on memory and on branches, not on arithmetic.
    fn closest_from(&self, p: &Point3<Real>, hint: Option<usize>, stack: &mut [Waiting]) -> (Closest, usize) {
        let mut best = Closest {
            point: *p,
            distance: Real::INFINITY,
            triangle: 0,
        };
        let mut best_squared = Real::INFINITY;
        // `None` until a triangle is taken (a query that is not finite and has no hint takes
        // none, and is answered by triangle 0 at an infinite distance, as before).
        let mut best_entry = None;
        if let Some(k) = hint.filter(|&k| k < self.corners.len()) {
            let [a, b, c] = &self.corners[k];
            let q = closest_on_triangle(p, a, b, c);
            best_squared = (q - p).norm_squared();
            best.point = q;
            best_entry = Some(k);
        }
        stack[0] = (0, box_distance_squared(&self.nodes[0], p));
        let mut top = 1;
        while top > 0 {
            top -= 1;
            let (index, distance) = stack[top];
            if distance >= best_squared {
                continue;
            }
            let node = &self.nodes[index as usize];
            if node.count > 0 {
                for k in node.start as usize..(node.start + node.count) as usize {
                    let [a, b, c] = &self.corners[k];
                    let plane = self.normals[k].dot(&(p - a));
                    if plane * plane >= best_squared {
                        continue;
                    }
                    let q = closest_on_triangle(p, a, b, c);
                    let d = (q - p).norm_squared();
                    if d < best_squared {
                        best_squared = d;
                        best.point = q;
                        best_entry = Some(k);
                    }
                }
                continue;
            }
            let (left, right) = (index + 1, node.start);
            let dl = box_distance_squared(&self.nodes[left as usize], p);
            let dr = box_distance_squared(&self.nodes[right as usize], p);
            // Push the farther child first so the nearer is searched first.
            if dl <= dr {
                stack[top] = (right, dr);
                stack[top + 1] = (left, dl);
            } else {
                stack[top] = (left, dl);
                stack[top + 1] = (right, dr);
            }
            top += 2;
        }
        best.distance = best_squared.sqrt();
        best.triangle = best_entry.map_or(0, |k| self.order[k] as usize);
        (best, best_entry.unwrap_or(0))
    }
}

/// Spreads the low 21 bits of `x` to every third bit.
fn spread(x: u64) -> u64 {
    let mut x = x & 0x1f_ffff;
    x = (x | x << 32) & 0x1f_0000_0000_ffff;
    x = (x | x << 16) & 0x1f_0000_ff00_00ff;
    x = (x | x << 8) & 0x100f_00f0_0f00_f00f;
    x = (x | x << 4) & 0x10c3_0c30_c30c_30c3;
    (x | x << 2) & 0x1249_2492_4924_9249
}

/// `answer` for every point, returned in the points' order but run in their Morton order, in
/// parallel chunks of `chunk` points: `answer` gets a chunk's points in that order, copied
/// together, and gives one value per point (a chunk's queries run one after another, so it may
/// carry state from one to the next). Neighbouring queries then touch the same parts of a
/// search structure, which stay in cache; and the copy's scattered loads do not wait on one
/// another, where a query read in its turn missed the cache behind the previous query's search
/// (a quarter of a spline inversion's profile).
pub(crate) fn in_morton_order<T: Send>(
    points: &[Point3<Real>],
    chunk: usize,
    answer: impl Fn(&[Point3<Real>]) -> Vec<T> + Sync,
) -> Vec<T> {
    use rayon::prelude::*;
    let order = morton_order(points);
    let found: Vec<T> = order
        .par_chunks(chunk)
        .flat_map_iter(|indices| {
            let gathered: Vec<Point3<Real>> = indices.iter().map(|&k| points[k as usize]).collect();
            answer(&gathered)
        })
        .collect();
    let mut slots: Vec<Option<T>> = std::iter::repeat_with(|| None).take(points.len()).collect();
    for (&k, value) in order.iter().zip(found) {
        slots[k as usize] = Some(value);
    }
    slots
        .into_iter()
        .map(|slot| slot.expect("the Morton order is a permutation of the points"))
        .collect()
}

/// Bits of a Morton cell index per axis: 1024 cells a side of the points' box, finer than
/// the caches can tell apart, and three axes' fit in the upper half of a `u64` whose lower
/// half holds the point's index.
const MORTON_BITS: u32 = 10;

/// The indices of `points` sorted by their Morton code over the points' bounding box (equal
/// codes in index order).
fn morton_order(points: &[Point3<Real>]) -> Vec<u32> {
    let mut lo = Vector3::repeat(Real::INFINITY);
    let mut hi = Vector3::repeat(Real::NEG_INFINITY);
    for p in points.iter().filter(|p| p.iter().all(|c| c.is_finite())) {
        lo = lo.inf(&p.coords);
        hi = hi.sup(&p.coords);
    }
    let top = ((1u32 << MORTON_BITS) - 1) as Real;
    let scale = (hi - lo).map(|e| if e > 0.0 { top / e } else { 0.0 });
    let mut keyed: Vec<u64> = points
        .iter()
        .enumerate()
        .map(|(k, p)| {
            let cell = |c: usize| {
                let x = ((p[c] - lo[c]) * scale[c]).clamp(0.0, top);
                if x.is_finite() { x as u64 } else { 0 }
            };
            (spread(cell(0)) | spread(cell(1)) << 1 | spread(cell(2)) << 2) << 32 | k as u64
        })
        .collect();
    radix_sort_codes(&mut keyed);
    keyed.into_iter().map(|x| x as u32).collect()
}

/// Sorts `keys` by their upper 32 bits, stably (so by the lower bits among equals when they
/// come in that order): least-significant-digit radix sort, `MORTON_BITS` bits a pass over
/// the `3 · MORTON_BITS` bits a code has (a comparison sort of the keys was a tenth of a
/// batch of point inversions).
fn radix_sort_codes(keys: &mut Vec<u64>) {
    let mut other = vec![0u64; keys.len()];
    let mask = (1u64 << MORTON_BITS) - 1;
    for pass in 0..3 {
        let shift = 32 + pass * MORTON_BITS;
        let mut starts = vec![0usize; (1 << MORTON_BITS) + 1];
        for &k in keys.iter() {
            starts[((k >> shift) & mask) as usize + 1] += 1;
        }
        for d in 0..1 << MORTON_BITS {
            starts[d + 1] += starts[d];
        }
        for &k in keys.iter() {
            let d = ((k >> shift) & mask) as usize;
            other[starts[d]] = k;
            starts[d] += 1;
        }
        std::mem::swap(keys, &mut other);
    }
}

fn box_distance_squared(node: &Node, p: &Point3<Real>) -> Real {
    let mut d = 0.0;
    for c in 0..3 {
        // At most one of the two is positive; no branch to mispredict.
        let excess = (Real::from(node.lo[c]) - p[c]).max(0.0) + (p[c] - Real::from(node.hi[c])).max(0.0);
        d += excess * excess;
    }
    d
}

/// `x` as an `f32` on the side of it that keeps a box whole: the nearest `f32` at or above `x`
/// when `up`, at or below it otherwise (beyond `f32`'s range, its largest finite value on the
/// inner side, or the infinity on the outer one).
fn outward(x: Real, up: bool) -> f32 {
    let y = x as f32;
    if up && Real::from(y) < x {
        y.next_up()
    } else if !up && Real::from(y) > x {
        y.next_down()
    } else {
        y
    }
}

/// The nodes on the longest path from `index` down to a leaf.
fn depth(nodes: &[Node], index: u32) -> usize {
    let node = &nodes[index as usize];
    if node.count > 0 {
        1
    } else {
        1 + depth(nodes, index + 1).max(depth(nodes, node.start))
    }
}

/// Builds the subtree over `order[..]` (whose first entry is triangle number `offset` in leaf
/// order), returning its node index.
fn build(
    nodes: &mut Vec<Node>,
    order: &mut [u32],
    offset: usize,
    triangles: &[[Point3<Real>; 3]],
    centroids: &[Vector3<Real>],
) -> u32 {
    let mut lo = [Real::INFINITY; 3];
    let mut hi = [Real::NEG_INFINITY; 3];
    let mut clo = Vector3::repeat(Real::INFINITY);
    let mut chi = Vector3::repeat(Real::NEG_INFINITY);
    for &k in order.iter() {
        for p in &triangles[k as usize] {
            for c in 0..3 {
                lo[c] = lo[c].min(p[c]);
                hi[c] = hi[c].max(p[c]);
            }
        }
        clo = clo.inf(&centroids[k as usize]);
        chi = chi.sup(&centroids[k as usize]);
    }
    let index = nodes.len() as u32;
    nodes.push(Node {
        lo: lo.map(|x| outward(x, false)),
        hi: hi.map(|x| outward(x, true)),
        start: offset as u32,
        count: order.len() as u32,
    });
    if order.len() <= LEAF {
        return index;
    }
    let axis = (chi - clo).imax();
    let middle = order.len() / 2;
    order.select_nth_unstable_by(middle, |&a, &b| {
        centroids[a as usize][axis].total_cmp(&centroids[b as usize][axis])
    });
    let (left, right) = order.split_at_mut(middle);
    build(nodes, left, offset, triangles, centroids);
    let right_index = build(nodes, right, offset + middle, triangles, centroids);
    nodes[index as usize].start = right_index;
    nodes[index as usize].count = 0;
    index
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The radix sort orders by the code and keeps equal codes in index order: the same as a
    /// comparison sort of the whole keys, which it must match exactly.
    #[test]
    fn a_radix_sort_orders_keys_like_a_comparison_sort() {
        let mut rng = crate::random::Lcg(3);
        // Few distinct codes (many ties) and codes over all 30 bits.
        for spread_bits in [4u32, 30] {
            let mut keys: Vec<u64> = (0..5000u64)
                .map(|k| ((rng.next() * (1u64 << spread_bits) as Real) as u64) << 32 | k)
                .collect();
            let mut expected = keys.clone();
            expected.sort_unstable();
            radix_sort_codes(&mut keys);
            assert_eq!(keys, expected);
        }
    }

    /// Points along a diagonal of their box (every coordinate rising together, so every cell
    /// index and so the code) come out in order along it, each index once.
    #[test]
    fn a_morton_order_is_a_permutation_that_follows_a_line() {
        let points: Vec<Point3<Real>> = (0..1000)
            .rev()
            .map(|k| Point3::new(k as Real, 2.0 * k as Real, 0.5 * k as Real))
            .collect();
        let order = morton_order(&points);
        let xs: Vec<Real> = order.iter().map(|&k| points[k as usize].x).collect();
        let mut sorted = order.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, (0..1000).collect::<Vec<u32>>());
        assert!(xs.windows(2).all(|w| w[0] <= w[1]));
    }

    /// Boxes rounded to `f32` still hold every coordinate: each bound is the nearest `f32` on
    /// its outer side (or the value itself when it is one), beyond `f32`'s range too.
    #[test]
    fn outward_rounding_keeps_the_box_whole() {
        let mut x = 0.1f64;
        let mut values = vec![
            0.0,
            -0.0,
            1.0,
            -3.5,
            1e39,
            -1e39,
            1e-50,
            -1e-50,
            f64::from(f32::MAX),
        ];
        for _ in 0..2000 {
            x = (x * 3.7 + 0.123).fract();
            values.push((x - 0.5) * 10f64.powi((x * 12.0) as i32 - 6));
        }
        for &v in &values {
            let (down, up) = (outward(v, false), outward(v, true));
            assert!(f64::from(down) <= v && v <= f64::from(up), "{v}: {down}, {up}");
            if down.is_finite() && f64::from(down) < v {
                assert!(
                    f64::from(down.next_up()) > v,
                    "{v}: {down} is not the nearest below"
                );
            }
            if up.is_finite() && f64::from(up) > v {
                assert!(
                    f64::from(up.next_down()) < v,
                    "{v}: {up} is not the nearest above"
                );
            }
        }
    }
}
