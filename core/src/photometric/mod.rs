//! Photometric calibration: camera response, vignetting and exposure times.
//!
//! Image formation (science notes, "Photometric calibration"): `O(x) = f(t · V(x) · L(x))`
//! with `f` the camera response, `t` the exposure, `V` the vignetting and `L` the scene
//! radiance. Everything is normalised: intensities `O / (2ⁿ − 1)` and irradiances in `[0, 1]`.
//!
//! * [`ResponseModel`] (gamma or EMoR, Grossberg & Nayar, PAMI 2004) and its
//!   [`InverseResponse`] table.
//! * [`photometric_response`]: response from a bracketed stack of a static scene (in the spirit
//!   of Debevec & Malik, SIGGRAPH 1997, but with the EMoR basis, monotonicity and robust
//!   weighting), optionally re-estimating the exposure ratios.
//! * [`vignetting`]: `V(r) = 1 + v1 r² + v2 r⁴ + v3 r⁶` (r = 1 at the corners) from flat fields,
//!   or a radial spline with an image-circle mask for wide and fisheye lenses ([`RadialSpline`]).
//! * [`photometric_online`]: response, vignetting and exposures from an auto-exposure video
//!   (Bergmann, Wang & Cremers, RA-L 2017): gain-robust KLT tracks (Kim & Pollefeys 2008), a
//!   fast linear exposure estimate, then a joint Huber Levenberg-Marquardt refinement.
//! * [`correct`]: undo response, vignetting and exposure.
//! * [`dso`]: DSO `pcalib.txt`, `vignette.png`, `times.txt` writers and validating readers.
//! * [`plot`]: SVG plots of the response, the vignette profile and the exposures.
//! * [`synth`]: deterministic synthetic bracketed stacks, flat fields and AE videos.

mod bracket;
mod correct;
pub mod dso;
mod emor;
mod flat;
mod joint;
pub mod metrics;
mod online;
pub mod plot;
mod response;
mod spline;
mod spline_center;
pub mod synth;
mod synth_lens;
mod vignette;

#[cfg(test)]
mod censor_tests;
#[cfg(test)]
mod online_fisheye_tests;
#[cfg(test)]
mod online_tests;
#[cfg(test)]
mod spline_tests;
#[cfg(test)]
mod tests;

pub use bracket::{ResponseParams, ResponseResult, photometric_response};
pub use correct::{CorrectParams, correct};
pub use emor::{EMOR_DIM, EMOR_SAMPLES, EmorBasis, emor_basis};
pub use flat::{VignetteKind, VignettingParams, VignettingResult, vignetting};
pub use online::{
    BrokenTracks, CenterMode, CenterReport, ChannelResponse, Channels, CircleMode,
    CompressionLevel, CompressionNote, ImageCircle, MeasuredLevels, OnlineParams, OnlineResult,
    judge_compression, photometric_online, photometric_online_rgb,
};
pub use response::{InverseResponse, ResponseModel};
pub use spline::RadialSpline;
pub use vignette::VignetteModel;

use image::DynamicImage;
use serde::{Deserialize, Serialize};

use crate::error::{CoreError, CoreResult};
use crate::io::{Gray, ImageLimits};

/// Schema name of the JSON document a photometric job produces.
pub const PHOTOMETRIC_SCHEMA: &str = "caliper.photometric/v1";

/// A single-channel 8- or 16-bit image as the camera delivered it (no conversion: the
/// response is what we are measuring).
#[derive(Debug, Clone, PartialEq)]
pub struct PhotoImage {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Largest code value: 255 (8-bit) or 65535 (16-bit).
    pub max_level: u16,
    /// Pixels, row after row.
    pub data: Vec<u16>,
}

impl PhotoImage {
    /// Build from raw values; fails on a size mismatch, an empty image or a value above
    /// `max_level`.
    pub fn new(width: usize, height: usize, max_level: u16, data: Vec<u16>) -> CoreResult<Self> {
        if width == 0 || height == 0 {
            return Err(CoreError::input("image is empty"));
        }
        if data.len() != width * height {
            return Err(CoreError::input(format!(
                "image {width}×{height} needs {} values, got {}",
                width * height,
                data.len()
            )));
        }
        if max_level == 0 {
            return Err(CoreError::input("max_level must be > 0"));
        }
        if let Some(i) = data.iter().position(|&v| v > max_level) {
            return Err(CoreError::input(format!(
                "pixel {i} has value {} above the maximum {max_level}",
                data[i]
            )));
        }
        Ok(Self {
            width,
            height,
            max_level,
            data,
        })
    }

    /// From an 8-bit grey image.
    pub fn from_gray(img: &Gray) -> Self {
        Self {
            width: img.width as usize,
            height: img.height as usize,
            max_level: 255,
            data: img.data.iter().map(|&v| u16::from(v)).collect(),
        }
    }

    /// From a video's limited-range 8-bit luma plane (black 16, white 235: the H.264 default),
    /// expanded to 16-bit full range so that no level is lost to rounding.
    pub fn from_limited_luma(width: usize, height: usize, luma: &[u8]) -> Self {
        let data = luma
            .iter()
            .map(|&y| {
                let v = (f64::from(y) - 16.0) * (65535.0 / 219.0);
                v.round().clamp(0.0, 65535.0) as u16
            })
            .collect();
        Self {
            width,
            height,
            max_level: 65535,
            data,
        }
    }

