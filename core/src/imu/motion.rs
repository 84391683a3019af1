//! Is the log static? A per-window motion detector for the noise analysis (`imu_noise`).
//!
//! The Allan deviation assumes the sensor measures only noise around a constant. A log in which
//! the IMU moves (a MAV flight, a hand-held sequence, the rotations of a multi-position
//! calibration) yields an Allan curve dominated by the motion, and the fitted "noise" is then
//! meaningless. We therefore split the log into windows (1 s by default) and flag a window as
//! moving when it differs from the sensor's own noise floor, in the spirit of the
//! variance-threshold static detectors of Tedaldi, Pretto & Menegatti (ICRA 2014) and of
//! zero-velocity detectors (Skog et al., "Zero-velocity detection — an algorithm evaluation",
//! IEEE TBME 57(11), 2010), but with the floor estimated robustly from the log itself so no
//! sensor-specific threshold is needed.
//!
//! Per window and per channel (gyro x, y, z, accel x, y, z and the accelerometer norm ‖a‖) we
//! compute the mean, the standard deviation and the first-difference noise
//! σ_d = rms(y[i+1] − y[i]) / √2 (equal to σ for white noise, insensitive to slow motion). The
//! norm adds sensitivity to accelerations along gravity; the axes catch horizontal pushes, which
//! change ‖a‖ only to second order. Floors are medians over all windows: a log
//! that is static more than half of the time has its true noise there. A window is moving when
//! any of:
//! 1. its std exceeds k × the floor std (vibration, shaking, motion that starts or stops);
//! 2. its mean departs from the median of the window means within ±30 windows by more than
//!    k × the floor std (a steady rotation or acceleration: no extra spread within the window).
//!    The local median follows bias drift, thermal drift and random walk, which move far less
//!    than k σ in 30 s, so those never flag a static log;
//! 3. std / σ_d exceeds max(5, min(2 × its 10th percentile over the windows, 15)):
//!    low-frequency content that white noise has not. This catches logs that move *all* the
//!    time, whose median floor is the motion itself. Sensors with a strong internal low-pass
//!    filter have std / σ_d above 1 even at rest (≈ 1/√(1 − φ) for an AR(1) filter φ), hence the
//!    relative term from the quietest windows, capped so motion cannot raise it without bound.
//!
//! Flagged windows are merged into moving intervals; the static stretches between them lose
//! one window at each end next to motion (the start or end of a movement may stay below the
//! thresholds inside its first window).

use serde::{Deserialize, Serialize};

use super::log::ImuLog;
use crate::error::CoreResult;
use crate::progress::Progress;

/// What `imu_noise` does with a log in which the IMU moves.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub enum MotionPolicy {
    /// Fail with `invalid_input`, naming the moving intervals (default: a noise model fitted to
    /// motion is wrong, and saying so beats a plausible-looking number).
    #[default]
    Refuse,
    /// Analyse only the longest static stretch (reported in `static_analysis`).
    LongestStatic,
    /// Analyse the whole log anyway and only warn (e.g. a constant-rate turntable).
    Ignore,
}

/// How the motion check went, in the `imu_noise` report.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct StaticAnalysis {
    /// The policy applied.
    pub policy: MotionPolicy,
    /// Whether the check ran (false for logs shorter than 5 windows: too few to estimate a
    /// noise floor; `note` says so).
    pub checked: bool,
    /// Why the check did not run, or other remarks.
    pub note: Option<String>,
    /// Window length, s.
    pub window_s: f64,
    /// Number of windows.
    pub windows: usize,
    /// Number of windows flagged as moving.
    pub moving_windows: usize,
    /// Threshold factor k.
    pub k: f64,
    /// Noise floors: median per-window std of gyro x, y, z (rad/s).
    pub gyro_std_floor: [f64; 3],
    /// Noise floors: median per-window std of accel x, y, z (m/s²).
    pub accel_std_floor: [f64; 3],
    /// Noise floor: median per-window std of the accelerometer norm (m/s²).
    pub accel_norm_std_floor: f64,
    /// Moving intervals `[start, end]`, s from the first sample.
    pub moving_intervals_s: Vec<[f64; 2]>,
    /// Static stretches `[start, end]` (guard window removed next to motion), s.
    pub static_intervals_s: Vec<[f64; 2]>,
    /// Interval analysed, s.
    pub used_interval_s: [f64; 2],
    /// Samples analysed.
    pub used_samples: usize,
}

