//! Square fiducial markers shared by the ChArUco and AprilGrid detectors: the standard code
//! tables ([`Dictionary`]) and a detector of black-bordered binary markers
//! ([`detect_markers`]).
//!
//! The codes are ArUco's (Garrido-Jurado, Muñoz-Salinas, Madrid-Cuevas, Marín-Jiménez,
//! "Automatic generation and detection of highly reliable fiducial markers under occlusion",
//! Pattern Recognition 47(6), 2014) and AprilTag's 36h11 family (Olson, "AprilTag: a robust and
//! flexible visual fiducial system", ICRA 2011), as OpenCV ships them; the tables are generated
//! from OpenCV by `core/scripts/gen_marker_dicts.py` (see `dict_data.rs`). Why a table and not a
//! crate: `kornia-apriltag` only knows AprilTag families and pins `faer` to an exact version
//! (Caliper uses `faer` too); `calib-targets-charuco` changes its API between minor versions.
//! The tables are 3,587 numbers; the detector is a few hundred lines.

mod decode;
#[rustfmt::skip]
#[allow(clippy::unreadable_literal)]
mod dict_data;
mod predict;
mod quads;

pub(crate) use decode::SquareMap;
pub use decode::{Marker, MarkerScan, detect_markers};
pub(crate) use predict::predict_missing;

/// A marker dictionary: `bits × bits` codes, and how many bit errors a read may correct.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Dictionary {
    name: &'static str,
    bits: usize,
    codes: &'static [u64],
    max_correction: u32,
}

/// (name, number of codes, OpenCV `maxCorrectionBits`) of each dictionary of a family.
type Prefixes = &'static [(&'static str, usize, u32)];

/// Every family: bits per side, all its codes, its dictionaries.
const FAMILIES: [(usize, &[u64], Prefixes); 4] = [
    (
        dict_data::DICT_4X4_1000_SIZE,
        &dict_data::DICT_4X4_1000,
        dict_data::DICT_4X4_1000_PREFIXES,
    ),
    (
        dict_data::DICT_5X5_1000_SIZE,
        &dict_data::DICT_5X5_1000,
        dict_data::DICT_5X5_1000_PREFIXES,
    ),
    (
        dict_data::DICT_6X6_1000_SIZE,
        &dict_data::DICT_6X6_1000,
        dict_data::DICT_6X6_1000_PREFIXES,
    ),
    (
        dict_data::DICT_APRILTAG_36H11_SIZE,
        &dict_data::DICT_APRILTAG_36H11,
        dict_data::DICT_APRILTAG_36H11_PREFIXES,
    ),
];

impl Dictionary {
    /// The dictionary called `name`, OpenCV's names (`DICT_4X4_50` … `DICT_6X6_1000`,
    /// `DICT_APRILTAG_36h11`), case-insensitive; `tag36h11` / `t36h11` (Kalibr) is
    /// `DICT_APRILTAG_36h11`.
    pub fn from_name(name: &str) -> Option<Self> {
        let key = name.trim();
        let key = if key.eq_ignore_ascii_case("tag36h11") || key.eq_ignore_ascii_case("t36h11") {
            "DICT_APRILTAG_36h11"
        } else {
            key
        };
        FAMILIES.iter().find_map(|&(bits, codes, prefixes)| {
            prefixes
                .iter()
                .find(|(n, _, _)| n.eq_ignore_ascii_case(key))
                .map(|&(n, len, max_correction)| Self {
                    name: n,
                    bits,
                    codes: &codes[..len],
                    max_correction,
                })
        })
    }

