//! Why over 600 lines: the diagnostics share one ground-truth observer and scorer, and about
//! half the file is the measured record of what each of them showed, kept beside the code.
//!
//! Diagnostics (ignored by default): the online fit fed with ground-truth observations, to tell
//! errors of the observations (tracks, sampling, noise) from errors of the fit.
//! `cargo test -p caliper-core --release --lib online::diag_tests -- --ignored --nocapture`
//! (env: `DIAG_LIN=1` also tracks on frames linearised by the true response, `DIAG_GT=1`
//! also fits ground-truth observations, `DIAG_CENSOR=1` keeps their clipped
//! samples as bounds, `DIAG_FREE=1` also fits the tracks with the gauge chosen from the data,
//! `DIAG_SCRIPTED=1` makes `diag_saturated` run scripted step / sweep exposure programs,
//! `DIAG_RM=1` also runs the second tracking pass, re-aligned through the first fit's response
//! and through the true one, with the position error of each;
//! `diag_truth_tests.rs` has the truth-start diagnostic).
//!
//! `diag_saturated` with `DIAG_SCRIPTED=1` (53–55 % of the pixels clipped, polynomial
//! vignetting; response / vignetting / exposure error with the common scale, clipped samples
//! censored): on the linear camera under steps, ground-truth observations give 0.0040 /
//! 0.0011 / 0.57 % (noise-free the same: the floor is EMoR-4's span), the tracks 0.0054 /
//! 0.0074 / 1.19 % and the same samples re-read at the true positions 0.0053 / 0.0072 /
//! 1.18 %. So neither the truncation nor track drift costs the vignetting there, but which
//! points are observed when: tracks under heavy clipping are short (samples at ages 0–9 / 10–19
//! / 20–29 / 30–39 frames: 34k / 15k / 7k / 4k), so few points cross enough radii. With the
//! gauge chosen from the data: 0.0020 / 0.0055 / 0.54 % (steps, linear) and 0.0004 / 0.0019 /
//! 0.56 % (sweep, mean EMoR response).
//!
//! Track re-association, tried and rejected (not in the code): a track lost by the tracker
//! (not one ended at `MAX_TRACK_AGE`) left a *ghost* carried by the median frame-to-frame
//! motion of its 6 nearest tracked neighbours for up to 20 frames; each frame a ghost was
//! re-aligned to its own birth template with its birth roll and zoom (`refine_to_template`,
//! the tracker's residual test), accepted within 1 px of its prediction and with a normalised
//! correlation ≥ 0.95 over the pixels unclipped in both, and continued as a new track with the
//! old point ids (one radiance unknown). On `diag_saturated` (`DIAG_SCRIPTED=1`, gauge at the
//! truth; response / vignetting / exposure with the common scale), reviving anywhere ≥ 3 px
//! from a live track, or only in empty re-detection cells: steps (linear) 0.0054 / 0.0074 /
//! 1.19 % → 0.0065 / 0.0048 / 1.40 % and 0.0061 / 0.0050 / 1.23 %; sweep (mean response)
//! 0.0004 / 0.0020 / 0.56 % → 0.0007 / 0.0007 / 0.41 % and 0.0004 / 0.0008 / 0.45 %. So the
//! span of the points is what the vignetting lacked. But most points were lost and re-found
//! again and again (31k / 37k merges against 2.4k / 1.9k fresh tracks anywhere, 24k / 26k in
//! cells: the pyramid match fails where a level-0 re-alignment from the neighbours' motion
//! succeeds), and the revived positions are worse: drift p90 0.24 px → 0.31–0.51 px, growing
//! with the span. On the sweep's tuning split (baseline 11/12 within the targets, medians
//! 0.0009 / 0.0018 / 0.42 %, CPU median 5.9 s per case):
//! * anywhere: accuracy targets met on 10/12 (tuning#3: vignetting 0.0111, exposure 1.85 %),
//!   medians 0.0021 / 0.0022 / 0.66 %, CPU median 8.4 s, worst 10.5 s (more tracks and samples);
//! * in empty cells: 9/12 (tuning#1 response 0.0056, tuning#4 0.0061), 0.0021 / 0.0024 /
//!   0.66 %, CPU 7.0 s;
//! * in cells, strict (correlation ≥ 0.99, ≤ 0.5 px, ≤ 10 frames): 9/12 (tuning#1 response
//!   0.0066, tuning#4 0.0054), 0.0014 / 0.0014 / 0.40 %, CPU 6.4 s;
//! * strict, and only ghosts whose predicted 9×9 patch is at least a quarter clipped (lost to
//!   clipping): 10/12, 0.0017 / 0.0022 / 0.52 %, CPU 5.7 s. Cases without such losses are
//!   unchanged; the two most clipped tuning cases gain (tuning#0 vignetting 0.0013 → 0.0004,
//!   tuning#5 0.0013 → 0.0003), but tuning#4 (1.5 % clipped) loses (response 0.0008 → 0.0055,
//!   exposure 0.25 → 1.02 %).
//!
//! `diag_discs` (the sweep's `scenes#1`, dead leaves, 15 % clipped, polynomial vignette;
//! response / vignetting / exposure error with the common scale): the tracks with the gauge
//! at the truth give 0.0007 / 0.0039 / 0.77 %, but with the gauge chosen from the data
//! 0.0127 / 0.0050 / 3.14 % (α 1.30): the observations were good enough, the profile's choice
//! was not (`gauge.rs`: its grid was ragged; with the two cheapest minima polished, 0.0010 /
//! 0.0057 / 0.75 %, not kept for want of a held-out gain). The residual RMS is 2.75 levels
//! against 1.97 on the waves scene (`DIAG_WAVES=1`), and ground-truth samples read
//! bilinearly at the true positions (`DIAG_GT=1`, unweighted)
//! are far off on this scene (0.040 / 0.040 / 10.9 % at the true gauge, against 0.0033 /
//! 0.0032 / 1.0 % on waves): interpolating output values across a sharp edge mixes `f(a)` and
//! `f(b)`, which is not `f` of the mixed radiance. Dropping samples whose four source pixels
//! spread more than 0.05 (full scale 1) brings the residual RMS to 1.39 and, with the truth's
//! gauge, 0.0002 / 0.0013 / 0.42 %; over the sweep it was not kept (see
//! `examples/photometric_sweep.rs`).
//!
//! The held-out sweep misses of `eval4` (`diag_eval4_1`, `diag_eval4_3`, run 2026-12-05 after
//! the split's one sweep run; gauge at the truth; response / vignetting / exposure error with
//! the common scale): the tracks give `eval4#1` 0.0022 / **0.0158** / 1.42 % and `eval4#3`
//! 0.0018 / 0.0043 / **2.24 %**; the same samples re-read at the true positions give 0.0005 /
//! 0.0052 / 0.54 % and 0.0004 / 0.0020 / 0.27 %, both within every target. Ground-truth
//! samples with the true noise and clipping (`eval4#3`, `DIAG_GT=1 DIAG_CENSOR=1`, `Exact`):
//! 0.0003 / 0.0003 / 0.13 %. So the fit is sound and so is the choice of samples; what
//! misses is where the tracker puts them: on `eval4#1` (±1-stop steps) the position error is
//! already 0.18 px median, 0.60 px p90 at ages 0–9 and does not grow with age (0.21 / 0.52 at
//! 30–39), a per-frame error of the gain-robust match under exposure changes rather than
//! drift. Tracked instead on the frames linearised by the true response (`DIAG_LIN=1`: an
//! exposure change is then a pure gain, which the gain-robust match models exactly) and
//! sampled from the frames as recorded, both meet every target: `eval4#1` 0.0006 / 0.0024 /
//! 0.59 %, `eval4#3` 0.0004 / 0.0008 / 0.63 %. Linearised by the response of a first default
//! fit instead (what a second pass of the fit would have), then fitted the default way (gauge
//! from the data): `eval4#1` 0.0046 / 0.0077 / 1.42 %, `eval4#3` 0.0007 / 0.0003 / 0.65 %,
//! both within every target (at the true gauge 0.0010 / 0.0021 / 0.58 % and 0.0007 / 0.0003 /
//! 0.65 %). The lead, not yet in the fit: that second pass (the joint tracking and calibration
//! of Kim & Pollefeys, PAMI 2008); it must be chosen on the tuning splits, checked on a fresh
//! held-out set, and fit the 10 s budget (one more tracking pass and fit).
//!
//! A false or imprecise re-association ties two radiances; the tuning split says the accepted
//! ones still include such cases. Untried: checking a re-found ghost forward-backward or over
//! a few frames before merging, or merging only the centre sample.

