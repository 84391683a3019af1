//! ChArUco detection vs OpenCV's `CharucoDetector` (`shared/peers/charuco_opencv.py detect`)
//! on the same synthetic 1280×960 views (tilted up to 60°, blur σ = 1, noise σ = 1 grey level,
//! some half out of frame), written as PNG files and handed to both: time per image, corners
//! found, agreement of ids and positions, and both sides' error against the true corners.
//!
//! `CALIPER_PYTHON=/var/tmp/caliper-py/bin/python cargo bench -p caliper-core --bench charuco_vs_opencv`
//! Env: `CALIPER_PYTHON` (a Python with cv2 ≥ 4.7; without it only our side runs, said
//! loudly), `CALIPER_BENCH_RUNS` (default 5; median per image), `CALIPER_PEERS` (the peers
//! folder, default `<workspace>/../shared/peers`, then `/work/shared/peers`).
//! Both sides single image, single thread per image (OpenCV's own threading left on, as its
//! users get it; say so when reporting).

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use caliper_core::board::{TargetOptions, TargetSpec, detect_target};

mod common;
#[path = "../tests/targets_render.rs"]
mod render;
use common::median;
use render::{Scene, render};

const SQUARES: (usize, usize) = (10, 7);
const SQUARE: f64 = 0.03;
const MARKER: f64 = 0.022;
const DICT: &str = "DICT_6X6_250";

