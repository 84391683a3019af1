//! A fisheye's image circle, found in the video itself.
//!
//! A circular or "full-frame" fisheye projects the scene into a disc; outside it the sensor
//! records black whatever the exposure. The tracks of the online fit never reach there, so the
//! vignetting model is unconstrained beyond the last track: DSO's polynomial extrapolates to
//! negative values and a spline wanders. The border itself is what the polynomial cannot
//! follow (its least-squares error on such a fall-off is several per cent).
//!
//! The circle is measured on the mean level each pixel recorded over the video (the camera
//! moves, so every pixel inside the disc sees many scene points), in recorded levels: a
//! threshold on linearised values would move with the fitted response's exponential gauge
//! (f → f^γ, V → V^γ). Outside the disc the mean stays at black. Along rays from the image
//! centre, coming in from the frame's edge, the first point where the level rises by
//! [`CIRCLE_FRACTION`] of the disc's local level above black is a border point (the local
//! level: the highest within a band just inside, since the scene's brightness differs from ray
//! to ray); a circle fitted to the points (algebraic fit of I. Kåsa, "A circle fitting
//! procedure and its error analysis", IEEE Trans. Instrum. Meas. 1976, then geometric
//! Gauss-Newton, with outliers dropped) gives the mask radius and the circle's centre. A dark
//! scene object in a corner gives points that do not lie on one circle, or too few of them,
//! and no circle is reported.
//!
//! The centre is less certain than the radius: on the tuning sweep (`photometric_sweep --
//! fisheye`) it is within 0.2–4.5 px of the truth (worst where only the corners are dark and
//! the scene above and below differ: in the border's tail a scene brighter by a factor ρ moves
//! a fixed fraction of the level outwards by the border's width times ln ρ), so with
//! `vignette_center: fixed` it is only a candidate, kept when its fit explains the samples
//! better than the image centre's (`vig_stage`). Border points at the border's steepest slope
//! instead of a fraction of the level were tried for the centre and scattered more (RMS 3–10
//! px on the tuning sweep against 1–2.4 px): the slope's peak follows the scene's own edges
//! inside the border.

use serde::{Deserialize, Serialize};

use super::super::joint::Obs;
use super::super::spline_center::kasa_circle;
use super::center::{CenterReport, r2_at};

/// The border: where the mean recorded level rises by this fraction of the disc's level above
/// black (as the offline `vignetting` job's `circle_fraction` bounds its mask).
pub(crate) const CIRCLE_FRACTION: f64 = 0.05;
/// Rays cast from the image centre.
const RAYS: usize = 720;
/// Least number of rays that must meet the border, in at least [`MIN_QUADRANTS`] quadrants
/// around the image centre (a full-frame fisheye shows it in the four corners only; an arc in
/// one corner leaves the centre and radius trading off).
const MIN_POINTS: usize = 24;
/// See [`MIN_POINTS`].
const MIN_QUADRANTS: usize = 3;
/// Largest RMS distance of the border points from the fitted circle, pixels.
const MAX_RMS_PX: f64 = 4.0;
/// Pixels farther than this beyond the circle must be dark ([`MIN_DARK_OUTSIDE`] of them).
const OUTSIDE_MARGIN_PX: f64 = 3.0;
/// See [`OUTSIDE_MARGIN_PX`].
const MIN_DARK_OUTSIDE: f64 = 0.95;
/// Step along the rays, pixels.
const STEP: f64 = 0.5;
/// Length of the band inside the dark crossing whose highest level is the disc's level, px.
const BAND: f64 = 48.0;
/// Least share of the image darker than the border threshold before rays are cast: a few
/// dark pixels in a corner are no circle.
const MIN_DARK_SHARE: f64 = 0.005;
/// Least share of the image beyond the fitted circle (and [`OUTSIDE_MARGIN_PX`]). Lower than
/// [`MIN_DARK_SHARE`]: once border points in three quadrants lie on one circle, a circle that
/// only just cuts the corners is still the lens's. A raised-cosine fisheye border recorded
/// through a gamma of 2.3 (`photometric_sweep -- fisheye-eval7`, case 2) crosses 5 % of the
/// level at r ≈ 190 px of a 200 px half diagonal: 48 border points within 0.10 px RMS, 0.4 %
/// of the frame outside. Refused at 0.5 %, the polynomial took the border and missed the
/// vignette by 0.047 RMSE (0.0022 with the circle found).
const MIN_OUTSIDE_SHARE: f64 = 0.001;

