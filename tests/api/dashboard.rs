//! What the dashboard reads, through the public API: the paged device list with quality
//! numbers, revision provenance, revision diffs, dataset file downloads, export formats per
//! kind, and the `/ui` files with their security headers.

use serde_json::{Value, json};

use crate::common::*;

/// Files a blur_score document for each device (fast jobs) and waits for them.
async fn file_documents(s: &TestServer, devices: &[&str]) -> String {
    let ds = s.dataset(vec![("a.png", png(&sharp_image(96, 72)))]).await;
    for d in devices {
        let id = s
            .job(json!({"kind": "blur_score", "dataset": ds, "device": d, "sensor": "cam0"}))
            .await;
        assert_eq!(s.wait_terminal(&id).await["status"], "succeeded");
    }
    ds
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn devices_are_listed_in_pages_with_their_latest_documents() {
    let s = start().await;
    file_documents(&s, &["cam-b", "cam-a", "imu-c", "cam-d", "cam-e"]).await;

    let (st, p1) = s.get_json("/v1/devices?limit=2").await;
    assert_eq!(st, 200, "{p1}");
    assert_eq!(p1["total"], 5);
    let serials = |p: &Value| -> Vec<String> {
        p["items"]
            .as_array()
            .expect("items")
            .iter()
            .map(|d| d["serial"].as_str().expect("serial").to_owned())
            .collect()
    };
    assert_eq!(serials(&p1), ["cam-a", "cam-b"]);
    let doc = &p1["items"][0]["documents"][0];
    assert_eq!(doc["kind"], "blur_score");
    assert_eq!(doc["latest_rev"], 1);
    assert!(doc["quality"]["images"].as_u64() == Some(1), "{doc}");
    assert!(doc["job"].is_string(), "{doc}");

    // Follow the cursor to the end: every device once, in serial order.
    let mut all = serials(&p1);
    let mut cursor = p1["next_cursor"].as_str().map(str::to_owned);
    while let Some(c) = cursor {
        let (st, p) = s.get_json(&format!("/v1/devices?limit=2&cursor={c}")).await;
        assert_eq!(st, 200, "{p}");
        all.extend(serials(&p));
        cursor = p["next_cursor"].as_str().map(str::to_owned);
    }
    assert_eq!(all, ["cam-a", "cam-b", "cam-d", "cam-e", "imu-c"]);

    // Search is a case-insensitive substring, counted on the server.
    let (_, q) = s.get_json("/v1/devices?q=CAM-").await;
    assert_eq!(q["total"], 4);
    let (_, q) = s.get_json("/v1/devices?q=imu").await;
    assert_eq!(serials(&q), ["imu-c"]);
    let (_, none) = s.get_json("/v1/devices?q=nothing-like-it").await;
    assert_eq!(none["total"], 0);
    assert!(none.get("next_cursor").is_none());

    // Bad queries are problems naming the field.
    for (q, field) in [
        ("limit=0", "limit"),
        ("limit=101", "limit"),
        ("cursor=a%20b", "cursor"),
        ("cursor=a%2Fb", "cursor"),
    ] {
        let (st, p) = s.get_json(&format!("/v1/devices?{q}")).await;
        assert_eq!(st, 400, "{q}: {p}");
        assert_eq!(p["field"], field, "{q}: {p}");
    }
    let long = "x".repeat(129);
    let (st, p) = s.get_json(&format!("/v1/devices?q={long}")).await;
    assert_eq!((st, p["field"].as_str()), (400, Some("q")), "{p}");
    let (st, p) = s.get_json(&format!("/v1/devices?cursor={long}")).await;
    assert_eq!((st, p["field"].as_str()), (400, Some("cursor")), "{p}");
    // Any cursor the spec's pattern admits is a key to list after, even one that is no serial.
    let (st, p) = s.get_json("/v1/devices?cursor=..").await;
    assert_eq!(st, 200, "{p}");
    assert_eq!(
        serials(&p),
        ["cam-a", "cam-b", "cam-d", "cam-e", "imu-c"],
        "{p}"
    );
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn revisions_carry_provenance_and_diff_in_sigma_units() {
    let s = start().await;
    // Two camera calibrations of different view sets: the intrinsics move by a few σ at most.
    let files = crate::camera::renders();
    let mut jobs = Vec::new();
    for n in [10, 8] {
        let ds = s.dataset(as_refs(&files[..n])).await;
        let id = s
            .job(json!({"kind": "camera_calibration", "dataset": ds, "device": "rig-1", "sensor": "cam0",
                        "params": {"board": {"cols": 9, "rows": 6, "square": 0.025}}}))
            .await;
        assert_eq!(s.wait_terminal(&id).await["status"], "succeeded");
        jobs.push((id, ds));
    }
    let base = "/v1/devices/rig-1/documents/cam0/camera_calibration";
    let (st, revs) = s.get_json(base).await;
    assert_eq!(st, 200, "{revs}");
    assert_eq!(revs[0]["rev"], 2);
    assert_eq!(revs[0]["job"], jobs[1].0.as_str());
    assert_eq!(revs[0]["dataset"], jobs[1].1.as_str());
    assert!(
        revs[0]["software"]
            .as_str()
            .is_some_and(|v| v.starts_with("caliper ")),
        "{revs}"
    );
    assert!(revs[0]["quality"]["rms"].is_number(), "{revs}");

    let (st, d) = s.get_json(&format!("{base}/diff?from=1&to=2")).await;
    assert_eq!(st, 200, "{d}");
    let entries = d["entries"].as_array().expect("entries");
    let fx = entries
        .iter()
        .find(|e| e["path"] == "parameters.calibration.parameters[fx]")
        .expect("fx compared");
    let (a, b) = (
        fx["from"].as_f64().expect("from"),
        fx["to"].as_f64().expect("to"),
    );
    assert!((fx["delta"].as_f64().expect("delta") - (b - a)).abs() < 1e-9);
    let sigma = fx["sigma"].as_f64().expect("σ of fx from both revisions");
    assert!(sigma > 0.0 && sigma < 5.0, "{fx}");
    // Same camera, same renderer: the two estimates agree to a few σ.
    assert!(fx["delta_sigma"].as_f64().expect("Δσ").abs() < 5.0, "{fx}");
    assert_eq!(
        d["changed"].as_u64().expect("changed") as usize,
        entries.iter().filter(|e| e["changed"] == true).count()
    );
    assert!(
        entries
            .iter()
            .all(|e| !e["path"].as_str().unwrap_or("").contains("residuals")),
        "per-corner lists are left out"
    );

    // Unknown revisions are 404, bad ones 400.
    let (st, _) = s.get_json(&format!("{base}/diff?from=1&to=9")).await;
    assert_eq!(st, 404);
    let (st, p) = s.get_json(&format!("{base}/diff?from=0&to=2")).await;
    assert_eq!((st, p["field"].as_str()), (400, Some("from")), "{p}");
    let (st, _) = s.get_json(&format!("{base}/diff?from=1")).await;
    assert_eq!(st, 400);
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn dataset_files_download_as_uploaded() {
    let s = start().await;
    let a = png(&sharp_image(64, 48));
    let b = png(&sharp_image(80, 60));
    let ds = s
        .dataset(vec![("a.png", a.clone()), ("b.png", b.clone())])
        .await;
    let r = s
        .client
        .get(s.url(&format!("/v1/datasets/{ds}/files/1")))
        .send()
        .await
        .expect("get");
    assert_eq!(r.status(), 200);
    assert_eq!(r.headers()["content-type"], "image/png");
    let etag = r.headers()["etag"].to_str().expect("etag").to_owned();
    assert_eq!(r.bytes().await.expect("bytes").to_vec(), b);
    let (_, view) = s.get_json(&format!("/v1/datasets/{ds}")).await;
    assert_eq!(
        etag,
        format!("\"{}\"", view["files"][1]["sha256"].as_str().expect("sha"))
    );
    let (st, p) = s.get_json(&format!("/v1/datasets/{ds}/files/2")).await;
    assert_eq!(st, 404, "{p}");
    let (st, _) = s
        .get_json("/v1/datasets/01935f2c-7a4e-7cc2-9d1e-3b8a2f6c1d00/files/0")
        .await;
    assert_eq!(st, 404);
    // A path that is not an index names no file (path errors are 404s, as elsewhere).
    let (st, p) = s.get_json(&format!("/v1/datasets/{ds}/files/-1")).await;
    assert_eq!((st, p["code"].as_str()), (404, Some("not_found")), "{p}");
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn job_kinds_list_their_export_formats() {
    let s = start().await;
    let (_, kinds) = s.get_json("/v1/job-kinds").await;
    let camera = kinds
        .as_array()
        .expect("kinds")
        .iter()
        .find(|k| k["name"] == "camera_calibration")
        .expect("camera kind");
    let formats: Vec<&str> = camera["exports"]
        .as_array()
        .expect("exports")
        .iter()
        .map(|e| e["format"].as_str().expect("format"))
        .collect();
    assert!(formats.contains(&"opencv-yaml"), "{formats:?}");
    let opencv = camera["exports"]
        .as_array()
        .expect("exports")
        .iter()
        .find(|e| e["format"] == "opencv-yaml")
        .expect("opencv");
    assert_eq!(opencv["extension"], "yaml");
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_dashboard_is_served_with_a_strict_policy() {
    let s = start().await;
    let no_redirect = reqwest::Client::builder()
        .redirect(reqwest::redirect::Policy::none())
        .build()
        .expect("client");
    let r = no_redirect.get(s.url("/")).send().await.expect("get /");
    assert!(r.status().is_redirection());
    assert_eq!(r.headers()["location"], "/ui/");
    let r = s.client.get(s.url("/ui/")).send().await.expect("index");
    assert_eq!(r.status(), 200);
    let csp = r.headers()["content-security-policy"]
        .to_str()
        .expect("csp")
        .to_owned();
    assert!(
        csp.contains("script-src 'self'") && !csp.contains("unsafe-inline"),
        "{csp}"
    );
    assert_eq!(r.headers()["x-content-type-options"], "nosniff");
    let html = r.text().await.expect("html");
    // No inline script and nothing from another origin: the page works offline.
    assert!(!html.contains("<script>") && !html.contains("http://") && !html.contains("https://"));
    for path in ["js/app.js", "vendor/uPlot.iife.min.js", "style.css"] {
        let r = s
            .client
            .get(s.url(&format!("/ui/{path}")))
            .send()
            .await
            .expect("asset");
        assert_eq!(r.status(), 200, "{path}");
    }
    let r = s
        .client
        .get(s.url("/ui/js/missing.js"))
        .send()
        .await
        .expect("missing");
    assert_eq!(r.status(), 404);
    assert_eq!(r.headers()["content-type"], "application/problem+json");
    // Every module the page imports is served.
    for asset in caliper_service::api::ui::ASSETS {
        if asset.0.ends_with(".js") && asset.0.starts_with("js/") {
            let text = std::str::from_utf8(asset.2).expect("utf-8");
            for line in text.lines().filter(|l| l.starts_with("import ")) {
                let Some(target) = line.split('\'').nth(1) else {
                    continue;
                };
                let name = format!("js/{}", target.trim_start_matches("./"));
                assert!(
                    caliper_service::api::ui::ASSETS.iter().any(|a| a.0 == name),
                    "{} imports {name}, which is not served",
                    asset.0
                );
            }
        }
    }
    s.stop().await;
}
