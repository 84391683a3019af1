//! Exports of a rig calibration ([`RigCalibration`]): OpenCV stereo YAML, ROS `CameraInfo` per
//! camera with its rectification, and Kalibr's `camchain.yaml` with `T_cn_cnm1`.
//!
//! Field lists: OpenCV's `stereoCalibrate` / `stereoRectify` outputs under the names the
//! `stereo_calib.cpp` sample stores them (`M1 D1 M2 D2` for the intrinsics, `R T E F R1 R2 P1
//! P2 Q` for the pair); ROS `camera_calibration_parsers` for `CameraInfo` (a rectified camera
//! has `rectification_matrix = R1|R2` and `projection_matrix = P1|P2`, as ROS's stereo
//! calibrator writes them); Kalibr's `ConfigReader.py` for the chain, where `T_cn_cnm1` maps
//! camera n−1's frame into camera n's.

use super::kalibr::{DEFAULT_ROSTOPIC, camera_entry, number_list};
use super::yaml::{self, NanStyle, fmt_f64};
use super::{opencv, ros};
use crate::camera::{Camera, CameraModel};
use crate::error::{CoreError, CoreResult};
use crate::lie::{Se3, So3};
use crate::rig::{PoseDoc, RigCalibration};

fn flat3(m: &[[f64; 3]; 3]) -> Vec<f64> {
    m.iter().flatten().copied().collect()
}

fn flat34(m: &[[f64; 4]; 3]) -> Vec<f64> {
    m.iter().flatten().copied().collect()
}

/// Distortion coefficients in OpenCV's order, and whether the camera is OpenCV's fisheye.
fn opencv_distortion(c: &Camera, what: &str) -> CoreResult<(Vec<f64>, bool)> {
    match c {
        Camera::PinholeRadTan(m) => Ok((m.distortion().to_vec(), false)),
        Camera::KannalaBrandt(_) => Ok((c.params()[4..8].to_vec(), true)),
        Camera::DoubleSphere(_) => Err(CoreError::param(
            "format",
            format!(
                "{what} is a double-sphere camera, which OpenCV and ROS cannot represent; \
                 export kalibr-yaml or json"
            ),
        )),
    }
}

fn k(c: &Camera) -> Vec<f64> {
    let p = c.params();
    vec![p[0], 0.0, p[2], 0.0, p[1], p[3], 0.0, 0.0, 1.0]
}

/// OpenCV stereo YAML of the pair of camera 0 and camera `second` (1 for a stereo rig): `M1
/// D1` are camera 0's, `M2 D2` camera `second`'s, and `R T E F R1 R2 P1 P2 Q` the pair's, as
/// `stereoCalibrate` and `stereoRectify` name them. A rig of more cameras has one such file per
/// camera beyond the first, each rectified with camera 0.
pub fn rig_opencv_stereo_yaml(
    rig: &RigCalibration,
    second: usize,
    time: Option<&str>,
) -> CoreResult<String> {
    let Some(pair) = rig.pairs.iter().find(|p| p.a == 0 && p.b == second) else {
        return Err(CoreError::param(
            "format",
            format!(
                "OpenCV's stereo YAML describes camera 0 with one other camera; this rig has {} \
                 cameras, so camera {second} is not one of them: export kalibr-yaml (every \
                 camera) or json",
                rig.cameras.len()
            ),
        ));
    };
    let (Some(a), Some(b)) = (rig.cameras.first(), rig.cameras.get(second)) else {
        return Err(CoreError::input(
            "rig document: a pair names a missing camera",
        ));
    };
    let (da, fa) = opencv_distortion(&a.camera, &a.name)?;
    let (db, fb) = opencv_distortion(&b.camera, &b.name)?;
    if fa != fb {
        return Err(CoreError::param(
            "format",
            "OpenCV's stereo functions take two pinhole or two fisheye cameras, not one of each",
        ));
    }
    let r = &pair.rectification;
    let num = |v: f64| fmt_f64(v, NanStyle::OpenCv);
    let strs = |v: &[f64]| v.iter().map(|x| num(*x)).collect::<Vec<_>>();
    let mut out = String::from("%YAML:1.0\n---\n");
    if let Some(t) = time {
        out.push_str(&format!(
            "calibration_time: {}\n",
            yaml::quote("calibration_time", t)?
        ));
    }
    let [w, h] = r.image_size;
    out.push_str(&format!(
        "image_width: {w}\nimage_height: {h}\nfisheye_model: {}\n",
        i32::from(fa)
    ));
    opencv::matrix(&mut out, "M1", 3, 3, 'd', &strs(&k(&a.camera)));
    opencv::matrix(&mut out, "D1", 1, da.len(), 'd', &strs(&da));
    opencv::matrix(&mut out, "M2", 3, 3, 'd', &strs(&k(&b.camera)));
    opencv::matrix(&mut out, "D2", 1, db.len(), 'd', &strs(&db));
    opencv::matrix(&mut out, "R", 3, 3, 'd', &strs(&flat3(&r.r)));
    opencv::matrix(&mut out, "T", 3, 1, 'd', &strs(&r.t));
    opencv::matrix(&mut out, "E", 3, 3, 'd', &strs(&flat3(&r.e)));
    if let Some(f) = &r.f {
        opencv::matrix(&mut out, "F", 3, 3, 'd', &strs(&flat3(f)));
    }
    opencv::matrix(&mut out, "R1", 3, 3, 'd', &strs(&flat3(&r.r1)));
    opencv::matrix(&mut out, "R2", 3, 3, 'd', &strs(&flat3(&r.r2)));
    opencv::matrix(&mut out, "P1", 3, 4, 'd', &strs(&flat34(&r.p1)));
    opencv::matrix(&mut out, "P2", 3, 4, 'd', &strs(&flat34(&r.p2)));
    let q: Vec<f64> = r.q.iter().flatten().copied().collect();
    opencv::matrix(&mut out, "Q", 4, 4, 'd', &strs(&q));
    out.push_str(&format!(
        "rms: {}\nepipolar_rms: {}\nbaseline: {}\n",
        num(rig.rms),
        num(pair.epipolar_rms_px),
        num(rig.extrinsics.get(second).map_or(f64::NAN, |e| e.baseline))
    ));
    Ok(out)
}

