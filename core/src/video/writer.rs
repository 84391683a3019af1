//! A minimal H.264 MP4 writer (OpenH264's encoder, boxes from `mp4-atom`) so tests anywhere
//! in the workspace can make clips without ffmpeg. Not meant for production encoding: it
//! keeps the whole clip in memory.

use image::{GrayImage, RgbImage};
use mp4_atom::{
    Avc1, Avcc, Dinf, Dref, DrefEntry, Encode, FourCC, Ftyp, Hdlr, Matrix, Mdat, Mdhd, Mdia, Minf,
    Moov, Mvhd, Stbl, Stco, Stsc, StscEntry, Stsd, Stss, Stsz, StszSamples, Stts, SttsEntry, Tkhd,
    Trak, Url, Visual, Vmhd,
};
use openh264::OpenH264API;
use openh264::encoder::{
    BitRate, Encoder, EncoderConfig, FrameRate, IntraFramePeriod, RateControlMode, VuiConfig,
};
use openh264::formats::YUVBuffer;

use super::error::VideoError;
use super::h264::split_annex_b;
use super::matrix::YCbCr;

/// A picture the writer accepts: 8-bit gray or RGB.
pub trait EncodableImage {
    /// Width × height.
    fn size(&self) -> (u32, u32);
    /// Writes the picture as I420 planes of `size()` (even width and height), with the
    /// colour matrix and sample range of `ycbcr`.
    fn to_i420(&self, yuv: &mut [u8], ycbcr: YCbCr);
}

impl EncodableImage for GrayImage {
    fn size(&self) -> (u32, u32) {
        self.dimensions()
    }

    /// Stores gray levels in the luma plane verbatim (neutral chroma), so
    /// `FrameFormat::Luma` gives them back unchanged up to coding loss (in either range:
    /// the gray levels are taken to be coded samples already).
    fn to_i420(&self, yuv: &mut [u8], _ycbcr: YCbCr) {
        let n = self.as_raw().len();
        yuv[..n].copy_from_slice(self.as_raw());
        yuv[n..].fill(128);
    }
}

impl EncodableImage for RgbImage {
    fn size(&self) -> (u32, u32) {
        self.dimensions()
    }

    /// BT.601 or BT.709 in the range asked for, the inverse of the reader's RGB conversion.
    fn to_i420(&self, yuv: &mut [u8], ycbcr: YCbCr) {
        let (w, h) = (self.width() as usize, self.height() as usize);
        let (y_plane, chroma) = yuv.split_at_mut(w * h);
        let (u_plane, v_plane) = chroma.split_at_mut(w * h / 4);
        let q = |v: f64| v.round().clamp(0.0, 255.0) as u8;
        for (i, p) in self.pixels().enumerate() {
            let [r, g, b] = p.0.map(f64::from);
            y_plane[i] = q(ycbcr.ycbcr_of_rgb(r, g, b)[0]);
        }
        for cy in 0..h / 2 {
            for cx in 0..w / 2 {
                let mut sum = [0.0f64; 3];
                for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    let p = self.get_pixel((2 * cx + dx) as u32, (2 * cy + dy) as u32).0;
                    for c in 0..3 {
                        sum[c] += f64::from(p[c]) / 4.0;
                    }
                }
                let [_, cb, cr] = ycbcr.ycbcr_of_rgb(sum[0], sum[1], sum[2]);
                u_plane[cy * w / 2 + cx] = q(cb);
                v_plane[cy * w / 2 + cx] = q(cr);
            }
        }
    }
}

/// Options of [`encode_h264_mp4_with`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WriterOptions {
    /// Clockwise display rotation written in the track matrix (0, 90, 180, 270).
    pub rotation_deg: u16,
    /// A keyframe every this many frames (0: only the first).
    pub keyframe_interval: u32,
    /// Target bit rate in bits per second (0: about 2 bits per pixel per second... high
    /// enough that test comparisons are not dominated by coding loss).
    pub bitrate: u32,
    /// Code full-range samples and say so in the SPS (`video_full_range_flag`), as some
    /// phones and action cameras do; `false`: limited range, the H.264 default, unsignalled.
    pub full_range: bool,
    /// Code with the BT.709 matrix and say so in the SPS (`matrix_coefficients` 1), as HD
    /// cameras do; `false`: BT.601, unsignalled unless `full_range` is set.
    pub bt709: bool,
}

