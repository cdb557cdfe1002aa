//! Synthetic photos of a face mesh: shaded, orthographic, with dark brows, eyes and lips
//! painted at the structure points, and the points where the photo sees them. For tests,
//! benchmarks, the evaluation harness and the demo.

use nalgebra::{Point2, Point3, Vector3};

use super::{DepthMap, RenderError, View, frame_raster};
use crate::Real;
use crate::align::GreyImage;
use crate::mesh::TriangleMesh;
use crate::structure::{Group, POINT_COUNT, POINTS};

/// A rendered photo and its 40 structure points in its pixels (`y` down).
#[derive(Debug, Clone)]
pub struct SyntheticPhoto {
    /// The image.
    pub image: GreyImage,
    /// The structure points as the photo sees them (hidden ones included).
    pub points: Vec<Point2<Real>>,
    /// The view it was taken from.
    pub view: View,
    /// Where its pixels lie on the view's plane.
    pub raster: crate::mesh::Raster,
}

impl SyntheticPhoto {
    /// Where the photo sees a point of the mesh's frame, in its pixels (`y` down).
    pub fn project(&self, p: &Point3<Real>) -> Point2<Real> {
        let q = self.view.apply(p);
        Point2::new(
            (q.x - self.raster.origin.x) / self.raster.spacing,
            (self.raster.height - 1) as Real - (q.y - self.raster.origin.y) / self.raster.spacing,
        )
    }
}

/// Renders `mesh` (whose 40-point structure is `structure`) seen from `view`, framed in
/// `width × height` pixels with `margin` (see [`frame_raster`]): Lambert shading from a light at
/// the viewer's upper left (25% ambient), times an albedo that darkens Gaussian spots of a
/// twentieth of the eye distance at the brow, eye and mouth points (the marks a face's texture
/// gives an aligner to hold on to); background 0.1.
///
/// # Errors
/// [`RenderError::Setting`] for a bad size or margin, [`RenderError::Structure`] for a
/// structure without 40 finite points.
pub fn synthetic_photo(
    mesh: &TriangleMesh,
    structure: &[Point3<Real>],
    view: &View,
    width: usize,
    height: usize,
    margin: Real,
) -> Result<SyntheticPhoto, RenderError> {
    if structure.len() != POINT_COUNT || structure.iter().any(|p| !p.iter().all(|c| c.is_finite())) {
        return Err(RenderError::Structure);
    }
    let raster = frame_raster(mesh.positions().iter().copied(), view, width, height, margin)?;
    let map = DepthMap::render(mesh, view, &raster);
    let points: Vec<Point2<Real>> = structure
        .iter()
        .map(|p| {
            let q = view.apply(p);
            Point2::new(
                (q.x - raster.origin.x) / raster.spacing,
                (height - 1) as Real - (q.y - raster.origin.y) / raster.spacing,
            )
        })
        .collect();
    let light = Vector3::new(-0.4, 0.5, 1.0).normalize();
    let eye_distance =
        (points[crate::structure::LEFT_EYE_CENTRE] - points[crate::structure::RIGHT_EYE_CENTRE]).norm();
    let sigma = (0.05 * eye_distance).max(0.5);
    let features: Vec<(Point2<Real>, Real)> = (0..POINT_COUNT)
        .filter_map(|k| match POINTS[k].group {
            Group::Eyes | Group::EyeCentres => Some((points[k], 0.6)),
            Group::Brows | Group::Mouth => Some((points[k], 0.45)),
            _ => None,
        })
        .collect();
    let reach = 4.0 * sigma;
    let mut data = Vec::with_capacity(width * height);
    for row in 0..height {
        let j = height - 1 - row;
        for i in 0..width {
            let value = match map.normal(i, j) {
                Some(n) => {
                    let shade = 0.25 + 0.75 * n.dot(&light).max(0.0);
                    let p = Point2::new(i as Real, row as Real);
                    let dark: Real = features
                        .iter()
                        .filter(|(c, _)| (c.x - p.x).abs() < reach && (c.y - p.y).abs() < reach)
                        .map(|(c, a)| a * (-(p - c).norm_squared() / (2.0 * sigma * sigma)).exp())
                        .sum();
                    shade * (1.0 - dark.min(0.9))
                }
                None => 0.1,
            };
            data.push(value as f32);
        }
    }
    let image = GreyImage::new(width, height, data).map_err(|e| RenderError::Setting {
        message: format!("the photo cannot be used: {e}"),
    })?;
    Ok(SyntheticPhoto {
        image,
        points,
        view: *view,
        raster,
    })
}
