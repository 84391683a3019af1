//! Levin et al.'s real camera-shake benchmark for `blind_eval` (A. Levin, Y. Weiss, F. Durand,
//! W. T. Freeman, "Understanding and evaluating blind deconvolution algorithms", CVPR 2009):
//! four 255×255 grey photos of posters, each shaken by hand under eight kernels measured from
//! point lights (13–27 px). The issue-16 numbers for published methods were scored on it.
//!
//! Nothing of it is in this repository (its licence is the authors'). `CALIPER_LEVIN_DIR`
//! names a folder in the layout of the copy that many deblurring projects ship as PNGs:
//! `gt/im{1..4}.png` (sharp), `gt/kernel{1..8}.png` (the kernels, scaled to a maximum of 255)
//! and `im{i}_kernel{j}_img.png` (the blurred captures). Both modes score the same 32 pairs:
//!
//! * `levin`: the captured blurred images themselves (real blur, real noise, and a shift of a
//!   few pixels between each capture and its sharp photo, removed from the reference in
//!   [`cases`]);
//! * `levin-synth`: the sharp photo blurred here with the measured kernel ('same' convolution,
//!   mirrored borders), N(0, 0.01²) noise, clipping and 8-bit quantisation, as the issue's
//!   report describes its run.

use std::path::Path;

use super::rng::Rng;

/// One pair: name, sharp and blurred planes (row-major, `[0, 1]`), the kernel (side, weights
/// summing to 1).
pub struct LevinCase {
    pub name: String,
    pub side: usize,
    pub sharp: Vec<f32>,
    pub blurred: Vec<f32>,
    pub kernel: (usize, usize, Vec<f64>),
}

fn grey(path: &Path) -> Result<(usize, usize, Vec<f32>), String> {
    let img = image::open(path)
        .map_err(|e| format!("{}: {e}", path.display()))?
        .to_luma8();
    let (w, h) = img.dimensions();
    let data = img
        .into_raw()
        .into_iter()
        .map(|v| f32::from(v) / 255.0)
        .collect();
    Ok((w as usize, h as usize, data))
}

/// Blurs `sharp` (side × side) with `k` ('same', mirrored borders), adds N(0, σ²), clips and
/// quantises to 8 bits.
fn synthesise(side: usize, sharp: &[f32], k: &(usize, usize, Vec<f64>), rng: &mut Rng) -> Vec<f32> {
    convolve(side, sharp, k)
        .into_iter()
        .map(|acc| {
            let v = (acc + 0.01 * rng.normal()).clamp(0.0, 1.0);
            ((v * 255.0).round() / 255.0) as f32
        })
        .collect()
}

/// 'same' convolution with mirrored borders, no noise.
fn convolve(side: usize, sharp: &[f32], k: &(usize, usize, Vec<f64>)) -> Vec<f64> {
    let (kw, kh, kd) = k;
    let mirror = |v: isize| -> usize {
        let n = side as isize;
        let m = if v < 0 {
            -v - 1
        } else if v >= n {
            2 * n - v - 1
        } else {
            v
        };
        m.clamp(0, n - 1) as usize
    };
    let mut out = Vec::with_capacity(side * side);
    for y in 0..side as isize {
        for x in 0..side as isize {
            let mut acc = 0.0;
            for ky in 0..*kh {
                for kx in 0..*kw {
                    let w = kd[ky * kw + kx];
                    if w > 0.0 {
                        let sy = mirror(y + (kh / 2) as isize - ky as isize);
                        let sx = mirror(x + (kw / 2) as isize - kx as isize);
                        acc += w * f64::from(sharp[sy * side + sx]);
                    }
                }
            }
            out.push(acc);
        }
    }
    out
}

/// RMS of `blurred − shift(model)` over the interior (20 px border) at the best integer shift
/// within ±6 px, and that shift: `blurred(y, x) ≈ model(y + dy, x + dx)`.
fn residual(side: usize, model: &[f64], blurred: &[f32]) -> (f64, isize, isize) {
    let mut best = (f64::INFINITY, 0, 0);
    for dy in -6isize..=6 {
        for dx in -6isize..=6 {
            let (mut s, mut n) = (0.0, 0.0);
            for y in 20..side as isize - 20 {
                for x in 20..side as isize - 20 {
                    let m = model[((y + dy) as usize) * side + (x + dx) as usize];
                    let d = f64::from(blurred[y as usize * side + x as usize]) - m;
                    s += d * d;
                    n += 1.0;
                }
            }
            let r = (s / n).sqrt();
            if r < best.0 {
                best = (r, dy, dx);
            }
        }
    }
    best
}

