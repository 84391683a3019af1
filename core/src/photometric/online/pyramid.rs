//! Image pyramids for the tracker: per-level intensity and gradients, bilinear sampling
//! (per pixel and on the pixel grid), the clipped-value test, and the Shi-Tomasi score.

/// One pyramid level: intensity and central-difference gradients, interleaved per pixel
/// (`[value, ∂x, ∂y]`): the tracker's inner loop ([`Level::sample3`]) then reads one cache line
/// per corner instead of three (a fifth of the tracking time went there).
pub(crate) struct Level {
    pub w: usize,
    pub h: usize,
    px: Vec<[f32; 3]>,
}

/// Channels of a [`Level`] for [`Level::sample`].
pub(crate) const VALUE: usize = 0;
pub(crate) const GRAD_X: usize = 1;
pub(crate) const GRAD_Y: usize = 2;

impl Level {
    pub(crate) fn new(w: usize, h: usize, data: Vec<f32>) -> Self {
        let mut px: Vec<[f32; 3]> = data.iter().map(|&d| [d, 0.0, 0.0]).collect();
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                let (xl, xr) = (x.saturating_sub(1), (x + 1).min(w - 1));
                let (yu, yd) = (y.saturating_sub(1), (y + 1).min(h - 1));
                px[i][GRAD_X] = (data[y * w + xr] - data[y * w + xl]) / (xr - xl).max(1) as f32;
                px[i][GRAD_Y] = (data[yd * w + x] - data[yu * w + x]) / (yd - yu).max(1) as f32;
            }
        }
        Self { w, h, px }
    }

    /// Intensity of pixel `i` (row-major), `None` outside the level.
    #[inline]
    pub fn value(&self, i: usize) -> Option<f32> {
        self.px.get(i).map(|p| p[VALUE])
    }

    /// Bilinear sample of channel `c` ([`VALUE`], [`GRAD_X`], [`GRAD_Y`]) at `(x, y)`; `None`
    /// outside `[0, w−1] × [0, h−1]`.
    #[inline]
    pub fn sample(&self, c: usize, x: f32, y: f32) -> Option<f32> {
        if !(x >= 0.0 && y >= 0.0 && x <= (self.w - 1) as f32 && y <= (self.h - 1) as f32) {
            return None;
        }
        // `as usize` floors a non-negative value (and saturates below 0) without the libm
        // `floorf` call, which cost 6 % of the tracking time.
        let x0 = (x as usize).min(self.w.saturating_sub(2));
        let y0 = (y as usize).min(self.h.saturating_sub(2));
        let (fx, fy) = (x - x0 as f32, y - y0 as f32);
        let i = y0 * self.w + x0;
        let (a, b) = (self.px[i][c], self.px[i + 1][c]);
        let (c, d) = (self.px[i + self.w][c], self.px[i + self.w + 1][c]);
        Some((a + fx * (b - a)) * (1.0 - fy) + (c + fx * (d - c)) * fy)
    }
}

impl Level {
    /// Whether any pixel of the bilinear support of `(x, y)` is [`clipped`] (`(x, y)` inside).
    #[inline]
    pub(crate) fn support_clipped(&self, x: f32, y: f32) -> bool {
        let x0 = (x as usize).min(self.w.saturating_sub(2));
        let y0 = (y as usize).min(self.h.saturating_sub(2));
        let i = y0 * self.w + x0;
        let j = i + self.w;
        clipped(self.px[i][VALUE])
            || clipped(self.px[i + 1][VALUE])
            || clipped(self.px[j][VALUE])
            || clipped(self.px[j + 1][VALUE])
    }

