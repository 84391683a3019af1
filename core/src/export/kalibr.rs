//! Kalibr `camchain.yaml`.
//!
//! Field list: `CameraParameters` in
//! `ethz-asl/kalibr: aslam_offline_calibration/kalibr/python/kalibr_common/ConfigReader.py`
//! (summarised in `/work/shared/docs/formats.md`).
//!
//! Model mapping:
//! * pinhole radial-tangential → `camera_model: pinhole`, `distortion_model: radtan`,
//!   `[k1, k2, r1, r2]`. Kalibr's radtan has no k3, so a camera with k3 ≠ 0 is **refused**
//!   rather than written without it or with a warning comment: a comment is invisible to every
//!   program that loads the file, and dropping k3 moves the image corners by k3·r⁶ (often
//!   pixels). Calibrate with `fix_k3` for a Kalibr-compatible pinhole.
//! * Kannala-Brandt → `camera_model: pinhole`, `distortion_model: equidistant`, `[k1..k4]`
//!   (Kalibr's equidistant model is OpenCV's fisheye model).
//! * double sphere → `camera_model: ds`, intrinsics `[xi, alpha, fu, fv, pu, pv]`,
//!   `distortion_model: none` (Kalibr's ds came from the model's authors, same convention).

use super::yaml::{self, Fields, NanStyle, Node, fmt_f64};
use super::{ExportInput, ImportedCamera, fixed_matrix, in_format, model_error};
use crate::camera::{Camera, CameraModel, DoubleSphere, KannalaBrandt, PinholeRadTan};
use crate::error::{CoreError, CoreResult};

const FMT: &str = "kalibr-yaml";

/// Kalibr's example topic, used when the caller gives none (the key is required by Kalibr).
pub(super) const DEFAULT_ROSTOPIC: &str = "/cam0/image_raw";

fn list(values: &[f64]) -> String {
    let items: Vec<String> = values.iter().map(|v| fmt_f64(*v, NanStyle::Yaml)).collect();
    yaml::flow(&items)
}

pub(super) fn write(input: &ExportInput<'_>) -> CoreResult<String> {
    let c = input.calibration;
    let topic = input.rostopic.unwrap_or(DEFAULT_ROSTOPIC);
    Ok(format!(
        "{}  cam_overlaps: []\n",
        camera_entry("cam0", &c.camera, c.image_size, topic)?
    ))
}

/// The `camN:` mapping of one camera, up to (not including) `T_cn_cnm1` and `cam_overlaps`,
/// which only a camera chain has.
pub(super) fn camera_entry(
    key: &str,
    camera: &Camera,
    image_size: [u32; 2],
    topic: &str,
) -> CoreResult<String> {
    let p = camera.params();
    let (camera_model, intrinsics, distortion_model, coeffs) = match camera {
        Camera::PinholeRadTan(m) => {
            let [k1, k2, p1, p2, k3] = m.distortion();
            if k3 != 0.0 {
                return Err(CoreError::param(
                    "format",
                    format!(
                        "Kalibr's radtan model has 4 coefficients (k1 k2 r1 r2) but this camera \
                         has k3 = {k3}; dropping it would change the camera. Calibrate with \
                         fix_k3, or export opencv-yaml, ros-yaml or json"
                    ),
                ));
            }
            ("pinhole", p[..4].to_vec(), "radtan", vec![k1, k2, p1, p2])
        }
        Camera::KannalaBrandt(_) => ("pinhole", p[..4].to_vec(), "equidistant", p[4..8].to_vec()),
        Camera::DoubleSphere(_) => (
            "ds",
            vec![p[4], p[5], p[0], p[1], p[2], p[3]],
            "none",
            Vec::new(),
        ),
    };
    let [w, h] = image_size;
    Ok(format!(
        "{key}:\n  camera_model: {camera_model}\n  intrinsics: {}\n  distortion_model: \
         {distortion_model}\n  distortion_coeffs: {}\n  resolution: [{w}, {h}]\n  rostopic: \
         {}\n",
        list(&intrinsics),
        list(&coeffs),
        yaml::quote("rostopic", topic)?
    ))
}

