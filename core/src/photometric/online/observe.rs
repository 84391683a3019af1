//! Tracking and sampling: the observations the fit reads.
//!
//! [`observe`] tracks corners through the video ([`super::klt`]) and samples a few pixels around
//! each track in every frame. In a second pass (`tracking_passes: 2`) every match is re-aligned
//! to its birth template through the first fit's response ([`super::response_match`]).

use super::super::PhotoImage;
use super::super::joint::{Censor, Obs};
use super::super::vignette::VignetteModel;
use super::OnlineParams;
use super::klt::{KltConfig, Track, patch, track_and_refine};
use super::pyramid::{GRAD_X, GRAD_Y, Level, Pyramid, VALUE, min_eigen};
use super::response_match::ResponseMatch;
use super::similarity::Similarity;
use crate::error::{CoreError, CoreResult};
use crate::progress::Progress;

const OFFSETS: [[f32; 2]; 9] = [
    [0.0, 0.0],
    [2.0, 0.0],
    [-2.0, 0.0],
    [0.0, 2.0],
    [0.0, -2.0],
    [2.0, 2.0],
    [-2.0, -2.0],
    [2.0, -2.0],
    [-2.0, 2.0],
];

/// Frames after which a track ends (its cell is re-detected). Chosen on the sweep's tuning
/// split when the birth patch was matched by translation only and drifted as the patch turned
/// and scaled (0.5 px after 70 frames, `diag_tests.rs`): targets met on 7 of 12 cases with 40,
/// 5 with 80, 4 without. With the roll-and-zoom chain the drift no longer grows with age
/// (~0.07 px median at every age); 80 frames then gave the same 8 of 12 tuning cases within the
/// accuracy targets (medians 0.0022 / 0.0018 / 0.51 % against 0.0019 / 0.0019 / 0.61 %) for
/// more time, so the cap stays, also for perspective changes that a similarity does not follow.
const MAX_TRACK_AGE: u32 = 40;

/// Gradient (normalised intensity per pixel) at which a sample's weight halves.
pub(crate) const GRAD_HALF_WEIGHT: f32 = 0.03;

/// Samples of tracked scene points, sorted by point (renumbered densely) then frame.
#[derive(Clone)]
pub(crate) struct Observations {
    pub obs: Vec<Obs>,
    pub n_points: u32,
    pub used_tracks: usize,
    pub mean_len: f64,
    /// Image position of each observation (same order as `obs`): the vignetting centre fit
    /// and the colour channels' samples read it.
    pub pos: Vec<[f32; 2]>,
    /// The mean normalised level each pixel recorded ([`super::circle::mean_levels`]): where
    /// a fisheye's image circle ends. Empty when not known.
    pub mean_level: Vec<f32>,
    /// The recorded gradient at each observation (same order as `obs`), normalised levels per
    /// pixel: the border stage reweights with it. Empty when not known.
    pub grad: Vec<[f32; 2]>,
}

/// A frame's intensities normalised to `[0, 1]`.
fn normalised(im: &PhotoImage) -> Vec<f32> {
    let s = 1.0 / f32::from(im.max_level);
    im.data.iter().map(|&v| f32::from(v) * s).collect()
}

