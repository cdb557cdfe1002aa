//! Shared by the programs in `tools/`: a seeded random generator and ICT-FaceKit subjects.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use nalgebra::{Point3, Similarity3};
use splineface::Real;
use splineface::face::{DenseFitOptions, FaceSpace, SpaceFit};
use splineface::landmarks::read_vertex_indices;
use splineface::mesh::{TriangleMesh, read_mesh};
use splineface::reference::ReferenceFace;
use splineface::structure::{IBUG_POINT_COUNT, from_ibug68, unify};

pub use splineface::random::Lcg;

/// The face space's fit to a scan's own 3D landmarks: its noise per coordinate, mm, and the
/// contour points' weight, chosen by the sweep `tools/face_space.rs` prints. Small ε follows
/// the landmarks: best on ICT identities, whose landmarks are the space's own vertices (0.38×
/// at 0.5 mm), but on the real scan, whose landmarks were placed by other hands, it fits their
/// definition differences into the shape (2.1× the mean face's error). 4 mm is the smallest
/// that keeps the real scan below the mean face (0.90×) and still gives 0.63× on ICT
/// identities (`tools/results/face-space.md`).
pub const LANDMARK_NOISE: Real = 4.0;
pub const CONTOUR_WEIGHT: Real = 1.0;

/// The space's MAP fit to a scan's own 3D landmarks ([`LANDMARK_NOISE`], [`CONTOUR_WEIGHT`]).
pub fn space_fit_to_landmarks(space: &FaceSpace, structure: &[Point3<Real>]) -> Result<SpaceFit> {
    Ok(space.fit_structure(
        structure,
        &splineface::structure::contour_weighted(CONTOUR_WEIGHT),
        LANDMARK_NOISE,
    )?)
}

/// The space fitted densely to a scan (every point of its surface, from its landmark fit
/// `start`; `DenseFitOptions::default`): the best the space can do for that face, its ceiling.
pub fn space_fit_densely(
    space: &FaceSpace,
    reference: &ReferenceFace,
    truth: &TriangleMesh,
    start: &SpaceFit,
) -> Result<SpaceFit> {
    Ok(space.fit_surface(reference, truth, start, &DenseFitOptions::default())?)
}

/// The ICT-FaceKit data (`../shared/data/ict-face`): the neutral face, its 68 landmark
/// vertices and the identity modes.
pub struct Ict {
    pub neutral: TriangleMesh,
    pub landmarks: Vec<usize>,
    pub identities: Vec<f32>,
    pub modes: usize,
    /// Expression blendshape offsets, `[expression][vertex][3]`, and their names.
    pub expressions: Vec<f32>,
    pub expression_names: Vec<String>,
}

/// A subject drawn from the ICT identity space, unified into the canonical frame.
pub struct Subject {
    /// The face mesh, canonical frame (50 units between the eye centres).
    pub mesh: TriangleMesh,
    /// Its 40-point structure, canonical frame.
    pub structure: Vec<Point3<Real>>,
    /// From the data's centimetres to the canonical frame.
    pub to_canonical: Similarity3<Real>,
}

impl Ict {
    /// The default location, relative to the repository.
    pub fn default_dir() -> PathBuf {
        PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../shared/data/ict-face"))
    }

    pub fn load(dir: &Path) -> Result<Self> {
        let neutral = read_mesh(&dir.join("neutral_face.obj"))?;
        let landmarks = read_vertex_indices(
            &dir.join("landmarks68.txt"),
            IBUG_POINT_COUNT,
            neutral.positions().len(),
        )?;
        let path = dir.join("identities.f32");
        let bytes = std::fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
        let per_mode = neutral.positions().len() * 3;
        if bytes.len() % (4 * per_mode) != 0 {
            bail!(
                "{}: {} bytes is not a whole number of modes",
                path.display(),
                bytes.len()
            );
        }
        let identities: Vec<f32> = bytes
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        let modes = identities.len() / per_mode;
        let read_f32 = |name: &str| -> Result<Vec<f32>> {
            let path = dir.join(name);
            let bytes = std::fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
            if bytes.len() % (4 * per_mode) != 0 {
                bail!(
                    "{}: {} bytes is not a whole number of shapes",
                    path.display(),
                    bytes.len()
                );
            }
            Ok(bytes
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect())
        };
        let expressions = read_f32("expressions.f32")?;
        let names_path = dir.join("expressions.txt");
        let expression_names = std::fs::read_to_string(&names_path)
            .with_context(|| format!("reading {}", names_path.display()))?
            .lines()
            .map(|l| l.trim().to_owned())
            .filter(|l| !l.is_empty())
            .collect();
        Ok(Ict {
            neutral,
            landmarks,
            identities,
            modes,
            expressions,
            expression_names,
        })
    }

