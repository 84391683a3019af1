//! [`FrameReader`]: frames of a clip, one at a time, upright and in presentation order.

use std::collections::BTreeSet;
use std::io::{ErrorKind, Read, Seek, SeekFrom};

use image::{GrayImage, RgbImage};
use serde::{Deserialize, Serialize};

use super::convert::{jpeg_to_image, picture_to_image, rotate};
use super::demux::{self, Track};
use super::error::VideoError;
use super::h264::{self, Picture, RawDecoder};
use super::limits::VideoLimits;
use super::matrix::YCbCr;
use super::reorder::{Key, Reorder};
use super::{Codec, VideoInfo};

/// Pixel format of delivered frames.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
#[serde(rename_all = "snake_case")]
pub enum FrameFormat {
    /// The decoder's luma plane as is (no RGB round trip; limited range for most cameras).
    /// Motion-JPEG frames are converted to gray.
    #[default]
    Luma,
    /// The luma plane in full range, as a player shows it: limited-range samples (16–235)
    /// are stretched to 0–255, so that measures on grey values (a Laplacian's variance)
    /// agree with those of the same scene as a still photo or read by OpenCV.
    /// Motion-JPEG frames are converted to gray.
    Gray,
    /// 8-bit RGB, converted with the colour matrix and sample range the stream signals
    /// ([`VideoInfo::matrix_coefficients`], [`VideoInfo::full_range`]; BT.601 limited range
    /// when an H.264 stream says nothing).
    Rgb,
}

/// A delivered picture.
#[derive(Debug, Clone, PartialEq)]
pub enum FrameImage {
    /// [`FrameFormat::Luma`].
    Luma(GrayImage),
    /// [`FrameFormat::Rgb`].
    Rgb(RgbImage),
}

impl FrameImage {
    /// Width × height in pixels.
    pub fn dimensions(&self) -> (u32, u32) {
        match self {
            Self::Luma(i) => i.dimensions(),
            Self::Rgb(i) => i.dimensions(),
        }
    }

    /// The luma image (converting an RGB one).
    pub fn into_luma(self) -> GrayImage {
        match self {
            Self::Luma(i) => i,
            Self::Rgb(i) => image::DynamicImage::ImageRgb8(i).to_luma8(),
        }
    }
}

/// One frame of a clip.
#[derive(Debug, Clone, PartialEq)]
pub struct Frame {
    /// Position in presentation order, 0-based, counting every frame of the clip (frames
    /// skipped by the options or lost to damage still count).
    pub index: u64,
    /// Presentation time, seconds (edit list applied: the first frame is usually at 0).
    pub pts_s: f64,
    /// Whether the frame is a sync sample.
    pub keyframe: bool,
    /// The picture, upright (the track's rotation applied).
    pub image: FrameImage,
}

/// Which frames to deliver, and how. H.264 still decodes every frame up to the last one
/// wanted (later frames depend on earlier ones); skipping a frame only saves its
/// conversion. Motion-JPEG frames that are not wanted are not decoded at all.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FrameOptions {
    /// Pixel format.
    pub format: FrameFormat,
    /// Deliver only frames whose index is a multiple of this (0 or 1: every frame).
    pub stride: u64,
    /// Deliver only frames presented within `[start, end]` seconds.
    pub time_range: Option<(f64, f64)>,
    /// Deliver only these frame indices.
    pub indices: Option<BTreeSet<u64>>,
}

/// Something that went wrong without stopping the decoding (a damaged frame).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DecodeIssue {
    /// Frame index (presentation order) concerned, if known.
    pub frame: Option<u64>,
    /// Its presentation time, seconds.
    pub pts_s: Option<f64>,
    /// What happened.
    pub message: String,
}

/// After this many samples in a row that give no picture because of errors, the rest of the
/// stream is taken as garbage: decoding stops and the break is reported.
const MAX_FAILURES_IN_A_ROW: u32 = 48;

enum Engine {
    H264 {
        decoder: Box<RawDecoder>,
        length_size: u8,
        annex_b: Vec<u8>,
    },
    Mjpeg,
}

#[derive(PartialEq, Eq)]
enum State {
    Running,
    Finishing,
    Done,
}

