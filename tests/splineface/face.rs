//! The face surface: the structure transform, both deformations, the clipped mesh.

use nalgebra::{Affine3, Matrix4, Point2, Point3, Vector3};
use splineface::Real;
use splineface::face::{Deformation, FaceError, FaceSurface, MeshOptions, Units, structure_transform};
use splineface::reference::ReferenceFace;

use crate::common::Lcg;

fn reference() -> &'static ReferenceFace {
    ReferenceFace::embedded()
}

fn affine(m: [Real; 12]) -> Affine3<Real> {
    Affine3::from_matrix_unchecked(Matrix4::new(
        m[0], m[1], m[2], m[3], m[4], m[5], m[6], m[7], m[8], m[9], m[10], m[11], 0.0, 0.0, 0.0, 1.0,
    ))
}

fn max_grid_difference(a: &FaceSurface, b: &[Point3<Real>]) -> Real {
    a.surface()
        .control_points()
        .iter()
        .zip(b)
        .map(|(p, q)| (p - q).norm())
        .fold(0.0, Real::max)
}

/// A smooth, non-affine change of the structure: what a real estimate differs by.
fn bent(points: &[Point3<Real>], amplitude: Real) -> Vec<Point3<Real>> {
    points
        .iter()
        .map(|p| {
            p + amplitude
                * Vector3::new(
                    (p.y / 40.0).sin(),
                    0.5 * (p.x / 30.0).cos(),
                    (p.x / 25.0).sin() * (p.y / 35.0).cos(),
                )
        })
        .collect()
}

#[test]
fn the_reference_structure_gives_the_reference_surface() {
    for mode in [Deformation::Affine, Deformation::default()] {
        let face = FaceSurface::deform(reference(), reference().structure(), mode).unwrap();
        let d = max_grid_difference(&face, reference().surface().control_points());
        assert!(d < 1e-9, "{mode:?}: grid moved by {d}");
        assert!((face.transform().matrix() - Matrix4::identity()).norm() < 1e-12);
        assert!(face.report().displacement_rms < 1e-9);
    }
}

#[test]
fn a_known_affine_map_is_recovered_and_applied_to_the_grid() {
    let a = affine([
        1.1, 0.05, -0.02, 3.0, -0.04, 0.95, 0.1, -2.0, 0.03, -0.06, 1.3, 5.0,
    ]);
    let moved: Vec<Point3<Real>> = reference().structure().iter().map(|p| a * p).collect();
    let found = structure_transform(reference().structure(), &moved).unwrap();
    assert!((found.matrix() - a.matrix()).norm() < 1e-10, "{found:?}");
    let expected: Vec<Point3<Real>> = reference()
        .surface()
        .control_points()
        .iter()
        .map(|p| a * p)
        .collect();
    for mode in [Deformation::Affine, Deformation::default()] {
        let face = FaceSurface::deform(reference(), &moved, mode).unwrap();
        let d = max_grid_difference(&face, &expected);
        // The local mode's displacements are all zero, so it must agree too.
        assert!(d < 1e-8, "{mode:?}: {d}");
    }
}

#[test]
fn the_affine_map_is_the_least_squares_one() {
    // Perturb the optimum's entries: the residual must not decrease.
    let target = bent(reference().structure(), 3.0);
    let found = structure_transform(reference().structure(), &target).unwrap();
    let cost = |m: &Affine3<Real>| -> Real {
        reference()
            .structure()
            .iter()
            .zip(&target)
            .map(|(p, q)| (m * p - q).norm_squared())
            .sum()
    };
    let best = cost(&found);
    for (i, j) in [(0, 0), (0, 3), (1, 2), (2, 2), (2, 3), (1, 0)] {
        for h in [-1e-3, 1e-3] {
            let mut m = *found.matrix();
            m[(i, j)] += h;
            assert!(cost(&Affine3::from_matrix_unchecked(m)) > best, "({i},{j}) {h}");
        }
    }
}

#[test]
fn the_local_mode_follows_every_point() {
    let target = bent(reference().structure(), 3.0);
    let affine_face = FaceSurface::deform(reference(), &target, Deformation::Affine).unwrap();
    // The affine map cannot follow a bend.
    assert!(
        affine_face.report().displacement_rms > 0.5,
        "{:?}",
        affine_face.report()
    );
    // Near interpolation at a tiny λ; the default smooths (it is chosen for noisy estimates)
    // and stays within 1% of the eye distance of a 3-unit bend.
    for (smoothness, tolerance) in [(1e-7, 0.02), (Deformation::DEFAULT_SMOOTHNESS, 0.5)] {
        let face = FaceSurface::deform(reference(), &target, Deformation::Local { smoothness }).unwrap();
        let report = face.report();
        assert!(
            report.displacement_max < tolerance,
            "λ = {smoothness}: {report:?}"
        );
        // Check the report independently: the surface carries every reference surface point
        // by its residual displacement.
        let t = face.transform();
        for (k, p) in face.structure_params().iter().enumerate() {
            let before = reference().surface().eval(p.x, p.y).unwrap();
            let after = face.surface().eval(p.x, p.y).unwrap();
            let wanted = t * before + (target[k] - t * reference().structure()[k]);
            assert!(
                (after - wanted).norm() <= report.displacement_max + 1e-9,
                "point {k}"
            );
        }
    }
}

