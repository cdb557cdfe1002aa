//! Orthographic depth maps of meshes: rendering, and writing them as EXR (float), 16-bit PNG
//! and shaded previews.
//!
//! A [`View`] turns the mesh (the camera looks along `−z` of the turned mesh, `+y` up); a
//! [`Raster`] places the pixels on the turned `x`-`y` plane. The map holds the **height** `z`
//! of the front-most surface above each pixel centre (larger is nearer the viewer), `NaN` where
//! no triangle covers it. Files never pass the background off as a depth: the EXR has a
//! coverage channel, the PNG reserves 0.

mod photo;
mod photoreal;
pub(crate) mod raster;
mod text;
mod write;

use nalgebra::{Point2, Point3, Rotation3, Vector3};

use crate::Real;
use crate::mesh::Raster;
use crate::mesh::TriangleMesh;
pub use photo::{SyntheticPhoto, synthetic_photo};
pub use photoreal::{Camera, ColourMap, Lighting, PhotoLook, linear_to_srgb, render_photo, srgb_to_linear};
pub(crate) use photoreal::{PhotoGeometry, linear_to_srgb8};
pub use raster::render_heights;
pub use text::{TextStyle, draw_text, text_width};
pub(crate) use text::{line_height, wrap_text};
pub use write::{encode_depth_exr, encode_depth_png, heatmap_png, shaded_png};

/// A viewing direction: the rotation applied to the mesh before looking along `−z`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct View {
    /// Turns the mesh's frame into the camera's.
    pub rotation: Rotation3<Real>,
}

impl View {
    /// The frontal view (no rotation): a canonical face seen from the front.
    pub fn front() -> Self {
        View {
            rotation: Rotation3::identity(),
        }
    }

    /// The view of a face with the given pose angles, as [`crate::depth::Pose`] defines them
    /// (yaw turns the nose toward the image's right, pitch tips it down, roll turns the face
    /// counter-clockwise).
    pub fn from_yaw_pitch_roll_degrees(yaw: Real, pitch: Real, roll: Real) -> Self {
        View {
            rotation: crate::depth::Pose::from_yaw_pitch_roll_degrees(yaw, pitch, roll, 1.0).rotation,
        }
    }

    /// Parses `front` or `YAW,PITCH,ROLL` (degrees, each finite and within ±180).
    ///
    /// # Errors
    /// [`RenderError::View`] saying what was expected.
    pub fn parse(text: &str) -> Result<Self, RenderError> {
        if text.trim().eq_ignore_ascii_case("front") {
            return Ok(View::front());
        }
        let parts: Vec<&str> = text.split(',').map(str::trim).collect();
        let angles: Option<Vec<Real>> = parts.iter().map(|p| p.parse::<Real>().ok()).collect();
        match angles.as_deref() {
            Some(&[yaw, pitch, roll])
                if [yaw, pitch, roll]
                    .iter()
                    .all(|a| a.is_finite() && a.abs() <= 180.0) =>
            {
                Ok(View::from_yaw_pitch_roll_degrees(yaw, pitch, roll))
            }
            _ => Err(RenderError::View {
                text: text.to_owned(),
            }),
        }
    }

    /// A point in the camera's frame.
    pub fn apply(&self, p: &Point3<Real>) -> Point3<Real> {
        self.rotation * p
    }
}

/// What went wrong rendering: a setting out of range, nothing to frame, a mesh or structure
/// the renderer cannot use, or a view that cannot be parsed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum RenderError {
    /// The mesh has no texture coordinates.
    #[error("the mesh has no texture coordinates")]
    NoTextureCoordinates,
    /// A size, margin, focal length or other setting is out of range.
    #[error("{message}")]
    Setting {
        /// What is wrong with which setting.
        message: String,
    },
    /// No finite point to frame.
    #[error("no finite points to frame")]
    NothingToFrame,
    /// The structure does not have 40 finite points.
    #[error("the structure must have 40 finite points")]
    Structure,
    /// A view that cannot be parsed ([`View::parse`]).
    #[error("`{text}` is not a view: expected `front` or YAW,PITCH,ROLL in degrees (each within ±180)")]
    View {
        /// The text given.
        text: String,
    },
}

