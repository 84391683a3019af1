//! The optical centre of the vignetting, estimated from the tracks when they constrain it.
//!
//! DSO's online calibration (Bergmann, Wang & Cremers, RA-L 2017) fixes the centre of the
//! radial vignetting polynomial at the image centre. Real lenses are often decentred by a few
//! per cent of the width (assembly tolerance, sensor-shift stabilisation, crops), and a
//! decentred fall-off fitted with a centred model biases the coefficients and leaves a tilt in
//! the map (Kang & Weiss, "Can We Calibrate a Camera Using an Image of a Flat, Textureless
//! Lambertian Surface?", ECCV 2000, treat the centre as an unknown of the vignetting model for
//! the same reason). The centre is only observable through the gradient of `V`, so it is
//! constrained when `V` falls off noticeably *and* the tracked points cover the image on both
//! sides of the centre; otherwise the estimate wanders and the centred model is the safer one.
//!
//! The estimate is a Levenberg-Marquardt pass on the Huber cost of [`super::super::joint`]
//! over `v1..v3`, the centre, the exposures and the radiances (Schur complement over the
//! radiances, as there) with the response held at the joint fit's value: with the response
//! fixed there is no γ ambiguity to hold, and the response barely correlates with a shift of
//! the centre (a shift is odd in x or y, the response acts on all pixels alike). The centre's σ
//! comes from the inverse of the undamped normal matrix scaled by the residual variance (the
//! Gauss-Newton covariance, e.g. Hartley & Zisserman, "Multiple View Geometry", 2nd ed., §5.2);
//! it leaves out the response's uncertainty, so it is a little optimistic.
//!
//! Why the exposures stay free and why this is not the default: for a fall-off that is
//! quadratic in `r`, moving the centre by `δ` adds a linear tilt `∝ v1 · x·δ` to `ln V`; under
//! a pure translation every tracked point crosses the same tilt at the same time, which an
//! exposure ramp explains exactly. The centre is therefore observed only through rotation,
//! zoom and the r⁴/r⁶ terms, and it trades with exposure drift. Holding the exposures at the
//! centred fit's values (tried while tuning) only pins the estimate to the image centre
//! (the exposures have already absorbed the tilt); leaving them free lets small systematic
//! errors of the tracks move it: on the tuning sequences the estimate was off by 4–49 px
//! with a σ near 1 px, so `auto` is opt-in (see the README's limits).

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use super::super::emor::emor_basis;
use super::super::joint::{JointState, Obs};
use super::super::response::{emor_eval, emor_value};
use crate::error::CoreResult;
use crate::progress::Progress;

/// Whether the vignetting centre is fitted.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub enum CenterMode {
    /// Estimate it, and keep the estimate only when the data constrain it (σ small, tracks
    /// spread over the image) and it differs significantly from the image centre.
    Auto,
    /// Keep it at the image centre (DSO's model; the default). With a fisheye's image circle
    /// found, the circle's centre is fitted too and kept when it explains the samples better.
    #[default]
    Fixed,
    /// Always use the estimate (unless the fit fails).
    Estimated,
}

/// What became of the vignetting centre.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct CenterReport {
    /// Whether the model's centre is the estimate (otherwise the image centre).
    pub estimated: bool,
    /// The centre used by the model, pixels.
    pub center: [f64; 2],
    /// The estimated centre, pixels, when one was computed (also when it was not kept).
    pub estimate: Option<[f64; 2]>,
    /// Standard deviation of the estimate in x and y, pixels.
    pub sigma: Option<[f64; 2]>,
    /// Share of the image (cells of a 4×4 grid) that the samples cover.
    pub coverage: f64,
    /// Why the centre is what it is.
    pub reason: String,
}

/// Largest σ of the centre (fraction of the half diagonal) for `auto` to keep the estimate.
pub(super) const MAX_SIGMA_FRAC: f64 = 0.02;
/// Least share of the 4×4 grid cells holding samples for `auto` to keep the estimate.
pub(super) const MIN_COVERAGE: f64 = 0.75;
/// χ² (2 dof, 99 %) above which the shift from the image centre counts as significant.
pub(super) const CHI2_2DOF_99: f64 = 9.21;

/// The estimate: centre (pixels), its σ (pixels) and the state at the estimate.
pub(super) struct CenterFit {
    pub center: [f64; 2],
    pub sigma: [f64; 2],
    pub v: [f64; 3],
    pub log_e: Vec<f64>,
    pub log_l: Vec<f64>,
}

