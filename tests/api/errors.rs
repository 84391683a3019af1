//! Bad input: every case gets a 4xx problem+json with a stable code, and leaves nothing
//! behind (no dataset, no blob, no temporary file).

use std::io::{Cursor, Write};

use serde_json::{Value, json};

use crate::common::*;
use crate::datasets::crc32;

async fn assert_clean(s: &TestServer) {
    let (_, list) = s.get_json("/v1/datasets").await;
    assert!(
        list["items"].as_array().unwrap().is_empty(),
        "no dataset recorded: {list}"
    );
    assert_eq!(
        count_files(&s.dir.path().join("data/blobs")),
        0,
        "no blob left"
    );
    assert_eq!(
        count_files(&s.dir.path().join("data/tmp")),
        0,
        "no temporary file left"
    );
}

fn assert_problem(status: u16, body: &Value, ct: &str, want_status: u16, code: &str) {
    assert_eq!(status, want_status, "{body}");
    assert_eq!(ct, "application/problem+json");
    assert_eq!(body["code"], code, "{body}");
    assert_eq!(body["type"], format!("/problems/{code}"));
    assert_eq!(body["status"], want_status);
}

fn huge_png_header() -> Vec<u8> {
    let mut p = png(&sharp_image(1, 1));
    p[16..20].copy_from_slice(&10_000u32.to_be_bytes());
    p[20..24].copy_from_slice(&10_000u32.to_be_bytes());
    let crc = crc32(&p[12..29]);
    p[29..33].copy_from_slice(&crc.to_be_bytes());
    p
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_uploads_are_refused_and_leave_nothing() {
    let s = start().await;
    let good = png(&sharp_image(64, 48));

    let mut truncated = jpeg(&sharp_image(64, 48));
    truncated.truncate(truncated.len() / 2);
    let (st, p, ct) = s
        .upload(vec![("ok.png", good.clone()), ("half.jpg", truncated)])
        .await;
    assert_problem(st, &p, &ct, 422, "corrupt_image");
    assert!(p["detail"].as_str().unwrap().contains("half.jpg"));

    let (st, p, ct) = s.upload(vec![("huge.png", huge_png_header())]).await;
    assert_problem(st, &p, &ct, 422, "image_too_large");

    let (st, p, ct) = s.upload(vec![("empty.png", Vec::new())]).await;
    assert_problem(st, &p, &ct, 422, "empty_upload");

    let r = s
        .client
        .post(s.url("/v1/datasets"))
        .header("content-type", "multipart/form-data; boundary=xyz")
        .body("--xyz--\r\n")
        .send()
        .await
        .unwrap();
    let st = r.status().as_u16();
    let p: Value = r.json().await.unwrap();
    assert_eq!((st, p["code"].as_str()), (422, Some("empty_upload")), "{p}");

    let (st, p, ct) = s
        .upload(vec![("notes.bin", vec![0u8, 1, 2, 3, 250, 251])])
        .await;
    assert_problem(st, &p, &ct, 422, "unsupported_file");

    let (st, p, ct) = s
        .upload(vec![("a.png", good.clone()), ("a.png", good.clone())])
        .await;
    assert_problem(st, &p, &ct, 422, "duplicate_name");

    let csv = b"#t,a,b,c,d,e,f\n1,2,3,4,5,6,7\n".to_vec();
    let (st, p, ct) = s
        .upload(vec![("a.png", good.clone()), ("imu.csv", csv)])
        .await;
    assert_problem(st, &p, &ct, 422, "mixed_dataset");

    let (st, p, ct) = s
        .upload(vec![(
            "imu.csv",
            b"hello,world\nthis is not imu data\n".to_vec(),
        )])
        .await;
    assert_problem(st, &p, &ct, 422, "invalid_imu_log");

    // Zip with a `../` entry.
    let mut w = zip::ZipWriter::new(Cursor::new(Vec::new()));
    let opts = zip::write::SimpleFileOptions::default();
    w.start_file("../evil.png", opts).unwrap();
    w.write_all(&good).unwrap();
    let evil = w.finish().unwrap().into_inner();
    let (st, p, ct) = s.upload(vec![("evil.zip", evil)]).await;
    assert_problem(st, &p, &ct, 422, "zip_unsafe_path");

    // Zip bomb: 64 MiB of zeros deflate to ~64 KiB (ratio ~1000, limit 200).
    let mut w = zip::ZipWriter::new(Cursor::new(Vec::new()));
    let opts = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Deflated)
        .large_file(false);
    w.start_file("zeros.png", opts).unwrap();
    let zeros = vec![0u8; 1 << 20];
    for _ in 0..64 {
        w.write_all(&zeros).unwrap();
    }
    let bomb = w.finish().unwrap().into_inner();
    assert!(bomb.len() < 1 << 20);
    let (st, p, ct) = s.upload(vec![("bomb.zip", bomb)]).await;
    assert_problem(st, &p, &ct, 422, "zip_bomb");

    // A zip that is not one.
    let (st, p, ct) = s
        .upload(vec![("broken.zip", b"PK\x03\x04garbage".to_vec())])
        .await;
    assert_problem(st, &p, &ct, 422, "corrupt_archive");

    // Not multipart at all.
    let r = s
        .client
        .post(s.url("/v1/datasets"))
        .json(&json!({"files": []}))
        .send()
        .await
        .unwrap();
    let st = r.status().as_u16();
    let ct = r.headers()["content-type"].to_str().unwrap().to_string();
    let p: Value = r.json().await.unwrap();
    assert_problem(st, &p, &ct, 415, "unsupported_media_type");
    assert_eq!(p["instance"], "/v1/datasets");

    assert_clean(&s).await;
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn oversize_upload_is_413() {
    let s = start_with(|c| c.max_upload_bytes = 200_000).await;
    let big = vec![7u8; 400_000];
    let (st, p, ct) = s.upload(vec![("big.png", big)]).await;
    assert_problem(st, &p, &ct, 413, "payload_too_large");
    assert_clean(&s).await;
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bad_job_requests_are_refused() {
    let s = start().await;
    let ds = s.dataset(vec![("a.png", png(&sharp_image(64, 48)))]).await;
    let cases = [
        (
            json!({"kind": "teleport", "dataset": ds}),
            422,
            "unknown_job_kind",
            Some("kind"),
        ),
        (
            json!({"kind": "blur_score", "dataset": ds, "params": {"k": "ten"}}),
            422,
            "invalid_param",
            Some("params.k"),
        ),
        (
            json!({"kind": "blur_score", "dataset": ds, "params": {"k": 0}}),
            422,
            "invalid_param",
            Some("params.k"),
        ),
        (
            json!({"kind": "blur_score", "dataset": ds, "params": {"sharpness": 1}}),
            422,
            "invalid_param",
            Some("params.sharpness"),
        ),
        (
            json!({"kind": "blur_score", "dataset": ds, "params": [1, 2]}),
            422,
            "invalid_param",
            Some("params"),
        ),
        (
            json!({"kind": "blur_score", "dataset": ds, "colour": "red"}),
            422,
            "invalid_body",
            None,
        ),
        (
            json!({"kind": "blur_score", "dataset": 42}),
            422,
            "invalid_body",
            Some("dataset"),
        ),
        (json!({"kind": "blur_score"}), 422, "invalid_body", None),
        (
            json!({"kind": "blur_score", "dataset": "01935f2c-7a4e-7cc2-9d1e-3b8a2f6c1d00"}),
            422,
            "unknown_dataset",
            Some("dataset"),
        ),
        (
            json!({"kind": "blur_score", "dataset": ds, "device": "../etc"}),
            422,
            "invalid_body",
            Some("device"),
        ),
    ];
    for (body, status, code, field) in cases {
        let r = s
            .client
            .post(s.url("/v1/jobs"))
            .json(&body)
            .send()
            .await
            .unwrap();
        let st = r.status().as_u16();
        let ct = r.headers()["content-type"].to_str().unwrap().to_string();
        let p: Value = r.json().await.unwrap();
        assert_problem(st, &p, &ct, status, code);
        if let Some(f) = field {
            assert_eq!(p["field"], f, "{body} → {p}");
        }
    }
    // Malformed JSON, wrong content type, oversize body.
    let r = s
        .client
        .post(s.url("/v1/jobs"))
        .header("content-type", "application/json")
        .body("{\"kind\": ")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 400);
    assert_eq!(r.json::<Value>().await.unwrap()["code"], "malformed_json");
    let r = s
        .client
        .post(s.url("/v1/jobs"))
        .header("content-type", "text/plain")
        .body("{}")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 415);
    let huge = format!("{{\"kind\": \"{}\"}}", "x".repeat(2 << 20));
    // A body somewhat over the limit is read and dropped before the 413, so the client
    // finishes writing and reads the answer (no broken pipe, no reset), every time. The
    // server then closes that connection: use a client of its own so the pooled connection
    // of `s.client` stays healthy.
    for _ in 0..4 {
        let r = reqwest::Client::new()
            .post(s.url("/v1/jobs"))
            .header("content-type", "application/json")
            .body(huge.clone())
            .send()
            .await
            .expect("the 413 is read, not a cut connection");
        assert_eq!(r.status(), 413);
        assert_eq!(
            r.headers().get("connection").map(|v| v.as_bytes()),
            Some(&b"close"[..])
        );
        assert_eq!(
            r.json::<Value>().await.unwrap()["code"],
            "payload_too_large"
        );
    }
    let r = s
        .client
        .post(s.url("/v1/jobs"))
        .header("Idempotency-Key", "")
        .json(&json!({"kind": "blur_score", "dataset": ds}))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 400);
    let (_, list) = s.get_json("/v1/jobs").await;
    assert!(
        list["items"].as_array().unwrap().is_empty(),
        "no job was created"
    );
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn unknown_routes_methods_and_ids_are_problems() {
    let s = start().await;
    for (method, path, status, code) in [
        ("GET", "/v2/nothing", 404, "route_not_found"),
        ("PUT", "/v1/jobs", 405, "method_not_allowed"),
        ("GET", "/v1/jobs/not-a-uuid", 404, "not_found"),
        (
            "GET",
            "/v1/jobs/01935f2c-7a4e-7cc2-9d1e-3b8a2f6c1d00",
            404,
            "not_found",
        ),
        (
            "GET",
            "/v1/datasets/01935f2c-7a4e-7cc2-9d1e-3b8a2f6c1d00",
            404,
            "not_found",
        ),
        (
            "GET",
            "/v1/devices/x/documents/cam0/blur_score/latest",
            404,
            "not_found",
        ),
    ] {
        let r = s
            .client
            .request(method.parse().unwrap(), s.url(path))
            .send()
            .await
            .unwrap();
        let st = r.status().as_u16();
        let ct = r.headers()["content-type"].to_str().unwrap().to_string();
        let p: Value = r.json().await.unwrap();
        assert_problem(st, &p, &ct, status, code);
        assert_eq!(p["instance"], path);
    }
    let (st, p) = s.get_json("/problems/zip_bomb").await;
    assert_eq!(st, 200);
    assert_eq!(p["status"], 422);
    s.stop().await;
}
