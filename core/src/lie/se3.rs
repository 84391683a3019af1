//! SE(3), the group of rigid motions `p ↦ R·p + t`.

use std::ops::Mul;

use nalgebra::{Matrix3, Matrix3x6, Matrix4, Matrix6, Vector3, Vector6};
use serde::{Deserialize, Serialize};

use super::{So3, coeff_b, coeff_q2, coeff_q3};
use crate::error::{CoreError, CoreResult};

/// How far the bottom row of a homogeneous matrix may be from `[0, 0, 0, 1]`.
const HOMOGENEOUS_ROW_TOLERANCE: f64 = 1e-6;

/// A rigid motion in 3-D, an element of the Lie group SE(3): `act(p) = R·p + t`.
///
/// Tangent vectors are `τ = [ρ, θ]` (translation part first, Solà et al. 2018, Appendix D);
/// `exp(τ) = (exp(θ), Jl(θ)·ρ)`, so ρ is *not* the translation unless θ = 0.
///
/// For camera extrinsics the convention is OpenCV's: `T_cam_world` maps world points into the
/// camera frame, `X_cam = R(rvec)·X_world + tvec` (see [`Se3::from_rvec_tvec`]).
///
/// Serialised as `{"rotation": [w, x, y, z], "translation": [x, y, z]}`.
#[derive(Clone, Copy, Debug, PartialEq, Default, Serialize, Deserialize)]
#[serde(try_from = "Se3Repr", into = "Se3Repr")]
pub struct Se3 {
    /// Rotation part `R`.
    pub rotation: So3,
    /// Translation part `t`.
    pub translation: Vector3<f64>,
}

/// Document form of [`Se3`].
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Se3Repr {
    rotation: So3,
    translation: [f64; 3],
}

impl TryFrom<Se3Repr> for Se3 {
    type Error = CoreError;
    fn try_from(r: Se3Repr) -> CoreResult<Self> {
        if r.translation.iter().any(|v| !v.is_finite()) {
            return Err(CoreError::param(
                "translation",
                "translation has non-finite components",
            ));
        }
        Ok(Se3::new(r.rotation, Vector3::from(r.translation)))
    }
}

impl From<Se3> for Se3Repr {
    fn from(t: Se3) -> Self {
        Se3Repr {
            rotation: t.rotation,
            translation: [t.translation.x, t.translation.y, t.translation.z],
        }
    }
}

/// Barfoot's `Q(ρ, θ)` block of the SE(3) left Jacobian (Solà et al. 2018, Appendix D):
/// `Q = ½[ρ]× + c₁([θ]×[ρ]× + [ρ]×[θ]× + [θ]×[ρ]×[θ]×)
///    + c₂([θ]×²[ρ]× + [ρ]×[θ]×² − 3[θ]×[ρ]×[θ]×) + c₃([θ]×[ρ]×[θ]×² + [θ]×²[ρ]×[θ]×)`.
fn q_matrix(rho: &Vector3<f64>, theta: &Vector3<f64>) -> Matrix3<f64> {
    let t = theta.norm();
    let th = So3::hat(theta);
    let rh = So3::hat(rho);
    let th_rh = th * rh;
    let rh_th = rh * th;
    let th_rh_th = th_rh * th;
    let th2 = th * th;
    rh * 0.5
        + (th_rh + rh_th + th_rh_th) * coeff_b(t)
        + (th2 * rh + rh_th * th - th_rh_th * 3.0) * coeff_q2(t)
        + (th_rh_th * th + th2 * rh * th) * coeff_q3(t)
}

/// Assembles `[[A, B], [0, A]]`.
fn block_upper(a: &Matrix3<f64>, b: &Matrix3<f64>) -> Matrix6<f64> {
    let mut m = Matrix6::zeros();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(a);
    m.fixed_view_mut::<3, 3>(0, 3).copy_from(b);
    m.fixed_view_mut::<3, 3>(3, 3).copy_from(a);
    m
}

fn split(tau: &Vector6<f64>) -> (Vector3<f64>, Vector3<f64>) {
    (
        Vector3::new(tau[0], tau[1], tau[2]),
        Vector3::new(tau[3], tau[4], tau[5]),
    )
}

impl Se3 {
    /// Builds a motion from its rotation and translation.
    pub fn new(rotation: So3, translation: Vector3<f64>) -> Self {
        Self {
            rotation,
            translation,
        }
    }

    /// The identity motion.
    pub fn identity() -> Self {
        Self::new(So3::identity(), Vector3::zeros())
    }

    /// Exponential map se(3) → SE(3), `τ = [ρ, θ]`: `(exp(θ), Jl(θ)·ρ)`.
    pub fn exp(tau: &Vector6<f64>) -> Self {
        let (rho, theta) = split(tau);
        Self::new(So3::exp(&theta), So3::jl(&theta) * rho)
    }

