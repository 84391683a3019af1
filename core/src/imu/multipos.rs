//! Multi-position IMU calibration without external equipment (`imu_intrinsics`). Slightly over
//! 600 lines: detection of static poses and the two fits share their types and helpers.
//!
//! Tedaldi, Pretto & Menegatti, "A robust and easy to implement method for IMU calibration
//! without external equipments", ICRA 2014 (the imu_tk method), with the conventions of the peer
//! `shared/peers/imu_multipos.py` and its truth files:
//!
//! X_cal = T · diag(s) · (X_raw − b),
//! accelerometer T = [[1, −yz, zy], [0, 1, −zx], [0, 0, 1]] (the body frame is the accelerometer
//! frame, so 3 misalignments), gyroscope T = [[1, −yz, zy], [xz, 1, −zx], [−xy, yx, 1]].
//!
//! 1. Static detection: the IMU must rest for the first `init_static_s` seconds. A sample is
//!    static while ‖per-axis variance of the accelerometer over a centred window‖ is below
//!    threshold = multiplier × that of the initial rest; runs shorter than `min_samples` are
//!    dropped. The multiplier is chosen automatically: every one in `threshold_multipliers` with
//!    enough intervals gets an accelerometer fit and the lowest cost wins (as the paper and the
//!    peer do).
//! 2. Accelerometer: Levenberg-Marquardt on the 9 parameters so that ‖X_cal‖ = g for the first
//!    `min_samples` samples of every static interval (or the interval means).
//! 3. Gyroscope: bias = mean over the initial rest; then LM on 6 misalignments + 3 scales so that
//!    integrating the corrected rates on SO(3) between consecutive static intervals rotates the
//!    calibrated gravity direction of one into that of the next. The integration composes
//!    Exp(ω̄ Δt) with ω̄ the mean of consecutive samples (exact for the fixed-axis rotations of
//!    the imu_tk protocol up to the trapezoid rule on the angle).

use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

use super::lm;
use super::log::{ImuCsvParams, ImuLog, ParseStats, read_imu_log};
use crate::error::{CoreError, CoreResult};
use crate::lie::So3;
use crate::progress::Progress;

/// Parameters of [`imu_intrinsics`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct ImuIntrinsicsParams {
    /// How to read the CSV.
    pub csv: ImuCsvParams,
    /// Local gravity magnitude, m/s² (default 9.80665).
    pub gravity_m_s2: f64,
    /// Length of the initial rest period, s (default 50, as imu_tk).
    pub init_static_s: f64,
    /// Variance window, samples (default 101; at least 11).
    pub window: usize,
    /// Samples per static interval used by the accelerometer fit; shorter intervals are dropped
    /// (default 100).
    pub min_samples: usize,
    /// Static intervals needed (default 12; at least 9 for 9 parameters).
    pub min_intervals: usize,
    /// Threshold multipliers tried (default 2, 3, …, 10).
    pub threshold_multipliers: Vec<f64>,
    /// Fit the accelerometer to interval means instead of `min_samples` samples per interval.
    pub use_means: bool,
    /// Also calibrate the gyroscope (default true).
    pub gyro: bool,
    /// LM iteration cap (default 100).
    pub max_iterations: usize,
}

impl Default for ImuIntrinsicsParams {
    fn default() -> Self {
        Self {
            csv: ImuCsvParams::default(),
            gravity_m_s2: 9.806_65,
            init_static_s: 50.0,
            window: 101,
            min_samples: 100,
            min_intervals: 12,
            threshold_multipliers: (2..=10).map(f64::from).collect(),
            use_means: false,
            gyro: true,
            max_iterations: 100,
        }
    }
}

/// Residual summary.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct ResidualStats {
    /// Number of residuals.
    pub count: usize,
    /// Root mean square.
    pub rms: f64,
    /// Largest absolute value.
    pub max_abs: f64,
}

