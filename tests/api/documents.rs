//! Documents: revisions per (device, sensor, kind), ETag and If-None-Match.

use serde_json::{Value, json};

use crate::common::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn device_documents_are_versioned_with_etags() {
    let s = start().await;
    let ds = s.dataset(vec![("a.png", png(&sharp_image(96, 72)))]).await;
    let body = json!({"kind": "blur_score", "dataset": ds, "device": "cam-0042", "sensor": "cam0"});
    let j1 = s.job(body.clone()).await;
    let done = s.wait_terminal(&j1).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    assert_eq!(done["document"]["rev"], 1);
    let base = "/v1/devices/cam-0042/documents/cam0/blur_score";

    let r = s
        .client
        .get(s.url(&format!("{base}/latest")))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    let etag1 = r.headers()["etag"].to_str().unwrap().to_string();
    let doc1: Value = r.json().await.unwrap();
    assert_eq!(doc1["rev"], 1);
    assert_eq!(doc1["device"], "cam-0042");
    assert_eq!(doc1["sensor"], "cam0");
    assert!(caliper_service::document::verify(&doc1));

    let r = s
        .client
        .get(s.url(&format!("{base}/latest")))
        .header("If-None-Match", &etag1)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 304);
    assert_eq!(r.headers()["etag"].to_str().unwrap(), etag1);

    // A second run files revision 2; revision 1 stays as it was.
    let j2 = s.job(json!({"kind": "blur_score", "dataset": ds, "device": "cam-0042", "sensor": "cam0", "params": {"k": 5}})).await;
    s.wait_terminal(&j2).await;
    let r = s
        .client
        .get(s.url(&format!("{base}/latest")))
        .header("If-None-Match", &etag1)
        .send()
        .await
        .unwrap();
    assert_eq!(
        r.status(),
        200,
        "a new revision does not match the old etag"
    );
    let doc2: Value = r.json().await.unwrap();
    assert_eq!(doc2["rev"], 2);
    assert_eq!(doc2["provenance"]["params"]["k"], 5);
    let (st, again1) = s.get_json(&format!("{base}/1")).await;
    assert_eq!(st, 200);
    assert_eq!(again1, doc1, "revisions are immutable");
    let (_, revs) = s.get_json(base).await;
    assert_eq!(revs.as_array().unwrap().len(), 2);
    let (_, all) = s.get_json("/v1/devices/cam-0042/documents").await;
    assert_eq!(all["documents"][0]["latest_rev"], 2);
    // The job's result is the same document as the revision it filed.
    let (_, res) = s.get_json(&format!("/v1/jobs/{j2}/result")).await;
    assert_eq!(res, doc2);
    let (st, p) = s.get_json(&format!("{base}/3")).await;
    assert_eq!(st, 404);
    assert_eq!(p["code"], "not_found");
    let (st, _) = s.get_json(&format!("{base}/two")).await;
    assert_eq!(st, 404);
    s.stop().await;
}
