//! Decoding inputs (images) with limits.
//!
//! Uploaded files are untrusted: a 200-byte PNG can announce a 100 000 × 100 000 image. Every
//! decode therefore goes through [`ImageLimits`], checked against the header *before* any pixel
//! buffer is allocated, and the same limits are handed to the `image` crate so that its own
//! allocations are bounded too. The format is guessed from the content, never from a file name.
//!
//! Grey conversion reproduces what the OpenCV peer (`cv2.imread(path, IMREAD_GRAYSCALE)`, OpenCV
//! 5.0) returns, so that blur scores agree with the peer bit for bit on PNG and 8-bit TIFF; see
//! [`decode_gray8`] for the measured rules.

pub mod archive;
mod sniff;
pub use sniff::{Sniffed, sniff};

use std::io::{BufRead, Cursor, Seek};

use image::{DynamicImage, ImageDecoder, ImageFormat, ImageReader};
use serde::{Deserialize, Serialize};

use crate::error::{CoreError, CoreResult};

/// Upper bounds applied to every decoded image.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct ImageLimits {
    /// Largest accepted width in pixels.
    pub max_width: u32,
    /// Largest accepted height in pixels.
    pub max_height: u32,
    /// Largest accepted width × height.
    pub max_pixels: u64,
    /// Largest allocation the decoder may make, in bytes (decoded buffer plus scratch).
    pub max_alloc_bytes: u64,
}

/// Largest image side any algorithm accepts (the default limit, and the ceiling of every
/// configured one, so an image accepted at upload is accepted by every job).
pub const MAX_IMAGE_SIDE: u32 = 16_384;
/// Largest image area any algorithm accepts.
pub const MAX_IMAGE_PIXELS: u64 = 100_000_000;

impl Default for ImageLimits {
    /// 16384 px per side, 100 Mpx, 512 MiB: room for any camera frame, far below what would
    /// exhaust a worker.
    fn default() -> Self {
        Self {
            max_width: MAX_IMAGE_SIDE,
            max_height: MAX_IMAGE_SIDE,
            max_pixels: MAX_IMAGE_PIXELS,
            max_alloc_bytes: 512 * 1024 * 1024,
        }
    }
}

impl ImageLimits {
    /// Reject dimensions outside the limits with a message a user can act on.
    pub fn check(&self, width: u32, height: u32) -> CoreResult<()> {
        if width == 0 || height == 0 {
            return Err(CoreError::input(format!(
                "image is {width}×{height}: it has no pixels"
            )));
        }
        if width > self.max_width || height > self.max_height {
            return Err(CoreError::input(format!(
                "image is {width}×{height}, larger than the limit of {}×{}",
                self.max_width, self.max_height
            )));
        }
        let pixels = u64::from(width) * u64::from(height);
        if pixels > self.max_pixels {
            return Err(CoreError::input(format!(
                "image is {width}×{height}, larger than the limit of {}",
                format_pixels(self.max_pixels)
            )));
        }
        Ok(())
    }

    /// Limits for the `image` crate. Dimensions are checked by [`ImageLimits::check`] right
    /// after the header is parsed (before any pixel allocation), which gives a clearer message
    /// than the crate's generic "image size exceeds limit"; the crate enforces the allocation cap.
    fn to_image_limits(self) -> image::Limits {
        let mut l = image::Limits::default();
        l.max_alloc = Some(self.max_alloc_bytes);
        l
    }
}

fn format_pixels(p: u64) -> String {
    if p >= 1_000_000 && p.is_multiple_of(1_000_000) {
        format!("{} Mpx", p / 1_000_000)
    } else if p >= 1_000_000 {
        format!("{:.1} Mpx", p as f64 / 1e6)
    } else {
        format!("{p} px")
    }
}

/// What the header of an image says, without decoding its pixels.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct ImageInfo {
    /// Container format guessed from the content: `png`, `jpeg` or `tiff`.
    pub format: String,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Bits per channel as decoded (8 or 16; 32 for floating-point TIFF).
    pub bit_depth: u8,
    /// Channels as decoded (1 grey, 2 grey + alpha, 3 RGB, 4 RGBA).
    pub channels: u8,
}

