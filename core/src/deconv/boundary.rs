//! Boundary handling: embedding an image in a larger, fast-FFT-sized periodic domain.
//!
//! FFT deconvolution assumes the image is periodic. A photo is not, and the jump between its
//! left and right (top and bottom) edges is a sharp edge that no blur produced, so inverse filters
//! answer it with ringing that runs across the whole frame. The cure used here (as in MATLAB's
//! `edgetaper` family, and Reeves 2005, "Fast image restoration without boundary artifacts",
//! IEEE TIP 14(10)) is to extend the image into a margin that is a mirror image of it near the
//! edges — continuous with the content — and fades smoothly to the image mean across the margin,
//! so that the wrap-around seam lies where both sides equal the same constant.

use rayon::prelude::*;

use super::Plane;

/// Where an image of `height × width` sits inside a padded `padded_height × padded_width` domain.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PadLayout {
    /// Original height.
    pub height: usize,
    /// Original width.
    pub width: usize,
    /// Padded (FFT) height.
    pub padded_height: usize,
    /// Padded (FFT) width.
    pub padded_width: usize,
    /// Row of the image's top-left pixel in the padded domain.
    pub off_y: usize,
    /// Column of the image's top-left pixel in the padded domain.
    pub off_x: usize,
}

impl PadLayout {
    /// Layout with at least `margin_y`/`margin_x` px on every side, grown to fast FFT sizes and
    /// centred (so both margins are about equal).
    pub fn new(height: usize, width: usize, margin_y: usize, margin_x: usize) -> Self {
        let padded_height = super::fft::fast_len(height + 2 * margin_y);
        let padded_width = super::fft::fast_len(width + 2 * margin_x);
        Self {
            height,
            width,
            padded_height,
            padded_width,
            off_y: (padded_height - height) / 2,
            off_x: (padded_width - width) / 2,
        }
    }

    /// The image part of a padded plane.
    pub fn crop(&self, padded: &[f32]) -> Vec<f32> {
        self.crop_map(padded, |v| v)
    }

    /// The image part of a padded plane with `f` applied to each value, in one pass.
    pub fn crop_map(&self, padded: &[f32], f: impl Fn(f32) -> f32 + Sync) -> Vec<f32> {
        let mut out = vec![0.0f32; self.height * self.width];
        out.par_chunks_mut(self.width)
            .enumerate()
            .for_each(|(y, row)| {
                let start = (y + self.off_y) * self.padded_width + self.off_x;
                for (o, &v) in row.iter_mut().zip(&padded[start..start + self.width]) {
                    *o = f(v);
                }
            });
        out
    }

    /// For each padded coordinate along one axis: the mirrored source index and the taper weight.
    fn axis(n: usize, padded: usize, off: usize) -> Vec<(usize, f32)> {
        let band = padded - n;
        (0..padded)
            .map(|q| {
                let i = q as isize - off as isize;
                let src = reflect(i, n);
                // Distance from the image's right edge going right and wrapping round: the band
                // runs s = 1..=band and the image edges sit at s = 0 and s = band + 1.
                let s = if i < 0 {
                    band - off + q + 1
                } else if i as usize >= n {
                    i as usize - n + 1
                } else {
                    return (src, 1.0);
                };
                let t = s as f64 / (band + 1) as f64;
                let w = 0.5 * (1.0 + (2.0 * std::f64::consts::PI * t).cos());
                (src, w as f32)
            })
            .collect()
    }

    /// The image mirrored into the margins and faded to its mean with a raised cosine.
    pub fn pad_tapered(&self, img: &Plane) -> Vec<f32> {
        let mean = img.mean() as f32;
        let ys = Self::axis(self.height, self.padded_height, self.off_y);
        let xs = Self::axis(self.width, self.padded_width, self.off_x);
        let mut out = vec![0.0f32; self.padded_height * self.padded_width];
        out.par_chunks_mut(self.padded_width)
            .zip(&ys)
            .for_each(|(row, &(sy, wy))| {
                let src = &img.data[sy * img.width..(sy + 1) * img.width];
                for (o, &(sx, wx)) in row.iter_mut().zip(&xs) {
                    *o = mean + wy * wx * (src[sx] - mean);
                }
            });
        out
    }

    /// The image mirrored into the whole padded domain (no taper).
    pub fn pad_mirror(&self, img: &Plane) -> Vec<f32> {
        let ys = Self::axis(self.height, self.padded_height, self.off_y);
        let xs = Self::axis(self.width, self.padded_width, self.off_x);
        let mut out = vec![0.0f32; self.padded_height * self.padded_width];
        out.par_chunks_mut(self.padded_width)
            .zip(&ys)
            .for_each(|(row, &(sy, _))| {
                let src = &img.data[sy * img.width..(sy + 1) * img.width];
                for (o, &(sx, _)) in row.iter_mut().zip(&xs) {
                    *o = src[sx];
                }
            });
        out
    }

    /// 1 on the image, 0 in the margins.
    pub fn mask(&self) -> Vec<f32> {
        let mut out = vec![0.0f32; self.padded_height * self.padded_width];
        for y in 0..self.height {
            let start = (y + self.off_y) * self.padded_width + self.off_x;
            out[start..start + self.width].fill(1.0);
        }
        out
    }
}

/// Half-sample symmetric reflection (`d c b a | a b c d | d c b a`, scipy's `reflect`), repeated
/// as often as needed so that margins wider than the image still map inside it.
pub fn reflect(i: isize, n: usize) -> usize {
    let p = 2 * n as isize;
    let m = i.rem_euclid(p) as usize;
    if m < n { m } else { 2 * n - 1 - m }
}
