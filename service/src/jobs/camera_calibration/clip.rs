//! `camera_calibration` from a video clip: search the sharpest frame of each stretch of the
//! clip for the target (`caliper_core::calib::clip`), choose diverse, sharp, distinct views
//! (`caliper_core::calib::select_views`), then solve exactly as for stills. The document's
//! `clip` lists every searched frame with its index, time and why it was or was not used.

use caliper_core::Progress;
use caliper_core::calib::clip::{DEFAULT_MAX_CANDIDATES, clip_candidates};
use caliper_core::calib::{
    MIN_VIEWS, PlanarTarget, ViewCandidate, ViewDecision, ViewObservations, ViewSelection,
    select_views,
};
use caliper_core::video::VideoLimits;
use serde::{Deserialize, Serialize};
use serde_json::json;
use utoipa::ToSchema;

use super::{CameraCalibParams, Evidence, permanent, solve_and_document, target_of};
use crate::jobs::spool::SpooledClip;
use crate::jobs::{JobError, JobInput, JobOutput, ParamError, to_value};
use crate::store::DatasetFile;

/// How a clip's frames are searched and chosen (video datasets only).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields, default)]
pub struct ClipParams {
    /// Most frames searched for the target (default 150): the clip is cut into this many
    /// stretches and the sharpest frame of each is searched.
    pub max_candidates: usize,
    /// Most views in the solve (default 40), chosen for diversity of board pose and image
    /// coverage.
    pub max_views: usize,
    /// Views whose board outline differs by less than this share of the image diagonal from a
    /// chosen view are near-duplicates (default 0.02).
    pub min_difference: f64,
}

impl Default for ClipParams {
    fn default() -> Self {
        let s = ViewSelection::default();
        Self {
            max_candidates: DEFAULT_MAX_CANDIDATES,
            max_views: s.max_views,
            min_difference: s.min_difference,
        }
    }
}

impl ClipParams {
    /// The view selection these parameters and the blur policy stand for.
    fn selection(&self, p: &CameraCalibParams) -> ViewSelection {
        ViewSelection {
            max_views: self.max_views,
            min_difference: self.min_difference,
            min_relative_sharpness: if p.blur.exclude {
                p.blur.min_relative_sharpness
            } else {
                0.0
            },
        }
    }

    /// Range checks, naming the field.
    pub(super) fn check(&self, p: &CameraCalibParams) -> Result<(), ParamError> {
        if !(1..=2000).contains(&self.max_candidates) {
            return Err(ParamError::new(
                "clip.max_candidates",
                "must be in [1, 2000]",
            ));
        }
        self.selection(p)
            .validate()
            .map_err(|e| ParamError::from_core("clip", e))
    }
}

/// One searched frame, for the document.
#[derive(Debug, Serialize)]
struct FrameOutcome {
    /// `frame_NNNNNN`, the name of its view in `observations` and `calibration.views`.
    name: String,
    index: u64,
    pts_s: f64,
    laplacian_variance: f64,
    corners: usize,
    /// `used`, or why not.
    #[serde(flatten)]
    decision: Outcome,
}

#[derive(Debug, Serialize)]
#[serde(untagged)]
enum Outcome {
    Decided(ViewDecision),
    NoBoard {
        decision: &'static str,
        reason: String,
    },
}

fn frame_name(index: u64) -> String {
    format!("frame_{index:06}")
}

/// Calibrates from the one clip `f` of `input`.
pub(super) fn run_clip(
    p: &CameraCalibParams,
    input: &JobInput,
    f: &DatasetFile,
    progress: &dyn Progress,
) -> Result<JobOutput, JobError> {
    let board = target_of(p);
    let mut clip = SpooledClip::new(input, f)?;
    let found = clip_candidates(
        clip.reader()?,
        &VideoLimits::default(),
        &board,
        &p.detection,
        p.clip.max_candidates,
        progress,
    )?;
    let with_board: Vec<usize> = (0..found.candidates.len())
        .filter(|&i| !found.candidates[i].detection.corners.is_empty())
        .collect();
    let views: Vec<ViewCandidate> = with_board
        .iter()
        .map(|&i| ViewCandidate {
            corners: found.candidates[i].detection.corners.clone(),
            sharpness: found.candidates[i].laplacian_variance,
        })
        .collect();
    let size = (found.image_size[0], found.image_size[1]);
    let decisions = select_views(&views, &board, size, &p.clip.selection(p))?;
    let mut frames: Vec<FrameOutcome> = found
        .candidates
        .iter()
        .map(|c| FrameOutcome {
            name: frame_name(c.index),
            index: c.index,
            pts_s: c.pts_s,
            laplacian_variance: c.laplacian_variance,
            corners: c.detection.corners.len(),
            decision: Outcome::NoBoard {
                decision: "no_board",
                reason: c.detection.reason.clone().unwrap_or_default(),
            },
        })
        .collect();
    let mut observations = Vec::new();
    for (k, d) in decisions.into_iter().enumerate() {
        let i = with_board[k];
        let d = match d {
            // Refer to frames by their index in the clip, not in the candidate list.
            ViewDecision::NearDuplicate { of, difference } => ViewDecision::NearDuplicate {
                of: found.candidates[with_board[of]].index as usize,
                difference,
            },
            other => other,
        };
        if matches!(d, ViewDecision::Used { .. }) {
            let c = &found.candidates[i];
            observations.push(ViewObservations {
                name: frame_name(c.index),
                corners: c.detection.corners.clone(),
            });
        }
        frames[i].decision = Outcome::Decided(d);
    }
    if observations.len() < MIN_VIEWS {
        return Err(permanent(
            "no_solution",
            format!(
                "{} frames of {} decoded were searched, {} show a usable {}, {} distinct and \
                 sharp enough; at least {MIN_VIEWS} views are needed (film the board from more \
                 positions and angles, more slowly)",
                found.candidates.len(),
                found.frames_decoded,
                with_board.len(),
                PlanarTarget::describe(&board),
                observations.len(),
            ),
        ));
    }
    let count = |pred: fn(&Outcome) -> bool| frames.iter().filter(|f| pred(&f.decision)).count();
    let summary = json!({
        "searched": frames.len(),
        "with_board": with_board.len(),
        "used": observations.len(),
        "blurred": count(|o| matches!(o, Outcome::Decided(ViewDecision::Blurred { .. }))),
        "near_duplicate": count(|o| matches!(o, Outcome::Decided(ViewDecision::NearDuplicate { .. }))),
        "cap_reached": count(|o| matches!(o, Outcome::Decided(ViewDecision::CapReached))),
    });
    let clip_doc = json!({
        "video": found.video,
        "frames_decoded": found.frames_decoded,
        "window": found.window,
        "summary": summary,
        "frames": frames,
        "issues": found.issues,
    });
    let evidence = Evidence {
        looked_at: frames.len(),
        detected: with_board.len(),
        images: to_value(&frames)?,
        clip: Some(clip_doc),
    };
    solve_and_document(p, &board, &observations, size, evidence, progress)
}
