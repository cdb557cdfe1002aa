//! Linear spaces of surfaces over one knot layout: a base control grid plus displacement grids.

use nalgebra::{Affine3, DMatrix, DVector, Point3, Vector3};

use super::BSplineError;
use super::fit::{FitReport, SurfaceFit};
use super::surface::{BSplineSurface, BasisMatrix};
use crate::Real;

/// A linear space of B-spline surfaces: a base surface `B₀` and `K` displacement grids `ΔBₖ` on
/// its knots, spanning
///
/// ```text
/// B(w) = B₀ + Σₖ wₖ ΔBₖ,       F_w(u, v) = Σᵢ Σⱼ Nᵢ,ₚ(u) Nⱼ,q(v) (b⁰ᵢⱼ + Σₖ wₖ Δbᵏᵢⱼ)
/// ```
///
/// Because a surface is linear in its control grid, `F_w = F₀ + Σₖ wₖ Dₖ` where `Dₖ` is the
/// spline of the `k`-th displacement grid: every member of the space, and every derivative of
/// one, is the base's plus a weighted sum of the modes'. The space is face-agnostic: a
/// statistical shape model (mean plus principal components), a set of blend shapes, or any
/// other linear family of surfaces on one parametrisation.
///
/// Affine invariance holds per mode: an affine map `x ↦ A x + t` takes the space to the space
/// with base `A B₀ + t` and modes `A ΔBₖ` (displacements are vectors, so the translation does
/// not touch them), and the member with weights `w` to the member with the same weights
/// ([`SurfaceSpace::transformed`]).
///
/// Modes come from displacement fields sampled on the base's parametrisation and fitted by the
/// kernel's least squares ([`SurfaceSpace::fit_displacement`]); weights that best explain
/// target points come from a regularised linear least-squares solve
/// ([`SurfaceSpace::fit_weights`]).
///
/// ```
/// use nalgebra::{Point3, Vector3};
/// use splineface::bspline::{BSplineSurface, KnotVector, SurfaceSpace};
///
/// // A flat bicubic patch and one mode that lifts its centre.
/// let k = KnotVector::clamped_uniform(3, 4, 0.0, 1.0)?;
/// let grid = (0..16).map(|i| Point3::new((i / 4) as f64, (i % 4) as f64, 0.0)).collect();
/// let base = BSplineSurface::new(k.clone(), k, 4, 4, grid)?;
/// let lift = (0..16)
///     .map(|i| if (1..3).contains(&(i / 4)) && (1..3).contains(&(i % 4)) { Vector3::z() } else { Vector3::zeros() })
///     .collect();
/// let space = SurfaceSpace::new(base, vec![lift])?;
/// let member = space.surface(&[2.0])?;
/// let p = member.eval(0.5, 0.5)?;
/// // At the centre the inner control points carry 3/4 of the cubic Bernstein weight per axis.
/// assert!((p.z - 2.0 * (0.75f64).powi(2)).abs() < 1e-12);
/// # Ok::<(), splineface::bspline::BSplineError>(())
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct SurfaceSpace {
    base: BSplineSurface,
    modes: Vec<Vec<Vector3<Real>>>,
}

/// The samples of a space at a list of parameters: the base's points and each mode's
/// displacement there, from [`SurfaceSpace::sample`].
#[derive(Debug, Clone, PartialEq)]
pub struct SpaceSamples {
    /// `F₀(uₛ, vₛ)`, one per parameter.
    pub base: Vec<Point3<Real>>,
    /// `Dₖ(uₛ, vₛ)`: `modes[k][s]`.
    pub modes: Vec<Vec<Vector3<Real>>>,
}

