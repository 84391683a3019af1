//! Overlapping Allan deviation and the three-term noise fit (`imu_noise`).
//!
//! Definitions follow IEEE Std 952-1997 (Annex C) and El-Sheimy, Hou & Niu, "Analysis and
//! modeling of inertial sensors using Allan variance", IEEE TIM 57(1), 2008. For a rate signal
//! y sampled every τ₀, with the cumulative sum x_k = Σ_{i<k} (y_i − ȳ) (the "phase", in units of
//! τ₀), the overlapping Allan variance at cluster size m (τ = m τ₀) is
//!
//! σ²(τ) = Σ_{k=0}^{n−1} (x_{k+2m} − 2x_{k+m} + x_k)² / (2 m² n),  n = N + 1 − 2m,
//!
//! which is what `allantools.oadev` computes. Removing the mean before the cumulative sum changes
//! nothing mathematically (a constant cancels in the second difference) but keeps |x| small.
//! x is kept as exact f64 values every 256 samples plus f32 offsets from them ([`PhaseBuffer`]):
//! the rounding is ~10⁻⁶ of the white-noise σ, far below the estimator's resolution, and it
//! halves the buffer and the memory traffic.
//!
//! Cost: O(N) per τ, done for all τ at once in cache-sized blocks (the short-τ windows stay in
//! cache; the long-τ terms stream through memory once per block row), split across threads.
//!
//! Noise model fitted to the AVAR (white noise N, flicker/bias instability B, random walk K):
//! σ²(τ) = N²/τ + (0.6643·B)² + K²·τ/3, 0.6643 = √(2 ln 2 / π). The fit is the one of the peer
//! (`shared/peers/imu_allan.py`) so numbers are comparable: non-negative least squares on the
//! octave points with τ ≥ 0.1 s and ≥ 2 clusters, each row divided by the measured AVAR and
//! weighted by √(clusters). The classic slope read-offs (N at τ = 1 s of the −½ line, K at
//! τ = 3 s of the +½ line, B = min ADEV / 0.6643) are reported beside it.
//!
//! Before the analysis the log goes through the motion check (`super::motion`): a moving log is
//! refused, trimmed to its longest static stretch or only flagged, per `params.motion`.
//!
//! Files: `types` (parameters and the report), `oavar` (the blocked multi-τ sum over the
//! cumulative sum), `edf` (equivalent degrees of freedom and confidence intervals), `fit` (the
//! NNLS noise fit, its uncertainty and the classic read-offs); this file runs the analysis
//! ([`imu_noise`]) and condenses it into Kalibr's worst-axis values.

mod edf;
mod fit;
mod oavar;
mod types;

pub use edf::{edf_for, edf_white_fm};
pub use fit::{FLICKER_FACTOR, fit_noise};
pub use oavar::cluster_sizes;
pub(crate) use oavar::{PhaseBuffer, oavar_sums};
pub use types::{
    AdevPoint, AxisNoise, ClassicReadoff, ImuNoiseParams, ImuNoiseReport, KalibrImu, NoiseFit,
    NoiseUnits,
};

use super::log::{ImuLog, read_imu_log};
use super::motion::choose_static;
use crate::error::{CoreError, CoreResult};
use crate::progress::Progress;
use edf::{avar_interval, normal_quantile};

/// Streams an IMU CSV log and characterises its noise by Allan deviation (see the module doc).
///
/// Progress steps: `"parse"` (bytes), `"motion"` (windows checked), `"allan"` (axes done of 6).
pub fn imu_noise(
    reader: impl std::io::BufRead,
    params: &ImuNoiseParams,
    progress: &dyn Progress,
) -> CoreResult<ImuNoiseReport> {
    params.validate()?;
    let log = read_imu_log(reader, &params.csv, progress)?;
    imu_noise_from_log(&log, params, progress)
}

