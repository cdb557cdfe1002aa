//! Any scan to a spline: exact on polynomials, knots inserted where the residual asks, folded
//! and closed scans refused, XYZ files read, and the command's files.

use nalgebra::{Point3, Rotation3, Vector3};
use splineface::Real;
use splineface::scan::{ScanError, ScanFitOptions, fit_scan, read_scan_points};

use super::common::{Lcg, s, scratch, splineface};

/// `count` points of `z = f(x, y)` over the unit disc (random), turned by `turn`.
fn disc(
    count: usize,
    seed: u64,
    turn: &Rotation3<Real>,
    f: impl Fn(Real, Real) -> Real,
) -> Vec<Point3<Real>> {
    let mut rng = Lcg(seed);
    let mut out = Vec::with_capacity(count);
    while out.len() < count {
        let (x, y) = (rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0));
        if x * x + y * y <= 1.0 {
            out.push(turn * Point3::new(x, y, f(x, y)));
        }
    }
    out
}

fn bump(x: Real, y: Real) -> Real {
    0.3 * (-20.0 * ((x - 0.3).powi(2) + y * y)).exp() + 0.1 * (x * x + y * y)
}

#[test]
fn a_bicubic_height_field_is_fitted_exactly_over_its_plane() {
    // z a cubic in x and y is a bicubic in (u, v) when the parameters are linear in (x, y),
    // which they are over the plane the caller names.
    let turn = Rotation3::from_euler_angles(0.3, -0.2, 0.7);
    let points = disc(4000, 1, &turn, |x, y| {
        0.2 * x * x * y - 0.1 * y * y * y + 0.05 * x
    });
    let options = ScanFitOptions {
        grid: 4,
        normal: Some(turn * Vector3::z()),
        smoothness: 0.0,
        ..Default::default()
    };
    // Without smoothing the rectangle's corners beyond the disc leave no control point free on
    // a 4 × 4 grid (one Bézier patch, every basis function reaches the disc).
    let fit = fit_scan(&points, &options).unwrap();
    assert!(
        fit.max < 1e-9 && fit.distances.max < 1e-9,
        "largest residual {}",
        fit.max
    );
    assert_eq!(fit.distances.count, 4000);
    assert_eq!((fit.surface.rows(), fit.surface.cols(), fit.rounds), (4, 4, 1));
    assert_eq!(fit.layered, 0.0);
    // The residual grid keeps each cell's largest residual; no cells for a side of 0.
    let grid = fit.residual_grid(8);
    assert_eq!(
        grid.iter().copied().filter(|r| !r.is_nan()).fold(0.0, Real::max),
        fit.max
    );
    assert!(fit.residual_grid(0).is_empty() && fit.mesh(0).is_err());
    // Every point's residual is its distance to the surface point at its parameters.
    for (k, p) in points.iter().enumerate().step_by(97) {
        let [u, v] = fit.params[k];
        assert!(((fit.surface.eval(u, v).unwrap() - p).norm() - fit.residuals[k]).abs() < 1e-12);
    }
}

#[test]
fn a_tolerance_inserts_knots_where_the_residual_is_and_is_met() {
    let turn = Rotation3::from_euler_angles(-0.4, 0.1, 0.2);
    let points = disc(60_000, 2, &turn, bump);
    let tolerance = 2e-5;
    let options = ScanFitOptions {
        grid: 8,
        tolerance: Some(tolerance),
        ..Default::default()
    };
    let fit = fit_scan(&points, &options).unwrap();
    assert_eq!(fit.within_tolerance, Some(true));
    assert!(
        fit.max <= tolerance && fit.rounds > 1,
        "{} after {}",
        fit.max,
        fit.rounds
    );
    // The true distances of every third point (20,000), by point inversion, are no larger
    // than the residuals, which bound them.
    let d = fit.distances;
    assert_eq!(d.count, 20_000);
    assert!(d.max <= fit.max + 1e-12 && d.p99 <= d.max && d.rms > 0.0, "{d:?}");
    // The knots were inserted unevenly: the spans differ by more than a factor of two.
    for knots in [fit.surface.knots_u(), fit.surface.knots_v()] {
        let breaks = knots.breakpoints();
        let widths: Vec<Real> = breaks.windows(2).map(|w| w[1] - w[0]).collect();
        let (lo, hi) = widths
            .iter()
            .fold((Real::MAX, 0.0 as Real), |(a, b), &w| (a.min(w), b.max(w)));
        assert!(hi > 2.5 * lo, "widths {lo} to {hi}");
    }
    // A uniform grid with as many control points in each direction does not meet it.
    let side = fit.surface.rows().max(fit.surface.cols());
    let uniform = fit_scan(
        &points,
        &ScanFitOptions {
            grid: side,
            ..Default::default()
        },
    )
    .unwrap();
    assert!(uniform.max > tolerance, "uniform {side}²: {}", uniform.max);
}

