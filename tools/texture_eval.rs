//! The texture atlas against the truth's colours (issue 19): the whole photo path on
//! `lps-head`'s two given photo sets (SeetaFace, dlib's 68 points, the default reconstruction),
//! then every texel of the face compared with the scan's own colour map where the aligned
//! reconstruction's surface point meets the scan.
//!
//! For each texel inside the clip region: its surface point is carried into the truth's frame
//! by the similarity that scores the shape ([`splineface::compare::inner_face_score`]:
//! landmarks, then trimmed ICP), the closest point of the textured scan is found (texels more
//! than 3 mm from it are left out), and the scan's colour there is the truth. The photos are
//! lit and the colour map is not, so each texture is first given the per-channel gain that
//! best maps it onto the truth (least squares in linear light); then, in sRGB levels (0–255):
//! the mean absolute error, the PSNR, and the colour steps between neighbouring texels that
//! differ from the truth's steps, across the atlas's seams (neighbours whose dominant photos
//! differ) and elsewhere. Comparing texel by texel on the reconstruction's own surface is
//! rendering both textures on the same geometry from every side at once.
//!
//! Compared: the atlas as the pipeline bakes it, variants of its options, and the texture the
//! pipeline made before (the whole most frontal photo, projected by the depth stage's pose).
//!
//! Run: `cargo run --release --example texture_eval -- [--out DIR] [--model PATH]
//! [--data DIR]`; writes `DIR/texture.md` (default `target/texture-eval`; the committed page is
//! `tools/results/texture.md`).

#[path = "common/mod.rs"]
mod common;
#[allow(dead_code)]
#[path = "photo_eval/photos.rs"]
mod photos;
#[allow(dead_code)]
#[path = "photo_eval/subjects.rs"]
mod subjects;

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use nalgebra::{Point2, Point3, Similarity3};
use splineface::Real;
use splineface::align::PhotoPoints;
use splineface::compare::{InnerFaceOptions, fit_similarity, inner_face_score};
use splineface::face::{FaceTexture, NO_PHOTO, TexelSource, TextureOptions};
use splineface::landmarker::ShapePredictor;
use splineface::mesh::ClosestPoints;
use splineface::pipeline::{Input, PhotoImage, PipelineOptions, Reconstruction, reconstruct};
use splineface::reference::ReferenceFace;

/// sRGB level (0–255) to linear light.
fn linear(level: Real) -> Real {
    Real::from(splineface::render::srgb_to_linear((level / 255.0) as f32))
}

/// Linear light to an sRGB level (0–255, not rounded).
fn level(c: Real) -> Real {
    255.0 * splineface::render::linear_to_srgb(c)
}

/// The texels compared: atlas index, the truth's colour (linear), the atlas's and the old
/// texture's (linear).
struct Texels {
    index: Vec<usize>,
    truth: Vec<[Real; 3]>,
    old: Vec<[Real; 3]>,
}

/// The truth's colour and the old single-photo texture's at every texel of `result`'s atlas
/// that lies inside the clip region and within 3 mm of the scan.
fn texels(
    result: &Reconstruction,
    subject: &subjects::Subject,
    photos: &[&image::RgbImage],
) -> Result<Texels> {
    let texture = result.texture.as_ref().context("no texture")?;
    let side = texture.atlas.width() as usize;
    // Canonical → truth frame: the scoring's similarity composed with the units, then out of
    // the truth's view frame.
    let comparison = inner_face_score(
        &result.output_mesh(),
        &subject.truth,
        (&result.structure(), &subject.structure),
        &InnerFaceOptions::default(),
    )?;
    let (to_view, rms) = fit_similarity(result.mesh.mesh.positions(), comparison.aligned.positions())
        .context("degenerate mesh")?;
    if rms > 1e-6 {
        bail!("the aligned mesh is not a similarity of the reconstruction ({rms} mm)");
    }
    let (unifying, _) = splineface::structure::unify(&subject.structure)?;
    let view = Similarity3::from_isometry(unifying.isometry, 1.0);
    let to_truth = view.inverse() * to_view;
    let scan = ClosestPoints::new(&subject.mesh);
    let uv = subject
        .mesh
        .texture()
        .context("the scan has no texture coordinates")?;

    let mut index = Vec::new();
    let mut points = Vec::new();
    let mut params = Vec::new();
    for k in 0..side * side {
        if texture.sources[k] != TexelSource::Seen {
            continue;
        }
        let (c, r) = (k % side, k / side);
        let p = [
            (c as Real + 0.5) / side as Real,
            1.0 - (r as Real + 0.5) / side as Real,
        ];
        index.push(k);
        params.push(p);
    }
    let surface_points = result.face.surface().eval_many(&params)?;
    for p in &surface_points {
        points.push(to_truth * p);
    }
    let found = scan.closest_many(&points);
    let frontal = result
        .depth
        .most_frontal_photo()
        .context("no photo fits well enough for the old texture")?;
    let fit = &result.depth.photos[frontal];
    let old_image = photos[frontal];
    let (mut kept, mut truth, mut old) = (Vec::new(), Vec::new(), Vec::new());
    for (n, hit) in found.iter().enumerate() {
        if hit.distance > 3.0 {
            continue;
        }
        let t = subject.mesh.triangles()[hit.triangle];
        let corners = t.map(|v| subject.mesh.positions()[v as usize]);
        let w = barycentric(&hit.point, &corners);
        let uvs = uv.triangles[hit.triangle].map(|v| uv.uvs[v as usize]);
        let at = Point2::from(w[0] * uvs[0].coords + w[1] * uvs[1].coords + w[2] * uvs[2].coords);
        truth.push(subject.colour.sample(at.x, at.y));
        let q = fit.pixel(&surface_points[n]);
        let (x, y) = (
            q.x.round().clamp(0.0, Real::from(old_image.width() - 1)) as u32,
            q.y.round().clamp(0.0, Real::from(old_image.height() - 1)) as u32,
        );
        old.push(old_image.get_pixel(x, y).0.map(|v| linear(Real::from(v))));
        kept.push(index[n]);
    }
    Ok(Texels {
        index: kept,
        truth,
        old,
    })
}

