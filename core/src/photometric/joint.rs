//! Why one file of over 600 lines: the cost, its normal equations and the LM loop must agree
//! term by term (every penalty appears in all three); split, a change to one would silently
//! miss the others.
//!
//! The joint photometric least-squares problem shared by the bracketed and the online fits.
//!
//! Each observation is one pixel value `O` of scene point `i` in frame `k` at normalised radius
//! `r`: `O = f(e_k · V(r) · L_i)` (Bergmann, Wang & Cremers, "Online Photometric Calibration of
//! Auto Exposure Video for Realtime Visual Odometry and SLAM", RA-L 2017, eq. 1; the same image
//! formation as DSO, Engel, Koltun & Cremers, PAMI 2018). Unknowns: the EMoR coefficients `c`,
//! the vignetting polynomial `v`, the log exposures and the log radiances. Levenberg-Marquardt
//! on the Huber cost; the radiances form a block-diagonal part that is eliminated with the
//! Schur complement, so each iteration solves only a (4 + 3 + frames)-sized dense system.
//!
//! Gauge: exposure 0 is fixed at 1 (log 0). With unknown exposures the γ ambiguity
//! (`f(x^{1/γ})`, `V^γ`, `e^γ`, `L^γ` explain the same images) is fixed by the constraint
//! `f(0.5) = gamma_gauge` (`f⁻¹(m) = 0.5`), added as a stiff residual; monotonicity of `f` is a
//! stiff one-sided penalty on every basis segment.
//!
//! A clipped sample is a bound rather than a value ([`Censor`]): its residual is one-sided.

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

use super::emor::{EMOR_DIM, EMOR_SAMPLES, emor_basis};
use super::response::{emor_eval, emor_value};
use super::spline::RadialSpline;
use crate::error::{CoreError, CoreResult};
use crate::progress::Progress;

/// One measured intensity.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Obs {
    pub point: u32,
    pub frame: u32,
    /// Squared normalised radius (vignetting argument).
    pub r2: f32,
    /// Normalised intensity in `[0, 1]`.
    pub value: f32,
    /// Confidence weight (0..1).
    pub weight: f32,
    /// Whether `value` is a measurement or only a bound (a clipped sample).
    pub censor: Censor,
}

/// What a sample says about the model's prediction `f`.
///
/// A clipped pixel still says that the point was at least as bright as the clip level at that
/// exposure; dropping it truncates the noise distribution near the clip (a selection bias) and
/// throws that bound away. A censored sample keeps it as a one-sided residual, the hinge
/// (noise-free) limit of the Tobit likelihood (J. Tobin, "Estimation of relationships for
/// limited dependent variables", Econometrica 1958): zero cost and no Jacobian while the
/// prediction is beyond the bound, the Huber cost of the shortfall otherwise.
///
/// The online fit censors a sample at the cut (`high_cut` / `low_cut`) when it and its whole
/// bilinear support are on that side of it. Measured first on `diag_tests.rs`'s
/// `diag_saturated` (about half the pixels clipped; response / vignetting / exposure error,
/// common scale, gauge at the truth): with ground-truth observations the truncation alone costs
/// little, noise-free 0 / 0 / 0 % → with noise 0.0006 / 0.0006 / 0.20 %, and censoring halves
/// that (0.0003 / 0.0004 / 0.11 %); on the linear camera the floor is EMoR-4's span (0.0043 /
/// 0.0013 / 0.83 % noise-free, unchanged). With tracks it changes little there either (+0.8 %
/// samples; 0.0005 / 0.0014 / 0.24 % → 0.0004 / 0.0014 / 0.25 %): the tracker does not follow
/// points into the clipped areas, so truncation is not what limits those sequences (short
/// tracks and EMoR-4's span do, see `online/diag_tests.rs`). Tuning split of
/// `examples/photometric_sweep.rs`: medians 0.0010 / 0.0020 / 0.48 % → 0.0009 / 0.0018 /
/// 0.42 %, still 11 of 12 within targets; the case it helps is tuning#3, whose exposure falls ~20×
/// over the first frames (0.0011 / 0.0035 / 0.90 % → 0.0008 / 0.0009 / 0.38 %); tuning#0 moved
/// 0.0005 / 0.0012 / 0.23 % → 0.0004 / 0.0013 / 0.34 %. Held-out eval split, run once before
/// and once after (not tuned on): accuracy targets met on the same 8 of 12; the four most
/// saturated sequences still miss, eval#1 exposure 2.49 → 2.38 %, eval#6 vignetting 0.0123 →
/// 0.0118, eval#9 0.0116 → 0.0101, eval#10 exposure 2.03 → 2.12 %; medians 0.0012 / 0.0036 /
/// 0.67 % → 0.0013 / 0.0035 / 0.69 %. Shared `ae_seq_seed0`: 0.0001 / 0.0004 / 0.15 % →
/// 0.0001 / 0.0004 / 0.17 %. CPU time per sequence unchanged.
///
/// Rejected on the tuning split: also censoring samples whose support blends clipped and
/// unclipped pixels, at their interpolated value (a valid lower bound; medians 0.0014 /
/// 0.0021 / 0.55 %, tuning#0 0.0018 / 0.0021 / 1.05 %), and censoring a noise band below the cut as
/// well (4 levels: 9 of 12 within targets; 2 levels: 10 of 12): on a strongly concave camera
/// (tuning#1, f(0.5) = 0.97) the top levels span a wide range of irradiance, and the band
/// throws that information away (response error 0.0034 → 0.015–0.019).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(crate) enum Censor {
    /// `value` was measured.
    #[default]
    Exact,
    /// Clipped high: the true value is at least `value`.
    AtLeast,
    /// Clipped low: the true value is at most `value`.
    AtMost,
}

