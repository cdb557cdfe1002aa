//! The clipped face mesh: a constrained Delaunay triangulation of the face region in the
//! frontal plane, lifted onto the surface.

use nalgebra::{Point2, Vector3};
use spade::{ConstrainedDelaunayTriangulation, Triangulation};

use super::{FaceError, FaceSurface};
use crate::Real;
use crate::depth::PhotoFit;
use crate::geometry::{bounding_box, polygon_contains};
use crate::mesh::{TextureCoordinates, TriangleMesh};

/// How the face region is triangulated.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshOptions {
    /// The spacing of the vertices over the reference's frontal plane, in canonical units
    /// (50 between the eye centres): interior vertices lie on a square grid of this spacing and
    /// boundary edges are split to at most this length. Default 1 (about 1.3 mm; some 25,000
    /// vertices over the embedded reference's face region).
    pub spacing: Real,
}

impl Default for MeshOptions {
    fn default() -> Self {
        MeshOptions { spacing: 1.0 }
    }
}

/// The largest number of vertices [`FaceSurface::mesh`] builds.
pub const MAX_VERTICES: usize = 20_000_000;

/// A triangle mesh of the clipped face with the surface parameters of its vertices.
#[derive(Debug, Clone, PartialEq)]
pub struct ClippedMesh {
    /// The mesh, with unit normals, triangles counter-clockwise seen from the front.
    pub mesh: TriangleMesh,
    /// The surface parameters `(u, v)` of each vertex.
    pub params: Vec<Point2<Real>>,
}

/// The distance from `p` to the segment `ab`.
fn segment_distance(p: Point2<Real>, a: Point2<Real>, b: Point2<Real>) -> Real {
    let ab = b - a;
    let t = ((p - a).dot(&ab) / ab.norm_squared().max(Real::MIN_POSITIVE)).clamp(0.0, 1.0);
    (p - (a + t * ab)).norm()
}

impl ClippedMesh {
    /// The mesh textured by a photo: each vertex's texture coordinates are where the photo's
    /// fitted pose sees it ([`PhotoFit::pixel`]), as fractions of the photo's `width` and
    /// `height` with `v` up (OBJ's convention), clamped to the image. The mesh must still be in
    /// the canonical frame the pose was fitted in (scale it afterwards; texture coordinates do
    /// not change). Parts the photo sees from behind are textured too: choose the most frontal
    /// photo ([`crate::depth::DepthEstimate::most_frontal_photo`]).
    pub fn photo_texture(&self, fit: &PhotoFit, width: u32, height: u32) -> TriangleMesh {
        let (w, h) = (Real::from(width.max(1)), Real::from(height.max(1)));
        let uvs = self
            .mesh
            .positions()
            .iter()
            .map(|p| {
                let q = fit.pixel(p);
                Point2::new((q.x / w).clamp(0.0, 1.0), (1.0 - q.y / h).clamp(0.0, 1.0))
            })
            .collect();
        self.with_vertex_uvs(uvs)
    }

    /// The mesh with each vertex's surface parameters as its texture coordinates: the
    /// coordinates of a texture atlas over the surface's `(u, v)`
    /// ([`crate::face::bake_texture`]).
    pub fn parameter_textured(&self) -> TriangleMesh {
        self.with_vertex_uvs(self.params.clone())
    }

    /// The mesh with one texture coordinate per vertex, indexed like the triangles.
    fn with_vertex_uvs(&self, uvs: Vec<Point2<Real>>) -> TriangleMesh {
        let texture = TextureCoordinates {
            uvs,
            triangles: self.mesh.triangles().to_vec(),
        };
        self.mesh
            .clone()
            .with_texture(texture)
            .expect("one finite coordinate per vertex, indexed like the triangles")
    }
}

