//! H.264 samples: profile description, length-prefixed → Annex B conversion, and decoding
//! with OpenH264 (pictures tagged with the sample they came from; see [`ffi`]).

mod ffi;
mod sps;

pub(crate) use ffi::{Picture, RawDecoder};
use mp4_atom::Avcc;

use super::Codec;

/// Readable name of an H.264 `profile_idc`, `None` for profiles OpenH264 cannot decode
/// (more than 8 bits or other than 4:2:0 chroma).
fn profile_name(profile_idc: u8, compat: u8) -> Result<&'static str, &'static str> {
    match profile_idc {
        66 if compat & 0x40 != 0 => Ok("Constrained Baseline"),
        66 => Ok("Baseline"),
        77 => Ok("Main"),
        88 => Ok("Extended"),
        100 => Ok("High"),
        110 => Err("H.264 High 10"),
        122 => Err("H.264 High 4:2:2"),
        244 => Err("H.264 High 4:4:4 Predictive"),
        44 => Err("H.264 CAVLC 4:4:4 Intra"),
        _ => Err("H.264 with an unknown profile"),
    }
}

/// What the first SPS of `avcc` says about the sample range and colour matrix (see
/// [`sps::video_signal`]).
pub(crate) fn video_signal(avcc: &Avcc) -> Option<sps::VideoSignal> {
    avcc.sequence_parameter_sets
        .first()
        .and_then(|nal| sps::video_signal(nal))
}

/// The codec of an `avc1`/`avc3` sample entry.
pub(crate) fn codec_of(avcc: &Avcc, fourcc: &str) -> Codec {
    let level = avcc.avc_level_indication;
    match profile_name(avcc.avc_profile_indication, avcc.profile_compatibility) {
        Ok(profile) => Codec::H264 {
            fourcc: fourcc.into(),
            profile: profile.into(),
            profile_idc: avcc.avc_profile_indication,
            level: format!("{}.{}", level / 10, level % 10),
        },
        Err(name) => Codec::Unsupported {
            fourcc: fourcc.into(),
            name: format!("{name} (profile {})", avcc.avc_profile_indication),
        },
    }
}

const START: [u8; 4] = [0, 0, 0, 1];

/// The SPS and PPS of `avcC` as one Annex B access unit, fed before the first sample.
pub(crate) fn parameter_sets(avcc: &Avcc) -> Vec<u8> {
    let mut out = Vec::new();
    for nal in avcc
        .sequence_parameter_sets
        .iter()
        .chain(&avcc.picture_parameter_sets)
        .filter(|n| !n.is_empty())
    {
        out.extend_from_slice(&START);
        out.extend_from_slice(nal);
    }
    out
}

/// Rewrites a sample of NAL units each prefixed by a `length_size`-byte big-endian length
/// into Annex B (start codes) in `out`. Fails on a length that runs past the sample.
pub(crate) fn to_annex_b(sample: &[u8], length_size: u8, out: &mut Vec<u8>) -> Result<(), String> {
    out.clear();
    let ls = usize::from(length_size);
    if !(1..=4).contains(&ls) {
        return Err(format!("NAL length size {length_size} is not 1 to 4 bytes"));
    }
    let mut rest = sample;
    while !rest.is_empty() {
        if rest.len() < ls {
            return Err("a NAL length field is cut short".into());
        }
        let (len_bytes, tail) = rest.split_at(ls);
        let len = len_bytes
            .iter()
            .fold(0usize, |acc, &b| (acc << 8) | usize::from(b));
        if len > tail.len() {
            return Err(format!(
                "a NAL unit claims {len} bytes, {} are left in the sample",
                tail.len()
            ));
        }
        let (nal, next) = tail.split_at(len);
        if !nal.is_empty() {
            out.extend_from_slice(&START);
            out.extend_from_slice(nal);
        }
        rest = next;
    }
    if out.is_empty() {
        return Err("the sample holds no NAL unit".into());
    }
    Ok(())
}

/// OpenH264 state bits that mean the picture or the stream is damaged (`dsFramePending`
/// is not an error).
pub(crate) fn is_error(state: i64) -> bool {
    state & !i64::from(openh264_sys2::dsFramePending) != 0
}

/// Splits an Annex B byte stream into NAL units (without start codes).
pub(crate) fn split_annex_b(stream: &[u8]) -> Vec<&[u8]> {
    let mut starts = Vec::new();
    let mut i = 0;
    while i + 3 <= stream.len() {
        if stream[i] == 0 && stream[i + 1] == 0 && stream[i + 2] == 1 {
            starts.push(i + 3);
            i += 3;
        } else {
            i += 1;
        }
    }
    let mut nals = Vec::with_capacity(starts.len());
    for (k, &s) in starts.iter().enumerate() {
        let mut e = starts.get(k + 1).map_or(stream.len(), |&n| n - 3);
        // A 4-byte start code leaves one zero byte before the next 3-byte pattern.
        while e > s && stream[e - 1] == 0 && starts.get(k + 1).is_some() {
            e -= 1;
        }
        nals.push(&stream[s..e]);
    }
    nals
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn length_prefixed_to_annex_b_and_back() {
        let sample = [0, 0, 0, 2, 0x65, 0xAA, 0, 0, 0, 1, 0x06];
        let mut out = Vec::new();
        to_annex_b(&sample, 4, &mut out).unwrap();
        assert_eq!(out, [0, 0, 0, 1, 0x65, 0xAA, 0, 0, 0, 1, 0x06]);
        assert_eq!(split_annex_b(&out), vec![&[0x65, 0xAA][..], &[0x06][..]]);
        assert!(to_annex_b(&[0, 0, 0, 9, 1], 4, &mut out).is_err());
        assert!(to_annex_b(&[0, 0], 4, &mut out).is_err());
        assert!(to_annex_b(&[], 4, &mut out).is_err());
    }
}
