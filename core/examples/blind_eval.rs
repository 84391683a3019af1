//! Why one file of over 600 lines: the harness, its generators, its scoring and the diagnostic
//! modes `size` and `starts` are one recipe that the published numbers depend on; split, the
//! recipe would be scattered.
//!
//! Held-out evaluation of blind deblurring (`estimate_kernel` + TV), regenerated from sharp
//! photos on every run so that it can be published as a command and cannot be over-fitted by
//! editing images.
//!
//! ```text
//! cargo run -p caliper-core --release --example blind_eval -- tune|tremor|texture|eval|eval2|eval3|eval4|eval5|eval6|eval7|eval8|eval9|levin|levin-synth|time [--only TEXT] [-v]
//! cargo run -p caliper-core --release --example blind_eval -- size|size-tremor|size-texture|size-eval|starts
//! cargo run -p caliper-core --release --example blind_eval -- thresholds tune|tremor|texture|levin|levin-synth|eval5|eval6|eval7|eval8|eval9
//! ```
//!
//! Sharp images come from `CALIPER_BLIND_DATA` (default `../shared/data`, i.e. the shared data
//! folder next to the workspace; nothing is copied into the repository): scikit-image's test
//! images (`blur/skimage`, public domain / CC0, scikit-image BSD-3), OpenCV's stereo samples
//! (`camera/opencv_stereo`, Apache-2.0) and BoofCV's fisheye chessboards
//! (`camera/boofcv_fisheye_chessboard`, CC-BY-4.0, Peter Abeles). Each is converted to grey,
//! its shorter side resized to a random 300–480 px (never upsampled beyond need), and a random 255 + 2·24 px square with
//! enough gradient energy is taken (the 24 px context means the border pixels see real content,
//! as in a photo).
//!
//! Fixed splits; the tuning ones share no source image and no seed with EVAL, and only half its
//! kernel generator:
//! * **TUNE**: astronaut, camera, coffee, chelsea, immunohistochemistry, OpenCV
//!   `left01/03/05/07/09/11`; 4 kernels each from [`shake_3d`], seeds from 1.
//! * **TREMOR** (tuning too): the TUNE photos with kernels from [`shake_tremor`] (drift plus
//!   an oscillating tremor: bright dwell points joined by faint strokes), seeds from 5 000 001.
//! * **TEXTURE** (tuning too): repetitive texture, the README's named failure case, without
//!   EVAL's texture photos: scikit-image's `text`, `moon` and `clock` (used nowhere else) and
//!   generated walls of tiles, packed pebbles and grass-like strands (`common/textures.rs`,
//!   two seeds each); [`shake_3d`] kernels, seeds from 7 000 001.
//! * **EVAL**: brick, coins, rocket, grass, gravel, hubble_deep_field, BoofCV `1/5/9/13/17/21`;
//!   2 kernels each from [`shake_3d`] (seeds from 1 000 001) and 2 from [`shake_impulsive`], a
//!   different trajectory model. EVAL is for reporting only: never tune on it.
//! * **EVAL2**: EVAL's photos and generators, seeds from 11 000 001 (other crops, kernels and
//!   noise): run once to confirm a choice made after seeing EVAL (used on 2026-12-05 for the
//!   choice between cleaning thresholds).
//! * **EVAL3**: the same with seeds from 21 000 001 (first run 2026-12-05: the shipped
//!   estimator and the `kernel.uncertain` flag, both chosen without it).
//! * **EVAL4**: the same with seeds from 31 000 001 (first run 2026-12-05: the shipped
//!   estimator, the agreement flag and the misfit experiment, all chosen without it).
//! * **EVAL5**: the same with seeds from 41 000 001 (first run 2026-12-05 at σ = 0.015 and
//!   0.02: the noise-dependent agreement threshold; then at σ = 0.01 and 0.003: the misfit).
//! * **EVAL6**: the same with seeds from 51 000 001 (first run 2026-12-05 at σ = 0.006: the
//!   misfit, not kept; then at σ = 0.01: the shipped estimator).
//! * **EVAL7**: the same with seeds from 61 000 001 (first run 2026-12-07 on the shipped
//!   estimator, after three experiments on TUNE alone that were not kept: 22 of 48).
//! * **EVAL8**: the same with seeds from 71 000 001, unused: for the next confirmation.
//! * **LEVIN** (`levin`, `levin-synth`): Levin et al. 2009's real camera-shake set (four
//!   poster photos × eight measured kernels, 13–27 px), read from `CALIPER_LEVIN_DIR` (not
//!   shipped; see `common/levin.rs`): the captured blurred images, or the sharp photos blurred
//!   here with the measured kernels and σ = 0.01. The benchmark issue 16 quotes; for reporting.
//!
//! Kernel extents are stratified over 11–41 px (four strata per image). Blur is a 'valid'
//! convolution, then N(0, 0.01²) noise, clipping and 8-bit quantisation.
//!
//! Scoring is Levin et al. (CVPR 2009): error ratio = SSD of the TV restoration with the
//! estimated kernel over that with the true kernel (same [`tv_deconv`] defaults), 15 px border
//! ignored, best integer shift within ±8 px. Reported: share ≤ 3 and ≤ 2, median, worst, and
//! the time of the kernel estimation + TV per image; the share ≤ 3 also per source image and
//! for kernel sides ≤ 29 px / beyond (generator extent ≤ 27 px / beyond).
//!
//! `time` measures one 255² case and one ~1 Mpx image (1155×866, 31 px shake kernel).
//! `large` / `large-eval` score whole photos of about a megapixel with the kernel estimated on
//! the default region and on the whole photo (`common/blind_large.rs`).
//!
//! Environment: `CALIPER_BLIND_DATA` (data root), `BLIND_NOISE=σ` (noise of the generated
//! cases instead of 0.01; the splits' published numbers are all at 0.01), `BLIND_KS` /
//! `BLIND_ITERS` / `BLIND_REG` / `BLIND_LAMBDA` (override `kernel_size` /
//! `iterations_per_level` / `kernel_reg` / `lambda_grad`, for experiments),
//! `BLIND_THRESHOLD` (override `kernel_threshold`: one threshold, no choice), `BLIND_PAIR=A,B`
//! (with `thresholds`: the two thresholds compared), `BLIND_ORACLE=F` (window = F × the true
//! kernel side: the ceiling of size estimation), `BLIND_NOSAT=1` (every pixel linear in
//! both solves: `saturation: null`), `BLIND_SAT=1` (over-exposed variant of
//! the split: 1–6 % of each scene above the white level, see [`overexpose`]), `BLIND_SAT=2`
//! (small light sources far above white, see [`light_sources`]), `BLIND_PROFILES=1` (with `size`: print the
//! gradient autocorrelation profiles to stderr), `BLIND_PEER=CMD` (also run a peer kernel
//! estimator on each case with our window and score its kernel the same way; see
//! `common/blind_peer.rs`), `BLIND_DUMP=DIR` (write the sharp,
//! blurred and restored PNGs of each case), `BLIND_TRACE=1` (also print, per pyramid level, the
//! error ratio of that level's kernel resampled to full scale and its extent, support and RMS
//! radius against the truth's: where the estimate goes wrong on the way up), `BLIND_FIXED=pyramid`
//! or `finest` (no blind run: the estimation started from the true kernel, in a window of 1.3 ×
//! its side, through every level or the full-resolution level alone; the ratio says whether
//! the truth is a fixed point of the estimator).

use std::path::{Path, PathBuf};
use std::time::Instant;

