//! Shared helpers: an in-process server on a temporary data directory, synthetic images,
//! and upload/poll helpers.

use std::io::Cursor;
use std::path::PathBuf;
use std::process::Command;
use std::time::{Duration, Instant};

use caliper_service::config::Config;
use caliper_service::server::Server;
use image::{ImageBuffer, ImageFormat, Luma};
use reqwest::multipart::{Form, Part};
use serde_json::Value;

pub struct TestServer {
    pub base: String,
    pub client: reqwest::Client,
    pub server: Option<Server>,
    pub dir: tempfile::TempDir,
    /// The PostgreSQL database of this server (production profile runs).
    pub db: Option<crate::postgres::TestDb>,
}

/// Whether this run exercises the production profile: `CALIPER_TEST_PROFILE=postgres` runs
/// every in-process server of the suite on its own fresh PostgreSQL database (from
/// `CALIPER_TEST_POSTGRES_URL`) instead of SQLite, so the same black-box tests cover both.
pub fn postgres_profile() -> bool {
    std::env::var("CALIPER_TEST_PROFILE").is_ok_and(|p| p == "postgres")
}

/// A server with fast heartbeats, on a fresh data directory.
pub async fn start() -> TestServer {
    start_with(|_| {}).await
}

pub async fn start_with(tweak: impl FnOnce(&mut Config)) -> TestServer {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut cfg = Config {
        listen: "127.0.0.1:0".parse().expect("addr"),
        data_dir: dir.path().join("data"),
        workers: 2,
        heartbeat_ms: 100,
        lease_secs: 5,
        backoff_base_ms: 50,
        backoff_cap_ms: 200,
        // Deletions are observable at once (the default keeps blobs a minute for downloads).
        blob_gc_grace_secs: 0,
        ..Config::default()
    };
    let db = if postgres_profile() {
        let db = crate::postgres::TestDb::create()
            .await
            .expect("CALIPER_TEST_PROFILE=postgres needs CALIPER_TEST_POSTGRES_URL");
        cfg.database_url = db.url.clone();
        // The suite's open requests stay open; tests that want tokens set `auth`.
        cfg.insecure_no_auth = true;
        Some(db)
    } else {
        None
    };
    tweak(&mut cfg);
    let server = caliper_service::server::start(cfg)
        .await
        .expect("server starts");
    TestServer {
        base: format!("http://{}", server.addr),
        // No connection reuse: a server that answers early (413) closes that connection, and
        // a pooled client would then fail its next request for a reason that is not the API's.
        client: reqwest::Client::builder()
            .pool_max_idle_per_host(0)
            .build()
            .expect("client"),
        server: Some(server),
        dir,
        db,
    }
}

impl TestServer {
    pub fn url(&self, path: &str) -> String {
        format!("{}{}", self.base, path)
    }

    pub async fn get_json(&self, path: &str) -> (u16, Value) {
        let r = self
            .client
            .get(self.url(path))
            .send()
            .await
            .expect("request");
        let status = r.status().as_u16();
        (status, r.json().await.unwrap_or(Value::Null))
    }

    pub async fn post_json(&self, path: &str, body: &Value) -> (u16, Value) {
        let r = self
            .client
            .post(self.url(path))
            .json(body)
            .send()
            .await
            .expect("request");
        let status = r.status().as_u16();
        (status, r.json().await.unwrap_or(Value::Null))
    }

    /// Upload files (name, bytes); returns (status, body).
    pub async fn upload(&self, files: Vec<(&str, Vec<u8>)>) -> (u16, Value, String) {
        let mut form = Form::new();
        for (name, bytes) in files {
            form = form.part("file", Part::bytes(bytes).file_name(name.to_string()));
        }
        let r = self
            .client
            .post(self.url("/v1/datasets"))
            .multipart(form)
            .send()
            .await
            .expect("request");
        let status = r.status().as_u16();
        let ct = r
            .headers()
            .get("content-type")
            .and_then(|v| v.to_str().ok())
            .unwrap_or("")
            .to_string();
        (status, r.json().await.unwrap_or(Value::Null), ct)
    }

    /// Upload and return the dataset id, asserting success.
    pub async fn dataset(&self, files: Vec<(&str, Vec<u8>)>) -> String {
        let (status, body, _) = self.upload(files).await;
        assert_eq!(status, 201, "upload failed: {body}");
        body["id"].as_str().expect("id").to_string()
    }

    /// Queue a job, asserting 202; returns its id.
    pub async fn job(&self, body: Value) -> String {
        let (status, job) = self.post_json("/v1/jobs", &body).await;
        assert_eq!(status, 202, "job not accepted: {job}");
        job["id"].as_str().expect("id").to_string()
    }

