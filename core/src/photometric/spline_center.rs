//! The optical centre of a radial falloff from its iso-intensity contours.
//!
//! The spline model ([`super::spline`]) needs the centre of the radial profile before it can
//! bin the flats by radius. The centroid of the region above half the maximum
//! ([`super::spline::centroid_center`]) is only right when that region is a whole disc; when the
//! frame clips it (a fisheye whose image circle is wider than the sensor, so it shows only in
//! the corners) the centroid is pulled towards the image centre: 2.3 px off on the
//! `fisheye_sweep` case with a 333 px circle in a 512 px frame, which put the map's border
//! 0.006 RMSE off. An iso-intensity contour of a radial falloff is a circle around the centre
//! whatever part of it the frame shows, so the centre is fitted to the contour's crossings
//! instead: algebraic circle fits (I. Kåsa, "A circle fitting procedure and its error analysis",
//! IEEE Trans. Instrum. Meas. 1976) at several levels, the median of their centres.

use super::PhotoImage;
use crate::stats::median;

/// Levels, as fractions of the smoothed maximum, whose contours are fitted.
const LEVELS: [f64; 5] = [0.3, 0.4, 0.5, 0.6, 0.7];

/// Fewest contour crossings for a level's circle to count.
const MIN_POINTS: usize = 60;

/// Half side of the box filter that tames pixel noise before the crossings are found.
const SMOOTH: usize = 2;

/// The centre of the radial falloff of `im` (the least saturated flat) from circle fits to its
/// contours; `None` when no level gives a usable circle (then the caller keeps the centroid).
pub(crate) fn contour_center(im: &PhotoImage) -> Option<[f64; 2]> {
    let (w, h) = (im.width, im.height);
    if w < 4 * SMOOTH + 4 || h < 4 * SMOOTH + 4 {
        return None;
    }
    let s = box_smooth(im);
    let max = s.iter().copied().fold(0.0f64, f64::max);
    if max <= 0.0 {
        return None;
    }
    let mut xs = Vec::new();
    let mut ys = Vec::new();
    for f in LEVELS {
        let pts = crossings(&s, w, h, f * max);
        if pts.len() < MIN_POINTS {
            continue;
        }
        if let Some((c, _)) = kasa_circle(&pts)
            && c[0].is_finite()
            && c[1].is_finite()
            && c[0].abs() < 4.0 * w as f64
            && c[1].abs() < 4.0 * h as f64
        {
            xs.push(c[0]);
            ys.push(c[1]);
        }
    }
    if xs.is_empty() {
        return None;
    }
    Some([median(xs), median(ys)])
}

/// `(2·SMOOTH + 1)²` box mean (via a summed-area table); the border keeps the raw values'
/// nearest fully covered mean.
fn box_smooth(im: &PhotoImage) -> Vec<f64> {
    let (w, h) = (im.width, im.height);
    let mut ii = vec![0.0f64; (w + 1) * (h + 1)];
    for y in 0..h {
        let mut row = 0.0;
        for x in 0..w {
            row += f64::from(im.data[y * w + x]);
            ii[(y + 1) * (w + 1) + x + 1] = ii[y * (w + 1) + x + 1] + row;
        }
    }
    let r = SMOOTH;
    let mut out = vec![0.0; w * h];
    for y in 0..h {
        let yc = y.clamp(r, h - 1 - r);
        for x in 0..w {
            let xc = x.clamp(r, w - 1 - r);
            let (x0, y0, x1, y1) = (xc - r, yc - r, xc + r + 1, yc + r + 1);
            let sum = ii[y1 * (w + 1) + x1] - ii[y0 * (w + 1) + x1] - ii[y1 * (w + 1) + x0]
                + ii[y0 * (w + 1) + x0];
            out[y * w + x] = sum / ((2 * r + 1) * (2 * r + 1)) as f64;
        }
    }
    out
}

/// Sub-pixel points where `s` crosses `thr` between horizontal and vertical neighbours (linear
/// interpolation), away from the frame's smoothed border.
fn crossings(s: &[f64], w: usize, h: usize, thr: f64) -> Vec<[f64; 2]> {
    let mut pts = Vec::new();
    let m = SMOOTH + 1;
    for y in m..h - m {
        for x in m..w - m {
            let a = s[y * w + x];
            for (b, dx, dy) in [(s[y * w + x + 1], 1.0, 0.0), (s[(y + 1) * w + x], 0.0, 1.0)] {
                if (a - thr) * (b - thr) < 0.0 {
                    let t = (thr - a) / (b - a);
                    pts.push([x as f64 + t * dx, y as f64 + t * dy]);
                }
            }
        }
    }
    pts
}

/// Kåsa's algebraic circle fit: least squares of `x² + y² + D·x + E·y + F = 0`, centre
/// `(−D/2, −E/2)` and radius. Coordinates are centred on the points' mean for conditioning.
/// Also the start of the online fit's image-circle fit (`online/circle.rs`).
pub(crate) fn kasa_circle(pts: &[[f64; 2]]) -> Option<([f64; 2], f64)> {
    let n = pts.len() as f64;
    let mx = pts.iter().map(|p| p[0]).sum::<f64>() / n;
    let my = pts.iter().map(|p| p[1]).sum::<f64>() / n;
    let mut a = nalgebra::Matrix3::<f64>::zeros();
    let mut b = nalgebra::Vector3::<f64>::zeros();
    for p in pts {
        let (x, y) = (p[0] - mx, p[1] - my);
        let row = nalgebra::Vector3::new(x, y, 1.0);
        a += row * row.transpose();
        b -= row * (x * x + y * y);
    }
    let sol = a.lu().solve(&b)?;
    let (cx, cy) = (-sol[0] / 2.0, -sol[1] / 2.0);
    let r2 = cx * cx + cy * cy - sol[2];
    (r2 > 0.0 && r2.is_finite()).then(|| ([mx + cx, my + cy], r2.sqrt()))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A falloff whose contours the frame clips on every side: the centroid is pulled to the
    /// image centre, the contour fit is not.
    #[test]
    fn clipped_falloff_centre_is_found() {
        let (w, h) = (300usize, 240usize);
        let (cx, cy) = (163.0, 111.0);
        let data = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f64, (i / w) as f64);
                let d = (x - cx).hypot(y - cy);
                let v = (0.6 * d / 200.0).cos().powi(4) / (1.0 + ((d - 180.0) / 8.0).exp());
                (v * 250.0).round() as u16
            })
            .collect();
        let im = PhotoImage {
            width: w,
            height: h,
            max_level: 255,
            data,
        };
        let c = contour_center(&im).expect("a centre");
        assert!((c[0] - cx).abs() < 0.5 && (c[1] - cy).abs() < 0.5, "{c:?}");
        let cen = super::super::spline::centroid_center(&im);
        assert!(
            (cen[0] - cx).abs() > 1.0,
            "the centroid is biased here: {cen:?}"
        );
    }

    #[test]
    fn flat_image_has_no_contour_centre() {
        let im = PhotoImage {
            width: 64,
            height: 64,
            max_level: 255,
            data: vec![128; 64 * 64],
        };
        assert!(contour_center(&im).is_none());
    }
}
