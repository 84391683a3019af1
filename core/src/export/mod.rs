//! Calibration exports, and readers for the same files.
//!
//! Caliper writes a [`Calibration`] in the formats downstream tools load directly, and reads
//! those files back (to compare against, or to start from, an existing calibration):
//!
//! | [`ExportFormat`] | File | Field list from | Models |
//! |---|---|---|---|
//! | `opencv-yaml` | OpenCV `FileStorage` YAML | OpenCV 4.x `samples/cpp/tutorial_code/calib3d/camera_calibration/camera_calibration.cpp` (`saveCameraParams`) | pinhole, Kannala-Brandt (`fisheye_model: 1`) |
//! | `ros-yaml` | ROS `sensor_msgs/CameraInfo` YAML | `ros-perception/image_common: camera_calibration_parsers/src/parse_yml.cpp` | pinhole (`plumb_bob`), Kannala-Brandt (`equidistant`) |
//! | `kalibr-yaml` | Kalibr `camchain.yaml` | `ethz-asl/kalibr: kalibr_common/ConfigReader.py` | pinhole (`radtan`, k3 = 0 only), Kannala-Brandt (`equidistant`), double sphere (`ds`) |
//! | `json` | Caliper's own document | [`CalibrationDocument`] | all |
//!
//! The exact field lists, in write order, are collected in `/work/shared/docs/formats.md`.
//!
//! Beside the camera formats, [`kalibr_imu_yaml`] writes Kalibr's IMU noise file (`imu.yaml`)
//! from plain values, and [`yaml_number`] is the float formatter of every YAML file written
//! here: it always produces a number PyYAML, OpenCV `FileStorage` and Kalibr read as a float.
//!
//! Design choices:
//! * **No YAML library.** OpenCV's `%YAML:1.0` header and `!!opencv-matrix` tag break
//!   conforming YAML parsers, so the YAML is written by hand and read by a strict reader for
//!   exactly the subset these files use (see the private `yaml` module).
//! * **Exact round trips.** Every `f64` is printed as its shortest round-trip decimal, so
//!   write → read gives the same bits (OpenCV `dt: f` data are `f32` by definition and come back
//!   as the `f32` rounding).
//! * **Refuse rather than approximate.** A camera a format cannot represent (double sphere in
//!   OpenCV or ROS, a pinhole with k3 ≠ 0 in Kalibr's 4-coefficient `radtan`) is an
//!   [`CoreError::InvalidParam`], never a silently different camera.
//! * **Strict readers.** Missing keys, wrong matrix shapes, non-numbers and unsupported models
//!   are [`CoreError::InvalidInput`] naming the key; keys the reader does not use (OpenCV's
//!   `image_points`, ROS's `binning_x`, Kalibr's `T_imu_body`…) are ignored.

mod json;
mod kalibr;
mod kalibr_imu;
mod opencv;
mod rig;
mod ros;
mod yaml;

#[cfg(test)]
mod tests;
#[cfg(test)]
mod tests_kalibr_imu;

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

pub use json::{
    CALIBRATION_DOCUMENT_FORMAT, CALIBRATION_DOCUMENT_VERSION, CalibrationDocument, read_json,
};
pub use kalibr::{read_kalibr_camchain, read_kalibr_yaml};
pub use kalibr_imu::{KalibrImuValues, kalibr_imu_yaml};
pub use opencv::read_opencv_yaml;
pub use rig::{rig_kalibr_camchain, rig_opencv_stereo_yaml, rig_ros_yaml};
pub use ros::read_ros_yaml;
pub use yaml::yaml_number;

use crate::calib::{BoardGeometry, CalibOptions, Calibration};
use crate::camera::Camera;
use crate::error::{CoreError, CoreResult};

/// A file format Caliper exports to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub enum ExportFormat {
    /// OpenCV `FileStorage` YAML, as the calibration sample writes it.
    OpencvYaml,
    /// ROS `sensor_msgs/CameraInfo` YAML (`camera_calibration_parsers`).
    RosYaml,
    /// Kalibr `camchain.yaml` with one camera (`cam0`).
    KalibrYaml,
    /// Caliper's JSON document ([`CalibrationDocument`]).
    Json,
}

/// YAML media type. RFC 9512 (2024) registered `application/yaml` and lists `application/x-yaml`,
/// `text/yaml` and `text/x-yaml` as deprecated aliases; the registered name is the one clients
/// and proxies are told to expect.
pub const YAML_MEDIA_TYPE: &str = "application/yaml";

impl ExportFormat {
    /// Every format, in documentation order.
    pub const ALL: [ExportFormat; 4] = [
        ExportFormat::OpencvYaml,
        ExportFormat::RosYaml,
        ExportFormat::KalibrYaml,
        ExportFormat::Json,
    ];

