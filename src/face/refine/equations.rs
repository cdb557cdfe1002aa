//! The refinement's Gauss-Newton normal equations, stored by their structure.
//!
//! The unknowns are a few dense ones (the identity weights, each photo's camera) and, with
//! [`super::RefineOptions::field`], one depth displacement per control point. A sample moves
//! only the control points its basis functions touch, and the field's prior couples only
//! neighbours, so the field × field block is banded once the points are numbered row by row
//! (half-bandwidth about three rows of the grid: 99 for the 32 × 32 grid); the dense × field
//! block is full. Stored densely, a 32 × 32 field made `H` 1140 × 1140, and every damped
//! solve a dense Cholesky factorisation of it: ten times the refinement's time without the
//! field. Here the field's block is a [`SymmetricBand`] and each damped solve eliminates it
//! (the Schur complement):
//!
//! ```text
//! [ A  B ] [x₁]   [g₁]      D = L Lᵀ (band),  V = L⁻¹ Bᵀ,  y = L⁻¹ g₂
//! [ Bᵀ D ] [x₂] = [g₂]      (A − Vᵀ V) x₁ = g₁ − Vᵀ y,   x₂ = L⁻ᵀ (y − V x₁)
//! ```
//!
//! at `n·k²/2` for the band's factorisation and `n·k` per right-hand side of the forward
//! substitution, with `n` field unknowns of half-bandwidth `k`, and one small dense
//! factorisation of the Schur complement.
//! Without a field the equations are the dense block alone and solved as before, to the bit.

use crate::Real;
use crate::bspline::band::SymmetricBand;
use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

/// Normal equations `H x = g` with `H = [A B; Bᵀ D]`: `A` over the first `dense` unknowns,
/// `D` banded over the rest (the field).
#[derive(Debug, Clone)]
pub(super) struct Equations {
    /// `A`: while the samples are added only its upper triangle, then whole
    /// ([`Equations::fill_lower`]).
    pub(super) a: DMatrix<Real>,
    /// `Bᵀ`, row-major: per field unknown, its `dense` entries against the dense unknowns.
    pub(super) cross: Vec<Real>,
    /// `D`.
    pub(super) band: SymmetricBand,
    /// `g`, the dense unknowns' entries first.
    pub(super) g: DVector<Real>,
}

impl Equations {
    /// Zero equations with `dense` dense unknowns and `field` banded ones of half-bandwidth
    /// `bandwidth`.
    pub(super) fn zeros(dense: usize, field: usize, bandwidth: usize) -> Self {
        Equations {
            a: DMatrix::zeros(dense, dense),
            cross: vec![0.0; dense * field],
            band: SymmetricBand::zeros(field, bandwidth),
            g: DVector::zeros(dense + field),
        }
    }

    /// The number of dense unknowns.
    pub(super) fn dense(&self) -> usize {
        self.a.nrows()
    }

    /// The number of field (banded) unknowns.
    pub(super) fn field(&self) -> usize {
        self.band.order()
    }

    /// Adds `other` (of the same shape) in place.
    pub(super) fn add(&mut self, other: &Equations) {
        self.a += &other.a;
        for (x, y) in self.cross.iter_mut().zip(&other.cross) {
            *x += y;
        }
        self.band.add_scaled(&other.band, 1.0);
        self.g += &other.g;
    }

    /// Completes `A` from its upper triangle.
    pub(super) fn fill_lower(&mut self) {
        self.a.fill_lower_triangle_with_upper_triangle();
    }

    /// Adds `value` to `H(i, j)` and `H(j, i)` for two field unknowns (indices among the
    /// field's), `|i − j|` within the band.
    pub(super) fn add_field(&mut self, i: usize, j: usize, value: Real) {
        self.band.add(i, j, value);
    }

    /// Holds unknown `t` where it is in a step: its row and column of `H` become the
    /// identity's, its gradient none.
    pub(super) fn hold(&mut self, t: usize) {
        let m = self.dense();
        if t < m {
            self.a.row_mut(t).fill(0.0);
            self.a.column_mut(t).fill(0.0);
            self.a[(t, t)] = 1.0;
            for row in self.cross.chunks_exact_mut(m) {
                row[t] = 0.0;
            }
        } else {
            let f = t - m;
            self.band.hold(f);
            self.cross[f * m..(f + 1) * m].fill(0.0);
        }
        self.g[t] = 0.0;
    }

