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
//!
//! Those independent starts are each a little short of convergence, by different amounts, and
//! near the best value the profile is flat enough for that to move the choice by a few
//! hundredths, which a concave camera pays dearly for (tuning#3, f(0.5) = 0.81: 0.781 chosen,
//! response / vignette / exposure error 0.013 / 0.019 / 4.9 %; with the gauge fixed at 0.81:
//! 0.0011 / 0.0010 / 0.4 %). So the choice is then polished by local steps whose fits are
//! warm-started from it. Tuning split: 8 → 11 of 12 cases within targets, response median
//! 0.0019 → 0.0010; held-out split (measured once, after): response median / worst 0.0013 /
//! 0.0082 → 0.0012 / 0.0035, still 8 of 12 (the four most saturated sequences); about 1.3 s
//! more per sequence.
//!
//! The local steps once stopped below 0.95 by skipping any bracket that would reach it, so a
//! choice at the grid's top value 0.92 was never refined, not even downwards: the `scripted`
//! tuning split's only miss (f(0.5) = 0.896, chosen 0.920). With the upper end pulled in
//! ([`local_bracket`]) that split went from 11 to 12 of 12 cases within targets; `tuning`
//! (11/12) and `saturated` (12/12) are unchanged, and so is the held-out `eval` split, measured
//! once after (8/12, identical numbers: none of its choices was at the top of the grid).
//!
//! On a scene of many small occluding shapes (the sweep's `scenes` split: dead leaves, added
//! to see whether the accuracy depends on the scene) the grid profile is ragged even so: on
//! `scenes#1` (f(0.5) = 0.68) the grid costs were 0.30 / 0.33 / 0.31 / **0.18** / 0.32 /
//! **0.20** / 0.39 / 1.00 over 0.25 … 0.92, the local steps from 0.55 settled at 0.58
//! (response / vignette / exposure error 0.0119 / 0.0080 / 3.0 %), while the fit at the true
//! gauge has the lower full-sample cost (`online/diag_tests.rs`, `diag_discs`). Polishing
//! the two cheapest local minima of the grid and keeping the cheaper result
//! ([`PROFILE_CANDIDATES`] = 2) fixes it: `scenes#1` → 0.0017 / 0.0025 / 0.76 %. Tuning
//! splits, cases within all four targets, one candidate → two: `tuning` 11 → 11, `scripted`
//! 12 → 12, `saturated` 12 → 12, `lens` 11 → 11, `scenes` 8 → 9 of 12, about 1 s more CPU per
//! sequence. But on the held-out `eval` split (run once with two, once with one, same day)
//! it stays at 8 of 12 with the same four misses, and three choices move where the profile is
//! flat — gamma-curve cameras, which every member of the family represents exactly, so the
//! cost cannot tell the members apart: `eval#1` (linear) exposure error 2.38 → 3.34 %,
//! `eval#0` (γ 2.6) response 0.0007 → 0.0013, `eval#11` exposure 0.56 → 0.36 %. No held-out
//! gain, so one candidate stays; [`polish`] and [`local_minima`] keep the experiment one
//! constant away. A margin that a second minimum must win by would keep flat profiles on the
//! first choice; it is untried (it would be tuned after seeing `eval`).
//!
//! Also tried (2026-12-04, not kept): relaxing the grid profile to its lower envelope, each
//! grid value refitted from a cheaper neighbour's converged state (forward, then backward) and
//! the cheaper fit kept. It smooths the ragged profiles (`scenes#1` → 0.0007 / 0.0024 / 0.45 %,
//! `scenes` 8 → 9 of 12, other tuning splits unchanged) for 1.2 s more per sequence, but the
//! held-out `eval` stays at 8 of 12 with two exposure errors worse (`eval#10` 2.12 → 2.99 %);
//! numbers in `examples/photometric_sweep.rs`.
//!
//! Also tried (2026-12-05, not kept): a prior on the response to break flat profiles, each
//! profiled cost multiplied by `1 + κ·d²`, `d²` the mean square distance of the fitted
//! response from the mean EMoR curve `f0` (so that a tie goes to the most typical curve; a
//! lead from `eval3#3`, whose costs at 0.80 and 0.85 differ by 0.1 %). Cases within the
//! accuracy targets on the five tuning splits (`tuning` / `saturated` / `lens` / `scenes` /
//! `scripted`; as shipped 11 / 12 / 11 / 8 / 12 = 54 of 60): κ = 1 10 / 11 / 11 / 9 / 11 = 52,
//! κ = 0.1 10 / 12 / 10 / 9 / ≥ 2 of 3 (stopped). The profiles of the strongly concave tuning
//! cameras are as flat as `eval3#3`'s and lean the other way: `tuning#1` (f(0.5) = 0.97) costs
//! 0.41692 at 0.854 and 0.41675 at 0.914 (0.04 %), chosen 0.914 as shipped (response 0.0034),
//! 0.85 with the prior (0.030). Where the data cannot tell the members apart a prior only
//! trades one response shape for another, so it is not in the fit; held-out splits were not
//! run with it. Nor does the flatness itself tell a miss, so it is not reported as a warning:
//! on `tuning#0`–`#8` the span of gauge values within 0.1 % of the best profiled cost is
//! 0.31–0.44 on the three gamma-curve cameras (every member of their family is a gamma curve,
//! so any gauge is right, and they pass), 0.06 and 0.08 on the two strongly concave ones (`#1`
//! passes, `#6` misses) and 0.001–0.06 on the others (all pass).
//!
//! The second tracking pass (`tracking_passes: 2`) profiles again on its new samples, and
//! there the grid sometimes misses the basin the first pass found: on `lens#3` the profile
//! chose 0.31 where the first pass's 0.54, refitted on the new samples from that choice's
//! state, costs 8.6 % less (response 0.0064 against 0.0004 at 0.54); `lens#7` −0.6 %. So the
//! first pass's gauge is one more candidate of the second pass's profile, kept when it costs
//! no more (2026-12-06). Tuning splits, cases within all targets (`tuning` / `saturated` /
//! `lens` / `scenes` / `scripted`, 2 passes): 10 / 12 / 10 / 11 / 12 = 55 → 10 / 12 / 12 / 11
//! / 12 = 57 of 60; median response 0.0012 → 0.0010. Preferring the first gauge unless the new
//! choice wins by 0.2 % also reached 57 (it fixes `tuning#1`, f(0.5) = 0.97, and loses
//! `lens#0`), with a tuned constant and a worse exposure median, so it was not taken.
//!
//! A colour camera (`channels: rgb`) has one gauge for its three responses, because the
//! exposures are shared: red and blue are fitted with green's exposures and vignetting held,
//! so the gauge that suits green may put red's curve outside the span. The profile therefore
//! sums, per gauge value, green's converged cost and the costs of red and blue fitted with
//! green's exposures and vignetting at that value (a profile over the joint likelihood of the
//! three channels).

