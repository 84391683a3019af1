//! The radial spline vignetting model and its fit to flat fields, for wide and fisheye lenses.
//!
//! The polynomial `1 + v1 r² + v2 r⁴ + v3 r⁶` of DSO (Engel, Koltun & Cremers, PAMI 2018) and of
//! the online calibration (Bergmann, Wang & Cremers, RA-L 2017) is smooth everywhere; a fisheye
//! whose image circle ends inside the frame falls from ~0.5 to ~0 within a few pixels, which no
//! low-order polynomial follows (it overshoots below zero). Here V is a C¹ piecewise cubic
//! Hermite curve in the radius with knots placed where the profile changes (dense at the border
//! of the image circle), fitted to radially binned flat-field values, and pixels beyond the
//! image circle are masked (V = 0). TUM's `vignetteCalib` (mono_dataset_code; Engel, Usenko &
//! Cremers, "A Photometrically Calibrated Benchmark For Monocular Visual Odometry", 2016)
//! estimates a dense map for the same reason; a radial curve needs far fewer flats because every
//! ring of pixels averages into one bin.
//!
//! Fit, in three passes over radial bins of 1 px (each flat j, bin b: mean linear value m_jb of
//! the pixels neither dark nor saturated, and their count n_jb):
//! 1. a non-parametric profile: the rank-one factorisation m_jb ≈ s_j P_b by alternating least
//!    squares (one scale per flat, one value per bin), normalised to 1 at the centre;
//! 2. the image circle: the radius beyond which P stays below `circle_fraction` (or no pixel is
//!    lit), and the knots: equally spaced in ½ (radius share) + ½ (share of the total variation
//!    of P), so a steep border gets as many knots as the slow cos⁴-like interior;
//! 3. the spline values and the scales by alternating weighted least squares (weights n_jb / s_j²,
//!    i.e. residuals in units of V), with a small penalty on second differences of the values so
//!    knots in sparsely covered rings stay well-posed.

use serde::{Deserialize, Serialize};

use super::PhotoImage;
use super::response::InverseResponse;
use crate::error::{CoreError, CoreResult};
use crate::progress::Progress;

/// `V(r)` as a C¹ piecewise cubic Hermite curve through `(knots[i], values[i])`, tangents from
/// three-point divided differences (the derivative of the parabola through neighbouring knots),
/// zero at `r = 0` (V is even in r). Beyond the last knot V keeps the last value (the model's
/// mask, if any, sets it to 0 outside the image circle).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct RadialSpline {
    /// Knot radii, normalised like the polynomial's `r` (distance / `radius`), from 0, increasing.
    pub knots: Vec<f64>,
    /// V at the knots (1 at r = 0).
    pub values: Vec<f64>,
}

impl RadialSpline {
    /// Check the shape: 3 to 256 knots, strictly increasing from 0, finite values.
    pub fn validate(&self) -> CoreResult<()> {
        let k = self.knots.len();
        if !(3..=256).contains(&k) || self.values.len() != k {
            return Err(CoreError::param(
                "vignette.spline",
                "needs 3 to 256 knots and one value per knot",
            ));
        }
        if self.knots[0] != 0.0
            || self
                .knots
                .windows(2)
                .any(|w| w[1].partial_cmp(&w[0]) != Some(std::cmp::Ordering::Greater))
            || self
                .knots
                .iter()
                .chain(&self.values)
                .any(|v| !v.is_finite())
        {
            return Err(CoreError::param(
                "vignette.spline",
                "knots must start at 0 and increase strictly; values must be finite",
            ));
        }
        Ok(())
    }

    /// V at normalised radius `r`.
    pub fn eval(&self, r: f64) -> f64 {
        eval_with(&self.knots, &self.values, r)
    }

    /// The basis weights of the values at `r` into `out` (`V(r) = Σ w_j values[j]`; at most
    /// four entries); `unit` is scratch of the values' length, all zero.
    pub(crate) fn basis_into(&self, r: f64, unit: &mut [f64], out: &mut Vec<(usize, f64)>) {
        if r >= self.knots[self.knots.len() - 1] {
            out.clear();
            out.push((self.knots.len() - 1, 1.0));
            return;
        }
        basis(&self.knots, r, unit, out);
    }
}

