//! The report of a finished solve: residuals and RMS from the final parameters, the residual
//! σ, the covariance of the camera parameters marginalised over the poses, and the projection
//! uncertainty it implies at the image centre and corners.

use nalgebra::{DMatrix, Matrix2, Vector2};

use super::problem::{CalibProblem, ViewData};
use super::solve::ViewState;
use super::types::{
    Calibration, CornerResidual, ModelKind, ParameterEstimate, ProjectionUncertainty,
    RejectedCorner, RejectedView, ViewResult,
};
use super::{init, pnp};
use crate::camera::{Camera, CameraModel};
use crate::error::{CoreError, CoreResult};
use crate::lie::Se3;
use crate::optim::{Termination, marginal_shared_covariance};
use crate::progress::Progress;

/// Residuals, RMS, covariance and projection uncertainty of the final estimate.
#[allow(clippy::too_many_arguments)]
pub(super) fn finish(
    mut views: Vec<ViewState>,
    camera: Camera,
    initial: Camera,
    model: ModelKind,
    image_size: (u32, u32),
    shared: &[f64],
    fixed: &[bool],
    aspect: Option<f64>,
    iterations: usize,
    termination: Termination,
    rejected_corners: Vec<RejectedCorner>,
    progress: &dyn Progress,
) -> CoreResult<Calibration> {
    let mut warnings = Vec::new();
    // Rejected views get a pose for the final camera, so their residuals mean something.
    for v in views.iter_mut().filter(|v| v.rejected.is_some()) {
        if v.data.object.len() >= 4 {
            match pnp::pose_for_view(&camera, &v.data, 50, progress) {
                Ok((pose, _)) => v.pose = Some(pose),
                Err(CoreError::Canceled) => return Err(CoreError::Canceled),
                Err(_) => v.pose = None,
            }
        }
    }

    let mut residuals = Vec::new();
    let mut view_results = Vec::with_capacity(views.len());
    let (mut sum_in, mut n_in, mut sum_all, mut n_all) = (0.0, 0usize, 0.0, 0usize);
    let mut num_corners = 0;
    for (i, v) in views.iter().enumerate() {
        num_corners += v.indices.len();
        let used = v.active();
        let (mut vs, mut vn) = (0.0, 0usize);
        for (k, (x, px)) in v.data.object.iter().zip(&v.data.pixels).enumerate() {
            let inlier = used && v.inlier[k];
            let r = v
                .pose
                .and_then(|pose| camera.project(&pose.act(x)))
                .map(|p| p - px);
            if let Some(r) = r {
                let s = r.norm_squared();
                sum_all += s;
                n_all += 1;
                if inlier {
                    sum_in += s;
                    n_in += 1;
                }
                if inlier || !used {
                    vs += s;
                    vn += 1;
                }
            }
            residuals.push(CornerResidual {
                view: i,
                index: v.indices[k],
                residual: r.map(|r| [r.x, r.y]),
                inlier,
            });
        }
        let rt = v.pose.map(|p| p.to_rvec_tvec());
        view_results.push(ViewResult {
            name: v.name.clone(),
            used,
            rvec: rt.map(|(r, _)| [r.x, r.y, r.z]),
            tvec: rt.map(|(_, t)| [t.x, t.y, t.z]),
            rms: (vn > 0).then(|| (vs / vn as f64).sqrt()),
            num_corners: v.indices.len(),
            num_inliers: if used {
                v.inlier.iter().filter(|x| **x).count()
            } else {
                0
            },
        });
    }
    let rms = if n_in > 0 {
        (sum_in / n_in as f64).sqrt()
    } else {
        f64::NAN
    };
    let rms_all = if n_all > 0 {
        (sum_all / n_all as f64).sqrt()
    } else {
        f64::NAN
    };

    // Covariance of the camera parameters, marginalised over the poses.
    let active: Vec<usize> = (0..views.len()).filter(|&i| views[i].active()).collect();
    let data: Vec<ViewData> = active.iter().map(|&i| views[i].inlier_data()).collect();
    let poses: Vec<Se3> = active.iter().filter_map(|&i| views[i].pose).collect();
    let problem = CalibProblem {
        kind: model,
        views: &data,
        aspect,
        known: Some(&camera),
    };
    let free = fixed.iter().filter(|f| !**f).count() + 6 * poses.len();
    let dof = 2 * n_in as isize - free as isize;
    let sigma = if dof > 0 {
        (sum_in / dof as f64).sqrt()
    } else {
        f64::NAN
    };
    let covariance = if dof <= 0 {
        warnings.push(format!(
            "no covariance: {} residuals for {free} free parameters",
            2 * n_in
        ));
        None
    } else {
        match marginal_shared_covariance(&problem, shared, fixed, &poses) {
            Ok(c) => {
                // Solver parameters → camera parameters (the aspect tie makes fy = ratio·fx).
                let n = c.nrows();
                let mut m = DMatrix::<f64>::identity(n, n);
                if let Some(ratio) = aspect {
                    m[(1, 0)] = ratio;
                    m[(1, 1)] = 0.0;
                }
                Some(&m * c * m.transpose() * (sigma * sigma))
            }
            Err(e) => {
                warnings.push(format!("no covariance: {e}"));
                None
            }
        }
    };
    let names = camera.param_names();
    let parameters = names
        .iter()
        .enumerate()
        .map(|(k, name)| ParameterEstimate {
            name: (*name).to_string(),
            value: camera.params()[k],
            std_dev: covariance.as_ref().map(|c| c[(k, k)].max(0.0).sqrt()),
            fixed: fixed[k] && !(k == 1 && aspect.is_some()),
        })
        .collect();

    let projection_uncertainty = covariance
        .as_ref()
        .map(|c| projection_uncertainty(&camera, image_size, c))
        .unwrap_or_default();

    let rejected_views = views
        .iter()
        .enumerate()
        .filter_map(|(i, v)| {
            v.rejected.as_ref().map(|r| RejectedView {
                view: i,
                name: v.name.clone(),
                reason: r.clone(),
            })
        })
        .collect();

    Ok(Calibration {
        camera,
        image_size: [image_size.0, image_size.1],
        parameters,
        rms,
        rms_all,
        sigma,
        num_inliers: n_in,
        num_corners,
        views: view_results,
        residuals,
        rejected_corners,
        rejected_views,
        projection_uncertainty,
        iterations,
        termination,
        initial_camera: initial,
        warnings,
    })
}

