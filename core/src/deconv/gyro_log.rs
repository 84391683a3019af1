//! Gyro traces cut out of an IMU log, so that a deblur can use the log a device recorded
//! beside its frames instead of a hand-made trace: one exposure of a still (offline
//! `--gyro imu0.csv`), or every chosen frame of a clip ([`GyroClipParams`]), each frame with
//! the exposure window its presentation time places on the log's clock.

use std::io::BufRead;

use serde::{Deserialize, Serialize};

use super::GyroSample;
use super::gyro::{GyroPsfParams, check_intrinsics};
use crate::error::{CoreError, CoreResult};
use crate::imu::{ImuCsvParams, ImuLog, read_imu_log};
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
    GyroLog::new(&log).trace(start_ns, exposure_s)
}

/// A parsed IMU log with its sample times, ready to cut many traces from.
pub struct GyroLog<'a> {
    log: &'a ImuLog,
    /// Sample times, s from the first sample.
    t: Vec<f64>,
}

impl<'a> GyroLog<'a> {
    /// Index the log's sample times once (they are stored as deltas).
    pub fn new(log: &'a ImuLog) -> Self {
        Self {
            log,
            t: log.times_s(),
        }
    }

    /// The trace over `[start_ns, start_ns + exposure_s]` on the log's clock (see
    /// [`gyro_trace_from_log`]); an error says which span the log covers.
    pub fn trace(&self, start_ns: i64, exposure_s: f64) -> CoreResult<Vec<GyroSample>> {
        let t = &self.t;
        let (Some(&t_first), Some(&t_last)) = (t.first(), t.last()) else {
            return Err(CoreError::input("the IMU log has no samples"));
        };
        let a = start_ns.saturating_sub(self.log.t0_ns()) as f64 * 1e-9;
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
                w: [
                    self.log.value(0, i),
                    self.log.value(1, i),
                    self.log.value(2, i),
                ],
            })
            .collect())
    }
}

/// Method `gyro` on a clip: where each frame's exposure lies on the IMU log's clock, and the
/// pinhole intrinsics the kernels are drawn with. A frame shown at presentation time `pts`
/// is exposed over `[clip_start_ns + pts·10⁹, … + exposure_s]` ns on the log's clock
/// (devices that stamp the middle of the exposure: subtract half the exposure from
/// `clip_start_ns`). One exposure time for all frames: auto-exposure clips whose exposure
/// changes per frame are restored with the given one.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct GyroClipParams {
    /// Id of the `imu_log` dataset holding the device's log (gyro in rad/s, ns timestamps on
    /// the same clock as `clip_start_ns`). Required by the service; `caliper run` takes the
    /// log from `--gyro` instead.
    #[serde(default)]
    #[cfg_attr(feature = "schema", schema(format = Uuid))]
    pub imu_dataset: Option<String>,
    /// Log-clock time at which the exposure of the frame with presentation time 0 starts, ns.
    pub clip_start_ns: i64,
    /// Exposure time of every frame, s (> 0, at most 1).
    pub exposure_s: f64,
    /// Focal lengths and principal point of the clip's frames as decoded (after rotation), px.
    pub fx: f64,
    /// See `fx`.
    pub fy: f64,
    /// See `fx`.
    pub cx: f64,
    /// See `fx`.
    pub cy: f64,
    /// Rotation from the gyro frame to the camera frame as a quaternion `[w, x, y, z]`
    /// (default: the gyro axes are the camera axes, x right, y down, z forward).
    #[serde(default)]
    pub gyro_to_camera_wxyz: Option<[f64; 4]>,
}

impl GyroClipParams {
    /// Check the values alone; errors name the field (relative to `gyro_clip`).
    pub fn validate(&self) -> CoreResult<()> {
        if !(self.exposure_s.is_finite() && self.exposure_s > 0.0 && self.exposure_s <= 1.0) {
            return Err(CoreError::param(
                "exposure_s",
                "must be finite, > 0 and at most 1 s",
            ));
        }
        check_intrinsics(
            [self.fx, self.fy, self.cx, self.cy],
            self.gyro_to_camera_wxyz,
        )
    }

    /// The kernel parameters of the frame shown at `pts_s`: its exposure's trace cut out of
    /// `log`. Errors when the log does not cover that exposure.
    pub fn frame(&self, log: &GyroLog<'_>, pts_s: f64) -> CoreResult<GyroPsfParams> {
        if !pts_s.is_finite() {
            return Err(CoreError::input(
                "the frame has no finite presentation time",
            ));
        }
        let offset_ns = (pts_s * 1e9).round();
        if offset_ns.abs() > 9.0e18 {
            return Err(CoreError::input("presentation time out of range"));
        }
        let start_ns = self.clip_start_ns.saturating_add(offset_ns as i64);
        let samples = log.trace(start_ns, self.exposure_s)?;
        let p = GyroPsfParams {
            samples,
            exposure_start_s: 0.0,
            exposure_s: self.exposure_s,
            fx: self.fx,
            fy: self.fy,
            cx: self.cx,
            cy: self.cy,
            gyro_to_camera_wxyz: self.gyro_to_camera_wxyz,
        };
        p.validate()?;
        Ok(p)
    }
}
