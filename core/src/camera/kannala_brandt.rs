//! Kannala-Brandt generic fisheye model (OpenCV `fisheye` parameterisation).

use std::f64::consts::PI;

use nalgebra::{Matrix2x3, Matrix2xX, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use super::{
    CameraModel, ProjectionJacobians, checked_params, first_nonpositive, schema_via_params,
    solve_increasing,
};
use crate::error::{CoreError, CoreResult};

const NAMES: [&str; 8] = ["fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"];

/// Below this distance from the optical axis (relative to the point's norm) the `θd/r` ratios
/// are replaced by their limits; they are exact there to O(r²).
const AXIS_EPS: f64 = 1e-12;

/// Kannala-Brandt fisheye projection (Kannala & Brandt, "A generic camera model and calibration
/// method for conventional, wide-angle, and fish-eye lenses", TPAMI 2006), parameters
/// `[fx, fy, cx, cy, k1, k2, k3, k4]` as in OpenCV's `fisheye` module:
///
/// ```text
/// r = √(X² + Y²), θ = atan2(r, Z)
/// θd = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)
/// x″ = (θd / r) X, y″ = (θd / r) Y
/// u = fx x″ + cx, v = fy y″ + cy
/// ```
///
/// Unlike OpenCV, which computes θ from X/Z and so stops at 90°, θ comes from `atan2` so rays
/// behind the image plane (θ > 90°) project too. Valid domain: θ below the first zero of
/// `dθd/dθ` (where the polynomial folds back) and below π.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "KannalaBrandtParams", into = "KannalaBrandtParams")]
pub struct KannalaBrandt {
    params: [f64; 8],
    /// Largest valid angle from the optical axis.
    theta_max: f64,
}

/// Document form of [`KannalaBrandt`]. Distortion coefficients default to 0 (equidistant).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct KannalaBrandtParams {
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
    /// Coefficient of θ³.
    #[serde(default)]
    pub k1: f64,
    /// Coefficient of θ⁵.
    #[serde(default)]
    pub k2: f64,
    /// Coefficient of θ⁷.
    #[serde(default)]
    pub k3: f64,
    /// Coefficient of θ⁹.
    #[serde(default)]
    pub k4: f64,
}

schema_via_params!(KannalaBrandt, KannalaBrandtParams, "KannalaBrandt");

impl TryFrom<KannalaBrandtParams> for KannalaBrandt {
    type Error = CoreError;
    fn try_from(p: KannalaBrandtParams) -> CoreResult<Self> {
        Self::from_slice(&[p.fx, p.fy, p.cx, p.cy, p.k1, p.k2, p.k3, p.k4])
    }
}

impl From<KannalaBrandt> for KannalaBrandtParams {
    fn from(m: KannalaBrandt) -> Self {
        let [fx, fy, cx, cy, k1, k2, k3, k4] = m.params;
        Self {
            fx,
            fy,
            cx,
            cy,
            k1,
            k2,
            k3,
            k4,
        }
    }
}

impl KannalaBrandt {
    /// A validated model (see [`CameraModel::set_params`] for the checks).
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        fx: f64,
        fy: f64,
        cx: f64,
        cy: f64,
        k1: f64,
        k2: f64,
        k3: f64,
        k4: f64,
    ) -> CoreResult<Self> {
        Self::from_slice(&[fx, fy, cx, cy, k1, k2, k3, k4])
    }

    /// A validated model from `[fx, fy, cx, cy, k1, k2, k3, k4]`.
    pub fn from_slice(params: &[f64]) -> CoreResult<Self> {
        let params = checked_params(params, &NAMES)?;
        let theta_max =
            first_nonpositive(|t| Self::dtheta_d(&params, t), 0.0, PI, 4000).unwrap_or(PI);
        Ok(Self { params, theta_max })
    }

    /// The largest angle from the optical axis (radians) the model projects.
    pub fn max_angle(&self) -> f64 {
        self.theta_max
    }

    /// θd(θ).
    fn theta_d(p: &[f64; 8], t: f64) -> f64 {
        let t2 = t * t;
        t * (1.0 + t2 * (p[4] + t2 * (p[5] + t2 * (p[6] + t2 * p[7]))))
    }

    /// dθd/dθ.
    fn dtheta_d(p: &[f64; 8], t: f64) -> f64 {
        let t2 = t * t;
        1.0 + t2 * (3.0 * p[4] + t2 * (5.0 * p[5] + t2 * (7.0 * p[6] + t2 * 9.0 * p[7])))
    }

    /// `(θ, r)` of a point, or `None` outside the valid domain.
    fn angles(&self, p: &Vector3<f64>) -> Option<(f64, f64)> {
        let r = p.x.hypot(p.y);
        let theta = r.atan2(p.z);
        // Positive tests so that NaN and the centre of projection are rejected.
        let valid = p.norm() > 0.0 && theta < self.theta_max;
        valid.then_some((theta, r))
    }
}

