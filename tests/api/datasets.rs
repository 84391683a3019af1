//! Datasets: uploads of images, zips, 16-bit TIFF, IMU logs and video; listing; deletion.

use std::io::{Cursor, Write};

use serde_json::json;

use crate::common::*;

fn zip_of(entries: &[(&str, &[u8])]) -> Vec<u8> {
    let mut w = zip::ZipWriter::new(Cursor::new(Vec::new()));
    let opts = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Deflated);
    for (name, data) in entries {
        w.start_file(*name, opts).unwrap();
        w.write_all(data).unwrap();
    }
    w.finish().unwrap().into_inner()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn images_and_zips_are_stored_content_addressed() {
    let s = start().await;
    let a = png(&sharp_image(64, 48));
    let b = jpeg(&sharp_image(80, 60));
    let z = zip_of(&[
        ("set/c.png", &png(&box_blur(&sharp_image(64, 48), 3))),
        ("__MACOSX/._c.png", b"junk"),
        ("d.png", &a),
    ]);
    let (st, ds, _) = s
        .upload(vec![("a.png", a.clone()), ("b.jpg", b), ("set.zip", z)])
        .await;
    assert_eq!(st, 201, "{ds}");
    assert_eq!(ds["kind"], "images");
    let files = ds["files"].as_array().unwrap();
    let names: Vec<&str> = files.iter().map(|f| f["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["a.png", "b.jpg", "set/c.png", "d.png"]);
    assert_eq!(files[1]["media_type"], "image/jpeg");
    assert_eq!(files[1]["image"]["width"], 80);
    // a.png and d.png have the same content: one blob.
    assert_eq!(files[0]["sha256"], files[3]["sha256"]);
    let blobs = count_files(&s.dir.path().join("data/blobs"));
    assert_eq!(blobs, 3, "deduplicated blobs");
    let id = ds["id"].as_str().unwrap();
    let (st, got) = s.get_json(&format!("/v1/datasets/{id}")).await;
    assert_eq!(st, 200);
    assert_eq!(got["sha256"], ds["sha256"]);
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sixteen_bit_tiff_imu_log_and_video_are_accepted() {
    let s = start().await;
    let img16: image::ImageBuffer<image::Luma<u16>, Vec<u16>> =
        image::ImageBuffer::from_fn(40, 30, |x, y| image::Luma([(x * 1000 + y * 7) as u16]));
    let mut tiff = Cursor::new(Vec::new());
    img16.write_to(&mut tiff, image::ImageFormat::Tiff).unwrap();
    let (st, ds, _) = s.upload(vec![("deep.tiff", tiff.into_inner())]).await;
    assert_eq!(st, 201, "{ds}");
    assert_eq!(ds["files"][0]["image"]["bit_depth"], 16);

    let mut csv = String::from(
        "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y,w_RS_S_z,a_RS_S_x [m s^-2],a_RS_S_y,a_RS_S_z\n",
    );
    for i in 0..100 {
        csv.push_str(&format!(
            "{},0.001,-0.002,0.0005,0.01,0.02,9.81\n",
            1_000_000_000u64 + i * 5_000_000
        ));
    }
    let (st, ds, _) = s.upload(vec![("imu.csv", csv.clone().into_bytes())]).await;
    assert_eq!(st, 201, "{ds}");
    assert_eq!(ds["kind"], "imu_log");
    let mut gz = flate2_gzip(csv.as_bytes());
    let (st, ds, _) = s
        .upload(vec![("imu.csv.gz", std::mem::take(&mut gz))])
        .await;
    assert_eq!(st, 201, "{ds}");
    assert_eq!(ds["files"][0]["media_type"], "application/gzip");

    let mp4 = crate::video::clip(8, 64, 48);
    let (st, ds, _) = s.upload(vec![("clip.mp4", mp4)]).await;
    assert_eq!(st, 201, "{ds}");
    assert_eq!(ds["kind"], "video");
    assert_eq!(ds["files"][0]["media_type"], "video/mp4");
    assert_eq!(ds["files"][0]["video"]["frame_count"], 8, "{ds}");

    // A job kind refuses a dataset of the wrong kind.
    let (st, p) = s
        .post_json(
            "/v1/jobs",
            &json!({"kind": "rig_calibration", "dataset": ds["id"], "params": {"board": {"cols": 9, "rows": 6, "square": 0.025}}}),
        )
        .await;
    assert_eq!(st, 422);
    assert_eq!(p["code"], "dataset_kind_mismatch");
    let (_, list) = s.get_json("/v1/datasets?limit=2").await;
    assert_eq!(list["items"].as_array().unwrap().len(), 2);
    assert!(list["next_cursor"].is_string());
    s.stop().await;
}

pub fn flate2_gzip(data: &[u8]) -> Vec<u8> {
    // A stored (uncompressed) gzip member, written by hand to avoid a test dependency.
    let mut out = vec![0x1f, 0x8b, 8, 0, 0, 0, 0, 0, 0, 255];
    let mut rest = data;
    loop {
        let n = rest.len().min(65535);
        let last = n == rest.len();
        out.push(if last { 1 } else { 0 });
        out.extend_from_slice(&(n as u16).to_le_bytes());
        out.extend_from_slice(&(!(n as u16)).to_le_bytes());
        out.extend_from_slice(&rest[..n]);
        rest = &rest[n..];
        if last {
            break;
        }
    }
    out.extend_from_slice(&crc32(data).to_le_bytes());
    out.extend_from_slice(&(data.len() as u32).to_le_bytes());
    out
}

pub fn crc32(data: &[u8]) -> u32 {
    let mut crc = 0xFFFF_FFFFu32;
    for &b in data {
        crc ^= b as u32;
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn delete_is_refused_while_a_job_uses_the_dataset() {
    let s = start_with(|c| c.workers = 1).await;
    let files = slow_dataset(40);
    let ds = s.dataset(as_refs(&files)).await;
    let id = s.job(json!({"kind": "blur_score", "dataset": ds})).await;
    let r = s
        .client
        .delete(s.url(&format!("/v1/datasets/{ds}")))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 409);
    let p: serde_json::Value = r.json().await.unwrap();
    assert_eq!(p["code"], "dataset_in_use");
    let _ = s
        .post_json(&format!("/v1/jobs/{id}/cancel"), &json!({}))
        .await;
    s.wait_terminal(&id).await;
    let r = s
        .client
        .delete(s.url(&format!("/v1/datasets/{ds}")))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 204);
    let (st, _) = s.get_json(&format!("/v1/datasets/{ds}")).await;
    assert_eq!(st, 404);
    assert_eq!(
        count_files(&s.dir.path().join("data/blobs")),
        0,
        "blobs of the dataset are gone"
    );
    s.stop().await;
}

/// The optional `kind` form field: a matching kind is taken, a contradicting one, an unknown
/// one or a repeated one is refused before anything is stored.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_kind_field_is_checked_against_the_content() {
    use reqwest::multipart::{Form, Part};
    let s = start().await;
    let img = png(&sharp_image(32, 24));
    let send = |kinds: &'static [&'static str]| {
        let mut form = Form::new().part("file", Part::bytes(img.clone()).file_name("a.png"));
        for k in kinds {
            form = form.text("kind", *k);
        }
        s.client.post(s.url("/v1/datasets")).multipart(form).send()
    };
    let r = send(&["images"]).await.expect("request");
    assert_eq!(r.status().as_u16(), 201);
    for (kinds, code) in [
        (&["video"][..], "mixed_dataset"),
        (&["photos"][..], "invalid_body"),
        (&["images", "images"][..], "invalid_body"),
    ] {
        let r = send(kinds).await.expect("request");
        assert_eq!(r.status().as_u16(), 422, "{kinds:?}");
        let p: serde_json::Value = r.json().await.expect("problem");
        assert_eq!(p["code"], code, "{kinds:?}: {p}");
    }
    let (_, list) = s.get_json("/v1/datasets").await;
    assert_eq!(list["items"].as_array().map(Vec::len), Some(1), "{list}");
    s.stop().await;
}
