//! Production-profile benchmark: three replicas of the release `caliper` on one PostgreSQL
//! database and one S3-compatible bucket, next to the embedded profile, on the same machine
//! as the load generator (`wrk`).
//!
//! Rows: job-status reads (req/s, p50, p99) spread over the replicas; job submissions (jobs/s,
//! p50, p99) while the replicas also run the jobs; submit-to-running latency of single jobs on
//! idle workers (the `NOTIFY` wake-up); and the peak RSS of a replica receiving a 1 GiB upload
//! (an IMU log) that streams to S3.
//!
//! Run: `BENCH_POSTGRES_URL=postgres://postgres@127.0.0.1:5432/test
//! BENCH_S3_ENDPOINT=http://127.0.0.1:5077 cargo bench -p caliper-service --bench fleet`
//! (`.ci/run` starts moto; `moto_server -p 5077` does by hand). Env: `BENCH_SECS` (10),
//! `BENCH_CONNS` (64), `BENCH_UPLOAD_MB` (1024), `BENCH_BIN` (a release `caliper` to measure
//! instead of the bench profile's; the harness only drives `wrk` and `curl`, so
//! `BENCH_BIN=target/release/caliper cargo test -p caliper-service --bench fleet` measures the
//! same binary without building the service a second time). Needs `wrk` and `curl`.

use std::io::{BufRead, BufReader, Write};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;

