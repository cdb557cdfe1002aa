//! A photo with what the pipeline found on it: the face box, the landmarks, and the fitted
//! face's points seen by the photo's camera, under a caption saying whether the photo was
//! used and why not.

use image::RgbImage;
use nalgebra::{Point2, Vector2};

use crate::Real;
use crate::render::{TextStyle, draw_text, line_height, wrap_text};

/// An overlay's longest side at most, pixels: larger photos are scaled down.
pub const MAX_SIDE: u32 = 1200;

/// An overlay's longest side at least, pixels: smaller photos are scaled up (so that the
/// marks and the caption stay legible on a thumbnail-sized photo).
pub const MIN_SIDE: u32 = 480;

/// What became of a photo.
#[derive(Debug, Clone, PartialEq)]
pub enum PhotoStatus {
    /// Landmarked, with no reconstruction (`splineface landmarks`).
    Landmarked,
    /// The reconstruction used it.
    Used,
    /// Landmarked, then left out by the reconstruction, for this reason.
    Dropped(String),
    /// Not landmarked (no face found, unreadable landmarks ...), for this reason.
    Skipped(String),
}

/// A photo's own 40 points and the fitted face's 40 points seen by its camera.
pub type FittedPoints<'a> = (&'a [Point2<Real>], &'a [Point2<Real>]);

/// What an overlay shows ([`draw_overlay`]).
#[derive(Debug, Clone, Copy)]
pub struct Overlay<'a> {
    /// The photo.
    pub image: &'a RgbImage,
    /// The photo's name, the caption's title.
    pub name: &'a str,
    /// What became of it.
    pub status: &'a PhotoStatus,
    /// Further caption lines (pose, residual ...).
    pub notes: &'a [String],
    /// The face detector's box `[x, y, width, height]`, pixels.
    pub face_box: Option<[Real; 4]>,
    /// The landmarks as found or given, pixels with `y` down: 68 iBUG points are joined
    /// along the face's contours, any other count is drawn as dots.
    pub landmarks: &'a [Point2<Real>],
    /// The photo's 40 structure points and the fitted face's 40 points seen by its camera
    /// (pixels, `y` down), drawn as crosses joined to the photo's points by a line: the
    /// fit's residuals.
    pub fitted: Option<FittedPoints<'a>>,
}

/// The colours of the marks (sRGB); the caption's legend names them.
const BOX: [u8; 3] = [255, 200, 0];
const LANDMARKS: [u8; 3] = [70, 235, 90];
const FITTED: [u8; 3] = [255, 60, 210];

/// The iBUG 68-point contours: index ranges, and whether each closes on itself.
const CONTOURS: [(std::ops::Range<usize>, bool); 9] = [
    (0..17, false),  // jaw
    (17..22, false), // right brow (the subject's)
    (22..27, false), // left brow
    (27..31, false), // nose bridge
    (31..36, false), // nose base
    (36..42, true),  // right eye
    (42..48, true),  // left eye
    (48..60, true),  // outer lips
    (60..68, true),  // inner lips
];

/// The scale an overlay puts a `width × height` photo at: down to [`MAX_SIDE`] or up to
/// [`MIN_SIDE`] along its longest side, else 1.
pub fn overlay_scale(width: u32, height: u32) -> Real {
    let long = Real::from(width.max(height).max(1));
    if long > Real::from(MAX_SIDE) {
        Real::from(MAX_SIDE) / long
    } else if long < Real::from(MIN_SIDE) {
        Real::from(MIN_SIDE) / long
    } else {
        1.0
    }
}

