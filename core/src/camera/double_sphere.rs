//! Double sphere camera model (Usenko, Demmel, Cremers, 3DV 2018).

use nalgebra::{Matrix2x3, Matrix2xX, RowVector3, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use super::{CameraModel, ProjectionJacobians, checked_params, schema_via_params};
use crate::error::{CoreError, CoreResult};

const NAMES: [&str; 6] = ["fx", "fy", "cx", "cy", "xi", "alpha"];

/// Double sphere projection (Usenko, Demmel, Cremers, "The Double Sphere Camera Model", 3DV
/// 2018), parameters `[fx, fy, cx, cy, ξ, α]`:
///
/// ```text
/// d1 = √(X² + Y² + Z²), d2 = √(X² + Y² + (ξ d1 + Z)²)
/// u = fx X / (α d2 + (1 − α)(ξ d1 + Z)) + cx, v likewise with fy, Y, cy
/// ```
///
/// The point is projected onto a unit sphere, then onto a second unit sphere shifted by ξ along
/// the optical axis, then by a pinhole shifted by α/(1 − α). Both directions are closed form,
/// which makes it fast and well suited to lenses with fields of view beyond 180°.
///
/// Valid domains (from the paper): projection needs `Z > −w2·d1` with
/// `w1 = α/(1 − α)` if α ≤ ½ else `(1 − α)/α`, and `w2 = (w1 + ξ)/√(2 w1 ξ + ξ² + 1)`;
/// unprojection needs `r² ≤ 1/(2α − 1)` when α > ½. Parameters are restricted to α ∈ [0, 1] and
/// ξ ∈ [−1, 1] (which keeps the unprojection's square root `mz² + (1 − ξ²) r²` real).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "DoubleSphereParams", into = "DoubleSphereParams")]
pub struct DoubleSphere {
    params: [f64; 6],
}

/// Document form of [`DoubleSphere`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct DoubleSphereParams {
    /// Focal length along x, pixels.
    pub fx: f64,
    /// Focal length along y, pixels.
    pub fy: f64,
    /// Principal point x, pixels.
    pub cx: f64,
    /// Principal point y, pixels.
    pub cy: f64,
    /// Distance between the two sphere centres, in [−1, 1].
    pub xi: f64,
    /// Pinhole shift weight, in [0, 1].
    pub alpha: f64,
}

schema_via_params!(DoubleSphere, DoubleSphereParams, "DoubleSphere");

impl TryFrom<DoubleSphereParams> for DoubleSphere {
    type Error = CoreError;
    fn try_from(p: DoubleSphereParams) -> CoreResult<Self> {
        Self::from_slice(&[p.fx, p.fy, p.cx, p.cy, p.xi, p.alpha])
    }
}

impl From<DoubleSphere> for DoubleSphereParams {
    fn from(m: DoubleSphere) -> Self {
        let [fx, fy, cx, cy, xi, alpha] = m.params;
        Self {
            fx,
            fy,
            cx,
            cy,
            xi,
            alpha,
        }
    }
}

/// Intermediate quantities of the projection.
struct Terms {
    d1: f64,
    k: f64,
    d2: f64,
    den: f64,
}

impl DoubleSphere {
    /// A validated model (see [`CameraModel::set_params`] and the type docs for the checks).
    pub fn new(fx: f64, fy: f64, cx: f64, cy: f64, xi: f64, alpha: f64) -> CoreResult<Self> {
        Self::from_slice(&[fx, fy, cx, cy, xi, alpha])
    }

    /// A validated model from `[fx, fy, cx, cy, ξ, α]`.
    pub fn from_slice(params: &[f64]) -> CoreResult<Self> {
        let params = checked_params(params, &NAMES)?;
        if !(-1.0..=1.0).contains(&params[4]) {
            return Err(CoreError::param("xi", "must be in [-1, 1]"));
        }
        if !(0.0..=1.0).contains(&params[5]) {
            return Err(CoreError::param("alpha", "must be in [0, 1]"));
        }
        Ok(Self { params })
    }

    fn xi(&self) -> f64 {
        self.params[4]
    }

    fn alpha(&self) -> f64 {
        self.params[5]
    }

