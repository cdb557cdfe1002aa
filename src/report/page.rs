//! `report.html`: one self-contained page of a run's outputs.
//!
//! Everything is inlined (pictures as `data:` URIs, the face as a GLB `data:` URI, the viewer's
//! script), so the page opens from a file, mailed or archived, with no network. The face is
//! shown by `<model-viewer>` 4.4.0 (Google, Apache-2.0; it bundles three.js, MIT), vendored in
//! `src/report/vendor/` by `tools/fetch-viewer` with its licences, and adding 1.07 MB to the
//! binary and to each page.
//!
//! The page is built from the run's output files as they are about to be written, so it shows
//! whatever subset is there: a missing or unreadable file leaves its section out (or says
//! so), never the page.
//!
//! A small script records what goes wrong while the page loads (script errors, console
//! errors and warnings, images that do not load) and, once the viewer has drawn the face, how much of its
//! canvas differs from the background; it writes both as JSON into the hidden element
//! `#self-check`. The browser test (`tests/splineface/report_page.rs`) reads it.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use serde_json::Value;

/// The viewer's script, inlined into each page.
static VIEWER: &str = include_str!("vendor/model-viewer.min.js");

/// Which outputs a page shows, and where they are among the files.
#[derive(Debug, Clone, PartialEq)]
pub struct PageOptions {
    /// The page's title.
    pub title: String,
    /// The folder of the reconstruction's outputs among the files (empty: the top).
    pub reconstruction: PathBuf,
    /// The folder of a comparison with a ground truth (`heatmap.png`, `stats.json`, ...), if
    /// one was made.
    pub comparison: Option<PathBuf>,
}

/// The files, looked up by path.
struct Files<'a> {
    files: &'a [(PathBuf, Vec<u8>)],
}

impl<'a> Files<'a> {
    fn get(&self, path: &Path) -> Option<&'a [u8]> {
        self.files
            .iter()
            .find(|(p, _)| p == path)
            .map(|(_, b)| b.as_slice())
    }

    fn json(&self, path: &Path) -> Option<Value> {
        self.get(path).and_then(|b| serde_json::from_slice(b).ok())
    }

    /// The files directly in `folder` with the extension `ext`, by name.
    fn in_folder(&self, folder: &Path, ext: &str) -> Vec<(&'a Path, &'a [u8])> {
        let mut found: Vec<(&Path, &[u8])> = self
            .files
            .iter()
            .filter(|(p, _)| p.parent() == Some(folder) && p.extension().is_some_and(|e| e == ext))
            .map(|(p, b)| (p.as_path(), b.as_slice()))
            .collect();
        found.sort_by(|a, b| a.0.cmp(b.0));
        found
    }
}

/// Escapes text for HTML content and attribute values.
fn escape(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            '\0' => out.push('\u{FFFD}'),
            c => out.push(c),
        }
    }
    out
}

/// A picture as a `data:` URI: a JPEG as it is; photographs given as PNG (`photo`)
/// re-encoded as JPEG ([`crate::io::encode_jpeg`] at [`crate::io::JPEG_QUALITY`]) to keep the
/// page small; other PNGs as they are (and a photograph wider or taller than JPEG's 65,535
/// pixels). A PNG that does not decode is inlined as is (the browser then reports it, and the
/// self-check names it).
fn picture_uri(bytes: &[u8], photo: bool) -> String {
    if bytes.starts_with(&[0xFF, 0xD8, 0xFF]) {
        return format!("data:image/jpeg;base64,{}", base64::encode(bytes));
    }
    if photo
        && let Ok(image) = image::load_from_memory_with_format(bytes, image::ImageFormat::Png)
        && let Ok(jpeg) = crate::io::encode_jpeg(&image.to_rgb8(), crate::io::JPEG_QUALITY)
    {
        return format!("data:image/jpeg;base64,{}", base64::encode(&jpeg));
    }
    format!("data:image/png;base64,{}", base64::encode(bytes))
}

/// The pictures of a page, inlined last and in parallel (decoding and re-encoding them is
/// most of a page's time): [`figure`] leaves a marker `NUL index NUL` where each goes.
type Pictures<'a> = Vec<(&'a [u8], bool)>;

