//! Kalibr's IMU noise file, `imu.yaml`, from plain values.
//!
//! Field list: `ImuParameters` in
//! `ethz-asl/kalibr: aslam_offline_calibration/kalibr/python/kalibr_common/ConfigReader.py`
//! (the four noise values, `update_rate` and `rostopic`). Kalibr loads the file with PyYAML, a
//! YAML 1.1 reader that types `2e-3` as a string, so every number is written by
//! [`yaml_number`], which always produces a YAML 1.1 float.
//!
//! A random walk that the log was too short to determine may be replaced by an upper bound,
//! marked by a comment; without a value or a bound the file is refused rather than written with
//! an invented number.

use super::yaml::{self, yaml_number};
use crate::error::{CoreError, CoreResult};

/// The values of a Kalibr `imu.yaml` (SI units, as Kalibr expects).
#[derive(Clone, Debug, PartialEq)]
pub struct KalibrImuValues {
    /// `accelerometer_noise_density`, m/s²/√Hz.
    pub accelerometer_noise_density: f64,
    /// `accelerometer_random_walk`, m/s³/√Hz; `None` when the log could not determine it.
    pub accelerometer_random_walk: Option<f64>,
    /// Written in place of a missing `accelerometer_random_walk`, with a comment saying so.
    pub accelerometer_random_walk_upper_bound: Option<f64>,
    /// `gyroscope_noise_density`, rad/s/√Hz.
    pub gyroscope_noise_density: f64,
    /// `gyroscope_random_walk`, rad/s²/√Hz; `None` when the log could not determine it.
    pub gyroscope_random_walk: Option<f64>,
    /// Written in place of a missing `gyroscope_random_walk`, with a comment saying so.
    pub gyroscope_random_walk_upper_bound: Option<f64>,
    /// `update_rate`, Hz.
    pub update_rate: f64,
    /// `rostopic` (Kalibr's example: `/imu0`).
    pub rostopic: String,
}

/// Renders Kalibr's `imu.yaml`:
///
/// ```text
/// # Kalibr imu.yaml written by Caliper from an imu_noise document
/// accelerometer_noise_density: 2.0e-03
/// accelerometer_random_walk: 3.0e-05  # upper bound: the log is too short to determine it
/// gyroscope_noise_density: 1.7e-04
/// gyroscope_random_walk: 2.0e-06
/// rostopic: /imu0
/// update_rate: 200.0
/// ```
///
/// A random walk that is `None` is written as its upper bound with that comment.
///
/// Errors: [`CoreError::InvalidInput`] naming the key when a random walk has neither a value nor
/// an upper bound, or when a number is not finite; [`CoreError::InvalidParam`] for an empty
/// `rostopic` or one with control characters. A topic made only of ROS name characters and
/// starting with `/` is written plain, any other is double-quoted.
pub fn kalibr_imu_yaml(v: &KalibrImuValues) -> CoreResult<String> {
    let mut out = String::from("# Kalibr imu.yaml written by Caliper from an imu_noise document\n");
    let noise = [
        (
            "accelerometer_noise_density",
            Some(v.accelerometer_noise_density),
            None,
        ),
        (
            "accelerometer_random_walk",
            v.accelerometer_random_walk,
            v.accelerometer_random_walk_upper_bound,
        ),
        (
            "gyroscope_noise_density",
            Some(v.gyroscope_noise_density),
            None,
        ),
        (
            "gyroscope_random_walk",
            v.gyroscope_random_walk,
            v.gyroscope_random_walk_upper_bound,
        ),
    ];
    for (key, value, bound) in noise {
        match (value, bound) {
            (Some(x), _) => out.push_str(&format!("{key}: {}\n", number(key, x)?)),
            (None, Some(b)) => out.push_str(&format!(
                "{key}: {}  # upper bound: the log is too short to determine it\n",
                number(key, b)?
            )),
            (None, None) => {
                return Err(CoreError::input(format!(
                    "{key} could not be determined from this log; no Kalibr file can be written"
                )));
            }
        }
    }
    out.push_str(&format!("rostopic: {}\n", topic(&v.rostopic)?));
    out.push_str(&format!(
        "update_rate: {}\n",
        number("update_rate", v.update_rate)?
    ));
    Ok(out)
}

/// `x` through [`yaml_number`], refusing NaN and infinities (no Kalibr value can be one).
fn number(key: &str, x: f64) -> CoreResult<String> {
    if !x.is_finite() {
        return Err(CoreError::input(format!(
            "{key} must be a finite number, got {x}"
        )));
    }
    Ok(yaml_number(x))
}

/// A ROS graph name (`/`, letters, digits, `_`) starting with `/` is a plain YAML string;
/// anything else is quoted so that YAML cannot read it as another type or structure.
fn topic(t: &str) -> CoreResult<String> {
    if t.is_empty() {
        return Err(CoreError::param("rostopic", "must not be empty"));
    }
    let plain = t.starts_with('/')
        && t.bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'/');
    if plain {
        Ok(t.to_string())
    } else {
        yaml::quote("rostopic", t)
    }
}