use super::{GaugeContext, Observations, OnlineParams, fit, observe};
use crate::photometric::joint::{Censor, Obs};
use crate::photometric::metrics::{
    exposure_error_common_pct, exposure_error_pct, gamma_align, vignette_rmse,
};
use crate::photometric::response::interp_table;
use crate::photometric::synth::{
    AeVideo, ExposureProgram, Rng, SynthCamera, Texture, clipped_fraction, render_ae_video,
};
use crate::photometric::{ResponseModel, VignetteModel};

struct NoProgress;
impl crate::progress::Progress for NoProgress {
    fn report(&self, _: &str, _: u64, _: u64) {}
    fn is_canceled(&self) -> bool {
        false
    }
}

/// Frame `k`'s pose: pixel (relative to the centre) → world.
fn pose(video: &AeVideo, k: usize) -> (f64, f64, f64, f64) {
    let t = k as f64;
    let (tx, ty) = (
        200.0 + 2.0 * video.speed * t,
        300.0 + 25.0 * (0.02 * video.speed * t).sin(),
    );
    let th = 0.15 * video.turn * (0.013 * t).sin();
    let sc = 1.0 + 0.15 * video.turn * (0.017 * t).sin();
    (th.cos() * sc, th.sin() * sc, tx, ty)
}

