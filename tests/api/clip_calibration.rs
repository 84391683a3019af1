//! `camera_calibration` from a video clip: a board filmed along a path (held still at some
//! poses, blurred while moving) is calibrated by the service and offline; the known camera
//! comes back, and the document says which frames were used and why the others were not.

use caliper_core::camera::{Camera, PinholeRadTan};
use caliper_core::lie::Se3;
use caliper_core::synth::{RenderOptions, render_chessboard};
use nalgebra::Vector3;
use serde_json::{Value, json};

use crate::common::*;

/// The filming camera, 480×360.
const CAMERA: [f64; 9] = [
    410.0, 409.0, 243.0, 178.0, -0.22, 0.05, 0.0008, -0.0004, 0.0,
];

/// A clip of a 9×6 board (25 mm squares): 14 poses, each held for 3 sharp frames, joined by
/// 3 frames of fast motion (rendered blurred). 84 frames at 30 fps, made once per test run.
fn board_clip() -> Vec<u8> {
    static CLIP: std::sync::OnceLock<Vec<u8>> = std::sync::OnceLock::new();
    CLIP.get_or_init(|| {
        let t0 = std::time::Instant::now();
        let mp4 = caliper_core::video::encode_h264_mp4(board_frames(), 30.0).expect("encode");
        eprintln!("board clip: encoded in {:?}", t0.elapsed());
        mp4
    })
    .clone()
}

/// The clip's frames: pose k is held in frames 6k..6k+2, frames 6k+3..6k+5 are moving.
fn board_frames() -> &'static [image::GrayImage] {
    static FRAMES: std::sync::OnceLock<Vec<image::GrayImage>> = std::sync::OnceLock::new();
    FRAMES.get_or_init(render_board_frames)
}

fn render_board_frames() -> Vec<image::GrayImage> {
    let t0 = std::time::Instant::now();
    let cam: Camera = PinholeRadTan::from_slice(&CAMERA).expect("camera").into();
    let (cols, rows, sq) = (9usize, 6usize, 0.025);
    let centre = Vector3::new(
        (cols - 1) as f64 * sq / 2.0,
        (rows - 1) as f64 * sq / 2.0,
        0.0,
    );
    let poses = [
        (0.0, 0.0, 0.0, 0.0, 0.0, 0.55),
        (0.4, 0.0, 0.1, -0.06, 0.02, 0.5),
        (-0.4, 0.1, -0.2, 0.07, -0.03, 0.55),
        (0.0, 0.45, 0.3, 0.06, 0.04, 0.5),
        (0.1, -0.45, -0.1, -0.05, -0.04, 0.52),
        (0.3, 0.3, 0.5, 0.07, 0.05, 0.6),
        (-0.3, -0.3, -0.4, -0.07, 0.04, 0.55),
        (0.25, -0.2, 1.2, 0.04, -0.05, 0.5),
        (-0.2, 0.3, -1.0, 0.06, 0.0, 0.58),
        (0.45, 0.1, 0.0, -0.02, 0.05, 0.55),
        (-0.1, -0.35, 0.6, 0.05, -0.05, 0.5),
        (0.2, 0.4, -0.6, -0.06, 0.03, 0.56),
        (0.0, -0.2, 0.2, 0.08, 0.06, 0.6),
        (-0.35, 0.0, 0.9, -0.08, -0.05, 0.57),
    ];
    let pose_of = |p: (f64, f64, f64, f64, f64, f64)| {
        let rvec = Vector3::new(p.0, p.1, p.2);
        let r = Se3::from_rvec_tvec(&rvec, &Vector3::zeros());
        let t = -r.act(&centre) + Vector3::new(p.3, p.4, p.5);
        Se3::from_rvec_tvec(&rvec, &t)
    };
    let render = |pose: &Se3, blur: f64, seed: u64| {
        let opts = RenderOptions {
            noise_sigma: 1.0,
            seed,
            blur_sigma: blur,
            ..RenderOptions::default()
        };
        let view =
            render_chessboard(&cam, pose, (cols, rows, sq), (480, 360), &opts).expect("render");
        image::GrayImage::from_raw(480, 360, view.image.data).expect("image")
    };
    let mut frames = Vec::new();
    for (k, &p) in poses.iter().enumerate() {
        let pose = pose_of(p);
        for j in 0..3 {
            frames.push(render(&pose, 0.5, 100 * k as u64 + j));
        }
        // Moving on to the next pose: halfway there, smeared.
        let next = poses[(k + 1) % poses.len()];
        let mid = |a: f64, b: f64| 0.5 * (a + b);
        let between = pose_of((
            mid(p.0, next.0),
            mid(p.1, next.1),
            mid(p.2, next.2),
            mid(p.3, next.3),
            mid(p.4, next.4),
            mid(p.5, next.5),
        ));
        for j in 0..3 {
            frames.push(render(&between, 4.0, 100 * k as u64 + 50 + j));
        }
    }
    eprintln!("board clip: rendered in {:?}", t0.elapsed());
    frames
}

