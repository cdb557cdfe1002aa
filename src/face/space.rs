//! A statistical face space on the reference's parametrisation: the reference surface plus
//! shape modes learnt from real faces, each carrying its displacement of the 40-point
//! structure and a prior standard deviation.

use std::ops::AddAssign;

use nalgebra::{DMatrix, DVector, Point2, Point3, Similarity3, Vector2, Vector3};

use super::{DeformationReport, FaceError, FaceSurface};
use crate::Real;
use crate::bspline::{BSplineSurface, SpaceSamples, SurfaceSpace};
use crate::depth::Pose;
use crate::mesh::{ClosestPoints, TriangleMesh, front_hits};
use crate::reference::{ExpressionModes, ReferenceFace};
use crate::structure::{IBUG_POINT_COUNT, INNER_LIP_PAIRS, POINT_COUNT, from_ibug68, inner_lip_gaps};

/// A linear face space: the reference's surface and structure plus `K` modes,
///
/// ```text
/// F(w) = F₀ + Σₖ wₖ Dₖ,      S(w) = S₀ + Σₖ wₖ ΔSₖ,      wₖ ~ N(0, σₖ²)
/// ```
///
/// with `F₀`, `S₀` the reference's surface and structure, `Dₖ` a displacement spline on its
/// knots ([`SurfaceSpace`]) and `ΔSₖ` the same mode's displacement of the 40 points. A space
/// may also carry expression modes (blendshapes, [`ExpressionModes`]) that add
/// `Σₗ eₗ Eₗ` with `eₗ ∈ [0, 1]` on top of an identity: the identity is the person, the
/// expression what one photo caught them doing. The modes
/// come from per-vertex displacement fields of the scan the reference was fitted to
/// ([`FaceSpace::from_displacements`]), so a member is the face the scan becomes under those
/// displacements, seen through the reference's parametrisation. Such a space also carries the
/// scan's 68 iBUG landmark vertices and every mode's displacement of them
/// ([`FaceSpace::landmarks`]): points a landmarker gives beyond the 40, such as the inner lips
/// that show an open mouth ([`FaceSpace::fit_photos_with_lips`]).
#[derive(Debug, Clone, PartialEq)]
pub struct FaceSpace {
    surfaces: SurfaceSpace,
    structure: SpaceSamples,
    sigma: Vec<Real>,
    expressions: ExpressionModes,
    /// The 68 iBUG landmarks and each identity mode's displacement of them, when the space
    /// carries them (the expressions' are in [`ExpressionModes::landmarks`]).
    landmarks: Option<SpaceSamples>,
}

/// A member of a [`FaceSpace`] fitted to data: its weights and where it sits.
#[derive(Debug, Clone, PartialEq)]
pub struct SpaceFit {
    /// The mode weights.
    pub weights: Vec<Real>,
    /// The similarity from the space's canonical frame onto the data.
    pub placement: Similarity3<Real>,
    /// RMS distance between the placed member and the data it was fitted to (the data's
    /// units; for a dense fit, over the samples kept by the trimming).
    pub rms: Real,
    /// Iterations run.
    pub iterations: usize,
}

impl FaceSpace {
    /// Builds the space from displacement fields of the reference's own scan.
    ///
    /// `scan` is the mesh the reference was fitted to and `landmarks` its 68 iBUG vertex
    /// indices, both in the reference's canonical frame; `fields[k][v]` is mode `k`'s
    /// displacement of vertex `v` (same frame) and `sigma[k]` its prior standard deviation.
    /// Each field is carried to the reference's parameters through the scan's front-most
    /// surface (the surface the reference's grid was fitted to, at the fit's sample spacing,
    /// interpolated linearly inside each triangle) and fitted on the reference's knots with
    /// the fit's thin-plate weight ([`SurfaceSpace::fit_displacement`]); the structure's
    /// displacement is the iBUG points' displacement reduced like the points
    /// ([`from_ibug68`]). The space has no expressions
    /// ([`FaceSpace::with_expression_displacements`] adds them).
    ///
    /// # Errors
    /// [`FaceError::Space`] when the scan is not the reference's (its front surface lies
    /// farther from the grid than the fit's residuals allow), when the landmark indices, a
    /// field or the deviations do not match, or for a non-finite displacement;
    /// [`FaceError::Kernel`] when a mode cannot be fitted.
    pub fn from_displacements(
        reference: &ReferenceFace,
        scan: &TriangleMesh,
        landmarks: &[usize],
        fields: &[Vec<Vector3<Real>>],
        sigma: &[Real],
    ) -> Result<Self, FaceError> {
        if sigma.len() != fields.len() {
            return Err(FaceError::Space(format!(
                "{} deviations for {} modes",
                sigma.len(),
                fields.len()
            )));
        }
        if let Some(k) = sigma.iter().position(|s| !(s.is_finite() && *s > 0.0)) {
            return Err(FaceError::Space(format!(
                "mode {k}: deviation {} must be positive and finite",
                sigma[k]
            )));
        }
        let carrier = Carrier::new(reference, scan, landmarks)?;
        let (grid, structure, landmark_modes) = carrier.carry(fields)?;
        Ok(FaceSpace {
            surfaces: SurfaceSpace::new(reference.surface().clone(), grid)?,
            structure: SpaceSamples {
                base: reference.structure().to_vec(),
                modes: structure,
            },
            sigma: sigma.to_vec(),
            expressions: ExpressionModes::default(),
            landmarks: Some(SpaceSamples {
                base: carrier.landmark_positions(),
                modes: landmark_modes,
            }),
        })
    }

    /// This space with expression modes (replacing any it had) made from displacement fields
    /// of the reference's scan at each expression's full strength, carried to the reference
    /// as [`FaceSpace::from_displacements`] carries identity modes. `note` says where they
    /// came from.
    ///
    /// # Errors
    /// As [`FaceSpace::from_displacements`], and [`FaceError::Space`] for names that are not
    /// one per field, or empty or repeated.
    pub fn with_expression_displacements(
        mut self,
        reference: &ReferenceFace,
        scan: &TriangleMesh,
        landmarks: &[usize],
        names: &[String],
        fields: &[Vec<Vector3<Real>>],
        note: &str,
    ) -> Result<Self, FaceError> {
        if names.len() != fields.len() {
            return Err(FaceError::Space(format!(
                "{} expression names for {} fields",
                names.len(),
                fields.len()
            )));
        }
        let (grid, structure, landmark_modes) = Carrier::new(reference, scan, landmarks)?.carry(fields)?;
        let expressions = ExpressionModes {
            names: names.to_vec(),
            grid,
            structure,
            note: note.to_owned(),
            // Only a space that carries the landmarks carries its expressions' moves of them.
            landmarks: if self.landmarks.is_some() {
                landmark_modes
            } else {
                Vec::new()
            },
        };
        expressions
            .check(self.surfaces.base().rows() * self.surfaces.base().cols())
            .map_err(FaceError::Space)?;
        self.expressions = expressions;
        Ok(self)
    }

    /// The space a reference stores ([`ReferenceFace::face_space`]) on `reference`: its
    /// surface and structure are the base, `modes` the displacements and deviations.
    ///
    /// # Errors
    /// [`FaceError::Space`] when the modes do not match the reference's grid, or a value is
    /// not finite (see [`crate::reference::SpaceModes`]).
    pub fn from_modes(
        reference: &ReferenceFace,
        modes: &crate::reference::SpaceModes,
    ) -> Result<Self, FaceError> {
        let surface = reference.surface();
        modes
            .check(surface.rows() * surface.cols())
            .map_err(FaceError::Space)?;
        Ok(FaceSpace {
            surfaces: SurfaceSpace::new(surface.clone(), modes.grid.clone())?,
            structure: SpaceSamples {
                base: reference.structure().to_vec(),
                modes: modes.structure.clone(),
            },
            sigma: modes.sigma.clone(),
            expressions: modes.expressions.clone(),
            landmarks: (!modes.landmark_base.is_empty()).then(|| SpaceSamples {
                base: modes.landmark_base.clone(),
                modes: modes.landmarks.clone(),
            }),
        })
    }

    /// The space's modes as a reference stores them ([`ReferenceFace::with_space`]); `note`
    /// is the identity modes' (the expressions keep their own).
    pub fn to_modes(&self, note: &str) -> crate::reference::SpaceModes {
        crate::reference::SpaceModes {
            grid: self.surfaces.modes().to_vec(),
            structure: self.structure.modes.clone(),
            sigma: self.sigma.clone(),
            note: note.to_owned(),
            expressions: self.expressions.clone(),
            landmark_base: self.landmarks.as_ref().map_or_else(Vec::new, |l| l.base.clone()),
            landmarks: self.landmarks.as_ref().map_or_else(Vec::new, |l| l.modes.clone()),
        }
    }

    /// The expression modes (empty when the space has none).
    pub fn expressions(&self) -> &ExpressionModes {
        &self.expressions
    }

    /// The surfaces of the space.
    pub fn surfaces(&self) -> &SurfaceSpace {
        &self.surfaces
    }

    /// The number of modes.
    pub fn mode_count(&self) -> usize {
        self.sigma.len()
    }

    /// Each mode's prior standard deviation.
    pub fn sigma(&self) -> &[Real] {
        &self.sigma
    }

    /// The mean structure and each mode's displacement of it.
    pub(crate) fn structure_samples(&self) -> &SpaceSamples {
        &self.structure
    }

    /// Each mode's displacement of the 40 points (`[mode][point]`).
    pub fn structure_modes(&self) -> &[Vec<Vector3<Real>>] {
        &self.structure.modes
    }

    /// The first `k` identity modes only (the expressions stay).
    pub fn truncated(&self, k: usize) -> Self {
        let k = k.min(self.mode_count());
        FaceSpace {
            surfaces: self.surfaces.truncated(k),
            structure: SpaceSamples {
                base: self.structure.base.clone(),
                modes: self.structure.modes[..k].to_vec(),
            },
            sigma: self.sigma[..k].to_vec(),
            expressions: self.expressions.clone(),
            landmarks: self.landmarks.as_ref().map(|l| SpaceSamples {
                base: l.base.clone(),
                modes: l.modes[..k].to_vec(),
            }),
        }
    }

