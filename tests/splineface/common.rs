//! Shared helpers: random knot vectors and surfaces, an independent Cox–de Boor oracle.

use nalgebra::Point3;
use proptest::prelude::*;
use splineface::Real;
use splineface::bspline::{BSplineSurface, KnotVector};

/// The Cox–de Boor recursion written from its definition, for every basis function at once:
/// slow, obviously correct, independent of the kernel's triangular A2.2 scheme.
/// `N_{i,0}(u) = 1` on `[u_i, u_{i+1})`; at the domain's right end the kernel's convention
/// (the limit from the left: only the last non-empty span of the domain) is used.
pub fn naive_basis(knots: &[Real], degree: usize, u: Real) -> Vec<Real> {
    let m = knots.len() - 1;
    let n = m - degree; // control points
    let end = knots[n];
    let last_span = (0..m)
        .rev()
        .find(|&i| knots[i] < knots[i + 1] && knots[i + 1] <= end)
        .unwrap();
    let mut values: Vec<Real> = (0..m)
        .map(|i| {
            let on = if u == end {
                i == last_span
            } else {
                knots[i] <= u && u < knots[i + 1]
            };
            if on { 1.0 } else { 0.0 }
        })
        .collect();
    for p in 1..=degree {
        values = (0..m - p)
            .map(|i| {
                let mut v = 0.0;
                let d1 = knots[i + p] - knots[i];
                if d1 > 0.0 {
                    v += (u - knots[i]) / d1 * values[i];
                }
                let d2 = knots[i + p + 1] - knots[i + 1];
                if d2 > 0.0 {
                    v += (knots[i + p + 1] - u) / d2 * values[i + 1];
                }
                v
            })
            .collect();
    }
    values.truncate(n);
    values
}

/// Random valid knot vectors: degree 0..=5, clamped or not, interior knots anywhere in
/// `[0, 1]` with repeats up to the degree.
pub fn knot_vector() -> impl Strategy<Value = KnotVector> {
    (
        0usize..=5,
        0usize..7,
        any::<bool>(),
        prop::collection::vec(0.0..1.0f64, 0..7),
    )
        .prop_filter_map("valid knots", |(degree, extra, clamped, interior)| {
            let n = degree + 1 + extra; // control points
            let interior_count = n - degree - 1;
            let mut inner: Vec<Real> = (0..interior_count)
                .map(|k| {
                    interior
                        .get(k)
                        .copied()
                        .unwrap_or((k + 1) as Real / (interior_count + 1) as Real)
                })
                .collect();
            // Duplicate a knot to exercise multiplicities.
            if interior_count >= 2 && degree >= 1 {
                inner[1] = inner[0];
            }
            inner.sort_by(|a, b| a.partial_cmp(b).unwrap());
            let mut knots = Vec::new();
            if clamped {
                knots.extend(std::iter::repeat_n(0.0, degree + 1));
                knots.extend(&inner);
                knots.extend(std::iter::repeat_n(1.0, degree + 1));
            } else {
                knots.extend((0..degree + 1).map(|k| -(degree as Real - k as Real) * 0.3));
                knots.extend(&inner);
                knots.extend((0..degree + 1).map(|k| 1.0 + k as Real * 0.3));
            }
            KnotVector::new(degree, knots).ok()
        })
}

/// A point of the domain of `knots`, from `t ∈ [0, 1]`.
pub fn in_domain(knots: &KnotVector, t: Real) -> Real {
    let (a, b) = knots.domain();
    (a + (b - a) * t).clamp(a, b)
}

/// `count` random control points in `[-10, 10]³`.
pub fn random_points(count: usize, seed: u64) -> Vec<Point3<Real>> {
    let mut rng = Lcg(seed);
    (0..count)
        .map(|_| rng.point_in([-10.0, -10.0, -10.0], [10.0, 10.0, 10.0]))
        .collect()
}

/// A random surface on the given knots with control points in `[-10, 10]³`.
pub fn random_surface(ku: KnotVector, kv: KnotVector, seed: u64) -> BSplineSurface {
    let (rows, cols) = (ku.num_control_points(), kv.num_control_points());
    BSplineSurface::new(ku, kv, rows, cols, random_points(rows * cols, seed)).unwrap()
}

/// Random surfaces of any supported shape.
pub fn surface() -> impl Strategy<Value = BSplineSurface> {
    (knot_vector(), knot_vector(), any::<u64>()).prop_map(|(ku, kv, seed)| random_surface(ku, kv, seed))
}

/// The seeded generator (tests must not depend on a crate's RNG stream).
pub use splineface::random::Lcg;

/// A fresh, empty scratch folder for a test: `splineface-GROUP-NAME-PID` in the temporary
/// folder.
pub fn scratch(group: &str, name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("splineface-{group}-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Runs the `splineface` binary with `args`.
pub fn splineface(args: &[&str]) -> std::process::Output {
    std::process::Command::new(env!("CARGO_BIN_EXE_splineface"))
        .args(args)
        .output()
        .unwrap()
}

/// A path as a command-line argument.
pub fn s(p: &std::path::Path) -> String {
    p.to_str().unwrap().to_owned()
}

/// The names of the entries of `dir`, sorted.
pub fn file_names(dir: &std::path::Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}
