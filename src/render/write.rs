//! Depth-map files: EXR (float32 with a coverage channel), 16-bit PNG, shaded previews and
//! error heatmaps with a colour bar.

use std::io::Cursor;

use nalgebra::Vector3;

use super::DepthMap;
use crate::Real;

use crate::io::{EncodeError, encode_png};

/// Encodes the map as OpenEXR, one layer `depth` of two float32 channels, rows from the top:
/// `Z`, the distance from the view plane through the origin along the viewing direction
/// (`−height`: positive behind the plane, negative in front of it, in the mesh's units), and
/// `A`, 1 on the surface and 0 on the background (where `Z` is 0 and means nothing). The
/// position of the top-left pixel centre (`x`, `y` of the view frame) and the pixel size are
/// stored in the layer's text attribute `splineface_frame` as
/// `origin_x X origin_y Y pixel_size S`. The bytes are the same on every run.
///
/// # Errors
/// The encoder's message (should not happen for a valid map).
pub fn encode_depth_exr(map: &DepthMap) -> Result<Vec<u8>, EncodeError> {
    use exr::prelude::*;
    let (width, height) = (map.raster.width, map.raster.height);
    let pixels = SpecificChannels::build()
        .with_channel("A")
        .with_channel("Z")
        .with_pixel_fn(|position: Vec2<usize>| {
            let j = height - 1 - position.y();
            match map.get(position.x(), j) {
                Some(h) => (1.0_f32, -h as f32),
                None => (0.0_f32, 0.0_f32),
            }
        });
    let top_left = map.raster.position(0, height - 1);
    let mut attributes = LayerAttributes::named("depth");
    // One attribute: the exr crate keeps custom attributes in a hash map and writes them in its
    // (per-process random) order, so two would make the bytes differ from run to run.
    attributes.other.insert(
        Text::from("splineface_frame"),
        AttributeValue::Text(Text::from(
            format!(
                "origin_x {:?} origin_y {:?} pixel_size {:?}",
                top_left.x, top_left.y, map.raster.spacing
            )
            .as_str(),
        )),
    );
    let layer = Layer::new((width, height), attributes, Encoding::SMALL_LOSSLESS, pixels);
    let image = Image::from_layer(layer);
    let mut bytes = Vec::new();
    // Compressed on one thread, so that nothing in the file can depend on scheduling (depth maps
    // are small; it costs little).
    image
        .write()
        .non_parallel()
        .to_buffered(Cursor::new(&mut bytes))
        .map_err(|e| EncodeError::new("EXR", e))?;
    Ok(bytes)
}

/// Encodes the map as a 16-bit greyscale PNG, rows from the top: 0 is background; covered
/// pixels run from 1 (the lowest height) to 65535 (the highest, nearest the viewer). The
/// mapping back to heights is stored in a `tEXt` chunk `splineface-depth` as
/// `height = LOW + (value - 1) * STEP` with both numbers given.
///
/// # Errors
/// The encoder's message.
pub fn encode_depth_png(map: &DepthMap) -> Result<Vec<u8>, EncodeError> {
    let (width, height) = (map.raster.width, map.raster.height);
    let (lo, hi) = map.range().unwrap_or((0.0, 0.0));
    let step = if hi > lo { (hi - lo) / 65534.0 } else { 1.0 };
    let mut data = Vec::with_capacity(2 * width * height);
    for r in 0..height {
        let j = height - 1 - r;
        for i in 0..width {
            let value: u16 = match map.get(i, j) {
                Some(h) => 1 + ((h - lo) / step).round().clamp(0.0, 65534.0) as u16,
                None => 0,
            };
            data.extend_from_slice(&value.to_be_bytes());
        }
    }
    let mut bytes = Vec::new();
    {
        let mut encoder = png::Encoder::new(Cursor::new(&mut bytes), width as u32, height as u32);
        encoder.set_color(png::ColorType::Grayscale);
        encoder.set_depth(png::BitDepth::Sixteen);
        // `fdeflate`'s fast mode, as `image` writes the other PNGs: on a 448 × 512 map of a
        // face, 1.1 ms and 259 KB against 21.7 ms and 199 KB for the default (zlib's level).
        encoder.set_compression(png::Compression::Fast);
        encoder
            .add_text_chunk(
                "splineface-depth".to_owned(),
                format!("height = {lo:?} + (value - 1) * {step:?}; value 0 = background"),
            )
            .map_err(|e| EncodeError::new("PNG", e))?;
        let mut writer = encoder.write_header().map_err(|e| EncodeError::new("PNG", e))?;
        writer
            .write_image_data(&data)
            .map_err(|e| EncodeError::new("PNG", e))?;
        writer.finish().map_err(|e| EncodeError::new("PNG", e))?;
    }
    Ok(bytes)
}