/// The raster of `width × height` square pixels that frames the points seen from `view`:
/// their `x`-`y` bounding box grown by `margin` (a fraction of its larger side) on every side,
/// centred, with the pixel size set by the tighter direction.
///
/// # Errors
/// [`RenderError::Setting`] for zero sizes, sizes over [`MAX_SIDE`] or a margin that is
/// negative or not finite; [`RenderError::NothingToFrame`] for an empty or non-finite point
/// set.
pub fn frame_raster(
    points: impl IntoIterator<Item = Point3<Real>>,
    view: &View,
    width: usize,
    height: usize,
    margin: Real,
) -> Result<Raster, RenderError> {
    if !(1..=MAX_SIDE).contains(&width) || !(1..=MAX_SIDE).contains(&height) {
        return Err(RenderError::Setting {
            message: format!("{width}×{height} pixels: each side must be between 1 and {MAX_SIDE}"),
        });
    }
    if !(margin >= 0.0 && margin.is_finite()) {
        return Err(RenderError::Setting {
            message: format!("margin {margin} must be non-negative and finite"),
        });
    }
    let mut lo = Point2::new(Real::INFINITY, Real::INFINITY);
    let mut hi = Point2::new(Real::NEG_INFINITY, Real::NEG_INFINITY);
    for p in points {
        let q = view.apply(&p);
        lo = lo.inf(&q.xy());
        hi = hi.sup(&q.xy());
    }
    if !(lo.x.is_finite() && lo.y.is_finite() && hi.x.is_finite() && hi.y.is_finite()) {
        return Err(RenderError::NothingToFrame);
    }
    let side = (hi.x - lo.x).max(hi.y - lo.y).max(Real::MIN_POSITIVE);
    let extent = (hi - lo).add_scalar(2.0 * margin * side);
    let spacing = (extent.x / width as Real)
        .max(extent.y / height as Real)
        .max(1e-300);
    let centre = nalgebra::center(&lo, &hi);
    Ok(Raster {
        origin: Point2::new(
            centre.x - spacing * (width as Real - 1.0) / 2.0,
            centre.y - spacing * (height as Real - 1.0) / 2.0,
        ),
        spacing,
        width,
        height,
    })
}

/// The largest side of a depth map, in pixels.
pub const MAX_SIDE: usize = 16384;

/// A depth map: heights over a raster (see the module documentation), row `j` at
/// `y = origin.y + j·spacing` (so row 0 is the *bottom*; image files flip it).
#[derive(Debug, Clone, PartialEq)]
pub struct DepthMap {
    /// Where the pixels are.
    pub raster: Raster,
    /// `width × height` heights, row-major from the bottom row; `NaN` is background.
    pub heights: Vec<Real>,
}

/// A depth map's file format ([`encode_depth_exr`], [`encode_depth_png`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DepthFormat {
    /// OpenEXR, float32 depth with a coverage channel.
    Exr,
    /// 16-bit greyscale PNG.
    Png,
}

impl DepthFormat {
    /// The format a path's extension names (`.exr` or `.png`, any case).
    pub fn from_path(path: &std::path::Path) -> Option<Self> {
        match path.extension()?.to_str()?.to_ascii_lowercase().as_str() {
            "exr" => Some(DepthFormat::Exr),
            "png" => Some(DepthFormat::Png),
            _ => None,
        }
    }

    /// The map's file in this format.
    ///
    /// # Errors
    /// As the encoder ([`encode_depth_exr`], [`encode_depth_png`]).
    pub fn encode(self, map: &DepthMap) -> Result<Vec<u8>, crate::io::EncodeError> {
        match self {
            DepthFormat::Exr => encode_depth_exr(map),
            DepthFormat::Png => encode_depth_png(map),
        }
    }
}

