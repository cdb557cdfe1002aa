//! A symmetric positive-definite band matrix and its Cholesky factorisation (LAPACK's `pbtrf`
//! idea, in the dot-product form so that every inner loop runs over contiguous memory).
//!
//! The normal equations of a tensor-product least-squares fit are banded once the control
//! points are numbered along the shorter grid dimension: a cubic 64 × 64 grid has 4096
//! unknowns and half-bandwidth 195, so the factorisation costs `n·k²/2 ≈ 8·10⁷` multiply-adds,
//! a few tens of milliseconds, with no fill-in outside the band.

use crate::Real;

/// The lower half of a symmetric `n × n` matrix with half-bandwidth `k`: row `i` stores
/// columns `i − k ..= i` (entries left of column 0 are padding, kept at zero).
#[derive(Debug, Clone)]
pub(crate) struct SymmetricBand {
    n: usize,
    k: usize,
    data: Vec<Real>,
}

impl SymmetricBand {
    /// The zero matrix.
    pub(crate) fn zeros(n: usize, k: usize) -> Self {
        SymmetricBand {
            n,
            k,
            data: vec![0.0; n * (k + 1)],
        }
    }

    /// Storage needed for an `n × n` matrix of half-bandwidth `k`, in entries.
    pub(crate) fn entries(n: usize, k: usize) -> usize {
        n.saturating_mul(k + 1)
    }

    #[inline(always)]
    fn index(&self, i: usize, j: usize) -> usize {
        debug_assert!(j <= i && i - j <= self.k && i < self.n);
        i * (self.k + 1) + self.k - (i - j)
    }

    /// Adds `value` to entry `(i, j)` (and so to `(j, i)`); needs `|i − j| ≤ k`.
    #[inline(always)]
    pub(crate) fn add(&mut self, i: usize, j: usize, value: Real) {
        let (i, j) = if i >= j { (i, j) } else { (j, i) };
        let idx = self.index(i, j);
        self.data[idx] += value;
    }

    /// Entry `(i, i)`.
    pub(crate) fn diagonal(&self, i: usize) -> Real {
        self.data[self.index(i, i)]
    }

    /// `self += factor · other` (same shape).
    pub(crate) fn add_scaled(&mut self, other: &SymmetricBand, factor: Real) {
        debug_assert!(self.n == other.n && self.k == other.k);
        for (a, b) in self.data.iter_mut().zip(&other.data) {
            *a += factor * b;
        }
    }

    /// Its order `n`.
    pub(crate) fn order(&self) -> usize {
        self.n
    }

    /// Entry `(i, j)` (zero outside the band).
    #[cfg(test)]
    pub(crate) fn get(&self, i: usize, j: usize) -> Real {
        let (i, j) = if i >= j { (i, j) } else { (j, i) };
        if i - j > self.k {
            0.0
        } else {
            self.data[self.index(i, j)]
        }
    }

    /// Makes row and column `i` those of the identity.
    pub(crate) fn hold(&mut self, i: usize) {
        for j in i.saturating_sub(self.k)..i {
            let idx = self.index(i, j);
            self.data[idx] = 0.0;
        }
        for r in i + 1..(i + self.k + 1).min(self.n) {
            let idx = self.index(r, i);
            self.data[idx] = 0.0;
        }
        let idx = self.index(i, i);
        self.data[idx] = 1.0;
    }

    /// Factorises in place into `L` with `A = L·Lᵀ`.
    ///
    /// Fails with the index of the first row whose pivot is not safely positive: its remaining
    /// pivot is at most `1e-12` of its own diagonal (the row is numerically a combination of
    /// earlier ones), or its diagonal is negligible next to the largest (nothing constrains it).
    pub(crate) fn cholesky(mut self) -> Result<BandCholesky, usize> {
        let (n, k) = (self.n, self.k);
        let w = k + 1;
        let max_diagonal = (0..n).map(|i| self.diagonal(i)).fold(0.0, Real::max);
        for i in 0..n {
            let first = i.saturating_sub(k);
            let original_diagonal = self.diagonal(i);
            for j in first..=i {
                // Columns both rows i and j store, left of j.
                let lo = first.max(j.saturating_sub(k));
                let row_i = &self.data[i * w + k - (i - lo)..i * w + k - (i - j)];
                let row_j = &self.data[j * w + k - (j - lo)..j * w + k];
                let s = self.data[i * w + k - (i - j)] - dot(row_i, row_j);
                if i == j {
                    if !(s > 1e-12 * original_diagonal && original_diagonal > 1e-14 * max_diagonal) {
                        return Err(i);
                    }
                    self.data[i * w + k] = s.sqrt();
                } else {
                    self.data[i * w + k - (i - j)] = s / self.data[j * w + k];
                }
            }
        }
        Ok(BandCholesky { l: self })
    }
}

/// The Cholesky factor of a [`SymmetricBand`].
#[derive(Debug, Clone)]
pub(crate) struct BandCholesky {
    l: SymmetricBand,
}

impl BandCholesky {
    /// Solves `A·x = b` in place for `D` right-hand sides stored as rows of `D` values.
    pub(crate) fn solve_in_place<const D: usize>(&self, b: &mut [[Real; D]]) {
        self.forward_in_place(b);
        self.backward_in_place(b);
    }

