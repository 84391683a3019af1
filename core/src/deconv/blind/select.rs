//! Choosing between kernel estimates without the truth.
//!
//! The cleaning threshold trades two failures (see [`super::DEFAULT_KERNEL_THRESHOLD`]): at
//! 10 % the faint strokes of long camera shake are cut and the kernel collapses onto its
//! bright dwell point; at 5 % the least squares' noise carpet survives, which ruins
//! chessboards and textures. Which one a photo needs is not known in advance, so both kernels
//! are estimated and the one whose restoration explains the photo better *and* is sharper
//! wins ([`selection_score`]).

use std::sync::Mutex;

use rayon::prelude::*;

use super::super::ops::SparseKernel;
use super::super::tv::tv_deconv;
use super::super::wiener::estimate_noise_sigma;
use super::super::{Plane, Psf};
use super::agreement::{AGREEMENT_SHIFT, kernel_agreement, uncertain_agreement};
use super::clipped::clipped_map;
use super::region::{Region, kernel_region};
use super::{BlindParams, DEFAULT_KERNEL_THRESHOLD};
use crate::error::CoreResult;
use crate::progress::Progress;

/// The region the kernel is estimated on is at least this many kernel windows wide (or the
/// whole photo). Measured with `blind_eval -- large` (TUNE's photos at 0.8–1.4 Mpx, one 3-D
/// shake kernel each of 15–43 px, whole-photo error ratio): a fixed 512 px region met
/// ratio ≤ 3 on 6 of 11 photos against 11 of 11 on the whole photo, all five misses with
/// kernels of 29–43 px (windows of 40–60 px: 8–13 windows wide); the whole photos that all
/// passed were 16–35 windows wide.
const REGION_PER_WINDOW: usize = 16;

/// The second cleaning threshold tried when [`BlindParams::kernel_threshold`] is not given.
pub const LOW_KERNEL_THRESHOLD: f64 = 0.05;

/// A blind kernel estimate with what [`estimate_kernel_restored`] learned on the way.
#[derive(Debug, Clone, PartialEq)]
pub struct KernelEstimate {
    /// The kernel.
    pub psf: Psf,
    /// The cleaning threshold it was estimated with (given, or chosen between
    /// [`DEFAULT_KERNEL_THRESHOLD`] and [`LOW_KERNEL_THRESHOLD`]).
    pub threshold: f64,
    /// The restoration `final_tv` made of the image with the kernel when choosing between
    /// thresholds needed one (`None` with a fixed threshold), so that a caller restoring the
    /// image itself need not solve it again.
    pub restored: Option<Plane>,
    /// [`kernel_agreement`] of the two candidate kernels when both were estimated (`None` with
    /// a fixed threshold); below [`KernelEstimate::uncertain_below`] the kernel is doubtful.
    pub agreement: Option<f64>,
    /// The agreement below which this photo's kernel counts as uncertain
    /// ([`super::uncertain_agreement`] of its measured noise; `None` with a fixed threshold).
    pub uncertain_below: Option<f64>,
    /// The region the kernel was estimated on (`None`: the whole photo); see
    /// [`BlindParams::kernel_region`].
    pub region: Option<Region>,
}

