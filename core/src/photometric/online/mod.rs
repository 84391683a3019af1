//! Why one file of over 600 lines: the pipeline below (tracking, sampling, start, gauge,
//! refinement, centre and vignetting model) is one sequence whose stages hand over state; the
//! stages with their own logic live in the submodules.
//!
//! Online photometric calibration of an auto-exposure video (Bergmann, Wang & Cremers,
//! "Online Photometric Calibration of Auto Exposure Video for Realtime Visual Odometry and
//! SLAM", RA-L 2017), run as a batch over the given frames:
//!
//! 1. [`klt`]: gain-robust KLT tracks (Kim & Pollefeys 2008) on a pyramid, re-detecting
//!    Shi-Tomasi corners on a grid when tracks are lost; every track gives a few pixel samples
//!    around its centre, weighted down where the gradient is steep. Each match is re-aligned to
//!    the patch where the track was born, clipped pixels are left out of the match (the fit
//!    keeps them as bounds, [`super::joint::Censor`]), the brightness model has a quadratic
//!    term, the birth patch follows the video's roll and zoom ([`similarity`]), and tracks end
//!    after [`MAX_TRACK_AGE`] frames: track drift and slide (not the renderer, the noise or the
//!    fit: with true positions the fit recovers response / vignetting / exposures to 0.0002 /
//!    0.0008 / 0.4 %, `diag_tests.rs`) biased the fit most.
//! 2. Exposures: frame-to-frame log ratios from the tracks under the mean EMoR response
//!    (a linear problem), then a Gauss-Newton pass on exposures and radiances only.
//! 3. Joint Huber Levenberg-Marquardt over response (EMoR-4), vignetting (`v1..v3`),
//!    exposures and radiances ([`super::joint`]), with the gauge fixed explicitly: exposure 0 is
//!    1 and `f(0.5) = m`, with `m` chosen from the data by default ([`gauge`]) or given as
//!    `gamma_gauge` (then results of one camera share the gauge).
//! 4. Optionally (`vignette_center: auto | estimated`; the default keeps DSO's image centre)
//!    the vignetting centre ([`center`]), followed by a final joint refinement around it.
//! 5. By default (`tracking_passes: 2`) steps 1–3 are a first look that stops at the gauge
//!    profile ([`first_look`]); the video is then tracked again with every match re-aligned
//!    through that response ([`response_match`]) and steps 2–4 run on the new samples (the
//!    module `observe` tracks and samples).
//!
//! Colour input with `channels: rgb` tracks on luma and fits one response per channel with
//! exposures and vignetting shared ([`channels`]).

mod border;
mod center;
mod channels;
mod circle;
mod compression;
#[cfg(test)]
mod diag_tests;
#[cfg(test)]
mod diag_truth_tests;
#[cfg(test)]
mod feature_tests;
mod gauge;
pub(crate) mod klt;
mod levels;
mod linked;
mod observe;
mod pyramid;
mod response_match;
mod similarity;
mod vig_model;
mod vig_stage;

pub use center::{CenterMode, CenterReport};
pub use channels::{ChannelResponse, Channels, photometric_online_rgb};
pub use circle::ImageCircle;
pub use compression::{CompressionLevel, CompressionNote, judge_compression};
pub use levels::MeasuredLevels;

use serde::{Deserialize, Serialize};

use super::flat::VignetteKind;
use super::joint::{JointConfig, JointState, Obs, gauge_start, refine};
use super::response::ResponseModel;
use super::{FitDiagnostics, PHOTOMETRIC_SCHEMA, PhotoImage, PhotometricModel, check_stack};
use crate::error::{CoreError, CoreResult};
use crate::progress::Progress;
use gauge::GaugeContext;
pub(crate) use observe::{GRAD_HALF_WEIGHT, Observations, observe};
use response_match::ResponseMatch;
pub use vig_model::VignetteChoice;

