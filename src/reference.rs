//! The reference face: a cubic control grid fitted once to reference scans, with the reference
//! 40-point structure, its edges and the face-region clip boundary. The surface stage deforms
//! it by the transform from this structure to an estimated one.
//!
//! # How a reference is built ([`build_reference`])
//!
//! 1. Each scan is unified into the canonical frame by its 40-point structure (eye centres at
//!    `(±25, 0, 0)`, `+z` toward the viewer); the reference structure is the mean of the
//!    unified structures.
//! 2. The face region is the polygon of the structure's contour (9 points, ear to ear under
//!    the chin) closed over its brows lifted by `brow_lift` units, grown by `margin` about its
//!    centroid. Its bounding box is the parameter domain: `u = (x − x₀)/(x₁ − x₀)`,
//!    `v = (y − y₀)/(y₁ − y₀)` (the frontal parametrisation of the paper).
//! 3. Every scan's front-most surface is rasterised over the box at `sample_spacing`
//!    ([`crate::mesh::front_heights`]); the samples are the mean heights where every scan has
//!    surface. Only the front-most surface is fitted: a scan's hidden parts (interior shells,
//!    the inside of the mouth, the back of the head) and the undersides of overhangs have no
//!    place on a frontal height field, and fitting them folds the surface.
//! 4. A clamped uniform cubic grid is fitted to the samples by [`SurfaceFit`] with a small
//!    thin-plate term, so that parts of the box without samples stay defined.
//!
//! The residuals are reported for all samples and for those inside the face region, in
//! canonical units (50 between the eye centres).
//!
//! # The file ([`ReferenceFace::to_json`])
//!
//! ```json
//! {
//!   "format": "splineface/reference",
//!   "version": 5,
//!   "surface": { …a splineface/bspline-surface… },
//!   "structure": [[x, y, z], …40],
//!   "photo_structure": { "points": [[x, y, z], …40], "note": "…" },   // optional, v2+
//!   "space": {                                                       // optional, v3+
//!     "modes": K, "sigma": [σ, …K], "structure": [[[dx, dy, dz], …40], …K],
//!     "grid_encoding": "f32le-base64", "grid": "…K × rows·cols × 3 floats…", "note": "…",
//!     "expressions": {                                               // optional, v4+
//!       "names": ["jawOpen", …L], "structure": [[[dx, dy, dz], …40], …L],
//!       "grid_encoding": "f32le-base64", "grid": "…", "note": "…",
//!       "landmarks": "…L × 68 × 3 floats…"                           // optional, v5+
//!     },
//!     "landmark_base": [[x, y, z], …68],                             // optional, v5+
//!     "landmarks": "…K × 68 × 3 floats…"                             // with it
//!   },
//!   "edges": [[i, j], …],
//!   "frame": { "x": [x0, x1], "y": [y0, y1] },
//!   "clip": [[u, v], …],
//!   "fit": { …ReferenceFit… },
//!   "provenance": { "program": "…", "sources": [ … ], "note": "…" }
//! }
//! ```
//!
//! Numbers are written in their shortest exact form, so the round trip is exact; reading
//! validates everything (40 finite points, edges in range, a clip polygon inside the domain).

use std::sync::OnceLock;

use nalgebra::{Point2, Point3, Vector3};
use serde::{Deserialize, Serialize};

use crate::Real;
use crate::bspline::{BSplineError, BSplineSurface, KnotVector, SurfaceFit, SurfaceSpace};
use crate::geometry::{bounding_box, polygon_contains};
use crate::mesh::{Raster, TriangleMesh, front_heights};
use crate::structure::{self, IBUG_POINT_COUNT, POINT_COUNT, StructureError, delaunay_edges, unify};

/// How a reference is fitted.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReferenceOptions {
    /// Control points along each side of the cubic grid.
    pub grid: usize,
    /// The thin-plate weight λ of [`SurfaceFit::smoothness`].
    pub smoothness: Real,
    /// The distance between frontal samples, in canonical units.
    pub sample_spacing: Real,
    /// How far above the brows the face region reaches, in canonical units.
    pub brow_lift: Real,
    /// The factor by which the clip region is grown about its centroid, beyond the fitted
    /// region.
    pub margin: Real,
    /// The factor by which the fitted region is grown: samples outside it are left out of the
    /// fit (beyond the jaw line a frontal view looks down a cliff onto the neck, and beside the
    /// cheeks onto the ears; a smooth surface cannot follow a cliff, and trying rings over the
    /// whole face).
    pub fit_margin: Real,
}

impl ReferenceOptions {
    /// Checks every option's range (the grid 4 to 256, the weights and spacings finite and in
    /// range), so callers can refuse bad settings before reading any scan.
    ///
    /// # Errors
    /// [`ReferenceError::Option`] naming the first option out of range.
    pub fn validate(&self) -> Result<(), ReferenceError> {
        if !(4..=256).contains(&self.grid) {
            return Err(ReferenceError::Option {
                name: "grid",
                value: self.grid.to_string(),
                expected: "4 to 256 control points a side",
            });
        }
        check_option("smoothness", self.smoothness, self.smoothness >= 0.0, "≥ 0")?;
        check_option(
            "sample spacing",
            self.sample_spacing,
            self.sample_spacing > 0.0,
            "> 0 canonical units",
        )?;
        check_option(
            "brow lift",
            self.brow_lift,
            self.brow_lift >= 0.0,
            "≥ 0 canonical units",
        )?;
        check_option(
            "margin",
            self.margin,
            (1.0..=3.0).contains(&self.margin),
            "1 to 3",
        )?;
        check_option(
            "fit margin",
            self.fit_margin,
            (0.5..=self.margin).contains(&self.fit_margin),
            "0.5 to the clip margin",
        )?;
        Ok(())
    }
}

impl Default for ReferenceOptions {
    /// The options the project's default reference was built with; the grid size and λ were
    /// chosen by measurement (see `reference/README.md`).
    fn default() -> Self {
        Self {
            grid: 32,
            smoothness: 1e-10,
            sample_spacing: 0.5,
            brow_lift: 20.0,
            margin: 1.05,
            fit_margin: 1.0,
        }
    }
}

/// Where one scan of a reference came from.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReferenceSource {
    /// The scan's file name.
    pub mesh: String,
    /// The FNV-1a 64-bit hash of the scan file's bytes, in hex: which version of it was used.
    pub mesh_fnv1a64: String,
    /// The landmark file's name.
    pub landmarks: String,
    /// The scan's vertex count.
    pub vertices: usize,
    /// The scan's triangle count.
    pub triangles: usize,
}

/// How a reference was made.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Provenance {
    /// The program and version that built it.
    pub program: String,
    /// The scans, in input order.
    pub sources: Vec<ReferenceSource>,
    /// Free text: licence, origin.
    pub note: String,
}

