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
//! final fit on all points at the chosen `m`.

use super::super::joint::{JointConfig, JointState, Obs, refine, regauge};
use crate::error::CoreResult;
use crate::progress::Progress;

/// Gauge values `f(0.5)` profiled; EMoR responses of real cameras (DoRF) lie well inside.
const GRID: [f64; 7] = [0.25, 0.35, 0.45, 0.55, 0.65, 0.75, 0.85];

/// Scene points used for the profile (every n-th point above this).
pub(super) const PROFILE_POINTS: usize = 1500;

/// LM iterations per profiled gauge value (warm-started from the neighbour).
const PROFILE_ITERATIONS: usize = 12;

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
        max_iterations: PROFILE_ITERATIONS,
        label: "gauge",
    };
    let run = |from: &JointState, m: f64| -> CoreResult<(f64, JointState)> {
        let mut st = from.clone();
        regauge(&mut st, m);
        let rep = refine(&sub, &cfg(m), &mut st, progress)?;
        Ok((rep.cost, st))
    };
    // Start in the middle, then walk out both ways, each value warm-started from its
    // neighbour (a shape that fits at `m` is a good start at `m ± 0.1`).
    let mid = GRID.len() / 2;
    let mut costs = vec![f64::INFINITY; GRID.len()];
    let mut states: Vec<Option<JointState>> = vec![None; GRID.len()];
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