/// Parameters of [`photometric_online`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct OnlineParams {
    /// Target number of simultaneously tracked features.
    pub max_features: usize,
    /// Pyramid levels used by the tracker.
    pub pyramid_levels: usize,
    /// Tracker half window (patch `2k+1` square).
    pub half_window: usize,
    /// Largest brightness-compensated patch RMS (normalised intensity) to keep a track.
    pub max_track_residual: f64,
    /// Pixel samples per track (1 = the centre, 5 = centre and ±2 px in x and y).
    pub samples_per_track: usize,
    /// Values at or below this fraction of full scale are left out.
    pub low_cut: f64,
    /// Values at or above this fraction of full scale are left out.
    pub high_cut: f64,
    /// Fit the vignetting (otherwise `V = 1`).
    pub fit_vignette: bool,
    /// γ gauge: `null` (default) chooses `m = f(0.5)` from the data by profiling the robust
    /// cost (the member of the exponential family that EMoR-4 represents best; a fixed value
    /// can keep EMoR-4 from following the camera's curve: over the sweep of
    /// `examples/photometric_sweep.rs` the median response RMSE falls from 0.0090 to 0.0018 on
    /// the held-out set); `m` makes the fitted response satisfy `f(0.5) = m` (repeatable
    /// across datasets of one camera, e.g. 0.5 as DSO's tools).
    pub gamma_gauge: Option<f64>,
    /// Huber threshold in 8-bit levels.
    pub huber_levels: f64,
    /// Joint refinement iteration limit.
    pub max_iterations: usize,
    /// Scene points kept for the refinement (evenly subsampled above this).
    pub max_points: usize,
    /// `luma` (default): one response for the luma of the frames; `rgb`: one response per
    /// colour channel with exposures and vignetting shared (colour frames only).
    pub channels: Channels,
    /// Vignetting centre: `fixed` (default) keeps the image centre (DSO's model), except that
    /// with an image circle found the circle's centre, refined by the spline fit, is used
    /// (with the polynomial requested: the circle's centre when it explains the samples
    /// better; `vig_stage`); `auto`
    /// estimates it and keeps the estimate when the data constrain it; `estimated` always
    /// uses the estimate. Experimental: on the synthetic tests the estimate can be biased by
    /// tens of pixels under mostly translational motion (see `center`).
    pub vignette_center: CenterMode,
    /// `polynomial` (DSO's `1 + v1 r² + v2 r⁴ + v3 r⁶`), `spline` (a radial spline, for
    /// wide-angle and mechanically vignetted lenses) or `auto` (both; the spline when it fits
    /// clearly better, see `vignette_choice` in the result).
    pub vignette_model: VignetteKind,
    /// Tracking passes: 2 (default) tracks the video again after a first fit, with every
    /// match re-aligned to its birth patch through that fit's response (`J = f(k·f⁻¹(T))`,
    /// Kim & Pollefeys 2008), and fits on the new samples (keeping the first fit's gauge
    /// `f(0.5)` when it explains them at least as well); 1 stops after the first fit, in
    /// about 55 % of the time. Two are at least as accurate on every sweep run (sequences
    /// within the accuracy targets: the sweep's tuning sets 58 against 54 of 60, held-out
    /// `eval5` 10 against 9, `eval6` 12 against 11, `eval7` and `eval8` 11 and 11 of 12 with
    /// lower median errors); see `examples/photometric_sweep.rs`.
    pub tracking_passes: usize,
    /// When the tracks break the video into parts that share no scene point (a cut, a jump,
    /// a stretch clipped white): `refuse` (default) fails with `invalid_input` naming the
    /// parts; `per_part` fits the response and vignetting from all parts and gives each
    /// part's exposures relative to its own first frame (`exposure_parts` in the result).
    pub broken_tracks: BrokenTracks,
    /// A fisheye's image circle: `auto` (default) looks for one in the video's mean recorded
    /// level (black beyond a circle, [`circle`]) and, when found, leaves out the samples
    /// beyond it, fits a radial spline inside it and masks the vignetting beyond it
    /// (`image_circle` in the result); with `vignette_center` `auto` or `estimated` its
    /// centre is the vignetting centre, with `fixed` the better of it and the image centre.
    /// `off` never looks.
    pub image_circle: CircleMode,
}

/// Whether `photometric_online` looks for a fisheye's image circle.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub enum CircleMode {
    /// Look for it and use it when found.
    #[default]
    Auto,
    /// Never look (the lens has no image circle, or the dark border is part of the scene).
    Off,
}

/// What `photometric_online` does with a video whose tracks break into parts that share no
/// scene point, so that their exposures have no common scale.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub enum BrokenTracks {
    /// Fail and name the parts: exposures across a break have no common scale.
    #[default]
    Refuse,
    /// Fit response and vignetting from every part; exposures per part.
    PerPart,
}