    /// `H` whole, for tests.
    #[cfg(test)]
    pub(super) fn to_dense(&self) -> DMatrix<Real> {
        let (m, f) = (self.dense(), self.field());
        let mut h = DMatrix::zeros(m + f, m + f);
        h.view_mut((0, 0), (m, m)).copy_from(&self.a);
        for c in 0..f {
            for i in 0..m {
                h[(i, m + c)] = self.cross[c * m + i];
                h[(m + c, i)] = self.cross[c * m + i];
            }
            for d in 0..f {
                h[(m + c, m + d)] = self.band.get(c, d);
            }
        }
        h
    }

    /// The fall of the Gauss-Newton model of the cost, `c(s) ≈ c − 2 gᵀ s + sᵀ H s` (`g`
    /// and `H` the half-gradient and half-Hessian), for the step `s = x` that
    /// [`Equations::solve_damped`] returned for `damping`: `2 gᵀ x − xᵀ H x`, which for that
    /// `x` is `gᵀ x + λ Σ dᵢ xᵢ²` (`dᵢ` the damped diagonal's entries, as the solve scales
    /// them) and costs no product with `H`.
    pub(super) fn predicted_fall(&self, x: &DVector<Real>, damping: Real) -> Real {
        let damped: Real = x
            .iter()
            .enumerate()
            .map(|(t, v)| v * v * self.damping_scale(t))
            .sum();
        self.g.dot(x) + damping * damped
    }

    /// The damping's scale for unknown `t`: `H`'s diagonal entry, at least 10⁻⁹
    /// ([`Equations::solve_damped`], [`Equations::predicted_fall`]).
    fn damping_scale(&self, t: usize) -> Real {
        let m = self.dense();
        let d = if t < m {
            self.a[(t, t)]
        } else {
            self.band.diagonal(t - m)
        };
        d.max(1e-9)
    }