/// `(value, σ)` of a named parameter of a camera document.
fn estimate(doc: &Value, name: &str) -> (f64, f64) {
    let p = doc["parameters"]["calibration"]["parameters"]
        .as_array()
        .and_then(|ps| ps.iter().find(|p| p["name"] == name))
        .unwrap_or_else(|| panic!("no {name}"));
    (
        p["value"].as_f64().expect("value"),
        p["std_dev"].as_f64().expect("σ"),
    )
}

fn check_camera(doc: &Value) {
    let cam = &doc["parameters"]["camera"];
    for (name, truth) in [
        ("fx", CAMERA[0]),
        ("fy", CAMERA[1]),
        ("cx", CAMERA[2]),
        ("cy", CAMERA[3]),
    ] {
        let v = cam[name].as_f64().unwrap_or(f64::NAN);
        assert!(
            (v - truth).abs() < 0.005 * truth,
            "{name} = {v}, truth {truth}: {cam}"
        );
    }
    let rms = doc["quality"]["rms"].as_f64().expect("rms");
    assert!(rms < 0.5, "rms {rms}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_filmed_board_calibrates_and_the_document_lists_the_frames() {
    let s = start().await;
    let mp4 = tokio::task::spawn_blocking(board_clip).await.expect("join");
    let (st, ds, _) = s.upload(vec![("board.mp4", mp4)]).await;
    assert_eq!(st, 201, "{ds}");
    // 42 searched frames (windows of 2), at most 12 views, for speed.
    let id = s
        .job(json!({"kind": "camera_calibration", "dataset": ds["id"],
            "params": {"board": {"cols": 9, "rows": 6, "square": 0.025},
                       "clip": {"max_candidates": 45, "max_views": 12}}}))
        .await;
    let done = s.wait_terminal(&id).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    let (_, doc) = s.get_json(&format!("/v1/jobs/{id}/result")).await;
    check_camera(&doc);
    let clip = &doc["parameters"]["clip"];
    assert_eq!(clip["frames_decoded"], 84, "{clip}");
    assert_eq!(clip["window"], 2, "{clip}");
    let frames = clip["frames"].as_array().expect("frames");
    assert_eq!(frames.len(), 42);
    let used: Vec<&Value> = frames.iter().filter(|f| f["decision"] == "used").collect();
    assert_eq!(used.len(), 12, "{}", clip["summary"]);
    // Every used frame is one of the held (sharp) ones: the first three of each six.
    for f in &used {
        let i = f["index"].as_u64().expect("index");
        assert!(i % 6 < 3, "a moving frame was used: {f}");
        assert!(f["pts_s"].as_f64().is_some(), "{f}");
    }
    // The poses are held for 3 frames: some searched frames duplicate a used one, and the
    // cap left distinct views out.
    let summary = &clip["summary"];
    assert!(
        summary["near_duplicate"].as_u64().unwrap_or(0)
            + summary["cap_reached"].as_u64().unwrap_or(0)
            > 0,
        "{summary}"
    );
    for f in frames.iter().filter(|f| f["decision"] == "near_duplicate") {
        let of = f["of"].as_u64().expect("of");
        assert!(
            used.iter().any(|u| u["index"] == of),
            "near-duplicate of a frame not used: {f}"
        );
    }
    assert_eq!(
        doc["parameters"]["observations"].as_array().map(Vec::len),
        Some(12)
    );

    // The same poses as stills (one sharp frame of each, as PNG): with the default selection
    // the clip uses every pose, and its intrinsics agree with the stills' within 1σ although
    // half of its frames are smeared.
    let id = s
        .job(json!({"kind": "camera_calibration", "dataset": ds["id"],
            "params": {"board": {"cols": 9, "rows": 6, "square": 0.025}}}))
        .await;
    let done = s.wait_terminal(&id).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    let (_, clip_doc) = s.get_json(&format!("/v1/jobs/{id}/result")).await;
    assert_eq!(clip_doc["parameters"]["clip"]["summary"]["used"], 14);
    let stills: Vec<(String, Vec<u8>)> = board_frames()
        .iter()
        .step_by(6)
        .enumerate()
        .map(|(k, f)| (format!("pose{k:02}.png"), png(f)))
        .collect();
    let ds3 = s.dataset(as_refs(&stills)).await;
    let id = s
        .job(json!({"kind": "camera_calibration", "dataset": ds3,
            "params": {"board": {"cols": 9, "rows": 6, "square": 0.025}}}))
        .await;
    let done = s.wait_terminal(&id).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    let (_, still_doc) = s.get_json(&format!("/v1/jobs/{id}/result")).await;
    for name in ["fx", "fy", "cx", "cy", "k1", "k2"] {
        let (c, sc) = estimate(&clip_doc, name);
        let (st, _) = estimate(&still_doc, name);
        eprintln!("{name}: clip {c:.5} ± {sc:.5}, stills {st:.5}");
        assert!((c - st).abs() < sc, "{name}: clip {c} ± {sc}, stills {st}");
    }

    // Too few distinct views: a clip of one held pose says what to do.
    let still: Vec<image::GrayImage> = {
        let cam: Camera = PinholeRadTan::from_slice(&CAMERA).expect("camera").into();
        let pose = Se3::from_rvec_tvec(
            &Vector3::new(0.1, 0.0, 0.0),
            &Vector3::new(-0.1, -0.06, 0.5),
        );
        let v = render_chessboard(
            &cam,
            &pose,
            (9, 6, 0.025),
            (480, 360),
            &RenderOptions::default(),
        )
        .expect("render");
        let img = image::GrayImage::from_raw(480, 360, v.image.data).expect("image");
        vec![img; 20]
    };
    let mp4 = caliper_core::video::encode_h264_mp4(&still, 30.0).expect("encode");
    let (_, ds2, _) = s.upload(vec![("still.mp4", mp4)]).await;
    let id = s
        .job(json!({"kind": "camera_calibration", "dataset": ds2["id"],
            "params": {"board": {"cols": 9, "rows": 6, "square": 0.025}}}))
        .await;
    let done = s.wait_terminal(&id).await;
    assert_eq!(done["status"], "failed", "{done}");
    let err = done["error"].to_string();
    assert!(
        err.contains("no_solution") && err.contains("distinct"),
        "{err}"
    );

    // Clip parameters out of range are refused at the edge.
    let (st, body) = s
        .post_json(
            "/v1/jobs",
            &json!({"kind": "camera_calibration", "dataset": ds["id"],
                "params": {"board": {"cols": 9, "rows": 6, "square": 0.025},
                           "clip": {"max_views": 1}}}),
        )
        .await;
    assert_eq!(st, 422, "{body}");
    assert_eq!(body["field"], "params.clip.max_views", "{body}");
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn offline_run_calibrates_from_a_clip() {
    let bin = tokio::task::spawn_blocking(caliper_bin)
        .await
        .expect("join");
    let dir = tempfile::tempdir().expect("tmp");
    let path = dir.path().join("board.mp4");
    let mp4 = tokio::task::spawn_blocking(board_clip).await.expect("join");
    std::fs::write(&path, mp4).expect("write");
    let t0 = std::time::Instant::now();
    let out = std::process::Command::new(&bin)
        .args([
            "run",
            "camera-calibration",
            "--board",
            "9x6",
            "--square",
            "0.025",
        ])
        .arg(&path)
        .output()
        .expect("run");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    eprintln!("offline clip calibration: {:?}", t0.elapsed());
    let doc: Value = serde_json::from_slice(&out.stdout).expect("json");
    assert_eq!(doc["schema"], "caliper.camera/v1");
    check_camera(&doc);
    assert_eq!(doc["parameters"]["clip"]["frames_decoded"], 84);
}