/// The fit of a reference: its options and residuals, the distances between the samples and
/// the surface at their parameters, in canonical units. (At a steep wall, such as the underside
/// of the nose seen from the front, this parametric distance is much larger than the distance
/// to the nearest surface point.)
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReferenceFit {
    /// The options used.
    pub options: ReferenceOptions,
    /// Frontal samples fitted.
    pub samples: usize,
    /// RMS distance.
    pub rms: Real,
    /// The largest distance.
    pub max: Real,
    /// Where the largest distance occurs (the sample, canonical frame).
    pub max_at: Point3<Real>,
    /// The median distance.
    pub median: Real,
    /// The 95th percentile of the distances.
    pub p95: Real,
}

/// The frontal box the parameters span: `u = (x − x[0])/(x[1] − x[0])`, likewise `v` from `y`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FrontalFrame {
    /// `x` at `u = 0` and `u = 1`.
    pub x: [Real; 2],
    /// `y` at `v = 0` and `v = 1`.
    pub y: [Real; 2],
}

impl FrontalFrame {
    /// The parameters of the frontal position `(x, y)`.
    pub fn parameters(&self, x: Real, y: Real) -> Point2<Real> {
        Point2::new(
            (x - self.x[0]) / (self.x[1] - self.x[0]),
            (y - self.y[0]) / (self.y[1] - self.y[0]),
        )
    }

    /// The frontal position of the parameters `(u, v)`.
    pub fn position(&self, u: Real, v: Real) -> Point2<Real> {
        Point2::new(
            self.x[0] + u * (self.x[1] - self.x[0]),
            self.y[0] + v * (self.y[1] - self.y[0]),
        )
    }

    /// Samples every `spacing` over the box from its lower corner: how a reference samples its
    /// scans ([`build_reference`]) and how modes are carried onto it
    /// ([`crate::face::FaceSpace::from_displacements`]). The counts saturate for absurdly
    /// small spacings; callers bound them.
    pub fn raster(&self, spacing: Real) -> Raster {
        Raster {
            origin: Point2::new(self.x[0], self.y[0]),
            spacing,
            width: (((self.x[1] - self.x[0]) / spacing).floor() + 1.0) as usize,
            height: (((self.y[1] - self.y[0]) / spacing).floor() + 1.0) as usize,
        }
    }
}

/// A reference face (see the module documentation).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "RawReference", into = "RawReference")]
pub struct ReferenceFace {
    surface: BSplineSurface,
    structure: Vec<Point3<Real>>,
    photo_structure: Option<PhotoStructure>,
    space: Option<SpaceModes>,
    edges: Vec<[usize; 2]>,
    frame: FrontalFrame,
    clip: Vec<Point2<Real>>,
    fit: ReferenceFit,
    provenance: Provenance,
}

/// A face space's modes as a reference carries them (see [`crate::face::FaceSpace`]): per
/// mode, its displacement of the control grid, of the 40 points and (since format version 5,
/// optionally) of the scan's 68 iBUG landmarks, and its prior standard deviation. Grid and
/// landmark displacements are stored as little-endian `f32` in base64 (a 32 × 32 grid with 60
/// modes is 0.7 MB of floats; as JSON numbers it would be five times that), and kept at `f32`
/// precision in memory too, so that writing and reading back is exact.
#[derive(Debug, Clone, PartialEq)]
pub struct SpaceModes {
    /// `grid[k]`: mode `k`'s displacement of every control point, row-major.
    pub grid: Vec<Vec<Vector3<Real>>>,
    /// `structure[k]`: mode `k`'s displacement of the 40 points.
    pub structure: Vec<Vec<Vector3<Real>>>,
    /// Each mode's prior standard deviation.
    pub sigma: Vec<Real>,
    /// Where the modes came from (data, licence).
    pub note: String,
    /// The expression modes, if any (empty for none).
    pub expressions: ExpressionModes,
    /// The 68 iBUG landmarks of the reference's scan (its landmark vertices, canonical frame),
    /// or empty when the space does not carry them (format versions 3 and 4). With them,
    /// [`SpaceModes::landmarks`] and [`ExpressionModes::landmarks`] say how every mode moves
    /// them: what a fit needs for points beyond the 40 (the inner lips, which show an open
    /// mouth, [`crate::structure::INNER_LIP_PAIRS`]).
    pub landmark_base: Vec<Point3<Real>>,
    /// `landmarks[k]`: mode `k`'s displacement of the 68 iBUG landmarks (empty without
    /// [`SpaceModes::landmark_base`]). Stored like the grid, as `f32`.
    pub landmarks: Vec<Vec<Vector3<Real>>>,
}

/// A face space's expression modes (blendshapes): per mode, its name and its displacement of
/// the control grid and of the 40 points at full strength. An expression's weight lies in
/// `[0, 1]` (0 neutral, 1 the full expression); unlike an identity mode it has no Gaussian
/// prior of its own, the fit chooses one ([`crate::face::PhotoFitOptions`]). Stored like the
/// identity modes.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ExpressionModes {
    /// Each mode's name (e.g. `jawOpen`), unique.
    pub names: Vec<String>,
    /// `grid[k]`: mode `k`'s displacement of every control point, row-major.
    pub grid: Vec<Vec<Vector3<Real>>>,
    /// `structure[k]`: mode `k`'s displacement of the 40 points.
    pub structure: Vec<Vec<Vector3<Real>>>,
    /// Where the modes came from (data, licence).
    pub note: String,
    /// `landmarks[k]`: mode `k`'s displacement of the 68 iBUG landmarks, when the space
    /// carries them ([`SpaceModes::landmark_base`]); empty otherwise.
    pub landmarks: Vec<Vec<Vector3<Real>>>,
}

impl ExpressionModes {
    /// The number of modes.
    pub fn len(&self) -> usize {
        self.names.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.names.is_empty()
    }
}

/// The serialised form of [`ExpressionModes`].
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawExpressions {
    names: Vec<String>,
    structure: Vec<Vec<Vector3<Real>>>,
    /// `"f32le-base64"`.
    grid_encoding: String,
    grid: String,
    note: String,
    /// `L × 68 × 3` floats, `grid_encoding` (v5+, with the space's `landmark_base`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    landmarks: Option<String>,
}

/// The serialised form of [`SpaceModes`].
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSpace {
    modes: usize,
    sigma: Vec<Real>,
    structure: Vec<Vec<Vector3<Real>>>,
    /// `"f32le-base64"`.
    grid_encoding: String,
    grid: String,
    note: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    expressions: Option<RawExpressions>,
    /// The 68 iBUG landmarks (v5+).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    landmark_base: Option<Vec<Point3<Real>>>,
    /// `K × 68 × 3` floats, `grid_encoding` (v5+).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    landmarks: Option<String>,
}

const GRID_ENCODING: &str = "f32le-base64";

/// Grid displacements as the file stores them: little-endian `f32`, base64.
fn encode_grid(grid: &[Vec<Vector3<Real>>]) -> String {
    let mut bytes = Vec::with_capacity(grid.iter().map(|g| g.len() * 12).sum());
    for d in grid.iter().flatten() {
        for c in d.iter() {
            bytes.extend_from_slice(&(*c as f32).to_le_bytes());
        }
    }
    base64::encode(bytes)
}