impl ResidualStats {
    fn of(r: &[f64]) -> Self {
        let n = r.len();
        Self {
            count: n,
            rms: if n == 0 {
                0.0
            } else {
                (r.iter().map(|v| v * v).sum::<f64>() / n as f64).sqrt()
            },
            max_abs: r.iter().fold(0.0, |m, v| m.max(v.abs())),
        }
    }
}

/// Accelerometer intrinsics.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct AccelIntrinsics {
    /// Misalignments `[yz, zy, zx]`, rad.
    pub misalignment_yz_zy_zx: [f64; 3],
    /// Scale factors `[sx, sy, sz]`.
    pub scale: [f64; 3],
    /// Bias, m/s² (raw units, subtracted before scaling).
    pub bias: [f64; 3],
    /// 1-σ standard errors of `[yz, zy, zx, sx, sy, sz, bx, by, bz]` (from JᵀJ and the residual
    /// variance; samples are treated as independent).
    pub std: Vec<f64>,
    /// T (row-major).
    pub t: [[f64; 3]; 3],
    /// T · diag(scale) (row-major).
    pub t_times_k: [[f64; 3]; 3],
    /// Residuals g − ‖X_cal‖ over the fitted samples, m/s².
    pub residual: ResidualStats,
    /// ‖mean X_cal‖ − g per static interval, m/s².
    pub pose_norm_error: Vec<f64>,
    /// ½ Σ r² (Ceres convention).
    pub cost: f64,
    /// LM iterations.
    pub iterations: usize,
    /// Whether LM converged.
    pub converged: bool,
}

/// Gyroscope intrinsics.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct GyroIntrinsics {
    /// Misalignments `[yz, zy, zx, xz, xy, yx]`, rad.
    pub misalignment_yz_zy_zx_xz_xy_yx: [f64; 6],
    /// Scale factors.
    pub scale: [f64; 3],
    /// Bias, rad/s (mean of the initial rest period).
    pub bias: [f64; 3],
    /// How the bias was obtained.
    pub bias_source: String,
    /// 1-σ standard errors of `[yz, zy, zx, xz, xy, yx, sx, sy, sz]`.
    pub std: Vec<f64>,
    /// T (row-major).
    pub t: [[f64; 3]; 3],
    /// T · diag(scale) (row-major).
    pub t_times_k: [[f64; 3]; 3],
    /// Rotation segments between consecutive static intervals.
    pub segments: usize,
    /// Residuals of the predicted minus observed gravity unit vectors (3 per segment).
    pub residual: ResidualStats,
    /// Angle between predicted and observed gravity direction per segment, degrees.
    pub segment_error_deg: Vec<f64>,
    /// ½ Σ r².
    pub cost: f64,
    /// LM iterations.
    pub iterations: usize,
    /// Whether LM converged.
    pub converged: bool,
}

/// A detected static interval (sample indices inclusive).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct StaticInterval {
    /// First sample.
    pub start_index: usize,
    /// Last sample.
    pub end_index: usize,
    /// Start time from the first sample, s.
    pub start_s: f64,
    /// End time, s.
    pub end_s: f64,
}

/// One tried threshold multiplier.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct ThresholdTrial {
    /// Multiplier of the initial-rest variance.
    pub multiplier: f64,
    /// Static intervals found (long enough).
    pub intervals: usize,
    /// Accelerometer fit cost (null when too few intervals).
    pub cost: Option<f64>,
}

/// Static detection summary.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct StaticDetection {
    /// Chosen multiplier.
    pub threshold_multiplier: f64,
    /// Chosen threshold on ‖windowed variance‖, (m/s²)².
    pub threshold: f64,
    /// ‖per-axis variance‖ of the initial rest, (m/s²)².
    pub init_variance: f64,
    /// Window, samples.
    pub window: usize,
    /// The intervals used.
    pub intervals: Vec<StaticInterval>,
    /// Every multiplier tried.
    pub tried: Vec<ThresholdTrial>,
}

