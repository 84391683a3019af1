//! Sub-pixel centre of a dark ellipse from its grey levels.
//!
//! The centre is the centroid of the darkness `B(p) − I(p)`, `B` being the card's brightness
//! under the blob (a plane fitted to a ring of pixels around it, so that a lighting gradient
//! does not pull the centroid), over a window that is the blob's ellipse grown by a factor and
//! centred on the current estimate (three rounds). Why this is exact for the ellipse centre:
//! the image of a circle is an ellipse, symmetric about its centre; blur with a symmetric
//! point-spread function and integration over square pixels keep that symmetry; a window
//! symmetric about the same centre cuts the blurred tails symmetrically. So the centroid of
//! what remains is the ellipse centre, whatever the blur, and the only errors left are noise,
//! the card's brightness estimate and neighbours reaching into the window, which the window
//! size (half-way to the nearest other blob) avoids. This gives the *ellipse* centre, not the
//! projected circle centre: [`super::perspective`] corrects the difference.

use super::blobs::Blob;
use crate::board::filter::ImageF;

/// Rounds of re-centring the window.
const ROUNDS: usize = 3;
/// Width of the background ring around the window, pixels (at least).
const RING_PX: f64 = 2.0;

/// A refined centre and the blob's contrast (card minus circle grey level).
#[derive(Clone, Copy, Debug)]
pub(super) struct Refined {
    pub c: [f64; 2],
    pub contrast: f64,
}

/// Least squares plane `v = a + b·dx + c·dy` through `(dx, dy, v)`, `None` when degenerate.
fn plane(pts: &[(f64, f64, f64)]) -> Option<[f64; 3]> {
    let mut m = nalgebra::Matrix3::<f64>::zeros();
    let mut r = nalgebra::Vector3::<f64>::zeros();
    for &(x, y, v) in pts {
        let a = nalgebra::Vector3::new(1.0, x, y);
        m += a * a.transpose();
        r += a * v;
    }
    let s = m.cholesky()?.solve(&r);
    Some([s[0], s[1], s[2]])
}

/// The centre of `blob` in `img` (see the module docs); `outer` is the ellipse-metric radius
/// the window and its background ring may reach (half-way to the nearest other blob).
pub(super) fn refine(img: &ImageF, blob: &Blob, outer: f64) -> Option<Refined> {
    let (_, minor) = blob.axes();
    if minor.is_nan() || minor <= 0.5 {
        return None;
    }
    let ring = (RING_PX / minor).max(0.15);
    let window = (outer - ring).max(1.1);
    let outer = window + ring;
    let mut c = blob.c;
    let mut contrast = 0.0;
    let [cxx, _, cyy] = blob.cov.map(|v| 4.0 * v);
    // Half-extents of the outer ellipse's bounding box.
    let (ex, ey) = (outer * cxx.sqrt() + 1.0, outer * cyy.sqrt() + 1.0);
    let mean_r = {
        let (a, b) = blob.axes();
        (a * b).sqrt()
    };
    let mut ring_pts = Vec::new();
    let mut inside = Vec::new();
    for _ in 0..ROUNDS {
        let probe = Blob { c, ..*blob };
        let x0 = (c[0] - ex).floor().max(0.0) as usize;
        let y0 = (c[1] - ey).floor().max(0.0) as usize;
        let x1 = ((c[0] + ex).ceil() as usize).min(img.w.checked_sub(1)?);
        let y1 = ((c[1] + ey).ceil() as usize).min(img.h.checked_sub(1)?);
        if (c[0] - ex) < 0.0 || (c[1] - ey) < 0.0 {
            return None;
        }
        if c[0] + ex > (img.w - 1) as f64 || c[1] + ey > (img.h - 1) as f64 {
            return None;
        }
        ring_pts.clear();
        inside.clear();
        for y in y0..=y1 {
            for x in x0..=x1 {
                let p = [x as f64, y as f64];
                let rho = probe.rho2(p).sqrt();
                let v = f64::from(img.data[y * img.w + x]);
                let (dx, dy) = (p[0] - c[0], p[1] - c[1]);
                if rho > window && rho <= outer {
                    ring_pts.push((dx, dy, v));
                }
                // A one-pixel soft edge keeps the window's discrete shape symmetric.
                let wgt = ((window - rho) * mean_r + 0.5).clamp(0.0, 1.0);
                if wgt > 0.0 {
                    inside.push((dx, dy, v, wgt));
                }
            }
        }
        if ring_pts.len() < 8 {
            return None;
        }
        let mut bg = plane(&ring_pts)?;
        // One robust round: drop ring pixels far from the plane (a neighbour's edge).
        let mut res: Vec<f64> = ring_pts
            .iter()
            .map(|&(x, y, v)| (v - bg[0] - bg[1] * x - bg[2] * y).abs())
            .collect();
        res.sort_by(f64::total_cmp);
        let mad = res[res.len() / 2].max(0.5);
        let kept: Vec<_> = ring_pts
            .iter()
            .copied()
            .filter(|&(x, y, v)| (v - bg[0] - bg[1] * x - bg[2] * y).abs() <= 4.5 * mad)
            .collect();
        if kept.len() >= 8 {
            bg = plane(&kept)?;
        }
        let (mut s, mut sx, mut sy, mut darkest) = (0.0, 0.0, 0.0, f64::INFINITY);
        for &(dx, dy, v, wgt) in &inside {
            let d = (bg[0] + bg[1] * dx + bg[2] * dy - v) * wgt;
            s += d;
            sx += d * dx;
            sy += d * dy;
            darkest = darkest.min(v);
        }
        if s.is_nan() || s <= 0.0 {
            return None;
        }
        c = [c[0] + sx / s, c[1] + sy / s];
        contrast = bg[0] - darkest;
        if (c[0] - blob.c[0]).hypot(c[1] - blob.c[1]) > 0.5 * minor {
            return None;
        }
    }
    Some(Refined { c, contrast })
}
