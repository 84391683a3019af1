//! Blind deconvolution: coarse-to-fine kernel estimation with an L0 gradient prior.
//!
//! One file over 600 lines because about 120 of them are this record of what was tried and
//! measured against the estimator below; the code itself (parameters, pyramid, one level)
//! is one path that reads top to bottom, and its parts with a job of their own already live
//! in the submodules.
//!
//! Tried and not kept (camera-shake harness `examples/blind_eval.rs`, TUNE split; baseline
//! 21 of 44 cases at error ratio ≤ 3, median 3.79; its chessboard photos, `--only left`, 4 of
//! 24, median 23.5; every change alone on top of the code below):
//! * the dark-channel term of J. Pan, D. Sun, H. Pfister, M.-H. Yang, "Blind image deblurring
//!   using dark channel prior", CVPR 2016, in the latent step (35 px patches, λ 0.004, its
//!   weight raised with β in the same splitting loop): chessboards 2 of 24, and skimage cases
//!   that passed went above 3 (camera 13 px: 2.1 → 3.9); at twice the time;
//! * the usefulness map of L. Xu, J. Jia, "Two-phase kernel estimation for robust motion
//!   deblurring", ECCV 2010 (`r = |Σ∇y| / (Σ|∇y| + 0.5)` over a window of about the kernel
//!   side, latent gradients kept where r ≥ 0.2): much worse (0 of the first 15 chessboard
//!   cases, several ratios above 50): it removes the board's corners, the only place where the
//!   board constrains the kernel in 2-D;
//! * Pan et al.'s salient-edge count (20 × kernel side pixels per direction bin instead of
//!   [`salient_threshold`]'s `2·√N·ks`): 19 of 44; 10 alternations at the coarse levels: 18 of
//!   the first 30 against 20; the off-support damping of [`entry_damping`] at every level:
//!   chessboards 2 of 24; coarse cleaning threshold 0.2: 3 of 24; coarse γ × 0.2: 3 of 24; the
//!   kernel's conjugate gradients started from a flat kernel (as Pan et al.'s code): 4 of 24
//!   (median 19.9); λ carried on from level to level (as their code): 0 of 24;
//! * a pyramid ratio of 0.8 instead of √½: 21 of 44 again (chessboards 6 of 24, median 12.0,
//!   the other photos 15 of 20 against 17; at ratio ≤ 2, 11 against 14), for ~40 % more time;
//! * the window from the true kernel side (`BLIND_ORACLE=1.3`): chessboards 5 of 24 (median 11.6);
//!   on the natural photos the oracle window leaves the same large-kernel failures (4 of 20
//!   against 3), so size estimation is not what limits them;
//! * a Gaussian pre-filter of both sides of the kernel step's data term (`∇y` and the latent
//!   gradients, so the kernel relation is unchanged; the noise handling of L. Zhong, S. Cho,
//!   D. Metaxas, S. Paris, J. Wang, "Handling noise in single image deblurring using
//!   directional filters", CVPR 2013, made isotropic): σ 1 px at the finest level 19 of 44,
//!   0.7 px 21 (median 3.33), with γ × 0.1 22 but twice the time, 0.7 px at every level 21;
//! * a coarsest level of at least 48 px image side instead of a ~5 px kernel (the trace shows a
//!   blob at a 26 px coarsest level on failing 39 px kernels): 19 of 44, 64 px 13;
//! * dropping kernel pieces below 25 % or 50 % of the mass instead of 10 % (against the ghost
//!   streaks): 20 of 44;
//! * extra full-resolution kernel steps against a TV restoration (40 ADMM iterations) instead
//!   of the L0 cartoon, salient edges kept: one step 17 of 44, three 9 (with γ × 5 instead of
//!   × 30, 11) — the softer latent lets the kernel grow by the image's own edge profile, the
//!   bias Levin et al. 2009 describe;
//! * the cleaning threshold relative to the mean of the `ks/2` (or `ks`) largest entries
//!   instead of the maximum, so that a faint loop next to a bright dwell point survives:
//!   15 (12) of 44 — the noise carpet survives with it;
//! * 10 or 20 alternations at the full-resolution level only (the trace shows the support
//!   still thinning there on the failing large kernels): 21 and 16 of 44, at 1.6× and 3× the
//!   time;
//! * the coarsest kernel started as a line along the direction with the longest
//!   autocorrelation lobe ([`estimate_blur_extent`]'s per-direction lag) instead of a 2 px
//!   segment: 22 of 44 (chessboards 5 of 24, natural photos 17 of 20 as before), within one
//!   case of the baseline at 1.6× the time, so not kept;
//! * salient edges chosen per tile (3×3 or 4×4 tiles, each keeping its share of the edge
//!   count, not below 0–50 % of the global threshold) so that a photo's edges outside a
//!   chessboard take part in the kernel step: 3×3 20–21 of 44 (median 3.57), 4×4 19; the
//!   chessboards stay at 3–4 of 24;
//! * no salient-edge selection at all (the kernel step fed the whole L0 latent's gradients;
//!   the L0 prior already keeps only strong edges): 20 of 44 as the baseline of the same run
//!   (natural photos 17 of 20, chessboards 3 of 24 as before), ≤ 2 on 12 against 14, median
//!   3.57 against 3.79, worst 60.6 against 39.3, mean PSNR 21.48 against 21.60 dB;
//! * the kernel step's data term weighted towards corners and junctions, `1 + α(1 − c)` with
//!   `c` the coherence of the blurred gradients' structure tensor over a kernel-sized box (the
//!   board's corners are the only places where it sees the kernel in 2-D, the opposite of
//!   the usefulness map above): α = 1 18 of 44, α = 3 17 (chessboards 1 of 24);
//! * a smoothness term `η·γ·‖∇k‖²` beside `γ‖k‖²` in the kernel step (against the scattered
//!   ghost segments): η = 1 20 of 44 (median 3.58), η = 5 21 (chessboards 6 of 24 against 3,
//!   but the natural photos 15 of 20 against 17 and ≤ 2 on 9 against 14, mean PSNR 21.82
//!   against 21.60 dB), η = 20 11 (the path thickens), η = 5 at the coarse levels only 18;
//! * hysteresis cleaning (entries down to 3 % of the peak kept when 8-connected to one above
//!   the 10 % threshold, so that the faint strokes between a tremor kernel's dwell points
//!   survive; `blind_eval -- tremor`, baseline 15 of 44): 6 of 44 at every level, 12 at the
//!   finest only — the noise carpet next to the path survives with the strokes;
//! * a polish after the finest level (one or three more kernel steps restricted to the
//!   current support dilated by a pixel, 3 % cleaning): from the truth (below) TREMOR 28 → 32 of
//!   44, from the usual start no change (TUNE 20, TREMOR 15 of 44);
//! * the smoothness term above only on two-direction images: `η = 5·clamp((s − 0.45)/0.15)`,
//!   `s` the share of the gradient energy within ±10° of the two strongest orientations (boards
//!   0.43–0.85, photos 0.33–0.57): TUNE 20 → 21 and TREMOR 15 → 20 of 44 (boards 3 → 5 and
//!   1 → 6), mean PSNR +0.5 and +0.8 dB; but on EVAL, run once against the same binary without
//!   it, 22 → 21 of 48 (median 3.54 → 3.27, worst 24 → 34, 23.39 → 23.40 dB): no held-out gain;
//! * Levin et al. 2011's variational latent (posterior mean, variance charged to `‖k‖²`) in
//!   place of the L0 cartoon: blobs, 0–2 of TUNE's 4 `camera` cases against 4; a non-negative
//!   kernel solve (projected Barzilai–Borwein) at the coarse levels: TUNE 23 and TREMOR 19 →
//!   20 of 44, but EVAL 22 → 20 of 48 (`core/benches/deconv_set.md` has both);
//! * on Levin et al.'s real set (`blind_eval -- levin`, 18 of 32): 5 % cleaning thresholds
//!   (`levin-synth` 23 → 29 of 32 but TUNE 23 → 12), a weak-prior polish step, Pan et al.
//!   2016's dark channel with its nested splitting, deferred or final-only lower cleaning —
//!   numbers in `core/benches/deconv_set.md`. Kept instead: both thresholds, and a blind
//!   choice between their kernels (`select.rs`).
//! * as that choice's score, the re-blur residual alone (Levin σ = 0.01: 24 of 32 against
//!   30 with the product), the restoration's normalised sparsity alone (TUNE 17 of 44 against
//!   23), the share of strong gradients, its product with the residual, or the residual times
//!   the restoration's TV: each behind the product on at least one split
//!   (`blind_eval -- thresholds <split>` prints every criterion per case); other pairs of
//!   thresholds (10 % and 3 %: +1 on TREMOR only; 20 % and 5 %: worse everywhere).
//!
//! **The estimator is biased, not lost.** Started from the true kernel
//! ([`estimate_kernel_from`], `BLIND_FIXED=pyramid|finest` in the harness, window 1.3 × the
//! truth), the whole pyramid ends at 23 of 44 TUNE cases at ratio ≤ 3 (chessboards 6 of 24,
//! natural photos 17 of 20) and 16 of 44 TREMOR (4 of 24, 12 of 20) — about where it ends from
//! a 2 px segment (20 and 15) — and the full-resolution level alone, from the truth, keeps 33
//! and 28 of 44 (all with the 20-step kernel solve of then; with the 8 steps of
//! `kernel_step` now: from the truth 24 and 19, the finest level alone 35 and 31, from scratch
//! 23 and 19). Merely cleaning the truth at 10 % keeps 44 and 43 of 44. On the boards even
//! the true sharp image as the latent leaves one kernel step at a geometric-mean ratio of 1.9
//! (TREMOR), the L0 latent 2.3: with edges in two directions the kernel is fixed only at the
//! board's lattice frequencies, the least squares is ill-conditioned, and the ratio there is
//! unforgiving (the true-kernel TV restoration of a board is nearly exact). So better starts,
//! schedules or candidate selection cannot reach the target; the alternation's fixed point has
//! to move, e.g. a latent estimate that is not a MAP cartoon (the marginal likelihood of
//! A. Levin, Y. Weiss, F. Durand, W. T. Freeman, "Efficient marginal likelihood optimization in
//! blind deconvolution", CVPR 2011) or a kernel prior stronger than `γ‖k‖²` on the
//! ill-conditioned directions.
//!
//! On the chessboards the window estimate reads the square period, not the blur: 37–55 px
//! windows for 19–27 px kernels on most boards (the oracle window, above, did not help either).
//!
//! Most TUNE failures are on chessboards. There the failure is structural: the board is
//! invariant under translation by its lattice vectors, so a part of the kernel moved by one
//! explains the board as well (the parallel ghost streaks that `-v` prints); only the photo
//! outside the board tells them apart, and the alternation settles on a speckled mixture.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

