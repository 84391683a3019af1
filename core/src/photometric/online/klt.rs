//! Gain-robust KLT tracking on an image pyramid.
//!
//! Auto exposure changes the brightness of every frame, which breaks the brightness-constancy
//! assumption of Lucas-Kanade. Following Kim, Frahm & Pollefeys ("Joint Feature Tracking and
//! Radiometric Calibration from Auto-Exposed Video", ICCV 2007) and Kim & Pollefeys (PAMI
//! 2008), each feature's patch is matched with a brightness change: we solve
//! `J(q + x) ≈ α · T(x) + β + γ · (T(x) − ½)²` for the displacement, the gain α, the bias β and
//! a curvature γ by Gauss-Newton, coarse to fine (γ, our addition, follows the camera response
//! over the patch's range; see [`align_step`]). A forward-backward check rejects drifting tracks.

use super::pyramid::{GridWindow, Level, Pyramid, VALUE, clipped};
use super::response_match::{ResponseMatch, refine_with_response};
use super::similarity::Similarity;

/// Tracker settings.
#[derive(Debug, Clone, Copy)]
pub(crate) struct KltConfig {
    pub half_window: i32,
    pub iterations: usize,
    /// Largest accepted RMS of the brightness-compensated patch residual.
    pub max_residual: f32,
    /// Largest accepted forward-backward distance in pixels.
    pub max_fb: f32,
}

/// Intensity about which the quadratic brightness term is centred (keeps it nearly orthogonal
/// to gain and bias, so the 5×5 system stays well conditioned).
const QUAD_CENTRE: f32 = 0.5;

/// Brightness state of a match: `J(q + x) ≈ gain·T(x) + bias + quad·(T(x) − ½)²`.
#[derive(Debug, Clone, Copy)]
struct Brightness {
    gain: f32,
    bias: f32,
    quad: f32,
}

impl Brightness {
    const IDENTITY: Self = Self {
        gain: 1.0,
        bias: 0.0,
        quad: 0.0,
    };
}

/// One Gauss-Newton step of the brightness-compensated translation model
/// `gain·T + bias + quad·(T − ½)² ≈ J(q + ·)` of the template `tmpl` (a `(2·hw + 1)²` window,
/// raster order) on level `lb` at `q`: the step `(dx, dy, dgain, dbias, dquad)` in that level's
/// pixels and the RMS residual. `None` when a sample leaves the level, fewer than half the
/// pixels are usable (clipped), or the system is singular.
///
/// Half, not fewer: accepting a quarter keeps tracks alive longer in heavily clipped video
/// (`diag_tests.rs`, scripted steps on a linear camera: vignetting error 0.0055 → 0.0031), but
/// the matches of mostly clipped patches are less accurate (a scripted sweep's exposure error
/// 0.56 → 0.79 %), and on the sweep's tuning split 10 instead of 11 of 12 cases met the targets
/// (tuning#1: vignetting 0.0029 → 0.0100, exposure 0.49 → 2.36 %; response median 0.0009 →
/// 0.0016).
///
/// Why a quadratic term: between two exposures the same scene patch is related by the
/// camera's response, `J = f(k·f⁻¹(T))`, which is not affine over a patch with contrast. An
/// affine model leaves a residual that is odd about an edge's midpoint, and the least-squares
/// shift absorbs it: the match slides towards the side where the mapping is steeper, by a
/// fraction of a pixel that grows with the exposure ratio to the template. For the template of
/// a track's birth, that ratio is largest in the quickly changing first frames of an
/// auto-exposure clip, and the sliding samples then bias those frames' exposures. The
/// quadratic term follows the curvature of the mapping over the patch's range.
fn align_step(
    lb: &Level,
    tmpl: &[f32],
    hw: i32,
    q: [f32; 2],
    b: Brightness,
    warp: Similarity,
) -> Option<([f64; 5], f32)> {
    let mut hm = [[0.0f32; 5]; 5];
    let mut g = [0.0f32; 5];
    let mut ss = 0.0f32;
    let mut used = 0usize;
    let mut add = |t: f32, [j, jx, jy]: [f32; 3]| {
        used += 1;
        let t2 = (t - QUAD_CENTRE) * (t - QUAD_CENTRE);
        let r = b.gain * t + b.bias + b.quad * t2 - j;
        ss += r * r;
        normal_add(&mut hm, &mut g, &[jx, jy, -t, -1.0, -t2], r);
    };
    match (warp == Similarity::IDENTITY)
        .then(|| GridWindow::inside(lb, q, hw))
        .flatten()
    {
        // Frame-to-frame tracking: the window is the level's pixel grid shifted by one
        // fraction, so the bilinear weights and row offsets are computed once (the per-pixel
        // sampling was a quarter of the fit's time).
        Some(grid) => grid.for_each(lb, tmpl, &mut add),
        None => {
            for (k, x, y) in window(hw, warp, q) {
                let t = tmpl[k];
                // All four pixels of the bilinear support must be unclipped: a clipped
                // neighbour's true value is beyond the clip, so the interpolation is biased.
                let s = lb.sample3(x, y)?;
                if clipped(t) || lb.support_clipped(x, y) {
                    continue;
                }
                add(t, s);
            }
        }
    }
    if used < tmpl.len() / 2 {
        return None;
    }
    // A small ridge on the quadratic term: a patch with only two grey levels (a clean step
    // edge) does not determine it, and then it should stay near 0.
    let ridge = 1e-4 * used as f64;
    let m = nalgebra::Matrix5::from_fn(|i, j| {
        let d = if i != j {
            0.0
        } else if i == 4 {
            ridge
        } else {
            1e-9
        };
        f64::from(hm[i.min(j)][i.max(j)]) + d
    });
    let step = m.lu().solve(&nalgebra::Vector5::from(g.map(f64::from)))?;
    Some((
        [step[0], step[1], step[2], step[3], step[4]],
        (ss / used as f32).sqrt(),
    ))
}