use caliper_core::deconv::{
    AGREEMENT_SHIFT, BlindOutput, BlindParams, DEFAULT_KERNEL_THRESHOLD, DEFAULT_SATURATION,
    KernelStart, LOW_KERNEL_THRESHOLD, Plane, Psf, TvParams, UNCERTAIN_AGREEMENT, blind_deconv,
    error_ratio_aligned, estimate_blur_extent, estimate_kernel_from, estimate_kernel_restored,
    estimate_kernel_trace, estimate_noise_sigma, gradient_autocorrelation, kernel_agreement, psnr,
    tv_deconv,
};
use caliper_core::io::{ImageLimits, decode_gray8};
use caliper_core::progress::NoProgress;

const SIDE: usize = 255;
const CONTEXT: usize = 24;
const NOISE: f64 = 0.01;
const BORDER: usize = 15;
const MAX_SHIFT: usize = 8;
/// Kernel side (px, the `true` column) that splits the summary into small and large kernels
/// (the large ones are where the estimate collapses or scatters): side ≤ 29 is a generator
/// extent ≤ 27 px (the number that ends the case name).
const SIZE_SPLIT: usize = 29;

/// The noise σ of the generated cases: [`NOISE`], or `BLIND_NOISE` (an experiment knob: how
/// the estimator and its warning signs behave on cleaner or noisier photos).
fn noise() -> f64 {
    static SIGMA: std::sync::OnceLock<f64> = std::sync::OnceLock::new();
    *SIGMA.get_or_init(|| {
        std::env::var("BLIND_NOISE")
            .ok()
            .and_then(|v| v.parse().ok())
            .filter(|v: &f64| v.is_finite() && *v >= 0.0)
            .unwrap_or(NOISE)
    })
}

#[path = "common/rng.rs"]
mod rng;
use rng::Rng;
#[path = "common/blind_peer.rs"]
mod blind_peer;
#[path = "common/blind_large.rs"]
mod large;
#[path = "common/levin.rs"]
mod levin;
#[path = "common/textures.rs"]
mod textures;

/// Splat a trajectory (equal-time samples, pixel offsets) bilinearly into an odd square kernel
/// whose larger extent is `extent` px, normalised.
fn rasterise(pts: &[(f64, f64)], extent: f64) -> Psf {
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for &(x, y) in pts {
        (x0, x1, y0, y1) = (x0.min(x), x1.max(x), y0.min(y), y1.max(y));
    }
    let span = (x1 - x0).max(y1 - y0).max(1e-9);
    let s = (extent - 1.0).max(0.0) / span;
    let size = ((extent.ceil() as usize) | 1) + 2;
    let ox = (size as f64 - 1.0 - (x1 - x0) * s) / 2.0;
    let oy = (size as f64 - 1.0 - (y1 - y0) * s) / 2.0;
    let mut w = vec![0.0; size * size];
    for pair in pts.windows(2) {
        // Sub-samples along each step so that fast segments are drawn as lines, not dots.
        let (a, b) = (pair[0], pair[1]);
        let len = ((b.0 - a.0).hypot(b.1 - a.1) * s).max(1e-9);
        let n = (len * 8.0).ceil().max(1.0) as usize;
        for i in 0..n {
            let t = (i as f64 + 0.5) / n as f64;
            let x = ox + (a.0 + t * (b.0 - a.0) - x0) * s;
            let y = oy + (a.1 + t * (b.1 - a.1) - y0) * s;
            let (fx, fy) = (x - x.floor(), y - y.floor());
            let (i0, j0) = (x.floor() as usize, y.floor() as usize);
            let (i1, j1) = ((i0 + 1).min(size - 1), (j0 + 1).min(size - 1));
            let wt = 1.0 / n as f64;
            w[j0 * size + i0] += wt * (1.0 - fx) * (1.0 - fy);
            w[j0 * size + i1] += wt * fx * (1.0 - fy);
            w[j1 * size + i0] += wt * (1.0 - fx) * fy;
            w[j1 * size + i1] += wt * fx * fy;
        }
    }
    Psf::from_weights(size, size, w).expect("kernel")
}

/// Hand-held camera during the exposure: angular velocities (yaw, pitch, roll) follow AR(1)
/// random walks with a per-kernel drift (inertia of the hand), plus a small translation; the
/// image motion of a random point (px, py) through a pinhole of focal length `f` is
/// `f·(yaw, pitch) + roll·(−py, px) + f·t/Z`.
fn shake_3d(rng: &mut Rng, extent: f64) -> Psf {
    let f = 600.0;
    let (px, py) = (rng.range(-300.0, 300.0), rng.range(-220.0, 220.0));
    let n = 300;
    let inertia = rng.range(0.9, 0.99);
    let twist = rng.range(0.0, 0.5);
    let drift = [rng.normal(), rng.normal(), 0.3 * rng.normal()];
    let depth = rng.range(1.0, 4.0);
    let (mut ang, mut vel, mut tr, mut tv) = ([0.0f64; 3], [0.0f64; 3], [0.0f64; 2], [0.0f64; 2]);
    let mut pts = Vec::with_capacity(n);
    for _ in 0..n {
        for a in 0..3 {
            let gain = if a == 2 { twist } else { 1.0 };
            vel[a] = inertia * vel[a] + 0.05 * gain * (rng.normal() + 0.4 * drift[a]);
            ang[a] += vel[a] * 1e-3;
        }
        for a in 0..2 {
            tv[a] = 0.95 * tv[a] + 0.01 * rng.normal();
            tr[a] += tv[a] * 1e-3;
        }
        let dx = f * ang[0] - ang[2] * py + f * tr[0] / depth;
        let dy = f * ang[1] + ang[2] * px + f * tr[1] / depth;
        pts.push((dx, dy));
    }
    rasterise(&pts, extent)
}

/// A second, different model (for EVAL only): a 2-D particle with inertia, Gaussian velocity
/// noise and rare impulsive jerks, seen during a random part of its path (after Boracchi & Foi,
/// "Modeling the performance of image restoration from motion blur", IEEE TIP 21(8), 2012).
fn shake_impulsive(rng: &mut Rng, extent: f64) -> Psf {
    let n = 1500;
    let keep = rng.range(0.3, 1.0);
    let jerk_p = rng.range(0.0, 0.01);
    let a0 = rng.range(0.0, std::f64::consts::TAU);
    let (mut v, mut x) = ((a0.cos(), a0.sin()), (0.0f64, 0.0f64));
    let start = (rng.uniform() * (1.0 - keep) * n as f64) as usize;
    let stop = start + (keep * n as f64) as usize;
    let mut pts = Vec::new();
    for t in 0..n {
        let mut a = (0.1 * rng.normal(), 0.1 * rng.normal());
        if rng.uniform() < jerk_p {
            let s = rng.range(1.0, 3.0);
            a = (a.0 - s * v.0 + rng.normal(), a.1 - s * v.1 + rng.normal());
        }
        v = (
            v.0 + a.0 - 0.0005 * x.0 * rng.uniform(),
            v.1 + a.1 - 0.0005 * x.1 * rng.uniform(),
        );
        let sp = v.0.hypot(v.1).max(1e-9);
        if sp > 2.0 {
            v = (2.0 * v.0 / sp, 2.0 * v.1 / sp);
        }
        x = (x.0 + v.0, x.1 + v.1);
        if (start..stop).contains(&t) {
            pts.push(x);
        }
    }
    rasterise(&pts, extent)
}