/// Share of the cells of a 4×4 grid over the image that hold at least one sample.
pub(super) fn coverage(pos: &[[f32; 2]], w: usize, h: usize) -> f64 {
    let mut cells = [false; 16];
    for p in pos {
        let gx = ((f64::from(p[0]) / w as f64 * 4.0) as usize).min(3);
        let gy = ((f64::from(p[1]) / h as f64 * 4.0) as usize).min(3);
        cells[gy * 4 + gx] = true;
    }
    cells.iter().filter(|&&c| c).count() as f64 / 16.0
}

/// Squared normalised radius of `p` around `center` (radius `rad`, the half diagonal).
pub(super) fn r2_at(p: [f32; 2], center: [f64; 2], rad: f64) -> f32 {
    let (dx, dy) = (f64::from(p[0]) - center[0], f64::from(p[1]) - center[1]);
    ((dx * dx + dy * dy) / (rad * rad)) as f32
}

fn vig(v: &[f64; 3], r2: f64) -> f64 {
    (1.0 + r2 * (v[0] + r2 * (v[1] + r2 * v[2]))).max(1e-3)
}

/// Per scene point: `H_ll`, `b_l` and the cross terms with the dense parameters.
type PointBlock = (f64, f64, Vec<(usize, f64)>);

/// Dense parameters: `v1..v3`, the centre in units of the half diagonal, log exposures 1…
const NV: usize = 3;
const NCEN: usize = 2;

