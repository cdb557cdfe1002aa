//! Landmark files: iBUG `.pts` (2D points), a JSON form (2D or 3D, 68 iBUG points or the 40 of
//! the structure, see [`parse_landmarks_json`]) and vertex-index lists (which vertices of a
//! scan are the landmarks, one index a line, `#` comments, as in `landmarks68.txt`).
//!
//! Every reader names the file and the line of the first problem it meets, and never panics.

use std::path::{Path, PathBuf};

use nalgebra::{Point, Point2, Point3};

use crate::Real;

/// More points than any landmark scheme has; a header claiming more is refused before
/// anything is allocated for it.
pub const MAX_POINTS: usize = 100_000;

/// A landmark file that could not be read.
#[derive(Debug, thiserror::Error)]
#[error("{}: {problem}", file.display())]
pub struct LandmarkError {
    /// The file.
    pub file: PathBuf,
    /// What is wrong with it.
    pub problem: LandmarkProblem,
}

/// What is wrong with a landmark file.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum LandmarkProblem {
    /// The file could not be read.
    #[error("cannot read it: {0}")]
    Io(#[from] std::io::Error),
    /// A line does not have the expected content.
    #[error("line {line}: {message}")]
    Syntax {
        /// 1-based line number.
        line: usize,
        /// What was expected.
        message: String,
    },
    /// A number is NaN or infinite.
    #[error("line {line}: the value is not finite")]
    NonFinite {
        /// 1-based line number.
        line: usize,
    },
    /// The file ends before all points are read.
    #[error("the file ends after {got} of {expected} points")]
    Truncated {
        /// Points read.
        got: usize,
        /// Points announced.
        expected: usize,
    },
    /// The number of points is not the one required.
    #[error("{got} points, expected {expected}")]
    WrongCount {
        /// Points found.
        got: usize,
        /// Points required.
        expected: usize,
    },
    /// The points have another dimension than required.
    #[error("the points are {got}D, expected {expected}D")]
    Dimension {
        /// Dimension found.
        got: usize,
        /// Dimension required.
        expected: usize,
    },
    /// Points of different dimensions in one file.
    #[error("point {point} has {got} coordinates, the first has {expected}")]
    MixedDimensions {
        /// 0-based point number.
        point: usize,
        /// Its coordinate count.
        got: usize,
        /// The first point's.
        expected: usize,
    },
    /// A point has a NaN or infinite coordinate.
    #[error("point {point} is not finite")]
    NonFinitePoint {
        /// 0-based point number.
        point: usize,
    },
    /// A vertex index is not below the mesh's vertex count.
    #[error("line {line}: vertex index {index} is out of range (the mesh has {vertices} vertices)")]
    IndexOutOfRange {
        /// 1-based line number.
        line: usize,
        /// The index.
        index: usize,
        /// The mesh's vertex count.
        vertices: usize,
    },
}

fn error(file: &Path, problem: LandmarkProblem) -> LandmarkError {
    LandmarkError {
        file: file.to_path_buf(),
        problem,
    }
}

fn syntax(line: usize, message: impl Into<String>) -> LandmarkProblem {
    LandmarkProblem::Syntax {
        line,
        message: message.into(),
    }
}

/// Reads an iBUG `.pts` file:
///
/// ```text
/// version: 1
/// n_points: 68
/// {
/// x y
/// …
/// }
/// ```
///
/// # Errors
/// A [`LandmarkError`] naming the file and the first problem.
pub fn read_pts(path: &Path) -> Result<Vec<Point2<Real>>, LandmarkError> {
    let text = crate::io::read_input_text(path, crate::io::MAX_SMALL_INPUT_BYTES)
        .map_err(|e| error(path, e.into()))?;
    parse_pts(&text).map_err(|p| error(path, p))
}

