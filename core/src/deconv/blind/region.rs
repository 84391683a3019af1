//! The part of a large photo the blind kernel is estimated on.
//!
//! The kernel estimate's cost grows with the pixel count (an FFT pass over the whole padded
//! image per splitting step, some 60 steps per alternation at full resolution), while a
//! uniform camera-shake kernel of at most [`super::super::psf::MAX_PSF_SIZE`] px is fixed by
//! far fewer pixels: the benchmark cases of Levin et al. 2009 are 255² and every case of
//! `examples/blind_eval.rs` is 255². T. Hu, M.-H. Yang, "Good regions to deblur", ECCV 2012,
//! show that a well-chosen region of a large photo gives a kernel as good as the whole photo
//! (often better: flat sky and clipped areas only add noise to the kernel's least squares)
//! at a fraction of the cost. Their region score is learned; the one here is a plain count of
//! what the kernel step feeds on: strong gradients in every direction, off clipped pixels.

use super::super::Plane;
use crate::error::CoreResult;
use crate::progress::Progress;

/// A rectangle of an image, in pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Region {
    /// Left column.
    pub x: usize,
    /// Top row.
    pub y: usize,
    /// Width.
    pub width: usize,
    /// Height.
    pub height: usize,
}

impl Region {
    /// The part of `img` inside the region.
    pub fn crop(&self, img: &Plane) -> CoreResult<Plane> {
        let mut data = Vec::with_capacity(self.width * self.height);
        for row in self.y..self.y + self.height {
            let start = row * img.width + self.x;
            data.extend_from_slice(&img.data[start..start + self.width]);
        }
        Plane::new(self.width, self.height, data)
    }
}

/// Share of the photo's gradients (by magnitude, unclipped pixels only) that count as strong.
const STRONG_SHARE: f64 = 0.1;

/// Candidate regions are placed on a grid of this many steps per region side.
const PLACEMENT_STEPS: usize = 8;

/// The `side × side` region (clamped to the image) of `img` with the most strong gradients,
/// weighted by how evenly their directions spread; `None` when the image fits in `side` both
/// ways (the whole image is used).
///
/// A gradient is strong when its magnitude is among the top [`STRONG_SHARE`] of the photo's
/// unclipped gradients (`clipped`: 1 where [`super::clipped_map`] marks a pixel). A region's
/// score is the count `n` of its strong gradients times `2·λ₂/(λ₁ + λ₂)` of their summed
/// structure tensor (1 when the directions are spread evenly, 0 when they all point one way):
/// edges of one direction leave the kernel free along them. Ties keep the region nearest the
/// image centre. O(pixels) through summed-area tables.
pub(super) fn kernel_region(
    img: &Plane,
    side: usize,
    clipped: Option<&[f64]>,
    progress: &dyn Progress,
) -> CoreResult<Option<Region>> {
    let (w, h) = (img.width, img.height);
    if w <= side && h <= side {
        return Ok(None);
    }
    let (rw, rh) = (side.min(w), side.min(h));
    // Forward differences; zero where the pixel or its right/lower neighbour is clipped or
    // missing (the last row and column).
    let mut grads = vec![(0.0f64, 0.0f64); w * h];
    for y in 0..h.saturating_sub(1) {
        progress.check()?;
        for x in 0..w.saturating_sub(1) {
            let i = y * w + x;
            if clipped.is_some_and(|c| c[i] > 0.0) {
                continue;
            }
            let v = f64::from(img.data[i]);
            grads[i] = (
                f64::from(img.data[i + 1]) - v,
                f64::from(img.data[i + w]) - v,
            );
        }
    }
    let threshold = strong_threshold(&grads);
    // Summed-area tables of the strong gradients' count and structure tensor.
    let stride = w + 1;
    let mut tables = vec![[0.0f64; 4]; stride * (h + 1)];
    for y in 0..h {
        progress.check()?;
        let mut row = [0.0f64; 4];
        for x in 0..w {
            let (gx, gy) = grads[y * w + x];
            if gx.hypot(gy) > threshold {
                row[0] += 1.0;
                row[1] += gx * gx;
                row[2] += gy * gy;
                row[3] += gx * gy;
            }
            let above = tables[y * stride + x + 1];
            tables[(y + 1) * stride + x + 1] = std::array::from_fn(|k| row[k] + above[k]);
        }
    }
    let sum = |x: usize, y: usize| -> [f64; 4] {
        let at = |xx: usize, yy: usize| tables[yy * stride + xx];
        let (a, b, c, d) = (at(x, y), at(x + rw, y), at(x, y + rh), at(x + rw, y + rh));
        std::array::from_fn(|k| d[k] - b[k] - c[k] + a[k])
    };
    let positions = |len: usize, part: usize| -> Vec<usize> {
        let span = len - part;
        let step = (part / PLACEMENT_STEPS).max(1);
        // The grid, its far end and the centred placement.
        let mut p: Vec<usize> = (0..=span).step_by(step).collect();
        p.extend([span, span / 2]);
        p.sort_unstable();
        p.dedup();
        p
    };
    let (cx, cy) = (((w - rw) / 2) as f64, ((h - rh) / 2) as f64);
    let mut best: Option<(f64, f64, Region)> = None;
    for &y in &positions(h, rh) {
        for &x in &positions(w, rw) {
            let [n, sxx, syy, sxy] = sum(x, y);
            let trace = sxx + syy;
            let spread = if trace > 0.0 {
                let root = ((sxx - syy).powi(2) + 4.0 * sxy * sxy).sqrt();
                (trace - root) / trace
            } else {
                0.0
            };
            let score = n * spread;
            let off = (x as f64 - cx).hypot(y as f64 - cy);
            let better = match &best {
                None => true,
                Some((s, o, _)) => score > *s || (score == *s && off < *o),
            };
            if better {
                best = Some((
                    score,
                    off,
                    Region {
                        x,
                        y,
                        width: rw,
                        height: rh,
                    },
                ));
            }
        }
    }
    Ok(best.map(|(_, _, r)| r))
}