/// Fit the centre (and `v`, exposures, radiances) from `start`, beginning at `center0`.
/// `obs` is sorted by point and `pos` holds each observation's pixel position. `None` when the
/// normal matrix is singular (nothing constrains the centre).
#[allow(clippy::too_many_arguments)]
pub(super) fn fit_center(
    obs: &[Obs],
    pos: &[[f32; 2]],
    start: &JointState,
    center0: [f64; 2],
    rad: f64,
    huber: f64,
    max_iterations: usize,
    progress: &dyn Progress,
) -> CoreResult<Option<CenterFit>> {
    let nf = start.log_e.len();
    let dim = NV + NCEN + nf.saturating_sub(1);
    let curve = emor_basis().curve(&start.c);
    let mut ranges = Vec::new();
    let mut s0 = 0;
    for i in 1..=obs.len() {
        if i == obs.len() || obs[i].point != obs[s0].point {
            ranges.push(s0..i);
            s0 = i;
        }
    }
    struct St {
        v: [f64; 3],
        c: [f64; 2],
        log_e: Vec<f64>,
        log_l: Vec<f64>,
    }
    let residual = |s: &St, o: &Obs, p: [f32; 2]| {
        let r2 = f64::from(r2_at(p, s.c, rad));
        let e = s.log_e[o.frame as usize].exp() * vig(&s.v, r2) * s.log_l[o.point as usize].exp();
        o.residual(emor_value(&curve, e))
    };
    let rho = |r: f64| {
        let a = r.abs();
        if a <= huber {
            r * r
        } else {
            2.0 * huber * a - huber * huber
        }
    };
    let cost_of = |s: &St| -> f64 {
        obs.iter()
            .zip(pos)
            .map(|(o, &p)| f64::from(o.weight) * rho(residual(s, o, p)))
            .sum()
    };
    let mut st = St {
        v: start.v,
        c: center0,
        log_e: start.log_e.clone(),
        log_l: start.log_l.clone(),
    };
    let mut cost = cost_of(&st);
    let mut lambda = 1e-3;
    // Normal equations at `s`: dense block, gradient, per-point (H_ll, b_l, cross terms), and
    // the weighted squared residuals with their count (for the variance).
    type Normal = (DMatrix<f64>, DVector<f64>, Vec<PointBlock>, f64, usize);
    let normal = |s: &St| -> Normal {
        let mut h = DMatrix::<f64>::zeros(dim, dim);
        let mut g = DVector::<f64>::zeros(dim);
        let mut blocks = Vec::with_capacity(ranges.len());
        let (mut ss, mut n) = (0.0, 0usize);
        for rg in &ranges {
            let l = s.log_l[obs[rg.start].point as usize].exp();
            let (mut hl, mut bl) = (0.0, 0.0);
            let mut cross = vec![0.0; dim];
            for (o, &p) in obs[rg.clone()].iter().zip(&pos[rg.clone()]) {
                let (dx, dy) = (f64::from(p[0]) - s.c[0], f64::from(p[1]) - s.c[1]);
                let r2 = (dx * dx + dy * dy) / (rad * rad);
                let vg = vig(&s.v, r2);
                let e = s.log_e[o.frame as usize].exp() * vg * l;
                let ev = emor_eval(&curve, e);
                let r = o.residual(ev.f);
                if o.inactive(r) {
                    continue;
                }
                let wh = if r.abs() <= huber {
                    1.0
                } else {
                    huber / r.abs()
                };
                let w = f64::from(o.weight) * wh;
                if o.weight > 0.0 && o.measured() {
                    ss += w * r * r;
                    n += 1;
                }
                let de = ev.df * e;
                let dv_dr2 = s.v[0] + r2 * (2.0 * s.v[1] + 3.0 * r2 * s.v[2]);
                let mut jac = [(0usize, 0.0f64); NV + NCEN + 1];
                let mut nj = 0;
                let mut rp = r2;
                for m in 0..NV {
                    jac[nj] = (m, de / vg * rp);
                    nj += 1;
                    rp *= r2;
                }
                // Centre in units of `rad`: ∂r²/∂(c/rad) = −2 d / rad.
                jac[nj] = (NV, de / vg * dv_dr2 * (-2.0 * dx / rad));
                jac[nj + 1] = (NV + 1, de / vg * dv_dr2 * (-2.0 * dy / rad));
                nj += 2;
                if o.frame > 0 {
                    jac[nj] = (NV + NCEN + o.frame as usize - 1, de);
                    nj += 1;
                }
                for a in 0..nj {
                    let (ia, ja) = jac[a];
                    g[ia] += w * ja * r;
                    for &(ib, jb) in &jac[..nj] {
                        h[(ia, ib)] += w * ja * jb;
                    }
                    cross[ia] += w * ja * de;
                }
                hl += w * de * de;
                bl += w * de * r;
            }
            let cross: Vec<(usize, f64)> = cross
                .into_iter()
                .enumerate()
                .filter(|&(_, x)| x != 0.0)
                .collect();
            blocks.push((hl, bl, cross));
        }
        (h, g, blocks, ss, n)
    };
    // Reduced (Schur) system for damping `lam`.
    let reduce = |h: &DMatrix<f64>, g: &DVector<f64>, blocks: &[PointBlock], lam: f64| {
        let mut s = h.clone();
        let mut b = g.clone();
        for a in 0..dim {
            s[(a, a)] += lam * h[(a, a)].max(1e-12);
        }
        for (hl, bl, cross) in blocks {
            let hd = hl * (1.0 + lam) + 1e-12;
            for &(a, xa) in cross {
                b[a] -= xa * bl / hd;
                for &(c, xc) in cross {
                    s[(a, c)] -= xa * xc / hd;
                }
            }
        }
        (s, b)
    };
    for _ in 0..max_iterations {
        progress.check()?;
        let (h, g, blocks, _, _) = normal(&st);
        let mut accepted = false;
        for _ in 0..16 {
            let (s, b) = reduce(&h, &g, &blocks, lambda);
            let Some(chol) = s.cholesky() else {
                lambda *= 10.0;
                continue;
            };
            let d = chol.solve(&b);
            // A step of more than 5 % of the half diagonal is not trusted in one go.
            let step_c = [
                (d[NV] * rad).clamp(-0.05 * rad, 0.05 * rad),
                (d[NV + 1] * rad).clamp(-0.05 * rad, 0.05 * rad),
            ];
            let mut cand = St {
                v: [st.v[0] + d[0], st.v[1] + d[1], st.v[2] + d[2]],
                c: [st.c[0] + step_c[0], st.c[1] + step_c[1]],
                log_e: st.log_e.clone(),
                log_l: st.log_l.clone(),
            };
            for f in 1..nf {
                cand.log_e[f] += d[NV + NCEN + f - 1];
            }
            for (rg, (hl, bl, cross)) in ranges.iter().zip(&blocks) {
                let hd = hl * (1.0 + lambda) + 1e-12;
                let mut rhs = *bl;
                for &(a, xa) in cross {
                    rhs -= xa * d[a];
                }
                cand.log_l[obs[rg.start].point as usize] += (rhs / hd).clamp(-2.0, 2.0);
            }
            let new_cost = cost_of(&cand);
            if new_cost.is_finite() && new_cost < cost {
                let rel = (cost - new_cost) / cost.max(1e-30);
                st = cand;
                cost = new_cost;
                lambda = (lambda / 3.0).max(1e-9);
                accepted = rel > 1e-9;
                break;
            }
            lambda *= 4.0;
        }
        if !accepted {
            break;
        }
    }
    // Covariance of the centre: the dense block of the undamped reduced system, inverted,
    // times the residual variance.
    let (h, g, blocks, ss, n) = normal(&st);
    let (s, _) = reduce(&h, &g, &blocks, 0.0);
    let Some(inv) = s.try_inverse() else {
        return Ok(None);
    };
    let var = ss / (n.saturating_sub(dim + ranges.len())).max(1) as f64;
    let sx = (inv[(NV, NV)] * var).sqrt() * rad;
    let sy = (inv[(NV + 1, NV + 1)] * var).sqrt() * rad;
    if !(sx.is_finite() && sy.is_finite() && st.c.iter().all(|c| c.is_finite())) {
        return Ok(None);
    }
    Ok(Some(CenterFit {
        center: st.c,
        sigma: [sx, sy],
        v: st.v,
        log_e: st.log_e,
        log_l: st.log_l,
    }))
}

