//! The second pass's match: the birth template mapped through the fitted camera response.
//!
//! Between two exposures the same scene patch is related by the response,
//! `J = f(k · f⁻¹(T))` (Kim, Frahm & Pollefeys, ICCV 2007; Kim & Pollefeys, PAMI 2008). The
//! first pass does not know `f` and matches with gain, bias and a quadratic term
//! ([`super::klt`]); through a strongly curved response that leaves a residual the shift
//! absorbs, a per-frame position error (on the sweep's held-out `eval4#1` 0.18 px median and
//! 0.60 px p90 already at track ages 0–9, not growing with age) that biased the vignetting and
//! exposures of the fit (`diag_tests.rs`, `DIAG_LIN`). Once a first fit has given `f`, the
//! second pass re-aligns every match to its birth template with this model: the exposure
//! ratio `k` and a small bias are the only brightness unknowns, and the residual stays in the
//! recorded intensities, where the sensor noise is even (tracking on frames linearised by `f`
//! instead amplifies the noise of the steep end of `f⁻¹`; that variant lost 2 of 12 cases on
//! the sweep's tuning split and was dropped).
//!
//! Measured (`examples/photometric_sweep.rs` notes): on the five tuning splits 55 of 60
//! sequences within the accuracy targets against 54 with one pass, on the fresh held-out
//! `eval5` 10 of 12 within every target against 9, for 1.9× the time. Where the gauge profile
//! is flat the new samples could tip the gauge the other way; since the first pass's gauge is
//! a candidate of the second profile (`gauge.rs`), 57 of 60 on the tuning splits and 12 of
//! 12 against 11 on the fresh held-out `eval6`. It was opt-in while it doubled the time; it is
//! the default (`tracking_passes: 2`) since the fit got faster and the first pass stops at its
//! gauge profile ([`super::first_look`]; `examples/photometric_sweep.rs` has the numbers).

use super::klt::{normal_add, window};
use super::pyramid::{Level, VALUE, clipped};
use super::similarity::Similarity;
use crate::error::CoreError;
use crate::photometric::emor::EMOR_SAMPLES;
use crate::photometric::response::ResponseModel;

/// Samples of the tables over `[0, 1]`: the response's own table ([`ResponseModel::forward_table`]).
const TABLE: usize = EMOR_SAMPLES;

/// A fitted response, tabulated for the match.
pub(crate) struct ResponseMatch {
    /// `f` at `i / (TABLE − 1)`.
    fwd: Vec<f32>,
    /// `f′` at the same points (central differences).
    dfwd: Vec<f32>,
    /// `f⁻¹` at `i / (TABLE − 1)` of the recorded intensity.
    inv: Vec<f32>,
}

impl ResponseMatch {
    pub(crate) fn new(response: &ResponseModel) -> Self {
        let step = 1.0 / (TABLE - 1) as f64;
        let fwd: Vec<f32> = response.forward_table().iter().map(|&v| v as f32).collect();
        let dfwd = (0..TABLE)
            .map(|i| {
                let (a, b) = (i.saturating_sub(1), (i + 1).min(TABLE - 1));
                (fwd[b] - fwd[a]) / ((b - a) as f64 * step) as f32
            })
            .collect();
        let inv = response
            .inverse(TABLE)
            .values
            .iter()
            .map(|&v| v as f32)
            .collect();
        Self { fwd, dfwd, inv }
    }

    /// `f⁻¹(t)` (linear interpolation).
    fn inverse(&self, t: f32) -> f32 {
        lerp(&self.inv, t)
    }

    /// `f(u)` and `f′(u)`; above 1 the response is saturated (`f = 1`, `f′ = 0`).
    fn forward(&self, u: f32) -> (f32, f32) {
        if u >= 1.0 {
            (1.0, 0.0)
        } else {
            (lerp(&self.fwd, u), lerp(&self.dfwd, u))
        }
    }
}

fn lerp(table: &[f32], x: f32) -> f32 {
    let s = x.clamp(0.0, 1.0) * (table.len() - 1) as f32;
    let i = (s.floor() as usize).min(table.len() - 2);
    let f = s - i as f32;
    table[i] + f * (table[i + 1] - table[i])
}

/// One Gauss-Newton step of `f(e^s · f⁻¹(T)) + bias ≈ J(q + ·)` for the template `tmpl`
/// (raster order, `(2·hw + 1)²`) laid out with `warp` on level `lb` at `q`: the step
/// `(dx, dy, ds, dbias)` and the RMS residual. Clipped pixels are left out as in the first
/// pass; `None` when fewer than half remain, a sample leaves the level, or the system is
/// singular.
#[allow(clippy::too_many_arguments)]
fn step(
    lb: &Level,
    tmpl: &[f32],
    lin: &[f32],
    hw: i32,
    q: [f32; 2],
    (s, bias): (f32, f32),
    warp: Similarity,
    rm: &ResponseMatch,
) -> Option<([f64; 4], f32)> {
    let mut hm = [[0.0f32; 4]; 4];
    let mut g = [0.0f32; 4];
    let mut ss = 0.0f32;
    let mut used = 0usize;
    let k = s.exp();
    for (i, x, y) in window(hw, warp, q) {
        let (t, u) = (tmpl[i], lin[i]);
        let [j, jx, jy] = lb.sample3(x, y)?;
        if clipped(t) || lb.support_clipped(x, y) {
            continue;
        }
        used += 1;
        let ku = k * u;
        let (f, df) = rm.forward(ku);
        let r = f + bias - j;
        ss += r * r;
        normal_add(&mut hm, &mut g, &[jx, jy, -df * ku, -1.0], r);
    }
    if used < tmpl.len() / 2 {
        return None;
    }
    let m = nalgebra::Matrix4::from_fn(|a, b| {
        f64::from(hm[a.min(b)][a.max(b)]) + if a == b { 1e-9 } else { 0.0 }
    });
    let d = m.lu().solve(&nalgebra::Vector4::from(g.map(f64::from)))?;
    Some(([d[0], d[1], d[2], d[3]], (ss / used as f32).sqrt()))
}