fn to_world(video: &AeVideo, w: f64, h: f64, k: usize, x: f64, y: f64) -> (f64, f64) {
    let (c, s, tx, ty) = pose(video, k);
    let (px, py) = (x - w / 2.0, y - h / 2.0);
    (c * px - s * py + tx, s * px + c * py + ty)
}

fn to_image(video: &AeVideo, w: f64, h: f64, k: usize, u: f64, v: f64) -> (f64, f64) {
    let (c, s, tx, ty) = pose(video, k);
    let n = c * c + s * s;
    let (du, dv) = (u - tx, v - ty);
    (
        w / 2.0 + (c * du + s * dv) / n,
        h / 2.0 + (-s * du + c * dv) / n,
    )
}

fn bilinear(im: &crate::photometric::PhotoImage, x: f64, y: f64) -> Option<f64> {
    if !(0.0..(im.width - 1) as f64).contains(&x) || !(0.0..(im.height - 1) as f64).contains(&y) {
        return None;
    }
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (fx, fy) = (x - x0 as f64, y - y0 as f64);
    Some(
        (im.get(x0, y0) * (1.0 - fx) + im.get(x0 + 1, y0) * fx) * (1.0 - fy)
            + (im.get(x0, y0 + 1) * (1.0 - fx) + im.get(x0 + 1, y0 + 1) * fx) * fy,
    )
}

/// Track drift against the truth (from each point's first observation) and the observations
/// re-sampled at the true positions.
fn drift(
    video: &AeVideo,
    frames: &[crate::photometric::PhotoImage],
    seen: &Observations,
) -> Observations {
    let (w, h) = (frames[0].width as f64, frames[0].height as f64);
    let mut by_age: Vec<Vec<f64>> = vec![Vec::new(); 8];
    let mut obs = Vec::new();
    let mut first = (u32::MAX, 0.0, 0.0, 0usize);
    for (o, p) in seen.obs.iter().zip(&seen.pos) {
        if o.point != first.0 {
            let (u, v) = to_world(
                video,
                w,
                h,
                o.frame as usize,
                f64::from(p[0]),
                f64::from(p[1]),
            );
            first = (o.point, u, v, o.frame as usize);
        }
        let (x, y) = to_image(video, w, h, o.frame as usize, first.1, first.2);
        let d = ((x - f64::from(p[0])).powi(2) + (y - f64::from(p[1])).powi(2)).sqrt();
        let age = (o.frame as usize - first.3) / 10;
        by_age[age.min(7)].push(d);
        if !o.measured() {
            obs.push(*o);
        } else if let Some(val) = bilinear(&frames[o.frame as usize], x, y)
            && val > 3.0 / 255.0
            && val < 250.0 / 255.0
        {
            obs.push(Obs {
                value: val as f32,
                ..*o
            });
        }
    }
    let txt: Vec<String> = by_age
        .iter_mut()
        .enumerate()
        .map(|(i, v)| {
            v.sort_by(f64::total_cmp);
            let q = |f: f64| {
                v.get((f * v.len() as f64) as usize)
                    .copied()
                    .unwrap_or(f64::NAN)
            };
            format!(
                "age{}0: n {} med {:.3} p90 {:.3}",
                i,
                v.len(),
                q(0.5),
                q(0.9)
            )
        })
        .collect();
    eprintln!("   drift px: {}", txt.join(" | "));
    if std::env::var_os("DIAG_FRAMES").is_some() {
        // Per frame: observations, their median value and how many points they share with
        // later frames.
        for f in 0..8u32 {
            let mut v: Vec<f32> = obs
                .iter()
                .filter(|o| o.frame == f && o.measured())
                .map(|o| o.value)
                .collect();
            v.sort_by(f32::total_cmp);
            let pts: std::collections::BTreeSet<u32> = obs
                .iter()
                .filter(|o| o.frame == f)
                .map(|o| o.point)
                .collect();
            let later = obs
                .iter()
                .filter(|o| o.frame > f && pts.contains(&o.point))
                .count();
            eprintln!(
                "   frame {f}: obs {} points {} median {:.3} p10 {:.3} p90 {:.3} later obs {later}",
                v.len(),
                pts.len(),
                v.get(v.len() / 2).copied().unwrap_or(f32::NAN),
                v.get(v.len() / 10).copied().unwrap_or(f32::NAN),
                v.get(9 * v.len() / 10).copied().unwrap_or(f32::NAN),
            );
        }
    }
    with_obs(seen, obs)
}