/// The gradient magnitude above which [`STRONG_SHARE`] of the non-zero gradients lie.
fn strong_threshold(grads: &[(f64, f64)]) -> f64 {
    let mut mags: Vec<f64> = grads
        .iter()
        .map(|(gx, gy)| gx.hypot(*gy))
        .filter(|m| *m > 0.0)
        .collect();
    if mags.is_empty() {
        return 0.0;
    }
    let k = ((mags.len() as f64 * (1.0 - STRONG_SHARE)) as usize).min(mags.len() - 1);
    let (_, v, _) = mags.select_nth_unstable_by(k, f64::total_cmp);
    *v
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::progress::NoProgress;

    /// A flat image with a patch of edges in both directions at `(px, py)`.
    fn with_patch(w: usize, h: usize, px: usize, py: usize, both: bool) -> Plane {
        let mut data = vec![0.5f32; w * h];
        for y in py..py + 100 {
            for x in px..px + 100 {
                let v = if both {
                    ((x / 7 + y / 5) % 2) as f32
                } else {
                    ((x / 7) % 2) as f32
                };
                data[y * w + x] = 0.2 + 0.6 * v;
            }
        }
        Plane::new(w, h, data).expect("plane")
    }

    #[test]
    fn a_small_image_is_used_whole() {
        let img = with_patch(300, 200, 10, 10, true);
        assert_eq!(
            kernel_region(&img, 512, None, &NoProgress).expect("ok"),
            None
        );
    }

    #[test]
    fn the_region_covers_the_edges() {
        let img = with_patch(900, 700, 650, 500, true);
        let r = kernel_region(&img, 256, None, &NoProgress)
            .expect("ok")
            .expect("a region");
        assert_eq!((r.width, r.height), (256, 256));
        assert!(r.x <= 650 && r.x + 256 >= 750, "{r:?}");
        assert!(r.y <= 500 && r.y + 256 >= 600, "{r:?}");
        let crop = r.crop(&img).expect("crop");
        assert_eq!(crop.at(650 - r.x, 500 - r.y), img.at(650, 500));
    }

    #[test]
    fn edges_of_one_direction_lose_to_edges_of_two() {
        // Stripes (one direction) top left, a checker pattern bottom right.
        let mut img = with_patch(900, 700, 50, 50, false);
        let checker = with_patch(900, 700, 650, 500, true);
        for y in 500..600 {
            for x in 650..750 {
                img.data[y * 900 + x] = checker.at(x, y);
            }
        }
        let r = kernel_region(&img, 256, None, &NoProgress)
            .expect("ok")
            .expect("a region");
        assert!(r.x + 256 >= 750 && r.y + 256 >= 600, "{r:?}");
    }

    #[test]
    fn clipped_pixels_do_not_count() {
        let img = with_patch(900, 700, 650, 500, true);
        let mut clipped = vec![0.0f64; 900 * 700];
        for y in 490..610 {
            for x in 640..760 {
                clipped[y * 900 + x] = 1.0;
            }
        }
        let r = kernel_region(&img, 256, Some(&clipped), &NoProgress).expect("ok");
        // Nothing strong is left: the region nearest the centre.
        let r = r.expect("a region");
        assert_eq!((r.x, r.y), (322, 222), "{r:?}");
    }
}
