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
//! checked once on a held-out split (`soft-eval2`: moderate clips 9 of 11 within the targets,
//! exposure median 0.97 %; heavy ones 6 of 13, 1.8 %; the frames 12 of 12, 0.42 %).
//!
//! A clip whose every frame is coded alone (Motion-JPEG from USB cameras, all-intra H.264)
//! needs several times the bits: with x264 coding every frame as a keyframe at rate factor 23
//! (0.26–0.33 bits per pixel) the tuning sequences' exposures were 2.3 % off at the median,
//! worse than with predicted frames at a quarter of the rate (2.0 % at 0.06–0.16), since each
//! frame's quantisation error is new; such clips are judged on [`INTRA_LEVELS`].
//!
//! Bits per pixel is a proxy: the same rate buys more on a smooth, slowly moving scene than on
//! a detailed, fast one, and hardware encoders spend bits less well than x264. The judgement is
//! therefore a warning with the measured numbers, not a refusal.

use serde::{Deserialize, Serialize};

/// Where a clip's bits per pixel and frame stop costing the fit little (at or above `light`)
/// and start costing it its targets (below `heavy`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RateLevels {
    /// At or above: compression costs the fit little.
    pub light: f64,
    /// Below: the exposures miss the 2 % target on most sequences.
    pub heavy: f64,
}

/// Clips with predicted frames (H.264 as cameras and phones write it). On the sweep's tuning
/// splits (`tuning`, `soft`; x264 at rate factors 14, 18, 23, 28) cases at ≥ 0.5 bits per pixel
/// met all three accuracy targets on 19 of 22 (exposure median 0.67 %; the frames themselves
/// 0.30–0.39 %), at 0.15–0.5 on 24 of 27 (0.95 %), below 0.15 on 12 of 47 (2.4 %).
pub const PREDICTED_LEVELS: RateLevels = RateLevels {
    light: 0.5,
    heavy: 0.15,
};

/// Clips whose every frame is coded alone (Motion-JPEG, all-intra H.264): each frame pays for
/// its whole picture, so the same accuracy needs more bits. Set on the tuning sequences coded
/// as Motion-JPEG at ffmpeg qualities 2, 5 and 10 (1.1–1.9, 0.6–0.8 and 0.4–0.6 bits per
/// pixel: 9, 9 and 4 of 12 within the targets) and as all-intra x264 (0.26–0.33: 3 of 12).
pub const INTRA_LEVELS: RateLevels = RateLevels {
    light: 0.6,
    heavy: 0.45,
};

/// How hard a clip was compressed, for the photometric fit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub enum CompressionLevel {
    /// At least the `light` rate: errors within about twice those of the frames themselves.
    Light,
    /// Between the two levels: the response and vignetting usually within the targets,
    /// exposures about 1 % off.
    Moderate,
    /// Below the `heavy` rate: exposures typically 2 % off (up to 6 %), the response and
    /// vignetting often outside the targets.
    Heavy,
}

/// A clip's compression as the document reports it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct CompressionNote {
    /// Coded bits per pixel and frame of the clip.
    pub bits_per_pixel: f64,
    /// Whether every frame is coded alone (judged on [`INTRA_LEVELS`], else
    /// [`PREDICTED_LEVELS`]).
    pub intra_only: bool,
    /// How hard that is for the fit.
    pub level: CompressionLevel,
    /// What to expect and what to do, for `moderate` and `heavy`.
    pub warning: Option<String>,
}

/// Judges a clip coded with `bits_per_pixel` bits per pixel and frame, `intra_only` when every
/// frame is a keyframe. A value that is not a positive finite number (an index without sample
/// sizes) is judged heavy, since nothing says otherwise.
pub fn judge_compression(bits_per_pixel: f64, intra_only: bool) -> CompressionNote {
    let at = if intra_only {
        INTRA_LEVELS
    } else {
        PREDICTED_LEVELS
    };
    let level = if !(bits_per_pixel.is_finite() && bits_per_pixel > 0.0) {
        CompressionLevel::Heavy
    } else if bits_per_pixel >= at.light {
        CompressionLevel::Light
    } else if bits_per_pixel >= at.heavy {
        CompressionLevel::Moderate
    } else {
        CompressionLevel::Heavy
    };
    let what = if intra_only {
        "every frame coded alone"
    } else {
        "with predicted frames"
    };
    let advice = format!(
        "record at a higher bit rate (≥ {} bits per pixel for such a clip) or upload the frames \
         as images",
        at.light
    );
    let warning = match level {
        CompressionLevel::Light => None,
        CompressionLevel::Moderate => Some(format!(
            "the clip is coded with {bits_per_pixel:.2} bits per pixel ({what}): compression \
             typically puts the exposures about 1 % off and raises the response error by half; \
             for the best fit {advice}"
        )),
        CompressionLevel::Heavy => Some(format!(
            "the clip is coded with {bits_per_pixel:.2} bits per pixel ({what}): at this \
             compression the exposures are typically 2 % off (up to 6 %) and the response and \
             vignetting can miss their accuracy; {advice}"
        )),
    };
    CompressionNote {
        bits_per_pixel,
        intra_only,
        level,
        warning,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn levels_follow_the_rate_and_bad_values_are_heavy() {
        assert_eq!(judge_compression(2.0, false).level, CompressionLevel::Light);
        assert!(judge_compression(2.0, false).warning.is_none());
        let m = judge_compression(0.3, false);
        assert_eq!(m.level, CompressionLevel::Moderate);
        assert!(m.warning.as_deref().is_some_and(|w| w.contains("0.30")));
        assert_eq!(
            judge_compression(0.05, false).level,
            CompressionLevel::Heavy
        );
        for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert_eq!(
                judge_compression(bad, false).level,
                CompressionLevel::Heavy,
                "{bad}"
            );
        }
        // The boundaries belong to the better level.
        for (intra, at) in [(false, PREDICTED_LEVELS), (true, INTRA_LEVELS)] {
            assert_eq!(
                judge_compression(at.light, intra).level,
                CompressionLevel::Light
            );
            assert_eq!(
                judge_compression(at.heavy, intra).level,
                CompressionLevel::Moderate
            );
        }
    }

    #[test]
    fn intra_only_clips_need_more_bits() {
        // A rate that is light with predicted frames is not when every frame is coded alone.
        let rate = PREDICTED_LEVELS.light;
        assert_eq!(
            judge_compression(rate, false).level,
            CompressionLevel::Light
        );
        assert_ne!(judge_compression(rate, true).level, CompressionLevel::Light);
        // And where predicted frames start to be heavy, an intra-only clip is already heavy.
        assert_eq!(
            judge_compression(PREDICTED_LEVELS.heavy, true).level,
            CompressionLevel::Heavy
        );
        let note = judge_compression(rate, true);
        assert!(note.intra_only);
        assert!(
            note.warning
                .as_deref()
                .is_some_and(|w| w.contains("coded alone"))
        );
    }
}
