//! `rig_calibration` end to end: a synthetic stereo rig (renders of one board through two known
//! cameras) uploaded as a zip of `cam0/` and `cam1/`, calibrated by the service and offline;
//! the known baseline and rotation come back; exports parse; bad rigs fail with the reason.

use std::io::{Cursor, Write};

use caliper_core::camera::{Camera, CameraModel, PinholeRadTan};
use caliper_core::lie::{Se3, So3};
use caliper_core::synth::{RenderOptions, render_chessboard};
use nalgebra::Vector3;
use serde_json::{Value, json};

use crate::common::*;

const LEFT: [f64; 9] = [540.0, 539.0, 322.0, 241.0, -0.25, 0.07, 0.001, -0.0005, 0.0];
const RIGHT: [f64; 9] = [
    545.0, 544.5, 318.0, 238.0, -0.24, 0.06, -0.0008, 0.0004, 0.0,
];

/// `T_right_left`: 8 cm baseline, 1.5° toe-in.
fn truth() -> Se3 {
    Se3::new(
        So3::exp(&Vector3::new(0.002, -0.026, 0.004)),
        Vector3::new(-0.08, 0.001, 0.002),
    )
}

/// Twelve frames of a 9×6 board (25 mm squares) seen by both cameras.
fn stereo_renders() -> Vec<(String, Vec<u8>)> {
    let cams: [Camera; 2] = [
        PinholeRadTan::from_slice(&LEFT).expect("camera").into(),
        PinholeRadTan::from_slice(&RIGHT).expect("camera").into(),
    ];
    let (cols, rows, sq) = (9usize, 6usize, 0.025);
    let centre = Vector3::new(
        (cols - 1) as f64 * sq / 2.0,
        (rows - 1) as f64 * sq / 2.0,
        0.0,
    );
    let tilts = [
        (0.0, 0.0, 0.0, 0.04, 0.0),
        (0.4, 0.0, 0.1, 0.0, 0.02),
        (-0.4, 0.1, -0.2, 0.08, -0.03),
        (0.0, 0.45, 0.3, 0.06, 0.04),
        (0.1, -0.45, -0.1, 0.02, -0.04),
        (0.3, 0.3, 0.5, 0.07, 0.05),
        (-0.3, -0.3, -0.4, 0.0, 0.04),
        (0.25, -0.2, 1.2, 0.04, -0.05),
        (-0.2, 0.3, -1.0, 0.06, 0.0),
        (0.45, 0.1, 0.0, 0.02, 0.05),
        (-0.1, -0.35, 0.6, 0.05, -0.02),
        (0.2, 0.4, -0.6, 0.03, 0.03),
    ];
    let mut out = Vec::new();
    for (i, &(ax, ay, az, ox, oy)) in tilts.iter().enumerate() {
        let rvec = Vector3::new(ax, ay, az);
        let r = Se3::from_rvec_tvec(&rvec, &Vector3::zeros());
        let t = -r.act(&centre) + Vector3::new(ox, oy, 0.5 + 0.03 * (i % 3) as f64);
        let pose = Se3::from_rvec_tvec(&rvec, &t);
        for (c, cam) in cams.iter().enumerate() {
            let p = if c == 0 { pose } else { truth().compose(&pose) };
            let opts = RenderOptions {
                noise_sigma: 1.0,
                seed: 10 * i as u64 + c as u64 + 1,
                blur_sigma: 0.5,
                ..RenderOptions::default()
            };
            let view =
                render_chessboard(cam, &p, (cols, rows, sq), (640, 480), &opts).expect("render");
            assert!(view.all_visible(), "frame {i} camera {c} leaves the image");
            let img = image::GrayImage::from_raw(640, 480, view.image.data).expect("image");
            out.push((format!("cam{c}/frame{i:02}.png"), png(&img)));
        }
    }
    out
}

fn zip_of(entries: &[(String, Vec<u8>)]) -> Vec<u8> {
    let mut w = zip::ZipWriter::new(Cursor::new(Vec::new()));
    let opts = zip::write::SimpleFileOptions::default();
    for (name, data) in entries {
        w.start_file(name.as_str(), opts).expect("zip entry");
        w.write_all(data).expect("zip write");
    }
    w.finish().expect("zip").into_inner()
}