    /// The ridge `ρₖ = ε² / σₖ²` of the MAP fits for data with noise `ε` per coordinate (in
    /// the space's units): the Gaussian prior on the weights against the data's error.
    fn ridge(&self, noise: Real) -> Vec<Real> {
        self.sigma.iter().map(|s| (noise / s).powi(2)).collect()
    }

    /// The member's 40 points, canonical frame.
    ///
    /// # Errors
    /// [`FaceError::Kernel`] unless there is one finite weight per mode.
    pub fn structure(&self, weights: &[Real]) -> Result<Vec<Point3<Real>>, FaceError> {
        self.surfaces.control_points(weights)?; // validates the weights
        Ok(self.structure.member(weights))
    }

    /// The member as a face surface over the reference's clip region, canonical frame.
    ///
    /// The face is the space's own surface: its transform is the identity, its deformation
    /// reported as [`super::Deformation::Affine`] (none is applied), and its report's
    /// `point_rms` says how far the surface passes from the member's structure.
    ///
    /// # Errors
    /// As [`FaceSpace::structure`].
    pub fn face(&self, reference: &ReferenceFace, weights: &[Real]) -> Result<FaceSurface, FaceError> {
        self.face_with_expression(reference, weights, &[])
    }

    /// The member with an expression: identity `weights` and expression weights `expression`
    /// (one per expression mode, each in `[0, 1]`; empty for the neutral face).
    ///
    /// # Errors
    /// As [`FaceSpace::structure`], and [`FaceError::Option`] for expression weights that
    /// are not one per mode in `[0, 1]`.
    pub fn face_with_expression(
        &self,
        reference: &ReferenceFace,
        weights: &[Real],
        expression: &[Real],
    ) -> Result<FaceSurface, FaceError> {
        let structure = self.structure_with_expression(weights, expression)?;
        let mut controls = self.surfaces.control_points(weights)?;
        add_weighted(&mut controls, &self.expressions.grid, expression);
        let base = self.surfaces.base();
        let surface = BSplineSurface::new(
            base.knots_u().clone(),
            base.knots_v().clone(),
            base.rows(),
            base.cols(),
            controls,
        )?;
        FaceSurface::from_surface(reference, surface, structure)
    }

    /// The member's 40 points with an expression, as [`FaceSpace::face_with_expression`].
    ///
    /// # Errors
    /// As [`FaceSpace::face_with_expression`].
    pub fn structure_with_expression(
        &self,
        weights: &[Real],
        expression: &[Real],
    ) -> Result<Vec<Point3<Real>>, FaceError> {
        let mut points = self.structure(weights)?;
        if expression.is_empty() {
            return Ok(points);
        }
        if expression.len() != self.expressions.len() || expression.iter().any(|e| !(0.0..=1.0).contains(e)) {
            return Err(FaceError::Option {
                name: "expression weights",
                value: format!("{expression:?}"),
                expected: "one per expression mode, each in [0, 1]",
            });
        }
        add_weighted(&mut points, &self.expressions.structure, expression);
        Ok(points)
    }

    /// Whether the space carries the 68 iBUG landmarks ([`FaceSpace::landmarks`]).
    pub fn carries_landmarks(&self) -> bool {
        self.landmarks.is_some()
    }

    /// The member's 68 iBUG landmarks with an expression (`expression` as
    /// [`FaceSpace::face_with_expression`]'s), canonical frame, or `None` when the space does not
    /// carry them ([`crate::reference::SpaceModes::landmark_base`]).
    ///
    /// # Errors
    /// As [`FaceSpace::structure_with_expression`].
    pub fn landmarks(
        &self,
        weights: &[Real],
        expression: &[Real],
    ) -> Result<Option<Vec<Point3<Real>>>, FaceError> {
        self.structure_with_expression(weights, expression)?; // validates the weights
        Ok(self.landmarks.as_ref().map(|landmarks| {
            let mut points = landmarks.member(weights);
            add_weighted(&mut points, &self.expressions.landmarks, expression);
            points
        }))
    }

    /// The MAP fit of the space's structure to 40 target points in any frame: weights and a
    /// similarity minimising `Σ ‖M S(w)ᵢ − tᵢ‖² / ε² + Σₖ wₖ² / σₖ²` over the points whose
    /// `point_weights` are positive (weighted), alternating the similarity (Umeyama) and the
    /// weights (linear, [`SpaceSamples::fit_weights`]) until the weights settle.
    ///
    /// `noise` is `ε`, the targets' error per coordinate in their own units.
    ///
    /// # Errors
    /// [`FaceError::PointCount`], [`FaceError::NonFinite`] for bad targets,
    /// [`FaceError::Option`] for a noise that is not positive or weights that are negative,
    /// [`FaceError::FlatReference`] when no similarity is determined.
    pub fn fit_structure(
        &self,
        target: &[Point3<Real>],
        point_weights: &[Real; POINT_COUNT],
        noise: Real,
    ) -> Result<SpaceFit, FaceError> {
        super::check_structure(target)?;
        if !(noise > 0.0 && noise.is_finite()) {
            return Err(FaceError::Option {
                name: "noise",
                value: noise.to_string(),
                expected: "positive and finite",
            });
        }
        if point_weights.iter().any(|w| !(w.is_finite() && *w >= 0.0)) {
            return Err(FaceError::Option {
                name: "point weight",
                value: format!("{point_weights:?}"),
                expected: "finite and non-negative",
            });
        }
        let k = self.mode_count();
        let mut weights = vec![0.0; k];
        let mut placement = Similarity3::identity();
        let mut iterations = 0;
        // Weighted points enter both solves by repetition-free scaling: √wᵢ on every term.
        let roots: Vec<Real> = point_weights.iter().map(|w| w.sqrt()).collect();
        let scaled = SpaceSamples {
            base: self
                .structure
                .base
                .iter()
                .zip(&roots)
                .map(|(p, r)| p * *r)
                .collect(),
            modes: self
                .structure
                .modes
                .iter()
                .map(|m| m.iter().zip(&roots).map(|(d, r)| d * *r).collect())
                .collect(),
        };
        let used: Vec<usize> = (0..POINT_COUNT).filter(|&i| point_weights[i] > 0.0).collect();
        for iteration in 0..100 {
            iterations = iteration + 1;
            let current = self.structure.member(&weights);
            let pick = |ps: &[Point3<Real>]| used.iter().map(|&i| ps[i]).collect::<Vec<_>>();
            let (map, _) = crate::compare::fit_similarity(&pick(&current), &pick(target))
                .ok_or(FaceError::FlatReference)?;
            placement = map;
            let inverse = map.inverse();
            let pulled: Vec<Point3<Real>> = target
                .iter()
                .zip(&roots)
                .map(|(t, r)| (inverse * t) * *r)
                .collect();
            // ε in the space's units: the targets' noise divided by the placement's scale.
            let next = scaled.fit_weights(&pulled, &self.ridge(noise / map.scaling()))?;
            let change = largest_change(&next, &weights);
            weights = next;
            if change < 1e-9 {
                break;
            }
        }
        let current = self.structure.member(&weights);
        let total: Real = point_weights.iter().sum();
        let rms = (current
            .iter()
            .zip(target)
            .zip(point_weights)
            .map(|((c, t), w)| w * (placement * c - t).norm_squared())
            .sum::<Real>()
            / total.max(Real::MIN_POSITIVE))
        .sqrt();
        Ok(SpaceFit {
            weights,
            placement,
            rms,
            iterations,
        })
    }

    /// The MAP fit of the space's surface to a mesh (a scan), starting from `start` (a
    /// structure fit): trimmed iterative closest points. The member is sampled on a lattice of
    /// `spacing` (canonical units) over the reference's clip region; each iteration moves the
    /// samples by the placement, finds the mesh's closest points, drops the `trim` fraction
    /// farthest, then refits the weights (ridge as in [`FaceSpace::fit_structure`], `noise` in
    /// the mesh's units) and the similarity.
    ///
    /// This is what the space can do with the whole surface as data: the ceiling of any fit
    /// to landmarks or photos.
    ///
    /// # Errors
    /// [`FaceError::Option`] for options out of range; [`FaceError::Kernel`] when the weights
    /// are not determined; [`FaceError::FlatReference`] when no similarity is.
    pub fn fit_surface(
        &self,
        reference: &ReferenceFace,
        mesh: &TriangleMesh,
        start: &SpaceFit,
        options: &DenseFitOptions,
    ) -> Result<SpaceFit, FaceError> {
        options.validate()?;
        let mut params = Vec::new();
        let (w, h) = (
            reference.frame().x[1] - reference.frame().x[0],
            reference.frame().y[1] - reference.frame().y[0],
        );
        let (nu, nv) = (
            (w / options.spacing).ceil() as usize,
            (h / options.spacing).ceil() as usize,
        );
        for i in 0..=nu {
            for j in 0..=nv {
                let (u, v) = (i as Real / nu as Real, j as Real / nv as Real);
                if reference.in_face_region(u, v) {
                    params.push([u, v]);
                }
            }
        }
        let samples = self.surfaces.sample(&params)?;
        let closest = ClosestPoints::new(mesh);
        let mut fit = start.clone();
        for iteration in 0..options.iterations {
            let member = samples.member(&fit.weights);
            let placed: Vec<Point3<Real>> = member.iter().map(|p| fit.placement * p).collect();
            let found = closest.closest_many(&placed);
            let mut order: Vec<usize> = (0..found.len()).collect();
            order.sort_by(|&a, &b| found[a].distance.total_cmp(&found[b].distance));
            order.truncate(((1.0 - options.trim) * found.len() as Real).ceil() as usize);
            order.sort_unstable();
            let inverse = fit.placement.inverse();
            let kept = SpaceSamples {
                base: order.iter().map(|&s| samples.base[s]).collect(),
                modes: samples
                    .modes
                    .iter()
                    .map(|m| order.iter().map(|&s| m[s]).collect())
                    .collect(),
            };
            let targets: Vec<Point3<Real>> = order.iter().map(|&s| inverse * found[s].point).collect();
            let ridge = self.ridge(options.noise / fit.placement.scaling());
            fit.weights = kept.fit_weights(&targets, &ridge)?;
            let moved = kept.member(&fit.weights);
            let on_mesh: Vec<Point3<Real>> = order.iter().map(|&s| found[s].point).collect();
            let (map, rms) =
                crate::compare::fit_similarity(&moved, &on_mesh).ok_or(FaceError::FlatReference)?;
            fit.placement = map;
            fit.rms = rms;
            fit.iterations = start.iterations + iteration + 1;
        }
        Ok(fit)
    }
}

