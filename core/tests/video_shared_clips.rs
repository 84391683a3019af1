//! The video decoder on the shared sample clips (`make_clips.py` in the shared data's
//! `video/` folder): B-frame ordering and timestamps, rotation, refused codecs and
//! containers, truncation. Each test says loudly when the shared data is absent and passes.
#![cfg(feature = "video")]

use std::io::Cursor;
use std::path::PathBuf;

use caliper_core::video::{
    Codec, Frame, FrameFormat, FrameImage, FrameOptions, FrameReader, VideoError, VideoLimits,
    inspect, probe,
};
use image::GrayImage;

fn shared(rel: &str) -> Option<PathBuf> {
    let roots = [
        std::env::var_os("CALIPER_SHARED_DATA").map(PathBuf::from),
        Some(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data")),
    ];
    let found = roots
        .into_iter()
        .flatten()
        .map(|r| r.join(rel))
        .find(|p| p.exists());
    if found.is_none() {
        eprintln!("\n*** NOT RUN: shared data {rel} not found (set CALIPER_SHARED_DATA) ***\n");
    }
    found
}

fn decode_all(data: &[u8], format: FrameFormat) -> (Vec<Frame>, Option<VideoError>) {
    let options = FrameOptions {
        format,
        ..Default::default()
    };
    let reader = FrameReader::open(Cursor::new(data), &VideoLimits::default(), options).unwrap();
    let (mut frames, mut err) = (Vec::new(), None);
    for item in reader {
        match item {
            Ok(f) => frames.push(f),
            Err(e) => err = Some(e),
        }
    }
    (frames, err)
}

fn luma(f: &Frame) -> &GrayImage {
    match &f.image {
        FrameImage::Luma(i) => i,
        FrameImage::Rgb(_) => panic!("luma expected"),
    }
}

fn psnr(a: &GrayImage, b: &GrayImage) -> f64 {
    let mse = a
        .as_raw()
        .iter()
        .zip(b.as_raw())
        .map(|(&p, &q)| (f64::from(p) - f64::from(q)).powi(2))
        .sum::<f64>()
        / a.as_raw().len() as f64;
    if mse == 0.0 {
        99.0
    } else {
        10.0 * (255.0f64 * 255.0 / mse).log10()
    }
}

/// `(pts_s, source, blurred)` per frame of `left_frames.json`.
fn truth(path: &std::path::Path) -> Vec<(f64, String, bool)> {
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap();
    v["frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|f| {
            (
                f["pts_s"].as_f64().unwrap(),
                f["source"].as_str().unwrap().to_string(),
                f["blurred"].as_bool().unwrap(),
            )
        })
        .collect()
}

#[test]
fn b_frame_clip_comes_out_in_presentation_order() {
    let (Some(high), Some(base), Some(json)) = (
        shared("video/left_high.mp4"),
        shared("video/left_baseline.mp4"),
        shared("video/left_frames.json"),
    ) else {
        return;
    };
    let truth = truth(&json);
    let high = std::fs::read(high).unwrap();
    let base = std::fs::read(base).unwrap();
    let info = probe(Cursor::new(&high), &VideoLimits::default()).unwrap();
    assert!(
        matches!(&info.codec, Codec::H264 { profile, .. } if profile == "High"),
        "{:?}",
        info.codec
    );
    assert!(info.reordered, "the High clip should have B-frames");
    assert_eq!(
        (info.width, info.height, info.frame_count),
        (640, 480, truth.len() as u64)
    );
    assert!((info.fps - 30.0).abs() < 0.01, "{}", info.fps);
    let binfo = probe(Cursor::new(&base), &VideoLimits::default()).unwrap();
    assert!(
        matches!(&binfo.codec, Codec::H264 { profile, .. } if profile == "Constrained Baseline")
    );
    assert!(!binfo.reordered);

    let (hf, herr) = decode_all(&high, FrameFormat::Luma);
    let (bf, berr) = decode_all(&base, FrameFormat::Luma);
    assert!(herr.is_none() && berr.is_none(), "{herr:?} {berr:?}");
    assert_eq!(hf.len(), truth.len());
    assert_eq!(bf.len(), truth.len());
    for (i, (h, b)) in hf.iter().zip(&bf).enumerate() {
        assert_eq!((h.index, b.index), (i as u64, i as u64));
        assert!(
            (h.pts_s - truth[i].0).abs() < 1e-6,
            "frame {i}: pts {} vs {}",
            h.pts_s,
            truth[i].0
        );
        assert!((b.pts_s - truth[i].0).abs() < 1e-6);
        let same = psnr(luma(h), luma(b));
        assert!(same > 32.0, "frame {i}: High vs Baseline PSNR {same:.1}");
        // A frame of another picture (another source, or blurred vs sharp) must differ more:
        // this catches frames that come out in decode order.
        for j in [i.saturating_sub(1), (i + 1).min(truth.len() - 1)] {
            if truth[j].1 != truth[i].1 || truth[j].2 != truth[i].2 {
                let other = psnr(luma(h), luma(&bf[j]));
                assert!(
                    other + 3.0 < same,
                    "frame {i} looks like frame {j}: {other:.1} vs {same:.1}"
                );
            }
        }
    }
}

