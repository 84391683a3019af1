//! Calibration boards: finding the known pattern a camera is calibrated against in an image.
//!
//! One module per board type, each with its own detector that returns the board's corners in
//! the board's own order, ready for [`crate::calib::calibrate`]:
//!
//! - [`chessboard`]: plain chessboards (inner corners, OpenCV's order), [`detect_chessboard`].
//!
//! Detectors for ChArUco and AprilGrid boards will sit beside `chessboard` as sibling modules.
//! `filter` holds the floating-point image filtering they share (and the synthetic renderer
//! uses).
//!
//! The module was called `target`, a name that collides with Cargo's build folder, which many
//! tools (search, backups, editors' ignore lists) skip; hence `board`.

pub mod chessboard;
pub(crate) mod filter;

pub use chessboard::{DetectOptions, Detection, detect_chessboard};
