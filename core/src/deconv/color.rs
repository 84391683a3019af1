//! Colour and 16-bit images: split a [`DynamicImage`] into `[0, 1]` planes and put it back
//! together in the same pixel format and bit depth.

use image::{DynamicImage, ImageBuffer, Luma, LumaA, Rgb, Rgba};

use super::Plane;
use crate::error::{CoreError, CoreResult};

/// Channel arrangement of a split image.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ChannelLayout {
    /// One grey channel.
    Luma,
    /// Grey + alpha.
    LumaAlpha,
    /// Red, green, blue.
    Rgb,
    /// Red, green, blue + alpha.
    Rgba,
}

/// Sample type of the source image (and of the reassembled one).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SampleDepth {
    /// 8-bit integers.
    U8,
    /// 16-bit integers.
    U16,
    /// 32-bit floats (kept unclipped in `[0, 1]` convention).
    F32,
}

/// An image as planes in `[0, 1]`: the colour channels (1 or 3) and, separately, alpha.
///
/// Alpha is carried through untouched: it is a matte, not light that went through the lens, so
/// deconvolving it would only add ringing to the mask.
#[derive(Debug, Clone, PartialEq)]
pub struct SplitImage {
    /// Channel arrangement of the source.
    pub layout: ChannelLayout,
    /// Sample type of the source.
    pub depth: SampleDepth,
    /// Colour planes: `[grey]` or `[r, g, b]`.
    pub color: Vec<Plane>,
    /// Alpha plane, when the source has one.
    pub alpha: Option<Plane>,
}

impl SplitImage {
    /// Rec. 601 luma of the colour planes (the plane itself for grey): blur is the same in every
    /// channel, and luma has the best signal-to-noise ratio for estimating it.
    pub fn luma(&self) -> Plane {
        match self.color.as_slice() {
            [r, g, b] => Plane {
                width: r.width,
                height: r.height,
                data: r
                    .data
                    .iter()
                    .zip(&g.data)
                    .zip(&b.data)
                    .map(|((r, g), b)| 0.299 * r + 0.587 * g + 0.114 * b)
                    .collect(),
            },
            [p, ..] => p.clone(),
            [] => Plane {
                width: 0,
                height: 0,
                data: Vec::new(),
            },
        }
    }
}

/// Splits an 8/16-bit (or float) grey, grey+alpha, RGB or RGBA image into planes in `[0, 1]`.
pub fn split_image(img: &DynamicImage) -> CoreResult<SplitImage> {
    let (w, h) = (img.width() as usize, img.height() as usize);
    if w == 0 || h == 0 {
        return Err(CoreError::input("image is empty"));
    }
    let (layout, depth, chans, samples): (_, _, usize, Vec<f32>) = match img {
        DynamicImage::ImageLuma8(b) => (ChannelLayout::Luma, SampleDepth::U8, 1, u8s(b.as_raw())),
        DynamicImage::ImageLumaA8(b) => (
            ChannelLayout::LumaAlpha,
            SampleDepth::U8,
            2,
            u8s(b.as_raw()),
        ),
        DynamicImage::ImageRgb8(b) => (ChannelLayout::Rgb, SampleDepth::U8, 3, u8s(b.as_raw())),
        DynamicImage::ImageRgba8(b) => (ChannelLayout::Rgba, SampleDepth::U8, 4, u8s(b.as_raw())),
        DynamicImage::ImageLuma16(b) => {
            (ChannelLayout::Luma, SampleDepth::U16, 1, u16s(b.as_raw()))
        }
        DynamicImage::ImageLumaA16(b) => (
            ChannelLayout::LumaAlpha,
            SampleDepth::U16,
            2,
            u16s(b.as_raw()),
        ),
        DynamicImage::ImageRgb16(b) => (ChannelLayout::Rgb, SampleDepth::U16, 3, u16s(b.as_raw())),
        DynamicImage::ImageRgba16(b) => {
            (ChannelLayout::Rgba, SampleDepth::U16, 4, u16s(b.as_raw()))
        }
        DynamicImage::ImageRgb32F(b) => (ChannelLayout::Rgb, SampleDepth::F32, 3, b.to_vec()),
        DynamicImage::ImageRgba32F(b) => (ChannelLayout::Rgba, SampleDepth::F32, 4, b.to_vec()),
        other => {
            return Err(CoreError::input(format!(
                "unsupported pixel format {:?}",
                other.color()
            )));
        }
    };
    if samples.iter().any(|v| !v.is_finite()) {
        return Err(CoreError::input("image has non-finite samples"));
    }
    let plane = |c: usize| Plane {
        width: w,
        height: h,
        data: samples.iter().skip(c).step_by(chans).copied().collect(),
    };
    let n_color = if chans >= 3 { 3 } else { 1 };
    Ok(SplitImage {
        layout,
        depth,
        color: (0..n_color).map(plane).collect(),
        alpha: (chans % 2 == 0).then(|| plane(chans - 1)),
    })
}

