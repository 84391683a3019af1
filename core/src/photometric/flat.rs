//! Vignetting from flat-field images (a uniformly lit, uniform white target filling the view).
//!
//! After undoing the response, a flat field is `I_j(x) = s_j · V(x)` with one unknown scale
//! per image (exposure × target radiance). We fit `s_j`, `v1..v3` and optionally the optical
//! centre by Gauss-Newton on the pixels that are neither saturated nor under-exposed — the
//! same polynomial model as the online calibration and DSO (Engel et al.; the
//! tum-vision `vignetteCalib` tool fits a dense map instead).
//!
//! Wide and fisheye lenses whose image circle ends inside the frame need the radial spline with
//! an image-circle mask (`spline`). `vignette_model: auto` (the default) fits both and keeps the
//! polynomial unless the spline fits clearly better or the polynomial turns negative: where the
//! polynomial fits, its result is exactly what it was before the spline existed.

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use super::response::InverseResponse;
use super::spline::{SplineOptions, estimate_center, fit_spline};
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
    /// `polynomial`, `spline` (radial spline with an image-circle mask, for fisheye and wide
    /// lenses) or `auto` (default: both, the polynomial unless it goes negative or the spline
    /// fits clearly better; see `model_choice` in the result).
    pub vignette_model: VignetteKind,
    /// Spline knots (4 to 64), placed densely where the profile changes fast.
    pub knots: usize,
    /// Image circle: pixels beyond the radius where V stays below this fraction of the centre
    /// are masked (V = 0). 0 disables the mask. Range 0 to 0.5.
    pub circle_fraction: f64,
    /// Weight of the spline's second-difference penalty relative to the data (0 to 1).
    pub smoothing: f64,
}

/// Vignetting model family.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub enum VignetteKind {
    /// `1 + v1 r² + v2 r⁴ + v3 r⁶` (DSO, online calibration).
    Polynomial,
    /// Radial Hermite spline with an image-circle mask.
    Spline,
    /// Polynomial where it fits, else spline.
    #[default]
    Auto,
}

