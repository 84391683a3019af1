//! Blur-extent estimation from the autocorrelation of the blurred image's gradients, so that the
//! kernel window (and with it the pyramid depth) can follow the blur instead of a fixed 31 px.
//!
//! If the sharp image's directional derivative `∂_d x` were white, the blurred one would have the
//! autocorrelation of `∂_d k`: its values along `d` vanish beyond the kernel's extent along `d`,
//! and for a motion path the two ends of the path (where the projected kernel starts and stops)
//! give the deepest negative lobe at a lag equal to that extent (a box of length `L` has a
//! derivative of two opposite impulses `L` apart). Natural images are far from white, but their
//! derivative autocorrelation decays within a few pixels, so the kernel's lobe dominates at the
//! lags that matter. This follows the idea of T. Hu and M.-H. Yang's / C. Liu et al.'s kernel
//! size estimation from gradient autocorrelation (e.g. G. Liu, S. Chang, Y. Ma, "Blind image
//! deblurring using spectral properties of convolution operators", IEEE TIP 23(12), 2014), in
//! a simple per-direction form: four directions (0°, 90°, ±45°), each lag in steps of that
//! direction, so that a diagonal path of bounding box `L × L` also reads `L`.

use rayon::prelude::*;

use super::super::Plane;
use super::BlindParams;
use crate::error::CoreResult;
use crate::progress::Progress;

/// The four directions as pixel steps: the lag `s` of direction `(dx, dy)` is the offset
/// `(s·dx, s·dy)`, which moves the bounding box by `s` px along x and/or y.
const DIRECTIONS: [(isize, isize); 4] = [(1, 0), (0, 1), (1, 1), (1, -1)];

/// The kernel window when none is given: [`WINDOW_FACTOR`] × the blur extent estimated by
/// [`estimate_blur_extent`], within [`MIN_WINDOW`] and a third of the shorter image side
/// (the fixed default of [`BlindParams::kernel_size_for`] when no blur lobe is found). A
/// fixed window is either too small for long shakes (the path is clipped) or too large for
/// short ones (the coarsest level no longer resolves them and the kernel step has more
/// unknowns to fit noise with; since the kernel solve stops early this costs little, hence the
/// 27 px floor, [`MIN_WINDOW`]); the pyramid depth follows the window so that the coarsest
/// level always sees a ~5 px kernel.
pub(super) fn adaptive_kernel_size(
    img: &Plane,
    saturation: Option<f32>,
    progress: &dyn Progress,
) -> CoreResult<usize> {
    let fixed = BlindParams::default().kernel_size_for(img.width, img.height)?;
    let Some(extent) = estimate_blur_extent(img, saturation, progress)? else {
        return Ok(fixed);
    };
    let max = (img.width.min(img.height) / 3) | 1;
    let ks = ((extent * WINDOW_FACTOR).round() as usize) | 1;
    Ok(ks.clamp(MIN_WINDOW.min(max), max.max(3)))
}

/// Window / estimated extent: estimates are within −33 %/+58 % of the truth on 80 % of the
/// TUNE cases, and an underestimate clips the kernel while an overestimate costs time and
/// accuracy (TUNE split at ratio ≤ 3: 1.2× 14 of 44, 1.4× 20, 1.7× 18; the fixed 31 px
/// window 17, a window of 1.3× the true kernel side 19).
const WINDOW_FACTOR: f64 = 1.4;

/// The smallest automatic window (px). The blur-extent estimate reads the scene's own scale on
/// repetitive texture (tiles, pebbles, grass, text: the first autocorrelation lobe is the
/// texture's, estimate/truth median 0.27 on the `texture` tuning split), and a window below the
/// kernel clips it, while a window larger than a small kernel now costs little (the 8-step
/// kernel solve leaves the unused entries near zero). Camera-shake harness, cases at ratio ≤ 3,
/// TUNE / TREMOR / TEXTURE (tuning splits, 44 / 44 / 36): 15 px 23 / 19 / 13, 21 px
/// 23 / 19 / 14, **27 px 23 / 19 / 16**, 31 px 23 / 17 / 15, 35 px 23 / 16 / 15. Held-out
/// EVAL, run once with 27 against the same code with 15: 22 → 27 of 48 (median 3.57 → 2.93,
/// mean PSNR 23.61 → 23.80 dB; its texture photos brick, grass, gravel 1 → 5 of 12), time per
/// 255² image unchanged (0.68 s median).
const MIN_WINDOW: usize = 27;

