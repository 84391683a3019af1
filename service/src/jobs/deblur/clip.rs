//! `deblur` on a video clip: the chosen frames (`params.frames`: every n-th, at given times,
//! or the ones the blur verdict flags) are decoded as RGB and restored one by one, each with
//! its own kernel for the blind method. At most [`MAX_CLIP_FRAMES`] frames per job.

use caliper_core::Progress;
use caliper_core::blur::BlurParams;
use caliper_core::deconv::{DeblurParams, FramePick, GyroLog, MAX_CLIP_FRAMES};
use caliper_core::imu::{ImuCsvParams, ImuLog, read_imu_log};
use caliper_core::video::{FrameFormat, FrameOptions, FrameReader, VideoError, VideoLimits};
use image::{DynamicImage, ImageFormat};
use serde_json::json;

use super::{permanent, restore};
use crate::jobs::spool::{SpooledClip, video_error};
use crate::jobs::{JobError, JobInput, JobOutput};
use crate::store::DatasetFile;

/// The IMU log of method gyro: the job's second dataset (or `--gyro` offline), parsed.
fn read_gyro_log(input: &JobInput, progress: &dyn Progress) -> Result<ImuLog, JobError> {
    let f = input.aux_files.first().ok_or_else(|| {
        permanent(
            "method gyro on a clip needs the IMU log: gyro_clip.imu_dataset (offline: --gyro)"
                .into(),
        )
    })?;
    let reader = crate::jobs::imu::open_log_file(input, f)?;
    read_imu_log(reader, &ImuCsvParams::default(), progress).map_err(|e| match e {
        caliper_core::CoreError::Canceled => JobError::Canceled,
        other => permanent(format!("IMU log {}: {other}", f.name)),
    })
}

/// Restores the frames `pick` chooses from the clip `f`.
pub(super) fn deblur_clip(
    p: &DeblurParams,
    pick: &FramePick,
    input: &JobInput,
    f: &DatasetFile,
    progress: &dyn Progress,
) -> Result<JobOutput, JobError> {
    let mut clip = SpooledClip::new(input, f)?;
    let limits = VideoLimits::default();
    let info = caliper_core::video::probe(clip.reader()?, &limits).map_err(video_error)?;
    let mut notes = Vec::new();
    let wanted: Vec<u64> = match pick {
        FramePick::Blurred => {
            let scores = caliper_core::blur::clip::score_clip(
                clip.reader()?,
                &limits,
                &BlurParams::default(),
                progress,
            )?;
            let flagged: Vec<u64> = scores
                .frames
                .iter()
                .filter(|s| s.blurred)
                .map(|s| s.index)
                .collect();
            if flagged.len() > MAX_CLIP_FRAMES {
                notes.push(format!(
                    "{} frames are flagged blurred; the first {MAX_CLIP_FRAMES} are restored \
                     (at most {MAX_CLIP_FRAMES} per job: use `times` for the others)",
                    flagged.len()
                ));
            }
            flagged.into_iter().take(MAX_CLIP_FRAMES).collect()
        }
        other => other
            .indices(info.frame_count, info.fps)
            .map_err(|e| permanent(e.to_string()))?,
    };
    if wanted.is_empty() {
        return Err(permanent(
            "no frame to restore: the blur verdict flags no frame of the clip".into(),
        ));
    }
    let options = FrameOptions {
        format: FrameFormat::Rgb,
        indices: Some(wanted.iter().copied().collect()),
        ..FrameOptions::default()
    };
    // Method gyro: the IMU log is parsed once; each frame's trace is cut out of it.
    let imu = match &p.gyro_clip {
        Some(_) => Some(read_gyro_log(input, progress)?),
        None => None,
    };
    let gyro_log = imu.as_ref().map(GyroLog::new);
    let mut reader = FrameReader::open(clip.reader()?, &limits, options).map_err(video_error)?;
    let (mut artifacts, mut frames) = (Vec::new(), Vec::new());
    let total = wanted.len() as u64;
    while let Some(next) = reader.next_frame() {
        progress.check()?;
        let frame = match next {
            Ok(fr) => fr,
            Err(VideoError::Canceled) => return Err(JobError::Canceled),
            Err(e) => {
                notes.push(format!("decoding stopped: {e}"));
                break;
            }
        };
        let img = match frame.image {
            caliper_core::video::FrameImage::Rgb(rgb) => DynamicImage::ImageRgb8(rgb),
            caliper_core::video::FrameImage::Luma(g) => DynamicImage::ImageLuma8(g),
        };
        let name = format!("frame_{:06}.png", frame.index);
        progress.report("deblur", frames.len() as u64, total);
        // Each frame's own exposure window on the log's clock, for method gyro.
        let per_frame;
        let frame_params = match (&p.gyro_clip, &gyro_log) {
            (Some(g), Some(log)) => {
                let trace = g.frame(log, frame.pts_s).map_err(|e| {
                    permanent(format!(
                        "frame {} at {:.3} s: {e}",
                        frame.index, frame.pts_s
                    ))
                })?;
                per_frame = DeblurParams {
                    gyro: Some(trace),
                    gyro_clip: None,
                    frames: None,
                    ..p.clone()
                };
                &per_frame
            }
            _ => p,
        };
        let mut entry = restore(
            &img,
            ImageFormat::Png,
            &name,
            frame_params,
            &name,
            &mut artifacts,
            progress,
        )?;
        if let Some(g) = &p.gyro_clip {
            entry["exposure_start_ns"] = json!(
                g.clip_start_ns
                    .saturating_add((frame.pts_s * 1e9).round() as i64)
            );
        }
        entry["index"] = json!(frame.index);
        entry["pts_s"] = json!(frame.pts_s);
        frames.push(entry);
    }
    notes.extend(reader.issues().iter().map(|i| i.message.clone()));
    if frames.is_empty() {
        return Err(permanent(format!(
            "none of the chosen frames could be decoded{}",
            notes.first().map(|n| format!(": {n}")).unwrap_or_default()
        )));
    }
    let quality = super::quality(&frames, p);
    Ok(JobOutput {
        parameters: json!({"method": p.method, "video": info, "frames_chosen": wanted,
                           "images": frames, "notes": notes}),
        quality,
        artifacts,
    })
}