#[test]
fn rotated_clip_is_delivered_upright() {
    let (Some(high), Some(rot)) = (
        shared("video/left_high.mp4"),
        shared("video/left_rot90.mp4"),
    ) else {
        return;
    };
    let rot = std::fs::read(rot).unwrap();
    let info = probe(Cursor::new(&rot), &VideoLimits::default()).unwrap();
    // make_clips.py's `rotate=90` tag is written by ffmpeg as a display matrix that turns
    // the picture a quarter turn counterclockwise, i.e. 270 degrees clockwise; ffmpeg's own
    // autorotation shows it that way too.
    assert_eq!(info.rotation_deg, 270);
    assert_eq!((info.display_width, info.display_height), (480, 640));
    let (rf, err) = decode_all(&rot, FrameFormat::Luma);
    assert!(err.is_none());
    let (hf, _) = decode_all(&std::fs::read(high).unwrap(), FrameFormat::Luma);
    assert_eq!(rf.len(), hf.len());
    for i in [0, 50, 116] {
        assert_eq!(
            luma(&rf[i]),
            &image::imageops::rotate270(luma(&hf[i])),
            "frame {i}"
        );
    }
}

#[test]
fn hevc_and_avi_are_refused_by_name() {
    if let Some(hevc) = shared("video/left_hevc.mp4") {
        let data = std::fs::read(hevc).unwrap();
        let e = probe(Cursor::new(&data), &VideoLimits::default()).unwrap_err();
        assert_eq!(e.code(), "video_codec_unsupported");
        let msg = e.to_string();
        assert!(msg.contains("hvc1") && msg.contains("HEVC"), "{msg}");
        assert!(
            msg.contains("ffmpeg -i in.mov -c:v libx264 out.mp4"),
            "{msg}"
        );
        let info = inspect(Cursor::new(&data), &VideoLimits::default()).unwrap();
        assert!(matches!(info.codec, Codec::Unsupported { ref fourcc, .. } if fourcc == "hvc1"));
        assert_eq!(info.frame_count, 117);
        assert!(
            FrameReader::open(
                Cursor::new(&data),
                &VideoLimits::default(),
                FrameOptions::default()
            )
            .is_err()
        );
    }
    if let Some(avi) = shared("video/left_mjpeg.avi") {
        let e = probe(std::fs::File::open(avi).unwrap(), &VideoLimits::default()).unwrap_err();
        assert_eq!(e.code(), "video_container_unsupported");
        assert!(e.to_string().contains("RIFF AVI"), "{e}");
    }
}