/// A shaded preview of the map as an 8-bit RGB PNG: the height field's normals lit by a
/// light from the upper left in front (Lambert, 15% ambient), background dark grey.
///
/// # Errors
/// The encoder's message.
pub fn shaded_png(map: &DepthMap) -> Result<Vec<u8>, EncodeError> {
    let (width, height) = (map.raster.width, map.raster.height);
    let light = Vector3::new(-0.4, 0.5, 1.0).normalize();
    let image = image::RgbImage::from_fn(width as u32, height as u32, |x, y| {
        let j = height - 1 - y as usize;
        match map.normal(x as usize, j) {
            Some(n) => {
                let v = (255.0 * (0.15 + 0.85 * n.dot(&light).max(0.0))).round() as u8;
                image::Rgb([v, v, v])
            }
            None => image::Rgb([40, 40, 40]),
        }
    });
    encode_png(&image)
}

/// The viridis colour map at `t ∈ [0, 1]` (9 samples of matplotlib's table, interpolated).
pub(crate) fn viridis(t: Real) -> [u8; 3] {
    const TABLE: [[Real; 3]; 9] = [
        [68.0, 1.0, 84.0],
        [71.0, 44.0, 122.0],
        [59.0, 81.0, 139.0],
        [44.0, 113.0, 142.0],
        [33.0, 144.0, 141.0],
        [39.0, 173.0, 129.0],
        [92.0, 200.0, 99.0],
        [170.0, 220.0, 50.0],
        [253.0, 231.0, 37.0],
    ];
    let x = if t.is_finite() {
        t.clamp(0.0, 1.0) * 8.0
    } else {
        0.0
    };
    let k = (x.floor() as usize).min(7);
    let f = x - k as Real;
    let mix = |c: usize| (TABLE[k][c] + f * (TABLE[k + 1][c] - TABLE[k][c])).round() as u8;
    [mix(0), mix(1), mix(2)]
}

/// A heatmap of per-pixel values (row-major from the bottom row, `NaN` = no value, drawn dark
/// grey) as an RGB PNG, viridis from 0 to `max`, with a colour bar on the right labelled with
/// 0, `max`/2 and `max` followed by `unit`, in DejaVu Sans ([`super::draw_text`]) about a 28th of
/// the map's height (12 to 28 pixels).
///
/// # Errors
/// A message for a size mismatch or a `max` that is not positive and finite.
pub fn heatmap_png(
    values: &[Real],
    width: usize,
    height: usize,
    max: Real,
    unit: &str,
) -> Result<Vec<u8>, EncodeError> {
    if values.len() != width * height || width == 0 || height == 0 {
        return Err(EncodeError::new(
            "PNG",
            format!("{} values for a {width}×{height} heatmap", values.len()),
        ));
    }
    if !(max > 0.0 && max.is_finite()) {
        return Err(EncodeError::new(
            "PNG",
            format!("heatmap scale {max} must be positive and finite"),
        ));
    }
    let size = (height as f32 / 28.0).clamp(12.0, 28.0);
    let digits = if max >= 10.0 {
        1
    } else if max >= 1.0 {
        2
    } else {
        3
    };
    let labels: Vec<(Real, String)> = [1.0, 0.5, 0.0]
        .iter()
        .map(|&t| {
            let text = format!("{:.digits$} {unit}", t * max);
            (t, text.trim_end().to_owned())
        })
        .collect();
    let widest = labels
        .iter()
        .map(|(_, text)| super::text::text_width(text, size))
        .fold(0.0f32, f32::max);
    let bar = (size * 1.2).round() as u32;
    let total = width as u32 + 2 * bar + (widest + size).ceil() as u32;
    let mut image = image::RgbImage::from_pixel(total, height as u32, image::Rgb([30, 30, 30]));
    for y in 0..height {
        let j = height - 1 - y;
        for i in 0..width {
            let v = values[j * width + i];
            if v.is_finite() {
                image.put_pixel(i as u32, y as u32, image::Rgb(viridis(v / max)));
            }
        }
    }
    // The bar runs from half a line below the top to half a line above the bottom, so that
    // each label can be centred on its value.
    let margin = ((size * 0.6).ceil() as u32).min(height as u32 / 4);
    let (top, bottom) = (margin, (height as u32).saturating_sub(margin).max(margin + 1));
    let x0 = width as u32 + bar / 2;
    for y in top..bottom {
        let t = 1.0 - (y - top) as Real / (bottom - 1 - top).max(1) as Real;
        for x in x0..x0 + bar {
            image.put_pixel(x, y, image::Rgb(viridis(t)));
        }
    }
    let text_x = (x0 + bar) as f32 + size * 0.4;
    let style = super::text::TextStyle::white(size);
    let ascent = size * 0.76; // DejaVu's cap height is about 0.73 of the size
    for (t, text) in &labels {
        let y = top as f32 + (1.0 - *t as f32) * (bottom - 1 - top) as f32;
        super::text::draw_text(&mut image, text, text_x, y - ascent / 2.0 - size * 0.2, style);
    }
    encode_png(&image)
}
