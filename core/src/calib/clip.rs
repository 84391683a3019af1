//! Calibration views from a video clip: decode, score, detect.
//!
//! Detection is the expensive step (tens of milliseconds a frame at 1080p), and neighbouring
//! frames of a clip are nearly the same view, so not every frame is searched: the clip is cut
//! into windows of `⌈frames / max_candidates⌉` consecutive frames and only the sharpest frame
//! of each window (Laplacian variance of the luma plane) goes to the detector. Decoding runs on
//! the calling thread while the rayon pool detects earlier batches (at most two batches in
//! flight; past that the decoding thread detects the batch itself), so decoding and detection
//! overlap on every core. Frames stream through the decoder: one window's best frame and a few
//! batches being detected are all that is held, whatever the clip's length. [`super::select::select_views`]
//! then chooses among the candidates.

use std::io::{Read, Seek};

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::blur::laplacian_variance;
use crate::board::{TargetDetection, TargetOptions, TargetSpec, detect_target};
use crate::error::{CoreError, CoreResult};
use crate::io::Gray;
use crate::progress::Progress;
use crate::video::{
    FrameFormat, FrameOptions, FrameReader, VideoError, VideoInfo, VideoLimits, overlap_batches,
};

/// One frame the detector searched.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct ClipCandidate {
    /// Frame index in presentation order.
    pub index: u64,
    /// Presentation time, seconds.
    pub pts_s: f64,
    /// Laplacian variance of the luma plane (the sharpest of its window).
    pub laplacian_variance: f64,
    /// What the detector found.
    pub detection: TargetDetection,
}

/// The outcome of [`clip_candidates`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct ClipCandidates {
    /// The clip, as probed.
    pub video: VideoInfo,
    /// Frames decoded.
    pub frames_decoded: u64,
    /// Frames per window: only the sharpest of each window was searched.
    pub window: u64,
    /// Frame width and height (upright).
    pub image_size: [u32; 2],
    /// The searched frames, in time order.
    pub candidates: Vec<ClipCandidate>,
    /// Where decoding lost frames or stopped early (empty for a sound clip).
    pub issues: Vec<String>,
}

/// Most frames searched for the target by default.
pub const DEFAULT_MAX_CANDIDATES: usize = 150;

fn video_error(e: VideoError) -> CoreError {
    match e {
        VideoError::Canceled => CoreError::Canceled,
        other => CoreError::input(other.to_string()),
    }
}

struct Pending {
    index: u64,
    pts_s: f64,
    lap: f64,
    gray: Gray,
}

