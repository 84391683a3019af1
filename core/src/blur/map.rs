//! Blur maps: local sharpness per block, so that a user sees whether the whole frame shook
//! (every block soft) or one object moved or fell out of focus (some blocks soft).
//!
//! Su, Lu & Tan ("Blurred image region detection and classification", ACM MM 2011) compute
//! their singular-value feature on local patches for exactly this. Here each block gets the
//! same quantity as the image's combined score ([`super::verdict`]): the share ρ of its edge
//! pixels' noise-corrected gradient energy that survives a 4-px average, all directions
//! pooled; a block's edge pixels are those with a coarse gradient of at least 60 % of the
//! block's strongest. Unlike a local β it is cheap (no decomposition per patch), does not
//! depend on the block's contrast, and its scale matches the image verdict, so a block is
//! "sharp" exactly when it would pass the image threshold on its own.

use image::{ImageEncoder, Rgb, RgbImage};
use serde::{Deserialize, Serialize};

use super::verdict::{
    DEFAULT_BLUR_THRESHOLD, EDGE_FRACTION, Plane, block_energies, coarse_extremes, noise_sigma,
    texture_floor, working_plane,
};
use crate::error::{CoreError, CoreResult};
use crate::io::Gray;

/// Smallest and largest accepted block side, in pixels of the input image.
pub const MAP_BLOCK_RANGE: (u32, u32) = (8, 1024);

/// Whether the blur is everywhere, in part of the frame, or nowhere.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub enum BlurExtent {
    /// At least 80 % of the textured blocks are sharp.
    Sharp,
    /// Between 20 % and 80 % are sharp: an object moved, or depth of field.
    Local,
    /// At most 20 % are sharp: camera shake or a missed focus.
    Global,
    /// No block has texture enough to judge.
    Undetermined,
}

/// Short reading of a [`BlurMap`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct MapSummary {
    /// Share of the textured blocks that are sharp (value ≥ 1 − threshold); 0 without any.
    pub sharp_share: f64,
    /// Share of all blocks that have texture enough to judge.
    pub textured_share: f64,
    /// Global, local or no blur.
    pub extent: BlurExtent,
}

/// Local sharpness per block.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct BlurMap {
    /// Block side in pixels of the input image (the requested size rounded to the working
    /// resolution of large images).
    pub block_px: u32,
    /// Blocks per row.
    pub cols: u32,
    /// Block rows.
    pub rows: u32,
    /// Row-major local sharpness in [0, 1]: 1 − ρ, where ρ is the block's share of gradient
    /// energy surviving a 4-px average (see [`super::verdict`]). ≈ 0.75 for ideal edges,
    /// ≈ 0.55 for typical sharp photos, ≈ 0.4 at 3-px blur, → 0 for strong blur. A block is
    /// sharp when its value is at least 1 − `blur_threshold`.
    pub values: Vec<f64>,
    /// Row-major: true where the block has too little texture to judge (its value is then
    /// meaningless and left out of the summary).
    pub flat: Vec<bool>,
    /// Share of sharp blocks and whether the blur is global or local.
    pub summary: MapSummary,
}

/// Blur map with blocks of `block` pixels, summarised at the default threshold
/// ([`DEFAULT_BLUR_THRESHOLD`]).
pub fn blur_map(gray: &Gray, block: u32) -> CoreResult<BlurMap> {
    blur_map_at(gray, block, DEFAULT_BLUR_THRESHOLD)
}

