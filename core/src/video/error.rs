//! The errors of reading a clip, each with a stable code the service maps to a problem type.

/// Why a clip could not be probed or decoded (or where decoding stopped).
///
/// Messages are meant for the uploader: they name the cause and, where one exists, the fix.
/// [`VideoError::code`] is stable and machine-readable; the messages may be reworded.
#[derive(Debug, thiserror::Error)]
pub enum VideoError {
    /// The underlying reader failed (not a property of the clip).
    #[error("reading the clip failed: {0}")]
    Io(#[from] std::io::Error),

    /// Not an MP4/MOV file, or a container Caliper does not read (AVI, Matroska, ...).
    #[error("{container} is not a container Caliper reads; re-mux or convert it to MP4: ffmpeg -i in.{ext} -c:v libx264 out.mp4", ext = container_ext(container))]
    ContainerUnsupported {
        /// What the file looks like (`"RIFF AVI"`, `"Matroska/WebM"`, `"unknown"`).
        container: String,
    },

    /// No `moov` box: a recording that was cut before the index was written, or not a clip.
    #[error("the clip has no index (moov box){}; it was probably cut while recording. If the recording is complete, re-mux it: ffmpeg -i in.mp4 -c copy -movflags +faststart out.mp4", if *.mdat_cut { " and its media data (mdat) is cut short" } else { "" })]
    MoovMissing {
        /// Whether the file ends inside an `mdat` box (the index would have come after it).
        mdat_cut: bool,
    },

    /// Boxes or sample tables that contradict themselves or the file.
    #[error("malformed MP4: {0}")]
    Malformed(String),

    /// Movie fragments (`moof`/`trun`), as written by streaming recorders.
    #[error(
        "fragmented MP4 (movie fragments) is not supported; re-mux it: ffmpeg -i in.mp4 -c copy out.mp4"
    )]
    Fragmented,

    /// The file has no video track.
    #[error("the clip has no video track")]
    NoVideoTrack,

    /// A codec Caliper does not decode (HEVC, AV1, VP9, H.264 beyond 8-bit 4:2:0, ...).
    #[error(
        "the clip's video codec is {name} ({fourcc}), which Caliper does not decode; convert it to H.264: ffmpeg -i in.mov -c:v libx264 out.mp4"
    )]
    CodecUnsupported {
        /// The sample entry's four-character code (`hvc1`, `av01`, ...).
        fourcc: String,
        /// A readable name of the codec (`"HEVC (H.265)"`).
        name: String,
    },

    /// A track matrix that is not a rotation by a multiple of 90 degrees (shear, scale, mirror).
    #[error(
        "the track's display matrix [{a} {b}; {c} {d}] is not a rotation by 0, 90, 180 or 270 degrees"
    )]
    MatrixUnsupported {
        /// Matrix entries, 16.16 fixed point as stored.
        a: i32,
        /// See `a`.
        b: i32,
        /// See `a`.
        c: i32,
        /// See `a`.
        d: i32,
    },

    /// Longer than `VideoLimits::max_duration_s`.
    #[error("the clip lasts {duration_s:.1} s, over the limit of {max_s:.1} s")]
    TooLong {
        /// The clip's duration.
        duration_s: f64,
        /// The limit.
        max_s: f64,
    },

    /// More pixels per frame than `VideoLimits::max_pixels`.
    #[error("frames of {width}x{height} pixels are over the limit of {max_pixels} pixels")]
    TooLarge {
        /// Coded width.
        width: u32,
        /// Coded height.
        height: u32,
        /// The limit.
        max_pixels: u64,
    },

    /// More frames than `VideoLimits::max_frames`.
    #[error("the clip has {frames} frames, over the limit of {max_frames}")]
    TooManyFrames {
        /// Frames in the sample table.
        frames: u64,
        /// The limit.
        max_frames: u64,
    },

    /// Decoding every frame would produce more than `VideoLimits::max_decoded_bytes`.
    #[error(
        "decoding the clip would produce {bytes} bytes of pictures, over the limit of {max_bytes}"
    )]
    DecodedBytesOverLimit {
        /// Frames × bytes of one decoded 4:2:0 picture.
        bytes: u64,
        /// The limit.
        max_bytes: u64,
    },

    /// A single sample larger than `VideoLimits::max_sample_bytes`.
    #[error("sample {index} is {size} bytes, over the limit of {max_bytes}")]
    SampleTooLarge {
        /// Sample index in decode order.
        index: u64,
        /// Its size from `stsz`.
        size: u64,
        /// The limit.
        max_bytes: u64,
    },

    /// A sample of zero bytes: no picture can come from it.
    #[error("sample {index} is empty (zero bytes)")]
    EmptySample {
        /// Sample index in decode order.
        index: u64,
    },

    /// The file ends (or the bitstream breaks) before the last frame: frames up to
    /// `after_frame` were delivered.
    #[error("the clip is cut or corrupt{}: {reason}", describe_break(*.after_frame, *.at_s))]
    Truncated {
        /// Index of the last frame delivered before the break (`None`: none was).
        after_frame: Option<u64>,
        /// Presentation time of that frame, seconds.
        at_s: Option<f64>,
        /// What broke.
        reason: String,
    },

    /// Not one frame of the clip could be decoded.
    #[error("no frame of the clip could be decoded: {reason}")]
    NoDecodableFrame {
        /// Why the first attempts failed.
        reason: String,
    },

    /// The caller's cancellation hook asked to stop.
    #[error("decoding was canceled")]
    Canceled,

    /// The test-clip writer failed.
    #[error("encoding the clip failed: {0}")]
    Encode(String),
}

