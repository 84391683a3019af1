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

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::log::{ImuCsvParams, ImuLog, ParseStats, read_imu_log};
use crate::error::{CoreError, CoreResult};
use crate::progress::Progress;

/// Flicker floor factor: the ADEV of flicker (1/f) rate noise is 0.6643·B (IEEE 952, C.2).
pub const FLICKER_FACTOR: f64 = 0.664_282_473_934_844_4;

/// Inflation of the formal fit uncertainty for the correlation between adjacent overlapping
/// octave estimates (treating them as independent would count each datum about twice).
const CORRELATION_INFLATION: f64 = std::f64::consts::SQRT_2;

/// Block length (samples) of the multi-τ pass and of the f32 delta storage of x.
const BLOCK: usize = 256;

/// Parameters of [`imu_noise`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct ImuNoiseParams {
    /// How to read the CSV.
    pub csv: ImuCsvParams,
    /// Sample rate override, Hz (default: 1 / median timestamp step).
    pub rate_hz: Option<f64>,
    /// τ points per octave of the curve (1 = octave m = 2^k, as allantools "octave"; up to 16
    /// for a denser plot). The fit always uses the octave points only, so it does not depend on
    /// this setting (adjacent dense points are strongly correlated).
    pub taus_per_octave: u32,
    /// Smallest τ used by the fit, s (0.1 as the peer).
    pub fit_tau_min_s: f64,
    /// Smallest number of clusters (n_terms / m) a τ needs to enter the fit (2 as the peer).
    pub fit_min_clusters: f64,
    /// B or K is reported as not determinable (null + reason) when its 1-σ relative uncertainty
    /// from the fit exceeds this (default 0.3: a reported value is within ~60 % at 2 σ, and
    /// typically much closer; see [`fit_noise`]).
    pub max_relative_uncertainty: f64,
    /// Two-sided confidence level of the per-τ intervals (default 0.683, ±1 σ).
    pub confidence: f64,
}

impl Default for ImuNoiseParams {
    fn default() -> Self {
        Self {
            csv: ImuCsvParams::default(),
            rate_hz: None,
            taus_per_octave: 1,
            fit_tau_min_s: 0.1,
            fit_min_clusters: 2.0,
            max_relative_uncertainty: 0.3,
            confidence: 0.683,
        }
    }
}

impl ImuNoiseParams {
    /// Check the parameters (the service does so before queueing a job).
    pub fn validate(&self) -> CoreResult<()> {
        if !(1..=16).contains(&self.taus_per_octave) {
            return Err(CoreError::param("taus_per_octave", "must be within 1..=16"));
        }
        if let Some(r) = self.rate_hz
            && !(r.is_finite() && r > 0.0)
        {
            return Err(CoreError::param("rate_hz", "must be a positive number"));
        }
        if !(self.fit_tau_min_s.is_finite() && self.fit_tau_min_s >= 0.0) {
            return Err(CoreError::param("fit_tau_min_s", "must be ≥ 0"));
        }
        if !(self.fit_min_clusters.is_finite() && self.fit_min_clusters >= 1.0) {
            return Err(CoreError::param("fit_min_clusters", "must be ≥ 1"));
        }
        if !(self.max_relative_uncertainty.is_finite() && self.max_relative_uncertainty > 0.0) {
            return Err(CoreError::param("max_relative_uncertainty", "must be > 0"));
        }
        if !(self.confidence > 0.0 && self.confidence < 1.0) {
            return Err(CoreError::param("confidence", "must be within (0, 1)"));
        }
        Ok(())
    }
}

/// One point of an Allan deviation curve.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct AdevPoint {
    /// Averaging time τ = m / rate, s.
    pub tau_s: f64,
    /// Cluster size m, samples.
    pub m: u64,
    /// Overlapping Allan deviation (sensor unit).
    pub adev: f64,
    /// Number of second differences summed, N + 1 − 2m.
    pub n_terms: u64,
    /// Number of clusters n_terms / m (the peer's fit weight is its square root).
    pub clusters: f64,
    /// Equivalent degrees of freedom of the AVAR, for the noise type the fitted model says
    /// dominates at this τ (see [`edf_for`]; white rate noise when there is no fit).
    pub edf: f64,
    /// Lower bound of the confidence interval of the ADEV (null if the EDF is too small).
    pub ci_low: Option<f64>,
    /// Upper bound of the confidence interval of the ADEV (null if the EDF is too small).
    pub ci_high: Option<f64>,
    /// Whether m is a power of two (the points the fit uses).
    pub octave: bool,
    /// Whether the fit used this point.
    pub fitted: bool,
}

