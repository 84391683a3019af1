//! Per-channel responses of a colour camera, with exposure and vignetting shared.
//!
//! A colour camera applies one exposure to all channels and its lens vignettes them alike (to
//! first order: colour shading is left out), but each channel has its own response (the tone
//! curve after white balance and the colour matrix differ per channel). So the image formation
//! of Bergmann, Wang & Cremers (RA-L 2017, eq. 1) becomes `O_c = f_c(e_k · V(x) · L_{c,i})`,
//! with `e_k` and `V` shared and `f_c`, `L_c` per channel (the per-channel radiometric model
//! of Debevec & Malik, SIGGRAPH 1997, and of Grossberg & Nayar, PAMI 2004, who fit each
//! channel's response separately).
//!
//! Staged rather than joint:
//!
//! 1. Track on luma (Rec. 709 weights on the coded values), as for grey input: the tracker
//!    only needs texture, and luma has the best signal-to-noise ratio.
//! 2. Sample R, G and B at the same track positions (each channel's own clipping and gradient
//!    weights) and run the full fit (exposures, response, vignetting, centre) on **green**:
//!    luma is a blend of three different responses and so not of the form `f(e V L)`, while
//!    green is a single channel, carries most of the luma weight and has half of a Bayer
//!    sensor's sites (the least noisy channel). Red and blue take part in choosing the
//!    shared γ gauge only: each profiled gauge value adds their costs with green's exposures
//!    and vignetting held (`gauge`).
//! 3. Fit the red and blue responses (and their radiances) with the exposures and the
//!    vignetting held at green's values. With the exposures fixed there is no γ ambiguity left
//!    (`e^γ` is not free), so the red and blue responses come out in the same gauge as green's
//!    and the three curves are directly comparable (a neutral scene gives equal curves).
//!
//! A joint fit of all three would use red and blue for the exposures and vignetting too, but
//! green alone already determines them to ~1 % on the test sequences, the three-response
//! problem would triple the dense part of the normal equations, and a poor channel (e.g. blue
//! in tungsten light, nearly black) could pull the shared quantities; the staged fit keeps the
//! shared part identical to the grey fit of the green plane.

use serde::{Deserialize, Serialize};

use super::super::emor::EMOR_DIM;
use super::super::joint::{JointConfig, JointReport, JointState, Obs, refine};
use super::super::response::ResponseModel;
use super::super::spline::RadialSpline;
use super::super::{PhotoImage, check_stack};
use super::center::r2_at;
use super::circle;
use super::gauge::{GaugeContext, OtherChannel};
use super::pyramid::Level;
use super::response_match::{ResponseMatch, recoverable};
use super::{
    GRAD_HALF_WEIGHT, Observations, OnlineParams, OnlineResult, find_circle, first_look, fit,
    observe,
};
use crate::error::{CoreError, CoreResult};
use crate::progress::Progress;

/// Which responses are fitted.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub enum Channels {
    /// One response, for the luma of the frames (colour is reduced to luma).
    #[default]
    Luma,
    /// One response per colour channel (R, G, B), exposures and vignetting shared.
    Rgb,
}

/// The response of one colour channel.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct ChannelResponse {
    /// `r`, `g` or `b`.
    pub channel: String,
    /// The channel's response.
    pub response: ResponseModel,
    /// Its inverse, 256 levels (`pcalib.txt` / 255).
    pub inverse_256: Vec<f64>,
    /// RMS of the inlier residuals of this channel, 8-bit levels.
    pub residual_rms_levels: f64,
    /// Pixel samples of this channel used.
    pub observations: usize,
    /// Whether the fitted response is strictly increasing before any repair.
    pub monotone: bool,
}

