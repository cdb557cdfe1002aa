//! Comparing a reconstructed face with a ground-truth scan: alignment, depth maps of both, the
//! per-pixel height error and the paper's measures (`../METHOD.md` §5) with millimetre errors.
//!
//! Both meshes are taken in millimetres. The reconstruction is moved onto the truth:
//!
//! * with both 40-point structures, by the least-squares **similarity** between them (Umeyama
//!   1991; photos do not fix a face's absolute size, so the scale is part of the alignment and
//!   reported);
//! * without, by **rigid ICP** (point-to-point, the 10% worst pairs trimmed each step) from the
//!   reconstruction's vertices to the truth's surface, starting from their centroids: the two
//!   must then already share their orientation and units.
//!
//! The view is the truth's frontal frame when its structure is known (eye axis along `x`, origin
//! between the eyes; see [`crate::structure::unify`]), else the truth's own frame seen from
//! `+z`. Both meshes are rendered over the raster that frames the aligned reconstruction, and
//! the pixels both cover are compared: `Δz = z_reconstruction − z_truth`.
//!
//! The paper's measures, as computed here:
//! * `mean_abs_dz_over_eye_distance`: mean `|Δz|` divided by the truth's eye distance (the
//!   paper's `|Δz|/50` in canonical units, 50 = eye distance); 63 mm when no structure is given;
//! * `percent_of_depth`: `100·mean|Δz| / mean z_truth`, with `z_truth` measured from the deepest
//!   compared truth pixel. The paper's `100·|Δz|/z_gt` leaves the origin of depth open; any
//!   origin on the face makes the mean of the per-pixel ratios explode where the truth nears it
//!   (measured on ICT subjects: 46% ± 59% for the mean face), so this is the ratio of the means,
//!   which is stable and independent of the frame;
//! * `structure_ssim` and `depth_correlation` (with both structures): the multi-substructure SSIM
//!   of the aligned structures' edge lengths and the correlation of their 40 depths.

pub use crate::geometry::LengthUnit;
use std::path::PathBuf;

use nalgebra::{
    Affine3, Matrix3, Matrix4, Point2, Point3, Rotation3, Similarity3, Translation3, UnitQuaternion, Vector3,
};
use serde::Serialize;

use crate::Real;
use crate::bspline::{BSplineSurface, ClosestPoints as ClosestSurfacePoints};
use crate::error::SettingError;
use crate::face::MeanFace;
use crate::io::EncodeError;
use crate::landmarks::read_mesh_structure;
use crate::mesh::{ClosestPoints, TriangleMesh};
use crate::reference::ReferenceFace;
use crate::render::{DepthMap, View, encode_depth_exr, frame_raster, heatmap_png, shaded_png};
use crate::structure::{self, LEFT_EYE_CENTRE, POINT_COUNT, RIGHT_EYE_CENTRE};

/// How a comparison is run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CompareOptions {
    /// Pixels along the longer side of the depth maps.
    pub size: usize,
    /// The top of the heatmap's scale, mm; `None` for the 99th percentile of `|Δz|`.
    pub heatmap_max: Option<Real>,
    /// ICP iterations at most.
    pub icp_iterations: usize,
}

impl CompareOptions {
    /// Checks the options a person gives (`size`, `heatmap_max`), naming the first that
    /// cannot be used; [`compare`] refuses them too, this says which flag is wrong.
    ///
    /// # Errors
    /// A [`SettingError`] for a size outside 16 to [`crate::render::MAX_SIDE`] or a heatmap
    /// top that is not a positive number.
    ///
    /// # Examples
    /// ```
    /// use splineface::compare::CompareOptions;
    ///
    /// assert!(CompareOptions::default().validate().is_ok());
    /// let error = CompareOptions { size: 8, ..CompareOptions::default() }.validate().unwrap_err();
    /// assert_eq!(error.flag_message(), format!("--size 8: must be between 16 and {}", splineface::render::MAX_SIDE));
    /// ```
    pub fn validate(&self) -> Result<(), SettingError> {
        if !(16..=crate::render::MAX_SIDE).contains(&self.size) {
            return Err(SettingError::new(
                "size",
                self.size.to_string(),
                format!("must be between 16 and {}", crate::render::MAX_SIDE),
            ));
        }
        if let Some(max) = self.heatmap_max
            && !(max > 0.0 && max.is_finite())
        {
            return Err(SettingError::new(
                "max",
                max.to_string(),
                "must be a positive number of millimetres",
            ));
        }
        Ok(())
    }
}

/// Two mesh files to compare, as `splineface compare` takes them (see [`compare_files`]).
#[derive(Debug, Clone, PartialEq)]
pub struct MeshFiles {
    /// The reconstruction: OBJ, PLY, glTF or GLB.
    pub reconstruction: PathBuf,
    /// The ground truth.
    pub truth: PathBuf,
    /// Each one's landmark file ([`crate::landmarks::read_mesh_structure`]), to align by
    /// their structures and score the inner face; without, they are aligned by ICP.
    pub landmarks: Option<(PathBuf, PathBuf)>,
    /// The units of the reconstruction's and the truth's coordinates.
    pub units: (LengthUnit, LengthUnit),
    /// The reconstruction's exact surface (its `surface.json`, in the reconstruction's frame
    /// and units), to score the inner face against it as well as against the mesh
    /// ([`FileComparison::inner_face_surface`]; with `landmarks` only).
    pub surface: Option<PathBuf>,
}

