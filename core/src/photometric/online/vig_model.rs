//! The vignetting model of the online fit: DSO's even polynomial or a radial spline.
//!
//! The polynomial `1 + v1 r² + v2 r⁴ + v3 r⁶` (Bergmann, Wang & Cremers, RA-L 2017; DSO) follows
//! smooth fall-offs (cos⁴ up to a ~40° corner half-angle, Gaussian laws) to ~0.001, but not a
//! plateau with a steep shoulder (a lens hood, a filter ring, a lens too small for the sensor)
//! nor the strong cos⁴ of a wide lens: its least-squares error on a 320×240 frame is 0.013–0.016
//! RMS on mechanical laws and 0.015 on a 55° cos⁴, above the whole error budget of the fit.
//! The spline stage refits the joint problem from the polynomial's result with `V` a radial
//! Hermite spline ([`RadialSpline`], the curve of the offline `vignetting` job) of
//! [`KNOTS`] knots equally spaced in `r` up to the farthest corner, plus a small
//! second-difference penalty (`joint`'s `SPLINE_SMOOTHING`) that carries it on where no track
//! goes.

use serde::{Deserialize, Serialize};

use super::super::flat::VignetteKind;
use super::super::joint::{
    JointConfig, JointReport, JointState, Obs, fit_even_polynomial, refine, vignette,
};
use super::super::spline::RadialSpline;
use super::super::vignette::VignetteModel;
use crate::error::CoreResult;
use crate::progress::Progress;

/// Spline knots, `r = 0` included (seven free values).
pub(super) const KNOTS: usize = 8;

/// Spline knots inside a fisheye's image circle (`r = 0` and the circle's radius included),
/// equally spaced in `r²` ([`knot_radii`]): its border falls from most of the light to nothing
/// over a tenth of the radius or less, and the last intervals are 3–5 px wide on a 320×240
/// frame. 18 were chosen with equal steps in `r` (`fisheye` 0.0068 → 0.0050, `fisheye-eval`
/// 0.0178 → 0.0092 from 12; held out on `fisheye-eval4`, see the README's limits); with equal
/// area, 12 and 18 were within one sequence of each other on `fisheye-eval2` (6 and 7 of 12
/// within every target), so 18 stayed. 24, tried after the border stage (`super::border`):
/// `fisheye-eval` 10 of 11 either way (vignette median 0.0049 → 0.0048), `fisheye-eval2` 10 of
/// 12 either way (0.0058 → 0.0060), `fisheye` no better on the nine sequences run; 18 stays.
pub(super) const CIRCLE_KNOTS: usize = 18;

/// Iteration limit of the spline stage: it starts at the polynomial's optimum, and the rest
/// of the state moves little.
pub(super) const SPLINE_ITERATIONS: usize = 20;

/// `auto` keeps the spline when it lowers the robust cost and departs from its nearest
/// polynomial by more than this RMS over the image's pixels. Measured on the tuning sets of
/// `examples/photometric_sweep.rs` (36 polynomial or Gaussian laws, 12 more in `lens`): the
/// departure is 0.0002–0.0033 on every smooth law and 0.0066–0.0171 on the 8 mechanical
/// lenses of `lens`. The cost condition rejects one scripted sequence (47 % clipped) whose
/// spline wandered to 0.0060 at a higher cost (vignette error 0.0216 against 0.0055 with the
/// polynomial). A relative cost gain alone does not separate the laws: 0.01–1.8 % on the
/// mechanical lenses, −0.3–0.01 % on the smooth ones (the noise dominates the cost).
pub(super) const AUTO_DEPARTURE: f64 = 0.005;