impl Default for WriterOptions {
    fn default() -> Self {
        Self {
            rotation_deg: 0,
            keyframe_interval: 30,
            bitrate: 0,
            full_range: false,
            bt709: false,
        }
    }
}

/// Encodes `frames` at `fps` as an H.264 (Constrained Baseline) MP4, entirely in memory.
pub fn encode_h264_mp4<I: EncodableImage>(frames: &[I], fps: f64) -> Result<Vec<u8>, VideoError> {
    encode_h264_mp4_with(frames, fps, &WriterOptions::default())
}

/// [`encode_h264_mp4`] with a rotation, keyframe interval and bit rate.
pub fn encode_h264_mp4_with<I: EncodableImage>(
    frames: &[I],
    fps: f64,
    options: &WriterOptions,
) -> Result<Vec<u8>, VideoError> {
    let err = VideoError::Encode;
    let (w, h) = check_frames(frames, fps)?;
    let bitrate = if options.bitrate > 0 {
        options.bitrate
    } else {
        ((f64::from(w) * f64::from(h) * fps * 2.0) as u32).max(500_000)
    };
    let config = EncoderConfig::new()
        .skip_frames(false)
        .max_frame_rate(FrameRate::from_hz(fps as f32))
        .rate_control_mode(RateControlMode::Bitrate)
        .bitrate(BitRate::from_bps(bitrate))
        .intra_frame_period(IntraFramePeriod::from_num_frames(options.keyframe_interval));
    let ycbcr = YCbCr::new(options.bt709, options.full_range);
    let config = match (options.bt709, options.full_range) {
        (false, false) => config,
        (bt709, full) => config.vui(if bt709 {
            VuiConfig::bt709().full_range(full)
        } else {
            VuiConfig::bt601().full_range(full)
        }),
    };
    let mut encoder = Encoder::with_api_config(OpenH264API::from_source(), config)
        .map_err(|e| err(e.to_string()))?;

    let mut yuv = vec![0u8; (w * h * 3 / 2) as usize];
    let (mut sps, mut pps): (Option<Vec<u8>>, Option<Vec<u8>>) = (None, None);
    let mut data = Vec::new();
    let mut sizes = Vec::with_capacity(frames.len());
    let mut keyframes = Vec::new();
    let mut annex_b = Vec::new();
    for (i, frame) in frames.iter().enumerate() {
        frame.to_i420(&mut yuv, ycbcr);
        let source = YUVBuffer::from_vec(yuv.clone(), w as usize, h as usize);
        let bits = encoder.encode(&source).map_err(|e| err(e.to_string()))?;
        annex_b.clear();
        bits.write_vec(&mut annex_b);
        let start = data.len();
        let mut idr = false;
        for nal in split_annex_b(&annex_b) {
            match nal.first().map(|b| b & 0x1F) {
                Some(7) => {
                    sps.get_or_insert_with(|| nal.to_vec());
                }
                Some(8) => {
                    pps.get_or_insert_with(|| nal.to_vec());
                }
                Some(t) => {
                    idr |= t == 5;
                    data.extend_from_slice(&(nal.len() as u32).to_be_bytes());
                    data.extend_from_slice(nal);
                }
                None => {}
            }
        }
        if data.len() == start {
            return Err(err(format!(
                "the encoder produced no picture for frame {i}"
            )));
        }
        sizes.push((data.len() - start) as u32);
        if idr {
            keyframes.push(i as u32 + 1);
        }
    }
    let (Some(sps), Some(pps)) = (sps, pps) else {
        return Err(err("the encoder produced no parameter sets".into()));
    };
    let avcc = Avcc::new(&sps, &pps).map_err(|e| err(e.to_string()))?;
    let entry = Avc1 {
        visual: visual(w, h),
        avcc,
        ..Default::default()
    }
    .into();
    let track = Samples {
        rotation_deg: options.rotation_deg,
        keyframes: Some(keyframes),
        ..Samples::new((w, h), fps, sizes, data)
    };
    mux(entry, track)
}

