//! The depth rasteriser: for every pixel centre, the largest height of the triangles covering
//! it.

use nalgebra::Point3;
use rayon::prelude::*;

use crate::Real;
use crate::mesh::Raster;

/// Rows per parallel band: enough that a band's pass over the triangle list pays off.
const BAND_ROWS: usize = 64;

/// One triangle prepared for scanning: its corners in pixel units and the plane of its heights.
#[derive(Clone, Copy)]
struct Prepared {
    /// Corners in pixel coordinates (`i`, `j`).
    corners: [[Real; 2]; 3],
    /// Row range covered (inclusive), clamped to the raster.
    rows: (usize, usize),
    /// `z = z0 + i·dz_di + j·dz_dj`.
    z0: Real,
    dz_di: Real,
    dz_dj: Real,
}

fn prepare(positions: &[Point3<Real>], t: &[u32; 3], raster: &Raster) -> Option<Prepared> {
    let p = t.map(|k| positions[k as usize]);
    let to_pixel = |q: &Point3<Real>| {
        [
            (q.x - raster.origin.x) / raster.spacing,
            (q.y - raster.origin.y) / raster.spacing,
        ]
    };
    let corners = [to_pixel(&p[0]), to_pixel(&p[1]), to_pixel(&p[2])];
    let [a, b, c] = corners;
    let area = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]);
    if area == 0.0 || !area.is_finite() {
        return None; // edge-on or degenerate: its neighbours cover its pixels
    }
    let lo = a[1].min(b[1]).min(c[1]).ceil().max(0.0);
    let hi = a[1].max(b[1]).max(c[1]).floor().min(raster.height as Real - 1.0);
    let left = a[0].min(b[0]).min(c[0]);
    let right = a[0].max(b[0]).max(c[0]);
    if lo > hi || right < 0.0 || left > raster.width as Real - 1.0 {
        return None;
    }
    // The plane through the three heights, in pixel coordinates.
    let (za, zb, zc) = (p[0].z, p[1].z, p[2].z);
    let dz_di = ((zb - za) * (c[1] - a[1]) - (zc - za) * (b[1] - a[1])) / area;
    let dz_dj = ((zc - za) * (b[0] - a[0]) - (zb - za) * (c[0] - a[0])) / area;
    Some(Prepared {
        corners,
        rows: (lo as usize, hi as usize),
        z0: za - a[0] * dz_di - a[1] * dz_dj,
        dz_di,
        dz_dj,
    })
}

/// Scans one triangle into the rows `first..first + band.len() / width` of `band`.
fn scan(t: &Prepared, band: &mut [Real], first: usize, width: usize) {
    let rows = band.len() / width;
    let (j0, j1) = (t.rows.0.max(first), t.rows.1.min(first + rows - 1));
    let [a, b, c] = t.corners;
    // Orient counter-clockwise so that inside means every edge function ≥ 0.
    let (b, c) = if (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]) > 0.0 {
        (b, c)
    } else {
        (c, b)
    };
    let edges = [(a, b), (b, c), (c, a)];
    for j in j0..=j1 {
        let y = j as Real;
        // Each edge's function along the row is linear in i: e(i) = s + i·d.
        let (mut lo, mut hi) = (0.0 as Real, width as Real - 1.0);
        let mut empty = false;
        for &(p, q) in &edges {
            let (ex, ey) = (q[0] - p[0], q[1] - p[1]);
            // e(i, y) = ex·(y − p.y) − ey·(i − p.x)
            let d = -ey;
            let s = ex * (y - p[1]) + ey * p[0];
            // A sliver of tolerance so that pixel centres on shared edges are not lost.
            let tolerance = 1e-9 * (ex.abs() + ey.abs());
            if d > 0.0 {
                lo = lo.max((-tolerance - s) / d);
            } else if d < 0.0 {
                hi = hi.min((-tolerance - s) / d);
            } else if s < -tolerance {
                empty = true;
            }
        }
        if empty || lo > hi {
            continue;
        }
        let (i0, i1) = (lo.ceil() as usize, hi.floor() as usize);
        let row = &mut band[(j - first) * width..(j - first + 1) * width];
        let base = t.z0 + y * t.dz_dj;
        for (i, cell) in row.iter_mut().enumerate().take(i1 + 1).skip(i0) {
            let z = base + i as Real * t.dz_di;
            if cell.is_nan() || z > *cell {
                *cell = z;
            }
        }
    }
}

/// The largest `z` over every pixel centre of `raster` among the triangles whose `x`-`y`
/// projection covers it (edges included), `NaN` where none does. Positions are in the
/// camera's frame. Row-major from the bottom row, like [`Raster`].
///
/// Each triangle's rows are scanned with the covered span of each row solved from its three
/// edge functions (no per-pixel inside test); bands of rows are rendered in parallel, each
/// over the triangles that reach it. The result does not depend on the thread count.
pub fn render_heights(positions: &[Point3<Real>], triangles: &[[u32; 3]], raster: &Raster) -> Vec<Real> {
    let width = raster.width;
    let mut heights = vec![Real::NAN; width * raster.height];
    if width == 0 || raster.height == 0 {
        return heights;
    }
    let prepared: Vec<Prepared> = triangles
        .par_iter()
        .filter_map(|t| prepare(positions, t, raster))
        .collect();
    // Bucket triangles by the bands they reach.
    let bands = raster.height.div_ceil(BAND_ROWS);
    let mut buckets: Vec<Vec<u32>> = vec![Vec::new(); bands];
    for (k, t) in prepared.iter().enumerate() {
        for bucket in &mut buckets[t.rows.0 / BAND_ROWS..=t.rows.1 / BAND_ROWS] {
            bucket.push(k as u32);
        }
    }
    heights
        .par_chunks_mut(BAND_ROWS * width)
        .zip(buckets.par_iter())
        .enumerate()
        .for_each(|(b, (band, bucket))| {
            for &k in bucket {
                scan(&prepared[k as usize], band, b * BAND_ROWS, width);
            }
        });
    heights
}