mod agreement;
mod clipped;
mod diagnose;
mod kernel;
mod latent;
mod region;
mod select;
mod size;

use super::fft::Fft2;
use super::ops::grad;
use super::psf::MAX_PSF_SIZE;
use super::resample::resize;
use super::tv::{TvParams, tv_deconv};
use super::wiener::gradient_power;
use super::{PadLayout, Plane, Psf};
use crate::error::{CoreError, CoreResult};
use crate::progress::Progress;
pub use agreement::{AGREEMENT_SHIFT, UNCERTAIN_AGREEMENT, kernel_agreement, uncertain_agreement};
use clipped::clipped_map;
pub use diagnose::{KernelStart, estimate_kernel_from};
use kernel::{clean_kernel, kernel_step, recentre};
use latent::{l0_restore, salient_threshold};
pub use region::Region;
pub use select::{KernelEstimate, LOW_KERNEL_THRESHOLD, estimate_kernel_restored};
use size::adaptive_kernel_size;
pub use size::{estimate_blur_extent, gradient_autocorrelation};

/// Parameters of [`blind_deconv`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct BlindParams {
    /// Kernel side in px (odd, 3–[`MAX_PSF_SIZE`]); should exceed the blur extent.
    /// Default (`null`): 1.4 × the blur extent estimated by [`estimate_blur_extent`], at least
    /// 27 and at most a third of the shorter image side; 31 (or that third) when no blur is
    /// measurable. [`BlindParams::kernel_size_for`] gives the fixed fallback.
    pub kernel_size: Option<usize>,
    /// Alternations of latent image and kernel per pyramid level (default 5, as Pan et al.).
    pub iterations_per_level: usize,
    /// Starting weight of the L0 gradient prior (default 0.004; divided by 1.1 per alternation
    /// down to 10⁻⁴, as Pan et al.).
    pub lambda_grad: f64,
    /// Weight of `‖k‖²` in the kernel step (default 2, on un-normalised gradient sums).
    pub kernel_reg: f64,
    /// Kernel entries below this fraction of the kernel's maximum are dropped after every
    /// kernel step, at every level (0.01–0.5). Lower keeps the faint strokes of a long
    /// camera-shake path, and also more of the least squares' noise; see
    /// [`DEFAULT_KERNEL_THRESHOLD`] for what each setting measured. Default (`null`): kernels
    /// at [`DEFAULT_KERNEL_THRESHOLD`] and [`LOW_KERNEL_THRESHOLD`] are both estimated and the
    /// one whose restoration scores better blindly is kept (`select::selection_score`).
    pub kernel_threshold: Option<f64>,
    /// Side (px) of the square region the kernel is estimated on when the photo is wider or
    /// taller ([`DEFAULT_KERNEL_REGION`]; 128–16384; raised to 16 kernel windows when that
    /// is more): the part with the most strong gradients in every direction, off clipped
    /// pixels (`region.rs`). The whole photo is then restored with that kernel. A value at
    /// least the photo's longer side uses the whole photo.
    pub kernel_region: usize,
    /// Final non-blind TV solve. Its `saturation` level also marks the clipped pixels that the
    /// kernel estimate and the blur-extent estimate leave out.
    pub final_tv: TvParams,
}

