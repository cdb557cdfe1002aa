//! A reconstruction's output files ([`Reconstruction::files`]), and the forms of its two JSON
//! files, `structure.json` ([`StructureFile`]) and `report.json` ([`ReportFile`]).
//!
//! The JSON forms' fields are declared in alphabetical order, the order in which the files have
//! always listed their keys (they were written from `serde_json` maps, which sort them), so that
//! the files stay byte for byte what they were.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Instant;

use nalgebra::Point3;
use rayon::prelude::*;
use serde::Serialize;

use super::{PipelineError, Reconstruction, encode_error};
use crate::Real;
use crate::bspline::{StepOptions, encode_step};
use crate::face::Units;
use crate::face::texture::Turntable;
use crate::geometry::LengthUnit;
use crate::io::encode_png;
use crate::mesh::{PlyEncoding, PngTexture, TriangleMesh, encode_glb, encode_ply};
use crate::render::{encode_depth_exr, encode_depth_png, shaded_png};
use crate::structure::{LEFT_EYE_CENTRE, RIGHT_EYE_CENTRE};

/// `structure.json`: the estimated 40-point structure and each photo's pose, in output units.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StructureFile {
    /// Each photo's expression weights (the non-zero ones, by name), when the face space has
    /// expressions.
    pub expressions: Option<Vec<PhotoExpression>>,
    /// The two eye centres.
    pub eye_centres: EyeCentres,
    /// `splineface/structure`.
    pub format: &'static str,
    /// The frame, in words.
    pub frame: &'static str,
    /// Output units per canonical unit.
    pub per_canonical_unit: Real,
    /// Each photo's pose and fit.
    pub photos: Vec<PhotoPose>,
    /// The 40 points, `[x, y, z]`.
    pub points: Vec<[Real; 3]>,
    /// The multi-substructure SSIM of the structure to the reference's.
    pub similarity: Real,
    /// The face space's identity weights, when the shape came from it.
    pub space_weights: Option<Vec<Real>>,
    /// The units' name.
    pub units: &'static str,
    /// 1.
    pub version: u32,
}

/// A photo's expression in [`StructureFile::expressions`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PhotoExpression {
    /// The photo.
    pub name: String,
    /// Its non-zero expression weights, by the expressions' names.
    pub weights: BTreeMap<String, Real>,
}

/// [`StructureFile::eye_centres`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EyeCentres {
    /// The subject's left eye centre (on the image's right).
    pub left: [Real; 3],
    /// The subject's right eye centre.
    pub right: [Real; 3],
}

/// A photo's pose in [`StructureFile::photos`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PhotoPose {
    /// The RMS distance of the final face's points from the photo's, pixels.
    pub fit_rms_pixels: Real,
    /// The photo.
    pub name: String,
    /// Pitch, degrees.
    pub pitch_degrees: Real,
    /// The depth stage's scale: pixels per output unit.
    pub pixels_per_unit: Real,
    /// The depth stage's reprojection RMS, pixels.
    pub rms_pixels: Real,
    /// The same in output units.
    pub rms_units: Real,
    /// Roll, degrees.
    pub roll_degrees: Real,
    /// Yaw, degrees.
    pub yaw_degrees: Real,
}

/// `report.json`: how the reconstruction went, stage by stage (the command line adds the photos'
/// own records to it).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ReportFile {
    /// The depth stage.
    pub depth: DepthReport,
    /// `splineface/report`.
    pub format: &'static str,
    /// How the frontal structure was found.
    pub frontal_method: String,
    /// Its residual, canonical units.
    pub frontal_residual_rms_units: Real,
    /// Each photo's landmark agreement with the others.
    pub landmark_agreement: Vec<NamedAgreement>,
    /// The photos alignment left out, and why.
    pub photos_dropped: Vec<DroppedPhoto>,
    /// The photos used.
    pub photos_used: Vec<String>,
    /// RASL, when it ran.
    pub rasl: Option<RaslReport>,
    /// The surface.
    pub surface: SurfaceReport,
    /// The texture: made, not made and why (`{"none": why}`), or `null` without photos.
    pub texture: Option<TextureReport>,
    /// Wall time per stage.
    pub timings: Vec<StageTime>,
    /// 1.
    pub version: u32,
    /// The depth stage's warnings.
    pub warnings: Vec<String>,
}