/// The default first pass's observations.
pub(super) fn tracked(
    frames: &[crate::photometric::PhotoImage],
    w: usize,
    h: usize,
) -> Observations {
    observe(frames, &OnlineParams::default(), w, h, None, &NoProgress).unwrap()
}

/// `seen` with other samples of the same points.
fn with_obs(seen: &Observations, obs: Vec<Obs>) -> Observations {
    Observations {
        obs,
        n_points: seen.n_points,
        used_tracks: seen.used_tracks,
        mean_len: seen.mean_len,
        pos: Vec::new(),
        mean_level: Vec::new(),
        grad: Vec::new(),
    }
}

/// A sample value as the fit sees it: clipped values become one-sided bounds at the cut.
fn censored(val: f64) -> (f64, Censor) {
    if val <= 3.0 / 255.0 {
        (3.0 / 255.0, Censor::AtMost)
    } else if val >= 250.0 / 255.0 {
        (250.0 / 255.0, Censor::AtLeast)
    } else {
        (val, Censor::Exact)
    }
}

#[derive(Clone, Copy, PartialEq, Debug)]
enum Mode {
    Ideal,
    Exact,
    Bilinear,
}

fn gt_obs(
    cam: &SynthCamera,
    video: &AeVideo,
    exposures: &[f64],
    frames: &[crate::photometric::PhotoImage],
    mode: Mode,
) -> Observations {
    let tex = Texture::new(cam.seed, video.mid, video.stops);
    let vm = cam.vignette_model();
    let fwd = cam.response.forward_table();
    let (w, h) = (cam.width as f64, cam.height as f64);
    let mut rng = Rng::new(77);
    let mut obs = Vec::new();
    let mut np = 0u32;
    let nf = exposures.len();
    let span = 2.0 * video.speed * nf as f64;
    for _ in 0..6000 {
        let (u, v) = (
            200.0 - w / 2.0 + (span + w) * rng.uniform(),
            300.0 - h / 2.0 - 20.0 + (h + 40.0) * rng.uniform(),
        );
        let l = tex.radiance(u, v);
        let mut n = 0;
        let start = obs.len();
        for k in 0..nf {
            let t = k as f64;
            let (tx, ty) = (
                200.0 + 2.0 * video.speed * t,
                300.0 + 25.0 * (0.02 * video.speed * t).sin(),
            );
            let th = 0.15 * video.turn * (0.013 * t).sin();
            let sc = 1.0 + 0.15 * video.turn * (0.017 * t).sin();
            let (du, dv) = (u - tx, v - ty);
            let (c, s) = (th.cos() / sc, th.sin() / sc);
            let (x, y) = (w / 2.0 + c * du + s * dv, h / 2.0 - s * du + c * dv);
            if !(2.0..w - 3.0).contains(&x) || !(2.0..h - 3.0).contains(&y) {
                continue;
            }
            let e = 10.0 * exposures[k] * vm.eval(x, y) * l;
            let val = match mode {
                Mode::Ideal => interp_table(&fwd, e.clamp(0.0, 1.0)),
                Mode::Exact => {
                    let sigma = (cam.shot * e + cam.read * cam.read).sqrt();
                    let e = (e + sigma * rng.normal()).clamp(0.0, 1.0);
                    (interp_table(&fwd, e) * 255.0).round() / 255.0
                }
                Mode::Bilinear => {
                    let im = &frames[k];
                    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
                    let (fx, fy) = (x - x0 as f64, y - y0 as f64);
                    (im.get(x0, y0) * (1.0 - fx) + im.get(x0 + 1, y0) * fx) * (1.0 - fy)
                        + (im.get(x0, y0 + 1) * (1.0 - fx) + im.get(x0 + 1, y0 + 1) * fx) * fy
                }
            };
            // `DIAG_CENSOR=1`: clipped values stay as one-sided bounds at the cut.
            let (value, censor) = censored(val);
            if censor != Censor::Exact && std::env::var_os("DIAG_CENSOR").is_none() {
                continue;
            }
            obs.push(Obs {
                point: np,
                frame: k as u32,
                r2: vm.r2(x, y) as f32,
                value: value as f32,
                weight: 1.0,
                censor,
            });
            n += usize::from(censor == Censor::Exact);
        }
        if n >= 2 {
            np += 1;
        } else {
            obs.truncate(start);
        }
    }
    Observations {
        obs,
        n_points: np,
        used_tracks: np as usize,
        mean_len: 0.0,
        pos: Vec::new(),
        mean_level: Vec::new(),
        grad: Vec::new(),
    }
}