fn format_name(f: ImageFormat) -> CoreResult<&'static str> {
    match f {
        ImageFormat::Png => Ok("png"),
        ImageFormat::Jpeg => Ok("jpeg"),
        ImageFormat::Tiff => Ok("tiff"),
        other => Err(CoreError::input(format!(
            "unsupported image format {other:?}: only PNG, JPEG and TIFF are accepted"
        ))),
    }
}

fn image_err(context: &str, e: image::ImageError) -> CoreError {
    match e {
        image::ImageError::Limits(l) => {
            CoreError::input(format!("{context}: image exceeds the decoder limits ({l})"))
        }
        other => CoreError::input(format!("{context}: {other}")),
    }
}

/// Open a reader, guess the format from the magic bytes and return the format plus a decoder
/// that has read the header only.
fn open_decoder<'a, R: BufRead + Seek + 'a>(
    reader: R,
    limits: &ImageLimits,
) -> CoreResult<(ImageFormat, impl ImageDecoder + 'a)> {
    let mut r = ImageReader::new(reader)
        .with_guessed_format()
        .map_err(|e| CoreError::input(format!("cannot read image: {e}")))?;
    let format = r
        .format()
        .ok_or_else(|| CoreError::input("unrecognised image format: expected PNG, JPEG or TIFF"))?;
    format_name(format)?;
    r.limits(limits.to_image_limits());
    let decoder = r
        .into_decoder()
        .map_err(|e| image_err("cannot read image header", e))?;
    let (w, h) = decoder.dimensions();
    limits.check(w, h)?;
    Ok((format, decoder))
}

/// Read the header of an image and check it against `limits`.
///
/// Only the header is parsed; no pixel buffer is allocated, so this is safe to call on any
/// upload before queueing work for it. Unsupported formats, unreadable headers and images
/// beyond the limits give [`CoreError::InvalidInput`].
pub fn probe_image<R: BufRead + Seek>(reader: R, limits: &ImageLimits) -> CoreResult<ImageInfo> {
    let (format, decoder) = open_decoder(reader, limits)?;
    let (width, height) = decoder.dimensions();
    let ct = decoder.color_type();
    let channels = ct.channel_count();
    let bit_depth = ct.bytes_per_pixel() / channels.max(1) * 8;
    Ok(ImageInfo {
        format: format_name(format)?.to_string(),
        width,
        height,
        bit_depth,
        channels,
    })
}

/// An 8-bit greyscale image, row-major, `data.len() == width * height`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Gray {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Pixels, row after row.
    pub data: Vec<u8>,
}

impl Gray {
    /// Build from raw pixels; fails if the length does not match the size.
    pub fn new(width: u32, height: u32, data: Vec<u8>) -> CoreResult<Self> {
        if data.len() as u64 != u64::from(width) * u64::from(height) {
            return Err(CoreError::input(format!(
                "grey image {width}×{height} needs {} bytes, got {}",
                u64::from(width) * u64::from(height),
                data.len()
            )));
        }
        Ok(Self {
            width,
            height,
            data,
        })
    }

    /// Row `y` as a slice.
    pub fn row(&self, y: usize) -> &[u8] {
        let w = self.width as usize;
        &self.data[y * w..(y + 1) * w]
    }
}

/// libpng's `rgb_to_gray` as configured by OpenCV (`png_set_rgb_to_gray(.., 0.299, 0.587)`):
/// 15-bit coefficients, *truncating* for 8-bit samples. Verified against `cv2.imread` on all
/// 2²⁴ RGB triples (OpenCV 5.0.0, libpng 1.6.58).
#[inline]
fn png_gray8(r: u8, g: u8, b: u8) -> u8 {
    ((9797 * u32::from(r) + 19234 * u32::from(g) + 3737 * u32::from(b)) >> 15) as u8
}

/// libpng's 16-bit `rgb_to_gray` (rounding) followed by OpenCV's 16→8 bit reduction (`>> 8`).
/// Verified against `cv2.imread` on 300 000 random 16-bit RGB triples.
#[inline]
fn png_gray16(r: u16, g: u16, b: u16) -> u8 {
    let y = (9797 * u64::from(r) + 19234 * u64::from(g) + 3737 * u64::from(b) + 16384) >> 15;
    (y >> 8) as u8
}

