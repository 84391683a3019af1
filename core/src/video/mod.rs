//! Video clips: probing and frame-by-frame decoding of MP4/MOV files (H.264 through the
//! bundled OpenH264, Motion-JPEG through `image`), plus a small H.264 MP4 writer for tests.
//!
//! Everything streams from a `Read + Seek` source: the index (`moov`) is read, never the
//! media data as a whole, and frames are produced one at a time by a [`FrameReader`], so a
//! long high-resolution clip never sits in memory. Untrusted input is bounded by
//! [`VideoLimits`], checked before decoding starts; damaged clips decode up to the damage
//! and then report where they broke ([`VideoError::Truncated`]).
//!
//! Containers: ISO BMFF (MP4, MOV). RIFF AVI, Matroska and fragmented MP4 are refused by name
//! with a conversion hint. Codecs other than H.264 (8-bit 4:2:0 profiles) and Motion-JPEG are
//! reported as [`Codec::Unsupported`] and refused by [`probe`].

mod convert;
mod demux;
mod error;
mod h264;
mod limits;
mod matrix;
mod overlap;
mod prune;
mod reader;
mod reorder;
mod sample_table;
#[cfg(test)]
mod tests;
mod writer;

use std::io::{Read, Seek};

use serde::{Deserialize, Serialize};

pub use error::VideoError;
pub use limits::VideoLimits;
pub use matrix::YCbCr;
pub(crate) use overlap::overlap_batches;
pub use reader::{DecodeIssue, Frame, FrameFormat, FrameImage, FrameOptions, FrameReader};
pub use writer::{
    EncodableImage, WriterOptions, encode_h264_mp4, encode_h264_mp4_with, encode_mjpeg_mov,
};

/// The container format of a clip.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[serde(rename_all = "snake_case")]
pub enum Container {
    /// ISO base media file (MP4 and relatives).
    Mp4,
    /// QuickTime movie (`ftyp` brand `qt  `), the same box structure.
    QuickTime,
}

/// The codec of the video track.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Codec {
    /// H.264 / AVC in an 8-bit 4:2:0 profile OpenH264 decodes.
    H264 {
        /// Sample entry (`avc1` or `avc3`).
        fourcc: String,
        /// Profile name ("Constrained Baseline", "Main", "High", ...).
        profile: String,
        /// `profile_idc` of the stream.
        profile_idc: u8,
        /// Level, e.g. "4.0".
        level: String,
    },
    /// Motion-JPEG: every sample a JPEG image.
    Mjpeg {
        /// Sample entry (`jpeg`, `mjpa`, `mjpb`).
        fourcc: String,
    },
    /// Anything else; [`probe`] refuses it with [`VideoError::CodecUnsupported`].
    Unsupported {
        /// Sample entry four-character code (`hvc1`, `av01`, `vp09`, ...).
        fourcc: String,
        /// A readable codec name.
        name: String,
    },
}

/// What a clip is, read from its index without decoding a frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct VideoInfo {
    /// Container format.
    pub container: Container,
    /// Codec of the first video track.
    pub codec: Codec,
    /// Coded width, pixels.
    pub width: u32,
    /// Coded height, pixels.
    pub height: u32,
    /// Width of the frames as delivered (after the rotation).
    pub display_width: u32,
    /// Height of the frames as delivered (after the rotation).
    pub display_height: u32,
    /// Clockwise rotation applied to every frame: 0, 90, 180 or 270.
    pub rotation_deg: u16,
    /// Mean frame rate, frames per second.
    pub fps: f64,
    /// Duration of the track, seconds.
    pub duration_s: f64,
    /// Frames (samples) in the track.
    pub frame_count: u64,
    /// Sync samples (frames decodable on their own).
    pub keyframe_count: u64,
    /// Whether presentation order differs from decode order (B-frames).
    pub reordered: bool,
    /// Frames whose data lies inside the file, counted in decode order up to the first one
    /// that does not; less than `frame_count` for a cut file.
    pub frames_in_file: u64,
    /// Whether the file ends before the last frame's data.
    pub truncated: bool,
    /// Coded bits per pixel and frame over the frames in the file (the mean bitrate divided
    /// by the pixel rate): how hard the clip was compressed. Below about 0.25, exposure
    /// changes can come out understated, since predicted frames carry small brightness
    /// changes only as quantised residuals (the README's photometric limits).
    #[serde(default)]
    pub bits_per_pixel: f64,
    /// What the stream says about its sample range: `true` full (0–255; Motion-JPEG, whose
    /// frames are JFIF, and H.264 that signals `video_full_range_flag`), `false` limited
    /// (16–235, signalled), `null` when the stream does not say (H.264 then means limited).
    #[serde(default)]
    pub full_range: Option<bool>,
    /// H.264's `matrix_coefficients` (ITU-T H.264 table E-5: 1 BT.709, 5 or 6 BT.601, 9
    /// BT.2020), `null` when the stream does not say. RGB frames (deblurred clip frames) are
    /// converted with BT.709 for 1 and BT.601 otherwise (JFIF's for Motion-JPEG); luma does not
    /// depend on it.
    #[serde(default)]
    pub matrix_coefficients: Option<u8>,
}