/// Parses the text of a `.pts` file (see [`read_pts`]).
///
/// # Errors
/// The first problem found, with its line number.
pub fn parse_pts(text: &str) -> Result<Vec<Point2<Real>>, LandmarkProblem> {
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty());
    let mut count = None;
    for (line, content) in lines.by_ref() {
        if content == "{" {
            break;
        }
        let (key, value) = content
            .split_once(':')
            .ok_or_else(|| syntax(line, "expected `key: value` or `{`"))?;
        match key.trim() {
            "version" => {}
            "n_points" => {
                let n: usize = value
                    .trim()
                    .parse()
                    .map_err(|_| syntax(line, format!("n_points `{}` is not a count", value.trim())))?;
                if n > MAX_POINTS {
                    return Err(syntax(
                        line,
                        format!("n_points {n} is above the limit {MAX_POINTS}"),
                    ));
                }
                count = Some(n);
            }
            other => return Err(syntax(line, format!("unknown header field `{other}`"))),
        }
    }
    let expected = count.ok_or_else(|| syntax(1, "no n_points header before `{`"))?;
    let mut points = Vec::with_capacity(expected);
    for (line, content) in lines.by_ref() {
        if content == "}" {
            if points.len() != expected {
                return Err(LandmarkProblem::WrongCount {
                    got: points.len(),
                    expected,
                });
            }
            if let Some((line, _)) = lines.next() {
                return Err(syntax(line, "text after the closing `}`"));
            }
            return Ok(points);
        }
        if points.len() == expected {
            return Err(syntax(line, format!("more than the {expected} points announced")));
        }
        let mut fields = content.split_whitespace();
        let mut number = || -> Result<Real, LandmarkProblem> {
            let field = fields
                .next()
                .ok_or_else(|| syntax(line, "expected two numbers `x y`"))?;
            let value: Real = field
                .parse()
                .map_err(|_| syntax(line, format!("`{field}` is not a number")))?;
            if value.is_finite() {
                Ok(value)
            } else {
                Err(LandmarkProblem::NonFinite { line })
            }
        };
        let (x, y) = (number()?, number()?);
        if fields.next().is_some() {
            return Err(syntax(line, "more than two numbers"));
        }
        points.push(Point2::new(x, y));
    }
    Err(LandmarkProblem::Truncated {
        got: points.len(),
        expected,
    })
}

/// Writes points in the `.pts` form [`parse_pts`] reads; numbers are written in their
/// shortest exact form, so the round trip is exact.
pub fn format_pts(points: &[Point2<Real>]) -> String {
    let mut out = format!("version: 1\nn_points: {}\n{{\n", points.len());
    for p in points {
        out.push_str(&format!("{:?} {:?}\n", p.x, p.y));
    }
    out.push_str("}\n");
    out
}

/// Reads a vertex-index list: one 0-based index a line, `#` starts a comment, blank lines are
/// ignored; exactly `expected` indices, each below `vertices`.
///
/// # Errors
/// A [`LandmarkError`] naming the file and the first problem.
pub fn read_vertex_indices(
    path: &Path,
    expected: usize,
    vertices: usize,
) -> Result<Vec<usize>, LandmarkError> {
    let text = crate::io::read_input_text(path, crate::io::MAX_SMALL_INPUT_BYTES)
        .map_err(|e| error(path, e.into()))?;
    parse_vertex_indices(&text, expected, vertices).map_err(|p| error(path, p))
}

/// Parses the text of a vertex-index list (see [`read_vertex_indices`]).
///
/// # Errors
/// The first problem found, with its line number.
pub fn parse_vertex_indices(
    text: &str,
    expected: usize,
    vertices: usize,
) -> Result<Vec<usize>, LandmarkProblem> {
    let mut indices = Vec::with_capacity(expected.min(MAX_POINTS));
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let content = raw.split('#').next().unwrap_or("").trim();
        if content.is_empty() {
            continue;
        }
        let index: usize = content
            .parse()
            .map_err(|_| syntax(line, format!("`{content}` is not a vertex index")))?;
        if index >= vertices {
            return Err(LandmarkProblem::IndexOutOfRange {
                line,
                index,
                vertices,
            });
        }
        if indices.len() == expected {
            return Err(LandmarkProblem::WrongCount {
                got: expected + 1,
                expected,
            });
        }
        indices.push(index);
    }
    if indices.len() != expected {
        return Err(LandmarkProblem::WrongCount {
            got: indices.len(),
            expected,
        });
    }
    Ok(indices)
}

/// Which points a landmark set holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Scheme {
    /// The 68-point iBUG / 300-W annotation, 0-based, in its usual order.
    Ibug68,
    /// The 40-point structure of [`crate::structure::POINTS`], in that order.
    Structure40,
}

impl Scheme {
    /// The number of points of the scheme.
    pub fn point_count(self) -> usize {
        match self {
            Self::Ibug68 => crate::structure::IBUG_POINT_COUNT,
            Self::Structure40 => crate::structure::POINT_COUNT,
        }
    }
}

/// The points of a landmark set: all 2D (image pixels, `y` down) or all 3D.
#[derive(Debug, Clone, PartialEq)]
pub enum LandmarkPoints {
    /// Image points.
    Planar(Vec<Point2<Real>>),
    /// Points in space.
    Spatial(Vec<Point3<Real>>),
}

/// A landmark set read from or written to the JSON form (see [`parse_landmarks_json`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Landmarks {
    /// The point scheme.
    pub scheme: Scheme,
    /// The points, as many as the scheme has.
    pub points: LandmarkPoints,
}