impl Default for OnlineParams {
    fn default() -> Self {
        Self {
            max_features: 300,
            pyramid_levels: 3,
            half_window: 4,
            max_track_residual: 0.04,
            samples_per_track: 5,
            low_cut: 3.0 / 255.0,
            high_cut: 250.0 / 255.0,
            fit_vignette: true,
            gamma_gauge: None,
            huber_levels: 3.0,
            max_iterations: 40,
            max_points: 6000,
            channels: Channels::Luma,
            vignette_center: CenterMode::Fixed,
            vignette_model: VignetteKind::Auto,
            tracking_passes: 2,
            broken_tracks: BrokenTracks::Refuse,
            image_circle: CircleMode::Auto,
        }
    }
}

impl OnlineParams {
    /// Check the ranges.
    pub fn validate(&self) -> CoreResult<()> {
        if !(10..=5000).contains(&self.max_features) {
            return Err(CoreError::param("max_features", "must be in 10..=5000"));
        }
        if !(1..=6).contains(&self.pyramid_levels) {
            return Err(CoreError::param("pyramid_levels", "must be in 1..=6"));
        }
        if !(2..=15).contains(&self.half_window) {
            return Err(CoreError::param("half_window", "must be in 2..=15"));
        }
        if !(self.max_track_residual > 0.0 && self.max_track_residual < 1.0) {
            return Err(CoreError::param("max_track_residual", "must be in (0, 1)"));
        }
        if !matches!(self.samples_per_track, 1 | 5 | 9) {
            return Err(CoreError::param("samples_per_track", "must be 1, 5 or 9"));
        }
        if !(self.low_cut >= 0.0 && self.low_cut < self.high_cut && self.high_cut <= 1.0) {
            return Err(CoreError::param(
                "low_cut",
                "need 0 ≤ low_cut < high_cut ≤ 1",
            ));
        }
        if self.gamma_gauge.is_some_and(|m| !(m > 0.05 && m < 0.95)) {
            return Err(CoreError::param("gamma_gauge", "must be in (0.05, 0.95)"));
        }
        if !(self.huber_levels.is_finite() && self.huber_levels > 0.0) {
            return Err(CoreError::param("huber_levels", "must be > 0"));
        }
        if !(1..=1000).contains(&self.max_iterations) {
            return Err(CoreError::param("max_iterations", "must be in 1..=1000"));
        }
        if !(1..=2).contains(&self.tracking_passes) {
            return Err(CoreError::param("tracking_passes", "must be 1 or 2"));
        }
        if self.max_points < 100 {
            return Err(CoreError::param("max_points", "must be ≥ 100"));
        }
        Ok(())
    }
}

/// Result of [`photometric_online`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct OnlineResult {
    /// Always [`PHOTOMETRIC_SCHEMA`].
    pub schema: String,
    /// Fitted response and vignetting.
    pub model: PhotometricModel,
    /// Exposure of each frame relative to frame 0 (in the γ gauge of the model).
    pub exposure_ratios: Vec<f64>,
    /// The fast linear estimate (mean response, no vignetting) before the joint refinement.
    pub initial_exposure_ratios: Vec<f64>,
    /// Feature tracks that contributed.
    pub tracks: usize,
    /// Mean track length in frames.
    pub mean_track_length: f64,
    /// Diagnostics of the joint refinement.
    pub diagnostics: FitDiagnostics,
    /// Whether the vignetting centre was estimated, where it is and how well it is known.
    #[serde(default)]
    pub vignette_center: CenterReport,
    /// Which vignetting model was kept and why.
    #[serde(default)]
    pub vignette_choice: VignetteChoice,
    /// With `channels: rgb`: the response of each channel (R, G, B), in the gauge of the shared
    /// exposures and vignetting; `model.response` is then the green one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub channel_responses: Option<Vec<ChannelResponse>>,
    /// Tracking passes whose samples were fitted (`tracking_passes`; 1 with two asked for
    /// when the second pass found too few tracks, and the first pass's samples were fitted).
    #[serde(default)]
    pub tracking_passes: usize,
    /// With `broken_tracks: per_part` and a video whose tracks broke: the part of each frame
    /// (0 = the part holding frame 0); `exposure_ratios` and `initial_exposure_ratios` are
    /// then relative to the first frame of each frame's part. Absent for a linked video.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exposure_parts: Option<Vec<usize>>,
    /// The recorded levels in which the fit saw measured (unclipped, uncut) samples; outside
    /// them the response follows the EMoR-4 model's shape, not the data (a strongly concave
    /// camera may show nothing unclipped in its top levels).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub measured_levels: Option<MeasuredLevels>,
    /// A fisheye's image circle, when the video shows one (`image_circle: auto`): the model is
    /// masked beyond it (V = 0, also in `vignette.png`) and centred on it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub image_circle: Option<ImageCircle>,
}