/// ROS `CameraInfo` YAML of camera `index`, with the rectification of its pair with camera 0
/// (camera 0 itself takes its pair with camera 1).
pub fn rig_ros_yaml(rig: &RigCalibration, index: usize, camera_name: &str) -> CoreResult<String> {
    let Some(cam) = rig.cameras.get(index) else {
        return Err(CoreError::param(
            "format",
            format!(
                "the rig has {} cameras, no camera {index}",
                rig.cameras.len()
            ),
        ));
    };
    let (dist, fisheye) = opencv_distortion(&cam.camera, &cam.name)?;
    let pair = rig
        .pairs
        .iter()
        .find(|p| p.b == index.max(1))
        .ok_or_else(|| CoreError::input("the rig document has no rectification"))?;
    let second = index != 0;
    let r = &pair.rectification;
    let [w, h] = cam.image_size;
    let mut out = format!(
        "image_width: {w}\nimage_height: {h}\ncamera_name: {}\n",
        yaml::quote("camera_name", camera_name)?
    );
    ros::matrix(&mut out, "camera_matrix", 3, 3, &k(&cam.camera));
    out.push_str(&format!(
        "distortion_model: {}\n",
        if fisheye { "equidistant" } else { "plumb_bob" }
    ));
    ros::matrix(&mut out, "distortion_coefficients", 1, dist.len(), &dist);
    let (rr, pp) = if second {
        (&r.r2, &r.p2)
    } else {
        (&r.r1, &r.p1)
    };
    ros::matrix(&mut out, "rectification_matrix", 3, 3, &flat3(rr));
    ros::matrix(&mut out, "projection_matrix", 3, 4, &flat34(pp));
    Ok(out)
}

fn se3_of(p: &PoseDoc) -> CoreResult<Se3> {
    Ok(Se3::new(
        So3::from_wxyz(p.quaternion_wxyz)?,
        nalgebra::Vector3::from(p.translation),
    ))
}

/// Kalibr `camchain.yaml` of every camera, with `T_cn_cnm1` and `cam_overlaps` (cameras that
/// saw the board in a common frame). `topics[i]` names camera i's topic (`/camI/image_raw` when
/// missing).
pub fn rig_kalibr_camchain(rig: &RigCalibration, topics: &[String]) -> CoreResult<String> {
    let n = rig.cameras.len();
    let mut out = String::new();
    for (i, cam) in rig.cameras.iter().enumerate() {
        let key = format!("cam{i}");
        let default_topic = if i == 0 {
            DEFAULT_ROSTOPIC.to_string()
        } else {
            format!("/cam{i}/image_raw")
        };
        let topic = topics.get(i).unwrap_or(&default_topic);
        out.push_str(&camera_entry(&key, &cam.camera, cam.image_size, topic)?);
        if i > 0 {
            let ti = se3_of(&rig.extrinsics[i].t_cam_cam0)?;
            let tp = se3_of(&rig.extrinsics[i - 1].t_cam_cam0)?;
            let m = ti.compose(&tp.inverse()).matrix();
            out.push_str("  T_cn_cnm1:\n");
            for r in 0..4 {
                let row: Vec<f64> = (0..4).map(|c| m[(r, c)]).collect();
                out.push_str(&format!("  - {}\n", number_list(&row)));
            }
        }
        let overlaps: Vec<String> = (0..n)
            .filter(|&j| {
                j != i
                    && rig
                        .frames
                        .iter()
                        .any(|f| f.used && f.seen_by.contains(&i) && f.seen_by.contains(&j))
            })
            .map(|j| j.to_string())
            .collect();
        out.push_str(&format!("  cam_overlaps: {}\n", yaml::flow(&overlaps)));
    }
    Ok(out)
}