impl Obs {
    /// Residual `value − f`; for a censored sample only the part that violates its bound (so
    /// zero, with a zero Jacobian, where the prediction is beyond the clip level).
    #[inline]
    pub(crate) fn residual(&self, f: f64) -> f64 {
        let r = f64::from(self.value) - f;
        match self.censor {
            Censor::Exact => r,
            Censor::AtLeast => r.max(0.0),
            Censor::AtMost => r.min(0.0),
        }
    }

    /// Whether `value` was measured (not a censored bound).
    #[inline]
    pub(crate) fn measured(&self) -> bool {
        self.censor == Censor::Exact
    }

    /// Whether the sample adds nothing at residual `r` (a censored sample within its bound).
    #[inline]
    pub(crate) fn inactive(&self, r: f64) -> bool {
        self.censor != Censor::Exact && r == 0.0
    }
}

/// What is free and how the cost looks.
#[derive(Debug, Clone)]
pub(crate) struct JointConfig {
    pub fit_response: bool,
    pub fit_vignette: bool,
    pub fit_exposures: bool,
    /// `Some(m)`: enforce `f(0.5) = m`.
    pub gamma_gauge: Option<f64>,
    /// Huber threshold in normalised intensity.
    pub huber: f64,
    pub max_iterations: usize,
    /// Step name for progress reports.
    pub label: &'static str,
}

/// Current estimate.
#[derive(Debug, Clone)]
pub(crate) struct JointState {
    pub c: [f64; EMOR_DIM],
    pub v: [f64; 3],
    /// A radial spline in `r` that replaces the polynomial `v` when present (its first value,
    /// at `r = 0`, stays 1: the gauge of the radiances).
    pub spline: Option<RadialSpline>,
    pub log_e: Vec<f64>,
    pub log_l: Vec<f64>,
}

impl JointState {
    /// The mean EMoR response and no vignetting with the given exposures and radiances: where
    /// every fit starts.
    pub(crate) fn at_mean_response(log_e: Vec<f64>, log_l: Vec<f64>) -> Self {
        Self {
            c: [0.0; EMOR_DIM],
            v: [0.0; 3],
            spline: None,
            log_e,
            log_l,
        }
    }

    /// `V` at squared normalised radius `r2`: the spline when there is one, else the polynomial.
    #[inline]
    pub(crate) fn vig(&self, r2: f64) -> f64 {
        match &self.spline {
            Some(s) => s.eval(r2.max(0.0).sqrt()).max(1e-3),
            None => vignette(&self.v, r2),
        }
    }

