//! Camera response from a bracketed stack of a static scene.
//!
//! Debevec & Malik ("Recovering High Dynamic Range Radiance Maps from Photographs", SIGGRAPH
//! 1997) solve for a free-form log inverse response with a smoothness prior. We instead fit the
//! four EMoR coefficients (Grossberg & Nayar 2004) and one radiance per sampled pixel by robust
//! Levenberg-Marquardt ([`super::joint`]): the low-dimensional basis needs no smoothness weight,
//! a monotonicity penalty keeps `f` invertible, and the per-pixel radiances absorb vignetting
//! (the scene is static). Saturated and under-exposed samples are left out, since they only
//! bound the radiance.

use serde::{Deserialize, Serialize};

use super::joint::{Censor, JointConfig, JointState, Obs, refine};
use super::response::ResponseModel;
use super::{FitDiagnostics, PHOTOMETRIC_SCHEMA, PhotoImage, PhotometricModel, check_stack};
use crate::error::{CoreError, CoreResult};
use crate::progress::Progress;

/// Parameters of [`photometric_response`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct ResponseParams {
    /// Pixels sampled on a regular grid (the fit cost grows linearly with it).
    pub max_points: usize,
    /// Values at or below this fraction of full scale are treated as under-exposed.
    pub low_cut: f64,
    /// Values at or above this fraction of full scale are treated as saturated.
    pub high_cut: f64,
    /// Re-estimate the exposure ratios (the given times are only a start); the γ gauge
    /// `f(0.5) = gamma_gauge` is then enforced.
    pub estimate_exposures: bool,
    /// Gauge value `f(0.5)` used when exposures are estimated.
    pub gamma_gauge: f64,
    /// Huber threshold in 8-bit levels.
    pub huber_levels: f64,
    /// Levenberg-Marquardt iteration limit.
    pub max_iterations: usize,
}

impl Default for ResponseParams {
    fn default() -> Self {
        Self {
            max_points: 4000,
            low_cut: 3.0 / 255.0,
            high_cut: 252.0 / 255.0,
            estimate_exposures: false,
            gamma_gauge: 0.5,
            huber_levels: 2.0,
            max_iterations: 60,
        }
    }
}

impl ResponseParams {
    /// Check the ranges.
    pub fn validate(&self) -> CoreResult<()> {
        if !(10..=1_000_000).contains(&self.max_points) {
            return Err(CoreError::param("max_points", "must be in 10..=1000000"));
        }
        if !(self.low_cut >= 0.0 && self.low_cut < self.high_cut && self.high_cut <= 1.0) {
            return Err(CoreError::param(
                "low_cut",
                "need 0 ≤ low_cut < high_cut ≤ 1",
            ));
        }
        if !(self.gamma_gauge > 0.05 && self.gamma_gauge < 0.95) {
            return Err(CoreError::param("gamma_gauge", "must be in (0.05, 0.95)"));
        }
        if !(self.huber_levels.is_finite() && self.huber_levels > 0.0) {
            return Err(CoreError::param("huber_levels", "must be > 0"));
        }
        if !(1..=1000).contains(&self.max_iterations) {
            return Err(CoreError::param("max_iterations", "must be in 1..=1000"));
        }
        Ok(())
    }
}

/// Result of [`photometric_response`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct ResponseResult {
    /// Always [`PHOTOMETRIC_SCHEMA`].
    pub schema: String,
    /// Fitted model (no vignetting: a static scene cannot separate it from radiance).
    pub model: PhotometricModel,
    /// Exposure of each image relative to image 0 (given, or estimated).
    pub exposure_ratios: Vec<f64>,
    /// Whether `exposure_ratios` were estimated.
    pub exposures_estimated: bool,
    /// Fit diagnostics.
    pub diagnostics: FitDiagnostics,
}

/// Fit the camera response to a bracketed stack of a static scene with exposure times
/// `exposures` (any unit; only ratios matter; one per image, > 0).
pub fn photometric_response(
    images: &[PhotoImage],
    exposures: &[f64],
    params: &ResponseParams,
    progress: &dyn Progress,
) -> CoreResult<ResponseResult> {
    params.validate()?;
    let (w, h) = check_stack(images, 2)?;
    if exposures.len() != images.len() {
        return Err(CoreError::input(format!(
            "{} images but {} exposure times",
            images.len(),
            exposures.len()
        )));
    }
    if let Some(i) = exposures.iter().position(|t| !(t.is_finite() && *t > 0.0)) {
        return Err(CoreError::input(format!(
            "exposure {i} is {}: exposure times must be > 0",
            exposures[i]
        )));
    }
    progress.report("sample", 0, 1);
    let stride = (((w * h) as f64 / params.max_points as f64).sqrt().floor() as usize).max(1);
    let g0 = ResponseModel::default().inverse(4096);
    let log_e: Vec<f64> = exposures.iter().map(|t| (t / exposures[0]).ln()).collect();
    let mut obs = Vec::new();
    let mut log_l = Vec::new();
    let mut logs = Vec::new();
    for y in (stride / 2..h).step_by(stride) {
        for x in (stride / 2..w).step_by(stride) {
            logs.clear();
            let start = obs.len();
            for (j, im) in images.iter().enumerate() {
                let v = im.get(x, y);
                if v > params.low_cut && v < params.high_cut {
                    obs.push(Obs {
                        point: log_l.len() as u32,
                        frame: j as u32,
                        r2: 0.0,
                        value: v as f32,
                        weight: 1.0,
                        censor: Censor::Exact,
                    });
                    logs.push(g0.eval(v).max(1e-6).ln() - log_e[j]);
                }
            }
            if logs.len() < 2 {
                obs.truncate(start);
                continue;
            }
            logs.sort_by(f64::total_cmp);
            log_l.push(logs[logs.len() / 2]);
        }
    }
    if log_l.len() < 10 {
        return Err(CoreError::input(format!(
            "only {} pixels are well exposed in at least two images: the bracket does not \
             overlap enough",
            log_l.len()
        )));
    }
    progress.check()?;
    let mut state = JointState::at_mean_response(log_e, log_l);
    let cfg = JointConfig {
        fit_response: true,
        fit_vignette: false,
        fit_exposures: params.estimate_exposures,
        gamma_gauge: params.estimate_exposures.then_some(params.gamma_gauge),
        huber: params.huber_levels / 255.0,
        max_iterations: params.max_iterations,
        label: "response",
    };
    let rep = refine(&obs, &cfg, &mut state, progress)?;
    let response = ResponseModel::Emor { c: state.c };
    let monotone = response.is_monotone();
    Ok(ResponseResult {
        schema: PHOTOMETRIC_SCHEMA.to_string(),
        model: PhotometricModel::new(response, None),
        exposure_ratios: state.log_e.iter().map(|l| l.exp()).collect(),
        exposures_estimated: params.estimate_exposures,
        diagnostics: FitDiagnostics {
            residual_rms_levels: rep.rms * 255.0,
            observations: obs.len(),
            points: state.log_l.len(),
            iterations: rep.iterations,
            converged: rep.converged,
            monotone,
        },
    })
}
