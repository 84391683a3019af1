//! Blur scores vs the OpenCV/numpy peer (`shared/peers/blur_scores.py`): timings and agreement.
//!
//! `cargo bench -p caliper-core --bench blur_vs_peer`
//! Env: `CALIPER_PYTHON` (the peer's interpreter, default `python3`),
//! `CALIPER_BLUR_DIR` (default `<workspace>/../shared/data/blur/synthetic_640x480`),
//! `CALIPER_BENCH_RUNS` (default 11), `RAYON_NUM_THREADS` (batch scoring), `CALIPER_BENCH_K` (10).

use std::path::{Path, PathBuf};
use std::process::Command;

use caliper_core::NoProgress;
use caliper_core::blur::{BlurParams, laplacian_variance, score_images, svd_beta};
use caliper_core::io::{ImageLimits, decode_gray8};

mod common;
use common::{median, timed};

struct Ours {
    name: String,
    size: (u32, u32),
    lap: f64,
    beta: f64,
    decode_ms: f64,
    lap_ms: f64,
    svd_ms: f64,
}

struct Peer {
    lap: f64,
    beta: f64,
    lap_ms: f64,
    svd_ms: f64,
}

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn run_peer(dir: &Path, runs: usize, k: usize) -> Result<(serde_json::Value, String), String> {
    let script = workspace_root().join("../shared/peers/blur_scores.py");
    if !script.exists() {
        return Err(format!("peer script {} not found", script.display()));
    }
    let pattern = format!("{}/*.png", dir.display());
    let out = Command::new(common::python())
        .arg(&script)
        .args(["--images", &pattern, "--runs", &runs.to_string()])
        .args(["--k", &k.to_string()])
        .output()
        .map_err(|e| format!("cannot run {:?}: {e}", common::python()))?;
    if !out.status.success() {
        return Err(format!(
            "peer failed (no cv2/numpy in CALIPER_PYTHON or python3?): {}",
            String::from_utf8_lossy(&out.stderr).trim()
        ));
    }
    let v: serde_json::Value =
        serde_json::from_slice(&out.stdout).map_err(|e| format!("peer output: {e}"))?;
    let env = v["env"].to_string();
    Ok((v, env))
}