/// Rec. 709 luma of an `[R, G, B]` frame on the coded values (what the `image` crate does for
/// grey conversion), at the planes' bit depth.
fn luma_of(f: &[PhotoImage; 3]) -> CoreResult<PhotoImage> {
    let [r, g, b] = f;
    if [g, b]
        .iter()
        .any(|p| p.width != r.width || p.height != r.height || p.max_level != r.max_level)
    {
        return Err(CoreError::input(
            "the R, G and B planes of a frame differ in size",
        ));
    }
    let data = r
        .data
        .iter()
        .zip(&g.data)
        .zip(&b.data)
        .map(|((&r, &g), &b)| {
            (0.2126 * f64::from(r) + 0.7152 * f64::from(g) + 0.0722 * f64::from(b)).round() as u16
        })
        .collect();
    PhotoImage::new(r.width, r.height, r.max_level, data)
}

/// Calibrate from colour frames (`[R, G, B]` planes each). With `channels: luma` the frames
/// are reduced to luma and fitted like grey frames; with `rgb` one response per channel is
/// fitted, exposures and vignetting shared (see the module notes).
pub fn photometric_online_rgb(
    frames: &[[PhotoImage; 3]],
    params: &OnlineParams,
    progress: &dyn Progress,
) -> CoreResult<OnlineResult> {
    params.validate()?;
    let mut luma = Vec::with_capacity(frames.len());
    for f in frames {
        progress.check()?;
        luma.push(luma_of(f)?);
    }
    if params.channels == Channels::Luma {
        return super::photometric_online(&luma, params, progress);
    }
    let (w, h) = check_stack(&luma, 3)?;
    // The tracks of the last pass (`tracking_passes`): a later pass re-aligns the luma matches
    // through the response of a luma fit of the previous pass.
    let mut seen = observe(&luma, params, w, h, None, progress)?;
    let mut passes = 1;
    for pass in 2..=params.tracking_passes {
        let again =
            first_look(frames.len(), (w, h), &seen, params, progress).and_then(|response| {
                let rm = ResponseMatch::new(&response);
                observe(&luma, params, w, h, Some(&rm), progress)
            });
        match again {
            Ok(next) => (seen, passes) = (next, pass),
            Err(e) if recoverable(&e) => break,
            Err(e) => return Err(e),
        }
    }
    drop(luma);
    let r = sample_channel(frames, 0, &seen, params, progress)?;
    let g = sample_channel(frames, 1, &seen, params, progress)?;
    let b = sample_channel(frames, 2, &seen, params, progress)?;
    // Red and blue take part in choosing the shared gauge (see `gauge`), with a fisheye's
    // border left out as for green (`circle::gauge_samples`).
    let image_circle = find_circle(params, &g.mean_level, (w, h));
    let interior = |o: &Observations| {
        image_circle
            .as_ref()
            .map(|c| circle::gauge_samples(c, &o.obs, &o.pos))
    };
    let (r_in, b_in) = (interior(&r), interior(&b));
    let others = [(&r, &r_in), (&b, &b_in)].map(|(o, inside)| OtherChannel {
        obs: inside.as_deref().unwrap_or(&o.obs),
        n_points: o.n_points as usize,
    });
    let mut result = fit(
        frames.len(),
        w,
        h,
        g,
        params,
        GaugeContext {
            others: &others,
            prefer: None,
        },
        progress,
    )?;
    result.tracking_passes = passes;
    let log_e: Vec<f64> = result.exposure_ratios.iter().map(|e| e.ln()).collect();
    let v = result.model.vignette.as_ref().map_or([0.0; 3], |m| m.v);
    let spline = result
        .model
        .vignette
        .as_ref()
        .and_then(|m| m.spline.clone());
    let green_c = match result.model.response {
        ResponseModel::Emor { c } => c,
        ResponseModel::Gamma { .. } => [0.0; EMOR_DIM],
    };
    let center = result.vignette_center.center;
    let rad = (w as f64 / 2.0).hypot(h as f64 / 2.0);
    let huber = params.huber_levels / 255.0;
    // Beyond a fisheye's image circle the vignetting is masked: green's samples there were
    // left out of the fit, and so are red's and blue's.
    let mask_r2 = result
        .model
        .vignette
        .as_ref()
        .and_then(|m| m.mask_radius)
        .filter(|_| result.image_circle.is_some())
        .map(|m| (m * m) as f32);
    let fit_other = |name: &str, mut seen: Observations| {
        for (o, &p) in seen.obs.iter_mut().zip(&seen.pos) {
            o.r2 = r2_at(p, center, rad);
            if mask_r2.is_some_and(|m| o.r2 > m) {
                o.weight = 0.0;
            }
        }
        fit_fixed(
            name,
            &seen,
            &log_e,
            (&v, spline.as_ref()),
            green_c,
            huber,
            params,
            progress,
        )
    };
    let red = fit_other("r", r)?;
    let blue = fit_other("b", b)?;
    let green = ChannelResponse {
        channel: "g".into(),
        response: result.model.response.clone(),
        inverse_256: result.model.inverse_256.clone(),
        residual_rms_levels: result.diagnostics.residual_rms_levels,
        observations: result.diagnostics.observations,
        monotone: result.diagnostics.monotone,
    };
    result.channel_responses = Some(vec![red, green, blue]);
    Ok(result)
}

