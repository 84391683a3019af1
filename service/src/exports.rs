//! Export formats of documents (`?format=`), rendered on request from the stored document so
//! that every revision can be exported in every format, including formats added later.

use caliper_core::calib::{BoardGeometry, CalibOptions, Calibration};
use serde_json::Value;

use crate::error::ApiError;

/// An export: its text and media type.
pub struct Rendered {
    pub body: String,
    pub media_type: &'static str,
}

/// Render a document in an export format.
pub fn render(doc: &Value, format: &str) -> Result<Rendered, ApiError> {
    let schema = doc.get("schema").and_then(Value::as_str).unwrap_or("");
    let unsupported = || {
        ApiError::new(
            "unsupported_format",
            format!(
                "documents of schema {schema:?} have no {format:?} export; camera documents offer opencv-yaml, ros-yaml, kalibr-yaml and json; imu_noise documents kalibr-yaml; photometric documents dso-pcalib"
            ),
        )
        .with_field("format")
    };
    if schema == "caliper.imu_noise/v1" && format == "kalibr-yaml" {
        return kalibr_imu_yaml(doc);
    }
    if schema == "caliper.photometric/v1" && format == "dso-pcalib" {
        return dso_pcalib(doc);
    }
    if schema != "caliper.camera/v1" {
        return Err(unsupported());
    }
    let fmt: caliper_core::export::ExportFormat = format.parse().map_err(|_| unsupported())?;
    let params = &doc["parameters"];
    let calibration: Calibration = serde_json::from_value(params["calibration"].clone())
        .map_err(|e| ApiError::internal(format!("stored camera document unreadable: {e}")))?;
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
    let body = caliper_core::export::export(&input, fmt)
        .map_err(|e| ApiError::new("unsupported_format", e.to_string()).with_field("format"))?;
    Ok(Rendered {
        body,
        media_type: fmt.media_type(),
    })
}

/// DSO's `pcalib.txt` (the inverse response as 256 values) of a photometric document.
fn dso_pcalib(doc: &Value) -> Result<Rendered, ApiError> {
    use caliper_core::photometric::{InverseResponse, PhotometricModel, dso};
    let model: PhotometricModel = serde_json::from_value(doc["parameters"]["model"].clone())
        .map_err(|e| ApiError::internal(format!("stored photometric document unreadable: {e}")))?;
    let inv = InverseResponse::new(model.inverse_256)
        .map_err(|e| ApiError::new("unsupported_format", e.to_string()).with_field("format"))?;
    Ok(Rendered {
        body: dso::write_pcalib(&inv),
        media_type: "text/plain; charset=utf-8",
    })
}

/// Kalibr `imu.yaml` (field list: `ImuParameters` in Kalibr's `ConfigReader.py`) from an
/// `imu_noise` document: the worst axis of each sensor. A random walk the log could not
/// determine is written as its upper bound, with a comment saying so; without even a bound
/// the export is refused rather than inventing a number.
fn kalibr_imu_yaml(doc: &Value) -> Result<Rendered, ApiError> {
    let k = &doc["parameters"]["kalibr"];
    let mut out = String::from("# Kalibr imu.yaml written by Caliper from an imu_noise document\n");
    for (key, bound) in [
        ("accelerometer_noise_density", None),
        (
            "accelerometer_random_walk",
            Some("accelerometer_random_walk_upper_bound"),
        ),
        ("gyroscope_noise_density", None),
        (
            "gyroscope_random_walk",
            Some("gyroscope_random_walk_upper_bound"),
        ),
    ] {
        match (k[key].as_f64(), bound.and_then(|b| k[b].as_f64())) {
            (Some(v), _) => out.push_str(&format!("{key}: {v:e}\n")),
            (None, Some(b)) => out.push_str(&format!(
                "{key}: {b:e}  # upper bound: the log is too short to determine it\n"
            )),
            (None, None) => {
                return Err(ApiError::new(
                    "unsupported_format",
                    format!(
                        "{key} could not be determined from this log; no Kalibr file can be written"
                    ),
                )
                .with_field("format"));
            }
        }
    }
    let rate = k["update_rate"].as_f64().unwrap_or(0.0);
    out.push_str("rostopic: /imu0\n");
    out.push_str(&format!("update_rate: {rate}\n"));
    Ok(Rendered {
        body: out,
        media_type: "application/yaml",
    })
}
