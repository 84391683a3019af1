//! Targets described once for every job: `board_detection` (corners with ids, reasons, overlays)
//! and `camera_calibration` with a `target` instead of a `board`; impossible targets refused at
//! the edge naming the field.

use serde_json::json;

use crate::common::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn board_detection_reports_corners_reasons_and_overlays() {
    let s = start().await;
    let mut files = crate::camera::renders();
    files.truncate(3);
    let mut all = as_refs(&files);
    all.push((
        "blank.png",
        png(&image::GrayImage::from_pixel(
            320,
            240,
            image::Luma([128u8]),
        )),
    ));
    let ds = s.dataset(all).await;
    let target = json!({"type": "chessboard", "cols": 9, "rows": 6, "square": 0.025});
    let id = s
        .job(json!({"kind": "board_detection", "dataset": ds, "params": {"target": target}}))
        .await;
    let done = s.wait_terminal(&id).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    let (st, doc) = s.get_json(&format!("/v1/jobs/{id}/result")).await;
    assert_eq!(st, 200, "{doc}");
    let images = doc["parameters"]["images"].as_array().expect("images");
    let view = images
        .iter()
        .find(|i| i["name"] == "view00.png")
        .expect("view00");
    assert_eq!(view["corners_found"], 54, "{view}");
    let ids: Vec<u64> = view["corners"]
        .as_array()
        .expect("corners")
        .iter()
        .filter_map(|c| c["index"].as_u64())
        .collect();
    assert_eq!(ids, (0..54).collect::<Vec<u64>>());
    let blank = images
        .iter()
        .find(|i| i["name"] == "blank.png")
        .expect("blank");
    assert_eq!(blank["corners_found"], 0);
    assert!(
        blank["reason"].as_str().is_some_and(|r| !r.is_empty()),
        "{blank}"
    );
    assert_eq!(doc["quality"]["images_with_corners"], 3);
    let resp = reqwest::get(s.url(&format!("/v1/jobs/{id}/artifacts/view00.png.overlay.png")))
        .await
        .expect("get");
    assert_eq!(resp.status().as_u16(), 200);
    let overlay = image::load_from_memory(&resp.bytes().await.expect("bytes")).expect("png");
    assert_eq!((overlay.width(), overlay.height()), (640, 480));

    // Targets that cannot exist are refused before any work, naming the field.
    for (target, field) in [
        (
            json!({"type": "charuco", "squares_x": 5, "squares_y": 7, "square": 0.02, "marker": 0.03, "dictionary": "DICT_6X6_250"}),
            "params.target.marker",
        ),
        (
            json!({"type": "charuco", "squares_x": 12, "squares_y": 12, "square": 0.04, "marker": 0.03, "dictionary": "DICT_4X4_50"}),
            "params.target.dictionary",
        ),
        (
            json!({"type": "aprilgrid", "tag_rows": 6, "tag_cols": 6, "tag_size": 0.088, "tag_spacing": 1.5}),
            "params.target.tag_spacing",
        ),
    ] {
        let (st, p) = s
            .post_json(
                "/v1/jobs",
                &json!({"kind": "board_detection", "dataset": ds, "params": {"target": target}}),
            )
            .await;
        assert_eq!(st, 422, "{p}");
        assert_eq!(p["field"], field, "{p}");
    }
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn camera_calibration_takes_a_target_instead_of_a_board() {
    let s = start().await;
    let files = crate::camera::renders();
    let ds = s.dataset(as_refs(&files)).await;
    let target = json!({"type": "chessboard", "cols": 9, "rows": 6, "square": 0.025});
    let id = s
        .job(json!({"kind": "camera_calibration", "dataset": ds, "params": {"target": target}}))
        .await;
    let done = s.wait_terminal(&id).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    let (_, doc) = s.get_json(&format!("/v1/jobs/{id}/result")).await;
    let fx = doc["parameters"]["camera"]["fx"].as_f64().expect("fx");
    assert!((fx - 536.0).abs() < 1.5, "fx {fx}");
    // Both, or neither: refused.
    let (st, p) = s
        .post_json("/v1/jobs", &json!({"kind": "camera_calibration", "dataset": ds, "params": {"target": target, "board": {"cols": 9, "rows": 6, "square": 0.025}}}))
        .await;
    assert_eq!(st, 422, "{p}");
    let (st, _) = s
        .post_json(
            "/v1/jobs",
            &json!({"kind": "camera_calibration", "dataset": ds, "params": {}}),
        )
        .await;
    assert_eq!(st, 422);
    s.stop().await;
}