/// Channel `c`'s samples at the luma tracks' positions: its own clipping test and gradient
/// weight; points left with fewer than two samples are dropped and the rest renumbered.
fn sample_channel(
    frames: &[[PhotoImage; 3]],
    c: usize,
    seen: &Observations,
    params: &OnlineParams,
    progress: &dyn Progress,
) -> CoreResult<Observations> {
    let mut by_frame: Vec<Vec<usize>> = vec![Vec::new(); frames.len()];
    for (i, o) in seen.obs.iter().enumerate() {
        if let Some(list) = by_frame.get_mut(o.frame as usize) {
            list.push(i);
        }
    }
    let clipped = |v: f32| f64::from(v) <= params.low_cut || f64::from(v) >= params.high_cut;
    let mut sampled: Vec<Option<Obs>> = vec![None; seen.obs.len()];
    for (k, idx) in by_frame.iter().enumerate() {
        progress.check()?;
        progress.report(
            "channels",
            (c * frames.len() + k) as u64,
            3 * frames.len() as u64,
        );
        if idx.is_empty() {
            continue;
        }
        let plane = &frames[k][c];
        let s = 1.0 / f32::from(plane.max_level);
        let level = Level::new(
            plane.width,
            plane.height,
            plane.data.iter().map(|&v| f32::from(v) * s).collect(),
        );
        for &i in idx {
            // Only where luma was measured: the clipping below is this channel's own test.
            if !seen.obs[i].measured() {
                continue;
            }
            let [x, y] = seen.pos[i];
            let Some([v, gx, gy]) = level.sample3(x, y) else {
                continue;
            };
            let (x0, y0) = (x.floor() as usize, y.floor() as usize);
            let i0 = y0 * level.w + x0;
            if clipped(v)
                || [i0, i0 + 1, i0 + level.w, i0 + level.w + 1]
                    .iter()
                    .any(|&j| level.value(j).is_none_or(clipped))
            {
                continue;
            }
            let g2 = (gx * gx + gy * gy) / (GRAD_HALF_WEIGHT * GRAD_HALF_WEIGHT);
            sampled[i] = Some(Obs {
                value: v,
                weight: 1.0 / (1.0 + g2),
                ..seen.obs[i]
            });
        }
    }
    let mut count = vec![0u32; seen.n_points as usize];
    for o in sampled.iter().flatten() {
        count[o.point as usize] += 1;
    }
    let mut remap = vec![u32::MAX; count.len()];
    let mut n_points = 0u32;
    for (p, &n) in count.iter().enumerate() {
        if n >= 2 {
            remap[p] = n_points;
            n_points += 1;
        }
    }
    let mut obs = Vec::with_capacity(sampled.len());
    let mut pos = Vec::with_capacity(sampled.len());
    for (o, &p) in sampled.into_iter().zip(&seen.pos) {
        if let Some(mut o) = o
            && remap[o.point as usize] != u32::MAX
        {
            o.point = remap[o.point as usize];
            obs.push(o);
            pos.push(p);
        }
    }
    const NAMES: [&str; 3] = ["red", "green", "blue"];
    if n_points < 20 || obs.len() < 200 {
        return Err(CoreError::input(format!(
            "the {} channel has only {n_points} unclipped tracked points ({} samples)",
            NAMES[c],
            obs.len()
        )));
    }
    Ok(Observations {
        obs,
        n_points,
        used_tracks: seen.used_tracks,
        mean_len: seen.mean_len,
        pos,
        mean_level: seen.mean_level.clone(),
        grad: Vec::new(),
    })
}

