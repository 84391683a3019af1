//! The three-term noise fit σ²(τ) = N²/τ + (0.6643·B)² + K²·τ/3 (weighted NNLS on the octave
//! points, as the peer), its uncertainty and determinability rules, the classic slope
//! read-offs and the upper bound on K.

use super::edf::{avar_interval, edf_for};
use super::types::{AdevPoint, ClassicReadoff, ImuNoiseParams, NoiseFit};

/// Flicker floor factor: the ADEV of flicker (1/f) rate noise is 0.6643·B (IEEE 952, C.2).
pub const FLICKER_FACTOR: f64 = 0.664_282_473_934_844_4;

/// Inflation of the formal fit uncertainty for the correlation between adjacent overlapping
/// octave estimates (treating them as independent would count each datum about twice).
const CORRELATION_INFLATION: f64 = std::f64::consts::SQRT_2;

/// The peer's fit (module doc) on the octave points of `curve` (marks them `fitted`), the
/// classic read-offs, and an upper bound on K.
///
/// Determinability: N, B, K are null when their NNLS term is 0 (the constraint is active: the
/// data do not show that noise), when the ADEV is still falling at the longest τ (for B and K:
/// no floor and no rising slope are visible), or when the 1-σ relative uncertainty exceeds
/// `max_relative_uncertainty`. That uncertainty comes from the same linear model on the support
/// of the solution, rows weighted by the χ² standard error of each AVAR, σ(σ²) = σ² √(2/edf),
/// with the EDF of the noise type the fitted model says dominates at that τ ([`edf_for`]; the
/// curve's intervals are updated the same way). Octave points are mildly correlated, so it is a
/// lower bound on the true spread: it is inflated by √2 to account for that.
pub fn fit_noise(
    curve: &mut [AdevPoint],
    params: &ImuNoiseParams,
    z: f64,
) -> (NoiseFit, ClassicReadoff, Option<f64>) {
    let mut idx = Vec::new();
    for (i, p) in curve.iter_mut().enumerate() {
        p.fitted = p.octave
            && p.tau_s >= params.fit_tau_min_s
            && p.clusters >= params.fit_min_clusters
            && p.adev.is_finite()
            && p.adev > 0.0;
        if p.fitted {
            idx.push(i);
        }
    }
    let mut fit = NoiseFit::default();
    let mut classic = ClassicReadoff::default();
    if idx.len() < 3 {
        let why = format!(
            "only {} usable τ (≥ {} s with ≥ {} clusters; need 3): log too short",
            idx.len(),
            params.fit_tau_min_s,
            params.fit_min_clusters
        );
        fit.n_reason = Some(why.clone());
        fit.b_reason = Some(why.clone());
        fit.k_reason = Some(why.clone());
        classic.reasons.push(why);
        return (fit, classic, None);
    }
    let tau: Vec<f64> = idx.iter().map(|&i| curve[i].tau_s).collect();
    let adev: Vec<f64> = idx.iter().map(|&i| curve[i].adev).collect();
    let clusters: Vec<f64> = idx.iter().map(|&i| curve[i].clusters).collect();
    let avar: Vec<f64> = adev.iter().map(|a| a * a).collect();
    let cols = |t: f64| [1.0 / t, 1.0, t / 3.0];

    // Weighted NNLS, exactly the peer's rows.
    let rows: Vec<[f64; 3]> = (0..tau.len())
        .map(|i| {
            let w = clusters[i].max(1.0).sqrt();
            let c = cols(tau[i]);
            [c[0] / avar[i] * w, c[1] / avar[i] * w, c[2] / avar[i] * w]
        })
        .collect();
    let rhs: Vec<f64> = clusters.iter().map(|c| c.max(1.0).sqrt()).collect();
    let coef = nnls3(&rows, &rhs);
    fit.raw = [
        coef[0].sqrt(),
        coef[1].sqrt() / FLICKER_FACTOR,
        coef[2].sqrt(),
    ];
    fit.taus_used = tau.len();
    fit.tau_range_used_s = [tau[0], tau[tau.len() - 1]];

    // Noise identification from the fitted model: each point's EDF and interval follow the
    // term that dominates its AVAR (white, flicker or random-walk rate noise).
    for p in curve.iter_mut() {
        let t = p.tau_s;
        let terms = [coef[0] / t, coef[1], coef[2] * t / 3.0];
        let dominant = (0..3)
            .max_by(|&a, &b| terms[a].total_cmp(&terms[b]))
            .unwrap_or(0);
        let n_phase = p.n_terms as usize + 2 * p.m as usize;
        p.edf = edf_for(dominant, n_phase, p.m as usize);
        let (lo, hi) = avar_interval(p.adev * p.adev, p.edf, z);
        p.ci_low = lo.map(f64::sqrt);
        p.ci_high = hi.map(f64::sqrt);
    }
    let edf: Vec<f64> = idx.iter().map(|&i| curve[i].edf.max(1.0)).collect();

    // Uncertainty on the support.
    let support: Vec<usize> = (0..3).filter(|&j| coef[j] > 0.0).collect();
    let mut rel_std = [None; 3];
    if !support.is_empty() {
        let k = support.len();
        let mut ata = nalgebra::DMatrix::<f64>::zeros(k, k);
        for i in 0..tau.len() {
            let sig = avar[i] * (2.0 / edf[i]).sqrt();
            let c = cols(tau[i]);
            for (a, &ja) in support.iter().enumerate() {
                for (b, &jb) in support.iter().enumerate() {
                    ata[(a, b)] += c[ja] * c[jb] / (sig * sig);
                }
            }
        }
        if let Some(inv) = ata.try_inverse() {
            for (a, &j) in support.iter().enumerate() {
                let var = inv[(a, a)];
                if var.is_finite() && var >= 0.0 {
                    // σ(√c)/√c = σ(c)/(2c), × √2 for the correlation of adjacent octave
                    // estimates (each shares data with its neighbours).
                    rel_std[j] = Some(CORRELATION_INFLATION * var.sqrt() / (2.0 * coef[j]));
                }
            }
        }
    }
    fit.rel_std = rel_std;

    let i_min = adev
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))
        .map_or(0, |(i, _)| i);
    let still_falling = i_min == tau.len() - 1;
    let last_tau = tau[tau.len() - 1];
    let max_rel = params.max_relative_uncertainty;

    // N
    if coef[0] > 0.0 {
        fit.n = Some(fit.raw[0]);
    } else {
        fit.n_reason =
            Some("fitted white-noise term is 0: the short-τ slope −½ is not visible".into());
    }
    // B, K
    let decide = |j: usize, name: &str, what: &str| -> (Option<f64>, Option<String>) {
        if still_falling {
            return (
                None,
                Some(format!(
                    "ADEV still falling at the longest usable τ ({last_tau:.1} s): no {what} \
                     visible, log too short for {name}"
                )),
            );
        }
        if coef[j] <= 0.0 {
            return (
                None,
                Some(format!(
                    "fitted {name} term is 0: {what} not visible within τ ≤ {last_tau:.1} s"
                )),
            );
        }
        match rel_std[j] {
            Some(r) if r <= max_rel => (Some(fit.raw[j]), None),
            Some(r) => (
                None,
                Some(format!(
                    "{name} = {:.3e} but uncertain (±{:.0} % at 1 σ > {:.0} %): log too short",
                    fit.raw[j],
                    100.0 * r,
                    100.0 * max_rel
                )),
            ),
            None => (None, Some(format!("{name} unconstrained (singular fit)"))),
        }
    };
    let (b, br) = decide(1, "B", "flicker floor");
    let (k, kr) = decide(2, "K", "rising +½ slope");
    fit.b = b;
    fit.b_reason = br;
    fit.k = k;
    fit.k_reason = kr;

    // Classic read-offs.
    let tmin = tau[i_min];
    let line = |sel: &dyn Fn(f64) -> bool, slope: f64| -> (Option<f64>, usize) {
        let mut s = 0.0;
        let mut c = 0usize;
        for i in 0..tau.len() {
            if sel(tau[i]) {
                s += adev[i].ln() - slope * tau[i].ln();
                c += 1;
            }
        }
        if c == 0 {
            (None, 0)
        } else {
            ((s / c as f64).exp().into(), c)
        }
    };
    let (nl, pn) = line(&|t| t <= tmin / 4.0, -0.5);
    let (kl, pk) = line(&|t| t >= tmin * 4.0, 0.5);
    classic.n_at_tau1 = nl;
    classic.points_for_n = pn;
    classic.k_at_tau3 = kl.map(|v| v * 3f64.sqrt());
    classic.points_for_k = pk;
    classic.tau_at_min_s = tmin;
    if nl.is_none() {
        classic
            .reasons
            .push("no point left of τ_min/4 for the −½ line".into());
    }
    if kl.is_none() {
        classic
            .reasons
            .push("no point right of 4·τ_min for the +½ line: log too short for K".into());
    }
    if still_falling {
        classic.reasons.push(
            "ADEV still falling at the longest usable τ: the minimum is not B's floor".into(),
        );
    } else {
        classic.b_min_over_0_6643 = Some(adev[i_min] / FLICKER_FACTOR);
    }

    // K upper bound from every fitted point's upper AVAR bound.
    let kub = idx
        .iter()
        .map(|&i| {
            let p = &curve[i];
            let hi = p.ci_high.unwrap_or(p.adev * 2.0);
            (3.0 * hi * hi / p.tau_s).sqrt()
        })
        .fold(f64::INFINITY, f64::min);
    (fit, classic, kub.is_finite().then_some(kub))
}