/// The inverse of [`encode_grid`] for `modes` modes of `points` displaced points each (the
/// grid's control points, or landmarks); `what` names the field in errors, `unit` the points.
fn decode_grid(
    encoding: &str,
    grid: &str,
    (modes, points): (usize, usize),
    what: &str,
    unit: &str,
) -> Result<Vec<Vec<Vector3<Real>>>, String> {
    if encoding != GRID_ENCODING {
        return Err(format!(
            "{what}: grid encoding {encoding:?} is not supported (expected {GRID_ENCODING:?})"
        ));
    }
    let bytes = base64::decode(grid).map_err(|e| format!("{what}: the grid is not valid base64 ({e})"))?;
    let expected = modes * points * 12;
    if bytes.len() != expected {
        return Err(format!(
            "{what}: the grid holds {} bytes; {modes} modes of {points} {unit} need {expected}",
            bytes.len()
        ));
    }
    let values: Vec<Real> = bytes
        .chunks_exact(4)
        .map(|c| Real::from(f32::from_le_bytes([c[0], c[1], c[2], c[3]])))
        .collect();
    Ok(values
        .chunks_exact((points * 3).max(1))
        .map(|mode| {
            mode.chunks_exact(3)
                .map(|c| Vector3::new(c[0], c[1], c[2]))
                .collect()
        })
        .collect())
}

/// Checks that every mode moves `controls` control points and the 40 points, finitely.
fn check_mode_shapes(
    grid: &[Vec<Vector3<Real>>],
    structure: &[Vec<Vector3<Real>>],
    controls: usize,
    what: &str,
) -> Result<(), String> {
    if grid.len() != structure.len() {
        return Err(format!(
            "{what}: {} grid modes and {} structure modes",
            grid.len(),
            structure.len()
        ));
    }
    let finite = |v: &Vec<Vector3<Real>>| v.iter().all(|d| d.iter().all(|c| c.is_finite()));
    for (m, (g, s)) in grid.iter().zip(structure).enumerate() {
        if g.len() != controls {
            return Err(format!(
                "{what}: mode {m} moves {} control points; the grid has {controls}",
                g.len()
            ));
        }
        if s.len() != POINT_COUNT {
            return Err(format!(
                "{what}: mode {m} moves {} structure points, expected {POINT_COUNT}",
                s.len()
            ));
        }
        if !finite(g) || !finite(s) {
            return Err(format!("{what}: mode {m} has a displacement that is not finite"));
        }
    }
    Ok(())
}

/// Checks that `modes` (`what`'s) are `count` displacements of the 68 iBUG landmarks, finite.
fn check_landmark_modes(modes: &[Vec<Vector3<Real>>], count: usize, what: &str) -> Result<(), String> {
    if modes.len() != count {
        return Err(format!(
            "{what}: {} landmark displacements for {count} modes",
            modes.len()
        ));
    }
    for (m, mode) in modes.iter().enumerate() {
        if mode.len() != IBUG_POINT_COUNT {
            return Err(format!(
                "{what}: mode {m} moves {} landmarks, expected {IBUG_POINT_COUNT}",
                mode.len()
            ));
        }
        if !mode.iter().all(|d| d.iter().all(|c| c.is_finite())) {
            return Err(format!(
                "{what}: mode {m} moves a landmark by a displacement that is not finite"
            ));
        }
    }
    Ok(())
}

impl SpaceModes {
    /// The first `k` identity modes only (all of them when there are fewer); the expressions
    /// stay.
    pub fn truncated(&self, k: usize) -> Self {
        let k = k.min(self.sigma.len());
        SpaceModes {
            grid: self.grid[..k].to_vec(),
            structure: self.structure[..k].to_vec(),
            sigma: self.sigma[..k].to_vec(),
            note: format!("{} (the first {k} modes)", self.note),
            expressions: self.expressions.clone(),
            landmark_base: self.landmark_base.clone(),
            landmarks: self.landmarks[..k.min(self.landmarks.len())].to_vec(),
        }
    }

    /// These modes without their expressions.
    pub fn without_expressions(mut self) -> Self {
        self.expressions = ExpressionModes::default();
        self
    }

    /// The modes with their grid and landmark displacements rounded to `f32` (what the file
    /// stores).
    pub fn rounded(mut self) -> Self {
        for mode in self
            .grid
            .iter_mut()
            .chain(&mut self.expressions.grid)
            .chain(&mut self.landmarks)
            .chain(&mut self.expressions.landmarks)
        {
            for d in mode.iter_mut() {
                *d = d.map(|c| Real::from(c as f32));
            }
        }
        self
    }

    pub(crate) fn check(&self, controls: usize) -> Result<(), String> {
        let k = self.sigma.len();
        if self.grid.len() != k || self.structure.len() != k {
            return Err(format!(
                "space: {k} deviations, {} grid modes and {} structure modes",
                self.grid.len(),
                self.structure.len()
            ));
        }
        if let Some(m) = self.sigma.iter().position(|s| !(s.is_finite() && *s > 0.0)) {
            return Err(format!(
                "space: mode {m}'s deviation {} is not positive",
                self.sigma[m]
            ));
        }
        check_mode_shapes(&self.grid, &self.structure, controls, "space")?;
        self.expressions.check(controls)?;
        // The landmarks come with every mode's displacement of them, or not at all.
        let (identity, expressions) = if self.landmark_base.is_empty() {
            (0, 0)
        } else {
            check_points_n(&self.landmark_base, IBUG_POINT_COUNT, "space landmark_base")?;
            (k, self.expressions.len())
        };
        check_landmark_modes(&self.landmarks, identity, "space landmarks")?;
        check_landmark_modes(
            &self.expressions.landmarks,
            expressions,
            "space expressions' landmarks",
        )
    }
}

impl ExpressionModes {
    /// Checks one distinct, non-empty name per mode and every mode's shape
    /// ([`check_mode_shapes`]) for a grid of `controls` control points.
    pub(crate) fn check(&self, controls: usize) -> Result<(), String> {
        if self.names.len() != self.grid.len() {
            return Err(format!(
                "space expressions: {} names for {} modes",
                self.names.len(),
                self.grid.len()
            ));
        }
        let mut seen = std::collections::HashSet::new();
        if let Some(name) = self
            .names
            .iter()
            .find(|n| n.is_empty() || !seen.insert(n.as_str()))
        {
            return Err(format!(
                "space expressions: the name {name:?} is empty or repeated"
            ));
        }
        check_mode_shapes(&self.grid, &self.structure, controls, "space expressions")
    }
}