    /// Bilinear sample of intensity and both gradients at once (shared weights).
    #[inline]
    pub fn sample3(&self, x: f32, y: f32) -> Option<[f32; 3]> {
        if !(x >= 0.0 && y >= 0.0 && x <= (self.w - 1) as f32 && y <= (self.h - 1) as f32) {
            return None;
        }
        let x0 = (x as usize).min(self.w.saturating_sub(2));
        let y0 = (y as usize).min(self.h.saturating_sub(2));
        let (fx, fy) = (x - x0 as f32, y - y0 as f32);
        let (wa, wb) = ((1.0 - fx) * (1.0 - fy), fx * (1.0 - fy));
        let (wc, wd) = ((1.0 - fx) * fy, fx * fy);
        let i = y0 * self.w + x0;
        let j = i + self.w;
        let (a, b, c, d) = (self.px[i], self.px[i + 1], self.px[j], self.px[j + 1]);
        let s = |m: usize| wa * a[m] + wb * b[m] + wc * c[m] + wd * d[m];
        Some([s(0), s(1), s(2)])
    }
}

/// A Gaussian-ish ([1 2 1]/4 separable) pyramid.
pub(crate) struct Pyramid {
    pub levels: Vec<Level>,
}

impl Pyramid {
    pub fn new(w: usize, h: usize, data: Vec<f32>, n_levels: usize) -> Self {
        let mut levels = vec![Level::new(w, h, data)];
        while levels.len() < n_levels {
            let Some(prev) = levels.last() else { break };
            if prev.w < 16 || prev.h < 16 {
                break;
            }
            let (nw, nh) = (prev.w / 2, prev.h / 2);
            let mut d = vec![0.0f32; nw * nh];
            let px = |x: isize, y: isize| -> f32 {
                let xc = x.clamp(0, prev.w as isize - 1) as usize;
                let yc = y.clamp(0, prev.h as isize - 1) as usize;
                prev.px[yc * prev.w + xc][VALUE]
            };
            for y in 0..nh {
                for x in 0..nw {
                    let (sx, sy) = (2 * x as isize, 2 * y as isize);
                    let mut acc = 0.0;
                    for (dy, wy) in [(-1, 1.0), (0, 2.0), (1, 1.0)] {
                        for (dx, wx) in [(-1, 1.0), (0, 2.0), (1, 1.0)] {
                            acc += wx * wy * px(sx + dx, sy + dy);
                        }
                    }
                    d[y * nw + x] = acc / 16.0;
                }
            }
            levels.push(Level::new(nw, nh, d));
        }
        Self { levels }
    }
}

/// Values this close to black or full scale are (or mix with) clipped pixels, which do not
/// follow the gain-and-bias brightness model and would pull the match: they are left out.
#[inline]
pub(crate) fn clipped(v: f32) -> bool {
    !(0.01..=0.985).contains(&v)
}

/// An unwarped `(2·hw + 1)²` window at `q` whose bilinear support lies inside the level: every
/// pixel shares the fractional offset `(fx, fy)` of its top-left corner.
pub(super) struct GridWindow {
    /// Index of the support's top-left pixel.
    origin: usize,
    side: usize,
    weights: [f32; 4],
}

impl GridWindow {
    /// `None` when the window's support reaches the level's last row or column (or beyond),
    /// where [`Level::sample3`]'s clamping applies.
    pub(super) fn inside(l: &Level, q: [f32; 2], hw: i32) -> Option<Self> {
        let (xa, ya) = (q[0] - hw as f32, q[1] - hw as f32);
        let side = (2 * hw + 1) as usize;
        // Compared as floats, so that a far-off (or NaN) position never reaches the integer
        // arithmetic below; `floor(xa) + side ≤ w − 1` follows.
        if !(xa >= 0.0
            && ya >= 0.0
            && xa + (side as f32) < l.w as f32
            && ya + (side as f32) < l.h as f32)
        {
            return None;
        }
        let (x0, y0) = (xa as usize, ya as usize);
        let (fx, fy) = (xa - x0 as f32, ya - y0 as f32);
        Some(Self {
            origin: y0 * l.w + x0,
            side,
            weights: [
                (1.0 - fx) * (1.0 - fy),
                fx * (1.0 - fy),
                (1.0 - fx) * fy,
                fx * fy,
            ],
        })
    }

