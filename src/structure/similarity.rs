//! Edges, the seven sub-structures of the paper's Fig. 3, and the structural similarity `SIM`.

use nalgebra::{Point, Point2};
use spade::{DelaunayTriangulation, Triangulation};

use super::{Group, POINT_COUNT, POINTS, StructureError, check_points};
use crate::Real;

/// The edges of a structure: the Delaunay triangulation of a reference structure's frontal
/// `(x, y)`, as sorted pairs `[i, j]` with `i < j`, sorted.
///
/// # Errors
/// The point checks of [`super::from_ibug68`] for 40 points, and
/// [`StructureError::DuplicatePoint`] when two points share a position (the triangulation
/// would merge them).
pub fn delaunay_edges(frontal: &[Point2<Real>]) -> Result<Vec<[usize; 2]>, StructureError> {
    check_points(frontal, POINT_COUNT)?;
    let mut triangulation: DelaunayTriangulation<spade::Point2<Real>> = DelaunayTriangulation::new();
    let mut vertex_of = Vec::with_capacity(frontal.len());
    for (index, p) in frontal.iter().enumerate() {
        let handle = triangulation
            .insert(spade::Point2::new(p.x, p.y))
            .map_err(|_| StructureError::NonFinitePoint { index })?;
        if let Some(first) = vertex_of.iter().position(|&h| h == handle) {
            return Err(StructureError::DuplicatePoint { first, second: index });
        }
        vertex_of.push(handle);
    }
    let input_index = |h| {
        vertex_of
            .iter()
            .position(|&v| v == h)
            .expect("every vertex was inserted")
    };
    let mut edges: Vec<[usize; 2]> = triangulation
        .undirected_edges()
        .map(|e| {
            let [a, b] = e.vertices().map(|v| input_index(v.fix()));
            [a.min(b), a.max(b)]
        })
        .collect();
    edges.sort_unstable();
    Ok(edges)
}

/// The organ classes that sub-structures G2–G4 and G7 speak of: the eye region (eyes, brows,
/// eye centres), the nose and the mouth. The contour is none of them.
fn organ(group: Group) -> Option<u8> {
    match group {
        Group::Eyes | Group::Brows | Group::EyeCentres => Some(0),
        Group::Nose => Some(1),
        Group::Mouth => Some(2),
        Group::Contour => None,
    }
}

/// The seven sub-structures of the paper's Fig. 3, as lists of indices into `edges`:
/// G1 all edges; G2 inside eyes + brows + eye centres; G3 inside the nose; G4 inside the mouth;
/// G5 "cheek", a contour point to a non-contour point; G6 inside the contour; G7
/// "cross-organ", joining two different organs among eye region, nose and mouth.
pub fn substructures(edges: &[[usize; 2]]) -> [Vec<usize>; 7] {
    let mut groups: [Vec<usize>; 7] = Default::default();
    for (k, &[a, b]) in edges.iter().enumerate() {
        let (ga, gb) = (POINTS[a].group, POINTS[b].group);
        let (oa, ob) = (organ(ga), organ(gb));
        let contour = (ga == Group::Contour, gb == Group::Contour);
        groups[0].push(k);
        if oa == Some(0) && ob == Some(0) {
            groups[1].push(k);
        }
        if oa == Some(1) && ob == Some(1) {
            groups[2].push(k);
        }
        if oa == Some(2) && ob == Some(2) {
            groups[3].push(k);
        }
        if contour.0 != contour.1 {
            groups[4].push(k);
        }
        if contour.0 && contour.1 {
            groups[5].push(k);
        }
        if let (Some(x), Some(y)) = (oa, ob)
            && x != y
        {
            groups[6].push(k);
        }
    }
    groups
}

/// The length of every edge of a structure (2D or 3D points).
pub fn edge_lengths<const D: usize>(points: &[Point<Real, D>], edges: &[[usize; 2]]) -> Vec<Real> {
    edges
        .iter()
        .map(|&[a, b]| (points[a] - points[b]).norm())
        .collect()
}

/// The structural similarity of two equally long vectors
/// `SSIM(x, y) = (2μₓμᵧ + C₁)(2σₓᵧ + C₂) / ((μₓ² + μᵧ² + C₁)(σₓ² + σᵧ² + C₂))` with
/// `C₁ = (0.01·L)²`, `C₂ = (0.03·L)²`, population (1/n) moments. 1 for equal vectors; an
/// empty pair is taken as identical (1).
///
/// # Panics
/// If the lengths differ.
pub fn ssim(x: &[Real], y: &[Real], dynamic_range: Real) -> Real {
    assert_eq!(x.len(), y.len(), "SSIM of vectors of different lengths");
    if x.is_empty() {
        return 1.0;
    }
    let Moments { mx, my, vx, vy, cxy } = moments(x, y);
    let c1 = (0.01 * dynamic_range).powi(2);
    let c2 = (0.03 * dynamic_range).powi(2);
    (2.0 * mx * my + c1) * (2.0 * cxy + c2) / ((mx * mx + my * my + c1) * (vx + vy + c2))
}

/// Population (1/n) means, variances and covariance of two equally long, non-empty samples.
struct Moments {
    mx: Real,
    my: Real,
    vx: Real,
    vy: Real,
    cxy: Real,
}

