//! A gyro trace cut out of an IMU log for one exposure, so that a deblur can use the IMU log a
//! device recorded beside its frames (offline `--gyro imu0.csv`, and any caller holding a
//! log) instead of a hand-made trace.

use std::io::BufRead;

use super::GyroSample;
use crate::error::{CoreError, CoreResult};
use crate::imu::{ImuCsvParams, read_imu_log};
use crate::progress::Progress;

/// The gyro samples of an IMU log (the `imu_noise` formats: ns timestamps, gyro in rad/s)
/// over the exposure that starts at `start_ns` on the log's clock and lasts `exposure_s`, with
/// one sample either side so that the trace spans it. Times count from the exposure start
/// (so the trace's `exposure_start_s` is 0).
pub fn gyro_trace_from_log(
    log: impl BufRead,
    start_ns: i64,
    exposure_s: f64,
    progress: &dyn Progress,
) -> CoreResult<Vec<GyroSample>> {
    if !(exposure_s.is_finite() && exposure_s > 0.0) {
        return Err(CoreError::param("exposure_s", "must be finite and > 0"));
    }
    let log = read_imu_log(log, &ImuCsvParams::default(), progress)?;
    let t = log.times_s();
    let (Some(&t_first), Some(&t_last)) = (t.first(), t.last()) else {
        return Err(CoreError::input("the IMU log has no samples"));
    };
    let a = start_ns.saturating_sub(log.t0_ns()) as f64 * 1e-9;
    let b = a + exposure_s;
    if a < t_first || b > t_last {
        return Err(CoreError::input(format!(
            "the log covers {t_first:.6}–{t_last:.6} s from its first sample, the exposure \
             needs {a:.6}–{b:.6} s"
        )));
    }
    let first = t.partition_point(|&x| x < a).saturating_sub(1);
    let end = (t.partition_point(|&x| x <= b) + 1).min(t.len());
    Ok((first..end)
        .map(|i| GyroSample {
            t: t[i] - a,
            w: [log.value(0, i), log.value(1, i), log.value(2, i)],
        })
        .collect())
}