impl SpaceSamples {
    /// The member with weights `w` at the sampled parameters: `F₀ + Σₖ wₖ Dₖ`.
    ///
    /// # Panics
    /// When `weights.len()` differs from the number of modes (a programming error; the
    /// checked entry points are on [`SurfaceSpace`]).
    pub fn member(&self, weights: &[Real]) -> Vec<Point3<Real>> {
        assert_eq!(weights.len(), self.modes.len(), "one weight per mode");
        let mut out = self.base.clone();
        for (mode, &w) in self.modes.iter().zip(weights) {
            if w != 0.0 {
                for (p, d) in out.iter_mut().zip(mode) {
                    *p += d * w;
                }
            }
        }
        out
    }

    /// The regularised least-squares weights for `targets` at the sampled places (see
    /// [`SurfaceSpace::fit_weights`], which samples and calls this); useful on its own when
    /// the samples are not surface points (a shape's landmarks carried by the modes).
    ///
    /// # Errors
    /// [`BSplineError::SampleCountMismatch`], [`BSplineError::NonFiniteSample`] for bad
    /// targets; [`BSplineError::ModeSize`] for a mode with another number of samples than the
    /// base; [`BSplineError::WeightCount`], [`BSplineError::InvalidWeight`] for a bad `ρ`;
    /// [`BSplineError::ModesUnderdetermined`].
    pub fn fit_weights(&self, targets: &[Point3<Real>], ridge: &[Real]) -> Result<Vec<Real>, BSplineError> {
        if targets.len() != self.base.len() {
            return Err(BSplineError::SampleCountMismatch {
                params: self.base.len(),
                values: targets.len(),
                what: "points",
            });
        }
        if let Some(index) = targets
            .iter()
            .position(|t| !t.coords.iter().all(|c| c.is_finite()))
        {
            return Err(BSplineError::NonFiniteSample { index });
        }
        if let Some(mode) = self.modes.iter().position(|m| m.len() != self.base.len()) {
            return Err(BSplineError::ModeSize {
                mode,
                got: self.modes[mode].len(),
                expected: self.base.len(),
            });
        }
        let k = self.modes.len();
        if ridge.len() != k {
            return Err(BSplineError::WeightCount {
                got: ridge.len(),
                expected: k,
            });
        }
        if let Some(index) = ridge.iter().position(|r| !(r.is_finite() && *r >= 0.0)) {
            return Err(BSplineError::InvalidWeight {
                index,
                value: ridge[index],
            });
        }
        if k == 0 {
            return Ok(Vec::new());
        }
        let residuals: Vec<Vector3<Real>> = targets.iter().zip(&self.base).map(|(t, b)| t - b).collect();
        let mut normal = DMatrix::<Real>::zeros(k, k);
        let mut rhs = DVector::<Real>::zeros(k);
        for a in 0..k {
            let da = &self.modes[a];
            rhs[a] = da.iter().zip(&residuals).map(|(d, r)| d.dot(r)).sum();
            for b in a..k {
                let dot: Real = da.iter().zip(&self.modes[b]).map(|(x, y)| x.dot(y)).sum();
                normal[(a, b)] = dot;
                normal[(b, a)] = dot;
            }
            normal[(a, a)] += ridge[a];
        }
        solve_normal_equations(normal, &rhs)
    }
}

impl SurfaceSpace {
    /// A space from its base surface and displacement grids, each row-major like the base's
    /// control grid (`rows·cols` vectors).
    ///
    /// # Errors
    /// [`BSplineError::ModeSize`] for a grid of another size, [`BSplineError::NonFiniteMode`]
    /// for a NaN or infinite displacement.
    pub fn new(base: BSplineSurface, modes: Vec<Vec<Vector3<Real>>>) -> Result<Self, BSplineError> {
        let expected = base.rows() * base.cols();
        for (k, mode) in modes.iter().enumerate() {
            if mode.len() != expected {
                return Err(BSplineError::ModeSize {
                    mode: k,
                    got: mode.len(),
                    expected,
                });
            }
            if let Some(at) = mode.iter().position(|d| !d.iter().all(|c| c.is_finite())) {
                return Err(BSplineError::NonFiniteMode {
                    mode: k,
                    row: at / base.cols(),
                    col: at % base.cols(),
                });
            }
        }
        Ok(SurfaceSpace { base, modes })
    }