/// Result of [`detect_motion`]: windows, flags and the derived intervals (sample ranges are
/// half-open `[start, end)`).
#[derive(Debug, Clone)]
pub struct MotionScan {
    /// Window length in samples.
    pub window: usize,
    /// Window boundaries (half-open sample ranges).
    pub windows: Vec<(usize, usize)>,
    /// Whether each window moves.
    pub moving: Vec<bool>,
    /// Median per-window std of gyro x, y, z.
    pub gyro_floor: [f64; 3],
    /// Median per-window std of accel x, y, z.
    pub accel_floor: [f64; 3],
    /// Median per-window std of ‖a‖.
    pub accel_norm_floor: f64,
    /// Merged moving runs, sample ranges.
    pub moving_runs: Vec<(usize, usize)>,
    /// Static stretches with the guard window removed, sample ranges.
    pub static_runs: Vec<(usize, usize)>,
}

/// Windows needed before the floors mean anything.
pub const MIN_WINDOWS: usize = 5;
/// Half-width, in windows, of the neighbourhood whose median mean is the local baseline.
const LOCAL_HALF: usize = 30;
/// Absolute part of the low-frequency test (criterion 3).
const RATIO_MIN: f64 = 5.0;
/// Largest limit of the low-frequency test, whatever the quiet windows say.
const RATIO_CAP: f64 = 15.0;
/// Channels tested: gyro x, y, z, accel x, y, z, ‖a‖.
const CH: usize = 7;

#[derive(Debug, Clone, Copy, Default)]
struct Win {
    mean: [f64; CH],
    std: [f64; CH],
    dstd: [f64; CH],
}

/// Flag moving windows of `log[range]` (see the module doc). `window` is the window length in
/// samples (≥ 10), `k` the threshold factor. Returns `None` when the range holds fewer than
/// [`MIN_WINDOWS`] windows.
pub fn detect_motion(
    log: &ImuLog,
    window: usize,
    k: f64,
    progress: &dyn Progress,
) -> CoreResult<Option<MotionScan>> {
    let n = log.len();
    let window = window.max(10);
    let nw = n / window;
    if nw < MIN_WINDOWS {
        return Ok(None);
    }
    // The last window absorbs the remainder (less than one window).
    let windows: Vec<(usize, usize)> = (0..nw)
        .map(|w| (w * window, if w + 1 == nw { n } else { (w + 1) * window }))
        .collect();
    let axes: [&[f32]; 6] = std::array::from_fn(|c| log.channel_offsets(c));
    let mut stats = Vec::with_capacity(nw);
    let mut norm = Vec::with_capacity(2 * window);
    for (w, &(a, b)) in windows.iter().enumerate() {
        if w % 64 == 0 {
            progress.check()?;
            progress.report("motion", w as u64, nw as u64);
        }
        let mut s = Win::default();
        for (c, g) in axes.iter().enumerate() {
            let (m, sd, d) = moments(g[a..b].iter().map(|&v| f64::from(v)));
            s.mean[c] = m;
            s.std[c] = sd;
            s.dstd[c] = d;
        }
        norm.clear();
        norm.extend((a..b).map(|i| {
            let (x, y, z) = (log.value(3, i), log.value(4, i), log.value(5, i));
            (x * x + y * y + z * z).sqrt()
        }));
        let (m, sd, d) = moments(norm.iter().copied());
        s.mean[6] = m;
        s.std[6] = sd;
        s.dstd[6] = d;
        stats.push(s);
    }
    progress.report("motion", nw as u64, nw as u64);

    let mut floor = [0.0; CH];
    let mut ratio_limit = [RATIO_MIN; CH];
    for c in 0..CH {
        let stds: Vec<f64> = stats.iter().map(|s| s.std[c]).collect();
        let med = median(stds.clone());
        // A channel quantised below one step can have a zero median std: fall back to the mean.
        floor[c] = if med > 0.0 {
            med
        } else {
            stds.iter().sum::<f64>() / nw as f64
        };
        let mut ratios: Vec<f64> = stats.iter().map(|s| ratio(s.std[c], s.dstd[c])).collect();
        let p10 = *ratios.select_nth_unstable_by(nw / 10, f64::total_cmp).1;
        ratio_limit[c] = RATIO_MIN.max((2.0 * p10).min(RATIO_CAP));
    }

    let mut moving = vec![false; nw];
    let mut local = Vec::with_capacity(2 * LOCAL_HALF + 1);
    for (w, s) in stats.iter().enumerate() {
        if w % 256 == 0 {
            progress.check()?;
        }
        let lo = w.saturating_sub(LOCAL_HALF);
        let hi = (w + LOCAL_HALF + 1).min(nw);
        moving[w] = (0..CH).any(|c| {
            if floor[c] <= 0.0 {
                // A constant channel carries no information about motion.
                return false;
            }
            local.clear();
            local.extend(stats[lo..hi].iter().map(|t| t.mean[c]));
            let base = median(std::mem::take(&mut local));
            s.std[c] > k * floor[c]
                || (s.mean[c] - base).abs() > k * floor[c]
                || ratio(s.std[c], s.dstd[c]) > ratio_limit[c]
        });
    }

    let mut moving_runs = Vec::new();
    let mut w = 0;
    while w < nw {
        if moving[w] {
            let start = w;
            while w < nw && moving[w] {
                w += 1;
            }
            moving_runs.push((start, w));
        } else {
            w += 1;
        }
    }
    // Static stretches in window indices, minus one guard window next to motion.
    let mut static_runs = Vec::new();
    let mut prev_end = 0usize;
    for &(s, e) in moving_runs.iter().chain(std::iter::once(&(nw, nw))) {
        let a = if prev_end == 0 && !moving[0] {
            0
        } else {
            prev_end + 1
        };
        let b = if s == nw { nw } else { s.saturating_sub(1) };
        if b > a {
            static_runs.push((windows[a].0, windows[b - 1].1));
        }
        prev_end = e;
    }
    let moving_runs = moving_runs
        .into_iter()
        .map(|(s, e)| (windows[s].0, windows[e - 1].1))
        .collect();
    Ok(Some(MotionScan {
        window,
        windows,
        moving,
        gyro_floor: [floor[0], floor[1], floor[2]],
        accel_floor: [floor[3], floor[4], floor[5]],
        accel_norm_floor: floor[6],
        moving_runs,
        static_runs,
    }))
}