impl FaceSurface {
    /// Triangulates the face region and lifts it onto the surface.
    ///
    /// The clip polygon (mapped to the reference's frontal plane, where distances are
    /// isotropic) is the exact boundary: its edges are split into equal pieces no longer than
    /// the spacing and kept as constraint edges of spade's constrained Delaunay triangulation.
    /// Interior vertices lie on the square grid of the spacing, leaving out those closer than
    /// half a spacing to the boundary (which would make slivers). Triangles outside the polygon
    /// are dropped. Vertices are evaluated on the surface; normals are the surface's exact
    /// normals (`F_u × F_v`, toward the viewer), falling back on the mean of the adjacent
    /// triangles' normals where the surface is singular.
    ///
    /// # Errors
    /// [`FaceError::Option`] for a spacing that is not positive and finite or that would need
    /// more than [`MAX_VERTICES`] vertices; [`FaceError::Triangulation`] for a clip polygon
    /// that intersects itself.
    pub fn mesh(&self, options: &MeshOptions) -> Result<ClippedMesh, FaceError> {
        let spacing = options.spacing;
        let frame = self.frame();
        let polygon: Vec<Point2<Real>> = self.clip().iter().map(|p| frame.position(p.x, p.y)).collect();
        let (lo, hi) = bounding_box(&polygon).expect("a clip polygon has points");
        let too_fine = |count: Real| count > MAX_VERTICES as Real;
        let columns = ((hi.x - lo.x) / spacing).floor() + 1.0;
        let rows = ((hi.y - lo.y) / spacing).floor() + 1.0;
        if !(spacing > 0.0 && spacing.is_finite()) || too_fine(columns * rows) {
            return Err(FaceError::Option {
                name: "spacing",
                value: spacing.to_string(),
                expected: "positive, finite and not so small that the mesh needs over 20 million vertices",
            });
        }

        // The boundary, split into pieces no longer than the spacing.
        let mut vertices: Vec<spade::Point2<Real>> = Vec::new();
        for k in 0..polygon.len() {
            let (a, b) = (polygon[k], polygon[(k + 1) % polygon.len()]);
            let pieces = ((b - a).norm() / spacing).ceil().max(1.0) as usize;
            for i in 0..pieces {
                let p = a + (b - a) * (i as Real / pieces as Real);
                vertices.push(spade::Point2::new(p.x, p.y));
            }
        }
        let boundary = vertices.len();
        let edges: Vec<[usize; 2]> = (0..boundary).map(|k| [k, (k + 1) % boundary]).collect();
        // The interior grid, aligned on whole multiples of the spacing.
        let (i0, j0) = ((lo.x / spacing).ceil() as i64, (lo.y / spacing).ceil() as i64);
        let (i1, j1) = ((hi.x / spacing).floor() as i64, (hi.y / spacing).floor() as i64);
        for j in j0..=j1 {
            for i in i0..=i1 {
                let p = Point2::new(i as Real * spacing, j as Real * spacing);
                if !polygon_contains(&polygon, p) {
                    continue;
                }
                let clearance = (0..polygon.len())
                    .map(|k| segment_distance(p, polygon[k], polygon[(k + 1) % polygon.len()]))
                    .fold(Real::INFINITY, Real::min);
                if clearance >= 0.5 * spacing {
                    vertices.push(spade::Point2::new(p.x, p.y));
                }
            }
        }

        let mut conflict = false;
        let cdt = ConstrainedDelaunayTriangulation::<spade::Point2<Real>>::try_bulk_load_cdt(
            vertices,
            edges,
            |_| conflict = true,
        )
        .map_err(|e| FaceError::Triangulation(e.to_string()))?;
        if conflict {
            return Err(FaceError::Triangulation(
                "the clip polygon intersects itself".to_owned(),
            ));
        }

        let params: Vec<Point2<Real>> = cdt
            .vertices()
            .map(|v| {
                let p = v.position();
                let q = frame.parameters(p.x, p.y);
                Point2::new(q.x.clamp(0.0, 1.0), q.y.clamp(0.0, 1.0))
            })
            .collect();
        let mut triangles = Vec::with_capacity(2 * params.len());
        for face in cdt.inner_faces() {
            let [a, b, c] = face.vertices();
            let [pa, pb, pc] = [a, b, c].map(|v| v.position());
            let centre = Point2::new((pa.x + pb.x + pc.x) / 3.0, (pa.y + pb.y + pc.y) / 3.0);
            // Slivers between (nearly) collinear boundary vertices cover nothing and have no
            // normal; their centroid may fall either side of the boundary.
            let area = (pb.x - pa.x) * (pc.y - pa.y) - (pc.x - pa.x) * (pb.y - pa.y);
            if area.abs() > 1e-9 * spacing * spacing && polygon_contains(&polygon, centre) {
                triangles.push([a, b, c].map(|v| v.fix().index() as u32));
            }
        }

        let flat: Vec<[Real; 2]> = params.iter().map(|p| [p.x, p.y]).collect();
        let positions = self.surface().eval_many(&flat)?;
        // Fallback normals: area-weighted triangle normals.
        let mut fallback = vec![Vector3::zeros(); positions.len()];
        for t in &triangles {
            let [a, b, c] = t.map(|i| positions[i as usize]);
            let n = (b - a).cross(&(c - a));
            for &i in t {
                fallback[i as usize] += n;
            }
        }
        let mut normals = Vec::with_capacity(positions.len());
        for (k, p) in params.iter().enumerate() {
            let n = match self.surface().normal(p.x, p.y)? {
                Some(n) => n.into_inner(),
                None => fallback[k].try_normalize(0.0).unwrap_or_else(Vector3::z),
            };
            normals.push(n);
        }
        let mesh = TriangleMesh::new(positions, triangles)
            .and_then(|m| m.with_normals(normals))
            .map_err(|e| FaceError::Triangulation(e.to_string()))?;
        Ok(ClippedMesh { mesh, params })
    }
}