/// A third model, for the `tremor` tuning split: the slow hand drift of [`shake_3d`] plus a
/// physiological tremor, an 8–12 Hz oscillation of the view direction (an ellipse of random
/// shape and axis) seen for 1–3 of its periods. At every turn of the oscillation the image
/// stands almost still, so the kernel is a zigzag or loop with bright dwell points and faint
/// fast strokes between them, the kind of kernel measured on real camera shake (Levin et al.
/// 2009) that the smooth [`shake_3d`] paths hardly produce. Not the EVAL model.
fn shake_tremor(rng: &mut Rng, extent: f64) -> Psf {
    let n = 600;
    let periods = rng.range(1.0, 3.0);
    let phase = rng.range(0.0, std::f64::consts::TAU);
    let axis = rng.range(0.0, std::f64::consts::PI);
    let ecc = rng.range(0.0, 0.6) * if rng.uniform() < 0.5 { -1.0 } else { 1.0 };
    // Drift speed relative to the tremor's peak speed: below 1 the path turns back on itself.
    let drift_ratio = rng.range(0.1, 1.2);
    let drift_dir = rng.range(0.0, std::f64::consts::TAU);
    let (mut jx, mut jy) = (0.0f64, 0.0f64);
    let (mut vx, mut vy) = (0.0f64, 0.0f64);
    let mut pts = Vec::with_capacity(n);
    let w = std::f64::consts::TAU * periods;
    for i in 0..n {
        let t = i as f64 / n as f64;
        let (u, v) = ((w * t + phase).sin(), ecc * (w * t + phase).cos());
        let (ox, oy) = (
            u * axis.cos() - v * axis.sin(),
            u * axis.sin() + v * axis.cos(),
        );
        // Slow wander of the drift direction (AR(1) velocity), scaled to the tremor's speed.
        vx = 0.98 * vx + 0.02 * rng.normal();
        vy = 0.98 * vy + 0.02 * rng.normal();
        jx += (drift_dir.cos() + vx) * drift_ratio * w / n as f64;
        jy += (drift_dir.sin() + vy) * drift_ratio * w / n as f64;
        pts.push((ox + jx, oy + jy));
    }
    rasterise(&pts, extent)
}

/// A grey source in `[0, 1]`.
fn load(path: &Path) -> Option<(usize, usize, Vec<f32>)> {
    let bytes = std::fs::read(path).ok()?;
    let g = decode_gray8(&bytes, &ImageLimits::default()).ok()?;
    let data = g.data.iter().map(|&v| f32::from(v) / 255.0).collect();
    Some((g.width as usize, g.height as usize, data))
}

/// A random (seeded) square of side 255 + 2·CONTEXT with texture, from a rescaled source.
fn crop(src: &(usize, usize, Vec<f32>), rng: &mut Rng) -> Vec<f64> {
    let (w, h, data) = src;
    let big = SIDE + 2 * CONTEXT;
    // Never upsample beyond what the 'valid' crop needs: upsampled sources are soft.
    let short = rng
        .range(300.0, 480.0)
        .min((*w).min(*h) as f64)
        .max(big as f64);
    let f = short / (*w).min(*h) as f64;
    let (nw, nh) = (
        ((*w as f64 * f).round() as usize).max(big),
        ((*h as f64 * f).round() as usize).max(big),
    );
    let img = image::ImageBuffer::<image::Luma<f32>, Vec<f32>>::from_raw(
        *w as u32,
        *h as u32,
        data.clone(),
    )
    .expect("buffer");
    let img = image::imageops::resize(
        &img,
        nw as u32,
        nh as u32,
        image::imageops::FilterType::Triangle,
    );
    let px = img.into_raw();
    let mut best: (f64, Vec<f64>) = (-1.0, Vec::new());
    for _ in 0..6 {
        let x0 = (rng.uniform() * (nw - big + 1) as f64) as usize;
        let y0 = (rng.uniform() * (nh - big + 1) as f64) as usize;
        let sq: Vec<f64> = (0..big * big)
            .map(|i| f64::from(px[(y0 + i / big) * nw + x0 + i % big]).clamp(0.0, 1.0))
            .collect();
        let mut g = 0.0;
        for y in 1..big {
            for x in 1..big {
                g += (sq[y * big + x] - sq[y * big + x - 1]).abs()
                    + (sq[y * big + x] - sq[(y - 1) * big + x]).abs();
            }
        }
        g /= (big * big) as f64;
        if g > best.0 {
            best = (g, sq);
        }
        // Enough texture: keep the first such crop (avoids always picking the busiest one).
        if g > 0.03 {
            break;
        }
    }
    best.1
}

/// Over-exposure (`BLIND_SAT=1`): the scene is scaled so that a random 1–6 % of its pixels
/// exceed the white level, and their excess is amplified 2–10×, as highlights and light
/// sources are in real shaken photos; the
/// sharp reference and the blurred photo are both clipped there (the camera clips before the
/// photo is stored). Drawn from its own generator so that crops, kernels and noise stay those of
/// the plain split.
fn overexpose(sq: &mut [f64], seed: u64) {
    let mut rng = Rng::new(seed ^ 0x5a7u64);
    let share = rng.range(0.01, 0.06);
    let mut sorted = sq.to_vec();
    sorted.sort_by(f64::total_cmp);
    let q = sorted[((1.0 - share) * (sorted.len() - 1) as f64) as usize].max(1e-3);
    // Highlights are brighter than the diffuse scene by more than the image shows.
    let gain = rng.range(2.0, 10.0);
    for v in sq.iter_mut() {
        *v /= q;
        if *v > 1.0 {
            *v = 1.0 + gain * (*v - 1.0);
        }
    }
}

/// Light sources (`BLIND_SAT=2`): 3–10 small discs (radius 0.5–2.5 px) 3–30× brighter than
/// white, the streaks of a shaken night photo; from their own generator as [`overexpose`].
fn light_sources(sq: &mut [f64], seed: u64) {
    let mut rng = Rng::new(seed ^ 0x11e);
    let big = SIDE + 2 * CONTEXT;
    let n = 3 + (rng.uniform() * 8.0) as usize;
    for _ in 0..n {
        let (cx, cy) = (rng.range(0.0, big as f64), rng.range(0.0, big as f64));
        let r = rng.range(0.5, 2.5);
        let v = rng.range(3.0, 30.0);
        let reach = r.ceil() as isize + 1;
        for dy in -reach..=reach {
            for dx in -reach..=reach {
                let (x, y) = (cx as isize + dx, cy as isize + dy);
                if x < 0 || y < 0 || x >= big as isize || y >= big as isize {
                    continue;
                }
                let d = (x as f64 + 0.5 - cx).hypot(y as f64 + 0.5 - cy);
                // Anti-aliased edge: full inside r − 0.5, none beyond r + 0.5.
                let cover = (r + 0.5 - d).clamp(0.0, 1.0);
                let p = &mut sq[y as usize * big + x as usize];
                *p += cover * (v - *p).max(0.0);
            }
        }
    }
}

struct Case {
    name: String,
    sharp: Plane,
    blurred: Plane,
    psf: Psf,
}

fn make_case(name: String, sq: &[f64], psf: Psf, rng: &mut Rng) -> Case {
    let big = SIDE + 2 * CONTEXT;
    let (cx, cy) = (psf.width / 2, psf.height / 2);
    let taps: Vec<(usize, usize, f64)> = (0..psf.height)
        .flat_map(|ky| (0..psf.width).map(move |kx| (kx, ky)))
        .map(|(kx, ky)| (kx, ky, psf.at(kx, ky)))
        .filter(|t| t.2 > 0.0)
        .collect();
    let mut sharp = Vec::with_capacity(SIDE * SIDE);
    let mut blurred = Vec::with_capacity(SIDE * SIDE);
    for y in CONTEXT..CONTEXT + SIDE {
        for x in CONTEXT..CONTEXT + SIDE {
            sharp.push(((sq[y * big + x].min(1.0) * 255.0).round() / 255.0) as f32);
            let mut acc = 0.0;
            for &(kx, ky, k) in &taps {
                acc += k * sq[(y + cy - ky) * big + x + cx - kx];
            }
            let v = (acc + noise() * rng.normal()).clamp(0.0, 1.0);
            blurred.push(((v * 255.0).round() / 255.0) as f32);
        }
    }
    Case {
        name,
        sharp: Plane::new(SIDE, SIDE, sharp).expect("plane"),
        blurred: Plane::new(SIDE, SIDE, blurred).expect("plane"),
        psf,
    }
}

