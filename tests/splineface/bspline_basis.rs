//! Basis functions against an independent Cox–de Boor oracle and finite differences.

use proptest::prelude::*;
use splineface::bspline::{KnotVector, MAX_DEGREE, basis_derivatives, basis_functions};

use crate::common::{in_domain, knot_vector, naive_basis};

proptest! {
    /// Partition of unity, non-negativity and local support: the p + 1 values on the span equal
    /// the oracle's, and every other basis function is zero there.
    #[test]
    fn basis_is_a_nonnegative_local_partition_of_unity(k in knot_vector(), t in 0.0..=1.0f64) {
        let u = in_domain(&k, t);
        let p = k.degree();
        let span = k.span(u).unwrap();
        let mut n = [0.0; MAX_DEGREE + 1];
        basis_functions(&k, span, u, &mut n);
        let sum: f64 = n[..=p].iter().sum();
        prop_assert!((sum - 1.0).abs() < 1e-13, "sum {sum}");
        prop_assert!(n[..=p].iter().all(|&x| x >= 0.0));

        let all = naive_basis(k.knots(), p, u);
        for (i, &oracle) in all.iter().enumerate() {
            if i + p >= span && i <= span {
                prop_assert!((n[i + p - span] - oracle).abs() < 1e-13, "N_{i}({u}) = {} vs oracle {oracle}", n[i + p - span]);
            } else {
                prop_assert_eq!(oracle, 0.0, "N_{} outside its support at u = {}", i, u);
            }
        }
    }

    /// Row 0 of A2.3 is A2.2; rows 1 and 2 match central differences; rows above p vanish.
    #[test]
    fn basis_derivatives_match_finite_differences(k in knot_vector(), t in 0.0..=1.0f64) {
        let p = k.degree();
        let u = in_domain(&k, t);
        let span = k.span(u).unwrap();
        let knots = k.knots();
        // Stay inside the span's interior so the finite differences see one polynomial piece.
        let (a, b) = (knots[span], knots[span + 1]);
        let h = 1e-4 * (b - a);
        let u = u.clamp(a + 3.0 * h, b - 3.0 * h);
        let order = p + 1;
        let w = p + 1;
        let mut d = vec![0.0; (order + 1) * w];
        basis_derivatives(&k, span, u, order, &mut d);
        let values = |x: f64| {
            let mut n = [0.0; MAX_DEGREE + 1];
            basis_functions(&k, span, x, &mut n);
            n
        };
        let (n0, nm, np) = (values(u), values(u - h), values(u + h));
        for r in 0..=p {
            prop_assert!((d[r] - n0[r]).abs() < 1e-14);
            let scale = 1.0 / (b - a);
            if p >= 1 {
                let fd1 = (np[r] - nm[r]) / (2.0 * h);
                prop_assert!((d[w + r] - fd1).abs() < 1e-5 * scale * (1.0 + d[w + r].abs()), "d1 {} vs {fd1}", d[w + r]);
            }
            if p >= 2 {
                let fd2 = (np[r] - 2.0 * n0[r] + nm[r]) / (h * h);
                prop_assert!((d[2 * w + r] - fd2).abs() < 1e-3 * scale * scale * (1.0 + d[2 * w + r].abs()), "d2 {} vs {fd2}", d[2 * w + r]);
            }
            prop_assert_eq!(d[order * w + r], 0.0, "derivative of order p + 1 must vanish");
        }
        // The derivatives of a partition of unity sum to zero.
        for kk in 1..=order {
            let s: f64 = d[kk * w..(kk + 1) * w].iter().sum();
            let size: f64 = d[kk * w..(kk + 1) * w].iter().map(|x| x.abs()).sum();
            prop_assert!(s.abs() <= 1e-10 * (1.0 + size));
        }
    }
}

#[test]
fn cubic_bezier_basis_is_bernstein() {
    let k = KnotVector::clamped_uniform(3, 4, 0.0, 1.0).unwrap();
    for i in 0..=20 {
        let u = i as f64 / 20.0;
        let mut n = [0.0; 4];
        basis_functions(&k, k.span(u).unwrap(), u, &mut n);
        let s = 1.0 - u;
        let bernstein = [s * s * s, 3.0 * u * s * s, 3.0 * u * u * s, u * u * u];
        for r in 0..4 {
            assert!((n[r] - bernstein[r]).abs() < 1e-15, "u={u} r={r}");
        }
        let mut d = [0.0; 8];
        basis_derivatives(&k, k.span(u).unwrap(), u, 1, &mut d);
        let db = [
            -3.0 * s * s,
            3.0 * s * s - 6.0 * u * s,
            6.0 * u * s - 3.0 * u * u,
            3.0 * u * u,
        ];
        for r in 0..4 {
            assert!((d[4 + r] - db[r]).abs() < 1e-13, "u={u} r={r}");
        }
    }
}

#[test]
fn uniform_cubic_basis_has_the_classic_values_at_knots() {
    // Plain uniform cubic: at a knot the three non-zero values are 1/6, 2/3, 1/6.
    let k = KnotVector::uniform(3, 8, 0.0, 5.0).unwrap();
    let mut n = [0.0; 4];
    basis_functions(&k, k.span(2.0).unwrap(), 2.0, &mut n);
    let expected = [1.0 / 6.0, 2.0 / 3.0, 1.0 / 6.0, 0.0];
    for r in 0..4 {
        assert!((n[r] - expected[r]).abs() < 1e-15);
    }
}