fn barycentric(p: &Point3<Real>, [a, b, c]: &[Point3<Real>; 3]) -> [Real; 3] {
    let (v0, v1, v2) = (b - a, c - a, p - a);
    let (d00, d01, d11) = (v0.dot(&v0), v0.dot(&v1), v1.dot(&v1));
    let (d20, d21) = (v2.dot(&v0), v2.dot(&v1));
    let den = d00 * d11 - d01 * d01;
    if den.abs() < 1e-30 {
        return [1.0, 0.0, 0.0];
    }
    let v = (d11 * d20 - d01 * d21) / den;
    let w = (d00 * d21 - d01 * d20) / den;
    [1.0 - v - w, v, w]
}

/// One texture's figures against the truth.
struct Figures {
    mean_error: Real,
    psnr: Real,
    seam_step: Real,
    other_step: Real,
    seam_pairs: usize,
}

/// Compares `colours` (linear, per compared texel) with the truth after the best per-channel
/// gain; `dominant` gives the seams (or none).
fn figures(colours: &[[Real; 3]], texels: &Texels, side: usize, dominant: Option<&[u16]>) -> Figures {
    let gains: [Real; 3] = std::array::from_fn(|ch| {
        let (mut num, mut den) = (0.0, 0.0);
        for (c, t) in colours.iter().zip(&texels.truth) {
            num += c[ch] * t[ch];
            den += c[ch] * c[ch];
        }
        if den > 0.0 { num / den } else { 1.0 }
    });
    let levels: Vec<[Real; 3]> = colours
        .iter()
        .map(|c| std::array::from_fn(|ch| level(gains[ch] * c[ch])))
        .collect();
    let truth: Vec<[Real; 3]> = texels.truth.iter().map(|t| t.map(level)).collect();
    let (mut abs, mut sq) = (0.0, 0.0);
    for (a, t) in levels.iter().zip(&truth) {
        for ch in 0..3 {
            abs += (a[ch] - t[ch]).abs();
            sq += (a[ch] - t[ch]).powi(2);
        }
    }
    let n = (3 * levels.len()).max(1) as Real;
    // Steps to the right and downward neighbours among the compared texels.
    let mut slot = vec![usize::MAX; side * side];
    for (n, &k) in texels.index.iter().enumerate() {
        slot[k] = n;
    }
    let (mut seam, mut seams, mut other, mut others) = (0.0, 0usize, 0.0, 0usize);
    for (n, &k) in texels.index.iter().enumerate() {
        for j in [k + 1, k + side] {
            if j >= side * side || (j == k + 1 && j % side == 0) || slot[j] == usize::MAX {
                continue;
            }
            let m = slot[j];
            let step: Real = (0..3)
                .map(|ch| ((levels[m][ch] - levels[n][ch]) - (truth[m][ch] - truth[n][ch])).abs())
                .sum::<Real>()
                / 3.0;
            let across = dominant.is_some_and(|d| d[k] != d[j] && d[k] != NO_PHOTO && d[j] != NO_PHOTO);
            if across {
                seam += step;
                seams += 1;
            } else {
                other += step;
                others += 1;
            }
        }
    }
    Figures {
        mean_error: abs / n,
        psnr: 10.0 * (255.0 * 255.0 / (sq / n)).log10(),
        seam_step: if seams > 0 {
            seam / seams as Real
        } else {
            Real::NAN
        },
        other_step: other / others.max(1) as Real,
        seam_pairs: seams,
    }
}