impl DepthMap {
    /// Renders `mesh` seen from `view` over the `width × height` raster that frames it with a
    /// 2% margin ([`frame_raster`]).
    ///
    /// # Errors
    /// As [`frame_raster`]: a size out of range, or a mesh with no finite vertex.
    pub fn framed(
        mesh: &TriangleMesh,
        view: &View,
        width: usize,
        height: usize,
    ) -> Result<Self, RenderError> {
        let raster = frame_raster(mesh.positions().iter().copied(), view, width, height, 0.02)?;
        Ok(DepthMap::render(mesh, view, &raster))
    }

    /// Renders `mesh` seen from `view` over `raster`.
    ///
    /// # Examples
    /// ```
    /// use splineface::mesh::TriangleMesh;
    /// use splineface::render::{DepthMap, View, frame_raster};
    /// use nalgebra::Point3;
    ///
    /// // A square tilted about y: its height rises with x.
    /// let p = |x: f64, y: f64| Point3::new(x, y, 0.5 * x);
    /// let square = TriangleMesh::new(vec![p(0., 0.), p(1., 0.), p(1., 1.), p(0., 1.)], vec![[0, 1, 2], [0, 2, 3]]).unwrap();
    /// let raster = frame_raster(square.positions().iter().copied(), &View::front(), 64, 64, 0.1).unwrap();
    /// let map = DepthMap::render(&square, &View::front(), &raster);
    /// assert!(map.covered() > 2000); // the square fills most of the 64 × 64 raster
    /// let (lo, hi) = map.range().unwrap();
    /// assert!(lo >= 0.0 && hi <= 0.5 && hi - lo > 0.45);
    /// ```
    pub fn render(mesh: &TriangleMesh, view: &View, raster: &Raster) -> Self {
        let turned: Vec<Point3<Real>> = mesh.positions().iter().map(|p| view.apply(p)).collect();
        DepthMap {
            raster: *raster,
            heights: render_heights(&turned, mesh.triangles(), raster),
        }
    }

    /// The height at pixel `(i, j)` (`j` from the bottom), `None` on background.
    pub fn get(&self, i: usize, j: usize) -> Option<Real> {
        let h = self.heights[j * self.raster.width + i];
        h.is_finite().then_some(h)
    }

    /// The number of covered pixels.
    pub fn covered(&self) -> usize {
        self.heights.iter().filter(|h| h.is_finite()).count()
    }

    /// The smallest and largest height, `None` if nothing is covered.
    pub fn range(&self) -> Option<(Real, Real)> {
        let mut covered = self.heights.iter().copied().filter(|h| h.is_finite());
        let first = covered.next()?;
        Some(covered.fold((first, first), |(lo, hi), h| (lo.min(h), hi.max(h))))
    }

    /// The unit normal of the height field at pixel `(i, j)` from central differences
    /// (one-sided at the edge of the covered region), `None` on background.
    pub fn normal(&self, i: usize, j: usize) -> Option<Vector3<Real>> {
        let h = self.get(i, j)?;
        let s = self.raster.spacing;
        let slope = |a: Option<Real>, b: Option<Real>, step: Real| match (a, b) {
            (Some(a), Some(b)) => (b - a) / (2.0 * step),
            (Some(a), None) => (h - a) / step,
            (None, Some(b)) => (b - h) / step,
            (None, None) => 0.0,
        };
        let left = if i > 0 { self.get(i - 1, j) } else { None };
        let right = if i + 1 < self.raster.width {
            self.get(i + 1, j)
        } else {
            None
        };
        let below = if j > 0 { self.get(i, j - 1) } else { None };
        let above = if j + 1 < self.raster.height {
            self.get(i, j + 1)
        } else {
            None
        };
        let (dx, dy) = (slope(left, right, s), slope(below, above, s));
        Vector3::new(-dx, -dy, 1.0).try_normalize(0.0)
    }
}
