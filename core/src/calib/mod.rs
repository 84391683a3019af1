//! Camera calibration solvers (being written).
