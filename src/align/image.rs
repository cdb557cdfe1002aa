//! Greyscale photos for RASL: reading, validation, mirroring, bilinear sampling and gradients.

use std::path::{Path, PathBuf};

use crate::Real;

/// The smallest photo side RASL accepts, in pixels.
pub const MIN_SIDE: usize = 32;

/// The largest photo RASL reads, in pixels (a 100-megapixel photo is 400 MB as `f32`).
pub const MAX_PIXELS: usize = 100_000_000;

/// A greyscale image, intensities in `[0, 1]`, row-major from the top row.
#[derive(Debug, Clone, PartialEq)]
pub struct GreyImage {
    width: usize,
    height: usize,
    data: Vec<f32>,
}

/// What is wrong with a photo.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum PhotoProblem {
    /// The file could not be read or decoded.
    #[error("cannot read the image: {0}")]
    Unreadable(String),
    /// No pixels.
    #[error("the image is empty")]
    Empty,
    /// Too small to hold a face.
    #[error("the image is {width}×{height} pixels: too small (each side must be at least 32)")]
    Tiny {
        /// Width.
        width: usize,
        /// Height.
        height: usize,
    },
    /// Too large to read.
    #[error("the image is {width}×{height} pixels: larger than 100 megapixels")]
    Huge {
        /// Width.
        width: usize,
        /// Height.
        height: usize,
    },
    /// Every pixel has the same intensity: nothing to align.
    #[error("the image has no contrast (every pixel is the same grey)")]
    Flat,
    /// A landmark lies outside the image.
    #[error("point {point} at ({x:.1}, {y:.1}) lies outside the {width}×{height} image")]
    PointOutside {
        /// The structure point.
        point: usize,
        /// Its position.
        x: Real,
        /// Its position.
        y: Real,
        /// The image width.
        width: usize,
        /// The image height.
        height: usize,
    },
    /// The data does not match the size.
    #[error("{got} intensities for a {width}×{height} image")]
    SizeMismatch {
        /// Intensities given.
        got: usize,
        /// Width.
        width: usize,
        /// Height.
        height: usize,
    },
    /// An intensity is NaN or infinite.
    #[error("intensity {0} is not finite")]
    NonFinite(usize),
}

/// A photo file that could not be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{}: {problem}", file.display())]
pub struct PhotoError {
    /// The file.
    pub file: PathBuf,
    /// What is wrong.
    pub problem: PhotoProblem,
}

