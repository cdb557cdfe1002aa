//! Orthographic rasterisation of a mesh's front-most surface along `−z`.

use nalgebra::Point2;

use super::TriangleMesh;
use crate::Real;

/// A regular grid of sample positions on the `x`-`y` plane: sample `(i, j)` lies at
/// `origin + (i·spacing, j·spacing)`, `i < width`, `j < height`, stored row-major
/// (`j·width + i`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Raster {
    /// The position of sample `(0, 0)`.
    pub origin: Point2<Real>,
    /// The distance between neighbouring samples, positive.
    pub spacing: Real,
    /// Samples along `x`.
    pub width: usize,
    /// Samples along `y`.
    pub height: usize,
}

impl Raster {
    /// The position of sample `(i, j)`.
    pub fn position(&self, i: usize, j: usize) -> Point2<Real> {
        Point2::new(
            self.origin.x + i as Real * self.spacing,
            self.origin.y + j as Real * self.spacing,
        )
    }
}

/// The height `z` of the mesh's front-most (largest-`z`) surface above every sample of the
/// raster, seen along `−z` (an orthographic view from `+z`); `NaN` where no triangle covers the
/// sample. This is what a frontal parametrisation can represent: surfaces hidden behind
/// others (the inside of the mouth, the back of the head, a scan's interior shells) and the
/// undersides of overhangs are left out.
///
/// Each triangle's depth is interpolated linearly at the samples inside its `x`-`y` projection,
/// edges included; triangles seen edge-on contribute nothing (their neighbours cover the
/// samples).
pub fn front_heights(mesh: &TriangleMesh, raster: &Raster) -> Vec<Real> {
    front_hits(mesh, raster)
        .into_iter()
        .map(|hit| hit.map_or(Real::NAN, |h| h.height))
        .collect()
}

/// Where the front-most surface lies above one raster sample: its triangle and the sample's
/// barycentric coordinates in it (from [`front_hits`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrontHit {
    /// The triangle's index in the mesh.
    pub triangle: usize,
    /// The weights of its three corners (sum 1, each ≥ 0 up to rounding).
    pub barycentric: [Real; 3],
    /// The surface's height `z` there.
    pub height: Real,
}

impl FrontHit {
    /// A per-vertex attribute interpolated at the hit (`attributes[v]` for vertex `v`).
    pub fn interpolate<T>(&self, mesh: &TriangleMesh, attributes: &[T]) -> T
    where
        T: Copy + std::ops::Mul<Real, Output = T> + std::ops::Add<Output = T>,
    {
        let [a, b, c] = mesh.triangles()[self.triangle];
        let [wa, wb, wc] = self.barycentric;
        attributes[a as usize] * wa + attributes[b as usize] * wb + attributes[c as usize] * wc
    }
}

/// The front-most surface above every sample of the raster (see [`front_heights`]), as the
/// triangle and barycentric coordinates there, so that any per-vertex attribute (a
/// displacement field, a colour) can be carried to the raster; `None` where no triangle covers
/// the sample.
pub fn front_hits(mesh: &TriangleMesh, raster: &Raster) -> Vec<Option<FrontHit>> {
    let mut hits: Vec<Option<FrontHit>> = vec![None; raster.width * raster.height];
    let to_grid = |x: Real, origin: Real| (x - origin) / raster.spacing;
    for k in 0..mesh.triangles().len() {
        let [a, b, c] = mesh.triangle(k);
        let area = (b.x - a.x) * (c.y - a.y) - (c.x - a.x) * (b.y - a.y);
        if area == 0.0 {
            continue;
        }
        let (lo_x, hi_x) = (a.x.min(b.x).min(c.x), a.x.max(b.x).max(c.x));
        let (lo_y, hi_y) = (a.y.min(b.y).min(c.y), a.y.max(b.y).max(c.y));
        let i0 = to_grid(lo_x, raster.origin.x).ceil().max(0.0);
        let i1 = to_grid(hi_x, raster.origin.x)
            .floor()
            .min(raster.width as Real - 1.0);
        let j0 = to_grid(lo_y, raster.origin.y).ceil().max(0.0);
        let j1 = to_grid(hi_y, raster.origin.y)
            .floor()
            .min(raster.height as Real - 1.0);
        if i0 > i1 || j0 > j1 {
            continue;
        }
        // A sliver of tolerance so that samples on shared edges are not lost to rounding.
        let tolerance = -1e-12;
        for j in j0 as usize..=j1 as usize {
            for i in i0 as usize..=i1 as usize {
                let p = raster.position(i, j);
                let wa = ((b.x - p.x) * (c.y - p.y) - (c.x - p.x) * (b.y - p.y)) / area;
                let wb = ((c.x - p.x) * (a.y - p.y) - (a.x - p.x) * (c.y - p.y)) / area;
                let wc = 1.0 - wa - wb;
                if wa < tolerance || wb < tolerance || wc < tolerance {
                    continue;
                }
                let z = wa * a.z + wb * b.z + wc * c.z;
                let cell = &mut hits[j * raster.width + i];
                if cell.is_none_or(|h| z > h.height) {
                    *cell = Some(FrontHit {
                        triangle: k,
                        barycentric: [wa, wb, wc],
                        height: z,
                    });
                }
            }
        }
    }
    hits
}
