//! ROS `sensor_msgs/CameraInfo` calibration YAML.
//!
//! Field list and order: `writeCalibrationYml` / `readCalibrationYml` in
//! `ros-perception/image_common: camera_calibration_parsers/src/parse_yml.cpp` (summarised in
//! `/work/shared/docs/formats.md`). For a monocular camera `R = I` and `P = [K | 0]`: the file
//! describes the raw camera, not a rectified one.

use super::yaml::{self, Fields, NanStyle, fmt_f64, ros_matrix};
use super::{ExportInput, ImportedCamera, in_format, intrinsics_from_k, model_error};
use crate::camera::{Camera, CameraModel, KannalaBrandt, PinholeRadTan};
use crate::error::{CoreError, CoreResult};

const FMT: &str = "ros-yaml";

pub(super) fn matrix(out: &mut String, key: &str, rows: usize, cols: usize, data: &[f64]) {
    let items: Vec<String> = data.iter().map(|v| fmt_f64(*v, NanStyle::Yaml)).collect();
    out.push_str(&format!(
        "{key}:\n  rows: {rows}\n  cols: {cols}\n  data: {}\n",
        yaml::flow(&items)
    ));
}

pub(super) fn write(input: &ExportInput<'_>) -> CoreResult<String> {
    let c = input.calibration;
    let p = c.camera.params();
    let (model, dist) = match &c.camera {
        Camera::PinholeRadTan(m) => ("plumb_bob", m.distortion().to_vec()),
        Camera::KannalaBrandt(_) => ("equidistant", p[4..8].to_vec()),
        Camera::DoubleSphere(_) => {
            return Err(CoreError::param(
                "format",
                "the double-sphere camera has no ROS CameraInfo form (distortion_model is one \
                 of plumb_bob, rational_polynomial, equidistant); export kalibr-yaml \
                 (camera_model: ds) or json instead",
            ));
        }
    };
    let [w, h] = c.image_size;
    let mut out = format!(
        "image_width: {w}\nimage_height: {h}\ncamera_name: {}\n",
        yaml::quote("camera_name", input.camera_name)?
    );
    let (fx, fy, cx, cy) = (p[0], p[1], p[2], p[3]);
    matrix(
        &mut out,
        "camera_matrix",
        3,
        3,
        &[fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0],
    );
    out.push_str(&format!("distortion_model: {model}\n"));
    matrix(&mut out, "distortion_coefficients", 1, dist.len(), &dist);
    matrix(
        &mut out,
        "rectification_matrix",
        3,
        3,
        &[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
    );
    matrix(
        &mut out,
        "projection_matrix",
        3,
        4,
        &[fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0],
    );
    Ok(out)
}

/// Reads a ROS camera-info YAML.
///
/// Required: `image_width`, `image_height`, `camera_matrix`, `distortion_coefficients`.
/// `distortion_model` defaults to `plumb_bob` and `camera_name` to `"unknown"`, as ROS reads
/// them. `plumb_bob` takes 5 coefficients, `rational_polynomial` 8 (k4..k6 must be 0, Caliper
/// does not model them), `equidistant` 4 (Kannala-Brandt); an empty coefficient list means no
/// distortion, as in ROS. `rectification_matrix` (3×3) and `projection_matrix` (3×4) are
/// optional and returned as read.
pub fn read_ros_yaml(text: &str) -> CoreResult<ImportedCamera> {
    let entries = yaml::parse(text).map_err(in_format(FMT))?;
    let f = Fields::new(FMT, &entries);
    let image_size = [f.size(&["image_width"])?, f.size(&["image_height"])?];
    let (k_key, k_node) = f.require(&["camera_matrix"])?;
    let [fx, fy, cx, cy] = intrinsics_from_k(FMT, k_key, &ros_matrix(FMT, k_key, k_node)?)?;
    let model = f
        .string(&["distortion_model"])?
        .unwrap_or_else(|| "plumb_bob".to_string());
    let (d_key, d_node) = f.require(&["distortion_coefficients"])?;
    let d = ros_matrix(FMT, d_key, d_node)?;
    if d.rows > 1 && d.cols > 1 {
        return Err(yaml::bad(
            FMT,
            d_key,
            format!("expected 1×N, got {}×{}", d.rows, d.cols),
        ));
    }
    let d = d.data;
    let count_error = |expected: &str| {
        yaml::bad(
            FMT,
            d_key,
            format!("`{model}` takes {expected} coefficients, got {}", d.len()),
        )
    };
    let camera: Camera = match model.as_str() {
        "plumb_bob" | "rational_polynomial" => {
            let full = if model == "plumb_bob" { 5 } else { 8 };
            let d = match d.len() {
                0 => vec![0.0; full],
                n if n == full => d.clone(),
                _ => return Err(count_error(if full == 5 { "5" } else { "8" })),
            };
            if let Some((i, v)) = d.iter().enumerate().skip(5).find(|(_, v)| **v != 0.0) {
                return Err(yaml::bad(
                    FMT,
                    d_key,
                    format!(
                        "k{} = {v}: Caliper does not model k4..k6 (they must be 0)",
                        i - 1
                    ),
                ));
            }
            PinholeRadTan::new(fx, fy, cx, cy, d[0], d[1], d[2], d[3], d[4])
                .map_err(model_error(FMT, d_key))?
                .into()
        }
        "equidistant" => {
            let d = match d.len() {
                0 => vec![0.0; 4],
                4 => d.clone(),
                _ => return Err(count_error("4")),
            };
            KannalaBrandt::new(fx, fy, cx, cy, d[0], d[1], d[2], d[3])
                .map_err(model_error(FMT, d_key))?
                .into()
        }
        other => {
            return Err(yaml::bad(
                FMT,
                "distortion_model",
                format!(
                    "unsupported model `{other}` (expected plumb_bob, rational_polynomial or \
                     equidistant)"
                ),
            ));
        }
    };
    let mut out = ImportedCamera::new(camera, image_size);
    out.camera_name = Some(
        f.string(&["camera_name"])?
            .unwrap_or_else(|| "unknown".to_string()),
    );
    if let Some((k, v)) = f.find(&["rectification_matrix"])? {
        let m = ros_matrix(FMT, k, v)?;
        m.expect(FMT, k, 3, 3)?;
        let mut r = [[0.0; 3]; 3];
        for (row, chunk) in r.iter_mut().zip(m.data.chunks_exact(3)) {
            row.copy_from_slice(chunk);
        }
        out.rectification_matrix = Some(r);
    }
    if let Some((k, v)) = f.find(&["projection_matrix"])? {
        let m = ros_matrix(FMT, k, v)?;
        m.expect(FMT, k, 3, 4)?;
        let mut p = [[0.0; 4]; 3];
        for (row, chunk) in p.iter_mut().zip(m.data.chunks_exact(4)) {
            row.copy_from_slice(chunk);
        }
        out.projection_matrix = Some(p);
    }
    Ok(out)
}
