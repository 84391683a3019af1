//! Access control with tokens: every boundary, through HTTP. 401 without or with a bad token,
//! 403 with the wrong scope, another device's documents, jobs and datasets answer 404 exactly
//! like missing ones, revocation holds at once, per-token rate limits, CORS.

use std::time::Duration;

use serde_json::{Value, json};

use crate::common::*;

/// A token made straight in the server's store (as `caliper token create` does).
async fn admin_token(s: &TestServer) -> String {
    let state = &s.server.as_ref().expect("running").state;
    let new =
        caliper_service::auth::generate("admin", caliper_service::store::Scope::Admin, None, 0)
            .expect("token");
    state
        .store()
        .insert_token(&new.record, &new.hash)
        .await
        .expect("stored");
    new.secret
}

async fn call(
    s: &TestServer,
    method: reqwest::Method,
    path: &str,
    token: Option<&str>,
    body: Option<Value>,
) -> (u16, Value, reqwest::header::HeaderMap) {
    let mut r = s.client.request(method, s.url(path));
    if let Some(t) = token {
        r = r.bearer_auth(t);
    }
    if let Some(b) = body {
        r = r.json(&b);
    }
    let resp = r.send().await.expect("request");
    let status = resp.status().as_u16();
    let headers = resp.headers().clone();
    (status, resp.json().await.unwrap_or(Value::Null), headers)
}

async fn get(s: &TestServer, path: &str, token: Option<&str>) -> (u16, Value) {
    let (st, v, _) = call(s, reqwest::Method::GET, path, token, None).await;
    (st, v)
}

async fn create_token(s: &TestServer, admin: &str, body: Value) -> String {
    let (st, v, _) = call(
        s,
        reqwest::Method::POST,
        "/v1/tokens",
        Some(admin),
        Some(body),
    )
    .await;
    assert_eq!(st, 201, "{v}");
    assert!(v["token"].as_str().is_some_and(|t| t.starts_with("clp_")));
    v["token"].as_str().expect("secret").to_owned()
}

/// Upload with a token; returns (status, body).
async fn upload_as(s: &TestServer, token: &str) -> (u16, Value) {
    let form = reqwest::multipart::Form::new().part(
        "file",
        reqwest::multipart::Part::bytes(png(&sharp_image(96, 72))).file_name("a.png"),
    );
    let r = s
        .client
        .post(s.url("/v1/datasets"))
        .bearer_auth(token)
        .multipart(form)
        .send()
        .await
        .expect("upload");
    let st = r.status().as_u16();
    (st, r.json().await.unwrap_or(Value::Null))
}

