//! Censored (clipped) samples in the joint fit ([`super::joint::Censor`]): a bound the truth
//! satisfies must not move the solution, and a violated bound must pull the prediction towards
//! it — the two properties the online fit relies on when it keeps clipped pixels.

use super::emor::emor_basis;
use super::joint::{Censor, JointConfig, JointState, Obs, refine};
use super::response::emor_eval;
use crate::progress::NoProgress;

/// True exposure of frame 1 (frame 0 is the gauge, 1).
const E1: f64 = 1.6;
/// The clip level used as the bound.
const CUT: f32 = 0.9;

/// Mean-EMoR response (coefficients 0), no vignetting.
fn predict(log_e: f64, log_l: f64) -> f64 {
    emor_eval(&emor_basis().curve(&[0.0; 4]), (log_e + log_l).exp()).f
}

/// Points with radiances spread over (0.05, 0.62), seen in frames 0 and 1 (exposure 1 and
/// [`E1`]); a frame-1 sample at or above [`CUT`] becomes an `AtLeast` bound. Sorted by point,
/// as `refine` requires.
fn observations() -> (Vec<Obs>, Vec<f64>) {
    let mut obs = Vec::new();
    let mut log_l = Vec::new();
    for p in 0..40u32 {
        let l: f64 = 0.05 + 0.57 * f64::from(p) / 39.0;
        log_l.push(l.ln());
        for (frame, e) in [(0u32, 1.0f64), (1, E1)] {
            let v = predict(e.ln(), l.ln()) as f32;
            let (value, censor) = if v >= CUT {
                (CUT, Censor::AtLeast)
            } else {
                (v, Censor::Exact)
            };
            obs.push(Obs {
                point: p,
                frame,
                r2: 0.0,
                value,
                weight: 1.0,
                censor,
            });
        }
    }
    (obs, log_l)
}

fn config() -> JointConfig {
    JointConfig {
        fit_response: false,
        fit_vignette: false,
        fit_exposures: true,
        gamma_gauge: None,
        huber: 3.0 / 255.0,
        max_iterations: 30,
        label: "censor-test",
    }
}

/// Start with frame 1's exposure and every radiance off by 10–20 %.
fn start(log_l: &[f64]) -> JointState {
    JointState {
        c: [0.0; 4],
        v: [0.0; 3],
        spline: None,
        log_e: vec![0.0, (E1 * 0.8).ln()],
        log_l: log_l.iter().map(|l| l + 0.1).collect(),
    }
}

#[test]
fn satisfied_bounds_leave_the_exact_solution() {
    let (obs, log_l) = observations();
    let bounds = obs.iter().filter(|o| !o.measured()).count();
    assert!(bounds >= 5, "the set must hold bounds ({bounds})");
    let mut st = start(&log_l);
    refine(&obs, &config(), &mut st, &NoProgress).expect("refine");
    let e1 = st.log_e[1].exp();
    assert!((e1 / E1 - 1.0).abs() < 1e-4, "exposure {e1} against {E1}");
    for o in obs.iter().filter(|o| !o.measured()) {
        let f = predict(st.log_e[1], st.log_l[o.point as usize]);
        assert!(
            f >= f64::from(CUT) - 1e-4,
            "point {} predicted {f} below its bound",
            o.point
        );
    }
}

#[test]
fn violated_bound_pulls_the_prediction_up() {
    let (mut obs, log_l) = observations();
    // Point 10 is mid-grey in frame 1; claim instead that it was clipped there.
    let i = obs
        .iter()
        .position(|o| o.point == 10 && o.frame == 1)
        .expect("sample");
    let (mut free, mut bound) = (start(&log_l), start(&log_l));
    refine(&obs, &config(), &mut free, &NoProgress).expect("refine");
    let before = predict(free.log_e[1], free.log_l[10]);
    assert!(
        before < f64::from(CUT) - 0.1,
        "point 10 must be below the cut ({before})"
    );
    obs[i].value = CUT;
    obs[i].censor = Censor::AtLeast;
    refine(&obs, &config(), &mut bound, &NoProgress).expect("refine");
    let after = predict(bound.log_e[1], bound.log_l[10]);
    assert!(
        after > before + 0.05,
        "the violated bound must raise the prediction: {before} → {after}"
    );
    // A lower bound only: the residual is one-sided.
    assert_eq!(obs[i].residual(f64::from(CUT) + 0.05), 0.0);
    assert!(obs[i].residual(f64::from(CUT) - 0.05) > 0.0);
}
