//! Tests of the colour (per-channel response) and vignetting-centre extensions on synthetic
//! auto-exposure videos with known truth (`synth::render_ae_video_rgb`, `AeVideo::vignette_shift`).
//!
//! The asserted tests use seeds 101.. (held out); `tune_*` (ignored) print the numbers on seeds
//! 1.. that the thresholds and constants were looked at with:
//! `cargo test -p caliper-core --lib online::feature_tests -- --ignored --nocapture`.

use super::{CenterMode, Channels, OnlineParams, photometric_online, photometric_online_rgb};
use crate::photometric::metrics::{exposure_error_pct, gamma_align, vignette_rmse};
use crate::photometric::synth::{AeVideo, SynthCamera, render_ae_video, render_ae_video_rgb};
use crate::photometric::{InverseResponse, OnlineResult, ResponseModel};

struct NoProgress;
impl crate::progress::Progress for NoProgress {
    fn report(&self, _: &str, _: u64, _: u64) {}
    fn is_canceled(&self) -> bool {
        false
    }
}

/// Three distinct monotone responses: a concave EMoR draw, the reference camera, a gamma curve.
fn rgb_responses() -> [ResponseModel; 3] {
    [
        ResponseModel::Emor {
            c: [1.5, 0.6, -0.3, 0.05],
        },
        ResponseModel::Emor {
            c: [3.0, -0.8, 0.2, -0.05],
        },
        ResponseModel::Gamma { gamma: 1.8 },
    ]
}

/// RMSE of `fit^alpha` against `truth` (both inverse responses normalised over levels
/// 1..254), i.e. `gamma_align` at a given exponent.
fn rmse_at(fit: &InverseResponse, truth: &InverseResponse, alpha: f64) -> f64 {
    let g: Vec<f64> = fit.resample(256).values[1..=254]
        .iter()
        .map(|v| v.max(0.0).powf(alpha))
        .collect();
    let (a, b) = (g[0], g[253]);
    let t = truth.normalized_1_254();
    (g.iter()
        .zip(&t)
        .map(|(x, y)| ((x - a) / (b - a) - y).powi(2))
        .sum::<f64>()
        / 254.0)
        .sqrt()
}

/// Scores of a colour run: per-channel response RMSE (own α and green's α), exposure error.
struct RgbScore {
    own: [f64; 3],
    shared: [f64; 3],
    alpha: [f64; 3],
    exposure_pct: f64,
    result: OnlineResult,
}

fn run_rgb(seed: u64, w: usize, h: usize, frames: usize) -> RgbScore {
    let cam = SynthCamera::reference(w, h, seed);
    let truth = rgb_responses();
    let seq = render_ae_video_rgb(&cam, &truth, [0.8, 1.0, 1.25], frames, &AeVideo::default());
    let p = OnlineParams {
        max_features: 150,
        channels: Channels::Rgb,
        ..OnlineParams::default()
    };
    let r = photometric_online_rgb(&seq.frames, &p, &NoProgress).expect("rgb fit");
    let ch = r.channel_responses.as_ref().expect("three responses");
    assert_eq!(ch.len(), 3);
    let fit: Vec<InverseResponse> = ch
        .iter()
        .map(|c| InverseResponse::new(c.inverse_256.clone()).expect("inverse"))
        .collect();
    let aligned: Vec<(f64, f64)> = (0..3)
        .map(|c| gamma_align(&fit[c], &truth[c].inverse(256)))
        .collect();
    let ag = aligned[1].0;
    let rms: Vec<f64> = ch.iter().map(|c| c.residual_rms_levels).collect();
    let score = RgbScore {
        own: [aligned[0].1, aligned[1].1, aligned[2].1],
        shared: [0, 1, 2].map(|c| rmse_at(&fit[c], &truth[c].inverse(256), ag)),
        alpha: [aligned[0].0, aligned[1].0, aligned[2].0],
        exposure_pct: exposure_error_pct(&r.exposure_ratios, &seq.exposures, ag),
        result: r,
    };
    eprintln!(
        "rgb seed {seed} {w}x{h}x{frames}: resp own {:.4?} at green α {:.4?} (α {:.3?}) exp {:.2}% \
         rms {:.2?}",
        score.own,
        score.shared,
        score.alpha,
        score.exposure_pct,
        rms
    );
    score
}

/// Scores of a grey run with the vignetting centre shifted by `shift` pixels.
struct CenterScore {
    fixed_vig: f64,
    auto_vig: f64,
    auto: OnlineResult,
}

fn run_center(seed: u64, w: usize, h: usize, frames: usize, shift: [f64; 2]) -> CenterScore {
    let cam = SynthCamera::reference(w, h, seed);
    let video = AeVideo {
        vignette_shift: shift,
        ..AeVideo::default()
    };
    let seq = render_ae_video(&cam, frames, &video);
    let truth = cam.response.inverse(256);
    let vig = |mode: CenterMode| {
        let p = OnlineParams {
            max_features: 150,
            vignette_center: mode,
            ..OnlineParams::default()
        };
        let r = photometric_online(&seq.frames, &p, &NoProgress).expect("fit");
        let fit = InverseResponse::new(r.model.inverse_256.clone()).expect("inverse");
        let (alpha, resp) = gamma_align(&fit, &truth);
        let m = r.model.vignette.as_ref().expect("vignette");
        let v = vignette_rmse(&m.map(), &seq.vignette_map, alpha);
        let e = exposure_error_pct(&r.exposure_ratios, &seq.exposures, alpha);
        eprintln!(
            "centre seed {seed} shift {shift:?} {mode:?}: resp {resp:.4} vig {v:.4} exp {e:.2}% \
             {:?}",
            r.vignette_center
        );
        (v, r)
    };
    let (fixed_vig, _) = vig(CenterMode::Fixed);
    let (auto_vig, auto) = vig(CenterMode::Auto);
    CenterScore {
        fixed_vig,
        auto_vig,
        auto,
    }
}

#[test]
#[ignore]
fn tune_rgb() {
    for seed in 1..=3 {
        run_rgb(seed, 160, 120, 80);
    }
}

#[test]
#[ignore]
fn tune_center() {
    for seed in 1..=3 {
        run_center(seed, 160, 120, 80, [12.8, 0.0]);
        run_center(seed, 160, 120, 80, [0.0; 2]);
    }
}