/// Result of [`imu_intrinsics`] (`caliper.imu_intrinsics/v1`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct ImuIntrinsicsReport {
    /// `caliper.imu_intrinsics/v1`.
    pub schema: String,
    /// The model convention.
    pub convention: String,
    /// Accelerometer result.
    pub accel: AccelIntrinsics,
    /// Gyroscope result (null when `params.gyro` is false).
    pub gyro: Option<GyroIntrinsics>,
    /// Static detection.
    pub static_detection: StaticDetection,
    /// Static poses used (including the initial rest).
    pub usable_poses: usize,
    /// Sample rate, Hz.
    pub rate_hz: f64,
    /// Duration, s.
    pub duration_s: f64,
    /// Warnings.
    pub warnings: Vec<String>,
    /// Parser statistics.
    pub parse: ParseStats,
}

/// Multi-position calibration of a CSV log (see the module doc). Progress steps: `"parse"`,
/// `"static_detect"`, `"accel_fit"`, `"gyro_fit"`.
pub fn imu_intrinsics(
    reader: impl std::io::BufRead,
    params: &ImuIntrinsicsParams,
    progress: &dyn Progress,
) -> CoreResult<ImuIntrinsicsReport> {
    validate(params)?;
    let log = read_imu_log(reader, &params.csv, progress)?;
    imu_intrinsics_from_log(&log, params, progress)
}

impl ImuIntrinsicsParams {
    /// Check the parameters (the service does so before queueing a job).
    pub fn validate(&self) -> CoreResult<()> {
        validate(self)
    }
}

fn validate(p: &ImuIntrinsicsParams) -> CoreResult<()> {
    if !(p.gravity_m_s2.is_finite() && p.gravity_m_s2 > 0.0) {
        return Err(CoreError::param("gravity_m_s2", "must be > 0"));
    }
    if !(p.init_static_s.is_finite() && p.init_static_s > 0.0) {
        return Err(CoreError::param("init_static_s", "must be > 0"));
    }
    if p.window > 100_000 {
        return Err(CoreError::param("window", "must be ≤ 100000"));
    }
    if p.min_samples < 2 {
        return Err(CoreError::param("min_samples", "must be ≥ 2"));
    }
    if p.min_intervals < 9 {
        return Err(CoreError::param(
            "min_intervals",
            "must be ≥ 9 (9 parameters)",
        ));
    }
    if p.threshold_multipliers.is_empty()
        || p.threshold_multipliers
            .iter()
            .any(|m| !(m.is_finite() && *m > 0.0))
    {
        return Err(CoreError::param(
            "threshold_multipliers",
            "need positive numbers",
        ));
    }
    if p.max_iterations == 0 || p.max_iterations > 10_000 {
        return Err(CoreError::param(
            "max_iterations",
            "must be within 1..=10000",
        ));
    }
    Ok(())
}

/// The winning threshold: multiplier, accelerometer fit, static intervals.
type Best = (f64, lm::LmResult, Vec<(usize, usize)>);

fn t_acc(p: &[f64]) -> Matrix3<f64> {
    Matrix3::new(1.0, -p[0], p[1], 0.0, 1.0, -p[2], 0.0, 0.0, 1.0)
}

fn t_gyro(p: &[f64]) -> Matrix3<f64> {
    // yz, zy, zx, xz, xy, yx
    Matrix3::new(1.0, -p[0], p[1], p[3], 1.0, -p[2], -p[4], p[5], 1.0)
}

fn rows(m: &Matrix3<f64>) -> [[f64; 3]; 3] {
    [
        [m[(0, 0)], m[(0, 1)], m[(0, 2)]],
        [m[(1, 0)], m[(1, 1)], m[(1, 2)]],
        [m[(2, 0)], m[(2, 1)], m[(2, 2)]],
    ]
}