/// `img(y + dy, x + dx)`, edges repeated.
fn shifted(side: usize, img: &[f32], dy: isize, dx: isize) -> Vec<f32> {
    let c = |v: isize| v.clamp(0, side as isize - 1) as usize;
    (0..side as isize)
        .flat_map(|y| (0..side as isize).map(move |x| (y, x)))
        .map(|(y, x)| img[c(y + dy) * side + c(x + dx)])
        .collect()
}

/// The kernel turned by 180°.
fn rotated(k: &(usize, usize, Vec<f64>)) -> (usize, usize, Vec<f64>) {
    (k.0, k.1, k.2.iter().rev().copied().collect())
}

/// The 32 pairs, captured (`synth` false) or synthesised from the sharp photos.
pub fn cases(dir: &Path, synth: bool) -> Result<Vec<LevinCase>, String> {
    let mut kernels = Vec::new();
    for j in 1..=8 {
        let (w, h, d) = grey(&dir.join(format!("gt/kernel{j}.png")))?;
        let sum: f64 = d.iter().map(|&v| f64::from(v)).sum();
        if sum <= 0.0 {
            return Err(format!("kernel{j}.png is empty"));
        }
        kernels.push((
            w,
            h,
            d.iter().map(|&v| f64::from(v) / sum).collect::<Vec<_>>(),
        ));
    }
    // The PNG copies do not all share one orientation (in that copy, kernels 4 and 8 explain the
    // captures as stored and the others turned by 180°), so each kernel takes the orientation
    // that explains its capture of the first photo best (residual 0.004–0.010 against
    // 0.02–0.06 for the other).
    let (w1, _, sharp1) = grey(&dir.join("gt/im1.png"))?;
    for (j, k) in kernels.iter_mut().enumerate() {
        let (_, _, cap) = grey(&dir.join(format!("im1_kernel{}_img.png", j + 1)))?;
        if w1 < 64 || cap.len() != w1 * w1 || sharp1.len() != w1 * w1 {
            return Err(
                "im1 and its captures must be square, of one size and at least 64 px".into(),
            );
        }
        let turned = rotated(k);
        if residual(w1, &convolve(w1, &sharp1, &turned), &cap).0
            < residual(w1, &convolve(w1, &sharp1, k), &cap).0
        {
            *k = turned;
        }
    }
    let mut out = Vec::new();
    for i in 1..=4 {
        let (w, h, sharp) = grey(&dir.join(format!("gt/im{i}.png")))?;
        if w != h || w < 64 {
            return Err(format!(
                "im{i}.png is {w}×{h}: square and at least 64 px expected"
            ));
        }
        for (j, k) in kernels.iter().enumerate() {
            let (blurred, reference) = if synth {
                let mut rng = Rng::new(9_000_001 + 10 * i as u64 + j as u64);
                (synthesise(w, &sharp, k, &mut rng), sharp.clone())
            } else {
                let (bw, bh, b) = grey(&dir.join(format!("im{i}_kernel{}_img.png", j + 1)))?;
                if (bw, bh) != (w, h) {
                    return Err(format!("im{i}_kernel{} is {bw}×{bh}", j + 1));
                }
                // A capture sits a few pixels off the sharp photo; the reference is moved onto
                // it, so that the restoration with the true kernel is aligned too (the scoring
                // searches shifts for the estimate only).
                let (_, dy, dx) = residual(w, &convolve(w, &sharp, k), &b);
                (b, shifted(w, &sharp, dy, dx))
            };
            out.push(LevinCase {
                name: format!("im{i}/k{}", j + 1),
                side: w,
                sharp: reference,
                blurred,
                kernel: k.clone(),
            });
        }
    }
    Ok(out)
}