/// The atlas's colours (linear) at the compared texels, which index an atlas of side `side`.
/// An atlas of another side is sampled as a renderer samples it: bilinearly (in linear light)
/// at each compared texel's centre `(u, v)`, so that a coarser atlas pays for its blur.
fn atlas_colours(texture: &FaceTexture, texels: &Texels, side: usize) -> Vec<[Real; 3]> {
    let own = texture.atlas.width() as usize;
    let at = |c: usize, r: usize| {
        texture
            .atlas
            .get_pixel(c as u32, r as u32)
            .0
            .map(|v| linear(Real::from(v)))
    };
    texels
        .index
        .iter()
        .map(|&k| {
            if own == side {
                return at(k % side, k / side);
            }
            // Texel centre (k + ½)/side in the compared atlas, at t·own − ½ in this one.
            let place = |k: usize| {
                ((k as Real + 0.5) / side as Real * own as Real - 0.5).clamp(0.0, (own - 1) as Real)
            };
            let (x, y) = (place(k % side), place(k / side));
            let (x0, y0) = (x as usize, y as usize);
            let (x1, y1) = ((x0 + 1).min(own - 1), (y0 + 1).min(own - 1));
            let (fx, fy) = (x - x0 as Real, y - y0 as Real);
            let (a, b, c, d) = (at(x0, y0), at(x1, y0), at(x0, y1), at(x1, y1));
            std::array::from_fn(|ch| {
                (a[ch] * (1.0 - fx) + b[ch] * fx) * (1.0 - fy) + (c[ch] * (1.0 - fx) + d[ch] * fx) * fy
            })
        })
        .collect()
}

/// The atlas's dominant photos on an atlas of side `side` (nearest texel).
fn dominant_at(texture: &FaceTexture, side: usize) -> Vec<u16> {
    let own = texture.atlas.width() as usize;
    if own == side {
        return texture.dominant.clone();
    }
    let nearest = |k: usize| (((k as Real + 0.5) / side as Real * own as Real) as usize).min(own - 1);
    (0..side * side)
        .map(|k| texture.dominant[nearest(k / side) * own + nearest(k % side)])
        .collect()
}

/// The side of the atlas whose texels are compared; every atlas is sampled at them.
const COMPARED_SIDE: usize = 1024;

