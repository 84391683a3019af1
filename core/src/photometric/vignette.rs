//! The radial vignetting model.

use serde::{Deserialize, Serialize};

use crate::error::{CoreError, CoreResult};

/// `V(r) = 1 + v1 r² + v2 r⁴ + v3 r⁶` around `center`, with `r` the distance to the centre
/// divided by `radius`. By default the centre is `(w/2, h/2)` in pixel coordinates (pixel
/// centres at integer coordinates) and `radius` the half diagonal, so `r = 1` at the corners
/// (the convention of the science notes and of the shared ground truth). The radius stays the
/// half diagonal when the centre is fitted, so `v` keeps its meaning.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct VignetteModel {
    /// Coefficients v1, v2, v3.
    pub v: [f64; 3],
    /// Optical centre `[x, y]` in pixels.
    pub center: [f64; 2],
    /// Normalising radius in pixels.
    pub radius: f64,
    /// Image width the model was fitted for.
    pub width: usize,
    /// Image height the model was fitted for.
    pub height: usize,
}

impl VignetteModel {
    /// Model centred on the image with `r = 1` at the corners.
    pub fn centered(width: usize, height: usize, v: [f64; 3]) -> Self {
        let (cx, cy) = (width as f64 / 2.0, height as f64 / 2.0);
        Self {
            v,
            center: [cx, cy],
            radius: cx.hypot(cy),
            width,
            height,
        }
    }

    /// No vignetting.
    pub fn none(width: usize, height: usize) -> Self {
        Self::centered(width, height, [0.0; 3])
    }

    /// Check that the model is usable: finite, positive radius and `V > 0` on the image.
    pub fn validate(&self) -> CoreResult<()> {
        if self.v.iter().chain(&self.center).any(|x| !x.is_finite())
            || !(self.radius.is_finite() && self.radius > 0.0)
        {
            return Err(CoreError::param(
                "vignette",
                "coefficients must be finite, radius > 0",
            ));
        }
        if self.width == 0 || self.height == 0 {
            return Err(CoreError::param("vignette", "image size must be non-zero"));
        }
        let rmax = self.max_r2();
        if (0..=64).any(|i| self.eval_r2(rmax * f64::from(i) / 64.0) <= 0.0) {
            return Err(CoreError::param(
                "vignette",
                "V(r) must stay positive over the image",
            ));
        }
        Ok(())
    }

    fn max_r2(&self) -> f64 {
        let (w, h) = (self.width as f64, self.height as f64);
        [(0.0, 0.0), (w, 0.0), (0.0, h), (w, h)]
            .iter()
            .map(|&(x, y)| self.r2(x, y))
            .fold(0.0, f64::max)
    }

    /// Squared normalised radius of pixel `(x, y)`.
    #[inline]
    pub fn r2(&self, x: f64, y: f64) -> f64 {
        let (dx, dy) = (x - self.center[0], y - self.center[1]);
        (dx * dx + dy * dy) / (self.radius * self.radius)
    }

    /// `V` as a function of `r²`.
    #[inline]
    pub fn eval_r2(&self, r2: f64) -> f64 {
        1.0 + r2 * (self.v[0] + r2 * (self.v[1] + r2 * self.v[2]))
    }

    /// `V` at pixel `(x, y)`.
    #[inline]
    pub fn eval(&self, x: f64, y: f64) -> f64 {
        self.eval_r2(self.r2(x, y))
    }

    /// The dense map `V(x, y)`, row-major, `width × height` (not normalised).
    pub fn map(&self) -> Vec<f32> {
        let mut out = Vec::with_capacity(self.width * self.height);
        for y in 0..self.height {
            for x in 0..self.width {
                out.push(self.eval(x as f64, y as f64) as f32);
            }
        }
        out
    }
}