/// Add one residual `r` with Jacobian row `jac` to the normal equations (`hm`'s upper
/// triangle, `g` = Σ jac·r) of a Gauss-Newton match.
#[inline]
pub(crate) fn normal_add<const N: usize>(
    hm: &mut [[f32; N]; N],
    g: &mut [f32; N],
    jac: &[f32; N],
    r: f32,
) {
    for i in 0..N {
        g[i] += jac[i] * r;
        for m in i..N {
            hm[i][m] += jac[i] * jac[m];
        }
    }
}

/// The template pixels of a `(2·hw + 1)²` window in raster order, laid out with `warp` around
/// `q`: `(index, x, y)`.
pub(crate) fn window(
    hw: i32,
    warp: Similarity,
    q: [f32; 2],
) -> impl Iterator<Item = (usize, f32, f32)> {
    (-hw..=hw)
        .flat_map(move |dy| (-hw..=hw).map(move |dx| (dx, dy)))
        .enumerate()
        .map(move |(i, (dx, dy))| {
            let [ox, oy] = warp.apply([dx as f32, dy as f32]);
            (i, q[0] + ox, q[1] + oy)
        })
}

/// Apply the brightness part of an [`align_step`] step; `false` when the gain leaves the
/// plausible range (the match is then rejected).
fn update_brightness(b: &mut Brightness, step: &[f64; 5]) -> bool {
    b.gain += step[2] as f32;
    b.bias += step[3] as f32;
    b.quad += step[4] as f32;
    (0.05..=20.0).contains(&b.gain)
}

/// Track one point from `a` to `b` (level-0 coordinates); returns the new position.
fn track_one(
    a: &Pyramid,
    b: &Pyramid,
    p: [f32; 2],
    guess: [f32; 2],
    cfg: &KltConfig,
    max_levels: usize,
) -> Option<[f32; 2]> {
    let nl = a.levels.len().min(b.levels.len()).min(max_levels);
    let hw = cfg.half_window;
    let npx = ((2 * hw + 1) * (2 * hw + 1)) as usize;
    let mut d = [guess[0] - p[0], guess[1] - p[1]];
    let mut bright = Brightness::IDENTITY;
    let mut tmpl = vec![0.0f32; npx];
    let mut last_rms = f32::INFINITY;
    for l in (0..nl).rev() {
        let s = 1.0 / (1u32 << l) as f32;
        let (la, lb) = (&a.levels[l], &b.levels[l]);
        let (px, py) = (p[0] * s, p[1] * s);
        if let Some(grid) = GridWindow::inside(la, [px, py], hw) {
            grid.values(la, &mut tmpl);
        } else {
            let mut k = 0;
            for dy in -hw..=hw {
                for dx in -hw..=hw {
                    tmpl[k] = la.sample(VALUE, px + dx as f32, py + dy as f32)?;
                    k += 1;
                }
            }
        }
        for _ in 0..cfg.iterations {
            let (step, rms) = align_step(
                lb,
                &tmpl,
                hw,
                [px + d[0] * s, py + d[1] * s],
                bright,
                Similarity::IDENTITY,
            )?;
            last_rms = rms;
            // Step is in this level's pixels.
            d[0] += (step[0] as f32) / s;
            d[1] += (step[1] as f32) / s;
            if !update_brightness(&mut bright, &step) {
                return None;
            }
            if step[0].abs() + step[1].abs() < 0.02 {
                break;
            }
        }
    }
    (last_rms <= cfg.max_residual).then_some([p[0] + d[0], p[1] + d[1]])
}

