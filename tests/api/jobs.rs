//! Jobs: the blur_score round trip, idempotency, cancel, SSE, filters, the bounded queue and
//! time limits.

use std::time::Duration;

use futures_util::StreamExt;
use serde_json::{Value, json};

use crate::common::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn blur_score_round_trip_ranks_the_sharp_image_first() {
    let s = start().await;
    let sharp = sharp_image(320, 240);
    let blurred = box_blur(&sharp, 7);
    let ds = s
        .dataset(vec![
            ("blurred.png", png(&blurred)),
            ("sharp.png", png(&sharp)),
        ])
        .await;
    let (status, job) = s
        .post_json(
            "/v1/jobs",
            &json!({"kind": "blur_score", "dataset": ds, "params": {}}),
        )
        .await;
    assert_eq!(status, 202, "{job}");
    assert_eq!(job["status"], "queued");
    assert_eq!(job["params"]["k"], 10, "defaults are filled in: {job}");
    let id = job["id"].as_str().unwrap().to_string();
    let done = s.wait_terminal(&id).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    assert_eq!(done["attempt"], 1);

    let r = s
        .client
        .get(s.url(&format!("/v1/jobs/{id}/result")))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    let etag = r.headers()["etag"].to_str().unwrap().to_string();
    let doc: Value = r.json().await.unwrap();
    assert_eq!(doc["schema"], "caliper.blur_score/v1");
    assert_eq!(doc["provenance"]["job"], id.as_str());
    assert_eq!(doc["provenance"]["dataset"], ds.as_str());
    assert_eq!(format!("\"{}\"", doc["etag"].as_str().unwrap()), etag);
    assert!(
        caliper_service::document::verify(&doc),
        "etag matches content"
    );
    let images = doc["parameters"]["images"].as_array().unwrap();
    let by_name = |n: &str| images.iter().find(|i| i["name"] == n).unwrap().clone();
    let (sh, bl) = (by_name("sharp.png"), by_name("blurred.png"));
    assert!(
        sh["laplacian_variance"].as_f64().unwrap()
            > 5.0 * bl["laplacian_variance"].as_f64().unwrap(),
        "sharp {sh} vs blurred {bl}"
    );
    assert!(bl["svd_beta"].as_f64().unwrap() > sh["svd_beta"].as_f64().unwrap());
    assert_eq!(doc["parameters"]["ranking"][0], "sharp.png");
    assert_eq!(sh["rank"], 1);

    // The artifacts: an SVG plot and a blur map per image.
    let (status, arts) = s.get_json(&format!("/v1/jobs/{id}/artifacts")).await;
    assert_eq!(status, 200);
    let names: Vec<&str> = arts["items"]
        .as_array()
        .expect("items")
        .iter()
        .filter_map(|a| a["name"].as_str())
        .collect();
    for want in ["scores.svg", "sharp.blurmap.png", "blurred.blurmap.png"] {
        assert!(names.contains(&want), "{want} missing from {names:?}");
    }
    let r = s
        .client
        .get(s.url(&format!("/v1/jobs/{id}/artifacts/scores.svg")))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    assert_eq!(r.headers()["content-type"], "image/svg+xml");
    assert!(r.text().await.unwrap().contains("<svg"));
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn idempotency_key_returns_the_same_job_or_conflicts() {
    let s = start().await;
    let ds = s.dataset(vec![("a.png", png(&sharp_image(64, 48)))]).await;
    let body = json!({"kind": "blur_score", "dataset": ds});
    let send = |b: Value| {
        s.client
            .post(s.url("/v1/jobs"))
            .header("Idempotency-Key", "key-1")
            .json(&b)
            .send()
    };
    let r1 = send(body.clone()).await.unwrap();
    assert_eq!(r1.status(), 202);
    let j1: Value = r1.json().await.unwrap();
    let r2 = send(body.clone()).await.unwrap();
    assert_eq!(r2.status(), 200);
    let j2: Value = r2.json().await.unwrap();
    assert_eq!(j1["id"], j2["id"]);
    // Spelling out a default is the same request.
    let r3 = send(json!({"kind": "blur_score", "dataset": ds, "params": {"k": 10}}))
        .await
        .unwrap();
    assert_eq!(r3.status(), 200);
    let r4 = send(json!({"kind": "blur_score", "dataset": ds, "params": {"k": 5}}))
        .await
        .unwrap();
    assert_eq!(r4.status(), 409);
    assert_eq!(r4.headers()["content-type"], "application/problem+json");
    let p: Value = r4.json().await.unwrap();
    assert_eq!(p["code"], "idempotency_conflict");
    let (_, list) = s.get_json("/v1/jobs").await;
    assert_eq!(
        list["items"].as_array().unwrap().len(),
        1,
        "only one job was created"
    );
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cancel_stops_a_running_job_and_a_queued_one() {
    let s = start_with(|c| c.workers = 1).await;
    let files = slow_dataset(60);
    let ds = s.dataset(as_refs(&files)).await;
    let running = s.job(json!({"kind": "blur_score", "dataset": ds})).await;
    let queued = s.job(json!({"kind": "blur_score", "dataset": ds})).await;
    s.wait_for(&running, Duration::from_secs(30), |j| {
        j["status"] == "running" && j["progress"]["done"].as_u64().unwrap_or(0) >= 1
    })
    .await;
    // The queued one is canceled at once.
    let (st, j) = s
        .post_json(&format!("/v1/jobs/{queued}/cancel"), &json!({}))
        .await;
    assert_eq!(st, 200, "{j}");
    assert_eq!(j["status"], "canceled");
    // The running one is flagged and stops well before it would have finished.
    let t0 = std::time::Instant::now();
    let (st, j) = s
        .post_json(&format!("/v1/jobs/{running}/cancel"), &json!({}))
        .await;
    assert_eq!(st, 202, "{j}");
    let done = s.wait_terminal(&running).await;
    assert_eq!(done["status"], "canceled", "{done}");
    assert!(
        t0.elapsed() < Duration::from_secs(3),
        "cancel took {:?}",
        t0.elapsed()
    );
    assert!(done["progress"]["done"].as_u64().unwrap() < 60, "{done}");
    // Canceling a finished job is a conflict.
    let (st, p) = s
        .post_json(&format!("/v1/jobs/{running}/cancel"), &json!({}))
        .await;
    assert_eq!(st, 409);
    assert_eq!(p["code"], "job_finished");
    // No result for a canceled job.
    let (st, p) = s.get_json(&format!("/v1/jobs/{running}/result")).await;
    assert_eq!(st, 409);
    assert_eq!(p["code"], "result_not_ready");
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn time_limit_fails_the_job_with_a_clear_code() {
    let s = start_with(|c| {
        c.workers = 1;
        c.time_limits.insert("blur_score".into(), 1);
    })
    .await;
    let files = slow_dataset(80);
    let ds = s.dataset(as_refs(&files)).await;
    let id = s.job(json!({"kind": "blur_score", "dataset": ds})).await;
    let done = s.wait_terminal(&id).await;
    assert_eq!(done["status"], "failed", "{done}");
    assert_eq!(done["error"]["code"], "time_limit_exceeded");
    assert_eq!(done["attempt"], 1, "a time limit is not retried");
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn events_stream_status_until_the_end() {
    let s = start().await;
    let ds = s
        .dataset(vec![("a.png", png(&sharp_image(200, 150)))])
        .await;
    let id = s.job(json!({"kind": "blur_score", "dataset": ds})).await;
    let r = s
        .client
        .get(s.url(&format!("/v1/jobs/{id}/events")))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    assert!(
        r.headers()["content-type"]
            .to_str()
            .unwrap()
            .starts_with("text/event-stream")
    );
    let mut body = String::new();
    let mut stream = r.bytes_stream();
    let read = async {
        while let Some(chunk) = stream.next().await {
            body.push_str(&String::from_utf8_lossy(&chunk.unwrap()));
        }
    };
    tokio::time::timeout(Duration::from_secs(30), read)
        .await
        .expect("stream ends after the job");
    assert!(body.contains("event: status"), "{body}");
    assert!(body.contains("\"status\":\"succeeded\""), "{body}");
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn list_filters_and_pages() {
    let s = start().await;
    let ds = s.dataset(vec![("a.png", png(&sharp_image(64, 48)))]).await;
    let mut ids = Vec::new();
    for i in 0..3 {
        let dev = format!("dev-{}", i % 2);
        ids.push(
            s.job(json!({"kind": "blur_score", "dataset": ds, "device": dev}))
                .await,
        );
    }
    for id in &ids {
        s.wait_terminal(id).await;
    }
    let (_, l) = s.get_json("/v1/jobs?device=dev-0&status=succeeded").await;
    assert_eq!(l["items"].as_array().unwrap().len(), 2);
    let (_, p1) = s.get_json("/v1/jobs?limit=2").await;
    assert_eq!(p1["items"].as_array().unwrap().len(), 2);
    assert_eq!(p1["items"][0]["id"], ids[2].as_str(), "newest first");
    let cursor = p1["next_cursor"].as_str().expect("more pages");
    let (_, p2) = s
        .get_json(&format!("/v1/jobs?limit=2&cursor={cursor}"))
        .await;
    assert_eq!(p2["items"].as_array().unwrap().len(), 1);
    assert_eq!(p2["items"][0]["id"], ids[0].as_str());
    assert!(p2.get("next_cursor").is_none());
    let (_, none) = s.get_json("/v1/jobs?status=failed,canceled").await;
    assert!(none["items"].as_array().unwrap().is_empty());
    let (_, after) = s
        .get_json("/v1/jobs?created_after=2999-01-01T00:00:00Z")
        .await;
    assert!(after["items"].as_array().unwrap().is_empty());
    let (st, p) = s.get_json("/v1/jobs?status=done").await;
    assert_eq!(st, 400);
    assert_eq!(p["code"], "invalid_query");
    let (st, p) = s.get_json("/v1/jobs?limit=1000").await;
    assert_eq!(st, 400);
    assert_eq!(p["field"], "limit");
    let (st, p) = s.get_json("/v1/jobs?colour=red").await;
    assert_eq!(st, 400, "{p}");
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn full_queue_answers_429_with_retry_after() {
    let s = start_with(|c| {
        c.workers = 1;
        c.max_queued_jobs = 1;
    })
    .await;
    let files = slow_dataset(40);
    let ds = s.dataset(as_refs(&files)).await;
    let mut saw_429 = false;
    for _ in 0..3 {
        let r = s
            .client
            .post(s.url("/v1/jobs"))
            .json(&json!({"kind": "blur_score", "dataset": ds}))
            .send()
            .await
            .unwrap();
        if r.status() == 429 {
            assert!(r.headers().contains_key("retry-after"));
            let p: Value = r.json().await.unwrap();
            assert_eq!(p["code"], "queue_full");
            saw_429 = true;
            break;
        }
        assert_eq!(r.status(), 202);
    }
    assert!(saw_429, "a queue of 1 must refuse the third job");
    // Free the worker so shutdown is quick.
    let (_, l) = s.get_json("/v1/jobs").await;
    for j in l["items"].as_array().unwrap() {
        let id = j["id"].as_str().unwrap();
        let _ = s
            .post_json(&format!("/v1/jobs/{id}/cancel"), &json!({}))
            .await;
    }
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn job_kinds_and_metrics_are_published() {
    let s = start().await;
    let (st, kinds) = s.get_json("/v1/job-kinds").await;
    assert_eq!(st, 200);
    assert_eq!(kinds[0]["name"], "blur_score");
    assert_eq!(kinds[0]["schema"], "caliper.blur_score/v1");
    assert!(
        kinds[0]["params_schema"]["properties"]["k"].is_object(),
        "{kinds}"
    );
    let r = s.client.get(s.url("/metrics")).send().await.unwrap();
    assert_eq!(r.status(), 200);
    let text = r.text().await.unwrap();
    assert!(text.contains("caliper_http_requests_total"), "{text}");
    assert!(text.contains("caliper_jobs_queued"), "{text}");
    let (st, h) = s.get_json("/readyz").await;
    assert_eq!((st, h["status"].as_str()), (200, Some("ok")));
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn storage_failures_are_retried_with_backoff_then_fail() {
    let s = start_with(|c| c.max_attempts = 3).await;
    let ds = s.dataset(vec![("a.png", png(&sharp_image(64, 48)))]).await;
    // Lose the blobs behind the dataset's back: reading them fails, which is not the input's fault.
    std::fs::remove_dir_all(s.dir.path().join("data/blobs/sha256")).unwrap();
    let id = s.job(json!({"kind": "blur_score", "dataset": ds})).await;
    let done = s.wait_terminal(&id).await;
    assert_eq!(done["status"], "failed", "{done}");
    assert_eq!(done["attempt"], 3, "retried up to max_attempts: {done}");
    assert_eq!(done["error"]["code"], "transient");
    s.stop().await;
}