/// [`compare_files`]' answer.
#[derive(Debug, Clone)]
pub struct FileComparison {
    /// The comparison, in millimetres.
    pub comparison: Comparison,
    /// The unchanged mean face ([`crate::face::MeanFace`], the embedded reference) scored
    /// against the same truth the same way, when the landmarks are given.
    pub mean_face: Option<InnerFaceScore>,
    /// The inner face scored against the reconstruction's exact surface
    /// ([`inner_face_score_to_surface`]), mm: when [`MeshFiles::surface`] and the landmarks
    /// are given.
    pub inner_face_surface: Option<InnerFaceScore>,
}

/// Compares two mesh files: reads them and their landmark files, scales both to millimetres,
/// runs [`compare`], and, with landmarks, scores the embedded mean face the same way
/// ([`FileComparison::mean_face`]): a reconstruction's figures mean little alone.
///
/// # Errors
/// [`crate::Error::Setting`] for options out of range ([`CompareOptions::validate`]),
/// [`crate::Error::Mesh`] or [`crate::Error::Landmarks`] naming a file that cannot be read,
/// [`crate::Error::Compare`] as [`compare`] fails.
pub fn compare_files(files: &MeshFiles, options: &CompareOptions) -> Result<FileComparison, crate::Error> {
    options.validate()?;
    let rec = crate::mesh::read_mesh(&files.reconstruction)?;
    let truth = crate::mesh::read_mesh(&files.truth)?;
    let surface = match &files.surface {
        Some(path) => Some(BSplineSurface::read_json(path)?),
        None => None,
    };
    let structures = match &files.landmarks {
        Some((a, b)) => Some((read_mesh_structure(a, &rec)?, read_mesh_structure(b, &truth)?)),
        None => None,
    };
    let (scale_a, scale_b) = (files.units.0.millimetres(), files.units.1.millimetres());
    let to_mm =
        |s: Real| Affine3::from_matrix_unchecked(Matrix4::new_nonuniform_scaling(&Vector3::repeat(s)));
    let rec = rec.transformed(&to_mm(scale_a));
    let truth = truth.transformed(&to_mm(scale_b));
    let structures = structures.map(|(a, b)| {
        (
            a.iter().map(|p| p * scale_a).collect::<Vec<_>>(),
            b.iter().map(|p| p * scale_b).collect::<Vec<_>>(),
        )
    });
    let comparison = compare(
        &rec,
        &truth,
        structures.as_ref().map(|(a, b)| (a.as_slice(), b.as_slice())),
        options,
    )?;
    let inner_face_surface = match (&surface, &structures) {
        (Some(surface), Some((rec_structure, truth_structure))) => {
            let surface = surface.transformed(&to_mm(scale_a));
            let scored = inner_face_score_to_surface(
                (&rec, &surface),
                &truth,
                (rec_structure.as_slice(), truth_structure.as_slice()),
                &InnerFaceOptions::default(),
            )?;
            Some(scored.score)
        }
        _ => None,
    };
    let mean_face = match &structures {
        Some((_, truth_structure)) => {
            let mean = MeanFace::new(
                ReferenceFace::embedded(),
                crate::face::Units::default(),
                &crate::face::MeshOptions::default(),
            )?;
            Some(
                inner_face_score(
                    &mean.mesh,
                    &truth,
                    (&mean.photo_structure, truth_structure),
                    &InnerFaceOptions::default(),
                )?
                .score,
            )
        }
        None => None,
    };
    Ok(FileComparison {
        comparison,
        mean_face,
        inner_face_surface,
    })
}

impl Comparison {
    /// The comparison's files, `(path, bytes)`: `heatmap.png` (`|Δz|` in mm on the heatmap's
    /// scale), with `depth_maps` `reconstruction-depth.exr` and `truth-depth.exr`, the shaded
    /// `reconstruction.png` and `truth.png`, and `stats.json`: [`CompareStats`] with the keys
    /// of `extra` added (a key of both takes `extra`'s value).
    ///
    /// # Errors
    /// An [`EncodeError`] (it does not happen for a finished comparison).
    pub fn files(
        &self,
        extra: serde_json::Map<String, serde_json::Value>,
        depth_maps: bool,
    ) -> Result<Vec<(PathBuf, Vec<u8>)>, EncodeError> {
        let (w, h) = (
            self.reconstruction.raster.width,
            self.reconstruction.raster.height,
        );
        let mut stats = serde_json::to_value(&self.stats).expect("the figures are finite or null");
        if let serde_json::Value::Object(map) = &mut stats {
            map.extend(extra);
        }
        let mut files = vec![(
            PathBuf::from("heatmap.png"),
            heatmap_png(&self.abs_dz, w, h, self.heatmap_max, "mm")?,
        )];
        if depth_maps {
            files.push((
                "reconstruction-depth.exr".into(),
                encode_depth_exr(&self.reconstruction)?,
            ));
            files.push(("truth-depth.exr".into(), encode_depth_exr(&self.truth)?));
        }
        files.push(("reconstruction.png".into(), shaded_png(&self.reconstruction)?));
        files.push(("truth.png".into(), shaded_png(&self.truth)?));
        files.push((
            "stats.json".into(),
            serde_json::to_vec_pretty(&stats).expect("JSON values serialise"),
        ));
        Ok(files)
    }
}