/// The JSON tag of a landmark file.
const LANDMARKS_FORMAT: &str = "splineface/landmarks";

#[derive(serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct RawLandmarks {
    format: String,
    version: u32,
    scheme: Scheme,
    points: Vec<Vec<Real>>,
}

impl Landmarks {
    /// The 40-point structure in 3D: the points themselves for [`Scheme::Structure40`],
    /// derived by [`crate::structure::from_ibug68`] for [`Scheme::Ibug68`].
    ///
    /// # Errors
    /// [`LandmarkProblem::Dimension`] if the points are 2D, [`LandmarkProblem::WrongCount`] if
    /// their number is not the scheme's.
    pub fn structure_3d(&self) -> Result<Vec<Point3<Real>>, LandmarkProblem> {
        match (&self.points, self.scheme) {
            (LandmarkPoints::Spatial(points), scheme) => structure(points, scheme),
            (LandmarkPoints::Planar(_), _) => Err(LandmarkProblem::Dimension { got: 2, expected: 3 }),
        }
    }

    /// The 40-point structure in 2D (see [`Landmarks::structure_3d`]).
    ///
    /// # Errors
    /// [`LandmarkProblem::Dimension`] if the points are 3D, [`LandmarkProblem::WrongCount`] if
    /// their number is not the scheme's.
    pub fn structure_2d(&self) -> Result<Vec<Point2<Real>>, LandmarkProblem> {
        match (&self.points, self.scheme) {
            (LandmarkPoints::Planar(points), scheme) => structure(points, scheme),
            (LandmarkPoints::Spatial(_), _) => Err(LandmarkProblem::Dimension { got: 3, expected: 2 }),
        }
    }
}

/// The 40-point structure of points in `scheme`.
fn structure<const D: usize>(
    points: &[Point<Real, D>],
    scheme: Scheme,
) -> Result<Vec<Point<Real, D>>, LandmarkProblem> {
    if points.len() != scheme.point_count() {
        return Err(LandmarkProblem::WrongCount {
            got: points.len(),
            expected: scheme.point_count(),
        });
    }
    if let Some(point) = points.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
        return Err(LandmarkProblem::NonFinitePoint { point });
    }
    Ok(match scheme {
        Scheme::Structure40 => points.to_vec(),
        Scheme::Ibug68 => crate::structure::from_ibug68(points).expect("count and values were checked"),
    })
}

/// The 40-point 3D structure of a scan from its landmark file: a JSON landmark file with 3D
/// points (68 iBUG or the structure's 40; see [`parse_landmarks_json`]), or, for any other
/// extension, a list of 68 vertex indices into `mesh` ([`read_vertex_indices`]) whose positions
/// are the iBUG points.
///
/// # Errors
/// A [`LandmarkError`] naming the file: unreadable, malformed, 2D points, or an index out of
/// the mesh's range.
pub fn read_mesh_structure(
    path: &Path,
    mesh: &crate::mesh::TriangleMesh,
) -> Result<Vec<Point3<Real>>, LandmarkError> {
    read_mesh_landmarks(path, mesh).map(|l| l.structure)
}

/// A scan's landmarks as [`read_mesh_landmarks`] reads them.
#[derive(Debug, Clone, PartialEq)]
pub struct MeshLandmarks {
    /// The 40-point structure.
    pub structure: Vec<Point3<Real>>,
    /// The 68 iBUG points it was made from, when the file gives them.
    pub ibug: Option<Vec<Point3<Real>>>,
}

/// [`read_mesh_structure`], with the 68 iBUG points themselves when the file gives them (68
/// vertex indices, or a JSON file of the `ibug68` scheme); none for a file of the structure's
/// 40 points.
///
/// # Errors
/// As [`read_mesh_structure`].
pub fn read_mesh_landmarks(
    path: &Path,
    mesh: &crate::mesh::TriangleMesh,
) -> Result<MeshLandmarks, LandmarkError> {
    if path.extension().is_some_and(|e| e.eq_ignore_ascii_case("json")) {
        let landmarks = read_landmarks_json(path)?;
        let structure = landmarks.structure_3d().map_err(|problem| error(path, problem))?;
        let ibug = match (landmarks.scheme, landmarks.points) {
            (Scheme::Ibug68, LandmarkPoints::Spatial(points)) => Some(points),
            _ => None,
        };
        return Ok(MeshLandmarks { structure, ibug });
    }
    let indices = read_vertex_indices(path, crate::structure::IBUG_POINT_COUNT, mesh.positions().len())?;
    let points: Vec<_> = indices.iter().map(|&i| mesh.positions()[i]).collect();
    let structure = structure(&points, Scheme::Ibug68).map_err(|problem| error(path, problem))?;
    Ok(MeshLandmarks {
        structure,
        ibug: Some(points),
    })
}