/// The reference's sampling of its own scan, which carries per-vertex displacement fields to
/// displacement grids on the reference's knots and displacements of its 40 points.
struct Carrier<'a> {
    scan: &'a TriangleMesh,
    landmarks: &'a [usize],
    params: Vec<[Real; 2]>,
    hits: Vec<crate::mesh::FrontHit>,
    base: SurfaceSpace,
    smoothness: Real,
}

impl<'a> Carrier<'a> {
    fn new(
        reference: &ReferenceFace,
        scan: &'a TriangleMesh,
        landmarks: &'a [usize],
    ) -> Result<Self, FaceError> {
        let vertices = scan.positions().len();
        let problem = |what: String| Err(FaceError::Space(what));
        if landmarks.len() != IBUG_POINT_COUNT || landmarks.iter().any(|&v| v >= vertices) {
            return problem(format!(
                "{} landmark vertex indices given for a scan of {vertices} vertices; need 68 valid ones",
                landmarks.len()
            ));
        }
        // The reference's sampling of its scan: the front-most surface over the frame.
        let frame = reference.frame();
        let options = reference.fit().options;
        let raster = frame.raster(options.sample_spacing);
        let mut hits = Vec::new();
        let mut params = Vec::new();
        let mut points = Vec::new();
        for (index, hit) in front_hits(scan, &raster).into_iter().enumerate() {
            let Some(hit) = hit else { continue };
            let p = raster.position(index % raster.width, index / raster.width);
            let uv = frame.parameters(p.x, p.y);
            if (0.0..=1.0).contains(&uv.x)
                && (0.0..=1.0).contains(&uv.y)
                && reference.in_face_region(uv.x, uv.y)
            {
                params.push([uv.x, uv.y]);
                points.push(Point3::new(p.x, p.y, hit.height));
                hits.push(hit);
            }
        }
        if params.len() < 16 {
            return problem(format!(
                "the scan covers only {} samples of the reference's face region: is it the reference's scan, in its canonical frame?",
                params.len()
            ));
        }
        // The scan must be the one the grid was fitted to: its front surface within the fit's
        // residuals of the grid (the median against ten times the fit's median, and a unit).
        let on_grid = reference.surface().eval_many(&params)?;
        let mut gaps: Vec<Real> = on_grid.iter().zip(&points).map(|(b, p)| (b - p).norm()).collect();
        gaps.sort_unstable_by(Real::total_cmp);
        let median = gaps[gaps.len() / 2];
        if median > 10.0 * reference.fit().median + 1.0 {
            return problem(format!(
                "the scan lies {median:.2} units from the reference's surface (median; the fit's own median is {:.3}): it is not the scan the reference was fitted to, or not in its canonical frame",
                reference.fit().median
            ));
        }
        Ok(Carrier {
            scan,
            landmarks,
            params,
            hits,
            base: SurfaceSpace::new(reference.surface().clone(), Vec::new())?,
            smoothness: options.smoothness,
        })
    }

    /// The scan's 68 landmark vertices.
    fn landmark_positions(&self) -> Vec<Point3<Real>> {
        self.landmarks.iter().map(|&v| self.scan.positions()[v]).collect()
    }

    /// Each field's displacement grid, structure displacement and landmark displacement.
    #[allow(clippy::type_complexity)]
    fn carry(
        &self,
        fields: &[Vec<Vector3<Real>>],
    ) -> Result<
        (
            Vec<Vec<Vector3<Real>>>,
            Vec<Vec<Vector3<Real>>>,
            Vec<Vec<Vector3<Real>>>,
        ),
        FaceError,
    > {
        let vertices = self.scan.positions().len();
        let mut grids = Vec::with_capacity(fields.len());
        let mut structures = Vec::with_capacity(fields.len());
        let mut landmarks = Vec::with_capacity(fields.len());
        for (k, field) in fields.iter().enumerate() {
            if field.len() != vertices {
                return Err(FaceError::Space(format!(
                    "mode {k} has {} displacements for a scan of {vertices} vertices",
                    field.len()
                )));
            }
            if field.iter().any(|d| !d.iter().all(|c| c.is_finite())) {
                return Err(FaceError::Space(format!(
                    "mode {k} has a displacement that is not finite"
                )));
            }
            let samples: Vec<Vector3<Real>> = self
                .hits
                .iter()
                .map(|hit| hit.interpolate(self.scan, field))
                .collect();
            let (grid, _) = self
                .base
                .fit_displacement(&self.params, &samples, self.smoothness)?;
            grids.push(grid);
            let ibug: Vec<Point3<Real>> = self.landmarks.iter().map(|&v| Point3::from(field[v])).collect();
            let moved = from_ibug68(&ibug).map_err(|e| FaceError::Space(e.to_string()))?;
            structures.push(moved.into_iter().map(|p| p.coords).collect());
            landmarks.push(ibug.into_iter().map(|p| p.coords).collect());
        }
        Ok((grids, structures, landmarks))
    }
}

/// `target += Σₖ weights[k] · modes[k]`, mode by mode (a member's expression, on control
/// points, structure points or displacements).
pub(crate) fn add_weighted<T: std::ops::AddAssign<Vector3<Real>>>(
    target: &mut [T],
    modes: &[Vec<Vector3<Real>>],
    weights: &[Real],
) {
    for (weight, mode) in weights.iter().zip(modes) {
        for (t, d) in target.iter_mut().zip(mode) {
            *t += d * *weight;
        }
    }
}

/// The joint fit of a [`FaceSpace`] to photos' 2D points, from [`FaceSpace::fit_photos`].
#[derive(Debug, Clone, PartialEq)]
pub struct PhotoSpaceFit {
    /// The identity weights shared by every photo.
    pub weights: Vec<Real>,
    /// Per photo: its expression weights, one per expression mode in `[0, 1]` (empty when
    /// the fit had no expressions, [`PhotoFitOptions::expressions`]).
    pub expressions: Vec<Vec<Real>>,
    /// The expression modes' names, in the order of each photo's weights (empty when the fit
    /// had none).
    pub expression_names: Vec<String>,
    /// Per photo: its scaled orthographic pose and where the structure's origin projects
    /// (`y` up), so that point `X` is seen at `offset + s·P·R·X`.
    pub poses: Vec<(Pose, Point2<Real>)>,
    /// Per photo: the weighted RMS reprojection error, canonical units.
    pub rms_units: Vec<Real>,
    /// Alternations run.
    pub iterations: usize,
    /// The modes whose weight left the prior's plausible range (beyond
    /// [`PLAUSIBLE_SIGMAS`] deviations) and was held at its edge.
    pub held: Vec<usize>,
    /// Per photo: how far the face's outline moved each of its points in the fit (pixels, `y`
    /// up; zero off [`super::OUTLINE_POINTS`]), to add to the photo's points wherever
    /// they are measured against the structure again; empty when the outline was not used.
    pub outline_shifts: Vec<Vec<Vector2<Real>>>,
}

impl PhotoSpaceFit {
    /// Photo `photo`'s points (`y` up) moved by its [`PhotoSpaceFit::outline_shifts`], the jaw
    /// points onto the face's outline where the fit measured them: the points
    /// [`FaceSpace::refine_photos`] takes. Unchanged when the outline was not used.
    pub fn outline_points(&self, photo: usize, points: &[Point2<Real>]) -> Vec<Point2<Real>> {
        let mut moved = points.to_vec();
        if let Some(shifts) = self.outline_shifts.get(photo) {
            for (p, s) in moved.iter_mut().zip(shifts) {
                *p += s;
            }
        }
        moved
    }
}

/// How many prior deviations a fitted weight may reach before [`FaceSpace::fit_photos`] holds
/// it there: a weight beyond 3σ is more likely the landmarks' error than the face (each mode's
/// prior puts 0.3% of faces there).
pub const PLAUSIBLE_SIGMAS: Real = 3.0;

/// Options of [`FaceSpace::fit_photos`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PhotoFitOptions {
    /// `ε`, the points' error per coordinate in canonical units: with the identity prior it
    /// sets how far the landmarks may pull the shape from the mean.
    pub noise: Real,
    /// The prior of each photo's expression weights, or `None` to fit no expressions (every
    /// photo neutral). Ignored for a space without expression modes.
    pub expressions: Option<ExpressionPrior>,
    /// Measure the jaw points off the chin against the face's outline as each photo sees it
    /// (where a landmarker puts them, [`super::OUTLINE_POINTS`]), not against fixed places of
    /// the face; [`PhotoSpaceFit::outline_shifts`] says how far it moved them.
    pub outline: bool,
    /// `ω_g`, the weight of each inner-lip gap ([`crate::structure::INNER_LIP_PAIRS`]) beside
    /// a point's in [`FaceSpace::fit_photos_with_lips`] (0 leaves the gaps out). A gap is the
    /// difference of two points, with twice a point's variance.
    pub lips: Real,
}

