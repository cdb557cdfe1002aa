//! Knot vectors: validation and span lookup.

use proptest::prelude::*;
use splineface::bspline::{BSplineError, KnotVector, MAX_DEGREE};

use crate::common::{in_domain, knot_vector};

#[test]
fn clamped_uniform_has_the_textbook_layout() {
    let k = KnotVector::clamped_uniform(3, 7, 0.0, 2.0).unwrap();
    assert_eq!(
        k.knots(),
        &[0.0, 0.0, 0.0, 0.0, 0.5, 1.0, 1.5, 2.0, 2.0, 2.0, 2.0]
    );
    assert_eq!(k.knots().len(), 7 + 3 + 1);
    assert!(k.is_clamped());
    assert!(k.is_uniform());
    assert_eq!(k.domain(), (0.0, 2.0));
}

#[test]
fn plain_uniform_spans_the_requested_domain() {
    let k = KnotVector::uniform(2, 5, 0.0, 3.0).unwrap();
    assert_eq!(k.knots(), &[-2.0, -1.0, 0.0, 1.0, 2.0, 3.0, 4.0, 5.0]);
    assert_eq!(k.num_control_points(), 5);
    assert_eq!(k.domain(), (0.0, 3.0));
    assert!(!k.is_clamped());
    assert!(k.is_uniform());
}

#[test]
fn greville_abscissae_of_a_clamped_cubic() {
    let k = KnotVector::clamped_uniform(3, 5, 0.0, 1.0).unwrap();
    // Knots 0 0 0 0 .5 1 1 1 1: averages of three consecutive inner knots.
    let g = k.greville();
    let expected = [0.0, 1.0 / 6.0, 0.5, 5.0 / 6.0, 1.0];
    for (a, b) in g.iter().zip(expected) {
        assert!((a - b).abs() < 1e-15);
    }
}

#[test]
fn invalid_knot_vectors_are_errors() {
    use BSplineError::*;
    let cases: Vec<(usize, Vec<f64>, &str)> = vec![
        (MAX_DEGREE + 1, vec![0.0; 40], "DegreeTooHigh"),
        (3, vec![0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0], "TooFewKnots"),
        (1, vec![0.0, 0.0, f64::NAN, 1.0], "NonFiniteKnot"),
        (1, vec![0.0, 0.0, f64::INFINITY, 1.0], "NonFiniteKnot"),
        (1, vec![0.0, 0.5, 0.4, 1.0], "DecreasingKnots"),
        (1, vec![0.0, 0.0, 0.0, 1.0, 1.0], "KnotMultiplicityTooHigh"),
        (1, vec![0.0, 1.0, 1.0, 2.0], "EmptyDomain"),
    ];
    for (degree, knots, expected) in cases {
        let err = KnotVector::new(degree, knots.clone()).unwrap_err();
        let name = match err {
            DegreeTooHigh { .. } => "DegreeTooHigh",
            TooFewKnots { .. } => "TooFewKnots",
            NonFiniteKnot { .. } => "NonFiniteKnot",
            DecreasingKnots { .. } => "DecreasingKnots",
            KnotMultiplicityTooHigh { .. } => "KnotMultiplicityTooHigh",
            EmptyDomain { .. } => "EmptyDomain",
            ref other => panic!("unexpected {other:?}"),
        };
        assert_eq!(name, expected, "degree {degree}, knots {knots:?}: {err}");
        assert!(!err.to_string().is_empty());
    }
}

#[test]
fn invalid_constructor_arguments_are_errors() {
    assert!(matches!(
        KnotVector::clamped_uniform(3, 3, 0.0, 1.0),
        Err(BSplineError::TooFewKnots { .. })
    ));
    assert!(matches!(
        KnotVector::clamped_uniform(3, 4, 1.0, 1.0),
        Err(BSplineError::EmptyDomain { .. })
    ));
    assert!(matches!(
        KnotVector::uniform(2, 4, 0.0, f64::NAN),
        Err(BSplineError::EmptyDomain { .. })
    ));
    assert!(matches!(
        KnotVector::uniform(99, 200, 0.0, 1.0),
        Err(BSplineError::DegreeTooHigh { .. })
    ));
}

#[test]
fn span_rejects_nan_and_outside_values() {
    let k = KnotVector::clamped_uniform(2, 5, -1.0, 1.0).unwrap();
    assert_eq!(k.span(f64::NAN), None);
    assert_eq!(k.span(-1.000001), None);
    assert_eq!(k.span(1.000001), None);
    assert_eq!(k.span(f64::INFINITY), None);
}

#[test]
fn span_at_the_right_end_skips_repeated_end_knots() {
    // Interior knot 0.5 doubled, end knots clamped: the right end belongs to span 4 (the last
    // non-empty one), never to an empty span.
    let k = KnotVector::new(2, vec![0.0, 0.0, 0.0, 0.5, 0.5, 1.0, 1.0, 1.0]).unwrap();
    assert_eq!(k.span(1.0), Some(4));
    assert_eq!(k.span(0.5), Some(4));
    assert_eq!(k.span(0.4999), Some(2));
}

proptest! {
    /// The span satisfies its definition, whichever lookup path (O(1) or bisection) ran.
    #[test]
    fn span_satisfies_its_definition(k in knot_vector(), t in 0.0..=1.0f64) {
        let u = in_domain(&k, t);
        let i = k.span(u).unwrap();
        let knots = k.knots();
        let n = k.num_control_points();
        prop_assert!(i >= k.degree() && i < n);
        prop_assert!(knots[i] < knots[i + 1], "span {i} is empty");
        if u == k.domain().1 {
            prop_assert!(knots[i + 1] == u);
        } else {
            prop_assert!(knots[i] <= u && u < knots[i + 1], "u={u} span={i} knots={knots:?}");
        }
    }

    /// On uniform knots, every knot value itself maps to the span that starts there.
    #[test]
    fn uniform_span_lookup_is_exact_at_knots(degree in 0usize..5, n in 1usize..40, a in -5.0..5.0f64, w in 0.1..10.0f64) {
        let k = KnotVector::clamped_uniform(degree, degree + n, a, a + w).unwrap();
        prop_assert!(k.is_uniform());
        let knots = k.knots();
        for i in degree..degree + n {
            prop_assert_eq!(k.span(knots[i]), Some(i));
        }
    }
}