    /// Free vignetting parameters: the polynomial's three or the spline's values after the
    /// first.
    fn vig_dim(&self) -> usize {
        self.spline.as_ref().map_or(3, |s| s.values.len() - 1)
    }
}

/// Weight of the spline's second-difference penalty, per unit of observation weight. Where the
/// tracks never reach (the corners of a fisheye, the ring outside a small scene) it carries
/// the curve on linearly; where they do it is negligible against the data (a kink of 0.05
/// adds 0.04 % to the data cost at 2 levels of noise).
pub(crate) const SPLINE_SMOOTHING: f64 = 1e-5;

/// Second differences of the spline's values (the smoothness penalty), each with its sparse
/// gradient in the free values (value `j` is free parameter `j − 1`; value 0 is fixed at 1).
pub(crate) fn spline_penalties(s: &RadialSpline) -> Vec<(f64, Vec<(usize, f64)>)> {
    let v = &s.values;
    (1..v.len().saturating_sub(1))
        .map(|j| {
            let d = v[j - 1] - 2.0 * v[j] + v[j + 1];
            let grad = [(j - 1, 1.0), (j, -2.0), (j + 1, 1.0)]
                .into_iter()
                .filter(|&(i, _)| i > 0)
                .map(|(i, w)| (i - 1, w))
                .collect();
            (d, grad)
        })
        .collect()
}

/// How the refinement went.
#[derive(Debug, Clone, Default)]
pub(crate) struct JointReport {
    pub iterations: usize,
    pub converged: bool,
    /// Unweighted RMS of the residuals of the measured (uncensored) inliers (|r| ≤ 3·huber),
    /// normalised intensity.
    pub rms: f64,
    pub inliers: usize,
    /// Final robust cost (data term plus penalties).
    pub cost: f64,
}

/// Step below which an EMoR segment counts as non-increasing (per sample of the basis grid).
const MONO_EPS: f64 = 1e-5;

/// Per scene point: `H_ll`, `b_l` and the non-zero cross terms `H_dl` (dense index, value).
type PointBlock = (f64, f64, Vec<(usize, f64)>);

struct Layout {
    nc: usize,
    nv: usize,
    ne: usize,
}

impl Layout {
    fn dim(&self) -> usize {
        self.nc + self.nv + self.ne
    }
    fn e_index(&self, frame: u32) -> Option<usize> {
        (self.ne > 0 && frame > 0).then(|| self.nc + self.nv + frame as usize - 1)
    }
}

pub(crate) fn vignette(v: &[f64; 3], r2: f64) -> f64 {
    (1.0 + r2 * (v[0] + r2 * (v[1] + r2 * v[2]))).max(1e-3)
}

fn huber_rho(r: f64, k: f64) -> f64 {
    let a = r.abs();
    if a <= k { r * r } else { 2.0 * k * a - k * k }
}

/// Penalty residuals that act on `c` only: the γ gauge and monotonicity. Returns
/// `(residual, ∂f/∂c)` pairs for `r = target − f`.
fn c_penalties(cfg: &JointConfig, curve: &[f64]) -> Vec<(f64, [f64; EMOR_DIM])> {
    let b = emor_basis();
    let mut out = Vec::new();
    if let Some(m) = cfg.gamma_gauge {
        let ev = emor_eval(curve, 0.5);
        out.push((m - ev.f, ev.dc));
    }
    for j in 0..EMOR_SAMPLES - 1 {
        let d = curve[j + 1] - curve[j];
        if d < MONO_EPS {
            let mut dc = [0.0; EMOR_DIM];
            for (k, x) in dc.iter_mut().enumerate() {
                *x = b.h[k][j + 1] - b.h[k][j];
            }
            out.push((MONO_EPS - d, dc));
        }
    }
    out
}