/// The weighted NNLS fit of σ²(τ) = N²/τ + (0.6643·B)² + K²·τ/3.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct NoiseFit {
    /// White noise density N (rad/s/√Hz or m/s²/√Hz); null with `n_reason` if not determinable.
    pub n: Option<f64>,
    /// Bias instability B (rad/s or m/s²); null with `b_reason` if not determinable.
    pub b: Option<f64>,
    /// Random walk K (rad/s²/√Hz or m/s³/√Hz); null with `k_reason` if not determinable.
    pub k: Option<f64>,
    /// Why N is null.
    pub n_reason: Option<String>,
    /// Why B is null.
    pub b_reason: Option<String>,
    /// Why K is null.
    pub k_reason: Option<String>,
    /// The raw NNLS values `[N, B, K]` (0 where the constraint is active), for comparison.
    pub raw: [f64; 3],
    /// 1-σ relative uncertainty of `[N, B, K]` from the fit (see [`fit_noise`]); null where the
    /// term is 0 or the system is singular.
    pub rel_std: [Option<f64>; 3],
    /// Number of τ points used.
    pub taus_used: usize,
    /// Smallest and largest τ used, s.
    pub tau_range_used_s: [f64; 2],
}

/// The classic slope read-offs (for comparison with other tools).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct ClassicReadoff {
    /// N: value at τ = 1 s of the slope −½ line through the points with τ ≤ τ_min / 4.
    pub n_at_tau1: Option<f64>,
    /// K: √3 × value at τ = 1 s of the slope +½ line through the points with τ ≥ 4 τ_min
    /// (equivalently the line's value at τ = 3 s).
    pub k_at_tau3: Option<f64>,
    /// B: minimum ADEV / 0.6643; null while the ADEV is still falling at the longest τ.
    pub b_min_over_0_6643: Option<f64>,
    /// Why a value is null.
    pub reasons: Vec<String>,
    /// τ of the ADEV minimum among the fitted points, s.
    pub tau_at_min_s: f64,
    /// Points on the −½ line.
    pub points_for_n: usize,
    /// Points on the +½ line.
    pub points_for_k: usize,
}

/// Noise analysis of one axis.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct AxisNoise {
    /// `gyro` or `accel`.
    pub sensor: String,
    /// `x`, `y` or `z`.
    pub axis: String,
    /// Units of N, B, K for this sensor.
    pub units: NoiseUnits,
    /// The Allan deviation curve.
    pub curve: Vec<AdevPoint>,
    /// The NNLS fit.
    pub fit: NoiseFit,
    /// Classic read-offs.
    pub classic: ClassicReadoff,
    /// Upper bound on K from the curve: min over fitted τ of √(3 σ²_high(τ) / τ) (the random
    /// walk term alone cannot exceed the measured AVAR). Useful when K is not determinable.
    pub k_upper_bound: Option<f64>,
}

/// Units of the three noise parameters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct NoiseUnits {
    /// Unit of N.
    pub n: String,
    /// Unit of B.
    pub b: String,
    /// Unit of K.
    pub k: String,
}

/// Kalibr `imu.yaml` values: the worst (largest) axis of each sensor. A value is null when an
/// axis of that sensor could not determine it (the reason is in `notes`), because taking the
/// largest of the *other* axes could under-report the noise.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct KalibrImu {
    /// Accelerometer white noise density, m/s²/√Hz.
    pub accelerometer_noise_density: Option<f64>,
    /// Accelerometer random walk, m/s³/√Hz.
    pub accelerometer_random_walk: Option<f64>,
    /// Gyroscope white noise density, rad/s/√Hz.
    pub gyroscope_noise_density: Option<f64>,
    /// Gyroscope random walk, rad/s²/√Hz.
    pub gyroscope_random_walk: Option<f64>,
    /// Sample rate, Hz.
    pub update_rate: f64,
    /// Conservative stand-in when `accelerometer_random_walk` is null: the largest per-axis
    /// upper bound (see [`AxisNoise::k_upper_bound`]).
    pub accelerometer_random_walk_upper_bound: Option<f64>,
    /// Same for the gyroscope.
    pub gyroscope_random_walk_upper_bound: Option<f64>,
    /// Which axis gave each value, and why values are null.
    pub notes: Vec<String>,
}

