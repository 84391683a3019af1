//! Nonlinear least squares (being written).
