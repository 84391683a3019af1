//! Chessboard detection + calibration vs the OpenCV peer (`shared/peers/camera_opencv.py`):
//! boards found, RMS, intrinsics and time per stage, on the shared image sets and on blurred
//! copies of the left images (9 px horizontal motion blur, Gaussian σ = 3) made here and handed
//! to both sides as the same PNG files.
//!
//! `cargo bench -p caliper-core --bench detect_vs_opencv`
//! Env: `CALIPER_PYTHON` (the peer's interpreter, default `python3`),
//! `CALIPER_SHARED_DATA` (default `<workspace>/../shared/data`, then `/work/shared/data`),
//! `CALIPER_BENCH_RUNS` (default 5, median reported), `RAYON_NUM_THREADS`,
//! `CALIPER_BENCH_SETS` (only the sets whose label contains one of these comma-separated
//! words), `CALIPER_BENCH_NO_PEER=1` (ours only, e.g. under a profiler).
//!
//! Ours: decode and detect run with rayon across the images (the caller's parallelism; one
//! image is single-threaded), then `calibrate` (pinhole k1,k2,p1,p2,k3 or Kannala-Brandt,
//! default options). The peer: `findChessboardCorners` + `cornerSubPix` + `calibrateCamera`
//! (or `fisheye.calibrate`), its own in-process timings.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use caliper_core::NoProgress;
use caliper_core::board::{DetectOptions, Detection, detect_chessboard};
use caliper_core::calib::{BoardGeometry, CalibOptions, ModelKind, calibrate};
use caliper_core::camera::CameraModel;
use caliper_core::io::{Gray, ImageLimits, decode_gray8};
use caliper_core::synth::{blur_gray, motion_blur_gray};
use rayon::prelude::*;

mod common;
use common::median;

