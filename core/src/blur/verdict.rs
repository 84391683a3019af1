//! One combined, scale-, contrast- and noise-normalised blur score with a default threshold
//! that needs no per-camera tuning.
//!
//! # Why not the Laplacian variance or β alone
//! Both are absolute: the Laplacian variance grows with contrast, resolution and sensor noise
//! (noise alone can lift a blurred frame above any fixed threshold), and β depends on how much
//! structure the scene has (a sharp photo of a plain wall looks "blurred"). On real photos the
//! fixed-threshold verdict caught about half the shaken photos while flagging one sharp photo in
//! eight.
//!
//! # The score
//! The score compares gradient energy at a fine and a coarse scale, the principle of the
//! re-blur metric of Crete, Dolmiere, Ladret & Nicolas, "The blur effect: perception and
//! estimation with a new no-reference perceptual blur metric", SPIE Electronic Imaging 6492
//! (2007): an image that is already blurred changes little when it is blurred again. For each
//! of four directions u (0°, 45°, 90°, 135°) and every pixel p,
//! - the fine derivative  f(p) = (I(p+u) − I(p)) / |u|,
//! - the coarse derivative c(p) = (I(p+2u) − I(p−2u)) / (4|u|), the mean of four consecutive
//!   fine derivatives,
//!
//! and ρ = Σc² / Σf² is the share of gradient energy that survives a 4-pixel average along u.
//! By Cauchy–Schwarz ρ ≤ 1; it is 1/4 for an ideal step edge, ≈ 0.44 for a 2-px ramp, ≈ 0.58
//! for a 3-px one, ≈ 0.69 for 4 px and → 1 for wide blur. A ratio of two energies of the same
//! image, it does not depend on brightness or contrast.
//!
//! - **Noise**: white noise has ρ = 1/16 and would make any blurred photo look sharp. Its
//!   variance σ² is estimated with Immerkær's mask ("Fast noise variance estimation", CVIU
//!   64(2), 1996) taking the *median* absolute response (robust to edges, after Donoho's MAD
//!   rule), and its known contribution (2σ²/|u|² to E f², 2σ²/(16|u|²) to E c²) is subtracted
//!   from both energies before the ratio.
//! - **Scale**: the image is first box-reduced by an integer factor to a long side of at most
//!   [`WORK_SIDE`] pixels, so that the 1–4 px scales of the score mean the same fraction of the
//!   frame on a phone photo and on a VGA frame (the slight softness of every lens and
//!   demosaicker at full resolution disappears, blur that is visible at screen size remains).
//! - **JPEG, low texture, depth of field**: only edge pixels count, those whose coarse gradient
//!   is at least [`EDGE_FRACTION`] of the image's 99th percentile (and well above the noise).
//!   Noise that went through JPEG is coloured, so the σ² correction misses part of it, and on a
//!   strongly blurred photo it would look like fine texture; compression block edges look like
//!   sharp steps. Both are weak next to the scene's strongest edges. The choice is relative, so
//!   a low-contrast sharp photo is judged on its own strongest edges, and those are in the
//!   sharp subject when the background is out of focus.
//! - **Motion vs defocus**: each direction keeps its own ratio. Motion blur raises ρ along the
//!   motion and hardly across it; defocus raises all four. The score is the mean of the pooled
//!   ratio and the blurriest direction's (pooling alone dilutes a one-directional blur by the
//!   three directions it hardly touches); the spread of the four ratios is reported as
//!   `anisotropy` and the blurriest direction as `blur_direction_deg`.

use serde::{Deserialize, Serialize};

use crate::io::Gray;

/// Longest side, in pixels, at which the score is computed (larger images are box-reduced by
/// the smallest integer factor that brings them to this size or below).
pub const WORK_SIDE: usize = 1024;

/// Default threshold of the combined score: an image is blurred if its score is above it.
/// Chosen on the TUNE split of `examples/blur_eval.rs` (see the module docs there) and checked
/// on its held-out split.
pub const DEFAULT_BLUR_THRESHOLD: f64 = 0.6;

/// Block side, in working-resolution pixels, of the texture count (`textured_share`).
pub(crate) const SCORE_BLOCK: usize = 32;

/// The four analysis directions (dx, dy) and their angles in degrees.
pub(crate) const DIRECTIONS: [(isize, isize, f64); 4] =
    [(1, 0, 0.0), (1, 1, 45.0), (0, 1, 90.0), (-1, 1, 135.0)];

