//! A pure-Rust reader and runtime for dlib's `shape_predictor` files: the ensemble of
//! regression trees of Kazemi & Sullivan (CVPR 2014) that finds 68 landmarks in a face box.
//!
//! # The file
//!
//! dlib's serialisation: an integer is a control byte (bit 7: negative, low 4 bits: the byte
//! count) then that many little-endian bytes; a `float` is an integer mantissa `m` and an
//! integer exponent `e` (`m·2^e`; `e` = 32000, 32001, 32002 mark +∞, −∞, NaN); a vector is its
//! length then its items; a matrix is `−rows`, `−cols` then its values row by row. The model is
//! a version (1), the mean shape (a column of `2·points` values, box-normalised), the cascades'
//! forests (each tree: splits `{idx1, idx2, threshold}`, then leaves of `2·points` values), the
//! anchor point of every feature pixel per cascade, and the pixel offsets (`deltas`) from them.
//!
//! Every length is checked against the bytes left before anything is allocated, so a damaged
//! file is an error, never a panic or a huge allocation.
//!
//! # The runtime
//!
//! Per cascade: the similarity from the mean shape to the current shape turns each feature
//! pixel's offset; the pixel is read (the mean of r, g, b, integer) where the box maps it, 0
//! outside the image; every tree descends by `f[idx1] − f[idx2] > threshold` (to child `2i+1`,
//! else `2i+2`) and adds its leaf to the shape. The result is mapped from the box's unit square
//! to the image (`(0,0)` → top-left corner, `(1,1)` → bottom-right).

use std::path::{Path, PathBuf};

use nalgebra::{Matrix2, Point2, Vector2};

use crate::Real;

/// A `shape_predictor` model.
#[derive(Debug, Clone)]
pub struct ShapePredictor {
    /// The mean shape, `(x, y)` per point, box-normalised.
    initial: Vec<[f32; 2]>,
    cascades: Vec<Cascade>,
}

#[derive(Debug, Clone)]
struct Cascade {
    anchors: Vec<u32>,
    deltas: Vec<[f32; 2]>,
    trees: Vec<Tree>,
}

#[derive(Debug, Clone)]
struct Tree {
    splits: Vec<Split>,
    /// Leaves, each `2·points` values.
    leaves: Vec<f32>,
}

#[derive(Debug, Clone, Copy)]
struct Split {
    idx1: u32,
    idx2: u32,
    threshold: f32,
}

/// A face box in image pixels, corners included (dlib's `rectangle`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FaceBox {
    /// Left column.
    pub left: i64,
    /// Top row.
    pub top: i64,
    /// Right column (inclusive).
    pub right: i64,
    /// Bottom row (inclusive).
    pub bottom: i64,
}

impl FaceBox {
    /// The box with top-left corner `(left, top)` and the given size (as dlib's XML gives it).
    pub fn from_size(left: i64, top: i64, width: i64, height: i64) -> Self {
        FaceBox {
            left,
            top,
            right: left + width - 1,
            bottom: top + height - 1,
        }
    }
}

/// An 8-bit intensity image (row-major from the top).
#[derive(Debug, Clone)]
pub struct Intensity {
    width: usize,
    height: usize,
    data: Vec<u8>,
}

impl Intensity {
    /// The intensity dlib reads from a colour image: `(r + g + b) / 3`, integer division.
    pub fn from_rgb(image: &image::RgbImage) -> Self {
        let data = image
            .pixels()
            .map(|p| ((u16::from(p[0]) + u16::from(p[1]) + u16::from(p[2])) / 3) as u8)
            .collect();
        Intensity {
            width: image.width() as usize,
            height: image.height() as usize,
            data,
        }
    }

    fn get(&self, x: i64, y: i64) -> u8 {
        if x >= 0 && y >= 0 && (x as usize) < self.width && (y as usize) < self.height {
            self.data[y as usize * self.width + x as usize]
        } else {
            0
        }
    }
}

/// A model file that could not be read.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{}: {problem}", file.display())]
pub struct ModelError {
    /// The file.
    pub file: PathBuf,
    /// What is wrong.
    pub problem: ModelProblem,
}

/// What is wrong with a model file.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ModelProblem {
    /// The file could not be read.
    #[error("cannot read the file: {0}")]
    Io(String),
    /// The bytes end early.
    #[error("truncated at byte {0}: not a complete dlib shape_predictor file")]
    Truncated(usize),
    /// Something is malformed.
    #[error("at byte {at}: {message}")]
    Malformed {
        /// Where.
        at: usize,
        /// What.
        message: String,
    },
}

