//! Camera projection models with analytic Jacobians, the building blocks of calibration.
//!
//! A [`CameraModel`] maps a point in the camera frame (x right, y down, z forward, as in OpenCV)
//! to a pixel and back. The Levenberg-Marquardt bundle adjuster calls
//! [`CameraModel::project_with_jacobians`] for every observation: it returns the pixel, the
//! 2×3 Jacobian with respect to the point (chain it with [`crate::lie::Se3::act_jacobian_left`]
//! for the pose) and the 2×N Jacobian with respect to the model's parameter vector
//! ([`CameraModel::params`], in the order of [`CameraModel::param_names`]).
//!
//! Models:
//! * [`PinholeRadTan`]: pinhole with Brown-Conrady radial-tangential distortion in OpenCV's
//!   order and conventions (Brown 1966; Zhang 2000; OpenCV `calib3d`).
//! * [`KannalaBrandt`]: the generic fisheye model of Kannala & Brandt (TPAMI 2006) with four
//!   odd-polynomial coefficients, as OpenCV's `fisheye` module uses it, extended past 90°.
//! * [`DoubleSphere`]: Usenko, Demmel, Cremers, "The Double Sphere Camera Model" (3DV 2018),
//!   closed-form in both directions and valid beyond 180° fields of view.
//!
//! [`Camera`] wraps them in a serde-tagged enum (`"model": "pinhole_radtan" | "kannala_brandt" |
//! "double_sphere"`) for documents.
//!
//! Conventions shared by every model:
//! * [`CameraModel::project`] returns `None` for points outside the model's valid domain: behind
//!   the camera (or past the model's maximum angle), at the centre of projection, or past the
//!   radius where the distortion polynomial stops being monotonic (there the model folds back
//!   and one pixel has two rays, which would let an optimiser converge to a wrong branch).
//! * [`CameraModel::unproject`] returns a **unit-norm bearing vector** (not a z = 1 ray, which
//!   cannot represent rays at or beyond 90°), or `None` when the pixel has no ray in the valid
//!   domain or the iterative inversion did not converge.

mod double_sphere;
mod kannala_brandt;
mod pinhole;

#[cfg(test)]
mod tests;

pub use double_sphere::{DoubleSphere, DoubleSphereParams};
pub use kannala_brandt::{KannalaBrandt, KannalaBrandtParams};
pub use pinhole::{PinholeRadTan, PinholeRadTanParams};

use nalgebra::{Matrix2x3, Matrix2xX, Vector2, Vector3};
use serde::{Deserialize, Serialize};

use crate::error::{CoreError, CoreResult};

/// Pixel, `∂pixel/∂point` (2×3) and `∂pixel/∂params` (2×N, columns in
/// [`CameraModel::param_names`] order).
pub type ProjectionJacobians = (Vector2<f64>, Matrix2x3<f64>, Matrix2xX<f64>);

/// Maximum iterations of the iterative unprojections before giving up.
pub const UNPROJECT_MAX_ITERATIONS: usize = 50;

/// Convergence tolerance of the iterative unprojections, in normalised image coordinates
/// (10⁻¹² · f is far below a nanopixel for any real focal length).
pub const UNPROJECT_TOLERANCE: f64 = 1e-12;

/// A central camera projection model with a flat parameter vector.
///
/// Object safe, so calibration code can hold `&dyn CameraModel` or the [`Camera`] enum.
pub trait CameraModel {
    /// The model's document name (`pinhole_radtan`, `kannala_brandt`, `double_sphere`).
    fn name(&self) -> &'static str;

