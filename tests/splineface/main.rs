//! Integration tests, one binary with a module per concern.

// Index loops mirror the formulas they check (Σᵢ Σⱼ …), which reads better than zips here.
#![allow(clippy::needless_range_loop)]

mod align;
mod bad_inputs;
mod batch;
mod bspline_basis;
mod bspline_curvature;
mod bspline_curve;
mod bspline_fit;
mod bspline_inversion;
mod bspline_knots;
mod bspline_refine;
mod bspline_serde;
mod bspline_space;
mod bspline_surface;
mod common;
mod compare;
mod depth;
mod export;
mod face;
mod face_space;
mod landmarker;
mod landmarks;
mod library_inputs;
mod mesh;
mod mesh_closest;
mod photoreal;
mod pipeline;
mod rasl;
mod reference;
mod refine;
mod render;
mod report;
mod report_page;
mod scan;
mod structure;
mod texture;
