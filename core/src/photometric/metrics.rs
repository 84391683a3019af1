//! Accuracy measures against a reference calibration, with the gauge aligned.
//!
//! A photometric calibration from unknown exposures is only defined up to the γ ambiguity
//! (`g^α`, `V^α`, `e^α` explain the same images) and an irradiance scale. These helpers
//! compare curves the way the shared reference scores do: inverse responses min-max normalised
//! over the 8-bit levels 1..254, then `α` chosen to minimise the response error and applied to
//! the vignetting and exposures too.

use super::response::InverseResponse;

/// RMSE between two inverse responses, each normalised so that level 1 → 0 and 254 → 1,
/// over levels 1..254.
pub fn inverse_rmse(fit: &InverseResponse, truth: &InverseResponse) -> f64 {
    rmse(&fit.normalized_1_254(), &truth.normalized_1_254())
}

fn rmse(a: &[f64], b: &[f64]) -> f64 {
    (a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>() / a.len().max(1) as f64).sqrt()
}

fn pow_norm(g: &[f64], alpha: f64) -> Vec<f64> {
    let p: Vec<f64> = g.iter().map(|v| v.max(0.0).powf(alpha)).collect();
    let (a, b) = (p[0], p[p.len() - 1]);
    p.iter().map(|v| (v - a) / (b - a).max(1e-300)).collect()
}

/// The exponent `α ∈ [0.1, 10]` that best maps `fit^α` onto `truth` (normalised inverse
/// responses over levels 1..254, golden-section search on `ln α`), and the RMSE there.
pub fn gamma_align(fit: &InverseResponse, truth: &InverseResponse) -> (f64, f64) {
    let g = fit.resample(256).values;
    let t = truth.normalized_1_254();
    let err = |la: f64| rmse(&pow_norm(&g[1..=254], la.exp()), &t);
    let (mut a, mut b) = (0.1f64.ln(), 10.0f64.ln());
    let phi = 0.5 * (5f64.sqrt() - 1.0);
    for _ in 0..80 {
        let (c, d) = (b - phi * (b - a), a + phi * (b - a));
        if err(c) < err(d) {
            b = d;
        } else {
            a = c;
        }
    }
    let la = 0.5 * (a + b);
    (la.exp(), err(la))
}

/// RMSE between two attenuation maps after raising `fit` to `alpha` and normalising both to
/// maximum 1.
pub fn vignette_rmse(fit: &[f32], truth: &[f32], alpha: f64) -> f64 {
    let (a, b) = aligned_maps(fit, truth, alpha);
    rmse(&a, &b)
}

/// The two attenuation maps as [`vignette_rmse`] compares them: `fit` raised to `alpha`, both
/// normalised to maximum 1.
pub fn aligned_maps(fit: &[f32], truth: &[f32], alpha: f64) -> (Vec<f64>, Vec<f64>) {
    let f: Vec<f64> = fit
        .iter()
        .map(|&v| f64::from(v).max(0.0).powf(alpha))
        .collect();
    let fm = f.iter().copied().fold(0.0, f64::max).max(1e-300);
    let tm = truth
        .iter()
        .map(|&v| f64::from(v))
        .fold(0.0, f64::max)
        .max(1e-300);
    let a: Vec<f64> = f.iter().map(|v| v / fm).collect();
    let b: Vec<f64> = truth.iter().map(|&v| f64::from(v) / tm).collect();
    (a, b)
}

/// RMS relative error (in %) of exposure ratios to frame 0 after raising `fit` to `alpha`.
pub fn exposure_error_pct(fit: &[f64], truth: &[f64], alpha: f64) -> f64 {
    if fit.is_empty() || fit.len() != truth.len() {
        return f64::NAN;
    }
    let (f0, t0) = (fit[0], truth[0]);
    let errs: Vec<f64> = fit
        .iter()
        .zip(truth)
        .map(|(f, t)| (f / f0).powf(alpha) / (t / t0) - 1.0)
        .collect();
    100.0 * (errs.iter().map(|e| e * e).sum::<f64>() / errs.len() as f64).sqrt()
}

