//! The depth rasteriser: for every pixel centre, the largest height of the triangles covering
//! it.

use nalgebra::Point3;
use rayon::prelude::*;

use crate::Real;
use crate::mesh::Raster;

/// Rows per parallel band: enough that a band's pass over the triangle list pays off.
const BAND_ROWS: usize = 64;

/// One triangle prepared for scanning: its corners in pixel units and the plane of its keys.
#[derive(Clone, Copy)]
struct Prepared {
    /// Corners in pixel coordinates (`i`, `j`).
    corners: [[Real; 2]; 3],
    /// Row range covered (inclusive), clamped to the raster.
    rows: (usize, usize),
    /// `key = z0 + i·dz_di + j·dz_dj`.
    z0: Real,
    dz_di: Real,
    dz_dj: Real,
    /// The triangle's index in the caller's list.
    index: u32,
}

fn prepare(
    corners: [[Real; 2]; 3],
    keys: [Real; 3],
    width: usize,
    height: usize,
    index: u32,
) -> Option<Prepared> {
    let [a, b, c] = corners;
    let area = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]);
    if area == 0.0 || !area.is_finite() {
        return None; // edge-on or degenerate: its neighbours cover its pixels
    }
    let lo = a[1].min(b[1]).min(c[1]).ceil().max(0.0);
    let hi = a[1].max(b[1]).max(c[1]).floor().min(height as Real - 1.0);
    let left = a[0].min(b[0]).min(c[0]);
    let right = a[0].max(b[0]).max(c[0]);
    if lo > hi || right < 0.0 || left > width as Real - 1.0 {
        return None;
    }
    // The plane through the three keys, in pixel coordinates.
    let [za, zb, zc] = keys;
    let dz_di = ((zb - za) * (c[1] - a[1]) - (zc - za) * (b[1] - a[1])) / area;
    let dz_dj = ((zc - za) * (b[0] - a[0]) - (zb - za) * (c[0] - a[0])) / area;
    Some(Prepared {
        corners,
        rows: (lo as usize, hi as usize),
        z0: za - a[0] * dz_di - a[1] * dz_dj,
        dz_di,
        dz_dj,
        index,
    })
}

/// Scans one triangle into the rows `first..first + band.len() / width` of `band` (and of
/// `ids`), keeping the larger key.
fn scan(t: &Prepared, band: &mut [Real], ids: &mut [u32], first: usize, width: usize) {
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
        let offset = (j - first) * width;
        let row = &mut band[offset..offset + width];
        let row_ids = &mut ids[offset..offset + width];
        let base = t.z0 + y * t.dz_dj;
        for i in i0..=i1 {
            let z = base + i as Real * t.dz_di;
            let cell = &mut row[i];
            if cell.is_nan() || z > *cell {
                *cell = z;
                row_ids[i] = t.index;
            }
        }
    }
}

/// The front-most triangle over every pixel centre: `(keys, ids)`, each `width × height`
/// row-major, where `keys` is the largest key among the triangles covering the pixel
/// (interpolated linearly in pixel coordinates; `NaN` where none does) and `ids` that
/// triangle's index (`u32::MAX` where none does). `pixels` are the vertices in pixel
/// coordinates (row `j` at `y = j`), `keys` one per vertex: the height for an orthographic
/// view, `1/depth` for a perspective one (both linear in the image plane, larger nearer).
///
/// Each triangle's rows are scanned with the covered span of each row solved from its three
/// edge functions (no per-pixel inside test); bands of rows are rendered in parallel, each
/// over the triangles that reach it. The result does not depend on the thread count.
pub(crate) fn rasterise(
    pixels: &[[Real; 2]],
    keys: &[Real],
    triangles: &[[u32; 3]],
    width: usize,
    height: usize,
) -> (Vec<Real>, Vec<u32>) {
    let mut values = vec![Real::NAN; width * height];
    let mut ids = vec![u32::MAX; width * height];
    if width == 0 || height == 0 {
        return (values, ids);
    }
    let prepared: Vec<Prepared> = triangles
        .par_iter()
        .enumerate()
        .filter_map(|(k, t)| {
            let corners = t.map(|v| pixels[v as usize]);
            prepare(corners, t.map(|v| keys[v as usize]), width, height, k as u32)
        })
        .collect();
    // Bucket triangles by the bands they reach.
    let bands = height.div_ceil(BAND_ROWS);
    let mut buckets: Vec<Vec<u32>> = vec![Vec::new(); bands];
    for (k, t) in prepared.iter().enumerate() {
        for bucket in &mut buckets[t.rows.0 / BAND_ROWS..=t.rows.1 / BAND_ROWS] {
            bucket.push(k as u32);
        }
    }
    values
        .par_chunks_mut(BAND_ROWS * width)
        .zip(ids.par_chunks_mut(BAND_ROWS * width))
        .zip(buckets.par_iter())
        .enumerate()
        .for_each(|(b, ((band, band_ids), bucket))| {
            for &k in bucket {
                scan(&prepared[k as usize], band, band_ids, b * BAND_ROWS, width);
            }
        });
    (values, ids)
}

/// The largest `z` over every pixel centre of `raster` among the triangles whose `x`-`y`
/// projection covers it (edges included), `NaN` where none does. Positions are in the
/// camera's frame. Row-major from the bottom row, like [`Raster`].
pub fn render_heights(positions: &[Point3<Real>], triangles: &[[u32; 3]], raster: &Raster) -> Vec<Real> {
    let pixels: Vec<[Real; 2]> = positions
        .iter()
        .map(|q| {
            [
                (q.x - raster.origin.x) / raster.spacing,
                (q.y - raster.origin.y) / raster.spacing,
            ]
        })
        .collect();
    let keys: Vec<Real> = positions.iter().map(|q| q.z).collect();
    rasterise(&pixels, &keys, triangles, raster.width, raster.height).0
}