    /// `w2` of the projection validity condition `Z > −w2·d1` (from the paper).
    fn w2(&self) -> f64 {
        let (xi, alpha) = (self.xi(), self.alpha());
        let w1 = if alpha <= 0.5 {
            alpha / (1.0 - alpha)
        } else {
            (1.0 - alpha) / alpha
        };
        (w1 + xi) / (2.0 * w1 * xi + xi * xi + 1.0).sqrt()
    }

    /// Projection terms, or `None` outside the valid domain.
    fn terms(&self, p: &Vector3<f64>) -> Option<Terms> {
        let (xi, alpha) = (self.xi(), self.alpha());
        let d1 = p.norm();
        let k = xi * d1 + p.z;
        let d2 = (p.x * p.x + p.y * p.y + k * k).sqrt();
        let den = alpha * d2 + (1.0 - alpha) * k;
        // Positive tests so that NaN and the centre of projection are rejected.
        let valid = d1 > 0.0 && p.z > -self.w2() * d1 && den > 0.0;
        valid.then_some(Terms { d1, k, d2, den })
    }
}

impl CameraModel for DoubleSphere {
    fn name(&self) -> &'static str {
        "double_sphere"
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
        let t = self.terms(p)?;
        let [fx, fy, cx, cy, ..] = self.params;
        Some(Vector2::new(fx * p.x / t.den + cx, fy * p.y / t.den + cy))
    }

    /// Closed form (from the paper); no iteration is needed. The result is normalised to a unit
    /// bearing, and rejected if it falls outside the projection domain so that
    /// `project(unproject(px))` always exists.
    fn unproject(&self, px: &Vector2<f64>) -> Option<Vector3<f64>> {
        let [fx, fy, cx, cy, xi, alpha] = self.params;
        let (mx, my) = ((px.x - cx) / fx, (px.y - cy) / fy);
        let r2 = mx * mx + my * my;
        let disc = 1.0 - (2.0 * alpha - 1.0) * r2;
        // Positive test: also rejects NaN.
        let in_domain = disc >= 0.0;
        if !in_domain {
            return None;
        }
        let mz = (1.0 - alpha * alpha * r2) / (alpha * disc.sqrt() + 1.0 - alpha);
        let scale = (mz * xi + (mz * mz + (1.0 - xi * xi) * r2).sqrt()) / (mz * mz + r2);
        let b = Vector3::new(scale * mx, scale * my, scale * mz - xi);
        let n = b.norm();
        if !(n.is_finite() && n > 0.0) {
            return None;
        }
        let b = b / n;
        self.terms(&b).map(|_| b)
    }

    fn project_with_jacobians(&self, p: &Vector3<f64>) -> Option<ProjectionJacobians> {
        let Terms { d1, k, d2, den } = self.terms(p)?;
        let [fx, fy, cx, cy, xi, alpha] = self.params;
        let (mx, my) = (p.x / den, p.y / den);
        let pixel = Vector2::new(fx * mx + cx, fy * my + cy);

        // ∂d1/∂P = Pᵀ/d1, ∂k/∂P = ξ Pᵀ/d1 + e_z, ∂d2/∂P = (X, Y, 0)/d2 + k ∂k/∂P / d2.
        let dd1 = p.transpose() / d1;
        let dk = dd1 * xi + RowVector3::new(0.0, 0.0, 1.0);
        let dd2 = (RowVector3::new(p.x, p.y, 0.0) + dk * k) / d2;
        let dden = dd2 * alpha + dk * (1.0 - alpha);
        let inv = 1.0 / den;
        let du = (RowVector3::new(inv, 0.0, 0.0) - dden * (p.x * inv * inv)) * fx;
        let dv = (RowVector3::new(0.0, inv, 0.0) - dden * (p.y * inv * inv)) * fy;
        let d_point = Matrix2x3::from_rows(&[du, dv]);

        // ∂den/∂ξ = α k d1/d2 + (1 − α) d1, ∂den/∂α = d2 − k.
        let dden_dxi = alpha * k * d1 / d2 + (1.0 - alpha) * d1;
        let dden_dalpha = d2 - k;
        let (gu, gv) = (-fx * mx * inv, -fy * my * inv);
        #[rustfmt::skip]
        let d_params = Matrix2xX::from_row_slice(&[
            mx,  0.0, 1.0, 0.0, gu * dden_dxi, gu * dden_dalpha,
            0.0, my,  0.0, 1.0, gv * dden_dxi, gv * dden_dalpha,
        ]);
        Some((pixel, d_point, d_params))
    }
}
