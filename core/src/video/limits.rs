//! Resource limits checked when a clip is probed, before any frame is decoded.

use serde::{Deserialize, Serialize};

/// Bounds on what a clip may cost to decode. Checked by [`super::probe`] and again when a
/// [`super::FrameReader`] opens, so a hostile file is refused before any work is done.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct VideoLimits {
    /// Longest clip, seconds.
    pub max_duration_s: f64,
    /// Most pixels in one frame (width × height, coded size).
    pub max_pixels: u64,
    /// Most frames (samples of the video track).
    pub max_frames: u64,
    /// Most bytes of decoded 4:2:0 pictures over the whole clip (frames × w × h × 1.5): the
    /// decoding work, whatever the compressed size.
    pub max_decoded_bytes: u64,
    /// Largest single compressed sample; also bounds the read buffer.
    pub max_sample_bytes: u64,
}

impl Default for VideoLimits {
    /// Five minutes of 4K at 60 frames/s at most; 64 GiB of pictures; 32 MiB per sample.
    fn default() -> Self {
        Self {
            max_duration_s: 300.0,
            max_pixels: 4096 * 2304,
            max_frames: 18_000,
            max_decoded_bytes: 64 << 30,
            max_sample_bytes: 32 << 20,
        }
    }
}

/// Largest `moov` box read into memory: its size grows with the sample count (about 20 bytes
/// a sample), so this allows far more samples than any limit above.
pub(crate) const MAX_MOOV_BYTES: u64 = 64 << 20;
