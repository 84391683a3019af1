//! Initial camera estimates that need no guess from the user.

use std::f64::consts::PI;

use nalgebra::{Matrix3, Vector2};

use super::ModelKind;
use super::homography::homography;
use super::pnp::pose_for_view;
use super::problem::ViewData;
use super::zhang::{Intrinsics, intrinsics_fixed_centre, zhang_intrinsics};
use crate::camera::Camera;
use crate::error::{CoreError, CoreResult};
use crate::progress::Progress;

/// Focal candidates of the coarse sweep: f0·2^(k/4) for k in −8..=8, i.e. f0/4 … 4·f0 in
/// quarter-octave steps.
const SWEEP_STEPS: i32 = 8;
/// Golden-section iterations after the sweep (the bracket shrinks by 0.618 each).
const GOLDEN_ITERATIONS: usize = 14;
/// Pose refinement budget per view while scoring a focal length.
const SCORE_POSE_ITERATIONS: usize = 8;

/// The image centre in pixel-centre coordinates (pixel (0, 0) covers [−½, ½]²), as OpenCV's
/// initialisation uses it.
pub(crate) fn image_centre(image_size: (u32, u32)) -> Vector2<f64> {
    Vector2::new(
        (f64::from(image_size.0) - 1.0) * 0.5,
        (f64::from(image_size.1) - 1.0) * 0.5,
    )
}

/// A model with focal length `f`, principal point `c` and "neutral" distortion: none for the
/// pinhole, the equidistant projection r = f·θ for Kannala-Brandt, and ξ = 0, α = ½ for the
/// double sphere (r = 2f·tan(θ/2), the stereographic projection, which is f·θ to first order).
pub(crate) fn neutral_camera(kind: ModelKind, f: f64, c: Vector2<f64>) -> CoreResult<Camera> {
    match kind {
        ModelKind::PinholeRadTan => kind.camera(&[f, f, c.x, c.y, 0.0, 0.0, 0.0, 0.0, 0.0]),
        ModelKind::KannalaBrandt => kind.camera(&[f, f, c.x, c.y, 0.0, 0.0, 0.0, 0.0]),
        ModelKind::DoubleSphere => kind.camera(&[f, f, c.x, c.y, 0.0, 0.5]),
    }
}

/// Median over views of the per-view RMS after a pose fit with this camera, or ∞ when fewer
/// than half the views can be fitted.
fn score(camera: &Camera, views: &[ViewData], progress: &dyn Progress) -> CoreResult<f64> {
    let mut rms = Vec::with_capacity(views.len());
    for v in views {
        match pose_for_view(camera, v, SCORE_POSE_ITERATIONS, progress) {
            Ok((_, e)) if e.is_finite() => rms.push(e),
            Err(CoreError::Canceled) => return Err(CoreError::Canceled),
            _ => {}
        }
    }
    if rms.is_empty() || 2 * rms.len() < views.len() {
        return Ok(f64::INFINITY);
    }
    rms.sort_by(f64::total_cmp);
    Ok(rms[rms.len() / 2])
}

/// Focal length for a wide-angle model without a user guess: c at the image centre, neutral
/// distortion ([`neutral_camera`]), and f chosen to minimise the median per-view reprojection
/// RMS after a per-view pose fit.
///
/// Why a sweep: for an equidistant-like lens the one unknown that matters at first order is f
/// (OpenCV's fisheye calibration fails on real fisheye sets exactly because its start,
/// f = max(w, h)/π with no search, can be far off). Closed forms that estimate f from the angles
/// subtended by known board distances need the board distance too, and break on partial or
/// grazing views. Scoring candidates by reprojection after PnP uses the same model as the final
/// solve, tolerates bad views (median) and costs only a few dozen cheap pose fits. The sweep
/// covers f0/4 … 4·f0 around f0 = max(w, h)/π (a 180° lens filling the larger image side), in
/// quarter octaves, then a golden-section search on log f refines the best bracket.
pub(crate) fn focal_sweep(
    kind: ModelKind,
    image_size: (u32, u32),
    views: &[ViewData],
    progress: &dyn Progress,
) -> CoreResult<Camera> {
    let c = image_centre(image_size);
    let f0 = f64::from(image_size.0.max(image_size.1)) / PI;
    let eval = |log_f: f64| -> CoreResult<f64> {
        let cam = neutral_camera(kind, log_f.exp(), c)?;
        score(&cam, views, progress)
    };
    let step = std::f64::consts::LN_2 / 4.0;
    let mut best = (f64::INFINITY, f0.ln());
    for k in -SWEEP_STEPS..=SWEEP_STEPS {
        let lf = f0.ln() + f64::from(k) * step;
        let s = eval(lf)?;
        progress.report(
            "initialise",
            (k + SWEEP_STEPS) as u64,
            (2 * SWEEP_STEPS) as u64,
        );
        if s < best.0 {
            best = (s, lf);
        }
    }
    if !best.0.is_finite() {
        return Err(CoreError::NoSolution(
            "initialisation: no focal length between f0/4 and 4·f0 fits the views".into(),
        ));
    }
    let (mut a, mut b) = (best.1 - step, best.1 + step);
    let g = (5.0_f64.sqrt() - 1.0) / 2.0;
    let mut x1 = b - g * (b - a);
    let mut x2 = a + g * (b - a);
    let (mut f1, mut f2) = (eval(x1)?, eval(x2)?);
    for _ in 0..GOLDEN_ITERATIONS {
        if f1 < f2 {
            b = x2;
            x2 = x1;
            f2 = f1;
            x1 = b - g * (b - a);
            f1 = eval(x1)?;
        } else {
            a = x1;
            x1 = x2;
            f1 = f2;
            x2 = a + g * (b - a);
            f2 = eval(x2)?;
        }
    }
    let (fbest, lbest) = [(best.0, best.1), (f1, x1), (f2, x2)]
        .into_iter()
        .min_by(|p, q| p.0.total_cmp(&q.0))
        .unwrap_or(best);
    debug_assert!(fbest.is_finite());
    neutral_camera(kind, lbest.exp(), c)
}

/// Pinhole start by Zhang's method: per-view homographies (pixels), closed-form K, zero
/// distortion. Falls back to focal lengths with the principal point at the image centre (as
/// OpenCV initialises) when the closed form is degenerate or its principal point lands outside
/// the image, and uses that directly when the principal point is fixed.
pub(crate) fn pinhole_start(
    views: &[ViewData],
    image_size: (u32, u32),
    fix_principal_point: bool,
) -> CoreResult<Intrinsics> {
    let hs: Vec<Matrix3<f64>> = views
        .iter()
        .filter_map(|v| {
            let src: Vec<Vector2<f64>> = v.object.iter().map(|p| p.xy()).collect();
            homography(&src, &v.pixels).ok()
        })
        .collect();
    let centre = image_centre(image_size);
    if !fix_principal_point && let Ok(k) = zhang_intrinsics(&hs, image_size) {
        let (w, h) = (f64::from(image_size.0), f64::from(image_size.1));
        if k.cx > 0.0 && k.cx < w && k.cy > 0.0 && k.cy < h {
            return Ok(k);
        }
    }
    intrinsics_fixed_centre(&hs, centre, image_size)
}
