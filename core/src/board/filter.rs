//! Floating-point image primitives shared by the detector and the synthetic renderer:
//! separable Gaussian and box filters with mirrored borders and bilinear sampling.
//!
//! Borders are mirrored without repeating the edge pixel (OpenCV's `BORDER_REFLECT_101`), which
//! keeps a straight edge that crosses the border straight after smoothing, so corners of a board
//! touching the border are not pulled inwards.

use crate::io::Gray;

/// A single-channel `f32` image, row-major.
#[derive(Clone, Debug)]
pub struct ImageF {
    /// Width in pixels.
    pub w: usize,
    /// Height in pixels.
    pub h: usize,
    /// Pixels, row after row.
    pub data: Vec<f32>,
}

impl ImageF {
    /// A `w × h` image filled with `v`.
    pub fn filled(w: usize, h: usize, v: f32) -> Self {
        Self {
            w,
            h,
            data: vec![v; w * h],
        }
    }

    /// Grey levels 0..255 as `f32`.
    pub fn from_gray(g: &Gray) -> Self {
        Self {
            w: g.width as usize,
            h: g.height as usize,
            data: g.data.iter().map(|&v| f32::from(v)).collect(),
        }
    }

    /// Rounds and clamps to 8 bits.
    pub fn to_gray(&self) -> Gray {
        Gray {
            width: self.w as u32,
            height: self.h as u32,
            data: self
                .data
                .iter()
                .map(|&v| v.round().clamp(0.0, 255.0) as u8)
                .collect(),
        }
    }

    /// Whether the bilinear neighbourhood of `(x, y)` lies `margin` pixels inside the image.
    #[inline]
    pub fn contains(&self, x: f64, y: f64, margin: f64) -> bool {
        x >= margin
            && y >= margin
            && x <= (self.w as f64 - 1.0 - margin)
            && y <= (self.h as f64 - 1.0 - margin)
    }

    /// Bilinear interpolation at `(x, y)` (pixel centres at integers), clamped to the image.
    #[inline]
    pub fn bilinear(&self, x: f64, y: f64) -> f32 {
        let xm = (self.w - 1) as f64;
        let ym = (self.h - 1) as f64;
        let x = x.clamp(0.0, xm);
        let y = y.clamp(0.0, ym);
        let x0 = (x.floor() as usize).min(self.w.saturating_sub(2));
        let y0 = (y.floor() as usize).min(self.h.saturating_sub(2));
        let fx = (x - x0 as f64) as f32;
        let fy = (y - y0 as f64) as f32;
        let x1 = (x0 + 1).min(self.w - 1);
        let y1 = (y0 + 1).min(self.h - 1);
        let r0 = y0 * self.w;
        let r1 = y1 * self.w;
        let a = self.data[r0 + x0] + fx * (self.data[r0 + x1] - self.data[r0 + x0]);
        let b = self.data[r1 + x0] + fx * (self.data[r1 + x1] - self.data[r1 + x0]);
        a + fy * (b - a)
    }
}

impl ImageF {
    /// [`ImageF::bilinear`] for a point whose bilinear neighbourhood is known to lie inside the
    /// image (`contains(x, y, 0)`): the same value without the clamps and the libm `floor`.
    #[inline]
    pub fn bilinear_inside(&self, x: f64, y: f64) -> f32 {
        debug_assert!(self.contains(x, y, 0.0));
        // Non-negative, so truncation is the floor.
        let x0 = (x as usize).min(self.w.saturating_sub(2));
        let y0 = (y as usize).min(self.h.saturating_sub(2));
        let fx = (x - x0 as f64) as f32;
        let fy = (y - y0 as f64) as f32;
        let r0 = y0 * self.w + x0;
        let r1 = r0 + self.w;
        let d = &self.data;
        let a = d[r0] + fx * (d[r0 + 1] - d[r0]);
        let b = d[r1] + fx * (d[r1 + 1] - d[r1]);
        a + fy * (b - a)
    }
}

/// Mirror an index into `0..n` (reflect-101).
#[inline]
fn mirror(i: isize, n: usize) -> usize {
    let n = n as isize;
    if n == 1 {
        return 0;
    }
    let period = 2 * (n - 1);
    let mut i = i.rem_euclid(period);
    if i >= n {
        i = period - i;
    }
    i as usize
}

/// Normalised Gaussian taps, radius `ceil(3σ)`.
pub fn gaussian_kernel(sigma: f64) -> Vec<f32> {
    let r = (3.0 * sigma).ceil().max(1.0) as isize;
    let mut k: Vec<f64> = (-r..=r)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let s: f64 = k.iter().sum();
    k.iter_mut().for_each(|v| *v /= s);
    k.into_iter().map(|v| v as f32).collect()
}

/// Taps of a centred box of (possibly fractional) length `len` ≥ 1: full weight inside,
/// fractional weight on the two end taps, summing to 1. A horizontal linear motion blur of
/// `len` pixels.
pub fn box_kernel(len: f64) -> Vec<f32> {
    let len = len.max(1.0);
    let half = 0.5 * len;
    let r = (half - 0.5).ceil().max(0.0) as isize;
    let mut k: Vec<f64> = (-r..=r)
        .map(|i| {
            // Overlap of [i − ½, i + ½] with [−half, half].
            let lo = (i as f64 - 0.5).max(-half);
            let hi = (i as f64 + 0.5).min(half);
            (hi - lo).max(0.0)
        })
        .collect();
    let s: f64 = k.iter().sum();
    k.iter_mut().for_each(|v| *v /= s);
    k.into_iter().map(|v| v as f32).collect()
}

