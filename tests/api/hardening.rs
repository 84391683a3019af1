//! What a hostile client found (issue "Hardening"): a parameter value that hung a worker, a
//! job body that ignores its stop request, a delete racing a re-upload of the same bytes, and
//! shutdowns that burned the retry budget.

use std::process::Command;
use std::time::{Duration, Instant};

use serde_json::json;

use crate::common::*;

#[tokio::test]
async fn a_huge_laplacian_threshold_is_refused_at_the_edge() {
    let s = start().await;
    let ds = s.dataset(vec![("a.png", png(&sharp_image(64, 64)))]).await;
    for t in [1e308, 9e307, 1e10] {
        let (status, p) = s
            .post_json(
                "/v1/jobs",
                &json!({"kind": "blur_score", "dataset": ds, "params": {"laplacian_threshold": t}}),
            )
            .await;
        assert_eq!(status, 422, "{t}: {p}");
        assert_eq!(p["code"], "invalid_param");
        assert_eq!(p["field"], "params.laplacian_threshold", "{p}");
    }
    // The largest accepted value runs to completion (the plot's axes stay finite).
    let id = s
        .job(json!({"kind": "blur_score", "dataset": ds, "params": {"laplacian_threshold": 1e9}}))
        .await;
    let j = s.wait_terminal(&id).await;
    assert_eq!(j["status"], "succeeded", "{j}");
    s.stop().await;
}

#[test]
fn a_huge_laplacian_threshold_is_refused_offline() {
    let dir = tempfile::tempdir().unwrap();
    let img = dir.path().join("good.png");
    std::fs::write(&img, png(&sharp_image(64, 64))).unwrap();
    let out = Command::new(caliper_bin())
        .args(["run", "blur-score", "--laplacian-threshold", "1e308"])
        .arg(&img)
        .output()
        .expect("run caliper");
    assert_eq!(out.status.code(), Some(2), "{out:?}");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("laplacian_threshold"), "{err}");
}

#[tokio::test]
async fn a_job_that_never_returns_is_failed_at_its_time_limit_and_its_slot_reused() {
    let s = start_with(|c| {
        c.workers = 1;
        c.debug_job_kinds = true;
        c.job_time_limit_secs = 1;
        c.job_abandon_secs = 1;
    })
    .await;
    let ds = s.dataset(vec![("a.png", png(&sharp_image(64, 64)))]).await;
    let hang = s.job(json!({"kind": "debug_hang", "dataset": ds})).await;
    let j = s
        .wait_for(&hang, Duration::from_secs(20), |j| j["status"] == "failed")
        .await;
    assert_eq!(j["error"]["code"], "time_limit_exceeded", "{j}");
    // The only worker is free again: a real job runs.
    let ok = s.job(json!({"kind": "blur_score", "dataset": ds})).await;
    let j = s.wait_terminal(&ok).await;
    assert_eq!(j["status"], "succeeded", "{j}");
    // A cancel of a job that ignores it takes effect within the abandon window.
    let hang = s.job(json!({"kind": "debug_hang", "dataset": ds})).await;
    s.wait_for(&hang, Duration::from_secs(20), |j| j["status"] == "running")
        .await;
    let (status, _) = s
        .post_json(&format!("/v1/jobs/{hang}/cancel"), &json!({}))
        .await;
    assert_eq!(status, 202);
    let j = s
        .wait_for(&hang, Duration::from_secs(10), |j| {
            j["status"] == "canceled"
        })
        .await;
    assert_eq!(j["status"], "canceled");
    s.stop().await;
}

