//! Tests of the online calibration (`photometric_online`) and its joint refinement against
//! ground truth from the crate's own generator ([`super::synth`]).

use super::metrics::{exposure_error_pct, gamma_align};
use super::synth::{SynthCamera, render_ae_sequence};
use super::*;
use crate::error::CoreError;
use crate::progress::NoProgress;

#[test]
fn online_calibration_recovers_model() {
    let cam = SynthCamera::reference(160, 120, 11);
    let seq = render_ae_sequence(&cam, 80);
    let p = OnlineParams {
        max_features: 150,
        ..OnlineParams::default()
    };
    let r = photometric_online(&seq.frames, &p, &NoProgress).unwrap();
    // A given gauge holds exactly.
    let fixed = OnlineParams {
        gamma_gauge: Some(0.5),
        ..p.clone()
    };
    let rf = photometric_online(&seq.frames, &fixed, &NoProgress).unwrap();
    assert!((rf.model.response.forward(0.5) - 0.5).abs() < 2e-3);
    // Two tracking passes by default; one can be asked for, and its samples differ.
    assert_eq!((r.tracking_passes, rf.tracking_passes), (2, 2));
    let one = OnlineParams {
        tracking_passes: 1,
        ..fixed.clone()
    };
    let r1 = photometric_online(&seq.frames, &one, &NoProgress).unwrap();
    assert_eq!(r1.tracking_passes, 1);
    assert_ne!(r1.diagnostics.observations, rf.diagnostics.observations);
    let e2 = exposure_error_pct(&rf.exposure_ratios, &seq.exposures, 1.0);
    let e1 = exposure_error_pct(&r1.exposure_ratios, &seq.exposures, 1.0);
    assert!(e2 < 1.5 * e1 + 1.0, "second pass {e2} % against {e1} %");
    for bad in [0, 3] {
        let p = OnlineParams {
            tracking_passes: bad,
            ..fixed.clone()
        };
        assert!(matches!(
            photometric_online(&seq.frames, &p, &NoProgress),
            Err(CoreError::InvalidParam { .. })
        ));
    }
    let fit = InverseResponse::new(r.model.inverse_256.clone()).unwrap();
    let (alpha, err) = gamma_align(&fit, &cam.response.inverse(256));
    let vig = r.model.vignette.as_ref().unwrap();
    let verr = metrics::vignette_rmse(&vig.map(), &cam.vignette_model().map(), alpha);
    let eerr = exposure_error_pct(&r.exposure_ratios, &seq.exposures, alpha);
    eprintln!(
        "online: alpha {alpha:.3} resp {err:.4} vig {verr:.4} exp {eerr:.2}% {:?}",
        r.diagnostics
    );
    // This short, small synthetic clip excites the response less than the shared 200-frame
    // sequence (where the bench measures < 0.005 / < 0.01 / < 2 %); raw, unaligned errors are
    // ~0.1 / ~0.05 / ~20 %.
    assert!(err < 0.02, "response RMSE {err}");
    assert!(verr < 0.03, "vignette RMSE {verr}");
    assert!(eerr < 6.0, "exposure error {eerr} %");
    assert!(r.diagnostics.monotone);
    // Exposure 0 is the unit.
    assert!((r.exposure_ratios[0] - 1.0).abs() < 1e-12);
    // The measured levels lie between the cuts (3 and 250) and span most of them on this
    // clip, whose auto-exposure sweeps the scene over the range.
    let m = r.measured_levels.expect("measured samples");
    assert!(
        m.low >= 3.0 && m.high <= 250.0 && m.high - m.low > 100.0,
        "{m:?}"
    );
}

/// The first of two passes stops at its gauge profile ([`online::first_look`]); the response
/// it hands to the second pass must be the one the full fit of the same samples arrives at,
/// in the same gauge, or the second pass would re-align its matches through a wrong curve.
#[test]
fn first_look_hands_on_the_full_fits_response() {
    let cam = SynthCamera::reference(160, 120, 11);
    let seq = render_ae_sequence(&cam, 80);
    let p = OnlineParams {
        max_features: 150,
        tracking_passes: 1,
        ..OnlineParams::default()
    };
    let seen = online::observe(&seq.frames, &p, 160, 120, None, &NoProgress).unwrap();
    let look = online::first_look(seq.frames.len(), (160, 120), &seen, &p, &NoProgress).unwrap();
    let full = photometric_online(&seq.frames, &p, &NoProgress).unwrap();
    let gap = (0..=100)
        .map(|i| f64::from(i) / 100.0)
        .map(|x| (look.forward(x) - full.model.response.forward(x)).abs())
        .fold(0.0, f64::max);
    eprintln!(
        "first look f(0.5) {:.4}, full fit {:.4}, largest gap {gap:.4}",
        look.forward(0.5),
        full.model.response.forward(0.5)
    );
    assert!(gap < 0.02, "first look departs from the full fit by {gap}");
    assert!((look.forward(0.5) - full.model.response.forward(0.5)).abs() < 5e-3);
    // And it is the camera's curve, not the mean-response start it began from.
    let (_, err) = gamma_align(&look.inverse(256), &cam.response.inverse(256));
    let (_, start) = gamma_align(
        &ResponseModel::default().inverse(256),
        &cam.response.inverse(256),
    );
    eprintln!("first look response RMSE {err:.4} (mean-response start {start:.4})");
    assert!(
        err < 0.02 && err < 0.5 * start,
        "first look {err}, start {start}"
    );
}

