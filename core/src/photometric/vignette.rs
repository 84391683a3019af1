//! The radial vignetting model: the DSO polynomial, or a radial spline with an image-circle
//! mask for wide and fisheye lenses (see `spline`).

use serde::{Deserialize, Serialize};

use super::spline::RadialSpline;
use crate::error::{CoreError, CoreResult};

/// `V(r) = 1 + v1 r² + v2 r⁴ + v3 r⁶` around `center`, with `r` the distance to the centre
/// divided by `radius`. By default the centre is `(w/2, h/2)` in pixel coordinates (pixel
/// centres at integer coordinates) and `radius` the half diagonal, so `r = 1` at the corners
/// (the convention of the science notes and of the shared ground truth). The radius stays the
/// half diagonal when the centre is fitted, so `v` keeps its meaning.
///
/// With `spline` set (the `spline` model, for lenses the polynomial cannot follow) V is that
/// curve of the same `r` instead, and with `mask_radius` V = 0 beyond it (outside the image
/// circle of a fisheye). Both fields are absent from the JSON of a polynomial model, which
/// therefore reads and writes exactly as before.
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
    /// Radial spline replacing the polynomial (the `spline` model).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub spline: Option<RadialSpline>,
    /// Image-circle radius, normalised like `r`: V = 0 (masked) beyond it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mask_radius: Option<f64>,
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
            spline: None,
            mask_radius: None,
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
        if let Some(s) = &self.spline {
            s.validate()?;
        }
        let mut rmax = self.max_r2();
        if let Some(m) = self.mask_radius {
            if !(m.is_finite() && m > 0.0) {
                return Err(CoreError::param("vignette", "mask_radius must be > 0"));
            }
            // Positive up to just inside the mask; 0 beyond it by definition.
            rmax = rmax.min(m * m * (1.0 - 1e-9));
        }
        let steps = if self.spline.is_some() { 1024 } else { 64 };
        if (0..=steps).any(|i| self.eval_r2(rmax * f64::from(i) / f64::from(steps)) <= 0.0) {
            return Err(CoreError::param(
                "vignette",
                "V(r) must stay positive over the image",
            ));
        }
        Ok(())
    }

    pub(crate) fn max_r2(&self) -> f64 {
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

    /// `V` as a function of `r²` (0 beyond the mask radius, if any).
    #[inline]
    pub fn eval_r2(&self, r2: f64) -> f64 {
        if let Some(m) = self.mask_radius
            && r2 > m * m
        {
            return 0.0;
        }
        match &self.spline {
            Some(s) => s.eval(r2.max(0.0).sqrt()),
            None => 1.0 + r2 * (self.v[0] + r2 * (self.v[1] + r2 * self.v[2])),
        }
    }

    /// Mask the model beyond the first radius where V falls to `floor` or below, and return
    /// that radius (None when V stays above `floor` over the image). For a polynomial fitted
    /// to tracks inside a fisheye's image circle (the online calibration), whose extrapolation
    /// to the dark corners turns negative: the corners carry no usable signal anyway, and a
    /// masked model is still a valid DSO `vignette.png` (0 there).
    pub fn mask_below(&mut self, floor: f64) -> Option<f64> {
        let rmax = self.max_r2().sqrt();
        let steps = 1024;
        let mut prev = 0.0f64;
        for i in 1..=steps {
            let r = rmax * f64::from(i) / f64::from(steps);
            if self.eval_r2(r * r).partial_cmp(&floor) != Some(std::cmp::Ordering::Greater) {
                self.mask_radius = Some(prev.max(1e-6));
                return self.mask_radius;
            }
            prev = r;
        }
        None
    }

    /// Whether pixel `(x, y)` lies outside the image circle (masked, V = 0).
    #[inline]
    pub fn masked(&self, x: f64, y: f64) -> bool {
        self.mask_radius.is_some_and(|m| self.r2(x, y) > m * m)
    }

    /// `V` at pixel `(x, y)`.
    #[inline]
    pub fn eval(&self, x: f64, y: f64) -> f64 {
        self.eval_r2(self.r2(x, y))
    }

    /// The dense map `V(x, y)`, row-major, `width × height` (not normalised; 0 where masked).
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