async fn wait_done(s: &TestServer, id: &str, token: &str) -> Value {
    let start = std::time::Instant::now();
    loop {
        let (st, j) = get(s, &format!("/v1/jobs/{id}"), Some(token)).await;
        assert_eq!(st, 200, "{j}");
        if matches!(
            j["status"].as_str(),
            Some("succeeded" | "failed" | "canceled")
        ) {
            return j;
        }
        assert!(start.elapsed() < Duration::from_secs(60), "{j}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tokens_guard_every_route_by_scope() {
    let s = start_with(|c| c.auth = true).await;
    // Open routes stay open.
    for path in [
        "/healthz",
        "/readyz",
        "/openapi.json",
        "/ui/",
        "/problems/unauthorized",
    ] {
        let r = s.client.get(s.url(path)).send().await.expect("get");
        assert_eq!(r.status(), 200, "{path}");
    }
    // Everything else needs a token.
    let (st, p, h) = call(&s, reqwest::Method::GET, "/v1/jobs", None, None).await;
    assert_eq!((st, p["code"].as_str()), (401, Some("unauthorized")), "{p}");
    assert!(
        h["www-authenticate"]
            .to_str()
            .expect("header")
            .starts_with("Bearer")
    );
    for bad in ["clp_0000000000000000000000000000000000000000", "nonsense"] {
        let (st, p) = get(&s, "/v1/datasets", Some(bad)).await;
        assert_eq!((st, p["code"].as_str()), (401, Some("unauthorized")), "{p}");
    }
    let (st, _) = get(&s, "/metrics", None).await;
    assert_eq!(st, 401, "metrics need a token unless --metrics-public");

    let admin = admin_token(&s).await;
    let write = create_token(&s, &admin, json!({"name": "ci", "scope": "write"})).await;
    let read = create_token(&s, &admin, json!({"name": "dash", "scope": "read"})).await;

    // read: reads only.
    let (st, _) = get(&s, "/v1/jobs", Some(&read)).await;
    assert_eq!(st, 200);
    let (st, p) = upload_as(&s, &read).await;
    assert_eq!((st, p["code"].as_str()), (403, Some("forbidden")), "{p}");
    // write: uploads and queues, but manages no tokens.
    let (st, ds) = upload_as(&s, &write).await;
    assert_eq!(st, 201, "{ds}");
    let (st, p) = get(&s, "/v1/tokens", Some(&write)).await;
    assert_eq!((st, p["code"].as_str()), (403, Some("forbidden")), "{p}");
    let (st, job, _) = call(
        &s,
        reqwest::Method::POST,
        "/v1/jobs",
        Some(&write),
        Some(json!({"kind": "blur_score", "dataset": ds["id"], "device": "cam-1"})),
    )
    .await;
    assert_eq!(st, 202, "{job}");

    // Tokens are listed without secrets; a revoked one stops at once.
    let (st, list) = get(&s, "/v1/tokens", Some(&admin)).await;
    assert_eq!(st, 200);
    assert_eq!(list.as_array().expect("list").len(), 3);
    assert!(
        !list.to_string().contains(&read),
        "a secret leaked into the list"
    );
    let read_id = list
        .as_array()
        .expect("list")
        .iter()
        .find(|t| t["name"] == "dash")
        .expect("dash")["id"]
        .as_str()
        .expect("id")
        .to_owned();
    let (st, _, _) = call(
        &s,
        reqwest::Method::DELETE,
        &format!("/v1/tokens/{read_id}"),
        Some(&admin),
        None,
    )
    .await;
    assert_eq!(st, 204);
    let (st, p) = get(&s, "/v1/jobs", Some(&read)).await;
    assert_eq!((st, p["code"].as_str()), (401, Some("unauthorized")), "{p}");
    // Bad token requests are problems naming the field.
    let (st, p, _) = call(
        &s,
        reqwest::Method::POST,
        "/v1/tokens",
        Some(&admin),
        Some(json!({"name": "x", "scope": "admin", "devices": ["cam-1"]})),
    )
    .await;
    assert_eq!((st, p["field"].as_str()), (422, Some("devices")), "{p}");
    let (st, _, _) = call(
        &s,
        reqwest::Method::POST,
        "/v1/tokens",
        Some(&admin),
        Some(json!({"name": "x", "scope": "root"})),
    )
    .await;
    assert_eq!(st, 422);
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_device_token_sees_only_its_own_devices() {
    let s = start_with(|c| c.auth = true).await;
    let admin = admin_token(&s).await;
    let cam1 = create_token(
        &s,
        &admin,
        json!({"name": "cam-1", "scope": "write", "devices": ["cam-1"]}),
    )
    .await;
    let cam2 = create_token(
        &s,
        &admin,
        json!({"name": "cam-2", "scope": "write", "devices": ["cam-2"]}),
    )
    .await;
    let fleet = create_token(&s, &admin, json!({"name": "prov", "scope": "read"})).await;

    // cam-1 uploads and files its own calibration; not for another device, not without one.
    let (st, ds) = upload_as(&s, &cam1).await;
    assert_eq!(st, 201, "{ds}");
    let ds_id = ds["id"].as_str().expect("id").to_owned();
    for (device, want) in [(json!("cam-2"), 403), (Value::Null, 403)] {
        let mut body = json!({"kind": "blur_score", "dataset": ds_id});
        if !device.is_null() {
            body["device"] = device;
        }
        let (st, p, _) = call(
            &s,
            reqwest::Method::POST,
            "/v1/jobs",
            Some(&cam1),
            Some(body),
        )
        .await;
        assert_eq!((st, p["field"].as_str()), (want, Some("device")), "{p}");
    }
    let (st, job, _) = call(
        &s,
        reqwest::Method::POST,
        "/v1/jobs",
        Some(&cam1),
        Some(json!({"kind": "blur_score", "dataset": ds_id, "device": "cam-1", "sensor": "cam0"})),
    )
    .await;
    assert_eq!(st, 202, "{job}");
    let job_id = job["id"].as_str().expect("id").to_owned();
    assert_eq!(wait_done(&s, &job_id, &cam1).await["status"], "succeeded");

    // cam-2 cannot use cam-1's dataset (as if it did not exist) …
    let (st, p, _) = call(
        &s,
        reqwest::Method::POST,
        "/v1/jobs",
        Some(&cam2),
        Some(json!({"kind": "blur_score", "dataset": ds_id, "device": "cam-2"})),
    )
    .await;
    assert_eq!(
        (st, p["code"].as_str()),
        (422, Some("unknown_dataset")),
        "{p}"
    );

    // … and every read of cam-1's things answers like a missing resource.
    let missing_job = "01935f2c-8b11-7d20-a1b2-c3d4e5f60718";
    let missing_ds = "01935f2c-7a4e-7cc2-9d1e-3b8a2f6c1d00";
    let doc = "/v1/devices/cam-1/documents/cam0/blur_score";
    let pairs = [
        (
            format!("/v1/jobs/{job_id}"),
            format!("/v1/jobs/{missing_job}"),
        ),
        (
            format!("/v1/jobs/{job_id}/result"),
            format!("/v1/jobs/{missing_job}/result"),
        ),
        (
            format!("/v1/jobs/{job_id}/artifacts"),
            format!("/v1/jobs/{missing_job}/artifacts"),
        ),
        (
            format!("/v1/datasets/{ds_id}"),
            format!("/v1/datasets/{missing_ds}"),
        ),
        (
            format!("/v1/datasets/{ds_id}/files/0"),
            format!("/v1/datasets/{missing_ds}/files/0"),
        ),
        (
            format!("{doc}/latest"),
            "/v1/devices/cam-9/documents/cam0/blur_score/latest".into(),
        ),
        (
            format!("{doc}/1"),
            "/v1/devices/cam-9/documents/cam0/blur_score/1".into(),
        ),
        (
            doc.into(),
            "/v1/devices/cam-9/documents/cam0/blur_score".into(),
        ),
    ];
    for (hidden, missing) in &pairs {
        let (a, pa) = get(&s, hidden, Some(&cam2)).await;
        let (b, pb) = get(&s, missing, Some(&cam2)).await;
        assert_eq!((a, b), (404, 404), "{hidden}: {pa} / {missing}: {pb}");
        assert_eq!(pa["code"], pb["code"], "{hidden}");
        assert_eq!(
            pa.as_object()
                .map(|o| o.keys().cloned().collect::<Vec<_>>()),
            pb.as_object()
                .map(|o| o.keys().cloned().collect::<Vec<_>>()),
            "{hidden}: same problem shape"
        );
        // The owner and a fleet-wide reader see it.
        for t in [&cam1, &fleet] {
            let (st, v) = get(&s, hidden, Some(t)).await;
            assert_eq!(st, 200, "{hidden}: {v}");
        }
    }
    let (st, _, _) = call(
        &s,
        reqwest::Method::POST,
        &format!("/v1/jobs/{job_id}/cancel"),
        Some(&cam2),
        None,
    )
    .await;
    assert_eq!(st, 404);
    // Lists hold only what the token may see.
    let (_, devs) = get(&s, "/v1/devices", Some(&cam2)).await;
    assert_eq!(devs["total"], 0, "{devs}");
    let (_, devs) = get(&s, "/v1/devices", Some(&cam1)).await;
    assert_eq!(devs["items"][0]["serial"], "cam-1", "{devs}");
    let (_, jobs) = get(&s, "/v1/jobs", Some(&cam2)).await;
    assert!(
        jobs["items"].as_array().expect("items").is_empty(),
        "{jobs}"
    );
    let (_, datasets) = get(&s, "/v1/datasets", Some(&cam2)).await;
    assert!(
        datasets["items"].as_array().expect("items").is_empty(),
        "{datasets}"
    );
    let (_, datasets) = get(&s, "/v1/datasets", Some(&cam1)).await;
    assert_eq!(datasets["items"].as_array().expect("items").len(), 1);
    let (_, docs) = get(&s, "/v1/devices/cam-1/documents", Some(&cam2)).await;
    assert!(
        docs["documents"].as_array().expect("docs").is_empty(),
        "{docs}"
    );
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn each_token_is_rate_limited_with_retry_after() {
    let s = start_with(|c| {
        c.auth = true;
        c.rate_limit_per_sec = 1;
        c.rate_limit_burst = 3;
    })
    .await;
    let admin = admin_token(&s).await;
    let other = create_token(&s, &admin, json!({"name": "other", "scope": "read"})).await;
    let mut limited = None;
    for _ in 0..6 {
        let (st, p, h) = call(&s, reqwest::Method::GET, "/v1/jobs", Some(&admin), None).await;
        if st == 429 {
            limited = Some((p, h));
            break;
        }
    }
    let (p, h) = limited.expect("the burst ran out");
    assert_eq!(p["code"], "rate_limited");
    let wait: u64 = h["retry-after"]
        .to_str()
        .expect("header")
        .parse()
        .expect("seconds");
    assert!((1..=2).contains(&wait), "{wait}");
    // Another token is not affected.
    let (st, _) = get(&s, "/v1/jobs", Some(&other)).await;
    assert_eq!(st, 200);
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cors_allows_only_the_configured_origins() {
    let s = start_with(|c| c.cors_origins = "https://dash.example.com".into()).await;
    let preflight = |origin: &'static str| {
        s.client
            .request(reqwest::Method::OPTIONS, s.url("/v1/jobs"))
            .header("origin", origin)
            .header("access-control-request-method", "POST")
            .header(
                "access-control-request-headers",
                "authorization,content-type",
            )
            .send()
    };
    let ok = preflight("https://dash.example.com")
        .await
        .expect("preflight");
    assert_eq!(
        ok.headers()["access-control-allow-origin"],
        "https://dash.example.com"
    );
    let other = preflight("https://evil.example.com")
        .await
        .expect("preflight");
    assert!(other.headers().get("access-control-allow-origin").is_none());
    s.stop().await;
}

#[test]
fn token_cli_makes_a_working_token_without_a_server() {
    let bin = caliper_bin();
    let dir = tempfile::tempdir().expect("dir");
    let out = std::process::Command::new(&bin)
        .args([
            "token",
            "create",
            "--scope",
            "admin",
            "--name",
            "first",
            "--data-dir",
        ])
        .arg(dir.path())
        .output()
        .expect("run");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let secret = String::from_utf8_lossy(&out.stdout).trim().to_owned();
    assert!(secret.starts_with("clp_") && secret.len() == 44, "{secret}");
    let list = std::process::Command::new(&bin)
        .args(["token", "list", "--data-dir"])
        .arg(dir.path())
        .output()
        .expect("run");
    let text = String::from_utf8_lossy(&list.stdout);
    assert!(text.contains("first") && text.contains(&secret[..12]) && !text.contains(&secret));
    let bad = std::process::Command::new(&bin)
        .args([
            "token",
            "create",
            "--scope",
            "root",
            "--name",
            "x",
            "--data-dir",
        ])
        .arg(dir.path())
        .output()
        .expect("run");
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("not a scope"));
    // The token opens a server on that store.
    let server = spawn_caliper(&bin, dir.path(), &["--auth"]);
    let base = server.base.clone();
    let rt = tokio::runtime::Runtime::new().expect("rt");
    rt.block_on(async {
        let c = reqwest::Client::new();
        let r = c
            .get(format!("{base}/v1/tokens"))
            .send()
            .await
            .expect("get");
        assert_eq!(r.status(), 401);
        let r = c
            .get(format!("{base}/v1/tokens"))
            .bearer_auth(&secret)
            .send()
            .await
            .expect("get");
        assert_eq!(r.status(), 200);
    });
    drop(server);
}
