//! Finding the index (`moov`) of an MP4/MOV file without reading its media data, choosing the
//! first video track and describing its codec and orientation.

use std::io::{Read, Seek, SeekFrom};

use mp4_atom::{Avcc, Codec as SampleEntry, Decode, Moov, Trak};

use super::error::VideoError;
use super::limits::{MAX_MOOV_BYTES, VideoLimits};
use super::sample_table::{self, Sample};
use super::{Codec, Container, prune};

/// Everything the decoder needs about the chosen track.
pub(crate) struct Track {
    pub container: Container,
    pub codec: Codec,
    /// The `avcC` record of an H.264 track.
    pub avcc: Option<Avcc>,
    /// Coded size from the sample entry.
    pub width: u32,
    pub height: u32,
    /// Clockwise rotation to apply for display: 0, 90, 180 or 270.
    pub rotation_deg: u16,
    pub timescale: u32,
    /// Sum of the samples' durations, timescale units.
    pub duration: i64,
    /// Decode order.
    pub samples: Vec<Sample>,
    pub file_len: u64,
}

struct BoxHeader {
    kind: [u8; 4],
    start: u64,
    /// End as declared (may lie past the end of the file).
    end: u64,
}

/// A box header parsed from `head`, the box's first bytes (16 are enough), with `left` bytes
/// from the box's start to the end of what contains it: `(code, declared size, header length)`.
/// `None` when `left` is too short for the header. Shared by the top-level scan below and the
/// index walk of [`super::prune`].
pub(super) fn parse_header(
    head: &[u8],
    left: u64,
) -> Result<Option<([u8; 4], u64, u64)>, VideoError> {
    if left < 8 || head.len() < 8 {
        return Ok(None);
    }
    let kind = [head[4], head[5], head[6], head[7]];
    let (size, header_len) = match u32::from_be_bytes([head[0], head[1], head[2], head[3]]) {
        0 => (left, 8),
        1 => match head.get(8..16) {
            Some(l) if left >= 16 => (
                u64::from_be_bytes([l[0], l[1], l[2], l[3], l[4], l[5], l[6], l[7]]),
                16,
            ),
            _ => return Ok(None),
        },
        s => (u64::from(s), 8),
    };
    if size < header_len {
        return Err(VideoError::Malformed(format!(
            "box '{}' declares {size} bytes, less than its header",
            String::from_utf8_lossy(&kind)
        )));
    }
    Ok(Some((kind, size, header_len)))
}

/// Reads the box header at `pos`; `None` when too few bytes are left for one.
fn read_header<R: Read + Seek>(
    r: &mut R,
    pos: u64,
    file_len: u64,
) -> Result<Option<BoxHeader>, VideoError> {
    let left = file_len.saturating_sub(pos);
    let mut head = [0u8; 16];
    let take = left.min(16) as usize;
    r.seek(SeekFrom::Start(pos))?;
    r.read_exact(&mut head[..take])?;
    let Some((kind, size, _)) = parse_header(&head[..take], left)? else {
        return Ok(None);
    };
    let end = pos
        .checked_add(size)
        .ok_or_else(|| VideoError::Malformed("a box size overflows".into()))?;
    Ok(Some(BoxHeader {
        kind,
        start: pos,
        end,
    }))
}

/// Recognises containers that are not ISO BMFF, to refuse them by name.
fn sniff_other(head: &[u8]) -> Option<&'static str> {
    if head.len() >= 12 && &head[0..4] == b"RIFF" && &head[8..12] == b"AVI " {
        Some("RIFF AVI")
    } else if head.starts_with(&[0x1A, 0x45, 0xDF, 0xA3]) {
        Some("Matroska/WebM")
    } else {
        None
    }
}

const TOP_LEVEL: [&[u8; 4]; 14] = [
    b"ftyp", b"moov", b"mdat", b"free", b"skip", b"wide", b"pnot", b"uuid", b"styp", b"sidx",
    b"moof", b"meta", b"pdin", b"mfra",
];