fn check_rig(doc: &Value) {
    let ext = &doc["parameters"]["extrinsics"][1];
    let t: Vec<f64> = ext["t_cam_cam0"]["translation"]
        .as_array()
        .expect("translation")
        .iter()
        .map(|x| x.as_f64().expect("number"))
        .collect();
    let want = truth().translation;
    let err = (Vector3::new(t[0], t[1], t[2]) - want).norm();
    assert!(err < 1e-3, "translation {t:?} vs {want:?}: {ext}");
    let rot = ext["rotation_deg"].as_f64().expect("rotation");
    assert!(
        (rot - truth().rotation.angle().to_degrees()).abs() < 0.05,
        "{ext}"
    );
    let sigma_b = ext["sigma"]["baseline"].as_f64().expect("σ");
    assert!(sigma_b > 0.0 && sigma_b < 1e-3, "{ext}");
    let pair = &doc["parameters"]["rig"]["pairs"][0];
    assert!(
        pair["epipolar_rms_px"].as_f64().expect("epipolar") < 0.3,
        "{pair}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stereo_zip_recovers_the_known_rig_and_exports() {
    let s = start().await;
    let files = stereo_renders();
    let ds = s.dataset(vec![("rig.zip", zip_of(&files))]).await;
    let body = json!({"kind": "rig_calibration", "dataset": ds, "device": "rig-1", "sensor": "stereo",
                      "params": {"board": {"cols": 9, "rows": 6, "square": 0.025}}});
    let id = s.job(body).await;
    let done = s.wait_terminal(&id).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    let base = "/v1/devices/rig-1/documents/stereo/rig_calibration";
    let (st, doc) = s.get_json(&format!("{base}/latest")).await;
    assert_eq!(st, 200);
    assert_eq!(doc["schema"], "caliper.rig/v1");
    check_rig(&doc);
    assert_eq!(doc["quality"]["frames_used"], 12);
    // Exports: OpenCV stereo YAML with every stereoRectify matrix, ROS per camera with its
    // rectification, Kalibr camchain read back by our own reader.
    let client = reqwest::Client::new();
    let get = |fmt: &str| {
        client
            .get(s.url(&format!("{base}/latest?format={fmt}")))
            .send()
    };
    let opencv = get("opencv-yaml")
        .await
        .expect("get")
        .text()
        .await
        .expect("text");
    for key in [
        "M1:", "D1:", "M2:", "D2:", "R:", "T:", "E:", "F:", "R1:", "R2:", "P1:", "P2:", "Q:",
    ] {
        assert!(
            opencv.contains(&format!("\n{key}")),
            "{key} missing:\n{opencv}"
        );
    }
    let ros = get("ros-yaml-cam1")
        .await
        .expect("get")
        .text()
        .await
        .expect("text");
    let ros_cam = caliper_core::export::read_ros_yaml(&ros).expect("ros yaml reads back");
    assert!((ros_cam.camera.params()[0] - RIGHT[0]).abs() < 3.0, "{ros}");
    assert!(
        ros.contains("rectification_matrix") && !ros.contains("data: [1, 0, 0, 0, 1, 0, 0, 0, 1]"),
        "{ros}"
    );
    let r = get("ros-yaml-cam2").await.expect("get");
    assert_eq!(r.status().as_u16(), 400, "a stereo rig has no camera 2");
    let r = get("opencv-yaml-cam2").await.expect("get");
    assert_eq!(r.status().as_u16(), 400, "a stereo rig has no pair 0-2");
    // Kalibr's radtan has no k3: the default solve frees k3, so ask for a Kalibr-ready solve.
    let body = json!({"kind": "rig_calibration", "dataset": ds, "device": "rig-1", "sensor": "stereo-kalibr",
                      "params": {"board": {"cols": 9, "rows": 6, "square": 0.025}, "options": {"camera": {"fix_k3": true}}}});
    let id = s.job(body).await;
    assert_eq!(s.wait_terminal(&id).await["status"], "succeeded");
    let kalibr = client
        .get(s.url(
            "/v1/devices/rig-1/documents/stereo-kalibr/rig_calibration/latest?format=kalibr-yaml",
        ))
        .send()
        .await
        .expect("get")
        .text()
        .await
        .expect("text");
    let cams = caliper_core::export::read_kalibr_camchain(&kalibr).expect("camchain reads back");
    assert_eq!(cams.len(), 2, "{kalibr}");
    assert!(kalibr.contains("T_cn_cnm1"), "{kalibr}");
    // The rectified preview is an artifact: a PNG of both images side by side.
    let resp = reqwest::get(s.url(&format!("/v1/jobs/{id}/artifacts/rectified_cam0_cam1.png")))
        .await
        .expect("get");
    assert_eq!(resp.status().as_u16(), 200);
    let preview = image::load_from_memory(&resp.bytes().await.expect("bytes")).expect("png");
    assert_eq!((preview.width(), preview.height()), (2 * 640 + 8, 480));
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_rigs_fail_with_the_reason() {
    let s = start().await;
    let mut files = stereo_renders();
    // One right image missing: the frame counts differ.
    files.retain(|(n, _)| n != "cam1/frame11.png");
    let ds = s.dataset(vec![("rig.zip", zip_of(&files))]).await;
    let id = s
        .job(json!({"kind": "rig_calibration", "dataset": ds, "params": {"board": {"cols": 9, "rows": 6, "square": 0.025}}}))
        .await;
    let done = s.wait_terminal(&id).await;
    assert_eq!(done["status"], "failed", "{done}");
    assert!(
        done.to_string().contains("different frame counts"),
        "{done}"
    );
    // …which pairing by timestamp in the names handles (frame11 of cam0 has no partner).
    let id = s
        .job(json!({"kind": "rig_calibration", "dataset": ds, "params": {"board": {"cols": 9, "rows": 6, "square": 0.025}, "pairing": "timestamp"}}))
        .await;
    let done = s.wait_terminal(&id).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    // Images not in camera folders.
    let flat: Vec<(&str, Vec<u8>)> =
        vec![("a.png", files[0].1.clone()), ("b.png", files[1].1.clone())];
    let ds = s.dataset(flat).await;
    let id = s
        .job(json!({"kind": "rig_calibration", "dataset": ds, "params": {"board": {"cols": 9, "rows": 6, "square": 0.025}}}))
        .await;
    let done = s.wait_terminal(&id).await;
    assert_eq!(done["status"], "failed");
    assert!(done.to_string().contains("camera folder"), "{done}");
    // A camera that never sees the board.
    let blank = png(&image::GrayImage::from_pixel(
        640,
        480,
        image::Luma([128u8]),
    ));
    let mut no_board = stereo_renders();
    for (n, b) in &mut no_board {
        if n.starts_with("cam1/") {
            *b = blank.clone();
        }
    }
    let ds = s.dataset(vec![("rig.zip", zip_of(&no_board))]).await;
    let id = s
        .job(json!({"kind": "rig_calibration", "dataset": ds, "params": {"board": {"cols": 9, "rows": 6, "square": 0.025}}}))
        .await;
    let done = s.wait_terminal(&id).await;
    assert_eq!(done["status"], "failed");
    assert!(done.to_string().contains("never sees"), "{done}");
    // Parameters checked at the edge.
    let (st, body) = s
        .post_json(
            "/v1/jobs",
            &json!({"kind": "rig_calibration", "dataset": ds, "params": {"board": {"cols": 9, "rows": 6, "square": 0.025}, "cameras": ["cam0"]}}),
        )
        .await;
    assert_eq!(st, 422, "{body}");
    assert_eq!(body["field"], "params.cameras", "{body}");
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn offline_rig_run_takes_one_directory_per_camera() {
    let bin = tokio::task::spawn_blocking(caliper_bin)
        .await
        .expect("join");
    let dir = tempfile::tempdir().expect("tmp");
    for (name, data) in stereo_renders() {
        let p = dir.path().join(&name);
        std::fs::create_dir_all(p.parent().expect("parent")).expect("mkdir");
        std::fs::write(p, data).expect("write");
    }
    let out = std::process::Command::new(&bin)
        .args([
            "run",
            "rig-calibration",
            "--board",
            "9x6",
            "--square",
            "0.025",
        ])
        .arg(dir.path().join("cam0"))
        .arg(dir.path().join("cam1"))
        .output()
        .expect("run");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let doc: Value = serde_json::from_slice(&out.stdout).expect("json");
    assert_eq!(doc["schema"], "caliper.rig/v1");
    check_rig(&doc);
}
