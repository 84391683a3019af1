//! The job-kind registry is the one list of kinds: every registered kind is accepted by the
//! router, described in the OpenAPI components, listed by `GET /v1/job-kinds` and runnable as
//! `caliper run <kind>`; its exports are what the export dispatch offers.

use std::process::Command;

use serde_json::json;

use crate::common::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_registered_kind_reaches_router_spec_listing_and_cli() {
    let spec: serde_json::Value =
        serde_json::from_str(&caliper_service::openapi_json()).expect("spec is JSON");
    let schemas = &spec["components"]["schemas"];
    let s = start().await;
    let (st, listed) = s.get_json("/v1/job-kinds").await;
    assert_eq!(st, 200);
    let listed: Vec<&str> = listed
        .as_array()
        .expect("array")
        .iter()
        .filter_map(|k| k["name"].as_str())
        .collect();
    let kinds = caliper_service::jobs::kinds();
    assert!(kinds.len() >= 10, "the registry lost kinds");
    let bin = caliper_bin();
    for k in kinds {
        // OpenAPI: the parameter type is a component, and the request names it.
        let mut comps = Vec::new();
        k.params_components(&mut comps);
        let (params_name, _) = comps.first().expect("a params schema");
        assert!(
            schemas[params_name.as_str()].is_object(),
            "{}: {params_name} missing from the spec",
            k.name()
        );
        let desc = spec["components"]["schemas"]["CreateJobRequest"]["properties"]["params"]
            ["description"]
            .as_str()
            .unwrap_or("");
        assert!(desc.contains(k.name()), "{}: not in {desc:?}", k.name());
        // Listing.
        assert!(listed.contains(&k.name()), "{} not listed", k.name());
        // Router: the kind is known (whatever its parameters or dataset).
        let (st, p) = s
            .post_json(
                "/v1/jobs",
                &json!({"kind": k.name(), "dataset": "01935f2c-7a4e-7cc2-9d1e-3b8a2f6c1d00"}),
            )
            .await;
        assert_eq!(st, 422, "{}: {p}", k.name());
        assert_ne!(p["code"], "unknown_job_kind", "{}: {p}", k.name());
        // CLI.
        let cli = k.name().replace('_', "-");
        let out = Command::new(&bin)
            .args(["run", &cli, "--help"])
            .output()
            .expect("run caliper");
        assert!(out.status.success(), "caliper run {cli} --help: {out:?}");
        assert!(String::from_utf8_lossy(&out.stdout).contains("--out"));
        // Exports: the dispatch offers what the kind declares.
        let offered: Vec<&str> = caliper_service::jobs::exports_for(k.schema())
            .iter()
            .map(|e| e.format)
            .collect();
        for e in k.exports() {
            assert!(offered.contains(&e.format), "{}: {}", k.name(), e.format);
        }
    }
    // And nothing is listed that the registry does not hold (the test-only kind included).
    assert_eq!(listed.len(), kinds.len(), "{listed:?}");
    s.stop().await;
}