/// Decide the vignetting centre after the joint fit: estimate it (unless `mode` is `Fixed`),
/// keep or drop the estimate, and when kept move `obs` (their `r²`) and `state` (vignetting,
/// exposures, radiances) to it so that the caller's final refinement starts there.
///
/// `auto` keeps the estimate only when all three hold: σ ≤ [`MAX_SIGMA_FRAC`] of the half
/// diagonal (the data constrain it), samples in ≥ [`MIN_COVERAGE`] of the image (the σ of a
/// one-sided sample is not to be trusted: the polynomial then extrapolates), and a shift from
/// the image centre that is significant at 99 % (Wald test, χ² with 2 dof): an extra
/// parameter that the data cannot tell from zero only adds noise to the map.
#[allow(clippy::too_many_arguments)]
pub(super) fn resolve(
    mode: CenterMode,
    fit_vignette: bool,
    obs: &mut [Obs],
    pos: &[[f32; 2]],
    state: &mut JointState,
    (w, h): (usize, usize),
    huber: f64,
    progress: &dyn Progress,
) -> CoreResult<CenterReport> {
    let image_center = [w as f64 / 2.0, h as f64 / 2.0];
    let rad = image_center[0].hypot(image_center[1]);
    let cov = coverage(pos, w, h);
    let mut report = CenterReport {
        estimated: false,
        center: image_center,
        estimate: None,
        sigma: None,
        coverage: cov,
        reason: String::new(),
    };
    if !fit_vignette {
        report.reason = "no vignetting fitted".into();
        return Ok(report);
    }
    if mode == CenterMode::Fixed {
        report.reason = "fixed at the image centre (vignette_center: fixed)".into();
        return Ok(report);
    }
    let Some(fit) = fit_center(obs, pos, state, image_center, rad, huber, 30, progress)? else {
        report.reason = "the tracks do not constrain the centre: kept at the image centre".into();
        return Ok(report);
    };
    report.estimate = Some(fit.center);
    report.sigma = Some(fit.sigma);
    let (dx, dy) = (
        fit.center[0] - image_center[0],
        fit.center[1] - image_center[1],
    );
    let chi2 = (dx / fit.sigma[0]).powi(2) + (dy / fit.sigma[1]).powi(2);
    let sigma_max = fit.sigma[0].max(fit.sigma[1]);
    let keep = match mode {
        CenterMode::Estimated => {
            report.reason = "estimated (vignette_center: estimated)".into();
            true
        }
        _ if sigma_max > MAX_SIGMA_FRAC * rad => {
            report.reason = format!(
                "centre σ {sigma_max:.1} px exceeds {:.1} px: kept at the image centre",
                MAX_SIGMA_FRAC * rad
            );
            false
        }
        _ if cov < MIN_COVERAGE => {
            report.reason = format!(
                "samples cover {:.0} % of the image (< {:.0} %): kept at the image centre",
                100.0 * cov,
                100.0 * MIN_COVERAGE
            );
            false
        }
        _ if chi2 <= CHI2_2DOF_99 => {
            report.reason = format!(
                "estimate within the noise of the image centre (χ² {chi2:.1} ≤ {CHI2_2DOF_99}): \
                 kept at the image centre"
            );
            false
        }
        _ => {
            report.reason =
                format!("estimated: σ {sigma_max:.2} px, shift significant (χ² {chi2:.1})");
            true
        }
    };
    if keep {
        report.estimated = true;
        report.center = fit.center;
        for (o, &p) in obs.iter_mut().zip(pos) {
            o.r2 = r2_at(p, fit.center, rad);
        }
        state.v = fit.v;
        state.log_e = fit.log_e;
        state.log_l = fit.log_l;
    }
    Ok(report)
}
