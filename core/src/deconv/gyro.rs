//! PSFs from a gyroscope trace: rotational camera shake drawn through the pinhole model.

use nalgebra::{Matrix3, Vector3};
use serde::{Deserialize, Serialize};

use super::Psf;
use super::psf::MAX_PSF_SIZE;
use crate::error::{CoreError, CoreResult};
use crate::lie::So3;

/// Largest number of gyro samples accepted (an hour at 1 kHz is far beyond one exposure).
pub const MAX_GYRO_SAMPLES: usize = 1_000_000;

/// One gyroscope reading: time and angular rate about the sensor axes.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct GyroSample {
    /// Timestamp, s (same clock as `exposure_start_s`).
    pub t: f64,
    /// Angular rate about x, y, z, rad/s.
    pub w: [f64; 3],
}

/// Everything a gyro PSF needs: the trace, the exposure, and the pinhole intrinsics.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct GyroPsfParams {
    /// Gyro samples in increasing time order, covering the exposure.
    pub samples: Vec<GyroSample>,
    /// Start of the exposure, s.
    pub exposure_start_s: f64,
    /// Exposure time, s (> 0).
    pub exposure_s: f64,
    /// Focal lengths and principal point, px.
    pub fx: f64,
    /// See `fx`.
    pub fy: f64,
    /// See `fx`.
    pub cx: f64,
    /// See `fx`.
    pub cy: f64,
    /// Rotation from the gyro frame to the camera frame as a quaternion `[w, x, y, z]`
    /// (default: the gyro axes are the camera axes, x right, y down, z forward).
    #[serde(default)]
    pub gyro_to_camera_wxyz: Option<[f64; 4]>,
}

/// Checks pinhole intrinsics `[fx, fy, cx, cy]` (focal lengths finite and > 0, principal
/// point finite) and the gyro-to-camera rotation of a gyro kernel; errors name the field.
pub(crate) fn check_intrinsics(k: [f64; 4], gyro_to_camera: Option<[f64; 4]>) -> CoreResult<()> {
    let [fx, fy, cx, cy] = k;
    for (name, v) in [("fx", fx), ("fy", fy)] {
        if !(v.is_finite() && v > 0.0) {
            return Err(CoreError::param(name, "must be finite and > 0"));
        }
    }
    for (name, v) in [("cx", cx), ("cy", cy)] {
        if !v.is_finite() {
            return Err(CoreError::param(name, "must be finite"));
        }
    }
    if let Some(q) = gyro_to_camera {
        So3::from_wxyz(q).map_err(|e| CoreError::param("gyro_to_camera_wxyz", e.to_string()))?;
    }
    Ok(())
}

impl GyroPsfParams {
    /// Check the trace, the exposure and the intrinsics; errors name the field.
    pub fn validate(&self) -> CoreResult<()> {
        if self.samples.len() < 2 || self.samples.len() > MAX_GYRO_SAMPLES {
            return Err(CoreError::param(
                "samples",
                format!("need between 2 and {MAX_GYRO_SAMPLES} gyro samples"),
            ));
        }
        for (i, s) in self.samples.iter().enumerate() {
            if !s.t.is_finite() || s.w.iter().any(|v| !v.is_finite()) {
                return Err(CoreError::param(
                    "samples",
                    format!("sample {i} is not finite"),
                ));
            }
            if i > 0 && s.t <= self.samples[i - 1].t {
                return Err(CoreError::param(
                    "samples",
                    format!("sample {i}: timestamps must increase"),
                ));
            }
        }
        if !self.exposure_start_s.is_finite() {
            return Err(CoreError::param("exposure_start_s", "must be finite"));
        }
        if !(self.exposure_s.is_finite() && self.exposure_s > 0.0) {
            return Err(CoreError::param("exposure_s", "must be finite and > 0"));
        }
        check_intrinsics(
            [self.fx, self.fy, self.cx, self.cy],
            self.gyro_to_camera_wxyz,
        )?;
        // The trace must cover the exposure, up to one sample interval at either end (the rate
        // is held constant there).
        let (first, last) = (self.samples[0].t, self.samples[self.samples.len() - 1].t);
        let dt = (last - first) / (self.samples.len() - 1) as f64;
        let end = self.exposure_start_s + self.exposure_s;
        if first > self.exposure_start_s + dt || last < end - dt {
            return Err(CoreError::param(
                "samples",
                format!(
                    "gyro trace {first}…{last} s does not cover the exposure {}…{end} s",
                    self.exposure_start_s
                ),
            ));
        }
        Ok(())
    }

    fn camera_matrix(&self) -> Matrix3<f64> {
        Matrix3::new(self.fx, 0.0, self.cx, 0.0, self.fy, self.cy, 0.0, 0.0, 1.0)
    }

    /// Angular rate at `t` in the camera frame, linearly interpolated (held at the ends).
    fn rate(&self, t: f64, to_cam: &So3) -> Vector3<f64> {
        let s = &self.samples;
        let i = s.partition_point(|p| p.t <= t);
        let w = if i == 0 {
            s[0].w
        } else if i == s.len() {
            s[s.len() - 1].w
        } else {
            let (a, b) = (&s[i - 1], &s[i]);
            let f = (t - a.t) / (b.t - a.t);
            [0, 1, 2].map(|k| a.w[k] + f * (b.w[k] - a.w[k]))
        };
        to_cam.act(&Vector3::new(w[0], w[1], w[2]))
    }