impl Default for BlindParams {
    fn default() -> Self {
        Self {
            kernel_size: None,
            iterations_per_level: 5,
            lambda_grad: 4e-3,
            kernel_reg: 2.0,
            kernel_threshold: None,
            kernel_region: DEFAULT_KERNEL_REGION,
            final_tv: TvParams::default(),
        }
    }
}

impl BlindParams {
    /// Check ranges; errors name the offending field.
    pub fn validate(&self) -> CoreResult<()> {
        if let Some(k) = self.kernel_size
            && (!(3..=MAX_PSF_SIZE).contains(&k) || k.is_multiple_of(2))
        {
            return Err(CoreError::param(
                "kernel_size",
                format!("must be odd, between 3 and {MAX_PSF_SIZE}"),
            ));
        }
        if !(1..=50).contains(&self.iterations_per_level) {
            return Err(CoreError::param(
                "iterations_per_level",
                "must be between 1 and 50",
            ));
        }
        if !(self.lambda_grad.is_finite() && self.lambda_grad > 0.0 && self.lambda_grad < 1.0) {
            return Err(CoreError::param("lambda_grad", "must be within (0, 1)"));
        }
        if !(self.kernel_reg.is_finite() && self.kernel_reg > 0.0) {
            return Err(CoreError::param("kernel_reg", "must be finite and > 0"));
        }
        if let Some(t) = self.kernel_threshold
            && !(t.is_finite() && (0.01..=0.5).contains(&t))
        {
            return Err(CoreError::param(
                "kernel_threshold",
                "must be between 0.01 and 0.5",
            ));
        }
        if !(MIN_KERNEL_REGION..=MAX_KERNEL_REGION).contains(&self.kernel_region) {
            return Err(CoreError::param(
                "kernel_region",
                format!("must be between {MIN_KERNEL_REGION} and {MAX_KERNEL_REGION}"),
            ));
        }
        self.final_tv.validate()
    }