impl Default for CompareOptions {
    fn default() -> Self {
        CompareOptions {
            size: 512,
            heatmap_max: None,
            icp_iterations: 50,
        }
    }
}

/// What went wrong comparing.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum CompareError {
    /// A structure is unusable.
    #[error("the {which} structure: {problem}")]
    Structure {
        /// `reconstruction` or `truth`.
        which: &'static str,
        /// Why.
        problem: String,
    },
    /// The meshes do not overlap in the view.
    #[error(
        "the aligned meshes share no pixel of the depth map: are they of the same face, in the same units?"
    )]
    NoOverlap,
    /// An option is out of range.
    #[error("{message}")]
    Option {
        /// Which, and its range.
        message: String,
    },
    /// A mesh could not be built (should not happen for valid input).
    #[error("the aligned mesh: {message}")]
    Mesh {
        /// Why.
        message: String,
    },
    /// The closest points of a surface could not be found (should not happen for a valid
    /// surface).
    #[error("the closest points of the reconstruction's surface: {message}")]
    Surface {
        /// Why.
        message: String,
    },
}

/// Summary statistics of a set of non-negative errors, mm.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ErrorStats {
    /// How many.
    pub count: usize,
    /// Mean.
    pub mean: Real,
    /// Root mean square.
    pub rms: Real,
    /// Median.
    pub median: Real,
    /// 90th percentile.
    pub p90: Real,
    /// Largest.
    pub max: Real,
}

impl ErrorStats {
    /// The statistics of `values` (sorted in place); zeros when empty.
    pub fn of(values: &mut [Real]) -> Self {
        values.sort_unstable_by(Real::total_cmp);
        let n = values.len();
        if n == 0 {
            return ErrorStats {
                count: 0,
                mean: 0.0,
                rms: 0.0,
                median: 0.0,
                p90: 0.0,
                max: 0.0,
            };
        }
        let at = |q: Real| values[((n - 1) as Real * q).round() as usize];
        ErrorStats {
            count: n,
            mean: values.iter().sum::<Real>() / n as Real,
            rms: (values.iter().map(|v| v * v).sum::<Real>() / n as Real).sqrt(),
            median: at(0.5),
            p90: at(0.9),
            max: values[n - 1],
        }
    }
}

/// The paper's measures (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PaperMeasures {
    /// Mean `|Δz|` over the truth's eye distance.
    pub mean_abs_dz_over_eye_distance: Real,
    /// `100·mean|Δz| / mean z_truth`, percent (see the module documentation).
    pub percent_of_depth: Real,
    /// Multi-substructure SSIM of the structures' edge lengths, when both are given.
    pub structure_ssim: Option<Real>,
    /// Correlation of the 40 depths, when both structures are given.
    pub depth_correlation: Option<Real>,
}

/// How the reconstruction was aligned.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Alignment {
    /// `structures (similarity)` or `icp (rigid)`.
    pub method: String,
    /// The scale applied to the reconstruction (1 for ICP).
    pub scale: Real,
    /// RMS distance after alignment: between the structures, or ICP's trimmed pairs, mm.
    pub rms: Real,
    /// ICP iterations run (0 with structures).
    pub iterations: usize,
}

/// The figures of a comparison, as written to `stats.json`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CompareStats {
    /// The alignment.
    pub alignment: Alignment,
    /// The eye distance the paper's measure divides by, mm.
    pub eye_distance: Real,
    /// The depth maps' pixel size, mm.
    pub pixel_size: Real,
    /// Pixels both meshes cover.
    pub pixels_compared: usize,
    /// `|Δz|` over those pixels, mm.
    pub depth_error: ErrorStats,
    /// Signed mean of `Δz`, mm (positive: the reconstruction stands in front of the truth).
    pub mean_signed_dz: Real,
    /// Distances from the reconstruction's vertices to the truth's surface, mm.
    pub point_to_surface: ErrorStats,
    /// The paper's measures.
    pub paper: PaperMeasures,
    /// Truth → reconstruction over the truth's inner face ([`inner_face_score`]), when both
    /// structures are given: the measure accuracy claims are made in.
    pub inner_face: Option<InnerFaceScore>,
}

/// A finished comparison: the figures, both depth maps and the `|Δz|` map.
#[derive(Debug, Clone)]
pub struct Comparison {
    /// The figures.
    pub stats: CompareStats,
    /// The reconstruction's depth map (truth's view frame).
    pub reconstruction: DepthMap,
    /// The truth's depth map.
    pub truth: DepthMap,
    /// `|Δz|` per pixel, `NaN` where either map is empty.
    pub abs_dz: Vec<Real>,
    /// The heatmap's scale top, mm.
    pub heatmap_max: Real,
    /// The reconstruction mesh, aligned and in the view frame.
    pub aligned: TriangleMesh,
}

/// Where a comparison puts the reconstruction: the map onto the truth, how it was found, the
/// view frame (the truth's frontal frame with its millimetres kept, or the identity), and the
/// eye distance the paper's measure divides by.
struct Placement {
    map: Similarity3<Real>,
    alignment: Alignment,
    view: Similarity3<Real>,
    eye_distance: Real,
}

