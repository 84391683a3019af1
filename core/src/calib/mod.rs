//! Monocular camera calibration from planar-board corners.
//!
//! The pipeline is Zhang's ("A flexible new technique for camera calibration", TPAMI 22(11),
//! 2000), with the refinements that mature tools (OpenCV `calibrateCamera`, Ceres, mrcal) add:
//!
//! 1. a homography per view by the normalised DLT, refined on the reprojection error
//!    ([`homography`]);
//! 2. a start for the camera that needs no guess: Zhang's closed-form intrinsics for the pinhole
//!    ([`zhang_intrinsics`], falling back to [`intrinsics_fixed_centre`]), and a focal-length
//!    search with an equidistant (or stereographic) start for the wide-angle models;
//! 3. a pose per view from the camera ([`estimate_pose`]);
//! 4. a joint Levenberg-Marquardt over intrinsics, distortion and every pose, the poses on
//!    SE(3), with a robust loss ([`crate::optim`]);
//! 5. outlier rejection (corners far beyond the robust residual spread, views far worse than the
//!    median view), each with its reason, and a re-solve;
//! 6. RMS recomputed from the final parameters, per-view and per-corner residuals, standard
//!    deviations of the intrinsics from `σ²·(JᵀJ)⁻¹` marginalised over the poses, and the
//!    resulting 1σ uncertainty of the projection at the image centre and corners (after mrcal's
//!    "projection uncertainty", here in its simplest form: a fixed ray in the camera frame).
//!
//! Board convention (OpenCV): inner corner `index = row·cols + col` sits at
//! `(col·square, row·square, 0)` in the board frame; poses are `T_cam_board`, reported as
//! OpenCV `rvec`/`tvec`.
//!
//! Files: `types` (inputs, options and the [`Calibration`] report), `solve` ([`calibrate`]:
//! steps 2–4 and the reject-and-resolve loop), `reject` (step 5), `finish` (step 6); the
//! building blocks are `homography`, `zhang`, `init` (starting cameras), `pnp` (poses) and
//! `problem` (the least-squares problem); [`report`] draws coverage maps. `select` chooses
//! diverse views among many candidates and `clip` (feature `video`) finds those candidates in
//! a video clip.

#[cfg(feature = "video")]
pub mod clip;
mod finish;
mod homography;
mod init;
mod pnp;
mod problem;
mod reject;
pub mod report;
mod select;
mod solve;
mod types;
mod zhang;

#[cfg(test)]
mod tests;

pub use homography::{homography, homography_dlt, refine_homography, transfer};
pub use pnp::estimate_pose;
pub use select::{ViewCandidate, ViewDecision, ViewSelection, select_views};
pub use solve::calibrate;
pub use types::{
    BoardGeometry, CalibOptions, Calibration, CornerObservation, CornerResidual,
    MIN_CORNERS_PER_VIEW, MIN_VIEWS, ModelKind, ParameterEstimate, PlanarTarget,
    ProjectionUncertainty, RejectedCorner, RejectedView, ViewObservations, ViewResult,
};
pub use zhang::{Intrinsics, intrinsics_fixed_centre, pose_from_homography, zhang_intrinsics};