/// `J Σ Jᵀ` of the projection of the fixed rays through the image centre and corners, J the
/// 2×N Jacobian of the pixel with respect to the camera parameters.
///
/// This is the first-order propagation of the intrinsic covariance only; mrcal ("projection
/// uncertainty", Kogan) additionally accounts for the uncertainty of the reference frame the ray
/// is fixed in (through the board poses), which makes its numbers larger at short range.
fn projection_uncertainty(
    camera: &Camera,
    image_size: (u32, u32),
    cov: &DMatrix<f64>,
) -> Vec<ProjectionUncertainty> {
    let (w, h) = (f64::from(image_size.0) - 1.0, f64::from(image_size.1) - 1.0);
    let c = init::image_centre(image_size);
    let spots = [
        ("centre", c.x, c.y),
        ("top_left", 0.0, 0.0),
        ("top_right", w, 0.0),
        ("bottom_left", 0.0, h),
        ("bottom_right", w, h),
    ];
    spots
        .iter()
        .filter_map(|(label, x, y)| {
            let ray = camera.unproject(&Vector2::new(*x, *y))?;
            let (_, _, j) = camera.project_with_jacobians(&ray)?;
            let s = &j * cov * j.transpose();
            let s = Matrix2::new(s[(0, 0)], s[(0, 1)], s[(1, 0)], s[(1, 1)]);
            let major = s.symmetric_eigenvalues().max().max(0.0).sqrt();
            Some(ProjectionUncertainty {
                location: (*label).to_string(),
                pixel: [*x, *y],
                std_x: s[(0, 0)].max(0.0).sqrt(),
                std_y: s[(1, 1)].max(0.0).sqrt(),
                std_major: major,
            })
        })
        .collect()
}