use super::super::emor::EMOR_DIM;
use super::super::joint::{JointConfig, JointState, Obs, refine, regauge};
use super::channels::fit_with_shared;
use crate::error::{CoreError, CoreResult};
use crate::progress::Progress;
use rayon::prelude::*;

/// Gauge values `f(0.5)` profiled; EMoR responses of real cameras (DoRF) lie well inside.
/// 0.92 lets the parabola refine a best value of 0.85 (tuning cases with f(0.5) = 0.81 and
/// 0.82 went from response RMSE 0.021 and 0.034 to 0.002 and 0.003; no held-out case changed).
const GRID: [f64; 8] = [0.25, 0.35, 0.45, 0.55, 0.65, 0.75, 0.85, 0.92];

/// Scene points used for the profile (every n-th point above this).
pub(super) const PROFILE_POINTS: usize = 1500;

/// LM iterations per profiled gauge value (independent starts need about this many to settle;
/// 12 left the profile ragged).
const PROFILE_ITERATIONS: usize = 25;

/// Half-width of the local bracket around the profile's choice, and how many times it may
/// move (a move happens when an end of the bracket is the cheapest). Measured on the tuning
/// split only (see the module notes).
const LOCAL_STEP: f64 = 0.03;
const LOCAL_ROUNDS: usize = 2;