    /// `neutral + Σ wₖ·identityₖ + Σ e·expression(name)`, unified by its structure.
    pub fn subject_with_expression(&self, weights: &[Real], expression: &[(&str, Real)]) -> Result<Subject> {
        let offsets: Vec<Real> = self
            .offsets(weights, expression)?
            .iter()
            .flat_map(|o| [o.x, o.y, o.z])
            .collect();
        self.unified(&offsets)
    }

    /// `Σₖ wₖ·identityₖ + Σ e·expression(name)` per vertex, the data's frame and centimetres.
    pub fn offsets(
        &self,
        weights: &[Real],
        expression: &[(&str, Real)],
    ) -> Result<Vec<nalgebra::Vector3<Real>>> {
        let n = self.neutral.positions().len();
        let mut offsets = vec![nalgebra::Vector3::zeros(); n];
        let mut add = |data: &[f32], w: Real| {
            for (o, m) in offsets.iter_mut().zip(data.chunks_exact(3)) {
                *o += w * nalgebra::Vector3::new(Real::from(m[0]), Real::from(m[1]), Real::from(m[2]));
            }
        };
        for (k, &w) in weights.iter().enumerate().take(self.modes) {
            add(&self.identities[k * n * 3..(k + 1) * n * 3], w);
        }
        for (name, w) in expression {
            let k = self
                .expression_names
                .iter()
                .position(|e| e == name)
                .with_context(|| format!("no expression {name}"))?;
            add(&self.expressions[k * n * 3..(k + 1) * n * 3], *w);
        }
        Ok(offsets)
    }

    /// `neutral + Σₖ wₖ·identityₖ` in the data's own frame and centimetres.
    pub fn positions(&self, weights: &[Real]) -> Vec<Point3<Real>> {
        self.positions_with_expression(weights, &[])
            .expect("no expression names to look up")
    }

    /// `neutral + Σₖ wₖ·identityₖ + Σ e·expression(name)` in the data's frame and centimetres.
    pub fn positions_with_expression(
        &self,
        weights: &[Real],
        expression: &[(&str, Real)],
    ) -> Result<Vec<Point3<Real>>> {
        Ok(self
            .neutral
            .positions()
            .iter()
            .zip(self.offsets(weights, expression)?)
            .map(|(p, o)| p + o)
            .collect())
    }

    fn unified(&self, offsets: &[Real]) -> Result<Subject> {
        let positions: Vec<Point3<Real>> = self
            .neutral
            .positions()
            .iter()
            .enumerate()
            .map(|(i, p)| p + nalgebra::Vector3::new(offsets[3 * i], offsets[3 * i + 1], offsets[3 * i + 2]))
            .collect();
        let mesh = TriangleMesh::new(positions, self.neutral.triangles().to_vec())?;
        let ibug: Vec<Point3<Real>> = self.landmarks.iter().map(|&i| mesh.positions()[i]).collect();
        let structure = from_ibug68(&ibug)?;
        let (to_canonical, structure) = unify(&structure)?;
        let mesh = mesh.transformed(&nalgebra::Affine3::from_matrix_unchecked(
            to_canonical.to_homogeneous(),
        ));
        Ok(Subject {
            mesh,
            structure,
            to_canonical,
        })
    }

    /// The identity modes `0..count` as a face space on `reference`, which must have been
    /// fitted to the mean face (the embedded one is, and so is its `as_seen_in_photos()`
    /// form, whose structure is the photo structure). Every mode's deviation is 1 (the
    /// data's identities are `w ~ N(0, 1)`). No expressions ([`Ict::with_expressions`]).
    pub fn face_space(
        &self,
        reference: &splineface::reference::ReferenceFace,
        count: usize,
    ) -> Result<splineface::face::FaceSpace> {
        let (scan, to_canonical) = self.canonical_scan()?;
        let fields = self.fields(&self.identities, 0..count.min(self.modes), &to_canonical);
        let sigma = vec![1.0; fields.len()];
        Ok(splineface::face::FaceSpace::from_displacements(
            reference,
            &scan,
            &self.landmarks,
            &fields,
            &sigma,
        )?)
    }