#[derive(Clone, Copy, PartialEq)]
enum Split {
    Tune,
    /// The TUNE photos with [`shake_tremor`] kernels and other seeds (tuning only).
    Tremor,
    /// Repetitive textures (tuning only): generated walls, pebbles and strands
    /// ([`textures`]) and the unused skimage photos `text`, `moon`, `clock`.
    Texture,
    Eval,
    /// EVAL's photos and kernel generators with other seeds: a second held-out split, for
    /// confirming a choice made after EVAL was seen (never tuned on).
    Eval2,
    /// The same with seeds from 21 000 001 (used once, 2026-12-05).
    Eval3,
    /// The same with seeds from 31 000 001 (used once, 2026-12-05).
    Eval4,
    /// The same with seeds from 41 000 001 (used 2026-12-05, at four noise levels).
    Eval5,
    /// The same with seeds from 51 000 001 (used 2026-12-05, at two noise levels).
    Eval6,
    /// The same with seeds from 61 000 001 (used 2026-12-07, the shipped estimator).
    Eval7,
    /// The same with seeds from 71 000 001 (used once, 2026-12-08, the shipped estimator).
    Eval8,
    /// The same with seeds from 101 000 001 (81 and 91 million seed the `large` modes): the
    /// next confirmation split, unused until then.
    Eval9,
    /// Levin et al. 2009's real camera-shake set from `CALIPER_LEVIN_DIR` (never tuned on):
    /// the captured blurred images ([`levin`]).
    Levin,
    /// The same pairs, blurred here with the measured kernels and σ = 0.01.
    LevinSynth,
}

impl Split {
    /// Whether this is one of the held-out splits made with EVAL's photos and generators.
    fn is_eval(self) -> bool {
        matches!(
            self,
            Split::Eval
                | Split::Eval2
                | Split::Eval3
                | Split::Eval4
                | Split::Eval5
                | Split::Eval6
                | Split::Eval7
                | Split::Eval8
                | Split::Eval9
        )
    }
}

fn sources(root: &Path, split: Split) -> Vec<(String, PathBuf)> {
    let sk = root.join("blur/skimage");
    let mut out = Vec::new();
    match split {
        Split::Tune | Split::Tremor => {
            for n in [
                "astronaut",
                "camera",
                "coffee",
                "chelsea",
                "immunohistochemistry",
            ] {
                out.push((n.to_string(), sk.join(format!("{n}.png"))));
            }
            for n in ["left01", "left03", "left05", "left07", "left09", "left11"] {
                out.push((
                    n.to_string(),
                    root.join(format!("camera/opencv_stereo/{n}.jpg")),
                ));
            }
        }
        Split::Texture => {
            for n in ["text", "moon", "clock"] {
                out.push((n.to_string(), sk.join(format!("{n}.png"))));
            }
        }
        Split::Levin | Split::LevinSynth => {}
        // The held-out splits (`Split::is_eval`): EVAL's photos.
        _ => {
            for n in [
                "brick",
                "coins",
                "rocket",
                "grass",
                "gravel",
                "hubble_deep_field",
            ] {
                out.push((n.to_string(), sk.join(format!("{n}.png"))));
            }
            for n in [1, 5, 9, 13, 17, 21] {
                out.push((
                    format!("fisheye{n}"),
                    root.join(format!("camera/boofcv_fisheye_chessboard/{n}.jpg")),
                ));
            }
        }
    }
    out
}

/// Levin et al.'s pairs as cases (see `common/levin.rs`); none when the folder is not set.
fn levin_cases(split: Split) -> Vec<Case> {
    let Ok(dir) = std::env::var("CALIPER_LEVIN_DIR") else {
        eprintln!("CALIPER_LEVIN_DIR is not set: no Levin cases");
        return Vec::new();
    };
    match levin::cases(Path::new(&dir), split == Split::LevinSynth) {
        Ok(v) => v
            .into_iter()
            .map(|c| Case {
                name: c.name,
                sharp: Plane::new(c.side, c.side, c.sharp).expect("plane"),
                blurred: Plane::new(c.side, c.side, c.blurred).expect("plane"),
                psf: Psf::from_weights(c.kernel.0, c.kernel.1, c.kernel.2).expect("psf"),
            })
            .collect(),
        Err(e) => {
            eprintln!("Levin set: {e}");
            Vec::new()
        }
    }
}

fn cases(root: &Path, split: Split) -> Vec<Case> {
    if matches!(split, Split::Levin | Split::LevinSynth) {
        return levin_cases(split);
    }
    let mut out = Vec::new();
    let saturate = std::env::var("BLIND_SAT").ok();
    let base = match split {
        Split::Tune => 1u64,
        Split::Tremor => 5_000_001,
        Split::Texture => 7_000_001,
        Split::Eval | Split::Levin | Split::LevinSynth => 1_000_001,
        Split::Eval2 => 11_000_001,
        Split::Eval3 => 21_000_001,
        Split::Eval4 => 31_000_001,
        Split::Eval5 => 41_000_001,
        Split::Eval6 => 51_000_001,
        Split::Eval7 => 61_000_001,
        Split::Eval8 => 71_000_001,
        Split::Eval9 => 101_000_001,
    };
    let mut srcs: Vec<(String, Option<textures::Source>)> = sources(root, split)
        .into_iter()
        .map(|(name, path)| {
            let src = load(&path);
            if src.is_none() {
                eprintln!("missing source {} (set CALIPER_BLIND_DATA)", path.display());
            }
            (name, src)
        })
        .collect();
    if split == Split::Texture {
        for k in 0..2u64 {
            srcs.push((format!("tiles{k}"), Some(textures::tiles(base + 100 + k))));
            srcs.push((
                format!("pebbles{k}"),
                Some(textures::pebbles(base + 200 + k)),
            ));
            srcs.push((
                format!("strands{k}"),
                Some(textures::strands(base + 300 + k)),
            ));
        }
    }
    for (si, (name, src)) in srcs.into_iter().enumerate() {
        let Some(src) = src else {
            continue;
        };
        for j in 0..4u64 {
            let seed = base + 10 * si as u64 + j;
            let mut rng = Rng::new(seed);
            let extent = 11.0 + 30.0 * (j as f64 + rng.uniform()) / 4.0;
            let (gen_name, psf) = if split.is_eval() && j % 2 == 1 {
                ("imp", shake_impulsive(&mut rng, extent))
            } else if split == Split::Tremor {
                ("trem", shake_tremor(&mut rng, extent))
            } else {
                ("3d", shake_3d(&mut rng, extent))
            };
            let mut sq = crop(&src, &mut rng);
            match saturate.as_deref() {
                Some("1") => overexpose(&mut sq, seed),
                Some("2") => light_sources(&mut sq, seed),
                _ => {}
            }
            out.push(make_case(
                format!("{name}/{gen_name}{seed}_{extent:.0}"),
                &sq,
                psf,
                &mut rng,
            ));
        }
    }
    out
}