/// The image circle of a fisheye video.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct ImageCircle {
    /// Centre of the circle, pixels (the vignetting centre when a circle is found).
    pub center: [f64; 2],
    /// Radius, pixels: the vignetting model is masked (V = 0) beyond it.
    pub radius_px: f64,
    /// Border points the circle was fitted to (one per ray that met the border).
    pub border_points: usize,
    /// RMS distance of those points from the circle, pixels.
    pub rms_px: f64,
    /// Share of the image's pixels outside the circle.
    pub outside_share: f64,
}

/// Use the circle `c`: with `use_center` (`vignette_center` `auto` or `estimated`) its centre
/// becomes the vignetting centre (`center` says so, and each observation's `r2` is recomputed
/// around it from `pos`). Observations outside the circle get weight 0: they carry no signal,
/// and the model is masked there. Returns the mask radius around the model's centre, pixels:
/// the circle's radius, or with the centre kept where it was, the largest disc around it that
/// lies inside the circle.
pub(crate) fn apply(
    c: &ImageCircle,
    use_center: bool,
    center: &mut CenterReport,
    obs: &mut [Obs],
    pos: &[[f32; 2]],
    (w, h): (usize, usize),
) -> f64 {
    let rad = (w as f64 / 2.0).hypot(h as f64 / 2.0);
    let mask = if use_center {
        center.estimated = true;
        center.center = c.center;
        center.estimate = Some(c.center);
        center.reason = format!(
            "the centre of the image circle (fitted to {} border points, RMS {:.2} px)",
            c.border_points, c.rms_px
        );
        c.radius_px
    } else {
        let off = (c.center[0] - center.center[0]).hypot(c.center[1] - center.center[1]);
        (c.radius_px - off).max(0.5 * c.radius_px)
    };
    let limit = (mask / rad).powi(2) as f32;
    for (o, &p) in obs.iter_mut().zip(pos) {
        if use_center {
            o.r2 = r2_at(p, c.center, rad);
        }
        if o.r2 > limit {
            o.weight = 0.0;
        }
    }
    mask
}

/// Share of the image circle's radius inside which the response's gauge is chosen
/// ([`gauge_samples`]). Chosen on the fisheye sweep's tuning splits (`photometric_sweep --
/// fisheye 8`, `fisheye-eval 12`, `fisheye-eval2 12`; with the spline stage's response and
/// equal-area knots): 0.7 and 0.8 leave 20 of 32 sequences within every accuracy target, 0.9
/// 18, the whole circle 15. The unit test `online_calibration_chooses_the_gauge_inside_a_
/// fisheye_border` is a sequence where 0.8 still misses the gauge (α 0.70) and 0.7 does not.
pub(crate) const GAUGE_DISC: f64 = 0.7;

/// The samples of `obs` (at `pos`) with those beyond [`GAUGE_DISC`] × the circle's radius from
/// its centre weighted 0: what the gauge profile and the first fits see. They fit DSO's even
/// polynomial, which cannot follow the border, and across the border's fall-off the misfit
/// biases the exponential gauge (`f → f^γ`, `V → V^γ`): on the raised-cosine tuning split
/// `fisheye-eval` the gauge came out at α 0.51 and 2.64 from the truth on 2 of 11 sequences
/// with every sample inside the circle, on none with the border left out. The vignetting
/// stage then fits every sample inside the circle with the spline, in the gauge chosen here.
pub(crate) fn gauge_samples(c: &ImageCircle, obs: &[Obs], pos: &[[f32; 2]]) -> Vec<Obs> {
    let limit = GAUGE_DISC * c.radius_px;
    obs.iter()
        .zip(pos)
        .map(|(o, p)| {
            let d = (f64::from(p[0]) - c.center[0]).hypot(f64::from(p[1]) - c.center[1]);
            Obs {
                weight: if d > limit { 0.0 } else { o.weight },
                ..*o
            }
        })
        .collect()
}

/// The mean normalised level (`[0, 1]`) each pixel recorded over `frames`. Not the
/// brightest: a clipped peak hides where the border begins to fall.
pub(crate) fn mean_levels(frames: &[super::super::PhotoImage]) -> Vec<f32> {
    let Some(first) = frames.first() else {
        return Vec::new();
    };
    let n = first.data.len();
    let mut sum = vec![0u32; n];
    for f in frames.iter().filter(|f| f.data.len() == n) {
        for (s, &v) in sum.iter_mut().zip(&f.data) {
            *s = s.saturating_add(u32::from(v));
        }
    }
    let scale = 1.0 / (f64::from(first.max_level.max(1)) * frames.len().max(1) as f64);
    sum.iter().map(|&v| (f64::from(v) * scale) as f32).collect()
}