    /// The name used in URLs and on the command line (`opencv-yaml`, …).
    pub fn as_str(&self) -> &'static str {
        match self {
            ExportFormat::OpencvYaml => "opencv-yaml",
            ExportFormat::RosYaml => "ros-yaml",
            ExportFormat::KalibrYaml => "kalibr-yaml",
            ExportFormat::Json => "json",
        }
    }

    /// `Content-Type` of the export: [`YAML_MEDIA_TYPE`] or `application/json`.
    pub fn media_type(&self) -> &'static str {
        match self {
            ExportFormat::Json => "application/json",
            _ => YAML_MEDIA_TYPE,
        }
    }

    /// The file extension each tool's documentation uses (OpenCV samples write `.yml`, ROS and
    /// Kalibr `.yaml`).
    pub fn file_extension(&self) -> &'static str {
        match self {
            ExportFormat::OpencvYaml => "yml",
            ExportFormat::RosYaml | ExportFormat::KalibrYaml => "yaml",
            ExportFormat::Json => "json",
        }
    }
}

impl fmt::Display for ExportFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for ExportFormat {
    type Err = CoreError;

    fn from_str(s: &str) -> CoreResult<Self> {
        ExportFormat::ALL
            .into_iter()
            .find(|f| f.as_str() == s)
            .ok_or_else(|| {
                CoreError::param(
                    "format",
                    format!(
                        "unknown export format {s:?} (expected one of: opencv-yaml, ros-yaml, \
                         kalibr-yaml, json)"
                    ),
                )
            })
    }
}

/// What an export needs besides the calibration itself.
#[derive(Clone, Copy, Debug)]
pub struct ExportInput<'a> {
    /// The result to export.
    pub calibration: &'a Calibration,
    /// The board it was calibrated with (OpenCV `board_width`/`board_height`/`square_size`,
    /// JSON `board`); omitted from the files when `None`.
    pub board: Option<BoardGeometry>,
    /// The options it was calibrated with: OpenCV `flags` are derived from them. Without them
    /// the flags are inferred from [`crate::calib::ParameterEstimate::fixed`], which cannot
    /// show a fixed aspect ratio.
    pub options: Option<&'a CalibOptions>,
    /// ROS `camera_name` (and the JSON document's); [`ExportInput::new`] uses `"camera"`.
    pub camera_name: &'a str,
    /// Kalibr `rostopic`; `/cam0/image_raw` (Kalibr's example topic) when `None`, since
    /// Kalibr's `ConfigReader` requires the key.
    pub rostopic: Option<&'a str>,
    /// OpenCV `calibration_time` (the sample writes `%c`) and the JSON document's; any text.
    /// The core has no clock: the caller passes the job's time, or `None` to omit the key.
    pub calibration_time: Option<&'a str>,
}

impl<'a> ExportInput<'a> {
    /// An input with no board, no options, camera name `"camera"`, default topic and no time.
    pub fn new(calibration: &'a Calibration) -> Self {
        Self {
            calibration,
            board: None,
            options: None,
            camera_name: "camera",
            rostopic: None,
            calibration_time: None,
        }
    }

    fn validate(&self) -> CoreResult<()> {
        if let Some(board) = &self.board {
            board.validate()?;
        }
        if self.camera_name.is_empty() {
            return Err(CoreError::param("camera_name", "must not be empty"));
        }
        if self.rostopic.is_some_and(str::is_empty) {
            return Err(CoreError::param("rostopic", "must not be empty"));
        }
        let [w, h] = self.calibration.image_size;
        if w == 0 || h == 0 {
            return Err(CoreError::param(
                "image_size",
                format!("must be positive, got {w}×{h}"),
            ));
        }
        Ok(())
    }
}

/// Renders `input` in `format`.
///
/// Errors ([`CoreError::InvalidParam`]) when the format cannot represent the camera (see the
/// module docs) or an input string cannot be written (control characters, empty name).
pub fn export(input: &ExportInput<'_>, format: ExportFormat) -> CoreResult<String> {
    input.validate()?;
    match format {
        ExportFormat::OpencvYaml => opencv::write(input),
        ExportFormat::RosYaml => ros::write(input),
        ExportFormat::KalibrYaml => kalibr::write(input),
        ExportFormat::Json => json::write(input),
    }
}

/// One view's pose `T_cam_board` as OpenCV `rvec`/`tvec`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct ImportedPose {
    /// Rotation vector (axis × angle, radians).
    pub rvec: [f64; 3],
    /// Translation, in board units.
    pub tvec: [f64; 3],
}