impl From<SpaceModes> for RawSpace {
    fn from(s: SpaceModes) -> Self {
        let with_landmarks = !s.landmark_base.is_empty();
        let expressions = (!s.expressions.is_empty()).then(|| RawExpressions {
            grid_encoding: GRID_ENCODING.to_owned(),
            grid: encode_grid(&s.expressions.grid),
            landmarks: with_landmarks.then(|| encode_grid(&s.expressions.landmarks)),
            names: s.expressions.names,
            structure: s.expressions.structure,
            note: s.expressions.note,
        });
        RawSpace {
            modes: s.sigma.len(),
            grid_encoding: GRID_ENCODING.to_owned(),
            grid: encode_grid(&s.grid),
            sigma: s.sigma,
            structure: s.structure,
            note: s.note,
            expressions,
            landmarks: with_landmarks.then(|| encode_grid(&s.landmarks)),
            landmark_base: with_landmarks.then_some(s.landmark_base),
        }
    }
}

impl RawSpace {
    /// Whether the space carries landmarks (format version 5).
    fn has_landmarks(&self) -> bool {
        self.landmark_base.is_some()
            || self.landmarks.is_some()
            || self.expressions.as_ref().is_some_and(|e| e.landmarks.is_some())
    }

    fn decode(self, controls: usize) -> Result<SpaceModes, String> {
        let encoding = &self.grid_encoding;
        let grid = decode_grid(
            encoding,
            &self.grid,
            (self.modes, controls),
            "space",
            "control points",
        )?;
        let landmarks = |field: Option<&String>, modes: usize, what: &str| match field {
            Some(l) => decode_grid(encoding, l, (modes, IBUG_POINT_COUNT), what, "landmarks"),
            None if self.landmark_base.is_some() && modes > 0 => {
                Err(format!("{what}: missing, while the space has a landmark_base"))
            }
            None => Ok(Vec::new()),
        };
        let expressions = match &self.expressions {
            None => ExpressionModes::default(),
            Some(e) => ExpressionModes {
                grid: decode_grid(
                    &e.grid_encoding,
                    &e.grid,
                    (e.names.len(), controls),
                    "space expressions",
                    "control points",
                )?,
                landmarks: landmarks(
                    e.landmarks.as_ref(),
                    e.names.len(),
                    "space expressions' landmarks",
                )?,
                names: e.names.clone(),
                structure: e.structure.clone(),
                note: e.note.clone(),
            },
        };
        let space = SpaceModes {
            grid,
            landmarks: landmarks(self.landmarks.as_ref(), self.modes, "space landmarks")?,
            structure: self.structure,
            sigma: self.sigma,
            note: self.note,
            expressions,
            landmark_base: self.landmark_base.unwrap_or_default(),
        };
        space.check(controls)?;
        Ok(space)
    }
}

/// Where the photo path puts a landmarker's points on a reference face: the 40-point structure
/// it estimates from photographs of the face itself (see [`ReferenceFace::photo_structure`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PhotoStructure {
    /// The 40 points, canonical frame.
    pub points: Vec<Point3<Real>>,
    /// How they were measured.
    pub note: String,
}

/// What went wrong building or reading a reference.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ReferenceError {
    /// No scan was given.
    #[error("no scan to build the reference from")]
    NoScans,
    /// An option is out of its range.
    #[error("option {name} = {value} is out of range: {expected}")]
    Option {
        /// The option.
        name: &'static str,
        /// Its value.
        value: String,
        /// The range.
        expected: &'static str,
    },
    /// A scan's structure cannot be unified.
    #[error("scan {scan}: {source}")]
    Structure {
        /// 0-based scan number.
        scan: usize,
        /// Why.
        source: StructureError,
    },
    /// The scans leave the face region (almost) empty.
    #[error(
        "only {samples} frontal samples where every scan has surface: do the landmarks belong to the scans?"
    )]
    TooFewSamples {
        /// Samples found.
        samples: usize,
    },
    /// The fit failed.
    #[error("fitting the control grid: {0}")]
    Fit(#[from] BSplineError),
    /// A face space that is not usable: learnt from the scans, or given with modes that do
    /// not match the grid ([`ReferenceFace::with_space`]).
    #[error("the face space: {problem}")]
    Space {
        /// What is wrong.
        problem: String,
    },
    /// A photo structure without 40 finite points ([`ReferenceFace::with_photo_structure`]).
    #[error("{problem}")]
    PhotoStructure {
        /// What is wrong.
        problem: String,
    },
}

/// One scan handed to [`build_reference`].
#[derive(Debug, Clone)]
pub struct ReferenceScan {
    /// The scan, in its own frame.
    pub mesh: TriangleMesh,
    /// Its 40-point structure, in the same frame.
    pub structure: Vec<Point3<Real>>,
    /// Its 68 iBUG landmarks, in the same frame, when its landmark file gives them (the
    /// structure is made from them): a face space learnt from scans that all have them
    /// ([`build_reference_with_space`]) moves them with its modes.
    pub landmarks: Option<Vec<Point3<Real>>>,
    /// Where it came from.
    pub source: ReferenceSource,
}

impl ReferenceScan {
    /// A scan from its mesh file (OBJ, PLY, glTF or GLB) and its landmark file
    /// ([`crate::landmarks::read_mesh_landmarks`]: 3D JSON or 68 vertex indices), with its
    /// source recorded: the files' names, the mesh's size and the FNV-1a hash of its bytes.
    ///
    /// # Errors
    /// [`crate::Error::Mesh`] or [`crate::Error::Landmarks`] naming the file that cannot be
    /// read.
    pub fn read(mesh_path: &std::path::Path, landmarks: &std::path::Path) -> Result<Self, crate::Error> {
        let mesh = crate::mesh::read_mesh(mesh_path)?;
        let bytes = crate::io::read_input(mesh_path, crate::io::MAX_LARGE_INPUT_BYTES).map_err(|e| {
            crate::mesh::MeshError {
                file: mesh_path.to_path_buf(),
                problem: e.into(),
            }
        })?;
        let crate::landmarks::MeshLandmarks { structure, ibug } =
            crate::landmarks::read_mesh_landmarks(landmarks, &mesh)?;
        let name = |path: &std::path::Path| {
            path.file_name().map_or_else(
                || path.display().to_string(),
                |n| n.to_string_lossy().into_owned(),
            )
        };
        Ok(ReferenceScan {
            source: ReferenceSource {
                mesh: name(mesh_path),
                mesh_fnv1a64: crate::io::fnv1a64_hex(&bytes),
                landmarks: name(landmarks),
                vertices: mesh.positions().len(),
                triangles: mesh.triangles().len(),
            },
            mesh,
            structure,
            landmarks: ibug,
        })
    }
}

fn check_option(
    name: &'static str,
    value: Real,
    ok: bool,
    expected: &'static str,
) -> Result<(), ReferenceError> {
    if ok && value.is_finite() {
        Ok(())
    } else {
        Err(ReferenceError::Option {
            name,
            value: value.to_string(),
            expected,
        })
    }
}

/// The largest raster [`build_reference`] accepts, in samples.
pub const MAX_SAMPLES: usize = 20_000_000;