fn data_dir() -> Option<PathBuf> {
    let candidates = [
        std::env::var_os("CALIPER_SHARED_DATA").map(PathBuf::from),
        Some(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data")),
        Some(PathBuf::from("/work/shared/data")),
    ];
    candidates
        .into_iter()
        .flatten()
        .find(|d| d.join("camera").is_dir())
}

fn peer_script(data: &Path) -> PathBuf {
    data.join("../peers/camera_opencv.py")
}

struct Set {
    label: String,
    files: Vec<PathBuf>,
    /// Glob handed to the peer.
    glob: String,
    cols: usize,
    rows: usize,
    model: ModelKind,
}

#[derive(Default)]
struct Side {
    found: usize,
    images: usize,
    rms: Option<f64>,
    k: Option<[f64; 4]>,
    decode_ms: f64,
    detect_ms: f64,
    solve_ms: f64,
    total_ms: f64,
    note: String,
}

fn run_ours(set: &Set, runs: usize) -> Side {
    let bytes: Vec<Vec<u8>> = set
        .files
        .iter()
        .map(|f| std::fs::read(f).unwrap_or_default())
        .collect();
    let limits = ImageLimits::default();
    let opts = DetectOptions::default();
    let board = BoardGeometry {
        cols: set.cols,
        rows: set.rows,
        square: 1.0,
    };
    let (mut td, mut tt, mut ts, mut tot) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut side = Side {
        images: set.files.len(),
        ..Side::default()
    };
    for _ in 0..runs {
        let t0 = Instant::now();
        let imgs: Vec<Option<Gray>> = bytes
            .par_iter()
            .map(|b| decode_gray8(b, &limits).ok())
            .collect();
        let t1 = Instant::now();
        let dets: Vec<Option<Detection>> = imgs
            .par_iter()
            .map(|im| {
                im.as_ref()
                    .map(|im| detect_chessboard(im, set.cols, set.rows, &opts))
            })
            .collect();
        let t2 = Instant::now();
        let obs: Vec<_> = dets
            .iter()
            .zip(&set.files)
            .filter_map(|(d, f)| {
                let name = f.file_name()?.to_string_lossy().to_string();
                d.as_ref()?.to_observations(name)
            })
            .collect();
        let size = imgs
            .iter()
            .flatten()
            .next()
            .map(|g| (g.width, g.height))
            .unwrap_or((1, 1));
        let cal = calibrate(
            &obs,
            &board,
            set.model,
            size,
            &CalibOptions::default(),
            &NoProgress,
        );
        let t3 = Instant::now();
        let ms = |a: Instant, b: Instant| (b - a).as_secs_f64() * 1e3;
        td.push(ms(t0, t1));
        tt.push(ms(t1, t2));
        ts.push(ms(t2, t3));
        tot.push(ms(t0, t3));
        side.found = obs.len();
        match cal {
            Ok(c) => {
                side.rms = Some(c.rms);
                let p = c.camera.params();
                side.k = Some([p[0], p[1], p[2], p[3]]);
                side.note = if c.rejected_views.is_empty() {
                    String::new()
                } else {
                    format!("{} views rejected", c.rejected_views.len())
                };
            }
            Err(e) => {
                side.rms = None;
                side.k = None;
                side.note = format!("calibration failed: {e}");
            }
        }
        let missing: Vec<String> = dets
            .iter()
            .zip(&set.files)
            .filter(|(d, _)| !d.as_ref().is_some_and(Detection::is_found))
            .filter_map(|(_, f)| Some(f.file_name()?.to_string_lossy().to_string()))
            .collect();
        if !missing.is_empty() {
            side.note = format!("{} not found: {}", side.note, missing.join(" "));
        }
    }
    let n = set.files.len().max(1) as f64;
    side.decode_ms = median(td) / n;
    side.detect_ms = median(tt) / n;
    side.solve_ms = median(ts);
    side.total_ms = median(tot);
    side
}

fn run_peer(set: &Set, data: &Path, runs: usize) -> Result<Side, String> {
    let script = peer_script(data);
    if !script.exists() {
        return Err(format!("peer script {} not found", script.display()));
    }
    let mut cmd = Command::new(common::python());
    cmd.arg(&script)
        .args(["--images", &set.glob])
        .args(["--cols", &set.cols.to_string()])
        .args(["--rows", &set.rows.to_string()])
        .args(["--runs", &runs.to_string()]);
    if set.model == ModelKind::KannalaBrandt {
        cmd.args(["--model", "fisheye"]);
    }
    let out = cmd
        .output()
        .map_err(|e| format!("cannot run {:?}: {e}", common::python()))?;
    if !out.status.success() {
        return Err(format!(
            "peer failed: {}",
            String::from_utf8_lossy(&out.stderr).trim()
        ));
    }
    let v: serde_json::Value =
        serde_json::from_slice(&out.stdout).map_err(|e| format!("peer output: {e}"))?;
    let f = |p: &str| v.pointer(p).and_then(serde_json::Value::as_f64);
    let k = match (
        f("/intrinsics/fx"),
        f("/intrinsics/fy"),
        f("/intrinsics/cx"),
        f("/intrinsics/cy"),
    ) {
        (Some(a), Some(b), Some(c), Some(d)) => Some([a, b, c, d]),
        _ => None,
    };
    let dropped = v
        .get("views_dropped")
        .and_then(|d| d.as_array())
        .map_or(0, Vec::len);
    Ok(Side {
        found: f("/detections/detected").unwrap_or(0.0) as usize,
        images: f("/detections/images").unwrap_or(0.0) as usize,
        rms: f("/rms_px"),
        k,
        decode_ms: f("/timings/load_ms_per_image").unwrap_or(f64::NAN),
        detect_ms: f("/timings/detect_ms_per_image").unwrap_or(f64::NAN),
        solve_ms: f("/timings/solve_ms").unwrap_or(f64::NAN),
        total_ms: f("/timings/total_ms").unwrap_or(f64::NAN),
        note: if dropped > 0 {
            format!("{dropped} views dropped")
        } else {
            String::new()
        },
    })
}

fn list(dir: &Path, names: impl Iterator<Item = String>) -> Vec<PathBuf> {
    names.map(|n| dir.join(n)).filter(|p| p.exists()).collect()
}

/// Blurred PNG copies of `files` in `out` (created), with the same names.
fn blurred_copies(files: &[PathBuf], out: &Path, f: &dyn Fn(&Gray) -> Gray) -> Vec<PathBuf> {
    if let Err(e) = std::fs::create_dir_all(out) {
        eprintln!("cannot create {}: {e}", out.display());
        return Vec::new();
    }
    let mut res = Vec::new();
    for file in files {
        let Ok(bytes) = std::fs::read(file) else {
            continue;
        };
        let Ok(img) = decode_gray8(&bytes, &ImageLimits::default()) else {
            continue;
        };
        let b = f(&img);
        let Some(stem) = file.file_stem() else {
            continue;
        };
        let path = out.join(format!("{}.png", stem.to_string_lossy()));
        let saved = image::GrayImage::from_raw(b.width, b.height, b.data)
            .map(|im| im.save(&path).is_ok())
            .unwrap_or(false);
        if saved {
            res.push(path);
        }
    }
    res
}

fn fmt_opt(v: Option<f64>, prec: usize) -> String {
    v.map_or("–".into(), |x| format!("{x:.prec$}"))
}

fn main() {
    let Some(data) = data_dir() else {
        println!(
            "\n!!!!! detect_vs_opencv: shared data not found (set CALIPER_SHARED_DATA to the folder \
             holding camera/): nothing measured !!!!!\n"
        );
        return;
    };
    let runs: usize = std::env::var("CALIPER_BENCH_RUNS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(5)
        .max(1);
    let cam = data.join("camera");
    let stereo = cam.join("opencv_stereo");
    let fisheye = cam.join("boofcv_fisheye_chessboard");
    let ids = [1, 2, 3, 4, 5, 6, 7, 8, 9, 11, 12, 13, 14];
    let left = list(&stereo, ids.iter().map(|k| format!("left{k:02}.jpg")));
    let right = list(&stereo, ids.iter().map(|k| format!("right{k:02}.jpg")));
    let fish = list(&fisheye, (1..=26).map(|k| format!("{k}.jpg")));

    let tmp = std::env::temp_dir().join(format!("caliper_detect_bench_{}", std::process::id()));
    let motion_dir = tmp.join("motion9");
    let gauss_dir = tmp.join("gauss3");
    let motion = blurred_copies(&left, &motion_dir, &|g| motion_blur_gray(g, 9.0));
    let gauss = blurred_copies(&left, &gauss_dir, &|g| blur_gray(g, 3.0));

    let pinhole = ModelKind::PinholeRadTan;
    let sets = vec![
        Set {
            label: "opencv_stereo left 9×6".into(),
            files: left,
            glob: format!("{}/left*.jpg", stereo.display()),
            cols: 9,
            rows: 6,
            model: pinhole,
        },
        Set {
            label: "opencv_stereo right 9×6".into(),
            files: right,
            glob: format!("{}/right*.jpg", stereo.display()),
            cols: 9,
            rows: 6,
            model: pinhole,
        },
        Set {
            label: "boofcv fisheye 4×6 (KB)".into(),
            files: fish,
            glob: format!("{}/*.jpg", fisheye.display()),
            cols: 4,
            rows: 6,
            model: ModelKind::KannalaBrandt,
        },
        Set {
            label: "left + motion blur 9 px".into(),
            files: motion,
            glob: format!("{}/*.png", motion_dir.display()),
            cols: 9,
            rows: 6,
            model: pinhole,
        },
        Set {
            label: "left + Gaussian σ=3".into(),
            files: gauss,
            glob: format!("{}/*.png", gauss_dir.display()),
            cols: 9,
            rows: 6,
            model: pinhole,
        },
    ];

    println!(
        "\ndetect_vs_opencv: {runs} runs (median), rayon threads {}, {} CPUs\n",
        rayon::current_num_threads(),
        std::thread::available_parallelism().map_or(0, |n| n.get())
    );
    println!(
        "| set | boards ours/peer | RMS px ours/peer | fx ours/peer | fy ours/peer | cx ours/peer | cy ours/peer | decode ms/img ours/peer | detect ms/img ours/peer | solve ms ours/peer | total ms ours/peer | peer/ours |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
    let mut notes = Vec::new();
    let only: Vec<String> = std::env::var("CALIPER_BENCH_SETS")
        .map(|v| v.split(',').map(|w| w.trim().to_string()).collect())
        .unwrap_or_default();
    let no_peer = std::env::var_os("CALIPER_BENCH_NO_PEER").is_some_and(|v| v != "0");
    for set in &sets {
        if !only.is_empty() && !only.iter().any(|w| set.label.contains(w.as_str())) {
            continue;
        }
        if set.files.is_empty() {
            println!("| {} | no images | | | | | | | | | | |", set.label);
            continue;
        }
        let ours = run_ours(set, runs);
        let peer = if no_peer {
            Err("not run (CALIPER_BENCH_NO_PEER)".to_string())
        } else {
            run_peer(set, &data, runs)
        };
        let peer = match peer {
            Ok(p) => p,
            Err(e) => {
                notes.push(format!("{}: peer unavailable: {e}", set.label));
                Side::default()
            }
        };
        let k = |s: &Side, i: usize| fmt_opt(s.k.map(|k| k[i]), 2);
        println!(
            "| {} | {}/{} of {} | {} / {} | {} / {} | {} / {} | {} / {} | {} / {} | {:.2} / {:.2} | {:.2} / {:.2} | {:.1} / {:.1} | {:.1} / {:.1} | {:.1}× |",
            set.label,
            ours.found,
            peer.found,
            ours.images,
            fmt_opt(ours.rms, 4),
            fmt_opt(peer.rms, 4),
            k(&ours, 0),
            k(&peer, 0),
            k(&ours, 1),
            k(&peer, 1),
            k(&ours, 2),
            k(&peer, 2),
            k(&ours, 3),
            k(&peer, 3),
            ours.decode_ms,
            peer.decode_ms,
            ours.detect_ms,
            peer.detect_ms,
            ours.solve_ms,
            peer.solve_ms,
            ours.total_ms,
            peer.total_ms,
            peer.total_ms / ours.total_ms,
        );
        if !ours.note.trim().is_empty() {
            notes.push(format!("{} (ours): {}", set.label, ours.note.trim()));
        }
        if !peer.note.is_empty() {
            notes.push(format!("{} (peer): {}", set.label, peer.note));
        }
    }
    for n in notes {
        println!("\n- {n}");
    }
    println!(
        "\nours: decode and detect in parallel over the images (rayon), calibrate with default \
         options; peer: its own in-process timings (load, findChessboardCorners + cornerSubPix, \
         solve). Blurred copies: {}",
        tmp.display()
    );
    let _ = std::fs::remove_dir_all(&tmp);
}