/// The combined score of one image and the quantities it was built from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct CombinedScore {
    /// Blur score in [0, 1], higher = blurrier: the share of the edge pixels' gradient energy
    /// that survives a 4-px average, after the sensor noise is taken out. ≈ 0.25 for ideal step edges, ≈ 0.45 for typical
    /// sharp photos, ≈ 0.6 for 3-px blur, → 1 for strong blur; 1 when nothing can be judged.
    pub score: f64,
    /// Estimated standard deviation of the sensor noise, in grey levels of the working image.
    pub noise_sigma: f64,
    /// The ratio per direction (0°, 45°, 90°, 135°), same scale as `score`; null where the
    /// direction has less than a tenth of the strongest direction's edge energy.
    pub directional: [Option<f64>; 4],
    /// Largest minus smallest directional ratio: near 0 for defocus or an isotropic scene,
    /// large for linear motion blur.
    pub anisotropy: f64,
    /// Direction (degrees, 0 = along x, 90 = along y) of the blurriest direction: the motion
    /// direction when `anisotropy` is large.
    pub blur_direction_deg: f64,
    /// Share of blocks with enough texture to be judged (0 for a flat image).
    pub textured_share: f64,
    /// Integer factor by which the image was reduced before scoring (1 up to [`WORK_SIDE`]).
    pub reduction: u32,
}

/// The grey image as f32, box-reduced to the working size.
pub(crate) struct Plane {
    pub w: usize,
    pub h: usize,
    pub px: Vec<f32>,
    pub factor: usize,
}

/// Box-reduce to a long side ≤ [`WORK_SIDE`] (mean of f×f blocks, partial blocks dropped).
pub(crate) fn working_plane(gray: &Gray) -> Plane {
    let (w, h) = (gray.width as usize, gray.height as usize);
    let f = w.max(h).div_ceil(WORK_SIDE).max(1);
    if f == 1 {
        let px = gray.data.iter().map(|&v| f32::from(v)).collect();
        return Plane {
            w,
            h,
            px,
            factor: 1,
        };
    }
    let (rw, rh) = (w / f, h / f);
    let mut px = vec![0f32; rw * rh];
    let scale = 1.0 / (f * f) as f32;
    for (ry, out) in px.chunks_mut(rw.max(1)).enumerate().take(rh) {
        for yy in ry * f..(ry + 1) * f {
            let row = gray.row(yy);
            for (rx, o) in out.iter_mut().enumerate() {
                let s: u32 = row[rx * f..(rx + 1) * f]
                    .iter()
                    .map(|&v| u32::from(v))
                    .sum();
                *o += s as f32;
            }
        }
        out.iter_mut().for_each(|o| *o *= scale);
    }
    Plane {
        w: rw,
        h: rh,
        px,
        factor: f,
    }
}

/// Noise standard deviation by Immerkær's mask [1 −2 1; −2 4 −2; 1 −2 1] (Σ coefficients² =
/// 36), which cancels every locally linear (and most locally quadratic) signal; the median
/// absolute response divided by 0.6745·6 is σ for Gaussian noise and ignores the minority of
/// pixels on edges. 0 for images smaller than 3×3.
pub(crate) fn noise_sigma(p: &Plane) -> f64 {
    if p.w < 3 || p.h < 3 {
        return 0.0;
    }
    let mut r = Vec::with_capacity((p.w - 2) * (p.h - 2));
    for y in 1..p.h - 1 {
        let (a, b, c) = (
            &p.px[(y - 1) * p.w..y * p.w],
            &p.px[y * p.w..(y + 1) * p.w],
            &p.px[(y + 1) * p.w..(y + 2) * p.w],
        );
        for x in 1..p.w - 1 {
            let v = (a[x - 1] + a[x + 1] + c[x - 1] + c[x + 1])
                - 2.0 * (a[x] + c[x] + b[x - 1] + b[x + 1])
                + 4.0 * b[x];
            r.push(v.abs());
        }
    }
    let mid = r.len() / 2;
    let (_, m, _) = r.select_nth_unstable_by(mid, f32::total_cmp);
    f64::from(*m) / (0.6745 * 6.0)
}

/// Share of the strongest coarse gradients above which pixels count as edges: a pixel enters
/// the energies along direction u when |c| ≥ `EDGE_FRACTION` × the reference gradient (the
/// image's 99th percentile of |c| for the score, the block's maximum for the map). Restricting
/// to strong edges keeps noise that survived JPEG (coloured, so not removed by the σ²
/// correction) and compression block edges out of the ratio; 0.6 was chosen on the TUNE split.
pub(crate) const EDGE_FRACTION: f32 = 0.6;

