//! Video decoding throughput in frames/s at 640×480 and 1920×1080, on clips made with the
//! crate's own writer: decode + luma; + Laplacian variance; and what a `blur_score` job on a
//! clip does (`score_clip`: Laplacian variance, β and the combined score of every frame,
//! scoring overlapped with decoding on the rayon pool). Next to `ffmpeg -i clip.mp4 -f null -`
//! on the same file when ffmpeg is on PATH. Target: ≥ 30 frames/s at 1080p with scoring.
//!
//! `cargo bench -p caliper-core --features video --bench video_decode`
//! Env: `CALIPER_BENCH_FRAMES` (frames per clip, default 150), `CALIPER_BENCH_RUNS` (3).

use std::io::Cursor;
use std::process::Command;
use std::time::Instant;

use caliper_core::blur::{BlurParams, laplacian_variance};
use caliper_core::io::Gray;
use caliper_core::video::{
    FrameOptions, FrameReader, VideoLimits, WriterOptions, encode_h264_mp4_with,
};
use image::{Rgb, RgbImage};

mod common;
use common::median;

/// A textured scene panning sideways, so motion compensation has real work to do.
fn scene(w: u32, h: u32, t: u32) -> RgbImage {
    RgbImage::from_fn(w, h, |x, y| {
        let xs = x + 4 * t;
        let checker = ((xs / 40) + (y / 40)).is_multiple_of(2);
        let n = (xs.wrapping_mul(2_654_435_761) ^ y.wrapping_mul(40_503)) >> 27;
        let base = if checker { 200 } else { 50 } as u32;
        Rgb([
            (base + n) as u8,
            ((base + xs / 8) % 256) as u8,
            ((y / 4 + n) % 256) as u8,
        ])
    })
}

/// Frames/s of decoding `clip` to luma, optionally scoring each frame.
fn decode_fps(clip: &[u8], score: bool) -> (f64, usize) {
    let t0 = Instant::now();
    let reader = FrameReader::open(
        Cursor::new(clip),
        &VideoLimits::default(),
        FrameOptions::default(),
    )
    .expect("open clip");
    let mut n = 0;
    let mut sink = 0.0;
    for f in reader {
        let f = f.expect("frame");
        if score {
            let img = f.image.into_luma();
            let (width, height) = img.dimensions();
            sink += laplacian_variance(&Gray {
                width,
                height,
                data: img.into_raw(),
            });
        }
        n += 1;
    }
    std::hint::black_box(sink);
    (n as f64 / t0.elapsed().as_secs_f64(), n)
}

/// Frames/s of the whole `blur_score` clip path.
fn score_clip_fps(clip: &[u8]) -> f64 {
    let t0 = Instant::now();
    let r = caliper_core::blur::clip::score_clip(
        Cursor::new(clip),
        &VideoLimits::default(),
        &BlurParams::default(),
        &caliper_core::NoProgress,
    )
    .expect("score clip");
    r.frames.len() as f64 / t0.elapsed().as_secs_f64()
}

fn ffmpeg_fps(path: &std::path::Path, frames: usize) -> Option<f64> {
    let t0 = Instant::now();
    let out = Command::new("ffmpeg")
        .args(["-v", "error", "-nostdin", "-threads", "2", "-i"])
        .arg(path)
        .args(["-f", "null", "-"])
        .output()
        .ok()?;
    out.status
        .success()
        .then(|| frames as f64 / t0.elapsed().as_secs_f64())
}

fn main() {
    let frames: u32 = std::env::var("CALIPER_BENCH_FRAMES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(150);
    let runs: usize = std::env::var("CALIPER_BENCH_RUNS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(3);
    let has_ffmpeg = Command::new("ffmpeg")
        .arg("-version")
        .output()
        .is_ok_and(|o| o.status.success());
    println!("video_decode: {frames} frames per clip, median of {runs} runs, 1 decoder thread");
    for (w, h) in [(640u32, 480u32), (1920, 1080)] {
        let t0 = Instant::now();
        let src: Vec<RgbImage> = (0..frames).map(|t| scene(w, h, t)).collect();
        let opts = WriterOptions {
            keyframe_interval: 60,
            ..Default::default()
        };
        let clip = encode_h264_mp4_with(&src, 30.0, &opts).expect("encode");
        drop(src);
        println!(
            "{w}x{h}: clip {:.1} MB made in {:.1} s",
            clip.len() as f64 / 1e6,
            t0.elapsed().as_secs_f64()
        );
        let path =
            std::env::temp_dir().join(format!("caliper_bench_{w}x{h}_{}.mp4", std::process::id()));
        std::fs::write(&path, &clip).expect("write clip");

        let ours: Vec<f64> = (0..runs).map(|_| decode_fps(&clip, false).0).collect();
        let scored: Vec<f64> = (0..runs).map(|_| decode_fps(&clip, true).0).collect();
        let full: Vec<f64> = (0..runs).map(|_| score_clip_fps(&clip)).collect();
        let (ours, scored, full) = (median(ours), median(scored), median(full));
        print!(
            "  caliper decode+luma {ours:7.1} frames/s   +laplacian {scored:7.1}   \
             blur_score (lap+β+combined, {} threads) {full:7.1} frames/s",
            rayon::current_num_threads()
        );
        if has_ffmpeg {
            let ff: Vec<f64> = (0..runs)
                .filter_map(|_| ffmpeg_fps(&path, frames as usize))
                .collect();
            if ff.is_empty() {
                print!("   ffmpeg failed");
            } else {
                let ff = median(ff);
                print!(
                    "   ffmpeg -f null {ff:7.1} frames/s   ours/ffmpeg {:.2}",
                    ours / ff
                );
            }
        } else {
            print!("   (ffmpeg not on PATH: no comparison)");
        }
        println!();
        let _ = std::fs::remove_file(&path);
    }
}