#[test]
fn a_tolerance_no_grid_can_meet_stops_at_the_data() {
    // Noise of ±0.01 cannot be fitted to 10⁻⁴; the grid stops growing where the knot cells
    // run out of points instead of reaching the cap with more control points than points.
    let mut rng = Lcg(9);
    let points: Vec<Point3<Real>> = disc(3000, 3, &Rotation3::identity(), bump)
        .into_iter()
        .map(|p| p + Vector3::z() * rng.uniform(-0.01, 0.01))
        .collect();
    let options = ScanFitOptions {
        grid: 6,
        tolerance: Some(1e-4),
        max_grid: 1024,
        ..Default::default()
    };
    let fit = fit_scan(&points, &options).unwrap();
    assert_eq!(fit.within_tolerance, Some(false));
    assert!(
        fit.surface.rows() * fit.surface.cols() < points.len(),
        "{} × {}",
        fit.surface.rows(),
        fit.surface.cols()
    );
}

#[test]
fn closed_and_folded_scans_are_refused() {
    let mut rng = Lcg(4);
    // A sphere.
    let sphere: Vec<Point3<Real>> = (0..5000)
        .map(|_| {
            let v = Vector3::new(
                rng.uniform(-1.0, 1.0),
                rng.uniform(-1.0, 1.0),
                rng.uniform(-1.0, 1.0),
            );
            Point3::from(v.normalize())
        })
        .collect();
    let error = fit_scan(&sphere, &ScanFitOptions::default()).unwrap_err();
    assert!(
        matches!(error, ScanError::NotHeightField { percent, .. } if percent > 50.0),
        "{error}"
    );
    assert!(error.to_string().contains("not a height field"), "{error}");
    // A sheet folded over itself: z = 0 for x in [0, 2], and z = 0.5 back over x in [1, 2].
    let folded: Vec<Point3<Real>> = (0..6000)
        .map(|k| {
            let y = rng.uniform(0.0, 2.0);
            if k % 3 == 0 {
                Point3::new(rng.uniform(1.0, 2.0), y, 0.5)
            } else {
                Point3::new(rng.uniform(0.0, 2.0), y, 0.0)
            }
        })
        .collect();
    assert!(matches!(
        fit_scan(&folded, &ScanFitOptions::default()),
        Err(ScanError::NotHeightField { .. })
    ));
    // The same sheet unfolded is fitted.
    let flat: Vec<Point3<Real>> = folded.iter().map(|p| Point3::new(p.x, p.y, 0.0)).collect();
    assert!(fit_scan(&flat, &ScanFitOptions::default()).unwrap().max < 1e-9);
}

