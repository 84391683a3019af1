//! Calibration boards: finding the known pattern a camera is calibrated against in an image.
//!
//! One module per board type, each with its own detector that returns the board's corners in
//! the board's own order, ready for [`crate::calib::calibrate`]:
//!
//! - [`chessboard`]: plain chessboards (inner corners, OpenCV's order), [`detect_chessboard`].
//! - [`charuco`]: OpenCV ChArUco boards (chessboard corners identified by ArUco markers).
//! - [`aprilgrid`]: Kalibr AprilGrids (the corners of AprilTag 36h11 tags).
//! - [`circles`]: OpenCV circle grids, symmetric and asymmetric, centres corrected for
//!   perspective.
//! - [`markers`]: the marker dictionaries and the square-marker detector the two share.
//! - [`target`]: one description of any of them ([`TargetSpec`]: JSON, Kalibr yaml, OpenCV
//!   ChArUco parameters) and one detector ([`detect_target`]) returning corners with ids, so
//!   that partial views of marker boards count.
//!
//! `filter` holds the floating-point image filtering they share (and the synthetic renderer
//! uses).
//!
//! The module was called `target`, a name that collides with Cargo's build folder, which many
//! tools (search, backups, editors' ignore lists) skip; hence `board` (the `target` submodule
//! is a source file, which those tools do not skip).

pub mod aprilgrid;
pub mod charuco;
pub mod chessboard;
pub mod circles;
pub(crate) mod filter;
pub mod markers;
pub mod target;

pub use chessboard::{DetectOptions, Detection, detect_chessboard};
pub use target::{TargetDetection, TargetOptions, TargetSpec, detect_target};