    /// The kernel side used for an image of `width × height`.
    pub fn kernel_size_for(&self, width: usize, height: usize) -> CoreResult<usize> {
        let ks = match self.kernel_size {
            Some(k) => k,
            None => (31usize).min((width.min(height) / 3) | 1).max(3),
        };
        if 2 * ks > width.min(height) {
            return Err(CoreError::param(
                "kernel_size",
                format!("{ks} px kernel is too large for a {width}×{height} image"),
            ));
        }
        Ok(ks)
    }
}

/// Result of [`blind_deconv`].
#[derive(Debug, Clone, PartialEq)]
pub struct BlindOutput {
    /// The deblurred image.
    pub image: Plane,
    /// The estimated kernel.
    pub psf: Psf,
}

/// Blind deconvolution: [`estimate_kernel`] then [`tv_deconv`] with that kernel.
pub fn blind_deconv(
    img: &Plane,
    params: &BlindParams,
    progress: &dyn Progress,
) -> CoreResult<BlindOutput> {
    let estimate = estimate_kernel_restored(img, params, progress)?;
    let psf = estimate.psf;
    let image = match estimate.restored {
        Some(image) => image,
        None => tv_deconv(img, &psf, &params.final_tv, progress)?,
    };
    Ok(BlindOutput { image, psf })
}