/// [`ReportFile::depth`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DepthReport {
    /// Whether the alternation converged.
    pub converged: bool,
    /// Alternations run.
    pub iterations: usize,
    /// The objective after each.
    pub objective: Vec<Real>,
    /// The final multi-substructure SSIM.
    pub similarity: Real,
}

/// A photo's entry in [`ReportFile::landmark_agreement`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct NamedAgreement {
    /// The agreement.
    pub agreement: Real,
    /// The photo.
    pub name: String,
}

/// A photo's entry in [`ReportFile::photos_dropped`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DroppedPhoto {
    /// The photo.
    pub name: String,
    /// Why.
    pub reason: String,
}

/// [`ReportFile::rasl`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RaslReport {
    /// Inner iterations, all outer iterations together.
    pub inner_iterations: usize,
    /// The objective after each outer iteration.
    pub objective: Vec<Real>,
    /// Outer iterations.
    pub outer_iterations: usize,
    /// Wall time, seconds.
    pub seconds: Real,
}

/// [`ReportFile::surface`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SurfaceReport {
    /// The deformation, in words.
    pub deformation: String,
    /// The largest control-point displacement, canonical units.
    pub displacement_max_units: Real,
    /// Their RMS.
    pub displacement_rms_units: Real,
    /// The mesh's triangles.
    pub mesh_triangles: usize,
    /// Its vertices.
    pub mesh_vertices: usize,
    /// How far the surface's points are from the structure, RMS, canonical units.
    pub point_rms_units: Real,
    /// The refinement by the photos' pixels, when it ran.
    pub refinement: Option<RefinementReport>,
    /// How the shape was made, in words.
    pub shape: String,
    /// The face-space modes held at their plausible range.
    pub space_held_modes: Option<Vec<usize>>,
    /// The face-space fit's RMS per photo, canonical units.
    pub space_rms_units: Option<Vec<Real>>,
    /// The face space's identity weights.
    pub space_weights: Option<Vec<Real>>,
    /// How closely the surface follows the estimated structure.
    pub structure_weight: Real,
    /// Why.
    pub structure_weight_reason: String,
    /// Whether the mesh is textured.
    pub textured: bool,
}

/// [`SurfaceReport::refinement`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RefinementReport {
    /// Whether the refined face was kept (whole or in part).
    pub accepted: bool,
    /// Each photo's share of the face it saw.
    pub coverage: Vec<Real>,
    /// The photos' disagreement on the refined face (the whole way, whatever the share kept).
    pub disagreement_after: Real,
    /// Before.
    pub disagreement_before: Real,
    /// The largest depth displacement of a control point kept from the refinement
    /// ([`crate::face::RefineOptions::field`]), canonical units; `None` without a field.
    pub field_max_units: Option<Real>,
    /// Its RMS over the control points.
    pub field_rms_units: Option<Real>,
    /// The photos left out's disagreement with the others on the face the others refined
    /// ([`crate::face::Refinement::held_out`]); `None` where the check did not run.
    pub held_out_after: Option<Real>,
    /// On the landmark fit's face.
    pub held_out_before: Option<Real>,
    /// Iterations run.
    pub iterations: usize,
    /// The landmark RMS after, canonical units.
    pub landmark_rms_units_after: Real,
    /// Before.
    pub landmark_rms_units_before: Real,
    /// Why it was kept or not, in words.
    pub note: String,
    /// Surface samples.
    pub samples: usize,
    /// Samples at least two photos see.
    pub samples_seen_twice: usize,
    /// How much of the way from the landmark fit to the refined face was kept
    /// ([`crate::face::Refinement::share`]).
    pub share: Real,
}