fn run(label: &str, response: ResponseModel, video: AeVideo, vig: [f64; 3]) {
    run_seeded(label, response, video, vig, 3);
}

/// [`run`] with the camera's seed (scene texture and noise), to replay a sweep case.
fn run_seeded(label: &str, response: ResponseModel, video: AeVideo, vig: [f64; 3], seed: u64) {
    let (w, h, nf) = (320, 240, 200);
    let cam = SynthCamera {
        width: w,
        height: h,
        response,
        vignette: vig,
        shot: 2e-4,
        read: 1.5e-3,
        sixteen_bit: false,
        seed,
    };
    let seq = render_ae_video(&cam, nf, &video);
    let truth_m = if std::env::var_os("DIAG_NOCLAMP").is_some() {
        cam.response.forward(0.5)
    } else {
        cam.response.forward(0.5).clamp(0.06, 0.94)
    };
    // The rendered law (the camera's polynomial unless the video sets another).
    let truth_vig = seq.vignette_map.clone();
    let score = |name: &str, seen: Observations, gauge: Option<f64>| {
        let p = OnlineParams {
            gamma_gauge: gauge,
            max_iterations: std::env::var("DIAG_ITERS")
                .ok()
                .and_then(|v| v.parse().ok())
                .unwrap_or(40),
            ..OnlineParams::default()
        };
        let nobs = seen.obs.len();
        let r = fit(nf, w, h, seen, &p, GaugeContext::default(), &NoProgress).unwrap();
        let fitinv = crate::photometric::InverseResponse {
            values: r.model.inverse_256.clone(),
        };
        let (alpha, resp) = gamma_align(&fitinv, &cam.response.inverse(256));
        let vmap = r
            .model
            .vignette
            .as_ref()
            .map(VignetteModel::map)
            .unwrap_or_default();
        let verr = vignette_rmse(&vmap, &truth_vig, alpha);
        let eerr = exposure_error_pct(&r.exposure_ratios, &seq.exposures, alpha);
        let ecom = exposure_error_common_pct(&r.exposure_ratios, &seq.exposures, alpha);
        let d: Vec<f64> = r
            .exposure_ratios
            .iter()
            .zip(&seq.exposures)
            .map(|(f, t)| alpha * f.ln() - t.ln())
            .collect();
        let mean = d.iter().sum::<f64>() / d.len() as f64;
        let first: Vec<String> = d
            .iter()
            .take(10)
            .map(|x| format!("{:+.1}", 100.0 * (x - mean).exp_m1()))
            .collect();
        eprintln!(
            "{label:12} {name:9} gauge {gauge:?} obs {nobs:7} resp {resp:.4} vig {verr:.4} exp {eerr:6.2}% common {ecom:5.2}% alpha {alpha:.3} it {} rms {:.2} first {}",
            r.diagnostics.iterations,
            r.diagnostics.residual_rms_levels,
            first.join(" ")
        );
    };
    let (lo, hi) = seq
        .exposures
        .iter()
        .fold((9.0f64, 0.0f64), |a, &e| (a.0.min(e), a.1.max(e)));
    let sat = clipped_fraction(&seq.frames);
    if std::env::var_os("DIAG_FRAMES").is_some() {
        eprintln!("   exposures {:.3?}", &seq.exposures[..12]);
    }
    eprintln!(
        "{label}: truth f(.5) {:.3}, exposures {lo:.3}..{hi:.3}, {:.1} % clipped",
        cam.response.forward(0.5),
        100.0 * sat
    );
    if std::env::var_os("DIAG_GT").is_some() {
        for mode in [Mode::Ideal, Mode::Exact, Mode::Bilinear] {
            for g in [Some(truth_m), Some(0.5)] {
                score(
                    &format!("{mode:?}"),
                    gt_obs(&cam, &video, &seq.exposures, &seq.frames, mode),
                    g,
                );
            }
        }
    }
    let seen = tracked(&seq.frames, w, h);
    let fixed = drift(&video, &seq.frames, &seen);
    if std::env::var_os("DIAG_FREE").is_some() {
        // The default: the gauge chosen from the data (`gauge.rs`).
        score("tracks", seen.clone(), None);
    }
    score("tracks", seen, Some(truth_m));
    score("truepos", fixed, Some(truth_m));
    if std::env::var_os("DIAG_RM").is_some() {
        // The second pass as shipped: matches re-aligned through the first fit's response.
        let p = OnlineParams::default();
        let first = tracked(&seq.frames, w, h);
        let r = fit(nf, w, h, first, &p, GaugeContext::default(), &NoProgress).unwrap();
        let rm = super::response_match::ResponseMatch::new(&r.model.response);
        let seen = observe(&seq.frames, &p, w, h, Some(&rm), &NoProgress).unwrap();
        let _ = drift(&video, &seq.frames, &seen);
        score("rmatch", seen.clone(), Some(truth_m));
        score("rmatch", seen, None);
        let truth = super::response_match::ResponseMatch::new(&cam.response);
        let seen = observe(&seq.frames, &p, w, h, Some(&truth), &NoProgress).unwrap();
        let _ = drift(&video, &seq.frames, &seen);
        score("rm-truth", seen, Some(truth_m));
    }
    if std::env::var_os("DIAG_LIN").is_some() {
        // Tracked on the frames linearised by the true response (an exposure change is then a
        // pure gain), sampled from the frames as recorded.
        let lin = linearised(&cam.response.inverse(256).values, &seq.frames);
        let seen = tracked(&lin, w, h);
        score("lintrack", reread(&seq.frames, &seen), Some(truth_m));
        // The same with the response of a first default fit (what a second pass would have).
        let first = tracked(&seq.frames, w, h);
        let r = fit(
            nf,
            w,
            h,
            first,
            &OnlineParams::default(),
            GaugeContext::default(),
            &NoProgress,
        )
        .unwrap();
        let lin = linearised(&r.model.inverse_256, &seq.frames);
        let seen = tracked(&lin, w, h);
        let again = reread(&seq.frames, &seen);
        score("linfit", again.clone(), Some(truth_m));
        score("linfit", again, None);
    }
}