fn main() {
    let dir = std::env::var_os("CALIPER_BLUR_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| workspace_root().join("../shared/data/blur/synthetic_640x480"));
    let runs: usize = std::env::var("CALIPER_BENCH_RUNS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(11)
        .max(1);
    let k: usize = std::env::var("CALIPER_BENCH_K")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(10);
    let Ok(entries) = std::fs::read_dir(&dir) else {
        println!(
            "blur_vs_peer: image directory {} not found (set CALIPER_BLUR_DIR); nothing to do",
            dir.display()
        );
        return;
    };
    let mut files: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "png"))
        .collect();
    files.sort();
    if files.is_empty() {
        println!("blur_vs_peer: no PNG in {}; nothing to do", dir.display());
        return;
    }
    let limits = ImageLimits::default();

    let mut ours = Vec::new();
    for f in &files {
        let bytes = std::fs::read(f).expect("read image");
        let (gray, decode_ms) = timed(runs, || decode_gray8(&bytes, &limits).expect("decode"));
        let (lap, lap_ms) = timed(runs, || laplacian_variance(&gray));
        let (beta, svd_ms) = timed(runs, || svd_beta(&gray, k).expect("svd_beta"));
        ours.push(Ours {
            name: f.file_name().unwrap_or_default().to_string_lossy().into(),
            size: (gray.width, gray.height),
            lap,
            beta,
            decode_ms,
            lap_ms,
            svd_ms,
        });
    }

    let peer = match run_peer(&dir, runs, k) {
        Ok((v, env)) => {
            println!("peer env: {env}");
            let mut m = std::collections::HashMap::new();
            for r in v["images"].as_array().into_iter().flatten() {
                let name = r["file"].as_str().unwrap_or_default().to_string();
                m.insert(
                    name,
                    Peer {
                        lap: r["laplacian_variance"].as_f64().unwrap_or(f64::NAN),
                        beta: r["svd_beta"].as_f64().unwrap_or(f64::NAN),
                        lap_ms: r["laplacian_ms"].as_f64().unwrap_or(f64::NAN),
                        svd_ms: r["svd_ms"].as_f64().unwrap_or(f64::NAN),
                    },
                );
            }
            Some(m)
        }
        Err(e) => {
            println!("peer skipped: {e}");
            None
        }
    };

    println!(
        "\nBlur scores, {} images from {}, median of {runs} runs, k = {k}, single thread per image\n",
        ours.len(),
        dir.display()
    );
    println!(
        "| image | size | decode ms | lap ms (ours) | lap ms (peer) | lap ratio | svd ms (ours) | svd ms (peer) | svd ratio | rel Δ lap var | abs Δ β |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    let (mut max_dlap, mut max_dbeta) = (0.0f64, 0.0f64);
    let mut cols: [Vec<f64>; 5] = Default::default();
    for o in &ours {
        let p = peer.as_ref().and_then(|m| m.get(&o.name));
        let f = |x: Option<f64>, prec: usize| x.map_or("–".into(), |v| format!("{v:.prec$}"));
        let (plap, psvd) = (p.map(|p| p.lap_ms), p.map(|p| p.svd_ms));
        let dlap = p.map(|p| (o.lap - p.lap).abs() / p.lap.abs().max(1e-300));
        let dbeta = p.map(|p| (o.beta - p.beta).abs());
        max_dlap = max_dlap.max(dlap.unwrap_or(0.0));
        max_dbeta = max_dbeta.max(dbeta.unwrap_or(0.0));
        cols[0].push(o.lap_ms);
        cols[1].push(o.svd_ms);
        cols[4].push(o.decode_ms);
        if let (Some(a), Some(b)) = (plap, psvd) {
            cols[2].push(a);
            cols[3].push(b);
        }
        println!(
            "| {} | {}×{} | {:.2} | {:.3} | {} | {} | {:.2} | {} | {} | {} | {} |",
            o.name,
            o.size.0,
            o.size.1,
            o.decode_ms,
            o.lap_ms,
            f(plap, 3),
            f(plap.map(|v| v / o.lap_ms), 1),
            o.svd_ms,
            f(psvd, 2),
            f(psvd.map(|v| v / o.svd_ms), 1),
            dlap.map_or("–".into(), |v| format!("{v:.1e}")),
            dbeta.map_or("–".into(), |v| format!("{v:.1e}")),
        );
    }
    let [lap_o, svd_o, lap_p, svd_p, dec_o] = cols.map(median);
    let have_peer = peer.is_some();
    let pm = |v: f64| {
        if have_peer {
            format!("{v:.3}")
        } else {
            "–".into()
        }
    };
    println!(
        "| **median** | | {dec_o:.2} | {lap_o:.3} | {} | {} | {svd_o:.2} | {} | {} | max {max_dlap:.1e} | max {max_dbeta:.1e} |",
        pm(lap_p),
        if have_peer {
            format!("{:.1}", lap_p / lap_o)
        } else {
            "–".into()
        },
        pm(svd_p),
        if have_peer {
            format!("{:.1}", svd_p / svd_o)
        } else {
            "–".into()
        },
    );

    // Whole batch through score_images (decode + both scores), parallel across images.
    let names: Vec<String> = ours.iter().map(|o| o.name.clone()).collect();
    let blobs: Vec<Vec<u8>> = files
        .iter()
        .map(|f| std::fs::read(f).expect("read image"))
        .collect();
    let params = BlurParams {
        k,
        ..BlurParams::default()
    };
    let (_, batch_ms) = timed(runs, || {
        score_images(
            &names,
            |i| Ok(blobs[i].clone()),
            &params,
            &limits,
            &NoProgress,
        )
        .expect("score_images")
    });
    println!(
        "\nscore_images on the whole set (decode + scores, rayon threads = {}, RAYON_NUM_THREADS={}): {batch_ms:.1} ms median",
        rayon::current_num_threads(),
        std::env::var("RAYON_NUM_THREADS").unwrap_or_else(|_| "unset".into()),
    );
}