/// Reads a JSON landmark file (the form is on [`parse_landmarks_json`]).
///
/// # Errors
/// A [`LandmarkError`] naming the file and the problem.
pub fn read_landmarks_json(path: &Path) -> Result<Landmarks, LandmarkError> {
    let text = crate::io::read_input_text(path, crate::io::MAX_SMALL_INPUT_BYTES)
        .map_err(|e| error(path, e.into()))?;
    parse_landmarks_json(&text).map_err(|p| error(path, p))
}

/// Parses the JSON landmark form:
///
/// ```json
/// {
///   "format": "splineface/landmarks",
///   "version": 1,
///   "scheme": "ibug68",
///   "points": [[x, y], …]
/// }
/// ```
///
/// `scheme` is `"ibug68"` (68 points, iBUG order) or `"structure40"` (the 40 points of
/// [`crate::structure::POINTS`], in order). `points` holds exactly that many points, all `[x, y]`
/// (image pixels, `y` down) or all `[x, y, z]`. Unknown fields are refused.
///
/// # Errors
/// The first problem: malformed JSON (with its line), another format or version, a wrong point
/// count, mixed or unsupported dimensions.
pub fn parse_landmarks_json(text: &str) -> Result<Landmarks, LandmarkProblem> {
    if !text.trim_start().starts_with('{') {
        return Err(syntax(
            1,
            "expected a JSON object ({\"format\": \"splineface/landmarks\", …})",
        ));
    }
    let raw: RawLandmarks =
        serde_json::from_str(text).map_err(|e| syntax(e.line(), crate::io::json_message(&e)))?;
    if raw.format != LANDMARKS_FORMAT {
        return Err(syntax(
            1,
            format!("format is {:?}, expected {LANDMARKS_FORMAT:?}", raw.format),
        ));
    }
    if raw.version != 1 {
        return Err(syntax(
            1,
            format!(
                "version {} is not supported (this build reads version 1)",
                raw.version
            ),
        ));
    }
    let expected = raw.scheme.point_count();
    if raw.points.len() != expected {
        return Err(LandmarkProblem::WrongCount {
            got: raw.points.len(),
            expected,
        });
    }
    let dimension = raw.points[0].len();
    if let Some(k) = raw.points.iter().position(|p| p.len() != dimension) {
        return Err(LandmarkProblem::MixedDimensions {
            point: k,
            got: raw.points[k].len(),
            expected: dimension,
        });
    }
    if let Some(k) = raw.points.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
        return Err(LandmarkProblem::NonFinitePoint { point: k });
    }
    let points = match dimension {
        2 => LandmarkPoints::Planar(raw.points.iter().map(|p| Point2::new(p[0], p[1])).collect()),
        3 => LandmarkPoints::Spatial(raw.points.iter().map(|p| Point3::new(p[0], p[1], p[2])).collect()),
        got => {
            return Err(syntax(
                1,
                format!("the points have {got} coordinates each, expected 2 or 3"),
            ));
        }
    };
    Ok(Landmarks {
        scheme: raw.scheme,
        points,
    })
}

/// Writes a landmark set in the JSON form [`parse_landmarks_json`] reads; the round trip is
/// exact.
///
/// # Errors
/// [`LandmarkProblem::WrongCount`] if the number of points is not the scheme's, and
/// [`LandmarkProblem::NonFinitePoint`] for a NaN or infinite coordinate (JSON cannot hold it).
pub fn format_landmarks_json(landmarks: &Landmarks) -> Result<String, LandmarkProblem> {
    let points: Vec<Vec<Real>> = match &landmarks.points {
        LandmarkPoints::Planar(points) => points.iter().map(|p| vec![p.x, p.y]).collect(),
        LandmarkPoints::Spatial(points) => points.iter().map(|p| vec![p.x, p.y, p.z]).collect(),
    };
    let expected = landmarks.scheme.point_count();
    if points.len() != expected {
        return Err(LandmarkProblem::WrongCount {
            got: points.len(),
            expected,
        });
    }
    if let Some(k) = points.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
        return Err(LandmarkProblem::NonFinitePoint { point: k });
    }
    let raw = RawLandmarks {
        format: LANDMARKS_FORMAT.to_owned(),
        version: 1,
        scheme: landmarks.scheme,
        points,
    };
    Ok(serde_json::to_string_pretty(&raw).expect("finite numbers always serialise"))
}
