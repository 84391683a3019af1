//! Which stereo calibration is right when ours and OpenCV's disagree on `opencv_stereo`?
//! That set has no ground truth, so this renders replicas of it that do: two 640×480 pinhole
//! cameras with OpenCV's own estimates of the sample's intrinsics and distortion, its
//! baseline (3.345 squares) and rotation (0.31°), 13 synchronised views of a 9×6 board 11–17
//! squares away, turned up to ~30°, blurred and noisy, saved as grey JPEGs like the sample.
//! Each replica goes through Caliper (detection + `calibrate_rig`, default options, and with
//! the intrinsics held at each camera's own calibration, as `CALIB_FIX_INTRINSIC`) and through
//! the OpenCV peer (`camera_opencv.py --stereo`: `findChessboardCorners` + `cornerSubPix`, mono
//! calibrations, `stereoCalibrate(CALIB_FIX_INTRINSIC)`); both are scored against the truth.
//!
//! ```text
//! CALIPER_PYTHON=… cargo run --release -p caliper-core --example stereo_replica -- [REPLICAS] [OUT_DIR]
//! ```
//! The peer script is looked up in `CALIPER_PEERS` (default `../shared/peers`).

use std::path::{Path, PathBuf};
use std::process::Command;

use caliper_core::NoProgress;
use caliper_core::board::{DetectOptions, Detection, detect_chessboard};
use caliper_core::calib::{BoardGeometry, ModelKind, ViewObservations};
use caliper_core::camera::{Camera, PinholeRadTan};
use caliper_core::io::{ImageLimits, decode_gray8};
use caliper_core::lie::{Se3, So3};
use caliper_core::photometric::synth::Rng;
use caliper_core::rig::{RigCalibration, RigCameraInput, RigOptions, calibrate_rig};
use caliper_core::synth::{RenderOptions, render_chessboard};
use nalgebra::{Matrix3, Vector3};

const BOARD: BoardGeometry = BoardGeometry {
    cols: 9,
    rows: 6,
    square: 1.0,
};

/// Errors of an estimate against the truth: |Δbaseline|, ‖ΔT‖ (squares), rotation (°).
#[derive(Clone, Copy, Default)]
struct Err3 {
    baseline: f64,
    t: f64,
    rot: f64,
}

fn score(r: &Matrix3<f64>, t: &Vector3<f64>, truth: &Se3) -> Err3 {
    let rt = truth.rotation.matrix();
    let d = r * rt.transpose();
    let c = ((d.trace() - 1.0) / 2.0).clamp(-1.0, 1.0);
    Err3 {
        baseline: (t.norm() - truth.translation.norm()).abs(),
        t: (t - truth.translation).norm(),
        rot: c.acos().to_degrees(),
    }
}

fn ours(rig: &RigCalibration) -> (Matrix3<f64>, Vector3<f64>) {
    let e = &rig.extrinsics[1].t_cam_cam0;
    let q = So3::from_wxyz(e.quaternion_wxyz).expect("unit quaternion");
    (q.matrix(), Vector3::from(e.translation))
}

