//! Outlier rejection between solves: corners beyond the robust residual spread, then views
//! far worse than the median view, each with its reason.

use nalgebra::Vector2;

use super::solve::ViewState;
use super::types::{CalibOptions, MIN_CORNERS_PER_VIEW, MIN_VIEWS, RejectedCorner};
use crate::camera::{Camera, CameraModel};
use crate::stats::median;

/// MAD → σ for a normal distribution.
const MAD_TO_SIGMA: f64 = 1.482_602_218_505_602;

/// One round of outlier rejection on the active views; returns whether anything was rejected.
///
/// Corners first: a corner is an outlier when its residual norm exceeds
/// `max(outlier_sigmas·σ, outlier_min_px)`, σ the robust (MAD) spread of the residual
/// coordinates of all inliers. Then views, judged on the corners that survive: a view whose RMS
/// exceeds `view_rms_factor` × the median view RMS (and `view_rms_min_px`) is dropped whole,
/// worst first, never below [`MIN_VIEWS`] views; so is a view left with fewer than
/// [`MIN_CORNERS_PER_VIEW`] inliers. Judging views after the corners keeps one mis-detected
/// corner from condemning a good view, while a view that is bad throughout (wrong ordering,
/// motion blur) still goes, with one reason instead of dozens.
pub(super) fn reject(
    views: &mut [ViewState],
    active: &[usize],
    camera: &Camera,
    options: &CalibOptions,
    rejected_corners: &mut Vec<RejectedCorner>,
) -> bool {
    // Residuals of every corner of the active views.
    let residuals: Vec<Vec<Option<Vector2<f64>>>> = active
        .iter()
        .map(|&i| {
            let v = &views[i];
            let pose = v.pose.unwrap_or_default();
            v.data
                .object
                .iter()
                .zip(&v.data.pixels)
                .map(|(x, px)| camera.project(&pose.act(x)).map(|p| p - px))
                .collect()
        })
        .collect();
    let mut components = Vec::new();
    for (a, &i) in active.iter().enumerate() {
        for (k, r) in residuals[a].iter().enumerate() {
            if views[i].inlier[k]
                && let Some(r) = r
            {
                components.push(r.x.abs());
                components.push(r.y.abs());
            }
        }
    }
    let sigma = MAD_TO_SIGMA * median(components);
    let threshold = (options.outlier_sigmas * sigma).max(options.outlier_min_px);

    // Tentative corner outliers and the RMS of what survives, per view.
    let mut new_outliers: Vec<Vec<(usize, String)>> = Vec::with_capacity(active.len());
    let mut view_rms = Vec::with_capacity(active.len());
    let mut survivors = Vec::with_capacity(active.len());
    for (a, &i) in active.iter().enumerate() {
        let v = &views[i];
        let mut out = Vec::new();
        let (mut sum, mut n) = (0.0, 0usize);
        for (k, r) in residuals[a].iter().enumerate() {
            if !v.inlier[k] {
                continue;
            }
            match r {
                None => out.push((k, "does not project with the current estimate".to_string())),
                Some(r) if r.norm() > threshold => out.push((
                    k,
                    format!(
                        "residual {:.3} px > {threshold:.3} px ({}·σ, robust σ = {sigma:.3} px)",
                        r.norm(),
                        options.outlier_sigmas
                    ),
                )),
                Some(r) => {
                    sum += r.norm_squared();
                    n += 1;
                }
            }
        }
        view_rms.push(if n > 0 {
            (sum / n as f64).sqrt()
        } else {
            f64::INFINITY
        });
        survivors.push(n);
        new_outliers.push(out);
    }
    let med_view = median(view_rms.iter().copied().filter(|x| x.is_finite()).collect());

    let mut changed = false;
    let mut remaining = active.len();
    let mut drop_view: Vec<(f64, usize, String)> = Vec::new();
    for (a, &rms) in view_rms.iter().enumerate() {
        if survivors[a] < MIN_CORNERS_PER_VIEW {
            drop_view.push((
                f64::INFINITY,
                a,
                format!(
                    "only {} inlier corners left (at least {MIN_CORNERS_PER_VIEW} needed)",
                    survivors[a]
                ),
            ));
        } else if rms > options.view_rms_factor * med_view && rms > options.view_rms_min_px {
            drop_view.push((
                rms,
                a,
                format!(
                    "RMS {rms:.3} px is more than {}× the median view RMS {med_view:.3} px",
                    options.view_rms_factor
                ),
            ));
        }
    }
    drop_view.sort_by(|x, y| y.0.total_cmp(&x.0));
    for (_, a, reason) in drop_view {
        if remaining <= MIN_VIEWS {
            break;
        }
        views[active[a]].rejected = Some(reason);
        remaining -= 1;
        changed = true;
    }
    for (a, &i) in active.iter().enumerate() {
        let v = &mut views[i];
        if v.rejected.is_some() {
            continue;
        }
        for (k, reason) in new_outliers[a].drain(..) {
            v.inlier[k] = false;
            changed = true;
            rejected_corners.push(RejectedCorner {
                view: i,
                view_name: v.name.clone(),
                index: v.indices[k],
                reason,
            });
        }
    }
    changed
}