/// A cursor over dlib's serialisation.
struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn malformed(&self, message: impl Into<String>) -> ModelProblem {
        ModelProblem::Malformed {
            at: self.at,
            message: message.into(),
        }
    }

    fn integer(&mut self) -> Result<i64, ModelProblem> {
        let &control = self.bytes.get(self.at).ok_or(ModelProblem::Truncated(self.at))?;
        let size = usize::from(control & 0x0f);
        if size > 8 || control & 0x70 != 0 {
            return Err(self.malformed(format!("bad integer control byte 0x{control:02x}")));
        }
        let body = self
            .bytes
            .get(self.at + 1..self.at + 1 + size)
            .ok_or(ModelProblem::Truncated(self.at))?;
        let mut value: u64 = 0;
        for (i, &b) in body.iter().enumerate() {
            value |= u64::from(b) << (8 * i);
        }
        if value > i64::MAX as u64 {
            return Err(self.malformed("integer out of range"));
        }
        self.at += 1 + size;
        let value = value as i64;
        Ok(if control & 0x80 != 0 { -value } else { value })
    }

    fn count(&mut self, item_bytes: usize, what: &str) -> Result<usize, ModelProblem> {
        let at = self.at;
        let n = self.integer()?;
        // Every item takes at least `item_bytes` bytes: a length beyond what is left is damage.
        let left = self.bytes.len() - self.at;
        if n < 0 || (n as u64).saturating_mul(item_bytes as u64) > left as u64 {
            return Err(ModelProblem::Malformed {
                at,
                message: format!("{what} claims {n} items, more than the file holds"),
            });
        }
        Ok(n as usize)
    }

    fn float(&mut self) -> Result<f32, ModelProblem> {
        let mantissa = self.integer()?;
        let exponent = self.integer()?;
        match exponent {
            32000 => Ok(f32::INFINITY),
            32001 => Ok(f32::NEG_INFINITY),
            32002 => Ok(f32::NAN),
            e if (-2000..=2000).contains(&e) => Ok((mantissa as f64 * 2f64.powi(e as i32)) as f32),
            e => Err(self.malformed(format!("float exponent {e} out of range"))),
        }
    }

    /// A column vector (`matrix<float,0,1>`): `−rows`, `−cols`, values.
    fn column(&mut self) -> Result<Vec<f32>, ModelProblem> {
        let at = self.at;
        let (rows, cols) = (self.integer()?, self.integer()?);
        let (rows, cols) = (rows.unsigned_abs(), cols.unsigned_abs());
        if cols != 1 && rows != 0 {
            return Err(ModelProblem::Malformed {
                at,
                message: format!("expected a column vector, found {rows}×{cols}"),
            });
        }
        let n = rows.saturating_mul(cols);
        if n.saturating_mul(2) > (self.bytes.len() - self.at) as u64 {
            return Err(ModelProblem::Malformed {
                at,
                message: format!("a {rows}×{cols} matrix is larger than the file"),
            });
        }
        (0..n).map(|_| self.float()).collect()
    }
}

impl ShapePredictor {
    /// Reads a model file (e.g. `shape_predictor_68_face_landmarks.dat`).
    ///
    /// # Errors
    /// A [`ModelError`] naming the file.
    pub fn read(path: &Path) -> Result<Self, ModelError> {
        let error = |problem| ModelError {
            file: path.to_path_buf(),
            problem,
        };
        let bytes = crate::io::read_input(path, crate::io::MAX_DATA_INPUT_BYTES)
            .map_err(|e| error(ModelProblem::Io(e.to_string())))?;
        Self::parse(&bytes).map_err(error)
    }

