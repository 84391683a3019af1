//! Blur scores of every frame of a video clip, on the decoder's luma plane (no RGB round
//! trip), and a choice of the sharpest frames spread over the clip.
//!
//! The selection is greedy: frames not judged blurred (all frames if every one is), sharpest
//! first (Laplacian variance),
//! each kept only if it is at least `min_spacing_s` from every frame already kept, until
//! `count` frames are kept. Spacing matters more than the last bit of sharpness for what the
//! frames are used for (calibration views, photometric samples): neighbouring frames of a clip
//! are nearly the same view.

use std::io::{Read, Seek};
use std::sync::Mutex;

use rayon::prelude::*;

use serde::{Deserialize, Serialize};

use super::{
    BlurParams, FrameSelection, clip_reduction_factor, combined_score, laplacian_variance,
    svd_beta_reduced,
};
use crate::error::{CoreError, CoreResult};
use crate::io::Gray;
use crate::progress::Progress;
use crate::video::{
    FrameFormat, FrameOptions, FrameReader, VideoError, VideoInfo, VideoLimits, overlap_batches,
};

/// The scores of one frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct FrameScore {
    /// Frame index in presentation order.
    pub index: u64,
    /// Presentation time, seconds.
    pub pts_s: f64,
    /// Variance of the 3×3 Laplacian of the luma plane.
    pub laplacian_variance: f64,
    /// Singular-value feature β of the luma plane, box-reduced by `beta_reduction` of the
    /// report first when its short side exceeds 480 px (see `MAX_CLIP_BETA_SIDE`).
    pub svd_beta: f64,
    /// Combined blur score of the luma plane in [0, 1] (higher = blurrier; see
    /// [`super::combined_score`]).
    pub blur_score: f64,
    /// The verdict of the parameters' rule.
    pub blurred: bool,
}

/// The outcome of [`score_clip`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct ClipReport {
    /// The clip, as probed.
    pub video: VideoInfo,
    /// Every decoded frame, in presentation order.
    pub frames: Vec<FrameScore>,
    /// Indices (into `frames`) of the sharpest frames picked, in time order.
    pub selected: Vec<usize>,
    /// Frames judged blurred.
    pub blurred_count: usize,
    /// Integer factor by which frames were box-reduced before β (1: full resolution; frames
    /// over 480 px on the short side are reduced so that scoring keeps up with the clip).
    pub beta_reduction: usize,
    /// Where decoding stopped early or lost frames, for the user (empty for a sound clip).
    pub issues: Vec<String>,
}

fn video_error(e: VideoError) -> CoreError {
    match e {
        VideoError::Canceled => CoreError::Canceled,
        other => CoreError::input(other.to_string()),
    }
}

/// Scores every frame of a clip and picks the sharpest (see the module docs).
///
/// A clip damaged part-way is scored up to the break, which is listed in `issues`.
/// Errors: [`CoreError::InvalidInput`] for a clip that cannot be opened or has no decodable
/// frame, [`CoreError::InvalidParam`] for bad parameters, [`CoreError::Canceled`].
pub fn score_clip<R: Read + Seek>(
    r: R,
    limits: &VideoLimits,
    params: &BlurParams,
    progress: &dyn Progress,
) -> CoreResult<ClipReport> {
    let select = &params.select;
    params.validate()?;
    select.validate()?;
    let options = FrameOptions {
        format: FrameFormat::Gray,
        ..FrameOptions::default()
    };
    let mut reader = FrameReader::open(r, limits, options).map_err(video_error)?;
    let info = reader.info().clone();
    let total = info.frame_count;
    // Scoring (β above all) costs more than decoding at 1080p: it runs on the rayon pool
    // while this thread decodes (`overlap_batches`).
    let batch_len = 2 * rayon::current_num_threads().max(1);
    let scored = Mutex::new(Vec::new());
    let failed: Mutex<Option<CoreError>> = Mutex::new(None);
    let score_batch = |batch: Vec<(u64, f64, Gray)>| {
        let out: CoreResult<Vec<FrameScore>> = batch
            .into_par_iter()
            .map(|(index, pts_s, gray)| {
                progress.check()?;
                let lap = laplacian_variance(&gray);
                let f = clip_reduction_factor(gray.width, gray.height);
                let beta = svd_beta_reduced(&gray, params.k, f)?;
                let score = combined_score(&gray).score;
                Ok(FrameScore {
                    index,
                    pts_s,
                    laplacian_variance: lap,
                    svd_beta: beta,
                    blur_score: score,
                    blurred: params.is_blurred(lap, beta, score),
                })
            })
            .collect();
        match out {
            Ok(v) => {
                if let Ok(mut s) = scored.lock() {
                    progress.report("scoring frames", (s.len() + v.len()) as u64, total);
                    s.extend(v);
                }
            }
            Err(e) => {
                if let Ok(mut f) = failed.lock() {
                    f.get_or_insert(e);
                }
            }
        }
    };
    let mut issues = Vec::new();
    let outcome: CoreResult<()> = overlap_batches(2, score_batch, |hand_off| {
        let mut batch = Vec::with_capacity(batch_len);
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
            let g = frame.image.into_luma();
            let (width, height) = g.dimensions();
            let gray = Gray {
                width,
                height,
                data: g.into_raw(),
            };
            batch.push((frame.index, frame.pts_s, gray));
            if batch.len() == batch_len {
                hand_off(std::mem::replace(&mut batch, Vec::with_capacity(batch_len)));
            }
        }
        if !batch.is_empty() {
            hand_off(batch);
        }
        Ok(())
    });
    outcome?;
    if let Some(e) = failed.into_inner().ok().flatten() {
        return Err(e);
    }
    let mut frames = scored.into_inner().unwrap_or_default();
    frames.sort_by_key(|f| f.index);
    issues.extend(reader.issues().iter().map(|i| format!("{i:?}")));
    if frames.is_empty() {
        return Err(CoreError::input(format!(
            "no frame of the clip could be decoded{}",
            issues.first().map(|i| format!(": {i}")).unwrap_or_default()
        )));
    }
    let selected = pick(&frames, select);
    let beta_reduction = clip_reduction_factor(info.width, info.height);
    Ok(ClipReport {
        video: info,
        blurred_count: frames.iter().filter(|f| f.blurred).count(),
        beta_reduction,
        frames,
        selected,
        issues,
    })
}