impl OnlineResult {
    /// How many parts the exposures fall into (`exposure_parts`; 1 for a linked video).
    pub fn exposure_part_count(&self) -> usize {
        self.exposure_parts
            .as_ref()
            .and_then(|l| l.iter().max())
            .map_or(1, |m| m + 1)
    }
}

/// Calibrate response, vignetting and exposures from an auto-exposure video.
pub fn photometric_online(
    frames: &[PhotoImage],
    params: &OnlineParams,
    progress: &dyn Progress,
) -> CoreResult<OnlineResult> {
    params.validate()?;
    if params.channels == Channels::Rgb {
        return Err(CoreError::param(
            "channels",
            "rgb needs colour frames; these are single-channel (grey): use luma",
        ));
    }
    let (w, h) = check_stack(frames, 3)?;
    let nf = frames.len();
    let seen = observe(frames, params, w, h, None, progress)?;
    if params.tracking_passes == 1 {
        return fit(nf, w, h, seen, params, GaugeContext::default(), progress);
    }
    let first = first_look(nf, (w, h), &seen, params, progress)?;
    let rm = ResponseMatch::new(&first);
    let next = match observe(frames, params, w, h, Some(&rm), progress) {
        Ok(next) => next,
        // Too few tracks in the second pass: the full fit of the first (said in
        // `tracking_passes`).
        Err(e) if response_match::recoverable(&e) => {
            return fit(nf, w, h, seen, params, GaugeContext::default(), progress);
        }
        Err(e) => return Err(e),
    };
    // Tracks that break in the second pass are refused like the first pass's: the first
    // pass's link across the break then rests on a few tracks the second could not follow
    // (the sweep's `eval7#4`: tied by the first pass, exposures 8.4 % off; per part, both
    // parts within 1.2 %), so falling back to it would return exposures without a scale.
    if params.broken_tracks == BrokenTracks::Refuse {
        linked::require_linked(&next.obs, nf)?;
    }
    let ctx = GaugeContext {
        prefer: Some(first.forward(0.5)),
        ..GaugeContext::default()
    };
    match fit(nf, w, h, next, params, ctx, progress) {
        Ok(result) => Ok(OnlineResult {
            tracking_passes: 2,
            ..result
        }),
        Err(e) if response_match::recoverable(&e) => {
            fit(nf, w, h, seen, params, GaugeContext::default(), progress)
        }
        Err(e) => Err(e),
    }
}

/// The first of two passes, cut to what the second takes from it: the response its matches
/// are re-aligned through and the gauge it keeps as a candidate. With the gauge profiled
/// (the default) that is the profile's fit on its subsample of the points; the first pass's
/// full refinement, centre and vignetting model would be thrown away (they took about 1.4 s
/// of 10.6 s on the sweep's `lens#7`).
pub(crate) fn first_look(
    nf: usize,
    (w, h): (usize, usize),
    seen: &Observations,
    params: &OnlineParams,
    progress: &dyn Progress,
) -> CoreResult<ResponseModel> {
    let (obs, n_points) = (&seen.obs, seen.n_points as usize);
    if params.broken_tracks == BrokenTracks::Refuse {
        linked::require_linked(obs, nf)?;
    }
    let huber = params.huber_levels / 255.0;
    // A fisheye's border is left out of the gauge's choice (see `circle::gauge_samples`).
    let interior = find_circle(params, &seen.mean_level, (w, h))
        .map(|c| circle::gauge_samples(&c, obs, &seen.pos));
    let obs = interior.as_deref().unwrap_or(obs);
    let mut state = start(nf, obs, n_points, huber, progress)?;
    let gauge = place_in_gauge(
        obs,
        n_points,
        &mut state,
        params,
        GaugeContext::default(),
        progress,
    )?;
    if params.gamma_gauge.is_some() {
        // No profile ran: fit the response at the given gauge.
        refine(obs, &joint_config(params, gauge), &mut state, progress)?;
    }
    Ok(ResponseModel::Emor { c: state.c })
}