/// Local minima of the grid profile that are polished ([`polish`]); the cheapest result wins.
/// Each grid value is fitted from the mean-response start with a bounded number of
/// iterations, so on noisy observations the profile can be ragged and the truth's basin need
/// not hold the cheapest grid value; but two candidates gained nothing held out (module notes).
const PROFILE_CANDIDATES: usize = 1;

/// A previous pass's gauge closer than this to the new choice is not refitted (the local
/// steps already looked there).
const PREFER_MIN_GAP: f64 = 0.005;

/// Highest gauge value the local steps try (below the 0.95 that `gamma_gauge` accepts).
const LOCAL_MAX: f64 = 0.945;

/// LM iterations of another channel's response at a profiled gauge value (response and
/// radiances from two starts; with 15 some values stopped in a poorer basin).
const OTHER_ITERATIONS: usize = 25;

/// Another channel observed at the same tracks (`channels: rgb`): its samples (sorted by
/// point) and its number of points.
pub(crate) struct OtherChannel<'a> {
    pub obs: &'a [Obs],
    pub n_points: usize,
}

/// What the gauge choice takes besides the fitted channel's samples.
#[derive(Default, Clone, Copy)]
pub(crate) struct GaugeContext<'a> {
    /// Further colour channels sharing the exposures and vignetting (`channels: rgb`).
    pub others: &'a [OtherChannel<'a>],
    /// The previous tracking pass's gauge: one more candidate, kept when its fit on the new
    /// samples costs no more than the profile's choice (see the module notes).
    pub prefer: Option<f64>,
}

/// The profile's choice.
pub(super) struct GaugeChoice {
    /// Chosen `f(0.5)`.
    pub gauge: f64,
    /// The profile fit there (response, vignetting and exposures; radiances only of the
    /// subsampled points).
    pub state: JointState,
}

/// Every n-th point of `obs` so that about [`PROFILE_POINTS`] remain.
fn subsample(obs: &[Obs], n_points: usize) -> Vec<Obs> {
    let every = n_points.div_ceil(PROFILE_POINTS).max(1) as u32;
    obs.iter()
        .filter(|o| o.point % every == 0)
        .copied()
        .collect()
}

/// Profile the converged cost over the gauge value and return the best. `start` is the
/// mean-response start (response coefficients zero); `obs` is sorted by point. `others` are
/// further channels sharing the exposures and vignetting: their costs at each gauge value
/// are added (see the module notes).
pub(super) fn choose_gauge(
    obs: &[Obs],
    n_points: usize,
    start: &JointState,
    huber: f64,
    fit_vignette: bool,
    ctx: GaugeContext<'_>,
    progress: &dyn Progress,
) -> CoreResult<GaugeChoice> {
    let sub = subsample(obs, n_points);
    let other_subs: Vec<(Vec<Obs>, usize)> = ctx
        .others
        .iter()
        .map(|o| (subsample(o.obs, o.n_points), o.n_points))
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
        let mut cost = refine(&sub, &cfg(m), &mut st, progress)?.cost;
        for (o, n) in &other_subs {
            let (_, rep) = fit_with_shared(
                o,
                *n,
                &st.log_e,
                (&st.v, st.spline.as_ref()),
                &[[0.0; EMOR_DIM], st.c],
                huber,
                OTHER_ITERATIONS,
                "gauge",
                progress,
            )?;
            cost += rep.cost;
        }
        Ok((cost, st))
    };
    // Every value from the start moved into its own gauge sheet: warm starts carried one
    // value's unconverged shape into the next and made the profile ragged (issue-16 eval
    // cases with costs jumping 2× between neighbours).
    // `start` has the mean response (c = 0), so `run`'s regauge is the move into m's sheet.
    // The values are independent, so they are fitted in parallel: one fit on the profile's
    // subsample keeps two cores only half busy.
    let (costs, states): (Vec<f64>, Vec<JointState>) = GRID
        .par_iter()
        .map(|&m| run(start, m))
        .collect::<CoreResult<Vec<_>>>()?
        .into_iter()
        .unzip();
    // Polish each of the profile's best local minima, keep the cheapest (see
    // [`PROFILE_CANDIDATES`]).
    let candidates = local_minima(&costs, PROFILE_CANDIDATES);
    let mut best: Option<(f64, GaugeChoice)> = None;
    for &i in &candidates {
        let (cost, choice) = polish(&run, &costs, i, states[i].clone())?;
        if best.as_ref().is_none_or(|(c, _)| cost < *c) {
            best = Some((cost, choice));
        }
    }
    let (cost, choice) = best.ok_or_else(|| CoreError::input("no gauge value could be fitted"))?;
    // The previous pass's gauge is one more candidate, fitted from the choice's state so that
    // the two costs compare cleanly (module notes: the grid can miss its basin).
    let Some(m) = ctx
        .prefer
        .filter(|m| (m - choice.gauge).abs() > PREFER_MIN_GAP)
    else {
        return Ok(choice);
    };
    let (kept_cost, kept) = run(&choice.state, m)?;
    if kept_cost <= cost {
        return Ok(GaugeChoice {
            gauge: m,
            state: kept,
        });
    }
    Ok(choice)
}

