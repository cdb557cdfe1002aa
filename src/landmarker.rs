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
#[derive(Debug, Clone, PartialEq)]
pub struct ShapePredictor {
    /// The mean shape, `(x, y)` per point, box-normalised.
    initial: Vec<[f32; 2]>,
    cascades: Vec<Cascade>,
}

#[derive(Debug, Clone, PartialEq)]
struct Cascade {
    anchors: Vec<u32>,
    deltas: Vec<[f32; 2]>,
    /// Each tree's place in `splits` and `leaves`.
    trees: Vec<TreeSpan>,
    /// Every tree's splits, tree after tree (each tree's in heap order: children of `i` at
    /// `2i + 1` and `2i + 2`).
    splits: Vec<Split>,
    /// Every tree's leaves, tree after tree, each leaf `2·points` values.
    leaves: Vec<f32>,
}

/// Where a tree's splits and leaves are in its cascade (it has `splits + 1` leaves).
#[derive(Debug, Clone, Copy, PartialEq)]
struct TreeSpan {
    split_start: usize,
    splits: usize,
    leaf_start: usize,
}

#[derive(Debug, Clone, Copy, PartialEq)]
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
#[derive(Debug, Clone, PartialEq, Eq)]
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

    /// The mirror image (left and right swapped): the intensity of the mirrored colour image,
    /// formed without it.
    pub fn mirrored(&self) -> Self {
        let mut data = self.data.clone();
        if self.width > 0 {
            for row in data.chunks_exact_mut(self.width) {
                row.reverse();
            }
        }
        Intensity { data, ..*self }
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
    /// A `.dat` was expected and the file is already in the compact form
    /// ([`write_compact`]).
    #[error("it is already in the compact form")]
    AlreadyCompact,
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
    /// Reads a model file: dlib's (e.g. `shape_predictor_68_face_landmarks.dat`, parsed) or
    /// splineface's compact form of one ([`ShapePredictor::to_compact`], copied into place),
    /// told apart by the compact form's first bytes.
    ///
    /// # Errors
    /// A [`ModelError`] naming the file.
    pub fn read(path: &Path) -> Result<Self, ModelError> {
        let error = |problem| ModelError {
            file: path.to_path_buf(),
            problem,
        };
        let io = |e: std::io::Error| error(ModelProblem::Io(e.to_string()));
        let mut file = crate::io::open_input(path, crate::io::MAX_DATA_INPUT_BYTES)
            .map_err(|e| error(ModelProblem::Io(e.to_string())))?;
        let length = file.metadata().map_err(io)?.len();
        let mut magic = [0u8; 16];
        let compact = {
            use std::io::{Read, Seek};
            let n = file.read(&mut magic).map_err(io)?;
            file.rewind().map_err(io)?;
            n == 16 && &magic == COMPACT_MAGIC
        };
        if compact {
            return Self::read_compact_file(path, file, length).map_err(error);
        }
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
        let mut forests: Vec<(Vec<TreeSpan>, Vec<Split>, Vec<f32>)> = Vec::with_capacity(cascades);
        for _ in 0..cascades {
            let trees = r.count(4, "a forest")?;
            let mut spans = Vec::with_capacity(trees);
            let mut splits = Vec::new();
            let mut leaves = Vec::new();
            for _ in 0..trees {
                let n_splits = r.count(6, "a tree's splits")?;
                let span = TreeSpan {
                    split_start: splits.len(),
                    splits: n_splits,
                    leaf_start: leaves.len(),
                };
                splits.reserve(n_splits);
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
                leaves.reserve(n_leaves.saturating_mul(dims).min(bytes.len() / 2));
                for _ in 0..n_leaves {
                    let leaf = r.column()?;
                    if leaf.len() != dims {
                        return Err(
                            r.malformed(format!("a leaf of {} values for a shape of {dims}", leaf.len()))
                        );
                    }
                    leaves.extend(leaf);
                }
                spans.push(span);
            }
            forests.push((spans, splits, leaves));
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
        for ((trees, splits, leaves), anchors) in forests.into_iter().zip(anchors) {
            let n = r.count(4, "a delta set")?;
            if n != anchors.len() {
                return Err(r.malformed(format!("{n} deltas for {} anchors", anchors.len())));
            }
            let deltas: Vec<[f32; 2]> = (0..n)
                .map(|_| Ok([r.float()?, r.float()?]))
                .collect::<Result<_, ModelProblem>>()?;
            if splits
                .iter()
                .any(|s| s.idx1 as usize >= n || s.idx2 as usize >= n)
            {
                return Err(r.malformed("a split reads a feature pixel the cascade does not have"));
            }
            result.push(Cascade {
                anchors,
                deltas,
                trees,
                splits,
                leaves,
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
        self.predict_all(&[(image, face)])
            .pop()
            .expect("one answer for one face")
    }

    /// The landmarks of several faces (each an image and a box), each exactly as
    /// [`ShapePredictor::predict`] gives it.
    ///
    /// The faces go through the cascades together, tree by tree: the model's leaves (65 MB for
    /// dlib's 68-point model) are read from memory once a tree for all of them rather than once
    /// a face, and the faces' reads overlap. Each face's sums are formed in the same order as
    /// alone, so the answers are bit-identical.
    pub fn predict_all(&self, faces: &[(&Intensity, FaceBox)]) -> Vec<Vec<Point2<Real>>> {
        let n = self.initial.len();
        // Each face's box: its corner and size, for the model's unit-square shape.
        let frames: Vec<[f32; 4]> = faces
            .iter()
            .map(|(_, face)| {
                [
                    face.left as f32,
                    face.top as f32,
                    (face.right - face.left) as f32,
                    (face.bottom - face.top) as f32,
                ]
            })
            .collect();
        let to_image = |f: &[f32; 4], p: [f32; 2]| [f[0] + p[0] * f[2], f[1] + p[1] * f[3]];
        let mut shapes: Vec<Vec<[f32; 2]>> = vec![self.initial.clone(); faces.len()];
        let mut features: Vec<Vec<f32>> = vec![Vec::new(); faces.len()];
        for cascade in &self.cascades {
            for (((image, _), frame), (shape, features)) in
                faces.iter().zip(&frames).zip(shapes.iter().zip(&mut features))
            {
                let turn = similarity_linear(&self.initial, shape);
                features.clear();
                features.extend(cascade.anchors.iter().zip(&cascade.deltas).map(|(&a, d)| {
                    let anchor = shape[a as usize];
                    let p = [
                        turn[(0, 0)] * d[0] + turn[(0, 1)] * d[1] + anchor[0],
                        turn[(1, 0)] * d[0] + turn[(1, 1)] * d[1] + anchor[1],
                    ];
                    let q = to_image(frame, p);
                    // dlib rounds to the nearest pixel.
                    f32::from(image.get(nearest(q[0]), nearest(q[1])))
                }));
            }
            for tree in &cascade.trees {
                let splits = &cascade.splits[tree.split_start..tree.split_start + tree.splits];
                for (shape, features) in shapes.iter_mut().zip(&features) {
                    let mut i = 0usize;
                    while i < splits.len() {
                        let s = &splits[i];
                        i = if features[s.idx1 as usize] - features[s.idx2 as usize] > s.threshold {
                            2 * i + 1
                        } else {
                            2 * i + 2
                        };
                    }
                    let start = tree.leaf_start + (i - splits.len()) * 2 * n;
                    let leaf = &cascade.leaves[start..start + 2 * n];
                    for (p, d) in shape.iter_mut().zip(leaf.chunks_exact(2)) {
                        p[0] += d[0];
                        p[1] += d[1];
                    }
                }
            }
        }
        shapes
            .iter()
            .zip(&frames)
            .map(|(shape, frame)| {
                shape
                    .iter()
                    .map(|&p| {
                        let q = to_image(frame, p);
                        Point2::new(Real::from(q[0]), Real::from(q[1]))
                    })
                    .collect()
            })
            .collect()
    }
}

/// `⌊x + ½⌋`, by truncation where that is the floor (no call into libm on baseline x86-64).
fn nearest(x: f32) -> i64 {
    let x = x + 0.5;
    if x >= 0.0 { x as i64 } else { x.floor() as i64 }
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

/// The first 16 bytes of splineface's compact form of a model ([`ShapePredictor::to_compact`]).
pub const COMPACT_MAGIC: &[u8; 16] = b"splineface-sp-1\n";

/// The dlib file a compact model was made from: its length and FNV-1a 64 hash
/// ([`crate::io::fnv1a64`]), recorded in the compact file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ModelSource {
    /// The `.dat` file's length in bytes.
    pub bytes: u64,
    /// Its FNV-1a 64 hash.
    pub fnv1a64: u64,
}

impl ModelSource {
    /// The source record of a `.dat` file's bytes.
    pub fn of(bytes: &[u8]) -> Self {
        ModelSource {
            bytes: bytes.len() as u64,
            fnv1a64: crate::io::fnv1a64(bytes),
        }
    }
}

/// Little-endian arrays read straight into place: the compact form's reader.
struct CompactReader<R> {
    reader: R,
    /// Bytes left in the file.
    left: u64,
    /// Bytes read so far.
    at: u64,
}

impl<R: std::io::Read> CompactReader<R> {
    fn fill(&mut self, bytes: &mut [u8]) -> Result<(), ModelProblem> {
        if bytes.len() as u64 > self.left {
            return Err(ModelProblem::Truncated(self.at as usize));
        }
        self.reader.read_exact(bytes).map_err(|e| match e.kind() {
            std::io::ErrorKind::UnexpectedEof => ModelProblem::Truncated(self.at as usize),
            _ => ModelProblem::Io(e.to_string()),
        })?;
        self.left -= bytes.len() as u64;
        self.at += bytes.len() as u64;
        Ok(())
    }

    /// Whether `n` 32-bit values fit in the bytes left (checked before anything is allocated).
    fn check_values(&self, n: usize, what: &str) -> Result<(), ModelProblem> {
        if (n as u64).saturating_mul(4) > self.left {
            return Err(ModelProblem::Malformed {
                at: self.at as usize,
                message: format!("{what} claims {n} values, more than the file holds"),
            });
        }
        Ok(())
    }

    /// `n` 32-bit words, checked against the bytes left before anything is allocated.
    fn words(&mut self, n: usize, what: &str) -> Result<Vec<u32>, ModelProblem> {
        self.check_values(n, what)?;
        let mut words = vec![0u32; n];
        self.fill(bytemuck::cast_slice_mut(&mut words))?;
        if cfg!(target_endian = "big") {
            for w in &mut words {
                *w = u32::from_le(*w);
            }
        }
        Ok(words)
    }

    fn word(&mut self) -> Result<u32, ModelProblem> {
        Ok(self.words(1, "a count")?[0])
    }

    fn count(&mut self, what: &str) -> Result<usize, ModelProblem> {
        let n = self.word()? as usize;
        if (n as u64) > self.left {
            return Err(ModelProblem::Malformed {
                at: self.at as usize - 4,
                message: format!("{what} claims {n} items, more than the file holds"),
            });
        }
        Ok(n)
    }

    fn floats(&mut self, n: usize, what: &str) -> Result<Vec<f32>, ModelProblem> {
        if cfg!(target_endian = "little") {
            self.check_values(n, what)?;
            let mut values = vec![0f32; n];
            self.fill(bytemuck::cast_slice_mut(&mut values))?;
            Ok(values)
        } else {
            Ok(self.words(n, what)?.into_iter().map(f32::from_bits).collect())
        }
    }
}

fn push_words(out: &mut Vec<u8>, words: impl IntoIterator<Item = u32>) {
    for w in words {
        out.extend_from_slice(&w.to_le_bytes());
    }
}

fn push_floats<'a>(out: &mut Vec<u8>, values: impl IntoIterator<Item = &'a f32>) {
    push_words(out, values.into_iter().map(|v| v.to_bits()));
}

impl ShapePredictor {
    /// The model in splineface's compact form: the same trees, every number a little-endian
    /// 32-bit word, arrays laid end to end, so that reading it is copying it into place
    /// (`tools/fetch-models` writes one beside the `.dat`; `splineface compact-model` makes
    /// one). `source` records the `.dat` it came from.
    ///
    /// The layout: [`COMPACT_MAGIC`]; the source's length and hash (two `u64`); the points,
    /// the cascades (`u32`); the mean shape (`2·points` `f32`); then per cascade the feature
    /// count `m`, `m` anchors (`u32`), `2m` deltas (`f32`), the tree count `t`, `t` split
    /// counts (`u32`), every split (`idx1`, `idx2` as `u32`, `threshold` as `f32`) and every
    /// leaf (`2·points` `f32` each, `splits + 1` a tree).
    pub fn to_compact(&self, source: ModelSource) -> Vec<u8> {
        let leaf_values: usize = self.cascades.iter().map(|c| c.leaves.len()).sum();
        let mut out = Vec::with_capacity(64 + 4 * leaf_values + 12 * self.cascades.len() * 10_000);
        out.extend_from_slice(COMPACT_MAGIC);
        out.extend_from_slice(&source.bytes.to_le_bytes());
        out.extend_from_slice(&source.fnv1a64.to_le_bytes());
        push_words(&mut out, [self.initial.len() as u32, self.cascades.len() as u32]);
        push_floats(&mut out, self.initial.iter().flatten());
        for c in &self.cascades {
            push_words(&mut out, [c.anchors.len() as u32]);
            push_words(&mut out, c.anchors.iter().copied());
            push_floats(&mut out, c.deltas.iter().flatten());
            push_words(&mut out, [c.trees.len() as u32]);
            push_words(&mut out, c.trees.iter().map(|t| t.splits as u32));
            push_words(
                &mut out,
                c.splits
                    .iter()
                    .flat_map(|s| [s.idx1, s.idx2, s.threshold.to_bits()]),
            );
            push_floats(&mut out, &c.leaves);
        }
        out
    }

    /// Reads a model in the compact form from `reader`, `length` bytes long, checking every
    /// count against the bytes left and every index against what it indexes; returns the
    /// model and its recorded source.
    ///
    /// # Errors
    /// The first problem, with its byte offset.
    pub fn read_compact(
        reader: impl std::io::Read,
        length: u64,
    ) -> Result<(Self, ModelSource), ModelProblem> {
        let mut r = CompactReader {
            reader,
            left: length,
            at: 0,
        };
        Self::read_compact_from(&mut r, None).map(|(model, source, _)| (model, source))
    }

    /// Reads a compact model file with its leaves (nearly all of its bytes) read in parallel,
    /// a cascade a task, after the rest: the fresh memory's page faults, which cost more than
    /// the copying, are then shared by the cores (dlib's model in a fresh process: 63 → 38 ms on 2 cores, best of 5).
    fn read_compact_file(path: &Path, file: std::fs::File, length: u64) -> Result<Self, ModelProblem> {
        use rayon::prelude::*;
        use std::io::Seek;
        let mut r = CompactReader {
            reader: file,
            left: length,
            at: 0,
        };
        let mut skip = |file: &mut std::fs::File, bytes: u64| {
            file.seek(std::io::SeekFrom::Current(bytes as i64)).map(|_| ())
        };
        let (mut model, _, spans) = Self::read_compact_from(&mut r, Some(&mut skip))?;
        let leaves = spans
            .par_iter()
            .map(|&(at, values)| {
                let io = |e: std::io::Error| ModelProblem::Io(e.to_string());
                let mut file = std::fs::File::open(path).map_err(io)?;
                file.seek(std::io::SeekFrom::Start(at)).map_err(io)?;
                CompactReader {
                    reader: file,
                    left: values as u64 * 4,
                    at,
                }
                .floats(values, "the leaves")
            })
            .collect::<Result<Vec<_>, ModelProblem>>()?;
        for (cascade, leaves) in model.cascades.iter_mut().zip(leaves) {
            cascade.leaves = leaves;
        }
        Ok(model)
    }

    /// The compact form's reader: with `skip_leaves`, each cascade's leaves are skipped (left
    /// empty) and their place (byte offset, values) returned for reading later.
    #[allow(clippy::type_complexity)]
    fn read_compact_from<R: std::io::Read>(
        r: &mut CompactReader<R>,
        mut skip_leaves: Option<&mut dyn FnMut(&mut R, u64) -> std::io::Result<()>>,
    ) -> Result<(Self, ModelSource, Vec<(u64, usize)>), ModelProblem> {
        let mut spans = Vec::new();
        let mut magic = [0u8; 16];
        r.fill(&mut magic)?;
        if &magic != COMPACT_MAGIC {
            return Err(ModelProblem::Malformed {
                at: 0,
                message: "not splineface's compact model form".into(),
            });
        }
        let mut head = [0u8; 16];
        r.fill(&mut head)?;
        let source = ModelSource {
            bytes: u64::from_le_bytes(head[..8].try_into().expect("8 bytes")),
            fnv1a64: u64::from_le_bytes(head[8..].try_into().expect("8 bytes")),
        };
        let points = r.count("the mean shape")?;
        let cascades = r.count("the cascades")?;
        if points == 0 {
            return Err(r_malformed(r, "a model of no points"));
        }
        let initial = r.floats(2 * points, "the mean shape")?;
        if initial.iter().any(|v| !v.is_finite()) {
            return Err(r_malformed(r, "the mean shape must be finite"));
        }
        let dims = 2 * points;
        let mut result = Vec::with_capacity(cascades.min(1024));
        for _ in 0..cascades {
            let m = r.count("a cascade's features")?;
            let anchors = r.words(m, "the anchors")?;
            if anchors.iter().any(|&a| a as usize >= points) {
                return Err(r_malformed(r, "an anchor is not one of the points"));
            }
            let deltas: Vec<[f32; 2]> = r
                .floats(2 * m, "the deltas")?
                .chunks_exact(2)
                .map(|d| [d[0], d[1]])
                .collect();
            let t = r.count("a cascade's trees")?;
            let counts = r.words(t, "the trees' split counts")?;
            let mut trees = Vec::with_capacity(t);
            let (mut split_start, mut leaf_start) = (0usize, 0usize);
            for &splits in &counts {
                let splits = splits as usize;
                trees.push(TreeSpan {
                    split_start,
                    splits,
                    leaf_start,
                });
                split_start = split_start.saturating_add(splits);
                leaf_start = leaf_start.saturating_add((splits + 1).saturating_mul(dims));
            }
            let raw = r.words(split_start.saturating_mul(3), "the splits")?;
            let splits: Vec<Split> = raw
                .chunks_exact(3)
                .map(|s| Split {
                    idx1: s[0],
                    idx2: s[1],
                    threshold: f32::from_bits(s[2]),
                })
                .collect();
            if splits
                .iter()
                .any(|s| s.idx1 as usize >= m || s.idx2 as usize >= m)
            {
                return Err(r_malformed(
                    r,
                    "a split reads a feature pixel the cascade does not have",
                ));
            }
            let leaves = match skip_leaves.as_mut() {
                None => r.floats(leaf_start, "the leaves")?,
                Some(skip) => {
                    r.check_values(leaf_start, "the leaves")?;
                    let bytes = leaf_start as u64 * 4;
                    skip(&mut r.reader, bytes).map_err(|e| ModelProblem::Io(e.to_string()))?;
                    spans.push((r.at, leaf_start));
                    r.left -= bytes;
                    r.at += bytes;
                    Vec::new()
                }
            };
            result.push(Cascade {
                anchors,
                deltas,
                trees,
                splits,
                leaves,
            });
        }
        if r.left != 0 {
            return Err(r_malformed(r, "bytes after the last cascade"));
        }
        Ok((
            ShapePredictor {
                initial: initial.chunks_exact(2).map(|c| [c[0], c[1]]).collect(),
                cascades: result,
            },
            source,
            spans,
        ))
    }
}

fn r_malformed<R>(r: &CompactReader<R>, message: &str) -> ModelProblem {
    ModelProblem::Malformed {
        at: r.at as usize,
        message: message.to_owned(),
    }
}

/// What [`write_compact`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Compacted {
    /// The compact file was written.
    Written,
    /// The compact file was already there, made from these very bytes: nothing was written.
    UpToDate,
}

/// Writes the compact form of dlib's `.dat` model `model` to `out` (`splineface compact-model`),
/// unless `out` already holds the compact form of the same bytes. Written whole or not at all.
///
/// # Errors
/// [`crate::Error::Output`] when `out` cannot be written, [`crate::Error::Model`] for a model
/// that cannot be read or parsed or that is already compact.
pub fn write_compact(model: &Path, out: &Path) -> Result<Compacted, crate::Error> {
    let error = |problem| ModelError {
        file: model.to_path_buf(),
        problem,
    };
    crate::io::check_output_file(out)?;
    let dat = crate::io::read_input(model, crate::io::MAX_DATA_INPUT_BYTES)
        .map_err(|e| error(ModelProblem::Io(e.to_string())))?;
    if dat.starts_with(COMPACT_MAGIC) {
        return Err(error(ModelProblem::AlreadyCompact).into());
    }
    let source = ModelSource::of(&dat);
    if let Ok(file) = std::fs::File::open(out)
        && let Ok(length) = file.metadata().map(|m| m.len())
        && let Ok((_, recorded)) = ShapePredictor::read_compact(std::io::BufReader::new(file), length)
        && recorded == source
    {
        return Ok(Compacted::UpToDate);
    }
    let predictor = ShapePredictor::parse(&dat).map_err(error)?;
    drop(dat);
    crate::io::write_atomically(out, &predictor.to_compact(source)).map_err(|e| {
        crate::io::OutputError::Write {
            path: out.to_path_buf(),
            error: e,
        }
    })?;
    Ok(Compacted::Written)
}