    /// Poll a job until `done(job)` or the timeout.
    pub async fn wait_for(
        &self,
        id: &str,
        timeout: Duration,
        done: impl Fn(&Value) -> bool,
    ) -> Value {
        let start = Instant::now();
        loop {
            let (status, job) = self.get_json(&format!("/v1/jobs/{id}")).await;
            assert_eq!(status, 200, "{job}");
            if done(&job) {
                return job;
            }
            assert!(
                start.elapsed() < timeout,
                "timed out waiting; last state {job}"
            );
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }

    pub async fn wait_terminal(&self, id: &str) -> Value {
        self.wait_for(id, Duration::from_secs(60), |j| {
            matches!(
                j["status"].as_str(),
                Some("succeeded" | "failed" | "canceled")
            )
        })
        .await
    }

    pub async fn stop(mut self) {
        if let Some(s) = self.server.take() {
            s.shutdown(Duration::from_secs(5)).await;
        }
        if let Some(db) = self.db.take() {
            db.drop_db().await;
        }
    }
}

/// A sharp synthetic scene: a checkerboard with fine texture (deterministic).
pub fn sharp_image(w: u32, h: u32) -> ImageBuffer<Luma<u8>, Vec<u8>> {
    let mut seed: u32 = 12345;
    ImageBuffer::from_fn(w, h, |x, y| {
        seed = seed.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
        let checker = if ((x / 16) + (y / 16)) % 2 == 0 {
            200.0
        } else {
            55.0
        };
        let texture = ((seed >> 24) as f64 - 128.0) * 0.2;
        Luma([(checker + texture).clamp(0.0, 255.0) as u8])
    })
}

/// The same image blurred by a k×k box kernel (clamped borders).
pub fn box_blur(img: &ImageBuffer<Luma<u8>, Vec<u8>>, k: i64) -> ImageBuffer<Luma<u8>, Vec<u8>> {
    let (w, h) = img.dimensions();
    let r = k / 2;
    ImageBuffer::from_fn(w, h, |x, y| {
        let mut sum = 0.0;
        for dy in -r..=r {
            for dx in -r..=r {
                let xx = (x as i64 + dx).clamp(0, w as i64 - 1) as u32;
                let yy = (y as i64 + dy).clamp(0, h as i64 - 1) as u32;
                sum += img.get_pixel(xx, yy)[0] as f64;
            }
        }
        Luma([(sum / (k * k) as f64).round() as u8])
    })
}

pub fn png(img: &ImageBuffer<Luma<u8>, Vec<u8>>) -> Vec<u8> {
    let mut out = Cursor::new(Vec::new());
    img.write_to(&mut out, ImageFormat::Png).expect("png");
    out.into_inner()
}

pub fn jpeg(img: &ImageBuffer<Luma<u8>, Vec<u8>>) -> Vec<u8> {
    let mut out = Cursor::new(Vec::new());
    img.write_to(&mut out, ImageFormat::Jpeg).expect("jpeg");
    out.into_inner()
}

/// A dataset whose blur scoring takes a few seconds: `n` copies (deduplicated in storage)
/// of one large image.
pub fn slow_dataset(n: usize) -> Vec<(String, Vec<u8>)> {
    let big = png(&sharp_image(1024, 768));
    (0..n)
        .map(|i| (format!("frame{i:03}.png"), big.clone()))
        .collect()
}

pub fn as_refs(files: &[(String, Vec<u8>)]) -> Vec<(&str, Vec<u8>)> {
    files.iter().map(|(n, b)| (n.as_str(), b.clone())).collect()
}

/// Count regular files under a directory, recursively.
pub fn count_files(dir: &std::path::Path) -> usize {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return 0;
    };
    rd.flatten()
        .map(|e| {
            let p = e.path();
            if p.is_dir() { count_files(&p) } else { 1 }
        })
        .sum()
}

/// The `caliper` binary next to this test's build output, built if missing.
pub fn caliper_bin() -> PathBuf {
    if let Ok(p) = std::env::var("CALIPER_BIN") {
        return PathBuf::from(p);
    }
    let exe = std::env::current_exe().expect("current exe");
    let profile_dir = exe.parent().and_then(|d| d.parent()).expect("target dir");
    let bin = profile_dir.join("caliper");
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let mut cmd = Command::new(cargo);
    cmd.args(["build", "-p", "caliper-service", "--bin", "caliper"]);
    if profile_dir.file_name().is_some_and(|n| n == "release") {
        cmd.arg("--release");
    }
    // Always (re)build: cargo is a no-op when the binary is fresh.
    let status = cmd.status().expect("cargo build");
    assert!(status.success(), "building the caliper binary failed");
    assert!(bin.exists(), "no binary at {}", bin.display());
    bin
}

/// A `caliper serve` process on `127.0.0.1:0`, killed when dropped (a failing assertion must
/// not leave a server running).
pub struct Proc {
    pub child: std::process::Child,
    pub base: String,
}

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Start `bin serve` on `data` with one worker, fast heartbeats and `extra` flags; returns once
/// it listens.
pub fn spawn_caliper(bin: &std::path::Path, data: &std::path::Path, extra: &[&str]) -> Proc {
    spawn_caliper_env(bin, data, extra, &[])
}

/// [`spawn_caliper`] with extra environment variables (e.g. `AWS_*` for S3 blobs).
pub fn spawn_caliper_env(
    bin: &std::path::Path,
    data: &std::path::Path,
    extra: &[&str],
    env: &[(&str, &str)],
) -> Proc {
    use std::io::BufRead;
    let mut child = Command::new(bin)
        .args([
            "serve",
            "--listen",
            "127.0.0.1:0",
            "--workers",
            "1",
            "--heartbeat-ms",
            "100",
        ])
        .args(extra)
        .arg("--data-dir")
        .arg(data)
        .env("RUST_LOG", "warn")
        .envs(env.iter().copied())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::inherit())
        .spawn()
        .expect("spawn caliper");
    let mut line = String::new();
    std::io::BufReader::new(child.stdout.take().expect("stdout"))
        .read_line(&mut line)
        .expect("read line");
    let base = line
        .trim()
        .strip_prefix("caliper listening on ")
        .unwrap_or_else(|| panic!("unexpected first line {line:?}"))
        .to_string();
    Proc { child, base }
}
