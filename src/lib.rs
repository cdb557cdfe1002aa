//! # splineface
//!
//! Smooth 3D faces from a handful of ordinary, uncalibrated photos of one person, after Peng,
//! Xu & Feng, *3D face modeling based on structure optimization and surface reconstruction with
//! B-Spline* (Neurocomputing 179, 2016): a C² B-spline surface, clipped triangle meshes and
//! depth maps.
//!
//! ## A tour
//!
//! * [`bspline`]: the geometry kernel. [`bspline::KnotVector`], the basis functions,
//!   [`bspline::BSplineSurface`] (evaluation, derivatives, normals, dense grids, the sparse
//!   basis matrix, affine maps, JSON and STEP files), [`bspline::SurfaceFit`] (least-squares control grids
//!   from up to millions of scattered samples) and [`bspline::SurfaceSpace`] (linear spaces
//!   of surfaces on one knot layout: a base grid plus displacement modes); [`scan`]: any
//!   scan that is a height field over some plane to a spline ([`scan::fit_scan`], knots
//!   inserted where the residual asks for them).
//!
//! * [`structure`]: the paper's 40-point face structure (points, groups, mirror partners), its
//!   derivation from the 68-point iBUG annotation, the canonical frame, edges, sub-structures
//!   and the multi-substructure SSIM.
//!
//! * [`reference`](mod@reference): the reference face (control grid, structure, edges, clip
//!   region, optionally a face space) fitted to scans, and the embedded default,
//!   [`reference::ReferenceFace::embedded`], which carries ICT-FaceKit's 60 identity modes.
//!
//! * [`mesh`]: triangle meshes and every mesh file format (OBJ, PLY, glTF/GLB in; OBJ with
//!   its MTL and texture, PLY, GLB out) and the frontal rasteriser; [`landmarks`]: landmark
//!   files (`.pts`, JSON, vertex indices); [`io`]: inputs read within limits (no devices,
//!   pipes or oversized files), PNG encoding, and outputs
//!   written whole (staged, then renamed).
//!
//! * [`align`]: the frontal 2D structure of a batch of photos ([`align::procrustes_frontal`]
//!   from their points alone); [`depth`]: the 3D structure by the paper's pose/depth
//!   alternation with the multi-substructure SSIM constraint ([`depth::estimate_depth`]).
//!
//! * [`align::rasl_frontal`]: the frontal structure from the photos themselves (RASL low-rank
//!   batch alignment of the photos and their mirror images); [`align::landmark_agreement`]:
//!   whether the photos' landmarks mark the same places of the face.
//!
//! * [`face`]: the face surface: the reference grid deformed to an estimated structure (the
//!   paper's affine `Tr_f`, or the local mode), or a member of the statistical face space
//!   ([`face::FaceSpace`]) fitted to the photos' points, the default by measurement
//!   ([`face::FaceSpace::fit_photos`]); and its clipped mesh; [`render`]: depth maps and
//!   their files (EXR, 16-bit PNG), previews, heatmaps, synthetic
//!   photos and photo-realistic ones ([`render::render_photo`]: a textured mesh, a perspective
//!   camera, light and shadow); [`compare`]: a reconstruction against a ground truth, with the
//!   paper's measures and the inner-face score accuracy is claimed in
//!   ([`compare::inner_face_score`]).
//!
//! * [`detect`]: face detection (SeetaFace, model embedded) and robust landmarking
//!   ([`detect::landmark_face`]); [`landmarker`]: dlib's 68-point `shape_predictor` in pure
//!   Rust; [`pipeline`]: the stages chained and every output file;
//!   [`demo`]: the embedded demo subject and its photos; [`report`]: per-photo overlays and
//!   the self-contained `report.html` with the face in a 3D viewer.
//!
//! The face front ends feed the kernel a transform; they are built on top of it.
//!
//! ## Conventions
//!
//! All geometry is `f64` ([`Real`]) over nalgebra types. Control grids are flat and row-major.
//! Degrees, never orders: a B-spline of degree `p` with `n` control points has
//! `n + p + 1` knots.
//!
//! ## Cargo features
//!
//! None yet: everything is always built.

#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod align;
pub mod batch;
pub mod bspline;
pub mod compare;
pub mod demo;
pub mod depth;
pub mod detect;
pub mod error;
pub mod face;
pub mod geometry;
pub mod io;
pub mod landmarker;
pub mod landmarks;
pub mod mesh;
pub mod pipeline;
pub mod random;
pub mod reference;
pub mod render;
pub mod report;
pub mod scan;
pub mod structure;

pub use error::Error;

/// The scalar type of all geometry.
pub type Real = f64;