/// Convolve every row with the odd-length kernel `k` (centred).
pub fn convolve_rows(img: &ImageF, k: &[f32]) -> ImageF {
    let (w, h) = (img.w, img.h);
    let r = (k.len() / 2) as isize;
    let mut out = ImageF::filled(w, h, 0.0);
    let mut line = vec![0.0f32; w + 2 * r as usize];
    for y in 0..h {
        let row = &img.data[y * w..(y + 1) * w];
        fill_mirrored(&mut line, row, r as usize, |v| v);
        // Tap-major accumulation: each tap is a vectorisable multiply-add over the row.
        let o = &mut out.data[y * w..(y + 1) * w];
        for (t, &kv) in k.iter().enumerate() {
            for (ov, lv) in o.iter_mut().zip(&line[t..t + w]) {
                *ov += kv * lv;
            }
        }
    }
    out
}

/// `line[i] = f(row[mirror(i − r)])`: the row with `r` mirrored pixels on either side.
#[inline]
fn fill_mirrored<T: Copy>(line: &mut [f32], row: &[T], r: usize, f: impl Fn(T) -> f32) {
    let w = row.len();
    for (o, &v) in line[r..r + w].iter_mut().zip(row) {
        *o = f(v);
    }
    for i in (0..r).chain(r + w..line.len()) {
        line[i] = f(row[mirror(i as isize - r as isize, w)]);
    }
}

/// Convolve every column with the odd-length kernel `k` (centred).
pub fn convolve_cols(img: &ImageF, k: &[f32]) -> ImageF {
    let (w, h) = (img.w, img.h);
    let r = (k.len() / 2) as isize;
    let mut out = ImageF::filled(w, h, 0.0);
    for y in 0..h {
        let o = &mut out.data[y * w..(y + 1) * w];
        for (t, &kv) in k.iter().enumerate() {
            let sy = mirror(y as isize + t as isize - r, h);
            let src = &img.data[sy * w..(sy + 1) * w];
            for (ov, sv) in o.iter_mut().zip(src) {
                *ov += kv * sv;
            }
        }
    }
    out
}

/// Isotropic Gaussian blur of standard deviation `sigma` pixels (identity for σ ≤ 0).
pub fn gaussian_blur(img: &ImageF, sigma: f64) -> ImageF {
    if sigma <= 0.0 || img.w == 0 || img.h == 0 {
        return img.clone();
    }
    let k = gaussian_kernel(sigma);
    convolve_cols(&convolve_rows(img, &k), &k)
}

/// Pixels per block of the symmetric convolution: the accumulators of one block stay in
/// registers while the taps are applied.
const BLOCK: usize = 16;

/// `out[x] = kc·centre[x] + Σₜ k[t]·(pairs[t].0[x] + pairs[t].1[x])`: one output row of a
/// convolution with a symmetric kernel, in register blocks.
#[inline]
fn symmetric_taps(out: &mut [f32], centre: &[f32], kc: f32, pairs: &[(&[f32], &[f32])], k: &[f32]) {
    let n = out.len();
    let full = n - n % BLOCK;
    for x in (0..full).step_by(BLOCK) {
        let mut acc = [0.0f32; BLOCK];
        let c = &centre[x..x + BLOCK];
        for l in 0..BLOCK {
            acc[l] = kc * c[l];
        }
        for (&(a, b), &kt) in pairs.iter().zip(k) {
            let (a, b) = (&a[x..x + BLOCK], &b[x..x + BLOCK]);
            for l in 0..BLOCK {
                acc[l] += kt * (a[l] + b[l]);
            }
        }
        out[x..x + BLOCK].copy_from_slice(&acc);
    }
    for x in full..n {
        let mut acc = kc * centre[x];
        for (&(a, b), &kt) in pairs.iter().zip(k) {
            acc += kt * (a[x] + b[x]);
        }
        out[x] = acc;
    }
}

/// Gaussian blur of an 8-bit image (σ > 0), the detector's smoothing: the same kernel and
/// borders as [`gaussian_blur`], with the symmetric taps paired (equal to it up to f32
/// round-off) and the conversion from 8 bits fused into the row pass.
pub fn gaussian_blur_gray(img: &Gray, sigma: f64) -> ImageF {
    let (w, h) = (img.width as usize, img.height as usize);
    if sigma <= 0.0 || w == 0 || h == 0 {
        return ImageF::from_gray(img);
    }
    let k = gaussian_kernel(sigma);
    let r = k.len() / 2;
    let kc = k[r];
    let side = &k[..r];
    // Rows.
    let mut tmp = ImageF::filled(w, h, 0.0);
    let mut line = vec![0.0f32; w + 2 * r];
    for y in 0..h {
        fill_mirrored(&mut line, &img.data[y * w..(y + 1) * w], r, f32::from);
        let pairs: Vec<(&[f32], &[f32])> = (0..r)
            .map(|t| (&line[t..t + w], &line[2 * r - t..2 * r - t + w]))
            .collect();
        symmetric_taps(
            &mut tmp.data[y * w..(y + 1) * w],
            &line[r..r + w],
            kc,
            &pairs,
            side,
        );
    }
    // Columns.
    let mut out = ImageF::filled(w, h, 0.0);
    let src = &tmp.data;
    let row = |yy: isize| {
        let m = mirror(yy, h);
        &src[m * w..(m + 1) * w]
    };
    for y in 0..h {
        let yi = y as isize;
        let pairs: Vec<(&[f32], &[f32])> = (0..r)
            .map(|t| {
                (
                    row(yi + t as isize - r as isize),
                    row(yi + r as isize - t as isize),
                )
            })
            .collect();
        symmetric_taps(&mut out.data[y * w..(y + 1) * w], row(yi), kc, &pairs, side);
    }
    out
}
