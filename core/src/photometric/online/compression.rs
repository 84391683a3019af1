//! What a clip's compression does to the online fit, judged from its coded bits per pixel.
//!
//! A video codec keeps the mean brightness of a block well but quantises its detail, and a
//! predicted frame carries a small brightness change (an auto-exposure step of 1–2 %) only as
//! a residual that the quantiser may round away. The fit samples pixels around tracked
//! corners, where both losses land, so a compressed clip gives a less accurate response and
//! biased exposures even when it looks clean. The sweep of `examples/photometric_sweep.rs`
//! (`SWEEP_CRF`: x264 High, yuv420p, the rendered frames encoded at several rate factors)
//! measured how much, against the coded bits per pixel and frame that the upload reports
//! (`VideoInfo::bits_per_pixel`); the levels below come from its tuning splits and were then
//! checked once on a held-out split (see the example's header).
//!
//! Bits per pixel is a proxy: the same rate buys more on a smooth, slowly moving scene than on
//! a detailed, fast one, and hardware encoders spend bits less well than x264. The judgement is
//! therefore a warning with the measured numbers, not a refusal.

use serde::{Deserialize, Serialize};

/// At or above this many coded bits per pixel and frame, compression costs the fit little
/// (x264 at rate factor 14 and below in the sweep).
pub const LIGHT_BITS_PER_PIXEL: f64 = 0.5;

/// Below this many coded bits per pixel and frame, the sweep's exposures miss the 2 % target
/// on most sequences (x264's default rate factor 23 lands here on 320×240 scenes).
pub const HEAVY_BITS_PER_PIXEL: f64 = 0.15;

/// How hard a clip was compressed, for the photometric fit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub enum CompressionLevel {
    /// At least [`LIGHT_BITS_PER_PIXEL`]: errors within about twice those of the frames
    /// themselves.
    Light,
    /// Between the two levels: the response and vignetting usually within the targets,
    /// exposures about 1 % off.
    Moderate,
    /// Below [`HEAVY_BITS_PER_PIXEL`]: exposures typically 2–5 % off, the response and
    /// vignetting often outside the targets.
    Heavy,
}

/// A clip's compression as the document reports it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct CompressionNote {
    /// Coded bits per pixel and frame of the clip.
    pub bits_per_pixel: f64,
    /// How hard that is for the fit.
    pub level: CompressionLevel,
    /// What to expect and what to do, for `moderate` and `heavy`.
    pub warning: Option<String>,
}

/// Judges a clip coded with `bits_per_pixel` bits per pixel and frame. A value that is not a
/// positive finite number (an index without sample sizes) is judged heavy, since nothing says
/// otherwise.
pub fn judge_compression(bits_per_pixel: f64) -> CompressionNote {
    let level = if !(bits_per_pixel.is_finite() && bits_per_pixel > 0.0) {
        CompressionLevel::Heavy
    } else if bits_per_pixel >= LIGHT_BITS_PER_PIXEL {
        CompressionLevel::Light
    } else if bits_per_pixel >= HEAVY_BITS_PER_PIXEL {
        CompressionLevel::Moderate
    } else {
        CompressionLevel::Heavy
    };
    let warning = match level {
        CompressionLevel::Light => None,
        CompressionLevel::Moderate => Some(format!(
            "the clip is coded with {bits_per_pixel:.2} bits per pixel: compression typically \
             puts the exposures about 1 % off and doubles the response error; record at a \
             higher bit rate (≥ {LIGHT_BITS_PER_PIXEL} bits per pixel) or upload the frames as \
             images for the best fit"
        )),
        CompressionLevel::Heavy => Some(format!(
            "the clip is coded with {bits_per_pixel:.2} bits per pixel: at this compression the \
             exposures are typically 2–5 % off and the response and vignetting can miss their \
             accuracy; record at a higher bit rate (≥ {LIGHT_BITS_PER_PIXEL} bits per pixel) or \
             upload the frames as images"
        )),
    };
    CompressionNote {
        bits_per_pixel,
        level,
        warning,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn levels_follow_the_rate_and_bad_values_are_heavy() {
        assert_eq!(judge_compression(2.0).level, CompressionLevel::Light);
        assert!(judge_compression(2.0).warning.is_none());
        let m = judge_compression(0.3);
        assert_eq!(m.level, CompressionLevel::Moderate);
        assert!(m.warning.as_deref().is_some_and(|w| w.contains("0.30")));
        assert_eq!(judge_compression(0.05).level, CompressionLevel::Heavy);
        for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert_eq!(
                judge_compression(bad).level,
                CompressionLevel::Heavy,
                "{bad}"
            );
        }
        // The boundaries belong to the better level.
        assert_eq!(
            judge_compression(LIGHT_BITS_PER_PIXEL).level,
            CompressionLevel::Light
        );
        assert_eq!(
            judge_compression(HEAVY_BITS_PER_PIXEL).level,
            CompressionLevel::Moderate
        );
    }
}