/// Greedy sharpest-first selection with a minimum spacing (see the module docs).
fn pick(frames: &[FrameScore], select: &FrameSelection) -> Vec<usize> {
    // Only frames the verdict passes; all frames when it passes none (its thresholds depend
    // on the camera: a clip it calls blurred throughout still has its sharpest frames).
    let any_sharp = frames.iter().any(|f| !f.blurred);
    let mut order: Vec<usize> = (0..frames.len())
        .filter(|&i| !(any_sharp && frames[i].blurred))
        .collect();
    order.sort_by(|&a, &b| {
        frames[b]
            .laplacian_variance
            .total_cmp(&frames[a].laplacian_variance)
    });
    let mut kept: Vec<usize> = Vec::new();
    for i in order {
        if kept.len() == select.count {
            break;
        }
        let t = frames[i].pts_s;
        if kept
            .iter()
            .all(|&k| (frames[k].pts_s - t).abs() >= select.min_spacing_s)
        {
            kept.push(i);
        }
    }
    kept.sort_by(|&a, &b| frames[a].pts_s.total_cmp(&frames[b].pts_s));
    kept
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::progress::NoProgress;

    fn sharp() -> image::GrayImage {
        image::GrayImage::from_fn(160, 120, |x, y| {
            image::Luma([if (x / 8 + y / 8) % 2 == 0 { 40 } else { 210 }])
        })
    }

    /// A clip whose frames alternate between a sharp pattern and a blurred copy.
    fn clip() -> Vec<u8> {
        let sharp = sharp();
        let blurred = image::imageops::blur(&sharp, 4.0);
        // As RGB, so that the writer codes them in limited range as a camera would.
        let [sharp, blurred] = [sharp, blurred].map(|g| image::DynamicImage::from(g).to_rgb8());
        let frames: Vec<image::RgbImage> = (0..30)
            .map(|k| {
                if k % 3 == 0 {
                    sharp.clone()
                } else {
                    blurred.clone()
                }
            })
            .collect();
        crate::video::encode_h264_mp4(&frames, 30.0).expect("encode")
    }

    #[test]
    fn sharp_frames_are_found_and_picked_with_spacing() {
        let data = clip();
        let params = BlurParams {
            select: FrameSelection {
                count: 4,
                min_spacing_s: 0.2,
            },
            ..BlurParams::default()
        };
        let r = score_clip(
            std::io::Cursor::new(data),
            &VideoLimits::default(),
            &params,
            &NoProgress,
        )
        .expect("scores");
        assert_eq!(r.frames.len(), 30);
        assert!(r.issues.is_empty(), "{:?}", r.issues);
        // Every third frame is the sharp one: far higher Laplacian variance.
        for f in &r.frames {
            let sharp_frame = f.index % 3 == 0;
            let other = &r.frames[if sharp_frame { 1 } else { 0 }];
            if sharp_frame {
                assert!(
                    f.laplacian_variance > 5.0 * other.laplacian_variance,
                    "{f:?} vs {other:?}"
                );
            }
        }
        // The clip is coded in limited range; scored as a player shows it, a sharp frame's
        // Laplacian variance is the still's (read as coded it would be (219/255)² ≈ 0.74 of it).
        let still = sharp();
        let still = laplacian_variance(&Gray {
            width: still.width(),
            height: still.height(),
            data: still.into_raw(),
        });
        let ratio = r.frames[0].laplacian_variance / still;
        assert!((0.9..1.1).contains(&ratio), "clip/still {ratio}");
        assert_eq!(r.selected.len(), 4);
        for w in r.selected.windows(2) {
            assert!(r.frames[w[1]].pts_s - r.frames[w[0]].pts_s >= 0.2 - 1e-9);
        }
        assert!(r.selected.iter().all(|&i| r.frames[i].index % 3 == 0));
    }

    #[test]
    fn bad_selection_names_the_field() {
        let e = FrameSelection {
            count: 0,
            min_spacing_s: 0.0,
        }
        .validate()
        .expect_err("refused");
        assert!(e.to_string().contains("select.count"));
    }
}
