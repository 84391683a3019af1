//! Dark elliptical blobs: the candidate circles.
//!
//! The image is thresholded at several grey levels spread between its dark and bright
//! percentiles (as OpenCV's `SimpleBlobDetector`), so that every circle is separated from the
//! card at some level even under uneven lighting or blur that merges neighbours at other
//! levels. At each level the dark connected components (8-connected) are measured by their
//! area moments and kept when they fill their moment ellipse (a circle seen in perspective is
//! an ellipse; letters, lines and merged pairs are not). Components found at two or more levels
//! at the same place are one blob; single-level ones are noise.

use std::collections::HashMap;

use rayon::prelude::*;

use crate::io::Gray;
use crate::union_find::root;

/// Threshold levels.
const LEVELS: usize = 9;
/// Least pixels of a component (a circle of about 4 px diameter).
const MIN_AREA: usize = 12;
/// Most blobs kept per level: beyond it the image is texture, not a target.
pub(super) const MAX_BLOBS: usize = 20_000;
/// Accepted range of area / (π·a·b) for the moment ellipse with semi-axes a, b.
const FILL: (f64, f64) = (0.82, 1.12);
/// Least minor / major axis ratio (a circle at 80° tilt).
const MIN_AXIS_RATIO: f64 = 0.15;

/// A dark blob: its area centre and second moments at one threshold level.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Blob {
    /// Area centre, pixels.
    pub c: [f64; 2],
    /// Covariance of the pixels `[xx, xy, yy]` (a filled ellipse of semi-axes a, b has
    /// eigenvalues a²/4, b²/4).
    pub cov: [f64; 3],
    /// Pixels.
    pub area: f64,
    /// Levels at which it was found.
    pub repeats: usize,
}

impl Blob {
    /// Semi-axes `(a, b)`, `a ≥ b`, of the moment ellipse.
    pub fn axes(&self) -> (f64, f64) {
        let [xx, xy, yy] = self.cov;
        let m = (xx + yy) / 2.0;
        let d = (((xx - yy) / 2.0).powi(2) + xy * xy).sqrt();
        (2.0 * (m + d).max(0.0).sqrt(), 2.0 * (m - d).max(0.0).sqrt())
    }

    /// Squared distance of `p` from the centre in the blob's ellipse metric (1 on its edge).
    pub fn rho2(&self, p: [f64; 2]) -> f64 {
        let [xx, xy, yy] = self.cov.map(|v| 4.0 * v);
        let det = xx * yy - xy * xy;
        if det <= 0.0 {
            return f64::INFINITY;
        }
        let (dx, dy) = (p[0] - self.c[0], p[1] - self.c[1]);
        (yy * dx * dx - 2.0 * xy * dx * dy + xx * dy * dy) / det
    }
}

/// Accumulated moments of one component.
#[derive(Default)]
struct Moments {
    n: usize,
    sx: f64,
    sy: f64,
    sxx: f64,
    sxy: f64,
    syy: f64,
    border: bool,
}

impl Moments {
    fn blob(&self) -> Option<Blob> {
        if self.border || self.n < MIN_AREA {
            return None;
        }
        let n = self.n as f64;
        let c = [self.sx / n, self.sy / n];
        // Pixels are unit squares: their own second moment (1/12) adds to the spread.
        let cov = [
            self.sxx / n - c[0] * c[0] + 1.0 / 12.0,
            self.sxy / n - c[0] * c[1],
            self.syy / n - c[1] * c[1] + 1.0 / 12.0,
        ];
        let b = Blob {
            c,
            cov,
            area: n,
            repeats: 1,
        };
        let (a, bb) = b.axes();
        let fill = n / (std::f64::consts::PI * a * bb);
        (bb > 0.0 && bb / a >= MIN_AXIS_RATIO && (FILL.0..=FILL.1).contains(&fill)).then_some(b)
    }
}

/// Grey level below which `frac` of the pixels lie.
fn percentile(hist: &[usize; 256], total: usize, frac: f64) -> u8 {
    let target = (total as f64 * frac) as usize;
    let mut acc = 0;
    for (v, &n) in hist.iter().enumerate() {
        acc += n;
        if acc > target {
            return v as u8;
        }
    }
    255
}