#[test]
fn bad_points_and_options_are_refused() {
    let points = disc(1000, 5, &Rotation3::identity(), bump);
    let fit = |points: &[Point3<Real>], options: ScanFitOptions| fit_scan(points, &options).unwrap_err();
    let mut nan = points.clone();
    nan[17].y = Real::NAN;
    assert!(matches!(
        fit(&nan, Default::default()),
        ScanError::NonFinite { index: 17 }
    ));
    assert!(matches!(
        fit(&points[..100], Default::default()),
        ScanError::TooFewPoints { count: 100, .. }
    ));
    let line: Vec<Point3<Real>> = (0..500)
        .map(|k| Point3::new(k as Real, 2.0 * k as Real, 0.0))
        .collect();
    assert!(matches!(fit(&line, Default::default()), ScanError::Degenerate));
    for (options, name) in [
        (
            ScanFitOptions {
                degree: 0,
                ..Default::default()
            },
            "degree",
        ),
        (
            ScanFitOptions {
                grid: 3,
                ..Default::default()
            },
            "grid",
        ),
        (
            ScanFitOptions {
                max_grid: 8,
                ..Default::default()
            },
            "max-grid",
        ),
        (
            ScanFitOptions {
                tolerance: Some(-1.0),
                ..Default::default()
            },
            "tolerance",
        ),
        (
            ScanFitOptions {
                smoothness: Real::NAN,
                ..Default::default()
            },
            "smoothness",
        ),
        (
            ScanFitOptions {
                normal: Some(Vector3::zeros()),
                ..Default::default()
            },
            "normal",
        ),
    ] {
        let error = fit(&points, options);
        assert!(
            matches!(error, ScanError::Option { name: n, .. } if n == name),
            "{name}: {error}"
        );
    }
}

