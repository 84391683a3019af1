//! The rig calibration's inputs, options and report ([`RigCalibration`]).

use serde::{Deserialize, Serialize};

use crate::calib::{CalibOptions, ModelKind, ParameterEstimate, ViewObservations};
use crate::camera::Camera;
use crate::error::{CoreError, CoreResult};
use crate::optim::{RobustLoss, Termination};

use super::rectify::Rectification;

/// Fewest frames in which a camera and the rest of the rig must see the board together for its
/// extrinsics to be estimated (one would do in theory; three let a bad detection stand out).
pub const MIN_SHARED_FRAMES: usize = 3;

/// Most cameras in one rig (each adds a dense block to the reduced system; beyond this a rig is
/// better calibrated in overlapping groups).
pub const MAX_CAMERAS: usize = 16;

/// One camera of the rig and what it saw, frame by frame.
#[derive(Clone, Debug, PartialEq)]
pub struct RigCameraInput {
    /// Name for reports (`cam0`, `left`…).
    pub name: String,
    /// Model to calibrate (ignored when `fixed` is given: the fixed camera's model is used).
    pub model: ModelKind,
    /// Image size `[width, height]`.
    pub image_size: [u32; 2],
    /// One entry per synchronised frame (the same length for every camera); `None` where the
    /// board was not detected. Partial views are fine.
    pub views: Vec<Option<ViewObservations>>,
    /// Known intrinsics to keep fixed (from an earlier calibration), or `None` to estimate them.
    pub fixed: Option<Camera>,
}

/// Settings of [`super::calibrate_rig`]. Every field has a default.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct RigOptions {
    /// Per-camera options (fixed parameters, loss, rejection thresholds), used for each camera's
    /// own calibration and for the joint solve.
    pub camera: CalibOptions,
    /// Iteration budget of the joint Levenberg-Marquardt solve.
    pub max_iterations: usize,
    /// Robust loss of the joint solve (scale in pixels).
    pub loss: RobustLoss,
    /// Drop corners whose joint residual is an outlier (same thresholds as `camera`) and solve
    /// again.
    pub reject_outliers: bool,
    /// Refine the intrinsics in the joint solve (default). Off: each camera keeps its own
    /// calibration and only the extrinsics and board poses move, as OpenCV's
    /// `stereoCalibrate` with `CALIB_FIX_INTRINSIC`.
    pub refine_intrinsics: bool,
}

impl Default for RigOptions {
    fn default() -> Self {
        Self {
            camera: CalibOptions::default(),
            max_iterations: 100,
            loss: RobustLoss::Huber { scale: 1.0 },
            reject_outliers: true,
            refine_intrinsics: true,
        }
    }
}

impl RigOptions {
    /// Checks the numbers.
    pub fn validate(&self) -> CoreResult<()> {
        self.loss.validate()?;
        if self.max_iterations == 0 {
            return Err(CoreError::param("max_iterations", "must be at least 1"));
        }
        Ok(())
    }
}

/// A rigid transform written the way documents carry it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct PoseDoc {
    /// Rotation as a unit quaternion `[w, x, y, z]`.
    pub quaternion_wxyz: [f64; 4],
    /// Rotation as an OpenCV Rodrigues vector, radians.
    pub rvec: [f64; 3],
    /// Rotation matrix, row-major.
    pub rotation_matrix: [[f64; 3]; 3],
    /// Translation, in board units.
    pub translation: [f64; 3],
}

/// 1σ uncertainty of one extrinsic transform, from the joint covariance.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct ExtrinsicSigma {
    /// σ of the translation components, board units.
    pub translation: [f64; 3],
    /// σ of the rotation about x, y, z (left perturbation), degrees.
    pub rotation_deg: [f64; 3],
    /// σ of the baseline (distance between the optical centres), board units.
    pub baseline: f64,
}