/// Decodes a clip frame by frame. Iterate it (or call [`FrameReader::next_frame`]): every
/// item is a frame, in presentation order; a damaged or cut clip yields the frames before
/// the damage and then one `Err(VideoError::Truncated { .. })`. Nothing is decoded before
/// the first call, and at most a few frames (the reorder depth) are held at a time.
pub struct FrameReader<R> {
    r: R,
    info: VideoInfo,
    track: Track,
    format: FrameFormat,
    /// The colour matrix and sample range of decoded H.264 pictures (what the SPS signals).
    ycbcr: YCbCr,
    max_pixels: u64,
    /// Presentation index of each sample (decode order).
    rank: Vec<u64>,
    wanted: Vec<bool>,
    wanted_left: u64,
    wanted_total: u64,
    next_sample: usize,
    engine: Engine,
    reorder: Reorder<Option<FrameImage>>,
    buf: Vec<u8>,
    state: State,
    issues: Vec<DecodeIssue>,
    last: Option<(u64, f64)>,
    delivered: u64,
    failures: u32,
    broke: Option<String>,
    cancel: Option<Box<dyn Fn() -> bool + Send>>,
}

impl<R: Read + Seek> FrameReader<R> {
    /// Reads the clip's index and prepares the decoder; refuses what [`super::probe`] refuses.
    pub fn open(mut r: R, limits: &VideoLimits, options: FrameOptions) -> Result<Self, VideoError> {
        let track = demux::open(&mut r, limits)?;
        let info = super::info_of(&track);
        super::check(&info, limits)?;
        let engine = match &info.codec {
            Codec::H264 { .. } => {
                let avcc = track
                    .avcc
                    .as_ref()
                    .ok_or_else(|| VideoError::Malformed("H.264 track without avcC".into()))?;
                let mut decoder =
                    Box::new(RawDecoder::new().map_err(|e| VideoError::NoDecodableFrame {
                        reason: format!("the H.264 decoder failed to start: {e}"),
                    })?);
                let ps = h264::parameter_sets(avcc);
                if !ps.is_empty() {
                    // Parameter sets alone never yield a picture; errors surface on samples.
                    let _ = decoder.decode(&ps, u64::MAX);
                }
                Engine::H264 {
                    decoder,
                    length_size: avcc.length_size,
                    annex_b: Vec::new(),
                }
            }
            Codec::Mjpeg { .. } => Engine::Mjpeg,
            Codec::Unsupported { fourcc, name } => {
                return Err(VideoError::CodecUnsupported {
                    fourcc: fourcc.clone(),
                    name: name.clone(),
                });
            }
        };

        let n = track.samples.len();
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by_key(|&i| (track.samples[i].pts, i));
        let mut rank = vec![0u64; n];
        for (pos, &i) in order.iter().enumerate() {
            rank[i] = pos as u64;
        }
        let ts = f64::from(track.timescale);
        let stride = options.stride.max(1);
        let wanted: Vec<bool> = (0..n)
            .map(|i| {
                let idx = rank[i];
                let t = track.samples[i].pts as f64 / ts;
                idx.is_multiple_of(stride)
                    && options.time_range.is_none_or(|(a, b)| t >= a && t <= b)
                    && options.indices.as_ref().is_none_or(|s| s.contains(&idx))
            })
            .collect();
        let wanted_total = wanted.iter().filter(|&&w| w).count() as u64;
        let ycbcr = YCbCr::signalled(info.matrix_coefficients, info.full_range.unwrap_or(false));
        Ok(Self {
            r,
            info,
            track,
            format: options.format,
            ycbcr,
            max_pixels: limits.max_pixels,
            rank,
            wanted,
            wanted_left: wanted_total,
            wanted_total,
            next_sample: 0,
            engine,
            reorder: Reorder::new(),
            buf: Vec::new(),
            state: State::Running,
            issues: Vec::new(),
            last: None,
            delivered: 0,
            failures: 0,
            broke: None,
            cancel: None,
        })
    }

    /// What the clip is (as [`super::probe`] reports it).
    pub fn info(&self) -> &VideoInfo {
        &self.info
    }

