//! Which frames of a video clip `deblur` restores. Deblurring costs seconds a frame, so a job
//! restores a chosen few (at most [`MAX_CLIP_FRAMES`]), never a whole clip.

use serde::{Deserialize, Serialize};

use crate::error::{CoreError, CoreResult};

/// Most frames one `deblur` job restores from a clip.
pub const MAX_CLIP_FRAMES: usize = 50;

/// The frames of a clip to deblur.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub enum FramePick {
    /// Every n-th frame from the first (0, n, 2n, …).
    Every(u64),
    /// The frames shown at these times, seconds (the nearest frame at the clip's mean rate).
    Times(Vec<f64>),
    /// The frames `blur_score`'s default verdict calls blurred.
    Blurred,
}

impl FramePick {
    /// Errors naming the field (`frames`) for an empty or invalid choice.
    pub fn validate(&self) -> CoreResult<()> {
        match self {
            Self::Every(0) => Err(CoreError::param("frames.every", "must be at least 1")),
            Self::Times(t) if t.is_empty() || t.len() > MAX_CLIP_FRAMES => Err(CoreError::param(
                "frames.times",
                format!("give 1 to {MAX_CLIP_FRAMES} times"),
            )),
            Self::Times(t) if t.iter().any(|v| !(v.is_finite() && *v >= 0.0)) => Err(
                CoreError::param("frames.times", "times must be finite and ≥ 0 seconds"),
            ),
            _ => Ok(()),
        }
    }

    /// The frame indices for a clip of `frame_count` frames at `fps` (sorted, unique), or an
    /// error when more than [`MAX_CLIP_FRAMES`] would be restored. `Blurred` needs the scores
    /// and is resolved by the caller (this returns an empty list for it).
    pub fn indices(&self, frame_count: u64, fps: f64) -> CoreResult<Vec<u64>> {
        let out: Vec<u64> = match self {
            Self::Every(n) => {
                let n = (*n).max(1);
                let count = frame_count.div_ceil(n);
                if count > MAX_CLIP_FRAMES as u64 {
                    return Err(CoreError::input(format!(
                        "every {n}th frame of {frame_count} is {count} frames; at most \
                         {MAX_CLIP_FRAMES} per job: choose every {} or more",
                        frame_count.div_ceil(MAX_CLIP_FRAMES as u64)
                    )));
                }
                (0..count).map(|k| k * n).collect()
            }
            Self::Times(t) => {
                let last = frame_count.saturating_sub(1);
                let mut v: Vec<u64> = t
                    .iter()
                    .map(|s| ((s * fps).round().max(0.0) as u64).min(last))
                    .collect();
                v.sort_unstable();
                v.dedup();
                v
            }
            Self::Blurred => Vec::new(),
        };
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn picks_resolve_to_frame_indices() {
        assert_eq!(
            FramePick::Every(10).indices(35, 30.0).ok(),
            Some(vec![0, 10, 20, 30])
        );
        assert_eq!(
            FramePick::Times(vec![0.5, 0.51, 100.0])
                .indices(60, 30.0)
                .ok(),
            Some(vec![15, 59])
        );
        assert!(FramePick::Every(1).indices(1000, 30.0).is_err());
        assert!(FramePick::Every(0).validate().is_err());
        assert!(FramePick::Times(vec![f64::NAN]).validate().is_err());
        assert!(FramePick::Times(Vec::new()).validate().is_err());
    }
}