/// Track features through the video and sample them; `rm`: the response of a previous pass,
/// through which the matches are re-aligned to their birth templates.
pub(crate) fn observe(
    frames: &[PhotoImage],
    params: &OnlineParams,
    w: usize,
    h: usize,
    rm: Option<&ResponseMatch>,
    progress: &dyn Progress,
) -> CoreResult<Observations> {
    let cfg = KltConfig {
        half_window: params.half_window as i32,
        iterations: 8,
        max_residual: params.max_track_residual as f32,
        max_fb: 0.3,
    };
    let border = (params.half_window + 3) as f32;
    let cell = (((w * h) as f64 / params.max_features as f64)
        .sqrt()
        .max(4.0)) as usize;
    let mut samples = Sampler::new(params, w, h);
    let mut tracks: Vec<Track> = Vec::new();
    let mut track_len: Vec<u32> = Vec::new();
    let mut prev: Option<Pyramid> = None;
    let mut chain = Similarity::IDENTITY;
    let build = |im: &PhotoImage| Pyramid::new(w, h, normalised(im), params.pyramid_levels);
    // The next frame's pyramid, built while this frame's tracks are matched (the build is
    // serial, the matching parallel: overlapping them keeps both cores busy).
    let mut pending: Option<Pyramid> = None;
    for (k, im) in frames.iter().enumerate() {
        progress.check()?;
        let stage = if rm.is_some() { "retrack" } else { "track" };
        progress.report(stage, k as u64, frames.len() as u64);
        let pyr = pending.take().unwrap_or_else(|| build(im));
        if let Some(pp) = &prev {
            // Tracks at the age limit end here, before they cost a match.
            tracks.retain(|t| track_len[t.id] < MAX_TRACK_AGE);
            let (tracked, next) = rayon::join(
                || track_and_refine(pp, &pyr, &tracks, &cfg, &mut chain, rm),
                || frames.get(k + 1).map(build),
            );
            pending = next;
            let mut kept = Vec::with_capacity(tracks.len());
            for (t, q) in tracks.drain(..).zip(tracked) {
                if let Some(q) = q.filter(|q| {
                    q[0] >= border
                        && q[1] >= border
                        && q[0] < w as f32 - border
                        && q[1] < h as f32 - border
                }) {
                    kept.push(Track {
                        vel: [q[0] - t.pos[0], q[1] - t.pos[1]],
                        pos: q,
                        ..t
                    });
                }
            }
            tracks = kept;
        }
        let l0 = &pyr.levels[0];
        // Re-detect in empty grid cells.
        if tracks.len() < params.max_features * 9 / 10 {
            let score = min_eigen(l0, 2);
            let (gw, gh) = (w.div_ceil(cell), h.div_ceil(cell));
            let mut occupied = vec![false; gw * gh];
            for t in &tracks {
                let (cx, cy) = (t.pos[0] as usize / cell, t.pos[1] as usize / cell);
                occupied[cy.min(gh - 1) * gw + cx.min(gw - 1)] = true;
            }
            let b = border as usize + 2;
            for gy in 0..gh {
                for gx in 0..gw {
                    if occupied[gy * gw + gx] {
                        continue;
                    }
                    let mut best = (1e-4f32, None);
                    for y in (gy * cell).max(b)..((gy + 1) * cell).min(h.saturating_sub(b)) {
                        for x in (gx * cell).max(b)..((gx + 1) * cell).min(w.saturating_sub(b)) {
                            if score[y * w + x] > best.0 {
                                best = (score[y * w + x], Some([x as f32, y as f32]));
                            }
                        }
                    }
                    if let (_, Some(p)) = best
                        && let Some(tmpl) = patch(&pyr, p, cfg.half_window)
                    {
                        tracks.push(Track {
                            id: track_len.len(),
                            pos: p,
                            vel: [0.0; 2],
                            birth: chain,
                            tmpl,
                        });
                        track_len.push(0);
                    }
                }
            }
        }
        for t in &tracks {
            track_len[t.id] += 1;
            samples.sample(l0, k, t.id, t.pos, chain.since(t.birth));
        }
        prev = Some(pyr);
    }
    let mut seen = samples.finish(&track_len)?;
    seen.mean_level = super::circle::mean_levels(frames);
    Ok(seen)
}

/// Collects the pixel samples around tracks.
struct Sampler {
    low_cut: f64,
    high_cut: f64,
    n_off: usize,
    max_points: usize,
    w: usize,
    vig0: VignetteModel,
    obs: Vec<Obs>,
    pos: Vec<[f32; 2]>,
    grad: Vec<[f32; 2]>,
}

impl Sampler {
    fn new(params: &OnlineParams, w: usize, h: usize) -> Self {
        Self {
            low_cut: params.low_cut,
            high_cut: params.high_cut,
            n_off: params.samples_per_track,
            max_points: params.max_points,
            w,
            vig0: VignetteModel::centered(w, h, [0.0; 3]),
            obs: Vec::new(),
            pos: Vec::new(),
            grad: Vec::new(),
        }
    }