    /// The window's bilinear intensities in raster order into `out` (`side²` long).
    pub(super) fn values(&self, l: &Level, out: &mut [f32]) {
        let [wa, wb, wc, wd] = self.weights;
        for (r, orow) in out.chunks_exact_mut(self.side).enumerate() {
            let i0 = self.origin + r * l.w;
            let top = &l.px[i0..i0 + self.side + 1];
            let bottom = &l.px[i0 + l.w..i0 + l.w + self.side + 1];
            for (c, o) in orow.iter_mut().enumerate() {
                *o = wa * top[c][VALUE]
                    + wb * top[c + 1][VALUE]
                    + wc * bottom[c][VALUE]
                    + wd * bottom[c + 1][VALUE];
            }
        }
    }

    /// Calls `f(template value, [J, ∂J/∂x, ∂J/∂y])` for every window pixel in raster order
    /// whose template value and bilinear support are unclipped.
    #[inline]
    pub(super) fn for_each(&self, l: &Level, tmpl: &[f32], f: &mut impl FnMut(f32, [f32; 3])) {
        let [wa, wb, wc, wd] = self.weights;
        for (r, trow) in tmpl.chunks_exact(self.side).enumerate() {
            let i0 = self.origin + r * l.w;
            let top = &l.px[i0..i0 + self.side + 1];
            let bottom = &l.px[i0 + l.w..i0 + l.w + self.side + 1];
            for (c, &t) in trow.iter().enumerate() {
                let (a, b) = (top[c], top[c + 1]);
                let (cc, d) = (bottom[c], bottom[c + 1]);
                if clipped(t)
                    || clipped(a[VALUE])
                    || clipped(b[VALUE])
                    || clipped(cc[VALUE])
                    || clipped(d[VALUE])
                {
                    continue;
                }
                let s = |m: usize| wa * a[m] + wb * b[m] + wc * cc[m] + wd * d[m];
                f(t, [s(0), s(1), s(2)]);
            }
        }
    }
}

/// Shi-Tomasi score (smaller eigenvalue of the structure tensor over a `2r+1` box) of every
/// pixel of a level, via integral images.
pub(crate) fn min_eigen(l: &Level, r: usize) -> Vec<f32> {
    let (w, h) = (l.w, l.h);
    let mut ii = [
        vec![0.0f64; (w + 1) * (h + 1)],
        vec![0.0f64; (w + 1) * (h + 1)],
        vec![0.0f64; (w + 1) * (h + 1)],
    ];
    for y in 0..h {
        let mut row = [0.0f64; 3];
        for x in 0..w {
            let [_, gx, gy] = l.px[y * w + x].map(f64::from);
            row[0] += gx * gx;
            row[1] += gx * gy;
            row[2] += gy * gy;
            for c in 0..3 {
                ii[c][(y + 1) * (w + 1) + x + 1] = ii[c][y * (w + 1) + x + 1] + row[c];
            }
        }
    }
    let mut out = vec![0.0f32; w * h];
    for y in r..h.saturating_sub(r) {
        for x in r..w.saturating_sub(r) {
            let (x0, y0, x1, y1) = (x - r, y - r, x + r + 1, y + r + 1);
            let s = |c: usize| {
                ii[c][y1 * (w + 1) + x1] - ii[c][y0 * (w + 1) + x1] - ii[c][y1 * (w + 1) + x0]
                    + ii[c][y0 * (w + 1) + x0]
            };
            let (a, b, c) = (s(0), s(1), s(2));
            let tr = 0.5 * (a + c);
            let det = ((0.5 * (a - c)).powi(2) + b * b).sqrt();
            out[y * w + x] = (tr - det) as f32;
        }
    }
    out
}
