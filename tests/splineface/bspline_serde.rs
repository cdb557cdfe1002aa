//! JSON serialisation: exact round trips and validated reading.

use nalgebra::{Affine3, Matrix4, Vector3};
use proptest::prelude::*;
use splineface::bspline::{BSplineSurface, KnotVector};

use crate::common::{random_surface, surface};

proptest! {
    #[test]
    fn json_round_trip_is_exact(s in surface(), scale in -1e300..1e300f64) {
        // Scale by awkward factors so that the numbers need all 17 significant digits.
        let factors = Vector3::new(scale / 3.0, std::f64::consts::PI, 1.0 / 7.0);
        let s = s.transformed(&Affine3::from_matrix_unchecked(Matrix4::new_nonuniform_scaling(&factors)));
        let back = BSplineSurface::from_json(&s.to_json()).unwrap();
        prop_assert_eq!(&back, &s);
        for (a, b) in back.control_points().iter().zip(s.control_points()) {
            for k in 0..3 {
                prop_assert_eq!(a[k].to_bits(), b[k].to_bits());
            }
        }
    }
}

fn json_of_small_surface() -> serde_json::Value {
    let k = KnotVector::clamped_uniform(2, 3, 0.0, 1.0).unwrap();
    serde_json::from_str(&random_surface(k.clone(), k, 9).to_json()).unwrap()
}

#[test]
fn json_names_the_format_and_version() {
    let v = json_of_small_surface();
    assert_eq!(v["format"], "splineface/bspline-surface");
    assert_eq!(v["version"], 1);
    assert_eq!(v["knots_u"]["degree"], 2);
    assert_eq!(v["control_points"].as_array().unwrap().len(), 9);
}

#[test]
fn invalid_json_surfaces_are_rejected_with_a_reason() {
    type Edit = Box<dyn Fn(&mut serde_json::Value)>;
    let cases: Vec<(&str, Edit, &str)> = vec![
        (
            "wrong format",
            Box::new(|v| v["format"] = "other".into()),
            "format",
        ),
        ("future version", Box::new(|v| v["version"] = 2.into()), "version"),
        (
            "unknown field",
            Box::new(|v| v["extra"] = 1.into()),
            "unknown field",
        ),
        (
            "missing field",
            Box::new(|v| {
                v.as_object_mut().unwrap().remove("rows");
            }),
            "rows",
        ),
        (
            "decreasing knots",
            Box::new(|v| v["knots_u"]["knots"][3] = (-1.0).into()),
            "decrease",
        ),
        (
            "grid mismatch",
            Box::new(|v| v["rows"] = 4.into()),
            "control grid",
        ),
        (
            "short grid",
            Box::new(|v| {
                v["control_points"].as_array_mut().unwrap().pop();
            }),
            "control points",
        ),
        (
            "bad point",
            Box::new(|v| v["control_points"][0] = serde_json::json!([1.0, 2.0])),
            "invalid length",
        ),
        (
            "negative degree",
            Box::new(|v| v["knots_v"]["degree"] = (-1).into()),
            "invalid value",
        ),
    ];
    for (what, edit, needle) in cases {
        let mut v = json_of_small_surface();
        edit(&mut v);
        let err = BSplineSurface::from_json(&v.to_string())
            .expect_err(what)
            .to_string();
        assert!(err.contains(needle), "{what}: {err}");
    }
    assert!(BSplineSurface::from_json("").is_err());
    assert!(BSplineSurface::from_json("{\"format\": ").is_err());
    // A number too large for f64 is not silently infinity.
    let mut v = json_of_small_surface().to_string();
    v = v.replacen("\"control_points\":[[", "\"control_points\":[[1e999,", 1);
    assert!(BSplineSurface::from_json(&v).is_err());
}
