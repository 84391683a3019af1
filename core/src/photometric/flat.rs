//! Vignetting from flat-field images (a uniformly lit, uniform white target filling the view).
//!
//! After undoing the response, a flat field is `I_j(x) = s_j · V(x)` with one unknown scale
//! per image (exposure × target radiance). We fit `s_j`, `v1..v3` and optionally the optical
//! centre by Gauss-Newton on the pixels that are neither saturated nor under-exposed — the
//! same polynomial model as the online calibration and DSO (Engel et al.; the
//! tum-vision `vignetteCalib` tool fits a dense map instead).

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use super::response::InverseResponse;
use super::vignette::VignetteModel;
use super::{PHOTOMETRIC_SCHEMA, PhotoImage, check_stack};
use crate::error::{CoreError, CoreResult};
use crate::progress::Progress;

/// Parameters of [`vignetting`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct VignettingParams {
    /// Also fit the optical centre (otherwise the image centre `(w/2, h/2)`).
    pub fit_center: bool,
    /// Use every `stride`-th pixel in x and y.
    pub stride: usize,
    /// Values at or below this fraction of full scale are left out.
    pub low_cut: f64,
    /// Values at or above this fraction of full scale are left out.
    pub high_cut: f64,
    /// Gauss-Newton iteration limit.
    pub max_iterations: usize,
}

impl Default for VignettingParams {
    fn default() -> Self {
        Self {
            fit_center: false,
            stride: 2,
            low_cut: 3.0 / 255.0,
            high_cut: 252.0 / 255.0,
            max_iterations: 20,
        }
    }
}

impl VignettingParams {
    /// Check the ranges.
    pub fn validate(&self) -> CoreResult<()> {
        if !(1..=64).contains(&self.stride) {
            return Err(CoreError::param("stride", "must be in 1..=64"));
        }
        if !(self.low_cut >= 0.0 && self.low_cut < self.high_cut && self.high_cut <= 1.0) {
            return Err(CoreError::param(
                "low_cut",
                "need 0 ≤ low_cut < high_cut ≤ 1",
            ));
        }
        if !(1..=1000).contains(&self.max_iterations) {
            return Err(CoreError::param("max_iterations", "must be in 1..=1000"));
        }
        Ok(())
    }
}

/// Result of [`vignetting`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct VignettingResult {
    /// Always [`PHOTOMETRIC_SCHEMA`].
    pub schema: String,
    /// Fitted model; [`VignetteModel::map`] gives the dense map.
    pub vignette: VignetteModel,
    /// Linear brightness of each flat field at the centre (relative exposure × radiance).
    pub scales: Vec<f64>,
    /// RMS of `I / (s V) − 1` over the pixels used.
    pub relative_rms: f64,
    /// Pixel samples used (over all images).
    pub pixels_used: usize,
    /// Gauss-Newton iterations run.
    pub iterations: usize,
}

/// Fit the vignetting to flat fields, given the camera's inverse response (use
/// [`InverseResponse::linear`] for a linear camera).
pub fn vignetting(
    images: &[PhotoImage],
    inverse: &InverseResponse,
    params: &VignettingParams,
    progress: &dyn Progress,
) -> CoreResult<VignettingResult> {
    params.validate()?;
    let (w, h) = check_stack(images, 1)?;
    let mut model = VignetteModel::centered(w, h, [0.0; 3]);
    // Samples: (x, y, image, linear value).
    let mut samples = Vec::new();
    for (j, im) in images.iter().enumerate() {
        for y in (0..h).step_by(params.stride) {
            for x in (0..w).step_by(params.stride) {
                let v = im.get(x, y);
                if v > params.low_cut && v < params.high_cut {
                    samples.push((x as f64, y as f64, j, inverse.eval(v)));
                }
            }
        }
    }
    let n_img = images.len();
    if samples.len() < 100 {
        return Err(CoreError::input(
            "fewer than 100 usable flat-field pixels: images are saturated or black",
        ));
    }
    let mut scales: Vec<f64> = (0..n_img)
        .map(|j| {
            let (s, n) = samples
                .iter()
                .filter(|s| s.2 == j)
                .fold((0.0, 0usize), |(a, n), s| (a + s.3, n + 1));
            if n > 0 { s / n as f64 } else { 1.0 }
        })
        .collect();
    let nc = if params.fit_center { 2 } else { 0 };
    let dim = n_img + 3 + nc;
    let rr = model.radius * model.radius;
    let mut iterations = 0;
    let mut last = f64::INFINITY;
    for it in 0..params.max_iterations {
        progress.check()?;
        progress.report("vignetting", it as u64, params.max_iterations as u64);
        iterations = it + 1;
        let mut hm = DMatrix::<f64>::zeros(dim, dim);
        let mut g = DVector::<f64>::zeros(dim);
        let mut cost = 0.0;
        let mut jac = vec![0.0; dim];
        for &(x, y, j, val) in &samples {
            let r2 = model.r2(x, y);
            let vg = model.eval_r2(r2);
            let s = scales[j];
            let r = val - s * vg;
            cost += r * r;
            jac.iter_mut().for_each(|v| *v = 0.0);
            jac[j] = vg;
            jac[n_img] = s * r2;
            jac[n_img + 1] = s * r2 * r2;
            jac[n_img + 2] = s * r2 * r2 * r2;
            if nc == 2 {
                let dv = model.v[0] + r2 * (2.0 * model.v[1] + 3.0 * r2 * model.v[2]);
                jac[n_img + 3] = s * dv * (-2.0 * (x - model.center[0]) / rr);
                jac[n_img + 4] = s * dv * (-2.0 * (y - model.center[1]) / rr);
            }
            let nz: [usize; 6] = [j, n_img, n_img + 1, n_img + 2, n_img + 3, n_img + 4];
            let nzl = 4 + nc;
            for a in 0..nzl {
                let ia = nz[a];
                g[ia] += jac[ia] * r;
                for &ib in &nz[..nzl] {
                    hm[(ia, ib)] += jac[ia] * jac[ib];
                }
            }
        }
        for a in 0..dim {
            hm[(a, a)] += 1e-12;
        }
        let Some(chol) = hm.cholesky() else {
            return Err(CoreError::NoSolution(
                "vignetting normal equations are singular (flat field too small?)".into(),
            ));
        };
        let d = chol.solve(&g);
        for (j, s) in scales.iter_mut().enumerate() {
            *s += d[j];
        }
        for m in 0..3 {
            model.v[m] += d[n_img + m];
        }
        if nc == 2 {
            model.center[0] += d[n_img + 3].clamp(-0.25 * w as f64, 0.25 * w as f64);
            model.center[1] += d[n_img + 4].clamp(-0.25 * h as f64, 0.25 * h as f64);
        }
        let step = d.iter().map(|v| v.abs()).fold(0.0, f64::max);
        if step < 1e-10 || (last - cost).abs() <= 1e-12 * cost {
            break;
        }
        last = cost;
    }
    let mut ss = 0.0;
    for &(x, y, j, val) in &samples {
        let p = scales[j] * model.eval(x, y);
        ss += (val / p - 1.0).powi(2);
    }
    model.validate()?;
    Ok(VignettingResult {
        schema: PHOTOMETRIC_SCHEMA.to_string(),
        vignette: model,
        scales,
        relative_rms: (ss / samples.len() as f64).sqrt(),
        pixels_used: samples.len(),
        iterations,
    })
}