/// Dark 8-connected components below `t` that look like filled ellipses, in the raster order
/// of their first pixel; `None` when there are more than [`MAX_BLOBS`].
///
/// Labelled by runs: each row's dark runs are joined (union-find) to the runs of the row above
/// that touch them, and a component's moments are summed in closed form per run. Every sum is
/// of integers below 2⁵³, so the result is exactly that of a pixel-by-pixel flood fill, several
/// times faster.
fn components(img: &Gray, t: u8) -> Option<Vec<Blob>> {
    let (w, h) = (img.width as usize, img.height as usize);
    // Runs `[x0, x1)` of row `y`, each with its union-find node (same index).
    let mut runs: Vec<(usize, usize, usize)> = Vec::new();
    let mut parent: Vec<usize> = Vec::new();
    let mut prev = 0..0;
    for y in 0..h {
        let row = &img.data[y * w..(y + 1) * w];
        let first = runs.len();
        let mut j = prev.start;
        let mut x = 0;
        while x < w {
            if row[x] >= t {
                x += 1;
                continue;
            }
            let x0 = x;
            while x < w && row[x] < t {
                x += 1;
            }
            let me = runs.len();
            runs.push((y, x0, x));
            parent.push(me);
            // Runs above touch this one (8-connected) when they overlap [x0 − 1, x].
            while j < prev.end && runs[j].2 < x0 {
                j += 1;
            }
            let mut k = j;
            while k < prev.end && runs[k].1 <= x {
                let (a, b) = (root(&mut parent, k), root(&mut parent, me));
                if a != b {
                    // The older run's root stays: roots are the first run of a component.
                    let (lo, hi) = (a.min(b), a.max(b));
                    parent[hi] = lo;
                }
                k += 1;
            }
        }
        prev = first..runs.len();
    }
    // Components in the order of their first run (raster order of the first pixel).
    let mut slot: Vec<usize> = vec![usize::MAX; runs.len()];
    let mut moments: Vec<Moments> = Vec::new();
    for (r, &(y, x0, x1)) in runs.iter().enumerate() {
        let top = root(&mut parent, r);
        if slot[top] == usize::MAX {
            slot[top] = moments.len();
            moments.push(Moments::default());
        }
        let m = &mut moments[slot[top]];
        let (len, y) = (x1 - x0, y as u64);
        // Σx and Σx² over x0..x1 in closed form.
        let s1 = |n: u64| n * (n + 1) / 2;
        let s2 = |n: u64| n * (n + 1) * (2 * n + 1) / 6;
        let (a, b) = (x0 as u64, x1 as u64);
        let sx = s1(b - 1) - if a > 0 { s1(a - 1) } else { 0 };
        let sxx = s2(b - 1) - if a > 0 { s2(a - 1) } else { 0 };
        m.n += len;
        m.sx += sx as f64;
        m.sy += (y * len as u64) as f64;
        m.sxx += sxx as f64;
        m.sxy += (y * sx) as f64;
        m.syy += (y * y * len as u64) as f64;
        m.border |= x0 == 0 || x1 == w || y == 0 || y as usize + 1 == h;
    }
    let mut out = Vec::new();
    for m in &moments {
        if let Some(b) = m.blob() {
            if out.len() >= MAX_BLOBS {
                return None;
            }
            out.push(b);
        }
    }
    Some(out)
}

/// What the blob stage found.
pub(super) struct BlobScan {
    /// Blobs seen at two or more levels, each with its moments at the middle one of them.
    pub blobs: Vec<Blob>,
    /// Spread between the dark and bright percentiles (0 for a flat image).
    pub contrast: f64,
    /// The image had more than [`MAX_BLOBS`] blobs at some level.
    pub too_many: bool,
}

