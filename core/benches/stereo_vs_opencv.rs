//! Stereo calibration vs OpenCV (`shared/peers/camera_opencv.py --stereo`: per-camera
//! `calibrateCamera`, then `stereoCalibrate` with `CALIB_FIX_INTRINSIC`) on
//! `shared/data/camera/opencv_stereo` (13 pairs, 9×6 corners, units of squares).
//!
//! Two comparisons, in one run:
//! 1. **Same corners** (`shared/data/camera/corners/opencv_stereo.json`, OpenCV's own
//!    detections): both solvers on identical input; baseline difference in units of our σ,
//!    rotation difference, joint RMS (recomputed from the final parameters on both sides), and
//!    the rectified epipolar RMS computed by the same code for both calibrations.
//! 2. **End to end** (each side detects its own corners): the same numbers, and the time ratio
//!    peer / ours for detect + solve (above 1 = Caliper faster).
//!
//! `cargo bench -p caliper-core --bench stereo_vs_opencv`
//! Env: `CALIPER_SHARED_DATA`, `CALIPER_PYTHON` (an interpreter with cv2; default `python3`),
//! `CALIPER_BENCH_RUNS` (default 5, median reported).

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use caliper_core::NoProgress;
use caliper_core::board::{DetectOptions, Detection, detect_chessboard};
use caliper_core::calib::{BoardGeometry, ModelKind, ViewObservations};
use caliper_core::camera::{Camera, CameraModel, PinholeRadTan};
use caliper_core::io::{ImageLimits, decode_gray8};
use caliper_core::lie::{Se3, So3};
use caliper_core::rig::{
    RigCalibration, RigCameraInput, RigOptions, calibrate_rig, rectify_pixel, stereo_rectify,
};
use nalgebra::{Matrix3, Vector2, Vector3};
use rayon::prelude::*;
use serde_json::Value;

mod common;
use common::median;

