//! Turning decoded pictures into upright 8-bit images.

use image::{GrayImage, ImageReader, RgbImage};

use super::h264::Picture;
use super::reader::{FrameFormat, FrameImage};

/// The luma plane (as coded: no range expansion) or BT.601 limited-range RGB of `pic`.
pub(crate) fn picture_to_image(pic: &Picture<'_>, format: FrameFormat) -> Option<FrameImage> {
    let (w, h) = (pic.width, pic.height);
    match format {
        FrameFormat::Luma => {
            let mut buf = Vec::with_capacity(w.checked_mul(h)?);
            for row in pic.y.chunks(pic.y_stride).take(h) {
                buf.extend_from_slice(row.get(..w)?);
            }
            GrayImage::from_raw(u32::try_from(w).ok()?, u32::try_from(h).ok()?, buf)
                .map(FrameImage::Luma)
        }
        FrameFormat::Rgb => {
            let mut buf = vec![0u8; w.checked_mul(h)?.checked_mul(3)?];
            let chroma_rows = h / 2;
            for (yy, out_row) in buf.chunks_exact_mut(w * 3).enumerate() {
                let y_row = pic.y.get(yy * pic.y_stride..yy * pic.y_stride + w)?;
                let cy = (yy / 2).min(chroma_rows.saturating_sub(1));
                let u_row = pic.u.get(cy * pic.uv_stride..)?;
                let v_row = pic.v.get(cy * pic.uv_stride..)?;
                for (x, px) in out_row.chunks_exact_mut(3).enumerate() {
                    let c = 298 * (i32::from(y_row[x]) - 16);
                    let d = i32::from(*u_row.get(x / 2)?) - 128;
                    let e = i32::from(*v_row.get(x / 2)?) - 128;
                    px[0] = clamp((c + 409 * e + 128) >> 8);
                    px[1] = clamp((c - 100 * d - 208 * e + 128) >> 8);
                    px[2] = clamp((c + 516 * d + 128) >> 8);
                }
            }
            RgbImage::from_raw(u32::try_from(w).ok()?, u32::try_from(h).ok()?, buf)
                .map(FrameImage::Rgb)
        }
    }
}

fn clamp(v: i32) -> u8 {
    v.clamp(0, 255) as u8
}

/// Decodes one Motion-JPEG sample, refusing pictures larger than `max_pixels`.
pub(crate) fn jpeg_to_image(
    data: &[u8],
    format: FrameFormat,
    max_pixels: u64,
) -> Result<FrameImage, String> {
    let mut reader = ImageReader::with_format(std::io::Cursor::new(data), image::ImageFormat::Jpeg);
    let mut limits = image::Limits::default();
    let side = u32::try_from(max_pixels.min(u64::from(u32::MAX))).unwrap_or(u32::MAX);
    limits.max_image_width = Some(side);
    limits.max_image_height = Some(side);
    limits.max_alloc = Some(max_pixels.saturating_mul(8).max(1 << 20));
    reader.limits(limits.clone());
    let (w, h) = reader.into_dimensions().map_err(|e| e.to_string())?;
    if u64::from(w) * u64::from(h) > max_pixels {
        return Err(format!("a {w}x{h} JPEG is over the pixel limit"));
    }
    let mut reader = ImageReader::with_format(std::io::Cursor::new(data), image::ImageFormat::Jpeg);
    reader.limits(limits);
    let img = reader.decode().map_err(|e| e.to_string())?;
    Ok(match format {
        FrameFormat::Luma => FrameImage::Luma(img.to_luma8()),
        FrameFormat::Rgb => FrameImage::Rgb(img.to_rgb8()),
    })
}

/// Rotates clockwise by `deg` (0, 90, 180 or 270).
pub(crate) fn rotate(img: FrameImage, deg: u16) -> FrameImage {
    use image::imageops::{rotate90, rotate180, rotate270};
    match (img, deg) {
        (FrameImage::Luma(i), 90) => FrameImage::Luma(rotate90(&i)),
        (FrameImage::Luma(i), 180) => FrameImage::Luma(rotate180(&i)),
        (FrameImage::Luma(i), 270) => FrameImage::Luma(rotate270(&i)),
        (FrameImage::Rgb(i), 90) => FrameImage::Rgb(rotate90(&i)),
        (FrameImage::Rgb(i), 180) => FrameImage::Rgb(rotate180(&i)),
        (FrameImage::Rgb(i), 270) => FrameImage::Rgb(rotate270(&i)),
        (img, _) => img,
    }
}