fn main() -> Result<()> {
    let shared = PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../shared"));
    let mut out = PathBuf::from("target/texture-eval");
    let mut model = shared.join("models/shape_predictor_68_face_landmarks.dat");
    let mut data = shared.join("data/lps-head");
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = || args.next().with_context(|| format!("{a} needs a value"));
        match a.as_str() {
            "--out" => out = value()?.into(),
            "--model" => model = value()?.into(),
            "--data" => data = value()?.into(),
            other => bail!("unknown argument `{other}`"),
        }
    }
    let started = std::time::Instant::now();
    let model = ShapePredictor::read(&model)?;
    let subject = subjects::lps(&data)?;
    let reference = ReferenceFace::embedded();
    std::fs::create_dir_all(&out)?;

    // The first variant's texels are the ones compared: a 1024² atlas's (the former default),
    // at which every other atlas is sampled.
    let variants: Vec<(&str, TextureOptions)> = vec![
        (
            "atlas 1024² (the former default)",
            TextureOptions {
                size: Some(COMPARED_SIDE as u32),
                ..TextureOptions::default()
            },
        ),
        (
            "atlas (default: side from the photos, p = 1, matched, mirror)",
            TextureOptions::default(),
        ),
        (
            "atlas, p = 4",
            TextureOptions {
                sharpness: 4.0,
                ..TextureOptions::default()
            },
        ),
        (
            "atlas, p = 0.5",
            TextureOptions {
                sharpness: 0.5,
                ..TextureOptions::default()
            },
        ),
        (
            "atlas, p = 2",
            TextureOptions {
                sharpness: 2.0,
                ..TextureOptions::default()
            },
        ),
        (
            "atlas, p = 16",
            TextureOptions {
                sharpness: 16.0,
                ..TextureOptions::default()
            },
        ),
        (
            "atlas, colours not matched",
            TextureOptions {
                match_colours: false,
                ..TextureOptions::default()
            },
        ),
    ];
    // Coarser atlases, sampled bilinearly at the default atlas's texels.
    let variants: Vec<(String, TextureOptions)> = variants
        .into_iter()
        .map(|(name, options)| (name.to_string(), options))
        .chain([768, 512, 384, 256].map(|size| {
            (
                format!("atlas {size}²"),
                TextureOptions {
                    size: Some(size),
                    ..TextureOptions::default()
                },
            )
        }))
        .collect();
    let mut page = String::new();
    writeln!(page, "# Texture atlas against the truth's colours\n")?;
    writeln!(
        page,
        "Made by `cargo run --release --example texture_eval` (tools/texture_eval.rs): the whole photo path on `lps-head`'s given photo sets, every texel of the face compared with the scan's own colour map where the aligned reconstruction meets the scan (within 3 mm), after the per-channel gain that best maps each texture onto the truth (the photos are lit, the map is not). Levels are sRGB, 0–255. Seam steps: the colour step between neighbouring texels whose dominant photos differ, less the truth's step there; other steps: the same between neighbours elsewhere. The texels compared are a 1024² atlas's; an atlas of another side is sampled at them bilinearly (in linear light), as a renderer samples it.\n"
    )?;
    writeln!(
        page,
        "The scan: \"Infinite, 3D Head Scan by Lee Perry-Smith is licensed under a Creative Commons Attribution 3.0 Unported License. Based on a work at www.triplegangers.com.\"\n"
    )?;
    writeln!(
        page,
        "| set | texture | side | texels | mean error | PSNR (dB) | seam step (pairs) | other step | bake (ms) |"
    )?;
    writeln!(page, "|---|---|---|---|---|---|---|---|---|")?;
    for set in ["photos-8", "photos-3"] {
        let photos = photos::read_set(&data.join(set))?;
        let mut inputs = Vec::new();
        let mut colours = Vec::new();
        for photo in &photos {
            let Ok(found) = splineface::detect::landmark_subject(&model, &photo.image) else {
                eprintln!("{set}/{}: no face found", photo.name);
                continue;
            };
            inputs.push(Input {
                points: PhotoPoints::from_ibug68(photo.name.clone(), &found.ibug)?,
                image: Some(PhotoImage::from_dynamic(&photo.image)?),
            });
            colours.push(photo.image.to_rgb8());
        }
        let mut reference_texels = None;
        for (name, texture_options) in &variants {
            let options = PipelineOptions {
                texture: *texture_options,
                ..PipelineOptions::default()
            };
            let result = reconstruct(&inputs, reference, &options, |_| {})?;
            let kept: Vec<&image::RgbImage> = result
                .depth
                .photos
                .iter()
                .map(|p| {
                    let k = inputs
                        .iter()
                        .position(|i| i.points.name == p.name)
                        .expect("a kept photo is an input");
                    &colours[k]
                })
                .collect();
            let texels = match reference_texels.take() {
                Some(t) => t,
                None => texels(&result, &subject, &kept)?,
            };
            let texture = result.texture.as_ref().context("no texture")?;
            let side = COMPARED_SIDE;
            let bake_ms: Real = result
                .timings
                .iter()
                .filter(|(s, _)| s == "texture")
                .map(|(_, t)| 1e3 * t)
                .sum();
            let atlas = figures(
                &atlas_colours(texture, &texels, side),
                &texels,
                side,
                Some(&dominant_at(texture, side)),
            );
            writeln!(
                page,
                "| {set} | {name} | {} | {} | {:.2} | {:.2} | {:.2} ({}) | {:.2} | {bake_ms:.0} |",
                texture.atlas.width(),
                texels.index.len(),
                atlas.mean_error,
                atlas.psnr,
                atlas.seam_step,
                atlas.seam_pairs,
                atlas.other_step
            )?;
            if name.starts_with("atlas (default") {
                let old = figures(&texels.old, &texels, side, None);
                writeln!(
                    page,
                    "| {set} | the most frontal photo alone (before) | – | {} | {:.2} | {:.2} | – | {:.2} | – |",
                    texels.index.len(),
                    old.mean_error,
                    old.psnr,
                    old.other_step
                )?;
                texture.atlas.save(out.join(format!("{set}-atlas.png")))?;
                texture
                    .turntable(&result.mesh)?
                    .save(out.join(format!("{set}-turntable.png")))?;
                texture
                    .confidence_image()
                    .save(out.join(format!("{set}-confidence.png")))?;
                let [seen, mirrored, filled] = texture.counts();
                eprintln!("{set}: seen {seen}, mirrored {mirrored}, filled {filled}");
            }
            reference_texels = Some(texels);
            eprintln!("{set} {name}: {:.0} s", started.elapsed().as_secs_f64());
        }
    }
    writeln!(
        page,
        "\nBake times are the pipeline's `texture` stage (2 cores).\n\nThe default atlas from photos-8, turned (`turntable.png`; derived from the scan, CC BY 3.0 as above):\n\n![photos-8](photos-8-turntable.png)"
    )?;
    std::fs::write(out.join("texture.md"), page)?;
    eprintln!("wrote {}", out.join("texture.md").display());
    Ok(())
}