/// The face-region polygon (frontal `x`, `y`) of a canonical structure: the contour closed
/// over the brows lifted by `brow_lift`, grown by `margin` about its vertex centroid.
pub fn face_region(structure: &[Point3<Real>], brow_lift: Real, margin: Real) -> Vec<Point2<Real>> {
    use structure::Group;
    let group = |g: Group| (0..POINT_COUNT).filter(move |&k| structure::POINTS[k].group == g);
    let mut polygon: Vec<Point2<Real>> = group(Group::Contour)
        .map(|k| Point2::new(structure[k].x, structure[k].y))
        .collect();
    let brows: Vec<usize> = group(Group::Brows).collect();
    polygon.extend(
        brows
            .iter()
            .rev()
            .map(|&k| Point2::new(structure[k].x, structure[k].y + brow_lift)),
    );
    let centroid = polygon.iter().map(|p| p.coords).sum::<nalgebra::Vector2<Real>>() / polygon.len() as Real;
    polygon
        .iter()
        .map(|p| Point2::from(centroid + margin * (p.coords - centroid)))
        .collect()
}

/// Builds a reference face from one or more scans (see the module documentation).
///
/// # Errors
/// [`ReferenceError::NoScans`], [`ReferenceError::Option`] for an option out of range,
/// [`ReferenceError::Structure`] when a scan's structure cannot be unified,
/// [`ReferenceError::TooFewSamples`] when the scans do not cover the face region,
/// [`ReferenceError::Fit`] when the fit fails.
pub fn build_reference(
    scans: &[ReferenceScan],
    options: &ReferenceOptions,
    note: &str,
) -> Result<ReferenceFace, ReferenceError> {
    if scans.is_empty() {
        return Err(ReferenceError::NoScans);
    }
    options.validate()?;
    let prepared = prepare(scans, options)?;
    fitted_reference(&prepared, scans, options, note)
}

/// Step 4 of [`build_reference`]: the grid fitted to the prepared scans' mean heights.
fn fitted_reference(
    prepared: &Prepared,
    scans: &[ReferenceScan],
    options: &ReferenceOptions,
    note: &str,
) -> Result<ReferenceFace, ReferenceError> {
    let mean_heights: Vec<Real> = (0..prepared.xy.len())
        .map(|i| prepared.heights.iter().map(|h| h[i]).sum::<Real>() / scans.len() as Real)
        .collect();
    let points = prepared.points(&mean_heights);
    let params = &prepared.params;

    // 4. The fit.
    let fitter = prepared.fitter(options)?;
    let fitted = fitter.fit(params, &points)?;
    let surface = fitted.surface;
    let mut distances: Vec<Real> = surface
        .eval_many(params)?
        .iter()
        .zip(&points)
        .map(|(e, p)| (e - p).norm())
        .collect();
    distances.sort_unstable_by(Real::total_cmp);
    let percentile = |q: Real| distances[((distances.len() - 1) as Real * q).round() as usize];
    let fit = ReferenceFit {
        options: *options,
        samples: points.len(),
        rms: fitted.report.rms,
        max: fitted.report.max,
        max_at: points[fitted.report.max_index],
        median: percentile(0.5),
        p95: percentile(0.95),
    };
    let frontal: Vec<Point2<Real>> = prepared.mean.iter().map(|p| p.xy()).collect();
    let edges = delaunay_edges(&frontal).map_err(|source| ReferenceError::Structure { scan: 0, source })?;
    Ok(ReferenceFace {
        surface,
        structure: prepared.mean.clone(),
        photo_structure: None,
        space: None,
        edges,
        frame: prepared.frame,
        clip: prepared.clip.clone(),
        fit,
        provenance: Provenance {
            program: format!("splineface {} fit-reference", env!("CARGO_PKG_VERSION")),
            sources: scans.iter().map(|s| s.source.clone()).collect(),
            note: note.to_owned(),
        },
    })
}

/// The scans unified and sampled over the face region: what [`build_reference`] fits.
struct Prepared {
    /// The mean structure and each scan's, canonical frame.
    mean: Vec<Point3<Real>>,
    structures: Vec<Vec<Point3<Real>>>,
    /// Each scan's 68 iBUG landmarks, canonical frame, when every scan has them
    /// ([`ReferenceScan::landmarks`]).
    landmarks: Option<Vec<Vec<Point3<Real>>>>,
    frame: FrontalFrame,
    clip: Vec<Point2<Real>>,
    /// The samples where every scan has surface, inside the fitted region: their parameters,
    /// their frontal positions and each scan's height there.
    params: Vec<[Real; 2]>,
    xy: Vec<Point2<Real>>,
    heights: Vec<Vec<Real>>,
}

impl Prepared {
    fn points(&self, heights: &[Real]) -> Vec<Point3<Real>> {
        self.xy
            .iter()
            .zip(heights)
            .map(|(p, z)| Point3::new(p.x, p.y, *z))
            .collect()
    }

    fn fitter(&self, options: &ReferenceOptions) -> Result<SurfaceFit<'_>, ReferenceError> {
        let needed = options.grid * options.grid;
        if self.xy.len() < needed {
            return Err(ReferenceError::TooFewSamples {
                samples: self.xy.len(),
            });
        }
        let knots = KnotVector::clamped_uniform(3, options.grid, 0.0, 1.0)?;
        Ok(SurfaceFit::new(knots.clone(), knots).smoothness(options.smoothness))
    }
}

/// Steps 1 to 3 of [`build_reference`].
fn prepare(scans: &[ReferenceScan], options: &ReferenceOptions) -> Result<Prepared, ReferenceError> {
    // 1. Unify every scan; the reference structure is the mean.
    let mut meshes = Vec::with_capacity(scans.len());
    let mut structures = Vec::with_capacity(scans.len());
    let mut landmarks = Some(Vec::with_capacity(scans.len()));
    let mut mean = vec![Point3::origin(); POINT_COUNT];
    for (k, scan) in scans.iter().enumerate() {
        let (similarity, canonical) =
            unify(&scan.structure).map_err(|source| ReferenceError::Structure { scan: k, source })?;
        meshes.push(scan.mesh.transformed(&nalgebra::convert(similarity)));
        if let Some(points) = &scan.landmarks {
            check_scan_landmarks(k, points)?;
        }
        landmarks = landmarks.zip(scan.landmarks.as_ref()).map(|(mut all, points)| {
            all.push(points.iter().map(|p| similarity * p).collect::<Vec<_>>());
            all
        });
        for (m, p) in mean.iter_mut().zip(&canonical) {
            m.coords += p.coords / scans.len() as Real;
        }
        structures.push(canonical);
    }

    // 2. The face region and the frontal box.
    let region = face_region(&mean, options.brow_lift, options.margin);
    let fitted_region = face_region(&mean, options.brow_lift, options.fit_margin);
    let (lo, hi) = bounding_box(&region).expect("the face region has points");
    let frame = FrontalFrame {
        x: [lo.x, hi.x],
        y: [lo.y, hi.y],
    };
    let clip: Vec<Point2<Real>> = region.iter().map(|p| frame.parameters(p.x, p.y)).collect();

    // 3. Front-most heights over the box, where every scan has surface.
    let spacing = options.sample_spacing;
    let raster = frame.raster(spacing);
    if raster.width as Real * raster.height as Real > MAX_SAMPLES as Real {
        return Err(ReferenceError::Option {
            name: "sample spacing",
            value: spacing.to_string(),
            expected: "coarse enough for at most 20 million samples over the face box",
        });
    }
    let all: Vec<Vec<Real>> = meshes.iter().map(|mesh| front_heights(mesh, &raster)).collect();
    let mut params = Vec::new();
    let mut xy = Vec::new();
    let mut kept = Vec::new();
    for j in 0..raster.height {
        for i in 0..raster.width {
            let index = j * raster.width + i;
            if all.iter().any(|h| h[index].is_nan()) {
                continue;
            }
            let p = raster.position(i, j);
            if !polygon_contains(&fitted_region, p) {
                continue;
            }
            let uv = frame.parameters(p.x, p.y);
            params.push([uv.x.clamp(0.0, 1.0), uv.y.clamp(0.0, 1.0)]);
            xy.push(Point2::new(p.x, p.y));
            kept.push(index);
        }
    }
    let heights = all
        .iter()
        .map(|h| kept.iter().map(|&index| h[index]).collect())
        .collect();
    Ok(Prepared {
        mean,
        structures,
        landmarks,
        frame,
        clip,
        params,
        xy,
        heights,
    })
}

