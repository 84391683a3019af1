//! Blur scoring of images: Laplacian variance, the singular-value feature β, a combined
//! normalised score with a default threshold, and per-block blur maps.
//!
//! The verdict (`blurred`) uses the combined score by default ([`combined_score`], module
//! `verdict`): a ratio of fine- to coarse-scale gradient energy after removing the estimated
//! sensor noise, which needs no per-camera threshold. [`blur_map`] gives the same quantity per
//! block. Two older, absolute no-reference scores stay in every result:
//! - [`laplacian_variance`]: variance of the 3×3 Laplacian; low = few sharp edges = blurred.
//! - [`svd_beta`]: β of Su, Lu & Tan, "Blurred image region detection and classification",
//!   ACM Multimedia 2011 — the share of the top-k singular values; high = blurred.
//!
//! Both thresholds are **data-dependent** (resolution, sensor noise, content; see the "Blur"
//! section of science.md: noise alone adds ~130 to the Laplacian variance at σ = 0.01, and the
//! β threshold has been measured anywhere from 0.47 to 0.6). The defaults in [`BlurParams`]
//! are only starting points: [`score_images`] always returns the raw scores and a ranking so
//! that users can calibrate thresholds on their own labelled frames.

#[cfg(feature = "video")]
pub mod clip;
mod laplacian;
mod map;
mod plot;
mod select;
mod svd;
mod verdict;

#[cfg(test)]
mod tests;
#[cfg(test)]
mod verdict_tests;

use std::sync::atomic::{AtomicU64, Ordering};

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{CoreError, CoreResult};
use crate::io::{ImageLimits, decode_gray8};
use crate::progress::Progress;

pub use laplacian::laplacian_variance;
pub use map::{
    BlurExtent, BlurMap, MAP_BLOCK_RANGE, MapSummary, blur_map, blur_map_at, render_map_png,
};
pub use plot::render_svg;
pub use select::FrameSelection;
pub use svd::{
    MAX_BETA_SIDE, MAX_CLIP_BETA_SIDE, clip_reduction_factor, reduction_factor, svd_beta,
    svd_beta_reduced,
};
pub use verdict::{CombinedScore, DEFAULT_BLUR_THRESHOLD, WORK_SIDE, combined_score};

/// Which score decides `blurred`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub enum BlurRule {
    /// The combined score is above `blur_threshold` (normalised for scale, contrast and noise;
    /// its threshold was chosen on one split of real photos and holds on a held-out split).
    #[default]
    Combined,
    /// Blurred if either absolute score says so (catches more blur, more false alarms; the
    /// thresholds depend on resolution, contrast and noise).
    Either,
    /// Blurred only if both scores agree (fewer false alarms).
    Both,
    /// Only the Laplacian variance decides.
    Laplacian,
    /// Only β decides.
    Beta,
}

/// Parameters of [`score_images`].
///
/// The default verdict is the combined score against `blur_threshold`, which needs no
/// per-camera tuning. The Laplacian and β thresholds are data-dependent (resolution, noise,
/// content) and only decide under the other rules: conventional starting points, not
/// calibrated values.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct BlurParams {
    /// Number of largest singular values in the numerator of β (Su et al. use 10). 1..=64.
    #[cfg_attr(feature = "schema", schema(minimum = 1, maximum = 64))]
    pub k: usize,
    /// An image is blurred by the Laplacian criterion if its Laplacian variance is below this.
    /// Data-dependent: grows with resolution, contrast and noise (100 is the folklore value for
    /// clean 640×480 frames; noisy frames can exceed it even when blurred). Must be within [0, 1e9].
    #[cfg_attr(feature = "schema", schema(minimum = 0.0, maximum = 1e9))]
    pub laplacian_threshold: f64,
    /// An image is blurred by the β criterion if β is above this (0.6 in the original paper's
    /// data; 0.47–0.52 measured elsewhere). Must be within [0, 1].
    #[cfg_attr(feature = "schema", schema(minimum = 0.0, maximum = 1.0))]
    pub beta_threshold: f64,
    /// An image is blurred by the combined criterion if its combined score is above this.
    /// The default was chosen on synthetic camera shake and defocus of real photos and holds
    /// on a held-out set (see `examples/blur_eval.rs`). Must be within [0, 1].
    #[cfg_attr(feature = "schema", schema(minimum = 0.0, maximum = 1.0))]
    pub blur_threshold: f64,
    /// Which criterion decides: `combined` (default), `either`, `both`, `laplacian` or `beta`.
    pub rule: BlurRule,
    /// Side in pixels of the blocks of the per-image blur map (8..=1024), or 0 for no map.
    #[cfg_attr(feature = "schema", schema(maximum = 1024))]
    pub map_block: u32,
    /// Video datasets: how many of the sharpest frames to pick, and how far apart.
    pub select: FrameSelection,
}