#[test]
fn bad_structures_are_refused() {
    let r = reference();
    let short = &r.structure()[..39];
    assert_eq!(
        FaceSurface::deform(r, short, Deformation::Affine).unwrap_err(),
        FaceError::PointCount(39)
    );
    let mut nan = r.structure().to_vec();
    nan[17].z = Real::NAN;
    assert_eq!(
        FaceSurface::deform(r, &nan, Deformation::Affine).unwrap_err(),
        FaceError::NonFinite(17)
    );
    let mirror: Vec<Point3<Real>> = r
        .structure()
        .iter()
        .map(|p| Point3::new(-p.x, p.y, p.z))
        .collect();
    assert!(matches!(
        FaceSurface::deform(r, &mirror, Deformation::Affine),
        Err(FaceError::Degenerate(_))
    ));
    let flat: Vec<Point3<Real>> = r.structure().iter().map(|p| Point3::new(p.x, p.y, 0.0)).collect();
    assert!(matches!(
        FaceSurface::deform(r, &flat, Deformation::Affine),
        Err(FaceError::Degenerate(_))
    ));
    assert_eq!(
        structure_transform(&flat, r.structure()).unwrap_err(),
        FaceError::FlatReference
    );
    for smoothness in [0.0, -1.0, Real::NAN, Real::INFINITY] {
        assert!(matches!(
            FaceSurface::deform(r, r.structure(), Deformation::Local { smoothness }),
            Err(FaceError::Option { .. })
        ));
    }
}

fn shoelace(polygon: &[Point2<Real>]) -> Real {
    (0..polygon.len())
        .map(|k| {
            let (a, b) = (polygon[k], polygon[(k + 1) % polygon.len()]);
            a.x * b.y - b.x * a.y
        })
        .sum::<Real>()
        / 2.0
}

#[test]
fn the_mesh_covers_exactly_the_clip_region() {
    let face = FaceSurface::deform(
        reference(),
        &bent(reference().structure(), 2.0),
        Deformation::default(),
    )
    .unwrap();
    for spacing in [4.0, 1.5] {
        let clipped = face.mesh(&MeshOptions { spacing }).unwrap();
        let mesh = &clipped.mesh;
        // Area in the parameter plane: the triangles tile the clip polygon exactly.
        let mut area = 0.0;
        for t in mesh.triangles() {
            let [a, b, c] = t.map(|i| clipped.params[i as usize]);
            let signed = ((b - a).perp(&(c - a))) / 2.0;
            assert!(
                signed > 0.0,
                "a triangle is clockwise or degenerate in (u, v): {signed} {a} {b} {c}"
            );
            area += signed;
        }
        let polygon = face.clip();
        let expected = shoelace(polygon).abs();
        assert!((area - expected).abs() < 1e-9 * expected, "{area} vs {expected}");
        // Every clip vertex is a mesh vertex.
        for p in polygon {
            assert!(
                clipped.params.iter().any(|q| (q - p).norm() < 1e-12),
                "clip vertex {p} is not in the mesh"
            );
        }
        // Vertices lie on the surface at their parameters.
        for (k, (p, uv)) in mesh
            .positions()
            .iter()
            .zip(&clipped.params)
            .enumerate()
            .step_by(97)
        {
            let on = face.surface().eval(uv.x, uv.y).unwrap();
            assert!((p - on).norm() < 1e-12, "vertex {k}");
        }
        // Normals are unit, agree with the triangles' winding and face the viewer on the whole.
        let normals = mesh.normals().expect("normals");
        let mut agreeing = 0;
        for (k, t) in mesh.triangles().iter().enumerate() {
            let [a, b, c] = mesh.triangle(k);
            let n = (b - a).cross(&(c - a));
            if t.iter().all(|&i| normals[i as usize].dot(&n) > 0.0) {
                agreeing += 1;
            }
        }
        assert!(
            agreeing as Real > 0.97 * mesh.triangles().len() as Real,
            "{agreeing}"
        );
        let facing = normals.iter().filter(|n| n.z > 0.0).count();
        assert!(facing as Real > 0.9 * normals.len() as Real);
    }
}

#[test]
fn the_spacing_sets_the_resolution_and_is_validated() {
    let face = FaceSurface::deform(reference(), reference().structure(), Deformation::Affine).unwrap();
    let coarse = face
        .mesh(&MeshOptions { spacing: 4.0 })
        .unwrap()
        .mesh
        .positions()
        .len();
    let fine = face
        .mesh(&MeshOptions { spacing: 2.0 })
        .unwrap()
        .mesh
        .positions()
        .len();
    let ratio = fine as Real / coarse as Real;
    assert!((3.2..4.2).contains(&ratio), "{coarse} → {fine}");
    for spacing in [0.0, -1.0, Real::NAN, Real::INFINITY, 1e-4] {
        assert!(
            matches!(face.mesh(&MeshOptions { spacing }), Err(FaceError::Option { .. })),
            "{spacing}"
        );
    }
}

#[test]
fn units_scale_by_the_eye_distance() {
    let mm = Units::default();
    assert!((mm.per_canonical_unit() - 1.26).abs() < 1e-12);
    let face = FaceSurface::deform(reference(), reference().structure(), Deformation::Affine).unwrap();
    let scaled = face.transformed(&mm.transform());
    let (r, l) = (scaled.structure()[23], scaled.structure()[24]);
    assert!(((l - r).norm() - 63.0).abs() < 1e-9);
    let mut rng = Lcg(5);
    for _ in 0..20 {
        let (u, v) = (rng.uniform(0.0, 1.0), rng.uniform(0.0, 1.0));
        let a = face.surface().eval(u, v).unwrap();
        let b = scaled.surface().eval(u, v).unwrap();
        assert!((b.coords - 1.26 * a.coords).norm() < 1e-9);
    }
    assert_eq!(Units::Canonical.per_canonical_unit(), 1.0);
}