/// The robust cost of `s`; `wsum` is the observations' total weight (the penalties scale
/// with it).
fn total_cost(obs: &[Obs], cfg: &JointConfig, s: &JointState, wsum: f64) -> f64 {
    let wpen = penalty_weight(wsum);
    let curve = emor_basis().curve(&s.c);
    let mut cost = data_cost(obs, cfg.huber, s);
    if cfg.fit_response {
        for (r, _) in c_penalties(cfg, &curve) {
            cost += wpen * r * r;
        }
    }
    if cfg.fit_vignette
        && let Some(sp) = &s.spline
    {
        for (d, _) in spline_penalties(sp) {
            cost += SPLINE_SMOOTHING * wsum * d * d;
        }
    }
    cost
}

/// The data term of the robust cost of `s` (Huber at `huber`), without the penalties: what
/// two fits of the same samples under different models are compared by.
pub(crate) fn data_cost(obs: &[Obs], huber: f64, s: &JointState) -> f64 {
    let curve = emor_basis().curve(&s.c);
    let (exposure, radiance) = (exps(&s.log_e), exps(&s.log_l));
    // Fixed chunks summed in order: the same result on any number of threads.
    let parts: Vec<f64> = obs
        .par_chunks(8192)
        .map(|chunk| {
            chunk
                .iter()
                .map(|o| {
                    let e = exposure[o.frame as usize]
                        * s.vig(f64::from(o.r2))
                        * radiance[o.point as usize];
                    let r = o.residual(emor_value(&curve, e));
                    f64::from(o.weight) * huber_rho(r, huber)
                })
                .sum::<f64>()
        })
        .collect();
    parts.iter().sum()
}

/// `exp` of each log value: once per frame or point instead of once per sample.
fn exps(logs: &[f64]) -> Vec<f64> {
    logs.iter().map(|l| l.exp()).collect()
}

/// Weight of the stiff penalties (γ gauge, monotonicity) for observations of total weight
/// `wsum`: stiff enough to hold them to ~1e-4 against the data term.
fn penalty_weight(wsum: f64) -> f64 {
    1e3 * wsum
}

