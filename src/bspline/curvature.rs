//! Curvatures of a surface from its first and second fundamental forms (do Carmo §3.3; The
//! NURBS Book leaves them to the differential geometry texts).

use nalgebra::{Unit, Vector3};

use super::{BSplineError, BSplineSurface};
use crate::Real;

/// The curvatures of a surface at one parameter. Signs follow the normal
/// `n = F_u × F_v / |F_u × F_v|` ([`BSplineSurface::normal`]): a curvature is positive where
/// the surface bends toward `n` (a bowl opening along `n`), negative where it bends away (a
/// dome seen from `n`'s side).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Curvature {
    /// The unit normal.
    pub normal: Unit<Vector3<Real>>,
    /// Gaussian curvature `K = κ₁κ₂ = (LN − M²)/(EG − F²)`.
    pub gaussian: Real,
    /// Mean curvature `H = (κ₁ + κ₂)/2 = (EN − 2FM + GL) / (2(EG − F²))`.
    pub mean: Real,
    /// The principal curvatures `κ₁ ≥ κ₂`.
    pub principal: (Real, Real),
    /// Their unit directions in space (tangent to the surface); at an umbilic (`κ₁ = κ₂`),
    /// where every direction is principal, `F_u`'s direction and the one orthogonal to it.
    pub directions: (Unit<Vector3<Real>>, Unit<Vector3<Real>>),
}

impl BSplineSurface {
    /// The curvatures at `(u, v)`, or `None` where the surface is degenerate (its tangents
    /// parallel or vanishing, as for [`BSplineSurface::normal`]).
    ///
    /// # Errors
    /// As [`BSplineSurface::eval`].
    ///
    /// # Examples
    ///
    /// ```
    /// use nalgebra::Point3;
    /// use splineface::bspline::{BSplineSurface, KnotVector};
    ///
    /// // z = (x² + y²)/2 over [0, 1]², exactly (a quadratic Bézier patch): at the origin both
    /// // principal curvatures are 1 (the surface bends toward its normal, +z).
    /// let k = KnotVector::clamped_uniform(2, 3, 0.0, 1.0)?;
    /// let z = |i: usize, j: usize| if i == 2 && j == 2 { 1.0 } else if i == 2 || j == 2 { 0.5 } else { 0.0 };
    /// let grid = (0..9).map(|k| Point3::new((k / 3) as f64 / 2.0, (k % 3) as f64 / 2.0, z(k / 3, k % 3))).collect();
    /// let bowl = BSplineSurface::new(k.clone(), k, 3, 3, grid)?;
    /// let c = bowl.curvature(0.0, 0.0)?.unwrap();
    /// assert!((c.gaussian - 1.0).abs() < 1e-12 && (c.mean - 1.0).abs() < 1e-12);
    /// # Ok::<(), splineface::bspline::BSplineError>(())
    /// ```
    pub fn curvature(&self, u: Real, v: Real) -> Result<Option<Curvature>, BSplineError> {
        let d = self.derivatives(u, v, 2)?;
        Ok(curvature_from(
            [d.get(1, 0), d.get(0, 1)],
            [d.get(2, 0), d.get(1, 1), d.get(0, 2)],
        ))
    }