/// Default of [`BlindParams::kernel_region`] (px): photos up to 2048 px both ways are
/// estimated whole, as every accuracy figure here was measured; beyond, the kernel
/// estimate's time and memory stop growing with the photo (a 4 Mpx region, four times the
/// whole photos of `blind_eval -- large`, which all passed). A smaller region is faster and
/// measurably less accurate (`select::REGION_PER_WINDOW`).
pub const DEFAULT_KERNEL_REGION: usize = 2048;

/// Bounds of [`BlindParams::kernel_region`]: below 128 px a long kernel's window no longer
/// fits twice; above, the largest image side any job accepts.
const MIN_KERNEL_REGION: usize = 128;
const MAX_KERNEL_REGION: usize = 16384;

/// Progress step name of the kernel estimate's alternations.
const KERNEL_STEP: &str = "blind_kernel";

/// Pyramid step between levels (Pan et al. use √½).
const LEVEL_RATIO: f64 = std::f64::consts::FRAC_1_SQRT_2;

/// Estimates the blur kernel of `img` (values in `[0, 1]`, typically luma) following
/// J. Pan, Z. Hu, Z. Su, M.-H. Yang, "Deblurring text images via L0-regularized intensity and
/// gradient prior", CVPR 2014 / "L0-regularized intensity and gradient prior for deblurring text
/// images and beyond", IEEE TPAMI 39(2), 2017, with the gradient term only (natural images):
///
/// * the kernel window from [`estimate_blur_extent`] unless `kernel_size` is given;
/// * a pyramid with ratio √½ from a ~5 px kernel, the kernel upsampled from level to level,
///   starting from a 2-px segment;
/// * per level, alternately: the latent image `x = argmin ‖k ⊛ x − y‖² + λ‖∇x‖₀` by half-quadratic
///   splitting (β from 2λ to 10⁵, doubling: a hard threshold of `∇x` at `√(λ/β)` and a Fourier
///   division), which keeps only the strong edges that carry the blur information; the salient
///   latent gradients ([`salient_threshold`], Cho & Lee 2009); and the kernel
///   `k = argmin ‖M(∇x ⊛ k − ∇y)‖² + γ‖k‖²` on the kernel's support by 20 conjugate-gradient
///   steps, `M` keeping the photo's own pixels; then entries below 10 % of the maximum are
///   dropped ([`BlindParams::kernel_threshold`]), so are 8-connected pieces holding less than 10 % of
///   the mass, and the rest is normalised; λ ← max(λ/1.1, 10⁻⁴);
/// * clipped pixels (at or above `final_tv.saturation`) and their neighbours are left out of
///   the kernel step ([`clipped_map`]) and of the window estimate;
/// * the kernel is re-centred on its centroid after every level, so that it stays inside its
///   window and the deblurred image is not shifted;
/// * the full-resolution level is estimated with a weaker image prior ([`FINEST_LAMBDA_FACTOR`]
///   × λ) and a stronger kernel regulariser ([`FINEST_REG_FACTOR`] × γ). At
///   σ = 0.01 the finest level with the coarse settings fits noise into the kernel (a speckle
///   carpet that the connected-component test cannot remove because it is all connected; error
///   ratios of 10–100 on the benchmark set). Skipping the level instead (the kernel of the √½
///   level upsampled by √2) avoids that but leaves every kernel about a pixel too thick, which
///   alone puts many error ratios near 3; with the stronger settings the finest level thins the
///   path (benchmark median 2.7 → 2.0, failures 11/32 → 0/32; on four images outside the set,
///   `rocket`, `clock`, `coins`, `brick` with the same kernels and noise, 10/32 → 14/32, 13/32
///   after the FFT column pass changed rounding: the brick texture, the smooth clock face and
///   the rocket's sky still defeat the edge-based latent — there the estimate grows into a blob).
///
/// Unless [`BlindParams::kernel_threshold`] fixes the cleaning threshold, the whole estimate
/// runs twice, at [`DEFAULT_KERNEL_THRESHOLD`] and [`LOW_KERNEL_THRESHOLD`], and the kernel
/// whose TV restoration scores better blindly (re-blur residual × normalised sparsity,
/// `select.rs`) is returned ([`estimate_kernel_restored`] also returns that restoration).
///
/// Each level works on the image mirrored and tapered into a periodic FFT domain (the role of
/// Liu & Jia's boundary wrapping in the authors' code). Levin et al., "Understanding and
/// evaluating blind deconvolution algorithms", CVPR 2009, explain why this works where MAP on the
/// image alone does not: the sparse-edge latent image makes the kernel, not the no-blur
/// solution, the better explanation.
pub fn estimate_kernel(
    img: &Plane,
    params: &BlindParams,
    progress: &dyn Progress,
) -> CoreResult<Psf> {
    estimate_kernel_restored(img, params, progress).map(|e| e.psf)
}