    /// Problems met so far that did not stop decoding (lost or damaged frames).
    pub fn issues(&self) -> &[DecodeIssue] {
        &self.issues
    }

    /// Installs a hook asked before every sample; when it returns `true` the reader yields
    /// `Err(VideoError::Canceled)` and stops.
    pub fn set_cancel(&mut self, hook: impl Fn() -> bool + Send + 'static) {
        self.cancel = Some(Box::new(hook));
    }

    /// The next frame, the final error of a damaged clip, or `None` at the end.
    pub fn next_frame(&mut self) -> Option<Result<Frame, VideoError>> {
        loop {
            let end = self.state != State::Running;
            if let Some(rel) = self.reorder.pop(end) {
                self.note_lost(&rel.lost);
                if self.wanted[sample_of(rel.key)] {
                    self.wanted_left = self.wanted_left.saturating_sub(1);
                }
                if let Some(image) = rel.item {
                    return Some(Ok(self.deliver(rel.key, image)));
                }
                continue;
            }
            match self.state {
                State::Done => return None,
                State::Finishing => {
                    let left = self.reorder.take_outstanding();
                    self.note_lost(&left);
                    self.state = State::Done;
                    if let Some(reason) = self.broke.take() {
                        if self.delivered == 0 && self.wanted_total > 0 {
                            return Some(Err(VideoError::NoDecodableFrame { reason }));
                        }
                        return Some(Err(VideoError::Truncated {
                            after_frame: self.last.map(|l| l.0),
                            at_s: self.last.map(|l| l.1),
                            reason,
                        }));
                    }
                    if self.delivered == 0 && self.wanted_total > 0 {
                        let reason = self.issues.first().map_or_else(
                            || "the decoder gave no picture".to_string(),
                            |i| i.message.clone(),
                        );
                        return Some(Err(VideoError::NoDecodableFrame { reason }));
                    }
                    return None;
                }
                State::Running => {
                    if self.cancel.as_ref().is_some_and(|c| c()) {
                        self.state = State::Done;
                        return Some(Err(VideoError::Canceled));
                    }
                    if self.wanted_left == 0 || self.next_sample >= self.track.samples.len() {
                        self.finish();
                        continue;
                    }
                    if let Err(e) = self.step() {
                        self.state = State::Done;
                        return Some(Err(e));
                    }
                }
            }
        }
    }

    fn deliver(&mut self, key: Key, image: FrameImage) -> Frame {
        let i = sample_of(key);
        let pts_s = key.0 as f64 / f64::from(self.track.timescale);
        let index = self.rank[i];
        self.last = Some((index, pts_s));
        self.delivered += 1;
        Frame {
            index,
            pts_s,
            keyframe: self.track.samples[i].keyframe,
            image,
        }
    }

    fn note_lost(&mut self, keys: &[Key]) {
        for &k in keys {
            let i = sample_of(k);
            if self.wanted.get(i).copied().unwrap_or(false) {
                self.wanted_left = self.wanted_left.saturating_sub(1);
            }
            if self.issues.len() < 1000 {
                self.issues.push(DecodeIssue {
                    frame: self.rank.get(i).copied(),
                    pts_s: Some(k.0 as f64 / f64::from(self.track.timescale)),
                    message: format!(
                        "frame {} could not be decoded",
                        self.rank.get(i).copied().unwrap_or(0)
                    ),
                });
            }
        }
    }

    fn issue(&mut self, i: usize, message: String) {
        if self.issues.len() < 1000 {
            let s = &self.track.samples[i];
            self.issues.push(DecodeIssue {
                frame: Some(self.rank[i]),
                pts_s: Some(s.pts as f64 / f64::from(self.track.timescale)),
                message,
            });
        }
    }

    /// Stops feeding: drains the decoder into the reorder buffer.
    fn finish(&mut self) {
        if let Engine::H264 { decoder, .. } = &mut self.engine {
            for _ in 0..64 {
                if decoder.buffered() == 0 {
                    break;
                }
                let Some(pic) = decoder.flush_one() else {
                    break;
                };
                accept(
                    &pic,
                    &self.track,
                    &self.wanted,
                    (self.format, self.ycbcr),
                    self.max_pixels,
                    &mut self.reorder,
                );
            }
        }
        self.state = State::Finishing;
    }

