//! Pose of a planar board seen by a known camera (planar PnP).

use nalgebra::{Matrix3, Vector2, Vector3};

use super::ModelKind;
use super::homography::homography;
use super::problem::{CalibProblem, ViewData};
use super::zhang::pose_from_homography;
use crate::camera::{Camera, CameraModel};
use crate::error::{CoreError, CoreResult};
use crate::lie::Se3;
use crate::optim::{LmOptions, solve};
use crate::progress::Progress;

/// Rays closer than this to the image plane (bearing z below it, ≈ 84° off-axis) are left out
/// of the homography: on the z = 1 plane they are far away and dominate the DLT. The nonlinear
/// refinement uses every corner.
const MIN_BEARING_Z: f64 = 0.1;

/// Pose `T_cam_board` of a planar board (points `(x, y, 0)`) from its pixels, for any camera
/// model: each pixel is unprojected to a bearing, the bearings are put on the z = 1 plane, a
/// homography from the board to that plane gives the pose as in Zhang (2000) with K = I, and
/// Levenberg-Marquardt on the reprojection error in pixels refines it (the camera held fixed).
///
/// Going through bearings rather than the model's own pixels is what lets one routine serve
/// pinhole, fisheye and double-sphere cameras. Errors: [`CoreError::InvalidInput`] for fewer
/// than 4 points or mismatched lengths, [`CoreError::NoSolution`] when too few pixels have a ray
/// or the layout is degenerate, [`CoreError::Canceled`].
pub fn estimate_pose(
    camera: &Camera,
    board_points: &[Vector2<f64>],
    pixels: &[Vector2<f64>],
    progress: &dyn Progress,
) -> CoreResult<Se3> {
    if board_points.len() != pixels.len() {
        return Err(CoreError::input(format!(
            "pose: {} board points but {} pixels",
            board_points.len(),
            pixels.len()
        )));
    }
    if board_points.len() < 4 {
        return Err(CoreError::input(format!(
            "pose: needs at least 4 points, got {}",
            board_points.len()
        )));
    }
    let view = ViewData {
        object: board_points
            .iter()
            .map(|p| Vector3::new(p.x, p.y, 0.0))
            .collect(),
        pixels: pixels.to_vec(),
    };
    Ok(pose_for_view(camera, &view, 50, progress)?.0)
}

/// [`estimate_pose`] on solver data with a given refinement budget; also returns the RMS
/// reprojection error of the refined pose.
pub(crate) fn pose_for_view(
    camera: &Camera,
    view: &ViewData,
    max_iterations: usize,
    progress: &dyn Progress,
) -> CoreResult<(Se3, f64)> {
    let mut src = Vec::with_capacity(view.object.len());
    let mut dst = Vec::with_capacity(view.object.len());
    for (x, px) in view.object.iter().zip(&view.pixels) {
        if let Some(b) = camera.unproject(px)
            && b.z > MIN_BEARING_Z
        {
            src.push(Vector2::new(x.x, x.y));
            dst.push(Vector2::new(b.x / b.z, b.y / b.z));
        }
    }
    if src.len() < 4 {
        return Err(CoreError::NoSolution(format!(
            "pose: only {} of {} corners have a ray in front of the camera",
            src.len(),
            view.object.len()
        )));
    }
    let h = homography(&src, &dst)?;
    let mut pose = pose_from_homography(&h, &Matrix3::identity())?;
    let kind = ModelKind::of(camera);
    let views = std::slice::from_ref(view);
    let problem = CalibProblem {
        kind,
        views,
        aspect: None,
        known: Some(camera),
    };
    let mut shared = camera.params().to_vec();
    let fixed = vec![true; shared.len()];
    let options = LmOptions {
        max_iterations,
        function_tolerance: 1e-10,
        ..LmOptions::default()
    };
    let mut poses = [pose];
    let summary = solve(
        &problem,
        &mut shared,
        &fixed,
        &mut poses,
        &options,
        progress,
    )?;
    pose = poses[0];
    let n = view.object.len().max(1) as f64;
    Ok((pose, (2.0 * summary.final_cost / n).sqrt()))
}