    /// The base surface `B₀` (all weights zero).
    pub fn base(&self) -> &BSplineSurface {
        &self.base
    }

    /// The number of modes `K`.
    pub fn mode_count(&self) -> usize {
        self.modes.len()
    }

    /// The displacement grid `ΔBₖ`, row-major.
    ///
    /// # Panics
    /// When `k ≥ mode_count()`.
    pub fn mode(&self, k: usize) -> &[Vector3<Real>] {
        &self.modes[k]
    }

    /// All displacement grids.
    pub fn modes(&self) -> &[Vec<Vector3<Real>>] {
        &self.modes
    }

    /// The space with one more mode.
    ///
    /// # Errors
    /// As [`SurfaceSpace::new`].
    pub fn with_mode(self, mode: Vec<Vector3<Real>>) -> Result<Self, BSplineError> {
        let SurfaceSpace { base, mut modes } = self;
        modes.push(mode);
        Self::new(base, modes)
    }

    /// The first `k` modes only (all of them when `k ≥ mode_count()`).
    pub fn truncated(&self, k: usize) -> Self {
        SurfaceSpace {
            base: self.base.clone(),
            modes: self.modes.iter().take(k).cloned().collect(),
        }
    }

    fn check_weights(&self, weights: &[Real]) -> Result<(), BSplineError> {
        if weights.len() != self.modes.len() {
            return Err(BSplineError::WeightCount {
                got: weights.len(),
                expected: self.modes.len(),
            });
        }
        if let Some(index) = weights.iter().position(|w| !w.is_finite()) {
            return Err(BSplineError::NonFiniteModeWeight {
                index,
                value: weights[index],
            });
        }
        Ok(())
    }

    /// The control grid `B₀ + Σₖ wₖ ΔBₖ`.
    ///
    /// # Errors
    /// [`BSplineError::WeightCount`] unless there is one weight per mode,
    /// [`BSplineError::NonFiniteModeWeight`] for a NaN or infinite weight.
    pub fn control_points(&self, weights: &[Real]) -> Result<Vec<Point3<Real>>, BSplineError> {
        self.check_weights(weights)?;
        let mut grid = self.base.control_points().to_vec();
        for (mode, &w) in self.modes.iter().zip(weights) {
            if w != 0.0 {
                for (b, d) in grid.iter_mut().zip(mode) {
                    *b += d * w;
                }
            }
        }
        Ok(grid)
    }

    /// The member surface with weights `w`.
    ///
    /// # Errors
    /// As [`SurfaceSpace::control_points`]; [`BSplineError::NonFiniteControlPoint`] when the
    /// weights are so large that the grid overflows.
    pub fn surface(&self, weights: &[Real]) -> Result<BSplineSurface, BSplineError> {
        self.base.with_control_points(self.control_points(weights)?)
    }

    /// The spline of mode `k` alone, `Dₖ(u, v)`, as a surface whose control points are the
    /// displacement vectors (its values are displacements, not positions).
    ///
    /// # Panics
    /// When `k ≥ mode_count()`.
    pub fn mode_surface(&self, k: usize) -> BSplineSurface {
        self.base
            .with_control_points(self.modes[k].iter().map(|d| Point3::from(*d)).collect())
            .expect("a validated mode on the base's knots")
    }