/// Decodes `r`, keeps the sharpest frame of each window and searches those for `target`.
///
/// Errors: [`CoreError::InvalidInput`] for a clip that cannot be opened, has no decodable
/// frame or changes resolution, [`CoreError::InvalidParam`] for `max_candidates` outside
/// [1, 10 000], [`CoreError::Canceled`].
pub fn clip_candidates<R: Read + Seek>(
    r: R,
    limits: &VideoLimits,
    target: &TargetSpec,
    detect: &TargetOptions,
    max_candidates: usize,
    progress: &dyn Progress,
) -> CoreResult<ClipCandidates> {
    if !(1..=10_000).contains(&max_candidates) {
        return Err(CoreError::param(
            "max_candidates",
            format!("must be in [1, 10000], got {max_candidates}"),
        ));
    }
    target.validate()?;
    detect.validate()?;
    let options = FrameOptions {
        format: FrameFormat::Luma,
        ..FrameOptions::default()
    };
    let mut reader = FrameReader::open(r, limits, options).map_err(video_error)?;
    let info = reader.info().clone();
    let total = info.frame_count.max(1);
    let window = total.div_ceil(max_candidates as u64).max(1);
    // Frames detected together: enough to keep every core busy, few enough to stay small.
    let batch_len = 2 * rayon::current_num_threads().max(1);
    let found = std::sync::Mutex::new(Vec::new());
    // Batches are detected on the rayon pool while this thread decodes (`overlap_batches`).
    let detect_batch = |batch: Vec<Pending>| {
        let out: Vec<ClipCandidate> = batch
            .into_par_iter()
            .map(|p| ClipCandidate {
                index: p.index,
                pts_s: p.pts_s,
                laplacian_variance: p.lap,
                detection: detect_target(&p.gray, target, detect),
            })
            .collect();
        if let Ok(mut f) = found.lock() {
            f.extend(out);
        }
    };
    let mut issues = Vec::new();
    let mut size: Option<[u32; 2]> = None;
    let mut decoded = 0u64;
    let outcome: CoreResult<()> = overlap_batches(2, detect_batch, |hand_off| {
        let mut batch: Vec<Pending> = Vec::with_capacity(batch_len);
        let mut best: Option<Pending> = None;
        while let Some(next) = reader.next_frame() {
            progress.check()?;
            let frame = match next {
                Ok(f) => f,
                Err(VideoError::Canceled) => return Err(CoreError::Canceled),
                Err(e) => {
                    issues.push(e.to_string());
                    break;
                }
            };
            decoded += 1;
            let g = frame.image.into_luma();
            let (width, height) = g.dimensions();
            match size {
                None => size = Some([width, height]),
                Some(s) if s != [width, height] => {
                    return Err(CoreError::input(format!(
                        "frame {} is {width}×{height}, earlier frames {}×{}: one camera, one \
                         resolution",
                        frame.index, s[0], s[1]
                    )));
                }
                Some(_) => {}
            }
            let gray = Gray {
                width,
                height,
                data: g.into_raw(),
            };
            let lap = laplacian_variance(&gray);
            let this = Pending {
                index: frame.index,
                pts_s: frame.pts_s,
                lap,
                gray,
            };
            // A new window starts: its predecessor's best frame goes to the detector.
            let same_window = best
                .as_ref()
                .is_some_and(|b| b.index / window == this.index / window);
            if same_window {
                if best.as_ref().is_some_and(|b| this.lap > b.lap) {
                    best = Some(this);
                }
            } else if let Some(done) = best.replace(this) {
                batch.push(done);
                if batch.len() == batch_len {
                    hand_off(std::mem::replace(&mut batch, Vec::with_capacity(batch_len)));
                }
            }
            progress.report("reading frames", decoded, total);
        }
        batch.extend(best);
        hand_off(batch);
        Ok(())
    });
    outcome?;
    let mut candidates = found.into_inner().unwrap_or_default();
    candidates.sort_by_key(|c| c.index);
    issues.extend(reader.issues().iter().map(|i| i.message.clone()));
    let Some(image_size) = size else {
        return Err(CoreError::input(format!(
            "no frame of the clip could be decoded{}",
            issues.first().map(|i| format!(": {i}")).unwrap_or_default()
        )));
    };
    Ok(ClipCandidates {
        video: info,
        frames_decoded: decoded,
        window,
        image_size,
        candidates,
        issues,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::progress::NoProgress;

    /// A chessboard of 9×6 inner corners (square 16 px) drifting across a 320×240 frame, every fourth frame
    /// blurred.
    fn clip(frames: usize) -> Vec<u8> {
        let imgs: Vec<image::GrayImage> = (0..frames)
            .map(|k| {
                let (ox, oy) = (20.0 + 4.0 * k as f64, 30.0 + 2.0 * k as f64);
                let img = image::GrayImage::from_fn(320, 240, |x, y| {
                    let (u, v) = ((f64::from(x) - ox) / 16.0, (f64::from(y) - oy) / 16.0);
                    let inside = (-1.0..9.0).contains(&u) && (-1.0..6.0).contains(&v);
                    let black = inside && (u.floor() + v.floor()).rem_euclid(2.0) == 0.0;
                    image::Luma([if black { 30 } else { 220 }])
                });
                if k % 4 == 3 {
                    image::imageops::blur(&img, 3.0)
                } else {
                    img
                }
            })
            .collect();
        crate::video::encode_h264_mp4(&imgs, 10.0).expect("encode")
    }

    #[test]
    fn sharpest_frame_of_each_window_is_searched() {
        let data = clip(16);
        let target = TargetSpec::Chessboard {
            cols: 9,
            rows: 6,
            square: 1.0,
        };
        let c = clip_candidates(
            std::io::Cursor::new(data),
            &VideoLimits::default(),
            &target,
            &TargetOptions::default(),
            4,
            &NoProgress,
        )
        .expect("candidates");
        assert_eq!(c.frames_decoded, 16);
        assert_eq!(c.window, 4);
        assert_eq!(c.image_size, [320, 240]);
        assert_eq!(c.candidates.len(), 4);
        for (w, cand) in c.candidates.iter().enumerate() {
            assert_eq!(cand.index / 4, w as u64);
            assert_ne!(cand.index % 4, 3, "a blurred frame was picked: {cand:?}");
            assert_eq!(
                cand.detection.corners.len(),
                54,
                "{:?}",
                cand.detection.reason
            );
        }
    }

    #[test]
    fn bad_candidate_count_is_refused() {
        let e = clip_candidates(
            std::io::Cursor::new(Vec::new()),
            &VideoLimits::default(),
            &TargetSpec::Chessboard {
                cols: 8,
                rows: 5,
                square: 1.0,
            },
            &TargetOptions::default(),
            0,
            &NoProgress,
        )
        .expect_err("refused");
        assert!(e.to_string().contains("max_candidates"));
    }
}