/// Encodes `frames` at `fps` as a QuickTime Motion-JPEG clip (`jpeg` sample entry, every frame
/// a baseline JFIF image at `quality` 1–100), entirely in memory: what USB cameras deliver.
pub fn encode_mjpeg_mov<I>(frames: &[I], fps: f64, quality: u8) -> Result<Vec<u8>, VideoError>
where
    I: EncodableImage + image::GenericImageView,
    I::Pixel: image::PixelWithColorType,
{
    let err = VideoError::Encode;
    let (w, h) = check_frames(frames, fps)?;
    let mut data = Vec::new();
    let mut sizes = Vec::with_capacity(frames.len());
    for frame in frames {
        let start = data.len();
        let mut enc =
            image::codecs::jpeg::JpegEncoder::new_with_quality(&mut data, quality.clamp(1, 100));
        enc.encode_image(frame).map_err(|e| err(e.to_string()))?;
        sizes.push((data.len() - start) as u32);
    }
    let entry = mp4_atom::Jpeg {
        visual: visual(w, h),
        ..Default::default()
    }
    .into();
    mux(entry, Samples::new((w, h), fps, sizes, data))
}

/// Checks that `frames` share one even, non-zero size and that `fps` is usable; the size.
fn check_frames<I: EncodableImage>(frames: &[I], fps: f64) -> Result<(u32, u32), VideoError> {
    let err = VideoError::Encode;
    let first = frames.first().ok_or_else(|| err("no frames".into()))?;
    let (w, h) = first.size();
    if w == 0
        || h == 0
        || !w.is_multiple_of(2)
        || !h.is_multiple_of(2)
        || w > u32::from(u16::MAX)
        || h > u32::from(u16::MAX)
    {
        return Err(err(format!(
            "frames of {w}x{h}: width and height must be even and non-zero"
        )));
    }
    if !(fps > 0.0 && fps <= 1000.0) {
        return Err(err(format!("frame rate {fps} is not in (0, 1000]")));
    }
    if let Some((i, f)) = frames.iter().enumerate().find(|(_, f)| f.size() != (w, h)) {
        return Err(err(format!(
            "frame {i} is {:?}, the first {w}x{h}",
            f.size()
        )));
    }
    Ok((w, h))
}

/// The coded frames of one video track, in decode order.
struct Samples {
    width: u32,
    height: u32,
    fps: f64,
    rotation_deg: u16,
    /// Bytes of each frame in `data`.
    sizes: Vec<u32>,
    /// 1-based sync samples (`None`: every frame is one).
    keyframes: Option<Vec<u32>>,
    data: Vec<u8>,
}

impl Samples {
    /// Frames of `size` at `fps`, upright, every one a sync sample.
    fn new(size: (u32, u32), fps: f64, sizes: Vec<u32>, data: Vec<u8>) -> Self {
        Self {
            width: size.0,
            height: size.1,
            fps,
            rotation_deg: 0,
            sizes,
            keyframes: None,
            data,
        }
    }
}

/// The visual part of a sample entry for `w` × `h` frames.
fn visual(w: u32, h: u32) -> Visual {
    Visual {
        data_reference_index: 1,
        width: w as u16,
        height: h as u16,
        ..Default::default()
    }
}