/// Levenberg-Marquardt on the joint problem. `obs` must be sorted by point.
pub(crate) fn refine(
    obs: &[Obs],
    cfg: &JointConfig,
    state: &mut JointState,
    progress: &dyn Progress,
) -> CoreResult<JointReport> {
    let n_frames = state.log_e.len();
    let lay = Layout {
        nc: if cfg.fit_response { EMOR_DIM } else { 0 },
        nv: if cfg.fit_vignette { state.vig_dim() } else { 0 },
        ne: if cfg.fit_exposures {
            n_frames.saturating_sub(1)
        } else {
            0
        },
    };
    let dim = lay.dim();
    let wsum: f64 = obs
        .iter()
        .map(|o| f64::from(o.weight))
        .sum::<f64>()
        .max(1.0);
    let wpen = penalty_weight(wsum);
    let mut lambda = 1e-3;
    let mut small_steps = 0;
    let mut cost = total_cost(obs, cfg, state, wsum);
    let mut report = JointReport::default();
    // Point ranges.
    let mut ranges = Vec::new();
    let mut start = 0;
    for i in 1..=obs.len() {
        if i == obs.len() || obs[i].point != obs[start].point {
            ranges.push(start..i);
            start = i;
        }
    }
    for it in 0..cfg.max_iterations {
        progress.check()?;
        progress.report(cfg.label, it as u64, cfg.max_iterations as u64);
        report.iterations = it + 1;
        let curve = emor_basis().curve(&state.c);
        let exposure = exps(&state.log_e);
        // Deterministic parallel accumulation: fixed chunks, summed in order.
        let parts: Vec<(DMatrix<f64>, DVector<f64>, Vec<PointBlock>)> = ranges
            .par_chunks(POINT_CHUNK)
            .map(|chunk| accumulate(obs, chunk, state, &exposure, &curve, cfg, &lay))
            .collect();
        let mut h = DMatrix::<f64>::zeros(dim, dim);
        let mut g = DVector::<f64>::zeros(dim);
        let mut point_blocks: Vec<PointBlock> = Vec::with_capacity(ranges.len());
        for (ph, pg, pb) in parts {
            h += ph;
            g += pg;
            point_blocks.extend(pb);
        }
        // Symmetrise the upper-triangle accumulation.
        for a in 0..dim {
            for b in 0..a {
                h[(a, b)] = h[(b, a)];
            }
        }
        if cfg.fit_response {
            for (r, dc) in c_penalties(cfg, &curve) {
                for a in 0..EMOR_DIM {
                    g[a] += wpen * dc[a] * r;
                    for b in 0..EMOR_DIM {
                        h[(a, b)] += wpen * dc[a] * dc[b];
                    }
                }
            }
            for a in 0..EMOR_DIM {
                h[(a, a)] += 1e-9 * wsum;
            }
        }
        if lay.nv > 0
            && let Some(sp) = &state.spline
        {
            let ws = SPLINE_SMOOTHING * wsum;
            for (d, grad) in spline_penalties(sp) {
                for &(ia, ja) in &grad {
                    g[lay.nc + ia] -= ws * ja * d;
                    for &(ib, jb) in &grad {
                        h[(lay.nc + ia, lay.nc + ib)] += ws * ja * jb;
                    }
                }
            }
        }
        // Try steps with increasing damping until the cost drops.
        let mut accepted = false;
        for _ in 0..24 {
            let mut s = h.clone();
            let mut bs = g.clone();
            for a in 0..dim {
                s[(a, a)] += lambda * h[(a, a)].max(1e-12);
            }
            let mut dls = Vec::with_capacity(point_blocks.len());
            // The Schur complement's upper triangle only, then mirrored: the serial half of
            // an iteration (each entry gets the same products in the same order as the full
            // square would give it, so the result is the same to the bit). Done in parallel
            // chunks it took more CPU for no shorter wall time on two cores.
            let ss = s.as_mut_slice();
            for (hl, bl, cross) in &point_blocks {
                let hd = hl * (1.0 + lambda) + 1e-12;
                for (i, &(a, xa)) in cross.iter().enumerate() {
                    bs[a] -= xa * bl / hd;
                    for &(b, xb) in &cross[i..] {
                        let (lo, hi) = if a <= b { (a, b) } else { (b, a) };
                        ss[lo + hi * dim] -= xa * xb / hd;
                    }
                }
                dls.push(hd);
            }
            for a in 0..dim {
                for b in 0..a {
                    s[(a, b)] = s[(b, a)];
                }
            }
            let Some(chol) = s.clone().cholesky() else {
                lambda *= 10.0;
                continue;
            };
            let dd = chol.solve(&bs);
            let mut cand = state.clone();
            for k in 0..lay.nc {
                cand.c[k] += dd[k];
            }
            match cand.spline.as_mut() {
                Some(sp) => {
                    for m in 0..lay.nv {
                        sp.values[m + 1] += dd[lay.nc + m];
                    }
                }
                None => {
                    for m in 0..lay.nv {
                        cand.v[m] += dd[lay.nc + m];
                    }
                }
            }
            for f in 1..n_frames {
                if let Some(ei) = lay.e_index(f as u32) {
                    cand.log_e[f] += dd[ei];
                }
            }
            for (rg, ((_, bl, cross), hd)) in ranges.iter().zip(point_blocks.iter().zip(&dls)) {
                let pi = obs[rg.start].point as usize;
                let mut rhs = *bl;
                for &(a, xa) in cross {
                    rhs -= xa * dd[a];
                }
                cand.log_l[pi] += (rhs / hd).clamp(-2.0, 2.0);
            }
            let new_cost = total_cost(obs, cfg, &cand, wsum);
            if new_cost.is_finite() && new_cost < cost {
                let rel = (cost - new_cost) / cost.max(1e-30);
                *state = cand;
                cost = new_cost;
                lambda = (lambda / 3.0).max(1e-9);
                accepted = true;
                // Tiny decreases under heavy damping are not convergence: only stop after a
                // few consecutive negligible, lightly damped steps.
                if rel < 1e-8 && lambda < 1e-2 {
                    small_steps += 1;
                } else {
                    small_steps = 0;
                }
                if small_steps >= 3 {
                    report.converged = true;
                }
                break;
            }
            lambda *= 4.0;
        }
        if !accepted || report.converged {
            report.converged = true;
            break;
        }
    }
    if !cost.is_finite() {
        return Err(CoreError::NoSolution(
            "photometric refinement diverged".into(),
        ));
    }
    let curve = emor_basis().curve(&state.c);
    let (mut ss, mut n) = (0.0, 0usize);
    for o in obs {
        let e = state.log_e[o.frame as usize].exp()
            * state.vig(f64::from(o.r2))
            * state.log_l[o.point as usize].exp();
        let r = f64::from(o.value) - emor_value(&curve, e);
        if o.measured() && r.abs() <= 3.0 * cfg.huber && o.weight > 0.0 {
            ss += r * r;
            n += 1;
        }
    }
    report.rms = if n > 0 {
        (ss / n as f64).sqrt()
    } else {
        f64::NAN
    };
    report.inliers = n;
    report.cost = cost;
    Ok(report)
}

