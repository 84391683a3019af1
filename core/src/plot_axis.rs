//! Axis ranges the plotting library can always draw.
//!
//! `plotters` searches for "nice" tick positions by stepping through the range; with an
//! infinite, NaN, empty or absurdly wide range that search never ends (issue D1: a
//! `laplacian_threshold` of 1e308 doubled to infinity hung a worker at 100 % CPU). Every chart
//! in core builds its axes through these two functions, so data and parameters of any value
//! produce a chart, perhaps a dull one, and never a hang.

/// Largest magnitude an axis bound may have.
const LIMIT: f64 = 1e15;

/// A finite, non-empty linear range covering `lo..hi` as far as possible.
pub(crate) fn linear(lo: f64, hi: f64) -> (f64, f64) {
    let fix = |v: f64, fallback: f64| {
        if v.is_nan() {
            fallback
        } else {
            v.clamp(-LIMIT, LIMIT)
        }
    };
    let (lo, hi) = (fix(lo, 0.0), fix(hi, 1.0));
    let (lo, hi) = if lo <= hi { (lo, hi) } else { (hi, lo) };
    if hi - lo > lo.abs().max(hi.abs()) * 1e-9 && hi - lo > 1e-300 {
        (lo, hi)
    } else {
        let pad = (lo.abs() * 0.05).max(1e-9);
        (lo - pad, hi + pad)
    }
}

/// A finite, positive, non-empty range for a log axis, at most 30 decades wide.
pub(crate) fn log(lo: f64, hi: f64) -> (f64, f64) {
    let fix = |v: f64, fallback: f64| {
        if v.is_nan() || v <= 0.0 {
            fallback
        } else {
            v.clamp(1.0 / LIMIT, LIMIT)
        }
    };
    let (lo, hi) = (fix(lo, 1.0 / LIMIT), fix(hi, LIMIT));
    let (lo, hi) = if lo <= hi { (lo, hi) } else { (hi, lo) };
    let lo = lo.max(hi * 1e-30);
    if hi > lo * (1.0 + 1e-9) {
        (lo, hi)
    } else {
        (lo / 2.0, hi * 2.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_input_gives_a_finite_non_empty_range() {
        let vals = [
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::MAX,
            -f64::MAX,
            0.0,
            -0.0,
            1e-320,
            1.0,
            -1.0,
            1e308,
        ];
        for &a in &vals {
            for &b in &vals {
                let (lo, hi) = linear(a, b);
                assert!(
                    lo.is_finite() && hi.is_finite() && lo < hi,
                    "linear {a} {b}"
                );
                let (lo, hi) = log(a, b);
                assert!(
                    lo.is_finite() && hi.is_finite() && lo > 0.0 && lo < hi,
                    "log {a} {b}"
                );
            }
        }
        assert_eq!(linear(2.0, 5.0), (2.0, 5.0));
        assert_eq!(log(0.5, 40.0), (0.5, 40.0));
    }
}