/// Extent (bounding box of entries ≥ 5 % of the max), support count and RMS radius.
fn kernel_stats(k: &Psf) -> String {
    let max = k.data.iter().copied().fold(0.0, f64::max);
    let (mut x0, mut x1, mut y0, mut y1, mut n) = (usize::MAX, 0, usize::MAX, 0, 0);
    let (mut mx, mut my) = (0.0, 0.0);
    for y in 0..k.height {
        for x in 0..k.width {
            let v = k.at(x, y);
            mx += v * x as f64;
            my += v * y as f64;
            if v >= 0.05 * max {
                (x0, x1, y0, y1) = (x0.min(x), x1.max(x), y0.min(y), y1.max(y));
                n += 1;
            }
        }
    }
    let mut r2 = 0.0;
    for y in 0..k.height {
        for x in 0..k.width {
            r2 += k.at(x, y) * ((x as f64 - mx).powi(2) + (y as f64 - my).powi(2));
        }
    }
    format!(
        "extent {:>2}x{:<2} support {:>3} rms {:5.2} peak {:.3}",
        x1 + 1 - x0,
        y1 + 1 - y0,
        n,
        r2.sqrt(),
        max
    )
}

fn print_kernel(k: &Psf) {
    let max = k.data.iter().copied().fold(0.0, f64::max);
    for y in 0..k.height {
        let row: String = (0..k.width)
            .map(|x| {
                let v = k.at(x, y) / max;
                match v {
                    v if v > 0.6 => '#',
                    v if v > 0.3 => '+',
                    v if v > 0.1 => '.',
                    v if v > 0.0 => ',',
                    _ => ' ',
                }
            })
            .collect();
        eprintln!("  |{row}|");
    }
}

/// The true kernel above the estimated one.
fn print_kernels(truth: &Psf, estimate: &Psf) {
    eprintln!(" true:");
    print_kernel(truth);
    eprintln!(" estimated:");
    print_kernel(estimate);
}

/// Counts a case at ratio ≤ 3 per source image and per kernel-size class.
fn tally(
    per_source: &mut Vec<(String, usize, usize)>,
    by_size: &mut [(usize, usize); 2],
    case: &Case,
    r: f64,
) {
    let src = case.name.split('/').next().unwrap_or("").to_string();
    match per_source.iter_mut().find(|(n, _, _)| *n == src) {
        Some(e) => {
            e.1 += usize::from(r <= 3.0);
            e.2 += 1;
        }
        None => per_source.push((src, usize::from(r <= 3.0), 1)),
    }
    let slot = &mut by_size[usize::from(case.psf.width > SIZE_SPLIT)];
    slot.0 += usize::from(r <= 3.0);
    slot.1 += 1;
}

/// Root of the sharp photos: `CALIPER_BLIND_DATA`, else the shared data beside the project.
fn data_root() -> PathBuf {
    PathBuf::from(std::env::var("CALIPER_BLIND_DATA").unwrap_or_else(|_| "../shared/data".into()))
}