/// Tangent at knot `i` for values `c`.
fn tangent(t: &[f64], c: &[f64], i: usize) -> f64 {
    let k = t.len();
    if i == 0 {
        0.0
    } else if i + 1 == k {
        (c[i] - c[i - 1]) / (t[i] - t[i - 1])
    } else {
        let (h0, h1) = (t[i] - t[i - 1], t[i + 1] - t[i]);
        let (d0, d1) = ((c[i] - c[i - 1]) / h0, (c[i + 1] - c[i]) / h1);
        (h1 * d0 + h0 * d1) / (h0 + h1)
    }
}

/// The Hermite curve through knots `t` with values `c` at `r` (constant outside the knots).
fn eval_with(t: &[f64], c: &[f64], r: f64) -> f64 {
    let k = t.len();
    if k == 0 {
        return 1.0;
    }
    if r <= t[0] {
        return c[0];
    }
    if r >= t[k - 1] {
        return c[k - 1];
    }
    let i = t.partition_point(|&v| v <= r).saturating_sub(1).min(k - 2);
    let h = t[i + 1] - t[i];
    let s = (r - t[i]) / h;
    let (s2, s3) = (s * s, s * s * s);
    let h00 = 2.0 * s3 - 3.0 * s2 + 1.0;
    let h10 = s3 - 2.0 * s2 + s;
    let h01 = -2.0 * s3 + 3.0 * s2;
    let h11 = s3 - s2;
    h00 * c[i] + h10 * h * tangent(t, c, i) + h01 * c[i + 1] + h11 * h * tangent(t, c, i + 1)
}

/// Basis weights of the knot values at `r`: V(r) = Σ w_i c_i with the nonzero `w` at most at
/// i − 1 … i + 2 of the segment (the curve is linear in the values).
fn basis(t: &[f64], r: f64, unit: &mut [f64], out: &mut Vec<(usize, f64)>) {
    out.clear();
    let k = t.len();
    let i = t.partition_point(|&v| v <= r).saturating_sub(1).min(k - 2);
    for j in i.saturating_sub(1)..(i + 3).min(k) {
        unit[j] = 1.0;
        let w = eval_with(t, unit, r);
        unit[j] = 0.0;
        if w != 0.0 {
            out.push((j, w));
        }
    }
}

/// Options of the spline fit (from `VignettingParams`).
pub(crate) struct SplineOptions {
    pub stride: usize,
    pub low_cut: f64,
    pub high_cut: f64,
    pub knots: usize,
    pub circle_fraction: f64,
    pub smoothing: f64,
}

/// Result of [`fit_spline`].
pub(crate) struct SplineFit {
    pub spline: RadialSpline,
    /// Image-circle radius, normalised (None: the profile never drops below the fraction).
    pub mask_r: Option<f64>,
    pub scales: Vec<f64>,
}

/// Radial bins of the flats: per image, per 1-px ring, the sum and count of usable linear values.
struct Bins {
    /// `[j][b]` sum of linear values.
    sum: Vec<Vec<f64>>,
    /// `[j][b]` count.
    cnt: Vec<Vec<f64>>,
    /// `[b]` sum of distances of all pixels (for the ring's mean radius).
    dsum: Vec<f64>,
    /// `[b]` pixels in the ring (per image).
    all: Vec<f64>,
    /// `[b]` pixels at or below the low cut, over all images.
    dark: Vec<f64>,
}