/// Track with a forward-backward check; `None` when lost.
pub(crate) fn track(
    a: &Pyramid,
    b: &Pyramid,
    p: [f32; 2],
    guess: [f32; 2],
    cfg: &KltConfig,
) -> Option<[f32; 2]> {
    let q = track_one(a, b, p, guess, cfg, usize::MAX)?;
    let back = track_one(b, a, q, p, cfg, usize::MAX)?;
    let fb = ((back[0] - p[0]).powi(2) + (back[1] - p[1]).powi(2)).sqrt();
    (fb <= cfg.max_fb).then_some(q)
}

/// The level-0 patch around `p` (the reference template of a track).
pub(crate) fn patch(a: &Pyramid, p: [f32; 2], hw: i32) -> Option<Vec<f32>> {
    let l = &a.levels[0];
    let mut out = Vec::with_capacity(((2 * hw + 1) * (2 * hw + 1)) as usize);
    for dy in -hw..=hw {
        for dx in -hw..=hw {
            out.push(l.sample(VALUE, p[0] + dx as f32, p[1] + dy as f32)?);
        }
    }
    Some(out)
}

/// Re-align a tracked position `q` in `b` to the track's reference template (the patch where it
/// was detected) with the same brightness model, so that frame-to-frame errors do not add
/// up to drift along the track (Shi & Tomasi, "Good Features to Track", CVPR 1994, check the
/// feature against its first appearance). The template is laid out with `warp`, the rotation
/// and scale of the image since the track's birth ([`Similarity`]). Returns the position and
/// the patch RMS.
pub(crate) fn refine_to_template(
    tmpl: &[f32],
    b: &Pyramid,
    q: [f32; 2],
    hw: i32,
    iterations: usize,
    warp: Similarity,
) -> Option<([f32; 2], f32)> {
    let lb = &b.levels[0];
    let mut d = [0.0f32; 2];
    let mut bright = Brightness::IDENTITY;
    let mut rms = f32::INFINITY;
    for _ in 0..iterations {
        let (step, r) = align_step(lb, tmpl, hw, [q[0] + d[0], q[1] + d[1]], bright, warp)?;
        rms = r;
        d[0] += step[0] as f32;
        d[1] += step[1] as f32;
        if !update_brightness(&mut bright, &step) || d[0].abs() + d[1].abs() > 2.0 {
            return None;
        }
        if step[0].abs() + step[1].abs() < 0.005 {
            break;
        }
    }
    Some(([q[0] + d[0], q[1] + d[1]], rms))
}

/// A feature followed through the video.
pub(crate) struct Track {
    pub id: usize,
    pub pos: [f32; 2],
    pub vel: [f32; 2],
    /// The video's roll-and-zoom chain at the track's birth ([`Similarity`]): the chain at the
    /// current frame divided by it lays out the template and the samples.
    pub birth: Similarity,
    /// Level-0 patch where the track was detected.
    pub tmpl: Vec<f32>,
}