    /// [`BSplineSurface::curvature`] over a grid of parameters, `us.len() × vs.len()` values,
    /// `u`-major (`index = i·vs.len() + j` for `(us[i], vs[j])`), computed in parallel over
    /// the rows. Each value is [`BSplineSurface::curvature`]'s to the last bit, for less work:
    /// the basis functions' derivatives are computed once per `uᵢ` and once per `vⱼ`, and each
    /// row's three intermediate curves (the surface and its first two `u` derivatives along
    /// `v`) once per row, which leaves `3(q + 1)` vector multiply-adds per point for its
    /// derivatives (256 × 256 values of a bicubic: 43 ms to 7, on a core).
    ///
    /// # Errors
    /// As [`BSplineSurface::eval`], for the first parameter outside the domain.
    ///
    /// # Examples
    ///
    /// ```
    /// use nalgebra::Point3;
    /// use splineface::bspline::{BSplineSurface, KnotVector};
    ///
    /// // A plane: no curvature anywhere.
    /// let k = KnotVector::clamped_uniform(1, 2, 0.0, 1.0)?;
    /// let grid = vec![Point3::new(0.0, 0.0, 0.0), Point3::new(0.0, 1.0, 0.0), Point3::new(1.0, 0.0, 0.0), Point3::new(1.0, 1.0, 0.0)];
    /// let plane = BSplineSurface::new(k.clone(), k, 2, 2, grid)?;
    /// let map = plane.curvature_grid(&[0.0, 0.5, 1.0], &[0.25, 0.75])?;
    /// assert_eq!(map.len(), 6);
    /// assert!(map.iter().all(|c| c.as_ref().is_some_and(|c| c.mean == 0.0 && c.gaussian == 0.0)));
    /// # Ok::<(), splineface::bspline::BSplineError>(())
    /// ```
    pub fn curvature_grid(&self, us: &[Real], vs: &[Real]) -> Result<Vec<Option<Curvature>>, BSplineError> {
        use rayon::prelude::*;
        if us.is_empty() || vs.is_empty() {
            return Ok(Vec::new());
        }
        let (p, q) = (self.degree_u(), self.degree_v());
        let (du, dv) = (p.min(2), q.min(2));
        // Every parameter's span (the first one outside the domain is the error), as
        // `eval_grid_into` finds them.
        let (lo_u, lo_v) = (self.domain_u().0, self.domain_v().0);
        let u_spans = us
            .iter()
            .map(|&u| self.locate(u, lo_v).map(|(su, _)| su))
            .collect::<Result<Vec<_>, _>>()?;
        let v_spans = vs
            .iter()
            .map(|&v| self.locate(lo_u, v).map(|(_, sv)| sv))
            .collect::<Result<Vec<_>, _>>()?;
        // A parameter's basis functions' derivatives on its span up to the second (`(p + 1)`
        // values per order, as `derivatives` lays them out).
        let basis = |knots: &super::KnotVector, span: usize, t: Real, order: usize| {
            let mut n = vec![0.0; (order + 1) * (knots.degree() + 1)];
            super::basis::basis_derivatives(knots, span, t, order, &mut n);
            n
        };
        let v_basis: Vec<(usize, Vec<Real>)> = vs
            .iter()
            .zip(&v_spans)
            .map(|(&v, &sv)| (sv, basis(self.knots_v(), sv, v, dv)))
            .collect();
        let cols = self.cols();
        let mut out = vec![None; us.len() * vs.len()];
        out.par_chunks_mut(vs.len())
            .zip(us.par_iter().zip(&u_spans))
            .for_each(|(row, (&u, &su))| {
                let nu = basis(self.knots_u(), su, u, du);
                // The intermediate curves' control points: `Σᵣ N⁽ᵏ⁾ᵣ(u) b_{su−p+r, c}`, summed in
                // `derivatives`' order.
                let curves: Vec<Vec<Vector3<Real>>> = (0..=du)
                    .map(|k| {
                        let weights = &nu[k * (p + 1)..(k + 1) * (p + 1)];
                        (0..cols)
                            .map(|c| {
                                let mut t = Vector3::zeros();
                                for (r, &w) in weights.iter().enumerate() {
                                    t += self.control_points()[(su - p + r) * cols + c].coords * w;
                                }
                                t
                            })
                            .collect()
                    })
                    .collect();
                for (o, (sv, nv)) in row.iter_mut().zip(&v_basis) {
                    let d = |k: usize, l: usize| -> Vector3<Real> {
                        if k > du || l > dv {
                            return Vector3::zeros();
                        }
                        let weights = &nv[l * (q + 1)..(l + 1) * (q + 1)];
                        curves[k][sv - q..=*sv]
                            .iter()
                            .zip(weights)
                            .map(|(t, &w)| t * w)
                            .sum()
                    };
                    *o = curvature_from([d(1, 0), d(0, 1)], [d(2, 0), d(1, 1), d(0, 2)]);
                }
            });
        Ok(out)
    }
}

/// The curvatures from the tangents `[F_u, F_v]` and second derivatives `[F_uu, F_uv, F_vv]`
/// at a point, or `None` where the tangents give no normal ([`BSplineSurface::normal`]).
fn curvature_from([fu, fv]: [Vector3<Real>; 2], [fuu, fuv, fvv]: [Vector3<Real>; 3]) -> Option<Curvature> {
    let normal = super::surface::unit_normal(&fu, &fv)?;
    let (e, f, g) = (fu.dot(&fu), fu.dot(&fv), fv.dot(&fv));
    let (l, m, n) = (fuu.dot(&normal), fuv.dot(&normal), fvv.dot(&normal));
    let det = e * g - f * f;
    let gaussian = (l * n - m * m) / det;
    let mean = (e * n - 2.0 * f * m + g * l) / (2.0 * det);
    let root = (mean * mean - gaussian).max(0.0).sqrt();
    let (k1, k2) = (mean + root, mean - root);
    // A principal direction (a, b) in the parameters solves (II − κ I)(a, b) = 0.
    let direction = |k: Real| -> Option<Unit<Vector3<Real>>> {
        let rows = [(l - k * e, m - k * f), (m - k * f, n - k * g)];
        let (p, q) = if rows[0].0.hypot(rows[0].1) >= rows[1].0.hypot(rows[1].1) {
            rows[0]
        } else {
            rows[1]
        };
        // (a, b) ⟂ (p, q); an all-zero system means every direction is principal.
        let scale = (l.abs() + m.abs() + n.abs()) * (e + g);
        if p.hypot(q) <= 1e-12 * scale.max(Real::MIN_POSITIVE) {
            return None;
        }
        Unit::try_new(fu * -q + fv * p, 0.0)
    };
    let directions = match (direction(k1), direction(k2)) {
        (Some(a), Some(b)) if root > 1e-12 * mean.abs().max(root) => (a, b),
        _ => {
            let a = Unit::new_normalize(fu);
            (a, Unit::new_normalize(normal.cross(&a)))
        }
    };
    Some(Curvature {
        normal,
        gaussian,
        mean,
        principal: (k1, k2),
        directions,
    })
}
