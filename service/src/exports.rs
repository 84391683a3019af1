//! Export formats of documents (`?format=`), rendered on request from the stored document so
//! that every revision can be exported in every format, including formats added later.
//!
//! Each kind declares its formats ([`crate::jobs::Kind::EXPORTS`]); the functions here only
//! read the stored document's fields and hand them to the writers in `caliper_core::export`.

use caliper_core::calib::{BoardGeometry, CalibOptions, Calibration};
use serde_json::Value;

use crate::error::ApiError;
use crate::jobs::{Export, ExportError, exports_for};

/// An export: its text and media type.
pub struct Rendered {
    pub body: String,
    pub media_type: &'static str,
}

/// Render a document in an export format its kind offers.
pub fn render(doc: &Value, format: &str) -> Result<Rendered, ApiError> {
    let schema = doc.get("schema").and_then(Value::as_str).unwrap_or("");
    let offered = exports_for(schema);
    let Some(export) = offered.iter().find(|e| e.format == format) else {
        let list: Vec<&str> = offered.iter().map(|e| e.format).collect();
        return Err(ApiError::new(
            "unsupported_format",
            if list.is_empty() {
                format!("documents of schema {schema:?} have no exports")
            } else {
                format!(
                    "documents of schema {schema:?} have no {format:?} export; they offer {}",
                    list.join(", ")
                )
            },
        )
        .with_field("format"));
    };
    let body = (export.render)(doc).map_err(|e| match e {
        ExportError::Unavailable(m) => ApiError::new("unsupported_format", m).with_field("format"),
        ExportError::Corrupt(m) => ApiError::internal(format!("export {format}: {m}")),
    })?;
    Ok(Rendered {
        body,
        media_type: export.media_type,
    })
}

/// The camera document's exports, one per `caliper_core::export` format.
pub const CAMERA_EXPORTS: &[Export] = &[
    Export {
        format: "opencv-yaml",
        media_type: caliper_core::export::YAML_MEDIA_TYPE,
        render: |d| camera(d, caliper_core::export::ExportFormat::OpencvYaml),
    },
    Export {
        format: "ros-yaml",
        media_type: caliper_core::export::YAML_MEDIA_TYPE,
        render: |d| camera(d, caliper_core::export::ExportFormat::RosYaml),
    },
    Export {
        format: "kalibr-yaml",
        media_type: caliper_core::export::YAML_MEDIA_TYPE,
        render: |d| camera(d, caliper_core::export::ExportFormat::KalibrYaml),
    },
    Export {
        format: "json",
        media_type: "application/json",
        render: |d| camera(d, caliper_core::export::ExportFormat::Json),
    },
];

fn camera(doc: &Value, fmt: caliper_core::export::ExportFormat) -> Result<String, ExportError> {
    let params = &doc["parameters"];
    let calibration: Calibration = serde_json::from_value(params["calibration"].clone())
        .map_err(|e| ExportError::Corrupt(e.to_string()))?;
    let board = &params["board"];
    let board = match (
        board["cols"].as_u64(),
        board["rows"].as_u64(),
        board["square"].as_f64(),
    ) {
        (Some(c), Some(r), Some(s)) => Some(BoardGeometry {
            cols: c as usize,
            rows: r as usize,
            square: s,
        }),
        _ => None,
    };
    let options: Option<CalibOptions> =
        serde_json::from_value(doc["provenance"]["params"]["options"].clone()).ok();
    let name = match (doc["device"].as_str(), doc["sensor"].as_str()) {
        (Some(d), Some(s)) => format!("{d}/{s}"),
        _ => "camera".to_string(),
    };
    let input = caliper_core::export::ExportInput {
        calibration: &calibration,
        board,
        options: options.as_ref(),
        camera_name: &name,
        rostopic: None,
        calibration_time: doc["created_at"].as_str(),
    };
    caliper_core::export::export(&input, fmt).map_err(|e| ExportError::Unavailable(e.to_string()))
}

/// The photometric documents' export: DSO's `pcalib.txt` (the inverse response as 256 values).
pub const PHOTOMETRIC_EXPORTS: &[Export] = &[
    Export {
        format: "dso-pcalib",
        media_type: "text/plain; charset=utf-8",
        render: dso_pcalib,
    },
    Export {
        format: "dso-pcalib-r",
        media_type: "text/plain; charset=utf-8",
        render: |d| dso_pcalib_channel(d, "r"),
    },
    Export {
        format: "dso-pcalib-g",
        media_type: "text/plain; charset=utf-8",
        render: |d| dso_pcalib_channel(d, "g"),
    },
    Export {
        format: "dso-pcalib-b",
        media_type: "text/plain; charset=utf-8",
        render: |d| dso_pcalib_channel(d, "b"),
    },
];

/// One colour channel's `pcalib.txt`, from a `photometric_online` document fitted with
/// `channels: rgb` (`parameters.channel_responses`); other documents have no channels.
fn dso_pcalib_channel(doc: &Value, channel: &str) -> Result<String, ExportError> {
    use caliper_core::photometric::{ChannelResponse, InverseResponse, dso};
    let Some(list) = doc["parameters"].get("channel_responses") else {
        return Err(ExportError::Unavailable(
            "this document has one response (no per-channel responses: fit photometric_online \
             with options.channels rgb); use dso-pcalib"
                .into(),
        ));
    };
    let list: Vec<ChannelResponse> =
        serde_json::from_value(list.clone()).map_err(|e| ExportError::Corrupt(e.to_string()))?;
    let ch = list
        .into_iter()
        .find(|c| c.channel == channel)
        .ok_or_else(|| ExportError::Corrupt(format!("no channel {channel}")))?;
    let inv = InverseResponse::new(ch.inverse_256)
        .map_err(|e| ExportError::Unavailable(e.to_string()))?;
    Ok(dso::write_pcalib(&inv))
}

