//! IMU calibration: streaming log parsing, Allan deviation noise characterisation, multi-position
//! scale/misalignment/bias calibration and temperature bias models.
//!
//! - [`log`]: bounded-memory EuRoC CSV parser with defined behaviour for every kind of bad row.
//! - [`allan`]: overlapping Allan deviation (IEEE Std 952-1997; El-Sheimy, Hou & Niu 2008) and
//!   the three-term noise fit → Kalibr `imu.yaml` values ([`imu_noise`]).
//! - [`multipos`]: multi-position calibration of Tedaldi, Pretto & Menegatti, "A robust and easy
//!   to implement method for IMU calibration without external equipments", ICRA 2014
//!   ([`imu_intrinsics`]).
//! - [`motion`]: per-window motion detector, so a moving log is refused (or trimmed to its
//!   longest static stretch) before the Allan analysis.
//! - [`thermal`]: per-axis bias polynomial in (T − T_ref), PX4 convention ([`imu_thermal`]).
//!
//! Channels are ordered gyro x, y, z (rad/s) then accel x, y, z (m/s²) everywhere.

pub mod allan;
mod lm;
pub mod log;
pub mod motion;
pub mod multipos;
mod plot;
pub mod thermal;

#[cfg(test)]
mod motion_tests;
#[cfg(test)]
mod tests;

pub use allan::{ImuNoiseParams, ImuNoiseReport, imu_noise, imu_noise_from_log};
pub use log::{
    AccelUnit, GyroUnit, ImuColumns, ImuCsvParams, ImuLog, ParseStats, TimeUnit, read_imu_log,
};
pub use motion::{MotionPolicy, StaticAnalysis, detect_motion};
pub use multipos::{
    ImuIntrinsicsParams, ImuIntrinsicsReport, imu_intrinsics, imu_intrinsics_from_log,
};
pub use plot::{allan_svg, thermal_svg};
pub use thermal::{ImuThermalParams, ImuThermalReport, imu_thermal, imu_thermal_from_log};