    /// `space` (on `reference`, as [`Ict::face_space`]) with all of ICT's expression
    /// blendshapes as its expression modes.
    pub fn with_expressions(
        &self,
        space: splineface::face::FaceSpace,
        reference: &splineface::reference::ReferenceFace,
    ) -> Result<splineface::face::FaceSpace> {
        let (scan, to_canonical) = self.canonical_scan()?;
        let fields = self.fields(&self.expressions, 0..self.expression_names.len(), &to_canonical);
        let note = "The 53 expression blendshapes of ICT-FaceKit (Copyright (c) 2020 USC Institute for Creative \
                    Technologies, MIT licence), each a per-vertex displacement of the mean face at full strength \
                    carried to this grid by tools/face_space --write.";
        Ok(space.with_expression_displacements(
            reference,
            &scan,
            &self.landmarks,
            &self.expression_names,
            &fields,
            note,
        )?)
    }

    /// The mean face in the canonical frame, and the map into it.
    fn canonical_scan(&self) -> Result<(TriangleMesh, nalgebra::Similarity3<Real>)> {
        let ibug: Vec<Point3<Real>> = self
            .landmarks
            .iter()
            .map(|&i| self.neutral.positions()[i])
            .collect();
        let (to_canonical, _) = unify(&from_ibug68(&ibug)?)?;
        let scan = self
            .neutral
            .transformed(&nalgebra::Affine3::from_matrix_unchecked(
                to_canonical.to_homogeneous(),
            ));
        Ok((scan, to_canonical))
    }

    /// The displacement fields `modes` of `data` (`[mode][vertex][3]`) in the canonical frame.
    fn fields(
        &self,
        data: &[f32],
        modes: std::ops::Range<usize>,
        to_canonical: &nalgebra::Similarity3<Real>,
    ) -> Vec<Vec<nalgebra::Vector3<Real>>> {
        let n = self.neutral.positions().len();
        modes
            .map(|k| {
                data[k * n * 3..(k + 1) * n * 3]
                    .chunks_exact(3)
                    .map(|m| {
                        to_canonical
                            * nalgebra::Vector3::new(Real::from(m[0]), Real::from(m[1]), Real::from(m[2]))
                    })
                    .collect()
            })
            .collect()
    }

    /// `neutral + Σₖ wₖ·modeₖ`, unified by its structure; `weights` may be shorter than the
    /// modes (the rest are 0).
    pub fn subject(&self, weights: &[Real]) -> Result<Subject> {
        self.subject_with_expression(weights, &[])
    }

    /// A random identity with `w ~ N(0, scale²)` on every mode.
    pub fn random_subject(&self, rng: &mut Lcg, scale: Real) -> Result<Subject> {
        let weights: Vec<Real> = (0..self.modes).map(|_| scale * rng.gaussian()).collect();
        self.subject(&weights)
    }
}

/// The 68 landmarks of a face seen from `view`, as a landmarker places them: the landmark
/// vertices, except the jaw points off the chin (iBUG 0–5 and 11–16), which a landmarker puts
/// on the face's visible outline at their height. For such a point, the candidates are the
/// mesh's vertices on its side of the face within `band` of its height (face frame), no
/// farther out than the landmark vertex and in front of it; the one seen farthest toward that
/// side (along the face's horizontal axis in the view) is the point on the outline. On a
/// frontal view that is close to the landmark vertex; on the side turned away it moves in
/// toward the nose, as the occluding contour does (eos's contour fitting models the same
/// behaviour).
pub fn landmarks_in_view(
    mesh: &TriangleMesh,
    landmarks: &[usize],
    view: &splineface::render::View,
    band: Real,
) -> Vec<Point3<Real>> {
    let positions = mesh.positions();
    let eyes = |side: std::ops::Range<usize>| {
        let n = side.len() as Real;
        Point3::from(
            side.map(|k| positions[landmarks[k]].coords)
                .sum::<nalgebra::Vector3<Real>>()
                / n,
        )
    };
    let axis = {
        let (right, left) = (view.apply(&eyes(36..42)), view.apply(&eyes(42..48)));
        (left - right).xy().normalize()
    };
    (0..landmarks.len())
        .map(|k| {
            let vertex = positions[landmarks[k]];
            if !(k <= 5 || (11..=16).contains(&k)) {
                return vertex;
            }
            let side = vertex.x.signum();
            let outward = |p: &Point3<Real>| side * view.apply(p).xy().coords.dot(&axis);
            positions
                .iter()
                .filter(|p| {
                    (p.y - vertex.y).abs() <= band
                        && p.x * side >= 0.0
                        && p.x.abs() <= vertex.x.abs()
                        && p.z >= vertex.z - band
                })
                .copied()
                .max_by(|a, b| outward(a).total_cmp(&outward(b)))
                .unwrap_or(vertex)
        })
        .collect()
}