/// [`compare`]'s alignment: by the structures' similarity when they are given, else by rigid
/// ICP onto the truth's surface (`indexed`).
fn placement(
    reconstruction: &TriangleMesh,
    truth: &TriangleMesh,
    indexed: &ClosestPoints,
    structures: Option<Structures<'_>>,
    options: &CompareOptions,
) -> Result<Placement, CompareError> {
    Ok(match structures {
        Some((rec, tru)) => {
            check_structure(rec, "reconstruction")?;
            check_structure(tru, "truth")?;
            let (map, rms) = fit_similarity(rec, tru).ok_or(CompareError::Structure {
                which: "reconstruction",
                problem: "its points are degenerate (collinear)".into(),
            })?;
            let (unifying, _) = structure::unify(tru).map_err(|e| CompareError::Structure {
                which: "truth",
                problem: e.to_string(),
            })?;
            // Keep the truth's millimetres: only turn and move it.
            Placement {
                map,
                alignment: Alignment {
                    method: "structures (similarity)".into(),
                    scale: map.scaling(),
                    rms,
                    iterations: 0,
                },
                view: Similarity3::from_isometry(unifying.isometry, 1.0),
                eye_distance: (tru[LEFT_EYE_CENTRE] - tru[RIGHT_EYE_CENTRE]).norm(),
            }
        }
        None => {
            let (map, rms, iterations) =
                icp(reconstruction.positions(), indexed, truth, options.icp_iterations);
            Placement {
                map,
                alignment: Alignment {
                    method: "icp (rigid)".into(),
                    scale: 1.0,
                    rms,
                    iterations,
                },
                view: Similarity3::identity(),
                eye_distance: crate::face::DEFAULT_EYE_DISTANCE_MM,
            }
        }
    })
}

/// The raster both depth maps are rendered over: the aligned reconstruction framed from the
/// front with a 2% margin, `size` pixels along its longer side.
fn comparison_raster(aligned: &TriangleMesh, size: usize) -> Result<crate::mesh::Raster, CompareError> {
    let (lo, hi) = crate::geometry::bounding_box(aligned.positions()).expect("a mesh has vertices");
    let (w, h) = if hi.x - lo.x >= hi.y - lo.y {
        (
            size,
            (((hi.y - lo.y) / (hi.x - lo.x).max(1e-300)) * size as Real).ceil() as usize,
        )
    } else {
        (
            (((hi.x - lo.x) / (hi.y - lo.y)) * size as Real).ceil() as usize,
            size,
        )
    };
    frame_raster(
        aligned.positions().iter().copied(),
        &View::front(),
        w.max(1),
        h.max(1),
        0.02,
    )
    .map_err(|e| CompareError::Option {
        message: e.to_string(),
    })
}

/// The paper's structure measures of two aligned structures (view frame): the
/// multi-substructure SSIM of their edge lengths (`reconstruction` against `truth`) and the
/// correlation of their depths.
fn structure_measures(
    reconstruction: &[Point3<Real>],
    truth: &[Point3<Real>],
) -> (Option<Real>, Option<Real>) {
    let reference = ReferenceFace::embedded();
    let edges = reference.edges();
    let groups = structure::substructures(edges);
    let ssim = structure::multi_substructure_similarity(
        &structure::edge_lengths(truth, edges),
        &structure::edge_lengths(reconstruction, edges),
        &groups,
    );
    let za: Vec<Real> = reconstruction.iter().map(|p| p.z).collect();
    let zb: Vec<Real> = truth.iter().map(|p| p.z).collect();
    (Some(ssim), structure::correlation(&za, &zb))
}