    fn stop(&mut self, reason: String) {
        self.broke = Some(reason);
        self.finish();
    }

    /// Reads and decodes the next sample in decode order.
    fn step(&mut self) -> Result<(), VideoError> {
        let i = self.next_sample;
        self.next_sample += 1;
        let s = self.track.samples[i];
        let key = (s.pts, i as u64);
        if matches!(self.engine, Engine::Mjpeg) && !self.wanted[i] {
            return Ok(());
        }
        if !s.in_file(self.track.file_len) {
            self.stop(format!(
                "the file ends at byte {} but frame data runs to byte {}",
                self.track.file_len,
                s.offset.saturating_add(u64::from(s.size))
            ));
            return Ok(());
        }
        self.buf.resize(s.size as usize, 0);
        self.r.seek(SeekFrom::Start(s.offset))?;
        if let Err(e) = self.r.read_exact(&mut self.buf) {
            if e.kind() == ErrorKind::UnexpectedEof {
                self.stop(format!("the file ends inside the data of sample {i}"));
                return Ok(());
            }
            return Err(e.into());
        }
        let failed = match &mut self.engine {
            Engine::H264 {
                decoder,
                length_size,
                annex_b,
            } => match h264::to_annex_b(&self.buf, *length_size, annex_b) {
                Err(e) => Some(e),
                Ok(()) => {
                    self.reorder.fed(key);
                    let (state, pic) = decoder.decode(annex_b, i as u64);
                    let got = pic.as_ref().is_some_and(|p| {
                        accept(
                            p,
                            &self.track,
                            &self.wanted,
                            (self.format, self.ycbcr),
                            self.max_pixels,
                            &mut self.reorder,
                        )
                    });
                    if got || !h264::is_error(state) {
                        self.failures = 0;
                        None
                    } else {
                        // The sample stays outstanding: its picture may still come out.
                        Some(format!(
                            "the H.264 decoder reported errors (state {state:#x})"
                        ))
                    }
                }
            },
            Engine::Mjpeg => match jpeg_to_image(&self.buf, self.format, self.max_pixels) {
                Ok(img) => {
                    self.reorder.fed(key);
                    self.reorder
                        .decoded(key, Some(rotate(img, self.track.rotation_deg)));
                    self.failures = 0;
                    None
                }
                Err(e) => Some(format!("the JPEG of this frame does not decode: {e}")),
            },
        };
        if let Some(message) = failed {
            self.issue(i, message);
            self.failures += 1;
            if self.failures >= MAX_FAILURES_IN_A_ROW {
                self.stop(format!(
                    "{MAX_FAILURES_IN_A_ROW} samples in a row failed to decode, the last at frame {}",
                    self.rank[i]
                ));
            }
        }
        Ok(())
    }
}

impl<R: Read + Seek> Iterator for FrameReader<R> {
    type Item = Result<Frame, VideoError>;

    fn next(&mut self) -> Option<Self::Item> {
        self.next_frame()
    }
}

fn sample_of(key: Key) -> usize {
    key.1 as usize
}

/// Files a decoded picture under the sample it came from (converted when wanted, in the
/// format, colour matrix and sample range given). Returns whether it belonged to a known sample.
fn accept(
    pic: &Picture<'_>,
    track: &Track,
    wanted: &[bool],
    (format, ycbcr): (FrameFormat, YCbCr),
    max_pixels: u64,
    reorder: &mut Reorder<Option<FrameImage>>,
) -> bool {
    let Some(s) = usize::try_from(pic.token)
        .ok()
        .and_then(|i| track.samples.get(i).map(|s| (i, s)))
    else {
        return false;
    };
    let key = (s.1.pts, s.0 as u64);
    if (pic.width as u64).saturating_mul(pic.height as u64) > max_pixels {
        return false;
    }
    let item = if wanted[s.0] {
        picture_to_image(pic, format, ycbcr).map(|img| rotate(img, track.rotation_deg))
    } else {
        None
    };
    if wanted[s.0] && item.is_none() {
        return false;
    }
    reorder.decoded(key, item);
    true
}