/// The frames mapped through an inverse response `inv` (256 levels; 16-bit, irradiance 0–1).
fn linearised(
    inv: &[f64],
    frames: &[crate::photometric::PhotoImage],
) -> Vec<crate::photometric::PhotoImage> {
    frames
        .iter()
        .map(|f| {
            let data = f
                .data
                .iter()
                .map(|&v| (inv[usize::from(v.min(255))].clamp(0.0, 1.0) * 65535.0).round() as u16)
                .collect();
            crate::photometric::PhotoImage::new(f.width, f.height, 65535, data).unwrap()
        })
        .collect()
}

/// `seen`'s samples re-read from `frames` at their tracked positions (clipped values as
/// bounds at the cut, as [`gt_obs`] does).
fn reread(frames: &[crate::photometric::PhotoImage], seen: &Observations) -> Observations {
    let mut obs = Vec::new();
    for (o, p) in seen.obs.iter().zip(&seen.pos) {
        let Some(val) = bilinear(&frames[o.frame as usize], f64::from(p[0]), f64::from(p[1]))
        else {
            continue;
        };
        let (value, censor) = censored(val);
        obs.push(Obs {
            value: value as f32,
            censor,
            ..*o
        });
    }
    with_obs(seen, obs)
}

#[test]
#[ignore]
fn diag_ground_truth_observations() {
    let ae = AeVideo {
        program: ExposureProgram::AutoExposure {
            target: 0.42,
            gain: 0.5,
            flicker: 0.05,
        },
        mid: 0.05,
        stops: 6.5,
        ..AeVideo::default()
    };
    run(
        "mean-emor",
        ResponseModel::Emor { c: [0.0; 4] },
        ae.clone(),
        [-0.35, 0.05, 0.0],
    );
    run(
        "concave",
        ResponseModel::Emor {
            c: [-1.55, 0.13, 0.98, -0.12],
        },
        ae.clone(),
        [-0.35, 0.05, 0.0],
    );
    run(
        "gamma2.4",
        ResponseModel::Gamma { gamma: 2.4 },
        ae,
        [-0.35, 0.05, 0.0],
    );
}

