//! Photometric calibration on the shared data (`bracket_seed0`, `ae_seq_seed0`) against the
//! OpenCV peer (Debevec, Robertson) and the shared reference batch fit.
//!
//! Data from `CALIPER_PHOTO_DATA` (default `../shared/data/photometric` next to the
//! workspace); the peer script runs under `CALIPER_PYTHON` (default `python3`, which needs cv2)
//! unless `CALIPER_BENCH_NO_PEER=1`.
//!
//! ```text
//! cargo bench -p caliper-core --bench photometric_vs_opencv
//! ```

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Mutex;
use std::time::Instant;

use caliper_core::io::ImageLimits;
use caliper_core::photometric::dso::{read_times, read_vignette_png};
use caliper_core::photometric::metrics::{
    exposure_error_pct, gamma_align, inverse_rmse, vignette_rmse,
};
use caliper_core::photometric::{
    InverseResponse, OnlineParams, PhotoImage, ResponseParams, photometric_online,
    photometric_response,
};
use caliper_core::{NoProgress, Progress};
use serde_json::Value;

fn data_dir() -> PathBuf {
    std::env::var_os("CALIPER_PHOTO_DATA").map_or_else(
        || Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/photometric"),
        PathBuf::from,
    )
}

fn load_images(dir: &Path) -> Result<Vec<PhotoImage>, String> {
    let mut paths: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| format!("{}: {e}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "png"))
        .collect();
    paths.sort();
    paths
        .iter()
        .map(|p| {
            let bytes = std::fs::read(p).map_err(|e| format!("{}: {e}", p.display()))?;
            PhotoImage::decode(&bytes, &ImageLimits::default())
                .map_err(|e| format!("{}: {e}", p.display()))
        })
        .collect()
}

fn read_json(p: &Path) -> Result<Value, String> {
    let t = std::fs::read_to_string(p).map_err(|e| format!("{}: {e}", p.display()))?;
    serde_json::from_str(&t).map_err(|e| format!("{}: {e}", p.display()))
}

fn f64s(v: &Value) -> Vec<f64> {
    v.as_array()
        .map(|a| a.iter().filter_map(Value::as_f64).collect())
        .unwrap_or_default()
}

/// Records when each named step starts (the algorithms report their steps through
/// [`Progress`]).
struct StepTimer {
    t0: Instant,
    steps: Mutex<Vec<(String, f64)>>,
}

impl Progress for StepTimer {
    fn report(&self, step: &str, _done: u64, _total: u64) {
        if let Ok(mut s) = self.steps.lock()
            && s.last().is_none_or(|l| l.0 != step)
        {
            s.push((step.to_string(), self.t0.elapsed().as_secs_f64()));
        }
    }

    fn is_canceled(&self) -> bool {
        false
    }
}

/// CPU seconds (user + system) of this process so far, from `/proc/self/stat` (Linux; NaN
/// elsewhere): on a loaded machine wall time overstates what the algorithm costs.
fn cpu_seconds() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else {
        return f64::NAN;
    };
    // Fields after the parenthesised command name; utime and stime are fields 14 and 15.
    let Some(rest) = stat.rsplit_once(')').map(|(_, r)| r) else {
        return f64::NAN;
    };
    let f: Vec<&str> = rest.split_whitespace().collect();
    let tick = |i: usize| {
        f.get(i)
            .and_then(|v| v.parse::<f64>().ok())
            .unwrap_or(f64::NAN)
    };
    // Linux reports in USER_HZ, 100 on every mainstream configuration.
    (tick(11) + tick(12)) / 100.0
}

struct Peer {
    debevec_rmse: f64,
    robertson_rmse: f64,
    debevec_ms: f64,
    robertson_ms: f64,
}

fn run_peer(data: &Path, bracket: &Path) -> Result<Peer, String> {
    let script = data.join("../../peers/photometric_opencv.py");
    let out = Command::new(common::python())
        .arg(&script)
        .arg("--images")
        .arg(format!("{}/images/*.png", bracket.display()))
        .arg("--times")
        .arg(bracket.join("times.txt"))
        .arg("--gt")
        .arg(bracket.join("gt.json"))
        .arg("--runs")
        .arg("3")
        .output()
        .map_err(|e| format!("cannot run {}: {e}", script.display()))?;
    if !out.status.success() {
        return Err(format!(
            "peer failed: {}",
            String::from_utf8_lossy(&out.stderr)
        ));
    }
    let v: Value = serde_json::from_slice(&out.stdout).map_err(|e| format!("peer output: {e}"))?;
    let g = |p: &str| v.pointer(p).and_then(Value::as_f64).unwrap_or(f64::NAN);
    Ok(Peer {
        debevec_rmse: g("/methods/debevec/rmse_vs_gt/channel_mean_1_254"),
        robertson_rmse: g("/methods/robertson/rmse_vs_gt/channel_mean_1_254"),
        debevec_ms: g("/timings/debevec_ms"),
        robertson_ms: g("/timings/robertson_ms"),
    })
}

fn main() {
    let data = data_dir();
    let bracket = data.join("bracket_seed0");
    let ae = data.join("ae_seq_seed0");
    if !bracket.is_dir() || !ae.is_dir() {
        println!(
            "photometric_vs_opencv: skipped, no data at {} (set CALIPER_PHOTO_DATA)",
            data.display()
        );
        return;
    }
    if let Err(e) = run(&data, &bracket, &ae) {
        eprintln!("photometric_vs_opencv: {e}");
        std::process::exit(1);
    }
}