#[test]
fn sigterm_exits_within_the_grace_period_whatever_a_job_does() {
    let dir = tempfile::tempdir().unwrap();
    let mut proc = spawn_caliper(
        &caliper_bin(),
        &dir.path().join("data"),
        &["--debug-job-kinds", "--shutdown-grace-secs", "2"],
    );
    let base = proc.base.clone();
    let rt = tokio::runtime::Runtime::new().unwrap();
    let client = reqwest::Client::new();
    let id = rt.block_on(async {
        let form = reqwest::multipart::Form::new().part(
            "file",
            reqwest::multipart::Part::bytes(png(&sharp_image(64, 64))).file_name("a.png"),
        );
        let ds: serde_json::Value = client
            .post(format!("{base}/v1/datasets"))
            .multipart(form)
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap();
        let job: serde_json::Value = client
            .post(format!("{base}/v1/jobs"))
            .json(&json!({"kind": "debug_hang", "dataset": ds["id"]}))
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap();
        let id = job["id"].as_str().unwrap().to_string();
        let deadline = Instant::now() + Duration::from_secs(20);
        loop {
            let j: serde_json::Value = client
                .get(format!("{base}/v1/jobs/{id}"))
                .send()
                .await
                .unwrap()
                .json()
                .await
                .unwrap();
            if j["status"] == "running" {
                break;
            }
            assert!(Instant::now() < deadline, "never ran: {j}");
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        id
    });
    let t0 = Instant::now();
    Command::new("kill")
        .args(["-TERM", &proc.child.id().to_string()])
        .status()
        .unwrap();
    let status = loop {
        if let Some(st) = proc.child.try_wait().unwrap() {
            break st;
        }
        if t0.elapsed() > Duration::from_secs(6) {
            let _ = proc.child.kill();
            panic!(
                "still alive {:?} after SIGTERM with a 2 s grace",
                t0.elapsed()
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let took = t0.elapsed();
    assert!(status.success(), "{status}");
    assert!(took < Duration::from_millis(3000), "took {took:?}");
    // The job went back to the queue without losing an attempt.
    let job = rt.block_on(async {
        use caliper_service::store::JobQueue;
        let store = caliper_service::store::SqliteStore::open(&dir.path().join("data/caliper.db"))
            .await
            .expect("open store");
        store
            .get_job(id.parse().unwrap())
            .await
            .unwrap()
            .expect("job")
    });
    assert_eq!(job.status.as_str(), "queued");
    assert_eq!((job.attempt, job.max_attempts), (1, 4), "{job:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 4)]
async fn a_delete_racing_a_reupload_of_the_same_bytes_loses_nothing() {
    let s = start().await;
    let blobs = s.dir.path().join("data/blobs/sha256");
    let mut lost = 0;
    for i in 0..60 {
        let body = format!("#t,gx,gy,gz,ax,ay,az\n{i},0.1,0.2,0.3,0,0,9.8\n").into_bytes();
        let sha = caliper_service::document::sha256_hex(&body);
        let first = s.dataset(vec![("u.csv", body.clone())]).await;
        let del = s
            .client
            .delete(s.url(&format!("/v1/datasets/{first}")))
            .send();
        let (r, (status, again, _)) = tokio::join!(del, s.upload(vec![("u.csv", body)]));
        assert_eq!(r.unwrap().status(), 204);
        assert_eq!(status, 201, "{again}");
        let path = blobs.join(&sha[0..2]).join(&sha[2..4]).join(&sha);
        if !path.exists() {
            lost += 1;
        }
        // The surviving dataset is readable by a job.
        let (st, ds) = s
            .get_json(&format!("/v1/datasets/{}", again["id"].as_str().unwrap()))
            .await;
        assert_eq!(st, 200, "{ds}");
    }
    assert_eq!(lost, 0, "blobs lost in 60 delete/re-upload races");
    s.stop().await;
}

/// D3: event streams end with their clients, and one watcher serves all clients of a job.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn event_streams_end_with_their_clients() {
    use futures_util::StreamExt;
    let s = start_with(|c| {
        c.workers = 1;
        c.debug_job_kinds = true;
        c.sse_keepalive_secs = 1;
    })
    .await;
    let ds = s.dataset(vec![("a.png", png(&sharp_image(64, 64)))]).await;
    let hang = s.job(json!({"kind": "debug_hang", "dataset": ds})).await;
    s.wait_for(&hang, Duration::from_secs(20), |j| j["status"] == "running")
        .await;
    let state = s.server.as_ref().expect("server").state.clone();
    let mut streams = Vec::new();
    for _ in 0..20 {
        let r = s
            .client
            .get(s.url(&format!("/v1/jobs/{hang}/events")))
            .send()
            .await
            .expect("events");
        assert_eq!(r.status(), 200);
        let mut body = r.bytes_stream();
        let first = body.next().await.expect("a first event").expect("bytes");
        assert!(String::from_utf8_lossy(&first).contains("running"));
        streams.push(body);
    }
    assert_eq!(
        caliper_service::job_watch::active(&state),
        1,
        "one watcher per job"
    );
    drop(streams);
    // The keep-alive (1 s here) finds the closed connections; the watcher then ends.
    let t0 = Instant::now();
    while caliper_service::job_watch::active(&state) != 0 {
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "watcher outlived its clients"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let _ = s
        .post_json(&format!("/v1/jobs/{hang}/cancel"), &json!({}))
        .await;
    s.stop().await;
}

/// D4: invented HTTP methods do not become metric label values.
#[tokio::test]
async fn invented_methods_do_not_grow_the_metrics() {
    let s = start().await;
    for i in 0..30 {
        let m = reqwest::Method::from_bytes(format!("INVENTED{i}").as_bytes()).unwrap();
        let _ = s.client.request(m, s.url("/v1/jobs")).send().await;
    }
    let text = s
        .client
        .get(s.url("/metrics"))
        .send()
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    assert!(
        !text.contains("INVENTED"),
        "method names leaked into labels"
    );
    assert!(text.contains("method=\"other\""), "{text}");
    s.stop().await;
}

/// D5: a declared oversize body is refused before any byte of it is read; trickled headers
/// and stalled bodies are cut off.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn slow_and_oversize_requests_are_cut_off() {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let s = start_with(|c| {
        c.header_timeout_secs = 1;
        c.body_timeout_secs = 1;
        c.max_upload_bytes = 1 << 20;
    })
    .await;
    let addr = s.base.trim_start_matches("http://").to_string();
    let read_all = |mut c: tokio::net::TcpStream| async move {
        let mut out = Vec::new();
        let r = tokio::time::timeout(Duration::from_secs(6), c.read_to_end(&mut out)).await;
        (r.is_ok(), String::from_utf8_lossy(&out).to_string())
    };
    // Declared 2 GiB, nothing sent: 413 at once.
    let mut c = tokio::net::TcpStream::connect(&addr).await.unwrap();
    c.write_all(
        b"POST /v1/datasets HTTP/1.1\r\nhost: x\r\ncontent-type: multipart/form-data; boundary=b\r\ncontent-length: 2147483648\r\n\r\nabc",
    )
    .await
    .unwrap();
    let t0 = Instant::now();
    let (closed, text) = read_all(c).await;
    assert!(closed, "connection left open");
    assert!(text.starts_with("HTTP/1.1 413"), "{text}");
    assert!(text.contains("payload_too_large"), "{text}");
    assert!(t0.elapsed() < Duration::from_secs(3));
    // Headers trickled and never finished: closed after the header timeout.
    let mut c = tokio::net::TcpStream::connect(&addr).await.unwrap();
    c.write_all(b"GET /healthz HTTP/1.1\r\nhost: x\r\n")
        .await
        .unwrap();
    let t0 = Instant::now();
    let (closed, _) = read_all(c).await;
    assert!(closed, "trickling client kept its connection");
    assert!(t0.elapsed() < Duration::from_secs(5), "{:?}", t0.elapsed());
    // A body that stalls: the request ends after the body timeout.
    let mut c = tokio::net::TcpStream::connect(&addr).await.unwrap();
    c.write_all(
        b"POST /v1/jobs HTTP/1.1\r\nhost: x\r\ncontent-type: application/json\r\ncontent-length: 100\r\n\r\n{\"ki",
    )
    .await
    .unwrap();
    let t0 = Instant::now();
    let (closed, text) = read_all(c).await;
    assert!(closed, "stalled body kept its connection");
    assert!(t0.elapsed() < Duration::from_secs(5), "{:?}", t0.elapsed());
    assert!(!text.contains(" 5"), "no 5xx for a stalled body: {text}");
    // And the server still answers.
    let (st, _) = s.get_json("/healthz").await;
    assert_eq!(st, 200);
    s.stop().await;
}

fn png_of(w: u32, h: u32) -> Vec<u8> {
    let img = image::ImageBuffer::from_fn(w, h, |x, y| image::Luma([((x + y) % 256) as u8]));
    png(&img)
}

/// D6, D9, D10, D11: uploads the issue found accepted or mangled.
#[tokio::test]
async fn hostile_uploads_are_refused_with_their_code() {
    let s = start().await;
    let corpus = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../core/fuzz/corpus/zip");
    let mut padded = png_of(64, 64);
    padded.extend(std::iter::repeat_n(0x5a_u8, 6 << 20));
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("padded.png", padded, "trailing_data"),
        ("wide.png", png_of(20_000, 2), "image_too_large"),
        (
            "dup.zip",
            std::fs::read(corpus.join("duplicate.zip")).unwrap(),
            "duplicate_name",
        ),
        (
            "abs.zip",
            std::fs::read(corpus.join("absolute.zip")).unwrap(),
            "zip_unsafe_path",
        ),
    ];
    for (name, bytes, code) in cases {
        let (st, p, ct) = s.upload(vec![(name, bytes)]).await;
        assert_eq!(st, 422, "{name}: {p}");
        assert_eq!(p["code"], code, "{name}: {p}");
        assert!(ct.starts_with("application/problem+json"));
    }
    assert_eq!(
        count_files(&s.dir.path().join("data/blobs")),
        0,
        "nothing stored"
    );
    s.stop().await;
}

/// D12, D13: kernels of huge values are normalised at the edge; gyro errors name their path.
#[tokio::test]
async fn deblur_parameters_are_checked_at_the_edge() {
    let s = start().await;
    let ds = s.dataset(vec![("a.png", png(&sharp_image(64, 64)))]).await;
    let (st, job) = s
        .post_json(
            "/v1/jobs",
            &json!({"kind": "deblur", "dataset": ds, "params": {"method": "wiener",
                "psf": {"width": 3, "height": 1, "data": [1e308, 1e308, 1e308]}}}),
        )
        .await;
    assert_eq!(st, 202, "{job}");
    let data = job["params"]["psf"]["data"].as_array().expect("kernel");
    for v in data {
        assert!((v.as_f64().unwrap() - 1.0 / 3.0).abs() < 1e-12, "{job}");
    }
    let j = s.wait_terminal(job["id"].as_str().unwrap()).await;
    assert_eq!(j["status"], "succeeded", "{j}");
    let gyro = json!({"samples": [{"t": 0.0, "w": [0, 0, 0]}, {"t": 0.1, "w": [0, 0, 0]}],
        "exposure_start_s": 0.0, "exposure_s": 0.05, "fx": -1.0, "fy": 500.0, "cx": 32.0, "cy": 32.0});
    let (st, p) = s
        .post_json(
            "/v1/jobs",
            &json!({"kind": "deblur", "dataset": ds, "params": {"method": "gyro", "gyro": gyro}}),
        )
        .await;
    assert_eq!(st, 422, "{p}");
    assert_eq!(p["field"], "params.gyro.fx", "{p}");
    s.stop().await;
}