/// The least-squares similarity `s·R·x + t` taking `from` onto `to` (Umeyama 1991), with its
/// RMS residual; `None` if `from` is degenerate (collinear or a point).
pub fn fit_similarity(from: &[Point3<Real>], to: &[Point3<Real>]) -> Option<(Similarity3<Real>, Real)> {
    let n = from.len() as Real;
    if from.len() != to.len() || from.len() < 3 {
        return None;
    }
    let ca = from.iter().map(|p| p.coords).sum::<Vector3<Real>>() / n;
    let cb = to.iter().map(|p| p.coords).sum::<Vector3<Real>>() / n;
    let mut covariance = Matrix3::zeros();
    let mut variance = 0.0;
    for (a, b) in from.iter().zip(to) {
        let (x, y) = (a.coords - ca, b.coords - cb);
        covariance += y * x.transpose();
        variance += x.norm_squared();
    }
    covariance /= n;
    variance /= n;
    let svd = covariance.svd(true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    let mut d = Matrix3::identity();
    if (u * v_t).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let sigma = svd.singular_values;
    let mut sorted = sigma.as_slice().to_vec();
    sorted.sort_by(Real::total_cmp);
    if variance <= 0.0 || variance.is_nan() || sorted[1] <= 1e-12 * sorted[2] {
        return None;
    }
    let rotation = Rotation3::from_matrix_unchecked(u * d * v_t);
    let trace = (Matrix3::from_diagonal(&sigma) * d).trace();
    let scale = trace / variance;
    let translation = cb - scale * (rotation * ca);
    let similarity = Similarity3::from_parts(
        Translation3::from(translation),
        UnitQuaternion::from_rotation_matrix(&rotation),
        scale,
    );
    let rms = (from
        .iter()
        .zip(to)
        .map(|(a, b)| (similarity * a - b).norm_squared())
        .sum::<Real>()
        / n)
        .sqrt();
    Some((similarity, rms))
}

fn check_structure(points: &[Point3<Real>], which: &'static str) -> Result<(), CompareError> {
    let problem = if points.len() != POINT_COUNT {
        format!("{} points, expected 40", points.len())
    } else if points.iter().any(|p| !p.iter().all(|c| c.is_finite())) {
        "a point is not finite".to_owned()
    } else if (points[LEFT_EYE_CENTRE] - points[RIGHT_EYE_CENTRE]).norm() == 0.0 {
        "the eye centres coincide".to_owned()
    } else {
        return Ok(());
    };
    Err(CompareError::Structure { which, problem })
}

/// The reconstruction's and the truth's 40-point structures.
pub type Structures<'a> = (&'a [Point3<Real>], &'a [Point3<Real>]);

/// An ICP pair: squared distance, moved point, closest point, normal there.
type Pair = (Real, Point3<Real>, Point3<Real>, Vector3<Real>);

/// Rigid trimmed point-to-plane ICP (Chen & Medioni 1992) of `points` onto the truth, linearised
/// in the rotation each step; the 10% most distant pairs are left out of each step. Returns
/// the rigid map, the trimmed RMS distance and the iterations run.
fn icp(
    points: &[Point3<Real>],
    index: &ClosestPoints,
    truth: &TriangleMesh,
    iterations: usize,
) -> (Similarity3<Real>, Real, usize) {
    let centroid =
        |ps: &[Point3<Real>]| ps.iter().map(|p| p.coords).sum::<Vector3<Real>>() / ps.len() as Real;
    let mut transform = Similarity3::from_parts(
        Translation3::from(centroid(truth.positions()) - centroid(points)),
        UnitQuaternion::identity(),
        1.0,
    );
    // Subsample to at most 20,000 points: ICP's answer does not need more.
    let step = points.len().div_ceil(20_000).max(1);
    let sample: Vec<Point3<Real>> = points.iter().step_by(step).copied().collect();
    let mut rms = Real::INFINITY;
    let mut done = 0;
    for iteration in 0..iterations {
        done = iteration + 1;
        let moved: Vec<Point3<Real>> = sample.iter().map(|p| transform * p).collect();
        let mut pairs: Vec<Pair> = moved
            .iter()
            .zip(index.closest_many(&moved))
            .filter_map(|(p, found)| {
                // Measured against the plane of the triangle the closest point lies on.
                let [a, b, c] = truth.triangle(found.triangle);
                let n = (b - a).cross(&(c - a)).try_normalize(0.0)?;
                Some((found.distance * found.distance, *p, found.point, n))
            })
            .collect();
        if pairs.len() < 6 {
            break;
        }
        pairs.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
        pairs.truncate((pairs.len() * 9 / 10).max(6));
        let new_rms = (pairs.iter().map(|x| x.0).sum::<Real>() / pairs.len() as Real).sqrt();
        let mut normal = nalgebra::Matrix6::<Real>::zeros();
        let mut rhs = nalgebra::Vector6::<Real>::zeros();
        // About the pairs' centroid, for conditioning.
        let c = pairs.iter().map(|x| x.1.coords).sum::<Vector3<Real>>() / pairs.len() as Real;
        for (_, p, q, n) in &pairs {
            let arm = p.coords - c;
            let row = nalgebra::Vector6::new(arm.cross(n).x, arm.cross(n).y, arm.cross(n).z, n.x, n.y, n.z);
            normal += row * row.transpose();
            rhs += row * (q - p).dot(n);
        }
        let Some(x) = normal.cholesky().map(|ch| ch.solve(&rhs)) else {
            break;
        };
        let rotation = UnitQuaternion::from_scaled_axis(Vector3::new(x[0], x[1], x[2]));
        let translation = Vector3::new(x[3], x[4], x[5]) + c - rotation * c;
        transform = Similarity3::from_parts(Translation3::from(translation), rotation, 1.0) * transform;
        let settled = x.norm() < 1e-7 || (rms - new_rms).abs() < 1e-7 * (1.0 + new_rms);
        rms = new_rms;
        if settled {
            break;
        }
    }
    (transform, rms, done)
}

/// Compares a reconstruction with the truth (see the module documentation). Both meshes and
/// structures are in millimetres; structures are both given or both ignored.
///
/// # Errors
/// [`CompareError::Structure`] for a bad structure, [`CompareError::Option`] for a size out of
/// range, [`CompareError::NoOverlap`] when the aligned meshes do not overlap,
/// [`CompareError::Mesh`] when the truth cannot be indexed.
///
/// # Examples
/// ```
/// use splineface::compare::{CompareOptions, compare};
/// use splineface::face::{MeanFace, MeshOptions, Units};
/// use splineface::reference::ReferenceFace;
///
/// let truth = MeanFace::new(ReferenceFace::embedded(), Units::default(), &MeshOptions { spacing: 2.0 }).unwrap();
/// // The same face 3 mm closer to the viewer: the structures align it back exactly.
/// let moved = truth.mesh.transformed(&nalgebra::convert(nalgebra::Translation3::new(0.0, 0.0, 3.0)));
/// let moved_structure: Vec<_> = truth.structure.iter().map(|p| p + nalgebra::Vector3::z() * 3.0).collect();
/// let options = CompareOptions { size: 128, ..CompareOptions::default() };
/// let result = compare(&moved, &truth.mesh, Some((&moved_structure, &truth.structure)), &options).unwrap();
/// assert!(result.stats.depth_error.mean < 1e-6);
/// assert!((result.stats.alignment.scale - 1.0).abs() < 1e-9);
/// ```
pub fn compare(
    reconstruction: &TriangleMesh,
    truth: &TriangleMesh,
    structures: Option<Structures<'_>>,
    options: &CompareOptions,
) -> Result<Comparison, CompareError> {
    options.validate().map_err(|e| CompareError::Option {
        message: e.to_string(),
    })?;
    let indexed = ClosestPoints::new(truth);
    let Placement {
        map: alignment_map,
        alignment,
        view: view_map,
        eye_distance,
    } = placement(reconstruction, truth, &indexed, structures, options)?;
    let to_view = |p: &Point3<Real>| view_map * p;
    let aligned_points: Vec<Point3<Real>> = reconstruction
        .positions()
        .iter()
        .map(|p| alignment_map * p)
        .collect();
    let aligned = TriangleMesh::new(
        aligned_points.iter().map(to_view).collect(),
        reconstruction.triangles().to_vec(),
    )
    .map_err(|e| CompareError::Mesh {
        message: e.to_string(),
    })?;
    let truth_view = truth.transformed(&nalgebra::Affine3::from_matrix_unchecked(
        view_map.to_homogeneous(),
    ));

    let front = View::front();
    let raster = comparison_raster(&aligned, options.size)?;
    let rec_map = DepthMap::render(&aligned, &front, &raster);
    let truth_map = DepthMap::render(&truth_view, &front, &raster);

    let abs_dz: Vec<Real> = rec_map
        .heights
        .iter()
        .zip(&truth_map.heights)
        .map(|(a, b)| (a - b).abs())
        .collect();
    let both: Vec<usize> = (0..abs_dz.len()).filter(|&k| abs_dz[k].is_finite()).collect();
    if both.is_empty() {
        return Err(CompareError::NoOverlap);
    }
    let deepest = both
        .iter()
        .map(|&k| truth_map.heights[k])
        .fold(Real::INFINITY, Real::min);
    let mut depth_sum = 0.0;
    let mut signed = 0.0;
    for &k in &both {
        depth_sum += truth_map.heights[k] - deepest;
        signed += rec_map.heights[k] - truth_map.heights[k];
    }
    let mut errors: Vec<Real> = both.iter().map(|&k| abs_dz[k]).collect();
    let depth_error = ErrorStats::of(&mut errors);
    let heatmap_max = options
        .heatmap_max
        .unwrap_or_else(|| errors[((errors.len() - 1) as Real * 0.99) as usize].max(1e-6));

    let mut distances: Vec<Real> = indexed
        .closest_many(&aligned_points)
        .iter()
        .map(|c| c.distance)
        .collect();
    let point_to_surface = ErrorStats::of(&mut distances);

    let (structure_ssim, depth_correlation) = match structures {
        Some((rec, tru)) => {
            let a: Vec<Point3<Real>> = rec.iter().map(|p| to_view(&(alignment_map * p))).collect();
            let b: Vec<Point3<Real>> = tru.iter().map(&to_view).collect();
            structure_measures(&a, &b)
        }
        None => (None, None),
    };

    let inner_face = match structures {
        Some(pair) => {
            Some(inner_face_score(reconstruction, truth, pair, &InnerFaceOptions::default())?.score)
        }
        None => None,
    };
    let stats = CompareStats {
        inner_face,
        alignment,
        eye_distance,
        pixel_size: raster.spacing,
        pixels_compared: both.len(),
        depth_error,
        mean_signed_dz: signed / both.len() as Real,
        point_to_surface,
        paper: PaperMeasures {
            mean_abs_dz_over_eye_distance: depth_error.mean / eye_distance,
            percent_of_depth: if depth_sum > 0.0 {
                100.0 * depth_error.mean * both.len() as Real / depth_sum
            } else {
                0.0
            },
            structure_ssim,
            depth_correlation,
        },
    };
    Ok(Comparison {
        stats,
        reconstruction: rec_map,
        truth: truth_map,
        abs_dz,
        heatmap_max,
        aligned,
    })
}

/// The truth's inner face as a polygon in its frontal plane (`x, y` of `structure`, which is
/// already in the view frame): the 9 contour points from the right ear under the chin to the
/// left ear, then the 6 brow points back from the left outer end to the right one.
pub(crate) fn inner_face_outline(structure: &[Point3<Real>]) -> Vec<Point2<Real>> {
    let contour = (0..POINT_COUNT).filter(|&k| structure::POINTS[k].group == structure::Group::Contour);
    let brows = (0..POINT_COUNT)
        .filter(|&k| structure::POINTS[k].group == structure::Group::Brows)
        .rev();
    contour.chain(brows).map(|k| structure[k].xy()).collect()
}

/// How [`inner_face_score`] samples and aligns.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InnerFaceOptions {
    /// The spacing of the truth's frontal samples, mm.
    pub spacing: Real,
    /// Alignment iterations at most (0: the structures' similarity alone).
    pub iterations: usize,
    /// The fraction of the farthest pairs each alignment step leaves out.
    pub trim: Real,
}