/// The joint refinement alone, on ideal correspondences (true geometry, bilinear samples of
/// the rendered frames): recovers the model from the mean-response start.
#[test]
fn joint_refinement_from_ideal_tracks() {
    use super::joint::{Censor, JointConfig, JointState, Obs, refine};
    let cam = SynthCamera::reference(160, 120, 11);
    let seq = render_ae_sequence(&cam, 80);
    let vm = cam.vignette_model();
    let mut rng = synth::Rng::new(5);
    {
        let mut obs = Vec::new();
        let mut np = 0u32;
        for _ in 0..2000 {
            let (u, v) = (100.0 + 300.0 * rng.uniform(), 250.0 + 120.0 * rng.uniform());
            let mut n = 0;
            for k in 0..80 {
                let t = k as f64;
                let (tx, ty) = (200.0 + 2.0 * t, 300.0 + 25.0 * (0.02 * t).sin());
                let th = 0.15 * (0.013 * t).sin();
                let sc = 1.0 + 0.15 * (0.017 * t).sin();
                let (du, dv) = (u - tx, v - ty);
                let (c, s) = (th.cos() / sc, th.sin() / sc);
                let (x, y) = (80.0 + c * du + s * dv, 60.0 - s * du + c * dv);
                if !(2.0..157.0).contains(&x) || !(2.0..117.0).contains(&y) {
                    continue;
                }
                let val = {
                    let im = &seq.frames[k];
                    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
                    let (fx, fy) = (x - x0 as f64, y - y0 as f64);
                    (im.get(x0, y0) * (1.0 - fx) + im.get(x0 + 1, y0) * fx) * (1.0 - fy)
                        + (im.get(x0, y0 + 1) * (1.0 - fx) + im.get(x0 + 1, y0 + 1) * fx) * fy
                };
                if val <= 3.0 / 255.0 || val >= 250.0 / 255.0 {
                    continue;
                }
                obs.push(Obs {
                    point: np,
                    frame: k as u32,
                    r2: vm.r2(x, y) as f32,
                    value: val as f32,
                    weight: 1.0,
                    censor: Censor::Exact,
                });
                n += 1;
            }
            if n >= 2 {
                np += 1;
            } else {
                obs.truncate(obs.len() - n);
            }
        }
        let g0 = ResponseModel::default().inverse(4096);
        let mut log_l = vec![(0.0, 0.0); np as usize];
        for o in &obs {
            let a = &mut log_l[o.point as usize];
            a.0 += g0.eval(f64::from(o.value)).max(1e-6).ln();
            a.1 += 1.0;
        }
        let mut st = JointState {
            c: [0.0; 4],
            v: [0.0; 3],
            spline: None,
            log_e: vec![0.0; 80],
            log_l: log_l.iter().map(|a| a.0 / a.1).collect(),
        };
        let mut cfg = JointConfig {
            fit_response: false,
            fit_vignette: false,
            fit_exposures: true,
            gamma_gauge: None,
            huber: 3.0 / 255.0,
            max_iterations: 5,
            label: "exposures",
        };
        refine(&obs, &cfg, &mut st, &NoProgress).unwrap();
        cfg.fit_response = true;
        cfg.fit_vignette = true;
        cfg.gamma_gauge = Some(0.5);
        super::joint::gauge_start(&mut st, 0.5);
        cfg.max_iterations = 60;
        let rep = refine(&obs, &cfg, &mut st, &NoProgress).unwrap();
        let fit = ResponseModel::Emor { c: st.c }.inverse(256);
        let (alpha, err) = gamma_align(&fit, &cam.response.inverse(256));
        let ee: Vec<f64> = st.log_e.iter().map(|l| l.exp()).collect();
        let e1 = exposure_error_pct(&ee, &seq.exposures, alpha);
        assert!(err < 0.008, "response RMSE {err}");
        assert!(e1 < 1.5, "exposure error {e1} %");
        assert!(rep.rms * 255.0 < 2.5, "residual {} levels", rep.rms * 255.0);
        let vm_fit = VignetteModel::centered(160, 120, st.v);
        let verr = metrics::vignette_rmse(&vm_fit.map(), &vm.map(), alpha);
        assert!(verr < 0.01, "vignette RMSE {verr}");
    }
}

