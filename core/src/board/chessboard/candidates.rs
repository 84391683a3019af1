//! Corner candidates: a Hessian saddle response, non-maximum suppression, and an X-junction
//! test on a circle around each maximum.
//!
//! Response. At an X-junction of a chessboard the smoothed image is locally a saddle,
//! `I ≈ a + b·(u·d)(v·d)` for the two edge directions u, v, whose Hessian has a strongly
//! negative determinant `−b²(1 − (u·v)²)`; along a straight edge the determinant vanishes and on
//! a blob it is positive. `R = max(0, −det H)` of the image smoothed at scale σ is therefore a
//! cheap, rotation-invariant saddle detector (the Hessian-determinant response of Beaudet 1978
//! used for chessboards by Lucchese & Mitra, "Using saddle points for subpixel feature
//! detection in camera calibration targets", APCCAS 2002, and Chen & Zhang, "Accurate
//! calibration for camera-projector measurement based on the Hessian matrix", 2005). Blur only
//! rescales it (the saddle survives any point-symmetric blur), which is why it keeps working on
//! motion-blurred and defocused images where threshold-and-quadrilateral detectors lose the
//! squares.
//!
//! X test. An L-corner (the corner of a single square, e.g. on the outline of the board) is a
//! saddle of the smoothed image too, with a quarter of the response. Like ChESS (Bennett &
//! Lasenby, "ChESS – Quick and robust detection of chess-board features", CVIU 118, 2014), we
//! sample a circle around the candidate and require exactly four alternating bright/dark
//! sectors whose boundaries come in two nearly opposite pairs: the two lines through an
//! X-junction. The sector boundaries give the edge directions used to seed the grid.

use std::cell::OnceCell;
use std::sync::OnceLock;

use crate::board::filter::ImageF;

/// Radius of the X-junction circle test, pixels.
pub const X_RADIUS: f64 = 4.0;
/// Larger radius tried when the first fails (blurred corners, large squares).
pub const X_RADIUS_WIDE: f64 = 6.5;

/// The corner candidates: the response maxima, strongest first, each with the edge lines of
/// its X-junction test (see the module docs). The test is run on first use only: the grid
/// search touches a few dozen of the (up to thousands of) maxima.
pub struct Candidates<'a> {
    s: &'a ImageF,
    min_contrast: f64,
    /// Positions (pixel centres at integers), sub-pixel from a parabola through the response.
    pub points: Vec<[f64; 2]>,
    lines: Vec<OnceCell<Option<[f64; 2]>>>,
}

impl<'a> Candidates<'a> {
    pub fn new(s: &'a ImageF, points: Vec<[f64; 2]>, min_contrast: f64) -> Self {
        let lines = points.iter().map(|_| OnceCell::new()).collect();
        Self {
            s,
            min_contrast,
            points,
            lines,
        }
    }

    /// Number of maxima.
    pub fn len(&self) -> usize {
        self.points.len()
    }

    /// Position of maximum `k`.
    #[inline]
    pub fn p(&self, k: usize) -> [f64; 2] {
        self.points[k]
    }

    /// Directions (radians, modulo π) of the two edge lines through maximum `k`, or `None`
    /// when it is not an X-junction (tested at [`X_RADIUS`], then [`X_RADIUS_WIDE`]).
    pub fn lines(&self, k: usize) -> Option<[f64; 2]> {
        *self.lines[k].get_or_init(|| {
            let p = self.points[k];
            x_junction(self.s, p, X_RADIUS, self.min_contrast)
                .or_else(|| x_junction(self.s, p, X_RADIUS_WIDE, self.min_contrast))
        })
    }
}