/// OpenCV's own BT.601 fixed-point conversion used by its TIFF reader: (R·4899 + G·9617 +
/// B·1868 + 8192) >> 14. Verified against `cv2.imread` on all 2²⁴ RGB triples for 8-bit TIFF.
/// (`cv2.cvtColor(BGR2GRAY)` in OpenCV 5.0 uses 15-bit coefficients 9798/19235/3735 instead;
/// the two differ by one level on 0.3 % of colours.)
#[inline]
fn bt601_gray8(r: u8, g: u8, b: u8) -> u8 {
    ((4899 * u32::from(r) + 9617 * u32::from(g) + 1868 * u32::from(b) + 8192) >> 14) as u8
}

fn rgb_to_gray<const C: usize, T: Copy>(raw: &[T], f: impl Fn(T, T, T) -> u8) -> Vec<u8> {
    raw.chunks_exact(C).map(|p| f(p[0], p[1], p[2])).collect()
}

fn channel0<const C: usize, T: Copy>(raw: &[T], f: impl Fn(T) -> u8) -> Vec<u8> {
    raw.chunks_exact(C).map(|p| f(p[0])).collect()
}

fn to_gray(img: DynamicImage, format: ImageFormat) -> Vec<u8> {
    // The colour rule depends on which library OpenCV delegates to for that container.
    let c8: fn(u8, u8, u8) -> u8 = match format {
        ImageFormat::Png => png_gray8,
        _ => bt601_gray8,
    };
    let c16 = |r: u16, g: u16, b: u16| -> u8 {
        match format {
            ImageFormat::Png => png_gray16(r, g, b),
            _ => bt601_gray8((r >> 8) as u8, (g >> 8) as u8, (b >> 8) as u8),
        }
    };
    let hi = |v: u16| (v >> 8) as u8;
    match img {
        DynamicImage::ImageLuma8(i) => i.into_raw(),
        DynamicImage::ImageLumaA8(i) => channel0::<2, u8>(i.as_raw(), |v| v),
        DynamicImage::ImageRgb8(i) => rgb_to_gray::<3, u8>(i.as_raw(), c8),
        DynamicImage::ImageRgba8(i) => rgb_to_gray::<4, u8>(i.as_raw(), c8),
        DynamicImage::ImageLuma16(i) => channel0::<1, u16>(i.as_raw(), hi),
        DynamicImage::ImageLumaA16(i) => channel0::<2, u16>(i.as_raw(), hi),
        DynamicImage::ImageRgb16(i) => rgb_to_gray::<3, u16>(i.as_raw(), c16),
        DynamicImage::ImageRgba16(i) => rgb_to_gray::<4, u16>(i.as_raw(), c16),
        // Floating-point TIFF and any future variant: through 8-bit RGB.
        other => rgb_to_gray::<3, u8>(other.to_rgb8().as_raw(), bt601_gray8),
    }
}

/// Decode a PNG, JPEG or TIFF file to 8-bit grey, as `cv2.imread(path, IMREAD_GRAYSCALE)` does.
///
/// The header is checked against `limits` before anything is allocated and the decoder runs
/// with the same limits; truncated or corrupt files give [`CoreError::InvalidInput`].
///
/// Grey conversion, measured against OpenCV 5.0.0 (alpha is always ignored):
/// - grey files: unchanged; 16-bit grey: `v >> 8` (exact match).
/// - PNG colour: libpng's conversion, `(9797 R + 19234 G + 3737 B) >> 15` for 8-bit samples,
///   `((9797 R + 19234 G + 3737 B + 16384) >> 15) >> 8` for 16-bit samples (exact match).
/// - TIFF colour: `(4899 R + 9617 G + 1868 B + 8192) >> 14` (exact match for 8-bit; 16-bit
///   samples are reduced with `>> 8` first, which can differ from OpenCV by one level).
/// - JPEG colour (YCbCr): as libjpeg does for OpenCV, the luma plane is decoded and the
///   chroma planes are never touched, so colour fringes (lateral chromatic aberration,
///   half-resolution chroma upsampled across an edge, clipping of the RGB reconstruction) cannot
///   move an edge. The IDCT is zune-jpeg's, not libjpeg's: values can differ by a level.
///   Other colour JPEGs (Adobe RGB or CMYK) are decoded to RGB and converted as above.
pub fn decode_gray8(bytes: &[u8], limits: &ImageLimits) -> CoreResult<Gray> {
    let (format, decoder) = open_decoder(Cursor::new(bytes), limits)?;
    if format == ImageFormat::Jpeg && decoder.color_type().channel_count() >= 3 {
        drop(decoder);
        if !jpeg_has_end_marker(bytes) {
            return Err(truncated_jpeg());
        }
        if let Some(g) = jpeg_luma(bytes, limits)? {
            return Ok(g);
        }
    }
    let (img, format) = decode_image(bytes, limits)?;
    let (width, height) = (img.width(), img.height());
    let data = to_gray(img, format);
    Gray::new(width, height, data)
}