fn env_u64(name: &str, default: u64) -> u64 {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

fn vm_hwm_mib(pid: u32) -> f64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .ok()
        .and_then(|t| {
            let line = t.lines().find(|l| l.starts_with("VmHWM:"))?.to_owned();
            line.split_whitespace().nth(1)?.parse::<f64>().ok()
        })
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

struct Proc {
    child: Child,
    base: String,
}

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The binary measured: `BENCH_BIN`, or the one cargo built with this bench.
fn caliper_bin() -> std::path::PathBuf {
    std::env::var_os("BENCH_BIN")
        .filter(|b| !b.is_empty())
        .map_or_else(|| env!("CARGO_BIN_EXE_caliper").into(), Into::into)
}

fn spawn(data: &std::path::Path, args: &[&str], env: &[(&str, String)]) -> Proc {
    let mut child = Command::new(caliper_bin())
        .args(["serve", "--listen", "127.0.0.1:0", "--data-dir"])
        .arg(data)
        .args(args)
        .envs(env.iter().map(|(k, v)| (*k, v.as_str())))
        .env("RUST_LOG", "error")
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
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
    Proc { child, base }
}

fn curl(args: &[&str]) -> String {
    let out = Command::new("curl")
        .arg("-sS")
        .args(args)
        .output()
        .expect("curl");
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// `wrk` against each base at once (one thread each), summed; returns (req/s, p50, p99, errors).
fn wrk(
    bases: &[String],
    path: &str,
    token: Option<&str>,
    script: Option<&std::path::Path>,
    conns_total: u64,
) -> String {
    let secs = env_u64("BENCH_SECS", 10);
    let conns = conns_total / bases.len() as u64;
    let children: Vec<_> = bases
        .iter()
        .map(|b| {
            let mut c = Command::new("wrk");
            c.args([
                "-t1",
                &format!("-c{}", conns.max(1)),
                &format!("-d{secs}s"),
                "--latency",
            ]);
            if let Some(t) = token {
                c.args(["-H", &format!("Authorization: Bearer {t}")]);
            }
            if let Some(s) = script {
                c.arg("-s").arg(s);
            }
            c.arg(format!("{b}{path}"))
                .stdout(Stdio::piped())
                .spawn()
                .expect("wrk")
        })
        .collect();
    let mut rps = 0.0;
    let mut p50 = Vec::new();
    let mut p99 = Vec::new();
    let mut errors = Vec::new();
    for ch in children {
        let out = ch.wait_with_output().expect("wrk output");
        let text = String::from_utf8_lossy(&out.stdout);
        let field = |prefix: &str| {
            text.lines()
                .find(|l| l.trim_start().starts_with(prefix))
                .and_then(|l| l.split_whitespace().nth(1))
                .unwrap_or("?")
                .to_owned()
        };
        rps += field("Requests/sec:").parse::<f64>().unwrap_or(0.0);
        p50.push(field("50%"));
        p99.push(field("99%"));
        if let Some(l) = text
            .lines()
            .find(|l| l.contains("Non-2xx") || l.contains("Socket errors"))
        {
            errors.push(l.trim().to_owned());
        }
    }
    format!(
        "{rps:.0} req/s, p50 {} , p99 {} (per replica){}",
        p50.join("/"),
        p99.join("/"),
        if errors.is_empty() {
            String::new()
        } else {
            format!("; {}", errors.join("; "))
        }
    )
}

struct Profile {
    name: &'static str,
    procs: Vec<Proc>,
    token: Option<String>,
    dataset: String,
    job: String,
    _dirs: Vec<tempfile::TempDir>,
}

fn auth_args(token: Option<&str>) -> Vec<String> {
    token
        .map(|t| vec!["-H".to_string(), format!("Authorization: Bearer {t}")])
        .unwrap_or_default()
}

/// Upload a small dataset and run one job to completion, for the read and submit rows.
fn prepare(bases: &[String], token: Option<&str>, dir: &std::path::Path) -> (String, String) {
    let img = dir.join("a.png");
    image::GrayImage::from_fn(64, 48, |x, y| image::Luma([((x * 7 + y * 13) % 251) as u8]))
        .save(&img)
        .expect("png");
    let mut args = auth_args(token);
    args.extend([
        "-F".into(),
        format!("file=@{}", img.display()),
        format!("{}/v1/datasets", bases[0]),
    ]);
    let refs: Vec<&str> = args.iter().map(String::as_str).collect();
    let ds: Value = serde_json::from_str(&curl(&refs)).expect("dataset");
    let ds = ds["id"].as_str().expect("dataset id").to_owned();
    let (id, _) = submit(&bases[0], token, &ds);
    wait_status(&bases[1 % bases.len()], token, &id, "succeeded");
    (ds, id)
}

fn submit(base: &str, token: Option<&str>, ds: &str) -> (String, Instant) {
    let mut args = auth_args(token);
    let body = format!("{{\"kind\":\"blur_score\",\"dataset\":\"{ds}\"}}");
    args.extend([
        "-H".into(),
        "content-type: application/json".into(),
        "-d".into(),
        body,
        format!("{base}/v1/jobs"),
    ]);
    let refs: Vec<&str> = args.iter().map(String::as_str).collect();
    let t = Instant::now();
    let j: Value = serde_json::from_str(&curl(&refs)).expect("job");
    (j["id"].as_str().expect("job id").to_owned(), t)
}

fn get_job(base: &str, token: Option<&str>, id: &str) -> Value {
    let mut args = auth_args(token);
    args.push(format!("{base}/v1/jobs/{id}"));
    let refs: Vec<&str> = args.iter().map(String::as_str).collect();
    serde_json::from_str(&curl(&refs)).unwrap_or_default()
}

fn wait_status(base: &str, token: Option<&str>, id: &str, want: &str) -> Value {
    let start = Instant::now();
    loop {
        let j = get_job(base, token, id);
        if j["status"] == want {
            return j;
        }
        assert!(start.elapsed() < Duration::from_secs(60), "{j}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn main() {
    let pg = std::env::var("BENCH_POSTGRES_URL")
        .ok()
        .filter(|s| !s.is_empty());
    let s3 = std::env::var("BENCH_S3_ENDPOINT")
        .ok()
        .filter(|s| !s.is_empty());
    println!("| profile | benchmark | result |");
    println!("|---|---|---|");
    let embedded = start_embedded();
    rows(&embedded);
    drop(embedded);
    match (pg, s3) {
        (Some(pg), Some(s3)) => {
            let fleet = start_fleet(&pg, &s3);
            rows(&fleet);
            upload_row(&fleet);
        }
        _ => println!("| 3 replicas | — | NOT RUN: set BENCH_POSTGRES_URL and BENCH_S3_ENDPOINT |"),
    }
}

fn start_embedded() -> Profile {
    let dir = tempfile::tempdir().expect("dir");
    let p = spawn(
        &dir.path().join("data"),
        &["--max-queued-jobs", "1000000"],
        &[],
    );
    let bases = vec![p.base.clone()];
    let (dataset, job) = prepare(&bases, None, dir.path());
    Profile {
        name: "embedded (1 process, SQLite)",
        procs: vec![p],
        token: None,
        dataset,
        job,
        _dirs: vec![dir],
    }
}

fn start_fleet(pg_admin: &str, s3: &str) -> Profile {
    let db = format!("caliper_bench_{}", std::process::id());
    let admin = pg_admin.to_owned();
    Command::new("psql")
        .args([
            &admin,
            "-q",
            "-c",
            &format!("DROP DATABASE IF EXISTS {db} WITH (FORCE)"),
        ])
        .status()
        .expect("psql");
    Command::new("psql")
        .args([&admin, "-q", "-c", &format!("CREATE DATABASE {db}")])
        .status()
        .expect("psql");
    let url = format!(
        "{}/{db}",
        admin.rsplit_once('/').map_or(admin.as_str(), |(b, _)| b)
    );
    let bucket = format!("caliper-bench-{}", std::process::id());
    curl(&["-X", "PUT", &format!("{s3}/{bucket}")]);
    let env = vec![
        ("AWS_ENDPOINT", s3.to_owned()),
        ("AWS_ALLOW_HTTP", "true".to_owned()),
        ("AWS_ACCESS_KEY_ID", "bench".to_owned()),
        ("AWS_SECRET_ACCESS_KEY", "bench".to_owned()),
        ("AWS_REGION", "us-east-1".to_owned()),
    ];
    let out = Command::new(env!("CARGO_BIN_EXE_caliper"))
        .args([
            "token",
            "create",
            "--scope",
            "admin",
            "--name",
            "bench",
            "--database-url",
            &url,
        ])
        .output()
        .expect("token");
    let token = String::from_utf8_lossy(&out.stdout).trim().to_owned();
    let mut dirs = Vec::new();
    let mut procs = Vec::new();
    let blob_url = format!("s3://{bucket}/bench");
    for _ in 0..3 {
        let d = tempfile::tempdir().expect("dir");
        procs.push(spawn(
            d.path(),
            &[
                "--database-url",
                &url,
                "--blob-url",
                &blob_url,
                "--max-queued-jobs",
                "1000000",
                "--rate-limit-per-sec",
                "0",
            ],
            &env,
        ));
        dirs.push(d);
    }
    let bases: Vec<String> = procs.iter().map(|p| p.base.clone()).collect();
    let (dataset, job) = prepare(&bases, Some(&token), dirs[0].path());
    Profile {
        name: "3 replicas (PostgreSQL + S3/moto)",
        procs,
        token: Some(token),
        dataset,
        job,
        _dirs: dirs,
    }
}

/// Wait (up to 10 minutes) until the queue is empty.
fn drain(bases: &[String], token: Option<&str>) {
    let start = Instant::now();
    while start.elapsed() < Duration::from_secs(600) {
        let mut args = auth_args(token);
        args.push(format!("{}/metrics", bases[0]));
        let refs: Vec<&str> = args.iter().map(String::as_str).collect();
        let m = curl(&refs);
        let queued = m
            .lines()
            .find(|l| l.starts_with("caliper_jobs_queued"))
            .and_then(|l| l.split_whitespace().last())
            .and_then(|v| v.parse::<f64>().ok())
            .unwrap_or(0.0);
        if queued < 1.0 {
            break;
        }
        std::thread::sleep(Duration::from_millis(500));
    }
}

fn rows(p: &Profile) {
    let bases: Vec<String> = p.procs.iter().map(|x| x.base.clone()).collect();
    let token = p.token.as_deref();
    let conns = env_u64("BENCH_CONNS", 64);
    let reads = wrk(&bases, &format!("/v1/jobs/{}", p.job), token, None, conns);
    println!("| {} | GET /v1/jobs/{{id}} | {reads} |", p.name);
    // Submissions: wrk posts the same small job body; the replicas run the jobs meanwhile.
    let script = tempfile::NamedTempFile::new().expect("script");
    writeln!(
        script.as_file(),
        "wrk.method = \"POST\"\nwrk.body = '{{\"kind\":\"blur_score\",\"dataset\":\"{}\"}}'\nwrk.headers[\"Content-Type\"] = \"application/json\"",
        p.dataset
    )
    .expect("script");
    let subs = wrk(&bases, "/v1/jobs", token, Some(script.path()), conns);
    println!(
        "| {} | POST /v1/jobs (jobs queued and run), {conns} connections | {subs} |",
        p.name
    );
    // With many connections a closed-loop client measures its own queue (latency ≈
    // connections / throughput); the latency of a submission at a given rate needs few.
    drain(&bases, token);
    let few = env_u64("BENCH_POST_CONNS", 6);
    let subs = wrk(&bases, "/v1/jobs", token, Some(script.path()), few);
    println!(
        "| {} | POST /v1/jobs (jobs queued and run), {few} connections | {subs} |",
        p.name
    );
    // Let the backlog drain before measuring wake-up latency on idle workers.
    drain(&bases, token);
    let mut lat = Vec::new();
    for i in 0..30 {
        let base = &bases[i % bases.len()];
        let (id, _) = submit(base, token, &p.dataset);
        let j = wait_status(&bases[(i + 1) % bases.len()], token, &id, "succeeded");
        // Both stamps come from the service clocks of one machine (ms).
        let created = chrono_ms(&j["created_at"]);
        let started = chrono_ms(&j["started_at"]);
        if let (Some(c), Some(s)) = (created, started) {
            lat.push(s - c);
        }
    }
    lat.sort_unstable();
    let p50 = lat.get(lat.len() / 2).copied().unwrap_or(-1);
    let p90 = lat.get(lat.len() * 9 / 10).copied().unwrap_or(-1);
    println!(
        "| {} | submit → running, idle workers, {} jobs | p50 {p50} ms, p90 {p90} ms |",
        p.name,
        lat.len()
    );
}

/// Milliseconds of an RFC 3339 UTC time `YYYY-MM-DDTHH:MM:SS.mmmZ` since midnight (enough for
/// differences within a run).
fn chrono_ms(v: &Value) -> Option<i64> {
    let s = v.as_str()?;
    let t = s.split('T').nth(1)?.trim_end_matches('Z');
    let mut parts = t.split(':');
    let h: i64 = parts.next()?.parse().ok()?;
    let m: i64 = parts.next()?.parse().ok()?;
    let sec: f64 = parts.next()?.parse().ok()?;
    Some(h * 3_600_000 + m * 60_000 + (sec * 1000.0).round() as i64)
}

fn upload_row(p: &Profile) {
    let mb = env_u64("BENCH_UPLOAD_MB", 1024);
    let dir = tempfile::tempdir().expect("dir");
    // A long IMU log (uploads are checked at the door: a clip must be a real one, a log
    // needs numeric rows), written in 1 MiB pieces.
    let big = dir.path().join("imu0.csv");
    {
        let mut f = std::io::BufWriter::new(std::fs::File::create(&big).expect("create"));
        f.write_all(b"#timestamp [ns],wx,wy,wz,ax,ay,az\n")
            .expect("write");
        let (mut written, mut t) = (0u64, 1_403_636_579_758_555_392u64);
        let mut piece = String::with_capacity(1 << 20);
        while written < mb << 20 {
            piece.clear();
            while piece.len() < (1 << 20) - 80 {
                piece.push_str(&format!("{t},0.0012,-0.0034,0.0021,0.081,-0.132,9.806\n"));
                t += 5_000_000;
            }
            f.write_all(piece.as_bytes()).expect("write");
            written += piece.len() as u64;
        }
    }
    let target = &p.procs[2];
    let before = vm_hwm_mib(target.child.id());
    let mut args = auth_args(p.token.as_deref());
    args.extend([
        "-F".into(),
        format!("file=@{}", big.display()),
        format!("{}/v1/datasets", target.base),
    ]);
    let refs: Vec<&str> = args.iter().map(String::as_str).collect();
    let t0 = Instant::now();
    let resp = curl(&refs);
    let secs = t0.elapsed().as_secs_f64();
    let peak = vm_hwm_mib(target.child.id());
    println!(
        "| {} | upload {mb} MiB to S3 ({}) | {secs:.1} s ({:.0} MiB/s); replica peak RSS {peak:.1} MiB (before {before:.1}) |",
        p.name,
        if resp.contains("\"kind\":\"imu_log\"") {
            "accepted"
        } else {
            "FAILED"
        },
        mb as f64 / secs
    );
}