/// The sweep's held-out `eval4#3` (f(0.5) = 0.73, a ±1.46-stop sweep, the wave texture, 32 %
/// clipped; exposure error 2.33 % as shipped, 2.24 % from the truth: `diag_truth_tests.rs`).
#[test]
#[ignore]
fn diag_eval4_3() {
    let (cam, video) = super::diag_truth_tests::eval4_3();
    run_seeded("eval4#3", cam.response, video, cam.vignette, cam.seed);
}

/// The sweep's held-out `eval4#1` (f(0.5) = 0.86, ±1-stop steps, the wave texture, a cos⁴
/// vignette, 35 % clipped; vignette RMSE 0.0201 as shipped). Ground-truth observations
/// (`DIAG_GT=1`) assume the camera's polynomial, so they do not apply to this law.
#[test]
#[ignore]
fn diag_eval4_1() {
    let (cam, video) = super::diag_truth_tests::eval4_1();
    run_seeded("eval4#1", cam.response, video, cam.vignette, cam.seed);
}

/// A heavily saturated auto-exposure video (about half the pixels clipped), to tell the
/// truncation of samples at the clip level from tracker errors.
#[test]
#[ignore]
fn diag_saturated() {
    let ae = AeVideo {
        program: ExposureProgram::AutoExposure {
            target: 0.62,
            gain: 0.5,
            flicker: 0.05,
        },
        mid: 0.05,
        stops: 9.0,
        ..AeVideo::default()
    };
    let vig = [-0.35, 0.05, 0.0];
    let mean = ResponseModel::Emor { c: [0.0; 4] };
    let linear = ResponseModel::Gamma { gamma: 1.0 };
    let mut cases = vec![
        ("sat-mean", mean.clone(), ae.clone()),
        ("sat-linear", linear.clone(), ae.clone()),
    ];
    if std::env::var_os("DIAG_TRANSIENT").is_some() {
        // A start far above the controller's target: the exposure falls ~20× in the first
        // frames (as the sweep's tuning#3, whose response this is).
        let fast = AeVideo {
            program: ExposureProgram::AutoExposure {
                target: 0.3,
                gain: 0.6,
                flicker: 0.03,
            },
            mid: 0.09,
            stops: 8.0,
            ..AeVideo::default()
        };
        let concave = ResponseModel::Emor {
            c: [-1.55, 0.13, 0.98, -0.12],
        };
        cases.push(("transient", concave, fast));
    }
    if std::env::var_os("DIAG_SCRIPTED").is_some() {
        // Scripted exposure programs (not reacting to the clipping), as saturated, instead.
        cases.clear();
        let steps = AeVideo {
            program: ExposureProgram::Steps {
                stops: 1.0,
                hold: 12,
            },
            mid: 0.08,
            stops: 8.0,
            ..AeVideo::default()
        };
        let sweep = AeVideo {
            program: ExposureProgram::Sweep {
                stops: 1.0,
                period: 80.0,
                flicker: 0.03,
            },
            ..steps.clone()
        };
        cases.push(("steps-lin", linear.clone(), steps.clone()));
        cases.push(("sweep-mean", mean.clone(), sweep.clone()));
    }
    if std::env::var_os("DIAG_NOTURN").is_some() {
        let still = AeVideo { turn: 0.0, ..ae };
        cases.push(("sat-mean-t0", mean, still.clone()));
        cases.push(("sat-lin-t0", linear, still));
    }
    for (label, response, video) in cases {
        run(label, response, video, vig);
    }
}