/// Fine and coarse derivative of pixel index `i` along offset `o` (scaled by `inv` = 1/|u|).
#[inline]
fn derivs(px: &[f32], i: isize, o: isize, inv: f32) -> (f32, f32) {
    let at = |k: isize| px[(i + k) as usize];
    ((at(o) - at(0)) * inv, (at(2 * o) - at(-2 * o)) * 0.25 * inv)
}

/// Calls `visit(x, y, d, f, c)` for every pixel 2 px away from the border and each direction.
fn for_each_deriv(p: &Plane, mut visit: impl FnMut(usize, usize, usize, f32, f32)) {
    if p.w < 5 || p.h < 5 {
        return;
    }
    let w = p.w as isize;
    let dirs = DIRECTIONS.map(|(dx, dy, _)| {
        let inv = if dx != 0 && dy != 0 {
            std::f32::consts::FRAC_1_SQRT_2
        } else {
            1.0
        };
        (dy * w + dx, inv)
    });
    for y in 2..p.h - 2 {
        let base = (y * p.w) as isize;
        for x in 2..p.w - 2 {
            for (d, &(o, inv)) in dirs.iter().enumerate() {
                let (f, c) = derivs(&p.px, base + x as isize, o, inv);
                visit(x, y, d, f, c);
            }
        }
    }
}

/// Histogram resolution of |c|: bins of 1/8 grey level per pixel up to 256.
const HIST_BINS: usize = 2048;

/// Per block and direction, the largest |c|; per direction, the 99th percentile of |c|.
pub(crate) fn coarse_extremes(p: &Plane, block: usize) -> (Vec<[f32; 4]>, [f32; 4]) {
    let block = block.max(1);
    let cols = p.w.div_ceil(block).max(1);
    let rows = p.h.div_ceil(block).max(1);
    let mut cmax = vec![[0f32; 4]; cols * rows];
    let mut hist = vec![[0u32; 4]; HIST_BINS];
    for_each_deriv(p, |x, y, d, _, c| {
        let a = c.abs();
        let b = (y / block) * cols + x / block;
        cmax[b][d] = cmax[b][d].max(a);
        hist[((a * 8.0) as usize).min(HIST_BINS - 1)][d] += 1;
    });
    let mut p99 = [0f32; 4];
    for (d, q) in p99.iter_mut().enumerate() {
        let total: u64 = hist.iter().map(|h| u64::from(h[d])).sum();
        let target = total - total / 100;
        let mut acc = 0u64;
        for (k, h) in hist.iter().enumerate() {
            acc += u64::from(h[d]);
            if acc >= target && total > 0 {
                *q = (k as f32 + 0.5) / 8.0;
                break;
            }
        }
    }
    (cmax, p99)
}

/// Fine and coarse directional gradient energies of the edge pixels, summed per block.
pub(crate) struct BlockEnergies {
    pub cols: usize,
    pub rows: usize,
    /// Σ f² per block and direction, noise contribution removed (≥ 0).
    pub fine: Vec<[f64; 4]>,
    /// Σ c² per block and direction, noise contribution removed (≥ 0).
    pub coarse: Vec<[f64; 4]>,
}

impl BlockEnergies {
    /// Isotropic ρ of one block (all directions pooled); 1 without energy.
    pub fn block_ratio(&self, b: usize) -> f64 {
        let f: f64 = self.fine[b].iter().sum();
        let c: f64 = self.coarse[b].iter().sum();
        if f > 0.0 { (c / f).min(1.0) } else { 1.0 }
    }

    /// Σf² and Σc² per direction over all blocks.
    pub fn totals(&self) -> ([f64; 4], [f64; 4]) {
        let (mut f, mut c) = ([0.0; 4], [0.0; 4]);
        for b in 0..self.fine.len() {
            for d in 0..4 {
                f[d] += self.fine[b][d];
                c[d] += self.coarse[b][d];
            }
        }
        (f, c)
    }
}