#[test]
fn auto_exposure_clip_times() {
    let Some(ae) = shared("video/ae_seq_seed0.mp4") else {
        return;
    };
    let data = std::fs::read(ae).unwrap();
    let info = probe(Cursor::new(&data), &VideoLimits::default()).unwrap();
    assert_eq!((info.width, info.height, info.frame_count), (320, 240, 200));
    let options = FrameOptions {
        stride: 7,
        ..Default::default()
    };
    let reader = FrameReader::open(Cursor::new(&data), &VideoLimits::default(), options).unwrap();
    let frames: Vec<Frame> = reader.map(|f| f.unwrap()).collect();
    assert_eq!(frames.len(), 29);
    for f in &frames {
        assert!(f.index.is_multiple_of(7));
        assert!((f.pts_s - f.index as f64 / 20.0).abs() < 1e-6);
    }
}

/// Moves `moov` in front of `mdat` (fixing the chunk offsets), as `-movflags +faststart`
/// does, so that a cut file still has its index.
fn faststart(data: &[u8]) -> Vec<u8> {
    use mp4_atom::{Decode, Encode};
    let mut boxes = Vec::new();
    let mut pos = 0;
    while pos + 8 <= data.len() {
        let size = u32::from_be_bytes(data[pos..pos + 4].try_into().unwrap()) as usize;
        boxes.push((data[pos + 4..pos + 8].to_vec(), pos, pos + size));
        pos += size;
    }
    let (_, ms, me) = boxes.iter().find(|b| b.0 == b"moov").unwrap().clone();
    let mut moov = mp4_atom::Moov::decode(&mut &data[ms..me]).unwrap();
    // mp4-atom may re-encode the index to another length than the original: measure it.
    let mut encoded = Vec::new();
    moov.encode(&mut encoded).unwrap();
    let shift = encoded.len() as u32;
    for t in &mut moov.trak {
        if let Some(stco) = t.mdia.minf.stbl.stco.as_mut() {
            for o in &mut stco.entries {
                if (*o as usize) < ms {
                    *o += shift;
                }
            }
        }
    }
    let mut out = Vec::new();
    let mut moved = false;
    for (kind, s, e) in &boxes {
        if kind == b"moov" {
            continue;
        }
        if kind == b"mdat" && !moved {
            moov.encode(&mut out).unwrap();
            moved = true;
        }
        out.extend_from_slice(&data[*s..*e]);
    }
    out
}

#[test]
fn cut_clips_decode_a_prefix_and_say_where_they_broke() {
    let Some(high) = shared("video/left_high.mp4") else {
        return;
    };
    let data = std::fs::read(high).unwrap();
    // As recorded (index at the end): a cut file has no index.
    let e = probe(
        Cursor::new(&data[..data.len() / 2]),
        &VideoLimits::default(),
    )
    .unwrap_err();
    assert!(
        matches!(e, VideoError::MoovMissing { mdat_cut: true }),
        "{e}"
    );
    assert!(e.to_string().contains("moov"));

    let fast = faststart(&data);
    assert_eq!(decode_all(&fast, FrameFormat::Luma).0.len(), 117);
    for frac in [0.1, 0.35, 0.6, 0.9, 0.99] {
        let cut = &fast[..(fast.len() as f64 * frac) as usize];
        let info = probe(Cursor::new(cut), &VideoLimits::default()).unwrap();
        assert!(info.truncated);
        let (frames, err) = decode_all(cut, FrameFormat::Luma);
        assert!(
            !frames.is_empty() && frames.len() < 117,
            "{frac}: {} frames",
            frames.len()
        );
        for w in frames.windows(2) {
            assert!(w[0].index < w[1].index && w[0].pts_s < w[1].pts_s);
        }
        match err {
            Some(VideoError::Truncated {
                after_frame,
                at_s,
                ref reason,
            }) => {
                assert_eq!(after_frame, frames.last().map(|f| f.index));
                assert_eq!(at_s, frames.last().map(|f| f.pts_s));
                assert!(reason.contains("ends"), "{reason}");
            }
            other => panic!("{frac}: expected Truncated, got {other:?}"),
        }
    }
}