/// Mean, standard deviation and first-difference noise rms(Δy)/√2 of a window.
fn moments(v: impl Iterator<Item = f64> + Clone) -> (f64, f64, f64) {
    let mut n = 0usize;
    let mut sum = 0.0;
    for x in v.clone() {
        n += 1;
        sum += x;
    }
    if n < 2 {
        return (sum, 0.0, 0.0);
    }
    let mean = sum / n as f64;
    let (mut ss, mut dd) = (0.0, 0.0);
    let mut prev: Option<f64> = None;
    for x in v {
        ss += (x - mean) * (x - mean);
        if let Some(p) = prev {
            dd += (x - p) * (x - p);
        }
        prev = Some(x);
    }
    let std = (ss / (n - 1) as f64).sqrt();
    let dstd = (dd / (2 * (n - 1)) as f64).sqrt();
    (mean, std, dstd)
}

/// std / σ_d, 1 for a constant window.
fn ratio(std: f64, dstd: f64) -> f64 {
    if dstd > 0.0 {
        std / dstd
    } else if std > 0.0 {
        f64::INFINITY
    } else {
        1.0
    }
}

/// Median (upper median for even lengths; NaN-free inputs), 0 for an empty vector.
fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let mid = v.len() / 2;
    let (_, m, _) = v.select_nth_unstable_by(mid, f64::total_cmp);
    *m
}

/// `"12.0–15.5 s, 40.0–41.0 s"`: the first `max` intervals, then a count of the rest.
pub fn describe_intervals(iv: &[[f64; 2]], max: usize) -> String {
    let mut parts: Vec<String> = iv
        .iter()
        .take(max)
        .map(|[a, b]| format!("{a:.1}–{b:.1} s"))
        .collect();
    if iv.len() > max {
        parts.push(format!("and {} more", iv.len() - max));
    }
    parts.join(", ")
}