/// [`ReportFile::texture`].
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(untagged)]
pub enum TextureReport {
    /// The texture was made.
    Made {
        /// The share of texels filled from neighbours.
        filled: Real,
        /// The share taken from the mirrored side.
        mirrored: Real,
        /// Each photo's colour gain and share.
        photos: Vec<TexturePhotoReport>,
        /// The share seen by a photo.
        seen: Real,
        /// The blend's sharpness.
        sharpness: Real,
        /// The atlas' side, pixels.
        size: u32,
        /// Texels inside the face.
        texels_inside: usize,
    },
    /// It was not, and why.
    None {
        /// Why.
        none: String,
    },
}

/// A photo's entry in [`TextureReport::Made`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TexturePhotoReport {
    /// Its colour gain, RGB.
    pub gain: [Real; 3],
    /// The photo.
    pub name: String,
    /// Its share of the texels.
    pub share: Real,
}

/// A stage's entry in [`ReportFile::timings`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StageTime {
    /// Milliseconds.
    pub ms: Real,
    /// The stage.
    pub stage: String,
}

use super::OutputFiles as Files;

/// One group of output files to encode.
type Part<'a> = Box<dyn Fn() -> Result<Files, PipelineError> + Send + Sync + 'a>;

/// The parts encoded side by side (most encoders run on one core), their files listed in the
/// parts' order.
fn encode_parts(parts: &[Part<'_>]) -> Result<Files, PipelineError> {
    let parts: Vec<Result<Files, PipelineError>> = parts.par_iter().map(|part| part()).collect();
    let mut files = Vec::new();
    for part in parts {
        files.extend(part?);
    }
    Ok(files)
}

/// [`Reconstruction::untextured_files`]' answer: the files, and the turntable's views made
/// ready for the atlas when asked for.
pub(super) struct Untextured {
    files: Files,
    turntable: Option<Turntable>,
}

/// Samples along each side of `curvature.png`.
pub const CURVATURE_SIDE: usize = 256;

impl Reconstruction {
    /// Every output file, as `(path relative to the output directory, bytes)`: see the module
    /// documentation.
    ///
    /// # Errors
    /// [`PipelineError::Encode`] naming the output that could not be encoded.
    pub fn files(&self) -> Result<Files, PipelineError> {
        let start = Instant::now();
        let mesh = self.output_mesh();
        let mut parts = self.textured_parts(&mesh, None);
        parts.extend(self.untextured_parts(&mesh));
        let files = encode_parts(&parts)?;
        self.finish_files(files, &mesh, start)
    }

    /// The files that do not depend on the texture, encoded: what [`super::reconstruct_files`]
    /// encodes while the texture is baked; and, `with_turntable`, the turntable's views made
    /// ready for the atlas. With their wall time, seconds.
    pub(super) fn untextured_files(&self, with_turntable: bool) -> Result<(Untextured, Real), PipelineError> {
        let start = Instant::now();
        let mesh = self.output_mesh();
        let (files, turntable) = rayon::join(
            || encode_parts(&self.untextured_parts(&mesh)),
            || with_turntable.then(|| Turntable::new(&self.mesh)),
        );
        let untextured = Untextured {
            files: files?,
            turntable: turntable.transpose().map_err(encode_error("turntable.png"))?,
        };
        Ok((untextured, start.elapsed().as_secs_f64()))
    }

    /// [`Reconstruction::files`] given [`Reconstruction::untextured_files`]'s: the same files
    /// in the same order.
    pub(super) fn files_after(&self, untextured: Untextured) -> Result<Files, PipelineError> {
        let start = Instant::now();
        let mesh = self.output_mesh();
        let turntable = untextured.turntable.as_ref();
        let mut files = encode_parts(&self.textured_parts(&mesh, turntable))?;
        files.extend(untextured.files);
        self.finish_files(files, &mesh, start)
    }

    /// The files that show the texture (the meshes carry it): encoded last, once it is baked;
    /// the turntable from `turntable`'s views when they were made ready.
    fn textured_parts<'a>(
        &'a self,
        mesh: &'a TriangleMesh,
        turntable: Option<&'a Turntable>,
    ) -> Vec<Part<'a>> {
        vec![
            Box::new(|| self.mesh_files(mesh)),
            Box::new(move || self.texture_files(turntable)),
        ]
    }

    /// The files that need no texture.
    fn untextured_parts<'a>(&'a self, mesh: &'a TriangleMesh) -> Vec<Part<'a>> {
        vec![
            Box::new(|| self.surface_files()),
            Box::new(|| self.depth_files(mesh)),
            Box::new(|| Ok(vec![("curvature.png".into(), self.curvature_png()?)])),
            // Where the photos agree, before and after the refinement.
            Box::new(|| {
                let Some(refinement) = &self.refinement else {
                    return Ok(Vec::new());
                };
                let png = consistency_png(&refinement.map).map_err(encode_error("consistency.png"))?;
                Ok(vec![("consistency.png".into(), png)])
            }),
            // RASL's pictures.
            Box::new(|| {
                let Some(rasl) = &self.rasl else {
                    return Ok(Vec::new());
                };
                let images = rasl.images().map_err(encode_error("aligned/"))?;
                Ok(images
                    .into_iter()
                    .map(|(name, bytes)| (PathBuf::from("aligned").join(name), bytes))
                    .collect())
            }),
        ]
    }

    /// `structure.json` and `report.json` after the encoded `files` (the report times the
    /// outputs from `start`).
    fn finish_files(
        &self,
        mut files: Files,
        mesh: &TriangleMesh,
        start: Instant,
    ) -> Result<Files, PipelineError> {
        let structure =
            serde_json::to_vec_pretty(&self.structure_file()).map_err(encode_error("structure.json"))?;
        files.push(("structure.json".into(), structure));
        let report = self.report_file(mesh, start.elapsed().as_secs_f64());
        let report = serde_json::to_vec_pretty(&report).map_err(encode_error("report.json"))?;
        files.push(("report.json".into(), report));
        Ok(files)
    }

    /// `face.obj` (with its material and texture files when textured), `face.glb`, `face.ply`.
    fn mesh_files(&self, mesh: &TriangleMesh) -> Result<Files, PipelineError> {
        let mut files: Files = Vec::new();
        match &self.texture {
            Some(texture) => {
                let png = encode_png(&texture.atlas).map_err(encode_error("face.png"))?;
                let obj = crate::mesh::format_obj_with_material(mesh, Some(("face.mtl", "face")));
                files.push(("face.obj".into(), obj.into_bytes()));
                files.push((
                    "face.mtl".into(),
                    crate::mesh::format_mtl("face.png").into_bytes(),
                ));
                files.push((
                    "face.glb".into(),
                    encode_glb(mesh, "face", Some(PngTexture { png: &png })),
                ));
                files.push(("face.png".into(), png));
            }
            None => {
                files.push(("face.obj".into(), crate::mesh::format_obj(mesh).into_bytes()));
                files.push(("face.glb".into(), encode_glb(mesh, "face", None)));
            }
        }
        files.push((
            "face.ply".into(),
            encode_ply(mesh, PlyEncoding::BinaryLittleEndian),
        ));
        Ok(files)
    }

    /// With a texture: `texture-confidence.png` and `turntable.png` (from `turntable`'s views
    /// when they were made ready).
    fn texture_files(&self, turntable: Option<&Turntable>) -> Result<Files, PipelineError> {
        let Some(texture) = &self.texture else {
            return Ok(Vec::new());
        };
        let confidence =
            encode_png(&texture.confidence_image()).map_err(encode_error("texture-confidence.png"))?;
        let turntable = match turntable {
            Some(views) => views.render(&texture.atlas),
            None => texture
                .turntable(&self.mesh)
                .map_err(encode_error("turntable.png"))?,
        };
        Ok(vec![
            ("texture-confidence.png".into(), confidence),
            (
                "turntable.png".into(),
                encode_png(&turntable).map_err(encode_error("turntable.png"))?,
            ),
        ])
    }

    /// `surface.json` and `surface.step`: the exact surface in output units, the STEP file's
    /// face trimmed to the face region (the clip polygon, exactly as the mesh is clipped).
    fn surface_files(&self) -> Result<Files, PipelineError> {
        let units = self.options.units;
        let surface = self.face.surface().transformed(&units.transform());
        let description = match units {
            Units::Millimetres { eye_distance } => {
                format!("splineface face, millimetres ({eye_distance} mm between the eye centres), x right, y up, z toward the viewer")
            }
            Units::Canonical => "splineface face, canonical units (50 between the eye centres), x right, y up, z toward the viewer".to_owned(),
        };
        let step = encode_step(
            &surface,
            &StepOptions {
                name: "face",
                description: &description,
                // Canonical units (50 between the eye centres, about 1.26 mm each) are
                // declared as millimetres: a CAD tool then opens the face near its natural size
                // rather than a thousand times too large; the description says what they are.
                unit: LengthUnit::Millimetre,
                trim: self.face.clip(),
            },
        )
        .map_err(encode_error("surface.step"))?;
        Ok(vec![
            ("surface.json".into(), surface.to_json().into_bytes()),
            ("surface.step".into(), step.into_bytes()),
        ])
    }

    /// `depth.exr`, `depth.png` and `preview.png`: the depth map from the front.
    fn depth_files(&self, mesh: &TriangleMesh) -> Result<Files, PipelineError> {
        let map = self.depth_map_of(mesh)?;
        Ok(vec![
            (
                "depth.exr".into(),
                encode_depth_exr(&map).map_err(encode_error("depth.exr"))?,
            ),
            (
                "depth.png".into(),
                encode_depth_png(&map).map_err(encode_error("depth.png"))?,
            ),
            (
                "preview.png".into(),
                shaded_png(&map).map_err(encode_error("preview.png"))?,
            ),
        ])
    }

    /// `curvature.png`: the surface's curvedness `√((κ₁² + κ₂²)/2)` (1/mm, or per canonical
    /// unit) over its `(u, v)` square, [`CURVATURE_SIDE`] samples a side (`v` up), dark outside
    /// the face region, on a viridis scale up to its 99th percentile over the face. Curvedness
    /// is how sharply the surface bends whatever the direction: where a smooth face is
    /// ridged, pinched or bumpy shows at a glance.
    fn curvature_png(&self) -> Result<Vec<u8>, PipelineError> {
        let units = self.options.units;
        let surface = self.face.surface().transformed(&units.transform());
        let side = CURVATURE_SIDE;
        let along = |(lo, hi): (Real, Real)| -> Vec<Real> {
            (0..side)
                .map(|i| (lo + (hi - lo) * (i as Real + 0.5) / side as Real).clamp(lo, hi))
                .collect()
        };
        let (us, vs) = (along(surface.domain_u()), along(surface.domain_v()));
        let grid = surface
            .curvature_grid(&us, &vs)
            .map_err(encode_error("curvature.png"))?;
        let clip = self.face.clip();
        let mut values = vec![Real::NAN; side * side];
        for (i, &u) in us.iter().enumerate() {
            for (j, &v) in vs.iter().enumerate() {
                if let Some(c) = &grid[i * side + j]
                    && crate::geometry::polygon_contains(clip, nalgebra::Point2::new(u, v))
                {
                    let (k1, k2) = c.principal;
                    values[j * side + i] = ((k1 * k1 + k2 * k2) / 2.0).sqrt();
                }
            }
        }
        let mut inside: Vec<Real> = values.iter().copied().filter(|v| v.is_finite()).collect();
        inside.sort_by(Real::total_cmp);
        let top = inside
            .get(((inside.len().max(1) - 1) as Real * 0.99) as usize)
            .copied()
            .filter(|t| *t > 0.0)
            .unwrap_or(1.0);
        let unit = match units {
            Units::Millimetres { .. } => "1/mm",
            Units::Canonical => "1/unit",
        };
        crate::render::heatmap_png(&values, side, side, top, unit).map_err(encode_error("curvature.png"))
    }

    /// `structure.json`'s content.
    pub fn structure_file(&self) -> StructureFile {
        let units = self.options.units;
        let scale = units.per_canonical_unit();
        let structure = self.structure();
        let point = |p: &Point3<Real>| [p.x, p.y, p.z];
        let photos = self
            .depth
            .photos
            .iter()
            .zip(&self.photo_fits)
            .map(|(p, fit)| {
                let [yaw, pitch, roll] = p.pose.yaw_pitch_roll_degrees();
                PhotoPose {
                    fit_rms_pixels: fit.rms_pixels,
                    name: p.name.clone(),
                    pitch_degrees: pitch,
                    pixels_per_unit: p.pose.scale / scale,
                    rms_pixels: p.rms_pixels,
                    rms_units: p.rms_units * scale,
                    roll_degrees: roll,
                    yaw_degrees: yaw,
                }
            })
            .collect();
        let expressions = self
            .space
            .as_ref()
            .filter(|s| !s.expression_names.is_empty())
            .map(|s| {
                self.depth
                    .photos
                    .iter()
                    .zip(&s.expressions)
                    .map(|(p, e)| PhotoExpression {
                        name: p.name.clone(),
                        weights: s
                            .expression_names
                            .iter()
                            .zip(e)
                            .filter(|(_, w)| **w > 0.0)
                            .map(|(name, w)| (name.clone(), *w))
                            .collect(),
                    })
                    .collect()
            });
        StructureFile {
            expressions,
            eye_centres: EyeCentres {
                left: point(&structure[LEFT_EYE_CENTRE]),
                right: point(&structure[RIGHT_EYE_CENTRE]),
            },
            format: "splineface/structure",
            frame: "x to the image's right, y up, z toward the viewer, origin between the eye centres",
            per_canonical_unit: scale,
            photos,
            points: structure.iter().map(point).collect(),
            similarity: self.depth.similarity,
            space_weights: self.space.as_ref().map(|s| s.weights.clone()),
            units: units.name(),
            version: 1,
        }
    }

    /// `report.json`'s content; `outputs_seconds` is the time spent encoding the outputs.
    pub fn report_file(&self, mesh: &TriangleMesh, outputs_seconds: Real) -> ReportFile {
        let mut timings: Vec<StageTime> = self
            .timings
            .iter()
            .map(|(stage, s)| StageTime {
                ms: 1e3 * s,
                stage: stage.clone(),
            })
            .collect();
        timings.push(StageTime {
            ms: 1e3 * outputs_seconds,
            stage: "outputs (encoding)".into(),
        });
        let report = self.face.report();
        let refinement = self.refinement.as_ref().map(|r| {
            let field = r.displacement_size();
            RefinementReport {
                accepted: r.accepted,
                share: r.share,
                coverage: r.coverage.clone(),
                disagreement_after: r.disagreement.1,
                disagreement_before: r.disagreement.0,
                field_max_units: field.map(|(max, _)| max),
                field_rms_units: field.map(|(_, rms)| rms),
                held_out_after: r.held_out.map(|h| h.1),
                held_out_before: r.held_out.map(|h| h.0),
                iterations: r.iterations,
                landmark_rms_units_after: r.landmark_rms.1,
                landmark_rms_units_before: r.landmark_rms.0,
                note: r.note.clone(),
                samples: r.samples.0,
                samples_seen_twice: r.samples.1,
            }
        });
        let texture = match (&self.texture, &self.texture_photos) {
            (Some(t), Ok(names)) => {
                let [seen, mirrored, filled] = t.counts();
                let inside = (seen + mirrored + filled).max(1) as Real;
                Some(TextureReport::Made {
                    filled: filled as Real / inside,
                    mirrored: mirrored as Real / inside,
                    photos: names
                        .iter()
                        .zip(&t.gains)
                        .zip(&t.shares)
                        .map(|((name, gain), share)| TexturePhotoReport {
                            gain: *gain,
                            name: name.clone(),
                            share: *share,
                        })
                        .collect(),
                    seen: seen as Real / inside,
                    sharpness: self.options.texture.sharpness,
                    size: t.atlas.width(),
                    texels_inside: seen + mirrored + filled,
                })
            }
            (_, Err(why)) => Some(TextureReport::None { none: why.clone() }),
            (None, Ok(_)) => None,
        };
        ReportFile {
            depth: DepthReport {
                converged: self.depth.converged,
                iterations: self.depth.iterations,
                objective: self.depth.objective.clone(),
                similarity: self.depth.similarity,
            },
            format: "splineface/report",
            frontal_method: format!("{:?}", self.frontal.method),
            frontal_residual_rms_units: self.frontal.residual_rms,
            landmark_agreement: self
                .agreement
                .iter()
                .map(|(name, a)| NamedAgreement {
                    agreement: *a,
                    name: name.clone(),
                })
                .collect(),
            photos_dropped: self
                .dropped
                .iter()
                .map(|d| DroppedPhoto {
                    name: d.name.clone(),
                    reason: d.reason.clone(),
                })
                .collect(),
            photos_used: self.depth.photos.iter().map(|p| p.name.clone()).collect(),
            rasl: self.rasl.as_ref().map(|r| RaslReport {
                inner_iterations: r.inner_iterations,
                objective: r.objective.clone(),
                outer_iterations: r.objective.len(),
                seconds: r.seconds,
            }),
            surface: SurfaceReport {
                deformation: if self.space.is_some() {
                    "none (the face space's member)".to_owned()
                } else {
                    format!("{:?}", self.face.deformation())
                },
                displacement_max_units: report.displacement_max,
                displacement_rms_units: report.displacement_rms,
                mesh_triangles: mesh.triangles().len(),
                mesh_vertices: mesh.positions().len(),
                point_rms_units: report.point_rms,
                refinement,
                shape: self.shape.clone(),
                space_held_modes: self.space.as_ref().map(|s| s.held.clone()),
                space_rms_units: self.space.as_ref().map(|s| s.rms_units.clone()),
                space_weights: self.space.as_ref().map(|s| s.weights.clone()),
                structure_weight: self.structure_weight.0,
                structure_weight_reason: self.structure_weight.1.clone(),
                textured: self.texture.is_some(),
            },
            texture,
            timings,
            version: 1,
            warnings: self.depth.warnings.iter().map(ToString::to_string).collect(),
        }
    }
}

/// The consistency map as a picture: the photos' disagreement on the landmark fit's face
/// (left) and on the refined one (right), each sample a 4 × 4 block, on one scale (0 to 1 in
/// units of the normalised intensity: a photo's deviation over the face with the default lit
/// measure, its local deviation with a window, [`crate::face::Window`]; dark where fewer than
/// two photos see the face).
fn consistency_png(map: &crate::face::ConsistencyMap) -> Result<Vec<u8>, crate::io::EncodeError> {
    const BLOCK: usize = 4;
    let (w, h) = (map.width, map.height);
    let gap = 4;
    let width = (2 * w + gap) * BLOCK;
    let height = h * BLOCK;
    let mut values = vec![Real::NAN; width * height];
    for (side, grid) in [(0, &map.before), (w + gap, &map.after)] {
        for r in 0..h {
            for c in 0..w {
                let v = grid[r * w + c];
                for dr in 0..BLOCK {
                    for dc in 0..BLOCK {
                        values[(r * BLOCK + dr) * width + (side + c) * BLOCK + dc] = v;
                    }
                }
            }
        }
    }
    crate::render::heatmap_png(&values, width, height, 1.0, "")
}