/// A figure with a picture and a caption.
fn figure<'a>(
    page: &mut String,
    pictures: &mut Pictures<'a>,
    png: &'a [u8],
    photo: bool,
    caption: &str,
    class: &str,
) {
    let _ = writeln!(
        page,
        "<figure class=\"{class}\"><img src=\"\0{}\0\" alt=\"{}\"><figcaption>{}</figcaption></figure>",
        pictures.len(),
        escape(caption),
        escape(caption)
    );
    pictures.push((png, photo));
}

/// The page with each picture's marker replaced by its `data:` URI.
fn inline_pictures(page: &str, pictures: &Pictures<'_>) -> String {
    use rayon::prelude::*;
    let uris: Vec<String> = pictures
        .par_iter()
        .map(|(png, photo)| picture_uri(png, *photo))
        .collect();
    let mut out = String::with_capacity(page.len() + uris.iter().map(String::len).sum::<usize>());
    for (k, part) in page.split('\0').enumerate() {
        if k % 2 == 0 {
            out.push_str(part);
        } else if let Some(uri) = part.parse::<usize>().ok().and_then(|i| uris.get(i)) {
            out.push_str(uri);
        }
    }
    out
}

/// A number with `digits` decimals, or a dash.
fn number(value: Option<&Value>, digits: usize) -> String {
    value
        .and_then(Value::as_f64)
        .filter(|v| v.is_finite())
        .map_or_else(|| "–".to_owned(), |v| format!("{v:.digits$}"))
}

/// `text` with its first letter capitalised and a full stop at its end (empty stays empty).
fn sentence(text: &str) -> String {
    let mut chars = text.trim().chars();
    match chars.next() {
        None => String::new(),
        Some(first) => {
            let mut out: String = first.to_uppercase().chain(chars).collect();
            if !out.ends_with('.') {
                out.push('.');
            }
            out
        }
    }
}

/// The string at `value`, or empty.
fn text(value: Option<&Value>) -> &str {
    value.and_then(Value::as_str).unwrap_or("")
}

/// One row of the photo table.
struct PhotoRow {
    name: String,
    status: &'static str,
    reason: String,
    pose: Option<Value>,
    agreement: Option<Value>,
    share: Option<Value>,
}

/// The photos named by the report (used, dropped, skipped), with what is known of each.
fn photo_rows(report: &Value, structure: &Value) -> Vec<PhotoRow> {
    let mut rows: Vec<PhotoRow> = Vec::new();
    let poses = structure["photos"].as_array().cloned().unwrap_or_default();
    let lookup = |list: &Value, key: &str, name: &str| -> Option<Value> {
        list.as_array()?
            .iter()
            .find(|e| e["name"].as_str() == Some(name))
            .map(|e| e[key].clone())
    };
    for name in report["photos_used"].as_array().into_iter().flatten() {
        let name = name.as_str().unwrap_or("").to_owned();
        rows.push(PhotoRow {
            pose: poses.iter().find(|p| p["name"].as_str() == Some(&name)).cloned(),
            agreement: lookup(&report["landmark_agreement"], "agreement", &name),
            share: lookup(&report["texture"]["photos"], "share", &name),
            status: "used",
            reason: String::new(),
            name,
        });
    }
    for dropped in report["photos_dropped"].as_array().into_iter().flatten() {
        let name = text(dropped.get("name")).to_owned();
        rows.push(PhotoRow {
            pose: None,
            agreement: lookup(&report["landmark_agreement"], "agreement", &name),
            share: None,
            status: "dropped",
            reason: text(dropped.get("reason")).to_owned(),
            name,
        });
    }
    for skipped in report["photos_skipped"].as_array().into_iter().flatten() {
        let line = skipped.as_str().unwrap_or("");
        let (name, reason) = line.split_once(": ").unwrap_or((line, ""));
        rows.push(PhotoRow {
            name: name.to_owned(),
            status: "skipped",
            reason: reason.to_owned(),
            pose: None,
            agreement: None,
            share: None,
        });
    }
    rows
}