/// RMS relative error (in %) of the exposures after raising `fit` to `alpha` and removing the
/// best common scale (the mean log ratio): the exposure score of the shared `score_ref.json`
/// (`ratio_rmse_pct_gauge_aligned`), and the one issue 16's targets are stated in. Exposures
/// are only defined up to one factor (it moves into the radiances), so unlike
/// [`exposure_error_pct`] it does not charge every frame with frame 0's own error.
pub fn exposure_error_common_pct(fit: &[f64], truth: &[f64], alpha: f64) -> f64 {
    exposure_error_parts_pct(fit, truth, alpha, &vec![0; fit.len()])
}

/// [`exposure_error_common_pct`] for a video fitted in parts (`broken_tracks: per_part`):
/// each part gets its own best scale, since nothing ties the parts' scales together; the RMS
/// runs over all frames. `parts[i]` is frame `i`'s part.
pub fn exposure_error_parts_pct(fit: &[f64], truth: &[f64], alpha: f64, parts: &[usize]) -> f64 {
    if fit.is_empty() || fit.len() != truth.len() || parts.len() != fit.len() {
        return f64::NAN;
    }
    let d: Vec<f64> = fit
        .iter()
        .zip(truth)
        .map(|(f, t)| alpha * f.max(1e-300).ln() - t.max(1e-300).ln())
        .collect();
    let n = parts.iter().copied().max().map_or(0, |m| m + 1);
    let mut sum = vec![(0.0, 0usize); n];
    for (x, &p) in d.iter().zip(parts) {
        sum[p].0 += x;
        sum[p].1 += 1;
    }
    let ss: f64 = d
        .iter()
        .zip(parts)
        .map(|(x, &p)| ((x - sum[p].0 / sum[p].1 as f64).exp() - 1.0).powi(2))
        .sum();
    100.0 * (ss / d.len() as f64).sqrt()
}

#[cfg(test)]
mod tests {
    use super::{exposure_error_common_pct, exposure_error_parts_pct, exposure_error_pct};

    /// Each part's own factor costs nothing; one part alone is the common-scale error.
    #[test]
    fn per_part_exposure_error_ignores_each_parts_factor() {
        let truth: Vec<f64> = (0..40).map(|k| 1.0 + 0.05 * f64::from(k)).collect();
        let parts: Vec<usize> = (0..40).map(|k| usize::from(k >= 25)).collect();
        let fit: Vec<f64> = truth
            .iter()
            .zip(&parts)
            .map(|(t, &p)| t * if p == 0 { 2.0 } else { 0.1 })
            .collect();
        assert!(exposure_error_parts_pct(&fit, &truth, 1.0, &parts) < 1e-9);
        assert!(exposure_error_common_pct(&fit, &truth, 1.0) > 50.0);
        let one = vec![0; 40];
        let mut noisy = truth.clone();
        noisy[3] *= 1.05;
        let a = exposure_error_parts_pct(&noisy, &truth, 1.0, &one);
        // By hand: one log error of ln 1.05 among 40, the mean removed.
        let m = 1.05f64.ln() / 40.0;
        let ss = 39.0 * ((-m).exp() - 1.0).powi(2) + ((1.05f64.ln() - m).exp() - 1.0).powi(2);
        let want = 100.0 * (ss / 40.0).sqrt();
        assert!((a - want).abs() < 1e-9, "{a} {want}");
        assert!((exposure_error_common_pct(&noisy, &truth, 1.0) - want).abs() < 1e-9);
        assert!(exposure_error_parts_pct(&noisy, &truth, 1.0, &one[..3]).is_nan());
    }

    /// A common factor (and the gauge exponent) cost nothing; one bad frame 0 charges every
    /// frame relative to frame 0 but only itself with the common scale.
    #[test]
    fn common_scale_exposure_error_ignores_the_overall_factor() {
        let truth: Vec<f64> = (0..50).map(|k| 1.0 + 0.1 * f64::from(k)).collect();
        let scaled: Vec<f64> = truth.iter().map(|t| (3.0 * t).powf(0.5)).collect();
        assert!(exposure_error_common_pct(&scaled, &truth, 2.0) < 1e-9);
        let mut bad0 = truth.clone();
        bad0[0] *= 1.1;
        let vs0 = exposure_error_pct(&bad0, &truth, 1.0);
        let common = exposure_error_common_pct(&bad0, &truth, 1.0);
        assert!(vs0 > 8.0, "{vs0}");
        assert!(common < 2.0 && common > 0.5, "{common}");
        assert!(exposure_error_common_pct(&truth[..3], &truth, 1.0).is_nan());
    }
}
