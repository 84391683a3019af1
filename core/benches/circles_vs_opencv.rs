//! Circle-grid centres vs OpenCV's `cv2.findCirclesGrid` on the same supersampled renders
//! (`tests/circles_render.rs`, 1280×960, symmetric 7×6 and asymmetric 4×11 grids tilted 0°,
//! 30°, 45°, 60°, blur σ 1 and 1.5 with noise σ 1 and 2 grey levels), written as PNG files and
//! handed to both: the RMS error against the true projected circle centres of our corrected
//! centres, our raw ellipse centres and OpenCV's centres, per tilt; and the median detection
//! time per image of both, with their ratio.
//!
//! `CALIPER_PYTHON=/var/tmp/caliper-py/bin/python cargo bench -p caliper-core --bench circles_vs_opencv`
//! Env: `CALIPER_PYTHON` (a Python with cv2; without it only our side runs, said loudly),
//! `CALIPER_BENCH_RUNS` (default 5; median per image). The peer script is embedded below and
//! written next to the images. OpenCV's order may be our order turned by a half turn (the
//! grids' own symmetry); its error is taken in whichever of the two numberings fits, and the
//! count of turned numberings is reported. Ours labels threshold levels on rayon's pool (the
//! machine's cores); OpenCV runs as its users get it.

use std::process::Command;
use std::time::Instant;

use caliper_core::board::TargetSpec;
use caliper_core::board::circles::{CircleGrid, CirclesDetection, detect_circles};

mod common;
#[path = "../tests/circles_render.rs"]
mod render;
use common::median;
use render::{Scene, render, tilted};

