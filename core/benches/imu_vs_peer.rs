//! `imu_noise` (parse + Allan + fit) vs the allantools peer (`shared/peers/imu_allan.py`) on a
//! synthetic static log: stage times, speed ratio, peak RSS and errors vs truth.
//!
//! `cargo bench -p caliper-core --bench imu_vs_peer`
//! Env: `CALIPER_PYTHON` (the peer's interpreter, default `python3`),
//! `IMU_HOURS` (default 1; 6 for the 460 MB log), `CALIPER_BENCH_RUNS` (default 3, ours),
//! `IMU_PEER_RUNS` (default 1), `IMU_SKIP_PEER=1` to time ours only. The log is generated with the
//! peer (`synth static --hours H --seed 6 --out /tmp/static_{H}h.csv`) when missing.

use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use caliper_core::NoProgress;
use caliper_core::imu::{
    ImuCsvParams, ImuNoiseParams, imu_noise, imu_noise_from_log, read_imu_log,
};

mod common;
use common::median;

fn vm_hwm_mib() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines().find(|l| l.starts_with("VmHWM:")).and_then(|l| {
                l.split_whitespace()
                    .nth(1)
                    .and_then(|v| v.parse::<f64>().ok())
            })
        })
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

fn peer_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/peers")
}

fn fmt_err(e: Option<f64>) -> String {
    match e {
        Some(v) => format!("{:+.1} %", 100.0 * v),
        None => "n/d".to_string(),
    }
}

