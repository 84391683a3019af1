//! Number parsing for the IMU log: decimals and exact integer timestamps.

pub(super) const NEG_POW10: [f64; 23] = [
    1e0, 1e-1, 1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11, 1e-12, 1e-13, 1e-14,
    1e-15, 1e-16, 1e-17, 1e-18, 1e-19, 1e-20, 1e-21, 1e-22,
];

pub(super) const POW10: [f64; 23] = [
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16,
    1e17, 1e18, 1e19, 1e20, 1e21, 1e22,
];

/// A decimal number split as `(negative, mantissa, exponent, digits)`: value = ±mantissa·10^exponent.
/// None when the text is not a plain decimal (then the caller falls back to `str::parse`).
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

/// Fast, exactly rounded parse of plain decimals (Clinger's fast path: mantissa < 2⁵³ and
/// |exponent| ≤ 22 make one correctly rounded multiplication or division); anything else goes
/// to the standard library parser. Returns None for non-numbers; NaN/inf parse as such.
#[inline]
pub(crate) fn parse_f64(s: &[u8]) -> Option<f64> {
    if let Some((neg, mant, exp, _)) = decimal(s)
        && mant < (1u64 << 53)
    {
        let m = mant as f64;
        let v = if mant == 0 {
            Some(0.0)
        } else if (0..=22).contains(&exp) {
            Some(m * POW10[exp as usize])
        } else if (-22..0).contains(&exp) {
            Some(m / POW10[(-exp) as usize])
        } else {
            None
        };
        if let Some(v) = v {
            return Some(if neg { -v } else { v });
        }
    }
    std::str::from_utf8(s).ok()?.parse::<f64>().ok()
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