/// Non-negative least squares for 3 unknowns: min ‖A x − b‖ s.t. x ≥ 0, exactly, by trying the
/// unconstrained least-squares solution on each of the 7 supports and keeping the best feasible
/// one (the NNLS optimum is the unconstrained optimum on its own support).
fn nnls3(a: &[[f64; 3]], b: &[f64]) -> [f64; 3] {
    let resid = |x: &[f64; 3]| -> f64 {
        a.iter()
            .zip(b)
            .map(|(r, &bi)| {
                let v = r[0] * x[0] + r[1] * x[1] + r[2] * x[2] - bi;
                v * v
            })
            .sum()
    };
    let mut best = [0.0; 3];
    let mut best_r = resid(&best);
    for mask in 1u32..8 {
        let cols: Vec<usize> = (0..3).filter(|j| mask & (1 << j) != 0).collect();
        let m = nalgebra::DMatrix::from_fn(a.len(), cols.len(), |i, j| a[i][cols[j]]);
        let rhs = nalgebra::DVector::from_column_slice(b);
        let svd = m.svd(true, true);
        let Ok(sol) = svd.solve(&rhs, 1e-14) else {
            continue;
        };
        if sol.iter().any(|v| !(v.is_finite() && *v >= 0.0)) {
            continue;
        }
        let mut x = [0.0; 3];
        for (k, &j) in cols.iter().enumerate() {
            x[j] = sol[k];
        }
        let r = resid(&x);
        if r < best_r {
            best_r = r;
            best = x;
        }
    }
    best
}