/// Refuses scan `k`'s 68 landmarks ([`ReferenceScan::landmarks`]) unless there are 68 and all
/// are finite.
fn check_scan_landmarks(k: usize, points: &[Point3<Real>]) -> Result<(), ReferenceError> {
    let problem = if points.len() != IBUG_POINT_COUNT {
        Some(StructureError::WrongPointCount {
            got: points.len(),
            expected: IBUG_POINT_COUNT,
        })
    } else {
        points
            .iter()
            .position(|p| !p.iter().all(|c| c.is_finite()))
            .map(|index| StructureError::NonFinitePoint { index })
    };
    problem.map_or(Ok(()), |source| {
        Err(ReferenceError::Structure { scan: k, source })
    })
}

/// A reference built from several scans ([`build_reference`]) with a face space learnt from
/// them: the principal components of their own fitted grids.
///
/// Every scan is fitted on the reference's knots, over the same samples (the scans are in
/// correspondence through the frontal parametrisation of their unified frames: a sample is the
/// same `(x, y)` on every face); by linearity the mean of those grids is the reference's grid.
/// The scans' deviations from it, `Dₛ = Gₛ − Ḡ`, are decomposed as `D = U S Vᵀ`; mode `k` is
/// `Vₖ sₖ / √(n − 1)`, the displacement of one standard deviation along it (so its prior
/// deviation is 1), and moves the 40 points by the same combination of the scans' structures,
/// `Σₛ Uₛₖ (Sₛ − S̄) / √(n − 1)`. At most `n − 1` modes, those whose singular value is not
/// negligible (above `10⁻⁹` of the largest). The grid modes move heights only (a sample's
/// `(x, y)` is shared), as the frontal parametrisation implies.
///
/// # Errors
/// As [`build_reference`], and [`ReferenceError::Option`] for fewer than 3 scans (two give one
/// direction, not a space).
pub fn build_reference_with_space(
    scans: &[ReferenceScan],
    options: &ReferenceOptions,
    note: &str,
) -> Result<ReferenceFace, ReferenceError> {
    if scans.len() < 3 {
        return Err(ReferenceError::Option {
            name: "scans",
            value: scans.len().to_string(),
            expected: "at least 3 for a face space learnt from scans",
        });
    }
    options.validate()?;
    let prepared = prepare(scans, options)?;
    let reference = fitted_reference(&prepared, scans, options, note)?;
    let fitter = prepared.fitter(options)?;
    let n = scans.len();
    let mut grids = Vec::with_capacity(n);
    for heights in &prepared.heights {
        let fitted = fitter.fit(&prepared.params, &prepared.points(heights))?;
        grids.push(fitted.surface.control_points().to_vec());
    }
    let controls = grids[0].len();
    let mean_grid: Vec<Point3<Real>> = (0..controls)
        .map(|c| Point3::from(grids.iter().map(|g| g[c].coords).sum::<Vector3<Real>>() / n as Real))
        .collect();
    let deviations = nalgebra::DMatrix::from_fn(n, 3 * controls, |s, i| {
        grids[s][i / 3][i % 3] - mean_grid[i / 3][i % 3]
    });
    let svd = deviations.svd(true, false);
    let u = svd.u.expect("asked for U");
    let largest = svd.singular_values.max();
    let scale = 1.0 / ((n - 1) as Real).sqrt();
    let mut order: Vec<usize> = (0..svd.singular_values.len()).collect();
    order.sort_by(|&a, &b| svd.singular_values[b].total_cmp(&svd.singular_values[a]));
    // The scans' 68 landmarks (when every scan has them) move with the same coefficients as
    // their grids and structures, about their mean.
    let landmark_base: Vec<Point3<Real>> = prepared.landmarks.as_ref().map_or_else(Vec::new, |all| {
        (0..IBUG_POINT_COUNT)
            .map(|j| Point3::from(all.iter().map(|l| l[j].coords).sum::<Vector3<Real>>() / n as Real))
            .collect()
    });
    let mut grid_modes = Vec::new();
    let mut structure_modes = Vec::new();
    let mut landmark_modes = Vec::new();
    for k in order.into_iter().take(n - 1) {
        if svd.singular_values[k].is_nan() || svd.singular_values[k] <= 1e-9 * largest {
            continue;
        }
        let coefficients: Vec<Real> = (0..n).map(|s| u[(s, k)] * scale).collect();
        let mut grid = vec![Vector3::zeros(); controls];
        let mut structure = vec![Vector3::zeros(); POINT_COUNT];
        for (s, c) in coefficients.iter().enumerate() {
            for (g, (p, m)) in grid.iter_mut().zip(grids[s].iter().zip(&mean_grid)) {
                *g += (p - m) * *c;
            }
            for (d, (p, m)) in structure
                .iter_mut()
                .zip(prepared.structures[s].iter().zip(&prepared.mean))
            {
                *d += (p - m) * *c;
            }
        }
        if let Some(all) = &prepared.landmarks {
            let mut landmarks = vec![Vector3::zeros(); IBUG_POINT_COUNT];
            for (l, c) in all.iter().zip(&coefficients) {
                for (d, (p, m)) in landmarks.iter_mut().zip(l.iter().zip(&landmark_base)) {
                    *d += (p - m) * *c;
                }
            }
            landmark_modes.push(landmarks);
        }
        grid_modes.push(grid);
        structure_modes.push(structure);
    }
    let space = SpaceModes {
        sigma: vec![1.0; grid_modes.len()],
        grid: grid_modes,
        structure: structure_modes,
        note: format!(
            "The principal components of the {n} scans' own grids (fit-reference --space-from-scans); {note}"
        ),
        expressions: ExpressionModes::default(),
        landmark_base,
        landmarks: landmark_modes,
    };
    reference.with_space(Some(space))
}