/// The image circle in `level` (the mean levels, `[0, 1]`, `w × h`); `None` when the video
/// shows none.
pub(crate) fn detect(level: &[f32], w: usize, h: usize) -> Option<ImageCircle> {
    if w < 16 || h < 16 || level.len() != w * h {
        return None;
    }
    // Recorded levels, not linearised ones: the fitted response's exponential gauge (f → f^γ,
    // V → V^γ) would move any threshold on linear values.
    let lev: Vec<f64> = level.iter().map(|&p| f64::from(p)).collect();
    let (cx, cy) = (w as f64 / 2.0, h as f64 / 2.0);
    let half_diag = cx.hypot(cy);
    // Reference: the bright end of the centre's levels (the centre region is inside any circle
    // this can report).
    let mut centre: Vec<f64> = Vec::new();
    for y in 0..h {
        for x in 0..w {
            if (x as f64 - cx).hypot(y as f64 - cy) <= 0.25 * half_diag {
                centre.push(lev[y * w + x]);
            }
        }
    }
    centre.sort_by(f64::total_cmp);
    let reference = *centre.get(centre.len() * 95 / 100)?;
    if reference.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return None;
    }
    let mut all = lev.clone();
    all.sort_by(f64::total_cmp);
    let black = all[all.len() / 200];
    // Outside an image circle the sensor records black; a video whose darkest pixels are not
    // near black has none (dark corners of strong vignetting are not a circle).
    if black > CIRCLE_FRACTION * reference {
        return None;
    }
    let threshold = black + CIRCLE_FRACTION * (reference - black);
    let dark_share =
        lev.iter().filter(|&&v| v < threshold).count() as f64 / lev.len().max(1) as f64;
    if dark_share < MIN_DARK_SHARE {
        return None;
    }
    // A 3 × 3 box filter against the noise of single pixels.
    let smooth = box3(&lev, w, h);
    let at = |x: f64, y: f64| -> f64 { bilinear(&smooth, w, h, x, y) };
    // Per ray, from the frame's edge inwards: where the level first reaches the global
    // threshold, the highest level within BAND px further in (the disc's level there: the
    // scene's brightness differs from ray to ray), and the outermost point where the level
    // reaches CIRCLE_FRACTION of that local level above black.
    let mut points: Vec<[f64; 2]> = Vec::new();
    for k in 0..RAYS {
        let a = std::f64::consts::TAU * k as f64 / RAYS as f64;
        let (dx, dy) = (a.cos(), a.sin());
        let tx = if dx.abs() > 1e-12 {
            (if dx > 0.0 { w as f64 - 1.0 - cx } else { cx }) / dx.abs()
        } else {
            f64::INFINITY
        };
        let ty = if dy.abs() > 1e-12 {
            (if dy > 0.0 { h as f64 - 1.0 - cy } else { cy }) / dy.abs()
        } else {
            f64::INFINITY
        };
        let t_edge = tx.min(ty);
        let t_min = 0.25 * half_diag;
        if t_edge <= t_min || at(cx + t_edge * dx, cy + t_edge * dy) >= threshold {
            continue; // the ray leaves the frame inside the circle
        }
        // Samples every STEP px from the edge inwards.
        let n = ((t_edge - t_min) / STEP) as usize;
        let profile: Vec<f64> = (0..=n)
            .map(|i| {
                let t = t_edge - STEP * i as f64;
                at(cx + t * dx, cy + t * dy)
            })
            .collect();
        let Some(first) = profile.iter().position(|&v| v >= threshold) else {
            continue;
        };
        let band_end = (first + (BAND / STEP) as usize).min(profile.len());
        let local = profile[first..band_end].iter().copied().fold(0.0, f64::max);
        let low = black + CIRCLE_FRACTION * (local - black);
        let Some(i) = profile.iter().position(|&v| v >= low).filter(|&i| i > 0) else {
            continue;
        };
        let (pa, pb) = (profile[i - 1], profile[i]);
        let f = ((low - pa) / (pb - pa).max(1e-12)).clamp(0.0, 1.0);
        let t = t_edge - STEP * (i as f64 - 1.0 + f);
        points.push([cx + t * dx, cy + t * dy]);
    }
    let quadrants = (0..4)
        .filter(|&q| {
            points.iter().any(|p| {
                let right = p[0] >= cx;
                let below = p[1] >= cy;
                usize::from(right) + 2 * usize::from(below) == q
            })
        })
        .count();
    if points.len() < MIN_POINTS || quadrants < MIN_QUADRANTS {
        return None;
    }
    let (center, radius, rms, used) = robust_circle(&points)?;
    let inside_frame = (0.0..w as f64).contains(&center[0]) && (0.0..h as f64).contains(&center[1]);
    if !inside_frame
        || used < MIN_POINTS
        || rms > MAX_RMS_PX
        || radius < 0.3 * half_diag
        || !radius.is_finite()
    {
        return None;
    }
    // Everything outside must be dark: a dark scene object (a black block in a corner) can
    // give border points on some circle, but the rest of that circle's outside is not black.
    let (mut outside, mut dark_outside) = (0usize, 0usize);
    for y in 0..h {
        for x in 0..w {
            if (x as f64 - center[0]).hypot(y as f64 - center[1]) > radius + OUTSIDE_MARGIN_PX {
                outside += 1;
                dark_outside += usize::from(smooth[y * w + x] < 2.0 * threshold);
            }
        }
    }
    if (outside as f64) < MIN_OUTSIDE_SHARE * (w * h) as f64
        || (dark_outside as f64) < MIN_DARK_OUTSIDE * outside as f64
    {
        return None;
    }
    Some(ImageCircle {
        center,
        radius_px: radius,
        border_points: used,
        rms_px: rms,
        outside_share: outside as f64 / (w * h) as f64,
    })
}