    /// The same space over a finer layout: the knots `values` added along `direction` to the
    /// base and to every mode ([`BSplineSurface::refine_knots`]). Knot insertion is linear in
    /// the control grid, so each mode's displacement grid is refined as a surface of its own on
    /// the base's knots, and `refine_knots(d, x).surface(w)` is `surface(w).refine_knots(d, x)`
    /// for every `w`: the same surfaces, each with more control points (where a finer
    /// displacement on top of them, such as a refinement's detail, can act).
    ///
    /// # Errors
    /// As [`BSplineSurface::refine_knots`].
    ///
    /// ```
    /// use nalgebra::{Point3, Vector3};
    /// use splineface::bspline::{BSplineSurface, Direction, KnotVector, SurfaceSpace};
    ///
    /// let k = KnotVector::clamped_uniform(3, 5, 0.0, 1.0)?;
    /// let grid = (0..25).map(|i| Point3::new((i / 5) as f64, (i % 5) as f64, 0.0)).collect();
    /// let base = BSplineSurface::new(k.clone(), k, 5, 5, grid)?;
    /// let lift = (0..25).map(|i| Vector3::z() * ((i * 7) % 3) as f64).collect();
    /// let space = SurfaceSpace::new(base, vec![lift])?;
    /// let finer = space.refine_knots(Direction::U, &[0.3, 0.6])?;
    /// assert_eq!((finer.base().rows(), finer.mode(0).len()), (7, 35));
    /// let (a, b) = (space.surface(&[1.5])?.eval(0.4, 0.7)?, finer.surface(&[1.5])?.eval(0.4, 0.7)?);
    /// assert!((a - b).norm() < 1e-12);
    /// # Ok::<(), splineface::bspline::BSplineError>(())
    /// ```
    pub fn refine_knots(&self, direction: super::Direction, values: &[Real]) -> Result<Self, BSplineError> {
        let base = self.base.refine_knots(direction, values)?;
        let modes = (0..self.modes.len())
            .map(|k| {
                let refined = self.mode_surface(k).refine_knots(direction, values)?;
                Ok(refined.control_points().iter().map(|d| d.coords).collect())
            })
            .collect::<Result<_, BSplineError>>()?;
        Ok(SurfaceSpace { base, modes })
    }

    /// The space mapped by an affine transform: base `A B₀ + t`, modes `A ΔBₖ`, so that
    /// `transformed(A).surface(w) = surface(w).transformed(A)` for every `w`.
    pub fn transformed(&self, affine: &Affine3<Real>) -> Self {
        let linear = affine.matrix().fixed_view::<3, 3>(0, 0).into_owned();
        SurfaceSpace {
            base: self.base.transformed(affine),
            modes: self
                .modes
                .iter()
                .map(|mode| mode.iter().map(|d| linear * d).collect())
                .collect(),
        }
    }

    /// The base's points and every mode's displacements at `params`: all that evaluating
    /// members at fixed parameters, or fitting weights there, needs (`K + 1` sparse products
    /// with one basis matrix).
    ///
    /// # Errors
    /// As [`BSplineSurface::basis_matrix`] for a parameter that is not finite or outside the
    /// domain.
    pub fn sample(&self, params: &[[Real; 2]]) -> Result<SpaceSamples, BSplineError> {
        let basis = self.base.basis_matrix(params)?;
        Ok(self.sample_with(&basis))
    }

    fn sample_with(&self, basis: &BasisMatrix) -> SpaceSamples {
        let modes = self
            .modes
            .iter()
            .map(|mode| {
                (0..basis.nrows())
                    .map(|r| {
                        let (cols, vals) = basis.row(r);
                        cols.iter().zip(vals).map(|(&c, &v)| mode[c] * v).sum()
                    })
                    .collect()
            })
            .collect();
        SpaceSamples {
            base: basis.mul(self.base.control_points()),
            modes,
        }
    }