/// The pose of one camera relative to the reference camera (`cam 0`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct Extrinsic {
    /// Camera index.
    pub camera: usize,
    /// Camera name.
    pub name: String,
    /// `T_cam_i_cam0`: maps a point from the reference camera's frame into this camera's frame
    /// (OpenCV `stereoCalibrate`'s `R`, `T` for the pair (cam0, cam i)).
    pub t_cam_cam0: PoseDoc,
    /// Distance between the optical centres, board units.
    pub baseline: f64,
    /// Rotation angle between the two cameras, degrees.
    pub rotation_deg: f64,
    /// 1σ uncertainty (`None` for the reference camera, or when no covariance was available).
    pub sigma: Option<ExtrinsicSigma>,
}

/// One calibrated camera of the rig.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct RigCameraResult {
    /// Camera name.
    pub name: String,
    /// The calibrated (or fixed) camera.
    pub camera: Camera,
    /// Image size `[width, height]`.
    pub image_size: [u32; 2],
    /// Each intrinsic parameter with its σ from the joint solve.
    pub parameters: Vec<ParameterEstimate>,
    /// Intrinsics held at given values.
    pub intrinsics_fixed: bool,
    /// RMS reprojection error of this camera's inlier corners in the joint solve, pixels.
    pub rms: f64,
    /// RMS of this camera's own (monocular) calibration, pixels (`None` with fixed intrinsics).
    pub mono_rms: Option<f64>,
    /// Frames in which this camera saw the board.
    pub frames_seen: usize,
    /// Frames of this camera used in the joint solve.
    pub frames_used: usize,
    /// Corners of this camera used in the joint solve.
    pub corners_used: usize,
}

/// The rectified geometry of a pair of cameras `(a, b)`, with its rectification quality.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct StereoPair {
    /// First camera (the reference of the pair).
    pub a: usize,
    /// Second camera.
    pub b: usize,
    /// Rectifying rotations and projections (OpenCV `stereoRectify` names).
    pub rectification: Rectification,
    /// RMS of the vertical (horizontal for a vertical rig) disparity of the same corner seen by
    /// both cameras, after rectification: 0 for a perfect calibration, pixels.
    pub epipolar_rms_px: f64,
    /// Corner pairs the epipolar error is computed over.
    pub epipolar_points: usize,
}

/// What happened to one synchronised frame.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct RigFrameResult {
    /// Frame index.
    pub index: usize,
    /// Cameras that saw the board.
    pub seen_by: Vec<usize>,
    /// Used in the joint solve.
    pub used: bool,
    /// Why not, when not.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
    /// `T_cam0_board` as OpenCV `rvec` (for used frames).
    pub rvec: Option<[f64; 3]>,
    /// `T_cam0_board` translation, board units.
    pub tvec: Option<[f64; 3]>,
    /// RMS over the frame's inlier corners in all cameras, pixels.
    pub rms: Option<f64>,
}

/// The outcome of [`super::calibrate_rig`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct RigCalibration {
    /// Cameras, in input order; camera 0 is the reference frame.
    pub cameras: Vec<RigCameraResult>,
    /// `T_cam_i_cam0` for every camera (identity for camera 0).
    pub extrinsics: Vec<Extrinsic>,
    /// Rectification of every pair (cam0, cam i).
    pub pairs: Vec<StereoPair>,
    /// RMS reprojection error over all inlier corners of all cameras, pixels.
    pub rms: f64,
    /// Residual σ per coordinate `√(Σ‖r‖²/(2N − p))`, the σ of the covariance.
    pub sigma: f64,
    /// Corners used, over all cameras.
    pub corners_used: usize,
    /// Corners left out as outliers.
    pub corners_rejected: usize,
    /// Per frame, in input order.
    pub frames: Vec<RigFrameResult>,
    /// Levenberg-Marquardt iterations of the joint solves.
    pub iterations: usize,
    /// How the last joint solve ended.
    pub termination: Termination,
    /// Anything the caller should know.
    pub warnings: Vec<String>,
}