/// Static intervals (inclusive sample ranges) where ‖windowed per-axis variance‖ < threshold.
fn static_intervals(acc: &[Vector3<f64>], threshold: f64, window: usize) -> Vec<(usize, usize)> {
    let h = window.max(11) / 2;
    let w = 2 * h + 1;
    let n = acc.len();
    if n < w {
        return Vec::new();
    }
    let mean = acc.iter().fold(Vector3::zeros(), |s, a| s + a) / n as f64;
    let mut c1 = Vec::with_capacity(n + 1);
    let mut c2 = Vec::with_capacity(n + 1);
    c1.push(Vector3::zeros());
    c2.push(Vector3::zeros());
    for a in acc {
        let x = a - mean;
        let l1 = c1[c1.len() - 1];
        let l2 = c2[c2.len() - 1];
        c1.push(l1 + x);
        c2.push(l2 + x.component_mul(&x));
    }
    let mut out = Vec::new();
    let mut start: Option<usize> = None;
    let wf = w as f64;
    for i in h..n - h {
        let s1 = c1[i + h + 1] - c1[i - h];
        let s2 = c2[i + h + 1] - c2[i - h];
        let var = (s2 - s1.component_mul(&s1) / wf).map(|v| (v / (wf - 1.0)).max(0.0));
        let still = var.norm() < threshold;
        match (still, start) {
            (true, None) => start = Some(i),
            (false, Some(s)) => {
                out.push((s, i - 1));
                start = None;
            }
            _ => {}
        }
    }
    if let Some(s) = start {
        out.push((s, n - h - 1));
    }
    out
}

fn acc_residuals(p: &[f64], samples: &[Vector3<f64>], g: f64) -> Vec<f64> {
    let tk = t_acc(p) * Matrix3::from_diagonal(&Vector3::new(p[3], p[4], p[5]));
    let b = Vector3::new(p[6], p[7], p[8]);
    samples.iter().map(|a| g - (tk * (a - b)).norm()).collect()
}

fn param_std(res: &lm::LmResult) -> Vec<f64> {
    let m = res.residuals.len();
    let p = res.x.len();
    let s2 = if m > p {
        2.0 * res.cost / (m - p) as f64
    } else {
        f64::NAN
    };
    match &res.jtj_inv {
        Some(inv) => (0..p).map(|j| (inv[(j, j)].max(0.0) * s2).sqrt()).collect(),
        None => vec![f64::NAN; p],
    }
}