/// A flow list of numbers, as Kalibr writes them.
pub(super) fn number_list(values: &[f64]) -> String {
    list(values)
}

/// Reads `cam0` of a Kalibr camchain (see [`read_kalibr_camchain`] for every camera).
pub fn read_kalibr_yaml(text: &str) -> CoreResult<ImportedCamera> {
    let entries = yaml::parse(text).map_err(in_format(FMT))?;
    let f = Fields::new(FMT, &entries);
    let (key, node) = f.require(&["cam0"])?;
    read_camera(key, node)
}

/// Reads every camera of a Kalibr camchain (`cam0`, `cam1`, … without gaps), in order.
/// Other top-level keys are ignored.
pub fn read_kalibr_camchain(text: &str) -> CoreResult<Vec<ImportedCamera>> {
    let entries = yaml::parse(text).map_err(in_format(FMT))?;
    let f = Fields::new(FMT, &entries);
    let cams = entries
        .iter()
        .filter(|(k, _)| {
            k.strip_prefix("cam")
                .is_some_and(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()))
        })
        .count();
    let mut out = Vec::with_capacity(cams);
    for i in 0..cams {
        let name = format!("cam{i}");
        let (key, node) = f.require(&[name.as_str()])?;
        out.push(read_camera(key, node)?);
    }
    if out.is_empty() {
        return Err(CoreError::input(format!("{FMT}: missing key `cam0`")));
    }
    Ok(out)
}