/// [`estimate_kernel`], also returning the kernel of every level resampled to full scale (for
/// the evaluation harness's diagnostics).
#[doc(hidden)]
pub fn estimate_kernel_trace(
    img: &Plane,
    params: &BlindParams,
    progress: &dyn Progress,
) -> CoreResult<(Psf, Vec<Psf>)> {
    let mut trace = Vec::new();
    let k = estimate_kernel_traced(img, params, progress, Some(&mut trace), None)?;
    Ok((k, trace))
}

fn estimate_kernel_traced(
    img: &Plane,
    params: &BlindParams,
    progress: &dyn Progress,
    mut trace: Option<&mut Vec<Psf>>,
    start: Option<&Psf>,
) -> CoreResult<Psf> {
    params.validate()?;
    super::check_inputs(img, &Psf::identity())?;
    let ks = kernel_window(img, params, progress)?;
    let levels = ((5.0 / ks as f64).ln() / LEVEL_RATIO.ln()).floor().max(0.0) as usize + 1;
    let sizes: Vec<usize> = (0..levels)
        .rev()
        .map(|i| ((ks as f64 * LEVEL_RATIO.powi(i as i32)).ceil() as usize) | 1)
        .map(|k| k.clamp(3, ks))
        .collect();
    let clipped = params
        .final_tv
        .saturation
        .and_then(|level| clipped_map(img, level as f32));
    let mut k_size = sizes[0];
    let mut kernel = vec![0.0f64; k_size * k_size];
    let c = k_size / 2;
    kernel[c * k_size + c] = 0.5;
    kernel[c * k_size + c + 1] = 0.5;
    if let Some(s) = start {
        kernel = resize(&s.data, s.width, s.height, k_size, k_size);
        clean_kernel(&mut kernel, k_size, 0.0);
    }
    let total = levels * params.iterations_per_level;
    for (li, &size) in sizes.iter().enumerate() {
        if size != k_size {
            kernel = resize(&kernel, k_size, k_size, size, size);
            clean_kernel(&mut kernel, size, 0.0);
            k_size = size;
        }
        let finest = li + 1 == levels;
        let f = if finest {
            1.0
        } else {
            LEVEL_RATIO.powi((levels - 1 - li) as i32)
        };
        let (level_img, coarse_clipped) = if finest {
            (img.clone(), None)
        } else {
            let nw = ((img.width as f64 * f).round() as usize).max(2 * size + 1);
            let nh = ((img.height as f64 * f).round() as usize).max(2 * size + 1);
            let data: Vec<f64> = img.data.iter().map(|&v| f64::from(v)).collect();
            let r = resize(&data, img.width, img.height, nw, nh);
            // A coarse pixel is clipped when any full-resolution pixel behind it is.
            let c = clipped.as_ref().map(|c| {
                resize(c, img.width, img.height, nw, nh)
                    .into_iter()
                    .map(|v| if v > 1e-3 { 1.0 } else { 0.0 })
                    .collect::<Vec<f64>>()
            });
            (
                Plane::new(nw, nh, r.into_iter().map(|v| v as f32).collect())?,
                c,
            )
        };
        kernel = estimate_level(
            (
                &level_img,
                if finest {
                    clipped.as_deref()
                } else {
                    coarse_clipped.as_deref()
                },
            ),
            kernel,
            size,
            params,
            progress,
            (li * params.iterations_per_level, total),
            finest,
        )?;
        recentre(&mut kernel, size);
        if let Some(t) = trace.as_deref_mut() {
            let mut up = resize(&kernel, size, size, ks, ks);
            clean_kernel(&mut up, ks, 0.0);
            t.push(Psf::from_weights(ks, ks, up)?);
        }
    }
    Psf::from_weights(k_size, k_size, kernel)
}