/// Blur map with blocks of `block` pixels (8..=1024), summarised with `threshold` (the blur
/// score threshold, in [0, 1]). Images larger than the working size are reduced first, so the
/// block side in the result is a multiple of the reduction factor.
pub fn blur_map_at(gray: &Gray, block: u32, threshold: f64) -> CoreResult<BlurMap> {
    if !(MAP_BLOCK_RANGE.0..=MAP_BLOCK_RANGE.1).contains(&block) {
        return Err(CoreError::param(
            "map_block",
            "must be between 8 and 1024 pixels",
        ));
    }
    if !(threshold.is_finite() && (0.0..=1.0).contains(&threshold)) {
        return Err(CoreError::param("blur_threshold", "must be within [0, 1]"));
    }
    if gray.width == 0 || gray.height == 0 {
        return Err(CoreError::input("image has no pixels"));
    }
    let plane = working_plane(gray);
    let wb = ((block as usize) / plane.factor).max(4);
    let sigma = noise_sigma(&plane);
    let (cmax, p99) = coarse_extremes(&plane, wb);
    let floor = texture_floor(sigma, &p99);
    let top: Vec<f32> = cmax
        .iter()
        .map(|m| m.iter().copied().fold(0.0, f32::max))
        .collect();
    let e = block_energies(&plane, wb, sigma, |b, _| {
        (EDGE_FRACTION * top[b]).max(floor)
    });
    let flat: Vec<bool> = top.iter().map(|&t| t < floor).collect();
    let values: Vec<f64> = (0..flat.len()).map(|b| 1.0 - e.block_ratio(b)).collect();
    let judged: Vec<f64> = (0..flat.len())
        .filter(|&b| !flat[b])
        .map(|b| values[b])
        .collect();
    let sharp = judged.iter().filter(|&&v| v >= 1.0 - threshold).count();
    let sharp_share = if judged.is_empty() {
        0.0
    } else {
        sharp as f64 / judged.len() as f64
    };
    let extent = if judged.is_empty() {
        BlurExtent::Undetermined
    } else if sharp_share >= 0.8 {
        BlurExtent::Sharp
    } else if sharp_share <= 0.2 {
        BlurExtent::Global
    } else {
        BlurExtent::Local
    };
    Ok(BlurMap {
        block_px: (wb * plane.factor) as u32,
        cols: e.cols as u32,
        rows: e.rows as u32,
        summary: MapSummary {
            sharp_share,
            textured_share: judged.len() as f64 / flat.len().max(1) as f64,
            extent,
        },
        values,
        flat,
    })
}

/// Colour of a sharpness value: red (blurred) through yellow to green (sharp), over the range
/// 0.2..0.7 where the values of real photos fall.
fn colour(v: f64) -> [f64; 3] {
    let t = ((v - 0.2) / 0.5).clamp(0.0, 1.0);
    if t < 0.5 {
        [230.0, 460.0 * t, 40.0]
    } else {
        [230.0 * (2.0 - 2.0 * t), 230.0, 40.0]
    }
}

/// The map as a PNG heat map: the image in grey (at the working resolution, long side ≤ 1024)
/// under a translucent colour per block, red = blurred to green = sharp; flat blocks are left
/// uncoloured and darkened. `map` must have been computed from `gray`.
pub fn render_map_png(gray: &Gray, map: &BlurMap) -> CoreResult<Vec<u8>> {
    let plane: Plane = working_plane(gray);
    if plane.w == 0 || plane.h == 0 {
        return Err(CoreError::input("image has no pixels"));
    }
    let factor = plane.factor as u32;
    let wb = (map.block_px / factor).max(1) as usize;
    let (cols, rows) = (map.cols as usize, map.rows as usize);
    if map.values.len() != cols * rows
        || map.flat.len() != cols * rows
        || plane.w.div_ceil(wb) != cols
        || plane.h.div_ceil(wb) != rows
    {
        return Err(CoreError::input(
            "the blur map does not belong to this image",
        ));
    }
    let img = RgbImage::from_fn(plane.w as u32, plane.h as u32, |x, y| {
        let g = f64::from(plane.px[y as usize * plane.w + x as usize]);
        let b = (y as usize / wb) * cols + x as usize / wb;
        let edge = (x as usize).is_multiple_of(wb) || (y as usize).is_multiple_of(wb);
        let px = if map.flat[b] {
            [0.6 * g; 3]
        } else {
            let c = colour(map.values[b]);
            let a = if edge { 0.7 } else { 0.4 };
            [
                (1.0 - a) * g + a * c[0],
                (1.0 - a) * g + a * c[1],
                (1.0 - a) * g + a * c[2],
            ]
        };
        Rgb(px.map(|v| v.round().clamp(0.0, 255.0) as u8))
    });
    let mut out = Vec::new();
    image::codecs::png::PngEncoder::new(&mut out)
        .write_image(
            img.as_raw(),
            img.width(),
            img.height(),
            image::ExtendedColorType::Rgb8,
        )
        .map_err(|e| CoreError::NoSolution(format!("PNG encoding failed: {e}")))?;
    Ok(out)
}