    /// Logarithmic map SE(3) → se(3): `[Jl⁻¹(θ)·t, θ]` with `θ = log(R)`, |θ| ≤ π.
    ///
    /// `Jl⁻¹` stays finite at θ = π (see [`So3::jl_inv`]), so this is stable there too.
    pub fn log(&self) -> Vector6<f64> {
        let theta = self.rotation.log();
        let rho = So3::jl_inv(&theta) * self.translation;
        Vector6::new(rho.x, rho.y, rho.z, theta.x, theta.y, theta.z)
    }

    /// `hat`: ℝ⁶ → se(3), `[ρ, θ] ↦ [[[θ]×, ρ], [0, 0]]`.
    pub fn hat(tau: &Vector6<f64>) -> Matrix4<f64> {
        let (rho, theta) = split(tau);
        let mut m = Matrix4::zeros();
        m.fixed_view_mut::<3, 3>(0, 0).copy_from(&So3::hat(&theta));
        m.fixed_view_mut::<3, 1>(0, 3).copy_from(&rho);
        m
    }

    /// `vee`: se(3) → ℝ⁶, the inverse of [`Se3::hat`] (reads the skew part of the rotation block).
    pub fn vee(m: &Matrix4<f64>) -> Vector6<f64> {
        let theta = So3::vee(&m.fixed_view::<3, 3>(0, 0).into_owned());
        Vector6::new(m[(0, 3)], m[(1, 3)], m[(2, 3)], theta.x, theta.y, theta.z)
    }

    /// Group composition `self · other` (apply `other` first): `(R₁R₂, R₁t₂ + t₁)`.
    pub fn compose(&self, other: &Se3) -> Se3 {
        Self::new(
            self.rotation.compose(&other.rotation),
            self.rotation.act(&other.translation) + self.translation,
        )
    }

    /// Group inverse `(Rᵀ, −Rᵀt)`.
    pub fn inverse(&self) -> Se3 {
        let r_inv = self.rotation.inverse();
        Self::new(r_inv, -r_inv.act(&self.translation))
    }

    /// Group action on a point: `R·p + t`.
    pub fn act(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.rotation.act(p) + self.translation
    }

    /// Same as [`Se3::act`] (Sophus/nalgebra naming).
    pub fn transform_point(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.act(p)
    }

    /// Adjoint for `[ρ, θ]` ordering: `Ad_T = [[R, [t]×R], [0, R]]`, so that
    /// `T·exp(τ)·T⁻¹ = exp(Ad_T·τ)`.
    pub fn adjoint(&self) -> Matrix6<f64> {
        let r = self.rotation.matrix();
        block_upper(&r, &(So3::hat(&self.translation) * r))
    }

    /// Left Jacobian `Jl(τ) = [[Jl(θ), Q(ρ, θ)], [0, Jl(θ)]]` (Solà et al. 2018, App. D):
    /// `exp(τ + δ) ≈ exp(Jl(τ)·δ)·exp(τ)`.
    pub fn jl(tau: &Vector6<f64>) -> Matrix6<f64> {
        let (rho, theta) = split(tau);
        block_upper(&So3::jl(&theta), &q_matrix(&rho, &theta))
    }

    /// Right Jacobian `Jr(τ) = Jl(−τ)`: `exp(τ + δ) ≈ exp(τ)·exp(Jr(τ)·δ)`.
    pub fn jr(tau: &Vector6<f64>) -> Matrix6<f64> {
        Self::jl(&-tau)
    }

    /// Inverse left Jacobian `[[Jl⁻¹, −Jl⁻¹·Q·Jl⁻¹], [0, Jl⁻¹]]`:
    /// `log(exp(δ)·exp(τ)) ≈ τ + Jl⁻¹(τ)·δ`. Finite for |θ| < 2π.
    pub fn jl_inv(tau: &Vector6<f64>) -> Matrix6<f64> {
        let (rho, theta) = split(tau);
        let ji = So3::jl_inv(&theta);
        block_upper(&ji, &(-ji * q_matrix(&rho, &theta) * ji))
    }

    /// Inverse right Jacobian `Jr⁻¹(τ) = Jl⁻¹(−τ)`: `log(exp(τ)·exp(δ)) ≈ τ + Jr⁻¹(τ)·δ`.
    pub fn jr_inv(tau: &Vector6<f64>) -> Matrix6<f64> {
        Self::jl_inv(&-tau)
    }