/// Exposures, then the joint refinement, from the observations. `others`: further colour
/// channels at the same tracks that take part in choosing the gauge (`channels: rgb`).
pub(crate) fn fit(
    nf: usize,
    w: usize,
    h: usize,
    seen: Observations,
    params: &OnlineParams,
    gauge_ctx: GaugeContext<'_>,
    progress: &dyn Progress,
) -> CoreResult<OnlineResult> {
    let Observations {
        mut obs,
        n_points,
        used_tracks,
        mean_len,
        pos,
        mean_level,
        grad,
    } = seen;
    let parts = match params.broken_tracks {
        BrokenTracks::Refuse => {
            linked::require_linked(&obs, nf)?;
            None
        }
        BrokenTracks::PerPart => linked::part_labels(&obs, nf),
    };
    let huber = params.huber_levels / 255.0;
    let image_circle = find_circle(params, &mean_level, (w, h));
    // A fisheye's border is left out of the gauge's choice (see `circle::gauge_samples`).
    let interior = image_circle
        .as_ref()
        .map(|c| circle::gauge_samples(c, &obs, &pos));
    let gauge_obs = interior.as_deref().unwrap_or(&obs);
    let mut state = start(nf, gauge_obs, n_points as usize, huber, progress)?;
    let mut initial: Vec<f64> = state.log_e.iter().map(|l| l.exp()).collect();
    let gamma_gauge = place_in_gauge(
        gauge_obs,
        n_points as usize,
        &mut state,
        params,
        gauge_ctx,
        progress,
    )?;
    let joint = joint_config(params, gamma_gauge);
    let mut rep = refine(&obs, &joint, &mut state, progress)?;
    let center = center::resolve(
        params.vignette_center,
        params.fit_vignette,
        &mut obs,
        &pos,
        &mut state,
        (w, h),
        huber,
        progress,
    )?;
    let vig_stage::Stage {
        response,
        mut model,
        choice: mut vignette_choice,
        center,
    } = vig_stage::fit(
        params,
        image_circle.as_ref(),
        (&mut obs, &pos),
        &joint,
        (&mut state, &mut rep),
        center,
        (w, h),
        progress,
    )?;
    // A fisheye's border refitted with the scene's gradient alone in the samples' weights
    // (see `border`).
    if let Some(c) = image_circle.as_ref()
        && model.spline.is_some()
    {
        let input = border::BorderInputs {
            obs: &obs,
            pos: &pos,
            grad: &grad,
            mean_level: &mean_level,
        };
        if let Some(n) = border::refit(c, &input, (w, h), &joint, &mut state, progress)? {
            model.spline = state.spline.clone();
            vignette_choice.reason.push_str(&format!(
                "; refitted over the border (beyond {:.0} % of the circle's radius) with \
                 {n} samples weighted by the scene's gradient alone, not the fall-off's",
                100.0 * circle::GAUGE_DISC
            ));
        }
    }
    let monotone = response.is_monotone();
    // Without a circle found, a fisheye's tracks still stay inside its image circle, and the
    // polynomial extrapolated to the dark corners may turn negative there. Mask it from where
    // it falls to 1 % (the mask radius is in the model) instead of failing the job on an
    // unusable `vignette.png`.
    let vignette = params.fit_vignette.then(|| {
        if model.validate().is_err() {
            model.mask_below(0.01);
        }
        model
    });
    let mut exposure_ratios: Vec<f64> = state.log_e.iter().map(|l| l.exp()).collect();
    if let Some(labels) = &parts {
        linked::normalise_parts(&mut exposure_ratios, labels);
        linked::normalise_parts(&mut initial, labels);
    }
    Ok(OnlineResult {
        schema: PHOTOMETRIC_SCHEMA.to_string(),
        model: PhotometricModel::new(response, vignette),
        exposure_ratios,
        initial_exposure_ratios: initial,
        tracks: used_tracks,
        mean_track_length: mean_len,
        diagnostics: FitDiagnostics {
            residual_rms_levels: rep.rms * 255.0,
            observations: obs.len(),
            points: n_points as usize,
            iterations: rep.iterations,
            converged: rep.converged,
            monotone,
        },
        vignette_center: center,
        vignette_choice,
        channel_responses: None,
        tracking_passes: 1,
        exposure_parts: parts,
        measured_levels: levels::measured_levels(&obs),
        image_circle,
    })
}

