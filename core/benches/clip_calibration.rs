//! Clip to calibration: a 30 s 1080p clip of a chessboard (20 poses, each held still, joined by
//! motion-blurred moves) calibrated by Caliper's pipeline (`calib::clip::clip_candidates` →
//! `select_views` → `calibrate`) and by the OpenCV recipe a user would script (every frame
//! decoded by `cv2.VideoCapture`, the sharpest frame of each stretch searched with
//! `findChessboardCorners` + `cornerSubPix`, up to 40 detected views spread evenly over time,
//! `calibrateCamera`). Same clip, same number of searched frames and views; errors against the
//! rendering camera, wall time and (ours) peak RSS of the process that does only the
//! calibration.
//!
//! `cargo bench -p caliper-core --features video --bench clip_calibration`
//! The clip is made with Debian's `ffmpeg` (libx264, High profile with B-frames, as a phone
//! would record) when it is on PATH, else with Caliper's own encoder; it is cached in the
//! temporary directory. The peer runs when `CALIPER_PYTHON` names a Python with `cv2`.

use std::io::BufReader;
use std::process::Command;
use std::time::Instant;

use caliper_core::board::{TargetOptions, TargetSpec};
use caliper_core::calib::clip::clip_candidates;
use caliper_core::calib::{
    CalibOptions, ModelKind, ViewCandidate, ViewDecision, ViewObservations, ViewSelection,
    calibrate, select_views,
};
use caliper_core::camera::{Camera, CameraModel, PinholeRadTan};
use caliper_core::lie::Se3;
use caliper_core::progress::NoProgress;
use caliper_core::synth::{RenderOptions, render_chessboard};
use caliper_core::video::VideoLimits;
use nalgebra::Vector3;

const TRUTH: [f64; 9] = [
    1400.0, 1398.0, 962.0, 538.0, -0.21, 0.06, 0.0005, -0.0003, 0.0,
];
const W: u32 = 1920;
const H: u32 = 1080;
const FPS: usize = 30;
const POSES: usize = 20;
/// Frames per pose: 36 held still, 9 moving (blurred): 45 × 20 = 900 frames = 30 s.
const HELD: usize = 36;
const MOVING: usize = 9;
const BOARD: (usize, usize, f64) = (9, 6, 0.03);
const CANDIDATES: usize = 150;
const VIEWS: usize = 40;

/// xorshift64*: a reproducible pose generator without a dependency.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, a: f64, b: f64) -> f64 {
        a + (b - a) * self.next()
    }
}

fn camera() -> Camera {
    PinholeRadTan::from_slice(&TRUTH).expect("camera").into()
}

/// Board poses spread over the image at 0.5–0.9 m with tilts up to ~30°, every corner in view.
fn poses() -> Vec<Se3> {
    let cam = camera();
    let (cols, rows, sq) = BOARD;
    let centre = Vector3::new(
        (cols - 1) as f64 * sq / 2.0,
        (rows - 1) as f64 * sq / 2.0,
        0.0,
    );
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    let mut out = Vec::new();
    while out.len() < POSES {
        let rvec = Vector3::new(
            rng.range(-0.55, 0.55),
            rng.range(-0.55, 0.55),
            rng.range(-0.8, 0.8),
        );
        let z = rng.range(0.5, 0.9);
        let off = Vector3::new(rng.range(-0.3, 0.3) * z, rng.range(-0.18, 0.18) * z, z);
        let r = Se3::from_rvec_tvec(&rvec, &Vector3::zeros());
        let pose = Se3::from_rvec_tvec(&rvec, &(-r.act(&centre) + off));
        let probe = RenderOptions {
            supersample: 1,
            ..RenderOptions::default()
        };
        let full = render_chessboard(&cam, &pose, BOARD, (W, H), &probe).expect("render");
        if full.all_visible() {
            out.push(pose);
        }
    }
    out
}

fn render(pose: &Se3, blur: f64, seed: u64) -> image::GrayImage {
    let opts = RenderOptions {
        supersample: 2,
        noise_sigma: 1.5,
        blur_sigma: 0.6,
        motion_blur_px: blur,
        seed,
        ..RenderOptions::default()
    };
    let v = render_chessboard(&camera(), pose, BOARD, (W, H), &opts).expect("render");
    image::GrayImage::from_raw(W, H, v.image.data).expect("image")
}