/// The page's style sheet.
const STYLE: &str = r#"
:root { color-scheme: dark; --fg: #e8e8e8; --muted: #a0a0a0; --bg: #1c1c1c; --panel: #262626; --accent: #7fc8ff; }
body { margin: 0; font: 15px/1.45 system-ui, sans-serif; color: var(--fg); background: var(--bg); }
header, section, footer { max-width: 1280px; margin: 0 auto; padding: 12px 24px; }
h1 { font-size: 22px; margin: 8px 0; } h2 { font-size: 18px; margin: 18px 0 8px; color: var(--accent); }
p.lead { color: var(--muted); margin: 4px 0; }
#face-row { display: flex; gap: 24px; flex-wrap: wrap; align-items: flex-start; }
model-viewer { width: 640px; height: 560px; background: #2e2e2e; border-radius: 6px; }
.controls { margin: 8px 0; } .controls label { margin-right: 16px; cursor: pointer; }
table { border-collapse: collapse; margin: 6px 0 12px; } td, th { padding: 3px 10px; text-align: left; border-bottom: 1px solid #333; vertical-align: top; }
th { color: var(--muted); font-weight: 600; } td.n { text-align: right; font-variant-numeric: tabular-nums; }
.used { color: #8ee08e; } .dropped { color: #ffbe46; } .skipped { color: #ff7a70; }
.grid { display: flex; flex-wrap: wrap; gap: 14px; }
figure { margin: 0; background: var(--panel); padding: 8px; border-radius: 6px; }
figure img { display: block; max-width: 100%; height: auto; }
figure.photo img { width: 380px; } figure.wide img { max-width: 1200px; } figure.small img { width: 300px; }
figcaption { color: var(--muted); font-size: 13px; margin-top: 4px; }
ul.warnings li { color: #ffbe46; }
footer { color: var(--muted); font-size: 13px; }
"#;

/// The error recorder, first in the page so that it sees everything.
const RECORDER: &str = r#"
window.__selfCheck = { errors: [], warnings: [] };
addEventListener('error', (e) => {
  const t = e.target;
  if (t && t !== window && (t.src || t.href)) {
    window.__selfCheck.errors.push('failed to load ' + (t.tagName || '') + ' ' + String(t.src || t.href).slice(0, 60));
  } else {
    window.__selfCheck.errors.push('error: ' + (e.message || e));
  }
}, true);
addEventListener('unhandledrejection', (e) => window.__selfCheck.errors.push('unhandled rejection: ' + e.reason));
for (const [level, list] of [['error', 'errors'], ['warn', 'warnings']]) {
  const original = console[level].bind(console);
  console[level] = (...args) => { window.__selfCheck[list].push('console.' + level + ': ' + args.join(' ')); original(...args); };
}
"#;

/// The viewer's controls and the self-check, last in the page.
const CHECK: &str = r#"
(async () => {
  const done = (result) => {
    const images = [...document.images];
    result.images = images.length;
    result.broken = images.filter((i) => !i.complete || i.naturalWidth === 0).map((i) => i.alt);
    result.errors = window.__selfCheck.errors;
    result.warnings = window.__selfCheck.warnings;
    const out = document.getElementById('self-check');
    out.textContent = JSON.stringify(result);
    out.dataset.done = 'true';
  };
  await new Promise((r) => (document.readyState === 'complete' ? r() : addEventListener('load', r)));
  const viewer = document.getElementById('viewer');
  if (!viewer) { done({ viewer: null }); return; }
  await customElements.whenDefined('model-viewer');
  if (!viewer.loaded) {
    await new Promise((r) => { viewer.addEventListener('load', r, { once: true }); viewer.addEventListener('error', r, { once: true }); });
  }
  // The textured / shaded switch.
  const material = viewer.model && viewer.model.materials[0];
  const slot = material && material.pbrMetallicRoughness.baseColorTexture;
  const texture = slot && slot.texture;
  const controls = document.getElementById('look');
  if (texture && controls) {
    controls.hidden = false;
    controls.addEventListener('change', (e) => {
      const textured = e.target.value === 'textured';
      slot.setTexture(textured ? texture : null);
      material.pbrMetallicRoughness.setBaseColorFactor(textured ? [1, 1, 1, 1] : [0.8, 0.8, 0.8, 1]);
    });
  }
  // Let the viewer draw a few frames, then see how much of its picture is not background.
  for (let k = 0; k < 10; k++) await new Promise((r) => requestAnimationFrame(r));
  let drawn = 0;
  try {
    const picture = new Image();
    picture.src = viewer.toDataURL('image/png');
    await picture.decode();
    const canvas = document.createElement('canvas');
    canvas.width = picture.naturalWidth; canvas.height = picture.naturalHeight;
    const context = canvas.getContext('2d');
    context.drawImage(picture, 0, 0);
    const pixels = context.getImageData(0, 0, canvas.width, canvas.height).data;
    const [r0, g0, b0] = [pixels[0], pixels[1], pixels[2]];
    let differ = 0;
    for (let i = 0; i < pixels.length; i += 4) {
      if (Math.abs(pixels[i] - r0) + Math.abs(pixels[i + 1] - g0) + Math.abs(pixels[i + 2] - b0) > 24) differ++;
    }
    drawn = differ / (pixels.length / 4);
  } catch (e) {
    window.__selfCheck.errors.push('self-check: ' + e);
  }
  done({ viewer: { loaded: !!viewer.loaded, textured: !!texture, drawn } });
})();
"#;

/// The page for a run's output `files` (paths relative to the output folder, as
/// [`crate::pipeline::Reconstruction::files`] gives them, plus any the caller adds: the
/// overlays in `overlays/`, a comparison).
pub fn report_page(files: &[(PathBuf, Vec<u8>)], options: &PageOptions) -> String {
    let files = Files { files };
    let r = |name: &str| options.reconstruction.join(name);
    let report = files.json(&r("report.json")).unwrap_or(Value::Null);
    let structure = files.json(&r("structure.json")).unwrap_or(Value::Null);
    let mut page = String::with_capacity(2 << 20);
    let mut pictures: Pictures<'_> = Vec::new();
    let _ = write!(
        page,
        "<!doctype html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n\
         <meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n\
         <meta name=\"generator\" content=\"splineface {}\">\n<title>{}</title>\n\
         <script>{RECORDER}</script>\n<style>{STYLE}</style>\n",
        env!("CARGO_PKG_VERSION"),
        escape(&options.title)
    );
    let glb = files.get(&r("face.glb"));
    if glb.is_some() {
        page.push_str("<script type=\"module\">\n");
        page.push_str(VIEWER);
        page.push_str("\n</script>\n");
    }
    page.push_str("</head>\n<body>\n<header>\n");
    let _ = writeln!(page, "<h1>{}</h1>", escape(&options.title));
    if report.is_null() {
        page.push_str("<p class=\"lead\">No report.json among the outputs: the summary is missing.</p>\n");
    } else {
        let used = report["photos_used"].as_array().map_or(0, Vec::len);
        let dropped = report["photos_dropped"].as_array().map_or(0, Vec::len);
        let skipped = report["photos_skipped"].as_array().map_or(0, Vec::len);
        let _ = writeln!(
            page,
            "<p class=\"lead\">{used} photo{} used, {dropped} dropped, {skipped} skipped. {}</p>",
            if used == 1 { "" } else { "s" },
            escape(&sentence(text(report["surface"].get("shape"))))
        );
    }
    page.push_str("</header>\n");

    // The face.
    page.push_str("<section id=\"face\">\n<h2>The face</h2>\n<div id=\"face-row\">\n<div>\n");
    match glb {
        Some(glb) => {
            let _ = writeln!(
                page,
                "<model-viewer id=\"viewer\" src=\"data:model/gltf-binary;base64,{}\" alt=\"The reconstructed face\" \
                 camera-controls interaction-prompt=\"none\" shadow-intensity=\"0.4\" exposure=\"1.1\" \
                 camera-orbit=\"0deg 90deg auto\"></model-viewer>",
                base64::encode(glb)
            );
            page.push_str(
                "<form class=\"controls\" id=\"look\" hidden><label><input type=\"radio\" name=\"look\" value=\"textured\" checked> textured</label>\
                 <label><input type=\"radio\" name=\"look\" value=\"shaded\"> shaded</label>\
                 <span class=\"lead\">drag to turn, scroll to zoom</span></form>\n",
            );
        }
        None => page.push_str("<p>No face.glb among the outputs.</p>\n"),
    }
    page.push_str("</div>\n<div>\n");
    if let Some(png) = files.get(&r("preview.png")) {
        figure(
            &mut page,
            &mut pictures,
            png,
            false,
            "depth map, shaded (preview.png)",
            "small",
        );
    }
    page.push_str("</div>\n</div>\n</section>\n");

    // The summary.
    if !report.is_null() {
        summary(&mut page, &report, &structure);
    }

    // The photos.
    let overlays = files.in_folder(&r("overlays"), "jpg");
    if !overlays.is_empty() {
        page.push_str("<section id=\"photos\">\n<h2>The photos</h2>\n<p class=\"lead\">Yellow: the face detector's box; \
                       green: the landmarks; magenta: the fitted face's points seen by each photo's camera, joined to the photo's own.</p>\n<div class=\"grid\">\n");
        for (path, png) in overlays {
            let name = path.file_stem().map(|s| s.to_string_lossy()).unwrap_or_default();
            figure(&mut page, &mut pictures, png, true, &name, "photo");
        }
        page.push_str("</div>\n</section>\n");
    }

    // The comparison with a ground truth.
    if let Some(folder) = &options.comparison {
        comparison(&mut page, &mut pictures, &files, folder);
    }

    // RASL, the refinement, the texture.
    // (section id, title, [(file, caption, photographic)]).
    type Listed<'a> = &'a [(&'a str, &'a str, bool)];
    let sections: [(&str, &str, Listed<'_>); 3] = [
        (
            "alignment",
            "Batch alignment (RASL)",
            &[
                (
                    "aligned/before.png",
                    "the photos and their mirror images before",
                    true,
                ),
                ("aligned/aligned.png", "after alignment", true),
                ("aligned/low-rank.png", "the low-rank part", true),
                (
                    "aligned/sparse.png",
                    "the sparse part (what no other photo shares)",
                    true,
                ),
                ("aligned/mean-before.png", "mean before", false),
                ("aligned/mean-after.png", "mean after", false),
            ],
        ),
        (
            "texture",
            "Texture",
            &[
                ("turntable.png", "the textured face from five directions", true),
                ("face.png", "the texture atlas (face.png)", true),
                ("texture-confidence.png", "where the texture comes from", true),
            ],
        ),
        (
            "depth",
            "Depth, curvature and consistency",
            &[
                (
                    "depth.png",
                    "the depth map (depth.png, 16-bit; depth.exr holds the floats)",
                    false,
                ),
                (
                    "curvature.png",
                    "how sharply the surface bends (curvedness over its (u, v) square)",
                    false,
                ),
                (
                    "consistency.png",
                    "how much the photos disagree on the face: the landmark fit (left), refined (right)",
                    false,
                ),
            ],
        ),
    ];
    for (id, title, listed) in sections {
        let present: Vec<(&[u8], &str, bool)> = listed
            .iter()
            .filter_map(|(name, caption, photo)| files.get(&r(name)).map(|b| (b, *caption, *photo)))
            .collect();
        if present.is_empty() {
            continue;
        }
        let _ = writeln!(
            page,
            "<section id=\"{id}\">\n<h2>{title}</h2>\n<div class=\"grid\">"
        );
        for (png, caption, photo) in present {
            figure(&mut page, &mut pictures, png, photo, caption, "wide");
        }
        page.push_str("</div>\n</section>\n");
    }

    page.push_str(
        "<footer>Made by splineface. The 3D viewer is &lt;model-viewer&gt; 4.4.0 (Google, Apache-2.0), which bundles \
         three.js (MIT), lit (BSD-3-Clause), fflate (MIT) and gainmap-js (MIT).</footer>\n\
         <pre id=\"self-check\" hidden></pre>\n<script type=\"module\">",
    );
    page.push_str(CHECK);
    page.push_str("</script>\n</body>\n</html>\n");
    inline_pictures(&page, &pictures)
}

/// The summary section: the photos, warnings, how the face was made, timings.
fn summary(page: &mut String, report: &Value, structure: &Value) {
    page.push_str("<section id=\"summary\">\n<h2>Summary</h2>\n");
    let rows = photo_rows(report, structure);
    if !rows.is_empty() {
        page.push_str(
            "<table class=\"photos\"><tr><th>photo</th><th>status</th><th>yaw °</th><th>pitch °</th><th>roll °</th>\
             <th>landmark fit, px RMS</th><th>face fit, px RMS</th><th>agreement</th><th>texture share</th><th>why</th></tr>\n",
        );
        for row in rows {
            let pose = row.pose.as_ref();
            let _ = writeln!(
                page,
                "<tr><td>{}</td><td class=\"{}\">{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td>\
                 <td class=\"n\">{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td><td>{}</td></tr>",
                escape(&row.name),
                row.status,
                row.status,
                number(pose.and_then(|p| p.get("yaw_degrees")), 1),
                number(pose.and_then(|p| p.get("pitch_degrees")), 1),
                number(pose.and_then(|p| p.get("roll_degrees")), 1),
                number(pose.and_then(|p| p.get("rms_pixels")), 2),
                number(pose.and_then(|p| p.get("fit_rms_pixels")), 2),
                number(row.agreement.as_ref(), 2),
                number(row.share.as_ref(), 2),
                escape(&row.reason)
            );
        }
        page.push_str("</table>\n");
    }
    let warnings: Vec<&str> = report["warnings"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(Value::as_str)
        .collect();
    if !warnings.is_empty() {
        page.push_str("<h3>Warnings</h3>\n<ul class=\"warnings\">\n");
        for w in warnings {
            let _ = writeln!(page, "<li>{}</li>", escape(w));
        }
        page.push_str("</ul>\n");
    }
    page.push_str("<table>\n");
    let surface = &report["surface"];
    let refinement = &surface["refinement"];
    let texture = &report["texture"];
    // Two of the refinement's figures, where the first is given.
    let pair = |first: &str, second: &str, digits: usize| {
        refinement[first].is_number().then(|| {
            (
                number(refinement.get(first), digits),
                number(refinement.get(second), digits),
            )
        })
    };
    let facts: Vec<(&str, String)> = vec![
        ("frontal structure", text(report.get("frontal_method")).to_owned()),
        ("shape", text(surface.get("shape")).to_owned()),
        (
            "refinement",
            if refinement.is_null() {
                "did not run".to_owned()
            } else {
                format!(
                    "{} (disagreement {} → {}{}{})",
                    match (refinement["accepted"].as_bool(), refinement["share"].as_f64()) {
                        (Some(true), Some(share)) if share < 1.0 => {
                            format!("kept {:.0}% of the way from the landmark fit", 100.0 * share)
                        }
                        (Some(true), _) => "accepted".to_owned(),
                        _ => "not accepted".to_owned(),
                    },
                    number(refinement.get("disagreement_before"), 3),
                    number(refinement.get("disagreement_after"), 3),
                    pair("held_out_before", "held_out_after", 3)
                        .map(|(before, after)| format!("; photos left out {before} → {after}"))
                        .unwrap_or_default(),
                    pair("field_max_units", "field_rms_units", 2)
                        .map(|(max, rms)| format!(
                            "; the control grid displaced in depth by up to {max} units, RMS {rms}"
                        ))
                        .unwrap_or_default()
                )
            },
        ),
        (
            "mesh",
            format!(
                "{} vertices, {} triangles",
                surface["mesh_vertices"].as_u64().unwrap_or(0),
                surface["mesh_triangles"].as_u64().unwrap_or(0)
            ),
        ),
        (
            "texture",
            if let Some(why) = texture["none"].as_str() {
                format!("none: {why}")
            } else if texture.is_null() {
                "none".to_owned()
            } else {
                let percent = |key: &str| {
                    texture[key]
                        .as_f64()
                        .filter(|v| v.is_finite())
                        .map_or_else(|| "–".to_owned(), |v| format!("{:.1}", 100.0 * v))
                };
                format!(
                    "{0}×{0}: {1}% seen, {2}% mirrored, {3}% filled",
                    texture["size"].as_u64().unwrap_or(0),
                    percent("seen"),
                    percent("mirrored"),
                    percent("filled"),
                )
            },
        ),
    ];
    for (name, value) in facts {
        if !value.is_empty() {
            let _ = writeln!(page, "<tr><th>{name}</th><td>{}</td></tr>", escape(&value));
        }
    }
    page.push_str("</table>\n");
    let timings: Vec<(String, f64)> = report["timings"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(|t| Some((t["stage"].as_str()?.to_owned(), t["ms"].as_f64()?)))
        .collect();
    if !timings.is_empty() {
        page.push_str("<h3>Timings</h3>\n<table>\n");
        let total: f64 = timings.iter().map(|(_, ms)| ms).sum();
        for (stage, ms) in &timings {
            let _ = writeln!(
                page,
                "<tr><td>{}</td><td class=\"n\">{ms:.0} ms</td></tr>",
                escape(stage)
            );
        }
        let _ = writeln!(
            page,
            "<tr><th>total</th><td class=\"n\">{total:.0} ms</td></tr>\n</table>"
        );
    }
    page.push_str("</section>\n");
}

/// The comparison section: the heatmap, the two shaded depth maps and the measures.
fn comparison<'a>(page: &mut String, pictures: &mut Pictures<'a>, files: &Files<'a>, folder: &Path) {
    let stats = files.json(&folder.join("stats.json"));
    let shown: Vec<(&[u8], &str)> = [
        ("heatmap.png", "|Δz| between the reconstruction and the truth"),
        ("reconstruction.png", "the reconstruction"),
        ("truth.png", "the truth"),
    ]
    .iter()
    .filter_map(|(name, caption)| files.get(&folder.join(name)).map(|b| (b, *caption)))
    .collect();
    if shown.is_empty() && stats.is_none() {
        return;
    }
    page.push_str("<section id=\"comparison\">\n<h2>Against the truth</h2>\n");
    if let Some(stats) = &stats {
        let units = text(stats.get("units"));
        let base = &stats["baseline_mean_face"];
        let rows: [(&str, &[&str]); 4] = [
            ("inner face, truth → surface", &["inner_face", "distance", "mean"]),
            ("mean |Δz|", &["depth_error", "mean"]),
            ("90th percentile |Δz|", &["depth_error", "p90"]),
            ("point to surface", &["point_to_surface", "mean"]),
        ];
        let _ = writeln!(
            page,
            "<table><tr><th></th><th>reconstruction ({0})</th><th>mean face ({0})</th></tr>",
            escape(units)
        );
        for (name, keys) in rows {
            let at = |root: &Value| keys.iter().fold(root.clone(), |v, k| v[*k].clone());
            let _ = writeln!(
                page,
                "<tr><td>{name}</td><td class=\"n\">{}</td><td class=\"n\">{}</td></tr>",
                number(Some(&at(stats)), 3),
                number(Some(&at(base)), 3)
            );
        }
        page.push_str("</table>\n");
    }
    page.push_str("<div class=\"grid\">\n");
    for (png, caption) in shown {
        figure(page, pictures, png, false, caption, "small");
    }
    page.push_str("</div>\n</section>\n");
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_viewer_can_be_inlined_in_a_script_element() {
        // An inline script ends at the first `</script`; one inside the viewer would cut it.
        assert!(!VIEWER.to_ascii_lowercase().contains("</script"));
        assert!(!VIEWER.to_ascii_lowercase().contains("<script"));
        assert!(VIEWER.len() > 500_000, "the vendored viewer is missing");
    }

    /// The refinement's line names the check on photos left out only where it ran.
    #[test]
    fn the_refinement_line_shows_the_photos_left_out_where_the_check_ran() {
        let line = |held: Value| {
            let report = serde_json::json!({
                "surface": {"refinement": {
                    "accepted": true,
                    "disagreement_before": 0.5,
                    "disagreement_after": 0.4,
                    "held_out_before": held,
                    "held_out_after": held.as_f64().map(|h| h - 0.02),
                }}
            });
            let mut page = String::new();
            summary(&mut page, &report, &Value::Null);
            page
        };
        let checked = line(serde_json::json!(0.4));
        assert!(
            checked.contains("accepted (disagreement 0.500 → 0.400; photos left out 0.400 → 0.380)"),
            "{checked}"
        );
        let unchecked = line(Value::Null);
        assert!(
            unchecked.contains("accepted (disagreement 0.500 → 0.400)"),
            "{unchecked}"
        );
        assert!(!unchecked.contains("left out"), "{unchecked}");
        // The line of a refinement accepted with `extra` (disagreement 0.5 → 0.43).
        let with = |extra: Value| {
            let mut refinement = serde_json::json!({
                "accepted": true,
                "disagreement_before": 0.5,
                "disagreement_after": 0.43,
            });
            for (key, value) in extra.as_object().expect("an object") {
                refinement[key] = value.clone();
            }
            let mut page = String::new();
            summary(
                &mut page,
                &serde_json::json!({"surface": {"refinement": refinement}}),
                &Value::Null,
            );
            page
        };
        // Kept in part: the share is named.
        let part = with(serde_json::json!({"share": 0.31}));
        assert!(
            part.contains("kept 31% of the way from the landmark fit (disagreement 0.500 → 0.430)"),
            "{part}"
        );
        // With a displacement field: its size.
        let field = with(serde_json::json!({"field_max_units": 1.234, "field_rms_units": 0.25}));
        assert!(
            field.contains("(disagreement 0.500 → 0.430; the control grid displaced in depth by up to 1.23 units, RMS 0.25)"),
            "{field}"
        );
    }

    #[test]
    fn text_is_escaped() {
        assert_eq!(
            escape("<a href=\"x\">&'"),
            "&lt;a href=&quot;x&quot;&gt;&amp;&#39;"
        );
    }
}