/// The image circle of the video whose mean levels are `level` (see [`circle`]); `None` when
/// not asked for or not found.
pub(super) fn find_circle(
    params: &OnlineParams,
    level: &[f32],
    (w, h): (usize, usize),
) -> Option<ImageCircle> {
    if params.image_circle == CircleMode::Off || !params.fit_vignette {
        return None;
    }
    circle::detect(level, w, h)
}

/// The joint refinement of response, vignetting, exposures and radiances at gauge `f(0.5)`.
fn joint_config(params: &OnlineParams, gauge: f64) -> JointConfig {
    JointConfig {
        fit_response: true,
        fit_vignette: params.fit_vignette,
        fit_exposures: true,
        gamma_gauge: Some(gauge),
        huber: params.huber_levels / 255.0,
        max_iterations: params.max_iterations,
        label: "refine",
    }
}

/// Move the start into the gauge: the given `gamma_gauge`, or the profile's choice
/// ([`gauge::choose_gauge`]) with the profile's fit taken over. Returns `f(0.5)`.
fn place_in_gauge(
    obs: &[Obs],
    n_points: usize,
    state: &mut JointState,
    params: &OnlineParams,
    gauge_ctx: GaugeContext<'_>,
    progress: &dyn Progress,
) -> CoreResult<f64> {
    let Some(m) = params.gamma_gauge else {
        let choice = gauge::choose_gauge(
            obs,
            n_points,
            state,
            params.huber_levels / 255.0,
            params.fit_vignette,
            gauge_ctx,
            progress,
        )?;
        // Radiances of the points left out of the profile: the start's, moved to the
        // chosen gauge.
        gauge_start(state, choice.gauge);
        let every = n_points.div_ceil(gauge::PROFILE_POINTS).max(1);
        for (i, l) in state.log_l.iter_mut().enumerate() {
            if i % every == 0 {
                *l = choice.state.log_l[i];
            }
        }
        state.c = choice.state.c;
        state.v = choice.state.v;
        state.log_e = choice.state.log_e;
        return Ok(choice.gauge);
    };
    gauge_start(state, m);
    Ok(m)
}

/// The start of the joint fit: frame-to-frame exposure ratios under the mean response (a
/// linear problem), then a few Gauss-Newton steps on exposures and radiances only.
fn start(
    nf: usize,
    obs: &[Obs],
    n_points: usize,
    huber: f64,
    progress: &dyn Progress,
) -> CoreResult<JointState> {
    // Frame-to-frame exposure ratios under the mean response.
    let g0 = ResponseModel::default().inverse(4096);
    let lg = |o: &Obs| g0.eval(f64::from(o.value)).max(1e-6).ln();
    let mut ratios: Vec<Vec<f64>> = vec![Vec::new(); nf];
    for pair in obs.windows(2) {
        let (a, b) = (&pair[0], &pair[1]);
        if a.point == b.point && b.frame == a.frame + 1 && a.measured() && b.measured() {
            ratios[b.frame as usize].push(lg(b) - lg(a));
        }
    }
    let mut log_e = vec![0.0; nf];
    for k in 1..nf {
        let r = &mut ratios[k];
        let step = if r.is_empty() {
            0.0
        } else {
            r.sort_by(f64::total_cmp);
            r[r.len() / 2]
        };
        log_e[k] = log_e[k - 1] + step;
    }
    let mut log_l = vec![0.0; n_points];
    let mut acc = vec![(0.0, 0.0); n_points];
    for o in obs.iter().filter(|o| o.measured()) {
        let a = &mut acc[o.point as usize];
        a.0 += lg(o) - log_e[o.frame as usize];
        a.1 += 1.0;
    }
    for (l, a) in log_l.iter_mut().zip(&acc) {
        *l = a.0 / a.1;
    }
    let mut state = JointState::at_mean_response(log_e, log_l);
    progress.check()?;
    refine(
        obs,
        &JointConfig {
            fit_response: false,
            fit_vignette: false,
            fit_exposures: true,
            gamma_gauge: None,
            huber,
            max_iterations: 5,
            label: "exposures",
        },
        &mut state,
        progress,
    )?;
    Ok(state)
}
