//! Photometric correction: from pixel values back to scene radiance.

use serde::{Deserialize, Serialize};

use super::{PhotoImage, PhotometricModel};
use crate::deconv::Plane;
use crate::error::{CoreError, CoreResult};
use crate::progress::Progress;

/// Parameters of [`correct`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct CorrectParams {
    /// Exposure of the image relative to the reference (frame 0 of the fit); the output is
    /// divided by it so that all frames share one radiance scale.
    pub exposure: f64,
    /// Multiply the output by this (e.g. to bring radiance back to a displayable range).
    pub gain: f64,
}

impl Default for CorrectParams {
    fn default() -> Self {
        Self {
            exposure: 1.0,
            gain: 1.0,
        }
    }
}

/// Undo response, vignetting and exposure: `L = gain · f⁻¹(O) / (V(x) · exposure)`. The
/// output is linear radiance (not clipped to `[0, 1]`: bright regions of a long exposure may
/// exceed 1 after correction).
pub fn correct(
    image: &PhotoImage,
    model: &PhotometricModel,
    params: &CorrectParams,
    progress: &dyn Progress,
) -> CoreResult<Plane> {
    if !(params.exposure.is_finite() && params.exposure > 0.0) {
        return Err(CoreError::param("exposure", "must be > 0"));
    }
    if !(params.gain.is_finite() && params.gain > 0.0) {
        return Err(CoreError::param("gain", "must be > 0"));
    }
    let inv = super::InverseResponse::new(model.inverse_256.clone())?;
    if let Some(v) = &model.vignette {
        v.validate()?;
        if (v.width, v.height) != (image.width, image.height) {
            return Err(CoreError::input(format!(
                "vignette is for {}×{} images, this one is {}×{}",
                v.width, v.height, image.width, image.height
            )));
        }
    }
    // Lookup table per code value: cheap for 8 and 16 bit alike.
    let lut: Vec<f32> = (0..=image.max_level)
        .map(|c| inv.eval(f64::from(c) / f64::from(image.max_level)) as f32)
        .collect();
    let k = (params.gain / params.exposure) as f32;
    let mut out = Vec::with_capacity(image.data.len());
    for y in 0..image.height {
        if y % 64 == 0 {
            progress.check()?;
        }
        for x in 0..image.width {
            let vg = model
                .vignette
                .as_ref()
                .map_or(1.0, |v| v.eval(x as f64, y as f64) as f32);
            // Masked pixels (outside a fisheye's image circle, V = 0) carry no radiance.
            let v = if vg > 0.0 {
                lut[usize::from(image.data[y * image.width + x])] * k / vg
            } else {
                0.0
            };
            out.push(v);
        }
    }
    Plane::new(image.width, image.height, out)
}