fn main() {
    let hours: f64 = std::env::var("IMU_HOURS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1.0);
    let runs: usize = std::env::var("CALIPER_BENCH_RUNS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(3)
        .max(1);
    let peer_runs: usize = std::env::var("IMU_PEER_RUNS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1)
        .max(1);
    let tag = if hours.fract() == 0.0 {
        format!("{}h", hours as u64)
    } else {
        format!("{hours}h")
    };
    let csv = PathBuf::from(format!("/tmp/static_{tag}.csv"));
    let truth = PathBuf::from(format!("/tmp/static_{tag}_truth.json"));
    let peer = peer_dir().join("imu_allan.py");
    if !csv.exists() || !truth.exists() {
        eprintln!("generating {} with the peer …", csv.display());
        let st = Command::new(common::python())
            .arg(&peer)
            .args([
                "synth",
                "static",
                "--hours",
                &hours.to_string(),
                "--seed",
                "6",
                "--out",
            ])
            .arg(&csv)
            .status();
        if !matches!(st, Ok(s) if s.success()) {
            eprintln!("could not generate the log ({st:?}); is python3 with numpy available?");
            return;
        }
    }
    let size_mb = std::fs::metadata(&csv)
        .map(|m| m.len() as f64 / 1e6)
        .unwrap_or(f64::NAN);
    let params = ImuNoiseParams::default();
    let open = || BufReader::with_capacity(1 << 20, File::open(&csv).expect("open the CSV"));

    // Whole pipeline (what the service runs), then the two stages separately.
    if std::env::var("IMU_PARSE_ONLY").is_ok() {
        for _ in 0..runs {
            let t0 = Instant::now();
            let log = read_imu_log(open(), &ImuCsvParams::default(), &NoProgress).expect("parse");
            let dt = t0.elapsed().as_secs_f64();
            println!(
                "parse {:.1} ms, {:.0} MB/s, {} samples",
                dt * 1e3,
                size_mb / dt,
                log.len()
            );
        }
        return;
    }
    // The first thing this process does is one whole imu_noise: its VmHWM is our peak RSS.
    let mut total = Vec::new();
    let mut report = None;
    let mut our_rss = f64::NAN;
    for _ in 0..runs {
        let t0 = Instant::now();
        let r = imu_noise(open(), &params, &NoProgress).expect("imu_noise");
        total.push(t0.elapsed().as_secs_f64() * 1e3);
        if report.is_none() {
            our_rss = vm_hwm_mib();
        }
        report = Some(r);
    }
    let report = report.expect("runs >= 1");
    let mut parse_ms = Vec::new();
    let mut allan_ms = Vec::new();
    for _ in 0..runs {
        let t0 = Instant::now();
        let log = read_imu_log(open(), &ImuCsvParams::default(), &NoProgress).expect("parse");
        let t1 = Instant::now();
        let _ = imu_noise_from_log(&log, &params, &NoProgress).expect("allan");
        parse_ms.push((t1 - t0).as_secs_f64() * 1e3);
        allan_ms.push(t1.elapsed().as_secs_f64() * 1e3);
    }

    let (ours_total, ours_parse, ours_allan) = (median(total), median(parse_ms), median(allan_ms));

    // Truth.
    let tj: serde_json::Value = std::fs::read_to_string(&truth)
        .ok()
        .and_then(|s| serde_json::from_str(&s).ok())
        .unwrap_or(serde_json::Value::Null);
    let truth_of = |sensor: &str, key: &str, i: usize| tj["params"][sensor][key][i].as_f64();

    // Peer.
    let peer_json: Option<serde_json::Value> = if std::env::var("IMU_SKIP_PEER").is_ok() {
        None
    } else {
        let out = Command::new(common::python())
            .arg(&peer)
            .arg("--csv")
            .arg(&csv)
            .arg("--truth")
            .arg(&truth)
            .args(["--runs", &peer_runs.to_string()])
            .output();
        match out {
            Ok(o) if o.status.success() => serde_json::from_slice(&o.stdout).ok(),
            Ok(o) => {
                eprintln!("peer failed: {}", String::from_utf8_lossy(&o.stderr));
                None
            }
            Err(e) => {
                eprintln!("peer not runnable: {e}");
                None
            }
        }
    };
    let pt = |k: &str| peer_json.as_ref().and_then(|p| p["timings"][k].as_f64());

    println!(
        "\n### imu_noise vs allantools peer — {tag} static log, {} samples, {size_mb:.0} MB\n",
        report.samples
    );
    println!(
        "ours: median of {runs} runs; peer: `imu_allan.py --runs {peer_runs}` in the same process run\n"
    );
    println!("| stage | Caliper (ms) | peer (ms) | peer / Caliper |");
    println!("|---|---|---|---|");
    let row = |name: &str, ours: f64, peer: Option<f64>| {
        let (p, r) = match peer {
            Some(p) => (format!("{p:.0}"), format!("{:.1}×", p / ours)),
            None => ("–".into(), "–".into()),
        };
        println!("| {name} | {ours:.1} | {p} | {r} |");
    };
    row("parse", ours_parse, pt("parse_ms"));
    row(
        "ADEV 6 axes + fit (peer: adev + fit)",
        ours_allan,
        pt("adev_ms").zip(pt("fit_ms")).map(|(a, b)| a + b),
    );
    row("**total imu_noise**", ours_total, pt("total_ms"));
    let peer_rss = peer_json.as_ref().and_then(|p| p["peak_rss_mib"].as_f64());
    println!(
        "| peak RSS (MiB) | {our_rss:.0} | {} | |",
        peer_rss.map_or("–".into(), |v| format!("{v:.0}"))
    );

    println!(
        "\n| axis | N err (ours / peer) | B err (ours / peer) | K err (ours / peer) | ours: B, K reasons |"
    );
    println!("|---|---|---|---|---|");
    for a in &report.axes {
        let i = ["x", "y", "z"]
            .iter()
            .position(|x| *x == a.axis)
            .unwrap_or(0);
        let rel = |est: Option<f64>, key: &str| {
            est.zip(truth_of(&a.sensor, key, i))
                .map(|(e, t)| e / t - 1.0)
        };
        let pe = |k: &str| {
            peer_json.as_ref().and_then(|p| {
                p["vs_truth"][format!("{}_{}", a.sensor, a.axis)]["fit_rel_err"][k].as_f64()
            })
        };
        let reasons: Vec<String> = [&a.fit.b_reason, &a.fit.k_reason]
            .iter()
            .filter_map(|r| r.as_ref().map(|s| s.chars().take(70).collect::<String>()))
            .collect();
        println!(
            "| {} {} | {} / {} | {} / {} | {} / {} | {} |",
            a.sensor,
            a.axis,
            fmt_err(rel(a.fit.n, "noise_density")),
            fmt_err(pe("N")),
            fmt_err(rel(a.fit.b, "bias_instability")),
            fmt_err(pe("B")),
            fmt_err(rel(a.fit.k, "random_walk")),
            fmt_err(pe("K")),
            reasons.join("; ")
        );
    }
    println!(
        "\nours raw fit (no determinability filter) K rel err: {}",
        report
            .axes
            .iter()
            .map(|a| {
                let i = ["x", "y", "z"]
                    .iter()
                    .position(|x| *x == a.axis)
                    .unwrap_or(0);
                let t = truth_of(&a.sensor, "random_walk", i).unwrap_or(f64::NAN);
                format!(
                    "{} {}: {:+.0} % (±{:.0} %)",
                    a.sensor,
                    a.axis,
                    100.0 * (a.fit.raw[2] / t - 1.0),
                    100.0 * a.fit.rel_std[2].unwrap_or(f64::NAN)
                )
            })
            .collect::<Vec<_>>()
            .join(", ")
    );
    println!(
        "kalibr: {}",
        serde_json::to_string(&report.kalibr).unwrap_or_default()
    );
}
