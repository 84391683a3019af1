//! The error type shared by every core algorithm.
//!
//! Errors are classified so that the job runner can decide whether a retry could help:
//! bad input never will, so it fails the job at once with a clear message.

use thiserror::Error;

/// Result alias for core algorithms.
pub type CoreResult<T> = Result<T, CoreError>;

/// What can go wrong inside an algorithm.
#[derive(Debug, Error)]
pub enum CoreError {
    /// The input cannot be used (undecodable, too large, too small, inconsistent).
    /// Permanent: the same input will fail the same way.
    #[error("invalid input: {0}")]
    InvalidInput(String),
    /// The parameters are inconsistent with each other or with the input. Permanent.
    #[error("invalid parameter `{field}`: {message}")]
    InvalidParam { field: String, message: String },
    /// The caller asked to stop (job canceled or shutting down).
    #[error("canceled")]
    Canceled,
    /// The algorithm ran but did not reach a usable answer (e.g. no convergence). Permanent.
    #[error("no solution: {0}")]
    NoSolution(String),
}

impl CoreError {
    /// Shorthand for [`CoreError::InvalidInput`].
    pub fn input(msg: impl Into<String>) -> Self {
        Self::InvalidInput(msg.into())
    }

    /// Shorthand for [`CoreError::InvalidParam`].
    pub fn param(field: impl Into<String>, message: impl Into<String>) -> Self {
        Self::InvalidParam {
            field: field.into(),
            message: message.into(),
        }
    }
}