/// Opens the file's index and builds the sample table of its first video track.
pub(crate) fn open<R: Read + Seek>(r: &mut R, limits: &VideoLimits) -> Result<Track, VideoError> {
    let file_len = r.seek(SeekFrom::End(0))?;
    let mut head = [0u8; 12];
    r.seek(SeekFrom::Start(0))?;
    let got = read_up_to(r, &mut head)?;
    if let Some(name) = sniff_other(&head[..got]) {
        return Err(VideoError::ContainerUnsupported {
            container: name.into(),
        });
    }

    let mut pos = 0u64;
    let mut moov: Option<BoxHeader> = None;
    let mut container = Container::Mp4;
    let mut mdat_cut = false;
    let mut fragmented = false;
    let mut first = true;
    while let Some(h) = read_header(r, pos, file_len)? {
        if first && !TOP_LEVEL.contains(&&h.kind) {
            return Err(VideoError::ContainerUnsupported {
                container: "unknown".into(),
            });
        }
        first = false;
        if &h.kind == b"ftyp" && h.end <= file_len && h.end - h.start >= 12 {
            let mut brand = [0u8; 4];
            r.seek(SeekFrom::Start(h.start + 8))?;
            r.read_exact(&mut brand)?;
            if &brand == b"qt  " {
                container = Container::QuickTime;
            }
        }
        if &h.kind == b"moof" {
            fragmented = true;
        }
        if h.end > file_len {
            if &h.kind == b"mdat" {
                mdat_cut = true;
            }
            if &h.kind == b"moov" {
                return Err(VideoError::Malformed(format!(
                    "the index (moov) is cut short: it needs {} bytes, the file has {}",
                    h.end, file_len
                )));
            }
            break;
        }
        let kind = h.kind;
        pos = h.end;
        if &kind == b"moov" {
            moov = Some(h);
        }
    }
    let Some(moov) = moov else {
        if first {
            return Err(VideoError::ContainerUnsupported {
                container: "unknown".into(),
            });
        }
        return Err(VideoError::MoovMissing { mdat_cut });
    };
    let len = moov.end - moov.start;
    if len > MAX_MOOV_BYTES {
        return Err(VideoError::Malformed(format!(
            "the index (moov) is {len} bytes, more than {MAX_MOOV_BYTES}"
        )));
    }
    let mut buf = vec![0u8; len as usize];
    r.seek(SeekFrom::Start(moov.start))?;
    r.read_exact(&mut buf)?;
    let pruned = prune::prune(&mut buf)?;
    let moov = Moov::decode(&mut buf.as_slice())?;
    drop(buf);

    let (index, trak) = moov
        .trak
        .iter()
        .enumerate()
        .find(|(_, t)| &<[u8; 4]>::from(t.mdia.hdlr.handler) == b"vide")
        .ok_or(VideoError::NoVideoTrack)?;
    let entry =
        trak.mdia.minf.stbl.stsd.codecs.first().ok_or_else(|| {
            VideoError::Malformed("the video track has no sample description".into())
        })?;
    let original = pruned.first_entry.get(index).copied().flatten();
    let (codec, avcc, width, height) = describe(entry, original)?;
    let rotation_deg = rotation(trak)?;
    let timescale = trak.mdia.mdhd.timescale;
    if timescale == 0 {
        return Err(VideoError::Malformed(
            "the video track's timescale is zero".into(),
        ));
    }
    let (samples, duration) = sample_table::build(trak, moov.mvhd.timescale, file_len, limits)?;
    if samples.is_empty() {
        if fragmented || moov.mvex.is_some() {
            return Err(VideoError::Fragmented);
        }
        return Err(VideoError::NoDecodableFrame {
            reason: "the video track has no samples".into(),
        });
    }
    Ok(Track {
        container,
        codec,
        avcc,
        width,
        height,
        rotation_deg,
        timescale,
        duration,
        samples,
        file_len,
    })
}