/// The OpenCV side: `peer.py COLS ROWS ASYM RUNS IMAGE...`, JSON on stdout.
const PEER: &str = r#"
import json, sys, time
import cv2
cols, rows, asym, runs = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3] == "1", int(sys.argv[4])
flags = cv2.CALIB_CB_ASYMMETRIC_GRID if asym else cv2.CALIB_CB_SYMMETRIC_GRID
out = []
for path in sys.argv[5:]:
    img = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
    times, ok, centres = [], False, None
    for _ in range(runs):
        t0 = time.perf_counter()
        ok, centres = cv2.findCirclesGrid(img, (cols, rows), flags=flags)
        times.append((time.perf_counter() - t0) * 1e3)
    times.sort()
    pts = centres.reshape(-1, 2).tolist() if ok and centres is not None else []
    out.append({"found": bool(ok), "centres": pts, "ms": times[len(times) // 2]})
print(json.dumps({"cv2": cv2.__version__, "images": out}))
"#;

struct Case {
    name: &'static str,
    spec: TargetSpec,
    dist: f64,
}

/// RMS error of `pts[id]` against `truth[id]`, and of the half-turned numbering; the smaller
/// with whether it was the turned one.
/// One view as OpenCV found it: found, centres, milliseconds.
type PeerView = (bool, Vec<[f64; 2]>, f64);

fn rms(pts: &[[f64; 2]], truth: &[(usize, [f64; 2])]) -> Option<(f64, bool)> {
    if pts.len() != truth.len() || pts.is_empty() {
        return None;
    }
    let n = pts.len();
    let e = |turn: bool| {
        let se: f64 = (0..n)
            .map(|k| {
                let t = truth[if turn { n - 1 - k } else { k }].1;
                (pts[k][0] - t[0]).powi(2) + (pts[k][1] - t[1]).powi(2)
            })
            .sum();
        (se / n as f64).sqrt()
    };
    let (a, b) = (e(false), e(true));
    Some(if a <= b { (a, false) } else { (b, true) })
}

fn mean(v: &[f64]) -> f64 {
    if v.is_empty() {
        f64::NAN
    } else {
        v.iter().sum::<f64>() / v.len() as f64
    }
}

fn main() {
    let runs: usize = std::env::var("CALIPER_BENCH_RUNS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(5)
        .max(1);
    let cases = [
        Case {
            name: "symmetric 7×6",
            spec: TargetSpec::Circles {
                cols: 7,
                rows: 6,
                spacing: 0.03,
                diameter: 0.018,
                asymmetric: false,
            },
            dist: 0.42,
        },
        Case {
            name: "asymmetric 4×11",
            spec: TargetSpec::Circles {
                cols: 4,
                rows: 11,
                spacing: 0.02,
                diameter: 0.02,
                asymmetric: true,
            },
            dist: 0.36,
        },
    ];
    let tilts = [0.0, 30.0, 45.0, 60.0];
    let blurs = [(1.0, 1.0), (1.5, 2.0)];
    let dir = std::env::temp_dir().join(format!("caliper-circles-bench-{}", std::process::id()));
    if let Err(e) = std::fs::create_dir_all(&dir) {
        eprintln!("cannot create {}: {e}", dir.display());
        return;
    }
    let python = std::env::var_os("CALIPER_PYTHON");
    if python.is_none() {
        println!("!!! OpenCV peer NOT RUN: set CALIPER_PYTHON to a Python with cv2 to compare !!!");
    }
    let (mut ours_ms_all, mut peer_ms_all) = (Vec::new(), Vec::new());
    for case in &cases {
        let TargetSpec::Circles {
            cols,
            rows,
            spacing,
            diameter,
            asymmetric,
        } = case.spec
        else {
            return;
        };
        let grid = match CircleGrid::new(cols, rows, spacing, diameter, asymmetric) {
            Ok(g) => g,
            Err(e) => {
                eprintln!("bad grid: {e}");
                return;
            }
        };
        println!(
            "{} (spacing {spacing}, diameter {diameter}), 1280×960, {runs} runs per image",
            case.name
        );
        println!(
            "  tilt  blur noise | ours corrected | ours raw | OpenCV         | ours ms | OpenCV ms"
        );
        let mut paths = Vec::new();
        let mut views = Vec::new();
        for &tilt in &tilts {
            for (k, &(blur, noise)) in blurs.iter().enumerate() {
                let scene = Scene {
                    blur,
                    noise,
                    seed: 1 + k as u64 + tilt as u64,
                    ..tilted(&case.spec, tilt, case.dist)
                };
                let v = render(&case.spec, &scene);
                let path = dir.join(format!(
                    "{}_{tilt}_{k}.png",
                    if asymmetric { "a" } else { "s" }
                ));
                let img =
                    image::GrayImage::from_raw(v.image.width, v.image.height, v.image.data.clone());
                let Some(img) = img else { return };
                if let Err(e) = img.save(&path) {
                    eprintln!("cannot write a PNG: {e}");
                    return;
                }
                paths.push(path);
                views.push((tilt, blur, noise, v));
            }
        }
        // OpenCV, all images of this case in one process.
        let peer: Option<Vec<PeerView>> = python.as_ref().and_then(|py| {
            let script = dir.join("peer.py");
            std::fs::write(&script, PEER).ok()?;
            let out = Command::new(py)
                .arg(&script)
                .args([
                    cols.to_string(),
                    rows.to_string(),
                    if asymmetric { "1" } else { "0" }.to_string(),
                    runs.to_string(),
                ])
                .args(&paths)
                .output();
            let out = match out {
                Ok(o) if o.status.success() => o,
                Ok(o) => {
                    println!(
                        "!!! OpenCV peer FAILED: {}",
                        String::from_utf8_lossy(&o.stderr)
                    );
                    return None;
                }
                Err(e) => {
                    println!(
                        "!!! OpenCV peer NOT RUN: cannot run {}: {e}",
                        py.to_string_lossy()
                    );
                    return None;
                }
            };
            let doc: serde_json::Value = serde_json::from_slice(&out.stdout).ok()?;
            let imgs = doc["images"].as_array()?;
            Some(
                imgs.iter()
                    .map(|im| {
                        let pts = im["centres"]
                            .as_array()
                            .map(|a| {
                                a.iter()
                                    .filter_map(|p| Some([p[0].as_f64()?, p[1].as_f64()?]))
                                    .collect()
                            })
                            .unwrap_or_default();
                        (
                            im["found"].as_bool().unwrap_or(false),
                            pts,
                            im["ms"].as_f64().unwrap_or(f64::NAN),
                        )
                    })
                    .collect(),
            )
        });
        let mut turned = 0;
        for (k, (tilt, blur, noise, v)) in views.iter().enumerate() {
            let mut ts = Vec::new();
            let mut det = None;
            for _ in 0..runs {
                let t0 = Instant::now();
                det = Some(detect_circles(&v.image, &grid, 20.0));
                ts.push(t0.elapsed().as_secs_f64() * 1e3);
            }
            let ms = median(ts);
            ours_ms_all.push(ms);
            let (corr, raw) = match det {
                Some(CirclesDetection::Found(cs)) => {
                    let c: Vec<[f64; 2]> = cs.iter().map(|c| c.corrected).collect();
                    let r: Vec<[f64; 2]> = cs.iter().map(|c| c.raw).collect();
                    (rms(&c, &v.truth), rms(&r, &v.truth))
                }
                _ => (None, None),
            };
            let fmt = |e: Option<(f64, bool)>| match e {
                Some((e, t)) => format!("{e:.4}{}", if t { " (turned)" } else { "" }),
                None => "not found".to_string(),
            };
            let (peer_txt, peer_ms) = match &peer {
                Some(p) => match p.get(k) {
                    Some((true, pts, ms)) => {
                        let e = rms(pts, &v.truth);
                        if let Some((_, true)) = e {
                            turned += 1;
                        }
                        peer_ms_all.push(*ms);
                        (fmt(e), format!("{ms:.2}"))
                    }
                    Some((false, _, ms)) => {
                        peer_ms_all.push(*ms);
                        ("not found".to_string(), format!("{ms:.2}"))
                    }
                    None => ("-".to_string(), "-".to_string()),
                },
                None => ("NOT RUN".to_string(), "-".to_string()),
            };
            println!(
                "  {tilt:>4}° {blur:>4} {noise:>5} | {:<14} | {:<8} | {peer_txt:<14} | {ms:>7.2} | {peer_ms:>9}",
                fmt(corr),
                fmt(raw).replace(" (turned)", "T"),
            );
        }
        if peer.is_some() {
            println!(
                "  OpenCV numbered {turned} of {} views turned by a half turn from ours",
                views.len()
            );
        }
    }
    let (o, p) = (median(ours_ms_all.clone()), median(peer_ms_all.clone()));
    println!(
        "time per image, median over all views: ours {o:.2} ms (mean {:.2}), OpenCV {}",
        mean(&ours_ms_all),
        if peer_ms_all.is_empty() {
            "NOT RUN".to_string()
        } else {
            format!(
                "{p:.2} ms (mean {:.2}); ratio OpenCV / ours {:.2}×",
                mean(&peer_ms_all),
                p / o
            )
        }
    );
    let _ = std::fs::remove_dir_all(&dir);
}