/// The weight [`PhotoFitOptions::lips`] takes when the inner lips are asked for (the
/// pipeline leaves them out by default, [`crate::pipeline::Shape::Space`]).
///
/// Measured by `tools/photo_eval --expressions --expression-oracle --seeds 2 --counts 3,8`
/// (six ICT-FaceKit identities wearing real skins, neutral, smiling (0.7) and with the jaw
/// open (0.35) in the same poses; dlib's landmarks; the whole photo path with the refinement;
/// error against the neutral identity over the mean face's, 3 / 8 photos):
///
/// | inner lips | neutral | smile | jaw open | jaw weight found (truth 0.35) |
/// |---|---|---|---|---|
/// | **left out** | **0.69 / 0.57** | **0.75 / 0.70** | **0.74 / 0.68** | 0.20 / 0.19 |
/// | ω_g = 0.5 | 0.71 / 0.60 | 0.80 / 0.69 | 0.75 / 0.70 | 0.22 / 0.22 |
/// | ω_g = 2 | 0.71 / 0.60 | 0.78 / 0.67 | 0.75 / 0.69 | |
/// | ω_g = 0.5, the gaps' changes read at 0.6 and 0.5 units more open | 0.70 / 0.59 | 0.79 / 0.69 | 0.74 / 0.70 | |
///
/// The gaps do not pay on these photos. dlib reads the inner lips' gap at about 0.6 of its
/// change (over the eye distance, on the pools of ict-0, ict-3 and ict-5: 0.020–0.038
/// neutral, 0.117–0.125 with the jaw open, where the mean face opens from 0.016 to 0.174), so
/// the landmark fit finds a little more of an open jaw (0.22 of 0.35) but not the face; and
/// reading more into a closed mouth's gaps than the mean face has, it fits the neutral photos'
/// mouths open and their faces worse. Reading the gaps at dlib's gain and offset (the last row)
/// brings the neutral back part of the way and the jaw no further. The rendered subjects'
/// open mouths were lip-coloured inside then (they are dark since, as in photos, and dlib
/// reads a little more of an open jaw: 0.22 / 0.23 of 0.35 against 0.20 / 0.19 without the
/// gaps); a real open mouth (teeth, a dark inside) may be read otherwise still.
///
/// On the main evaluation (`tools/photo_eval --methods lips` against the committed
/// `tools/results/photos.md`, 105 sets; mean ratio to the mean face for 2 / 3 / 4 / 8 / 16
/// photos) the gaps at this weight give 0.78 / 0.71 / 0.69 / 0.67 / 0.63 against the default's
/// 0.78 / 0.72 / 0.70 / 0.66 / 0.62: on average 0.003 worse per set, from 0.21 better to 0.09
/// worse, and the widest pair of halves of 16 photos 0.80 mm apart against 0.70. The real
/// scan, the one face with a real mouth, gains a little: its 15 sets 0.825× the mean face
/// against 0.834× (10 better, 1 worse: `photos-8` 1.09 mm against 1.08). One scan is too thin
/// a basis to turn them on.
///
/// Measured again with the open mouths dark inside (the same commands; expressions as in the
/// table above, then the main evaluation's 105 sets): neutral 0.70 / 0.60 against the
/// default's 0.69 / 0.58; smile / neutral 1.16 / 1.16 against 1.15 / 1.20; jaw / neutral
/// 1.05 / 1.15 against 1.06 / 1.19, the jaw found at 0.24 / 0.27 of 0.35 (0.22 / 0.23); set by
/// set 0.698 of the mean face against 0.694, the same 3 sets more than 2% worse than the
/// earlier landmark fit, the scan's 16 scored sets 0.773 against 0.782 (`photos-8` 0.84×
/// against 0.83×). Still off.
///
/// With perfect landmarks the gaps do pay. Handed the truth's own 68 points projected into
/// the same photos (the subjects' landmark vertices, with no occlusion test; `photo_eval
/// --expressions --projected-landmarks --seeds 2 --counts 3,8 --methods "lips,landmarks only
/// lips,landmarks only"` and `--methods default`), the whole
/// path gives smile / neutral 1.09 / 1.07 and jaw / neutral 1.00 / 1.09 with the gaps, against
/// 1.08 / 1.13 and 1.03 / 1.13 without (the jaw found at 0.25 / 0.27 against 0.19 / 0.20):
/// within the 10% the face-space issue asks. From dlib's points it is not, so what stands
/// between the expressive photos and that bound is the landmarker's reading of a mouth (the
/// rendered mouths had no teeth then).
///
/// With teeth in the rendered mouths (a band under each lip, `tools/photo_eval`'s subjects)
/// dlib reads an open mouth better: with the gaps the landmark fit finds the open jaw at
/// 0.30 / 0.32 of 0.35 (without them 0.24 / 0.24). The whole path gives smile / neutral
/// 1.15 / 1.12 and jaw / neutral 1.01 / 1.15 with the gaps, 1.12 / 1.18 and 0.99 / 1.15
/// without, neutral photos 0.71 / 0.61 of the mean face's error against 0.71 / 0.59
/// (`photo_eval --expressions --expression-oracle --seeds 2 --counts 3,8`,
/// `tools/results/expressions.md`): the open jaw found, the face from eight photos of it is
/// no better. Still off.
pub const LIP_WEIGHT: Real = 0.5;

/// A photo's inner-lip gaps, `y` up, in its pixels ([`crate::structure::inner_lip_gaps`]).
pub type LipGaps = [Vector2<Real>; 3];

/// The prior of the photos' expression weights in [`FaceSpace::fit_photos`]: per photo `i`
/// and expression mode `l`, the weight `eᵢₗ ∈ [0, 1]` costs
///
/// ```text
/// (eᵢₗ − cₗ)² / τ²  +  2 r eᵢₗ        and the photos' shared expression c:  Σₗ cₗ² / τₛ²
/// ```
///
/// (the Gaussian's and the exponential's negative logs, times two): a Gaussian of deviation
/// `τ` around an expression `c` that the photos share, itself drawn around the neutral face
/// with deviation `τₛ` (a hierarchical prior; without `τₛ`, `c = 0`), and an exponential prior
/// of rate `r` (most blendshapes are off in most photos).
///
/// The two additions each answer a bias of the plain Gaussian on `[0, 1]`, measured by
/// `tools/photo_eval --expressions` (six ICT-FaceKit identities wearing real skins, neutral,
/// smiling and with an open jaw in the same poses; the whole photo path; error against the
/// neutral identity over the mean face's, 3 / 8 photos; `photo_eval`'s "expressions
/// independent" method is the old prior):
///
/// | prior | neutral | smile | jaw open | smile / neutral, 8 |
/// |---|---|---|---|---|
/// | τ = 0.5 alone | 0.82 / 0.76 | 0.85 / 0.85 | 0.89 / 0.76 | 1.11 |
/// | + rate r = 1 | 0.76 / 0.73 | 0.83 / 0.91 | 0.88 / 0.76 | 1.20 |
/// | + shared, τₛ = 0.5 | 0.83 / 0.82 | 0.87 / 0.82 | 0.90 / 0.81 | 1.04 |
/// | + shared τₛ = 0.5, r = 1 | 0.77 / 0.73 | 0.82 / 0.88 | 0.87 / 0.74 | 1.17 |
/// | **+ shared τₛ = 0.5, r = 0.3** | **0.80 / 0.75** | **0.84 / 0.82** | **0.87 / 0.74** | **1.09** |
/// | + shared τₛ = 0.25, r = 0.3 | 0.80 / 0.75 | 0.84 / 0.84 | 0.88 / 0.74 | 1.11 |
/// | + shared τₛ = 1, r = 0.3 | 0.81 / 0.75 | 0.83 / 0.82 | 0.88 / 0.74 | 1.10 |
/// | + shared τₛ = 0.5, r = 0.5 | 0.79 / 0.74 | 0.82 / 0.83 | 0.87 / 0.74 | 1.11 |
///
/// * Clamped at zero, the landmarks' noise gives every photo small positive weights on
///   many of the 53 modes whatever the face does; their mean is a systematic expression that
///   the identity then answers. The exponential prior keeps a weight at zero until the
///   landmarks pull it harder than `r`: better on neutral photos, but it also shrinks real
///   expressions, and the identity takes up what it shrinks.
/// * Independent per photo, a smile shown in all of `n` photos pays its prior `n` times,
///   a change of identity that mimics it only once; with more photos the identity takes it
///   (smile, 3 → 8 photos: 0.85 → 0.91 with the rate alone). Centred on a shared
///   expression, it pays about once, and the expression keeps it.
/// * The rate still pays once per photo. Divided among the photos (each photo's `r / n`,
///   or `r / √n`) it was measured later with the refined default (`photo_eval --expressions
///   --seeds 2 --counts 3,8`; neutral, smile, jaw open, 3 / 8 photos): `r` 0.69 / 0.57,
///   0.75 / 0.70, 0.74 / 0.68; `r / n` 0.70 / 0.59, 0.74 / 0.67, 0.75 / 0.68; `r / √n`
///   0.70 / 0.57, 0.76 / 0.66, 0.76 / 0.67. A smile in 8 photos gains a little and the neutral
///   photos lose about as much, so the rate stays per photo.
/// * Perfect points do not find a whole smile either. The embedded space's own 40 points of
///   three members drawn with weights ~ N(0, 1), each smiling (`mouthSmile_L` and `_R` at
///   0.7) or with the jaw open (0.35) in 8 views from −40° to 40°, fitted with this prior
///   (a temporary test): the smile comes out at 0.34–0.56 with ε = 4 (the pipeline's) and
///   0.53–0.68 with ε = 0.5, the open jaw at 0.28–0.36. Without the expression prior the 53
///   blendshapes share the smile out (their weights summing to 10–14 at ε = 4). A shared
///   expression is told from identity only by the priors: the identity modes and the other
///   blendshapes explain the 40 points about as cheaply. From dlib's points on rendered
///   photos the open jaw comes out at 0.22 / 0.23 for 3 / 8 photos and the smile at
///   0.37 / 0.39 (`tools/results/expressions.md`). From the truth's own 68 points projected
///   into the same photos (`photo_eval --expressions --projected-landmarks`, the whole path
///   otherwise unchanged) they come out at 0.19 / 0.20 and 0.44 / 0.48: the open jaw's
///   shortfall is the fit's, not the landmarker's (a per-expression gain of the landmarker
///   would not find it), while dlib reads about 0.8 of the smile that the points show.
/// * The rate's shrinkage was measured and kept. Fitted again without the rate, the
///   expressions it picked (a "relaxed lasso": the rate chooses which weights move, a second
///   Levenberg–Marquardt run sizes them without it, the others held) come out larger, but the
///   identity hardly gains and the real scan loses (a temporary switch; `photo_eval
///   --expressions --methods default --seeds 2 --counts 3,8`: neutral, smile, jaw open, 3 / 8
///   photos, then expressive over neutral error and the weight found; `photo_eval
///   --ict-subjects 0 --baseline tools/results/photos.md`: the scan's 15 sets and
///   `photos-8`):
///
///   | second fit | neutral | smile | jaw open | smile / neutral | jaw / neutral | smile, jaw found, 8 photos | the scan | `photos-8` |
///   |---|---|---|---|---|---|---|---|---|
///   | **none** | 0.71 / 0.59 | 0.76 / 0.69 | 0.69 / 0.68 | 1.12 / 1.18 | 0.99 / 1.15 | 0.40, 0.24 | 0.834 | 0.83 |
///   | every weight above zero, each photo's | 0.71 / 0.59 | 0.79 / 0.67 | 0.69 / 0.68 | 1.14 / 1.15 | 0.99 / 1.15 | 0.48, 0.25 | | |
///   | the expressions whose mean reaches 0.05 | 0.70 / 0.59 | 0.76 / 0.64 | 0.69 / 0.67 | 1.11 / 1.11 | 1.00 / 1.14 | 0.49, 0.25 | 0.863 | 0.93 |
///
///   An open jaw stays at a quarter without the rate too: what holds it back is the identity
///   modes that mimic it, not the rate. On the scan the second fit sizes up the expressions
///   the fit finds where there are none (its sneer), and five of its 15 sets end more than
///   2% worse than the landmark fit alone.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExpressionPrior {
    /// `τ`, each photo's deviation from the shared expression.
    pub sigma: Real,
    /// `τₛ`, the shared expression's deviation from the neutral face, or `None` to centre
    /// every photo on the neutral face.
    pub shared_sigma: Option<Real>,
    /// `r`, the exponential prior's rate per weight (0 for none).
    pub rate: Real,
}