/// `n` knot radii from 0 to `r_max`. Without an image circle they are equally spaced in `r`.
/// Inside one they are equally spaced in `r²`, so that every interval covers the same image
/// area and so about the same number of samples: the border, where the knots must be dense,
/// lies at the largest radii, while the few samples near the centre no longer carry a knot
/// interval of their own. With equal steps in `r` the first interval (8 px on a 320×240
/// frame) held so few samples that its knot came out up to 10 % below `V(0) = 1`, and since
/// the map is normalised at the centre the whole interior followed (`fisheye-eval2#3`: the
/// interior 11 % low; the split's vignette median 0.0231 with equal steps in `r`, 0.0088 in
/// `r²`, with the gauge chosen inside the disc).
fn knot_radii(r_max: f64, n: usize, circle: bool) -> Vec<f64> {
    (0..n)
        .map(|j| {
            let t = j as f64 / (n - 1) as f64;
            r_max * if circle { t.sqrt() } else { t }
        })
        .collect()
}

/// Which vignetting model the result holds and why.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct VignetteChoice {
    /// `polynomial`, `spline`, or `none` (vignetting not fitted).
    pub model: String,
    /// Robust cost of the polynomial fit (when both were fitted).
    pub polynomial_cost: Option<f64>,
    /// Robust cost of the spline fit (when both were fitted).
    pub spline_cost: Option<f64>,
    /// Why this model.
    pub reason: String,
}

/// Runs the spline stage after the polynomial fit (`state`, `rep`) as `kind` asks; leaves
/// `state` and `rep` at the kept model.
pub(super) fn choose(
    kind: VignetteKind,
    obs: &[Obs],
    joint: &JointConfig,
    (state, rep): (&mut JointState, &mut JointReport),
    (model, circle): (&VignetteModel, Option<f64>),
    progress: &dyn Progress,
) -> CoreResult<VignetteChoice> {
    if !joint.fit_vignette {
        return Ok(VignetteChoice {
            model: "none".into(),
            reason: "fit_vignette is off".into(),
            ..VignetteChoice::default()
        });
    }
    if kind == VignetteKind::Polynomial {
        return Ok(VignetteChoice {
            model: "polynomial".into(),
            reason: "requested".into(),
            ..VignetteChoice::default()
        });
    }
    // Inside an image circle the knots span the circle only, and more of them follow its
    // border; beyond it the model is masked.
    let (r_max, n_knots) = match circle {
        Some(r) => (r.max(1e-6), CIRCLE_KNOTS),
        None => (model.max_r2().sqrt().max(1e-6), KNOTS),
    };
    let knots = knot_radii(r_max, n_knots, circle.is_some());
    let start = spline_through(state, knots);
    let mut cand = state.clone();
    cand.spline = Some(start);
    let stage = JointConfig {
        max_iterations: joint.max_iterations.min(SPLINE_ITERATIONS),
        label: "vignette_spline",
        ..joint.clone()
    };
    let srep = refine(obs, &stage, &mut cand, progress)?;
    let (pc, sc) = (rep.cost, srep.cost);
    let departure = cand
        .spline
        .as_ref()
        .map_or(0.0, |sp| polynomial_departure(sp, model));
    let keep = match kind {
        VignetteKind::Spline => true,
        _ if circle.is_some() => true,
        _ => departure > AUTO_DEPARTURE && sc < pc,
    };
    let reason = match (kind, keep) {
        (VignetteKind::Spline, _) => "requested".to_string(),
        _ if circle.is_some() => {
            "auto: the video shows an image circle, whose border no polynomial follows".to_string()
        }
        (_, true) => format!(
            "auto: the spline fits better and departs from every polynomial by {departure:.4} \
             RMS over the image (> {AUTO_DEPARTURE})"
        ),
        (_, false) if sc >= pc => {
            "auto: the spline does not lower the robust cost of the polynomial".to_string()
        }
        (_, false) => format!(
            "auto: the spline stays within {departure:.4} RMS of a polynomial \
             (≤ {AUTO_DEPARTURE})"
        ),
    };
    if keep {
        *state = cand;
        *rep = srep;
    }
    Ok(VignetteChoice {
        model: if keep { "spline" } else { "polynomial" }.into(),
        polynomial_cost: Some(pc),
        spline_cost: Some(sc),
        reason,
    })
}

