//! Service benchmark: `GET /v1/jobs/{id}` throughput and p99 latency under `wrk`, and the
//! peak RSS of the server while it receives a 1 GB upload.
//!
//! Run with `cargo bench -p caliper-service --bench service_load`. It starts the release
//! `caliper` binary on a temporary data directory, so the numbers are those of the embedded
//! profile as users run it. Needs `wrk` and `curl` on PATH (Debian packages); without them it
//! says so and skips that part. Env: `BENCH_SECS` (default 10), `BENCH_CONNS` (default 64),
//! `BENCH_UPLOAD_MB` (default 1024).

use std::io::{BufRead, BufReader, Write};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn env_u64(name: &str, default: u64) -> u64 {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn have(tool: &str) -> bool {
    Command::new("sh")
        .args(["-c", &format!("command -v {tool} >/dev/null")])
        .status()
        .is_ok_and(|s| s.success())
}

fn vm_hwm_mib(pid: u32) -> Option<f64> {
    let text = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = text.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

fn curl(args: &[&str]) -> String {
    let out = Command::new("curl")
        .arg("-sS")
        .args(args)
        .output()
        .expect("curl runs");
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn main() {
    if !have("curl") {
        println!("service_load: curl not found (apt-get install curl); skipped");
        return;
    }
    println!("| benchmark | result |");
    println!("|---|---|");
    // First without the finished-job cache (every request reads SQLite), then the default.
    let uncached = Server::start(&["--job-cache-entries", "0"]);
    wrk_row(
        &uncached,
        "SQLite read per request (`--job-cache-entries 0`)",
    );
    uncached.stop();
    let srv = Server::start(&[]);
    wrk_row(&srv, "default (finished jobs cached)");
    upload_row(&srv);
    srv.stop();
}

struct Server {
    child: std::process::Child,
    base: String,
    job: String,
    dir: tempfile::TempDir,
    rss_idle: f64,
}

impl Server {
    /// Start the release binary, upload a tiny dataset and run one job to completion.
    fn start(extra: &[&str]) -> Server {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut child = Command::new(env!("CARGO_BIN_EXE_caliper"))
            .args(["serve", "--listen", "127.0.0.1:0", "--data-dir"])
            .arg(dir.path().join("data"))
            .args(extra)
            .env("RUST_LOG", "warn")
            .stdout(Stdio::piped())
            .spawn()
            .expect("start caliper");
        let mut line = String::new();
        BufReader::new(child.stdout.take().expect("stdout"))
            .read_line(&mut line)
            .expect("read");
        let base = line
            .trim()
            .trim_start_matches("caliper listening on ")
            .to_string();
        let pid = child.id();
        let rss_idle = vm_hwm_mib(pid).unwrap_or(f64::NAN);

        // A tiny dataset and a finished job to read.
        let img = dir.path().join("a.png");
        image::GrayImage::from_fn(64, 48, |x, y| image::Luma([((x * 7 + y * 13) % 251) as u8]))
            .save(&img)
            .expect("write png");
        let ds = curl(&[
            "-F",
            &format!("file=@{}", img.display()),
            &format!("{base}/v1/datasets"),
        ]);
        let ds: serde_json::Value = serde_json::from_str(&ds).expect("dataset json");
        let job = curl(&[
            "-H",
            "content-type: application/json",
            "-d",
            &format!(
                "{{\"kind\":\"blur_score\",\"dataset\":\"{}\"}}",
                ds["id"].as_str().unwrap_or("")
            ),
            &format!("{base}/v1/jobs"),
        ]);
        let job: serde_json::Value = serde_json::from_str(&job).expect("job json");
        let id = job["id"].as_str().unwrap_or("").to_string();
        let start = Instant::now();
        while start.elapsed() < Duration::from_secs(30) {
            let j: serde_json::Value =
                serde_json::from_str(&curl(&[&format!("{base}/v1/jobs/{id}")])).unwrap_or_default();
            if j["status"] == "succeeded" {
                break;
            }
            std::thread::sleep(Duration::from_millis(50));
        }

        Server {
            child,
            base,
            job: id,
            dir,
            rss_idle,
        }
    }

    fn stop(mut self) {
        let _ = Command::new("kill")
            .args(["-TERM", &self.child.id().to_string()])
            .status();
        let _ = self.child.wait();
    }
}

fn wrk_row(srv: &Server, label: &str) {
    let base = &srv.base;
    let id = &srv.job;
    if have("wrk") {
        let secs = env_u64("BENCH_SECS", 10);
        let conns = env_u64("BENCH_CONNS", 64);
        let out = Command::new("wrk")
            .args([
                "-t2",
                &format!("-c{conns}"),
                &format!("-d{secs}s"),
                "--latency",
            ])
            .arg(format!("{base}/v1/jobs/{id}"))
            .output()
            .expect("wrk runs");
        let text = String::from_utf8_lossy(&out.stdout);
        let rps = text
            .lines()
            .find(|l| l.starts_with("Requests/sec:"))
            .and_then(|l| l.split_whitespace().nth(1))
            .unwrap_or("?");
        let p99 = text
            .lines()
            .find(|l| l.trim_start().starts_with("99%"))
            .and_then(|l| l.split_whitespace().nth(1))
            .unwrap_or("?");
        let p50 = text
            .lines()
            .find(|l| l.trim_start().starts_with("50%"))
            .and_then(|l| l.split_whitespace().nth(1))
            .unwrap_or("?");
        let non2xx = text
            .lines()
            .find(|l| l.contains("Non-2xx"))
            .map(|l| l.trim().to_string())
            .unwrap_or_else(|| "all 2xx".into());
        println!(
            "| GET /v1/jobs/{{id}}, {label}, wrk -t2 -c{conns} {secs}s | {rps} req/s, p50 {p50}, p99 {p99} ({non2xx}) |"
        );
    } else {
        println!("| GET /v1/jobs/{{id}} | wrk not found (apt-get install wrk); skipped |");
    }
}

fn upload_row(srv: &Server) {
    let (base, dir, pid, rss_idle) = (&srv.base, &srv.dir, srv.child.id(), srv.rss_idle);
    let mb = env_u64("BENCH_UPLOAD_MB", 1024);
    let big = dir.path().join("clip.mp4");
    {
        let mut f = std::io::BufWriter::new(std::fs::File::create(&big).expect("create"));
        let mut header = vec![0u8, 0, 0, 0x18];
        header.extend_from_slice(b"ftypmp42\0\0\0\0mp42isom");
        f.write_all(&header).expect("write");
        let chunk: Vec<u8> = (0..1 << 20)
            .map(|i: u32| (i.wrapping_mul(2654435761) >> 24) as u8)
            .collect();
        for _ in 0..mb {
            f.write_all(&chunk).expect("write");
        }
    }
    let before = vm_hwm_mib(pid).unwrap_or(f64::NAN);
    let t0 = Instant::now();
    let resp = curl(&[
        "-F",
        &format!("file=@{}", big.display()),
        &format!("{base}/v1/datasets"),
    ]);
    let secs = t0.elapsed().as_secs_f64();
    let ok = resp.contains("\"kind\":\"video\"");
    let peak = vm_hwm_mib(pid).unwrap_or(f64::NAN);
    println!(
        "| upload {mb} MiB video ({}) | {:.1} s ({:.0} MiB/s); server peak RSS {peak:.1} MiB (idle {rss_idle:.1}, before upload {before:.1}) |",
        if ok { "accepted" } else { "FAILED" },
        secs,
        mb as f64 / secs
    );
}
