//! `caliper run` prints the document the service would store for the same files.

use serde_json::{Value, json};

use crate::common::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn offline_run_matches_the_service_document() {
    let bin = tokio::task::spawn_blocking(caliper_bin).await.unwrap();
    let sharp = sharp_image(160, 120);
    let files = vec![("s.png", png(&sharp)), ("b.png", png(&box_blur(&sharp, 5)))];
    let dir = tempfile::tempdir().unwrap();
    for (n, b) in &files {
        std::fs::write(dir.path().join(n), b).unwrap();
    }
    let out = std::process::Command::new(&bin)
        .args(["run", "blur-score", "--k", "5", "--out"])
        .arg(dir.path().join("plots"))
        .arg(dir.path().join("s.png"))
        .arg(dir.path().join("b.png"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let offline: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(
        caliper_service::document::verify(&offline),
        "offline document carries a valid etag"
    );
    assert!(dir.path().join("plots/scores.svg").exists());

    let s = start().await;
    let ds = s.dataset(files).await;
    let id = s
        .job(json!({"kind": "blur_score", "dataset": ds, "params": {"k": 5}}))
        .await;
    s.wait_terminal(&id).await;
    let (_, online) = s.get_json(&format!("/v1/jobs/{id}/result")).await;
    for key in ["schema", "kind", "quality", "parameters", "artifacts"] {
        assert_eq!(offline[key], online[key], "{key} differs");
    }
    for key in ["files", "params", "dataset_sha256", "software"] {
        assert_eq!(
            offline["provenance"][key], online["provenance"][key],
            "provenance.{key} differs"
        );
    }
    assert!(offline["provenance"]["job"].is_null());

    // Bad input: a clear message and exit code 2.
    let out = std::process::Command::new(&bin)
        .args(["run", "blur-score", "--k", "0"])
        .arg(dir.path().join("s.png"))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("k"));
    s.stop().await;
}
