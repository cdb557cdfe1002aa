//! Text in images: labels of colour bars, plots and photo overlays, in DejaVu Sans.
//!
//! The font is embedded: a 27 kB subset of DejaVu Sans 2.37 (Basic Latin, Latin-1, Greek,
//! arrows and the usual maths signs; `tools/make-font` makes it from Debian's
//! `fonts-dejavu-core`, licence in `src/render/LICENSE-DejaVu.txt`), rasterised with
//! coverage anti-aliasing by `ab_glyph`. A character outside the subset is drawn as `?`.

use std::sync::LazyLock;

use ab_glyph::{Font, FontRef, PxScale, ScaleFont};

/// The embedded font file.
static FONT_FILE: &[u8] = include_bytes!("DejaVuSans-subset.ttf");

/// The parsed font; `None` only if the embedded file were corrupt (a test checks it is not).
static FONT: LazyLock<Option<FontRef<'static>>> = LazyLock::new(|| FontRef::try_from_slice(FONT_FILE).ok());

/// How text is drawn by [`draw_text`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TextStyle {
    /// The font's pixel height (ascent to descent); 13–16 reads well on screen.
    pub size: f32,
    /// The text's colour (sRGB).
    pub colour: [u8; 3],
}

impl TextStyle {
    /// White text of `size` pixels.
    pub fn white(size: f32) -> Self {
        TextStyle {
            size,
            colour: [255, 255, 255],
        }
    }
}

/// The glyphs of `text` laid out on one line from the origin (kerning applied), with the
/// line's advance width.
fn layout(font: &FontRef<'static>, text: &str, size: f32) -> (Vec<ab_glyph::Glyph>, f32) {
    let scaled = font.as_scaled(PxScale::from(size));
    let fallback = font.glyph_id('?');
    let mut glyphs = Vec::with_capacity(text.len());
    let mut x = 0.0f32;
    let mut previous: Option<ab_glyph::GlyphId> = None;
    for c in text.chars() {
        let c = if c.is_control() { ' ' } else { c };
        let mut id = font.glyph_id(c);
        if id.0 == 0 {
            id = fallback;
        }
        if let Some(p) = previous {
            x += scaled.kern(p, id);
        }
        glyphs.push(id.with_scale_and_position(size, ab_glyph::point(x, scaled.ascent())));
        x += scaled.h_advance(id);
        previous = Some(id);
    }
    (glyphs, x)
}

/// The width in pixels of `text` on one line at `size`.
pub fn text_width(text: &str, size: f32) -> f32 {
    FONT.as_ref().map_or(0.0, |font| layout(font, text, size).1)
}

/// The height in pixels of one line at `size` (ascent − descent + line gap).
pub(crate) fn line_height(size: f32) -> f32 {
    FONT.as_ref().map_or(size, |font| {
        let scaled = font.as_scaled(PxScale::from(size));
        scaled.ascent() - scaled.descent() + scaled.line_gap()
    })
}

/// Draws `text` on one line with its top-left corner at `(x, y)` (pixels; the glyphs' ascent
/// starts at `y`), blending the colour over the image by each pixel's coverage; what falls
/// outside the image is clipped. Returns the line's advance width.
pub fn draw_text(image: &mut image::RgbImage, text: &str, x: f32, y: f32, style: TextStyle) -> f32 {
    let Some(font) = FONT.as_ref() else {
        return 0.0;
    };
    let (glyphs, width) = layout(font, text, style.size);
    let (w, h) = (image.width() as i64, image.height() as i64);
    for mut glyph in glyphs {
        glyph.position = ab_glyph::point(glyph.position.x + x, glyph.position.y + y);
        let Some(outlined) = font.outline_glyph(glyph) else {
            continue; // a space
        };
        let bounds = outlined.px_bounds();
        outlined.draw(|gx, gy, coverage| {
            let px = bounds.min.x as i64 + i64::from(gx);
            let py = bounds.min.y as i64 + i64::from(gy);
            if px < 0 || py < 0 || px >= w || py >= h {
                return;
            }
            let a = coverage.clamp(0.0, 1.0);
            let pixel = image.get_pixel_mut(px as u32, py as u32);
            for (channel, &c) in pixel.0.iter_mut().zip(&style.colour) {
                *channel = (f32::from(*channel) * (1.0 - a) + f32::from(c) * a).round() as u8;
            }
        });
    }
    width
}

/// Breaks `text` into lines no wider than `width` pixels at `size`, at spaces (a word wider
/// than the line gets a line of its own).
pub(crate) fn wrap_text(text: &str, size: f32, width: f32) -> Vec<String> {
    let mut lines = Vec::new();
    for paragraph in text.split('\n') {
        let mut line = String::new();
        for word in paragraph.split(' ').filter(|w| !w.is_empty()) {
            let candidate = if line.is_empty() {
                word.to_owned()
            } else {
                format!("{line} {word}")
            };
            if !line.is_empty() && text_width(&candidate, size) > width {
                lines.push(std::mem::replace(&mut line, word.to_owned()));
            } else {
                line = candidate;
            }
        }
        lines.push(line);
    }
    lines
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_embedded_font_parses_and_has_the_label_characters() {
        let font = FONT.as_ref().expect("the embedded font parses");
        for c in "0123456789.-+ mm|Δz|µσ×°≤≥→abcxyzABCXYZ".chars() {
            assert_ne!(font.glyph_id(c).0, 0, "{c:?} is missing from the subset");
        }
    }
}