    /// Solves `(H + λ diag(H)) x = g` (each diagonal entry at least 10⁻⁹ before it is
    /// scaled), the Levenberg-Marquardt step's system; `None` when the damped `H` is not
    /// safely positive definite. Without field unknowns this is the dense Cholesky solve; with
    /// them, the Schur complement of the banded block (the [module](self)'s).
    pub(super) fn solve_damped(&self, damping: Real) -> Option<DVector<Real>> {
        let mut a = self.a.clone();
        for d in 0..a.nrows() {
            a[(d, d)] += damping * self.damping_scale(d);
        }
        let (m, f) = (self.dense(), self.field());
        if f == 0 {
            return a.cholesky().map(|c| c.solve(&self.g));
        }
        let mut band = self.band.clone();
        for d in 0..f {
            band.add(d, d, damping * self.damping_scale(m + d));
        }
        let l = band.cholesky().ok()?;
        // V = L⁻¹ Bᵀ and y = L⁻¹ g₂ (forward substitution alone): `m + 1` right-hand sides,
        // `BLOCK` at a time (each row of the factor read once per block; the blocks in
        // parallel, each one's arithmetic the same whatever the threads).
        const BLOCK: usize = 8;
        let column = |j: usize, c: usize| {
            if j < m {
                self.cross[c * m + j]
            } else {
                self.g[m + c]
            }
        };
        let solved: Vec<Vec<[Real; BLOCK]>> = (0..(m + 1).div_ceil(BLOCK))
            .into_par_iter()
            .map(|block| {
                let mut rows: Vec<[Real; BLOCK]> = (0..f)
                    .map(|c| {
                        std::array::from_fn(|t| {
                            let j = block * BLOCK + t;
                            if j <= m { column(j, c) } else { 0.0 }
                        })
                    })
                    .collect();
                l.forward_in_place(&mut rows);
                rows
            })
            .collect();
        let v = DMatrix::from_fn(f, m + 1, |c, j| solved[j / BLOCK][c][j % BLOCK]);
        let (v, y) = (v.columns(0, m), v.column(m));
        // S = A − B D⁻¹ Bᵀ = A − Vᵀ V, and its right-hand side g₁ − B D⁻¹ g₂ = g₁ − Vᵀ y.
        let mut s = a;
        // (nalgebra's `gemm` on the transposed copy is the blocked product; `gemm_tr` is not.)
        s.gemm(-1.0, &v.transpose(), &v, 1.0);
        let mut rhs = self.g.rows(0, m).into_owned();
        rhs.gemv_tr(-1.0, &v, &y, 1.0);
        let x1 = s.cholesky()?.solve(&rhs);
        // x₂ = D⁻¹ (g₂ − Bᵀ x₁) = L⁻ᵀ (y − V x₁).
        let mut t = y.into_owned();
        t.gemv(-1.0, &v, &x1, 1.0);
        let mut x2: Vec<[Real; 1]> = t.iter().map(|&r| [r]).collect();
        l.backward_in_place(&mut x2);
        let mut x = DVector::zeros(m + f);
        x.rows_mut(0, m).copy_from(&x1);
        for (to, from) in x.as_mut_slice()[m..].iter_mut().zip(&x2) {
            *to = from[0];
        }
        Some(x)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Equations with a dense block, a banded field and a full cross block, from
    /// pseudo-random values (the field's band `bandwidth` wide), positive definite.
    fn random(dense: usize, field: usize, bandwidth: usize, seed: usize) -> Equations {
        let value = |i: usize| (((i * 7919 + seed * 104729 + 13) % 1009) as Real / 1009.0) - 0.5;
        let mut e = Equations::zeros(dense, field, bandwidth);
        let n = dense + field;
        // H = Jᵀ J + I from a random J, the field's columns of each row within the band.
        for r in 0..3 * n {
            let mut row = DVector::<Real>::zeros(n);
            for i in 0..dense {
                row[i] = value(r * n + i);
            }
            let first = (r * 5) % field.max(1);
            for c in first..(first + bandwidth + 1).min(field) {
                row[dense + c] = value(r * n + dense + c);
            }
            for i in 0..n {
                for j in i..n {
                    let v = row[i] * row[j];
                    match (i < dense, j < dense) {
                        (true, true) => e.a[(i, j)] += v,
                        (true, false) => e.cross[(j - dense) * dense + i] += v,
                        _ => {
                            if j - i <= bandwidth {
                                e.add_field(i - dense, j - dense, v)
                            }
                        }
                    }
                }
                e.g[i] += row[i] * value(r + 17);
            }
        }
        for i in 0..dense {
            e.a[(i, i)] += 1.0;
        }
        for c in 0..field {
            e.add_field(c, c, 1.0);
        }
        e.fill_lower();
        e
    }

    /// The Schur solve against a dense Cholesky solve of the damped system, held unknowns
    /// included; and [`Equations::predicted_fall`] against the model's fall by its definition.
    #[test]
    fn schur_solve_equals_the_dense_solve() {
        for &(dense, field, bandwidth) in &[(3, 0, 0), (4, 1, 0), (5, 12, 3), (9, 40, 11), (2, 30, 29)] {
            for damping in [0.0, 1e-3, 0.7] {
                let mut e = random(dense, field, bandwidth, dense + field);
                if field > 2 {
                    e.hold(1);
                    e.hold(dense + 2);
                }
                let x = e.solve_damped(damping).expect("positive definite");
                let mut h = e.to_dense();
                for d in 0..h.nrows() {
                    h[(d, d)] += damping * h[(d, d)].max(1e-9);
                }
                let expected = h.cholesky().unwrap().solve(&e.g);
                assert!(
                    (&x - &expected).amax() < 1e-10 * expected.amax().max(1.0),
                    "dense {dense}, field {field}, band {bandwidth}, λ {damping}: {}",
                    (&x - &expected).amax()
                );
                if field > 2 {
                    assert_eq!((x[1], x[dense + 2]), (0.0, 0.0), "held unknowns stay");
                }
                // The model's fall by its definition, with the undamped H.
                let fall = 2.0 * e.g.dot(&x) - x.dot(&(e.to_dense() * &x));
                let predicted = e.predicted_fall(&x, damping);
                assert!(
                    (predicted - fall).abs() < 1e-9 * fall.abs().max(1.0),
                    "dense {dense}, field {field}, band {bandwidth}, λ {damping}: {predicted} against {fall}"
                );
            }
        }
    }

    #[test]
    fn sums_and_indefinite_systems() {
        let (a, b) = (random(4, 10, 2, 1), random(4, 10, 2, 2));
        let mut sum = a.clone();
        sum.add(&b);
        assert!((sum.to_dense() - (a.to_dense() + b.to_dense())).amax() < 1e-14);
        assert!((sum.g.clone() - (&a.g + &b.g)).amax() < 1e-14);
        // A negative field diagonal: no step.
        let mut bad = a.clone();
        bad.add_field(3, 3, -1e6);
        assert!(bad.solve_damped(0.0).is_none());
        // A negative dense diagonal: the Schur complement fails.
        let mut bad = a;
        bad.a[(0, 0)] = -1e6;
        assert!(bad.solve_damped(0.0).is_none());
    }
}