#[test]
fn xyz_files_are_read_and_their_errors_name_the_line() {
    let dir = scratch("scan", "xyz");
    let good = dir.join("points.xyz");
    std::fs::write(&good, "# a comment\n1 2 3\n\n4,5,6 extra\n// another\n7\t8\t9\n").unwrap();
    let points = read_scan_points(&good).unwrap();
    assert_eq!(
        points,
        vec![
            Point3::new(1.0, 2.0, 3.0),
            Point3::new(4.0, 5.0, 6.0),
            Point3::new(7.0, 8.0, 9.0)
        ]
    );
    for (text, expected) in [
        ("1 2 3\n4 5\n", "line 2: fewer than three numbers"),
        ("1 2 3\n4 5 x\n", "line 2: `x` is not a finite number"),
        ("1 2 inf\n", "line 1: `inf` is not a finite number"),
        ("# nothing\n", "no points"),
    ] {
        std::fs::write(&good, text).unwrap();
        let error = read_scan_points(&good).unwrap_err().to_string();
        assert!(
            error.contains("points.xyz") && error.contains(expected),
            "{error}"
        );
    }
    // A PLY point cloud (no faces) gives its vertices; so does a PLY mesh.
    let ply = dir.join("cloud.ply");
    std::fs::write(&ply, "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n4 5 6\n").unwrap();
    assert_eq!(
        read_scan_points(&ply).unwrap(),
        vec![Point3::new(1.0, 2.0, 3.0), Point3::new(4.0, 5.0, 6.0)]
    );
    std::fs::write(&ply, "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 nan\n").unwrap();
    let error = read_scan_points(&ply).unwrap_err().to_string();
    assert!(
        error.contains("cloud.ply") && error.contains("vertex 0"),
        "{error}"
    );
    // A mesh gives its vertices.
    let obj = dir.join("tri.obj");
    std::fs::write(&obj, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    assert_eq!(read_scan_points(&obj).unwrap().len(), 3);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_command_writes_the_surface_and_its_residuals_or_nothing() {
    let dir = scratch("scan", "command");
    let scan = dir.join("cap.xyz");
    let points = disc(20_000, 6, &Rotation3::identity(), bump);
    let text: String = points
        .iter()
        .map(|p| format!("{} {} {}\n", p.x, p.y, p.z))
        .collect();
    std::fs::write(&scan, text).unwrap();
    let out = dir.join("cap.step");
    let mesh = dir.join("cap.ply");
    let run = splineface(&[
        "fit-surface",
        &s(&scan),
        "--out",
        &s(&out),
        "--tolerance",
        "1e-3",
        "--grid",
        "6",
        "--mesh",
        &s(&mesh),
    ]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        stdout.contains("tolerance   1e-3 met") || stdout.contains("tolerance   0.001 met"),
        "{stdout}"
    );
    let step = std::fs::read_to_string(&out).unwrap();
    assert!(step.starts_with("ISO-10303-21;") && step.contains("B_SPLINE_SURFACE_WITH_KNOTS"));
    // Trimmed to the disc's footprint: one face, bounded in space and in (u, v).
    assert_eq!(step.matches("=ADVANCED_FACE(").count(), 1);
    assert_eq!(step.matches("=B_SPLINE_CURVE_WITH_KNOTS(").count(), 2);
    // The scan's numbers are declared millimetres unless told otherwise.
    assert!(step.contains("SI_UNIT(.MILLI.,.METRE.)") && step.contains("in millimetres"));
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("cap.residuals.json")).unwrap()).unwrap();
    assert_eq!(report["points"], 20_000);
    assert_eq!(report["within_tolerance"], true);
    assert!(report["residual"]["max"].as_f64().unwrap() <= 1e-3);
    assert!(report["distance"]["max"].as_f64().unwrap() <= report["residual"]["max"].as_f64().unwrap());
    let heatmap = image::open(dir.join("cap.residuals.png")).unwrap();
    assert_eq!(heatmap.height(), 256);
    // The mesh lies on the surface's part over the disc: no vertex of a kept triangle is
    // beyond the rectangle's corners by more than a cell.
    let triangles = splineface::mesh::read_mesh(&mesh).unwrap();
    assert!(!triangles.triangles().is_empty());
    for t in triangles.triangles() {
        let p = triangles.positions()[t[0] as usize];
        assert!(p.x.hypot(p.y) < 1.0 + 2.0 * 2.0_f64.sqrt() / 256.0 + 1e-9, "{p}");
    }
    // A closed scan: a clear error naming the file, a failure, and no files.
    let sphere = dir.join("sphere.xyz");
    let mut rng = Lcg(8);
    let text: String = (0..4000)
        .map(|_| {
            let v = Vector3::new(
                rng.uniform(-1.0, 1.0),
                rng.uniform(-1.0, 1.0),
                rng.uniform(-1.0, 1.0),
            )
            .normalize();
            format!("{} {} {}\n", v.x, v.y, v.z)
        })
        .collect();
    std::fs::write(&sphere, text).unwrap();
    let out = dir.join("sphere.json");
    let run = splineface(&["fit-surface", &s(&sphere), "--out", &s(&out)]);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(
        !run.status.success() && stderr.contains("sphere.xyz") && stderr.contains("not a height field"),
        "{stderr}"
    );
    assert!(!out.exists() && !dir.join("sphere.residuals.json").exists());
    // Bad flags and outputs are refused before any work, among them an output over the
    // scan itself (which is left as it was).
    let cloud = dir.join("cloud.ply");
    std::fs::write(&cloud, "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n").unwrap();
    let before = std::fs::read(&scan).unwrap();
    for (input, args, expected) in [
        (&sphere, vec!["--out", "x.obj"], "must be .json or .step"),
        (
            &sphere,
            vec!["--out", "x.json", "--mesh", "x.glb"],
            "must be .obj or .ply",
        ),
        (
            &sphere,
            vec!["--out", "x.json", "--normal", "1,2"],
            "--normal 1,2: expected X,Y,Z",
        ),
        (
            &sphere,
            vec!["--out", "x.step", "--units", "inch"],
            "--units `inch`: expected mm, cm or m",
        ),
        (
            &sphere,
            vec!["--out", "x.json", "--grid", "2"],
            "--grid 2: more than the degree",
        ),
        (
            &sphere,
            vec!["--out", "x.json", "--tolerance", "0"],
            "--tolerance 0: positive",
        ),
        (
            &scan,
            vec!["--out", "x.json", "--mesh", "cap.xyz"],
            "must be .obj or .ply",
        ),
        (
            &cloud,
            vec!["--out", "x.json", "--mesh", "cloud.ply"],
            "would overwrite the scan",
        ),
    ] {
        let mut all = vec!["fit-surface", input.to_str().unwrap()];
        all.extend(args.iter().copied());
        let run = std::process::Command::new(env!("CARGO_BIN_EXE_splineface"))
            .args(&all)
            .current_dir(&dir)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert!(
            !run.status.success() && stderr.contains(expected),
            "{args:?}: {stderr}"
        );
    }
    assert!(!dir.join("x.json").exists());
    assert!(std::fs::read_to_string(&cloud).unwrap().ends_with("1 2 3\n"));
    assert_eq!(std::fs::read(&scan).unwrap(), before);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Whether `polygon` is simple: no two of its sides cross or touch but neighbours at their
/// shared corner (sides are axis-parallel here, so a bounding-box overlap test is exact).
fn is_simple(polygon: &[nalgebra::Point2<Real>]) -> bool {
    let m = polygon.len();
    let side = |k: usize| (polygon[k], polygon[(k + 1) % m]);
    for a in 0..m {
        for b in a + 1..m {
            if b == a + 1 || (a == 0 && b == m - 1) {
                continue;
            }
            let ((p, q), (r, t)) = (side(a), side(b));
            let overlap =
                |x0: Real, x1: Real, y0: Real, y1: Real| x0.min(x1) <= y0.max(y1) && y0.min(y1) <= x0.max(x1);
            if overlap(p.x, q.x, r.x, t.x) && overlap(p.y, q.y, r.y, t.y) {
                return false;
            }
        }
    }
    true
}

#[test]
fn the_footprint_is_the_outline_of_the_cells_the_scan_covers() {
    use splineface::geometry::{polygon_contains, signed_area};
    let options = ScanFitOptions {
        grid: 6,
        normal: Some(Vector3::z()),
        ..ScanFitOptions::default()
    };
    let flat = |_: Real, _: Real| 0.0;
    // A disc: a simple counter-clockwise lattice polygon holding every point, a little more
    // than π/4 of the rectangle (the cells its rim crosses count whole).
    let points = disc(40_000, 8, &Rotation3::identity(), flat);
    let fit = fit_scan(&points, &options).unwrap();
    let side = 64;
    let outline = fit.footprint(side);
    let area = signed_area(&outline);
    assert!(
        area > std::f64::consts::FRAC_PI_4 && area < std::f64::consts::FRAC_PI_4 + 4.0 * 2.0 / side as Real,
        "{area}"
    );
    assert!(is_simple(&outline));
    for p in &outline {
        for c in [p.x, p.y] {
            assert_eq!(
                (c * side as Real).round(),
                c * side as Real,
                "{p} is not a cell corner"
            );
        }
    }
    let inside = |uv: &[Real; 2]| {
        // Nudged toward the centre: a point on a cell's edge may count either way.
        let q = nalgebra::Point2::new(uv[0], uv[1]);
        polygon_contains(&outline, q + (nalgebra::Point2::new(0.5, 0.5) - q) * 1e-9)
    };
    assert!(fit.params.iter().all(inside));

    // A ring: its hole is filled, so its centre lies inside.
    let ring: Vec<Point3<Real>> = disc(40_000, 9, &Rotation3::identity(), flat)
        .into_iter()
        .filter(|p| p.x * p.x + p.y * p.y > 0.25)
        .collect();
    let fit = fit_scan(&ring, &options).unwrap();
    let outline = fit.footprint(side);
    assert!(is_simple(&outline));
    assert!(polygon_contains(&outline, nalgebra::Point2::new(0.5, 0.5)));
    assert!(signed_area(&outline) > std::f64::consts::FRAC_PI_4);

    // Two islands: the larger is kept, the other left out.
    let mut islands = disc(40_000, 10, &Rotation3::identity(), flat);
    let small: Vec<Point3<Real>> = disc(2_000, 11, &Rotation3::identity(), flat)
        .into_iter()
        .map(|p| Point3::new(0.3 * p.x + 2.5, 0.3 * p.y, 0.0))
        .collect();
    islands.extend(&small);
    let fit = fit_scan(&islands, &options).unwrap();
    let outline = fit.footprint(side);
    let (big, other) = fit.params.split_at(40_000);
    assert!(big.iter().all(inside_of(&outline)));
    assert!(!other.iter().any(inside_of(&outline)));

    // Nothing to outline.
    assert!(fit.footprint(0).is_empty());
}

fn inside_of(outline: &[nalgebra::Point2<Real>]) -> impl Fn(&[Real; 2]) -> bool + '_ {
    move |uv| {
        let q = nalgebra::Point2::new(uv[0], uv[1]);
        let centre = splineface::geometry::bounding_box(outline)
            .map(|(a, b)| nalgebra::center(&a, &b))
            .unwrap();
        splineface::geometry::polygon_contains(outline, q + (centre - q) * 1e-9)
    }
}