/// Largest accepted `laplacian_threshold` (a thousand times the largest possible variance).
pub const MAX_LAPLACIAN_THRESHOLD: f64 = 1e9;

impl Default for BlurParams {
    fn default() -> Self {
        Self {
            k: 10,
            laplacian_threshold: 100.0,
            beta_threshold: 0.6,
            blur_threshold: DEFAULT_BLUR_THRESHOLD,
            rule: BlurRule::Combined,
            map_block: 32,
            select: FrameSelection::default(),
        }
    }
}

impl BlurParams {
    /// Check ranges; errors name the offending field.
    pub fn validate(&self) -> CoreResult<()> {
        if !(1..=64).contains(&self.k) {
            return Err(CoreError::param("k", "must be between 1 and 64"));
        }
        // The variance of a 3×3 Laplacian on 0..255 values cannot exceed (4·255)² ≈ 1.04e6;
        // a bound far above that keeps every threshold meaningful and every derived quantity
        // (plot axes are a factor of a few around it) finite.
        if !self.laplacian_threshold.is_finite()
            || !(0.0..=MAX_LAPLACIAN_THRESHOLD).contains(&self.laplacian_threshold)
        {
            return Err(CoreError::param(
                "laplacian_threshold",
                "must be a finite number within [0, 1e9]",
            ));
        }
        if !(0.0..=1.0).contains(&self.beta_threshold) {
            return Err(CoreError::param("beta_threshold", "must be within [0, 1]"));
        }
        if !(0.0..=1.0).contains(&self.blur_threshold) {
            return Err(CoreError::param("blur_threshold", "must be within [0, 1]"));
        }
        if self.map_block != 0 && !(MAP_BLOCK_RANGE.0..=MAP_BLOCK_RANGE.1).contains(&self.map_block)
        {
            return Err(CoreError::param(
                "map_block",
                "must be 0 (no map) or between 8 and 1024 pixels",
            ));
        }
        self.select.validate()
    }

    /// The verdict for one image's scores (`blur_score` is [`CombinedScore::score`]).
    pub fn is_blurred(&self, laplacian_variance: f64, svd_beta: f64, blur_score: f64) -> bool {
        let lap = laplacian_variance < self.laplacian_threshold;
        let beta = svd_beta > self.beta_threshold;
        match self.rule {
            BlurRule::Combined => blur_score > self.blur_threshold,
            BlurRule::Either => lap || beta,
            BlurRule::Both => lap && beta,
            BlurRule::Laplacian => lap,
            BlurRule::Beta => beta,
        }
    }
}

/// Scores of one image.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct ImageScore {
    /// The name the image was submitted under.
    pub name: String,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Variance of the 3×3 Laplacian response on 0..255 grey values (higher = sharper);
    /// equals OpenCV's `cv2.Laplacian(gray, CV_64F, ksize=1).var()`.
    pub laplacian_variance: f64,
    /// β = share of the top-k singular values, in [0, 1] (higher = blurrier).
    pub svd_beta: f64,
    /// Combined score in [0, 1] (higher = blurrier), the default verdict's score; equals
    /// `combined.score`.
    pub blur_score: f64,
    /// The combined score with its noise estimate and directional parts.
    pub combined: CombinedScore,
    /// Local sharpness per block (absent when `map_block` is 0).
    pub map: Option<BlurMap>,
    /// Verdict under the request's rule and thresholds.
    pub blurred: bool,
    /// Position in the ranking by Laplacian variance: 1 = sharpest.
    pub rank: usize,
}

/// Minimum, median and maximum of one score over the images.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct Stats {
    /// Smallest value.
    pub min: f64,
    /// Median (mean of the two middle values for an even count).
    pub median: f64,
    /// Largest value.
    pub max: f64,
}

impl Stats {
    fn of(values: impl Iterator<Item = f64>) -> Self {
        let mut v: Vec<f64> = values.collect();
        if v.is_empty() {
            return Self {
                min: 0.0,
                median: 0.0,
                max: 0.0,
            };
        }
        v.sort_by(f64::total_cmp);
        let n = v.len();
        let median = if n % 2 == 1 {
            v[n / 2]
        } else {
            0.5 * (v[n / 2 - 1] + v[n / 2])
        };
        Self {
            min: v[0],
            median,
            max: v[n - 1],
        }
    }
}

