//! Video uploads: a clip is probed at upload (codec, profile, size, rotation, rate, counts
//! stored with the dataset); what Caliper cannot decode is refused with a problem that names
//! the cause (unsupported codec with the command that converts it, a cut file, junk).

use crate::common::*;

/// An H.264 clip of `n` frames (a moving gradient), made by Caliper's own encoder.
pub(crate) fn clip(n: usize, w: u32, h: u32) -> Vec<u8> {
    let frames: Vec<image::GrayImage> = (0..n)
        .map(|k| {
            image::GrayImage::from_fn(w, h, |x, y| {
                image::Luma([((x * 3 + y + 7 * k as u32) % 256) as u8])
            })
        })
        .collect();
    caliper_core::video::encode_h264_mp4(&frames, 30.0).expect("encode")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn clips_are_probed_at_upload_and_bad_ones_refused_by_name() {
    let s = start().await;
    let (st, ds, _) = s.upload(vec![("walk.mp4", clip(30, 160, 120))]).await;
    assert_eq!(st, 201, "{ds}");
    let v = &ds["files"][0]["video"];
    assert_eq!(v["codec"]["kind"], "h264", "{v}");
    assert_eq!(
        (v["width"].as_u64(), v["height"].as_u64()),
        (Some(160), Some(120)),
        "{v}"
    );
    assert_eq!(v["frame_count"], 30);
    assert!(
        (v["fps"].as_f64().unwrap_or(0.0) - 30.0).abs() < 0.01,
        "{v}"
    );
    assert!(
        (v["duration_s"].as_f64().unwrap_or(0.0) - 1.0).abs() < 0.05,
        "{v}"
    );
    assert!(v["keyframe_count"].as_u64().unwrap_or(0) >= 1);
    let (st, again) = s
        .get_json(&format!("/v1/datasets/{}", ds["id"].as_str().unwrap_or("")))
        .await;
    assert_eq!(st, 200);
    assert_eq!(again["files"][0]["video"], *v, "stored with the dataset");

    // A cut file: the index (at the end, after `mdat`) is gone.
    let whole = clip(30, 160, 120);
    let (st, p, _) = s
        .upload(vec![("cut.mp4", whole[..whole.len() / 2].to_vec())])
        .await;
    assert_eq!(st, 422, "{p}");
    assert!(
        p["code"].as_str().unwrap_or("").starts_with("video_"),
        "{p}"
    );
    // Junk after an `ftyp` box.
    let mut junk = vec![0, 0, 0, 0x18];
    junk.extend_from_slice(b"ftypmp42\0\0\0\0mp42isom");
    junk.extend(std::iter::repeat_n(7u8, 4096));
    let (st, p, _) = s.upload(vec![("junk.mp4", junk)]).await;
    assert_eq!(st, 422, "{p}");
    assert!(
        p["code"].as_str().unwrap_or("").starts_with("video_"),
        "{p}"
    );

    // The iPhone default (HEVC) names the codec and the conversion.
    match shared_clip("left_hevc.mp4") {
        Some(hevc) => {
            let (st, p, _) = s.upload(vec![("iphone.mov", hevc)]).await;
            assert_eq!(st, 422, "{p}");
            assert_eq!(p["code"], "video_codec_unsupported", "{p}");
            let detail = p["detail"].as_str().unwrap_or("");
            assert!(
                detail.contains("HEVC") && detail.contains("libx264"),
                "{detail}"
            );
        }
        None => eprintln!("\n*** NOT RUN: HEVC refusal (set CALIPER_SHARED_DATA) ***\n"),
    }
    s.stop().await;
}

fn shared_clip(name: &str) -> Option<Vec<u8>> {
    let root = std::env::var_os("CALIPER_SHARED_DATA")
        .map(std::path::PathBuf::from)
        .or_else(|| {
            Some(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data"))
        })?;
    std::fs::read(root.join("video").join(name)).ok()
}
