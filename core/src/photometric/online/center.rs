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
//!
//! The same fit runs with the radial spline of a fisheye's image circle
//! ([`super::vig_stage`]): there the border falls from most of the light to none within a few
//! pixels, which no exposure ramp mimics, so the tracks that cross it fix the centre.

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::super::emor::emor_basis;
use super::super::joint::{JointState, Obs, SPLINE_SMOOTHING, spline_penalties};
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
    /// found, the circle's centre refined by the spline fit (with the polynomial requested,
    /// the circle's centre when it explains the samples better).
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

/// The estimate: centre (pixels), its σ (pixels) and the state at the estimate (the
/// response as it started).
pub(super) struct CenterFit {
    pub center: [f64; 2],
    pub sigma: [f64; 2],
    pub state: JointState,
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

/// Per scene point: `H_ll`, `b_l` and the cross terms with the dense parameters.
type PointBlock = (f64, f64, Vec<(usize, f64)>);

/// Dense parameters: the vignetting model's free values (the polynomial's `v1..v3` or the
/// spline's values after the first), the centre in units of the half diagonal, log exposures 1…
const NCEN: usize = 2;

/// Radius step of the spline's numerical derivative (normalised radius; the knots are at
/// least ~0.01 apart).
const DR: f64 = 1e-5;

/// `∂V/∂r²` of `s`'s vignetting at `r2`, and the weights `∂V/∂θ` of its free parameters into
/// `grad` (`unit` is scratch of the spline's length, all zero).
fn vig_derivatives(s: &JointState, r2: f64, unit: &mut [f64], grad: &mut Vec<(usize, f64)>) -> f64 {
    grad.clear();
    match &s.spline {
        None => {
            let v = &s.v;
            grad.extend([(0, r2), (1, r2 * r2), (2, r2 * r2 * r2)]);
            v[0] + r2 * (2.0 * v[1] + 3.0 * r2 * v[2])
        }
        Some(sp) => {
            let r = r2.max(0.0).sqrt();
            let mut w = Vec::with_capacity(4);
            sp.basis_into(r, unit, &mut w);
            grad.extend(
                w.into_iter()
                    .filter(|&(j, _)| j > 0)
                    .map(|(j, x)| (j - 1, x)),
            );
            if r < DR {
                return 0.0;
            }
            let dv_dr = (sp.eval(r + DR) - sp.eval(r - DR)) / (2.0 * DR);
            dv_dr / (2.0 * r)
        }
    }
}

/// `s` moved by the first `nv` entries of `d` (its free vignetting parameters).
fn step_vignette(s: &mut JointState, d: &[f64]) {
    match s.spline.as_mut() {
        Some(sp) => {
            for (v, x) in sp.values[1..].iter_mut().zip(d) {
                *v += x;
            }
        }
        None => {
            for (v, x) in s.v.iter_mut().zip(d) {
                *v += x;
            }
        }
    }
}

/// Fit the centre (and the vignetting model, exposures, radiances) from `start`, beginning at
/// `center0`, with the response held. The model is `start`'s: the polynomial or, when
/// `start.spline` is set, the spline (a fisheye's image circle, whose steep border pins the
/// centre far better than a smooth fall-off does). `obs` is sorted by point and `pos` holds
/// each observation's pixel position. `None` when the normal matrix is singular (nothing
/// constrains the centre).
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
    let nv = start.spline.as_ref().map_or(3, |s| s.values.len() - 1);
    let nk = start.spline.as_ref().map_or(0, |s| s.values.len());
    let dim = nv + NCEN + nf.saturating_sub(1);
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
        s: JointState,
        c: [f64; 2],
    }
    let residual = |st: &St, o: &Obs, p: [f32; 2]| {
        let r2 = f64::from(r2_at(p, st.c, rad));
        let s = &st.s;
        let e = s.log_e[o.frame as usize].exp() * s.vig(r2) * s.log_l[o.point as usize].exp();
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
    // The spline's second-difference penalty, weighted as in the joint fit: knots that no
    // sample reaches stay determined (and the covariance below invertible).
    let ws = SPLINE_SMOOTHING
        * obs
            .iter()
            .map(|o| f64::from(o.weight))
            .sum::<f64>()
            .max(1.0);
    // In fixed chunks summed in order: the same result on any number of threads.
    let cost_of = |s: &St| -> f64 {
        let parts: Vec<f64> = obs
            .par_chunks(8192)
            .zip(pos.par_chunks(8192))
            .map(|(oc, pc)| {
                oc.iter()
                    .zip(pc)
                    .map(|(o, &p)| f64::from(o.weight) * rho(residual(s, o, p)))
                    .sum()
            })
            .collect();
        let smooth = s.s.spline.as_ref().map_or(0.0, |sp| {
            spline_penalties(sp).iter().map(|(d, _)| ws * d * d).sum()
        });
        parts.iter().sum::<f64>() + smooth
    };
    let mut st = St {
        s: start.clone(),
        c: center0,
    };
    let mut cost = cost_of(&st);
    let mut lambda = 1e-3;
    // Normal equations at `s`: dense block, gradient, per-point (H_ll, b_l, cross terms), and
    // the weighted squared residuals with their count (for the variance).
    type Normal = (DMatrix<f64>, DVector<f64>, Vec<PointBlock>, f64, usize);
    // Built per chunk of points in parallel and summed in chunk order (deterministic).
    let normal_of = |st: &St, chunk: &[std::ops::Range<usize>]| -> Normal {
        let s = &st.s;
        let mut h = DMatrix::<f64>::zeros(dim, dim);
        let mut g = DVector::<f64>::zeros(dim);
        let mut blocks = Vec::with_capacity(chunk.len());
        let (mut ss, mut n) = (0.0, 0usize);
        let mut unit = vec![0.0; nk];
        let mut vgrad = Vec::with_capacity(4);
        let mut jac = Vec::with_capacity(8);
        for rg in chunk {
            let l = s.log_l[obs[rg.start].point as usize].exp();
            let (mut hl, mut bl) = (0.0, 0.0);
            let mut cross = vec![0.0; dim];
            for (o, &p) in obs[rg.clone()].iter().zip(&pos[rg.clone()]) {
                let (dx, dy) = (f64::from(p[0]) - st.c[0], f64::from(p[1]) - st.c[1]);
                let r2 = (dx * dx + dy * dy) / (rad * rad);
                let vg = s.vig(r2);
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
                let dv_dr2 = vig_derivatives(s, r2, &mut unit, &mut vgrad);
                jac.clear();
                jac.extend(vgrad.iter().map(|&(m, x)| (m, de / vg * x)));
                // Centre in units of `rad`: ∂r²/∂(c/rad) = −2 d / rad.
                jac.push((nv, de / vg * dv_dr2 * (-2.0 * dx / rad)));
                jac.push((nv + 1, de / vg * dv_dr2 * (-2.0 * dy / rad)));
                if o.frame > 0 {
                    jac.push((nv + NCEN + o.frame as usize - 1, de));
                }
                for &(ia, ja) in &jac {
                    g[ia] += w * ja * r;
                    for &(ib, jb) in &jac {
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
    let normal = |st: &St| -> Normal {
        let per = ranges.len().div_ceil(8).max(1);
        let parts: Vec<Normal> = ranges
            .par_chunks(per)
            .map(|chunk| normal_of(st, chunk))
            .collect();
        let mut it = parts.into_iter();
        let Some(mut acc) = it.next() else {
            return (
                DMatrix::zeros(dim, dim),
                DVector::zeros(dim),
                Vec::new(),
                0.0,
                0,
            );
        };
        for (h, g, blocks, ss, n) in it {
            acc.0 += h;
            acc.1 += g;
            acc.2.extend(blocks);
            acc.3 += ss;
            acc.4 += n;
        }
        if let Some(sp) = &st.s.spline {
            for (d, grad) in spline_penalties(sp) {
                for &(ia, ja) in &grad {
                    acc.1[ia] -= ws * ja * d;
                    for &(ib, jb) in &grad {
                        acc.0[(ia, ib)] += ws * ja * jb;
                    }
                }
            }
        }
        acc
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
                (d[nv] * rad).clamp(-0.05 * rad, 0.05 * rad),
                (d[nv + 1] * rad).clamp(-0.05 * rad, 0.05 * rad),
            ];
            let mut cand = St {
                s: st.s.clone(),
                c: [st.c[0] + step_c[0], st.c[1] + step_c[1]],
            };
            step_vignette(&mut cand.s, &d.as_slice()[..nv]);
            for f in 1..nf {
                cand.s.log_e[f] += d[nv + NCEN + f - 1];
            }
            for (rg, (hl, bl, cross)) in ranges.iter().zip(&blocks) {
                let hd = hl * (1.0 + lambda) + 1e-12;
                let mut rhs = *bl;
                for &(a, xa) in cross {
                    rhs -= xa * d[a];
                }
                cand.s.log_l[obs[rg.start].point as usize] += (rhs / hd).clamp(-2.0, 2.0);
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
    let sx = (inv[(nv, nv)] * var).sqrt() * rad;
    let sy = (inv[(nv + 1, nv + 1)] * var).sqrt() * rad;
    if !(sx.is_finite() && sy.is_finite() && st.c.iter().all(|c| c.is_finite())) {
        return Ok(None);
    }
    Ok(Some(CenterFit {
        center: st.c,
        sigma: [sx, sy],
        state: st.s,
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
        *state = fit.state;
    }
    Ok(report)
}