/// `v` box-filtered over 3 × 3 pixels (edges over what is inside the image).
pub(super) fn box3(v: &[f64], w: usize, h: usize) -> Vec<f64> {
    let mut out = vec![0.0; v.len()];
    for y in 0..h {
        for x in 0..w {
            let (mut s, mut n) = (0.0, 0.0);
            for yy in y.saturating_sub(1)..(y + 2).min(h) {
                for xx in x.saturating_sub(1)..(x + 2).min(w) {
                    s += v[yy * w + xx];
                    n += 1.0;
                }
            }
            out[y * w + x] = s / n;
        }
    }
    out
}

/// `v` (`w × h`, pixel centres at integers) at `(x, y)`, bilinear, clamped to the image.
pub(super) fn bilinear(v: &[f64], w: usize, h: usize, x: f64, y: f64) -> f64 {
    let x = x.clamp(0.0, (w - 1) as f64);
    let y = y.clamp(0.0, (h - 1) as f64);
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (fx, fy) = (x - x0 as f64, y - y0 as f64);
    let top = v[y0 * w + x0] * (1.0 - fx) + v[y0 * w + x1] * fx;
    let bottom = v[y1 * w + x0] * (1.0 - fx) + v[y1 * w + x1] * fx;
    top * (1.0 - fy) + bottom * fy
}

/// Circle through `points`: Kåsa's algebraic fit, then geometric Gauss-Newton, twice with the
/// points farther than 3 robust σ (and 1 px) from the circle dropped. Returns centre, radius,
/// RMS distance and the points kept.
fn robust_circle(points: &[[f64; 2]]) -> Option<([f64; 2], f64, f64, usize)> {
    let mut kept: Vec<[f64; 2]> = points.to_vec();
    let mut c = kasa_circle(&kept)?;
    for _ in 0..2 {
        c = geometric(&kept, c);
        let mut d: Vec<f64> = kept
            .iter()
            .map(|p| ((p[0] - c.0[0]).hypot(p[1] - c.0[1]) - c.1).abs())
            .collect();
        let mut sorted = d.clone();
        sorted.sort_by(f64::total_cmp);
        let mad = sorted[sorted.len() / 2] * 1.4826;
        let bound = (3.0 * mad).max(1.0);
        let before = kept.len();
        let mut i = 0;
        kept.retain(|_| {
            let ok = d[i] <= bound;
            i += 1;
            ok
        });
        d.clear();
        if kept.len() < 10 {
            return None;
        }
        if kept.len() == before {
            break;
        }
    }
    c = geometric(&kept, c);
    let ss: f64 = kept
        .iter()
        .map(|p| ((p[0] - c.0[0]).hypot(p[1] - c.0[1]) - c.1).powi(2))
        .sum();
    let rms = (ss / kept.len() as f64).sqrt();
    Some((c.0, c.1, rms, kept.len()))
}

