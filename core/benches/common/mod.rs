//! Helpers shared by the benchmark binaries.

/// Median of a sample (mean of the middle two for an even count; NaN when empty).
pub fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        f64::NAN
    } else if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Median wall time in ms of `runs` calls, and the last result. (Every bench binary compiles
/// this module; those that time their stages differently leave it unused.)
#[allow(dead_code)]
pub fn timed<T>(runs: usize, mut f: impl FnMut() -> T) -> (T, f64) {
    let mut ts = Vec::with_capacity(runs);
    let mut out = None;
    for _ in 0..runs {
        let t0 = std::time::Instant::now();
        out = Some(f());
        ts.push(t0.elapsed().as_secs_f64() * 1e3);
    }
    (out.expect("runs >= 1"), median(ts))
}

/// The Python interpreter the peer scripts run under: `CALIPER_PYTHON` (a virtual
/// environment with cv2, scikit-image, allantools) or `python3` from the `PATH`. A system
/// Python usually lacks cv2, and a peer that fails to import is a peer that did not run.
#[allow(dead_code)]
pub fn python() -> std::ffi::OsString {
    std::env::var_os("CALIPER_PYTHON").unwrap_or_else(|| "python3".into())
}