/// The project's default reference, fitted to the ICT-FaceKit mean face (see
/// `reference/README.md` for how, and the source's MIT notice).
const EMBEDDED: &str = include_str!("../reference/ict-mean-face.json");

impl ReferenceFace {
    /// The project's default reference, embedded in the library (parsed on first use).
    pub fn embedded() -> &'static ReferenceFace {
        static REFERENCE: OnceLock<ReferenceFace> = OnceLock::new();
        REFERENCE.get_or_init(|| {
            ReferenceFace::from_json(EMBEDDED).expect("the embedded reference is valid (a test checks it)")
        })
    }

    /// The fitted surface, in the canonical frame, over `[0, 1]²`.
    pub fn surface(&self) -> &BSplineSurface {
        &self.surface
    }

    /// The reference 40-point structure `T₀`, in the canonical frame.
    pub fn structure(&self) -> &[Point3<Real>] {
        &self.structure
    }

    /// The structure the photo stages deform from: where a 68-point landmarker's points fall on
    /// this face as the photo path estimates them, when the reference carries that
    /// measurement, else [`ReferenceFace::structure`].
    ///
    /// A landmarker does not put its points where a scan's landmark vertices are: dlib's
    /// mouth and nose points sit 2–5 units (canonical, 3–6 mm) below the ICT-FaceKit mean
    /// face's landmark vertices, its brows higher, and the weak-perspective depth stage adds
    /// a bias of its own. Deforming from the vertices would charge every face with those
    /// offsets; deforming from what the photo path sees on the reference itself cancels them.
    pub fn photo_structure(&self) -> &[Point3<Real>] {
        self.photo_structure
            .as_ref()
            .map_or(&self.structure, |p| &p.points)
    }

    /// The measurement behind [`ReferenceFace::photo_structure`], if the reference has one.
    pub fn photo_structure_measured(&self) -> Option<&PhotoStructure> {
        self.photo_structure.as_ref()
    }

    /// This reference with `points` as its photo structure (or without one, for `None`).
    ///
    /// # Errors
    /// [`ReferenceError::PhotoStructure`] when there are not 40 finite points.
    pub fn with_photo_structure(mut self, photo: Option<PhotoStructure>) -> Result<Self, ReferenceError> {
        if let Some(p) = &photo {
            check_points(&p.points, "photo structure")
                .map_err(|problem| ReferenceError::PhotoStructure { problem })?;
        }
        self.photo_structure = photo;
        Ok(self)
    }

    /// The face space the reference carries, if any ([`crate::face::FaceSpace`]), on its
    /// surface and [`ReferenceFace::structure`].
    pub fn face_space(&self) -> Option<crate::face::FaceSpace> {
        self.space
            .as_ref()
            .map(|s| crate::face::FaceSpace::from_modes(self, s).expect("modes checked when they were set"))
    }

    /// The modes behind [`ReferenceFace::face_space`], if any.
    pub fn space_modes(&self) -> Option<&SpaceModes> {
        self.space.as_ref()
    }

    /// This reference with a face space (rounded to what the file stores,
    /// [`SpaceModes::rounded`]), or without one for `None`.
    ///
    /// # Errors
    /// [`ReferenceError::Space`] when the modes do not match the grid or are not finite.
    pub fn with_space(mut self, space: Option<SpaceModes>) -> Result<Self, ReferenceError> {
        if let Some(s) = &space {
            s.check(self.surface.rows() * self.surface.cols())
                .map_err(|problem| ReferenceError::Space { problem })?;
        }
        self.space = space.map(SpaceModes::rounded);
        Ok(self)
    }

    /// The same reference over a finer control grid: the knots `values` added along
    /// `direction` to its surface and to every mode of its face space, identity and expression
    /// alike ([`crate::bspline::SurfaceSpace::refine_knots`]). Every face it describes is the
    /// same surface as before (to the `f32` the modes are stored at); what changes is where a
    /// displacement of the control grid can act: a refinement's field
    /// ([`crate::face::RefineOptions::field`]) gets finer detail where the knots were added.
    ///
    /// # Errors
    /// [`ReferenceError::Fit`] as [`BSplineSurface::refine_knots`]: a value outside `[0, 1]`
    /// or a knot that would appear more than three times.
    pub fn refine_knots(
        &self,
        direction: crate::bspline::Direction,
        values: &[Real],
    ) -> Result<Self, ReferenceError> {
        // The surface and every mode, identity then expression, refined as one space: the base
        // once, and each grid by the same insertion.
        let modes = self.space.as_ref();
        let grids: Vec<Vec<Vector3<Real>>> = modes
            .into_iter()
            .flat_map(|m| m.grid.iter().chain(&m.expressions.grid))
            .cloned()
            .collect();
        let finer = SurfaceSpace::new(self.surface.clone(), grids)?.refine_knots(direction, values)?;
        let space = modes.map(|m| {
            let (identity, expressions) = finer.modes().split_at(m.grid.len());
            SpaceModes {
                grid: identity.to_vec(),
                structure: m.structure.clone(),
                sigma: m.sigma.clone(),
                note: m.note.clone(),
                expressions: ExpressionModes {
                    names: m.expressions.names.clone(),
                    grid: expressions.to_vec(),
                    structure: m.expressions.structure.clone(),
                    note: m.expressions.note.clone(),
                    landmarks: m.expressions.landmarks.clone(),
                },
                landmark_base: m.landmark_base.clone(),
                landmarks: m.landmarks.clone(),
            }
        });
        let refined = ReferenceFace {
            surface: finer.base().clone(),
            structure: self.structure.clone(),
            photo_structure: self.photo_structure.clone(),
            space: None,
            edges: self.edges.clone(),
            frame: self.frame,
            clip: self.clip.clone(),
            fit: self.fit,
            provenance: self.provenance.clone(),
        };
        refined.with_space(space)
    }

    /// The reference the photo stages use: [`ReferenceFace::photo_structure`] as its structure
    /// (a copy when the two differ).
    pub fn as_seen_in_photos(&self) -> std::borrow::Cow<'_, ReferenceFace> {
        match &self.photo_structure {
            None => std::borrow::Cow::Borrowed(self),
            Some(p) => std::borrow::Cow::Owned(ReferenceFace {
                structure: p.points.clone(),
                photo_structure: None,
                ..self.clone()
            }),
        }
    }

    /// The structure's edges (Delaunay of its frontal positions), `i < j`.
    pub fn edges(&self) -> &[[usize; 2]] {
        &self.edges
    }

    /// The frontal box the parameters span.
    pub fn frame(&self) -> &FrontalFrame {
        &self.frame
    }

    /// The face-region clip polygon in `(u, v)`.
    pub fn clip(&self) -> &[Point2<Real>] {
        &self.clip
    }

    /// Whether `(u, v)` lies inside the face region.
    pub fn in_face_region(&self, u: Real, v: Real) -> bool {
        polygon_contains(&self.clip, Point2::new(u, v))
    }

    /// The fit's options and residuals.
    pub fn fit(&self) -> &ReferenceFit {
        &self.fit
    }

    /// How the reference was made.
    pub fn provenance(&self) -> &Provenance {
        &self.provenance
    }

    /// The reference in its JSON form (documented on the module), exact on reading back.
    pub fn to_json(&self) -> String {
        serde_json::to_string(self).expect("a validated reference always serialises")
    }

    /// Reads a reference written by [`ReferenceFace::to_json`], validating everything.
    ///
    /// # Errors
    /// A `serde_json` error that says what is wrong.
    pub fn from_json(json: &str) -> Result<Self, serde_json::Error> {
        serde_json::from_str(json)
    }

    /// Reads a reference file (within [`crate::io::MAX_DATA_INPUT_BYTES`]).
    ///
    /// # Errors
    /// [`ReferenceFileError`] naming the file.
    pub fn read(path: &std::path::Path) -> Result<Self, ReferenceFileError> {
        let text = crate::io::read_input_text(path, crate::io::MAX_DATA_INPUT_BYTES).map_err(|error| {
            ReferenceFileError::Unreadable {
                path: path.to_path_buf(),
                error,
            }
        })?;
        Self::from_json(&text).map_err(|error| ReferenceFileError::Invalid {
            path: path.to_path_buf(),
            error,
        })
    }
}