impl Default for InnerFaceOptions {
    /// 1 mm samples, 50 iterations, 10% trimmed.
    fn default() -> Self {
        InnerFaceOptions {
            spacing: 1.0,
            iterations: 50,
            trim: 0.1,
        }
    }
}

/// The inner-face score of a reconstruction (see [`inner_face_score`]), as written to
/// `stats.json`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct InnerFaceScore {
    /// Truth → reconstruction distances over the truth's inner face, mm (every sample, none
    /// trimmed).
    pub distance: ErrorStats,
    /// The fraction of the inner face's samples that the aligned reconstruction covers seen from
    /// the front.
    pub coverage: Real,
    /// The scale of the similarity that aligned the reconstruction.
    pub scale: Real,
    /// Alignment iterations run.
    pub iterations: usize,
}

/// [`inner_face_score`]'s answer: the score and the per-sample distances as a map.
#[derive(Debug, Clone)]
pub struct InnerFaceComparison {
    /// The figures.
    pub score: InnerFaceScore,
    /// The raster of the truth's frontal samples (truth's view frame).
    pub raster: crate::mesh::Raster,
    /// Truth → reconstruction distance per raster sample, mm; `NaN` outside the inner face.
    pub distances: Vec<Real>,
    /// The truth's frontal height per raster sample (its view frame, mm); `NaN` outside the
    /// inner face. With [`crate::mesh::front_heights`] of [`InnerFaceComparison::aligned`] it
    /// gives where the reconstruction lies in front of the truth and where behind it.
    pub truth_heights: Vec<Real>,
    /// The reconstruction, aligned, in the truth's view frame.
    pub aligned: TriangleMesh,
}