/// Describes a clip from its index, whatever the codec; checks only the limits needed to
/// read the index safely (frame count, sample sizes). See [`probe`] for the upload check.
pub fn inspect<R: Read + Seek>(mut r: R, limits: &VideoLimits) -> Result<VideoInfo, VideoError> {
    let track = demux::open(&mut r, limits)?;
    Ok(info_of(&track))
}

/// Describes a clip and refuses what Caliper cannot decode: unsupported codecs, and clips
/// over `limits` (duration, pixels, frames, decoded bytes, sample size).
pub fn probe<R: Read + Seek>(r: R, limits: &VideoLimits) -> Result<VideoInfo, VideoError> {
    let info = inspect(r, limits)?;
    check(&info, limits)?;
    Ok(info)
}

/// Checks a described clip against the codec list and the limits.
pub(crate) fn check(info: &VideoInfo, limits: &VideoLimits) -> Result<(), VideoError> {
    if let Codec::Unsupported { fourcc, name } = &info.codec {
        return Err(VideoError::CodecUnsupported {
            fourcc: fourcc.clone(),
            name: name.clone(),
        });
    }
    if info.width == 0 || info.height == 0 {
        return Err(VideoError::Malformed(
            "the video track has a zero frame size".into(),
        ));
    }
    let pixels = u64::from(info.width) * u64::from(info.height);
    if pixels > limits.max_pixels {
        return Err(VideoError::TooLarge {
            width: info.width,
            height: info.height,
            max_pixels: limits.max_pixels,
        });
    }
    if info.frame_count > limits.max_frames {
        return Err(VideoError::TooManyFrames {
            frames: info.frame_count,
            max_frames: limits.max_frames,
        });
    }
    if info.duration_s.is_nan() || info.duration_s > limits.max_duration_s {
        return Err(VideoError::TooLong {
            duration_s: info.duration_s,
            max_s: limits.max_duration_s,
        });
    }
    let bytes = info
        .frame_count
        .saturating_mul(pixels.saturating_mul(3) / 2);
    if bytes > limits.max_decoded_bytes {
        return Err(VideoError::DecodedBytesOverLimit {
            bytes,
            max_bytes: limits.max_decoded_bytes,
        });
    }
    Ok(())
}

fn info_of(track: &demux::Track) -> VideoInfo {
    let signal = track.avcc.as_ref().and_then(h264::video_signal);
    let n = track.samples.len() as u64;
    let keyframes = track.samples.iter().filter(|s| s.keyframe).count() as u64;
    let ts = f64::from(track.timescale);
    let duration_s = track.duration as f64 / ts;
    let fps = if duration_s > 0.0 {
        n as f64 / duration_s
    } else {
        0.0
    };
    let reordered = track.samples.windows(2).any(|w| w[1].pts < w[0].pts);
    let frames_in_file = track
        .samples
        .iter()
        .take_while(|s| s.in_file(track.file_len))
        .count() as u64;
    // In f64: the index is not checked against the limits yet, and a hostile header's
    // width × height × frames can overflow any integer.
    let coded_bytes: f64 = track
        .samples
        .iter()
        .take(frames_in_file as usize)
        .map(|s| f64::from(s.size))
        .sum();
    let pixels = f64::from(track.width) * f64::from(track.height) * frames_in_file as f64;
    let bits_per_pixel = if pixels > 0.0 {
        coded_bytes * 8.0 / pixels
    } else {
        0.0
    };
    let (display_width, display_height) = if track.rotation_deg % 180 == 90 {
        (track.height, track.width)
    } else {
        (track.width, track.height)
    };
    VideoInfo {
        container: track.container,
        codec: track.codec.clone(),
        width: track.width,
        height: track.height,
        display_width,
        display_height,
        rotation_deg: track.rotation_deg,
        fps,
        duration_s,
        frame_count: n,
        keyframe_count: keyframes,
        reordered,
        frames_in_file,
        truncated: frames_in_file < n,
        bits_per_pixel,
        full_range: match &track.codec {
            Codec::Mjpeg { .. } => Some(true),
            _ => signal.map(|s| s.full_range),
        },
        matrix_coefficients: signal.and_then(|s| s.matrix_coefficients),
    }
}
