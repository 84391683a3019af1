//! `camera_calibration` end to end: synthetic chessboard renders through a known camera are
//! uploaded, calibrated by the service, and the known parameters come back; exports too.

use caliper_core::camera::{Camera, PinholeRadTan};
use caliper_core::lie::Se3;
use caliper_core::synth::{RenderOptions, render_chessboard};
use nalgebra::Vector3;
use serde_json::{Value, json};

use crate::common::*;

const TRUTH: [f64; 9] = [
    536.0, 534.0, 322.0, 241.0, -0.26, 0.07, 0.0015, -0.0008, 0.0,
];

/// Ten views of a 9×6 board (25 mm squares) around 0.45 m, tilted up to ~35°.
pub(crate) fn renders() -> Vec<(String, Vec<u8>)> {
    let camera: Camera = PinholeRadTan::from_slice(&TRUTH).expect("camera").into();
    let (cols, rows, sq) = (9usize, 6usize, 0.025);
    let centre = Vector3::new(
        (cols - 1) as f64 * sq / 2.0,
        (rows - 1) as f64 * sq / 2.0,
        0.0,
    );
    let tilts = [
        (0.0, 0.0, 0.0, 0.0, 0.0),
        (0.45, 0.0, 0.1, -0.05, 0.02),
        (-0.45, 0.1, -0.2, 0.06, -0.03),
        (0.0, 0.5, 0.3, 0.04, 0.05),
        (0.1, -0.5, -0.1, -0.06, -0.04),
        (0.35, 0.35, 0.5, 0.07, 0.06),
        (-0.3, -0.35, -0.4, -0.07, 0.05),
        (0.25, -0.2, 1.2, 0.0, -0.06),
        (-0.2, 0.3, -1.0, 0.05, 0.0),
        (0.5, 0.1, 0.0, -0.02, 0.07),
    ];
    tilts
        .iter()
        .enumerate()
        .map(|(i, &(ax, ay, az, ox, oy))| {
            let rvec = Vector3::new(ax, ay, az);
            let r = Se3::from_rvec_tvec(&rvec, &Vector3::zeros());
            let t = -r.act(&centre) + Vector3::new(ox, oy, 0.42 + 0.02 * (i % 3) as f64);
            let pose = Se3::from_rvec_tvec(&rvec, &t);
            let opts = RenderOptions {
                noise_sigma: 1.0,
                seed: i as u64 + 1,
                blur_sigma: 0.5,
                ..RenderOptions::default()
            };
            let view = render_chessboard(&camera, &pose, (cols, rows, sq), (640, 480), &opts)
                .expect("render");
            assert!(view.all_visible(), "view {i} leaves the image");
            let img = image::GrayImage::from_raw(640, 480, view.image.data).expect("image");
            (format!("view{i:02}.png"), png(&img))
        })
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn synthetic_views_recover_the_known_camera_and_export() {
    let s = start().await;
    let files = renders();
    // One image without a board: reported, not fatal.
    let mut all = as_refs(&files);
    all.push((
        "empty.png",
        png(&image::GrayImage::from_pixel(
            640,
            480,
            image::Luma([120u8]),
        )),
    ));
    let ds = s.dataset(all).await;
    let body = json!({"kind": "camera_calibration", "dataset": ds, "device": "cam-7", "sensor": "cam0",
                      "params": {"board": {"cols": 9, "rows": 6, "square": 0.025}}});
    let id = s.job(body).await;
    let done = s.wait_terminal(&id).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    // The same views with the light correction on: same camera.
    let lit = json!({"kind": "camera_calibration", "dataset": ds, "device": "cam-7", "sensor": "cam0-lit",
                     "params": {"board": {"cols": 9, "rows": 6, "square": 0.025},
                                "detection": {"chessboard": {"light_correction": true}}}});
    let lit_id = s.job(lit).await;
    assert_eq!(s.wait_terminal(&lit_id).await["status"], "succeeded");
    let (_, lit_doc) = s
        .get_json("/v1/devices/cam-7/documents/cam0-lit/camera_calibration/latest")
        .await;
    let fx = lit_doc["parameters"]["camera"]["fx"]
        .as_f64()
        .unwrap_or(f64::NAN);
    assert!((fx - TRUTH[0]).abs() < 0.002 * TRUTH[0], "{lit_doc}");
    let base = "/v1/devices/cam-7/documents/cam0/camera_calibration";
    let (st, doc) = s.get_json(&format!("{base}/latest")).await;
    assert_eq!(st, 200);
    assert_eq!(doc["schema"], "caliper.camera/v1");
    let cam = &doc["parameters"]["camera"];
    assert_eq!(cam["model"], "pinhole_radtan");
    for (name, truth) in [
        ("fx", TRUTH[0]),
        ("fy", TRUTH[1]),
        ("cx", TRUTH[2]),
        ("cy", TRUTH[3]),
    ] {
        let v = cam[name].as_f64().unwrap_or(f64::NAN);
        assert!(
            (v - truth).abs() < 0.002 * truth,
            "{name} = {v}, truth {truth}: {cam}"
        );
    }
    assert!(
        (cam["k1"].as_f64().unwrap() - TRUTH[4]).abs() < 5e-3,
        "{cam}"
    );
    let q = &doc["quality"];
    assert!(q["rms"].as_f64().unwrap() < 0.3, "{q}");
    assert_eq!(q["boards_detected"], 10);
    assert_eq!(q["images"], 11);
    let images = doc["parameters"]["images"].as_array().unwrap();
    let empty = images.iter().find(|i| i["name"] == "empty.png").unwrap();
    assert!(
        empty["excluded"].as_str().unwrap().starts_with("no board"),
        "{empty}"
    );
    // Each parameter has a standard deviation.
    let params = doc["parameters"]["calibration"]["parameters"]
        .as_array()
        .unwrap();
    assert!(
        params
            .iter()
            .all(|p| p["std_dev"].as_f64().is_some_and(|s| s > 0.0)),
        "{params:?}"
    );

    // Artifacts.
    let (_, arts) = s.get_json(&format!("/v1/jobs/{id}/artifacts")).await;
    let names: Vec<&str> = arts["items"]
        .as_array()
        .unwrap()
        .iter()
        .map(|a| a["name"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["coverage.svg", "residuals.svg", "view_rms.svg"]);

    // Exports.
    let r = s
        .client
        .get(s.url(&format!("{base}/latest?format=opencv-yaml")))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    let yaml = r.text().await.unwrap();
    assert!(yaml.starts_with("%YAML:1.0"), "{yaml}");
    assert!(yaml.contains("camera_matrix: !!opencv-matrix"));
    for f in ["ros-yaml", "json"] {
        let r = s
            .client
            .get(s.url(&format!("{base}/1?format={f}")))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status(), 200, "{f}");
    }
    // Kalibr's radtan has no k3: a camera with k3 ≠ 0 is refused rather than silently changed.
    let (st, p) = s.get_json(&format!("{base}/1?format=kalibr-yaml")).await;
    assert_eq!(st, 400, "{p}");
    assert!(p["detail"].as_str().unwrap().contains("fix_k3"), "{p}");
    let (st, p) = s.get_json(&format!("{base}/latest?format=png")).await;
    assert_eq!(st, 400);
    assert_eq!(p["code"], "unsupported_format");
    let r = s
        .client
        .get(s.url(&format!("/v1/jobs/{id}/result?format=ros-yaml")))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    assert!(
        r.text()
            .await
            .unwrap()
            .contains("distortion_model: plumb_bob")
    );
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn too_few_boards_fail_with_a_clear_reason() {
    let s = start().await;
    let blank = png(&image::GrayImage::from_pixel(320, 240, image::Luma([90u8])));
    let ds = s
        .dataset(vec![
            ("a.png", blank.clone()),
            ("b.png", png(&sharp_image(320, 240))),
        ])
        .await;
    let id = s
        .job(json!({"kind": "camera_calibration", "dataset": ds, "params": {"board": {"cols": 9, "rows": 6, "square": 1.0, "unit": "squares"}}}))
        .await;
    let done: Value = s.wait_terminal(&id).await;
    assert_eq!(done["status"], "failed");
    assert_eq!(done["error"]["code"], "no_solution");
    assert_eq!(done["attempt"], 1, "bad input is not retried");
    let (st, p) = s
        .post_json("/v1/jobs", &json!({"kind": "camera_calibration", "dataset": ds, "params": {"board": {"cols": 1, "rows": 6, "square": 1.0}}}))
        .await;
    assert_eq!(st, 422);
    assert_eq!(p["field"], "params.board");
    let (st, p) = s
        .post_json("/v1/jobs", &json!({"kind": "camera_calibration", "dataset": ds, "params": {"board": {"cols": 9, "rows": 6, "square": 1.0},
                                                                                             "detection": {"chessboard": {"sigma": -1.0}}}}))
        .await;
    assert_eq!(st, 422, "{p}");
    assert!(
        p["field"]
            .as_str()
            .unwrap_or("")
            .starts_with("params.detection"),
        "{p}"
    );
    s.stop().await;
}

/// Views of a 7×5 board through a strong fisheye, placed across the field of view.
fn fisheye_renders(camera: &Camera) -> Vec<(String, Vec<u8>)> {
    use caliper_core::camera::CameraModel;
    let (cols, rows, sq) = (7usize, 5usize, 0.03);
    let centre = Vector3::new(
        (cols - 1) as f64 * sq / 2.0,
        (rows - 1) as f64 * sq / 2.0,
        0.0,
    );
    let spots = [
        ([320.0, 320.0], [0.0, 0.0, 0.0]),
        ([200.0, 220.0], [0.3, -0.4, 0.1]),
        ([450.0, 210.0], [0.3, 0.4, -0.2]),
        ([190.0, 440.0], [-0.3, -0.4, 0.3]),
        ([440.0, 450.0], [-0.3, 0.4, 0.0]),
        ([320.0, 150.0], [0.5, 0.0, 0.2]),
        ([320.0, 490.0], [-0.5, 0.0, -0.1]),
        ([150.0, 320.0], [0.0, -0.5, 0.4]),
        ([490.0, 320.0], [0.1, 0.5, 0.0]),
    ];
    spots
        .iter()
        .enumerate()
        .map(|(i, &(px, rot))| {
            let ray = camera
                .unproject(&nalgebra::Vector2::new(px[0], px[1]))
                .expect("ray");
            let rvec = Vector3::new(rot[0], rot[1], rot[2]);
            let r = Se3::from_rvec_tvec(&rvec, &Vector3::zeros());
            let t = ray.normalize() * 0.22 - r.act(&centre);
            let pose = Se3::from_rvec_tvec(&rvec, &t);
            let opts = RenderOptions {
                noise_sigma: 1.0,
                seed: 100 + i as u64,
                blur_sigma: 0.5,
                ..RenderOptions::default()
            };
            let view = render_chessboard(camera, &pose, (cols, rows, sq), (640, 640), &opts)
                .expect("render");
            assert!(view.all_visible(), "fisheye view {i} leaves the image");
            let img = image::GrayImage::from_raw(640, 640, view.image.data).expect("image");
            (format!("fish{i:02}.png"), png(&img))
        })
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn fisheye_views_calibrate_without_a_starting_guess() {
    use caliper_core::camera::KannalaBrandt;
    let truth = [200.0, 200.0, 319.5, 319.5, 0.02, -0.01, 0.002, 0.0];
    let camera: Camera = KannalaBrandt::from_slice(&truth).expect("camera").into();
    let s = start().await;
    let files = fisheye_renders(&camera);
    let ds = s.dataset(as_refs(&files)).await;
    let id = s
        .job(json!({"kind": "camera_calibration", "dataset": ds,
                    "params": {"board": {"cols": 7, "rows": 5, "square": 0.03}, "model": "kannala_brandt"}}))
        .await;
    let done = s.wait_terminal(&id).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    let (_, doc) = s.get_json(&format!("/v1/jobs/{id}/result")).await;
    let cam = &doc["parameters"]["camera"];
    assert_eq!(cam["model"], "kannala_brandt");
    for (name, t) in [
        ("fx", truth[0]),
        ("fy", truth[1]),
        ("cx", truth[2]),
        ("cy", truth[3]),
    ] {
        let v = cam[name].as_f64().unwrap_or(f64::NAN);
        assert!((v - t).abs() < 0.003 * t, "{name} = {v}, truth {t}: {cam}");
    }
    assert_eq!(
        doc["quality"]["views_used"], 9,
        "every view kept: {}",
        doc["quality"]
    );
    let r = s
        .client
        .get(s.url(&format!("/v1/jobs/{id}/result?format=opencv-yaml")))
        .send()
        .await
        .unwrap();
    let yaml = r.text().await.unwrap();
    assert!(yaml.contains("fisheye_model: 1"), "{yaml}");
    s.stop().await;
}
