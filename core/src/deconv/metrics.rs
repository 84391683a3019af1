//! Restoration quality against a reference: PSNR, SSIM, Levin's error ratio.

use super::Plane;
use crate::error::{CoreError, CoreResult};

fn same_size(a: &Plane, b: &Plane) -> CoreResult<()> {
    if a.width != b.width || a.height != b.height || a.data.len() != b.data.len() {
        return Err(CoreError::input(format!(
            "images differ in size: {}×{} and {}×{}",
            a.width, a.height, b.width, b.height
        )));
    }
    if a.data.is_empty() {
        return Err(CoreError::input("images are empty"));
    }
    Ok(())
}

fn ssd(a: &Plane, b: &Plane, border: usize) -> f64 {
    let mut s = 0.0;
    for y in border..a.height.saturating_sub(border) {
        for x in border..a.width.saturating_sub(border) {
            let d = f64::from(a.at(x, y)) - f64::from(b.at(x, y));
            s += d * d;
        }
    }
    s
}

/// Peak signal-to-noise ratio in dB, `10 log10(range² / MSE)`, as
/// `skimage.metrics.peak_signal_noise_ratio(a, b, data_range=range)`. No clipping is applied:
/// clip the restored image first to match the peer. Identical images give `+∞`.
pub fn psnr(a: &Plane, b: &Plane, data_range: f64) -> CoreResult<f64> {
    same_size(a, b)?;
    if !(data_range.is_finite() && data_range > 0.0) {
        return Err(CoreError::param(
            "data_range",
            "must be finite and positive",
        ));
    }
    let mse = ssd(a, b, 0) / a.data.len() as f64;
    Ok(10.0 * (data_range * data_range / mse).log10())
}

/// Mean structural similarity (Wang, Bovik, Sheikh, Simoncelli, "Image quality assessment: from
/// error visibility to structural similarity", IEEE TIP 13(4), 2004) for images in `[0, 1]`.
///
/// Matches `skimage.metrics.structural_similarity(a, b, data_range=1)` with its defaults, which
/// the peer uses: a 7×7 uniform window (not the paper's 11×11 Gaussian, σ 1.5), K1 = 0.01,
/// K2 = 0.03, sample covariances (normalised by N − 1 = 48), and the mean over the pixels whose
/// window lies inside the image (skimage crops 3 px from every side). Window sums come from
/// summed-area tables in f64, so the cost is linear in the pixel count.
pub fn ssim(a: &Plane, b: &Plane) -> CoreResult<f64> {
    same_size(a, b)?;
    const WIN: usize = 7;
    let (w, h) = (a.width, a.height);
    if w < WIN || h < WIN {
        return Err(CoreError::input(format!(
            "SSIM needs at least {WIN}×{WIN} px, got {w}×{h}"
        )));
    }
    // Summed-area tables of a, b, a², b², ab with a zero first row/column.
    let sw = w + 1;
    let mut tables = vec![[0.0f64; 5]; sw * (h + 1)];
    for y in 0..h {
        let mut row = [0.0f64; 5];
        for x in 0..w {
            let (p, q) = (f64::from(a.at(x, y)), f64::from(b.at(x, y)));
            for (r, v) in row.iter_mut().zip([p, q, p * p, q * q, p * q]) {
                *r += v;
            }
            let above = tables[y * sw + x + 1];
            let cell = &mut tables[(y + 1) * sw + x + 1];
            for i in 0..5 {
                cell[i] = above[i] + row[i];
            }
        }
    }
    let n = (WIN * WIN) as f64;
    let cov_norm = n / (n - 1.0);
    let (c1, c2) = (0.01f64 * 0.01, 0.03f64 * 0.03);
    let mut total = 0.0;
    let mut count = 0usize;
    for y0 in 0..=h - WIN {
        for x0 in 0..=w - WIN {
            let (y1, x1) = (y0 + WIN, x0 + WIN);
            let mut s = [0.0f64; 5];
            for (i, v) in s.iter_mut().enumerate() {
                *v = (tables[y1 * sw + x1][i] - tables[y0 * sw + x1][i] - tables[y1 * sw + x0][i]
                    + tables[y0 * sw + x0][i])
                    / n;
            }
            let (ua, ub) = (s[0], s[1]);
            let va = cov_norm * (s[2] - ua * ua);
            let vb = cov_norm * (s[3] - ub * ub);
            let vab = cov_norm * (s[4] - ua * ub);
            total += ((2.0 * ua * ub + c1) * (2.0 * vab + c2))
                / ((ua * ua + ub * ub + c1) * (va + vb + c2));
            count += 1;
        }
    }
    Ok(total / count as f64)
}

/// Levin's error ratio (Levin, Weiss, Durand, Freeman, "Understanding and evaluating blind
/// deconvolution algorithms", CVPR 2009): the SSD to `sharp` of the image restored with the
/// estimated kernel over the SSD of the image restored (same method) with the true kernel,
/// ignoring `border` px on every side. 1 is as good as knowing the kernel; ≤ 3 counts as success.
pub fn error_ratio(
    sharp: &Plane,
    with_estimate: &Plane,
    with_truth: &Plane,
    border: usize,
) -> CoreResult<f64> {
    same_size(sharp, with_estimate)?;
    same_size(sharp, with_truth)?;
    if 2 * border >= sharp.width || 2 * border >= sharp.height {
        return Err(CoreError::param(
            "border",
            format!(
                "{border} px leaves nothing of a {}×{} image",
                sharp.width, sharp.height
            ),
        ));
    }
    let truth = ssd(sharp, with_truth, border);
    let est = ssd(sharp, with_estimate, border);
    if truth <= 0.0 {
        return Ok(if est <= 0.0 { 1.0 } else { f64::INFINITY });
    }
    Ok(est / truth)
}

/// [`error_ratio`] with the estimate-based restoration allowed to move by up to `max_shift` px in
/// each direction (the smallest SSD wins), as in Levin et al.'s evaluation code: a blind kernel is
/// only defined up to a translation, which shifts the restored image without making it worse.
/// `border` must exceed `max_shift`.
pub fn error_ratio_aligned(
    sharp: &Plane,
    with_estimate: &Plane,
    with_truth: &Plane,
    border: usize,
    max_shift: usize,
) -> CoreResult<f64> {
    let base = error_ratio(sharp, with_estimate, with_truth, border)?;
    if max_shift >= border {
        return Err(CoreError::param("max_shift", "must be below the border"));
    }
    let truth = ssd(sharp, with_truth, border);
    if truth <= 0.0 {
        return Ok(base);
    }
    let m = max_shift as isize;
    let mut best = f64::INFINITY;
    for dy in -m..=m {
        for dx in -m..=m {
            let mut s = 0.0;
            for y in border..sharp.height - border {
                for x in border..sharp.width - border {
                    let e =
                        with_estimate.at((x as isize + dx) as usize, (y as isize + dy) as usize);
                    let d = f64::from(sharp.at(x, y)) - f64::from(e);
                    s += d * d;
                }
            }
            best = best.min(s);
        }
    }
    Ok(best / truth)
}