    /// Solves `L·y = b` in place (the first half of [`BandCholesky::solve_in_place`]), row by
    /// row.
    pub(crate) fn forward_in_place<const D: usize>(&self, b: &mut [[Real; D]]) {
        let (n, k) = (self.l.n, self.l.k);
        let w = k + 1;
        let data = &self.l.data;
        assert_eq!(b.len(), n);
        for i in 0..n {
            let first = i.saturating_sub(k);
            let row = &data[i * w + k - (i - first)..i * w + k];
            let mut s = b[i];
            for (&l, y) in row.iter().zip(&b[first..i]) {
                for d in 0..D {
                    s[d] -= l * y[d];
                }
            }
            let pivot = data[i * w + k];
            for v in &mut s {
                *v /= pivot;
            }
            b[i] = s;
        }
    }

    /// Solves `Lᵀ·x = y` in place (the second half of [`BandCholesky::solve_in_place`]),
    /// column by column (each column of `Lᵀ` is a contiguous row of `L`).
    pub(crate) fn backward_in_place<const D: usize>(&self, b: &mut [[Real; D]]) {
        let (n, k) = (self.l.n, self.l.k);
        let w = k + 1;
        let data = &self.l.data;
        assert_eq!(b.len(), n);
        for i in (0..n).rev() {
            let pivot = data[i * w + k];
            for v in &mut b[i] {
                *v /= pivot;
            }
            let x = b[i];
            let first = i.saturating_sub(k);
            let row = &data[i * w + k - (i - first)..i * w + k];
            for (&l, y) in row.iter().zip(&mut b[first..i]) {
                for d in 0..D {
                    y[d] -= l * x[d];
                }
            }
        }
    }
}

/// A dot product with four independent accumulators, so that it pipelines and vectorises.
#[inline(always)]
fn dot(a: &[Real], b: &[Real]) -> Real {
    let mut acc = [0.0; 4];
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for t in 0..4 {
            acc[t] += x[t] * y[t];
        }
    }
    let mut s = (acc[0] + acc[1]) + (acc[2] + acc[3]);
    for (x, y) in ra.iter().zip(rb) {
        s += x * y;
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DMatrix;

    /// A random symmetric positive-definite band matrix, as dense and as band.
    fn random_spd(n: usize, k: usize, seed: u64) -> (DMatrix<Real>, SymmetricBand) {
        let mut state = seed;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 11) as Real / (1u64 << 53) as Real) - 0.5
        };
        let mut dense = DMatrix::zeros(n, n);
        let mut band = SymmetricBand::zeros(n, k);
        for i in 0..n {
            for j in i.saturating_sub(k)..i {
                let v = next();
                dense[(i, j)] = v;
                dense[(j, i)] = v;
                band.add(i, j, v);
            }
            let d = 2.0 * k as Real + 1.0 + next();
            dense[(i, i)] = d;
            band.add(i, i, d);
        }
        (dense, band)
    }

    #[test]
    fn held_rows_match_dense() {
        for &(n, k) in &[(1, 0), (7, 2), (40, 7), (30, 29)] {
            let (mut dense, mut band) = random_spd(n, k, 5 * n as u64 + k as u64);
            for i in 0..n {
                for j in 0..n {
                    assert_eq!(band.get(i, j), dense[(i, j)], "n={n} k={k} ({i}, {j})");
                }
            }
            // Hold the middle row: the identity's row and column.
            let held = n / 2;
            band.hold(held);
            dense.row_mut(held).fill(0.0);
            dense.column_mut(held).fill(0.0);
            dense[(held, held)] = 1.0;
            assert_eq!(band.order(), n);
            let rhs: Vec<Real> = (0..n).map(|i| (i as Real * 0.37).sin()).collect();
            let mut x: Vec<[Real; 1]> = rhs.iter().map(|&r| [r]).collect();
            band.cholesky().expect("SPD").solve_in_place(&mut x);
            let expected = dense.cholesky().unwrap().solve(&nalgebra::DVector::from_vec(rhs));
            for i in 0..n {
                assert!((x[i][0] - expected[i]).abs() < 1e-10, "n={n} k={k} i={i}");
            }
        }
    }

    #[test]
    fn band_solve_matches_dense_solve() {
        for &(n, k) in &[(1, 0), (5, 1), (40, 7), (60, 59), (100, 3)] {
            let (dense, band) = random_spd(n, k, n as u64 * 31 + k as u64);
            let rhs: Vec<[Real; 2]> = (0..n).map(|i| [i as Real, 1.0 - i as Real * 0.5]).collect();
            let mut x = rhs.clone();
            band.cholesky().expect("SPD").solve_in_place(&mut x);
            for d in 0..2 {
                let b = nalgebra::DVector::from_iterator(n, rhs.iter().map(|r| r[d]));
                let expected = dense.clone().cholesky().unwrap().solve(&b);
                for i in 0..n {
                    assert!((x[i][d] - expected[i]).abs() < 1e-10, "n={n} k={k} i={i}");
                }
            }
        }
    }

    #[test]
    fn singular_band_reports_the_first_dependent_row() {
        let mut band = SymmetricBand::zeros(4, 1);
        band.add(0, 0, 1.0);
        band.add(1, 1, 1.0);
        // Row 2 is empty: nothing constrains unknown 2.
        band.add(3, 3, 1.0);
        assert_eq!(band.cholesky().unwrap_err(), 2);
    }
}