    /// From a decoded video luma plane: taken as is when the clip is full range (0–255, e.g.
    /// Motion-JPEG), else expanded from limited range ([`Self::from_limited_luma`]).
    pub fn from_video_luma(width: usize, height: usize, luma: Vec<u8>, full_range: bool) -> Self {
        if full_range {
            Self {
                width,
                height,
                max_level: 255,
                data: luma.into_iter().map(u16::from).collect(),
            }
        } else {
            Self::from_limited_luma(width, height, &luma)
        }
    }

    /// Decode PNG/TIFF/JPEG bytes keeping the bit depth: 16-bit files stay 16-bit, everything
    /// else becomes 8-bit; colour is reduced to luma by the `image` crate (Rec. 709 weights).
    pub fn decode(bytes: &[u8], limits: &ImageLimits) -> CoreResult<Self> {
        let (img, _) = crate::io::decode_image(bytes, limits)?;
        let (w, h) = (img.width(), img.height());
        let sixteen = matches!(
            img,
            DynamicImage::ImageLuma16(_)
                | DynamicImage::ImageLumaA16(_)
                | DynamicImage::ImageRgb16(_)
                | DynamicImage::ImageRgba16(_)
        );
        if sixteen {
            let l = img.into_luma16();
            Self::new(w as usize, h as usize, u16::MAX, l.into_raw())
        } else {
            let l = img.into_luma8();
            Self::new(
                w as usize,
                h as usize,
                255,
                l.into_raw().into_iter().map(u16::from).collect(),
            )
        }
    }

    /// Decode a colour PNG/TIFF/JPEG into its `[R, G, B]` planes, keeping the bit depth like
    /// [`Self::decode`] (alpha is dropped). Grey images are refused: a per-channel fit needs
    /// three channels.
    pub fn decode_rgb(bytes: &[u8], limits: &ImageLimits) -> CoreResult<[Self; 3]> {
        let (img, _) = crate::io::decode_image(bytes, limits)?;
        let (w, h) = (img.width() as usize, img.height() as usize);
        if !img.color().has_color() {
            return Err(CoreError::input(
                "the image is greyscale: channels rgb needs colour images (use luma)",
            ));
        }
        let sixteen = matches!(
            img,
            DynamicImage::ImageRgb16(_) | DynamicImage::ImageRgba16(_)
        );
        let (max, data): (u16, Vec<u16>) = if sixteen {
            (u16::MAX, img.into_rgb16().into_raw())
        } else {
            (
                255,
                img.into_rgb8()
                    .into_raw()
                    .into_iter()
                    .map(u16::from)
                    .collect(),
            )
        };
        let plane = |c: usize| {
            let v: Vec<u16> = data.iter().skip(c).step_by(3).copied().collect();
            Self::new(w, h, max, v)
        };
        Ok([plane(0)?, plane(1)?, plane(2)?])
    }

    /// Normalised value at integer coordinates.
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> f64 {
        f64::from(self.data[y * self.width + x]) / f64::from(self.max_level)
    }
}

/// Check a stack: non-empty, same size, same bit depth.
pub(crate) fn check_stack(images: &[PhotoImage], min: usize) -> CoreResult<(usize, usize)> {
    let first = images
        .first()
        .ok_or_else(|| CoreError::input("no images given"))?;
    if images.len() < min {
        return Err(CoreError::input(format!(
            "need at least {min} images, got {}",
            images.len()
        )));
    }
    for (i, im) in images.iter().enumerate() {
        if im.width != first.width || im.height != first.height || im.max_level != first.max_level {
            return Err(CoreError::input(format!(
                "image {i} is {}×{} (max {}), image 0 is {}×{} (max {}): all images must match",
                im.width, im.height, im.max_level, first.width, first.height, first.max_level
            )));
        }
    }
    Ok((first.width, first.height))
}

/// A complete photometric model: what [`correct`] needs and what the DSO files describe.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct PhotometricModel {
    /// Camera response.
    pub response: ResponseModel,
    /// Inverse response, 256 levels (`pcalib.txt` / 255).
    pub inverse_256: Vec<f64>,
    /// Vignetting, if known.
    pub vignette: Option<VignetteModel>,
}

impl PhotometricModel {
    /// Model from a response and an optional vignette (the inverse table is derived).
    pub fn new(response: ResponseModel, vignette: Option<VignetteModel>) -> Self {
        let inverse_256 = response.inverse(256).values;
        Self {
            response,
            inverse_256,
            vignette,
        }
    }
}

/// Diagnostics common to the fits.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct FitDiagnostics {
    /// RMS of the inlier residuals in 8-bit intensity levels.
    pub residual_rms_levels: f64,
    /// Observations (pixel values) used.
    pub observations: usize,
    /// Scene points (pixels or track samples) used.
    pub points: usize,
    /// Levenberg-Marquardt iterations run.
    pub iterations: usize,
    /// Whether the optimiser stopped on a converged step (not on the iteration limit).
    pub converged: bool,
    /// Whether the fitted response is strictly increasing before any repair.
    pub monotone: bool,
}
