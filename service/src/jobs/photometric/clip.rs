//! The frames of a clip for `photometric_online`: decoded on the luma plane (the response is
//! fitted on what the camera wrote, so no colour conversion is added; limited-range samples
//! are expanded to full range as a player would show them), spread evenly over the clip, with
//! their presentation times for `times.txt`.
//!
//! The fit holds every frame in memory, so a clip is thinned to at most `max_frames` frames and
//! to [`PIXEL_BUDGET`] pixels in all (a 1080p clip keeps about 30 frames, a 640×480 one 200):
//! the document says which frames were used. Thinning keeps every `stride`-th frame; the
//! tracker needs overlap between consecutive kept frames, so slow camera motion suits it.

use caliper_core::Progress;
use caliper_core::photometric::{CompressionNote, PhotoImage, judge_compression};
use caliper_core::video::{FrameFormat, FrameOptions, FrameReader, VideoError, VideoLimits};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

use crate::jobs::spool::{SpooledClip, video_error};
use crate::jobs::{JobError, JobInput, ParamError};
use crate::store::DatasetFile;

/// Pixels of all kept frames together (about 130 MB as 16-bit samples).
pub const PIXEL_BUDGET: u64 = 64_000_000;

/// The range of the coded luma samples.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum LumaRange {
    /// What the clip says (`video.full_range`): full for Motion-JPEG and for H.264 that
    /// signals it, limited otherwise (the H.264 default).
    #[default]
    Auto,
    /// Black at 16, white at 235 (ITU-R BT.601/709 "video" range: the H.264 default and what
    /// cameras and ffmpeg write unless told otherwise).
    Limited,
    /// Black at 0, white at 255 (JPEG range, e.g. some phone and screen recordings).
    Full,
}

/// How a clip's frames are taken (video datasets only).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ClipFrames {
    /// Most frames fitted (default 200), spread evenly over the clip.
    pub max_frames: usize,
    /// Range of the coded luma (default `auto`: what the clip signals, limited when it says
    /// nothing): limited-range samples are expanded to full range (as a player shows them)
    /// before the fit, so that the response starts at black; they are kept at 16 bits so that
    /// no level is lost to rounding.
    pub luma_range: LumaRange,
    /// Only frames presented within `[start, end]` seconds (default: the whole clip).
    pub time_range: Option<[f64; 2]>,
}

impl Default for ClipFrames {
    fn default() -> Self {
        Self {
            max_frames: 200,
            luma_range: LumaRange::Auto,
            time_range: None,
        }
    }
}

/// The range the frames are read in: the asked one, or for `auto` what the clip signals
/// (`None`: nothing, so H.264's default, limited).
fn resolve_range(asked: LumaRange, signalled: Option<bool>) -> LumaRange {
    match (asked, signalled) {
        (LumaRange::Auto, Some(true)) => LumaRange::Full,
        (LumaRange::Auto, _) => LumaRange::Limited,
        (r, _) => r,
    }
}

impl ClipFrames {
    pub(super) fn check(&self) -> Result<(), ParamError> {
        if !(3..=5000).contains(&self.max_frames) {
            return Err(ParamError::new("clip.max_frames", "must be in [3, 5000]"));
        }
        if let Some([a, b]) = self.time_range
            && !(a.is_finite() && b.is_finite() && a >= 0.0 && a < b)
        {
            return Err(ParamError::new(
                "clip.time_range",
                "must be [start, end] seconds with 0 ≤ start < end",
            ));
        }
        Ok(())
    }
}

/// The kept frames, `(index, pts_s)` of each, and the `clip` section of the document.
pub(super) struct ClipSequence {
    pub images: Vec<PhotoImage>,
    pub frames: Vec<(u64, f64)>,
    pub summary: Value,
    /// How hard the clip was compressed, for the fit (also in `summary`).
    pub compression: CompressionNote,
}