/// Result of [`imu_noise`] (`caliper.imu_noise/v1`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct ImuNoiseReport {
    /// `caliper.imu_noise/v1`.
    pub schema: String,
    /// Sample rate used, Hz.
    pub rate_hz: f64,
    /// How the rate was obtained.
    pub rate_source: String,
    /// Log duration, s.
    pub duration_s: f64,
    /// Samples analysed.
    pub samples: usize,
    /// Six axes: gyro x, y, z then accel x, y, z.
    pub axes: Vec<AxisNoise>,
    /// Kalibr worst-axis summary.
    pub kalibr: KalibrImu,
    /// Method summary (estimator, fit, CI approximation).
    pub method: String,
    /// Warnings (gaps, short log, ...).
    pub warnings: Vec<String>,
    /// Parser statistics.
    pub parse: ParseStats,
}

/// Streams an IMU CSV log and characterises its noise by Allan deviation (see the module doc).
///
/// Progress steps: `"parse"` (bytes), `"allan"` (axes done of 6).
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
    let n = log.len();
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
        sums.push(oavar_sums(log.channel_offsets(c), &ms, &mut x, progress)?);
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

    let mut warnings = Vec::new();
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
            stats.duration_s
        ));
    }
    let kalibr = kalibr_summary(&axes, rate);
    Ok(ImuNoiseReport {
        schema: "caliper.imu_noise/v1".to_string(),
        rate_hz: rate,
        rate_source,
        duration_s: stats.duration_s,
        samples: n,
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

/// Cluster sizes: powers of two (allantools "octave": m < N + 1) plus, for `per_octave` > 1,
/// rounded 2^(j/per_octave) in between; only m with at least 2 second differences.
pub fn cluster_sizes(n_samples: usize, per_octave: u32) -> Vec<usize> {
    let len = n_samples + 1; // phase points
    let mut ms = Vec::new();
    let p = per_octave.max(1);
    let mut j: u32 = 0;
    loop {
        let m = if p == 1 {
            1usize.checked_shl(j).unwrap_or(usize::MAX)
        } else {
            2f64.powf(f64::from(j) / f64::from(p)).round() as usize
        };
        // At least 2 second differences: n_terms = len − 2m ≥ 2.
        if m == 0 || m.checked_mul(2).is_none_or(|v| v + 2 > len) {
            break;
        }
        if ms.last() != Some(&m) {
            ms.push(m);
        }
        j += 1;
        if j > 64 * p {
            break;
        }
    }
    ms
}

/// Compact form of the cumulative sum x of one axis: x_i = heads[i / BLOCK] + deltas[i], the
/// heads exact in f64, the deltas (|x_i − x_head| ≲ √BLOCK·σ for a static log) in f32. Rounding
/// a delta costs ~6·10⁻⁸ of its size, i.e. ~10⁻⁶ σ — far below what the estimator resolves —
/// and halves both the buffer and the memory traffic of the long-τ passes, which read ~2 log₂ N
/// streams of x and are bandwidth-bound.
#[derive(Default)]
pub(crate) struct PhaseBuffer {
    heads: Vec<f64>,
    deltas: Vec<f32>,
}

/// Σ (x_{k+2m} − 2x_{k+m} + x_k)² for every m in `ms`, x the mean-removed cumulative sum of
/// `y` (offsets; a constant cancels) kept in `buf` (reused across axes). The pass over x is
/// blocked (all m per block, so the short-m windows stay in cache) and split in index ranges
/// across threads. For m a multiple of the block length the heads of the three terms combine
/// into one constant per block, so the inner loop reads only f32 deltas.
pub(crate) fn oavar_sums(
    y: &[f32],
    ms: &[usize],
    buf: &mut PhaseBuffer,
    progress: &dyn Progress,
) -> CoreResult<Vec<f64>> {
    let n = y.len();
    let len = n + 1;
    // Mean and prefix sums in parallel chunks (chunk = whole blocks): chunk totals, their
    // running offsets, then each chunk fills its heads and deltas.
    let chunk_blocks = (len.div_ceil(BLOCK) / (rayon::current_num_threads() * 4).max(1)).max(16);
    let chunk = chunk_blocks * BLOCK;
    let mean = y
        .par_chunks(chunk)
        .map(|c| c.iter().map(|&v| f64::from(v)).sum::<f64>())
        .sum::<f64>()
        / n.max(1) as f64;
    buf.heads.clear();
    buf.heads.resize(len.div_ceil(BLOCK), 0.0);
    buf.deltas.clear();
    buf.deltas.resize(len, 0.0);
    let totals: Vec<f64> = y
        .par_chunks(chunk)
        .map(|c| c.iter().map(|&v| f64::from(v) - mean).sum::<f64>())
        .collect();
    let mut starts = Vec::with_capacity(totals.len() + 1);
    let mut acc = 0.0f64;
    for t in &totals {
        starts.push(acc);
        acc += t;
    }
    starts.push(acc);
    buf.deltas
        .par_chunks_mut(chunk)
        .zip(buf.heads.par_chunks_mut(chunk_blocks))
        .enumerate()
        .for_each(|(ci, (dd, hh))| {
            let i0 = ci * chunk;
            let mut s = starts[ci];
            let mut head = s;
            for (k, out) in dd.iter_mut().enumerate() {
                if k % BLOCK == 0 {
                    head = s;
                    hh[k / BLOCK] = head;
                }
                *out = (s - head) as f32;
                if let Some(&v) = y.get(i0 + k) {
                    s += f64::from(v) - mean;
                }
            }
        });
    let (heads, d) = (&buf.heads[..], &buf.deltas[..]);
    let longest = ms
        .iter()
        .map(|&m| len.saturating_sub(2 * m))
        .max()
        .unwrap_or(0);
    let n_blocks = longest.div_ceil(BLOCK);
    let parts = (rayon::current_num_threads() * 4)
        .clamp(1, 64)
        .min(n_blocks.max(1));
    let per = n_blocks.div_ceil(parts.max(1)).max(1);
    let mut scratch_len = 0;
    for &m in ms {
        if m < BLOCK {
            scratch_len = scratch_len.max(BLOCK + 2 * m);
        }
    }
    let x_at = |j: usize| heads[j / BLOCK] + f64::from(d[j]);
    let partial: Vec<Vec<f64>> = (0..parts)
        .into_par_iter()
        .map(|p| {
            let mut sums = vec![0.0f64; ms.len()];
            let mut xs = vec![0.0f64; scratch_len];
            let (b0, b1) = (p * per, ((p + 1) * per).min(n_blocks));
            for blk in b0..b1 {
                let b = blk * BLOCK;
                // Exact f64 x over the window the unaligned m need.
                let w_end = (b + scratch_len).min(len);
                for (k, v) in xs[..w_end - b].iter_mut().enumerate() {
                    *v = x_at(b + k);
                }
                for (k, &m) in ms.iter().enumerate() {
                    let n_terms = len.saturating_sub(2 * m);
                    if b >= n_terms {
                        continue;
                    }
                    let e = (b + BLOCK).min(n_terms);
                    let cnt = e - b;
                    sums[k] += if m < BLOCK {
                        second_diff_sq(&xs[..cnt], &xs[m..m + cnt], &xs[2 * m..2 * m + cnt])
                    } else if m % BLOCK == 0 {
                        let q = m / BLOCK;
                        let h = heads[blk + 2 * q] - 2.0 * heads[blk + q] + heads[blk];
                        second_diff_sq_f32(h, &d[b..e], &d[b + m..e + m], &d[b + 2 * m..e + 2 * m])
                    } else {
                        // Dense (non-octave) long m: reconstruct each term.
                        (b..e)
                            .map(|i| {
                                let v = x_at(i + 2 * m) - 2.0 * x_at(i + m) + x_at(i);
                                v * v
                            })
                            .sum()
                    };
                }
                if blk % 1024 == 0 {
                    progress.check()?;
                }
            }
            Ok(sums)
        })
        .collect::<CoreResult<_>>()?;
    let mut sums = vec![0.0f64; ms.len()];
    for p in &partial {
        for (s, v) in sums.iter_mut().zip(p) {
            *s += v;
        }
    }
    Ok(sums)
}

/// Σ (h + c − 2b + a)² over f32 deltas, in f64, four accumulators.
#[inline]
fn second_diff_sq_f32(h: f64, a: &[f32], b: &[f32], c: &[f32]) -> f64 {
    let n = a.len().min(b.len()).min(c.len());
    let (a, b, c) = (&a[..n], &b[..n], &c[..n]);
    let mut acc = [0.0f64; 4];
    let n4 = n / 4 * 4;
    let mut i = 0;
    while i < n4 {
        for j in 0..4 {
            let e = h + (f64::from(c[i + j]) - 2.0 * f64::from(b[i + j]) + f64::from(a[i + j]));
            acc[j] += e * e;
        }
        i += 4;
    }
    let mut tail = 0.0;
    for k in n4..n {
        let e = h + (f64::from(c[k]) - 2.0 * f64::from(b[k]) + f64::from(a[k]));
        tail += e * e;
    }
    (acc[0] + acc[1]) + (acc[2] + acc[3]) + tail
}

/// Σ (c − 2b + a)², four independent accumulators so the loop vectorises.
#[inline]
fn second_diff_sq(a: &[f64], b: &[f64], c: &[f64]) -> f64 {
    let n = a.len().min(b.len()).min(c.len());
    let (a, b, c) = (&a[..n], &b[..n], &c[..n]);
    let mut acc = [0.0f64; 4];
    let n4 = n / 4 * 4;
    let mut i = 0;
    while i < n4 {
        for j in 0..4 {
            let d = c[i + j] - 2.0 * b[i + j] + a[i + j];
            acc[j] += d * d;
        }
        i += 4;
    }
    let mut tail = 0.0;
    for k in n4..n {
        let d = c[k] - 2.0 * b[k] + a[k];
        tail += d * d;
    }
    (acc[0] + acc[1]) + (acc[2] + acc[3]) + tail
}

/// Equivalent degrees of freedom of the overlapping AVAR for white frequency (rate) noise with
/// `n_phase` phase points and cluster size m (Howe, Allan & Barnes 1981; NIST SP 1065 §5.3):
/// edf = (3(N−1)/(2m) − 2(N−2)/N) · 4m²/(4m² + 5). White rate noise dominates the short τ where
/// the fit's weight lies; for the long τ (random walk) the true EDF is smaller, so those
/// intervals are somewhat optimistic.
pub fn edf_white_fm(n_phase: usize, m: usize) -> f64 {
    let nn = n_phase as f64;
    let m = m as f64;
    let e =
        (3.0 * (nn - 1.0) / (2.0 * m) - 2.0 * (nn - 2.0) / nn) * 4.0 * m * m / (4.0 * m * m + 5.0);
    e.max(0.0)
}

/// EDF of the overlapping AVAR for the dominant noise type (0 white FM, 1 flicker FM, 2 random
/// walk FM), the simple approximations of Howe, Allan & Barnes (1981) tabulated in NIST SP 1065
/// (Riley 2008), Table 5; `n_phase` phase points, cluster size m.
pub fn edf_for(kind: usize, n_phase: usize, m: usize) -> f64 {
    let nn = n_phase as f64;
    let mf = m as f64;
    let e = match kind {
        1 => {
            if m == 1 {
                2.0 * (nn - 2.0).powi(2) / (2.3 * nn - 4.9)
            } else {
                5.0 * nn * nn / (4.0 * mf * (nn + 3.0 * mf))
            }
        }
        2 => {
            (nn - 2.0) / mf * ((nn - 1.0).powi(2) - 3.0 * mf * (nn - 1.0) + 4.0 * mf * mf)
                / (nn - 3.0).powi(2)
        }
        _ => return edf_white_fm(n_phase, m),
    };
    if e.is_finite() { e.max(0.0) } else { 0.0 }
}

/// χ² confidence interval of an AVAR with `edf` degrees of freedom: [avar·ν/χ²_hi, avar·ν/χ²_lo]
/// with Wilson-Hilferty quantiles χ²_p(ν) ≈ ν (1 − 2/(9ν) + z_p √(2/(9ν)))³.
fn avar_interval(avar: f64, edf: f64, z: f64) -> (Option<f64>, Option<f64>) {
    if edf.is_nan() || edf <= 0.5 || !avar.is_finite() {
        return (None, None);
    }
    let q = |zp: f64| {
        let a = 2.0 / (9.0 * edf);
        let base = 1.0 - a + zp * a.sqrt();
        if base > 0.0 {
            Some(edf * base.powi(3))
        } else {
            None
        }
    };
    let lo = q(z).map(|c| avar * edf / c);
    let hi = q(-z).map(|c| avar * edf / c);
    (lo, hi)
}

/// Standard normal quantile (Acklam's rational approximation, |error| < 1.2·10⁻⁹).
pub(crate) fn normal_quantile(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969_683_028_665_376e1,
        2.209_460_984_245_205e2,
        -2.759_285_104_469_687e2,
        1.383_577_518_672_69e2,
        -3.066_479_806_614_716e1,
        2.506_628_277_459_239,
    ];
    const B: [f64; 5] = [
        -5.447_609_879_822_406e1,
        1.615_858_368_580_409e2,
        -1.556_989_798_598_866e2,
        6.680_131_188_771_972e1,
        -1.328_068_155_288_572e1,
    ];
    const C: [f64; 6] = [
        -7.784_894_002_430_293e-3,
        -3.223_964_580_411_365e-1,
        -2.400_758_277_161_838,
        -2.549_732_539_343_734,
        4.374_664_141_464_968,
        2.938_163_982_698_783,
    ];
    const D: [f64; 4] = [
        7.784_695_709_041_462e-3,
        3.224_671_290_700_398e-1,
        2.445_134_137_142_996,
        3.754_408_661_907_416,
    ];
    let p = p.clamp(1e-300, 1.0 - 1e-16);
    let pl = 0.02425;
    if p < pl {
        let q = (-2.0 * p.ln()).sqrt();
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    } else if p <= 1.0 - pl {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    } else {
        let q = (-2.0 * (1.0 - p).ln()).sqrt();
        -(((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    }
}

/// The peer's fit (module doc) on the octave points of `curve` (marks them `fitted`), the
/// classic read-offs, and an upper bound on K.
///
/// Determinability: N, B, K are null when their NNLS term is 0 (the constraint is active: the
/// data do not show that noise), when the ADEV is still falling at the longest τ (for B and K:
/// no floor and no rising slope are visible), or when the 1-σ relative uncertainty exceeds
/// `max_relative_uncertainty`. That uncertainty comes from the same linear model on the support
/// of the solution, rows weighted by the χ² standard error of each AVAR, σ(σ²) = σ² √(2/edf),
/// with the EDF of the noise type the fitted model says dominates at that τ ([`edf_for`]; the
/// curve's intervals are updated the same way). Octave points are mildly correlated, so it is a
/// lower bound on the true spread: it is inflated by √2 to account for that.
pub fn fit_noise(
    curve: &mut [AdevPoint],
    params: &ImuNoiseParams,
    z: f64,
) -> (NoiseFit, ClassicReadoff, Option<f64>) {
    let mut idx = Vec::new();
    for (i, p) in curve.iter_mut().enumerate() {
        p.fitted = p.octave
            && p.tau_s >= params.fit_tau_min_s
            && p.clusters >= params.fit_min_clusters
            && p.adev.is_finite()
            && p.adev > 0.0;
        if p.fitted {
            idx.push(i);
        }
    }
    let mut fit = NoiseFit::default();
    let mut classic = ClassicReadoff::default();
    if idx.len() < 3 {
        let why = format!(
            "only {} usable τ (≥ {} s with ≥ {} clusters; need 3): log too short",
            idx.len(),
            params.fit_tau_min_s,
            params.fit_min_clusters
        );
        fit.n_reason = Some(why.clone());
        fit.b_reason = Some(why.clone());
        fit.k_reason = Some(why.clone());
        classic.reasons.push(why);
        return (fit, classic, None);
    }
    let tau: Vec<f64> = idx.iter().map(|&i| curve[i].tau_s).collect();
    let adev: Vec<f64> = idx.iter().map(|&i| curve[i].adev).collect();
    let clusters: Vec<f64> = idx.iter().map(|&i| curve[i].clusters).collect();
    let avar: Vec<f64> = adev.iter().map(|a| a * a).collect();
    let cols = |t: f64| [1.0 / t, 1.0, t / 3.0];

    // Weighted NNLS, exactly the peer's rows.
    let rows: Vec<[f64; 3]> = (0..tau.len())
        .map(|i| {
            let w = clusters[i].max(1.0).sqrt();
            let c = cols(tau[i]);
            [c[0] / avar[i] * w, c[1] / avar[i] * w, c[2] / avar[i] * w]
        })
        .collect();
    let rhs: Vec<f64> = clusters.iter().map(|c| c.max(1.0).sqrt()).collect();
    let coef = nnls3(&rows, &rhs);
    fit.raw = [
        coef[0].sqrt(),
        coef[1].sqrt() / FLICKER_FACTOR,
        coef[2].sqrt(),
    ];
    fit.taus_used = tau.len();
    fit.tau_range_used_s = [tau[0], tau[tau.len() - 1]];

    // Noise identification from the fitted model: each point's EDF and interval follow the
    // term that dominates its AVAR (white, flicker or random-walk rate noise).
    for p in curve.iter_mut() {
        let t = p.tau_s;
        let terms = [coef[0] / t, coef[1], coef[2] * t / 3.0];
        let dominant = (0..3)
            .max_by(|&a, &b| terms[a].total_cmp(&terms[b]))
            .unwrap_or(0);
        let n_phase = p.n_terms as usize + 2 * p.m as usize;
        p.edf = edf_for(dominant, n_phase, p.m as usize);
        let (lo, hi) = avar_interval(p.adev * p.adev, p.edf, z);
        p.ci_low = lo.map(f64::sqrt);
        p.ci_high = hi.map(f64::sqrt);
    }
    let edf: Vec<f64> = idx.iter().map(|&i| curve[i].edf.max(1.0)).collect();

    // Uncertainty on the support.
    let support: Vec<usize> = (0..3).filter(|&j| coef[j] > 0.0).collect();
    let mut rel_std = [None; 3];
    if !support.is_empty() {
        let k = support.len();
        let mut ata = nalgebra::DMatrix::<f64>::zeros(k, k);
        for i in 0..tau.len() {
            let sig = avar[i] * (2.0 / edf[i]).sqrt();
            let c = cols(tau[i]);
            for (a, &ja) in support.iter().enumerate() {
                for (b, &jb) in support.iter().enumerate() {
                    ata[(a, b)] += c[ja] * c[jb] / (sig * sig);
                }
            }
        }
        if let Some(inv) = ata.try_inverse() {
            for (a, &j) in support.iter().enumerate() {
                let var = inv[(a, a)];
                if var.is_finite() && var >= 0.0 {
                    // σ(√c)/√c = σ(c)/(2c), × √2 for the correlation of adjacent octave
                    // estimates (each shares data with its neighbours).
                    rel_std[j] = Some(CORRELATION_INFLATION * var.sqrt() / (2.0 * coef[j]));
                }
            }
        }
    }
    fit.rel_std = rel_std;

    let i_min = adev
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))
        .map_or(0, |(i, _)| i);
    let still_falling = i_min == tau.len() - 1;
    let last_tau = tau[tau.len() - 1];
    let max_rel = params.max_relative_uncertainty;

    // N
    if coef[0] > 0.0 {
        fit.n = Some(fit.raw[0]);
    } else {
        fit.n_reason =
            Some("fitted white-noise term is 0: the short-τ slope −½ is not visible".into());
    }
    // B, K
    let decide = |j: usize, name: &str, what: &str| -> (Option<f64>, Option<String>) {
        if still_falling {
            return (
                None,
                Some(format!(
                    "ADEV still falling at the longest usable τ ({last_tau:.1} s): no {what} \
                     visible, log too short for {name}"
                )),
            );
        }
        if coef[j] <= 0.0 {
            return (
                None,
                Some(format!(
                    "fitted {name} term is 0: {what} not visible within τ ≤ {last_tau:.1} s"
                )),
            );
        }
        match rel_std[j] {
            Some(r) if r <= max_rel => (Some(fit.raw[j]), None),
            Some(r) => (
                None,
                Some(format!(
                    "{name} = {:.3e} but uncertain (±{:.0} % at 1 σ > {:.0} %): log too short",
                    fit.raw[j],
                    100.0 * r,
                    100.0 * max_rel
                )),
            ),
            None => (None, Some(format!("{name} unconstrained (singular fit)"))),
        }
    };
    let (b, br) = decide(1, "B", "flicker floor");
    let (k, kr) = decide(2, "K", "rising +½ slope");
    fit.b = b;
    fit.b_reason = br;
    fit.k = k;
    fit.k_reason = kr;

    // Classic read-offs.
    let tmin = tau[i_min];
    let line = |sel: &dyn Fn(f64) -> bool, slope: f64| -> (Option<f64>, usize) {
        let mut s = 0.0;
        let mut c = 0usize;
        for i in 0..tau.len() {
            if sel(tau[i]) {
                s += adev[i].ln() - slope * tau[i].ln();
                c += 1;
            }
        }
        if c == 0 {
            (None, 0)
        } else {
            ((s / c as f64).exp().into(), c)
        }
    };
    let (nl, pn) = line(&|t| t <= tmin / 4.0, -0.5);
    let (kl, pk) = line(&|t| t >= tmin * 4.0, 0.5);
    classic.n_at_tau1 = nl;
    classic.points_for_n = pn;
    classic.k_at_tau3 = kl.map(|v| v * 3f64.sqrt());
    classic.points_for_k = pk;
    classic.tau_at_min_s = tmin;
    if nl.is_none() {
        classic
            .reasons
            .push("no point left of τ_min/4 for the −½ line".into());
    }
    if kl.is_none() {
        classic
            .reasons
            .push("no point right of 4·τ_min for the +½ line: log too short for K".into());
    }
    if still_falling {
        classic.reasons.push(
            "ADEV still falling at the longest usable τ: the minimum is not B's floor".into(),
        );
    } else {
        classic.b_min_over_0_6643 = Some(adev[i_min] / FLICKER_FACTOR);
    }

    // K upper bound from every fitted point's upper AVAR bound.
    let kub = idx
        .iter()
        .map(|&i| {
            let p = &curve[i];
            let hi = p.ci_high.unwrap_or(p.adev * 2.0);
            (3.0 * hi * hi / p.tau_s).sqrt()
        })
        .fold(f64::INFINITY, f64::min);
    (fit, classic, kub.is_finite().then_some(kub))
}

/// Non-negative least squares for 3 unknowns: min ‖A x − b‖ s.t. x ≥ 0, exactly, by trying the
/// unconstrained least-squares solution on each of the 7 supports and keeping the best feasible
/// one (the NNLS optimum is the unconstrained optimum on its own support).
fn nnls3(a: &[[f64; 3]], b: &[f64]) -> [f64; 3] {
    let resid = |x: &[f64; 3]| -> f64 {
        a.iter()
            .zip(b)
            .map(|(r, &bi)| {
                let v = r[0] * x[0] + r[1] * x[1] + r[2] * x[2] - bi;
                v * v
            })
            .sum()
    };
    let mut best = [0.0; 3];
    let mut best_r = resid(&best);
    for mask in 1u32..8 {
        let cols: Vec<usize> = (0..3).filter(|j| mask & (1 << j) != 0).collect();
        let m = nalgebra::DMatrix::from_fn(a.len(), cols.len(), |i, j| a[i][cols[j]]);
        let rhs = nalgebra::DVector::from_column_slice(b);
        let svd = m.svd(true, true);
        let Ok(sol) = svd.solve(&rhs, 1e-14) else {
            continue;
        };
        if sol.iter().any(|v| !(v.is_finite() && *v >= 0.0)) {
            continue;
        }
        let mut x = [0.0; 3];
        for (k, &j) in cols.iter().enumerate() {
            x[j] = sol[k];
        }
        let r = resid(&x);
        if r < best_r {
            best_r = r;
            best = x;
        }
    }
    best
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
