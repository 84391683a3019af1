//! Temperature bias model (`imu_thermal`): per axis, bias(T) = Σ_i c_i (T − T_ref)^i.
//!
//! This is PX4's thermal compensation convention (`TC_G0_X{i}_{axis}`, `TC_A0_X{i}_{axis}`,
//! reference `TC_*_TREF`, cubic by default): coefficients in rad/s/°Cⁱ for the gyroscope and
//! m/s²/°Cⁱ for the accelerometer. The log is a static IMU warming up (or cooling down); every
//! sample is one observation of bias(T) plus noise, fitted by least squares on a scaled
//! variable (T − T_mid)/half-range so the normal equations stay well conditioned, then
//! re-expanded around T_ref.
//! The accelerometer also sees gravity: by default it is removed from the axis that carries it
//! (the one whose mean is closest to ±g), as a level IMU records it — the truth files add +g to
//! a_z. Only the recorded temperature range is valid: the report says which.

use nalgebra::{DMatrix, DVector};
use serde::{Deserialize, Serialize};

use super::log::{ImuCsvParams, ImuLog, ParseStats, read_imu_log};
use crate::error::{CoreError, CoreResult};
use crate::progress::Progress;

/// Which accelerometer axis carries gravity.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub enum GravityAxis {
    /// The axis whose mean is within 0.5 g of ±g (error if none).
    #[default]
    Auto,
    /// Do not remove gravity (c0 then includes it).
    None,
    /// +x up.
    PosX,
    /// −x up.
    NegX,
    /// +y up.
    PosY,
    /// −y up.
    NegY,
    /// +z up.
    PosZ,
    /// −z up.
    NegZ,
}

/// Parameters of [`imu_thermal`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct ImuThermalParams {
    /// How to read the CSV (the log needs a temperature column: named `temp…` in the header or
    /// given in `csv.columns.temperature`).
    pub csv: ImuCsvParams,
    /// Polynomial degree, 0..=6 (default 3, as PX4).
    pub degree: usize,
    /// Reference temperature T_ref, °C (default 25).
    pub t_ref_c: f64,
    /// Gravity magnitude removed from the accelerometer, m/s² (default 9.80665).
    pub gravity_m_s2: f64,
    /// Which accelerometer axis carries gravity (default `auto`).
    pub gravity_axis: GravityAxis,
    /// Temperature bins of the plot's data points (default 60).
    pub plot_bins: usize,
}

impl Default for ImuThermalParams {
    fn default() -> Self {
        Self {
            csv: ImuCsvParams::default(),
            degree: 3,
            t_ref_c: 25.0,
            gravity_m_s2: 9.806_65,
            gravity_axis: GravityAxis::Auto,
            plot_bins: 60,
        }
    }
}

/// Thermal model of one axis.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct AxisThermal {
    /// `gyro` or `accel`.
    pub sensor: String,
    /// `x`, `y` or `z`.
    pub axis: String,
    /// c_0 … c_degree of bias(T) = Σ c_i (T − T_ref)^i (unit/°Cⁱ: rad/s or m/s²).
    pub coeffs: Vec<f64>,
    /// 1-σ standard errors of the coefficients (white-residual assumption: optimistic when the
    /// sensor also drifts).
    pub coeff_std: Vec<f64>,
    /// Fit residuals (data − model), RMS.
    pub residual_rms: f64,
    /// Largest absolute residual.
    pub residual_max_abs: f64,
    /// Binned data for plotting: (mean T, mean bias) per temperature bin.
    pub binned: Vec<[f64; 2]>,
}

/// Result of [`imu_thermal`] (`caliper.imu_thermal/v1`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct ImuThermalReport {
    /// `caliper.imu_thermal/v1`.
    pub schema: String,
    /// Model description.
    pub model: String,
    /// Polynomial degree.
    pub degree: usize,
    /// T_ref, °C.
    pub t_ref_c: f64,
    /// Valid temperature range (recorded min and max), °C.
    pub valid_range_c: [f64; 2],
    /// Gravity removed: axis label (`+z`, …) or null.
    pub gravity_removed: Option<String>,
    /// Six axes: gyro x, y, z then accel x, y, z.
    pub axes: Vec<AxisThermal>,
    /// Warnings.
    pub warnings: Vec<String>,
    /// Parser statistics.
    pub parse: ParseStats,
}

/// Fits the thermal bias model of a static warm-up (or cool-down) log. Progress steps:
/// `"parse"`, `"fit"`.
pub fn imu_thermal(
    reader: impl std::io::BufRead,
    params: &ImuThermalParams,
    progress: &dyn Progress,
) -> CoreResult<ImuThermalReport> {
    validate(params)?;
    let log = read_imu_log(reader, &params.csv, progress)?;
    imu_thermal_from_log(&log, params, progress)
}