impl ExpressionPrior {
    /// `τ = 0.5`, `τₛ = 0.5`, `r = 0.3` (measured, see the type's documentation).
    pub const DEFAULT: ExpressionPrior = ExpressionPrior {
        sigma: 0.5,
        shared_sigma: Some(0.5),
        rate: 0.3,
    };

    /// The plain prior of deviation `τ` around the neutral face, every photo on its own
    /// (the prior before the shared expression and the rate).
    pub fn independent(sigma: Real) -> ExpressionPrior {
        ExpressionPrior {
            sigma,
            shared_sigma: None,
            rate: 0.0,
        }
    }
}

impl Default for ExpressionPrior {
    fn default() -> Self {
        Self::DEFAULT
    }
}

impl FaceSpace {
    /// The MAP fit of the space to photos' 2D points under scaled orthographic cameras:
    /// identity weights `w` shared by all photos, and per photo `i` a pose, an offset and
    /// (when the space has expression modes and [`PhotoFitOptions::expressions`] asks
    /// for them) expression weights `eᵢ ∈ [0, 1]ᴸ`, minimising
    ///
    /// ```text
    /// Σᵢ Σⱼ ωⱼ ‖oᵢ + sᵢ P Rᵢ (S(w) + E eᵢ)ⱼ − xᵢⱼ‖² / (sᵢ² ε²)  +  Σₖ wₖ² / σₖ²  +  prior(e, c)
    /// ```
    ///
    /// (reprojection errors measured in about canonical units, in a fixed unit per photo, see
    /// `PhotoUnknowns`; `ε` per coordinate, `E eᵢ` the expressions' displacement of the
    /// structure, `prior` the [`ExpressionPrior`]'s with its shared expression `c`, fitted
    /// with the identity). Every photo starts from its pose for the mean face (closed form, then
    /// refined), neutral; then Levenberg–Marquardt runs over all unknowns at once, each
    /// photo's pose and expression eliminated onto the identity (a Schur complement, so that
    /// the cost grows linearly with the photos), with a backtracking search along each step
    /// (expression weights are clamped to `[0, 1]`), until the cost stops falling. An identity
    /// weight beyond [`PLAUSIBLE_SIGMAS`] prior deviations is then held there
    /// ([`PhotoSpaceFit::held`]). `views[i]` are photo `i`'s 40 points with `y` up
    /// ([`crate::align::PhotoPoints::y_up`]).
    ///
    /// With [`PhotoFitOptions::outline`], the jaw points off the chin are measured against the
    /// face's outline as each photo sees it, where a landmarker puts them: for each photo, the
    /// place `Oⱼ` where the mean face shows its outline in the photo's starting pose at each
    /// such point's height ([`super::OUTLINE_POINTS`]) gives the shift `b P R (Pⱼ − Oⱼ)` added
    /// to the photo's point (`Pⱼ` the surface at the point's own place), so that its residual
    /// against `Sⱼ` is its residual against `Sⱼ` moved along the surface to the outline. The
    /// shifts hold still during the fit: its derivatives are those of `Sⱼ`, which moves with
    /// the modes much as `Oⱼ` does.
    ///
    /// The mean face's outline in the starting pose, by measurement: a second fit against the
    /// fitted face's outline, pose and expression moved the photo-realistic evaluation's mean
    /// ratios to the mean face by at most 0.01 (`tools/photo_eval --ict-subjects 6 --seeds 1
    /// --counts 3,8`: 0.81 / 0.75 against 0.82 / 0.75, one set of the 16 by 0.04) and the
    /// synthetic one's from 0.563 to 0.556 (`tools/eval`, seed 8), for 1.3× the fit's time
    /// (35 photos: 31 against 23.5 ms, `cargo bench --bench depth -- "face space"`).
    ///
    /// # Errors
    /// [`FaceError::Option`] for no views, a view without 40 finite points, a noise or an
    /// expression deviation that is not positive, or point weights that are negative or all
    /// zero; [`FaceError::Degenerate`] when a photo's pose is not determined.
    pub fn fit_photos(
        &self,
        views: &[Vec<Point2<Real>>],
        point_weights: &[Real; POINT_COUNT],
        options: &PhotoFitOptions,
    ) -> Result<PhotoSpaceFit, FaceError> {
        self.fit_photos_with_lips(views, &[], point_weights, options)
    }

    /// [`FaceSpace::fit_photos`] with each photo's inner-lip gaps: `lips[i]` photo `i`'s
    /// ([`LipGaps`], `y` up), `None` for a photo without them (its landmarker gave the 40
    /// points only), or no entries at all for none. Each gap adds
    ///
    /// ```text
    /// ω_g ‖sᵢ P Rᵢ (G(w) + Σₗ eᵢₗ ΔGₗ)_g − gᵢ_g‖² / (sᵢ² ε²)
    /// ```
    ///
    /// to the objective, `G` the space's own gaps (its lower inner-lip landmarks minus the
    /// upper, [`crate::structure::INNER_LIP_PAIRS`]) and `ω_g` [`PhotoFitOptions::lips`]. A
    /// gap needs no offset: it is a direction in the photo, not a place. The gaps are what
    /// tells an open mouth from a long chin: no identity opens the mouth, and only the
    /// expressions do. A space that does not carry the landmarks
    /// ([`crate::reference::SpaceModes::landmark_base`]) ignores them.
    ///
    /// # Errors
    /// As [`FaceSpace::fit_photos`], and [`FaceError::Option`] for gaps that are not one
    /// entry per view, not finite, or a negative gap weight.
    pub fn fit_photos_with_lips(
        &self,
        views: &[Vec<Point2<Real>>],
        lips: &[Option<LipGaps>],
        point_weights: &[Real; POINT_COUNT],
        options: &PhotoFitOptions,
    ) -> Result<PhotoSpaceFit, FaceError> {
        let (noise, total) = check_photo_fit(views, lips, point_weights, options)?;
        let expression_modes: &[Vec<Vector3<Real>>] = match options.expressions {
            Some(_) => &self.expressions.structure,
            None => &[],
        };
        let gaps = match &self.landmarks {
            Some(landmarks) if options.lips > 0.0 && lips.iter().any(Option::is_some) => {
                Some(self.lip_gap_samples(landmarks, options.expressions.is_some()))
            }
            _ => None,
        };
        let problem = JointProblem::new(
            self,
            expression_modes,
            gaps,
            point_weights,
            options.lips,
            noise,
            options.expressions.unwrap_or(ExpressionPrior::DEFAULT),
        );

        let mut photos = self.starting_photos(views, point_weights, total, expression_modes.len())?;
        if problem.with_gaps() {
            for (photo, gaps) in photos.iter_mut().zip(lips) {
                photo.sees_gaps = gaps.is_some();
                let gaps = gaps.unwrap_or([Vector2::zeros(); 3]);
                photo.targets.extend(gaps.iter().map(|g| g / photo.unit));
            }
        }
        let mut weights = vec![0.0; self.mode_count() + problem.shared];
        let outline_shifts = if options.outline {
            let outline = super::outline::Outline::new(self)?;
            photos
                .iter_mut()
                .map(|photo| {
                    let rows: nalgebra::Matrix2x3<Real> =
                        photo.rotation.matrix().fixed_rows::<2>(0) * photo.relative_scale;
                    let shifts = super::outline::outline_shifts(&outline.places(&rows), &rows);
                    for (t, s) in photo.targets.iter_mut().zip(&shifts) {
                        *t += s;
                    }
                    shifts.iter().map(|s| s * photo.unit).collect()
                })
                .collect()
        } else {
            Vec::new()
        };
        let iterations = problem.minimise(&mut weights, &mut photos);
        weights.truncate(self.mode_count());
        // Weights outside the prior's plausible range are held at its edge, and named.
        let mut held = Vec::new();
        for (k, (w, sigma)) in weights.iter_mut().zip(&self.sigma).enumerate() {
            let limit = PLAUSIBLE_SIGMAS * sigma;
            if w.abs() > limit {
                *w = w.clamp(-limit, limit);
                held.push(k);
            }
        }
        let identity = problem.points.member(&weights);
        let rms_units = photos
            .iter()
            .map(|photo| {
                let shape = problem.shape(&identity, &photo.expression);
                // Over the 40 points (the gaps follow them in the residuals).
                let sum: Real = problem
                    .residuals(photo, &shape)
                    .iter()
                    .zip(point_weights)
                    .map(|(r, w)| w * r.norm_squared())
                    .sum();
                // From the photo's fixed unit to its fitted scale's canonical units.
                (sum / total).sqrt() / photo.relative_scale
            })
            .collect();
        Ok(PhotoSpaceFit {
            weights,
            expression_names: if expression_modes.is_empty() {
                Vec::new()
            } else {
                self.expressions.names.clone()
            },
            poses: photos
                .iter()
                .map(|p| {
                    let pose = Pose {
                        rotation: p.rotation,
                        scale: p.relative_scale * p.unit,
                    };
                    (pose, Point2::from(p.centre + p.shift * p.unit))
                })
                .collect(),
            expressions: photos.into_iter().map(|p| p.expression).collect(),
            rms_units,
            iterations,
            held,
            outline_shifts,
        })
    }
}