/// The clip, made once and cached.
fn clip_path() -> std::path::PathBuf {
    let path = std::env::temp_dir().join("caliper_bench_board_1080p_30s.mp4");
    if path.exists() {
        return path;
    }
    let t0 = Instant::now();
    let poses = poses();
    let dir = tempfile_dir();
    // Each pose: one sharp still (held), one smeared copy (moving on).
    let mut list = String::new();
    let has_ffmpeg = Command::new("ffmpeg")
        .arg("-version")
        .output()
        .is_ok_and(|o| o.status.success());
    let mut frames = Vec::new();
    for (k, pose) in poses.iter().enumerate() {
        let sharp = render(pose, 0.0, 2 * k as u64 + 1);
        let moving = render(pose, 40.0, 2 * k as u64 + 2);
        if has_ffmpeg {
            let (a, b) = (
                dir.join(format!("p{k:02}a.png")),
                dir.join(format!("p{k:02}b.png")),
            );
            sharp.save(&a).expect("png");
            moving.save(&b).expect("png");
            list.push_str(&format!(
                "file '{}'\nduration {}\nfile '{}'\nduration {}\n",
                a.display(),
                HELD as f64 / FPS as f64,
                b.display(),
                MOVING as f64 / FPS as f64
            ));
        } else {
            frames.extend(std::iter::repeat_n(sharp, HELD));
            frames.extend(std::iter::repeat_n(moving, MOVING));
        }
    }
    if has_ffmpeg {
        let concat = dir.join("list.txt");
        std::fs::write(&concat, list).expect("list");
        let st = Command::new("ffmpeg")
            .args(["-v", "error", "-y", "-f", "concat", "-safe", "0", "-i"])
            .arg(&concat)
            .args([
                "-vf",
                &format!("fps={FPS},format=yuv420p"),
                "-frames:v",
                &(POSES * (HELD + MOVING)).to_string(),
                "-c:v",
                "libx264",
                "-profile:v",
                "high",
                "-bf",
                "2",
                "-crf",
                "18",
            ])
            .arg(&path)
            .status()
            .expect("ffmpeg");
        assert!(st.success(), "ffmpeg failed");
    } else {
        let mp4 = caliper_core::video::encode_h264_mp4(&frames, FPS as f64).expect("encode");
        std::fs::write(&path, mp4).expect("write clip");
    }
    let _ = std::fs::remove_dir_all(&dir);
    println!(
        "clip made in {:.1} s ({}; {:.1} MB)",
        t0.elapsed().as_secs_f64(),
        if has_ffmpeg {
            "ffmpeg libx264 High, B-frames"
        } else {
            "Caliper's encoder"
        },
        std::fs::metadata(&path).map(|m| m.len()).unwrap_or(0) as f64 / 1e6
    );
    path
}

fn tempfile_dir() -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("caliper_bench_clip_{}", std::process::id()));
    std::fs::create_dir_all(&d).expect("tmp dir");
    d
}

/// Peak resident set of this process, MB (Linux `VmHWM`).
fn peak_rss_mb() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<f64>().ok())
        })
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

/// Relative errors of fx, fy and absolute errors of cx, cy (px) and k1.
fn errors(p: &[f64]) -> String {
    format!(
        "fx {:+.3} %  fy {:+.3} %  cx {:+.2} px  cy {:+.2} px  k1 {:+.4}",
        100.0 * (p[0] - TRUTH[0]) / TRUTH[0],
        100.0 * (p[1] - TRUTH[1]) / TRUTH[1],
        p[2] - TRUTH[2],
        p[3] - TRUTH[3],
        p[4] - TRUTH[4]
    )
}

/// The calibration alone, in this (child) process: prints one result line.
fn child(path: &str) {
    let t0 = Instant::now();
    let target = TargetSpec::Chessboard {
        cols: BOARD.0,
        rows: BOARD.1,
        square: BOARD.2,
    };
    let file = std::fs::File::open(path).expect("clip");
    let found = clip_candidates(
        BufReader::new(file),
        &VideoLimits::default(),
        &target,
        &TargetOptions::default(),
        CANDIDATES,
        &NoProgress,
    )
    .expect("candidates");
    let t_detect = t0.elapsed().as_secs_f64();
    let with: Vec<_> = found
        .candidates
        .iter()
        .filter(|c| !c.detection.corners.is_empty())
        .collect();
    let views: Vec<ViewCandidate> = with
        .iter()
        .map(|c| ViewCandidate {
            corners: c.detection.corners.clone(),
            sharpness: c.laplacian_variance,
        })
        .collect();
    let size = (found.image_size[0], found.image_size[1]);
    let settings = ViewSelection {
        max_views: VIEWS,
        ..ViewSelection::default()
    };
    let d = select_views(&views, &target, size, &settings).expect("select");
    let obs: Vec<ViewObservations> = d
        .iter()
        .zip(&with)
        .filter(|(d, _)| matches!(d, ViewDecision::Used { .. }))
        .map(|(_, c)| ViewObservations {
            name: format!("frame_{}", c.index),
            corners: c.detection.corners.clone(),
        })
        .collect();
    let cal = calibrate(
        &obs,
        &target,
        ModelKind::PinholeRadTan,
        size,
        &CalibOptions::default(),
        &NoProgress,
    )
    .expect("calibrate");
    let total = t0.elapsed().as_secs_f64();
    println!(
        "  caliper: {:.2} s (decode+search {:.2} s), peak RSS {:.0} MB, {} frames, {} searched, \
         {} with board, {} views; rms {:.3} px\n    {}",
        total,
        t_detect,
        peak_rss_mb(),
        found.frames_decoded,
        found.candidates.len(),
        with.len(),
        obs.len(),
        cal.rms,
        errors(cal.camera.params())
    );
    println!("CHILD_SECONDS {total}");
}