/// The outcome of the motion check for `imu_noise`: the half-open sample range to analyse,
/// the report section and an optional warning.
pub(crate) struct StaticChoice {
    pub range: (usize, usize),
    pub analysis: StaticAnalysis,
    pub warning: Option<String>,
}

/// Run [`detect_motion`] on the whole log and apply `policy`: refuse a moving log with
/// `invalid_input` naming the moving intervals, keep its longest static stretch, or only warn.
pub(crate) fn choose_static(
    log: &ImuLog,
    rate: f64,
    policy: MotionPolicy,
    window_s: f64,
    k: f64,
    progress: &dyn Progress,
) -> CoreResult<StaticChoice> {
    let n = log.len();
    let window = ((window_s * rate).round() as usize).max(10);
    let times = log.times_s();
    let t = |i: usize| times.get(i).copied().unwrap_or(0.0);
    let span = |(a, b): (usize, usize)| [t(a), t(b.saturating_sub(1))];
    let mut analysis = StaticAnalysis {
        policy,
        window_s: window as f64 / rate,
        k,
        used_interval_s: span((0, n)),
        used_samples: n,
        ..Default::default()
    };
    let Some(scan) = detect_motion(log, window, k, progress)? else {
        analysis.note = Some(format!(
            "motion check skipped: fewer than {MIN_WINDOWS} windows of {:.2} s",
            analysis.window_s
        ));
        return Ok(StaticChoice {
            range: (0, n),
            warning: analysis.note.clone(),
            analysis,
        });
    };
    analysis.checked = true;
    analysis.windows = scan.windows.len();
    analysis.moving_windows = scan.moving.iter().filter(|&&m| m).count();
    analysis.gyro_std_floor = scan.gyro_floor;
    analysis.accel_std_floor = scan.accel_floor;
    analysis.accel_norm_std_floor = scan.accel_norm_floor;
    analysis.moving_intervals_s = scan.moving_runs.iter().map(|&r| span(r)).collect();
    analysis.static_intervals_s = scan.static_runs.iter().map(|&r| span(r)).collect();
    if scan.moving_runs.is_empty() {
        return Ok(StaticChoice {
            range: (0, n),
            analysis,
            warning: None,
        });
    }
    let moving = describe_intervals(&analysis.moving_intervals_s, 8);
    let share = 100.0 * analysis.moving_windows as f64 / analysis.windows as f64;
    let longest = scan.static_runs.iter().copied().max_by_key(|&(a, b)| b - a);
    match policy {
        MotionPolicy::Refuse => {
            let hint = match longest {
                Some(r) => {
                    let [a, b] = span(r);
                    format!(
                        "set params.motion to \"longest_static\" to analyse the longest static \
                         stretch ({a:.1}–{b:.1} s)"
                    )
                }
                None => "no static stretch was found".to_string(),
            };
            Err(crate::error::CoreError::input(format!(
                "the IMU moves during the log, so its Allan deviation would measure the motion, \
                 not the noise: moving {moving} ({share:.0} % of {} windows of {:.2} s); {hint}, \
                 or record the IMU at rest",
                analysis.windows, analysis.window_s
            )))
        }
        MotionPolicy::LongestStatic => {
            let min = MIN_WINDOWS * scan.window;
            let Some(r) = longest.filter(|&(a, b)| b - a >= min) else {
                return Err(crate::error::CoreError::input(format!(
                    "the IMU moves during the log ({moving}) and no static stretch lasts \
                     {MIN_WINDOWS} windows ({:.1} s)",
                    MIN_WINDOWS as f64 * analysis.window_s
                )));
            };
            analysis.used_interval_s = span(r);
            analysis.used_samples = r.1 - r.0;
            let [a, b] = analysis.used_interval_s;
            Ok(StaticChoice {
                range: r,
                warning: Some(format!(
                    "the IMU moves during the log ({moving}): only the longest static stretch \
                     {a:.1}–{b:.1} s ({:.0} % of the samples) was analysed",
                    100.0 * (r.1 - r.0) as f64 / n as f64
                )),
                analysis,
            })
        }
        MotionPolicy::Ignore => Ok(StaticChoice {
            range: (0, n),
            warning: Some(format!(
                "the IMU moves during the log ({moving}, {share:.0} % of the windows); analysed \
                 anyway because params.motion is \"ignore\""
            )),
            analysis,
        }),
    }
}
