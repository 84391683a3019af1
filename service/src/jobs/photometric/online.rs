//! `photometric_online`: response, vignetting and per-frame exposures of an auto-exposure
//! image sequence (Bergmann et al. 2017), or of a video clip ([`super::clip`]).

use caliper_core::Progress;
use caliper_core::photometric::{
    Channels, InverseResponse, OnlineParams, dso, photometric_online, photometric_online_rgb, plot,
};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

use super::clip::{ClipFrames, clip_sequence};
use super::{
    decode_all, decode_all_rgb, permanent, response_artifacts, sorted_files, text_artifact,
    times_entries, vignette_artifacts,
};
use crate::jobs::{
    Artifact, CliContext, Export, JobError, JobInput, JobOutput, JsonParams, Kind, ParamError,
    RunError, to_value,
};
use crate::store::DatasetKind;

/// Parameters of `photometric_online`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields, default)]
pub struct OnlineJobParams {
    /// Time between frames, s, for the `times.txt` timestamps (default: frame index).
    pub frame_interval_s: Option<f64>,
    /// Fit options.
    pub options: OnlineParams,
    /// For a video dataset: how many frames are fitted (timestamps come from the clip).
    pub clip: ClipFrames,
}

/// `photometric_online`: response, vignetting and exposures of an auto-exposure sequence.
pub struct PhotometricOnline;

impl Kind for PhotometricOnline {
    const NAME: &'static str = "photometric_online";
    const SCHEMA: &'static str = "caliper.photometric/v1";
    const DATASET: DatasetKind = DatasetKind::Images;
    const ALSO_VIDEO: bool = true;
    const DESCRIPTION: &'static str = "Online photometric calibration of an auto-exposure image sequence or video clip (Bergmann et al. 2017): response (one per colour channel with options.channels rgb), vignetting (centre estimated when the data constrain it) and per-frame exposures; DSO pcalib.txt, vignette.png, times.txt.";
    const EXPORTS: &'static [Export] = super::EXPORTS;
    type Params = OnlineJobParams;
    type Cli = JsonParams;

    fn check(p: &mut OnlineJobParams) -> Result<(), ParamError> {
        p.options
            .validate()
            .map_err(|e| ParamError::from_core("options", e))?;
        if let Some(d) = p.frame_interval_s
            && !(d.is_finite() && d > 0.0)
        {
            return Err(ParamError::new(
                "frame_interval_s",
                "must be finite and > 0",
            ));
        }
        p.clip.check()
    }

    fn cli_params(a: &JsonParams, _: &CliContext<'_>) -> Result<Value, RunError> {
        a.value()
    }

    fn run(
        &self,
        p: OnlineJobParams,
        input: &JobInput,
        progress: &dyn Progress,
    ) -> Result<JobOutput, JobError> {
        let rgb = p.options.channels == Channels::Rgb;
        let clip = match crate::jobs::spool::single_clip(input) {
            // A clip is decoded on its luma plane only (see `clip`): no colour to fit.
            Some(_) if rgb => {
                return Err(JobError::Permanent {
                    code: "invalid_param",
                    message: "options.channels: rgb needs image frames (PNG/JPEG/TIFF); video \
                              clips are fitted on their luma plane, use luma"
                        .into(),
                });
            }
            Some(f) => Some(clip_sequence(input, f, &p.clip, progress)?),
            None => None,
        };
        let files = sorted_files(input);
        let (r, n_frames) = match &clip {
            Some(c) => (
                photometric_online(&c.images, &p.options, progress)?,
                c.images.len(),
            ),
            None if rgb => {
                let frames = decode_all_rgb(input, &files, progress)?;
                (
                    photometric_online_rgb(&frames, &p.options, progress)?,
                    frames.len(),
                )
            }
            None => {
                let frames = decode_all(input, &files, progress)?;
                (
                    photometric_online(&frames, &p.options, progress)?,
                    frames.len(),
                )
            }
        };
        let quality = json!({
            "frames": n_frames,
            "tracks": r.tracks,
            "mean_track_length": r.mean_track_length,
            "residual_rms_levels": r.diagnostics.residual_rms_levels,
            "converged": r.diagnostics.converged,
            "vignette_center_estimated": r.vignette_center.estimated,
            "vignette_model": r.vignette_choice.model,
            "exposure_parts": r.exposure_part_count(),
            "measured_levels": r.measured_levels,
            // A fisheye's image circle was found (`parameters.image_circle` says where).
            "image_circle": r.image_circle.is_some(),
            // A clip's compression (`clip.compression` says more); null for image frames.
            "clip_compression": clip.as_ref().map(|c| c.compression.level),
        });
        let mut artifacts = response_artifacts(&r.model)?;
        // One DSO pcalib per channel (DSO reads one response; pick the channel it images).
        for ch in r.channel_responses.iter().flatten() {
            let inv = InverseResponse::new(ch.inverse_256.clone())
                .map_err(|e| permanent(format!("channel {}: {e}", ch.channel)))?;
            artifacts.push(text_artifact(
                &format!("pcalib_{}.txt", ch.channel),
                dso::write_pcalib(&inv),
            ));
        }
        if let Some(v) = &r.model.vignette {
            artifacts.extend(vignette_artifacts(v)?);
        }
        // Exposures of a video whose tracks broke have no common scale across its parts
        // (`broken_tracks: per_part`): DSO's `times.txt` and the plot would show jumps that
        // are not in the camera, so they are left out; the parameters hold the ratios per part.
        if r.exposure_parts.is_none() {
            let entries = match &clip {
                // A clip's own times, frames named by their index in the clip.
                Some(c) => c
                    .frames
                    .iter()
                    .zip(&r.exposure_ratios)
                    .map(|(&(index, pts_s), &e)| dso::TimeEntry {
                        id: format!("{index:06}"),
                        timestamp: pts_s,
                        exposure_ms: e,
                    })
                    .collect(),
                None => times_entries(&files, &r.exposure_ratios, p.frame_interval_s),
            };
            artifacts.push(text_artifact("times.txt", dso::write_times(&entries)));
            let ts: Vec<f64> = entries.iter().map(|e| e.timestamp).collect();
            artifacts.push(Artifact::svg(
                "exposures.svg",
                plot::exposure_svg(&r.exposure_ratios, Some(&ts), None),
            ));
        }
        let mut parameters = to_value(&r)?;
        if let Some(c) = clip {
            parameters["clip"] = c.summary;
        }
        Ok(JobOutput {
            parameters,
            quality,
            artifacts,
        })
    }
}
