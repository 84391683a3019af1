//! YCbCr ↔ RGB for 8-bit video: the BT.601 and BT.709 matrices (ITU-R BT.601-7 and BT.709-6,
//! via their luma weights Kr and Kb) in full or limited sample range. The reader's RGB frames
//! use the matrix and range the stream signals; the test writer codes with the same formulas,
//! so a clip written and read back keeps its colours.

/// One YCbCr ↔ RGB conversion (what [`EncodableImage`](super::EncodableImage) writes with).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct YCbCr {
    kr: f64,
    kb: f64,
    full_range: bool,
}

/// The conversion written in fixed point (×256) for the decoder's hot loop.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct FixedToRgb {
    /// Luma gain and black level: `c = gain · (Y − black)`.
    pub gain: i32,
    pub black: i32,
    /// `R = c + r_cr·Cr`, `G = c − g_cb·Cb − g_cr·Cr`, `B = c + b_cb·Cb` (chroma centred on 0).
    pub r_cr: i32,
    pub g_cb: i32,
    pub g_cr: i32,
    pub b_cb: i32,
}

impl YCbCr {
    /// BT.709 when `bt709`, BT.601 otherwise.
    pub(crate) fn new(bt709: bool, full_range: bool) -> Self {
        let (kr, kb) = if bt709 {
            (0.2126, 0.0722)
        } else {
            (0.299, 0.114)
        };
        Self { kr, kb, full_range }
    }

    /// What an H.264 stream's VUI asks for: `matrix_coefficients` 1 is BT.709; every other
    /// code (5 and 6 are BT.601, unsignalled streams default to it in practice) gets BT.601.
    pub(crate) fn signalled(matrix_coefficients: Option<u8>, full_range: bool) -> Self {
        Self::new(matrix_coefficients == Some(1), full_range)
    }

    /// Whether samples use the full 0–255 range.
    pub(crate) fn full_range(self) -> bool {
        self.full_range
    }

    /// (luma scale, chroma scale, luma offset) from 0–255 RGB to code values.
    fn range(self) -> (f64, f64, f64) {
        if self.full_range {
            (1.0, 1.0, 0.0)
        } else {
            (219.0 / 255.0, 224.0 / 255.0, 16.0)
        }
    }

    /// Y, Cb, Cr code values (not rounded) of an RGB triple on 0–255.
    pub(crate) fn ycbcr_of_rgb(self, r: f64, g: f64, b: f64) -> [f64; 3] {
        let (ys, cs, y0) = self.range();
        let kg = 1.0 - self.kr - self.kb;
        let y = self.kr * r + kg * g + self.kb * b;
        let cb = (b - y) / (2.0 * (1.0 - self.kb));
        let cr = (r - y) / (2.0 * (1.0 - self.kr));
        [y0 + ys * y, 128.0 + cs * cb, 128.0 + cs * cr]
    }

    /// The inverse of [`YCbCr::ycbcr_of_rgb`] in fixed point.
    pub(crate) fn to_rgb_fixed(self) -> FixedToRgb {
        let (ys, cs, y0) = self.range();
        let kg = 1.0 - self.kr - self.kb;
        let fixed = |v: f64| (v * 256.0).round() as i32;
        FixedToRgb {
            gain: fixed(1.0 / ys),
            black: y0 as i32,
            r_cr: fixed(2.0 * (1.0 - self.kr) / cs),
            g_cb: fixed(2.0 * self.kb * (1.0 - self.kb) / kg / cs),
            g_cr: fixed(2.0 * self.kr * (1.0 - self.kr) / kg / cs),
            b_cb: fixed(2.0 * (1.0 - self.kb) / cs),
        }
    }
}

impl FixedToRgb {
    /// RGB of one sample.
    pub(crate) fn rgb(&self, y: u8, cb: u8, cr: u8) -> [u8; 3] {
        let c = self.gain * (i32::from(y) - self.black);
        let d = i32::from(cb) - 128;
        let e = i32::from(cr) - 128;
        let clamp = |v: i32| ((v + 128) >> 8).clamp(0, 255) as u8;
        [
            clamp(c + self.r_cr * e),
            clamp(c - self.g_cb * d - self.g_cr * e),
            clamp(c + self.b_cb * d),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bt601_limited_matches_the_classic_integer_coefficients() {
        let f = YCbCr::new(false, false).to_rgb_fixed();
        assert_eq!(
            (f.gain, f.black, f.r_cr, f.g_cb, f.g_cr, f.b_cb),
            (298, 16, 409, 100, 208, 516)
        );
        let f = YCbCr::new(false, true).to_rgb_fixed();
        assert_eq!(
            (f.gain, f.r_cr, f.g_cb, f.g_cr, f.b_cb),
            (256, 359, 88, 183, 454)
        );
    }

    #[test]
    fn round_trips_every_matrix_and_range() {
        for bt709 in [false, true] {
            for full in [false, true] {
                let m = YCbCr::new(bt709, full);
                let inv = m.to_rgb_fixed();
                for rgb in [
                    [0.0, 0.0, 0.0],
                    [255.0; 3],
                    [200.0, 40.0, 30.0],
                    [20.0, 60.0, 220.0],
                ] {
                    let [y, cb, cr] = m.ycbcr_of_rgb(rgb[0], rgb[1], rgb[2]);
                    let q = |v: f64| v.round().clamp(0.0, 255.0) as u8;
                    let back = inv.rgb(q(y), q(cb), q(cr));
                    for c in 0..3 {
                        let e = (f64::from(back[c]) - rgb[c]).abs();
                        assert!(e <= 2.0, "709 {bt709} full {full} {rgb:?} → {back:?}");
                    }
                }
            }
        }
    }

    #[test]
    fn the_wrong_matrix_shifts_saturated_colours() {
        let (m601, m709) = (YCbCr::new(false, false), YCbCr::new(true, false));
        let [y, cb, cr] = m709.ycbcr_of_rgb(200.0, 40.0, 30.0);
        let q = |v: f64| v.round() as u8;
        let wrong = m601.to_rgb_fixed().rgb(q(y), q(cb), q(cr));
        let off = wrong
            .iter()
            .zip([200.0, 40.0, 30.0])
            .map(|(&a, b)| (f64::from(a) - b).abs())
            .fold(0.0, f64::max);
        assert!(off > 8.0, "{wrong:?}");
    }
}
