//! Crash recovery: SIGKILL the `caliper` binary mid-job, start it again on the same data
//! directory, and the job completes exactly once.

use std::process::Command;
use std::time::Duration;

use serde_json::{Value, json};

use crate::common::*;

async fn get(client: &reqwest::Client, url: String) -> Value {
    client
        .get(url)
        .send()
        .await
        .expect("request")
        .json()
        .await
        .expect("json")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn killed_server_resumes_its_job_and_completes_it_once() {
    let bin = tokio::task::spawn_blocking(caliper_bin).await.unwrap();
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let client = reqwest::Client::new();

    let mut p = spawn_caliper(&bin, &data, &["--lease-secs", "3"]);
    let files = slow_dataset(60);
    let mut form = reqwest::multipart::Form::new();
    for (n, b) in &files {
        form = form.part(
            "file",
            reqwest::multipart::Part::bytes(b.clone()).file_name(n.clone()),
        );
    }
    let ds: Value = client
        .post(format!("{}/v1/datasets", p.base))
        .multipart(form)
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    let body =
        json!({"kind": "blur_score", "dataset": ds["id"], "device": "dev-9", "sensor": "cam0"});
    let job: Value = client
        .post(format!("{}/v1/jobs", p.base))
        .json(&body)
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    let id = job["id"].as_str().unwrap().to_string();
    // Wait until it is running and has made progress, then kill -9.
    let deadline = std::time::Instant::now() + Duration::from_secs(60);
    loop {
        let j = get(&client, format!("{}/v1/jobs/{id}", p.base)).await;
        if j["status"] == "running" && j["progress"]["done"].as_u64().unwrap_or(0) >= 2 {
            break;
        }
        assert!(
            j["status"] != "succeeded",
            "job finished before the kill; make the dataset bigger"
        );
        assert!(std::time::Instant::now() < deadline, "job never ran: {j}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    p.child.kill().expect("kill");
    p.child.wait().expect("wait");

    let mut p = spawn_caliper(&bin, &data, &["--lease-secs", "3"]);
    let deadline = std::time::Instant::now() + Duration::from_secs(90);
    let done = loop {
        let j = get(&client, format!("{}/v1/jobs/{id}", p.base)).await;
        if matches!(
            j["status"].as_str(),
            Some("succeeded" | "failed" | "canceled")
        ) {
            break j;
        }
        assert!(
            std::time::Instant::now() < deadline,
            "job not finished after restart: {j}"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    };
    assert_eq!(done["status"], "succeeded", "{done}");
    assert_eq!(
        done["attempt"], 2,
        "one killed attempt, one completed: {done}"
    );
    let revs = get(
        &client,
        format!("{}/v1/devices/dev-9/documents/cam0/blur_score", p.base),
    )
    .await;
    assert_eq!(
        revs.as_array().map(Vec::len),
        Some(1),
        "exactly one document: {revs}"
    );
    let doc = get(&client, format!("{}/v1/jobs/{id}/result", p.base)).await;
    assert_eq!(
        doc["parameters"]["images"].as_array().map(Vec::len),
        Some(60)
    );

    // Graceful stop: SIGTERM ends the process cleanly.
    let pid = p.child.id().to_string();
    Command::new("kill").args(["-TERM", &pid]).status().unwrap();
    let status = p.child.wait().unwrap();
    assert!(status.success(), "graceful shutdown exits 0: {status}");
}