/// One `camN` mapping. Required: `camera_model`, `intrinsics`, `distortion_model`,
/// `distortion_coeffs`, `resolution`; Caliper supports `pinhole` with `radtan`, `equidistant`
/// or `none`, and `ds` with `none`.
fn read_camera(cam: &str, node: &Node) -> CoreResult<ImportedCamera> {
    let entries = yaml::as_map(FMT, cam, node)?;
    let f = Fields::new(FMT, entries);
    let key = |k: &str| format!("{cam}.{k}");
    let (_, model_node) = f
        .require(&["camera_model"])
        .map_err(|_| missing(cam, "camera_model"))?;
    let model = yaml::as_str(FMT, &key("camera_model"), model_node)?;
    let (_, dm_node) = f
        .require(&["distortion_model"])
        .map_err(|_| missing(cam, "distortion_model"))?;
    let distortion = yaml::as_str(FMT, &key("distortion_model"), dm_node)?;
    let (_, i_node) = f
        .require(&["intrinsics"])
        .map_err(|_| missing(cam, "intrinsics"))?;
    let intr = yaml::f64_seq(FMT, &key("intrinsics"), i_node)?;
    let (_, d_node) = f
        .require(&["distortion_coeffs"])
        .map_err(|_| missing(cam, "distortion_coeffs"))?;
    let d = yaml::f64_seq(FMT, &key("distortion_coeffs"), d_node)?;
    let (_, r_node) = f
        .require(&["resolution"])
        .map_err(|_| missing(cam, "resolution"))?;
    let res_key = key("resolution");
    let res = yaml::as_seq(FMT, &res_key, r_node)?;
    let image_size: [u32; 2] = match res {
        [w, h] => [
            yaml::positive_u32(FMT, &res_key, yaml::as_int(FMT, &res_key, w)?)?,
            yaml::positive_u32(FMT, &res_key, yaml::as_int(FMT, &res_key, h)?)?,
        ],
        _ => {
            return Err(yaml::bad(
                FMT,
                &res_key,
                format!("expected [width, height], got {} values", res.len()),
            ));
        }
    };

    let expect_len = |k: &str, v: &[f64], n: usize, what: &str| -> CoreResult<()> {
        if v.len() == n {
            Ok(())
        } else {
            Err(yaml::bad(
                FMT,
                &key(k),
                format!("{what} takes {n} values, got {}", v.len()),
            ))
        }
    };
    let camera: Camera = match (model, distortion) {
        ("pinhole", "radtan" | "equidistant" | "none") => {
            expect_len("intrinsics", &intr, 4, "pinhole [fu, fv, pu, pv]")?;
            let (fx, fy, cx, cy) = (intr[0], intr[1], intr[2], intr[3]);
            let intr_key = key("intrinsics");
            let err = model_error(FMT, &intr_key);
            match distortion {
                "radtan" => {
                    expect_len("distortion_coeffs", &d, 4, "radtan [k1, k2, r1, r2]")?;
                    PinholeRadTan::new(fx, fy, cx, cy, d[0], d[1], d[2], d[3], 0.0)
                        .map_err(err)?
                        .into()
                }
                "equidistant" => {
                    expect_len("distortion_coeffs", &d, 4, "equidistant [k1, k2, k3, k4]")?;
                    KannalaBrandt::new(fx, fy, cx, cy, d[0], d[1], d[2], d[3])
                        .map_err(err)?
                        .into()
                }
                _ => {
                    expect_len("distortion_coeffs", &d, 0, "distortion model none")?;
                    PinholeRadTan::new(fx, fy, cx, cy, 0.0, 0.0, 0.0, 0.0, 0.0)
                        .map_err(err)?
                        .into()
                }
            }
        }
        ("ds", "none") => {
            expect_len("intrinsics", &intr, 6, "ds [xi, alpha, fu, fv, pu, pv]")?;
            expect_len("distortion_coeffs", &d, 0, "distortion model none")?;
            let intr_key = key("intrinsics");
            DoubleSphere::new(intr[2], intr[3], intr[4], intr[5], intr[0], intr[1])
                .map_err(model_error(FMT, &intr_key))?
                .into()
        }
        ("pinhole" | "ds", other) => {
            return Err(yaml::bad(
                FMT,
                &key("distortion_model"),
                format!(
                    "`{other}` is not supported with camera_model {model} (Caliper reads \
                     pinhole with radtan, equidistant or none, and ds with none)"
                ),
            ));
        }
        (other, _) => {
            return Err(yaml::bad(
                FMT,
                &key("camera_model"),
                format!("`{other}` is not supported (Caliper reads pinhole and ds)"),
            ));
        }
    };

    let mut out = ImportedCamera::new(camera, image_size);
    if let Some((k, v)) = f.find(&["rostopic"])? {
        out.rostopic = Some(yaml::as_str(FMT, &key(k), v)?.to_string());
    }
    if let Some((k, v)) = f.find(&["cam_overlaps"])? {
        let k = key(k);
        out.cam_overlaps = yaml::as_seq(FMT, &k, v)?
            .iter()
            .map(|n| {
                let i = yaml::as_int(FMT, &k, n)?;
                usize::try_from(i).map_err(|_| yaml::bad(FMT, &k, format!("bad index {i}")))
            })
            .collect::<CoreResult<_>>()?;
    }
    if let Some((k, v)) = f.find(&["T_cn_cnm1"])? {
        out.t_cn_cnm1 = Some(fixed_matrix::<4, 4>(FMT, &key(k), v)?);
    }
    if let Some((k, v)) = f.find(&["T_cam_imu"])? {
        out.t_cam_imu = Some(fixed_matrix::<4, 4>(FMT, &key(k), v)?);
    }
    if let Some((k, v)) = f.find(&["timeshift_cam_imu"])? {
        out.timeshift_cam_imu = Some(yaml::as_f64(FMT, &key(k), v)?);
    }
    if let Some((k, v)) = f.find(&["line_delay"])? {
        out.line_delay = Some(yaml::as_f64(FMT, &key(k), v)?);
    }
    Ok(out)
}

fn missing(cam: &str, k: &str) -> CoreError {
    CoreError::input(format!("{FMT}: missing key `{cam}.{k}`"))
}