impl CameraModel for KannalaBrandt {
    fn name(&self) -> &'static str {
        "kannala_brandt"
    }

    fn param_names(&self) -> &'static [&'static str] {
        &NAMES
    }

    fn params(&self) -> &[f64] {
        &self.params
    }

    fn set_params(&mut self, params: &[f64]) -> CoreResult<()> {
        *self = Self::from_slice(params)?;
        Ok(())
    }

    fn project(&self, p: &Vector3<f64>) -> Option<Vector2<f64>> {
        let (theta, r) = self.angles(p)?;
        let [fx, fy, cx, cy, ..] = self.params;
        let scale = if r > AXIS_EPS * p.norm() {
            Self::theta_d(&self.params, theta) / r
        } else {
            // On the axis θ < θmax ≤ π forces Z > 0, and θd/r → 1/Z.
            1.0 / p.z
        };
        Some(Vector2::new(fx * scale * p.x + cx, fy * scale * p.y + cy))
    }

    /// Solves `θd(θ) = |x″|` for θ on `[0, θmax)`, where θd is monotonic, by Newton's method
    /// safeguarded with bisection (so it always converges inside the bracket); `None` if the
    /// radius is beyond `θd(θmax)` or the residual does not get below
    /// [`super::UNPROJECT_TOLERANCE`].
    fn unproject(&self, px: &Vector2<f64>) -> Option<Vector3<f64>> {
        let [fx, fy, cx, cy, ..] = self.params;
        let (mx, my) = ((px.x - cx) / fx, (px.y - cy) / fy);
        let rd = mx.hypot(my);
        if !rd.is_finite() {
            return None;
        }
        if rd < AXIS_EPS {
            return Some(Vector3::new(mx, my, 1.0).normalize());
        }
        if rd >= Self::theta_d(&self.params, self.theta_max) {
            return None;
        }
        let theta = solve_increasing(
            |t| Self::theta_d(&self.params, t),
            |t| Self::dtheta_d(&self.params, t),
            rd,
            0.0,
            self.theta_max,
            rd,
        )?;
        let (s, c) = theta.sin_cos();
        Some(Vector3::new(s * mx / rd, s * my / rd, c))
    }

    fn project_with_jacobians(&self, p: &Vector3<f64>) -> Option<ProjectionJacobians> {
        let (theta, r) = self.angles(p)?;
        let [fx, fy, cx, cy, ..] = self.params;
        let rho2 = p.norm_squared();
        let td = Self::theta_d(&self.params, theta);
        let dtd = Self::dtheta_d(&self.params, theta);

        // With A = θd'·Z/ρ² (radial rate) and B = θd/r (tangential rate):
        // ∂x″/∂X = A X²/r² + B Y²/r², ∂x″/∂Y = (A − B) X Y/r², ∂x″/∂Z = −θd' X/ρ².
        // On the axis A = B = 1/Z and the mixed terms vanish.
        let on_axis = r <= AXIS_EPS * rho2.sqrt();
        let a = dtd * p.z / rho2;
        let (b, theta_over_r, cx2, cy2, cxy) = if on_axis {
            (1.0 / p.z, 1.0 / p.z, 1.0, 0.0, 0.0)
        } else {
            let r2 = r * r;
            (
                td / r,
                theta / r,
                p.x * p.x / r2,
                p.y * p.y / r2,
                p.x * p.y / r2,
            )
        };
        let mx = b * p.x;
        let my = b * p.y;
        let pixel = Vector2::new(fx * mx + cx, fy * my + cy);

        let dm = Matrix2x3::new(
            a * cx2 + b * cy2,
            (a - b) * cxy,
            -dtd * p.x / rho2,
            (a - b) * cxy,
            a * cy2 + b * cx2,
            -dtd * p.y / rho2,
        );
        let d_point = Matrix2x3::new(
            fx * dm[(0, 0)],
            fx * dm[(0, 1)],
            fx * dm[(0, 2)],
            fy * dm[(1, 0)],
            fy * dm[(1, 1)],
            fy * dm[(1, 2)],
        );

        // ∂x″/∂k_i = θ^(2i+1) X / r = θ^(2i) (θ/r) X.
        let t2 = theta * theta;
        let (ux, uy) = (theta_over_r * p.x, theta_over_r * p.y);
        let (w1, w2, w3, w4) = (t2, t2 * t2, t2 * t2 * t2, t2 * t2 * t2 * t2);
        #[rustfmt::skip]
        let d_params = Matrix2xX::from_row_slice(&[
            mx,  0.0, 1.0, 0.0, fx * w1 * ux, fx * w2 * ux, fx * w3 * ux, fx * w4 * ux,
            0.0, my,  0.0, 1.0, fy * w1 * uy, fy * w2 * uy, fy * w3 * uy, fy * w4 * uy,
        ]);
        Some((pixel, d_point, d_params))
    }
}