/// Directional energies of `p` per `block`×`block` tile over the pixels whose |c| reaches
/// `threshold(block index, direction)` (the 2-px border, where c is undefined, is left out),
/// with the noise variance `sigma²` subtracted per counted pixel.
pub(crate) fn block_energies(
    p: &Plane,
    block: usize,
    sigma: f64,
    threshold: impl Fn(usize, usize) -> f32,
) -> BlockEnergies {
    let block = block.max(1);
    let cols = p.w.div_ceil(block).max(1);
    let rows = p.h.div_ceil(block).max(1);
    let mut fine = vec![[0f64; 4]; cols * rows];
    let mut coarse = vec![[0f64; 4]; cols * rows];
    let mut count = vec![[0u32; 4]; cols * rows];
    let thr: Vec<[f32; 4]> = (0..cols * rows)
        .map(|b| [0, 1, 2, 3].map(|d| threshold(b, d)))
        .collect();
    for_each_deriv(p, |x, y, d, f, c| {
        let b = (y / block) * cols + x / block;
        if c.abs() >= thr[b][d] {
            fine[b][d] += f64::from(f * f);
            coarse[b][d] += f64::from(c * c);
            count[b][d] += 1;
        }
    });
    let var = sigma * sigma;
    for b in 0..fine.len() {
        for (d, &(dx, dy, _)) in DIRECTIONS.iter().enumerate() {
            let n = f64::from(count[b][d]);
            let len2 = (dx * dx + dy * dy) as f64;
            fine[b][d] = (fine[b][d] - n * 2.0 * var / len2).max(0.0);
            coarse[b][d] = (coarse[b][d] - n * 2.0 * var / (16.0 * len2)).max(0.0);
        }
    }
    BlockEnergies {
        cols,
        rows,
        fine,
        coarse,
    }
}

/// Smallest coarse gradient that is texture rather than noise: 5 σ_c (σ_c = σ/(2√2), the
/// noise of c; the maximum of ~1000 noise samples is about 3.3 σ_c), at least 0.5 grey level
/// per pixel, and at least 5 % of the image's 99th percentile (so that brightness scaling does
/// not change the decision).
pub(crate) fn texture_floor(sigma: f64, p99: &[f32; 4]) -> f32 {
    let top = p99.iter().copied().fold(0.0, f32::max);
    (5.0 * sigma as f32 / (2.0 * std::f32::consts::SQRT_2))
        .max(0.5)
        .max(0.05 * top)
}

/// The combined blur score of a grey image (see the module docs). Never fails: an image too
/// small or too flat to judge gets score 1 (nothing sharp in it) and `textured_share` 0.
pub fn combined_score(gray: &Gray) -> CombinedScore {
    let plane = working_plane(gray);
    let sigma = noise_sigma(&plane);
    let (cmax, p99) = coarse_extremes(&plane, SCORE_BLOCK);
    let floor = texture_floor(sigma, &p99);
    let thr = p99.map(|q| (EDGE_FRACTION * q).max(floor));
    let e = block_energies(&plane, SCORE_BLOCK, sigma, |_, d| thr[d]);
    let textured = cmax
        .iter()
        .filter(|m| m.iter().copied().fold(0.0, f32::max) >= floor)
        .count();
    let textured_share = textured as f64 / cmax.len().max(1) as f64;
    let (f, c) = e.totals();
    let (fs, cs): (f64, f64) = (f.iter().sum(), c.iter().sum());
    // A direction is judged where the scene has structure along it at the coarse scale: motion
    // blur removes the fine energy along the motion, so the fine energy cannot decide that.
    let cmax = c.iter().copied().fold(0.0, f64::max);
    let mut directional = [None; 4];
    for d in 0..4 {
        if f[d] > 0.0 && c[d] >= 0.1 * cmax {
            directional[d] = Some((c[d] / f[d]).min(1.0));
        }
    }
    let mut blurriest = (0.0, 0);
    for (d, r) in directional.iter().enumerate() {
        if let Some(r) = *r
            && r > blurriest.0
        {
            blurriest = (r, d);
        }
    }
    let present: Vec<f64> = directional.iter().flatten().copied().collect();
    let anisotropy = if present.is_empty() {
        0.0
    } else {
        present.iter().copied().fold(0.0, f64::max) - present.iter().copied().fold(1.0, f64::min)
    };
    // Pooled over directions, a blur along one direction is diluted by the three it hardly
    // touches: the score averages the pooled ratio with the blurriest direction's.
    let pooled = if fs > 0.0 { (cs / fs).min(1.0) } else { 1.0 };
    let score = if present.is_empty() {
        pooled
    } else {
        0.5 * (pooled + blurriest.0)
    };
    CombinedScore {
        score,
        noise_sigma: sigma,
        directional,
        anisotropy,
        blur_direction_deg: DIRECTIONS[blurriest.1].2,
        textured_share,
        reduction: plane.factor as u32,
    }
}