/// [`super::estimate_kernel`], with the threshold used and, when there was a choice, the
/// restoration that decided it. On a photo larger than [`BlindParams::kernel_region`] (or
/// [`REGION_PER_WINDOW`] kernel windows, if more) the kernel is estimated (and chosen) on that
/// region alone; the window is still estimated on the whole photo, whose blur it measures
/// from more data.
pub fn estimate_kernel_restored(
    img: &Plane,
    params: &BlindParams,
    progress: &dyn Progress,
) -> CoreResult<KernelEstimate> {
    params.validate()?;
    super::super::check_inputs(img, &Psf::identity())?;
    // The window is the same for both candidates: estimate it once, on the whole photo.
    let window = super::kernel_window(img, params, progress)?;
    // A long kernel needs more of the photo than a short one (`REGION_PER_WINDOW`).
    let side = params.kernel_region.max(REGION_PER_WINDOW * window);
    let region = if img.width <= side && img.height <= side {
        None
    } else {
        let clipped = params
            .final_tv
            .saturation
            .and_then(|level| clipped_map(img, level as f32));
        kernel_region(img, side, clipped.as_deref(), progress)?
    };
    let cropped = region.map(|r| r.crop(img)).transpose()?;
    let part = cropped.as_ref().unwrap_or(img);
    let params = &BlindParams {
        kernel_size: Some(window),
        ..params.clone()
    };
    if let Some(threshold) = params.kernel_threshold {
        return Ok(KernelEstimate {
            psf: super::estimate_kernel_traced(part, params, progress, None, None)?,
            threshold,
            restored: None,
            agreement: None,
            uncertain_below: None,
            region,
        });
    }
    let done = Mutex::new([0u64; 2]);
    // Each candidate: its kernel, its restoration of the part and the blind score of the pair.
    let candidate = |index: usize, threshold: f64| -> CoreResult<(f64, KernelEstimate)> {
        let fixed = BlindParams {
            kernel_threshold: Some(threshold),
            ..params.clone()
        };
        let part_progress = Share {
            inner: progress,
            index,
            done: &done,
        };
        let psf = super::estimate_kernel_traced(part, &fixed, &part_progress, None, None)?;
        let image = tv_deconv(part, &psf, &params.final_tv, &part_progress)?;
        progress.check()?;
        let score = selection_score(part, &image, &psf);
        // A restoration of the region alone is no use to the caller.
        let restored = region.is_none().then_some(image);
        Ok((
            score,
            KernelEstimate {
                psf,
                threshold,
                restored,
                agreement: None,
                uncertain_below: None,
                region,
            },
        ))
    };
    // The two estimates are independent; run side by side they keep both cores busy where
    // one alone leaves gaps (serial steps between its parallel FFT passes).
    let (default, low) = rayon::join(
        || candidate(0, DEFAULT_KERNEL_THRESHOLD),
        || candidate(1, LOW_KERNEL_THRESHOLD),
    );
    let (default, low) = (default?, low?);
    let agreement = Some(kernel_agreement(
        &default.1.psf,
        &low.1.psf,
        AGREEMENT_SHIFT,
    ));
    // Ties and non-finite scores keep the default candidate.
    let kept = if low.0 < default.0 { low.1 } else { default.1 };
    let uncertain_below = Some(uncertain_agreement(estimate_noise_sigma(part)));
    Ok(KernelEstimate {
        agreement,
        uncertain_below,
        ..kept
    })
}

/// Reports one of two concurrent candidate runs as its share of a single bar. Each run's place
/// is kept in thousandths of its whole run (the kernel estimate as the first
/// [`KERNEL_SHARE`], the restoration as the rest) and the bar shows the sum of both runs, so
/// it never runs backwards however the two interleave.
struct Share<'a> {
    inner: &'a dyn Progress,
    index: usize,
    /// Each run's place, in thousandths; under a lock so that reports reach `inner` in order.
    done: &'a Mutex<[u64; 2]>,
}

/// Share of one candidate's run reported for its kernel estimate (most of its time).
const KERNEL_SHARE: f64 = 0.8;

impl Progress for Share<'_> {
    fn report(&self, step: &str, done: u64, total: u64) {
        let f = done.min(total) as f64 / total.max(1) as f64;
        let place = if step == super::KERNEL_STEP {
            KERNEL_SHARE * f
        } else {
            KERNEL_SHARE + (1.0 - KERNEL_SHARE) * f
        };
        let mut done = self.done.lock().unwrap_or_else(|e| e.into_inner());
        done[self.index] = done[self.index].max((place * 1000.0) as u64);
        self.inner.report(step, done[0] + done[1], 2000);
    }

    fn is_canceled(&self) -> bool {
        self.inner.is_canceled()
    }
}

/// Pixels ignored at each border of the restoration when measuring its sharpness: the TV
/// solve's unknown-boundary margin is least constrained there.
const SHARPNESS_BORDER: usize = 15;