fn bin_flats(
    images: &[PhotoImage],
    inverse: &InverseResponse,
    o: &SplineOptions,
    center: [f64; 2],
    progress: &dyn Progress,
) -> CoreResult<Bins> {
    let (w, h) = (images[0].width, images[0].height);
    let dmax = [
        (0.0, 0.0),
        (w as f64, 0.0),
        (0.0, h as f64),
        (w as f64, h as f64),
    ]
    .iter()
    .map(|&(x, y)| (x - center[0]).hypot(y - center[1]))
    .fold(0.0, f64::max);
    let nb = dmax.ceil() as usize + 2;
    let nj = images.len();
    let mut b = Bins {
        sum: vec![vec![0.0; nb]; nj],
        cnt: vec![vec![0.0; nb]; nj],
        dsum: vec![0.0; nb],
        all: vec![0.0; nb],
        dark: vec![0.0; nb],
    };
    for y in (0..h).step_by(o.stride) {
        if y % 64 == 0 {
            progress.check()?;
        }
        for x in (0..w).step_by(o.stride) {
            let d = (x as f64 - center[0]).hypot(y as f64 - center[1]);
            let k = (d as usize).min(nb - 1);
            b.dsum[k] += d;
            b.all[k] += 1.0;
            for (j, im) in images.iter().enumerate() {
                let v = im.get(x, y);
                if v <= o.low_cut {
                    b.dark[k] += 1.0;
                } else if v < o.high_cut {
                    b.sum[j][k] += inverse.eval(v);
                    b.cnt[j][k] += 1.0;
                }
            }
        }
    }
    Ok(b)
}

/// The flat with the fewest saturated pixels.
fn least_saturated(images: &[PhotoImage], high_cut: f64) -> Option<&PhotoImage> {
    let sat = |im: &PhotoImage| {
        im.data
            .iter()
            .filter(|&&v| f64::from(v) >= high_cut * f64::from(im.max_level))
            .count()
    };
    images.iter().min_by_key(|im| sat(im))
}

/// Optical centre for the spline model when it is fitted, from the least saturated flat:
/// circle fits to its contours ([`super::spline_center`]), or, when it has no usable contour,
/// [`centroid_center`]. The image centre when there is no flat.
pub(crate) fn estimate_center(images: &[PhotoImage], high_cut: f64) -> [f64; 2] {
    match least_saturated(images, high_cut) {
        Some(im) => super::spline_center::contour_center(im).unwrap_or_else(|| centroid_center(im)),
        None => images.first().map_or([0.0; 2], |im| {
            [im.width as f64 / 2.0, im.height as f64 / 2.0]
        }),
    }
}

/// The centroid of the region above half the maximum of `im` (a disc for a radial falloff,
/// unless the frame clips it). Falls back to the image centre when that region is empty.
pub(crate) fn centroid_center(im: &PhotoImage) -> [f64; 2] {
    let (w, h) = (im.width, im.height);
    let max = im.data.iter().copied().max().unwrap_or(0);
    let thr = f64::from(max) / 2.0;
    let (mut sx, mut sy, mut n) = (0.0, 0.0, 0.0);
    for y in 0..h {
        for x in 0..w {
            if f64::from(im.data[y * w + x]) >= thr {
                sx += x as f64;
                sy += y as f64;
                n += 1.0;
            }
        }
    }
    if n > 0.0 && max > 0 {
        [sx / n, sy / n]
    } else {
        [w as f64 / 2.0, h as f64 / 2.0]
    }
}