impl GreyImage {
    /// An image from intensities (row-major from the top), checked: non-empty, at least
    /// 32 pixels a side, at most 100 megapixels, finite, not flat.
    ///
    /// # Errors
    /// The [`PhotoProblem`].
    pub fn new(width: usize, height: usize, data: Vec<f32>) -> Result<Self, PhotoProblem> {
        if width == 0 || height == 0 {
            return Err(PhotoProblem::Empty);
        }
        if width.saturating_mul(height) > MAX_PIXELS {
            return Err(PhotoProblem::Huge { width, height });
        }
        if data.len() != width * height {
            return Err(PhotoProblem::SizeMismatch {
                got: data.len(),
                width,
                height,
            });
        }
        if width < MIN_SIDE || height < MIN_SIDE {
            return Err(PhotoProblem::Tiny { width, height });
        }
        if let Some(k) = data.iter().position(|v| !v.is_finite()) {
            return Err(PhotoProblem::NonFinite(k));
        }
        let (lo, hi) = data
            .iter()
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &v| {
                (lo.min(v), hi.max(v))
            });
        if hi - lo < 1.0 / 512.0 {
            return Err(PhotoProblem::Flat);
        }
        Ok(GreyImage { width, height, data })
    }

    /// The luma of a decoded image (Rec. 709 weights, as the `image` crate computes it).
    ///
    /// The photo path converts each photo twice, to this and to `image`'s `to_luma8` for
    /// detection: about 5 ms for an 800 × 1000 photo. Measured and dropped: both made in one
    /// pass with `image`'s arithmetic (bit for bit, its weights read back from its conversion
    /// of the primaries) took 4.4 ms; most of the time is the first touch of the new buffers'
    /// memory, not the arithmetic, and the saving did not show in `reconstruct`'s times.
    ///
    /// # Errors
    /// As [`GreyImage::new`].
    pub fn from_dynamic(image: &image::DynamicImage) -> Result<Self, PhotoProblem> {
        let (width, height) = (image.width() as usize, image.height() as usize);
        if width.saturating_mul(height) > MAX_PIXELS {
            return Err(PhotoProblem::Huge { width, height });
        }
        let luma = image.to_luma32f();
        GreyImage::new(width, height, luma.into_raw())
    }

    /// Reads a photo (JPEG, PNG, BMP, TIFF or WebP, recognised by content) as grey.
    ///
    /// # Errors
    /// A [`PhotoError`] naming the file: unreadable, undecodable, or failing
    /// [`GreyImage::new`]'s checks. Headers announcing more than 100 megapixels are refused
    /// before decoding.
    pub fn read(path: &Path) -> Result<Self, PhotoError> {
        let decoded = decode_photo(path)?;
        GreyImage::from_dynamic(&decoded).map_err(|problem| PhotoError {
            file: path.to_path_buf(),
            problem,
        })
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// The intensities, row-major from the top.
    pub fn data(&self) -> &[f32] {
        &self.data
    }

    /// The intensity at pixel `(x, y)`.
    pub fn get(&self, x: usize, y: usize) -> f32 {
        self.data[y * self.width + x]
    }

    /// The image mirrored left to right.
    pub fn mirrored(&self) -> Self {
        let mut data = Vec::with_capacity(self.data.len());
        for row in self.data.chunks_exact(self.width) {
            data.extend(row.iter().rev());
        }
        GreyImage { data, ..*self }
    }

    /// Central-difference gradients (`∂/∂x`, `∂/∂y`), one-sided at the borders.
    pub fn gradients(&self) -> (Vec<f32>, Vec<f32>) {
        central_differences(&self.data, self.width, self.height)
    }

    /// Bilinear interpolation of `values` (laid out like this image) at `(x, y)` in pixel
    /// coordinates (pixel centres at whole numbers), clamped to the border.
    pub fn sample(&self, values: &[f32], x: Real, y: Real) -> f32 {
        let (w, h) = (self.width, self.height);
        let xc = x.clamp(0.0, (w - 1) as Real);
        let yc = y.clamp(0.0, (h - 1) as Real);
        // Truncation is the floor here (xc, yc ≥ 0), and no call into libm on baseline x86-64.
        let (x0, y0) = (xc as usize, yc as usize);
        let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
        let (fx, fy) = ((xc - x0 as Real) as f32, (yc - y0 as Real) as f32);
        let top = values[y0 * w + x0] * (1.0 - fx) + values[y0 * w + x1] * fx;
        let bottom = values[y1 * w + x0] * (1.0 - fx) + values[y1 * w + x1] * fx;
        top * (1.0 - fy) + bottom * fy
    }
}

/// Central-difference gradients (`∂/∂x`, `∂/∂y`) of `values` (`width × height`, row-major),
/// one-sided at the borders (zero along a side of one pixel).
pub(crate) fn central_differences(values: &[f32], width: usize, height: usize) -> (Vec<f32>, Vec<f32>) {
    use rayon::prelude::*;
    let (w, h) = (width, height);
    let mut gx = vec![0.0; w * h];
    let mut gy = vec![0.0; w * h];
    if w == 0 || h == 0 {
        return (gx, gy);
    }
    // Row by row in parallel, the interiors as plain slices (vectorised), the same
    // arithmetic as the formula at every pixel: `(next − previous) / spacing`.
    gx.par_chunks_mut(w)
        .zip(gy.par_chunks_mut(w))
        .enumerate()
        .for_each(|(y, (gx, gy))| {
            let row = &values[y * w..(y + 1) * w];
            if w > 1 {
                gx[0] = row[1] - row[0];
                gx[w - 1] = row[w - 1] - row[w - 2];
                for ((g, next), previous) in gx[1..w - 1].iter_mut().zip(&row[2..]).zip(row) {
                    *g = (next - previous) / 2.0;
                }
            }
            let (y0, y1) = (y.saturating_sub(1), (y + 1).min(h - 1));
            let spacing = (y1 - y0).max(1) as f32;
            let (above, below) = (&values[y0 * w..(y0 + 1) * w], &values[y1 * w..(y1 + 1) * w]);
            for ((g, next), previous) in gy.iter_mut().zip(below).zip(above) {
                *g = (next - previous) / spacing;
            }
        });
    (gx, gy)
}