fn moments(x: &[Real], y: &[Real]) -> Moments {
    let n = x.len() as Real;
    let (mx, my) = (x.iter().sum::<Real>() / n, y.iter().sum::<Real>() / n);
    let (mut vx, mut vy, mut cxy) = (0.0, 0.0, 0.0);
    for (a, b) in x.iter().zip(y) {
        vx += (a - mx) * (a - mx);
        vy += (b - my) * (b - my);
        cxy += (a - mx) * (b - my);
    }
    Moments {
        mx,
        my,
        vx: vx / n,
        vy: vy / n,
        cxy: cxy / n,
    }
}

/// Pearson's correlation of two equally long samples, the paper's measure for the 40 depths;
/// `None` when either sample is constant (or empty).
///
/// # Panics
/// If the lengths differ.
pub fn correlation(x: &[Real], y: &[Real]) -> Option<Real> {
    assert_eq!(x.len(), y.len(), "correlation of samples of different lengths");
    if x.is_empty() {
        return None;
    }
    let Moments { vx, vy, cxy, .. } = moments(x, y);
    (vx > 0.0 && vy > 0.0).then(|| cxy / (vx * vy).sqrt())
}

/// The multi-substructure similarity `SIM = Πₖ (SSIM(V_ref^Gₖ, V^Gₖ) + 1) / 2` over the seven
/// sub-structures, in `(0, 1]`, with `L` the largest reference edge length.
///
/// # Panics
/// If the two length vectors differ in length or an index in `groups` is out of range.
pub fn multi_substructure_similarity(reference: &[Real], lengths: &[Real], groups: &[Vec<usize>; 7]) -> Real {
    assert_eq!(
        reference.len(),
        lengths.len(),
        "edge length vectors differ in length"
    );
    let range = reference.iter().copied().fold(0.0, Real::max);
    groups
        .iter()
        .map(|g| {
            let x: Vec<Real> = g.iter().map(|&k| reference[k]).collect();
            let y: Vec<Real> = g.iter().map(|&k| lengths[k]).collect();
            (ssim(&x, &y, range) + 1.0) / 2.0
        })
        .product()
}

/// [`multi_substructure_similarity`] and its gradient with respect to the edge lengths:
/// returns `SIM` and writes `∂SIM/∂lengths[e]` into `gradient[e]`.
///
/// For one sub-structure with reference lengths `x` and lengths `y` (`n` of them),
/// `SSIM = A·B / (C·D)` with `A = 2μₓμᵧ + C₁`, `B = 2σₓᵧ + C₂`, `C = μₓ² + μᵧ² + C₁`,
/// `D = σₓ² + σᵧ² + C₂`, and `∂A/∂yₑ = 2μₓ/n`, `∂B/∂yₑ = 2(xₑ − μₓ)/n`, `∂C/∂yₑ = 2μᵧ/n`,
/// `∂D/∂yₑ = 2(yₑ − μᵧ)/n`. The product over sub-structures is differentiated with the
/// products of the other factors (no division by a factor, which may be 0).
///
/// # Panics
/// As [`multi_substructure_similarity`], and if `gradient` is not as long as `lengths`.
pub fn multi_substructure_similarity_gradient(
    reference: &[Real],
    lengths: &[Real],
    groups: &[Vec<usize>; 7],
    gradient: &mut [Real],
) -> Real {
    assert_eq!(
        reference.len(),
        lengths.len(),
        "edge length vectors differ in length"
    );
    assert_eq!(gradient.len(), lengths.len(), "gradient has the wrong length");
    let range = reference.iter().copied().fold(0.0, Real::max);
    let c1 = (0.01 * range).powi(2);
    let c2 = (0.03 * range).powi(2);
    // Per group: its factor h = (SSIM + 1)/2 and the derivative terms of SSIM, kept to be
    // scaled by the product of the other factors.
    let mut factors = [1.0; 7];
    let mut parts = [(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0); 7];
    for (k, g) in groups.iter().enumerate() {
        if g.is_empty() {
            continue;
        }
        let n = g.len() as Real;
        let (mut mx, mut my) = (0.0, 0.0);
        for &e in g {
            mx += reference[e];
            my += lengths[e];
        }
        let (mx, my) = (mx / n, my / n);
        let (mut vx, mut vy, mut cxy) = (0.0, 0.0, 0.0);
        for &e in g {
            let (dx, dy) = (reference[e] - mx, lengths[e] - my);
            vx += dx * dx;
            vy += dy * dy;
            cxy += dx * dy;
        }
        let (vx, vy, cxy) = (vx / n, vy / n, cxy / n);
        let a = 2.0 * mx * my + c1;
        let b = 2.0 * cxy + c2;
        let c = mx * mx + my * my + c1;
        let d = vx + vy + c2;
        let s = a * b / (c * d);
        factors[k] = (s + 1.0) / 2.0;
        parts[k] = (a, b, c, d, s, mx, my, n);
    }
    let sim: Real = factors.iter().product();
    gradient.iter_mut().for_each(|g| *g = 0.0);
    for (k, g) in groups.iter().enumerate() {
        if g.is_empty() {
            continue;
        }
        let others: Real = (0..7).filter(|&m| m != k).map(|m| factors[m]).product();
        let (a, b, c, d, s, mx, my, n) = parts[k];
        for &e in g {
            let da = 2.0 * mx / n;
            let db = 2.0 * (reference[e] - mx) / n;
            let dc = 2.0 * my / n;
            let dd = 2.0 * (lengths[e] - my) / n;
            let ds = (da * b + a * db) / (c * d) - s * (dc * d + c * dd) / (c * d);
            gradient[e] += others * ds / 2.0;
        }
    }
    sim
}
