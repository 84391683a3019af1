//! The IMU job kinds: `imu_noise` (Allan deviation), `imu_intrinsics` (multi-position scale,
//! misalignment and bias) and `imu_thermal` (bias vs temperature). Each reads the dataset's one
//! log as a stream (gzip decompressed on the fly), so memory stays bounded for logs of
//! hundreds of MB; the science is in `caliper_core::imu`.

use std::io::{BufRead, BufReader, Read};

use caliper_core::Progress;
use caliper_core::imu::{
    ImuIntrinsicsParams, ImuNoiseParams, ImuThermalParams, allan_svg, imu_intrinsics, imu_noise,
    imu_thermal, thermal_svg,
};
use serde_json::{Value, json};

use super::{
    Artifact, CliContext, Export, JobError, JobInput, JobOutput, JsonParams, Kind, ParamError,
    RunError, to_value,
};
use crate::store::DatasetKind;

/// Open the dataset's log for streaming, decompressing gzip.
fn open_log(input: &JobInput) -> Result<Box<dyn BufRead>, JobError> {
    let f = input.files.first().ok_or_else(|| JobError::Permanent {
        code: "invalid_input",
        message: "the dataset has no file".into(),
    })?;
    open_log_file(input, f)
}

/// Open one log file of the input (its own dataset's or the second one's) for streaming.
pub(crate) fn open_log_file(
    input: &JobInput,
    f: &crate::store::DatasetFile,
) -> Result<Box<dyn BufRead>, JobError> {
    let raw = (input.open)(f)
        .map_err(|e| JobError::Transient(format!("storage: cannot open {}: {e}", f.name)))?;
    let reader: Box<dyn Read> = if f.media_type == "application/gzip" {
        Box::new(flate2::read::MultiGzDecoder::new(raw))
    } else {
        Box::new(raw)
    };
    Ok(Box::new(BufReader::with_capacity(1 << 20, reader)))
}

/// `imu_noise`: Allan deviation and the noise model of a static log.
pub struct ImuNoise;

impl Kind for ImuNoise {
    const NAME: &'static str = "imu_noise";
    const SCHEMA: &'static str = "caliper.imu_noise/v1";
    const DATASET: DatasetKind = DatasetKind::ImuLog;
    const DESCRIPTION: &'static str = "Allan deviation of a static IMU log: noise density N, bias instability B and random walk K per axis, fitted by weighted NNLS, with Kalibr imu.yaml values. A log in which the IMU moves is refused (invalid_input naming the moving intervals) unless params.motion is longest_static (analyse the longest static stretch) or ignore.";
    const EXPORTS: &'static [Export] = &[Export {
        format: "kalibr-yaml",
        media_type: "application/yaml",
        render: crate::exports::kalibr_imu_yaml,
    }];
    type Params = ImuNoiseParams;
    type Cli = JsonParams;

    fn check(p: &mut ImuNoiseParams) -> Result<(), ParamError> {
        p.validate().map_err(|e| ParamError::from_core("", e))
    }
    fn cli_params(a: &JsonParams, _: &CliContext<'_>) -> Result<Value, RunError> {
        a.value()
    }
    fn run(
        &self,
        p: ImuNoiseParams,
        input: &JobInput,
        progress: &dyn Progress,
    ) -> Result<JobOutput, JobError> {
        let report = imu_noise(open_log(input)?, &p, progress)?;
        let quality = json!({
            "rate_hz": report.rate_hz,
            "duration_s": report.duration_s,
            "samples": report.samples,
            "moving_intervals_s": report.static_analysis.moving_intervals_s,
            "used_interval_s": report.static_analysis.used_interval_s,
            "kalibr": report.kalibr,
            "warnings": report.warnings.len(),
        });
        Ok(JobOutput {
            parameters: to_value(&report)?,
            quality,
            artifacts: vec![Artifact::svg("allan.svg", allan_svg(&report))],
        })
    }
}

/// `imu_intrinsics`: multi-position accelerometer and gyroscope calibration.
pub struct ImuIntrinsics;

impl Kind for ImuIntrinsics {
    const NAME: &'static str = "imu_intrinsics";
    const SCHEMA: &'static str = "caliper.imu_intrinsics/v1";
    const DATASET: DatasetKind = DatasetKind::ImuLog;
    const DESCRIPTION: &'static str = "Multi-position calibration (Tedaldi et al. 2014): accelerometer and gyroscope scale, misalignment and bias from static poses.";
    type Params = ImuIntrinsicsParams;
    type Cli = JsonParams;

    fn check(p: &mut ImuIntrinsicsParams) -> Result<(), ParamError> {
        p.validate().map_err(|e| ParamError::from_core("", e))
    }
    fn cli_params(a: &JsonParams, _: &CliContext<'_>) -> Result<Value, RunError> {
        a.value()
    }
    fn run(
        &self,
        p: ImuIntrinsicsParams,
        input: &JobInput,
        progress: &dyn Progress,
    ) -> Result<JobOutput, JobError> {
        let report = imu_intrinsics(open_log(input)?, &p, progress)?;
        let quality = json!({
            "usable_poses": report.usable_poses,
            "rate_hz": report.rate_hz,
            "duration_s": report.duration_s,
            "warnings": report.warnings.len(),
        });
        Ok(JobOutput {
            parameters: to_value(&report)?,
            quality,
            artifacts: vec![],
        })
    }
}

/// `imu_thermal`: bias against temperature.
pub struct ImuThermal;

impl Kind for ImuThermal {
    const NAME: &'static str = "imu_thermal";
    const SCHEMA: &'static str = "caliper.imu_thermal/v1";
    const DATASET: DatasetKind = DatasetKind::ImuLog;
    const DESCRIPTION: &'static str = "Per-axis bias as a polynomial in (T − T_ref) over the recorded temperature range (PX4 convention), with residuals.";
    type Params = ImuThermalParams;
    type Cli = JsonParams;

    fn check(p: &mut ImuThermalParams) -> Result<(), ParamError> {
        p.validate().map_err(|e| ParamError::from_core("", e))
    }
    fn cli_params(a: &JsonParams, _: &CliContext<'_>) -> Result<Value, RunError> {
        a.value()
    }
    fn run(
        &self,
        p: ImuThermalParams,
        input: &JobInput,
        progress: &dyn Progress,
    ) -> Result<JobOutput, JobError> {
        let report = imu_thermal(open_log(input)?, &p, progress)?;
        let quality = json!({
            "degree": report.degree,
            "valid_range_c": report.valid_range_c,
            "warnings": report.warnings.len(),
        });
        Ok(JobOutput {
            parameters: to_value(&report)?,
            quality,
            artifacts: vec![Artifact::svg("thermal.svg", thermal_svg(&report))],
        })
    }
}