/// Writes one video track with the sample entry `entry` as an MP4/QuickTime file: `ftyp`,
/// `moov`, then one `mdat` chunk holding every frame.
fn mux(entry: mp4_atom::Codec, track: Samples) -> Result<Vec<u8>, VideoError> {
    let err = VideoError::Encode;
    let Samples {
        width: w,
        height: h,
        fps,
        rotation_deg,
        sizes,
        keyframes,
        data,
    } = track;
    let matrix =
        matrix_for(rotation_deg).ok_or_else(|| err("rotation must be 0, 90, 180 or 270".into()))?;
    // Time base: 1/1000 of a frame is exact for integer rates and close for NTSC ones.
    let timescale: u32 = (fps * 1000.0).round() as u32;
    let delta: u32 = 1000;
    let n = sizes.len() as u32;
    let ftyp = Ftyp {
        major_brand: FourCC::new(b"isom"),
        minor_version: 512,
        compatible_brands: [b"isom", b"iso2", b"avc1", b"mp41"]
            .map(FourCC::new)
            .to_vec(),
    };
    let duration = u64::from(n) * u64::from(delta);
    let movie_duration = duration * 1000 / u64::from(timescale);
    let mut moov = Moov {
        mvhd: Mvhd {
            timescale: 1000,
            duration: movie_duration,
            rate: 1.into(),
            volume: 1.into(),
            matrix: matrix_for(0).unwrap_or_default(),
            next_track_id: 2,
            ..Default::default()
        },
        trak: vec![Trak {
            tkhd: Tkhd {
                track_id: 1,
                duration: movie_duration,
                enabled: true,
                in_movie: true,
                matrix,
                width: (w as u16).into(),
                height: (h as u16).into(),
                ..Default::default()
            },
            mdia: Mdia {
                mdhd: Mdhd {
                    timescale,
                    duration,
                    language: "und".into(),
                    ..Default::default()
                },
                hdlr: Hdlr {
                    handler: FourCC::new(b"vide"),
                    name: "Caliper video".into(),
                },
                minf: Minf {
                    vmhd: Some(Vmhd::default()),
                    dinf: Dinf {
                        dref: Dref {
                            entries: vec![DrefEntry::Url(Url {
                                location: String::new(),
                            })],
                        },
                    },
                    stbl: Stbl {
                        stsd: Stsd {
                            codecs: vec![entry],
                        },
                        stts: Stts {
                            entries: vec![SttsEntry {
                                sample_count: n,
                                sample_delta: delta,
                            }],
                        },
                        stss: keyframes.map(|entries| Stss { entries }),
                        stsc: Stsc {
                            entries: vec![StscEntry {
                                first_chunk: 1,
                                samples_per_chunk: n,
                                sample_description_index: 1,
                            }],
                        },
                        stsz: Stsz {
                            samples: StszSamples::Different { sizes },
                        },
                        stco: Some(Stco { entries: vec![0] }),
                        ..Default::default()
                    },
                    ..Default::default()
                },
            },
            ..Default::default()
        }],
        ..Default::default()
    };

    let mut head = Vec::new();
    ftyp.encode(&mut head)?;
    let mut moov_bytes = Vec::new();
    moov.encode(&mut moov_bytes)?;
    // The chunk offset does not change the size of `moov`: encode again with the real one.
    let offset = u32::try_from(head.len() + moov_bytes.len() + 8)
        .map_err(|_| err("the clip is too large for 32-bit chunk offsets".into()))?;
    if let Some(stco) = moov.trak[0].mdia.minf.stbl.stco.as_mut() {
        stco.entries = vec![offset];
    }
    moov_bytes.clear();
    moov.encode(&mut moov_bytes)?;
    let mut out = head;
    out.extend_from_slice(&moov_bytes);
    Mdat { data }.encode(&mut out)?;
    Ok(out)
}

fn matrix_for(deg: u16) -> Option<Matrix> {
    const ONE: i32 = 1 << 16;
    let (a, b, c, d) = match deg {
        0 => (ONE, 0, 0, ONE),
        90 => (0, ONE, -ONE, 0),
        180 => (-ONE, 0, 0, -ONE),
        270 => (0, -ONE, ONE, 0),
        _ => return None,
    };
    Some(Matrix {
        a,
        b,
        u: 0,
        c,
        d,
        v: 0,
        x: 0,
        y: 0,
        w: 1 << 30,
    })
}