/// `max(0, −det H)` by central differences of the smoothed image; zero on a 2-pixel border.
pub fn saddle_response(s: &ImageF) -> ImageF {
    let (w, h) = (s.w, s.h);
    let mut r = ImageF::filled(w, h, 0.0);
    if w < 5 || h < 5 {
        return r;
    }
    let d = &s.data;
    let n = w - 4;
    for y in 2..h - 2 {
        // Equal-length slices of the three rows (centre column x = 2 + i) so that the loop
        // has no bounds checks and vectorises.
        let row = |yy: usize, dx: usize| &d[yy * w + 1 + dx..yy * w + 1 + dx + n];
        let (ul, ur) = (row(y - 1, 0), row(y - 1, 2));
        let (ml, mc, mr) = (row(y, 0), row(y, 1), row(y, 2));
        let (dl, dc, dr) = (row(y + 1, 0), row(y + 1, 1), row(y + 1, 2));
        let uc = row(y - 1, 1);
        let out = &mut r.data[y * w + 2..y * w + 2 + n];
        for i in 0..n {
            let ixx = mr[i] - 2.0 * mc[i] + ml[i];
            let iyy = dc[i] - 2.0 * mc[i] + uc[i];
            let ixy = 0.25 * (dr[i] - dl[i] - ur[i] + ul[i]);
            let v = ixy * ixy - ixx * iyy;
            out[i] = v.max(0.0);
        }
    }
    r
}

/// Local maxima of `r` in a 5×5 window above `threshold`, strongest first, at most `max`.
pub fn local_maxima(r: &ImageF, threshold: f32, max: usize) -> Vec<([f64; 2], f32)> {
    let (w, h) = (r.w, r.h);
    let mut out = Vec::new();
    if w < 7 || h < 7 {
        return out;
    }
    let d = &r.data;
    let n = w - 6;
    let mut flag = vec![false; n];
    for y in 3..h - 3 {
        // Cheap rejections first, branch-free over the row (same tie rule as the window test
        // below): most pixels above the threshold lie on the flank of a peak and have a
        // larger direct neighbour.
        let row = |yy: usize, dx: usize| &d[yy * w + 2 + dx..yy * w + 2 + dx + n];
        let (l, c, rr) = (row(y, 0), row(y, 1), row(y, 2));
        let (up, dn) = (row(y - 1, 1), row(y + 1, 1));
        for i in 0..n {
            let v = c[i];
            flag[i] = (v > threshold) & (l[i] < v) & (rr[i] <= v) & (up[i] < v) & (dn[i] <= v);
        }
        for x in 3..w - 3 {
            if !flag[x - 3] {
                continue;
            }
            let v = d[y * w + x];
            let c = y * w + x;
            let mut is_max = true;
            'win: for dy in -2isize..=2 {
                let row = (y as isize + dy) as usize * w;
                for dx in -2isize..=2 {
                    if dx == 0 && dy == 0 {
                        continue;
                    }
                    let u = d[row + (x as isize + dx) as usize];
                    // Ties go to the first pixel in raster order, so a plateau yields one maximum.
                    if u > v || (u == v && (dy < 0 || (dy == 0 && dx < 0))) {
                        is_max = false;
                        break 'win;
                    }
                }
            }
            if !is_max {
                continue;
            }
            // Sub-pixel peak from a parabola per axis (only a start for the grid search).
            let px = parabola(d[c - 1], v, d[c + 1]);
            let py = parabola(d[c - w], v, d[c + w]);
            out.push(([x as f64 + px, y as f64 + py], v));
        }
    }
    out.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0[1].total_cmp(&b.0[1])));
    out.truncate(max);
    out
}

fn parabola(a: f32, b: f32, c: f32) -> f64 {
    let den = a - 2.0 * b + c;
    if den.abs() < 1e-12 {
        0.0
    } else {
        f64::from((0.5 * (a - c) / den).clamp(-0.5, 0.5))
    }
}

/// Samples on the circle of the X test.
const CIRCLE_SAMPLES: usize = 32;

/// `(sin, cos)` of the sample angles of the X test.
fn circle() -> &'static [(f64, f64); CIRCLE_SAMPLES] {
    static TABLE: OnceLock<[(f64, f64); CIRCLE_SAMPLES]> = OnceLock::new();
    TABLE.get_or_init(|| {
        let step = std::f64::consts::TAU / CIRCLE_SAMPLES as f64;
        std::array::from_fn(|k| (k as f64 * step).sin_cos())
    })
}