/// The spline on `knots` nearest (least squares over `r`) to the state's polynomial: the start
/// of the spline stage (interpolating at the knots alone leaves the start off the polynomial
/// between them, and LM then spends its iterations getting back).
fn spline_through(state: &JointState, knots: Vec<f64>) -> RadialSpline {
    let k = knots.len();
    let r_max = knots[k - 1];
    let mut sp = RadialSpline {
        values: knots.iter().map(|&r| state.vig(r * r)).collect(),
        knots,
    };
    let mut unit = vec![0.0; k];
    let mut w = Vec::with_capacity(4);
    let mut ata = nalgebra::DMatrix::<f64>::zeros(k - 1, k - 1);
    let mut atb = nalgebra::DVector::<f64>::zeros(k - 1);
    for i in 0..=256 {
        let r = r_max * f64::from(i) / 256.0;
        sp.basis_into(r, &mut unit, &mut w);
        // V(r) − w₀·1 = Σ_{j>0} w_j c_j.
        let w0 = w.iter().find(|(j, _)| *j == 0).map_or(0.0, |x| x.1);
        let t = state.vig(r * r) - w0;
        for &(a, wa) in w.iter().filter(|(j, _)| *j > 0) {
            atb[a - 1] += wa * t;
            for &(b, wb) in w.iter().filter(|(j, _)| *j > 0) {
                ata[(a - 1, b - 1)] += wa * wb;
            }
        }
    }
    if let Some(ch) = ata.cholesky() {
        let c = ch.solve(&atb);
        for j in 1..k {
            sp.values[j] = c[j - 1];
        }
    }
    sp
}

/// RMS over the image's pixels (every 4th in x and y) of the spline minus its least-squares
/// polynomial `1 + v1 r² + v2 r⁴ + v3 r⁶`: how far the data pulled the curve from the family
/// the polynomial can represent.
fn polynomial_departure(sp: &RadialSpline, model: &VignetteModel) -> f64 {
    let mut samples = Vec::new();
    for y in (0..model.height).step_by(4) {
        for x in (0..model.width).step_by(4) {
            let r2 = model.r2(x as f64 + 0.5, y as f64 + 0.5);
            samples.push((r2, sp.eval(r2.sqrt())));
        }
    }
    let Some(v) = fit_even_polynomial(samples.iter().copied()) else {
        return 0.0;
    };
    let ss: f64 = samples
        .iter()
        .map(|&(r2, t)| {
            let d = t - vignette(&v, r2);
            d * d
        })
        .sum();
    (ss / samples.len().max(1) as f64).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn poly_state(v: [f64; 3]) -> JointState {
        JointState {
            c: [0.0; 4],
            v,
            spline: None,
            log_e: Vec::new(),
            log_l: Vec::new(),
        }
    }

    /// The start of the spline stage reproduces the polynomial, and a polynomial curve departs
    /// from the polynomials by nothing while a plateau with a shoulder departs clearly.
    #[test]
    fn spline_start_and_departure() {
        let st = poly_state([-0.6, 0.2, -0.05]);
        let model = VignetteModel::centered(160, 120, st.v);
        let knots: Vec<f64> = (0..KNOTS).map(|j| j as f64 / (KNOTS - 1) as f64).collect();
        let sp = spline_through(&st, knots.clone());
        for i in 0..=50 {
            let r = f64::from(i) / 50.0;
            let d = (sp.eval(r) - st.vig(r * r)).abs();
            assert!(
                d < 2e-3,
                "r {r}: spline {} polynomial {}",
                sp.eval(r),
                st.vig(r * r)
            );
        }
        assert!(polynomial_departure(&sp, &model) < 1e-3);
        let plateau = RadialSpline {
            values: knots
                .iter()
                .map(|&r| {
                    let t = ((r * r - 0.3) / 0.7).clamp(0.0, 1.0);
                    1.0 - 0.5 * t * t * (3.0 - 2.0 * t)
                })
                .collect(),
            knots,
        };
        let d = polynomial_departure(&plateau, &model);
        assert!(d > AUTO_DEPARTURE, "departure {d}");
    }
}