/// Indices of the `n` cheapest strict local minima of a profile (ends count when lower than
/// their one neighbour), cheapest first; the argmin alone when there is none (a flat profile).
fn local_minima(costs: &[f64], n: usize) -> Vec<usize> {
    let mut out: Vec<usize> = (0..costs.len())
        .filter(|&i| {
            (i == 0 || costs[i] < costs[i - 1]) && (i + 1 == costs.len() || costs[i] < costs[i + 1])
        })
        .collect();
    out.sort_by(|&a, &b| costs[a].total_cmp(&costs[b]));
    out.truncate(n);
    if out.is_empty() {
        out.extend((0..costs.len()).min_by(|&a, &b| costs[a].total_cmp(&costs[b])));
    }
    out
}

/// A converged profile fit at one gauge value: its cost and state.
type Profiled = (f64, JointState);

/// The grid value `GRID[best]` (cost `costs[best]`, state `state`) polished: the parabola
/// through it and its grid neighbours, then local steps whose fits are warm-started from the
/// choice, so their costs compare cleanly where the grid's did not (module notes). Returns
/// the final cost with the choice.
fn polish(
    run: &(dyn Fn(&JointState, f64) -> CoreResult<Profiled> + Sync),
    costs: &[f64],
    best: usize,
    state: JointState,
) -> CoreResult<(f64, GaugeChoice)> {
    let mut cost = costs[best];
    let mut choice = GaugeChoice {
        gauge: GRID[best],
        state,
    };
    // Parabola through the best value and its neighbours (the grid is not evenly spaced at
    // its top end, so the general three-point vertex).
    if best > 0
        && best + 1 < GRID.len()
        && let Some(m) = parabola_vertex(
            [GRID[best - 1], GRID[best], GRID[best + 1]],
            [costs[best - 1], costs[best], costs[best + 1]],
        )
    {
        let (cm, sm) = run(&choice.state, m)?;
        if cm < cost {
            cost = cm;
            choice = GaugeChoice {
                gauge: m,
                state: sm,
            };
        }
    }
    for _ in 0..LOCAL_ROUNDS {
        let m = choice.gauge;
        let Some(xs) = local_bracket(m) else {
            break;
        };
        let mut fits = xs
            .par_iter()
            .map(|&x| run(&choice.state, x))
            .collect::<CoreResult<Vec<_>>>()?;
        let ys = [fits[0].0, fits[1].0, fits[2].0];
        let lo = (0..3).min_by(|&a, &b| ys[a].total_cmp(&ys[b])).unwrap_or(1);
        let vertex = match parabola_vertex(xs, ys) {
            Some(v) if lo == 1 => Some(v.clamp(xs[0], xs[2])),
            _ => None,
        };
        let (c, best_state) = fits.swap_remove(lo);
        cost = c;
        choice = GaugeChoice {
            gauge: xs[lo],
            state: best_state,
        };
        if let Some(v) = vertex {
            let (cv, sv) = run(&choice.state, v)?;
            if cv < cost {
                cost = cv;
                choice = GaugeChoice {
                    gauge: v,
                    state: sv,
                };
            }
        }
        if lo == 1 {
            break; // bracketed: the vertex was the last step
        }
    }
    Ok((cost, choice))
}