    /// Camera orientations (relative to the one at mid-exposure) at `n + 1` evenly spaced times
    /// across the exposure, integrating `Ṙ = R [ω]×` on SO(3) with the exponential map (midpoint
    /// rate per step), so large rotations stay exact rotations.
    fn orientations(&self, n: usize) -> CoreResult<Vec<So3>> {
        let to_cam = match self.gyro_to_camera_wxyz {
            Some(q) => So3::from_wxyz(q)?,
            None => So3::identity(),
        };
        let h = self.exposure_s / n as f64;
        let mut r = vec![So3::identity()];
        for i in 0..n {
            let t = self.exposure_start_s + (i as f64 + 0.5) * h;
            let step = So3::exp(&(self.rate(t, &to_cam) * h));
            let next = r[i].compose(&step);
            r.push(next);
        }
        let mid_inv = r[n / 2].inverse();
        Ok(r.iter().map(|q| mid_inv.compose(q)).collect())
    }
}

/// Steps along the exposure: enough that consecutive positions are well under a pixel apart for
/// any plausible shake, cheap either way.
const TRAJECTORY_STEPS: usize = 2_000;

/// The PSF at the principal point (`cx`, `cy`); see [`gyro_psf_at`].
pub fn gyro_psf(params: &GyroPsfParams) -> CoreResult<Psf> {
    gyro_psf_at(params, params.cx, params.cy)
}

/// The blur kernel at pixel (`px`, `py`) caused by the camera rotation the gyro recorded during
/// the exposure, for a scene far enough away that translation does not matter (N. Joshi,
/// S. B. Kang, C. L. Zitnick, R. Szeliski, "Image deblurring using inertial measurement sensors",
/// SIGGRAPH 2010).
///
/// The orientation `R(t)` relative to mid-exposure is integrated from the rates on SO(3); a scene
/// point seen at `p` at mid-exposure is seen at `K R(t)ᵀ K⁻¹ p` at time `t`. The PSF is the time
/// density of that displacement: the trajectory is sampled finely, each sample is splatted
/// bilinearly (anti-aliasing), and the result is normalised, odd-sized, centred on the
/// mid-exposure position.
pub fn gyro_psf_at(params: &GyroPsfParams, px: f64, py: f64) -> CoreResult<Psf> {
    params.validate()?;
    if !(px.is_finite() && py.is_finite()) {
        return Err(CoreError::param("point", "must be finite"));
    }
    let k = params.camera_matrix();
    let k_inv = k
        .try_inverse()
        .ok_or_else(|| CoreError::param("fx", "camera matrix is singular"))?;
    let ray = k_inv * Vector3::new(px, py, 1.0);
    let mut offsets = Vec::with_capacity(TRAJECTORY_STEPS + 1);
    for r in params.orientations(TRAJECTORY_STEPS)? {
        let q = k * r.inverse().act(&ray);
        if q.z <= 1e-9 {
            return Err(CoreError::input(
                "the camera turned by 90° or more during the exposure",
            ));
        }
        offsets.push((q.x / q.z - px, q.y / q.z - py));
    }
    let reach = offsets
        .iter()
        .fold(0.0f64, |m, (dx, dy)| m.max(dx.abs()).max(dy.abs()));
    let size = 2 * ((reach - 1e-9).max(0.0).ceil() as usize) + 3;
    if size > MAX_PSF_SIZE {
        return Err(CoreError::input(format!(
            "gyro blur spans {:.0} px; at most {MAX_PSF_SIZE} px kernels are supported",
            2.0 * reach
        )));
    }
    let c = (size / 2) as f64;
    let mut w = vec![0.0f64; size * size];
    // Trapezoid weights in time: the end samples cover half a step each.
    let last = offsets.len() - 1;
    for (i, (dx, dy)) in offsets.iter().enumerate() {
        let wt = if i == 0 || i == last { 0.5 } else { 1.0 };
        let (x, y) = (c + dx, c + dy);
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let (x0, y0) = (x0 as usize, y0 as usize);
        w[y0 * size + x0] += wt * (1.0 - fx) * (1.0 - fy);
        w[y0 * size + x0 + 1] += wt * fx * (1.0 - fy);
        w[(y0 + 1) * size + x0] += wt * (1.0 - fx) * fy;
        w[(y0 + 1) * size + x0 + 1] += wt * fx * fy;
    }
    Psf::from_weights(size, size, w)
}

/// Spatially varying blur: the PSF at the centres of an `nx × ny` grid of cells over a
/// `width × height` image, row by row, as `(x, y, psf)`. Rotation blur grows away from the
/// principal point (and rolls around it), which one kernel cannot describe on wide lenses.
pub fn gyro_psf_grid(
    params: &GyroPsfParams,
    width: usize,
    height: usize,
    nx: usize,
    ny: usize,
) -> CoreResult<Vec<(f64, f64, Psf)>> {
    if nx == 0 || ny == 0 || nx > 64 || ny > 64 {
        return Err(CoreError::param("grid", "between 1 and 64 cells per axis"));
    }
    let mut out = Vec::with_capacity(nx * ny);
    for j in 0..ny {
        for i in 0..nx {
            let x = (i as f64 + 0.5) * width as f64 / nx as f64 - 0.5;
            let y = (j as f64 + 0.5) * height as f64 / ny as f64 - 0.5;
            out.push((x, y, gyro_psf_at(params, x, y)?));
        }
    }
    Ok(out)
}
