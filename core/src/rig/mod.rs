//! Calibration of rigs of 2..N synchronised cameras (stereo pairs, multi-camera heads) from a
//! planar board seen by some or all of them in each frame.
//!
//! Method: every camera is first calibrated on its own ([`crate::calib::calibrate`], or posed
//! with intrinsics kept fixed); the extrinsics start from a robust average of the relative
//! poses in shared frames; then one joint Levenberg-Marquardt refines all intrinsics, the
//! extrinsics `T_cam_i_cam0` (on SE(3), left perturbations) and one board pose per frame — the
//! problem Kalibr's camera-chain calibration and OpenCV `stereoCalibrate` solve — with outlier
//! rejection. The report gives per-camera RMS, baselines, rotations, the σ of every extrinsic
//! parameter from the marginal covariance, and per pair (cam0, cam i) Bouguet's rectification
//! with the RMS epipolar error of the rectified corners.
//!
//! Files: `types` (inputs, options, report), `init` (per-camera starts, extrinsic averaging and
//! corner-numbering consistency), `problem` (the least-squares problem), `solve`
//! ([`calibrate_rig`]), [`rectify`] (Bouguet rectification, epipolar error, resampling).

mod init;
mod problem;
pub mod rectify;
mod solve;
mod types;

#[cfg(test)]
mod tests;

pub use rectify::{Rectification, rectify_gray, rectify_pixel, stereo_rectify};
pub use solve::calibrate_rig;
pub use types::{
    Extrinsic, ExtrinsicSigma, MAX_CAMERAS, MIN_SHARED_FRAMES, PoseDoc, RigCalibration,
    RigCameraInput, RigCameraResult, RigFrameResult, RigOptions, StereoPair,
};
