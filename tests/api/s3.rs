//! Blobs in S3: a real S3-compatible server on loopback (moto, started by `.ci/run`, whose
//! address is in `CALIPER_TEST_S3_ENDPOINT`). Without it the tests say loudly that they did
//! not run.

use std::time::{Duration, Instant};

use serde_json::{Value, json};

use crate::common::*;

/// The endpoint, and a fresh bucket on it.
pub(crate) async fn bucket() -> Option<(String, String)> {
    let Some(endpoint) = std::env::var("CALIPER_TEST_S3_ENDPOINT")
        .ok()
        .filter(|u| !u.is_empty())
    else {
        eprintln!(
            "\n*** S3 tests NOT RUN: set CALIPER_TEST_S3_ENDPOINT to an S3-compatible server \
             (.ci/run starts moto and sets it) ***\n"
        );
        return None;
    };
    let name = format!(
        "caliper-{}",
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos())
            .unwrap_or(0)
    );
    let r = reqwest::Client::new()
        .put(format!("{endpoint}/{name}"))
        .send()
        .await
        .expect("create bucket");
    assert!(r.status().is_success(), "create bucket: {}", r.status());
    Some((endpoint, name))
}

/// Keys under `prefix` in the bucket (S3 ListObjectsV2, unsigned: moto accepts it).
pub(crate) async fn keys(endpoint: &str, bucket: &str, prefix: &str) -> Vec<String> {
    let text = reqwest::get(format!("{endpoint}/{bucket}?list-type=2&prefix={prefix}"))
        .await
        .expect("list")
        .text()
        .await
        .expect("body");
    text.split("<Key>")
        .skip(1)
        .filter_map(|s| s.split("</Key>").next())
        .map(str::to_owned)
        .collect()
}

pub(crate) fn aws_env(endpoint: &str) -> Vec<(&'static str, String)> {
    vec![
        ("AWS_ENDPOINT", endpoint.to_owned()),
        ("AWS_ALLOW_HTTP", "true".into()),
        ("AWS_ACCESS_KEY_ID", "test".into()),
        ("AWS_SECRET_ACCESS_KEY", "test".into()),
        ("AWS_REGION", "us-east-1".into()),
    ]
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn uploads_and_artifacts_live_in_s3_and_are_collected() {
    let Some((endpoint, bucket)) = bucket().await else {
        return;
    };
    let data = tempfile::tempdir().expect("data");
    let url = format!("s3://{bucket}/fleet-a");
    let env = aws_env(&endpoint);
    let env_refs: Vec<(&str, &str)> = env.iter().map(|(k, v)| (*k, v.as_str())).collect();
    let server = spawn_caliper_env(
        &caliper_bin(),
        data.path(),
        &["--blob-url", &url, "--blob-gc-grace-secs", "0"],
        &env_refs,
    );
    let base = server.base.clone();
    let c = reqwest::Client::new();

    // A large-ish upload streams to S3 in parts; the dataset answers with the same bytes.
    let big = png(&sharp_image(1600, 1200));
    let form = reqwest::multipart::Form::new().part(
        "file",
        reqwest::multipart::Part::bytes(big.clone()).file_name("big.png"),
    );
    let ds: Value = c
        .post(format!("{base}/v1/datasets"))
        .multipart(form)
        .send()
        .await
        .expect("upload")
        .json()
        .await
        .expect("json");
    let ds_id = ds["id"].as_str().expect("id").to_owned();
    let sha = ds["files"][0]["sha256"].as_str().expect("sha").to_owned();
    let stored = keys(&endpoint, &bucket, "fleet-a/").await;
    assert!(stored.iter().any(|k| k.ends_with(&sha)), "{stored:?}");
    let back = c
        .get(format!("{base}/v1/datasets/{ds_id}/files/0"))
        .send()
        .await
        .expect("file")
        .bytes()
        .await
        .expect("bytes");
    assert_eq!(back.to_vec(), big);

    // A job reads its input from S3 and writes its artifacts there.
    let job: Value = c
        .post(format!("{base}/v1/jobs"))
        .json(&json!({"kind": "blur_score", "dataset": ds_id}))
        .send()
        .await
        .expect("job")
        .json()
        .await
        .expect("json");
    let id = job["id"].as_str().expect("id").to_owned();
    let start = Instant::now();
    let done = loop {
        let j: Value = c
            .get(format!("{base}/v1/jobs/{id}"))
            .send()
            .await
            .expect("get")
            .json()
            .await
            .expect("json");
        if j["status"] != "queued" && j["status"] != "running" {
            break j;
        }
        assert!(start.elapsed() < Duration::from_secs(60), "{j}");
        tokio::time::sleep(Duration::from_millis(100)).await;
    };
    assert_eq!(done["status"], "succeeded", "{done}");
    let arts: Value = c
        .get(format!("{base}/v1/jobs/{id}/artifacts"))
        .send()
        .await
        .expect("artifacts")
        .json()
        .await
        .expect("json");
    let art = &arts["items"][0];
    let art_sha = art["sha256"].as_str().expect("artifact sha").to_owned();
    let stored = keys(&endpoint, &bucket, "fleet-a/").await;
    assert!(stored.iter().any(|k| k.ends_with(&art_sha)), "{stored:?}");

    // Deleting the dataset collects its blob from the bucket; the artifact stays.
    let r = c
        .delete(format!("{base}/v1/datasets/{ds_id}"))
        .send()
        .await
        .expect("delete");
    assert_eq!(r.status(), 204);
    let stored = keys(&endpoint, &bucket, "fleet-a/").await;
    assert!(!stored.iter().any(|k| k.ends_with(&sha)), "{stored:?}");
    assert!(stored.iter().any(|k| k.ends_with(&art_sha)), "{stored:?}");
    drop(server);
}
