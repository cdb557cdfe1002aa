//! A statistical face space on the reference's parametrisation: the reference surface plus
//! shape modes learnt from real faces, each carrying its displacement of the 40-point
//! structure and a prior standard deviation.

use nalgebra::{Point2, Point3, Similarity3, Vector3};

use super::{DeformationReport, FaceError, FaceSurface};
use crate::Real;
use crate::bspline::{BSplineSurface, SpaceSamples, SurfaceSpace};
use crate::depth::Pose;
use crate::mesh::{ClosestPoints, TriangleMesh, front_hits};
use crate::reference::ReferenceFace;
use crate::structure::{IBUG_POINT_COUNT, POINT_COUNT, from_ibug68};

/// A linear face space: the reference's surface and structure plus `K` modes,
///
/// ```text
/// F(w) = F₀ + Σₖ wₖ Dₖ,      S(w) = S₀ + Σₖ wₖ ΔSₖ,      wₖ ~ N(0, σₖ²)
/// ```
///
/// with `F₀`, `S₀` the reference's surface and structure, `Dₖ` a displacement spline on its
/// knots ([`SurfaceSpace`]) and `ΔSₖ` the same mode's displacement of the 40 points. The modes
/// come from per-vertex displacement fields of the scan the reference was fitted to
/// ([`FaceSpace::from_displacements`]), so a member is the face the scan becomes under those
/// displacements, seen through the reference's parametrisation.
#[derive(Debug, Clone, PartialEq)]
pub struct FaceSpace {
    surfaces: SurfaceSpace,
    structure: SpaceSamples,
    sigma: Vec<Real>,
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
    /// ([`from_ibug68`]).
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
        let vertices = scan.positions().len();
        let problem = |what: String| Err(FaceError::Space(what));
        if landmarks.len() != IBUG_POINT_COUNT || landmarks.iter().any(|&v| v >= vertices) {
            return problem(format!(
                "{} landmark vertex indices given for a scan of {vertices} vertices; need 68 valid ones",
                landmarks.len()
            ));
        }
        if sigma.len() != fields.len() {
            return problem(format!("{} deviations for {} modes", sigma.len(), fields.len()));
        }
        if let Some(k) = sigma.iter().position(|s| !(s.is_finite() && *s > 0.0)) {
            return problem(format!(
                "mode {k}: deviation {} must be positive and finite",
                sigma[k]
            ));
        }
        for (k, field) in fields.iter().enumerate() {
            if field.len() != vertices {
                return problem(format!(
                    "mode {k} has {} displacements for a scan of {vertices} vertices",
                    field.len()
                ));
            }
            if field.iter().any(|d| !d.iter().all(|c| c.is_finite())) {
                return problem(format!("mode {k} has a displacement that is not finite"));
            }
        }

