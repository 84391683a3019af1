//! Number parsing for the IMU log's general line parser: values through the standard library,
//! timestamps as exact integer nanoseconds.
//!
//! Values used to go through a hand-written parser (Clinger's fast path: a mantissa below 2⁵³
//! times or divided by an exact power of ten up to 10²², else the standard library). It gave the
//! same bits as `str::parse::<f64>` on every input — on all ~290 000 calls the test suite makes
//! and on 34 million generated decimal strings (signs, leading zeros, up to 21 integer and 21
//! fraction digits, exponents, stray characters, and every format the tests print values in) —
//! and saved nothing measurable: well-formed lines, which is what the `imu_vs_peer` benchmark's
//! logs consist of, are parsed by `line::fast_line` and never reach it. So it is gone.

/// A decimal number split as `(negative, mantissa, exponent, digits)`: value =
/// ±mantissa·10^exponent. None when the text is not a plain decimal (then [`parse_timestamp`]
/// falls back to `str::parse`).
#[inline]
fn decimal(s: &[u8]) -> Option<(bool, u64, i32, u32)> {
    let mut i = 0;
    let n = s.len();
    let neg = match s.first() {
        Some(b'-') => {
            i = 1;
            true
        }
        Some(b'+') => {
            i = 1;
            false
        }
        _ => false,
    };
    let mut mant: u64 = 0;
    let mut digits: u32 = 0; // significant digits accumulated
    let mut any = false;
    let mut exp: i32 = 0;
    while i < n && s[i].is_ascii_digit() {
        any = true;
        if mant != 0 || s[i] != b'0' {
            digits += 1;
            if digits > 19 {
                return None;
            }
        }
        mant = mant * 10 + u64::from(s[i] - b'0');
        i += 1;
    }
    if i < n && s[i] == b'.' {
        i += 1;
        while i < n && s[i].is_ascii_digit() {
            any = true;
            if mant != 0 || s[i] != b'0' {
                digits += 1;
                if digits > 19 {
                    return None;
                }
            }
            mant = mant * 10 + u64::from(s[i] - b'0');
            exp -= 1;
            i += 1;
        }
    }
    if !any {
        return None;
    }
    if i < n && (s[i] == b'e' || s[i] == b'E') {
        i += 1;
        let eneg = take_sign(s, &mut i);
        let mut e: i32 = 0;
        let mut ed = false;
        while i < n && s[i].is_ascii_digit() {
            ed = true;
            e = (e * 10 + i32::from(s[i] - b'0')).min(100_000);
            i += 1;
        }
        if !ed {
            return None;
        }
        exp += if eneg { -e } else { e };
    }
    if i != n {
        return None;
    }
    Some((neg, mant, exp, digits))
}

/// A field as `f64`, or None when it is not a number (bytes that are not UTF-8 included). This
/// is the standard library's parser, which is correctly rounded and also accepts `nan`, `inf`
/// and `infinity` in any case (the line parser then counts such rows as NaN rows). Only the
/// general line parser and the header detection use it; well-formed lines never get here (see
/// `line::fast_line`).
#[inline]
pub(super) fn parse_f64(s: &[u8]) -> Option<f64> {
    std::str::from_utf8(s).ok()?.parse().ok()
}

/// Timestamp in integer ns from a decimal in `unit` (10^pow10 ns), exactly when the text has at
/// most 19 significant digits (`1.700000000005e+18` included), else via f64.
pub(super) fn parse_timestamp(s: &[u8], pow10: i32) -> Option<i64> {
    if let Some((neg, mant, exp, _)) = decimal(s) {
        let e = exp + pow10;
        let m = i128::from(mant);
        let v: i128 = if e >= 0 {
            if e > 38 {
                return if mant == 0 { Some(0) } else { None };
            }
            m.checked_mul(10i128.checked_pow(e as u32)?)?
        } else if e < -38 {
            0
        } else {
            let d = 10i128.pow((-e) as u32);
            (m + d / 2) / d
        };
        let v = if neg { -v } else { v };
        return i64::try_from(v).ok();
    }
    let x: f64 = std::str::from_utf8(s).ok()?.parse().ok()?;
    let ns = x * 10f64.powi(pow10);
    if ns.is_finite() && ns.abs() < 9.2e18 {
        Some(ns.round() as i64)
    } else {
        None
    }
}

/// Consume an optional `+`/`-` at `*pos` (of an exponent); true for `-`.
#[inline]
pub(super) fn take_sign(s: &[u8], pos: &mut usize) -> bool {
    match s.get(*pos) {
        Some(b'-') => {
            *pos += 1;
            true
        }
        Some(b'+') => {
            *pos += 1;
            false
        }
        _ => false,
    }
}