/// Tracks every track from `pp` into `pyr` (frame to frame, translation only), updates the
/// roll-and-zoom `chain` from the matches, and re-aligns each match to its birth template laid
/// out with the roll and zoom since its birth. `None` for lost tracks.
///
/// With `rm` (a later pass) the re-alignment maps the template through the fitted response
/// ([`refine_with_response`]).
pub(crate) fn track_and_refine(
    pp: &Pyramid,
    pyr: &Pyramid,
    tracks: &[Track],
    cfg: &KltConfig,
    chain: &mut Similarity,
    rm: Option<&ResponseMatch>,
) -> Vec<Option<[f32; 2]>> {
    use rayon::prelude::*;
    let moved: Vec<Option<[f32; 2]>> = tracks
        .par_iter()
        .map(|t| {
            let guess = [t.pos[0] + t.vel[0], t.pos[1] + t.vel[1]];
            track(pp, pyr, t.pos, guess, cfg)
        })
        .collect();
    let (from, to): (Vec<[f32; 2]>, Vec<[f32; 2]>) = tracks
        .iter()
        .zip(&moved)
        .filter_map(|(t, q)| q.map(|q| (t.pos, q)))
        .unzip();
    if let Some(step) = Similarity::fit(&from, &to) {
        *chain = chain.then(step);
    }
    let now = *chain;
    tracks
        .par_iter()
        .zip(moved.par_iter())
        .map(|(t, q)| {
            let (hw, warp) = (cfg.half_window, now.since(t.birth));
            let (q2, rms) = match rm {
                Some(rm) => refine_with_response(&t.tmpl, &pyr.levels[0], (*q)?, hw, 10, warp, rm),
                None => refine_to_template(&t.tmpl, pyr, (*q)?, hw, 10, warp),
            }?;
            (rms <= cfg.max_residual).then_some(q2)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The grid path of [`align_step`] (unwarped windows) computes what the per-pixel path
    /// does: a warp that is the identity to f32 precision but not `IDENTITY` takes the latter.
    #[test]
    fn grid_window_matches_per_pixel_sampling() {
        let (w, h) = (64usize, 48usize);
        let data: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32, (i / w) as f32);
                // Values that reach both clip levels, so the clipped tests are exercised.
                (0.5 + 0.6 * (0.31 * x).sin() * (0.23 * y + 0.4 * (0.11 * x).cos()).cos())
                    .clamp(0.0, 1.0)
            })
            .collect();
        let level = Level::new(w, h, data);
        let hw = 4;
        let near_identity = Similarity { c: 1.0, s: 1e-30 };
        assert_ne!(near_identity, Similarity::IDENTITY);
        let b = Brightness {
            gain: 1.1,
            bias: -0.02,
            quad: 0.05,
        };
        let mut compared = 0;
        for k in 0..400 {
            let q = [
                3.0 + (k as f32 * 0.618_034).fract() * (w as f32 - 6.0),
                3.0 + (k as f32 * 0.414_213_5).fract() * (h as f32 - 6.0),
            ];
            let tmpl: Vec<f32> = window(hw, Similarity::IDENTITY, [q[1], q[0] * 0.7])
                .map(|(_, x, y)| level.sample(VALUE, x, y).unwrap_or(0.5))
                .collect();
            let grid = GridWindow::inside(&level, q, hw);
            if let Some(g) = &grid {
                let mut v = vec![0.0f32; tmpl.len()];
                g.values(&level, &mut v);
                for ((_, x, y), v) in window(hw, Similarity::IDENTITY, q).zip(&v) {
                    let s = level.sample(VALUE, x, y).expect("inside");
                    assert!((v - s).abs() < 1e-5, "{q:?}: {v} vs {s}");
                }
            }
            let grid = grid.is_some();
            let fast = align_step(&level, &tmpl, hw, q, b, Similarity::IDENTITY);
            let slow = align_step(&level, &tmpl, hw, q, b, near_identity);
            match (fast, slow) {
                (Some((a, ra)), Some((s, rs))) => {
                    compared += usize::from(grid);
                    assert!(
                        (ra - rs).abs() <= 1e-4 * rs.max(1e-3),
                        "{q:?}: rms {ra} vs {rs}"
                    );
                    for (x, y) in a.iter().zip(&s) {
                        assert!(
                            (x - y).abs() <= 1e-3 * y.abs().max(1e-2),
                            "{q:?}: {a:?} vs {s:?}"
                        );
                    }
                }
                (None, None) => {}
                (f, s) => panic!("{q:?}: {f:?} vs {s:?}"),
            }
        }
        assert!(compared > 200, "only {compared} windows took the grid path");
        // Positions whose support leaves the level take the per-pixel path, however far off.
        for q in [
            [f32::NAN, 10.0],
            [f32::INFINITY, 10.0],
            [1e30, 10.0],
            [10.0, 3.0e19],
            [(w - 1) as f32 - hw as f32, 10.0],
            [3.9, 10.0],
        ] {
            assert!(GridWindow::inside(&level, q, hw).is_none(), "{q:?}");
        }
        assert!(GridWindow::inside(&level, [(w - 2) as f32 - hw as f32 - 0.5, 10.0], hw).is_some());
    }
}