const PEER: &str = r#"
import cv2, json, sys, time
import numpy as np
path, cols, rows, sq, maxc, maxv = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4]), int(sys.argv[5]), int(sys.argv[6])
t0 = time.time()
cap = cv2.VideoCapture(path)
n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
win = max(1, -(-n // maxc))
cands, best, i = [], None, 0
while True:
    ok, fr = cap.read()
    if not ok:
        break
    g = cv2.cvtColor(fr, cv2.COLOR_BGR2GRAY)
    lv = cv2.Laplacian(g, cv2.CV_64F).var()
    if best is None or best[0] // win != i // win:
        if best is not None:
            cands.append(best)
        best = (i, lv, g)
    elif lv > best[1]:
        best = (i, lv, g)
    i += 1
cands.append(best)
t_decode = time.time() - t0
objp = np.zeros((cols * rows, 3), np.float32)
objp[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * sq
crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 1e-3)
views = []
for (k, lv, g) in cands:
    ok, c = cv2.findChessboardCorners(g, (cols, rows), cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK)
    if ok:
        views.append(cv2.cornerSubPix(g, c, (11, 11), (-1, -1), crit))
step = max(1, len(views) // maxv)
sel = views[::step][:maxv]
h, w = cands[0][2].shape
rms, K, D, _, _ = cv2.calibrateCamera([objp] * len(sel), sel, (w, h), None, None)
print(json.dumps({"seconds": time.time() - t0, "decode_s": t_decode, "frames": i, "searched": len(cands),
                  "with_board": len(views), "views": len(sel), "rms": rms,
                  "params": [K[0, 0], K[1, 1], K[0, 2], K[1, 2], float(D[0, 0]), float(D[0, 1]), float(D[0, 2]), float(D[0, 3]), float(D[0, 4])]}))
"#;

fn main() {
    if let Ok(path) = std::env::var("CALIPER_BENCH_CLIP_CHILD") {
        child(&path);
        return;
    }
    println!(
        "clip_calibration: {POSES} poses, {} frames at {W}x{H}, {FPS} fps; {CANDIDATES} frames \
         searched, ≤ {VIEWS} views",
        POSES * (HELD + MOVING)
    );
    let path = clip_path();
    let out = Command::new(std::env::current_exe().expect("exe"))
        .env("CALIPER_BENCH_CLIP_CHILD", &path)
        .output()
        .expect("child");
    let text = String::from_utf8_lossy(&out.stdout);
    print!(
        "{}",
        text.lines()
            .filter(|l| !l.starts_with("CHILD_"))
            .map(|l| format!("{l}\n"))
            .collect::<String>()
    );
    if !out.status.success() {
        println!("  caliper FAILED: {}", String::from_utf8_lossy(&out.stderr));
        return;
    }
    let ours: f64 = text
        .lines()
        .find_map(|l| l.strip_prefix("CHILD_SECONDS ")?.trim().parse().ok())
        .unwrap_or(f64::NAN);
    let Some(py) = std::env::var_os("CALIPER_PYTHON") else {
        println!("  *** peer NOT RUN: set CALIPER_PYTHON to a Python with cv2 ***");
        return;
    };
    let peer = Command::new(py)
        .args(["-c", PEER])
        .arg(&path)
        .args([
            BOARD.0.to_string(),
            BOARD.1.to_string(),
            BOARD.2.to_string(),
            CANDIDATES.to_string(),
            VIEWS.to_string(),
        ])
        .output()
        .expect("python");
    if !peer.status.success() {
        println!("  peer FAILED: {}", String::from_utf8_lossy(&peer.stderr));
        return;
    }
    let v: serde_json::Value = serde_json::from_slice(&peer.stdout).expect("peer json");
    let p: Vec<f64> = v["params"]
        .as_array()
        .map(|a| a.iter().filter_map(|x| x.as_f64()).collect())
        .unwrap_or_default();
    let secs = v["seconds"].as_f64().unwrap_or(f64::NAN);
    println!(
        "  opencv:  {:.2} s (decode {:.2} s), {} frames, {} searched, {} with board, {} views; \
         rms {:.3} px\n    {}",
        secs,
        v["decode_s"].as_f64().unwrap_or(f64::NAN),
        v["frames"],
        v["searched"],
        v["with_board"],
        v["views"],
        v["rms"].as_f64().unwrap_or(f64::NAN),
        if p.len() >= 5 {
            errors(&p)
        } else {
            "no parameters".into()
        }
    );
    println!("  time ours/opencv {:.2}", ours / secs);
}