/// [`FaceSpace::fit_photos_with_lips`]' checks: some views of 40 finite points, a positive
/// noise and expression deviation, finite non-negative point weights not all zero, a finite
/// non-negative gap weight, and no gaps or one entry per view, finite where given. Returns the
/// noise and the weights' sum.
fn check_photo_fit(
    views: &[Vec<Point2<Real>>],
    lips: &[Option<LipGaps>],
    point_weights: &[Real; POINT_COUNT],
    options: &PhotoFitOptions,
) -> Result<(Real, Real), FaceError> {
    if views.is_empty() {
        return FaceError::option("views", "none", "at least one photo");
    }
    if let Some(i) = views
        .iter()
        .position(|v| v.len() != POINT_COUNT || v.iter().any(|p| !(p.x.is_finite() && p.y.is_finite())))
    {
        return FaceError::option("view", i, "40 finite points");
    }
    let noise = options.noise;
    if !(noise > 0.0 && noise.is_finite()) {
        return FaceError::option("noise", noise, "positive and finite");
    }
    if let Some(prior) = options.expressions {
        let positive = |x: Real| x > 0.0 && x.is_finite();
        if !positive(prior.sigma) {
            return FaceError::option("expression deviation", prior.sigma, "positive and finite");
        }
        if let Some(shared) = prior.shared_sigma
            && !positive(shared)
        {
            return FaceError::option("shared expression deviation", shared, "positive and finite");
        }
        if !(prior.rate >= 0.0 && prior.rate.is_finite()) {
            return FaceError::option("expression rate", prior.rate, "non-negative and finite");
        }
    }
    let total: Real = point_weights.iter().sum();
    if point_weights.iter().any(|w| !(w.is_finite() && *w >= 0.0)) || total <= 0.0 {
        return FaceError::option(
            "point weight",
            format!("{point_weights:?}"),
            "finite, non-negative, not all zero",
        );
    }
    let weight = options.lips;
    if !(weight >= 0.0 && weight.is_finite()) {
        return FaceError::option("lip weight", weight, "non-negative and finite");
    }
    if !lips.is_empty() && lips.len() != views.len() {
        return FaceError::option(
            "lip gaps",
            format!("{} for {} views", lips.len(), views.len()),
            "none, or one entry per view",
        );
    }
    if let Some(i) = lips
        .iter()
        .position(|g| g.is_some_and(|g| !g.iter().all(|v| v.x.is_finite() && v.y.is_finite())))
    {
        return FaceError::option("lip gaps", format!("view {i}"), "finite");
    }
    Ok((noise, total))
}

impl FaceSpace {
    /// [`FaceSpace::fit_photos`]' start: every photo's pose for the mean face (closed form, then
    /// refined), neutral (`expressions` zero weights).
    fn starting_photos(
        &self,
        views: &[Vec<Point2<Real>>],
        point_weights: &[Real; POINT_COUNT],
        total: Real,
        expressions: usize,
    ) -> Result<Vec<PhotoUnknowns>, FaceError> {
        let centroid = |points: &[Point2<Real>]| {
            points
                .iter()
                .zip(point_weights)
                .fold(Vector2::zeros(), |acc, (p, w)| acc + p.coords * *w)
                / total
        };
        let mean = &self.structure.base;
        let mean_centre = mean
            .iter()
            .zip(point_weights)
            .fold(Vector3::zeros(), |acc, (p, w)| acc + p.coords * *w)
            / total;
        let centred_mean: Vec<Point3<Real>> = mean.iter().map(|p| p - mean_centre).collect();
        let mut photos = Vec::with_capacity(views.len());
        for view in views {
            let centre = centroid(view);
            let points: Vec<Vector2<Real>> = view.iter().map(|p| p.coords - centre).collect();
            let flat: Vec<Point2<Real>> = points.iter().map(|p| Point2::from(*p)).collect();
            let start = crate::depth::closed_form_pose(&flat, &centred_mean, point_weights).ok_or(
                FaceError::Degenerate("seen in a photo whose points do not fix a pose"),
            )?;
            let pose = crate::depth::refine_pose(start, &flat, &centred_mean, point_weights);
            // The structure's origin sits where the mean face's centre projects minus its image.
            let seen = pose.rotation * mean_centre;
            photos.push(PhotoUnknowns {
                rotation: pose.rotation,
                relative_scale: 1.0,
                shift: -Vector2::new(seen.x, seen.y),
                expression: vec![0.0; expressions],
                targets: points.iter().map(|p| p / pose.scale).collect(),
                centre,
                unit: pose.scale,
                sees_gaps: false,
            });
        }
        Ok(photos)
    }
}

impl JointProblem {
    /// Levenberg–Marquardt from `weights` and `photos` (moved in place) with a backtracking
    /// search along each direction: the clamping of the expression weights makes a full step
    /// overshoot where a mode reaches a bound, and halving the step is far cheaper than a new
    /// direction. Returns the iterations run.
    fn minimise(&self, weights: &mut Vec<Real>, photos: &mut Vec<PhotoUnknowns>) -> usize {
        let mut cost = self.cost(weights, photos);
        let mut damping: Real = 1e-4;
        let mut iterations = 0;
        for _ in 0..100 {
            iterations += 1;
            let Some(direction) = self.step(weights, photos, damping) else {
                damping *= 10.0;
                if damping > 1e8 {
                    break;
                }
                continue;
            };
            let mut accepted = None;
            let mut alpha = 1.0;
            for _ in 0..6 {
                let (next_weights, next_photos) =
                    JointProblem::moved_along(weights, photos, &direction, alpha);
                let next_cost = self.cost(&next_weights, &next_photos);
                if next_cost.is_finite() && next_cost <= cost {
                    accepted = Some((next_weights, next_photos, next_cost));
                    break;
                }
                alpha /= 2.0;
            }
            match accepted {
                Some((next_weights, next_photos, next_cost)) => {
                    let decrease = cost - next_cost;
                    *weights = next_weights;
                    *photos = next_photos;
                    cost = next_cost;
                    if alpha == 1.0 {
                        damping = (damping / 10.0).max(1e-12);
                    }
                    // A relative decrease below 10⁻⁸ moves the weights in their sixth digit
                    // (measured on the bench's 35 photos); 10⁻¹⁰ took a tenth longer.
                    if decrease <= 1e-8 * cost.max(Real::MIN_POSITIVE) {
                        break;
                    }
                }
                None => {
                    damping *= 10.0;
                    if damping > 1e8 {
                        break;
                    }
                }
            }
        }
        iterations
    }
}

/// One photo's unknowns in [`FaceSpace::fit_photos`]. Its camera `x = o + s P R X` is
/// written `s = b s₀`, `o = x̄ + s₀ d` with `x̄` the view's weighted centroid and `s₀` the
/// scale of its starting pose (fixed), so that the residual of point `j`,
/// `rⱼ = b P R Xⱼ + d − (xⱼ − x̄)/s₀`, is measured in a fixed unit per photo (about a
/// canonical unit). A unit that followed the fitted scale would reward shrinking the face: the
/// scale and the face's size trade against each other exactly under these cameras, and only the
/// prior should decide the size.
#[derive(Clone)]
struct PhotoUnknowns {
    rotation: nalgebra::Rotation3<Real>,
    /// `b`.
    relative_scale: Real,
    /// `d`.
    shift: Vector2<Real>,
    expression: Vec<Real>,
    /// `(xⱼ − x̄)/s₀`.
    targets: Vec<Vector2<Real>>,
    /// `x̄`.
    centre: Vector2<Real>,
    /// `s₀`.
    unit: Real,
    /// Whether the photo's inner-lip gaps are among its targets (after the 40 points).
    sees_gaps: bool,
}

/// The constants of [`FaceSpace::fit_photos`]'s Levenberg–Marquardt iterations over all
/// unknowns at once (identity weights, and per photo its rotation, `b`, `d` and expression),
/// solved by eliminating each photo's unknowns (a Schur complement onto the identity weights).
/// The photos' shared expression `c` ([`ExpressionPrior::shared_sigma`]) follows the identity
/// weights in the state and is solved with them: a photo's prior couples its expression to
/// `c` only, so `c` joins the Schur complement (a diagonal block) and the photos stay apart.
///
/// A photo's normal-equation blocks between modes only involve `Rᵀ Pᵀ P R = I − n nᵀ` (`n` its
/// view direction, the rotation's third row), so they are `Σₐᵦ (δₐᵦ − nₐ nᵦ) Fₐᵦ` with
/// `Fₐᵦ = Σⱼ ωⱼ Dⱼ[a]ᵀ D'ⱼ[b]` over the modes' displacements, computed once per fit: a photo's
/// blocks then cost nine products per entry whatever the number of points ([`Products`]).
struct JointProblem {
    /// What the photos see of the identity: the 40 points, then the inner-lip gaps when they
    /// are fitted (`base` the mean face's, `modes` each identity mode's displacement).
    points: SpaceSamples,
    /// Each expression mode's displacement of [`JointProblem::points`].
    expressions: Vec<Vec<Vector3<Real>>>,
    /// `ωⱼ` of each of [`JointProblem::points`]: the 40 points' weights, then the gaps'.
    point_weights: Vec<Real>,
    /// `ε² / σₖ²` per identity mode.
    ridge: Vec<Real>,
    /// `ε² / τ²`.
    expression_ridge: Real,
    /// `ε² r`, the exponential prior's rate `r` on each expression weight.
    expression_push: Real,
    /// How many shared expression weights (the photos' expressions' prior centre) follow
    /// the identity weights in the state: the expression modes' count, or 0.
    shared: usize,
    /// `ε² / τₛ²`.
    shared_ridge: Real,
    /// `Fₐᵦ` identity × identity, expression × expression and expression × identity, over the
    /// 40 points and, apart, over the gaps (a photo without gaps takes the first only).
    identity_products: [Products; 2],
    expression_products: [Products; 2],
    cross_products: [Products; 2],
    /// The identity and expression modes' displacements of the points stacked, `3N × K` and
    /// `3N × L` (row `3j + a` is point `j`'s coordinate `a`): a photo's blocks against the
    /// pose are then one matrix product each.
    identity_stacked: DMatrix<Real>,
    expression_stacked: DMatrix<Real>,
}

/// The inner-lip gaps of a space ([`FaceSpace::fit_photos_with_lips`]): the mean face's and
/// each identity mode's, and each expression mode's (empty when the fit has no expressions).
struct GapSamples {
    identity: SpaceSamples,
    expressions: Vec<Vec<Vector3<Real>>>,
}