/// The kernel window of `img`: [`BlindParams::kernel_size`] when given, else
/// [`adaptive_kernel_size`].
fn kernel_window(img: &Plane, params: &BlindParams, progress: &dyn Progress) -> CoreResult<usize> {
    match params.kernel_size {
        Some(_) => params.kernel_size_for(img.width, img.height),
        None => adaptive_kernel_size(img, params.final_tv.saturation.map(|v| v as f32), progress),
    }
}

/// Default of [`BlindParams::kernel_threshold`]: entries of the kernel below this fraction of its
/// maximum are dropped after every kernel step. Pan et al.'s code uses 5 % only on the final
/// kernel; at the coarse levels 10 % keeps the low halo of the least squares from growing into
/// the next level's start (benchmark: 31 → 32 of 32 cases at ratio ≤ 3 with the finest-level
/// settings below; 15 % loses two). At full resolution, where the least squares fits the most
/// noise, a camera-shake path placed by the coarse levels stays well above 20 % of the peak
/// along its length and the noise carpet around it does not (benchmark: 15 % leaves 31 of 32
/// cases, 20 % 32, 25 % 28); with the support-aware damping of [`entry_damping`] the carpet is
/// held down by the damping instead, and 10 % keeps more of the path.
///
/// 5 % everywhere keeps the faint strokes between the dwell points of long real camera shake
/// and the noise carpet with them (cases at error ratio ≤ 3, `examples/blind_eval.rs`): Levin
/// et al.'s set re-blurred at σ = 0.01 (`levin-synth`) 23 → 29 of 32 and the captures 18 → 21,
/// EVAL (held out) 27 → 26 of 48, but TUNE 23 → 12 (chessboards collapse) and TREMOR 19 → 18.
/// Hence 10 % as the default, and the parameter for users whose kernels are long and faint.
pub const DEFAULT_KERNEL_THRESHOLD: f64 = 0.1;

/// Factor on `kernel_reg` at full resolution: there the noise is not averaged down by the
/// pyramid (each √½ step halves its variance), so the kernel step needs more damping for the
/// same trust in its data (benchmark: 1× leaves 24 of 32 cases at ratio ≤ 3 with a 15 %
/// threshold and 5 % at the coarse levels, 4× 25, 10× 29; with the final thresholds 10× 32
/// and 20× 31). Re-measured on the camera-shake harness (`examples/blind_eval.rs`, TUNE split)
/// together with [`FINEST_LAMBDA_FACTOR`]: 10× 16 of 44 at ratio ≤ 3 (median 5.5), 30× 17 of 44
/// (median 5.2); EVAL 14 of 48 against 13 before either change.
const FINEST_REG_FACTOR: f64 = 30.0;

/// Factor on `lambda_grad` at full resolution. The L0 latent is a cartoon of step edges; the
/// kernel step then has to explain the photo's own soft edges (optics, resampling) and grows the
/// kernel by that edge profile while the strong finest-level cleaning shortens it — the
/// diagnostic trace (`BLIND_TRACE=1` in `examples/blind_eval.rs`) showed the support shrinking
/// from ~130 to ~50 entries at the last level on failing cases. A weaker prior there keeps ramps
/// in the latent (Levin et al. 2009: the sharper-than-true latent is what biases MAP kernels).
/// Camera-shake harness, TUNE split: 1 → median 5.9, 0.25 → 5.5 (with 10× γ), 0.1 → 6.5.
const FINEST_LAMBDA_FACTOR: f64 = 0.25;