/// The X-junction test on a circle of radius `radius` around `p` (see the module docs).
/// Returns the two edge-line directions (radians modulo π), or `None` when the neighbourhood
/// is not an X-junction with at least `min_contrast` grey levels between the sectors.
pub fn x_junction(s: &ImageF, p: [f64; 2], radius: f64, min_contrast: f64) -> Option<[f64; 2]> {
    if !s.contains(p[0], p[1], radius + 1.0) {
        return None;
    }
    let mut v = [0.0f64; CIRCLE_SAMPLES];
    let step = std::f64::consts::TAU / CIRCLE_SAMPLES as f64;
    for (vk, &(sn, cs)) in v.iter_mut().zip(circle()) {
        // Inside: `contains(p, radius + 1)` above.
        *vk = f64::from(s.bilinear_inside(p[0] + radius * cs, p[1] + radius * sn));
    }
    let (lo, hi) = v
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), &x| (a.min(x), b.max(x)));
    if hi - lo < min_contrast {
        return None;
    }
    let mid = 0.5 * (hi + lo);
    let band = 0.1 * (hi - lo);
    let label = |x: f64| -> i8 {
        if x > mid + band {
            1
        } else if x < mid - band {
            -1
        } else {
            0
        }
    };
    // Start from a labelled sample, walk once around, record transitions between labels.
    let start = (0..CIRCLE_SAMPLES).find(|&k| label(v[k]) != 0)?;
    let mut last = start;
    let mut transitions = [0.0f64; 4];
    let mut nt = 0;
    for t in 1..=CIRCLE_SAMPLES {
        let k = (start + t) % CIRCLE_SAMPLES;
        let l = label(v[k]);
        if l == 0 {
            continue;
        }
        if l != label(v[last]) {
            if nt == 4 {
                return None;
            }
            // Crossing of `mid` between sample `last` and sample `k`, linearly.
            let gap = (k + CIRCLE_SAMPLES - last) % CIRCLE_SAMPLES;
            let mut angle = last as f64 * step;
            for g in 0..gap {
                let a = v[(last + g) % CIRCLE_SAMPLES];
                let b = v[(last + g + 1) % CIRCLE_SAMPLES];
                if (a - mid) * (b - mid) <= 0.0 && a != b {
                    angle = (last + g) as f64 * step + step * (a - mid) / (a - b);
                    break;
                }
            }
            transitions[nt] = angle.rem_euclid(std::f64::consts::TAU);
            nt += 1;
        }
        last = k;
    }
    if nt != 4 {
        return None;
    }
    transitions.sort_by(f64::total_cmp);
    let pi = std::f64::consts::PI;
    // Opposite boundaries of the same line must be nearly π apart.
    let mut lines = [0.0; 2];
    for (i, line) in lines.iter_mut().enumerate() {
        let (a, b) = (transitions[i], transitions[i + 2]);
        if ((b - a) - pi).abs() > 0.6 {
            return None;
        }
        *line = mean_angle_mod_pi(a, b - pi);
    }
    if angle_diff_mod_pi(lines[0], lines[1]) < 0.25 {
        return None;
    }
    Some(lines)
}

/// The mean of two directions modulo π.
fn mean_angle_mod_pi(a: f64, b: f64) -> f64 {
    // Double the angles to make them periodic in 2π, average the unit vectors, halve.
    let (s, c) = (
        (2.0 * a).sin() + (2.0 * b).sin(),
        (2.0 * a).cos() + (2.0 * b).cos(),
    );
    (0.5 * s.atan2(c)).rem_euclid(std::f64::consts::PI)
}

/// Unsigned difference of two directions modulo π, in [0, π/2].
pub fn angle_diff_mod_pi(a: f64, b: f64) -> f64 {
    let pi = std::f64::consts::PI;
    let d = (a - b).rem_euclid(pi);
    d.min(pi - d)
}