fn read_up_to<R: Read>(r: &mut R, buf: &mut [u8]) -> Result<usize, VideoError> {
    let mut n = 0;
    while n < buf.len() {
        match r.read(&mut buf[n..]) {
            Ok(0) => break,
            Ok(k) => n += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e.into()),
        }
    }
    Ok(n)
}

/// The codec of a sample entry, its `avcC` and its coded size. `original` is the entry's code
/// before [`prune`] made every entry but H.264's opaque.
fn describe(
    entry: &SampleEntry,
    original: Option<[u8; 4]>,
) -> Result<(Codec, Option<Avcc>, u32, u32), VideoError> {
    let unsupported = |fourcc: &str, name: &str| Codec::Unsupported {
        fourcc: fourcc.into(),
        name: name.into(),
    };
    let (codec, avcc) = match entry {
        SampleEntry::Avc1(a) => (super::h264::codec_of(&a.avcc, "avc1"), Some(a.avcc.clone())),
        SampleEntry::Avc3(a) => (super::h264::codec_of(&a.avcc, "avc3"), Some(a.avcc.clone())),
        SampleEntry::Unknown(fourcc, body) => {
            let code = match original {
                Some(code) if <[u8; 4]>::from(*fourcc) == prune::OPAQUE_ENTRY => code,
                _ => <[u8; 4]>::from(*fourcc),
            };
            let f = String::from_utf8_lossy(&code).into_owned();
            let codec = match &code {
                b"jpeg" | b"mjpa" | b"mjpb" => Codec::Mjpeg { fourcc: f },
                b"hvc1" | b"hev1" => unsupported(&f, "HEVC (H.265)"),
                b"av01" => unsupported(&f, "AV1"),
                b"vp09" => unsupported(&f, "VP9"),
                b"vp08" => unsupported(&f, "VP8"),
                b"uncv" => unsupported(&f, "uncompressed video"),
                b"apch" | b"apcn" | b"apcs" | b"apco" | b"ap4h" | b"ap4x" => {
                    unsupported(&f, "Apple ProRes")
                }
                b"mp4v" => unsupported(&f, "MPEG-4 Part 2"),
                b"dvh1" | b"dvhe" => unsupported(&f, "Dolby Vision (HEVC)"),
                b"avc2" | b"avc4" => unsupported(&f, "H.264 (multi-view/SVC)"),
                _ => unsupported(&f, "an unknown codec"),
            };
            // A visual sample entry: 8 bytes of header fields, 16 reserved, then width, height.
            let (w, h) = match body.get(24..28) {
                Some(b) => (
                    u32::from(u16::from_be_bytes([b[0], b[1]])),
                    u32::from(u16::from_be_bytes([b[2], b[3]])),
                ),
                None => (0, 0),
            };
            return Ok((codec, None, w, h));
        }
        other => {
            return Err(VideoError::Malformed(
                format!("the video track's sample entry is not a video codec ({other:?})",)
                    .chars()
                    .take(200)
                    .collect(),
            ));
        }
    };
    let visual = entry
        .visual()
        .ok_or_else(|| VideoError::Malformed("the video sample entry has no size".into()))?;
    Ok((
        codec,
        avcc,
        u32::from(visual.width),
        u32::from(visual.height),
    ))
}

/// Clockwise display rotation from the track header's matrix (16.16 fixed point; the
/// translation is ignored). Anything but a rotation by a multiple of 90 degrees is refused:
/// a mirrored or sheared clip would give wrong calibrations silently.
fn rotation(trak: &Trak) -> Result<u16, VideoError> {
    let m = &trak.tkhd.matrix;
    const ONE: i32 = 1 << 16;
    match (m.a, m.b, m.c, m.d) {
        (ONE, 0, 0, ONE) => Ok(0),
        (0, ONE, n, 0) if n == -ONE => Ok(90),
        (n, 0, 0, k) if n == -ONE && k == -ONE => Ok(180),
        (0, n, ONE, 0) if n == -ONE => Ok(270),
        (a, b, c, d) => Err(VideoError::MatrixUnsupported { a, b, c, d }),
    }
}