/// Per-entry damping of the kernel step. At the finest level, in the spirit of the iterative
/// support detection of L. Xu, J. Jia, "Two-phase kernel estimation for robust motion
/// deblurring", ECCV 2010: the support of the current kernel (dilated by one pixel) keeps the
/// full-resolution damping `gamma`, entries off it get [`OFF_SUPPORT_FACTOR`] × `gamma`. That
/// suppresses the noise carpet around the path, so the hard cleaning threshold can be halved
/// ([`DEFAULT_KERNEL_THRESHOLD`]) and the faint parts of the path survive instead of the kernel
/// collapsing at full resolution. Camera-shake harness, TUNE split, at ratio ≤ 3 (≤ 2, median):
/// before 20 (12, 4.55) of 44; threshold 0.1 alone 18 (13, 3.87); with 5× off the support
/// 21 (14, 3.79), 10× 21 (14, 3.73); 10× with threshold 0.05, 16. A weaker damping *on* the
/// support instead (γ/15 or γ·0.4 there) lost 6 and 2 cases: the path thickens.
fn entry_damping(kernel: &[f64], ks: usize, gamma: f64, finest: bool) -> Vec<f64> {
    if !finest {
        return vec![gamma; kernel.len()];
    }
    let mut out = vec![gamma * OFF_SUPPORT_FACTOR; kernel.len()];
    for (i, _) in kernel.iter().enumerate().filter(|(_, v)| **v > 0.0) {
        let (x, y) = (i % ks, i / ks);
        for ny in y.saturating_sub(1)..(y + 2).min(ks) {
            for nx in x.saturating_sub(1)..(x + 2).min(ks) {
                out[ny * ks + nx] = gamma;
            }
        }
    }
    out
}

/// Damping factor off the current support at the finest level ([`entry_damping`]).
const OFF_SUPPORT_FACTOR: f64 = 5.0;

/// One pyramid level of [`estimate_kernel`] on `y` (with its clipped-pixel map, [`clipped_map`]
/// resampled to the level); `finest` selects the full-resolution settings.
fn estimate_level(
    (y, clipped): (&Plane, Option<&[f64]>),
    mut kernel: Vec<f64>,
    ks: usize,
    params: &BlindParams,
    progress: &dyn Progress,
    (done, total): (usize, usize),
    finest: bool,
) -> CoreResult<Vec<f64>> {
    let gamma = if finest {
        params.kernel_reg * FINEST_REG_FACTOR
    } else {
        params.kernel_reg
    };
    let layout = PadLayout::new(y.height, y.width, ks, ks);
    let fft = Fft2::new(layout.padded_height, layout.padded_width);
    let yp = layout.pad_tapered(y);
    let y_spec = fft.forward(&yp);
    let (gyx, gyy) = grad(&yp, fft.width);
    // Observed gradients: both pixels of the difference inside the photo and not clipped.
    let mask = {
        let mut m = layout.mask();
        if let Some(c) = clipped {
            let c = Plane::new(y.width, y.height, c.iter().map(|&v| v as f32).collect())?;
            for (m, c) in m.iter_mut().zip(layout.pad_mirror(&c)) {
                *m *= 1.0 - c;
            }
        }
        let w = fft.width;
        let n = m.len();
        (0..n)
            .map(|i| {
                let right = if (i + 1) % w == 0 { 0.0 } else { m[i + 1] };
                let down = if i + w < n { m[i + w] } else { 0.0 };
                m[i] * right * down
            })
            .collect::<Vec<f32>>()
    };
    let dpow = gradient_power(&fft);
    let mut lambda = if finest {
        params.lambda_grad * FINEST_LAMBDA_FACTOR
    } else {
        params.lambda_grad
    };
    let mut threshold: Option<f32> = None;
    for it in 0..params.iterations_per_level {
        progress.check()?;
        let gammas = entry_damping(&kernel, ks, gamma, finest);
        let kspec = fft.kernel_spectrum(ks, ks, |x, yy| kernel[yy * ks + x]);
        let latent = l0_restore(&fft, &y_spec, &kspec, &dpow, lambda as f32, progress)?;
        let (mut lx, mut ly) = grad(&latent, fft.width);
        let t = *threshold.get_or_insert_with(|| salient_threshold(&lx, &ly, &mask, ks));
        lx.par_iter_mut()
            .zip(ly.par_iter_mut())
            .for_each(|(gx, gy)| {
                if gx.hypot(*gy) < t {
                    *gx = 0.0;
                    *gy = 0.0;
                }
            });
        threshold = Some(t / 1.1);
        let lx_spec = fft.forward(&lx);
        let ly_spec = fft.forward(&ly);
        kernel = kernel_step(
            &fft,
            [&lx_spec, &ly_spec],
            [&gyx, &gyy],
            &mask,
            ks,
            &gammas,
            &kernel,
        );
        clean_kernel(
            &mut kernel,
            ks,
            params.kernel_threshold.unwrap_or(DEFAULT_KERNEL_THRESHOLD),
        );
        lambda = (lambda / 1.1).max(1e-4);
        progress.report(KERNEL_STEP, (done + it + 1) as u64, total as u64);
    }
    Ok(kernel)
}
