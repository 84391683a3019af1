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

use super::filter::ImageF;

/// A corner candidate.
#[derive(Clone, Debug)]
pub struct Candidate {
    /// Position (pixel centres at integers), sub-pixel from a parabola through the response.
    pub p: [f64; 2],
    /// Directions (radians, modulo π) of the two edge lines through the corner.
    pub lines: [f64; 2],
}

/// `max(0, −det H)` by central differences of the smoothed image; zero on a 2-pixel border.
pub fn saddle_response(s: &ImageF) -> ImageF {
    let (w, h) = (s.w, s.h);
    let mut r = ImageF::filled(w, h, 0.0);
    if w < 5 || h < 5 {
        return r;
    }
    let d = &s.data;
    for y in 2..h - 2 {
        let row = y * w;
        for x in 2..w - 2 {
            let c = row + x;
            let ixx = d[c + 1] - 2.0 * d[c] + d[c - 1];
            let iyy = d[c + w] - 2.0 * d[c] + d[c - w];
            let ixy = 0.25 * (d[c + w + 1] - d[c + w - 1] - d[c - w + 1] + d[c - w - 1]);
            let v = ixy * ixy - ixx * iyy;
            r.data[c] = v.max(0.0);
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
    for y in 3..h - 3 {
        for x in 3..w - 3 {
            let v = d[y * w + x];
            if v <= threshold {
                continue;
            }
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
            let c = y * w + x;
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

/// The X-junction test on a circle of radius `radius` around `p` (see the module docs).
/// Returns the two edge-line directions (radians modulo π), or `None` when the neighbourhood
/// is not an X-junction with at least `min_contrast` grey levels between the sectors.
pub fn x_junction(s: &ImageF, p: [f64; 2], radius: f64, min_contrast: f64) -> Option<[f64; 2]> {
    if !s.contains(p[0], p[1], radius + 1.0) {
        return None;
    }
    let mut v = [0.0f64; CIRCLE_SAMPLES];
    let step = std::f64::consts::TAU / CIRCLE_SAMPLES as f64;
    for (k, vk) in v.iter_mut().enumerate() {
        let (sn, cs) = (k as f64 * step).sin_cos();
        *vk = f64::from(s.bilinear(p[0] + radius * cs, p[1] + radius * sn));
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
    let mut transitions: Vec<f64> = Vec::with_capacity(4);
    for t in 1..=CIRCLE_SAMPLES {
        let k = (start + t) % CIRCLE_SAMPLES;
        let l = label(v[k]);
        if l == 0 {
            continue;
        }
        if l != label(v[last]) {
            if transitions.len() == 4 {
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
            transitions.push(angle.rem_euclid(std::f64::consts::TAU));
        }
        last = k;
    }
    if transitions.len() != 4 {
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