    /// The samples of track `id` centred at `c` in frame `k` (level 0 `l0`), the sample
    /// pattern laid out with `warp` (the roll and zoom since the track's birth).
    fn sample(&mut self, l0: &Level, k: usize, id: usize, c: [f32; 2], warp: Similarity) {
        let w = self.w;
        for (o, off) in OFFSETS[..self.n_off].iter().enumerate() {
            let [ox, oy] = warp.apply(*off);
            let (x, y) = (c[0] + ox, c[1] + oy);
            let (Some(v), Some(gx), Some(gy)) = (
                l0.sample(VALUE, x, y),
                l0.sample(GRAD_X, x, y),
                l0.sample(GRAD_Y, x, y),
            ) else {
                continue;
            };
            // A sample at or beyond a cut with its whole bilinear support on that side is a
            // bound (censored, see `Censor`); one that blends clipped and unclipped pixels
            // is biased and left out.
            let (x0, y0) = (x.floor() as usize, y.floor() as usize);
            let i0 = y0 * w + x0;
            let [Some(a), Some(b), Some(c), Some(d)] =
                [i0, i0 + 1, i0 + w, i0 + w + 1].map(|i| l0.value(i))
            else {
                continue;
            };
            let px = [v, a, b, c, d];
            let low = px.iter().any(|&p| f64::from(p) <= self.low_cut);
            let high = px.iter().any(|&p| f64::from(p) >= self.high_cut);
            let (value, censor) = match (low, high) {
                (false, false) => (v, Censor::Exact),
                (false, true) if f64::from(v) >= self.high_cut => {
                    (self.high_cut as f32, Censor::AtLeast)
                }
                (true, false) if f64::from(v) <= self.low_cut => {
                    (self.low_cut as f32, Censor::AtMost)
                }
                _ => continue,
            };
            let g2 = (gx * gx + gy * gy) / (GRAD_HALF_WEIGHT * GRAD_HALF_WEIGHT);
            self.pos.push([x, y]);
            self.grad.push([gx, gy]);
            self.obs.push(Obs {
                point: (id * self.n_off + o) as u32,
                frame: k as u32,
                r2: self.vig0.r2(f64::from(x), f64::from(y)) as f32,
                value,
                weight: 1.0 / (1.0 + g2),
                censor,
            });
        }
    }

    /// Points with ≥ 2 measured samples, evenly subsampled to `max_points`, renumbered
    /// densely; `track_len`: frames each track was sampled in.
    fn finish(self, track_len: &[u32]) -> CoreResult<Observations> {
        let Self {
            obs,
            pos,
            grad,
            n_off,
            max_points,
            ..
        } = self;
        let used_tracks = track_len.iter().filter(|&&n| n >= 2).count();
        let mean_len = if used_tracks > 0 {
            track_len
                .iter()
                .filter(|&&n| n >= 2)
                .map(|&n| f64::from(n))
                .sum::<f64>()
                / used_tracks as f64
        } else {
            0.0
        };
        let mut order: Vec<u32> = (0..obs.len() as u32).collect();
        order.sort_by_key(|&i| (obs[i as usize].point, obs[i as usize].frame));
        let mut obs: Vec<Obs> = order.iter().map(|&i| obs[i as usize]).collect();
        let mut pos: Vec<[f32; 2]> = order.iter().map(|&i| pos[i as usize]).collect();
        let mut grad: Vec<[f32; 2]> = order.iter().map(|&i| grad[i as usize]).collect();
        drop(order);
        let n_raw = (track_len.len() * n_off) as u32;
        let mut count = vec![0u32; n_raw as usize];
        for o in obs.iter().filter(|o| o.measured()) {
            count[o.point as usize] += 1;
        }
        let eligible: Vec<u32> = (0..n_raw).filter(|&p| count[p as usize] >= 2).collect();
        let keep_every = eligible.len().div_ceil(max_points).max(1);
        let mut remap = vec![u32::MAX; n_raw as usize];
        let mut n_points = 0u32;
        for &p in eligible.iter().step_by(keep_every) {
            remap[p as usize] = n_points;
            n_points += 1;
        }
        // Positions and gradients follow their observations (before `obs` is renumbered).
        let kept: Vec<bool> = obs
            .iter()
            .map(|o| remap[o.point as usize] != u32::MAX)
            .collect();
        let mut keep = kept.iter();
        pos.retain(|_| keep.next().copied().unwrap_or(false));
        let mut keep = kept.iter();
        grad.retain(|_| keep.next().copied().unwrap_or(false));
        obs.retain_mut(|o| {
            let m = remap[o.point as usize];
            o.point = m;
            m != u32::MAX
        });
        if n_points < 20 || obs.len() < 200 {
            return Err(CoreError::input(format!(
                "only {n_points} trackable scene points ({} samples): the video needs texture \
                 and overlap between frames",
                obs.len()
            )));
        }
        Ok(Observations {
            obs,
            n_points,
            used_tracks,
            mean_len,
            pos,
            mean_level: Vec::new(),
            grad,
        })
    }
}