    /// The 4×4 homogeneous matrix `[[R, t], [0, 1]]`.
    pub fn matrix(&self) -> Matrix4<f64> {
        let mut m = Matrix4::identity();
        m.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&self.rotation.matrix());
        m.fixed_view_mut::<3, 1>(0, 3).copy_from(&self.translation);
        m
    }

    /// From a 4×4 homogeneous matrix; the rotation block is re-orthonormalised
    /// ([`So3::from_matrix`]). Errors on non-finite entries or a bottom row other than
    /// `[0, 0, 0, 1]` (within 10⁻⁶).
    pub fn from_matrix(m: &Matrix4<f64>) -> CoreResult<Se3> {
        if m.iter().any(|v| !v.is_finite()) {
            return Err(CoreError::param("pose", "matrix has non-finite entries"));
        }
        let bottom = [m[(3, 0)], m[(3, 1)], m[(3, 2)], m[(3, 3)] - 1.0];
        if bottom.iter().any(|v| v.abs() > HOMOGENEOUS_ROW_TOLERANCE) {
            return Err(CoreError::param(
                "pose",
                "bottom row of a homogeneous transform must be [0, 0, 0, 1]",
            ));
        }
        let rotation = So3::from_matrix(&m.fixed_view::<3, 3>(0, 0).into_owned())?;
        Ok(Self::new(rotation, m.fixed_view::<3, 1>(0, 3).into_owned()))
    }

    /// From OpenCV extrinsics (`rvec`, `tvec`): `X_cam = R(rvec)·X_world + tvec`.
    pub fn from_rvec_tvec(rvec: &Vector3<f64>, tvec: &Vector3<f64>) -> Se3 {
        Self::new(So3::from_rotation_vector(rvec), *tvec)
    }

    /// To OpenCV extrinsics (`rvec`, `tvec`), rotation angle in `[0, π]`.
    pub fn to_rvec_tvec(&self) -> (Vector3<f64>, Vector3<f64>) {
        (self.rotation.to_rotation_vector(), self.translation)
    }

    /// Jacobian of `act(p)` with respect to the point: `R`.
    pub fn act_jacobian_point(&self, _p: &Vector3<f64>) -> Matrix3<f64> {
        self.rotation.matrix()
    }

    /// Jacobian of `act(p)` with respect to a **right** perturbation `T·exp(δ)`, δ = [ρ, θ],
    /// at δ = 0: `[R, −R·[p]×]`.
    pub fn act_jacobian_right(&self, p: &Vector3<f64>) -> Matrix3x6<f64> {
        let r = self.rotation.matrix();
        let mut j = Matrix3x6::zeros();
        j.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
        j.fixed_view_mut::<3, 3>(0, 3)
            .copy_from(&(-r * So3::hat(p)));
        j
    }

    /// Jacobian of `act(p)` with respect to a **left** perturbation `exp(δ)·T`, δ = [ρ, θ],
    /// at δ = 0: `[I, −[T·p]×]`. This is the one to use with the optimiser update
    /// `T ← exp(δ)·T` ([`Se3::left_plus`]).
    pub fn act_jacobian_left(&self, p: &Vector3<f64>) -> Matrix3x6<f64> {
        let q = self.act(p);
        let mut j = Matrix3x6::zeros();
        j.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&Matrix3::identity());
        j.fixed_view_mut::<3, 3>(0, 3).copy_from(&-So3::hat(&q));
        j
    }

    /// Left update `exp(δ)·self`, the update used by Caliper's optimisers.
    pub fn left_plus(&self, delta: &Vector6<f64>) -> Se3 {
        Self::exp(delta).compose(self)
    }

    /// Right update `self·exp(δ)`.
    pub fn right_plus(&self, delta: &Vector6<f64>) -> Se3 {
        self.compose(&Self::exp(delta))
    }

    /// Left difference `log(self·other⁻¹)`, the inverse of [`Se3::left_plus`].
    pub fn left_minus(&self, other: &Se3) -> Vector6<f64> {
        self.compose(&other.inverse()).log()
    }

    /// Right difference `log(other⁻¹·self)`, the inverse of [`Se3::right_plus`].
    pub fn right_minus(&self, other: &Se3) -> Vector6<f64> {
        other.inverse().compose(self).log()
    }
}

impl Mul for Se3 {
    type Output = Se3;
    fn mul(self, rhs: Se3) -> Se3 {
        self.compose(&rhs)
    }
}

impl Mul<&Se3> for &Se3 {
    type Output = Se3;
    fn mul(self, rhs: &Se3) -> Se3 {
        self.compose(rhs)
    }
}

impl Mul<Vector3<f64>> for Se3 {
    type Output = Vector3<f64>;
    fn mul(self, rhs: Vector3<f64>) -> Vector3<f64> {
        self.act(&rhs)
    }
}

#[cfg(feature = "schema")]
impl utoipa::PartialSchema for Se3 {
    fn schema() -> utoipa::openapi::RefOr<utoipa::openapi::schema::Schema> {
        use utoipa::openapi::schema::{ArrayBuilder, ObjectBuilder, Type};
        use utoipa::openapi::{KnownFormat, SchemaFormat};
        let number = || {
            ObjectBuilder::new()
                .schema_type(Type::Number)
                .format(Some(SchemaFormat::KnownFormat(KnownFormat::Double)))
        };
        ObjectBuilder::new()
            .property("rotation", <So3 as utoipa::PartialSchema>::schema())
            .required("rotation")
            .property(
                "translation",
                ArrayBuilder::new()
                    .items(number())
                    .min_items(Some(3))
                    .max_items(Some(3)),
            )
            .required("translation")
            .description(Some(
                "Rigid motion X ↦ R·X + t; rotation as unit quaternion [w, x, y, z].",
            ))
            .into()
    }
}

#[cfg(feature = "schema")]
impl utoipa::ToSchema for Se3 {
    fn name() -> std::borrow::Cow<'static, str> {
        std::borrow::Cow::Borrowed("Se3")
    }
}
