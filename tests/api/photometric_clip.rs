//! `photometric_online` on video clips: an H.264 clip fitted like its frames, with the clip's
//! timestamps, compression judged and parameters checked at the edge; a Motion-JPEG clip read in
//! the full range it is coded in.

use caliper_core::photometric::synth::{SynthCamera, render_ae_sequence};
use caliper_core::photometric::{CompressionLevel, PhotoImage, dso, judge_compression, metrics};
use serde_json::json;

use super::photometric::artifact_text;
use crate::common::*;

/// 8-bit rendered frames as grey images, for the clip writers.
fn gray_frames(frames: &[PhotoImage]) -> Vec<image::GrayImage> {
    frames
        .iter()
        .map(|f| {
            image::GrayImage::from_raw(
                f.width as u32,
                f.height as u32,
                f.data.iter().map(|&v| v as u8).collect(),
            )
            .expect("frame")
        })
        .collect()
}

/// An auto-exposure clip (the synthetic sequence encoded as H.264): `photometric_online` fits
/// it like the frames as images, with the clip's own timestamps in `times.txt`.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn photometric_online_fits_an_auto_exposure_clip() {
    let cam = SynthCamera::reference(160, 120, 11);
    let seq = render_ae_sequence(&cam, 80);
    let frames = gray_frames(&seq.frames);
    let mp4 = caliper_core::video::encode_h264_mp4(&frames, 20.0).expect("encode");
    let s = start().await;
    let (st, ds, _) = s.upload(vec![("ae.mp4", mp4)]).await;
    assert_eq!(st, 201, "{ds}");
    // Every second frame (max_frames 40 of 80); Caliper's encoder stores grey levels as
    // full-range luma.
    let id = s
        .job(json!({"kind": "photometric_online", "dataset": ds["id"], "params": {"clip": {"max_frames": 40, "luma_range": "full"}}}))
        .await;
    let done = s.wait_terminal(&id).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    let (_, doc) = s.get_json(&format!("/v1/jobs/{id}/result")).await;
    let clip = &doc["parameters"]["clip"];
    assert_eq!(clip["stride"], 2, "{clip}");
    assert_eq!(clip["frames_used"], 40, "{clip}");
    // The clip's compression, judged from its coded bits per pixel (the same number as the
    // upload's), in the parameters and as a level in the quality.
    let bpp = clip["video"]["bits_per_pixel"].as_f64().unwrap_or(f64::NAN);
    assert_eq!(
        clip["compression"]["bits_per_pixel"].as_f64(),
        Some(bpp),
        "{clip}"
    );
    let level = judge_compression(bpp, false).level;
    assert_eq!(clip["compression"]["level"], json!(level), "{clip}");
    assert_eq!(doc["quality"]["clip_compression"], json!(level), "{doc}");
    assert_eq!(
        clip["compression"]["warning"].is_string(),
        level != CompressionLevel::Light,
        "{clip}"
    );
    let times = dso::read_times(&artifact_text(&s, &id, "times.txt").await).expect("times.txt");
    assert_eq!(times.len(), 40);
    assert_eq!(times[1].id, "000002");
    assert!((times[1].timestamp - 0.1).abs() < 1e-6, "{:?}", times[1]);
    let pcalib = artifact_text(&s, &id, "pcalib.txt").await;
    let inv = dso::read_pcalib(&pcalib).expect("pcalib");
    let (alpha, resp_rmse) = metrics::gamma_align(&inv, &cam.response.inverse(256));
    assert!(resp_rmse < 0.03, "response RMSE {resp_rmse} (α {alpha})");
    let truth: Vec<f64> = seq.exposures.iter().step_by(2).copied().collect();
    let fit: Vec<f64> = times.iter().map(|e| e.exposure_ms).collect();
    let exp_err = metrics::exposure_error_pct(&fit, &truth, alpha);
    assert!(exp_err < 8.0, "exposure RMS error {exp_err} %");
    // Out-of-range clip parameters are refused at the edge.
    let (st, body) = s
        .post_json(
            "/v1/jobs",
            &json!({"kind": "photometric_online", "dataset": ds["id"], "params": {"clip": {"max_frames": 1}}}),
        )
        .await;
    assert_eq!(st, 422, "{body}");
    assert_eq!(body["field"], "params.clip.max_frames", "{body}");
    s.stop().await;
}

/// A Motion-JPEG clip (what USB cameras deliver): its samples are full range, and the default
/// `luma_range: auto` reads them so; taken as limited range, the darkest and brightest levels
/// would be clipped and the exposures come out far off.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn photometric_online_reads_a_motion_jpeg_clip_in_full_range() {
    let cam = SynthCamera::reference(160, 120, 11);
    let seq = render_ae_sequence(&cam, 60);
    let frames = gray_frames(&seq.frames);
    let mov = caliper_core::video::encode_mjpeg_mov(&frames, 20.0, 95).expect("encode");
    let s = start().await;
    let (st, ds, _) = s.upload(vec![("ae.mov", mov)]).await;
    assert_eq!(st, 201, "{ds}");
    assert_eq!(ds["files"][0]["video"]["full_range"], true, "{ds}");
    let id = s
        .job(json!({"kind": "photometric_online", "dataset": ds["id"]}))
        .await;
    let done = s.wait_terminal(&id).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    let (_, doc) = s.get_json(&format!("/v1/jobs/{id}/result")).await;
    let clip = &doc["parameters"]["clip"];
    assert_eq!(
        clip["luma_range"],
        json!({"range": "full", "from": "clip"}),
        "{clip}"
    );
    // Every frame of a Motion-JPEG clip is coded alone: judged on the intra-only scale.
    let bpp = clip["video"]["bits_per_pixel"].as_f64().unwrap_or(f64::NAN);
    assert_eq!(
        clip["compression"]["level"],
        json!(judge_compression(bpp, true).level),
        "{clip}"
    );
    let times = dso::read_times(&artifact_text(&s, &id, "times.txt").await).expect("times.txt");
    assert_eq!(times.len(), 60);
    let inv = dso::read_pcalib(&artifact_text(&s, &id, "pcalib.txt").await).expect("pcalib");
    let (alpha, resp_rmse) = metrics::gamma_align(&inv, &cam.response.inverse(256));
    assert!(resp_rmse < 0.03, "response RMSE {resp_rmse} (α {alpha})");
    let fit: Vec<f64> = times.iter().map(|e| e.exposure_ms).collect();
    let exp_err = metrics::exposure_error_pct(&fit, &seq.exposures, alpha);
    assert!(exp_err < 8.0, "exposure RMS error {exp_err} %");
    s.stop().await;
}
