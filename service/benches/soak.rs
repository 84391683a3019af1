//! Soak benchmark: mixed uploads, jobs, event-stream clients, cancels, deletes and re-uploads
//! of deleted bytes against the release `caliper` binary, with a `kill -9` and restart every
//! few minutes. Reports whether RSS, file descriptors, temporary files and blob count return to
//! baseline, and checks that no document is lost or duplicated: every succeeded job with a
//! device has exactly one document revision, and no revision cites a job twice.
//!
//! Run: `cargo bench -p caliper-service --bench soak`. Env: `SOAK_SECS` (default 1800),
//! `SOAK_KILL_SECS` (default 180, the time between kills), `SOAK_CLIENTS` (default 4),
//! `SOAK_BIN` (a `caliper` binary to use instead of building the release one).

use std::collections::{BTreeMap, BTreeSet};
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use rand::Rng;
use serde_json::{Value, json};
use tokio::sync::Mutex;

fn env_u64(name: &str, default: u64) -> u64 {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

struct Server {
    child: Child,
    base: String,
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn caliper_release() -> PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let status = Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()))
        .args([
            "build",
            "--release",
            "-q",
            "-p",
            "caliper-service",
            "--bin",
            "caliper",
        ])
        .current_dir(&root)
        .status()
        .expect("cargo build");
    assert!(status.success());
    let target =
        std::env::var("CARGO_TARGET_DIR").map_or_else(|_| root.join("target"), PathBuf::from);
    target.join("release/caliper")
}

fn start(bin: &Path, data: &Path) -> Server {
    let mut child = Command::new(bin)
        .args([
            "serve",
            "--listen",
            "127.0.0.1:0",
            "--workers",
            "2",
            "--heartbeat-ms",
            "200",
            "--lease-secs",
            "3",
            "--blob-gc-grace-secs",
            "0",
            "--sse-keepalive-secs",
            "2",
        ])
        .arg("--data-dir")
        .arg(data)
        .env("RUST_LOG", "error")
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("spawn caliper");
    let mut line = String::new();
    BufReader::new(child.stdout.take().expect("stdout"))
        .read_line(&mut line)
        .expect("first line");
    let base = line
        .trim()
        .strip_prefix("caliper listening on ")
        .expect("listening line")
        .to_string();
    Server { child, base }
}

/// (RSS MiB, open file descriptors) of a process.
fn usage(pid: u32) -> (f64, usize) {
    let rss = std::fs::read_to_string(format!("/proc/{pid}/status"))
        .ok()
        .and_then(|t| {
            t.lines()
                .find(|l| l.starts_with("VmRSS:"))
                .and_then(|l| l.split_whitespace().nth(1)?.parse::<f64>().ok())
        })
        .unwrap_or(0.0)
        / 1024.0;
    let fds = std::fs::read_dir(format!("/proc/{pid}/fd")).map_or(0, |d| d.count());
    (rss, fds)
}

fn count_files(dir: &Path) -> usize {
    std::fs::read_dir(dir).map_or(0, |d| {
        d.flatten()
            .map(|e| {
                let p = e.path();
                if p.is_dir() { count_files(&p) } else { 1 }
            })
            .sum()
    })
}

fn png(seed: u64) -> Vec<u8> {
    let img = image::ImageBuffer::from_fn(64, 64, |x, y| {
        image::Luma([((u64::from(x) * 7 + u64::from(y) * 13 + seed * 31) % 256) as u8])
    });
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png)
        .expect("png");
    out.into_inner()
}

#[derive(Default)]
struct Book {
    datasets: Vec<String>,
    /// Jobs queued with a device, by id.
    jobs: BTreeSet<String>,
    ops: BTreeMap<&'static str, u64>,
}