/// Aggregate view of a [`BlurReport`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct BlurSummary {
    /// Number of images scored.
    pub count: usize,
    /// Number of images judged blurred.
    pub blurred_count: usize,
    /// Laplacian variance over the images.
    pub laplacian: Stats,
    /// β over the images.
    pub beta: Stats,
    /// Combined score over the images.
    pub blur_score: Stats,
}

/// Result of [`score_images`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct BlurReport {
    /// One entry per image, in input order, with the raw scores.
    pub images: Vec<ImageScore>,
    /// Image names from sharpest to blurriest by Laplacian variance.
    pub ranking: Vec<String>,
    /// Counts and score statistics.
    pub summary: BlurSummary,
}

/// One image's scores before ranking.
struct Scored {
    width: u32,
    height: u32,
    lap: f64,
    beta: f64,
    combined: CombinedScore,
    map: Option<BlurMap>,
}

/// Score every image: decode (lazily: `load(i)` returns the bytes of image `i`), compute
/// [`laplacian_variance`], [`svd_beta`], [`combined_score`] and (unless `map_block` is 0) the
/// [`blur_map`], judge with the rule and thresholds of `params`, rank by Laplacian variance.
///
/// Images run in parallel on the rayon pool; each is decoded only when its turn comes, so memory
/// stays at a few images regardless of the batch size. Cancellation is checked before each
/// image and reported as [`CoreError::Canceled`]; progress is reported as step `"scoring"`.
/// An image that cannot be loaded or decoded fails the whole call with
/// [`CoreError::InvalidInput`] naming it.
///
/// The thresholds are data-dependent (resolution, noise, content): the report always carries the
/// raw scores so users can calibrate thresholds on their own data.
pub fn score_images<F>(
    names: &[String],
    load: F,
    params: &BlurParams,
    limits: &ImageLimits,
    progress: &dyn Progress,
) -> CoreResult<BlurReport>
where
    F: Fn(usize) -> CoreResult<Vec<u8>> + Sync,
{
    params.validate()?;
    if names.is_empty() {
        return Err(CoreError::input("no images to score"));
    }
    let total = names.len() as u64;
    let done = AtomicU64::new(0);
    progress.report("scoring", 0, total);
    let scored: Vec<Scored> = (0..names.len())
        .into_par_iter()
        .map(|i| {
            progress.check()?;
            let name = &names[i];
            let named = |e: CoreError| match e {
                CoreError::InvalidInput(m) => CoreError::input(format!("{name}: {m}")),
                other => other,
            };
            let bytes = load(i).map_err(named)?;
            let gray = decode_gray8(&bytes, limits).map_err(named)?;
            drop(bytes);
            progress.check()?;
            let lap = laplacian_variance(&gray);
            let beta = svd_beta(&gray, params.k).map_err(named)?;
            let combined = combined_score(&gray);
            let map = match params.map_block {
                0 => None,
                b => Some(blur_map_at(&gray, b, params.blur_threshold).map_err(named)?),
            };
            let d = done.fetch_add(1, Ordering::Relaxed) + 1;
            progress.report("scoring", d, total);
            Ok(Scored {
                width: gray.width,
                height: gray.height,
                lap,
                beta,
                combined,
                map,
            })
        })
        .collect::<CoreResult<_>>()?;

    // Ranking: sharpest (highest variance) first; ties keep input order.
    let mut order: Vec<usize> = (0..names.len()).collect();
    order.sort_by(|&a, &b| scored[b].lap.total_cmp(&scored[a].lap));
    let mut rank = vec![0usize; names.len()];
    for (pos, &i) in order.iter().enumerate() {
        rank[i] = pos + 1;
    }
    let images: Vec<ImageScore> = scored
        .into_iter()
        .enumerate()
        .map(|(i, s)| ImageScore {
            name: names[i].clone(),
            width: s.width,
            height: s.height,
            laplacian_variance: s.lap,
            svd_beta: s.beta,
            blur_score: s.combined.score,
            blurred: params.is_blurred(s.lap, s.beta, s.combined.score),
            combined: s.combined,
            map: s.map,
            rank: rank[i],
        })
        .collect();
    let summary = BlurSummary {
        count: images.len(),
        blurred_count: images.iter().filter(|s| s.blurred).count(),
        laplacian: Stats::of(images.iter().map(|s| s.laplacian_variance)),
        beta: Stats::of(images.iter().map(|s| s.svd_beta)),
        blur_score: Stats::of(images.iter().map(|s| s.blur_score)),
    };
    Ok(BlurReport {
        ranking: order.iter().map(|&i| names[i].clone()).collect(),
        images,
        summary,
    })
}