impl VideoError {
    /// A stable, machine-readable code for this error (the service's problem type).
    pub fn code(&self) -> &'static str {
        match self {
            Self::Io(_) => "video_io",
            Self::ContainerUnsupported { .. } => "video_container_unsupported",
            Self::MoovMissing { .. } => "video_moov_missing",
            Self::Malformed(_) => "video_malformed",
            Self::Fragmented => "video_fragmented_unsupported",
            Self::NoVideoTrack => "video_no_video_track",
            Self::CodecUnsupported { .. } => "video_codec_unsupported",
            Self::MatrixUnsupported { .. } => "video_matrix_unsupported",
            Self::TooLong { .. } => "video_too_long",
            Self::TooLarge { .. } => "video_too_large",
            Self::TooManyFrames { .. } => "video_too_many_frames",
            Self::DecodedBytesOverLimit { .. } => "video_decoded_bytes_over_limit",
            Self::SampleTooLarge { .. } => "video_sample_too_large",
            Self::EmptySample { .. } => "video_empty_sample",
            Self::Truncated { .. } => "video_truncated",
            Self::NoDecodableFrame { .. } => "video_no_decodable_frame",
            Self::Canceled => "video_canceled",
            Self::Encode(_) => "video_encode_failed",
        }
    }

    /// Whether the clip itself is at fault (a 4xx for the uploader) rather than the machine.
    pub fn is_input_error(&self) -> bool {
        !matches!(self, Self::Io(_) | Self::Canceled | Self::Encode(_))
    }
}

fn container_ext(container: &str) -> &'static str {
    match container {
        "RIFF AVI" => "avi",
        "Matroska/WebM" => "mkv",
        _ => "video",
    }
}

fn describe_break(after_frame: Option<u64>, at_s: Option<f64>) -> String {
    match (after_frame, at_s) {
        (Some(f), Some(t)) => format!(" after frame {f} ({t:.3} s)"),
        (Some(f), None) => format!(" after frame {f}"),
        _ => " before its first frame".to_string(),
    }
}

impl From<mp4_atom::Error> for VideoError {
    fn from(e: mp4_atom::Error) -> Self {
        match e {
            mp4_atom::Error::Io(io) => Self::Io(io),
            other => Self::Malformed(other.to_string()),
        }
    }
}