/// [`imu_noise`] on an already parsed log.
pub fn imu_noise_from_log(
    log: &ImuLog,
    params: &ImuNoiseParams,
    progress: &dyn Progress,
) -> CoreResult<ImuNoiseReport> {
    params.validate()?;
    let stats = &log.stats;
    let (rate, rate_source) = match params.rate_hz {
        Some(r) => (r, "params.rate_hz".to_string()),
        None => (stats.rate_hz, "1 / median timestamp step".to_string()),
    };
    if !(rate.is_finite() && rate > 0.0) {
        return Err(CoreError::input(
            "cannot estimate the sample rate from the timestamps",
        ));
    }
    let choice = choose_static(
        log,
        rate,
        params.motion,
        params.motion_window_s,
        params.motion_k,
        progress,
    )?;
    let (lo, hi) = choice.range;
    let n = hi - lo;
    let duration_s = if n == log.len() {
        stats.duration_s
    } else {
        choice.analysis.used_interval_s[1] - choice.analysis.used_interval_s[0]
    };
    let ms = cluster_sizes(n, params.taus_per_octave);
    if ms.len() < 3 {
        return Err(CoreError::input(format!(
            "only {n} samples: too short for an Allan deviation (need at least 8)"
        )));
    }
    let z = normal_quantile(0.5 + 0.5 * params.confidence);

    progress.report("allan", 0, 6);
    let mut x = PhaseBuffer::default();
    let mut sums: Vec<Vec<f64>> = Vec::with_capacity(6);
    for c in 0..6 {
        sums.push(oavar_sums(
            &log.channel_offsets(c)[lo..hi],
            &ms,
            &mut x,
            progress,
        )?);
        progress.report("allan", c as u64 + 1, 6);
    }
    drop(x);

    let mut axes = Vec::with_capacity(6);
    for (c, s) in sums.iter().enumerate() {
        let sensor = if c < 3 { "gyro" } else { "accel" };
        let mut curve: Vec<AdevPoint> = ms
            .iter()
            .zip(s)
            .map(|(&m, &sum)| {
                let n_terms = (n + 1 - 2 * m) as u64;
                let avar = sum / (2.0 * (m as f64).powi(2) * n_terms as f64);
                let edf = edf_white_fm(n + 1, m);
                let (lo, hi) = avar_interval(avar, edf, z);
                AdevPoint {
                    tau_s: m as f64 / rate,
                    m: m as u64,
                    adev: avar.sqrt(),
                    n_terms,
                    clusters: n_terms as f64 / m as f64,
                    edf,
                    ci_low: lo.map(f64::sqrt),
                    ci_high: hi.map(f64::sqrt),
                    octave: m.is_power_of_two(),
                    fitted: false,
                }
            })
            .collect();
        let (fit, classic, kub) = fit_noise(&mut curve, params, z);
        axes.push(AxisNoise {
            sensor: sensor.to_string(),
            axis: ["x", "y", "z"][c % 3].to_string(),
            units: units(sensor),
            curve,
            fit,
            classic,
            k_upper_bound: kub,
        });
    }

    let mut warnings: Vec<String> = choice.warning.clone().into_iter().collect();
    if stats.gaps > 0 {
        warnings.push(format!(
            "{} timestamp gaps totalling {:.3} s ({:.2} % of the log): the Allan deviation assumes \
             uniform sampling and treats the samples as contiguous",
            stats.gaps,
            stats.gap_time_s,
            100.0 * stats.gap_time_s / stats.duration_s.max(1e-12)
        ));
    }
    let skipped =
        stats.junk_rows + stats.nan_rows + stats.duplicate_timestamps + stats.backwards_timestamps;
    if skipped > 0 {
        warnings.push(format!(
            "{skipped} rows skipped (junk {}, NaN {}, duplicate {}, backwards {})",
            stats.junk_rows, stats.nan_rows, stats.duplicate_timestamps, stats.backwards_timestamps
        ));
    }
    if axes.iter().any(|a| a.fit.b.is_none() || a.fit.k.is_none()) {
        warnings.push(format!(
            "log of {:.0} s: B or K not determinable on some axes (see the reasons); \
             bias instability and random walk typically need hours of static data",
            duration_s
        ));
    }
    let kalibr = kalibr_summary(&axes, rate);
    Ok(ImuNoiseReport {
        schema: "caliper.imu_noise/v1".to_string(),
        rate_hz: rate,
        rate_source,
        duration_s,
        samples: n,
        static_analysis: choice.analysis,
        axes,
        kalibr,
        method: format!(
            "overlapping Allan deviation (IEEE Std 952 / El-Sheimy et al. 2008) from a mean-removed \
             f64 cumulative sum; weighted NNLS of N²/τ + (0.6643 B)² + K²τ/3 on octave τ ≥ {} s with \
             ≥ {} clusters, rows / AVAR, weights √clusters; {:.1} % intervals from the EDF of the \
             noise type dominating each τ in the fitted model (Howe, Allan & Barnes 1981; NIST SP \
             1065) and Wilson-Hilferty χ² quantiles",
            params.fit_tau_min_s,
            params.fit_min_clusters,
            100.0 * params.confidence
        ),
        warnings,
        parse: stats.clone(),
    })
}

fn units(sensor: &str) -> NoiseUnits {
    if sensor == "gyro" {
        NoiseUnits {
            n: "rad/s/sqrt(Hz)".into(),
            b: "rad/s".into(),
            k: "rad/s^2/sqrt(Hz)".into(),
        }
    } else {
        NoiseUnits {
            n: "m/s^2/sqrt(Hz)".into(),
            b: "m/s^2".into(),
            k: "m/s^3/sqrt(Hz)".into(),
        }
    }
}

fn kalibr_summary(axes: &[AxisNoise], rate: f64) -> KalibrImu {
    let mut out = KalibrImu {
        update_rate: rate,
        ..Default::default()
    };
    let mut notes = Vec::new();
    let mut worst = |sensor: &str, label: &str, get: &dyn Fn(&AxisNoise) -> Option<f64>| {
        let sel: Vec<&AxisNoise> = axes.iter().filter(|a| a.sensor == sensor).collect();
        let missing: Vec<String> = sel
            .iter()
            .filter(|a| get(a).is_none())
            .map(|a| a.axis.clone())
            .collect();
        if !missing.is_empty() {
            notes.push(format!(
                "{label}: not determinable on {sensor} axis {} (see axes[].fit reasons)",
                missing.join(", ")
            ));
            return None;
        }
        let best = sel
            .iter()
            .filter_map(|a| get(a).map(|v| (v, a.axis.clone())))
            .max_by(|a, b| a.0.total_cmp(&b.0));
        if let Some((v, ax)) = &best {
            notes.push(format!("{label}: worst axis {sensor} {ax}"));
            Some(*v)
        } else {
            None
        }
    };
    out.accelerometer_noise_density = worst("accel", "accelerometer_noise_density", &|a| a.fit.n);
    out.accelerometer_random_walk = worst("accel", "accelerometer_random_walk", &|a| a.fit.k);
    out.gyroscope_noise_density = worst("gyro", "gyroscope_noise_density", &|a| a.fit.n);
    out.gyroscope_random_walk = worst("gyro", "gyroscope_random_walk", &|a| a.fit.k);
    let ub = |sensor: &str| {
        axes.iter()
            .filter(|a| a.sensor == sensor)
            .map(|a| a.k_upper_bound)
            .try_fold(0.0f64, |m, v| v.map(|v| m.max(v)))
    };
    out.accelerometer_random_walk_upper_bound = ub("accel");
    out.gyroscope_random_walk_upper_bound = ub("gyro");
    out.notes = notes;
    out
}