/// A reference file that could not be read ([`ReferenceFace::read`]).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ReferenceFileError {
    /// The file could not be read.
    #[error("cannot read {}: {error}", path.display())]
    Unreadable {
        /// The file.
        path: std::path::PathBuf,
        /// Why.
        error: std::io::Error,
    },
    /// The file is not a reference face.
    #[error("{} is not a valid reference face: {error}", path.display())]
    Invalid {
        /// The file.
        path: std::path::PathBuf,
        /// What is wrong.
        error: serde_json::Error,
    },
}

const FORMAT: &str = "splineface/reference";
/// Version 2 added the optional `photo_structure`, version 3 the optional `space`, version 4
/// its optional `expressions`, version 5 its optional landmarks (`landmark_base` and every
/// mode's `landmarks`); older files still load.
const VERSION: u32 = 5;

fn check_points(points: &[Point3<Real>], what: &str) -> Result<(), String> {
    check_points_n(points, POINT_COUNT, what)
}

/// Checks `count` finite points.
fn check_points_n(points: &[Point3<Real>], count: usize, what: &str) -> Result<(), String> {
    if points.len() != count {
        return Err(format!("{what} has {} points, expected {count}", points.len()));
    }
    if let Some(k) = points.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
        return Err(format!("{what} point {k} is not finite"));
    }
    Ok(())
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawReference {
    format: String,
    version: u32,
    surface: BSplineSurface,
    structure: Vec<Point3<Real>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    photo_structure: Option<PhotoStructure>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    space: Option<RawSpace>,
    edges: Vec<[usize; 2]>,
    frame: FrontalFrame,
    clip: Vec<Point2<Real>>,
    fit: ReferenceFit,
    provenance: Provenance,
}

impl From<ReferenceFace> for RawReference {
    fn from(r: ReferenceFace) -> Self {
        Self {
            format: FORMAT.to_owned(),
            version: VERSION,
            surface: r.surface,
            structure: r.structure,
            photo_structure: r.photo_structure,
            space: r.space.map(RawSpace::from),
            edges: r.edges,
            frame: r.frame,
            clip: r.clip,
            fit: r.fit,
            provenance: r.provenance,
        }
    }
}

impl TryFrom<RawReference> for ReferenceFace {
    type Error = String;
    fn try_from(raw: RawReference) -> Result<Self, String> {
        if raw.format != FORMAT {
            return Err(format!("format is {:?}, expected {FORMAT:?}", raw.format));
        }
        if !(1..=VERSION).contains(&raw.version) {
            return Err(format!(
                "format version {} is not supported (this build reads versions 1 to {VERSION})",
                raw.version
            ));
        }
        if raw.version < 2 && raw.photo_structure.is_some() {
            return Err("photo_structure needs format version 2".to_owned());
        }
        if raw.version < 3 && raw.space.is_some() {
            return Err("space needs format version 3".to_owned());
        }
        if raw.version < 4 && raw.space.as_ref().is_some_and(|s| s.expressions.is_some()) {
            return Err("space expressions need format version 4".to_owned());
        }
        if raw.version < 5 && raw.space.as_ref().is_some_and(RawSpace::has_landmarks) {
            return Err("space landmarks need format version 5".to_owned());
        }
        let controls = raw.surface.rows() * raw.surface.cols();
        let space = raw.space.map(|s| s.decode(controls)).transpose()?;
        check_points(&raw.structure, "structure")?;
        if let Some(p) = &raw.photo_structure {
            check_points(&p.points, "photo_structure")?;
        }
        let mut seen = std::collections::HashSet::new();
        for &[i, j] in &raw.edges {
            if !(i < j && j < POINT_COUNT) {
                return Err(format!("edge [{i}, {j}] is not a pair i < j < {POINT_COUNT}"));
            }
            if !seen.insert([i, j]) {
                return Err(format!("edge [{i}, {j}] is repeated"));
            }
        }
        let [x0, x1] = raw.frame.x;
        let [y0, y1] = raw.frame.y;
        if !(x0.is_finite() && x1.is_finite() && y0.is_finite() && y1.is_finite() && x0 < x1 && y0 < y1) {
            return Err("frame is not a finite box with x0 < x1 and y0 < y1".to_owned());
        }
        if raw.surface.domain_u() != (0.0, 1.0) || raw.surface.domain_v() != (0.0, 1.0) {
            return Err("the surface's domain is not [0, 1]²".to_owned());
        }
        for (knots, name) in [(raw.surface.knots_u(), "u"), (raw.surface.knots_v(), "v")] {
            // Where the surface jumps, its exact export (the trimmed STEP face's edge, the
            // image of the clip polygon) would not be one curve, and no face tears.
            if let Some((k, _)) = knots.jump() {
                return Err(format!(
                    "the surface is discontinuous at {name} = {k} (a knot repeated more than its degree)"
                ));
            }
        }
        let mut distinct = raw.clip.clone();
        distinct.dedup();
        if distinct.len() > 1 && distinct.first() == distinct.last() {
            distinct.pop();
        }
        if distinct.len() < 3 {
            return Err(format!(
                "clip polygon has {} distinct points, at least 3 needed",
                distinct.len()
            ));
        }
        if let Some(k) = raw
            .clip
            .iter()
            .position(|p| !(p.iter().all(|c| (0.0..=1.0).contains(c))))
        {
            return Err(format!("clip point {k} lies outside [0, 1]²"));
        }
        Ok(Self {
            surface: raw.surface,
            structure: raw.structure,
            photo_structure: raw.photo_structure,
            space,
            edges: raw.edges,
            frame: raw.frame,
            clip: raw.clip,
            fit: raw.fit,
            provenance: raw.provenance,
        })
    }
}