fn run(data: &Path, bracket: &Path, ae: &Path) -> Result<(), String> {
    // Bracketed stack.
    let imgs = load_images(&bracket.join("images"))?;
    let times =
        read_times(&std::fs::read_to_string(bracket.join("times.txt")).map_err(|e| e.to_string())?)
            .map_err(|e| e.to_string())?;
    let exps: Vec<f64> = times.iter().map(|t| t.exposure_ms).collect();
    let gt = read_json(&bracket.join("gt.json"))?;
    let truth = InverseResponse {
        values: f64s(&gt["response"]["inverse_256"]),
    };
    let mut secs = Vec::new();
    let mut res = None;
    for _ in 0..5 {
        let t0 = Instant::now();
        res = Some(
            photometric_response(&imgs, &exps, &ResponseParams::default(), &NoProgress)
                .map_err(|e| e.to_string())?,
        );
        secs.push(t0.elapsed().as_secs_f64());
    }
    let res = res.ok_or("no run")?;
    let ours_ms = common::median(secs) * 1e3;
    let fit = InverseResponse {
        values: res.model.inverse_256.clone(),
    };
    let ours_rmse = inverse_rmse(&fit, &truth);
    let peer = if std::env::var("CALIPER_BENCH_NO_PEER").is_ok_and(|v| v == "1") {
        None
    } else {
        match run_peer(data, bracket) {
            Ok(p) => Some(p),
            Err(e) => {
                println!("peer not run: {e}");
                None
            }
        }
    };

    // Online calibration.
    let frames = load_images(&ae.join("images"))?;
    let gt = read_json(&ae.join("gt.json"))?;
    let truth_inv = InverseResponse {
        values: f64s(&gt["response"]["inverse_256"]),
    };
    let truth_e = f64s(&gt["exposure_ratio_to_frame0"]);
    let vig_png = std::fs::read(ae.join("vignette.png")).map_err(|e| e.to_string())?;
    let truth_v =
        read_vignette_png(&vig_png, &ImageLimits::default(), None).map_err(|e| e.to_string())?;
    let cpu0 = cpu_seconds();
    let timer = StepTimer {
        t0: Instant::now(),
        steps: Mutex::new(Vec::new()),
    };
    let on =
        photometric_online(&frames, &OnlineParams::default(), &timer).map_err(|e| e.to_string())?;
    let online_s = timer.t0.elapsed().as_secs_f64();
    let online_cpu = cpu_seconds() - cpu0;
    let stages: Vec<String> = timer
        .steps
        .lock()
        .map(|s| {
            s.iter()
                .map(|(n, t)| format!("{n} from {t:.2} s"))
                .collect()
        })
        .unwrap_or_default();
    let fit = InverseResponse {
        values: on.model.inverse_256.clone(),
    };
    let (alpha, resp_err) = gamma_align(&fit, &truth_inv);
    let vmap = on
        .model
        .vignette
        .as_ref()
        .map(|v| v.map())
        .unwrap_or_default();
    let vig_err = vignette_rmse(&vmap, &truth_v.data, alpha);
    let exp_err = exposure_error_pct(&on.exposure_ratios, &truth_e, alpha);
    let ref_score = read_json(&ae.join("score_ref.json")).ok();
    let rs = |p: &str| {
        ref_score
            .as_ref()
            .and_then(|v| v.pointer(p))
            .and_then(Value::as_f64)
            .unwrap_or(f64::NAN)
    };

    println!("\nbracket_seed0 (9 × 320×240): inverse-response RMSE on [0,1], levels 1..254");
    println!("| method | RMSE | monotone | time [ms] | time / ours |");
    println!("|---|---|---|---|---|");
    println!(
        "| caliper (EMoR-4 LM) | {ours_rmse:.4} | {} | {ours_ms:.1} | 1.00 |",
        res.diagnostics.monotone
    );
    if let Some(p) = &peer {
        println!(
            "| OpenCV Debevec | {:.4} | – | {:.1} | {:.2} |",
            p.debevec_rmse,
            p.debevec_ms,
            p.debevec_ms / ours_ms
        );
        println!(
            "| OpenCV Robertson | {:.4} | – | {:.1} | {:.2} |",
            p.robertson_rmse,
            p.robertson_ms,
            p.robertson_ms / ours_ms
        );
    }
    println!(
        "\nae_seq_seed0 ({} frames): errors after aligning the γ gauge (α = {alpha:.3})",
        frames.len()
    );
    println!("| method | response RMSE | vignette RMSE | exposure ratio RMS [%] | time [s] |");
    println!("|---|---|---|---|---|");
    println!(
        "| caliper online (own KLT tracks) | {resp_err:.4} | {vig_err:.4} | {exp_err:.2} | {online_s:.2} |"
    );
    println!(
        "| reference batch fit (GT tracks, Python) | {:.4} | {:.4} | {:.2} | ~116 |",
        rs("/response/inverse_rmse_gauge_aligned"),
        rs("/vignette/rmse_gauge_aligned"),
        rs("/exposure/ratio_rmse_pct_gauge_aligned")
    );
    println!(
        "online: {} tracks (mean length {:.1}), {} points, {} observations, {} iterations, residual {:.2} levels, monotone {}",
        on.tracks,
        on.mean_track_length,
        on.diagnostics.points,
        on.diagnostics.observations,
        on.diagnostics.iterations,
        on.diagnostics.residual_rms_levels,
        on.diagnostics.monotone
    );
    println!(
        "online stages: {}; total {online_s:.2} s wall, {online_cpu:.2} s CPU ({} threads)",
        stages.join(", "),
        rayon::current_num_threads()
    );
    Ok(())
}