impl FaceSpace {
    /// The gaps of [`crate::structure::INNER_LIP_PAIRS`] on the space's `landmarks`, with the
    /// expressions' when `with_expressions`.
    fn lip_gap_samples(&self, landmarks: &SpaceSamples, with_expressions: bool) -> GapSamples {
        let gaps = |mode: &[Vector3<Real>]| inner_lip_gaps(|i| mode[i]).to_vec();
        GapSamples {
            identity: SpaceSamples {
                base: inner_lip_gaps(|i| landmarks.base[i].coords)
                    .map(Point3::from)
                    .to_vec(),
                modes: landmarks.modes.iter().map(|m| gaps(m)).collect(),
            },
            expressions: if with_expressions {
                self.expressions.landmarks.iter().map(|m| gaps(m)).collect()
            } else {
                Vec::new()
            },
        }
    }
}

impl JointProblem {
    fn new(
        space: &FaceSpace,
        expressions: &[Vec<Vector3<Real>>],
        gaps: Option<GapSamples>,
        point_weights: &[Real; POINT_COUNT],
        lip_weight: Real,
        noise: Real,
        prior: ExpressionPrior,
    ) -> Self {
        let mut points = space.structure.clone();
        let mut expressions = expressions.to_vec();
        let mut weights = point_weights.to_vec();
        if let Some(gaps) = gaps {
            points.base.extend(gaps.identity.base);
            for (mode, extra) in points.modes.iter_mut().zip(gaps.identity.modes) {
                mode.extend(extra);
            }
            for (mode, extra) in expressions.iter_mut().zip(gaps.expressions) {
                mode.extend(extra);
            }
            weights.extend([lip_weight; INNER_LIP_PAIRS.len()]);
        }
        let all = points.base.len();
        let products = |left: &[Vec<Vector3<Real>>], right: &[Vec<Vector3<Real>>]| {
            // Without gaps the second set has no entries (what `contracted_pair` skips).
            [0..POINT_COUNT, POINT_COUNT..all].map(|range| Products {
                rows: left.len(),
                entries: (0..if range.is_empty() { 0 } else { right.len() })
                    .flat_map(|m| {
                        let range = range.clone();
                        let weights = &weights;
                        (0..left.len()).map(move |l| {
                            std::array::from_fn(|ab| {
                                let (a, b) = (ab / 3, ab % 3);
                                range
                                    .clone()
                                    .map(|j| weights[j] * left[l][j][a] * right[m][j][b])
                                    .sum()
                            })
                        })
                    })
                    .collect(),
            })
        };
        let stacked = |modes: &[Vec<Vector3<Real>>]| {
            DMatrix::from_fn(3 * all, modes.len(), |row, k| modes[k][row / 3][row % 3])
        };
        JointProblem {
            identity_stacked: stacked(&points.modes),
            expression_stacked: stacked(&expressions),
            ridge: space.ridge(noise),
            expression_ridge: (noise / prior.sigma).powi(2),
            expression_push: noise * noise * prior.rate,
            shared: if prior.shared_sigma.is_some() {
                expressions.len()
            } else {
                0
            },
            shared_ridge: prior.shared_sigma.map_or(0.0, |t| (noise / t).powi(2)),
            identity_products: products(&points.modes, &points.modes),
            expression_products: products(&expressions, &expressions),
            cross_products: products(&expressions, &points.modes),
            point_weights: weights,
            points,
            expressions,
        }
    }

    /// Whether the fit sees inner-lip gaps.
    fn with_gaps(&self) -> bool {
        self.points.base.len() > POINT_COUNT
    }

    /// `ωⱼ` of point `j` in `photo` (a gap's is zero for a photo without gaps).
    fn weight(&self, photo: &PhotoUnknowns, j: usize) -> Real {
        if j < POINT_COUNT || photo.sees_gaps {
            self.point_weights[j]
        } else {
            0.0
        }
    }

    /// The identity's points moved by an expression.
    fn shape(&self, identity: &[Point3<Real>], expression: &[Real]) -> Vec<Point3<Real>> {
        let mut shape = identity.to_vec();
        for (e, mode) in expression.iter().zip(&self.expressions) {
            if *e != 0.0 {
                for (p, d) in shape.iter_mut().zip(mode) {
                    *p += d * *e;
                }
            }
        }
        shape
    }

    /// The photo's residuals for a shape, in its unit: the points', then the gaps' (which
    /// take no offset).
    fn residuals(&self, photo: &PhotoUnknowns, shape: &[Point3<Real>]) -> Vec<Vector2<Real>> {
        let rows = photo.rotation.matrix().fixed_rows::<2>(0) * photo.relative_scale;
        shape
            .iter()
            .zip(&photo.targets)
            .enumerate()
            .map(|(j, (x, y))| {
                if j < POINT_COUNT {
                    rows * x.coords + photo.shift - y
                } else {
                    rows * x.coords - y
                }
            })
            .collect()
    }

    /// The objective (times `ε²`).
    fn cost(&self, weights: &[Real], photos: &[PhotoUnknowns]) -> Real {
        let (weights, centre) = weights.split_at(self.ridge.len());
        let identity = self.points.member(weights);
        let mut cost: Real = weights
            .iter()
            .zip(&self.ridge)
            .map(|(w, r)| r * w * w)
            .sum::<Real>()
            + self.shared_ridge * centre.iter().map(|c| c * c).sum::<Real>();
        for photo in photos {
            if photo.relative_scale.is_nan() || photo.relative_scale <= 0.0 {
                return Real::INFINITY;
            }
            let shape = self.shape(&identity, &photo.expression);
            cost += self
                .residuals(photo, &shape)
                .iter()
                .enumerate()
                .map(|(j, r)| self.weight(photo, j) * r.norm_squared())
                .sum::<Real>();
            cost += photo
                .expression
                .iter()
                .enumerate()
                .map(|(l, e)| {
                    let c = centre.get(l).copied().unwrap_or(0.0);
                    self.expression_ridge * (e - c) * (e - c) + 2.0 * self.expression_push * e
                })
                .sum::<Real>();
        }
        cost
    }

    /// The damped Gauss–Newton direction from `weights` and `photos`; `None` when a system
    /// is not positive definite. Expression weights at a bound whose gradient points out of
    /// `[0, 1]` are held there; the others are clamped to it along the direction
    /// ([`JointProblem::moved_along`]).
    fn step(&self, weights: &[Real], photos: &[PhotoUnknowns], damping: Real) -> Option<Direction> {
        let k = weights.len();
        let modes = self.ridge.len();
        let centre = DVector::from_column_slice(&weights[modes..]);
        let identity = self.points.member(&weights[..modes]);
        let all = identity.len();
        // Σᵢ Mᵢ over every photo, and over the photos that see gaps.
        let mut summed = nalgebra::Matrix3::zeros();
        let mut summed_gaps = nalgebra::Matrix3::zeros();
        let mut rhs = DVector::from_iterator(
            k,
            weights[..modes]
                .iter()
                .zip(&self.ridge)
                .map(|(w, r)| r * w)
                .chain(centre.iter().map(|c| self.shared_ridge * c)),
        );
        // Per photo: its free expression modes, L⁻¹ and L⁻¹ [H_lw | g_l] (H = L Lᵀ).
        let mut eliminated = Vec::with_capacity(photos.len());
        let mut schur = DMatrix::<Real>::zeros(k, k);
        for photo in photos {
            let r = photo.rotation.matrix();
            let b = photo.relative_scale;
            let rows = r.fixed_rows::<2>(0) * b;
            let n = r.row(2).transpose();
            let m = (nalgebra::Matrix3::identity() - n * n.transpose()) * (b * b);
            summed += m;
            let m_gaps = if photo.sees_gaps {
                m
            } else {
                nalgebra::Matrix3::zeros()
            };
            summed_gaps += m_gaps;
            let shape = self.shape(&identity, &photo.expression);
            let residuals = self.residuals(photo, &shape);
            // pulled = [ωⱼ (b P R)ᵀ rⱼ]ⱼ and q = [ωⱼ ∂rⱼ/∂(δ, b, d)ᵀ (b P R)]ⱼ, stacked over the
            // points, give the gradients in the modes (stackedᵀ pulled) and the pose × mode
            // blocks (q stacked) as matrix products.
            let mut pulled = DVector::<Real>::zeros(3 * all);
            let mut q = DMatrix::<Real>::zeros(6, 3 * all);
            let mut h = DMatrix::<Real>::zeros(6, 6);
            let mut g_pose = nalgebra::Vector6::<Real>::zeros();
            for j in 0..all {
                let wj = self.weight(photo, j);
                if wj == 0.0 {
                    continue;
                }
                let x = shape[j].coords;
                // ∂r/∂(δ, b, d): −b P R [X]×, P R X, I (a gap takes no offset d).
                let jr = -(rows * x.cross_matrix());
                let mut jp = nalgebra::Matrix2x6::<Real>::zeros();
                jp.fixed_view_mut::<2, 3>(0, 0).copy_from(&jr);
                jp.set_column(3, &(rows * x / b));
                if j < POINT_COUNT {
                    jp[(0, 4)] = 1.0;
                    jp[(1, 5)] = 1.0;
                }
                let jpt = jp.transpose() * wj;
                h.fixed_view_mut::<6, 6>(0, 0).add_assign(&(jpt * jp));
                g_pose += jpt * residuals[j];
                pulled
                    .fixed_rows_mut::<3>(3 * j)
                    .copy_from(&(rows.transpose() * residuals[j] * wj));
                q.fixed_view_mut::<6, 3>(0, 3 * j).copy_from(&(jpt * rows));
            }
            rhs.rows_mut(0, modes)
                .gemv_tr(1.0, &self.identity_stacked, &pulled, 1.0);
            // The expression gradient decides which modes are free.
            let gradient = if self.expressions.is_empty() {
                DVector::zeros(0)
            } else {
                let mut offset = DVector::from_column_slice(&photo.expression);
                if self.shared > 0 {
                    offset -= &centre;
                    // The centre's gradient from this photo's prior.
                    rhs.rows_mut(modes, self.shared)
                        .axpy(-self.expression_ridge, &offset, 1.0);
                }
                self.expression_stacked.tr_mul(&pulled)
                    + offset * self.expression_ridge
                    + DVector::from_element(self.expressions.len(), self.expression_push)
            };
            let free: Vec<usize> = (0..self.expressions.len())
                .filter(|&l| {
                    let (e, g) = (photo.expression[l], gradient[l]);
                    !((e <= 0.0 && g > 0.0) || (e >= 1.0 && g < 0.0))
                })
                .collect();
            let local = 6 + free.len();
            let mut h = h.resize(local, local, 0.0);
            let mut hw = DMatrix::<Real>::zeros(local, k);
            hw.view_mut((0, 0), (6, modes))
                .gemm(1.0, &q, &self.identity_stacked, 0.0);
            let mut g = DVector::<Real>::zeros(local);
            g.fixed_rows_mut::<6>(0).copy_from(&g_pose);
            if !free.is_empty() {
                let free_columns = self.expression_stacked.select_columns(&free);
                let pose_expression = &q * &free_columns;
                h.view_mut((0, 6), (6, free.len())).copy_from(&pose_expression);
                h.view_mut((6, 0), (free.len(), 6))
                    .copy_from(&pose_expression.transpose());
                // The free modes' entries of Σₐᵦ Mₐᵦ Fₐᵦ.
                let m9 = [Products::flat(&m), Products::flat(&m_gaps)];
                for (f2, &l2) in free.iter().enumerate() {
                    for (f, &l) in free.iter().enumerate() {
                        h[(6 + f, 6 + f2)] = Products::contracted_pair(&self.expression_products, l, l2, &m9);
                    }
                }
                for col in 0..modes {
                    for (f, &l) in free.iter().enumerate() {
                        hw[(6 + f, col)] = Products::contracted_pair(&self.cross_products, l, col, &m9);
                    }
                }
                for (f, &l) in free.iter().enumerate() {
                    h[(6 + f, 6 + f)] += self.expression_ridge;
                    g[6 + f] = gradient[l];
                    if self.shared > 0 {
                        hw[(6 + f, modes + l)] = -self.expression_ridge;
                    }
                }
            }
            for d in 0..local {
                h[(d, d)] *= 1.0 + damping;
            }
            // With H = L Lᵀ and Y = L⁻¹ [H_lw | g]: the Schur complement loses Y_wᵀ Y_w and the
            // right-hand side Y_wᵀ Y_g; the photo's step is then −L⁻ᵀ (Y_g + Y_w Δw). L⁻¹ is
            // formed explicitly (small) so that the products run in the blocked kernel.
            let inverse = lower_inverse(&nalgebra::linalg::Cholesky::new(h)?.unpack());
            let mut stacked = DMatrix::<Real>::zeros(local, k + 1);
            stacked.columns_mut(0, k).copy_from(&hw);
            stacked.set_column(k, &g);
            let y = &inverse * &stacked;
            let product = y.columns(0, k).transpose() * &y;
            schur -= product.columns(0, k);
            rhs -= product.column(k);
            eliminated.push((free, inverse, y));
        }
        let summed9 = [Products::flat(&summed), Products::flat(&summed_gaps)];
        // The shared expression's block has no data term: only its prior, on the diagonal.
        let mut whole = DMatrix::from_fn(k, k, |a, b| {
            if a < modes && b < modes {
                Products::contracted_pair(&self.identity_products, a, b, &summed9)
            } else {
                0.0
            }
        });
        let centre_ridge = self.shared_ridge + photos.len() as Real * self.expression_ridge;
        for c in 0..k {
            let ridge = if c < modes { self.ridge[c] } else { centre_ridge };
            whole[(c, c)] = (whole[(c, c)] + ridge) * (1.0 + damping);
        }
        schur += whole;
        let step_w = -nalgebra::linalg::Cholesky::new(schur)?.solve(&rhs);
        let photos = eliminated
            .into_iter()
            .map(|(free, inverse, y)| {
                let v = y.column(k) + y.columns(0, k) * &step_w;
                (free, -(inverse.transpose() * v))
            })
            .collect();
        Some(Direction {
            weights: step_w,
            photos,
        })
    }