/// Gauss-Newton on the geometric distances `|p − c| − r` from `start` (10 steps at most).
fn geometric(points: &[[f64; 2]], start: ([f64; 2], f64)) -> ([f64; 2], f64) {
    let (mut c, mut r) = start;
    for _ in 0..10 {
        let mut jtj = nalgebra::Matrix3::<f64>::zeros();
        let mut jtr = nalgebra::Vector3::<f64>::zeros();
        for p in points {
            let (dx, dy) = (p[0] - c[0], p[1] - c[1]);
            let d = dx.hypot(dy).max(1e-9);
            let res = d - r;
            let j = nalgebra::Vector3::new(-dx / d, -dy / d, -1.0);
            jtj += j * j.transpose();
            jtr += j * res;
        }
        let Some(ch) = jtj.cholesky() else {
            break;
        };
        let step = ch.solve(&-jtr);
        c = [c[0] + step[0], c[1] + step[1]];
        r += step[2];
        if step.norm() < 1e-6 {
            break;
        }
    }
    (c, r)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A mean-level image: 0.9 inside a circle (with a soft border), black outside, optional
    /// dark blob.
    fn disc(w: usize, h: usize, c: [f64; 2], r: f64, blob: Option<([f64; 2], f64)>) -> Vec<f32> {
        let mut out = Vec::with_capacity(w * h);
        for y in 0..h {
            for x in 0..w {
                let d = (x as f64 - c[0]).hypot(y as f64 - c[1]);
                let mut v = 0.9 / (1.0 + ((d - r) / 2.0).exp());
                if let Some((b, br)) = blob
                    && (x as f64 - b[0]).hypot(y as f64 - b[1]) < br
                {
                    v = 0.0;
                }
                out.push(v as f32);
            }
        }
        out
    }

    #[test]
    fn finds_an_off_centre_circle_cut_by_the_frame() {
        let (w, h) = (320, 240);
        for (c, r) in [
            ([163.0, 118.0], 150.0),
            ([155.0, 124.0], 175.0),
            ([160.0, 120.0], 110.0),
        ] {
            let level = disc(w, h, c, r, None);
            let got = detect(&level, w, h).unwrap_or_else(|| panic!("no circle {c:?} {r}"));
            assert!(
                (got.center[0] - c[0]).abs() < 0.5 && (got.center[1] - c[1]).abs() < 0.5,
                "{got:?} vs {c:?}"
            );
            // The border crosses 5 % of the disc's level at d − r = 2 ln(19) ≈ 5.9 px.
            assert!((got.radius_px - (r + 5.89)).abs() < 0.7, "{got:?} vs {r}");
            assert!(got.rms_px < 0.5);
        }
    }

    #[test]
    fn finds_a_circle_that_only_just_cuts_the_corners() {
        let (w, h) = (320, 240);
        // Radius 184 of a 200 px half diagonal: 0.28 % of the frame lies beyond the circle,
        // 48 rays meet the border in the four corners.
        let level = disc(w, h, [160.0, 120.0], 184.0, None);
        let got = detect(&level, w, h).expect("a circle cutting the corners");
        assert!((got.center[0] - 160.0).abs() < 0.5 && (got.center[1] - 120.0).abs() < 0.5);
        // Within 1.5 px: the border points all lie in the corners, where the 3 × 3 box filter
        // sees the frame's edge (189.0 px here against the 189.9 of the level's 5 % crossing).
        assert!((got.radius_px - (184.0 + 5.89)).abs() < 1.5, "{got:?}");
        assert!(
            got.outside_share > 0.001 && got.outside_share < 0.005,
            "{got:?}"
        );
        // Radius 188: 0.05 % beyond it (28 rays) is below MIN_OUTSIDE_SHARE, no circle.
        let level = disc(w, h, [160.0, 120.0], 188.0, None);
        assert!(detect(&level, w, h).is_none());
    }

    #[test]
    fn no_circle_in_a_frame_without_one_or_with_a_dark_object() {
        let (w, h) = (320, 240);
        // Circle larger than the frame's diagonal.
        let level = disc(w, h, [160.0, 120.0], 260.0, None);
        assert!(detect(&level, w, h).is_none());
        // A dark object in one corner of a frame without a circle.
        let level = disc(w, h, [160.0, 120.0], 400.0, Some(([300.0, 220.0], 40.0)));
        assert!(detect(&level, w, h).is_none());
        // Dark blocks in two corners of a frame without a circle (a Mondrian scene).
        let mut level = disc(w, h, [160.0, 120.0], 400.0, None);
        for y in 0..h {
            for x in 0..w {
                if (x < 70 && y < 50) || (x > 260 && y > 190) {
                    level[y * w + x] = 0.0;
                }
            }
        }
        assert!(detect(&level, w, h).is_none());
        // Strong vignetting without a circle: the corners are dark but not black.
        let vignetted: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f64 - 160.0, (i / w) as f64 - 120.0);
                (0.6 * (0.15f64).powf((x * x + y * y) / 200.0f64.powi(2))) as f32
            })
            .collect();
        assert!(detect(&vignetted, w, h).is_none());
        // A flat grey frame, and a black one.
        assert!(detect(&vec![0.5; w * h], w, h).is_none());
        assert!(detect(&vec![0.0; w * h], w, h).is_none());
    }
}