fn run(split: Split, only: Option<&str>, verbose: bool) {
    let root = data_root();
    let mut params = BlindParams::default();
    // Experiment knobs (defaults = the library's defaults).
    if let Some(k) = std::env::var("BLIND_KS").ok().and_then(|v| v.parse().ok()) {
        params.kernel_size = Some(k);
    }
    if let Some(k) = std::env::var("BLIND_ITERS")
        .ok()
        .and_then(|v| v.parse().ok())
    {
        params.iterations_per_level = k;
    }
    if let Some(t) = std::env::var("BLIND_THRESHOLD")
        .ok()
        .and_then(|v| v.parse().ok())
    {
        params.kernel_threshold = Some(t);
    }
    if let Some(g) = std::env::var("BLIND_REG").ok().and_then(|v| v.parse().ok()) {
        params.kernel_reg = g;
    }
    if let Some(l) = std::env::var("BLIND_LAMBDA")
        .ok()
        .and_then(|v| v.parse().ok())
    {
        params.lambda_grad = l;
    }
    let fixed = match std::env::var("BLIND_FIXED").as_deref() {
        Ok("finest") => Some(KernelStart::Finest),
        Ok("pyramid") => Some(KernelStart::Pyramid),
        _ => None,
    };
    let mut ratios = Vec::new();
    // (the shipped flag: agreement below the photo's threshold, the misfit experiment of the
    // kept kernel, ratio) of the cases that had two candidates.
    let mut warnings: Vec<(bool, f64, f64)> = Vec::new();
    let mut times = Vec::new();
    let mut per_source: Vec<(String, usize, usize)> = Vec::new();
    // Cases at ratio <= 3 and all cases, by true kernel side <= SIZE_SPLIT px and beyond.
    let mut by_size = [(0usize, 0usize); 2];
    let mut psnrs: Vec<(f64, f64)> = Vec::new();
    // The peer (`BLIND_PEER`, see `common/blind_peer.rs`): its ratios and times, its tallies.
    let peer = std::env::var("BLIND_PEER").ok();
    let peer_dir = std::env::temp_dir().join(format!("blind_peer_{}", std::process::id()));
    if peer.is_some() {
        std::fs::create_dir_all(&peer_dir).expect("peer scratch dir");
    }
    let mut peer_rows: Vec<(f64, f64)> = Vec::new();
    let mut peer_source: Vec<(String, usize, usize)> = Vec::new();
    let mut peer_size = [(0usize, 0usize); 2];
    for case in cases(&root, split) {
        if only.is_some_and(|o| !case.name.contains(o)) {
            continue;
        }
        let mut params = params.clone();
        if let Some(f) = std::env::var("BLIND_ORACLE")
            .ok()
            .and_then(|v| v.parse::<f64>().ok())
        {
            // Experiment: window from the true kernel extent (upper bound for size estimation).
            params.kernel_size = Some(((f * case.psf.width as f64).round() as usize) | 1);
        }
        if std::env::var("BLIND_NOSAT").is_ok() {
            params.final_tv.saturation = None;
        }
        if let Some(mode) = fixed {
            // Is the truth a fixed point? Start from it in a window of 1.3 × its side.
            let truth =
                tv_deconv(&case.blurred, &case.psf, &params.final_tv, &NoProgress).expect("tv");
            let side = ((1.3 * case.psf.width as f64).round() as usize) | 1;
            let start = Psf::from_weights(side, side, case.psf.centred_weights(side)).expect("psf");
            let k = estimate_kernel_from(&case.blurred, &params, &start, mode).expect("refine");
            let img = tv_deconv(&case.blurred, &k, &params.final_tv, &NoProgress).expect("tv");
            let r =
                error_ratio_aligned(&case.sharp, &img, &truth, BORDER, MAX_SHIFT).expect("ratio");
            println!(
                "{:<34} true {:>2} px  from truth  ratio {r:7.2}{}  {}",
                case.name,
                case.psf.width,
                if r > 3.0 { "  FAIL" } else { "" },
                kernel_stats(&k)
            );
            if verbose {
                print_kernels(&case.psf, &k);
            }
            tally(&mut per_source, &mut by_size, &case, r);
            ratios.push(r);
            times.push(0.0);
            continue;
        }
        let t = Instant::now();
        // `blind_deconv`, keeping the estimate's agreement between candidates.
        let est = estimate_kernel_restored(&case.blurred, &params, &NoProgress).expect("blind");
        let image = match est.restored {
            Some(x) => x,
            None => tv_deconv(&case.blurred, &est.psf, &params.final_tv, &NoProgress).expect("tv"),
        };
        let out = BlindOutput {
            image,
            psf: est.psf,
        };
        let dt = t.elapsed().as_secs_f64();
        let truth = tv_deconv(&case.blurred, &case.psf, &params.final_tv, &NoProgress).expect("tv");
        let r =
            error_ratio_aligned(&case.sharp, &out.image, &truth, BORDER, MAX_SHIFT).expect("ratio");
        // Absolute quality beside the ratio: PSNR (15 px border) of the true-kernel restoration
        // and, through the ratio of SSDs, of the aligned estimate.
        let inner = |p: &Plane| {
            let mut v = Vec::new();
            for y in BORDER..p.height - BORDER {
                v.extend_from_slice(&p.data[y * p.width + BORDER..(y + 1) * p.width - BORDER]);
            }
            Plane::new(p.width - 2 * BORDER, p.height - 2 * BORDER, v).expect("plane")
        };
        let p_truth = psnr(&inner(&case.sharp), &inner(&truth), 1.0).expect("psnr");
        let p_est = p_truth - 10.0 * r.log10();
        println!(
            "{:<34} true {:>2} px  est {:>2} px  ratio {:>7.2}  {:.2} s  psnr {:5.2} / {:5.2}{}",
            case.name,
            case.psf.width,
            out.psf.width,
            r,
            dt,
            p_est,
            p_truth,
            if r > 3.0 { "  FAIL" } else { "" }
        );
        psnrs.push((p_est, p_truth));
        if let Some(cmd) = peer.as_deref() {
            // Same input, same window, same TV restoration and ratio.
            let stem = case.name.replace('/', "_");
            match blind_peer::estimate(cmd, &case.blurred, out.psf.width, &peer_dir, &stem) {
                Ok((k, secs)) => {
                    let img =
                        tv_deconv(&case.blurred, &k, &params.final_tv, &NoProgress).expect("tv");
                    let rp = error_ratio_aligned(&case.sharp, &img, &truth, BORDER, MAX_SHIFT)
                        .expect("ratio");
                    println!(
                        "{:<34} peer ratio {rp:>7.2}  {secs:.2} s{}",
                        "",
                        if rp > 3.0 { "  FAIL" } else { "" }
                    );
                    if verbose {
                        eprintln!(" peer:");
                        print_kernel(&k);
                    }
                    tally(&mut peer_source, &mut peer_size, &case, rp);
                    peer_rows.push((rp, secs));
                }
                Err(e) => eprintln!("peer: {e}"),
            }
        }
        if let Ok(dir) = std::env::var("BLIND_DUMP") {
            let stem = case.name.replace('/', "_");
            for (tag, p) in [
                ("sharp", &case.sharp),
                ("blurred", &case.blurred),
                ("est", &out.image),
            ] {
                let g = p.to_gray();
                let _ = image::GrayImage::from_raw(g.width, g.height, g.data)
                    .map(|i| i.save(format!("{dir}/{stem}_{tag}.png")));
            }
        }
        if std::env::var("BLIND_TRACE").is_ok() {
            let (_, levels) =
                estimate_kernel_trace(&case.blurred, &params, &NoProgress).expect("trace");
            eprintln!("  truth {}", kernel_stats(&case.psf));
            for (i, k) in levels.iter().enumerate() {
                let img = tv_deconv(&case.blurred, k, &params.final_tv, &NoProgress).expect("tv");
                let r = error_ratio_aligned(&case.sharp, &img, &truth, BORDER, MAX_SHIFT)
                    .expect("ratio");
                eprintln!("  level {i}: ratio {r:7.2}  {}", kernel_stats(k));
            }
        }
        if verbose {
            print_kernels(&case.psf, &out.psf);
        }
        tally(&mut per_source, &mut by_size, &case, r);
        if let (Some(a), Some(below)) = (est.agreement, est.uncertain_below) {
            warnings.push((a < below, misfit(&case.blurred, &out.image, &out.psf), r));
        }
        ratios.push(r);
        times.push(dt);
    }
    let line: Vec<String> = per_source
        .iter()
        .map(|(n, ok, all)| format!("{n} {ok}/{all}"))
        .collect();
    println!("per source (<=3): {}", line.join(", "));
    // The shipped warning sign, then the misfit experiment alone and with it (see `misfit`).
    type Sign = fn(&(bool, f64, f64)) -> bool;
    let signs: [(String, Sign); 3] = [
        (
            format!("uncertain (agreement < {UNCERTAIN_AGREEMENT} at σ̂ <= 0.01, lower above)"),
            |w| w.0,
        ),
        (format!("misfit > {MISFIT_LIMIT} (experiment)"), |w| {
            w.1 > MISFIT_LIMIT
        }),
        ("either (experiment)".into(), |w| w.0 || w.1 > MISFIT_LIMIT),
    ];
    for (label, flagged) in signs.iter().filter(|_| !warnings.is_empty()) {
        let (on, off): (Vec<_>, Vec<_>) = warnings.iter().partition(|w| flagged(w));
        let ok = |v: &[&(bool, f64, f64)]| v.iter().filter(|w| w.2 <= 3.0).count();
        println!(
            "{label}: {} cases, {} at <=3; the others {}, {} at <=3",
            on.len(),
            ok(&on),
            off.len(),
            ok(&off)
        );
    }
    if !psnrs.is_empty() {
        let n = psnrs.len() as f64;
        println!(
            "mean PSNR (dB): estimated kernel {:.2}, true kernel {:.2}",
            psnrs.iter().map(|p| p.0).sum::<f64>() / n,
            psnrs.iter().map(|p| p.1).sum::<f64>() / n
        );
    }
    println!(
        "by kernel side (<=3): <= {SIZE_SPLIT} px {}/{}, > {SIZE_SPLIT} px {}/{}",
        by_size[0].0, by_size[0].1, by_size[1].0, by_size[1].1
    );
    if !peer_rows.is_empty() {
        let line: Vec<String> = peer_source
            .iter()
            .map(|(n, ok, all)| format!("{n} {ok}/{all}"))
            .collect();
        println!("peer per source (<=3): {}", line.join(", "));
        println!(
            "peer by kernel side (<=3): <= {SIZE_SPLIT} px {}/{}, > {SIZE_SPLIT} px {}/{}",
            peer_size[0].0, peer_size[0].1, peer_size[1].0, peer_size[1].1
        );
        let n = peer_rows.len();
        let mut r: Vec<f64> = peer_rows.iter().map(|p| p.0).collect();
        let mut t: Vec<f64> = peer_rows.iter().map(|p| p.1).collect();
        r.sort_by(f64::total_cmp);
        t.sort_by(f64::total_cmp);
        let le = |x: f64| r.iter().filter(|&&v| v <= x).count();
        println!(
            "peer {n} cases: <=3 {}/{n} ({:.0} %), <=2 {}/{n}, median {:.2}, worst {:.2}, \
             s/image (kernel only) median {:.2}",
            le(3.0),
            100.0 * le(3.0) as f64 / n as f64,
            le(2.0),
            r[n / 2],
            r[n - 1],
            t[n / 2]
        );
        let _ = std::fs::remove_dir_all(&peer_dir);
    }
    if ratios.is_empty() {
        return;
    }
    let n = ratios.len();
    let mut sorted = ratios.clone();
    sorted.sort_by(f64::total_cmp);
    let le = |t: f64| ratios.iter().filter(|&&r| r <= t).count();
    times.sort_by(f64::total_cmp);
    println!(
        "{} cases: <=3 {}/{} ({:.0} %), <=2 {}/{} ({:.0} %), median {:.2}, worst {:.2}, \
         s/image median {:.2} max {:.2}",
        n,
        le(3.0),
        n,
        100.0 * le(3.0) as f64 / n as f64,
        le(2.0),
        n,
        100.0 * le(2.0) as f64 / n as f64,
        sorted[n / 2],
        sorted[n - 1],
        times[n / 2],
        times[n - 1]
    );
}