impl ImuThermalParams {
    /// Check the parameters (the service does so before queueing a job).
    pub fn validate(&self) -> CoreResult<()> {
        validate(self)
    }
}

fn validate(p: &ImuThermalParams) -> CoreResult<()> {
    if p.degree > 6 {
        return Err(CoreError::param("degree", "must be within 0..=6"));
    }
    if !p.t_ref_c.is_finite() {
        return Err(CoreError::param("t_ref_c", "must be finite"));
    }
    if !(p.gravity_m_s2.is_finite() && p.gravity_m_s2 > 0.0) {
        return Err(CoreError::param("gravity_m_s2", "must be > 0"));
    }
    if p.plot_bins == 0 || p.plot_bins > 10_000 {
        return Err(CoreError::param("plot_bins", "must be within 1..=10000"));
    }
    Ok(())
}

/// [`imu_thermal`] on an already parsed log.
pub fn imu_thermal_from_log(
    log: &ImuLog,
    params: &ImuThermalParams,
    progress: &dyn Progress,
) -> CoreResult<ImuThermalReport> {
    validate(params)?;
    let Some(temp) = log.temperature() else {
        return Err(CoreError::input(
            "the log has no temperature column: name it `temperature` in the header or set \
             `csv.columns.temperature`",
        ));
    };
    let n = log.len();
    let d = params.degree;
    let (tmin, tmax) = temp
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
            (a.min(f64::from(v)), b.max(f64::from(v)))
        });
    if tmax.is_nan() || tmin.is_nan() || tmax - tmin <= 0.5 {
        return Err(CoreError::input(format!(
            "temperature spans only {:.3} °C ({tmin:.2}..{tmax:.2}): a thermal model needs a warm-up \
             or cool-down over several °C",
            tmax - tmin
        )));
    }
    if n < 10 * (d + 1) {
        return Err(CoreError::input(format!(
            "only {n} samples for a degree-{d} fit"
        )));
    }

    // Gravity on the accelerometer.
    let g = params.gravity_m_s2;
    let means: Vec<f64> = (3..6)
        .map(|c| log.channel(c).iter().sum::<f64>() / n as f64)
        .collect();
    let grav: Option<(usize, f64)> = match params.gravity_axis {
        GravityAxis::None => None,
        GravityAxis::PosX => Some((0, 1.0)),
        GravityAxis::NegX => Some((0, -1.0)),
        GravityAxis::PosY => Some((1, 1.0)),
        GravityAxis::NegY => Some((1, -1.0)),
        GravityAxis::PosZ => Some((2, 1.0)),
        GravityAxis::NegZ => Some((2, -1.0)),
        GravityAxis::Auto => {
            let best = (0..3).min_by(|&a, &b| {
                (means[a].abs() - g)
                    .abs()
                    .total_cmp(&(means[b].abs() - g).abs())
            });
            match best {
                Some(a) if (means[a].abs() - g).abs() < 0.5 * g => Some((a, means[a].signum())),
                _ => {
                    return Err(CoreError::input(format!(
                        "no accelerometer axis reads ±g (means {:.3}, {:.3}, {:.3} m/s²): set \
                         `gravity_axis` (or `none`) explicitly",
                        means[0], means[1], means[2]
                    )));
                }
            }
        }
    };
    let mut warnings = Vec::new();
    if let Some((a, _)) = grav {
        let off: f64 = (0..3)
            .filter(|&b| b != a)
            .map(|b| means[b].powi(2))
            .sum::<f64>()
            .sqrt();
        if off > 0.05 * g {
            warnings.push(format!(
                "the IMU is tilted ({:.1}° from level): gravity leaks into the other accelerometer \
                 axes' c0",
                (off / g).atan().to_degrees()
            ));
        }
    }

    // Normal equations on u = (T − mid)/h ∈ [−1, 1] (well conditioned up to degree 6), then the
    // coefficients are re-expanded around T_ref: with x = T − T_ref and δ = T_ref − mid,
    // ((x + δ)/h)^j = Σ_k C(j,k) x^k δ^(j−k) / h^j, so c = L a with L[k][j] = C(j,k) δ^(j−k)/h^j.
    let dts: Vec<f64> = temp
        .iter()
        .map(|&v| f64::from(v) - params.t_ref_c)
        .collect();
    let mid = 0.5 * (tmin + tmax);
    let h = 0.5 * (tmax - tmin);
    let us: Vec<f64> = temp.iter().map(|&v| (f64::from(v) - mid) / h).collect();
    let p = d + 1;
    let mut ata = DMatrix::<f64>::zeros(p, p);
    let mut pw = vec![0.0; p];
    for &u in &us {
        pw[0] = 1.0;
        for j in 1..p {
            pw[j] = pw[j - 1] * u;
        }
        for i in 0..p {
            for j in 0..p {
                ata[(i, j)] += pw[i] * pw[j];
            }
        }
    }
    let ata_inv = ata.clone().try_inverse().filter(|m| m.iter().all(|v| v.is_finite())).ok_or_else(|| {
        CoreError::input(format!(
            "the temperatures do not determine a degree-{d} polynomial (too few distinct values)"
        ))
    })?;
    let delta = params.t_ref_c - mid;
    let binom = |n: usize, k: usize| -> f64 {
        (0..k).fold(1.0, |acc, i| acc * (n - i) as f64 / (i + 1) as f64)
    };
    let l = DMatrix::from_fn(p, p, |k, j| {
        if j < k {
            0.0
        } else {
            binom(j, k) * delta.powi((j - k) as i32) / h.powi(j as i32)
        }
    });

    let mut axes = Vec::with_capacity(6);
    for c in 0..6 {
        progress.check()?;
        progress.report("fit", c as u64, 6);
        let mut y = log.channel(c);
        if let Some((ga, sign)) = grav
            && c == 3 + ga
        {
            for v in &mut y {
                *v -= sign * g;
            }
        }
        let mut aty = DVector::<f64>::zeros(p);
        for (&u, &v) in us.iter().zip(&y) {
            let mut q = 1.0;
            for j in 0..p {
                aty[j] += q * v;
                q *= u;
            }
        }
        let a_coef = &ata_inv * &aty;
        let eval = |u: f64| a_coef.iter().rev().fold(0.0, |acc, &cj| acc * u + cj);
        let res: Vec<f64> = us.iter().zip(&y).map(|(&u, &v)| v - eval(u)).collect();
        let dof = (n - p).max(1) as f64;
        let s2 = res.iter().map(|v| v * v).sum::<f64>() / dof;
        let coeffs = &l * &a_coef;
        let cov = &l * &ata_inv * l.transpose() * s2;
        let binned = bin(&dts, &y, params.plot_bins, params.t_ref_c);
        axes.push(AxisThermal {
            sensor: if c < 3 { "gyro" } else { "accel" }.into(),
            axis: ["x", "y", "z"][c % 3].into(),
            coeffs: coeffs.iter().copied().collect(),
            coeff_std: (0..p).map(|j| cov[(j, j)].max(0.0).sqrt()).collect(),
            residual_rms: (res.iter().map(|v| v * v).sum::<f64>() / n as f64).sqrt(),
            residual_max_abs: res.iter().fold(0.0, |m, v| m.max(v.abs())),
            binned,
        });
    }
    progress.report("fit", 6, 6);
    if params.t_ref_c < tmin || params.t_ref_c > tmax {
        warnings.push(format!(
            "T_ref = {} °C is outside the recorded range {tmin:.2}..{tmax:.2} °C: c0 is an \
             extrapolation",
            params.t_ref_c
        ));
    }
    Ok(ImuThermalReport {
        schema: "caliper.imu_thermal/v1".into(),
        model: format!(
            "bias(T) = Σ_i c_i (T − T_ref)^i, i = 0..{d} (PX4 TC_* convention); gyro rad/s, accel \
             m/s²; least squares over every sample"
        ),
        degree: d,
        t_ref_c: params.t_ref_c,
        valid_range_c: [tmin, tmax],
        gravity_removed: grav
            .map(|(a, s)| format!("{}{}", if s > 0.0 { "+" } else { "-" }, ["x", "y", "z"][a])),
        axes,
        warnings,
        parse: log.stats.clone(),
    })
}

/// Mean (T, y) per equal-width temperature bin (empty bins skipped).
fn bin(dts: &[f64], y: &[f64], bins: usize, t_ref: f64) -> Vec<[f64; 2]> {
    let (lo, hi) = dts
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    let w = ((hi - lo) / bins as f64).max(1e-12);
    let mut acc = vec![(0.0f64, 0.0f64, 0usize); bins];
    for (&t, &v) in dts.iter().zip(y) {
        let k = (((t - lo) / w) as usize).min(bins - 1);
        acc[k].0 += t;
        acc[k].1 += v;
        acc[k].2 += 1;
    }
    acc.iter()
        .filter(|b| b.2 > 0)
        .map(|b| [b.0 / b.2 as f64 + t_ref, b.1 / b.2 as f64])
        .collect()
}