        // The reference's sampling of its scan: the front-most surface over the frame.
        let frame = reference.frame();
        let options = reference.fit().options;
        let raster = frame.raster(options.sample_spacing);
        let mut hits = Vec::new();
        let mut params = Vec::new();
        for (index, hit) in front_hits(scan, &raster).into_iter().enumerate() {
            let Some(hit) = hit else { continue };
            let p = raster.position(index % raster.width, index / raster.width);
            let uv = frame.parameters(p.x, p.y);
            if (0.0..=1.0).contains(&uv.x)
                && (0.0..=1.0).contains(&uv.y)
                && reference.in_face_region(uv.x, uv.y)
            {
                params.push([uv.x, uv.y]);
                hits.push((hit, Point3::new(p.x, p.y, hit.height)));
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
        let base = reference.surface().eval_many(&params)?;
        let mut gaps: Vec<Real> = base.iter().zip(&hits).map(|(b, (_, p))| (b - p).norm()).collect();
        gaps.sort_unstable_by(Real::total_cmp);
        let median = gaps[gaps.len() / 2];
        if median > 10.0 * reference.fit().median + 1.0 {
            return problem(format!(
                "the scan lies {median:.2} units from the reference's surface (median; the fit's own median is {:.3}): it is not the scan the reference was fitted to, or not in its canonical frame",
                reference.fit().median
            ));
        }

        let mut surfaces = SurfaceSpace::new(reference.surface().clone(), Vec::new())?;
        let mut structure_modes = Vec::with_capacity(fields.len());
        for field in fields {
            let samples: Vec<Vector3<Real>> =
                hits.iter().map(|(hit, _)| hit.interpolate(scan, field)).collect();
            let (grid, _) = surfaces.fit_displacement(&params, &samples, options.smoothness)?;
            surfaces = surfaces.with_mode(grid)?;
            let ibug: Vec<Point3<Real>> = landmarks.iter().map(|&v| Point3::from(field[v])).collect();
            let moved = from_ibug68(&ibug).map_err(|e| FaceError::Space(e.to_string()))?;
            structure_modes.push(moved.into_iter().map(|p| p.coords).collect());
        }
        Ok(FaceSpace {
            surfaces,
            structure: SpaceSamples {
                base: reference.structure().to_vec(),
                modes: structure_modes,
            },
            sigma: sigma.to_vec(),
        })
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
        })
    }

    /// The space's modes as a reference stores them ([`ReferenceFace::with_space`]).
    pub fn to_modes(&self, note: &str) -> crate::reference::SpaceModes {
        crate::reference::SpaceModes {
            grid: self.surfaces.modes().to_vec(),
            structure: self.structure.modes.clone(),
            sigma: self.sigma.clone(),
            note: note.to_owned(),
        }
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

    /// Each mode's displacement of the 40 points (`[mode][point]`).
    pub fn structure_modes(&self) -> &[Vec<Vector3<Real>>] {
        &self.structure.modes
    }

    /// The first `k` modes only.
    pub fn truncated(&self, k: usize) -> Self {
        let k = k.min(self.mode_count());
        FaceSpace {
            surfaces: self.surfaces.truncated(k),
            structure: SpaceSamples {
                base: self.structure.base.clone(),
                modes: self.structure.modes[..k].to_vec(),
            },
            sigma: self.sigma[..k].to_vec(),
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
        let surface = self.surfaces.surface(weights)?;
        let structure = self.structure.member(weights);
        FaceSurface::from_surface(reference, surface, structure)
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

/// The joint fit of a [`FaceSpace`] to photos' 2D points, from [`FaceSpace::fit_photos`].
#[derive(Debug, Clone, PartialEq)]
pub struct PhotoSpaceFit {
    /// The identity weights shared by every photo.
    pub weights: Vec<Real>,
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
}

/// How many prior deviations a fitted weight may reach before [`FaceSpace::fit_photos`] holds
/// it there: a weight beyond 3σ is more likely the landmarks' error than the face (each mode's
/// prior puts 0.3% of faces there).
pub const PLAUSIBLE_SIGMAS: Real = 3.0;

impl FaceSpace {
    /// The MAP fit of the space to photos' 2D points under scaled orthographic cameras:
    /// identity weights `w` shared by all photos and a pose and offset per photo minimising
    ///
    /// ```text
    /// Σᵢ Σⱼ ωⱼ ‖oᵢ + sᵢ P Rᵢ S(w)ⱼ − xᵢⱼ‖² / (sᵢ² ε²)  +  Σₖ wₖ² / σₖ²
    /// ```
    ///
    /// (reprojection errors measured in canonical units, `ε` per coordinate), by alternating
    /// the poses (closed form, then Levenberg–Marquardt, on centred points) and the weights
    /// (linear, summed over the photos first, so that the cost does not grow with their number)
    /// until the weights settle; a weight beyond [`PLAUSIBLE_SIGMAS`] prior deviations is then
    /// held there ([`PhotoSpaceFit::held`]). `views[i]` are photo `i`'s 40 points with `y` up
    /// ([`crate::align::PhotoPoints::y_up`]).
    ///
    /// # Errors
    /// [`FaceError::Option`] for no views, a view without 40 finite points, a noise that is not
    /// positive or point weights that are negative or all zero; [`FaceError::Degenerate`]
    /// when a photo's pose is not determined; [`FaceError::Kernel`] when the weights are not.
    pub fn fit_photos(
        &self,
        views: &[Vec<Point2<Real>>],
        point_weights: &[Real; POINT_COUNT],
        noise: Real,
    ) -> Result<PhotoSpaceFit, FaceError> {
        let bad = |name: &'static str, value: String, expected: &'static str| {
            Err(FaceError::Option {
                name,
                value,
                expected,
            })
        };
        if views.is_empty() {
            return bad("views", "none".into(), "at least one photo");
        }
        if let Some(i) = views
            .iter()
            .position(|v| v.len() != POINT_COUNT || v.iter().any(|p| !(p.x.is_finite() && p.y.is_finite())))
        {
            return bad("view", i.to_string(), "40 finite points");
        }
        if !(noise > 0.0 && noise.is_finite()) {
            return bad("noise", noise.to_string(), "positive and finite");
        }
        let total: Real = point_weights.iter().sum();
        if point_weights.iter().any(|w| !(w.is_finite() && *w >= 0.0)) || total <= 0.0 {
            return bad(
                "point weight",
                format!("{point_weights:?}"),
                "finite, non-negative, not all zero",
            );
        }
        let centroid = |points: &[Point2<Real>]| {
            points
                .iter()
                .zip(point_weights)
                .fold(nalgebra::Vector2::zeros(), |acc, (p, w)| acc + p.coords * *w)
                / total
        };
        let ridge = self.ridge(noise);
        let mut weights = vec![0.0; self.mode_count()];
        let mut poses = vec![
            (
                Pose::from_yaw_pitch_roll_degrees(0.0, 0.0, 0.0, 1.0),
                Point2::origin()
            );
            views.len()
        ];
        let mut iterations = 0;
        for iteration in 0..100 {
            iterations = iteration + 1;
            // Poses for the current shape, on centred points (the offset is then closed form).
            let shape = self.structure.member(&weights);
            let shape_centre = shape
                .iter()
                .zip(point_weights)
                .fold(Vector3::zeros(), |acc, (p, w)| acc + p.coords * *w)
                / total;
            let centred: Vec<Point3<Real>> = shape.iter().map(|p| p - shape_centre).collect();
            for (view, pose) in views.iter().zip(poses.iter_mut()) {
                let view_centre = centroid(view);
                let flat: Vec<Point2<Real>> = view.iter().map(|p| p - view_centre).collect();
                let start = if iteration == 0 {
                    crate::depth::closed_form_pose(&flat, &centred, point_weights).ok_or(
                        FaceError::Degenerate("seen in a photo whose points do not fix a pose"),
                    )?
                } else {
                    pose.0
                };
                let refined = crate::depth::refine_pose(start, &flat, &centred, point_weights);
                let projected_centre = refined.project(&Point3::from(shape_centre));
                pose.0 = refined;
                pose.1 = Point2::from(view_centre - projected_centre.coords);
            }
            // Weights for the poses. With every photo's residual in canonical units,
            // rᵢⱼ = P Rᵢ S(w)ⱼ − (xᵢⱼ − oᵢ)/sᵢ, the normal equations only need, per point,
            // Mⱼ-free sums over the photos: Σᵢ Rᵢᵀ Pᵀ P Rᵢ (one 3 × 3 matrix for all points) and
            // Σᵢ Rᵢᵀ Pᵀ (xᵢⱼ − oᵢ)/sᵢ (one vector per point), so that the cost does not grow
            // with the number of photos.
            let mut m = nalgebra::Matrix3::<Real>::zeros();
            let mut pulled = vec![Vector3::<Real>::zeros(); POINT_COUNT];
            for (view, (pose, offset)) in views.iter().zip(&poses) {
                let r = pose.rotation.matrix();
                let rows = r.fixed_rows::<2>(0);
                m += rows.transpose() * rows;
                for j in 0..POINT_COUNT {
                    let x = (view[j] - offset) / pose.scale;
                    pulled[j] += rows.transpose() * x;
                }
            }
            let k = self.mode_count();
            let base = &self.structure.base;
            let modes = &self.structure.modes;
            let mut normal = nalgebra::DMatrix::<Real>::zeros(k, k);
            let mut rhs = nalgebra::DVector::<Real>::zeros(k);
            for j in 0..POINT_COUNT {
                let wj = point_weights[j];
                if wj == 0.0 {
                    continue;
                }
                let residual = pulled[j] - m * base[j].coords;
                let mapped: Vec<Vector3<Real>> = modes.iter().map(|mode| m * mode[j]).collect();
                for a in 0..k {
                    rhs[a] += wj * modes[a][j].dot(&residual);
                    for b in a..k {
                        normal[(a, b)] += wj * modes[a][j].dot(&mapped[b]);
                    }
                }
            }
            for a in 0..k {
                for b in 0..a {
                    normal[(a, b)] = normal[(b, a)];
                }
                normal[(a, a)] += ridge[a];
            }
            let next = crate::bspline::solve_normal_equations(normal, &rhs)?;
            let change = largest_change(&next, &weights);
            weights = next;
            if change < 1e-7 {
                break;
            }
        }
        // Weights outside the prior's plausible range are held at its edge, and named.
        let mut held = Vec::new();
        for (k, (w, sigma)) in weights.iter_mut().zip(&self.sigma).enumerate() {
            let limit = PLAUSIBLE_SIGMAS * sigma;
            if w.abs() > limit {
                *w = w.clamp(-limit, limit);
                held.push(k);
            }
        }
        let shape = self.structure.member(&weights);
        let rms_units = views
            .iter()
            .zip(&poses)
            .map(|(view, (pose, offset))| {
                let sum: Real = view
                    .iter()
                    .zip(&shape)
                    .zip(point_weights)
                    .map(|((x, p), w)| w * ((offset + pose.project(p).coords) - x).norm_squared())
                    .sum();
                (sum / total).sqrt() / pose.scale
            })
            .collect();
        Ok(PhotoSpaceFit {
            weights,
            poses,
            rms_units,
            iterations,
            held,
        })
    }
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
        let bad = |name, value: Real, expected| {
            Err(FaceError::Option {
                name,
                value: value.to_string(),
                expected,
            })
        };
        if !(self.spacing > 0.0 && self.spacing.is_finite()) {
            return bad("spacing", self.spacing, "positive and finite");
        }
        if !(0.0..0.9).contains(&self.trim) {
            return bad("trim", self.trim, "in [0, 0.9)");
        }
        if !(self.noise > 0.0 && self.noise.is_finite()) {
            return bad("noise", self.noise, "positive and finite");
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
        let flat: Vec<[Real; 2]> = params.iter().map(|p| [p.x, p.y]).collect();
        let on_surface = surface.eval_many(&flat)?;
        let point_rms = (on_surface
            .iter()
            .zip(&structure)
            .map(|(a, b)| (a - b).norm_squared())
            .sum::<Real>()
            / POINT_COUNT as Real)
            .sqrt();
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
