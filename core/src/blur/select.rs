//! Which frames of a clip to keep as its sharpest (the parameters; the scoring is in
//! `clip`, built with the `video` feature).

use serde::{Deserialize, Serialize};

use crate::error::{CoreError, CoreResult};

/// Which frames to pick as the clip's sharpest.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct FrameSelection {
    /// How many frames to pick (1..=1000).
    pub count: usize,
    /// Least time between two picked frames, seconds (≥ 0).
    pub min_spacing_s: f64,
}

impl Default for FrameSelection {
    fn default() -> Self {
        Self {
            count: 10,
            min_spacing_s: 0.5,
        }
    }
}

impl FrameSelection {
    /// Check ranges; errors name the offending field.
    pub fn validate(&self) -> CoreResult<()> {
        if !(1..=1000).contains(&self.count) {
            return Err(CoreError::param(
                "select.count",
                "must be between 1 and 1000",
            ));
        }
        if !(self.min_spacing_s.is_finite() && (0.0..=3600.0).contains(&self.min_spacing_s)) {
            return Err(CoreError::param(
                "select.min_spacing_s",
                "must be within [0, 3600] seconds",
            ));
        }
        Ok(())
    }
}