/// Decodes the kept frames of the clip `f`.
pub(super) fn clip_sequence(
    input: &JobInput,
    f: &DatasetFile,
    params: &ClipFrames,
    progress: &dyn Progress,
) -> Result<ClipSequence, JobError> {
    let mut clip = SpooledClip::new(input, f)?;
    let limits = VideoLimits::default();
    let info = caliper_core::video::probe(clip.reader()?, &limits).map_err(video_error)?;
    let pixels = u64::from(info.width) * u64::from(info.height);
    let by_budget = (PIXEL_BUDGET / pixels.max(1)).max(3);
    let keep = (params.max_frames as u64).min(by_budget).max(1);
    // Frames in the asked time range, from the clip's mean rate.
    let in_range = match params.time_range {
        Some([a, b]) => {
            let span = (b.min(info.duration_s) - a).max(0.0);
            ((span * info.fps).ceil() as u64).clamp(1, info.frame_count.max(1))
        }
        None => info.frame_count,
    };
    let stride = in_range.div_ceil(keep).max(1);
    let options = FrameOptions {
        format: FrameFormat::Luma,
        stride,
        time_range: params.time_range.map(|[a, b]| (a, b)),
        ..FrameOptions::default()
    };
    let range = resolve_range(params.luma_range, info.full_range);
    let mut reader = FrameReader::open(clip.reader()?, &limits, options).map_err(video_error)?;
    let (mut images, mut frames, mut issues) = (Vec::new(), Vec::new(), Vec::new());
    while let Some(next) = reader.next_frame() {
        progress.check()?;
        let frame = match next {
            Ok(fr) => fr,
            Err(VideoError::Canceled) => return Err(JobError::Canceled),
            Err(e) => {
                issues.push(e.to_string());
                break;
            }
        };
        let g = frame.image.into_luma();
        let (width, height) = g.dimensions();
        images.push(PhotoImage::from_video_luma(
            width as usize,
            height as usize,
            g.into_raw(),
            range == LumaRange::Full,
        ));
        frames.push((frame.index, frame.pts_s));
        progress.report("decode", frames.len() as u64, keep);
    }
    issues.extend(reader.issues().iter().map(|i| i.message.clone()));
    if images.len() < 3 {
        return Err(JobError::Permanent {
            code: "invalid_input",
            message: format!(
                "{} frames of the clip could be decoded; the fit needs at least 3{}",
                images.len(),
                issues
                    .first()
                    .map(|i| format!(" ({i})"))
                    .unwrap_or_default()
            ),
        });
    }
    // Every frame a keyframe: Motion-JPEG or all-intra H.264, judged on the intra scale.
    let compression =
        judge_compression(info.bits_per_pixel, info.keyframe_count >= info.frame_count);
    let summary = json!({
        "video": info,
        "compression": compression,
        // The range the luma was read in, and whether the clip or the request chose it.
        "luma_range": {
            "range": range,
            "from": match params.luma_range {
                LumaRange::Auto if info.full_range.is_some() => "clip",
                LumaRange::Auto => "default",
                _ => "params",
            },
        },
        "stride": stride,
        "frames_used": frames.len(),
        "limited_by": if by_budget < params.max_frames as u64 { "pixel_budget" } else { "max_frames" },
        "frames": frames.iter().map(|(i, t)| json!({"index": i, "pts_s": t})).collect::<Vec<_>>(),
        "issues": issues,
    });
    Ok(ClipSequence {
        images,
        frames,
        summary,
        compression,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn auto_follows_the_clip_and_an_asked_range_wins() {
        assert_eq!(resolve_range(LumaRange::Auto, Some(true)), LumaRange::Full);
        assert_eq!(
            resolve_range(LumaRange::Auto, Some(false)),
            LumaRange::Limited
        );
        assert_eq!(resolve_range(LumaRange::Auto, None), LumaRange::Limited);
        assert_eq!(
            resolve_range(LumaRange::Limited, Some(true)),
            LumaRange::Limited
        );
        assert_eq!(resolve_range(LumaRange::Full, None), LumaRange::Full);
    }
}