fn peer(py: &Path, script: &Path, dir: &Path) -> Option<(Matrix3<f64>, Vector3<f64>)> {
    let out = Command::new(py)
        .arg(script)
        .args(["--stereo", "--cols", "9", "--rows", "6", "--runs", "1"])
        .arg("--left")
        .arg(dir.join("left*.jpg"))
        .arg("--right")
        .arg(dir.join("right*.jpg"))
        .output()
        .ok()?;
    if !out.status.success() {
        eprintln!("peer failed: {}", String::from_utf8_lossy(&out.stderr));
        return None;
    }
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).ok()?;
    let s = &v["result"]["stereo"];
    let s = if s.is_null() { &v["stereo"] } else { s };
    let r: Vec<f64> = s["R"]
        .as_array()?
        .iter()
        .flat_map(|row| row.as_array().cloned().unwrap_or_default())
        .filter_map(|x| x.as_f64())
        .collect();
    let t: Vec<f64> = s["T"]
        .as_array()?
        .iter()
        .filter_map(|x| x.as_f64())
        .collect();
    (r.len() == 9 && t.len() == 3)
        .then(|| (Matrix3::from_row_slice(&r), Vector3::new(t[0], t[1], t[2])))
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let replicas: u64 = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(6);
    let root = PathBuf::from(
        args.get(2)
            .cloned()
            .unwrap_or_else(|| "/tmp/stereo_replica".into()),
    );
    let py = std::env::var_os("CALIPER_PYTHON").map(PathBuf::from);
    let peers = std::env::var_os("CALIPER_PEERS").map_or_else(
        || Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/peers"),
        PathBuf::from,
    );
    let script = peers.join("camera_opencv.py");
    let left: Camera = PinholeRadTan::new(
        536.07, 536.02, 342.37, 235.54, -0.2651, -0.0467, 0.00183, -0.00031, 0.2523,
    )
    .expect("camera")
    .into();
    let right: Camera = PinholeRadTan::new(
        542.36, 541.62, 328.32, 246.95, -0.2780, 0.0120, 0.00050, 0.00040, 0.1500,
    )
    .expect("camera")
    .into();
    let truth = Se3::new(
        So3::exp(&Vector3::new(0.0032, 0.0041, -0.0012)),
        Vector3::new(-3.344, 0.042, 0.053),
    );
    let centre = Vector3::new(4.0, 2.5, 0.0);
    let mut rows: Vec<[Option<Err3>; 3]> = Vec::new();
    for rep in 0..replicas {
        let dir = root.join(format!("r{rep}"));
        std::fs::create_dir_all(&dir).expect("out dir");
        let mut rng = Rng::new(1000 + rep);
        let mut views: [Vec<Option<ViewObservations>>; 2] = [Vec::new(), Vec::new()];
        let mut k = 0;
        while k < 13 {
            let r = So3::exp(&Vector3::new(
                1.0 * (rng.uniform() - 0.5),
                1.0 * (rng.uniform() - 0.5),
                0.6 * (rng.uniform() - 0.5),
            ));
            let z = 11.0 + 6.0 * rng.uniform();
            let p = Vector3::new(
                z * 0.45 * (rng.uniform() - 0.5) - 1.5,
                z * 0.35 * (rng.uniform() - 0.5),
                z,
            );
            let pose = Se3::new(r, p - r.act(&centre));
            let mut imgs = Vec::new();
            for (c, (cam, t)) in [(&left, Se3::identity()), (&right, truth)]
                .iter()
                .enumerate()
            {
                let opts = RenderOptions {
                    blur_sigma: 0.8,
                    noise_sigma: 2.0,
                    seed: rep * 1000 + k * 2 + c as u64,
                    ..RenderOptions::default()
                };
                match render_chessboard(cam, &t.compose(&pose), (9, 6, 1.0), (640, 480), &opts) {
                    Ok(v) if v.all_visible() => imgs.push(v.image),
                    _ => break,
                }
            }
            if imgs.len() < 2 {
                continue;
            }
            for (c, img) in imgs.into_iter().enumerate() {
                let side = if c == 0 { "left" } else { "right" };
                let g = image::GrayImage::from_raw(640, 480, img.data).expect("image");
                let path = dir.join(format!("{side}{:02}.jpg", k + 1));
                let mut buf = Vec::new();
                image::codecs::jpeg::JpegEncoder::new_with_quality(&mut buf, 92)
                    .encode_image(&g)
                    .expect("jpeg");
                std::fs::write(&path, &buf).expect("write");
                let gray = decode_gray8(&buf, &ImageLimits::default()).expect("decode");
                let det = match detect_chessboard(&gray, 9, 6, &DetectOptions::default()) {
                    Detection::Found { corners, .. } => {
                        let dense: Vec<Option<[f64; 2]>> =
                            corners.iter().map(|&p| Some(p)).collect();
                        Some(ViewObservations::from_dense(format!("{k}"), &dense))
                    }
                    Detection::NotFound { .. } => None,
                };
                views[c].push(det);
            }
            k += 1;
        }
        let inputs = |views: &[Vec<Option<ViewObservations>>; 2]| -> Vec<RigCameraInput> {
            ["left", "right"]
                .iter()
                .zip(views.iter())
                .map(|(n, v)| RigCameraInput {
                    name: (*n).into(),
                    model: ModelKind::PinholeRadTan,
                    image_size: [640, 480],
                    views: v.clone(),
                    fixed: None,
                })
                .collect()
        };
        let run = |opts: &RigOptions| {
            calibrate_rig(&inputs(&views), &BOARD, opts, &NoProgress)
                .ok()
                .map(|rig| {
                    let (r, t) = ours(&rig);
                    score(&r, &t, &truth)
                })
        };
        let default = run(&RigOptions::default());
        let fixed = run(&RigOptions {
            refine_intrinsics: false,
            ..RigOptions::default()
        });
        let cv = py
            .as_deref()
            .and_then(|py| peer(py, &script, &dir))
            .map(|(r, t)| score(&r, &t, &truth));
        let f = |e: Option<Err3>| {
            e.map_or_else(
                || "–".to_string(),
                |e| format!("{:.4} / {:.4} / {:.4}°", e.baseline, e.t, e.rot),
            )
        };
        println!(
            "replica {rep}: |Δbaseline| / ‖ΔT‖ / Δrotation — Caliper default {}, Caliper intrinsics fixed {}, OpenCV {}",
            f(default),
            f(fixed),
            f(cv)
        );
        rows.push([default, fixed, cv]);
    }
    let names = [
        "Caliper default",
        "Caliper, intrinsics fixed",
        "OpenCV FIX_INTRINSIC",
    ];
    println!(
        "\n| estimator | replicas | RMS |Δbaseline| (squares) | RMS ‖ΔT‖ | RMS Δrotation (°) |"
    );
    println!("|---|---|---|---|---|");
    for (i, name) in names.iter().enumerate() {
        let v: Vec<Err3> = rows.iter().filter_map(|r| r[i]).collect();
        if v.is_empty() {
            println!("| {name} | 0 | – | – | – |");
            continue;
        }
        let rms = |f: fn(&Err3) -> f64| {
            (v.iter().map(|e| f(e).powi(2)).sum::<f64>() / v.len() as f64).sqrt()
        };
        println!(
            "| {name} | {} | {:.4} | {:.4} | {:.4} |",
            v.len(),
            rms(|e| e.baseline),
            rms(|e| e.t),
            rms(|e| e.rot)
        );
    }
}
