//! Parameters of [`imu_noise`] and the types of its report
//! (`caliper.imu_noise/v1`): the curve points, the fit, the classic read-offs, the per-axis
//! results and Kalibr's summary.

use serde::{Deserialize, Serialize};

use crate::error::{CoreError, CoreResult};
use crate::imu::log::{ImuCsvParams, ParseStats};
use crate::imu::motion::{MotionPolicy, StaticAnalysis};
// Items the doc comments link to. The comments themselves stay as they are: with the `schema`
// feature they are the OpenAPI descriptions.
#[cfg(doc)]
use super::{edf_for, fit_noise, imu_noise};

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
    /// What to do when the IMU moves during the log: `refuse` (default; the job fails with
    /// `invalid_input` naming the moving intervals), `longest_static` (analyse the longest
    /// static stretch only) or `ignore` (analyse everything, warn).
    pub motion: MotionPolicy,
    /// Window of the motion check, s (default 1; 0.05 to 600). Each window must hold ≥ 10
    /// samples (shorter windows are widened).
    pub motion_window_s: f64,
    /// Threshold factor of the motion check: a window moves when its spread or its mean
    /// departs from the log's own noise floor by more than this many floor standard deviations
    /// (default 3; 1.5 to 1000).
    pub motion_k: f64,
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
            motion: MotionPolicy::Refuse,
            motion_window_s: 1.0,
            motion_k: 3.0,
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
        if !(self.motion_window_s.is_finite() && (0.05..=600.0).contains(&self.motion_window_s)) {
            return Err(CoreError::param(
                "motion_window_s",
                "must be within 0.05..=600 s",
            ));
        }
        if !(self.motion_k.is_finite() && (1.5..=1000.0).contains(&self.motion_k)) {
            return Err(CoreError::param("motion_k", "must be within 1.5..=1000"));
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
    /// The motion check: moving intervals found, static stretches, the interval analysed.
    #[serde(default)]
    pub static_analysis: StaticAnalysis,
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
