//! Turning decoded pictures into upright 8-bit images.

use image::{GrayImage, ImageReader, RgbImage};

use super::h264::Picture;
use super::matrix::YCbCr;
use super::reader::{FrameFormat, FrameImage};

/// The luma plane (as coded: no range expansion; `Gray` expands limited range) or RGB of
/// `pic`, with the matrix and sample range the stream signals (`ycbcr`). Converting a
/// full-range picture as limited would stretch it by 255/219 and clip near black and white.
pub(crate) fn picture_to_image(
    pic: &Picture<'_>,
    format: FrameFormat,
    ycbcr: YCbCr,
) -> Option<FrameImage> {
    let (w, h) = (pic.width, pic.height);
    match format {
        FrameFormat::Luma | FrameFormat::Gray => {
            let mut buf = Vec::with_capacity(w.checked_mul(h)?);
            for row in pic.y.chunks(pic.y_stride).take(h) {
                buf.extend_from_slice(row.get(..w)?);
            }
            if format == FrameFormat::Gray && !ycbcr.full_range() {
                // The luma of the RGB conversion: grey (neutral chroma) as a player shows it.
                let to_rgb = ycbcr.to_rgb_fixed();
                let lut: [u8; 256] = std::array::from_fn(|y| to_rgb.rgb(y as u8, 128, 128)[0]);
                buf.iter_mut().for_each(|v| *v = lut[usize::from(*v)]);
            }
            GrayImage::from_raw(u32::try_from(w).ok()?, u32::try_from(h).ok()?, buf)
                .map(FrameImage::Luma)
        }
        FrameFormat::Rgb => {
            let to_rgb = ycbcr.to_rgb_fixed();
            let mut buf = vec![0u8; w.checked_mul(h)?.checked_mul(3)?];
            let chroma_rows = h / 2;
            for (yy, out_row) in buf.chunks_exact_mut(w * 3).enumerate() {
                let y_row = pic.y.get(yy * pic.y_stride..yy * pic.y_stride + w)?;
                let cy = (yy / 2).min(chroma_rows.saturating_sub(1));
                let u_row = pic.u.get(cy * pic.uv_stride..)?;
                let v_row = pic.v.get(cy * pic.uv_stride..)?;
                for (x, px) in out_row.chunks_exact_mut(3).enumerate() {
                    px.copy_from_slice(&to_rgb.rgb(
                        y_row[x],
                        *u_row.get(x / 2)?,
                        *v_row.get(x / 2)?,
                    ));
                }
            }
            RgbImage::from_raw(u32::try_from(w).ok()?, u32::try_from(h).ok()?, buf)
                .map(FrameImage::Rgb)
        }
    }
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
        FrameFormat::Luma | FrameFormat::Gray => FrameImage::Luma(img.to_luma8()),
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A 2×2 picture (4:2:0: one chroma sample).
    fn picture<'a>(ys: &'a [u8; 4], u: &'a [u8; 1], v: &'a [u8; 1]) -> Picture<'a> {
        Picture {
            token: 0,
            width: 2,
            height: 2,
            y: ys,
            y_stride: 2,
            u,
            v,
            uv_stride: 1,
        }
    }

    /// RGB of a 2×2 picture of one colour.
    fn rgb_of(y: u8, u: u8, v: u8, full_range: bool) -> [u8; 3] {
        let (ys, us, vs) = ([y; 4], [u], [v]);
        let pic = picture(&ys, &us, &vs);
        match picture_to_image(&pic, FrameFormat::Rgb, YCbCr::new(false, full_range)) {
            Some(FrameImage::Rgb(img)) => img.get_pixel(1, 1).0,
            other => panic!("expected RGB, got {other:?}"),
        }
    }

    #[test]
    fn limited_range_stretches_16_235_to_0_255() {
        assert_eq!(rgb_of(16, 128, 128, false), [0, 0, 0]);
        assert_eq!(rgb_of(235, 128, 128, false), [255, 255, 255]);
        assert_eq!(rgb_of(126, 128, 128, false), [128, 128, 128]);
    }

    #[test]
    fn full_range_keeps_grey_levels_and_the_ends() {
        for y in [0u8, 1, 16, 100, 235, 254, 255] {
            assert_eq!(rgb_of(y, 128, 128, true), [y, y, y]);
        }
        // Limited conversion of the same full-range samples clips near black and white.
        assert_eq!(rgb_of(10, 128, 128, false), [0, 0, 0]);
        assert_eq!(rgb_of(245, 128, 128, false), [255, 255, 255]);
    }

    #[test]
    fn gray_expands_limited_luma_only() {
        let ys = [16u8, 126, 235, 250];
        let pic = picture(&ys, &[128], &[128]);
        let raw = |format, full| match picture_to_image(&pic, format, YCbCr::new(false, full)) {
            Some(FrameImage::Luma(img)) => img.into_raw(),
            other => panic!("expected luma, got {other:?}"),
        };
        assert_eq!(raw(FrameFormat::Gray, false), [0, 128, 255, 255]);
        assert_eq!(raw(FrameFormat::Gray, true), ys);
        assert_eq!(raw(FrameFormat::Luma, false), ys);
    }

    #[test]
    fn full_range_colours_follow_jfif() {
        // JFIF red: Y 76, Cb 85, Cr 255 → (255, 0, 0) within a level of rounding.
        let [r, g, b] = rgb_of(76, 85, 255, true);
        assert!(r >= 254 && g <= 1 && b <= 1, "{r} {g} {b}");
        // Full-range blue: Y 29, Cb 255, Cr 107.
        let [r, g, b] = rgb_of(29, 255, 107, true);
        assert!(r <= 1 && g <= 1 && b >= 254, "{r} {g} {b}");
    }
}