/// A camera read from an OpenCV, ROS or Kalibr file, with whatever else the file holds.
///
/// Fields a format does not have are `None` or empty; which reader fills which is noted per
/// field.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct ImportedCamera {
    /// The camera model and its parameters.
    pub camera: Camera,
    /// `[width, height]`, pixels (OpenCV `image_width`/`image_height`, ROS the same, Kalibr
    /// `resolution`).
    pub image_size: [u32; 2],
    /// ROS `camera_name` (`"unknown"` when absent, as ROS reads it).
    pub camera_name: Option<String>,
    /// OpenCV `calibration_time`.
    pub calibration_time: Option<String>,
    /// OpenCV `board_width`, `board_height`, `square_size` (when all three are present).
    pub board: Option<BoardGeometry>,
    /// OpenCV `nr_of_frames` (`nrOfFrames`, `nframes`).
    pub num_frames: Option<usize>,
    /// OpenCV `flags`.
    pub flags: Option<i64>,
    /// OpenCV `fix_aspect_ratio` (`aspectRatio`): the fixed fx/fy.
    pub fixed_aspect_ratio: Option<f64>,
    /// OpenCV `avg_reprojection_error`, pixels.
    pub avg_reprojection_error: Option<f64>,
    /// OpenCV `per_view_reprojection_errors`, pixels (single precision in the file).
    pub per_view_reprojection_errors: Vec<f64>,
    /// OpenCV `extrinsic_parameters`, one pose per view.
    pub extrinsics: Vec<ImportedPose>,
    /// ROS `rectification_matrix`, row-major.
    pub rectification_matrix: Option<[[f64; 3]; 3]>,
    /// ROS `projection_matrix`, row-major.
    pub projection_matrix: Option<[[f64; 4]; 3]>,
    /// Kalibr `rostopic`.
    pub rostopic: Option<String>,
    /// Kalibr `cam_overlaps`.
    pub cam_overlaps: Vec<usize>,
    /// Kalibr `T_cn_cnm1`: previous camera → this camera.
    pub t_cn_cnm1: Option<[[f64; 4]; 4]>,
    /// Kalibr `T_cam_imu`: IMU → this camera.
    pub t_cam_imu: Option<[[f64; 4]; 4]>,
    /// Kalibr `timeshift_cam_imu`, seconds (`t_imu = t_cam + shift`).
    pub timeshift_cam_imu: Option<f64>,
    /// Kalibr `line_delay` (rolling shutter), seconds per line.
    pub line_delay: Option<f64>,
}

impl ImportedCamera {
    /// A camera with nothing else known.
    fn new(camera: Camera, image_size: [u32; 2]) -> Self {
        Self {
            camera,
            image_size,
            camera_name: None,
            calibration_time: None,
            board: None,
            num_frames: None,
            flags: None,
            fixed_aspect_ratio: None,
            avg_reprojection_error: None,
            per_view_reprojection_errors: Vec::new(),
            extrinsics: Vec::new(),
            rectification_matrix: None,
            projection_matrix: None,
            rostopic: None,
            cam_overlaps: Vec::new(),
            t_cn_cnm1: None,
            t_cam_imu: None,
            timeshift_cam_imu: None,
            line_delay: None,
        }
    }
}

/// `[fx, fy, cx, cy]` from a 3×3 camera matrix, which must be `[fx 0 cx; 0 fy cy; 0 0 1]`:
/// Caliper's models have no skew, so a non-zero skew is refused rather than dropped.
fn intrinsics_from_k(fmt: &str, key: &str, m: &yaml::Matrix) -> CoreResult<[f64; 4]> {
    m.expect(fmt, key, 3, 3)?;
    let k = &m.data;
    if k[1] != 0.0 {
        return Err(yaml::bad(
            fmt,
            key,
            format!(
                "skew {} is not supported (Caliper's models have none)",
                k[1]
            ),
        ));
    }
    if k[3] != 0.0 || k[6] != 0.0 || k[7] != 0.0 || k[8] != 1.0 {
        return Err(yaml::bad(
            fmt,
            key,
            "not a camera matrix: the last row must be [0, 0, 1] and K[1][0] must be 0",
        ));
    }
    Ok([k[0], k[1 + 3], k[2], k[2 + 3]])
}

/// Prefixes a parser error with the format name.
fn in_format(fmt: &'static str) -> impl Fn(CoreError) -> CoreError {
    move |e| match e {
        CoreError::InvalidInput(m) => CoreError::InvalidInput(format!("{fmt}: {m}")),
        other => other,
    }
}

/// A model constructor's error as an input error naming the key it came from.
fn model_error(fmt: &str, key: &str) -> impl Fn(CoreError) -> CoreError {
    move |e| yaml::bad(fmt, key, e)
}

/// `[[a, b, …], …]` with exactly `R` rows of `C` numbers.
fn fixed_matrix<const R: usize, const C: usize>(
    fmt: &str,
    key: &str,
    node: &yaml::Node,
) -> CoreResult<[[f64; C]; R]> {
    let rows = yaml::as_seq(fmt, key, node)?;
    if rows.len() != R {
        return Err(yaml::bad(
            fmt,
            key,
            format!("expected {R} rows, got {}", rows.len()),
        ));
    }
    let mut out = [[0.0; C]; R];
    for (dst, row) in out.iter_mut().zip(rows) {
        *dst = yaml::f64_array::<C>(fmt, key, row)?;
    }
    Ok(out)
}