async fn client(
    base: Arc<Mutex<String>>,
    book: Arc<Mutex<Book>>,
    stop: Arc<AtomicBool>,
    errors: Arc<AtomicU64>,
) {
    let http = reqwest::Client::builder()
        .timeout(Duration::from_secs(20))
        .build()
        .expect("client");
    while !stop.load(Ordering::Relaxed) {
        let b = base.lock().await.clone();
        let op = rand::rng().random_range(0..100);
        let r: Result<&'static str, reqwest::Error> = async {
            if op < 30 {
                // Upload (seeds repeat: same bytes again and again, also after deletes).
                let mut form = reqwest::multipart::Form::new();
                for i in 0..3 {
                    let seed = rand::rng().random_range(0..40);
                    form = form.part(
                        "file",
                        reqwest::multipart::Part::bytes(png(seed)).file_name(format!("f{i}.png")),
                    );
                }
                let v: Value = http.post(format!("{b}/v1/datasets")).multipart(form).send().await?.json().await?;
                if let Some(id) = v["id"].as_str() {
                    book.lock().await.datasets.push(id.to_string());
                }
                Ok("upload")
            } else if op < 60 {
                let ds = {
                    let bk = book.lock().await;
                    if bk.datasets.is_empty() {
                        return Ok("idle");
                    }
                    bk.datasets[rand::rng().random_range(0..bk.datasets.len())].clone()
                };
                let body = json!({"kind": "blur_score", "dataset": ds, "device": "soak-dev", "sensor": "cam0"});
                let v: Value = http.post(format!("{b}/v1/jobs")).json(&body).send().await?.json().await?;
                if let Some(id) = v["id"].as_str() {
                    book.lock().await.jobs.insert(id.to_string());
                }
                Ok("job")
            } else if op < 75 {
                let job = {
                    let bk = book.lock().await;
                    bk.jobs.iter().nth(rand::rng().random_range(0..bk.jobs.len().max(1))).cloned()
                };
                if let Some(j) = job {
                    let r = http.get(format!("{b}/v1/jobs/{j}/events")).send().await?;
                    let mut s = r.bytes_stream();
                    use futures_util::StreamExt;
                    let _ = tokio::time::timeout(Duration::from_millis(300), s.next()).await;
                }
                Ok("events")
            } else if op < 85 {
                let job = {
                    let bk = book.lock().await;
                    bk.jobs.iter().nth(rand::rng().random_range(0..bk.jobs.len().max(1))).cloned()
                };
                if let Some(j) = job {
                    http.post(format!("{b}/v1/jobs/{j}/cancel")).json(&json!({})).send().await?;
                }
                Ok("cancel")
            } else {
                let ds = {
                    let mut bk = book.lock().await;
                    if bk.datasets.is_empty() {
                        return Ok("idle");
                    }
                    let i = rand::rng().random_range(0..bk.datasets.len());
                    bk.datasets.swap_remove(i)
                };
                let r = http.delete(format!("{b}/v1/datasets/{ds}")).send().await?;
                if r.status() == 409 {
                    book.lock().await.datasets.push(ds);
                }
                Ok("delete")
            }
        }
        .await;
        match r {
            Ok(op) => *book.lock().await.ops.entry(op).or_default() += 1,
            // Expected around kills: the server is briefly gone.
            Err(_) => {
                errors.fetch_add(1, Ordering::Relaxed);
                tokio::time::sleep(Duration::from_millis(200)).await;
            }
        }
    }
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() {
    let secs = env_u64("SOAK_SECS", 1800);
    let kill_every = env_u64("SOAK_KILL_SECS", 180);
    let clients = env_u64("SOAK_CLIENTS", 4);
    let bin = match std::env::var_os("SOAK_BIN") {
        Some(b) => PathBuf::from(b),
        None => tokio::task::spawn_blocking(caliper_release)
            .await
            .expect("build"),
    };
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    let mut server = start(&bin, &data);
    tokio::time::sleep(Duration::from_secs(1)).await;
    let (rss0, fds0) = usage(server.child.id());
    let base = Arc::new(Mutex::new(server.base.clone()));
    let book = Arc::new(Mutex::new(Book::default()));
    let stop = Arc::new(AtomicBool::new(false));
    let errors = Arc::new(AtomicU64::new(0));
    let tasks: Vec<_> = (0..clients)
        .map(|_| {
            tokio::spawn(client(
                base.clone(),
                book.clone(),
                stop.clone(),
                errors.clone(),
            ))
        })
        .collect();
    let t0 = Instant::now();
    let mut kills = 0;
    let mut peak_rss = rss0;
    let mut next_kill = Instant::now() + Duration::from_secs(kill_every);
    while t0.elapsed() < Duration::from_secs(secs) {
        tokio::time::sleep(Duration::from_secs(1)).await;
        peak_rss = peak_rss.max(usage(server.child.id()).0);
        if Instant::now() >= next_kill {
            // kill -9, then the same data directory again.
            let _ = server.child.kill();
            let _ = server.child.wait();
            kills += 1;
            server = start(&bin, &data);
            *base.lock().await = server.base.clone();
            next_kill = Instant::now() + Duration::from_secs(kill_every);
        }
    }
    stop.store(true, Ordering::Relaxed);
    for t in tasks {
        let _ = t.await;
    }
    // Let every job end, then measure the quiet server.
    let http = reqwest::Client::new();
    let b = server.base.clone();
    let jobs: Vec<String> = book.lock().await.jobs.iter().cloned().collect();
    let mut succeeded = BTreeSet::new();
    let deadline = Instant::now() + Duration::from_secs(600);
    for j in &jobs {
        loop {
            let v: Value = http
                .get(format!("{b}/v1/jobs/{j}"))
                .send()
                .await
                .expect("job")
                .json()
                .await
                .expect("json");
            match v["status"].as_str() {
                Some("succeeded") => {
                    succeeded.insert(j.clone());
                    break;
                }
                Some("failed" | "canceled") => break,
                _ if Instant::now() > deadline => panic!("job {j} never ended: {v}"),
                _ => tokio::time::sleep(Duration::from_millis(200)).await,
            }
        }
    }
    tokio::time::sleep(Duration::from_secs(10)).await;
    let pid = server.child.id();
    let (rss1, fds1) = usage(pid);
    let revs: Value = http
        .get(format!("{b}/v1/devices/soak-dev/documents/cam0/blur_score"))
        .send()
        .await
        .expect("revisions")
        .json()
        .await
        .expect("json");
    let mut cited = BTreeMap::<String, usize>::new();
    for r in revs.as_array().cloned().unwrap_or_default() {
        let rev = r["rev"].as_u64().unwrap_or(0);
        let d: Value = http
            .get(format!(
                "{b}/v1/devices/soak-dev/documents/cam0/blur_score/{rev}"
            ))
            .send()
            .await
            .expect("doc")
            .json()
            .await
            .expect("json");
        if let Some(j) = d["provenance"]["job"].as_str() {
            *cited.entry(j.to_string()).or_default() += 1;
        }
    }
    let duplicated = cited.values().filter(|&&n| n > 1).count();
    let lost = succeeded.iter().filter(|j| !cited.contains_key(*j)).count();
    // Blobs: every stored blob is referenced by a dataset or an artifact.
    let mut referenced = BTreeSet::new();
    let mut cursor: Option<String> = None;
    loop {
        let url = match &cursor {
            Some(c) => format!("{b}/v1/datasets?limit=100&cursor={c}"),
            None => format!("{b}/v1/datasets?limit=100"),
        };
        let page: Value = http
            .get(url)
            .send()
            .await
            .expect("datasets")
            .json()
            .await
            .expect("json");
        for d in page["items"].as_array().cloned().unwrap_or_default() {
            for f in d["files"].as_array().cloned().unwrap_or_default() {
                referenced.insert(f["sha256"].as_str().unwrap_or("").to_string());
            }
        }
        cursor = page["next_cursor"].as_str().map(String::from);
        if cursor.is_none() {
            break;
        }
    }
    for j in &jobs {
        let a: Value = http
            .get(format!("{b}/v1/jobs/{j}/artifacts"))
            .send()
            .await
            .expect("artifacts")
            .json()
            .await
            .expect("json");
        for x in a["items"].as_array().cloned().unwrap_or_default() {
            referenced.insert(x["sha256"].as_str().unwrap_or("").to_string());
        }
    }
    // Garbage collection runs every 30 s: give blobs orphaned by the last kill time to go.
    let gc_deadline = Instant::now() + Duration::from_secs(70);
    let mut blobs = count_files(&data.join("blobs/sha256"));
    while blobs != referenced.len() && Instant::now() < gc_deadline {
        tokio::time::sleep(Duration::from_secs(2)).await;
        blobs = count_files(&data.join("blobs/sha256"));
    }
    let tmp = count_files(&data.join("tmp"));
    let ops = book.lock().await.ops.clone();
    println!(
        "{}",
        serde_json::to_string_pretty(&json!({
            "seconds": secs, "kills": kills, "clients": clients, "ops": ops,
            "client_errors_around_kills": errors.load(Ordering::Relaxed),
            "jobs": jobs.len(), "succeeded_with_device": succeeded.len(),
            "documents": cited.len(), "lost_documents": lost, "duplicated_documents": duplicated,
            "rss_mib": {"first_start": rss0, "peak": peak_rss, "end_quiet": rss1},
            "fds": {"first_start": fds0, "end_quiet": fds1},
            "tmp_files_end": tmp, "blobs_on_disk": blobs, "blobs_referenced": referenced.len(),
        }))
        .unwrap_or_default()
    );
    assert_eq!(lost, 0, "lost documents");
    assert_eq!(duplicated, 0, "duplicated documents");
    assert_eq!(tmp, 0, "temporary files left");
    assert_eq!(
        blobs,
        referenced.len(),
        "blob count differs from the referenced set"
    );
}