/// Scores a reconstruction against the truth over the truth's inner face, the measure that
/// accuracy claims are made in:
///
/// 1. The view is the truth's frontal frame ([`structure::unify`] without its scaling); the
///    inner face is the region inside the truth's contour and brows
///    (the contour and the brows of its structure), and its samples are the truth's front-most surface over it, every
///    `spacing` mm (the surface seen from the front).
/// 2. The reconstruction is aligned by a similarity: first between the two structures over
///    their 31 points off the contour (a scan's contour landmarks may lie on the outline near
///    the ears, far behind the face), then refined by trimmed similarity ICP from the truth's
///    samples to the reconstruction's surface (Umeyama on closest-point pairs, the `trim`
///    farthest left out of each step), as the NoW benchmark aligns (Sanyal et al. 2019:
///    landmarks, then ICP). Photos do not fix a face's size, so the scale is part of the
///    alignment. The refinement measures shape: a landmark-only alignment would also charge a
///    face for where its landmark definitions sit on its surface.
/// 3. The score is the distance from every sample to the aligned reconstruction's surface,
///    and the fraction of samples its front view covers.
///
/// Both meshes and structures are in millimetres. Score a baseline (the unchanged mean face)
/// the same way beside every reconstruction: the figures mean little alone.
///
/// # Errors
/// [`CompareError::Structure`] for a bad structure or an inner face with no samples,
/// [`CompareError::Option`] for options out of range, [`CompareError::Mesh`] when the aligned
/// mesh cannot be built.
pub fn inner_face_score(
    reconstruction: &TriangleMesh,
    truth: &TriangleMesh,
    structures: Structures<'_>,
    options: &InnerFaceOptions,
) -> Result<InnerFaceComparison, CompareError> {
    let index = ClosestPoints::new(reconstruction);
    let closest = |points: &[Point3<Real>]| {
        Ok(index
            .closest_many(points)
            .iter()
            .map(|c| (c.point, c.distance))
            .collect())
    };
    score_inner_face(reconstruction, truth, structures, options, closest)
}

/// [`inner_face_score`] against the reconstruction's exact B-spline surface (its
/// `surface.json`, in the reconstruction's frame and millimetres): the alignment's refinement
/// and the distances find the closest points on `surface` by point inversion
/// ([`crate::bspline::ClosestPoints`]) instead of on the mesh that tessellates it, whose flat
/// triangles cut under a curved face by their chord error. The surface counts over its whole
/// parameter domain, which reaches past the mesh's clip outline (near the outline a sample
/// may find the surface nearer than the mesh); the coverage is still the mesh's.
///
/// # Errors
/// As [`inner_face_score`], and [`CompareError::Surface`] if the inversion fails (it does
/// not for a valid surface).
pub fn inner_face_score_to_surface(
    (reconstruction, surface): (&TriangleMesh, &BSplineSurface),
    truth: &TriangleMesh,
    structures: Structures<'_>,
    options: &InnerFaceOptions,
) -> Result<InnerFaceComparison, CompareError> {
    let index = ClosestSurfacePoints::new(surface);
    let closest = |points: &[Point3<Real>]| {
        let found = index.closest_many(points).map_err(|e| CompareError::Surface {
            message: e.to_string(),
        })?;
        Ok(found.iter().map(|c| (c.point, c.distance)).collect())
    };
    score_inner_face(reconstruction, truth, structures, options, closest)
}

