//! Black-box tests of the Caliper service through real HTTP on 127.0.0.1.
//!
//! One test binary (link time), one module per area. Inputs are rendered in-test; nothing
//! here needs files outside the repository.

mod auth;
mod browser;
mod camera;
mod clip_calibration;
mod common;
mod crash_loop;
mod dashboard;
mod datasets;
mod deblur;
mod deblur_gyro_clip;
mod documents;
mod errors;
mod hardening;
mod imu;
mod jobs;
mod offline;
mod openapi;
mod overload;
mod photometric;
mod photometric_clip;
mod postgres;
mod readme;
mod recovery;
mod registry;
mod rig;
mod s3;
mod targets;
mod video;