/// Normalised autocorrelation `R_d(s) / R_d(0)` of the derivative along each of [`DIRECTIONS`]
/// for lags `0..=max_lag`, over the pixel pairs that are both inside the image and, with a
/// `saturation` level, below it: the flat top of a clipped highlight and its cliff-like rim are
/// not blur, and a clipped light streak's rim otherwise gives the first lobe at the streak's
/// width (on the camera-shake harness with light sources, `BLIND_SAT=2`, the window fell to
/// the 15 px minimum on 7 of the 20 natural photos, kernels of 17–41 px; with clipped pixels
/// left out, on 2, a 17 px and a 37 px kernel).
#[doc(hidden)]
pub fn gradient_autocorrelation(
    img: &Plane,
    max_lag: usize,
    saturation: Option<f32>,
    progress: &dyn Progress,
) -> CoreResult<[Vec<f64>; 4]> {
    let (w, h) = (img.width as isize, img.height as isize);
    let level = saturation.unwrap_or(f32::INFINITY);
    let at = |x: isize, y: isize| {
        let v = img.data[(y * w + x) as usize];
        if v >= level { f64::NAN } else { f64::from(v) }
    };
    let mut out: [Vec<f64>; 4] = Default::default();
    for (slot, &(dx, dy)) in out.iter_mut().zip(&DIRECTIONS) {
        progress.check()?;
        // Derivative along (dx, dy), defined where both samples are inside; NaN elsewhere.
        let g: Vec<f64> = (0..h)
            .into_par_iter()
            .flat_map_iter(|y| {
                (0..w).map(move |x| {
                    let (nx, ny) = (x + dx, y + dy);
                    if nx < 0 || ny < 0 || nx >= w || ny >= h {
                        f64::NAN
                    } else {
                        at(nx, ny) - at(x, y)
                    }
                })
            })
            .collect();
        let r: Vec<f64> = (0..=max_lag as isize)
            .into_par_iter()
            .map(|s| {
                let (ox, oy) = (s * dx, s * dy);
                let (mut acc, mut n) = (0.0f64, 0usize);
                for y in 0.max(-oy)..h.min(h - oy) {
                    for x in 0.max(-ox)..w.min(w - ox) {
                        let a = g[(y * w + x) as usize];
                        let b = g[((y + oy) * w + x + ox) as usize];
                        if a.is_finite() && b.is_finite() {
                            acc += a * b;
                            n += 1;
                        }
                    }
                }
                if n > 0 { acc / n as f64 } else { 0.0 }
            })
            .collect();
        let r0 = r[0].max(f64::MIN_POSITIVE);
        *slot = r.into_iter().map(|v| v / r0).collect();
    }
    Ok(out)
}

/// Lags below this are left out of the search: the derivative of pixel noise (and of the
/// quantisation) is anti-correlated at lag 1, which says nothing about the blur.
const MIN_LAG: usize = 2;

/// Estimated blur extent (largest side of the kernel's bounding box, px) of `img`: over the four
/// directions, the largest lag of the first negative local minimum (below
/// [`LOBE_DEPTH`]) of the [1 2 1]-smoothed [`gradient_autocorrelation`].
///
/// The first lobe, not the deepest: image structure (chessboard squares, repeated texture)
/// gives negative lobes of its own at its period, often deeper than the kernel's; the
/// kernel's comes first unless the blur is longer than that period. On the camera-shake
/// harness (`examples/blind_eval.rs size`, TUNE split) the deepest lobe overestimates by 1.9×
/// in the median; the first lobe is within 20 % of the truth on 27 of 44 cases and within
/// 35 % on 32 (median estimate/truth 1.00, 10–90 % 0.67–1.58). Returns `None` when no
/// direction shows a lobe (no measurable blur).
/// Pixels at or above `saturation` are left out (see [`gradient_autocorrelation`]).
pub fn estimate_blur_extent(
    img: &Plane,
    saturation: Option<f32>,
    progress: &dyn Progress,
) -> CoreResult<Option<f64>> {
    let max_lag = (img.width.min(img.height) / 3).clamp(MIN_LAG + 1, MAX_LAG);
    let profiles = gradient_autocorrelation(img, max_lag, saturation, progress)?;
    Ok(extent_from_profiles(&profiles))
}

/// The longest lag searched (px): kernels beyond this are not estimated (the library's default
/// windows stay well below).
const MAX_LAG: usize = 80;

/// Depth (fraction of `R(0)`) a local minimum must reach to count as the kernel's lobe: small,
/// so as not to skip a weak first lobe for a deeper texture lobe further out (TUNE split: 0 and
/// 0.01 are equal within one case, 0.03 loses three).
const LOBE_DEPTH: f64 = 0.01;

/// See [`estimate_blur_extent`].
fn extent_from_profiles(profiles: &[Vec<f64>; 4]) -> Option<f64> {
    profiles
        .iter()
        .filter_map(|r| {
            let s: Vec<f64> = (0..r.len())
                .map(|i| {
                    if i == 0 || i + 1 == r.len() {
                        r[i]
                    } else {
                        (r[i - 1] + 2.0 * r[i] + r[i + 1]) / 4.0
                    }
                })
                .collect();
            (MIN_LAG..s.len().saturating_sub(1))
                .find(|&i| s[i] < -LOBE_DEPTH && s[i] <= s[i - 1] && s[i] <= s[i + 1])
                .map(|i| i as f64)
        })
        .max_by(f64::total_cmp)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::deconv::Psf;
    use crate::deconv::tests::{blur_reflect, scene};
    use crate::progress::NoProgress;

    #[test]
    fn extent_of_line_kernels() {
        let sharp = scene(200, 200);
        for (len, angle) in [(9.0, 0.0), (15.0, 30.0), (21.0, 90.0), (27.0, 135.0)] {
            let psf = Psf::motion(len, angle).expect("motion");
            let blurred = blur_reflect(&sharp, &psf);
            let est = estimate_blur_extent(&blurred, None, &NoProgress)
                .expect("estimate")
                .expect("some");
            let rad = f64::to_radians(angle);
            let truth = len * rad.cos().abs().max(rad.sin().abs());
            eprintln!("len {len} angle {angle}: truth {truth:.1} est {est}");
            assert!(
                (est - truth).abs() <= 0.25 * truth + 2.0,
                "len {len} angle {angle}: truth {truth:.1} est {est}"
            );
        }
    }
}