/// Move a start that assumed the mean response `f0` into the γ gauge `f(0.5) = gauge` without
/// changing what it predicts (see [`regauge`]). Starting in the right gauge sheet avoids a
/// first step dominated by the gauge constraint, after which LM can stall in the curved γ
/// valley.
pub(crate) fn gauge_start(state: &mut JointState, gauge: f64) {
    state.c = [0.0; EMOR_DIM];
    regauge(state, gauge);
}

/// Move `state` along the exponential ambiguity to the sheet `f(0.5) = gauge` while keeping
/// its predictions: `f̃(x) = f(x^k)` with `0.5^k = f⁻¹(gauge)`, exposures and radiances raised
/// to `1/k`, `Ṽ = V^{1/k}`; `f̃` and `Ṽ` are projected onto the EMoR basis and the
/// polynomial by least squares, so the move is exact only where the models can follow (that
/// residual is what makes some gauges fit better than others).
pub(crate) fn regauge(state: &mut JointState, gauge: f64) {
    use super::response::interp_table;
    let b = emor_basis();
    let curve = b.curve(&state.c);
    // f⁻¹(gauge) on the (monotone-repaired) table.
    let mut mono = curve.clone();
    for j in 1..mono.len() {
        mono[j] = mono[j].max(mono[j - 1] + 1e-9);
    }
    let n = (EMOR_SAMPLES - 1) as f64;
    let j = mono
        .partition_point(|&y| y < gauge)
        .clamp(1, EMOR_SAMPLES - 1);
    let (a, bb) = (mono[j - 1], mono[j]);
    let x_m = (j as f64 - 1.0 + ((gauge - a) / (bb - a).max(1e-12)).clamp(0.0, 1.0)) / n;
    let k = x_m.max(1e-6).ln() / 0.5f64.ln();
    if !(k.is_finite() && k > 0.05 && k < 20.0) {
        return;
    }
    let mut ata = nalgebra::Matrix4::<f64>::zeros();
    let mut atb = nalgebra::Vector4::<f64>::zeros();
    for j in 0..EMOR_SAMPLES {
        let x = j as f64 / n;
        let target = interp_table(&mono, x.powf(k)) - b.f0[j];
        for a in 0..EMOR_DIM {
            atb[a] += b.h[a][j] * target;
            for c in 0..EMOR_DIM {
                ata[(a, c)] += b.h[a][j] * b.h[c][j];
            }
        }
    }
    if let Some(ch) = ata.cholesky() {
        let c = ch.solve(&atb);
        state.c = [c[0], c[1], c[2], c[3]];
    }
    // V^{1/k} - 1 = v1 r² + v2 r⁴ + v3 r⁶ by least squares on r² ∈ [0, 1.2].
    let samples = (0..=48).map(|i| {
        let r2 = 1.2 * f64::from(i) / 48.0;
        (r2, vignette(&state.v, r2).powf(1.0 / k))
    });
    if let Some(v) = fit_even_polynomial(samples) {
        state.v = v;
    }
    if let Some(sp) = state.spline.as_mut() {
        for v in &mut sp.values {
            *v = v.max(1e-3).powf(1.0 / k);
        }
    }
    for l in state.log_e.iter_mut().chain(state.log_l.iter_mut()) {
        *l /= k;
    }
}