    /// The state `α` along `direction`, the expression weights clamped to `[0, 1]`.
    fn moved_along(
        weights: &[Real],
        photos: &[PhotoUnknowns],
        direction: &Direction,
        alpha: Real,
    ) -> (Vec<Real>, Vec<PhotoUnknowns>) {
        let next_weights = weights
            .iter()
            .zip(direction.weights.iter())
            .map(|(w, d)| w + alpha * d)
            .collect();
        let next_photos = photos
            .iter()
            .zip(&direction.photos)
            .map(|(photo, (free, step))| {
                let mut next = photo.clone();
                let turn = Vector3::new(step[0], step[1], step[2]) * alpha;
                next.rotation = photo.rotation * nalgebra::Rotation3::new(turn);
                next.relative_scale += alpha * step[3];
                next.shift += Vector2::new(step[4], step[5]) * alpha;
                for (f, &l) in free.iter().enumerate() {
                    next.expression[l] = (photo.expression[l] + alpha * step[6 + f]).clamp(0.0, 1.0);
                }
                next
            })
            .collect();
        (next_weights, next_photos)
    }
}

/// `Fₐᵦ = Σⱼ ωⱼ Dⱼ[a]ᵀ D'ⱼ[b]` for the nine `(a, b)`, stored entry by entry (column-major,
/// the nine values of an entry together) so that a contraction `Σₐᵦ Mₐᵦ Fₐᵦ` reads one
/// contiguous run per entry, and only the entries asked for.
struct Products {
    rows: usize,
    entries: Vec<[Real; 9]>,
}

impl Products {
    /// `M` row-major, as the entries hold `(a, b)` at `3a + b`.
    fn flat(m: &nalgebra::Matrix3<Real>) -> [Real; 9] {
        std::array::from_fn(|ab| m[(ab / 3, ab % 3)])
    }

    /// Entry `(row, col)` of `Σₐᵦ Mₐᵦ Fₐᵦ`.
    fn contracted(&self, row: usize, col: usize, m: &[Real; 9]) -> Real {
        let entry = &self.entries[col * self.rows + row];
        entry.iter().zip(m).map(|(f, m)| f * m).sum()
    }

    /// Entry `(row, col)` of `Σₐᵦ (M₀ₐᵦ F₀ₐᵦ + M₁ₐᵦ F₁ₐᵦ)` for products over two sets of
    /// points (the second skipped while it has no entries or `M₁` is zero).
    fn contracted_pair(pair: &[Products; 2], row: usize, col: usize, m: &[[Real; 9]; 2]) -> Real {
        let first = pair[0].contracted(row, col, &m[0]);
        if pair[1].entries.is_empty() || m[1] == [0.0; 9] {
            first
        } else {
            first + pair[1].contracted(row, col, &m[1])
        }
    }
}

/// The inverse of a lower-triangular matrix with a positive diagonal (forward substitution on
/// the identity, a column at a time).
fn lower_inverse(lower: &DMatrix<Real>) -> DMatrix<Real> {
    let n = lower.nrows();
    let mut inverse = DMatrix::<Real>::zeros(n, n);
    for col in 0..n {
        inverse[(col, col)] = 1.0 / lower[(col, col)];
        for row in col + 1..n {
            let mut sum = 0.0;
            for k in col..row {
                sum += lower[(row, k)] * inverse[(k, col)];
            }
            inverse[(row, col)] = -sum / lower[(row, row)];
        }
    }
    inverse
}

/// A Gauss–Newton step of [`JointProblem`]: the identity weights' change, and per photo its
/// free expression modes and the change of `(δ, b, d, e_free)`.
struct Direction {
    weights: DVector<Real>,
    photos: Vec<(Vec<usize>, DVector<Real>)>,
}

/// The largest change of any weight between two iterations.
fn largest_change(next: &[Real], previous: &[Real]) -> Real {
    next.iter()
        .zip(previous)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, Real::max)
}

/// Options of [`FaceSpace::fit_surface`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DenseFitOptions {
    /// The sample lattice's spacing, canonical units (default 1).
    pub spacing: Real,
    /// The fraction of farthest samples left out each iteration, in `[0, 0.9)` (default 0.1).
    pub trim: Real,
    /// The mesh's error per coordinate, its units (default 0.5).
    pub noise: Real,
    /// Iterations (default 15).
    pub iterations: usize,
}

impl Default for DenseFitOptions {
    fn default() -> Self {
        DenseFitOptions {
            spacing: 1.0,
            trim: 0.1,
            noise: 0.5,
            iterations: 15,
        }
    }
}

impl DenseFitOptions {
    fn validate(&self) -> Result<(), FaceError> {
        if !(self.spacing > 0.0 && self.spacing.is_finite()) {
            return FaceError::option("spacing", self.spacing, "positive and finite");
        }
        if !(0.0..0.9).contains(&self.trim) {
            return FaceError::option("trim", self.trim, "in [0, 0.9)");
        }
        if !(self.noise > 0.0 && self.noise.is_finite()) {
            return FaceError::option("noise", self.noise, "positive and finite");
        }
        Ok(())
    }
}

impl FaceSurface {
    /// A face whose surface was made on the reference's parametrisation some other way (a
    /// [`FaceSpace`] member), with its structure: transform the identity, deformation
    /// reported as affine, and a report of how far the surface passes from the structure.
    ///
    /// # Errors
    /// [`FaceError::PointCount`], [`FaceError::NonFinite`] for a bad structure;
    /// [`FaceError::Space`] for a surface on other knots than the reference's.
    pub fn from_surface(
        reference: &ReferenceFace,
        surface: BSplineSurface,
        structure: Vec<Point3<Real>>,
    ) -> Result<Self, FaceError> {
        super::check_structure(&structure)?;
        let own = reference.surface();
        if surface.knots_u() != own.knots_u() || surface.knots_v() != own.knots_v() {
            return Err(FaceError::Space(
                "the surface is not on the reference's knots".to_owned(),
            ));
        }
        let frame = *reference.frame();
        let params = super::structure_params(reference);
        let point_rms = super::point_rms(&surface, &params, &structure)?;
        Ok(FaceSurface {
            surface,
            frame,
            clip: reference.clip().to_vec(),
            structure,
            params,
            transform: nalgebra::Affine3::identity(),
            deformation: super::Deformation::Affine,
            report: DeformationReport {
                displacement_rms: 0.0,
                displacement_max: 0.0,
                point_rms,
            },
        })
    }
}