/// One channel's response (and radiances) with the exposures and vignetting fixed.
#[allow(clippy::too_many_arguments)]
fn fit_fixed(
    name: &str,
    seen: &Observations,
    log_e: &[f64],
    v: (&[f64; 3], Option<&RadialSpline>),
    green: [f64; EMOR_DIM],
    huber: f64,
    params: &OnlineParams,
    progress: &dyn Progress,
) -> CoreResult<ChannelResponse> {
    let (state, rep) = fit_with_shared(
        &seen.obs,
        seen.n_points as usize,
        log_e,
        v,
        &[[0.0; EMOR_DIM], green],
        huber,
        params.max_iterations,
        if name == "r" { "red" } else { "blue" },
        progress,
    )?;
    let response = ResponseModel::Emor { c: state.c };
    Ok(ChannelResponse {
        channel: name.into(),
        monotone: response.is_monotone(),
        inverse_256: response.inverse(256).values,
        response,
        residual_rms_levels: rep.rms * 255.0,
        observations: seen.obs.len(),
    })
}

/// A channel's response and radiances fitted with the exposures `log_e` and the vignetting
/// `v` (the polynomial, or the spline when there is one) held, from each response start in
/// `starts`, keeping the lowest robust cost.
///
/// Started from the mean response and from green's response (channels of one camera are
/// usually alike): with the exposures fixed the problem has no gauge freedom left, but LM from
/// a single start can still settle in a poor basin when the channel's curve is far from the
/// start (seen on the tuning sequences with the mean start).
#[allow(clippy::too_many_arguments)]
pub(super) fn fit_with_shared(
    obs: &[Obs],
    n_points: usize,
    log_e: &[f64],
    (v, spline): (&[f64; 3], Option<&RadialSpline>),
    starts: &[[f64; EMOR_DIM]],
    huber: f64,
    max_iterations: usize,
    label: &'static str,
    progress: &dyn Progress,
) -> CoreResult<(JointState, JointReport)> {
    let mut best: Option<(JointState, JointReport)> = None;
    for &c0 in starts {
        // Radiances from the start response: `ln L = ln f₀⁻¹(O) − ln e − ln V`, per point.
        let g0 = ResponseModel::Emor { c: c0 }.inverse(4096);
        let mut acc = vec![(0.0f64, 0.0f64); n_points];
        let held = JointState {
            c: c0,
            v: *v,
            spline: spline.cloned(),
            log_e: Vec::new(),
            log_l: Vec::new(),
        };
        for o in obs {
            let vg = held.vig(f64::from(o.r2));
            let Some(a) = acc.get_mut(o.point as usize) else {
                continue;
            };
            a.0 += g0.eval(f64::from(o.value)).max(1e-6).ln() - log_e[o.frame as usize] - vg.ln();
            a.1 += 1.0;
        }
        let mut state = JointState {
            log_e: log_e.to_vec(),
            log_l: acc.iter().map(|a| a.0 / a.1.max(1.0)).collect(),
            ..held
        };
        let rep = refine(
            obs,
            &JointConfig {
                fit_response: true,
                fit_vignette: false,
                fit_exposures: false,
                gamma_gauge: None,
                huber,
                max_iterations,
                label,
            },
            &mut state,
            progress,
        )?;
        if best.as_ref().is_none_or(|(_, b)| rep.cost < b.cost) {
            best = Some((state, rep));
        }
    }
    best.ok_or_else(|| CoreError::NoSolution("no response start given".into()))
}