/// The local step's bracket around `m`, `None` at the ends of the range. Near the top the
/// upper end is pulled in to [`LOCAL_MAX`] rather than the step skipped ([`parabola_vertex`]
/// takes uneven spacing): a choice at the grid's top value (0.92) must still be able to move.
/// Skipping it (the first version, `m + LOCAL_STEP ≥ 0.95`) left the sweep's scripted#7
/// (f(0.5) = 0.896) at 0.920: response / vignette / exposure error 0.0153 / 0.0196 / 2.11 %
/// → 0.0011 / 0.0035 / 0.54 % at 0.898 with the bracket (`online/diag_truth_tests.rs` shows
/// the full-sample cost agrees).
fn local_bracket(m: f64) -> Option<[f64; 3]> {
    let xs = [m - LOCAL_STEP, m, (m + LOCAL_STEP).min(LOCAL_MAX)];
    (xs[0] > 0.05 && xs[2] - m >= 0.005).then_some(xs)
}

/// Abscissa of the vertex of the parabola through `(x[i], y[i])`, when it is a minimum
/// (`None` for a flat or concave triple).
fn parabola_vertex(x: [f64; 3], y: [f64; 3]) -> Option<f64> {
    let (d0, d2) = (x[1] - x[0], x[1] - x[2]);
    let (e0, e2) = (y[1] - y[0], y[1] - y[2]);
    // Second divided difference > 0 ⇔ convex.
    let convex = (y[2] - y[1]) / (x[2] - x[1]) - (y[1] - y[0]) / (x[1] - x[0]) > 0.0;
    let den = d0 * e2 - d2 * e0;
    if !convex || den == 0.0 {
        return None;
    }
    Some(x[1] - 0.5 * (d0 * d0 * e2 - d2 * d2 * e0) / den)
}

#[cfg(test)]
mod tests {
    use super::{GRID, LOCAL_MAX, local_bracket, local_minima, parabola_vertex};

    /// A ragged profile (the sweep's `scenes#1` grid: the truth, 0.68, lies in the basin of
    /// the second-cheapest grid value) yields both minima, cheapest first; a monotone one its
    /// end; a flat one its first value.
    #[test]
    fn local_minima_of_a_ragged_profile() {
        let ragged = [0.303, 0.334, 0.310, 0.182, 0.321, 0.195, 0.394, 1.002];
        assert_eq!(local_minima(&ragged, 2), vec![3, 5]);
        assert_eq!(local_minima(&ragged, 3), vec![3, 5, 0]);
        assert_eq!(local_minima(&[0.5, 0.4, 0.3, 0.2], 2), vec![3]);
        assert_eq!(local_minima(&[0.2; 4], 2), vec![0]);
    }

    /// The grid's top value still gets a local step (with the upper end pulled in), and the
    /// bracket's vertex formula handles the uneven spacing; at the very top there is none.
    #[test]
    fn local_bracket_at_the_top_of_the_grid() {
        let top = GRID[GRID.len() - 1];
        let xs = local_bracket(top).expect("a bracket at the grid's top");
        assert!(xs[0] < top && xs[2] > top && xs[2] <= LOCAL_MAX, "{xs:?}");
        let f = |x: f64| 5.0 * (x - 0.9) * (x - 0.9);
        let v = parabola_vertex(xs, xs.map(f)).expect("convex");
        assert!((v - 0.9).abs() < 1e-9, "{v}");
        assert!(local_bracket(LOCAL_MAX - 0.001).is_none());
        assert!(local_bracket(0.06).is_none());
        let mid = local_bracket(0.5).expect("a bracket mid-range");
        assert!(
            (mid[0] - 0.47).abs() < 1e-12 && (mid[2] - 0.53).abs() < 1e-12,
            "{mid:?}"
        );
    }

    #[test]
    fn vertex_of_an_unevenly_sampled_parabola() {
        let f = |x: f64| 3.0 * (x - 0.81) * (x - 0.81) + 0.2;
        let x = [0.75, 0.85, 0.92];
        let m = parabola_vertex(x, x.map(f)).expect("convex");
        assert!((m - 0.81).abs() < 1e-12, "{m}");
        assert!(parabola_vertex(x, x.map(|x| -f(x))).is_none());
    }
}