    /// Parses a model (see the module documentation).
    ///
    /// # Errors
    /// The first problem, with its byte offset.
    pub fn parse(bytes: &[u8]) -> Result<Self, ModelProblem> {
        let mut r = Reader { bytes, at: 0 };
        let version = r.integer()?;
        if version != 1 {
            return Err(ModelProblem::Malformed {
                at: 0,
                message: format!("version {version}; this reader knows version 1"),
            });
        }
        let initial = r.column()?;
        if initial.is_empty() || initial.len() % 2 != 0 || initial.iter().any(|v| !v.is_finite()) {
            return Err(r.malformed("the mean shape must hold finite (x, y) pairs"));
        }
        let dims = initial.len();
        let points = dims / 2;
        let cascades = r.count(2, "the forests")?;
        let mut forests = Vec::with_capacity(cascades);
        for _ in 0..cascades {
            let trees = r.count(4, "a forest")?;
            let mut forest = Vec::with_capacity(trees);
            for _ in 0..trees {
                let n_splits = r.count(6, "a tree's splits")?;
                let mut splits = Vec::with_capacity(n_splits);
                for _ in 0..n_splits {
                    let (idx1, idx2) = (r.integer()?, r.integer()?);
                    let threshold = r.float()?;
                    let (Ok(idx1), Ok(idx2)) = (u32::try_from(idx1), u32::try_from(idx2)) else {
                        return Err(r.malformed("a split's feature index is out of range"));
                    };
                    splits.push(Split {
                        idx1,
                        idx2,
                        threshold,
                    });
                }
                let n_leaves = r.count(2, "a tree's leaves")?;
                if n_leaves != n_splits + 1 {
                    return Err(r.malformed(format!("{n_leaves} leaves for {n_splits} splits")));
                }
                // Each value takes at least two bytes: reserve no more than the file can hold.
                let mut leaves = Vec::with_capacity(n_leaves.saturating_mul(dims).min(bytes.len() / 2));
                for _ in 0..n_leaves {
                    let leaf = r.column()?;
                    if leaf.len() != dims {
                        return Err(
                            r.malformed(format!("a leaf of {} values for a shape of {dims}", leaf.len()))
                        );
                    }
                    leaves.extend(leaf);
                }
                forest.push(Tree { splits, leaves });
            }
            forests.push(forest);
        }
        let n_anchor_sets = r.count(1, "the anchors")?;
        if n_anchor_sets != cascades {
            return Err(r.malformed(format!("{n_anchor_sets} anchor sets for {cascades} cascades")));
        }
        let mut anchors = Vec::with_capacity(cascades);
        for _ in 0..cascades {
            let n = r.count(2, "an anchor set")?;
            let set: Vec<u32> = (0..n)
                .map(|_| {
                    let a = r.integer()?;
                    u32::try_from(a)
                        .ok()
                        .filter(|&a| (a as usize) < points)
                        .ok_or_else(|| r.malformed(format!("anchor {a} is not one of the {points} points")))
                })
                .collect::<Result<_, _>>()?;
            anchors.push(set);
        }
        let n_delta_sets = r.count(1, "the deltas")?;
        if n_delta_sets != cascades {
            return Err(r.malformed(format!("{n_delta_sets} delta sets for {cascades} cascades")));
        }
        let mut result = Vec::with_capacity(cascades);
        for (trees, anchors) in forests.into_iter().zip(anchors) {
            let n = r.count(4, "a delta set")?;
            if n != anchors.len() {
                return Err(r.malformed(format!("{n} deltas for {} anchors", anchors.len())));
            }
            let deltas: Vec<[f32; 2]> = (0..n)
                .map(|_| Ok([r.float()?, r.float()?]))
                .collect::<Result<_, ModelProblem>>()?;
            for tree in &trees {
                if tree
                    .splits
                    .iter()
                    .any(|s| s.idx1 as usize >= n || s.idx2 as usize >= n)
                {
                    return Err(r.malformed("a split reads a feature pixel the cascade does not have"));
                }
            }
            result.push(Cascade {
                anchors,
                deltas,
                trees,
            });
        }
        Ok(ShapePredictor {
            initial: initial.chunks_exact(2).map(|c| [c[0], c[1]]).collect(),
            cascades: result,
        })
    }

    /// The number of landmarks (68 for the iBUG model).
    pub fn points(&self) -> usize {
        self.initial.len()
    }

    /// The box in which the model's mean shape fits `points` best (least squares over a shift
    /// and one scale: dlib's boxes are square): the box a face with these landmarks is
    /// predicted from most naturally. Fed back to [`ShapePredictor::predict`], it re-centres a
    /// prediction made from a box that framed the face poorly.
    pub fn box_for(&self, points: &[Point2<Real>]) -> Option<FaceBox> {
        if points.len() != self.initial.len() || points.is_empty() {
            return None;
        }
        let n = points.len() as Real;
        let mean_of = |xs: &mut dyn Iterator<Item = (Real, Real)>| {
            let (sx, sy) = xs.fold((0.0, 0.0), |(a, b), (x, y)| (a + x, b + y));
            (sx / n, sy / n)
        };
        let (mx, my) = mean_of(&mut self.initial.iter().map(|p| (Real::from(p[0]), Real::from(p[1]))));
        let (px, py) = mean_of(&mut points.iter().map(|p| (p.x, p.y)));
        let (mut cross, mut var) = (0.0, 0.0);
        for (m, p) in self.initial.iter().zip(points) {
            let (dx, dy) = (Real::from(m[0]) - mx, Real::from(m[1]) - my);
            cross += dx * (p.x - px) + dy * (p.y - py);
            var += dx * dx + dy * dy;
        }
        let side = cross / var;
        if !(side > 1.0 && side.is_finite()) {
            return None;
        }
        let (left, top) = (px - side * mx, py - side * my);
        Some(FaceBox {
            left: left.round() as i64,
            top: top.round() as i64,
            right: (left + side).round() as i64,
            bottom: (top + side).round() as i64,
        })
    }

