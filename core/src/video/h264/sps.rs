//! The fields of an H.264 sequence parameter set that Caliper needs before decoding: whether
//! the stream says its samples use the full 0–255 range (`video_full_range_flag` in the VUI,
//! ITU-T H.264 §7.3.2.1.1 and Annex E.1.1), and which matrix turns its YCbCr into RGB
//! (`matrix_coefficients`, Annex E table E-5). Phones that record full-range video say so
//! there, and a photometric fit that expanded such samples as if they were limited range
//! would clip the darkest and brightest levels; HD cameras code with the BT.709 matrix, and
//! converting their colours with BT.601's shifts saturated colours by several levels.
//!
//! The parser walks the SPS fields in order up to the video signal type and stops; every read
//! is bounded by the NAL's length, so a malformed SPS gives `None`, never a panic.

/// The video signal type of an SPS's VUI.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct VideoSignal {
    /// `video_full_range_flag`.
    pub full_range: bool,
    /// `matrix_coefficients` when the colour description is present.
    pub matrix_coefficients: Option<u8>,
}

/// What the SPS `nal` (with its one-byte NAL header, as stored in `avcC`) says about the
/// sample range: `Some(true)` full range, `Some(false)` limited range, `None` when the SPS does
/// not signal it (H.264 then means limited range) or cannot be parsed.
#[cfg(test)]
pub(crate) fn video_full_range(nal: &[u8]) -> Option<bool> {
    video_signal(nal).map(|s| s.full_range)
}

/// The SPS's video signal type; `None` when the SPS has none or cannot be parsed.
pub(crate) fn video_signal(nal: &[u8]) -> Option<VideoSignal> {
    let rbsp = unescape(nal.get(1..)?);
    let mut r = Bits::new(&rbsp);
    let profile_idc = r.bits(8)?;
    r.bits(16)?; // constraint flags, level_idc
    r.ue()?; // seq_parameter_set_id
    if matches!(
        profile_idc,
        100 | 110 | 122 | 244 | 44 | 83 | 86 | 118 | 128 | 138 | 139 | 134 | 135
    ) {
        let chroma_format_idc = r.ue()?;
        if chroma_format_idc == 3 {
            r.bits(1)?; // separate_colour_plane_flag
        }
        r.ue()?; // bit_depth_luma_minus8
        r.ue()?; // bit_depth_chroma_minus8
        r.bits(1)?; // qpprime_y_zero_transform_bypass_flag
        if r.bits(1)? == 1 {
            let lists = if chroma_format_idc == 3 { 12 } else { 8 };
            for i in 0..lists {
                if r.bits(1)? == 1 {
                    skip_scaling_list(&mut r, if i < 6 { 16 } else { 64 })?;
                }
            }
        }
    }
    r.ue()?; // log2_max_frame_num_minus4
    match r.ue()? {
        0 => {
            r.ue()?; // log2_max_pic_order_cnt_lsb_minus4
        }
        1 => {
            r.bits(1)?; // delta_pic_order_always_zero_flag
            r.se()?; // offset_for_non_ref_pic
            r.se()?; // offset_for_top_to_bottom_field
            let cycle = r.ue()?;
            if cycle > 255 {
                return None;
            }
            for _ in 0..cycle {
                r.se()?;
            }
        }
        _ => {}
    }
    r.ue()?; // max_num_ref_frames
    r.bits(1)?; // gaps_in_frame_num_value_allowed_flag
    r.ue()?; // pic_width_in_mbs_minus1
    r.ue()?; // pic_height_in_map_units_minus1
    if r.bits(1)? == 0 {
        r.bits(1)?; // mb_adaptive_frame_field_flag
    }
    r.bits(1)?; // direct_8x8_inference_flag
    if r.bits(1)? == 1 {
        for _ in 0..4 {
            r.ue()?; // frame_crop_{left,right,top,bottom}_offset
        }
    }
    if r.bits(1)? == 0 {
        return None; // no VUI
    }
    if r.bits(1)? == 1 {
        // aspect_ratio_idc; 255 is Extended_SAR with an explicit width and height.
        if r.bits(8)? == 255 {
            r.bits(32)?;
        }
    }
    if r.bits(1)? == 1 {
        r.bits(1)?; // overscan_appropriate_flag
    }
    if r.bits(1)? == 0 {
        return None; // no video signal type
    }
    r.bits(3)?; // video_format
    let full_range = r.bits(1)? == 1;
    let matrix_coefficients = match r.bits(1) {
        Some(1) => {
            r.bits(16)?; // colour_primaries, transfer_characteristics
            r.bits(8).and_then(|m| u8::try_from(m).ok())
        }
        _ => None,
    };
    Some(VideoSignal {
        full_range,
        matrix_coefficients,
    })
}

