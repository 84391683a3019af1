//! Cross-check of the video reader against OpenCV's (runs only with `CALIPER_PYTHON` set to a
//! Python with cv2, whose FFmpeg backend follows the range and matrix a stream signals; says
//! loudly when skipped): clips written in every combination of limited/full range and
//! BT.601/BT.709 come back with the same colours as OpenCV reads them, and `FrameFormat::Gray`
//! gives the Laplacian variance OpenCV gives on its grey conversion (BT.601 clips, where
//! OpenCV's grey is the coded luma).
#![cfg(feature = "video")]

use std::io::Cursor;
use std::process::Command;

use caliper_core::blur::laplacian_variance;
use caliper_core::io::Gray;
use caliper_core::video::{
    FrameFormat, FrameImage, FrameOptions, FrameReader, VideoLimits, WriterOptions,
    encode_h264_mp4_with,
};
use image::{Rgb, RgbImage};

/// Reads every frame with OpenCV, writes them as PNG into `dir` and prints the Laplacian
/// variance of each frame's grey conversion.
const READ: &str = r#"
import cv2, json, sys
cap = cv2.VideoCapture(sys.argv[1])
out = []
while True:
    ok, frame = cap.read()
    if not ok:
        break
    cv2.imwrite(f"{sys.argv[2]}/f{len(out)}.png", frame)
    grey = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
    out.append(cv2.Laplacian(grey, cv2.CV_64F, ksize=1).var())
print(json.dumps(out))
"#;

/// A textured colour scene that moves with `t`, with saturated, black and white areas.
fn scene(t: u32) -> RgbImage {
    RgbImage::from_fn(96, 64, |x, y| {
        let u = x + 2 * t;
        match (u / 24 % 4, y / 32) {
            (0, 0) => Rgb([0, 0, 0]),
            (1, 0) => Rgb([255, 255, 255]),
            (2, 0) => Rgb([200, 40, 30]),
            (3, 0) => Rgb([20, 60, 220]),
            _ => {
                let v = ((u * 37 + y * 91) % 200 + 30) as u8;
                Rgb([v, 255 - v, (u * 5 % 256) as u8])
            }
        }
    })
}

#[test]
fn frames_match_opencv_in_every_range_and_matrix() {
    let Some(py) = std::env::var_os("CALIPER_PYTHON") else {
        eprintln!(
            "\n*** NOT RUN: set CALIPER_PYTHON to a Python with cv2 to cross-check video ***\n"
        );
        return;
    };
    let frames: Vec<RgbImage> = (0..4).map(scene).collect();
    let dir = std::env::temp_dir().join(format!("caliper-video-ocv-{}", std::process::id()));
    for (full_range, bt709) in [(false, false), (true, false), (false, true), (true, true)] {
        let options = WriterOptions {
            full_range,
            bt709,
            ..Default::default()
        };
        let clip = encode_h264_mp4_with(&frames, 10.0, &options).expect("encode");
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("temp dir");
        let path = dir.join("clip.mp4");
        std::fs::write(&path, &clip).expect("write clip");
        let out = Command::new(&py)
            .args(["-c", READ])
            .arg(&path)
            .arg(&dir)
            .output()
            .expect("run python");
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let theirs: Vec<f64> = serde_json::from_slice(&out.stdout).expect("laplacian json");
        assert_eq!(theirs.len(), frames.len(), "{options:?}");

        let read = |format| {
            let opts = FrameOptions {
                format,
                ..Default::default()
            };
            FrameReader::open(Cursor::new(&clip), &VideoLimits::default(), opts)
                .expect("open")
                .map(|f| f.expect("frame").image)
                .collect::<Vec<_>>()
        };
        for (i, img) in read(FrameFormat::Rgb).into_iter().enumerate() {
            let FrameImage::Rgb(ours) = img else {
                panic!("rgb expected")
            };
            let cv = image::open(dir.join(format!("f{i}.png")))
                .expect("opencv frame")
                .to_rgb8();
            let diff: f64 = ours
                .as_raw()
                .iter()
                .zip(cv.as_raw())
                .map(|(&a, &b)| (f64::from(a) - f64::from(b)).abs())
                .sum::<f64>()
                / ours.as_raw().len() as f64;
            eprintln!("{options:?} frame {i}: mean |ours − OpenCV| {diff:.2} levels");
            assert!(
                diff < 3.0,
                "{options:?} frame {i}: {diff:.2} levels from OpenCV"
            );
        }
        for (i, img) in read(FrameFormat::Gray).into_iter().enumerate() {
            let g = img.into_luma();
            let gray = Gray {
                width: g.width(),
                height: g.height(),
                data: g.into_raw(),
            };
            let ratio = laplacian_variance(&gray) / theirs[i];
            eprintln!("{options:?} frame {i}: Laplacian variance ours/OpenCV {ratio:.4}");
            // OpenCV's grey is BT.601 weights on its RGB, which is the coded luma only for
            // BT.601 clips; on a BT.709 clip of this colourful scene the two differ by ~4 %.
            if !bt709 {
                assert!(
                    (ratio - 1.0).abs() < 0.02,
                    "{options:?} frame {i}: ratio {ratio:.4}"
                );
            }
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}