/// Reassembles planes (same size as `like`'s) into `like`'s pixel format and bit depth; integer
/// formats are clipped to `[0, 1]` and rounded.
pub fn merge_image(like: &SplitImage, color: &[Plane]) -> CoreResult<DynamicImage> {
    let want = if matches!(like.layout, ChannelLayout::Rgb | ChannelLayout::Rgba) {
        3
    } else {
        1
    };
    if color.len() != want {
        return Err(CoreError::input(format!(
            "{} colour planes for a {:?} image",
            color.len(),
            like.layout
        )));
    }
    let (w, h) = (color[0].width, color[0].height);
    let mut planes: Vec<&Plane> = color.iter().collect();
    if let Some(a) = &like.alpha {
        planes.push(a);
    }
    if planes
        .iter()
        .any(|p| p.width != w || p.height != h || p.data.len() != w * h)
    {
        return Err(CoreError::input("planes differ in size"));
    }
    let chans = planes.len();
    let mut interleaved = vec![0.0f32; w * h * chans];
    for (c, p) in planes.iter().enumerate() {
        for (o, v) in interleaved.iter_mut().skip(c).step_by(chans).zip(&p.data) {
            *o = *v;
        }
    }
    let (wu, hu) = (w as u32, h as u32);
    let bad = || CoreError::input("buffer size mismatch");
    let to8 = |v: &[f32]| -> Vec<u8> {
        v.iter()
            .map(|x| (x.clamp(0.0, 1.0) * 255.0).round() as u8)
            .collect()
    };
    let to16 = |v: &[f32]| -> Vec<u16> {
        v.iter()
            .map(|x| (x.clamp(0.0, 1.0) * 65535.0).round() as u16)
            .collect()
    };
    let v = &interleaved;
    Ok(match (like.layout, like.depth) {
        (ChannelLayout::Luma, SampleDepth::U8) => DynamicImage::ImageLuma8(
            ImageBuffer::<Luma<u8>, _>::from_raw(wu, hu, to8(v)).ok_or_else(bad)?,
        ),
        (ChannelLayout::LumaAlpha, SampleDepth::U8) => DynamicImage::ImageLumaA8(
            ImageBuffer::<LumaA<u8>, _>::from_raw(wu, hu, to8(v)).ok_or_else(bad)?,
        ),
        (ChannelLayout::Rgb, SampleDepth::U8) => DynamicImage::ImageRgb8(
            ImageBuffer::<Rgb<u8>, _>::from_raw(wu, hu, to8(v)).ok_or_else(bad)?,
        ),
        (ChannelLayout::Rgba, SampleDepth::U8) => DynamicImage::ImageRgba8(
            ImageBuffer::<Rgba<u8>, _>::from_raw(wu, hu, to8(v)).ok_or_else(bad)?,
        ),
        (ChannelLayout::Luma, SampleDepth::U16) => DynamicImage::ImageLuma16(
            ImageBuffer::<Luma<u16>, _>::from_raw(wu, hu, to16(v)).ok_or_else(bad)?,
        ),
        (ChannelLayout::LumaAlpha, SampleDepth::U16) => DynamicImage::ImageLumaA16(
            ImageBuffer::<LumaA<u16>, _>::from_raw(wu, hu, to16(v)).ok_or_else(bad)?,
        ),
        (ChannelLayout::Rgb, SampleDepth::U16) => DynamicImage::ImageRgb16(
            ImageBuffer::<Rgb<u16>, _>::from_raw(wu, hu, to16(v)).ok_or_else(bad)?,
        ),
        (ChannelLayout::Rgba, SampleDepth::U16) => DynamicImage::ImageRgba16(
            ImageBuffer::<Rgba<u16>, _>::from_raw(wu, hu, to16(v)).ok_or_else(bad)?,
        ),
        (ChannelLayout::Rgb, SampleDepth::F32) => DynamicImage::ImageRgb32F(
            ImageBuffer::<Rgb<f32>, _>::from_raw(wu, hu, v.clone()).ok_or_else(bad)?,
        ),
        (ChannelLayout::Rgba, SampleDepth::F32) => DynamicImage::ImageRgba32F(
            ImageBuffer::<Rgba<f32>, _>::from_raw(wu, hu, v.clone()).ok_or_else(bad)?,
        ),
        (layout, depth) => {
            return Err(CoreError::input(format!(
                "no {depth:?} {layout:?} pixel format"
            )));
        }
    })
}

fn u8s(v: &[u8]) -> Vec<f32> {
    v.iter().map(|&x| f32::from(x) / 255.0).collect()
}

fn u16s(v: &[u16]) -> Vec<f32> {
    v.iter().map(|&x| f32::from(x) / 65535.0).collect()
}