/// The sweep's `scenes` split (dead leaves) fails where the other scenes pass; its
/// `scenes#1` (14.7 % clipped, response 0.0119, exposures 3.0 %) rebuilt with a polynomial
/// vignette, to tell the observations from the fit there.
#[test]
#[ignore]
fn diag_discs() {
    use crate::photometric::synth::SceneForm;
    const VIGNETTE: [f64; 3] = [-0.4965, -0.048, -0.0298];
    let video = AeVideo {
        program: ExposureProgram::Steps {
            stops: 1.35,
            hold: 13,
        },
        scene: SceneForm::Discs,
        mid: 0.0316,
        stops: 5.89,
        speed: 0.83,
        ..AeVideo::default()
    };
    let response = ResponseModel::Emor {
        c: [1.947, -0.433, -0.382, -0.221],
    };
    run("discs-steps", response.clone(), video.clone(), VIGNETTE);
    if std::env::var_os("DIAG_WAVES").is_some() {
        // The same camera and program on the tuning scene.
        let waves = AeVideo {
            scene: SceneForm::Waves,
            ..video
        };
        run("waves-steps", response, waves, VIGNETTE);
    }
}

/// The sweep's tuning#1 (f(0.5) = 0.97, auto exposure, the wave texture; printed by the sweep
/// with `SWEEP_DEBUG=1`). With `DIAG_RM=1` (2026-12-05): the second pass lowers the position
/// error from 0.224 to 0.166 px median (p90 0.747 → 0.575) at ages 0–9, and the true response
/// does no better (0.164 px), yet with the gauge chosen again the response comes out at 0.0183
/// against 0.0034 with one pass: this camera's gauge profile is flat (`gauge.rs`) and the new
/// samples tip it from 0.914 to 0.870. At the true gauge (clamped to 0.94) neither pass fits
/// (0.046): EMoR-4 does not follow this curve in that gauge.
#[test]
#[ignore]
fn diag_tuning_1() {
    let video = AeVideo {
        program: ExposureProgram::AutoExposure {
            target: 0.3208212121055762,
            gain: 0.5651694086635342,
            flicker: 0.07703433542105612,
        },
        scene: crate::photometric::synth::SceneForm::Waves,
        mid: 0.04176286934303376,
        stops: 6.139768597110924,
        speed: 0.9694629647424873,
        ..AeVideo::default()
    };
    run_seeded(
        "tuning#1",
        ResponseModel::Emor {
            c: [-6.0, 0.5, 0.3, 0.0],
        },
        video,
        [
            -0.2556901693383523,
            0.04875236045462812,
            -0.030235086419528226,
        ],
        1,
    );
}

/// The sweep's tuning#6 (f(0.5) = 0.95, the wave texture, auto-exposure over 0.05–1.00):
/// where its samples lose the response, tracker or fit (`DIAG_GT=1`, `DIAG_RM=1`;
/// `DIAG_NOCLAMP=1` scores at the true gauge 0.955, beyond what `gamma_gauge` accepts;
/// `DIAG_FRAMES=1` prints the first frames' samples). Measured 2026-12-06: ideal samples at
/// every pixel give the truth exactly at 0.955, but at 0.94 response 0.059 / vignette 0.060
/// at a residual of 0.34 levels (converged: `DIAG_ITERS=300` changes nothing); the tracks'
/// samples at true positions (`truepos`) at 0.955 give 0.048 / 0.22, frame 0's exposure 117 %
/// off (27 measured samples in that frame, the brightest of the auto-exposure's transient,
/// against about 110 in the next frames); the one-pass fit with its own gauge 0.044 / 0.085.
#[test]
#[ignore]
fn diag_tuning6() {
    let (cam, video) = super::diag_truth_tests::tuning6();
    run_seeded("tuning#6", cam.response, video, cam.vignette, cam.seed);
}