fn peers_dir() -> Option<PathBuf> {
    [
        std::env::var_os("CALIPER_PEERS").map(PathBuf::from),
        Some(Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/peers")),
        Some(PathBuf::from("/work/shared/peers")),
    ]
    .into_iter()
    .flatten()
    .find(|d| d.join("charuco_opencv.py").is_file())
}

fn scenes() -> Vec<Scene> {
    let centre = [
        SQUARES.0 as f64 * SQUARE / 2.0,
        SQUARES.1 as f64 * SQUARE / 2.0,
    ];
    let base = Scene {
        size: (1280, 960),
        f: 1100.0,
        centre,
        dist: 0.45,
        blur: 1.0,
        noise: 1.0,
        ..Scene::default()
    };
    let rots = [
        [0.0, 0.0, 0.0],
        [1.047, 0.0, 0.0],
        [0.0, 1.047, 0.0],
        [0.4, -0.6, 0.3],
        [-0.5, 0.3, 1.2],
        [0.2, 0.2, -0.4],
        [0.7, 0.5, 2.0],
        [-0.3, -0.7, 0.1],
    ];
    let shifts = [
        [0.0, 0.0],
        [0.0, 0.0],
        [0.0, 0.0],
        [300.0, 0.0],
        [0.0, -250.0],
        [-420.0, 200.0],
        [0.0, 0.0],
        [0.0, 0.0],
    ];
    rots.iter()
        .zip(shifts)
        .enumerate()
        .map(|(k, (r, s))| Scene {
            rot: *r,
            shift: s,
            seed: k as u64 + 1,
            ..base.clone()
        })
        .collect()
}

fn main() {
    let runs: usize = std::env::var("CALIPER_BENCH_RUNS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(5)
        .max(1);
    let spec = TargetSpec::Charuco {
        squares_x: SQUARES.0,
        squares_y: SQUARES.1,
        square: SQUARE,
        marker: MARKER,
        dictionary: DICT.into(),
        legacy: false,
    };
    let dir = std::env::temp_dir().join(format!("caliper-charuco-bench-{}", std::process::id()));
    if let Err(e) = std::fs::create_dir_all(&dir) {
        eprintln!("cannot create {}: {e}", dir.display());
        return;
    }
    let views: Vec<_> = scenes()
        .iter()
        .map(|s| render(&spec, s, 0.5 * SQUARE))
        .collect();
    for (k, v) in views.iter().enumerate() {
        let img = image::GrayImage::from_raw(v.image.width, v.image.height, v.image.data.clone());
        let Some(img) = img else { return };
        if let Err(e) = img.save(dir.join(format!("view{k:02}.png"))) {
            eprintln!("cannot write a PNG: {e}");
            return;
        }
    }
    // Ours.
    let opts = TargetOptions::default();
    let mut ours_ms = Vec::new();
    let mut ours = Vec::new();
    for v in &views {
        let mut ts = Vec::new();
        let mut det = None;
        for _ in 0..runs {
            let t0 = Instant::now();
            det = Some(detect_target(&v.image, &spec, &opts));
            ts.push(t0.elapsed().as_secs_f64() * 1e3);
        }
        ours_ms.push(median(ts));
        let Some(det) = det else { return };
        ours.push(
            det.corners
                .iter()
                .map(|c| (c.index, c.pixel))
                .collect::<Vec<_>>(),
        );
    }
    let err_vs_truth = |dets: &[Vec<(usize, [f64; 2])>]| {
        let (mut se, mut n, mut worst) = (0.0, 0usize, 0.0f64);
        for (d, v) in dets.iter().zip(&views) {
            for (id, p) in d {
                if let Some((_, t)) = v.truth.iter().find(|(i, _)| i == id) {
                    let e = (p[0] - t[0]).hypot(p[1] - t[1]);
                    se += e * e;
                    n += 1;
                    worst = worst.max(e);
                }
            }
        }
        ((se / n.max(1) as f64).sqrt(), n, worst)
    };
    let (rms, n, worst) = err_vs_truth(&ours);
    let ours_med = median(ours_ms.clone());
    println!(
        "charuco {}x{} {DICT}, {} views 1280×960, {runs} runs per view",
        SQUARES.0,
        SQUARES.1,
        views.len()
    );
    println!(
        "  ours:   {n} corners, RMS vs truth {rms:.4} px (max {worst:.3}), median {ours_med:.2} ms/image  per view {:?}",
        ours.iter().map(Vec::len).collect::<Vec<_>>()
    );

    // OpenCV.
    let Some(py) = std::env::var_os("CALIPER_PYTHON") else {
        println!("  OpenCV: SKIPPED — set CALIPER_PYTHON to a Python with cv2 to compare");
        let _ = std::fs::remove_dir_all(&dir);
        return;
    };
    let Some(peers) = peers_dir() else {
        println!("  OpenCV: SKIPPED — charuco_opencv.py not found (set CALIPER_PEERS)");
        return;
    };
    let mut peer_ms = Vec::new();
    let mut peer: Vec<Vec<(usize, [f64; 2])>> = Vec::new();
    for _ in 0..runs.min(3) {
        let out = Command::new(&py)
            .arg(peers.join("charuco_opencv.py"))
            .args([
                "detect",
                "--squares",
                &format!("{}x{}", SQUARES.0, SQUARES.1),
            ])
            .args([
                "--square",
                &SQUARE.to_string(),
                "--marker",
                &MARKER.to_string(),
                "--dict",
                DICT,
            ])
            .args(["--images", &dir.join("view*.png").to_string_lossy()])
            .output();
        let out = match out {
            Ok(o) if o.status.success() => o,
            Ok(o) => {
                println!(
                    "  OpenCV: peer failed: {}",
                    String::from_utf8_lossy(&o.stderr)
                );
                return;
            }
            Err(e) => {
                println!("  OpenCV: cannot run {}: {e}", py.to_string_lossy());
                return;
            }
        };
        let Ok(doc) = serde_json::from_slice::<serde_json::Value>(&out.stdout) else {
            println!("  OpenCV: unreadable peer output");
            return;
        };
        peer_ms.push(doc["detect_ms_median"].as_f64().unwrap_or(f64::NAN));
        peer = doc["images"]
            .as_array()
            .map(|imgs| {
                imgs.iter()
                    .map(|im| {
                        let ids = im["ids"].as_array().cloned().unwrap_or_default();
                        let cs = im["corners"].as_array().cloned().unwrap_or_default();
                        ids.iter()
                            .zip(cs)
                            .filter_map(|(i, c)| {
                                Some((i.as_u64()? as usize, [c[0].as_f64()?, c[1].as_f64()?]))
                            })
                            .collect()
                    })
                    .collect()
            })
            .unwrap_or_default();
    }
    let (prms, pn, pworst) = err_vs_truth(&peer);
    let peer_med = median(peer_ms);
    println!(
        "  OpenCV: {pn} corners, RMS vs truth {prms:.4} px (max {pworst:.3}), median {peer_med:.2} ms/image  per view {:?}",
        peer.iter().map(Vec::len).collect::<Vec<_>>()
    );
    // Agreement: ids in both, ids in one only, RMS of the difference.
    let (mut both, mut only_ours, mut only_peer, mut sd) = (0, 0, 0, 0.0);
    for (a, b) in ours.iter().zip(&peer) {
        for (id, p) in a {
            match b.iter().find(|(i, _)| i == id) {
                Some((_, q)) => {
                    both += 1;
                    sd += (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2);
                }
                None => only_ours += 1,
            }
        }
        only_peer += b
            .iter()
            .filter(|(i, _)| !a.iter().any(|(j, _)| j == i))
            .count();
    }
    println!(
        "  agreement: {both} ids in both, {only_ours} ours only, {only_peer} OpenCV only, RMS difference {:.4} px",
        (sd / both.max(1) as f64).sqrt()
    );
    println!("  speed ratio OpenCV / ours: {:.2}×", peer_med / ours_med);
    let _ = std::fs::remove_dir_all(&dir);
}
