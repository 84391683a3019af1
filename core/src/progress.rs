//! Progress reporting and cooperative cancellation for long algorithms.
//!
//! Core code is synchronous and runs on blocking threads; the caller owns the clock and the
//! cancel flag. Algorithms call [`Progress::report`] at natural step boundaries and
//! [`Progress::check`] inside their inner loops often enough (every few milliseconds of work)
//! that a cancel takes effect promptly.

use crate::error::{CoreError, CoreResult};

/// Sink for progress and source of cancellation, implemented by the job runner and the CLI.
pub trait Progress: Sync {
    /// Report that `done` of `total` units of the step named `step` are complete.
    fn report(&self, step: &str, done: u64, total: u64);

    /// Whether the caller wants the algorithm to stop.
    fn is_canceled(&self) -> bool;

    /// Return `Err(CoreError::Canceled)` if the caller asked to stop.
    fn check(&self) -> CoreResult<()> {
        if self.is_canceled() {
            Err(CoreError::Canceled)
        } else {
            Ok(())
        }
    }
}

/// A [`Progress`] that ignores reports and never cancels (tests, benchmarks).
#[derive(Debug, Default, Clone, Copy)]
pub struct NoProgress;

impl Progress for NoProgress {
    fn report(&self, _step: &str, _done: u64, _total: u64) {}

    fn is_canceled(&self) -> bool {
        false
    }
}