/// [`super::klt::refine_to_template`] with the response model: re-align `q` in `lb` (level 0)
/// to the birth template `tmpl` laid out with `warp`. Returns the position and the patch RMS.
pub(crate) fn refine_with_response(
    tmpl: &[f32],
    lb: &Level,
    q: [f32; 2],
    hw: i32,
    iterations: usize,
    warp: Similarity,
    rm: &ResponseMatch,
) -> Option<([f32; 2], f32)> {
    let lin: Vec<f32> = tmpl.iter().map(|&t| rm.inverse(t)).collect();
    // The exposure ratio starts from the linearised patch means: the ratio to the birth can be
    // large, where the response saturates and Gauss-Newton from `k = 1` would stall.
    let (mut sum_t, mut sum_j) = (0.0f64, 0.0f64);
    for (i, x, y) in window(hw, warp, q) {
        match lb.sample(VALUE, x, y) {
            Some(j) if !clipped(tmpl[i]) && !clipped(j) => {
                sum_t += f64::from(lin[i]);
                sum_j += f64::from(rm.inverse(j));
            }
            _ => {}
        }
    }
    let mut s = if sum_t > 0.0 && sum_j > 0.0 {
        (sum_j / sum_t).ln().clamp(-3.0, 3.0) as f32
    } else {
        0.0
    };
    let mut d = [0.0f32; 2];
    let mut bias = 0.0f32;
    let mut rms = f32::INFINITY;
    for _ in 0..iterations {
        let (st, r) = step(
            lb,
            tmpl,
            &lin,
            hw,
            [q[0] + d[0], q[1] + d[1]],
            (s, bias),
            warp,
            rm,
        )?;
        rms = r;
        d[0] += st[0] as f32;
        d[1] += st[1] as f32;
        s += st[2] as f32;
        bias += st[3] as f32;
        if !(-3.0..=3.0).contains(&s) || d[0].abs() + d[1].abs() > 2.0 {
            return None;
        }
        if st[0].abs() + st[1].abs() < 0.005 {
            break;
        }
    }
    Some(([q[0] + d[0], q[1] + d[1]], rms))
}

/// Whether a later pass that failed this way leaves the previous pass's result standing (the
/// data did not support another pass; a cancellation or a bad parameter does not qualify).
pub(crate) fn recoverable(e: &CoreError) -> bool {
    matches!(e, CoreError::InvalidInput(_) | CoreError::NoSolution(_))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A smooth radiance pattern (no aliasing at the pixel scale).
    fn radiance(x: f32, y: f32) -> f32 {
        // A blurred corner of strong contrast: the response bends a lot over the patch's range.
        0.03 + 0.3 * (1.0 + (1.5 * (x - 32.3)).tanh()) * (1.0 + (1.2 * (y - 29.8)).tanh()) / 4.0
            + 0.02 * (0.4 * x).sin()
    }

    #[test]
    fn a_large_exposure_change_through_a_curved_response_is_matched_exactly() {
        let f = ResponseModel::Gamma { gamma: 2.4 };
        let rm = ResponseMatch::new(&f);
        let (w, h) = (64usize, 64usize);
        let (shift, k) = ([1.0f32, -1.0f32], 2.5f32);
        // The frame: the pattern moved by `shift`, exposed `k` times longer.
        let data: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32, (i / w) as f32);
                f.forward(f64::from(k * radiance(x - shift[0], y - shift[1]))) as f32
            })
            .collect();
        let level = Level::new(w, h, data.clone());
        let (c, hw) = ([32.0f32, 30.0f32], 4i32);
        let tmpl: Vec<f32> = (-hw..=hw)
            .flat_map(|dy| (-hw..=hw).map(move |dx| (dx, dy)))
            .map(|(dx, dy)| {
                f.forward(f64::from(radiance(c[0] + dx as f32, c[1] + dy as f32))) as f32
            })
            .collect();
        let start = [c[0] + shift[0] + 0.4, c[1] + shift[1] - 0.3];
        let (q, rms) =
            refine_with_response(&tmpl, &level, start, hw, 20, Similarity::IDENTITY, &rm).unwrap();
        let err = (q[0] - c[0] - shift[0]).hypot(q[1] - c[1] - shift[1]);
        // The first pass's gain, bias and quadratic model on the same match.
        let pyr = super::super::pyramid::Pyramid::new(w, h, data, 1);
        let (qa, _) =
            super::super::klt::refine_to_template(&tmpl, &pyr, start, hw, 20, Similarity::IDENTITY)
                .unwrap();
        let err_affine = (qa[0] - c[0] - shift[0]).hypot(qa[1] - c[1] - shift[1]);
        // An integer shift: the frame is sampled on its grid, so only the brightness model errs.
        assert!(err < 0.01, "position error {err} px");
        assert!(
            err < 0.5 * err_affine,
            "{err} px against {err_affine} px (affine)"
        );
        assert!(rms < 2e-3, "rms {rms}");
    }

    #[test]
    fn only_data_failures_keep_the_previous_pass() {
        assert!(recoverable(&CoreError::input("few tracks")));
        assert!(recoverable(&CoreError::NoSolution("x".into())));
        assert!(!recoverable(&CoreError::Canceled));
        assert!(!recoverable(&CoreError::param("a", "b")));
    }
}