    /// Names of every dictionary [`Dictionary::from_name`] knows.
    pub fn names() -> Vec<&'static str> {
        FAMILIES
            .iter()
            .flat_map(|(_, _, p)| p.iter().map(|(n, _, _)| *n))
            .collect()
    }

    /// OpenCV's name.
    pub fn name(&self) -> &'static str {
        self.name
    }

    /// Data bits per side (4, 5, 6).
    pub fn bits(&self) -> usize {
        self.bits
    }

    /// Number of codes (marker ids `0..len`).
    pub fn len(&self) -> usize {
        self.codes.len()
    }

    /// Never: every dictionary has codes.
    pub fn is_empty(&self) -> bool {
        self.codes.is_empty()
    }

    /// Bit errors a read may have and still be accepted (OpenCV's `maxCorrectionBits`: half
    /// the least Hamming distance between codes, rotations included, rounded down).
    pub fn max_correction(&self) -> u32 {
        self.max_correction
    }

    /// The code of marker `id`: `bits²` bits, row-major from the top-left, MSB first,
    /// 1 = white.
    pub fn code(&self, id: usize) -> Option<u64> {
        self.codes.get(id).copied()
    }

    /// Whether cell `(row, col)` of marker `id` (data bits only) is white.
    pub fn is_white(&self, id: usize, row: usize, col: usize) -> bool {
        let n = self.bits;
        self.code(id)
            .is_some_and(|c| row < n && col < n && (c >> (n * n - 1 - (row * n + col))) & 1 == 1)
    }

    /// The best match of a read `code` (same layout as [`Dictionary::code`]) among every
    /// code and its four rotations: `(id, rotation, bit errors)` where `rotation` is the number
    /// of quarter turns clockwise the read is from the canonical marker, or `None` when no code
    /// is within [`Dictionary::max_correction`] errors.
    pub fn identify(&self, code: u64) -> Option<(usize, usize, u32)> {
        let mut rots = [code; 4];
        for k in 1..4 {
            rots[k] = rotate_ccw(rots[k - 1], self.bits);
        }
        let mut best: Option<(usize, usize, u32)> = None;
        for (id, &c) in self.codes.iter().enumerate() {
            for (k, &r) in rots.iter().enumerate() {
                let d = (c ^ r).count_ones();
                if best.is_none_or(|b| d < b.2) {
                    best = Some((id, k, d));
                }
            }
        }
        best.filter(|b| b.2 <= self.max_correction)
    }
}

/// The `n × n` bit matrix `code` turned a quarter counter-clockwise:
/// `out[i][j] = in[j][n − 1 − i]`.
pub(crate) fn rotate_ccw(code: u64, n: usize) -> u64 {
    let bit = |c: u64, i: usize, j: usize| (c >> (n * n - 1 - (i * n + j))) & 1;
    let mut out = 0u64;
    for i in 0..n {
        for j in 0..n {
            out = (out << 1) | bit(code, j, n - 1 - i);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dictionaries_have_opencv_sizes_and_correction_bits() {
        for (name, len, corr) in [
            ("DICT_4X4_50", 50, 1),
            ("DICT_4X4_1000", 1000, 0),
            ("DICT_5X5_250", 250, 2),
            ("DICT_6X6_250", 250, 5),
            ("DICT_APRILTAG_36h11", 587, 5),
            ("tag36h11", 587, 5),
        ] {
            let d = Dictionary::from_name(name).expect(name);
            assert_eq!((d.len(), d.max_correction()), (len, corr), "{name}");
        }
        assert!(Dictionary::from_name("DICT_7X7_50").is_none());
        assert_eq!(Dictionary::names().len(), 13);
    }

    #[test]
    fn identify_corrects_errors_and_rotations() {
        let d = Dictionary::from_name("DICT_6X6_250").expect("dict");
        let c = d.code(17).expect("code");
        // A quarter turn counter-clockwise of the read = the read is turned clockwise by 3.
        let rotated = rotate_ccw(rotate_ccw(rotate_ccw(c, 6), 6), 6);
        let flipped = rotated ^ 0b1001_0000_0001;
        assert_eq!(d.identify(flipped), Some((17, 1, 3)));
        assert_eq!(rotate_ccw(rotated, 6), c);
    }
}