/// The decoded luma plane of a YCbCr JPEG (`None` for other colour spaces). The header has
/// been checked against `limits` by the caller; the decoder gets the same bounds.
fn jpeg_luma(bytes: &[u8], limits: &ImageLimits) -> CoreResult<Option<Gray>> {
    use zune_core::bytestream::ZCursor;
    use zune_core::colorspace::ColorSpace;
    use zune_core::options::DecoderOptions;
    let side = |v: u32| usize::try_from(v).unwrap_or(usize::MAX);
    let opts = DecoderOptions::default()
        .set_max_width(side(limits.max_width))
        .set_max_height(side(limits.max_height))
        .jpeg_set_out_colorspace(ColorSpace::Luma);
    let mut dec = zune_jpeg::JpegDecoder::new_with_options(ZCursor::new(bytes), opts);
    dec.decode_headers()
        .map_err(|e| CoreError::input(format!("cannot read image header: {e}")))?;
    if dec.input_colorspace() != Some(ColorSpace::YCbCr) {
        return Ok(None);
    }
    let data = dec
        .decode()
        .map_err(|e| CoreError::input(format!("cannot decode image: {e}")))?;
    let (w, h) = dec
        .dimensions()
        .ok_or_else(|| CoreError::input("cannot decode image: no dimensions"))?;
    let (w, h) = (
        u32::try_from(w).map_err(|_| CoreError::input("image too wide"))?,
        u32::try_from(h).map_err(|_| CoreError::input("image too tall"))?,
    );
    Gray::new(w, h, data).map(Some)
}

fn truncated_jpeg() -> CoreError {
    CoreError::input("truncated JPEG: the file does not end with an end-of-image marker")
}

/// Decode PNG, JPEG or TIFF bytes keeping their pixel format (bit depth and channels), with the
/// header checked against `limits` before any pixel is allocated and truncated JPEGs refused
/// (see [`decode_gray8`]). Returns the image and its container format.
pub fn decode_image(bytes: &[u8], limits: &ImageLimits) -> CoreResult<(DynamicImage, ImageFormat)> {
    let (format, decoder) = open_decoder(Cursor::new(bytes), limits)?;
    if format == ImageFormat::Jpeg && !jpeg_has_end_marker(bytes) {
        return Err(truncated_jpeg());
    }
    let img =
        DynamicImage::from_decoder(decoder).map_err(|e| image_err("cannot decode image", e))?;
    Ok((img, format))
}

/// Whether a JPEG file ends with its EOI marker (FF D9), ignoring trailing zero or whitespace
/// padding that some writers add. The JPEG decoder used by `image` is lenient: it fills the
/// missing part of a truncated file with grey instead of failing, which would silently score a
/// half-received upload. Inside entropy-coded data an FF byte is always followed by 00 or a
/// restart marker, so a file cut mid-scan cannot end in FF D9 by accident.
fn jpeg_has_end_marker(bytes: &[u8]) -> bool {
    let end = bytes
        .iter()
        .rposition(|&b| !matches!(b, 0 | b' ' | b'\t' | b'\r' | b'\n'))
        .map_or(0, |i| i + 1);
    bytes[..end].ends_with(&[0xFF, 0xD9])
}

#[cfg(test)]
mod tests;