/// The polynomial `v` of [`vignette`] nearest, by least squares, to samples `(r², V)`; `None`
/// when the samples do not determine it.
pub(crate) fn fit_even_polynomial(samples: impl Iterator<Item = (f64, f64)>) -> Option<[f64; 3]> {
    let mut ata = nalgebra::Matrix3::<f64>::zeros();
    let mut atb = nalgebra::Vector3::<f64>::zeros();
    for (r2, v) in samples {
        let p = nalgebra::Vector3::new(r2, r2 * r2, r2 * r2 * r2);
        ata += p * p.transpose();
        atb += p * (v - 1.0);
    }
    let v = ata.cholesky()?.solve(&atb);
    Some([v[0], v[1], v[2]])
}

/// Points per parallel work item of the normal-equation accumulation.
const POINT_CHUNK: usize = 512;

/// Normal equations of a chunk of points: the dense block (upper triangle), its right-hand
/// side and each point's block for the Schur complement.
fn accumulate(
    obs: &[Obs],
    ranges: &[std::ops::Range<usize>],
    state: &JointState,
    exposure: &[f64],
    curve: &[f64],
    cfg: &JointConfig,
    lay: &Layout,
) -> (DMatrix<f64>, DVector<f64>, Vec<PointBlock>) {
    let dim = lay.dim();
    let mut scratch = vec![0.0; dim];
    let mut mark = vec![false; dim];
    let mut touched: Vec<usize> = Vec::new();
    let mut h = DMatrix::<f64>::zeros(dim, dim);
    let mut g = DVector::<f64>::zeros(dim);
    let mut point_blocks: Vec<PointBlock> = Vec::with_capacity(ranges.len());
    let mut unit = vec![0.0; state.spline.as_ref().map_or(0, |s| s.values.len())];
    let mut weights: Vec<(usize, f64)> = Vec::with_capacity(4);
    for rg in ranges {
        let pi = obs[rg.start].point as usize;
        let l = state.log_l[pi].exp();
        let (mut hl, mut bl) = (0.0, 0.0);
        touched.clear();
        for o in &obs[rg.clone()] {
            let r2 = f64::from(o.r2);
            let vg = state.vig(r2);
            let e = exposure[o.frame as usize] * vg * l;
            let ev = emor_eval(curve, e);
            let r = o.residual(ev.f);
            if o.inactive(r) {
                continue;
            }
            let wh = if r.abs() <= cfg.huber {
                1.0
            } else {
                cfg.huber / r.abs()
            };
            let w = f64::from(o.weight) * wh;
            let de = ev.df * e;
            let mut jac = [(0usize, 0.0f64); EMOR_DIM + 6];
            let mut nj = 0;
            for k in 0..lay.nc {
                jac[nj] = (k, ev.dc[k]);
                nj += 1;
            }
            match &state.spline {
                Some(sp) if lay.nv > 0 => {
                    sp.basis_into(r2.max(0.0).sqrt(), &mut unit, &mut weights);
                    for &(j, wj) in weights.iter().filter(|(j, _)| *j > 0) {
                        jac[nj] = (lay.nc + j - 1, de / vg * wj);
                        nj += 1;
                    }
                }
                _ => {
                    let mut rp = r2;
                    for m in 0..lay.nv {
                        jac[nj] = (lay.nc + m, de / vg * rp);
                        nj += 1;
                        rp *= r2;
                    }
                }
            }
            if let Some(ei) = lay.e_index(o.frame) {
                jac[nj] = (ei, de);
                nj += 1;
            }
            for a in 0..nj {
                let (ia, ja) = jac[a];
                g[ia] += w * ja * r;
                for &(ib, jb) in &jac[a..nj] {
                    h[(ia, ib)] += w * ja * jb;
                }
                if !mark[ia] {
                    mark[ia] = true;
                    touched.push(ia);
                }
                scratch[ia] += w * ja * de;
            }
            hl += w * de * de;
            bl += w * de * r;
        }
        let cross: Vec<(usize, f64)> = touched.iter().map(|&i| (i, scratch[i])).collect();
        for &i in &touched {
            scratch[i] = 0.0;
            mark[i] = false;
        }
        point_blocks.push((hl, bl, cross));
    }
    (h, g, point_blocks)
}