    /// Least-squares displacement grid of a displacement field sampled on the base's
    /// parametrisation: `displacements[s]` at `params[s]`, with the thin-plate smoothness `λ`
    /// of [`SurfaceFit`]. The fit is linear in the data, so fitting the displaced positions
    /// and subtracting the fitted base gives the same grid; fitting the field directly keeps
    /// the base's fitting error out of the mode. Add the result with
    /// [`SurfaceSpace::with_mode`].
    ///
    /// # Errors
    /// As [`SurfaceFit::fit`].
    pub fn fit_displacement(
        &self,
        params: &[[Real; 2]],
        displacements: &[Vector3<Real>],
        smoothness: Real,
    ) -> Result<(Vec<Vector3<Real>>, FitReport), BSplineError> {
        let as_points: Vec<Point3<Real>> = displacements.iter().map(|d| Point3::from(*d)).collect();
        let fitted = SurfaceFit::new(self.base.knots_u().clone(), self.base.knots_v().clone())
            .smoothness(smoothness)
            .fit(params, &as_points)?;
        Ok((
            fitted.surface.control_points().iter().map(|p| p.coords).collect(),
            fitted.report,
        ))
    }

    /// The weights whose member passes closest to `targets[s]` at `params[s]`, regularised:
    ///
    /// ```text
    /// w* = argmin_w  Σₛ ‖F₀(uₛ, vₛ) + Σₖ wₖ Dₖ(uₛ, vₛ) − targetₛ‖²  +  Σₖ ρₖ wₖ²
    /// ```
    ///
    /// With a Gaussian prior `wₖ ~ N(0, σₖ²)` and isotropic sample noise of deviation `ε` this
    /// is the MAP estimate for `ρₖ = ε² / σₖ²`; `ρ = 0` is plain least squares. Solved by the
    /// `K × K` normal equations (Cholesky), which is exact and cheap for the tens of modes a
    /// shape space has.
    ///
    /// # Errors
    /// [`BSplineError::NoSamples`], [`BSplineError::SampleCountMismatch`],
    /// [`BSplineError::NonFiniteSample`], [`BSplineError::InvalidSampleParameter`] for bad
    /// samples; [`BSplineError::WeightCount`] unless there is one `ρ` per mode,
    /// [`BSplineError::InvalidWeight`] for a negative or non-finite `ρ`;
    /// [`BSplineError::ModesUnderdetermined`] when the samples do not determine the weights
    /// (modes that are zero, or dependent, at the samples) and `ρ` does not either.
    pub fn fit_weights(
        &self,
        params: &[[Real; 2]],
        targets: &[Point3<Real>],
        ridge: &[Real],
    ) -> Result<Vec<Real>, BSplineError> {
        if params.is_empty() {
            return Err(BSplineError::NoSamples);
        }
        // The targets are checked by `SpaceSamples::fit_weights`; the parameters here, so that
        // an error names the sample.
        for (index, &[u, v]) in params.iter().enumerate() {
            super::surface::check_parameter(self.base.knots_u(), self.base.knots_v(), u, v).map_err(|e| {
                BSplineError::InvalidSampleParameter {
                    index,
                    source: Box::new(e),
                }
            })?;
        }
        self.sample(params)?.fit_weights(targets, ridge)
    }
}

/// Solves the symmetric positive definite normal equations of a weights fit by Cholesky, or
/// refuses: dependent modes make the matrix singular to rounding, and weights that rounding
/// chose would be meaningless (the threshold is relative to the largest diagonal entry).
fn solve_normal_equations(normal: DMatrix<Real>, rhs: &DVector<Real>) -> Result<Vec<Real>, BSplineError> {
    let k = normal.nrows();
    let scale = (0..k).map(|a| normal[(a, a)]).fold(0.0, Real::max);
    let cholesky = nalgebra::linalg::Cholesky::new(normal);
    let ok = scale > 0.0
        && cholesky.as_ref().is_some_and(|c| {
            let l = c.l_dirty();
            (0..k).all(|a| l[(a, a)] * l[(a, a)] > 1e-12 * scale)
        });
    match cholesky {
        Some(c) if ok => Ok(c.solve(rhs).iter().copied().collect()),
        _ => Err(BSplineError::ModesUnderdetermined),
    }
}