fn time() {
    let root = data_root();
    let cs = cases(&root, Split::Tune);
    let c = &cs[1];
    let mut params = BlindParams::default();
    if std::env::var("BLIND_NOSAT").is_ok() {
        params.final_tv.saturation = None;
    }
    let t = Instant::now();
    blind_deconv(&c.blurred, &params, &NoProgress).expect("blind");
    println!("255x255 ({}): {:.2} s", c.name, t.elapsed().as_secs_f64());
    // ~1 Mpx: astronaut resized to 1155×866, 31 px shake.
    let (w, h, data) = load(&root.join("blur/skimage/astronaut.png")).expect("astronaut");
    let img = image::ImageBuffer::<image::Luma<f32>, Vec<f32>>::from_raw(w as u32, h as u32, data)
        .expect("buffer");
    let img = image::imageops::resize(&img, 1155, 866, image::imageops::FilterType::Triangle);
    let psf = shake_3d(&mut Rng::new(77), 31.0);
    let src: Vec<f32> = img.into_raw();
    let (w, h) = (1155usize, 866usize);
    let (cx, cy) = (psf.width / 2, psf.height / 2);
    let mut rng = Rng::new(78);
    let mut data = vec![0.0f32; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut acc = 0.0;
            for ky in 0..psf.height {
                for kx in 0..psf.width {
                    let k = psf.at(kx, ky);
                    if k > 0.0 {
                        let sx = (x + cx).saturating_sub(kx).min(w - 1);
                        let sy = (y + cy).saturating_sub(ky).min(h - 1);
                        acc += k * f64::from(src[sy * w + sx]);
                    }
                }
            }
            data[y * w + x] = (acc + noise() * rng.normal()).clamp(0.0, 1.0) as f32;
        }
    }
    let blurred = Plane::new(w, h, data).expect("plane");
    let t = Instant::now();
    let out = blind_deconv(&blurred, &params, &NoProgress).expect("blind");
    println!(
        "1155x866 (1.0 Mpx): {:.2} s (kernel {} px)",
        t.elapsed().as_secs_f64(),
        out.psf.width
    );
    // The peer's kernel estimate on the same photo with the same window, timed by its own
    // process (`BLIND_PEER`; it runs on one core).
    if let Ok(cmd) = std::env::var("BLIND_PEER") {
        let dir = std::env::temp_dir().join("blind_eval_time_peer");
        std::fs::create_dir_all(&dir).expect("peer dir");
        match blind_peer::estimate(&cmd, &blurred, out.psf.width, &dir, "mpx") {
            Ok((_, secs)) => println!("1155x866 peer kernel estimate alone: {secs:.2} s"),
            Err(e) => eprintln!("peer: {e}"),
        }
    }
    // The share of one final TV solve in that time (the rest is the two kernel estimates and
    // their restorations, run side by side).
    let t = Instant::now();
    tv_deconv(&blurred, &out.psf, &params.final_tv, &NoProgress).expect("tv");
    println!(
        "1155x866 one TV solve alone: {:.2} s",
        t.elapsed().as_secs_f64()
    );
}

/// Blind selection criteria of a restoration `x` with kernel `k` of `y`: mean squared reblur
/// residual over the pixels whose kernel footprint is inside, mean |∇x| (L1), share of |∇x| > 0.02.
fn criteria(y: &Plane, x: &Plane, k: &Psf) -> (f64, f64, f64) {
    let (w, h) = (y.width, y.height);
    let (cx, cy) = (k.width / 2, k.height / 2);
    let m = k.width.max(k.height);
    let (mut res, mut n) = (0.0, 0usize);
    for py in m..h - m {
        for px in m..w - m {
            let mut acc = 0.0;
            for ky in 0..k.height {
                for kx in 0..k.width {
                    let v = k.at(kx, ky);
                    if v > 0.0 {
                        acc += v * f64::from(x.at(px + cx - kx, py + cy - ky));
                    }
                }
            }
            res += (acc - f64::from(y.at(px, py))).powi(2);
            n += 1;
        }
    }
    let (mut tv, mut l0, mut g) = (0.0, 0usize, 0usize);
    for py in BORDER..h - BORDER {
        for px in BORDER..w - BORDER {
            let gx = f64::from(x.at(px + 1, py) - x.at(px, py));
            let gy = f64::from(x.at(px, py + 1) - x.at(px, py));
            let mag = gx.hypot(gy);
            tv += gx.abs() + gy.abs();
            l0 += usize::from(mag > 0.02);
            g += 1;
        }
    }
    (res / n as f64, tv / g as f64, l0 as f64 / g as f64)
}

/// Experiment: several starts per case with their true ratios and blind criteria.
fn starts(split: Split) {
    let root = data_root();
    for case in cases(&root, split) {
        let truth =
            tv_deconv(&case.blurred, &case.psf, &TvParams::default(), &NoProgress).expect("tv");
        let lam = caliper_core::deconv::auto_tv_lambda(&case.blurred);
        let est = estimate_blur_extent(&case.blurred, Some(DEFAULT_SATURATION as f32), &NoProgress)
            .expect("size")
            .unwrap_or(0.0);
        for ks in [None, Some(21), Some(31), Some(45)] {
            let params = BlindParams {
                kernel_size: ks,
                ..BlindParams::default()
            };
            let out = blind_deconv(&case.blurred, &params, &NoProgress).expect("blind");
            let r = error_ratio_aligned(&case.sharp, &out.image, &truth, BORDER, MAX_SHIFT)
                .expect("ratio");
            let (res, tv, l0) = criteria(&case.blurred, &out.image, &out.psf);
            println!(
                "C {} {} {} {est} {r:.4} {res:.6e} {tv:.6e} {l0:.6e} {lam:.6e}",
                case.name,
                ks.unwrap_or(0),
                out.psf.width
            );
        }
    }
}

/// Experiment: the kernel at two cleaning thresholds (the default and 0.05) per case, with
/// the true ratio of each and blind selection criteria, for offline analysis of whether a
/// blind criterion picks the better threshold or flags a wrong kernel. One line per candidate,
/// `T case threshold window ratio residual tv l0 sparsity support border effective misfit`
/// ([`criteria`]; the normalised sparsity `Σ|∇x| / ‖∇x‖₂` of the restoration; [`kernel_shape`];
/// [`misfit`]), then `A case agreement σ̂` ([`kernel_agreement`], [`estimate_noise_sigma`]).
fn thresholds(split: Split) {
    let root = data_root();
    // `BLIND_PAIR=A,B` tries other thresholds, `BLIND_KS` fixes the window (experiments).
    let pair: Vec<f64> = std::env::var("BLIND_PAIR")
        .ok()
        .map(|v| v.split(',').filter_map(|t| t.trim().parse().ok()).collect())
        .unwrap_or_else(|| vec![DEFAULT_KERNEL_THRESHOLD, LOW_KERNEL_THRESHOLD]);
    let kernel_size = std::env::var("BLIND_KS").ok().and_then(|v| v.parse().ok());
    for case in cases(&root, split) {
        let truth =
            tv_deconv(&case.blurred, &case.psf, &TvParams::default(), &NoProgress).expect("tv");
        let mut psfs = Vec::new();
        for &t in &pair {
            let params = BlindParams {
                kernel_threshold: Some(t),
                kernel_size,
                ..BlindParams::default()
            };
            let out = blind_deconv(&case.blurred, &params, &NoProgress).expect("blind");
            let r = error_ratio_aligned(&case.sharp, &out.image, &truth, BORDER, MAX_SHIFT)
                .expect("ratio");
            let (res, tv, l0) = criteria(&case.blurred, &out.image, &out.psf);
            let x = &out.image;
            let (mut l1, mut l2) = (0.0f64, 0.0f64);
            for py in BORDER..x.height - BORDER {
                for px in BORDER..x.width - BORDER {
                    let gx = f64::from(x.at(px + 1, py) - x.at(px, py));
                    let gy = f64::from(x.at(px, py + 1) - x.at(px, py));
                    l1 += gx.abs() + gy.abs();
                    l2 += gx * gx + gy * gy;
                }
            }
            let support = out.psf.data.iter().filter(|&&v| v > 0.0).count();
            let (border, eff) = kernel_shape(&out.psf);
            let misfit = misfit(&case.blurred, &out.image, &out.psf);
            psfs.push(out.psf.clone());
            println!(
                "T {} {t} {} {r:.4} {res:.6e} {tv:.6e} {l0:.6e} {:.6e} {support} {border:.4} {eff:.2} {misfit:.4}",
                case.name,
                out.psf.width,
                l1 / l2.sqrt().max(1e-12)
            );
        }
        if psfs.len() == 2 {
            println!(
                "A {} {:.4} {:.6e}",
                case.name,
                kernel_agreement(&psfs[0], &psfs[1], AGREEMENT_SHIFT),
                estimate_noise_sigma(&case.blurred)
            );
        }
    }
}

