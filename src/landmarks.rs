//! Landmark files: iBUG `.pts` (2D points) and vertex-index lists (which vertices of a scan are
//! the landmarks, one index a line, `#` comments, as in `landmarks68.txt`).
//!
//! Every reader names the file and the line of the first problem it meets, and never panics.

use std::path::{Path, PathBuf};

use nalgebra::Point2;

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
    let text = std::fs::read_to_string(path).map_err(|e| error(path, e.into()))?;
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
                    .map_err(|_| syntax(line, "n_points is not a whole number"))?;
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
    let text = std::fs::read_to_string(path).map_err(|e| error(path, e.into()))?;
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