/// Fit the radial spline (see the module doc) around `center`; `radius` normalises r.
// The bins are parallel arrays indexed [image][ring]: index loops read clearer than zips.
#[allow(clippy::needless_range_loop)]
pub(crate) fn fit_spline(
    images: &[PhotoImage],
    inverse: &InverseResponse,
    o: &SplineOptions,
    center: [f64; 2],
    radius: f64,
    progress: &dyn Progress,
) -> CoreResult<SplineFit> {
    let bins = bin_flats(images, inverse, o, center, progress)?;
    let nj = images.len();
    let nb = bins.all.len();
    let mean_m = |j: usize, b: usize| bins.sum[j][b] / bins.cnt[j][b];
    // Pass 1: non-parametric profile P_b and scales s_j.
    let mut p = vec![1.0; nb];
    let mut s: Vec<f64> = (0..nj)
        .map(|j| {
            let (a, n) = (
                bins.sum[j].iter().sum::<f64>(),
                bins.cnt[j].iter().sum::<f64>(),
            );
            if n > 0.0 { a / n } else { 1.0 }
        })
        .collect();
    for _ in 0..60 {
        progress.check()?;
        for (b, pb) in p.iter_mut().enumerate() {
            let (mut num, mut den) = (0.0, 0.0);
            for j in 0..nj {
                let n = bins.cnt[j][b];
                if n > 0.0 {
                    num += n * mean_m(j, b) * s[j] / (s[j] * s[j]);
                    den += n;
                }
            }
            *pb = if den > 0.0 { num / den } else { f64::NAN };
        }
        for (j, sj) in s.iter_mut().enumerate() {
            let (mut num, mut den) = (0.0, 0.0);
            for b in 0..nb {
                let n = bins.cnt[j][b];
                if n > 0.0 && p[b].is_finite() {
                    num += n * bins.sum[j][b] / n * p[b];
                    den += n * p[b] * p[b];
                }
            }
            if den > 0.0 {
                *sj = num / den;
            }
        }
    }
    // Normalise to 1 at the centre: the count-weighted mean over the innermost rings.
    let inner = (radius * 0.02).max(3.0) as usize;
    let (mut a, mut n) = (0.0, 0.0);
    for b in 0..inner.min(nb) {
        let c: f64 = (0..nj).map(|j| bins.cnt[j][b]).sum();
        if c > 0.0 && p[b].is_finite() {
            a += c * p[b];
            n += c;
        }
    }
    if !(n > 0.0 && a > 0.0) {
        return Err(CoreError::input(
            "no usable flat-field pixel near the optical centre (saturated or black in every \
             flat): cannot normalise the vignetting",
        ));
    }
    let p0 = a / n;
    p.iter_mut().for_each(|v| *v /= p0);
    s.iter_mut().for_each(|v| *v *= p0);
    let ring_r = |b: usize| {
        if bins.all[b] > 0.0 {
            bins.dsum[b] / bins.all[b]
        } else {
            b as f64 + 0.5
        }
    };

    // Pass 2: image circle and knots. A ring is dark when P is below the fraction or when it
    // has no usable pixel and most of its pixels are dark.
    let lit_rings: Vec<usize> = (0..nb).filter(|&b| bins.all[b] > 0.0).collect();
    let dark_ring = |b: usize| {
        if p[b].is_finite() {
            p[b] < o.circle_fraction
        } else {
            bins.dark[b] >= 0.5 * bins.all[b] * nj as f64
        }
    };
    let mut edge = None;
    if o.circle_fraction > 0.0 {
        for (i, &b) in lit_rings.iter().enumerate().rev() {
            if !dark_ring(b) {
                if i + 1 < lit_rings.len() {
                    edge = Some(lit_rings[i + 1]);
                }
                break;
            }
        }
    }
    let last_ring = match edge {
        Some(e) => e.saturating_sub(1),
        None => *lit_rings.last().unwrap_or(&0),
    };
    let r_max = (ring_r(last_ring) + 0.5) / radius;
    let mask_r = edge.map(|e| e as f64 / radius);
    // Cumulative variation of a lightly smoothed P (monotone by construction).
    let used: Vec<usize> = (0..=last_ring)
        .filter(|&b| p[b].is_finite() && bins.all[b] > 0.0)
        .collect();
    if used.len() < o.knots {
        return Err(CoreError::input(format!(
            "only {} radial rings have usable flat-field pixels; the spline needs at least {}",
            used.len(),
            o.knots
        )));
    }
    let sm: Vec<f64> = (0..used.len())
        .map(|i| {
            let lo = i.saturating_sub(2);
            let hi = (i + 3).min(used.len());
            used[lo..hi].iter().map(|&b| p[b]).sum::<f64>() / (hi - lo) as f64
        })
        .collect();
    let mut cum = vec![0.0; used.len()];
    for i in 1..used.len() {
        cum[i] = cum[i - 1] + (sm[i] - sm[i - 1]).abs();
    }
    let tv = cum[used.len() - 1].max(1e-12);
    let share = |i: usize| 0.5 * ring_r(used[i]) / radius / r_max + 0.5 * cum[i] / tv;
    let mut knots = vec![0.0];
    let mut i = 0;
    for k in 1..o.knots - 1 {
        let target = k as f64 / (o.knots - 1) as f64;
        while i + 1 < used.len() && share(i) < target {
            i += 1;
        }
        let r = (ring_r(used[i]) / radius).min(r_max);
        // Keep knots at least half a pixel apart.
        if r > knots[knots.len() - 1] + 0.5 / radius {
            knots.push(r);
        }
    }
    if r_max > knots[knots.len() - 1] + 0.5 / radius {
        knots.push(r_max);
    }
    let k = knots.len();
    if k < 3 {
        return Err(CoreError::input(
            "flat fields too small for the spline model",
        ));
    }

    // Pass 3: alternating weighted least squares for the values and the scales.
    let mut c = vec![1.0; k];
    // Rows: (ring radius, per-image mean and count).
    let rows: Vec<(f64, usize)> = used.iter().map(|&b| (ring_r(b) / radius, b)).collect();
    let mut unit = vec![0.0; k];
    let mut bw = Vec::with_capacity(4);
    let basis_rows: Vec<Vec<(usize, f64)>> = rows
        .iter()
        .map(|&(r, _)| {
            basis(&knots, r, &mut unit, &mut bw);
            bw.clone()
        })
        .collect();
    let total: f64 = used
        .iter()
        .map(|&b| (0..nj).map(|j| bins.cnt[j][b]).sum::<f64>())
        .sum();
    let lambda = o.smoothing * total;
    for _ in 0..25 {
        progress.check()?;
        let mut a = nalgebra::DMatrix::<f64>::zeros(k, k);
        let mut g = nalgebra::DVector::<f64>::zeros(k);
        for (row, &(_, b)) in basis_rows.iter().zip(&rows) {
            for j in 0..nj {
                let n = bins.cnt[j][b];
                if n <= 0.0 {
                    continue;
                }
                // Residual in V units: m / s − V, weight n.
                let y = mean_m(j, b) / s[j];
                for &(ia, wa) in row {
                    g[ia] += n * wa * y;
                    for &(ib, wb) in row {
                        a[(ia, ib)] += n * wa * wb;
                    }
                }
            }
        }
        // Second differences of the values, scaled to the local knot spacing.
        for i in 1..k - 1 {
            let (h0, h1) = (knots[i] - knots[i - 1], knots[i + 1] - knots[i]);
            let hm = 0.5 * (h0 + h1);
            let coef = [hm / h0, -(hm / h0 + hm / h1), hm / h1];
            let idx = [i - 1, i, i + 1];
            for (p1, &ia) in idx.iter().enumerate() {
                for (p2, &ib) in idx.iter().enumerate() {
                    a[(ia, ib)] += lambda * coef[p1] * coef[p2];
                }
            }
        }
        for d in 0..k {
            a[(d, d)] += 1e-12 * total;
        }
        let Some(chol) = a.cholesky() else {
            return Err(CoreError::NoSolution(
                "spline vignetting normal equations are singular".into(),
            ));
        };
        let sol = chol.solve(&g);
        let c0 = sol[0];
        if !(c0.is_finite() && c0 > 0.0) {
            return Err(CoreError::NoSolution(
                "spline vignetting fit diverged (V at the centre ≤ 0)".into(),
            ));
        }
        c = sol.iter().map(|v| v / c0).collect();
        for (j, sj) in s.iter_mut().enumerate() {
            let (mut num, mut den) = (0.0, 0.0);
            for (row, &(_, b)) in basis_rows.iter().zip(&rows) {
                let n = bins.cnt[j][b];
                if n > 0.0 {
                    let v: f64 = row.iter().map(|&(i, w)| w * c[i]).sum();
                    num += bins.sum[j][b] * v;
                    den += n * v * v;
                }
            }
            if den > 0.0 {
                *sj = num / den;
            }
        }
    }
    Ok(SplineFit {
        spline: RadialSpline { knots, values: c },
        mask_r,
        scales: s,
    })
}