/// Blind score of restoration `x` with kernel `k` of photo `y`; lower is better.
///
/// The product of two terms, each blind to the truth:
/// * the mean squared re-blur residual `(k ⊛ x − y)²` over the pixels whose kernel footprint
///   lies inside the photo: a kernel that misses part of the path leaves its blur unexplained;
/// * the normalised sparsity `Σ|∇x| / ‖∇x‖₂` of the restoration, the scale-invariant sharpness
///   measure of D. Krishnan, T. Tay, R. Fergus, "Blind deconvolution using a normalized sparsity
///   measure", CVPR 2011: a kernel carrying a noise carpet leaves ghost edges, a denser
///   gradient field.
///
/// Measured on the tuning splits of `examples/blind_eval.rs` (cases at error ratio ≤ 3, the
/// better of the 10 % and 5 % kernels by this score against always 10 %): TUNE 23 → 23 of 44,
/// TREMOR 19 → 19, TEXTURE 16 → 17 of 36, Levin et al.'s set re-blurred at σ = 0.01 23 → 30
/// of 32 and captured 18 → 22; the mean log error ratio fell on all five. The residual alone
/// picks 5 % too rarely (Levin re-blurred 24 of 32), the sparsity alone too often (TUNE 17).
pub(super) fn selection_score(y: &Plane, x: &Plane, k: &Psf) -> f64 {
    let (w, h) = (y.width, y.height);
    let reblurred = {
        let taps = SparseKernel::new(k.width, k.height, |kx, ky| k.at(kx, ky));
        let mut out = vec![0.0f32; x.data.len()];
        taps.convolve_into(&x.data, w, false, &mut out);
        out
    };
    // The circular convolution is exact where the footprint stays inside.
    let m = k.width.max(k.height);
    let (rows, cols) = if h > 2 * m && w > 2 * m {
        (m..h - m, m..w - m)
    } else {
        (0..h, 0..w)
    };
    let (res, n) = rows
        .clone()
        .into_par_iter()
        .map(|py| {
            cols.clone().fold((0.0f64, 0usize), |(s, n), px| {
                let i = py * w + px;
                (s + f64::from(reblurred[i] - y.data[i]).powi(2), n + 1)
            })
        })
        .reduce(|| (0.0, 0), |a, b| (a.0 + b.0, a.1 + b.1));
    let b = if h > 2 * SHARPNESS_BORDER + 1 && w > 2 * SHARPNESS_BORDER + 1 {
        SHARPNESS_BORDER
    } else {
        0
    };
    let (l1, l2) = (b..h - b.max(1))
        .into_par_iter()
        .map(|py| {
            (b..w - b.max(1)).fold((0.0f64, 0.0f64), |(l1, l2), px| {
                let gx = f64::from(x.at(px + 1, py) - x.at(px, py));
                let gy = f64::from(x.at(px, py + 1) - x.at(px, py));
                (l1 + gx.abs() + gy.abs(), l2 + gx * gx + gy * gy)
            })
        })
        .reduce(|| (0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
    let residual = res / n.max(1) as f64;
    residual * l1 / l2.sqrt().max(1e-12)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::deconv::blind::{BlindParams, DEFAULT_KERNEL_THRESHOLD, LOW_KERNEL_THRESHOLD};
    use crate::deconv::tests::{add_noise, blur_reflect, scene};
    use crate::deconv::tv::{TvParams, tv_deconv};
    use crate::deconv::{blind_deconv, estimate_kernel};
    use crate::progress::NoProgress;

    /// Both factors act: a restoration that does not re-blur to the photo, or one with the
    /// same fit but denser gradients, scores worse; the photo's own scale does not matter.
    #[test]
    fn the_score_charges_misfit_and_dense_gradients() {
        let sharp = scene(96, 80);
        let k = Psf::motion(7.0, 30.0).expect("motion");
        let blurred = blur_reflect(&sharp, &k);
        let x = tv_deconv(&blurred, &k, &TvParams::default(), &NoProgress).expect("tv");
        let base = selection_score(&blurred, &x, &k);
        // The identity kernel: the blurred photo itself fits exactly but is not sparse.
        let flat = selection_score(&blurred, &blurred, &Psf::identity());
        assert!(base.is_finite() && base > 0.0, "{base}");
        assert!(flat < 1e-12, "an exact fit scores zero: {flat:e}");
        // Noise on the restoration: worse fit and denser gradients.
        let noisy = add_noise(&x, 0.02, 3);
        assert!(selection_score(&blurred, &noisy, &k) > 2.0 * base);
    }

    /// The two candidates run side by side and report into one bar: it never runs backwards
    /// and ends full.
    #[test]
    fn both_candidates_share_one_monotone_bar() {
        struct Record(Mutex<Vec<(u64, u64)>>);
        impl Progress for Record {
            fn report(&self, _step: &str, done: u64, total: u64) {
                self.0.lock().expect("lock").push((done, total));
            }
            fn is_canceled(&self) -> bool {
                false
            }
        }
        let sharp = scene(96, 80);
        let truth = Psf::motion(7.0, 30.0).expect("motion");
        let blurred = add_noise(&blur_reflect(&sharp, &truth), 0.01, 9);
        let params = BlindParams {
            kernel_size: Some(11),
            ..BlindParams::default()
        };
        let record = Record(Mutex::new(Vec::new()));
        estimate_kernel_restored(&blurred, &params, &record).expect("estimate");
        let seen = record.0.into_inner().expect("lock");
        assert!(seen.len() > 4, "{seen:?}");
        assert!(seen.iter().all(|&(_, total)| total == 2000), "{seen:?}");
        assert!(seen.windows(2).all(|w| w[0].0 <= w[1].0), "{seen:?}");
        assert_eq!(seen.last().map(|s| s.0), Some(2000));
    }

    /// Without a fixed threshold the estimate is the better-scoring of the two fixed ones, and
    /// `blind_deconv` returns the restoration it scored.
    #[test]
    fn the_default_keeps_the_better_scoring_kernel() {
        let sharp = scene(128, 112);
        let truth = Psf::motion(9.0, 30.0).expect("motion");
        let blurred = add_noise(&blur_reflect(&sharp, &truth), 0.01, 5);
        let at = |t: Option<f64>| BlindParams {
            kernel_size: Some(15),
            kernel_threshold: t,
            ..BlindParams::default()
        };
        let scored = |t: f64| {
            let out = blind_deconv(&blurred, &at(Some(t)), &NoProgress).expect("blind");
            (selection_score(&blurred, &out.image, &out.psf), out)
        };
        let (s_hi, hi) = scored(DEFAULT_KERNEL_THRESHOLD);
        let (s_lo, lo) = scored(LOW_KERNEL_THRESHOLD);
        let want_a = kernel_agreement(&hi.psf, &lo.psf, AGREEMENT_SHIFT);
        let want = if s_lo < s_hi { lo } else { hi };
        // Parallel sums may round differently from run to run: compare within a tolerance.
        let close = |a: &[f64], b: &[f64]| a.iter().zip(b).all(|(a, b)| (a - b).abs() < 1e-6);
        let auto = blind_deconv(&blurred, &at(None), &NoProgress).expect("auto");
        assert!(close(&auto.psf.data, &want.psf.data));
        assert!(
            auto.image
                .data
                .iter()
                .zip(&want.image.data)
                .all(|(a, b)| (a - b).abs() < 1e-4)
        );
        let kernel = estimate_kernel(&blurred, &at(None), &NoProgress).expect("kernel");
        assert!(close(&kernel.data, &want.psf.data));
        let chosen = estimate_kernel_restored(&blurred, &at(None), &NoProgress).expect("estimate");
        let want_t = if s_lo < s_hi {
            LOW_KERNEL_THRESHOLD
        } else {
            DEFAULT_KERNEL_THRESHOLD
        };
        assert_eq!(chosen.threshold, want_t);
        // The agreement compares the two candidates, whichever was kept; a clean streak on a
        // textured scene pins the kernel down, so they agree.
        let agreement = chosen.agreement.expect("two candidates");
        assert!((agreement - want_a).abs() < 1e-6, "{agreement} vs {want_a}");
        // The threshold follows the photo's measured noise, within its measured range.
        let below = chosen.uncertain_below.expect("a threshold");
        let want_below = uncertain_agreement(estimate_noise_sigma(&blurred));
        assert!(
            (below - want_below).abs() < 1e-12,
            "{below} vs {want_below}"
        );
        assert!((0.45..=super::super::UNCERTAIN_AGREEMENT).contains(&below));
        assert!(agreement >= below, "{agreement} < {below}");
        let fixed = estimate_kernel_restored(&blurred, &at(Some(0.2)), &NoProgress).expect("fixed");
        assert_eq!(fixed.threshold, 0.2);
        assert!(
            fixed.restored.is_none()
                && fixed.agreement.is_none()
                && fixed.uncertain_below.is_none()
        );
    }
}