/// [`imu_intrinsics`] on an already parsed log.
pub fn imu_intrinsics_from_log(
    log: &ImuLog,
    params: &ImuIntrinsicsParams,
    progress: &dyn Progress,
) -> CoreResult<ImuIntrinsicsReport> {
    validate(params)?;
    let n = log.len();
    let t = log.times_s();
    let g = params.gravity_m_s2;
    let acc: Vec<Vector3<f64>> = (0..n)
        .map(|i| Vector3::new(log.value(3, i), log.value(4, i), log.value(5, i)))
        .collect();
    let gyr: Vec<Vector3<f64>> = (0..n)
        .map(|i| Vector3::new(log.value(0, i), log.value(1, i), log.value(2, i)))
        .collect();

    // Initial rest: samples with t ≤ init_static_s (first index with t ≥ init, inclusive).
    let i_init = t
        .partition_point(|&v| v < params.init_static_s)
        .min(n.saturating_sub(1));
    let wlen = params.window.max(11) | 1;
    if i_init < wlen {
        return Err(CoreError::input(format!(
            "the initial rest period ({} s) holds only {i_init} samples, fewer than the variance \
             window ({wlen}): record a longer rest or lower `init_static_s`/`window`",
            params.init_static_s
        )));
    }
    let init = &acc[..=i_init];
    let mean0 = init.iter().fold(Vector3::zeros(), |s, a| s + a) / init.len() as f64;
    let var0 = init.iter().fold(Vector3::zeros(), |s, a| {
        s + (a - mean0).component_mul(&(a - mean0))
    }) / (init.len() as f64 - 1.0);
    let base = var0.norm();
    if !(base.is_finite() && base > 0.0) {
        return Err(CoreError::input(
            "the accelerometer variance of the initial rest is zero or not finite (constant or \
             broken signal)",
        ));
    }

    // Try every multiplier; the lowest accelerometer cost wins.
    let mut tried = Vec::new();
    // (multiplier, accelerometer fit, intervals) of the lowest cost so far.
    let mut best: Option<Best> = None;
    let n_mult = params.threshold_multipliers.len() as u64;
    for (k, &mult) in params.threshold_multipliers.iter().enumerate() {
        progress.report("static_detect", k as u64, n_mult);
        progress.check()?;
        let ivs: Vec<(usize, usize)> = static_intervals(&acc, mult * base, params.window)
            .into_iter()
            .filter(|&(s, e)| e + 1 - s >= params.min_samples)
            .collect();
        let mut trial = ThresholdTrial {
            multiplier: mult,
            intervals: ivs.len(),
            cost: None,
        };
        if ivs.len() >= params.min_intervals {
            progress.report("accel_fit", k as u64, n_mult);
            let samples: Vec<Vector3<f64>> = if params.use_means {
                ivs.iter()
                    .map(|&(s, e)| {
                        acc[s..=e].iter().fold(Vector3::zeros(), |a, b| a + b) / (e + 1 - s) as f64
                    })
                    .collect()
            } else {
                ivs.iter()
                    .flat_map(|&(s, _)| acc[s..s + params.min_samples].iter().copied())
                    .collect()
            };
            let x0 = [0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0];
            let res = lm::solve(
                &x0,
                |p| acc_residuals(p, &samples, g),
                params.max_iterations,
                progress,
            )?;
            trial.cost = Some(res.cost);
            if best.as_ref().is_none_or(|b| res.cost < b.1.cost) {
                best = Some((mult, res, ivs));
            }
        }
        tried.push(trial);
    }
    let Some((mult, acc_res, ivs)) = best else {
        let counts: Vec<String> = tried
            .iter()
            .map(|t| format!("×{}: {}", t.multiplier, t.intervals))
            .collect();
        return Err(CoreError::NoSolution(format!(
            "too few static poses: need {} static intervals of ≥ {} samples, found [{}] at the \
             tried thresholds; hold the IMU still in more orientations (Tedaldi et al. use 36–50)",
            params.min_intervals,
            params.min_samples,
            counts.join(", ")
        )));
    };

    let p = &acc_res.x;
    let tka = t_acc(p) * Matrix3::from_diagonal(&Vector3::new(p[3], p[4], p[5]));
    let ba = Vector3::new(p[6], p[7], p[8]);
    let up: Vec<Vector3<f64>> = ivs
        .iter()
        .map(|&(s, e)| {
            acc[s..=e]
                .iter()
                .fold(Vector3::zeros(), |m, a| m + tka * (a - ba))
                / (e + 1 - s) as f64
        })
        .collect();
    let pose_norm_error: Vec<f64> = up.iter().map(|u| u.norm() - g).collect();
    let accel = AccelIntrinsics {
        misalignment_yz_zy_zx: [p[0], p[1], p[2]],
        scale: [p[3], p[4], p[5]],
        bias: [p[6], p[7], p[8]],
        std: param_std(&acc_res),
        t: rows(&t_acc(p)),
        t_times_k: rows(&tka),
        residual: ResidualStats::of(&acc_res.residuals),
        pose_norm_error,
        cost: acc_res.cost,
        iterations: acc_res.iterations,
        converged: acc_res.converged,
    };
    let mut warnings = Vec::new();
    if !acc_res.converged {
        warnings.push("accelerometer LM hit the iteration cap".into());
    }
    let intervals: Vec<StaticInterval> = ivs
        .iter()
        .map(|&(s, e)| StaticInterval {
            start_index: s,
            end_index: e,
            start_s: t[s],
            end_s: t[e],
        })
        .collect();

    let gyro = if params.gyro {
        progress.report("gyro_fit", 0, 1);
        let up_dir: Vec<Vector3<f64>> = up.iter().map(|u| u / u.norm().max(1e-300)).collect();
        let bias = gyr[..=i_init].iter().fold(Vector3::zeros(), |s, w| s + w) / (i_init + 1) as f64;
        // Per segment: the trapezoid increments (w_j + w_{j+1})/2 · Δt_j of the bias-free raw rate.
        let segs: Vec<Vec<Vector3<f64>>> = (0..ivs.len().saturating_sub(1))
            .map(|k| {
                let s = ivs[k].1;
                let e = ivs[k + 1].0.saturating_sub(1).max(s);
                (s..e)
                    .map(|j| ((gyr[j] - bias) + (gyr[j + 1] - bias)) * (0.5 * (t[j + 1] - t[j])))
                    .collect()
            })
            .collect();
        if segs.len() < 3 {
            return Err(CoreError::NoSolution(format!(
                "only {} rotations between static poses: too few for the gyroscope fit",
                segs.len()
            )));
        }
        let predict = |q: &[f64]| -> Vec<Vector3<f64>> {
            let m = t_gyro(q) * Matrix3::from_diagonal(&Vector3::new(q[6], q[7], q[8]));
            segs.iter()
                .enumerate()
                .map(|(k, seg)| {
                    let mut r = So3::identity();
                    for inc in seg {
                        r = r.compose(&So3::exp(&(m * inc)));
                    }
                    r.inverse().act(&up_dir[k])
                })
                .collect()
        };
        let resid = |q: &[f64]| -> Vec<f64> {
            predict(q)
                .iter()
                .enumerate()
                .flat_map(|(k, v)| {
                    let d = v - up_dir[k + 1];
                    [d.x, d.y, d.z]
                })
                .collect()
        };
        let x0 = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0];
        let res = lm::solve(&x0, resid, params.max_iterations, progress)?;
        let q = &res.x;
        let tg = t_gyro(q);
        let tkg = tg * Matrix3::from_diagonal(&Vector3::new(q[6], q[7], q[8]));
        let seg_err: Vec<f64> = predict(q)
            .iter()
            .enumerate()
            .map(|(k, v)| {
                let c = (v.dot(&up_dir[k + 1]) / v.norm().max(1e-300)).clamp(-1.0, 1.0);
                c.acos().to_degrees()
            })
            .collect();
        if !res.converged {
            warnings.push("gyroscope LM hit the iteration cap".into());
        }
        progress.report("gyro_fit", 1, 1);
        Some(GyroIntrinsics {
            misalignment_yz_zy_zx_xz_xy_yx: [q[0], q[1], q[2], q[3], q[4], q[5]],
            scale: [q[6], q[7], q[8]],
            bias: [bias.x, bias.y, bias.z],
            bias_source: format!(
                "mean of the first {} s ({} samples)",
                params.init_static_s,
                i_init + 1
            ),
            std: param_std(&res),
            t: rows(&tg),
            t_times_k: rows(&tkg),
            segments: segs.len(),
            residual: ResidualStats::of(&res.residuals),
            segment_error_deg: seg_err,
            cost: res.cost,
            iterations: res.iterations,
            converged: res.converged,
        })
    } else {
        None
    };
    if log.stats.gaps > 0 {
        warnings.push(format!(
            "{} timestamp gaps: rotations across a gap are integrated with the long step",
            log.stats.gaps
        ));
    }

    Ok(ImuIntrinsicsReport {
        schema: "caliper.imu_intrinsics/v1".into(),
        convention: "imu_tk (Tedaldi et al. 2014): X_cal = T · diag(scale) · (X_raw − bias); accel \
                     T = [[1,−yz,zy],[0,1,−zx],[0,0,1]], gyro T = [[1,−yz,zy],[xz,1,−zx],[−xy,yx,1]]"
            .into(),
        accel,
        gyro,
        static_detection: StaticDetection {
            threshold_multiplier: mult,
            threshold: mult * base,
            init_variance: base,
            window: params.window.max(11) / 2 * 2 + 1,
            intervals,
            tried,
        },
        usable_poses: ivs.len(),
        rate_hz: log.stats.rate_hz,
        duration_s: log.stats.duration_s,
        warnings,
        parse: log.stats.clone(),
    })
}