    /// The landmarks of the face in `face`, in image pixels.
    pub fn predict(&self, image: &Intensity, face: FaceBox) -> Vec<Point2<Real>> {
        let n = self.initial.len();
        let mut shape: Vec<[f32; 2]> = self.initial.clone();
        let (left, top) = (face.left as f32, face.top as f32);
        let (width, height) = ((face.right - face.left) as f32, (face.bottom - face.top) as f32);
        let to_image = |p: [f32; 2]| [left + p[0] * width, top + p[1] * height];
        let mut features = Vec::new();
        for cascade in &self.cascades {
            let turn = similarity_linear(&self.initial, &shape);
            features.clear();
            features.extend(cascade.anchors.iter().zip(&cascade.deltas).map(|(&a, d)| {
                let anchor = shape[a as usize];
                let p = [
                    turn[(0, 0)] * d[0] + turn[(0, 1)] * d[1] + anchor[0],
                    turn[(1, 0)] * d[0] + turn[(1, 1)] * d[1] + anchor[1],
                ];
                let q = to_image(p);
                // dlib rounds to the nearest pixel.
                f32::from(image.get((q[0] + 0.5).floor() as i64, (q[1] + 0.5).floor() as i64))
            }));
            for tree in &cascade.trees {
                let mut i = 0usize;
                while i < tree.splits.len() {
                    let s = &tree.splits[i];
                    i = if features[s.idx1 as usize] - features[s.idx2 as usize] > s.threshold {
                        2 * i + 1
                    } else {
                        2 * i + 2
                    };
                }
                let leaf = &tree.leaves[(i - tree.splits.len()) * 2 * n..(i - tree.splits.len() + 1) * 2 * n];
                for (p, d) in shape.iter_mut().zip(leaf.chunks_exact(2)) {
                    p[0] += d[0];
                    p[1] += d[1];
                }
            }
        }
        shape
            .iter()
            .map(|&p| {
                let q = to_image(p);
                Point2::new(Real::from(q[0]), Real::from(q[1]))
            })
            .collect()
    }
}

/// The linear part `c·R` of the least-squares similarity taking `from` onto `to` (Umeyama
/// 1991, as dlib's `find_similarity_transform`), in `f32` as dlib uses it.
fn similarity_linear(from: &[[f32; 2]], to: &[[f32; 2]]) -> Matrix2<f32> {
    let n = from.len() as f64;
    let mean = |ps: &[[f32; 2]]| {
        ps.iter().fold(Vector2::<f64>::zeros(), |s, p| {
            s + Vector2::new(f64::from(p[0]), f64::from(p[1]))
        }) / n
    };
    let (mf, mt) = (mean(from), mean(to));
    let mut sigma_from = 0.0;
    let mut cov = Matrix2::<f64>::zeros();
    for (a, b) in from.iter().zip(to) {
        let x = Vector2::new(f64::from(a[0]), f64::from(a[1])) - mf;
        let y = Vector2::new(f64::from(b[0]), f64::from(b[1])) - mt;
        sigma_from += x.norm_squared();
        cov += y * x.transpose();
    }
    sigma_from /= n;
    cov /= n;
    let svd = cov.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Matrix2::identity();
    };
    let mut s = Matrix2::<f64>::identity();
    if cov.determinant() < 0.0 || (cov.determinant() == 0.0 && (u * v_t).determinant() < 0.0) {
        // Pick the reflection-free solution on the smaller singular value.
        let k = if svd.singular_values[1] < svd.singular_values[0] {
            1
        } else {
            0
        };
        s[(k, k)] = -1.0;
    }
    let rotation = u * s * v_t;
    let c = if sigma_from != 0.0 {
        (Matrix2::from_diagonal(&svd.singular_values) * s).trace() / sigma_from
    } else {
        1.0
    };
    (rotation * c).map(|x| x as f32)
}