/// [`inner_face_score`] with the reconstruction's closest points (point, distance) to a batch
/// of points found by `closest`.
fn score_inner_face(
    reconstruction: &TriangleMesh,
    truth: &TriangleMesh,
    structures: Structures<'_>,
    options: &InnerFaceOptions,
    closest: impl Fn(&[Point3<Real>]) -> Result<Vec<(Point3<Real>, Real)>, CompareError>,
) -> Result<InnerFaceComparison, CompareError> {
    let (rec, tru) = structures;
    check_structure(rec, "reconstruction")?;
    check_structure(tru, "truth")?;
    if !(options.spacing > 0.0 && options.spacing.is_finite()) {
        return Err(CompareError::Option {
            message: format!("inner-face spacing {} must be positive", options.spacing),
        });
    }
    if !(0.0..0.9).contains(&options.trim) {
        return Err(CompareError::Option {
            message: format!("inner-face trim {} must be in [0, 0.9)", options.trim),
        });
    }
    let (unifying, _) = structure::unify(tru).map_err(|e| CompareError::Structure {
        which: "truth",
        problem: e.to_string(),
    })?;
    let view_map = Similarity3::from_isometry(unifying.isometry, 1.0);
    let truth_view = truth.transformed(&nalgebra::Affine3::from_matrix_unchecked(
        view_map.to_homogeneous(),
    ));
    let tru_view: Vec<Point3<Real>> = tru.iter().map(|p| view_map * p).collect();
    let outline = inner_face_outline(&tru_view);

    // The truth's frontal samples inside the outline.
    let (lo, hi) = crate::geometry::bounding_box(&outline).expect("the outline has points");
    let width = ((hi.x - lo.x) / options.spacing).floor() as usize + 1;
    let height = ((hi.y - lo.y) / options.spacing).floor() as usize + 1;
    if width > crate::render::MAX_SIDE || height > crate::render::MAX_SIDE {
        return Err(CompareError::Option {
            message: format!(
                "inner-face spacing {} mm makes a {width}×{height} raster",
                options.spacing
            ),
        });
    }
    let raster = crate::mesh::Raster {
        origin: lo,
        spacing: options.spacing,
        width,
        height,
    };
    let heights = crate::render::render_heights(truth_view.positions(), truth_view.triangles(), &raster);
    let mut slots = Vec::new();
    let mut samples = Vec::new();
    for j in 0..height {
        for i in 0..width {
            let z = heights[j * width + i];
            let p = raster.position(i, j);
            if z.is_finite() && crate::geometry::polygon_contains(&outline, p) {
                slots.push(j * width + i);
                samples.push(Point3::new(p.x, p.y, z));
            }
        }
    }
    if samples.len() < 3 {
        return Err(CompareError::Structure {
            which: "truth",
            problem: "its surface has no samples inside its contour and brows".into(),
        });
    }

    // Start: the similarity between the structures off the contour.
    let inner: Vec<usize> = (0..POINT_COUNT)
        .filter(|&k| structure::POINTS[k].group != structure::Group::Contour)
        .collect();
    let pick = |ps: &[Point3<Real>]| inner.iter().map(|&k| ps[k]).collect::<Vec<_>>();
    let (mut map, _) = fit_similarity(&pick(rec), &pick(&tru_view)).ok_or(CompareError::Structure {
        which: "reconstruction",
        problem: "its points are degenerate (collinear)".into(),
    })?;

    // Refine: the samples are moved into the reconstruction's frame, whose index stays fixed.
    let keep = ((samples.len() as Real) * (1.0 - options.trim)).ceil().max(3.0) as usize;
    let mut iterations = 0;
    let mut previous = Real::INFINITY;
    for _ in 0..options.iterations {
        iterations += 1;
        let inverse = map.inverse();
        let moved: Vec<Point3<Real>> = samples.iter().map(|p| inverse * p).collect();
        let found = closest(&moved)?;
        let mut order: Vec<usize> = (0..samples.len()).collect();
        order.sort_unstable_by(|&a, &b| found[a].1.total_cmp(&found[b].1));
        order.truncate(keep);
        let from: Vec<Point3<Real>> = order.iter().map(|&k| found[k].0).collect();
        let to: Vec<Point3<Real>> = order.iter().map(|&k| samples[k]).collect();
        let Some((next, rms)) = fit_similarity(&from, &to) else {
            break;
        };
        map = next;
        if previous - rms < 1e-6 * (1.0 + rms) {
            break;
        }
        previous = rms;
    }

    let inverse = map.inverse();
    let moved: Vec<Point3<Real>> = samples.iter().map(|p| inverse * p).collect();
    let scale = map.scaling();
    let mut distances = vec![Real::NAN; width * height];
    let mut values = Vec::with_capacity(samples.len());
    for (slot, (_, distance)) in slots.iter().zip(closest(&moved)?) {
        distances[*slot] = scale * distance;
        values.push(scale * distance);
    }
    let aligned = TriangleMesh::new(
        reconstruction.positions().iter().map(|p| map * p).collect(),
        reconstruction.triangles().to_vec(),
    )
    .map_err(|e| CompareError::Mesh {
        message: e.to_string(),
    })?;
    let covering = crate::render::render_heights(aligned.positions(), aligned.triangles(), &raster);
    let covered = slots.iter().filter(|&&k| covering[k].is_finite()).count();
    let mut truth_heights = vec![Real::NAN; width * height];
    for &slot in &slots {
        truth_heights[slot] = heights[slot];
    }
    Ok(InnerFaceComparison {
        score: InnerFaceScore {
            distance: ErrorStats::of(&mut values),
            coverage: covered as Real / slots.len() as Real,
            scale,
            iterations,
        },
        raster,
        distances,
        truth_heights,
        aligned,
    })
}