    /// Names of the parameters, in [`CameraModel::params`] order.
    fn param_names(&self) -> &'static [&'static str];

    /// Number of parameters (columns of the parameter Jacobian).
    fn num_params(&self) -> usize {
        self.param_names().len()
    }

    /// The parameter vector, in [`CameraModel::param_names`] order.
    fn params(&self) -> &[f64];

    /// Replaces the parameter vector. Errors on a wrong length, non-finite values or values
    /// outside the model's domain (e.g. non-positive focal length); the model is then unchanged.
    fn set_params(&mut self, params: &[f64]) -> CoreResult<()>;

    /// Projects a point in the camera frame to a pixel, or `None` outside the valid domain.
    fn project(&self, p: &Vector3<f64>) -> Option<Vector2<f64>>;

    /// The unit bearing vector of the ray through a pixel, or `None` when there is none in the
    /// valid domain or the inversion did not converge.
    fn unproject(&self, px: &Vector2<f64>) -> Option<Vector3<f64>>;

    /// [`CameraModel::project`] together with its analytic Jacobians with respect to the point
    /// and to the parameters.
    fn project_with_jacobians(&self, p: &Vector3<f64>) -> Option<ProjectionJacobians>;
}

/// Any supported camera model, tagged by `"model"` in documents.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "model")]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub enum Camera {
    /// Pinhole with radial-tangential (Brown-Conrady, OpenCV) distortion.
    #[serde(rename = "pinhole_radtan")]
    PinholeRadTan(PinholeRadTan),
    /// Kannala-Brandt fisheye (OpenCV `fisheye`).
    #[serde(rename = "kannala_brandt")]
    KannalaBrandt(KannalaBrandt),
    /// Double sphere (Usenko et al. 2018).
    #[serde(rename = "double_sphere")]
    DoubleSphere(DoubleSphere),
}

impl Camera {
    /// The wrapped model as a trait object.
    pub fn as_model(&self) -> &dyn CameraModel {
        match self {
            Camera::PinholeRadTan(m) => m,
            Camera::KannalaBrandt(m) => m,
            Camera::DoubleSphere(m) => m,
        }
    }

    /// The wrapped model as a mutable trait object.
    pub fn as_model_mut(&mut self) -> &mut dyn CameraModel {
        match self {
            Camera::PinholeRadTan(m) => m,
            Camera::KannalaBrandt(m) => m,
            Camera::DoubleSphere(m) => m,
        }
    }
}

impl CameraModel for Camera {
    fn name(&self) -> &'static str {
        self.as_model().name()
    }
    fn param_names(&self) -> &'static [&'static str] {
        self.as_model().param_names()
    }
    fn params(&self) -> &[f64] {
        self.as_model().params()
    }
    fn set_params(&mut self, params: &[f64]) -> CoreResult<()> {
        self.as_model_mut().set_params(params)
    }
    fn project(&self, p: &Vector3<f64>) -> Option<Vector2<f64>> {
        self.as_model().project(p)
    }
    fn unproject(&self, px: &Vector2<f64>) -> Option<Vector3<f64>> {
        self.as_model().unproject(px)
    }
    fn project_with_jacobians(&self, p: &Vector3<f64>) -> Option<ProjectionJacobians> {
        self.as_model().project_with_jacobians(p)
    }
}

impl From<PinholeRadTan> for Camera {
    fn from(m: PinholeRadTan) -> Self {
        Camera::PinholeRadTan(m)
    }
}

impl From<KannalaBrandt> for Camera {
    fn from(m: KannalaBrandt) -> Self {
        Camera::KannalaBrandt(m)
    }
}

impl From<DoubleSphere> for Camera {
    fn from(m: DoubleSphere) -> Self {
        Camera::DoubleSphere(m)
    }
}

/// Copies `params` into a fixed array after checking length and finiteness, and the focal
/// lengths (always the first two parameters) for positivity.
fn checked_params<const N: usize>(params: &[f64], names: &[&str; N]) -> CoreResult<[f64; N]> {
    let arr: [f64; N] = params.try_into().map_err(|_| {
        CoreError::param(
            "params",
            format!("expected {N} parameters, got {}", params.len()),
        )
    })?;
    for (v, name) in arr.iter().zip(names.iter()) {
        if !v.is_finite() {
            return Err(CoreError::param(*name, "must be finite"));
        }
    }
    for (v, name) in arr.iter().zip(names.iter()).take(2) {
        if *v <= 0.0 {
            return Err(CoreError::param(*name, "focal length must be positive"));
        }
    }
    Ok(arr)
}