fn data_dir() -> Option<PathBuf> {
    [
        std::env::var_os("CALIPER_SHARED_DATA").map(PathBuf::from),
        Some(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data")),
        Some(PathBuf::from("/work/shared/data")),
    ]
    .into_iter()
    .flatten()
    .find(|d| d.join("camera/opencv_stereo").is_dir())
}

const BOARD: BoardGeometry = BoardGeometry {
    cols: 9,
    rows: 6,
    square: 1.0,
};

fn files(dir: &Path, prefix: &str) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|r| {
            r.flatten()
                .map(|e| e.path())
                .filter(|p| {
                    p.file_name()
                        .and_then(|n| n.to_str())
                        .is_some_and(|n| n.starts_with(prefix) && n.ends_with(".jpg"))
                })
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

fn view(name: &str, pts: &[[f64; 2]]) -> ViewObservations {
    let dense: Vec<Option<[f64; 2]>> = pts.iter().map(|&p| Some(p)).collect();
    ViewObservations::from_dense(name, &dense)
}

fn rig_inputs(
    left: Vec<Option<ViewObservations>>,
    right: Vec<Option<ViewObservations>>,
) -> Vec<RigCameraInput> {
    [("left", left), ("right", right)]
        .into_iter()
        .map(|(n, views)| RigCameraInput {
            name: n.into(),
            model: ModelKind::PinholeRadTan,
            image_size: [640, 480],
            views,
            fixed: None,
        })
        .collect()
}

/// One camera's views, frame by frame.
type Views = Vec<Option<ViewObservations>>;

/// Corners from the shared JSON file (`corners.left[name]`, `corners.right[name]`).
fn shared_corners(data: &Path) -> Option<(Views, Views)> {
    let text = std::fs::read_to_string(data.join("camera/corners/opencv_stereo.json")).ok()?;
    let v: Value = serde_json::from_str(&text).ok()?;
    let side = |s: &str| -> Vec<Option<ViewObservations>> {
        let m = v["corners"][s].as_object().cloned().unwrap_or_default();
        let mut names: Vec<&String> = m.keys().collect();
        names.sort();
        names
            .iter()
            .map(|n| {
                let pts: Option<Vec<[f64; 2]>> = m[*n].as_array().map(|a| {
                    a.iter()
                        .filter_map(|p| Some([p[0].as_f64()?, p[1].as_f64()?]))
                        .collect()
                });
                pts.map(|p| view(n, &p))
            })
            .collect()
    };
    Some((side("left"), side("right")))
}

struct Peer {
    k: [PinholeRadTan; 2],
    r: Matrix3<f64>,
    t: Vector3<f64>,
    baseline: f64,
    rms: f64,
    ms: f64,
}

fn camera_of(v: &Value) -> Option<PinholeRadTan> {
    let i = &v["intrinsics"];
    let d = &v["distortion"];
    let g = |x: &Value, k: &str| x[k].as_f64();
    PinholeRadTan::new(
        g(i, "fx")?,
        g(i, "fy")?,
        g(i, "cx")?,
        g(i, "cy")?,
        g(d, "k1")?,
        g(d, "k2")?,
        g(d, "p1")?,
        g(d, "p2")?,
        g(d, "k3")?,
    )
    .ok()
}

/// Runs the peer on the shared images; with `corners_in`, on those corners instead of its own
/// detections.
fn run_peer(data: &Path, corners_in: Option<&Path>, runs: usize) -> Result<Peer, String> {
    let py = common::python();
    let dir = data.join("camera/opencv_stereo");
    let mut cmd = Command::new(py);
    cmd.arg(data.join("../peers/camera_opencv.py"))
        .arg("--stereo")
        .args(["--left", &format!("{}/left*.jpg", dir.display())])
        .args(["--right", &format!("{}/right*.jpg", dir.display())])
        .args(["--cols", "9", "--rows", "6", "--runs", &runs.to_string()]);
    if let Some(file) = corners_in {
        cmd.arg("--corners-in").arg(file);
    }
    let out = cmd
        .output()
        .map_err(|e| format!("cannot run the peer: {e}"))?;
    if !out.status.success() {
        return Err(String::from_utf8_lossy(&out.stderr).into_owned());
    }
    let v: Value = serde_json::from_slice(&out.stdout).map_err(|e| e.to_string())?;
    let s = &v["stereo"];
    let r: Vec<f64> = s["R"]
        .as_array()
        .ok_or("no R")?
        .iter()
        .flat_map(|row| row.as_array().cloned().unwrap_or_default())
        .filter_map(|x| x.as_f64())
        .collect();
    let t: Vec<f64> = s["T"]
        .as_array()
        .ok_or("no T")?
        .iter()
        .filter_map(Value::as_f64)
        .collect();
    let tm = &v["timings"];
    let f = |k: &str| tm[k].as_f64().unwrap_or(0.0);
    let images = 26.0;
    let ms = f("detect_ms_per_image") * images + f("solve_ms") + f("stereo_solve_ms");
    Ok(Peer {
        k: [
            camera_of(&v["left"]).ok_or("left camera")?,
            camera_of(&v["right"]).ok_or("right camera")?,
        ],
        r: Matrix3::from_row_slice(&r),
        t: Vector3::new(t[0], t[1], t[2]),
        baseline: s["baseline"].as_f64().unwrap_or(f64::NAN),
        rms: s["rms_px"].as_f64().unwrap_or(f64::NAN),
        ms,
    })
}

/// Rectified epipolar RMS of a calibration (cameras, `x_r = R·x_l + T`) over corners seen in
/// both images of a pair, by our rectification code: the same yardstick for both sides.
fn epipolar(
    cams: [&Camera; 2],
    t: &Se3,
    left: &[Option<ViewObservations>],
    right: &[Option<ViewObservations>],
) -> f64 {
    let Ok(rect) = stereo_rectify(cams[0], cams[1], t, [640, 480]) else {
        return f64::NAN;
    };
    let (mut s, mut n) = (0.0, 0);
    for (l, r) in left.iter().zip(right) {
        let (Some(l), Some(r)) = (l, r) else { continue };
        // Corner numbering of the right view may be reversed (symmetric board): match it.
        let flip = {
            let (a, b) = (&l.corners, &r.corners);
            let dl = [
                a[a.len() - 1].pixel[0] - a[0].pixel[0],
                a[a.len() - 1].pixel[1] - a[0].pixel[1],
            ];
            let dr = [
                b[b.len() - 1].pixel[0] - b[0].pixel[0],
                b[b.len() - 1].pixel[1] - b[0].pixel[1],
            ];
            dl[0] * dr[0] + dl[1] * dr[1] < 0.0
        };
        let last = BOARD.num_corners() - 1;
        for c in &l.corners {
            let want = if flip { last - c.index } else { c.index };
            let Some(cr) = r.corners.iter().find(|x| x.index == want) else {
                continue;
            };
            let qa = rectify_pixel(
                cams[0],
                &rect.rotation(false),
                &rect.projection(false),
                &Vector2::from(c.pixel),
            );
            let qb = rectify_pixel(
                cams[1],
                &rect.rotation(true),
                &rect.projection(true),
                &Vector2::from(cr.pixel),
            );
            if let (Some(qa), Some(qb)) = (qa, qb) {
                s += (qa.y - qb.y).powi(2);
                n += 1;
            }
        }
    }
    (s / n.max(1) as f64).sqrt()
}

fn ours_t(rig: &RigCalibration) -> Se3 {
    let e = &rig.extrinsics[1].t_cam_cam0;
    Se3::new(
        So3::from_wxyz(e.quaternion_wxyz).expect("unit"),
        Vector3::from(e.translation),
    )
}

fn report(
    label: &str,
    rig: &RigCalibration,
    peer: &Peer,
    left: &[Option<ViewObservations>],
    right: &[Option<ViewObservations>],
) {
    let ext = &rig.extrinsics[1];
    let sigma_b = ext.sigma.as_ref().map_or(f64::NAN, |s| s.baseline);
    let ours = ours_t(rig);
    let peer_rot = So3::from_matrix(&peer.r).expect("rotation");
    let drot = ours
        .rotation
        .compose(&peer_rot.inverse())
        .angle()
        .to_degrees();
    let peer_t = Se3::new(peer_rot, peer.t);
    let peer_cams: [Camera; 2] = [peer.k[0].clone().into(), peer.k[1].clone().into()];
    let epi_ours = epipolar(
        [&rig.cameras[0].camera, &rig.cameras[1].camera],
        &ours,
        left,
        right,
    );
    let epi_peer = epipolar([&peer_cams[0], &peer_cams[1]], &peer_t, left, right);
    println!("## {label}");
    println!("| | Caliper | OpenCV |\n|---|---|---|");
    println!(
        "| baseline (squares) | {:.4} ± {:.4} | {:.4} |",
        ext.baseline, sigma_b, peer.baseline
    );
    println!(
        "| baseline difference / our σ | {:.2} | |",
        (ext.baseline - peer.baseline).abs() / sigma_b
    );
    println!(
        "| rotation (°) | {:.4} | {:.4} |",
        ext.rotation_deg,
        peer_rot.angle().to_degrees()
    );
    println!("| rotation difference (°) | {drot:.4} | |");
    println!("| joint RMS (px) | {:.4} | {:.4} |", rig.rms, peer.rms);
    println!("| rectified epipolar RMS (px, same code) | {epi_ours:.4} | {epi_peer:.4} |");
    println!(
        "| frames used | {} | |",
        rig.frames.iter().filter(|f| f.used).count()
    );
    println!(
        "| corners used / rejected | {} / {} | |",
        rig.corners_used, rig.corners_rejected
    );
    for (c, pk) in rig.cameras.iter().zip(&peer.k) {
        let p = c.camera.params();
        let q = pk.params();
        println!(
            "| {} fx fy cx cy k1 | {:.2} {:.2} {:.2} {:.2} {:.4} (mono RMS {:.4}, joint {:.4}) | {:.2} {:.2} {:.2} {:.2} {:.4} |",
            c.name,
            p[0],
            p[1],
            p[2],
            p[3],
            p[4],
            c.mono_rms.unwrap_or(f64::NAN),
            c.rms,
            q[0],
            q[1],
            q[2],
            q[3],
            q[4]
        );
    }
}

fn main() {
    let Some(data) = data_dir() else {
        eprintln!("*** NOT RUN: shared data not found (set CALIPER_SHARED_DATA) ***");
        return;
    };
    let runs: usize = std::env::var("CALIPER_BENCH_RUNS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(5);
    let opts = RigOptions::default();

    // 1. Same corners.
    if let Some((l, r)) = shared_corners(&data) {
        let rig = calibrate_rig(
            &rig_inputs(l.clone(), r.clone()),
            &BOARD,
            &opts,
            &NoProgress,
        )
        .expect("rig");
        match run_peer(
            &data,
            Some(&data.join("camera/corners/opencv_stereo.json")),
            1,
        ) {
            Ok(peer) => {
                report("same corners (OpenCV's detections)", &rig, &peer, &l, &r);
                // The same problem as OpenCV's `stereoCalibrate(CALIB_FIX_INTRINSIC)`: its
                // intrinsics held fixed, plain least squares, no rejection.
                let plain = RigOptions {
                    loss: caliper_core::optim::RobustLoss::None,
                    reject_outliers: false,
                    ..RigOptions::default()
                };
                let mut inputs = rig_inputs(l.clone(), r.clone());
                for (i, k) in inputs.iter_mut().zip(&peer.k) {
                    i.fixed = Some(k.clone().into());
                }
                let fixed = calibrate_rig(&inputs, &BOARD, &plain, &NoProgress).expect("rig");
                report(
                    "same corners, OpenCV's intrinsics fixed, plain least squares (solver check)",
                    &fixed,
                    &peer,
                    &l,
                    &r,
                );
                let mut plain_free = plain;
                plain_free.camera.reject_outliers = false;
                plain_free.camera.loss = caliper_core::optim::RobustLoss::None;
                let free = calibrate_rig(
                    &rig_inputs(l.clone(), r.clone()),
                    &BOARD,
                    &plain_free,
                    &NoProgress,
                )
                .expect("rig");
                report(
                    "same corners, intrinsics free, plain least squares, no rejection",
                    &free,
                    &peer,
                    &l,
                    &r,
                );
            }
            Err(e) => println!("peer failed: {e}"),
        }
    }

    // 2. End to end.
    let dir = data.join("camera/opencv_stereo");
    let (lf, rf) = (files(&dir, "left"), files(&dir, "right"));
    let bytes: Vec<Vec<u8>> = lf
        .iter()
        .chain(&rf)
        .map(|p| std::fs::read(p).unwrap_or_default())
        .collect();
    let mut times = Vec::new();
    let mut last = None;
    for _ in 0..runs {
        let t0 = Instant::now();
        let views: Vec<Option<ViewObservations>> = bytes
            .par_iter()
            .enumerate()
            .map(|(k, b)| {
                let g = decode_gray8(b, &ImageLimits::default()).ok()?;
                match detect_chessboard(&g, 9, 6, &DetectOptions::default()) {
                    Detection::Found { corners, .. } => Some(view(&format!("{k}"), &corners)),
                    Detection::NotFound { .. } => None,
                }
            })
            .collect();
        let n = lf.len();
        let (l, r) = (views[..n].to_vec(), views[n..].to_vec());
        let rig = calibrate_rig(
            &rig_inputs(l.clone(), r.clone()),
            &BOARD,
            &opts,
            &NoProgress,
        )
        .expect("rig");
        times.push(t0.elapsed().as_secs_f64() * 1e3);
        last = Some((rig, l, r));
    }
    let ours_ms = median(times);
    let Some((rig, l, r)) = last else { return };
    match run_peer(&data, None, runs) {
        Ok(peer) => {
            report("end to end (each side detects)", &rig, &peer, &l, &r);
            println!(
                "\ntime (decode + detect 26 images + solve): Caliper {ours_ms:.1} ms, OpenCV {:.1} ms (detect + two mono solves + stereo solve), ratio {:.2}× (median of {runs})",
                peer.ms,
                peer.ms / ours_ms
            );
        }
        Err(e) => println!("peer failed: {e}"),
    }

    // 3. Our corners through OpenCV's solver: separates the corners' share of the difference
    // from the solvers'.
    let names = |files: &[PathBuf]| -> Vec<String> {
        files
            .iter()
            .map(|p| {
                p.file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_default()
            })
            .collect()
    };
    let side = |views: &[Option<ViewObservations>], files: &[String]| {
        let m: serde_json::Map<String, Value> = files
            .iter()
            .zip(views)
            .map(|(n, v)| {
                let dense = v.as_ref().and_then(|v| {
                    (v.corners.len() == BOARD.num_corners()).then(|| {
                        let mut c = v.corners.clone();
                        c.sort_by_key(|c| c.index);
                        Value::from(
                            c.iter()
                                .map(|c| vec![c.pixel[0], c.pixel[1]])
                                .collect::<Vec<_>>(),
                        )
                    })
                });
                (n.clone(), dense.unwrap_or(Value::Null))
            })
            .collect();
        Value::Object(m)
    };
    let file = std::env::temp_dir().join(format!(
        "caliper-stereo-corners-{}.json",
        std::process::id()
    ));
    let json = serde_json::json!({"corners": {"left": side(&l, &names(&lf)), "right": side(&r, &names(&rf))}});
    if std::fs::write(&file, json.to_string()).is_ok() {
        match run_peer(&data, Some(&file), 1) {
            Ok(peer) => report(
                "our corners, OpenCV's solver (mono calibrations + stereoCalibrate FIX_INTRINSIC) vs our default",
                &rig,
                &peer,
                &l,
                &r,
            ),
            Err(e) => println!("peer failed: {e}"),
        }
        std::fs::remove_file(&file).ok();
    }
}