/// Online calibration off the default generators: a third or more of the pixels clipped by a
/// drifting manual exposure, over a Mondrian scene under a Gaussian vignetting law that the
/// polynomial only approximates (the form of the sweep's `saturated` split, other seed).
#[test]
fn online_calibration_on_saturated_drifting_exposure() {
    use super::synth::{
        AeVideo, ExposureProgram, SceneForm, VignetteForm, clipped_fraction, render_ae_video,
    };
    let cam = SynthCamera::reference(160, 120, 23);
    let video = AeVideo {
        program: ExposureProgram::Walk {
            stops: 1.2,
            step: 0.15,
        },
        scene: SceneForm::Blocks,
        vignette: VignetteForm::Gaussian { corner: 0.5 },
        mid: 0.08,
        stops: 8.0,
        ..AeVideo::default()
    };
    let seq = render_ae_video(&cam, 80, &video);
    let clipped = clipped_fraction(&seq.frames);
    assert!(
        clipped > 0.25,
        "only {clipped} clipped: not the saturated case"
    );
    let p = OnlineParams {
        max_features: 150,
        ..OnlineParams::default()
    };
    let r = photometric_online(&seq.frames, &p, &NoProgress).unwrap();
    let fit = InverseResponse::new(r.model.inverse_256.clone()).unwrap();
    let (alpha, err) = gamma_align(&fit, &cam.response.inverse(256));
    let vig = r.model.vignette.as_ref().unwrap();
    let verr = metrics::vignette_rmse(&vig.map(), &seq.vignette_map, alpha);
    let eerr = exposure_error_pct(&r.exposure_ratios, &seq.exposures, alpha);
    eprintln!(
        "saturated walk: clipped {clipped:.2} alpha {alpha:.3} resp {err:.4} vig {verr:.4} exp {eerr:.2}%"
    );
    // The bounds of `online_calibration_recovers_model` (same size and length).
    assert!(err < 0.02, "response RMSE {err}");
    assert!(verr < 0.03, "vignette RMSE {verr}");
    assert!(eerr < 6.0, "exposure error {eerr} %");
}

/// A mechanically vignetted lens (flat to r² = 0.3, then a smoothstep down to half at the
/// corner): `auto` keeps the spline, which follows it where the polynomial cannot.
#[test]
fn online_calibration_follows_mechanical_vignetting() {
    use super::synth::{AeVideo, VignetteForm, render_ae_video};
    let (w, h) = (240, 180);
    let cam = SynthCamera::reference(w, h, 31);
    let video = AeVideo {
        vignette: VignetteForm::Mechanical {
            start: 0.3,
            depth: 0.5,
        },
        mid: 0.06,
        stops: 6.5,
        speed: 1.0,
        ..AeVideo::default()
    };
    let seq = render_ae_video(&cam, 120, &video);
    // The generator: 1 on the plateau, 1 − depth at the corner.
    let v = &seq.vignette_map;
    assert!((v[h / 2 * w + w / 2] - 1.0).abs() < 1e-3);
    assert!((v[0] - 0.5).abs() < 0.02, "corner {}", v[0]);
    let run = |kind: VignetteKind| {
        let p = OnlineParams {
            max_features: 150,
            vignette_model: kind,
            ..OnlineParams::default()
        };
        let r = photometric_online(&seq.frames, &p, &NoProgress).unwrap();
        let fit = InverseResponse::new(r.model.inverse_256.clone()).unwrap();
        let (alpha, rerr) = gamma_align(&fit, &cam.response.inverse(256));
        let vig = r.model.vignette.as_ref().unwrap();
        let verr = metrics::vignette_rmse(&vig.map(), &seq.vignette_map, alpha);
        let eerr = exposure_error_pct(&r.exposure_ratios, &seq.exposures, alpha);
        eprintln!("{kind:?}: response {rerr:.4} exposure {eerr:.2} %");
        (r.vignette_choice, vig.spline.is_some(), verr)
    };
    let (choice, has_spline, spline_err) = run(VignetteKind::Auto);
    let (_, poly_has_spline, poly_err) = run(VignetteKind::Polynomial);
    eprintln!("mechanical: {choice:?} spline {spline_err:.4} polynomial {poly_err:.4}");
    assert_eq!(choice.model, "spline", "{}", choice.reason);
    assert!(has_spline && !poly_has_spline);
    assert!(spline_err < 0.01, "spline vignette RMSE {spline_err}");
    assert!(
        spline_err < 0.6 * poly_err,
        "spline {spline_err} against polynomial {poly_err}"
    );
}