/// Skips a `scaling_list` of `size` entries (§7.3.2.1.1.1): deltas until one ends the list.
fn skip_scaling_list(r: &mut Bits<'_>, size: usize) -> Option<()> {
    let (mut last, mut next) = (8i64, 8i64);
    for _ in 0..size {
        if next != 0 {
            let delta = r.se()?;
            next = (last + delta).rem_euclid(256);
        }
        if next != 0 {
            last = next;
        }
    }
    Some(())
}

/// The RBSP of a NAL payload: every `00 00 03` emulation-prevention byte removed.
fn unescape(payload: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(payload.len());
    let mut zeros = 0;
    for &b in payload {
        if zeros >= 2 && b == 3 {
            zeros = 0;
            continue;
        }
        zeros = if b == 0 { zeros + 1 } else { 0 };
        out.push(b);
    }
    out
}

/// A big-endian bit reader; every read past the end gives `None`.
struct Bits<'a> {
    data: &'a [u8],
    pos: usize,
}

impl<'a> Bits<'a> {
    fn new(data: &'a [u8]) -> Self {
        Self { data, pos: 0 }
    }

    /// `n ≤ 32` bits as an unsigned number.
    fn bits(&mut self, n: u32) -> Option<u32> {
        let mut v = 0u32;
        for _ in 0..n {
            let byte = *self.data.get(self.pos / 8)?;
            let bit = (byte >> (7 - self.pos % 8)) & 1;
            v = (v << 1) | u32::from(bit);
            self.pos += 1;
        }
        Some(v)
    }

    /// An unsigned Exp-Golomb number (§9.1); more than 31 leading zeros is malformed.
    fn ue(&mut self) -> Option<u32> {
        let mut zeros = 0;
        while self.bits(1)? == 0 {
            zeros += 1;
            if zeros > 31 {
                return None;
            }
        }
        let rest = self.bits(zeros)?;
        Some(((1u64 << zeros) - 1 + u64::from(rest)).min(u64::from(u32::MAX)) as u32)
    }

    /// A signed Exp-Golomb number (§9.1.1).
    fn se(&mut self) -> Option<i64> {
        let k = i64::from(self.ue()?);
        Some(if k % 2 == 1 { (k + 1) / 2 } else { -(k / 2) })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hex(s: &str) -> Vec<u8> {
        (0..s.len())
            .step_by(2)
            .map(|i| u8::from_str_radix(&s[i..i + 2], 16).unwrap_or(0))
            .collect()
    }

    /// SPSs written by x264 (through ffmpeg) for a 64×48 clip; `ffprobe` reads the same
    /// ranges from the streams they came from.
    #[test]
    fn reads_the_signalled_range() {
        // High profile, `yuvj420p`: full range.
        let full = hex("6764000aacd9447b016c80000003008000000a078912cb");
        assert_eq!(video_full_range(&full), Some(true));
        // High profile, limited range with BT.709 primaries signalled.
        let limited = hex("6764000aacd9447b016a02040480000003008000000a078912cb");
        assert_eq!(video_full_range(&limited), Some(false));
        // Only the primaries were set there: the matrix is 2, "unspecified" (read as BT.601).
        assert_eq!(
            video_signal(&limited).and_then(|s| s.matrix_coefficients),
            Some(2)
        );
        assert_eq!(
            video_signal(&full).and_then(|s| s.matrix_coefficients),
            None
        );
        // Constrained Baseline without a video signal type: not said.
        let silent = hex("6742c00ad9047b011000000300100000030140f1226480");
        assert_eq!(video_full_range(&silent), None);
    }

    #[test]
    fn malformed_parameter_sets_give_none() {
        let full = hex("6764000aacd9447b016c80000003008000000a078912cb");
        for cut in 0..full.len() - 2 {
            // Every prefix either parses to the same answer or gives up; none panics.
            let r = video_full_range(&full[..cut]);
            assert!(r.is_none() || r == Some(true), "{cut}: {r:?}");
        }
        assert_eq!(video_full_range(&[]), None);
        assert_eq!(video_full_range(&[0x67, 0, 0, 0, 0, 0, 0, 0]), None);
    }

    #[test]
    fn exp_golomb_codes() {
        // 1 → 0, 010 → 1, 011 → 2, 00100 → 3; signed 010 → +1, 011 → −1.
        let data = [0b1010_0110, 0b0100_0000];
        let mut r = Bits::new(&data);
        assert_eq!(
            (r.ue(), r.ue(), r.ue(), r.ue()),
            (Some(0), Some(1), Some(2), Some(3))
        );
        let data = [0b0100_1100];
        let mut r = Bits::new(&data);
        assert_eq!((r.se(), r.se()), (Some(1), Some(-1)));
        assert_eq!(unescape(&[0, 0, 3, 1, 0, 0, 3]), vec![0, 0, 1, 0, 0]);
    }
}
