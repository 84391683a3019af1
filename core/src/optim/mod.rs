//! Nonlinear least squares for calibration: a Levenberg-Marquardt solver specialised to
//! bundle-adjustment-shaped problems (a few shared parameters, many independent 6-DoF pose
//! blocks), with robust losses and the marginal covariance of the shared parameters.
//!
//! The layout follows the way Ceres Solver and mrcal pose camera calibration (residual blocks of
//! 2 per observed corner, one parameter block for the camera, one per board pose) and solves the
//! normal equations by the Schur complement over the poses (Triggs, McLauchlan, Hartley,
//! Fitzgibbon, "Bundle adjustment — a modern synthesis", 2000; Agarwal et al., "Bundle
//! adjustment in the large", ECCV 2010). Nothing here knows about cameras: the problem is a
//! [`SchurProblem`] implemented by [`crate::calib`].

mod lm;
mod loss;

#[cfg(test)]
mod tests;

pub use lm::{
    Linearized, LmOptions, LmSummary, SchurProblem, Termination, cost, marginal_shared_covariance,
    solve,
};
pub use loss::RobustLoss;