fn dso_pcalib(doc: &Value) -> Result<String, ExportError> {
    use caliper_core::photometric::{InverseResponse, PhotometricModel, dso};
    let model: PhotometricModel = serde_json::from_value(doc["parameters"]["model"].clone())
        .map_err(|e| ExportError::Corrupt(e.to_string()))?;
    let inv = InverseResponse::new(model.inverse_256)
        .map_err(|e| ExportError::Unavailable(e.to_string()))?;
    Ok(dso::write_pcalib(&inv))
}

/// Kalibr `imu.yaml` from an `imu_noise` document: the worst axis of each sensor, written by
/// `caliper_core::export::kalibr_imu_yaml` (every number a YAML 1.1 float, as Kalibr's PyYAML
/// needs). A random walk the log could not determine is written as its upper bound, with a
/// comment saying so; without even a bound, or without a noise density, the export is refused
/// rather than inventing a number.
pub fn kalibr_imu_yaml(doc: &Value) -> Result<String, ExportError> {
    let k = &doc["parameters"]["kalibr"];
    let need = |key: &str| {
        k[key].as_f64().ok_or_else(|| {
            ExportError::Unavailable(format!(
                "{key} could not be determined from this log; no Kalibr file can be written"
            ))
        })
    };
    let values = caliper_core::export::KalibrImuValues {
        accelerometer_noise_density: need("accelerometer_noise_density")?,
        accelerometer_random_walk: k["accelerometer_random_walk"].as_f64(),
        accelerometer_random_walk_upper_bound: k["accelerometer_random_walk_upper_bound"].as_f64(),
        gyroscope_noise_density: need("gyroscope_noise_density")?,
        gyroscope_random_walk: k["gyroscope_random_walk"].as_f64(),
        gyroscope_random_walk_upper_bound: k["gyroscope_random_walk_upper_bound"].as_f64(),
        update_rate: k["update_rate"].as_f64().unwrap_or(0.0),
        rostopic: "/imu0".into(),
    };
    caliper_core::export::kalibr_imu_yaml(&values)
        .map_err(|e| ExportError::Unavailable(e.to_string()))
}

/// The rig document's exports: OpenCV stereo YAML of camera 0 with camera 1 (`opencv-yaml`),
/// 2 or 3, ROS `CameraInfo` with rectification for the first cameras, Kalibr's camchain for
/// every camera, and JSON.
pub const RIG_EXPORTS: &[Export] = &[
    Export {
        format: "opencv-yaml",
        media_type: caliper_core::export::YAML_MEDIA_TYPE,
        render: |d| rig_opencv(d, 1),
    },
    Export {
        format: "opencv-yaml-cam2",
        media_type: caliper_core::export::YAML_MEDIA_TYPE,
        render: |d| rig_opencv(d, 2),
    },
    Export {
        format: "opencv-yaml-cam3",
        media_type: caliper_core::export::YAML_MEDIA_TYPE,
        render: |d| rig_opencv(d, 3),
    },
    Export {
        format: "ros-yaml-cam0",
        media_type: caliper_core::export::YAML_MEDIA_TYPE,
        render: |d| rig_ros(d, 0),
    },
    Export {
        format: "ros-yaml-cam1",
        media_type: caliper_core::export::YAML_MEDIA_TYPE,
        render: |d| rig_ros(d, 1),
    },
    Export {
        format: "ros-yaml-cam2",
        media_type: caliper_core::export::YAML_MEDIA_TYPE,
        render: |d| rig_ros(d, 2),
    },
    Export {
        format: "ros-yaml-cam3",
        media_type: caliper_core::export::YAML_MEDIA_TYPE,
        render: |d| rig_ros(d, 3),
    },
    Export {
        format: "kalibr-yaml",
        media_type: caliper_core::export::YAML_MEDIA_TYPE,
        render: |d| {
            let rig = rig_of(d)?;
            let topics: Vec<String> = rig
                .cameras
                .iter()
                .map(|c| format!("/{}/image_raw", c.name))
                .collect();
            caliper_core::export::rig_kalibr_camchain(&rig, &topics)
                .map_err(|e| ExportError::Unavailable(e.to_string()))
        },
    },
    Export {
        format: "json",
        media_type: "application/json",
        render: |d| {
            serde_json::to_string_pretty(&d["parameters"]["rig"])
                .map_err(|e| ExportError::Corrupt(e.to_string()))
        },
    },
];

fn rig_of(doc: &Value) -> Result<caliper_core::rig::RigCalibration, ExportError> {
    serde_json::from_value(doc["parameters"]["rig"].clone())
        .map_err(|e| ExportError::Corrupt(e.to_string()))
}

/// OpenCV stereo YAML of camera 0 with camera `second`.
fn rig_opencv(d: &Value, second: usize) -> Result<String, ExportError> {
    let rig = rig_of(d)?;
    caliper_core::export::rig_opencv_stereo_yaml(&rig, second, d["created_at"].as_str())
        .map_err(|e| ExportError::Unavailable(e.to_string()))
}

fn rig_ros(doc: &Value, index: usize) -> Result<String, ExportError> {
    let rig = rig_of(doc)?;
    let cam = rig
        .cameras
        .get(index)
        .map(|c| c.name.clone())
        .unwrap_or_default();
    let name = match (doc["device"].as_str(), doc["sensor"].as_str()) {
        (Some(d), Some(s)) => format!("{d}/{s}/{cam}"),
        _ => cam,
    };
    caliper_core::export::rig_ros_yaml(&rig, index, &name)
        .map_err(|e| ExportError::Unavailable(e.to_string()))
}