/// Reads and decodes a photo in any format the `image` crate has enabled, within limits: the
/// file must be a regular file of at most [`crate::io::MAX_LARGE_INPUT_BYTES`], and
/// [`decode_photo_bytes`]'s limits apply.
///
/// # Errors
/// A [`PhotoError`] naming the file: unreadable, of an unknown format, too large, or failing
/// to decode (a truncated download, say).
pub fn decode_photo(path: &Path) -> Result<image::DynamicImage, PhotoError> {
    let error = |problem| PhotoError {
        file: path.to_path_buf(),
        problem,
    };
    let bytes = crate::io::read_input(path, crate::io::MAX_LARGE_INPUT_BYTES)
        .map_err(|e| error(PhotoProblem::Unreadable(e.to_string())))?;
    decode_photo_bytes(&bytes).map_err(error)
}

/// Decodes a photo from its bytes (format by content), within limits: the header must
/// announce at most [`MAX_PIXELS`] (checked before decoding), and decoding may allocate at
/// most 2 GiB. A decoder that panics on a malformed file (none is known; the `photo` fuzz
/// target looks) fails this photo, not the program.
///
/// # Errors
/// [`PhotoProblem::Unreadable`] for an unknown format or a decoding failure,
/// [`PhotoProblem::Huge`] for a header beyond the limit.
pub fn decode_photo_bytes(bytes: &[u8]) -> Result<image::DynamicImage, PhotoProblem> {
    let unreadable =
        |e: &dyn std::fmt::Display| PhotoProblem::Unreadable(e.to_string().trim_end().to_owned());
    let reader = || -> Result<image::ImageReader<std::io::Cursor<&[u8]>>, PhotoProblem> {
        let mut reader = image::ImageReader::new(std::io::Cursor::new(bytes))
            .with_guessed_format()
            .map_err(|e| unreadable(&e))?;
        let mut limits = image::Limits::default();
        limits.max_alloc = Some(2 * 1024 * 1024 * 1024);
        reader.limits(limits);
        Ok(reader)
    };
    let (width, height) = reader()?.into_dimensions().map_err(|e| unreadable(&e))?;
    let (width, height) = (width as usize, height as usize);
    if width.saturating_mul(height) > MAX_PIXELS {
        return Err(PhotoProblem::Huge { width, height });
    }
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        reader()?.decode().map_err(|e| unreadable(&e))
    }))
    .unwrap_or_else(|_| Err(unreadable(&"the decoder failed on this file")))
}

#[cfg(test)]
mod gradient_tests {
    use super::central_differences;

    /// The row-sliced gradients against the formula at every pixel, on sizes with one-pixel
    /// sides and two-pixel sides (all borders), to the bit.
    #[test]
    fn central_differences_follow_the_formula() {
        for (w, h) in [(1, 1), (1, 5), (5, 1), (2, 3), (17, 9)] {
            let values: Vec<f32> = (0..w * h).map(|i| ((i * 37 + 11) % 23) as f32 * 0.37).collect();
            let (gx, gy) = central_differences(&values, w, h);
            for y in 0..h {
                for x in 0..w {
                    let (x0, x1) = (x.saturating_sub(1), (x + 1).min(w - 1));
                    let (y0, y1) = (y.saturating_sub(1), (y + 1).min(h - 1));
                    let ex = (values[y * w + x1] - values[y * w + x0]) / (x1 - x0).max(1) as f32;
                    let ey = (values[y1 * w + x] - values[y0 * w + x]) / (y1 - y0).max(1) as f32;
                    assert_eq!(gx[y * w + x].to_bits(), ex.to_bits(), "{w}x{h} gx at ({x}, {y})");
                    assert_eq!(gy[y * w + x].to_bits(), ey.to_bits(), "{w}x{h} gy at ({x}, {y})");
                }
            }
        }
    }
}