/// Experiment (2026-12-05, not shipped; `core/benches/deconv_set.md`): the mean squared
/// re-blur residual of restoration `x` with kernel `k` over `σ̂² + ε·TV(x)²`, σ̂ the photo's
/// noise (the TV weight's estimate, at least 0.003), `TV(x)` the restoration's mean
/// anisotropic gradient magnitude, ε [`MISFIT_SIGNAL_WEIGHT`]. A kernel that claims more blur
/// than the photo has leaves a residual no latent explains. The first version (ε = 0) fired on
/// good restorations of clean photos (`BLIND_NOISE=0.003`); the signal term stands for the
/// residual of a kernel a little off, which scales with the latent's gradients. Chosen on the
/// tuning splits at σ = 0.003, 0.01 and 0.02 (no passing case flagged), it caught few
/// failures held out (EVAL5 at 0.01 and 0.003, EVAL6 at 0.006), so it stays here.
fn misfit(y: &Plane, x: &Plane, k: &Psf) -> f64 {
    let (res, tv, _) = criteria(y, x, k);
    let sigma = estimate_noise_sigma(y).max(0.003);
    res / (sigma * sigma + MISFIT_SIGNAL_WEIGHT * tv * tv)
}

/// The misfit above which the experiment flags a kernel (chosen on the tuning splits).
const MISFIT_LIMIT: f64 = 1.5;

/// ε of [`misfit`] (chosen on the tuning splits with [`MISFIT_LIMIT`]).
const MISFIT_SIGNAL_WEIGHT: f64 = 0.02;

/// Share of the kernel's mass within 2 px of its window's edge, and its effective number of
/// entries `1 / Σk²` (the kernel is normalised).
fn kernel_shape(k: &Psf) -> (f64, f64) {
    let (mut edge, mut sq) = (0.0, 0.0);
    for y in 0..k.height {
        for x in 0..k.width {
            let v = k.at(x, y);
            sq += v * v;
            if x < 2 || y < 2 || x + 2 >= k.width || y + 2 >= k.height {
                edge += v;
            }
        }
    }
    (edge, 1.0 / sq.max(1e-12))
}

/// Blur-extent estimate against the truth's bounding box (entries >= 5 % of the max).
fn sizes(split: Split) {
    let root = data_root();
    let mut rel = Vec::new();
    for case in cases(&root, split) {
        let k = &case.psf;
        let max = k.data.iter().copied().fold(0.0, f64::max);
        let (mut x0, mut x1, mut y0, mut y1) = (usize::MAX, 0, usize::MAX, 0);
        for y in 0..k.height {
            for x in 0..k.width {
                if k.at(x, y) >= 0.05 * max {
                    (x0, x1, y0, y1) = (x0.min(x), x1.max(x), y0.min(y), y1.max(y));
                }
            }
        }
        let truth = (x1 + 1 - x0).max(y1 + 1 - y0) as f64;
        let est = estimate_blur_extent(&case.blurred, Some(DEFAULT_SATURATION as f32), &NoProgress)
            .expect("size");
        let e = est.unwrap_or(0.0);
        if std::env::var("BLIND_PROFILES").is_ok() {
            let pr = gradient_autocorrelation(
                &case.blurred,
                80,
                Some(DEFAULT_SATURATION as f32),
                &NoProgress,
            )
            .expect("r");
            for r in &pr {
                let v: Vec<String> = r.iter().map(|v| format!("{v:.4}")).collect();
                eprintln!("P {} {truth} {}", case.name, v.join(" "));
            }
        }
        rel.push(e / truth);
        println!(
            "{:<34} truth {truth:>3}  est {e:>5.1}  ratio {:.2}",
            case.name,
            e / truth
        );
    }
    rel.sort_by(f64::total_cmp);
    let n = rel.len();
    let within = |t: f64| rel.iter().filter(|&&r| (r - 1.0).abs() <= t).count();
    println!(
        "{n} cases: est/truth median {:.2}, 10-90 % {:.2}-{:.2}, within 20 % {}, within 35 % {}",
        rel[n / 2],
        rel[n / 10],
        rel[n * 9 / 10],
        within(0.2),
        within(0.35)
    );
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let only = args
        .iter()
        .position(|a| a == "--only")
        .and_then(|i| args.get(i + 1))
        .map(String::as_str);
    let verbose = args.iter().any(|a| a == "-v");
    match args.first().map(String::as_str) {
        Some("tune") => run(Split::Tune, only, verbose),
        Some("tremor") => run(Split::Tremor, only, verbose),
        Some("texture") => run(Split::Texture, only, verbose),
        Some("eval") => run(Split::Eval, only, verbose),
        Some("eval2") => run(Split::Eval2, only, verbose),
        Some("eval3") => run(Split::Eval3, only, verbose),
        Some("eval4") => run(Split::Eval4, only, verbose),
        Some("eval5") => run(Split::Eval5, only, verbose),
        Some("eval6") => run(Split::Eval6, only, verbose),
        Some("eval7") => run(Split::Eval7, only, verbose),
        Some("eval8") => run(Split::Eval8, only, verbose),
        Some("eval9") => run(Split::Eval9, only, verbose),
        Some("levin") => run(Split::Levin, only, verbose),
        Some("levin-synth") => run(Split::LevinSynth, only, verbose),
        Some("time") => time(),
        Some("large") => large::large(false),
        Some("large-eval") => large::large(true),
        Some("huge") => large::huge(
            args.get(1)
                .and_then(|v| v.parse().ok())
                .unwrap_or(BlindParams::default().kernel_region),
        ),
        // `size`: blur-extent estimate vs truth; `starts`: several windows per TUNE case with
        // their true ratios and blind selection criteria (for offline analysis).
        Some("size") => sizes(Split::Tune),
        Some("starts") => starts(Split::Tune),
        // Tuning splits only: the held-out ones are not for per-criterion analysis.
        Some("thresholds") => match args.get(1).map(String::as_str) {
            Some("tune") | None => thresholds(Split::Tune),
            Some("tremor") => thresholds(Split::Tremor),
            Some("texture") => thresholds(Split::Texture),
            Some("levin") => thresholds(Split::Levin),
            Some("levin-synth") => thresholds(Split::LevinSynth),
            Some("eval5") => thresholds(Split::Eval5),
            Some("eval6") => thresholds(Split::Eval6),
            Some("eval7") => thresholds(Split::Eval7),
            Some("eval8") => thresholds(Split::Eval8),
            Some("eval9") => thresholds(Split::Eval9),
            Some(other) => {
                eprintln!("thresholds: {other}? tune|tremor|texture|levin|levin-synth")
            }
        },
        Some("size-tremor") => sizes(Split::Tremor),
        Some("size-texture") => sizes(Split::Texture),
        Some("size-eval") => sizes(Split::Eval),
        _ => eprintln!(
            "usage: blind_eval tune|tremor|texture|eval|eval2|eval3|eval4|eval5|eval6|eval7|eval8|eval9|levin|levin-synth|time|large|large-eval|huge [SIDE]|size|size-tremor|size-texture|size-eval|starts|thresholds [SPLIT] [--only TEXT] [-v]"
        ),
    }
}