/// Finds the dark elliptical blobs of `img` (see the module docs). Blobs need the image's
/// dark-to-bright spread to reach `min_contrast`.
pub(super) fn find_blobs(img: &Gray, min_contrast: f64) -> BlobScan {
    let (w, h) = (img.width as usize, img.height as usize);
    let mut hist = [0usize; 256];
    for &v in &img.data {
        hist[v as usize] += 1;
    }
    let lo = f64::from(percentile(&hist, w * h, 0.01));
    let hi = f64::from(percentile(&hist, w * h, 0.99));
    let contrast = hi - lo;
    let mut scan = BlobScan {
        blobs: Vec::new(),
        contrast,
        too_many: false,
    };
    if contrast < min_contrast.max(1.0) {
        return scan;
    }
    // The levels are independent: label them in parallel, merge in order.
    let levels: Vec<Option<Vec<Blob>>> = (0..LEVELS)
        .into_par_iter()
        .map(|k| {
            let t = lo + contrast * (k + 1) as f64 / (LEVELS + 1) as f64;
            components(img, t.round() as u8)
        })
        .collect();
    // Groups of the same blob across levels: members, bucketed by their first centre.
    let mut groups: Vec<(Vec<Blob>, usize)> = Vec::new();
    let mut buckets: HashMap<(i64, i64), Vec<usize>> = HashMap::new();
    const CELL: f64 = 8.0;
    let key = |p: [f64; 2]| ((p[0] / CELL).floor() as i64, (p[1] / CELL).floor() as i64);
    for (k, level) in levels.into_iter().enumerate() {
        let Some(level_blobs) = level else {
            scan.too_many = true;
            return scan;
        };
        for b in &level_blobs {
            let (_, minor) = b.axes();
            let tol = (0.5 * minor).min(CELL);
            let (kx, ky) = key(b.c);
            let mut found = None;
            'search: for gx in kx - 1..=kx + 1 {
                for gy in ky - 1..=ky + 1 {
                    for &g in buckets.get(&(gx, gy)).into_iter().flatten() {
                        let c = groups[g].0[0].c;
                        if (c[0] - b.c[0]).hypot(c[1] - b.c[1]) <= tol {
                            found = Some(g);
                            break 'search;
                        }
                    }
                }
            }
            match found {
                // One member per level: the first one found at this level wins.
                Some(g) if groups[g].1 < k => {
                    groups[g].0.push(*b);
                    groups[g].1 = k;
                }
                Some(_) => {}
                None => {
                    buckets.entry(key(b.c)).or_default().push(groups.len());
                    groups.push((vec![*b], k));
                }
            }
        }
    }
    scan.blobs = groups
        .into_iter()
        .filter(|(g, _)| g.len() >= 2)
        .map(|(g, _)| Blob {
            repeats: g.len(),
            ..g[g.len() / 2]
        })
        .collect();
    scan
}

/// The pixel-by-pixel flood fill that [`components`] replaces: the reference of its test.
#[cfg(test)]
fn components_flood(img: &Gray, t: u8) -> Option<Vec<Blob>> {
    let (w, h) = (img.width as usize, img.height as usize);
    let mut seen = vec![false; w * h];
    let mut out = Vec::new();
    let mut stack = Vec::new();
    for (start, &v) in img.data.iter().enumerate() {
        if v >= t || seen[start] {
            continue;
        }
        seen[start] = true;
        stack.push(start);
        let mut m = Moments::default();
        // Each pixel is pushed at most once (it is labelled when pushed): bounded by w·h.
        while let Some(k) = stack.pop() {
            let (x, y) = (k % w, k / w);
            let (fx, fy) = (x as f64, y as f64);
            m.n += 1;
            m.sx += fx;
            m.sy += fy;
            m.sxx += fx * fx;
            m.sxy += fx * fy;
            m.syy += fy * fy;
            m.border |= x == 0 || y == 0 || x + 1 == w || y + 1 == h;
            for dy in -1i64..=1 {
                for dx in -1i64..=1 {
                    let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                    if nx < 0 || ny < 0 || nx >= w as i64 || ny >= h as i64 {
                        continue;
                    }
                    let q = ny as usize * w + nx as usize;
                    if img.data[q] < t && !seen[q] {
                        seen[q] = true;
                        stack.push(q);
                    }
                }
            }
        }
        if let Some(b) = m.blob() {
            if out.len() >= MAX_BLOBS {
                return None;
            }
            out.push(b);
        }
    }
    Some(out)
}

#[cfg(test)]
mod run_tests {
    use super::*;

    /// Random blobs, lines, noise and border-touching shapes at several thresholds: the runs
    /// labelling gives exactly the flood fill's components, in the same order.
    #[test]
    fn run_labelling_equals_the_flood_fill() {
        let (w, h) = (211u32, 157u32);
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        };
        let mut data = vec![220u8; (w * h) as usize];
        for _ in 0..60 {
            let (cx, cy) = (
                (next() % u64::from(w)) as f64,
                (next() % u64::from(h)) as f64,
            );
            let (a, b) = (2.0 + (next() % 12) as f64, 2.0 + (next() % 9) as f64);
            let grey = (next() % 160) as u8;
            for y in 0..h {
                for x in 0..w {
                    let (dx, dy) = ((f64::from(x) - cx) / a, (f64::from(y) - cy) / b);
                    if dx * dx + dy * dy <= 1.0 {
                        data[(y * w + x) as usize] = grey;
                    }
                }
            }
        }
        for v in data.iter_mut() {
            if next() % 50 == 0 {
                *v = (next() % 256) as u8;
            }
        }
        let img = Gray {
            width: w,
            height: h,
            data,
        };
        let mut most = 0;
        for t in [30u8, 90, 150, 200, 230] {
            let runs = components(&img, t);
            assert_eq!(runs, components_flood(&img, t), "threshold {t}");
            most = most.max(runs.map_or(0, |v| v.len()));
        }
        assert!(most >= 5, "the scene should hold ellipses: {most}");
    }
}