impl Default for VignettingParams {
    fn default() -> Self {
        Self {
            fit_center: false,
            stride: 2,
            low_cut: 3.0 / 255.0,
            high_cut: 252.0 / 255.0,
            max_iterations: 20,
            vignette_model: VignetteKind::Auto,
            knots: 24,
            circle_fraction: 0.05,
            smoothing: 1e-5,
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
        if !(4..=64).contains(&self.knots) {
            return Err(CoreError::param("knots", "must be in 4..=64"));
        }
        if !(self.circle_fraction >= 0.0 && self.circle_fraction <= 0.5) {
            return Err(CoreError::param(
                "circle_fraction",
                "must be within 0..=0.5",
            ));
        }
        if !(self.smoothing >= 0.0 && self.smoothing <= 1.0) {
            return Err(CoreError::param("smoothing", "must be within 0..=1"));
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
    /// Gauss-Newton iterations run (alternating least-squares rounds for the spline).
    pub iterations: usize,
    /// The model fitted: `polynomial` or `spline`.
    pub model: VignetteKind,
    /// Why that model (for `auto`: the comparison made).
    pub model_choice: String,
    /// Image-circle radius in pixels (spline model with a detected circle); V = 0 beyond.
    pub mask_radius_px: Option<f64>,
    /// RMS of `I / s − V` (in units of V) of the polynomial fit over the usable pixels inside
    /// the image circle, when it was fitted.
    pub polynomial_rms: Option<f64>,
    /// Same for the spline fit.
    pub spline_rms: Option<f64>,
}

/// Fit the vignetting to flat fields, given the camera's inverse response (use
/// [`InverseResponse::linear`] for a linear camera). `params.vignette_model` picks the model
/// (see the module doc).
pub fn vignetting(
    images: &[PhotoImage],
    inverse: &InverseResponse,
    params: &VignettingParams,
    progress: &dyn Progress,
) -> CoreResult<VignettingResult> {
    params.validate()?;
    check_stack(images, 1)?;
    let poly = match params.vignette_model {
        VignetteKind::Spline => None,
        _ => Some(fit_polynomial(images, inverse, params, progress)),
    };
    if params.vignette_model == VignetteKind::Polynomial {
        let mut r = poly.unwrap_or_else(|| Err(CoreError::input("no polynomial fit")))?;
        r.polynomial_rms = Some(v_rms(images, inverse, params, &r.vignette, &r.scales, None));
        r.model_choice = "polynomial (requested)".into();
        return Ok(r);
    }
    let spline = fit_spline_result(images, inverse, params, progress);
    let Some(poly) = poly else {
        let mut r = spline?;
        r.model_choice = "spline (requested)".into();
        return Ok(r);
    };
    match (poly, spline) {
        (Ok(mut p), Ok(sp)) => {
            let mask = sp.vignette.mask_radius.map(|m| (sp.vignette.clone(), m));
            let prms = v_rms(
                images,
                inverse,
                params,
                &p.vignette,
                &p.scales,
                mask.as_ref(),
            );
            let srms = sp.spline_rms.unwrap_or(f64::INFINITY);
            // The spline has ~8× the parameters, so it always fits a little better; keep the
            // polynomial unless the gain is clearly more than noise.
            if prms <= 1.2 * srms + 0.002 {
                p.polynomial_rms = Some(prms);
                p.spline_rms = Some(srms);
                p.model_choice =
                    format!("auto: polynomial (RMS {prms:.4} ≤ 1.2 × spline {srms:.4} + 0.002)");
                Ok(p)
            } else {
                let mut sp = sp;
                sp.polynomial_rms = Some(prms);
                sp.model_choice = format!(
                    "auto: spline (polynomial RMS {prms:.4} > 1.2 × spline {srms:.4} + 0.002)"
                );
                Ok(sp)
            }
        }
        (Err(e), Ok(mut sp)) => {
            sp.model_choice = format!("auto: spline (the polynomial does not fit: {e})");
            Ok(sp)
        }
        (Ok(mut p), Err(e)) => {
            p.model_choice = format!("auto: polynomial (the spline fit failed: {e})");
            Ok(p)
        }
        (Err(e), Err(_)) => Err(e),
    }
}

/// RMS of `I / s_j − V` (V units) over the usable pixels, leaving out those masked by `mask`
/// (a spline model and its mask radius) so both models are compared on the same pixels.
fn v_rms(
    images: &[PhotoImage],
    inverse: &InverseResponse,
    params: &VignettingParams,
    model: &VignetteModel,
    scales: &[f64],
    mask: Option<&(VignetteModel, f64)>,
) -> f64 {
    let (mut ss, mut n) = (0.0, 0usize);
    for (j, im) in images.iter().enumerate() {
        for y in (0..im.height).step_by(params.stride) {
            for x in (0..im.width).step_by(params.stride) {
                let v = im.get(x, y);
                let (xf, yf) = (x as f64, y as f64);
                if v <= params.low_cut
                    || v >= params.high_cut
                    || mask.is_some_and(|(m, _)| m.masked(xf, yf))
                {
                    continue;
                }
                ss += (inverse.eval(v) / scales[j] - model.eval(xf, yf)).powi(2);
                n += 1;
            }
        }
    }
    if n > 0 {
        (ss / n as f64).sqrt()
    } else {
        f64::INFINITY
    }
}

/// The spline model as a [`VignettingResult`].
fn fit_spline_result(
    images: &[PhotoImage],
    inverse: &InverseResponse,
    params: &VignettingParams,
    progress: &dyn Progress,
) -> CoreResult<VignettingResult> {
    let (w, h) = (images[0].width, images[0].height);
    let mut model = VignetteModel::centered(w, h, [0.0; 3]);
    if params.fit_center {
        model.center = estimate_center(images, params.high_cut);
    }
    let o = SplineOptions {
        stride: params.stride,
        low_cut: params.low_cut,
        high_cut: params.high_cut,
        knots: params.knots,
        circle_fraction: params.circle_fraction,
        smoothing: params.smoothing,
    };
    let fit = fit_spline(images, inverse, &o, model.center, model.radius, progress)?;
    model.spline = Some(fit.spline);
    model.mask_radius = fit.mask_r;
    model.validate()?;
    let (mut ss, mut n) = (0.0, 0usize);
    for (j, im) in images.iter().enumerate() {
        for y in (0..h).step_by(params.stride) {
            for x in (0..w).step_by(params.stride) {
                let v = im.get(x, y);
                let p = fit.scales[j] * model.eval(x as f64, y as f64);
                if v > params.low_cut && v < params.high_cut && p > 0.0 {
                    ss += (inverse.eval(v) / p - 1.0).powi(2);
                    n += 1;
                }
            }
        }
    }
    let srms = v_rms(images, inverse, params, &model, &fit.scales, None);
    Ok(VignettingResult {
        schema: PHOTOMETRIC_SCHEMA.to_string(),
        mask_radius_px: fit.mask_r.map(|m| m * model.radius),
        vignette: model,
        scales: fit.scales,
        relative_rms: if n > 0 { (ss / n as f64).sqrt() } else { 0.0 },
        pixels_used: n,
        iterations: 25,
        model: VignetteKind::Spline,
        model_choice: String::new(),
        polynomial_rms: None,
        spline_rms: Some(srms),
    })
}

/// The polynomial model (the original fit, unchanged).
fn fit_polynomial(
    images: &[PhotoImage],
    inverse: &InverseResponse,
    params: &VignettingParams,
    progress: &dyn Progress,
) -> CoreResult<VignettingResult> {
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
        model: VignetteKind::Polynomial,
        model_choice: String::new(),
        mask_radius_px: None,
        polynomial_rms: None,
        spline_rms: None,
    })
}
