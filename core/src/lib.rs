//! Caliper's core: calibration numerics with no I/O beyond decoding bytes handed to it,
//! no async and no HTTP. Every long-running algorithm takes a [`progress::Progress`] so that
//! callers (the worker pool, the CLI) can show progress and cancel cooperatively.

pub mod blur;
pub mod board;
pub mod calib;
pub mod camera;
pub mod deconv;
pub mod error;
pub mod export;
#[doc(hidden)]
pub mod fuzz_harness;
pub mod imu;
pub mod io;
pub mod lie;
pub mod optim;
pub mod photometric;
mod plot_axis;
pub mod progress;
pub mod rig;
mod stats;
pub mod synth;
#[cfg(test)]
mod test_env;
mod union_find;
#[cfg(feature = "video")]
pub mod video;

pub use error::{CoreError, CoreResult};
pub use progress::{NoProgress, Progress};
