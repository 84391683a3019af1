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

/// Dark 8-connected components below `t` that look like filled ellipses; `None` when there
/// are more than [`MAX_BLOBS`].
fn components(img: &Gray, t: u8) -> Option<Vec<Blob>> {
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