/// The first point in `(0, hi]` where `f` stops being positive, given `f(0) > 0`, or `None`.
///
/// Used for the end of the monotonic part of a distortion polynomial. `f` is sampled on `steps`
/// points spaced geometrically from `lo` (or uniformly from 0 when `lo` is 0) and the first
/// sign change is bisected; the returned point is on the positive side, so it is a conservative
/// bound. A dip narrower than the sampling step could be missed; distortion polynomials of real
/// lenses are far smoother than that.
fn first_nonpositive(f: impl Fn(f64) -> f64, lo: f64, hi: f64, steps: usize) -> Option<f64> {
    let at = |i: usize| {
        let t = i as f64 / steps as f64;
        if lo > 0.0 {
            lo * (hi / lo).powf(t)
        } else {
            hi * t
        }
    };
    let mut a = if lo > 0.0 { lo } else { 0.0 };
    for i in 1..=steps {
        let b = at(i);
        if f(b) <= 0.0 {
            let (mut pos, mut neg) = (a, b);
            for _ in 0..100 {
                let mid = 0.5 * (pos + neg);
                if mid <= pos || mid >= neg {
                    break;
                }
                if f(mid) > 0.0 {
                    pos = mid;
                } else {
                    neg = mid;
                }
            }
            return Some(pos);
        }
        a = b;
    }
    None
}

/// Solves `f(x) = target` for x in `[lo, hi]` where `f` is increasing, by Newton's method
/// safeguarded with bisection (a Newton step leaving the current bracket is replaced by the
/// midpoint), so it converges for any monotonic `f`. Converged when
/// `|f(x) − target| ≤ UNPROJECT_TOLERANCE · max(1, |target|)`; `None` otherwise.
fn solve_increasing(
    f: impl Fn(f64) -> f64,
    df: impl Fn(f64) -> f64,
    target: f64,
    mut lo: f64,
    mut hi: f64,
    start: f64,
) -> Option<f64> {
    let tol = UNPROJECT_TOLERANCE * target.abs().max(1.0);
    let mut x = if start > lo && start < hi {
        start
    } else {
        0.5 * (lo + hi)
    };
    // Bisection halves the bracket at least every other step, so 4× the Newton budget always
    // suffices to reach round-off.
    for _ in 0..4 * UNPROJECT_MAX_ITERATIONS {
        let g = f(x) - target;
        if !g.is_finite() {
            return None;
        }
        if g.abs() <= tol {
            return Some(x);
        }
        if g < 0.0 {
            lo = x;
        } else {
            hi = x;
        }
        let newton = x - g / df(x);
        x = if newton > lo && newton < hi {
            newton
        } else {
            0.5 * (lo + hi)
        };
    }
    None
}

/// Implements utoipa's schema traits for a model by delegating to its document struct.
macro_rules! schema_via_params {
    ($ty:ty, $params:ty, $name:literal) => {
        #[cfg(feature = "schema")]
        impl utoipa::PartialSchema for $ty {
            fn schema() -> utoipa::openapi::RefOr<utoipa::openapi::schema::Schema> {
                <$params as utoipa::PartialSchema>::schema()
            }
        }

        #[cfg(feature = "schema")]
        impl utoipa::ToSchema for $ty {
            fn name() -> std::borrow::Cow<'static, str> {
                std::borrow::Cow::Borrowed($name)
            }

            fn schemas(
                schemas: &mut Vec<(
                    String,
                    utoipa::openapi::RefOr<utoipa::openapi::schema::Schema>,
                )>,
            ) {
                <$params as utoipa::ToSchema>::schemas(schemas);
            }
        }
    };
}
pub(crate) use schema_via_params;
