//! The committed OpenAPI document matches the code, and the served one too.

use crate::common::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn committed_spec_matches_the_generated_one() {
    let generated = caliper_service::openapi_json();
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../openapi/openapi.json");
    let committed = std::fs::read_to_string(&path).unwrap_or_default();
    assert!(
        committed == generated,
        "openapi/openapi.json is stale: run `cargo run -p caliper-service -- openapi > openapi/openapi.json`"
    );
    let spec: serde_json::Value = serde_json::from_str(&generated).unwrap();
    for p in [
        "/v1/datasets",
        "/v1/jobs",
        "/v1/jobs/{id}/events",
        "/v1/devices/{serial}/documents/{sensor}/{kind}/latest",
        "/healthz",
        "/metrics",
    ] {
        assert!(spec["paths"][p].is_object(), "spec lacks {p}");
    }
    assert!(spec["components"]["schemas"]["Problem"].is_object());
    assert!(spec["components"]["schemas"]["BlurParams"].is_object());

    let s = start().await;
    let (st, served) = s.get_json("/openapi.json").await;
    assert_eq!(st, 200);
    assert_eq!(served, spec);
    let r = s.client.get(s.url("/docs/")).send().await.unwrap();
    assert_eq!(r.status(), 200);
    assert!(r.text().await.unwrap().to_lowercase().contains("swagger"));
    s.stop().await;
}