/// Draws the overlay: the photo scaled by [`overlay_scale`] (greyscale photos come as RGB
/// already, [`image::DynamicImage::to_rgb8`]) under a caption band with the name, the status
/// (green for used, amber for dropped, red for skipped), the notes and a legend, and on it the
/// face box, the landmarks and the fitted points. Marks outside the photo are clipped;
/// non-finite points are skipped.
pub fn draw_overlay(overlay: &Overlay<'_>) -> RgbImage {
    let (w0, h0) = overlay.image.dimensions();
    let scale = overlay_scale(w0, h0);
    let (w, h) = (
        ((Real::from(w0) * scale).round() as u32).max(1),
        ((Real::from(h0) * scale).round() as u32).max(1),
    );
    let photo = if (w, h) == (w0, h0) {
        overlay.image.clone()
    } else {
        image::imageops::resize(overlay.image, w, h, image::imageops::FilterType::Triangle)
    };

    // The caption: title, status, notes and legend, wrapped to the photo's width.
    let size = (w as f32 / 40.0).clamp(14.0, 22.0);
    let line = line_height(size).ceil();
    let pad = (size * 0.6).round();
    let text_width = w as f32 - 2.0 * pad;
    let (status_text, status_colour) = match overlay.status {
        PhotoStatus::Landmarked => ("landmarked".to_owned(), [120, 230, 120]),
        PhotoStatus::Used => ("used".to_owned(), [120, 230, 120]),
        PhotoStatus::Dropped(why) => (format!("dropped: {why}"), [255, 190, 70]),
        PhotoStatus::Skipped(why) => (format!("skipped: {why}"), [255, 110, 100]),
    };
    let mut lines: Vec<(String, [u8; 3])> = vec![(overlay.name.to_owned(), [255, 255, 255])];
    lines.extend(
        wrap_text(&status_text, size, text_width)
            .into_iter()
            .map(|l| (l, status_colour)),
    );
    for note in overlay.notes {
        lines.extend(
            wrap_text(note, size, text_width)
                .into_iter()
                .map(|l| (l, [210, 210, 210])),
        );
    }
    let mut legend: Vec<(&str, [u8; 3])> = Vec::new();
    if overlay.face_box.is_some() {
        legend.push(("face box", BOX));
    }
    if !overlay.landmarks.is_empty() {
        legend.push((
            if overlay.landmarks.len() == 68 {
                "68 landmarks"
            } else {
                "landmarks"
            },
            LANDMARKS,
        ));
    }
    if overlay.fitted.is_some() {
        legend.push(("fitted face's points", FITTED));
    }
    let rows = lines.len() + usize::from(!legend.is_empty());
    let band = (2.0 * pad + line * rows as f32).ceil() as u32;
    let mut image = RgbImage::from_pixel(w, h + band, image::Rgb([28, 28, 28]));
    image::imageops::replace(&mut image, &photo, 0, i64::from(band));
    let mut y = pad;
    for (text, colour) in &lines {
        draw_text(
            &mut image,
            text,
            pad,
            y,
            TextStyle {
                size,
                colour: *colour,
            },
        );
        y += line;
    }
    let mut x = pad;
    for (label, colour) in legend {
        let swatch = size * 0.35;
        let centre = Point2::new(Real::from(x + swatch), Real::from(y + line * 0.45));
        draw_segment(&mut image, centre, centre, Real::from(swatch), colour);
        x += 2.0 * swatch + size * 0.3;
        x += draw_text(
            &mut image,
            label,
            x,
            y,
            TextStyle {
                size,
                colour: [210, 210, 210],
            },
        ) + size;
    }

    // The marks, in the scaled photo's pixels below the band.
    let at = |p: &Point2<Real>| Point2::new(p.x * scale, p.y * scale + Real::from(band));
    let width = (Real::from(w.max(h)) / 500.0).max(1.5);
    if let Some([x, y, bw, bh]) = overlay.face_box {
        let corners = [
            Point2::new(x, y),
            Point2::new(x + bw, y),
            Point2::new(x + bw, y + bh),
            Point2::new(x, y + bh),
        ];
        for k in 0..4 {
            draw_segment(&mut image, at(&corners[k]), at(&corners[(k + 1) % 4]), width, BOX);
        }
    }
    if let Some((given, fitted)) = overlay.fitted {
        let arm = width * 2.5;
        for (g, f) in given.iter().zip(fitted) {
            let (g, f) = (at(g), at(f));
            draw_segment(&mut image, g, f, width * 0.6, FITTED);
            draw_segment(
                &mut image,
                f + Vector2::new(-arm, -arm),
                f + Vector2::new(arm, arm),
                width,
                FITTED,
            );
            draw_segment(
                &mut image,
                f + Vector2::new(-arm, arm),
                f + Vector2::new(arm, -arm),
                width,
                FITTED,
            );
        }
    }
    // The landmarks last, over the crosses.
    let marks = overlay.landmarks;
    if marks.len() == 68 {
        for (range, closed) in CONTOURS {
            let indices: Vec<usize> = range.clone().collect();
            let segments = if closed { indices.len() } else { indices.len() - 1 };
            for k in 0..segments {
                let (a, b) = (marks[indices[k]], marks[indices[(k + 1) % indices.len()]]);
                draw_segment(&mut image, at(&a), at(&b), width * 0.6, LANDMARKS);
            }
        }
    }
    for p in marks {
        draw_segment(&mut image, at(p), at(p), width * 1.6, LANDMARKS);
    }
    image
}

/// Blends a segment from `a` to `b` of `width` pixels with round ends (a dot when `a = b`)
/// over the image, each pixel by its coverage (1 inside, fading over one pixel at the edge).
/// Non-finite ends draw nothing.
pub(crate) fn draw_segment(
    image: &mut RgbImage,
    a: Point2<Real>,
    b: Point2<Real>,
    width: Real,
    colour: [u8; 3],
) {
    if !(a.coords.iter().chain(b.coords.iter()).all(|c| c.is_finite()) && width.is_finite()) {
        return;
    }
    let r = width / 2.0;
    let (w, h) = (Real::from(image.width()), Real::from(image.height()));
    let x0 = (a.x.min(b.x) - r - 1.0).floor().max(0.0);
    let x1 = (a.x.max(b.x) + r + 1.0).ceil().min(w - 1.0);
    let y0 = (a.y.min(b.y) - r - 1.0).floor().max(0.0);
    let y1 = (a.y.max(b.y) + r + 1.0).ceil().min(h - 1.0);
    if x0 > x1 || y0 > y1 {
        return;
    }
    let d = b - a;
    let length_squared = d.norm_squared();
    for py in y0 as u32..=y1 as u32 {
        for px in x0 as u32..=x1 as u32 {
            let p = Point2::new(Real::from(px) + 0.5, Real::from(py) + 0.5);
            let t = if length_squared > 0.0 {
                ((p - a).dot(&d) / length_squared).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let distance = (p - (a + d * t)).norm();
            let coverage = (r + 0.5 - distance).clamp(0.0, 1.0);
            if coverage > 0.0 {
                let pixel = image.get_pixel_mut(px, py);
                for (channel, &c) in pixel.0.iter_mut().zip(&colour) {
                    *channel =
                        (Real::from(*channel) * (1.0 - coverage) + Real::from(c) * coverage).round() as u8;
                }
            }
        }
    }
}
