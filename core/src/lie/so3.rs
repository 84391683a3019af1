//! SO(3), the group of 3-D rotations, stored as a unit quaternion.

use std::fmt;
use std::ops::Mul;

use nalgebra::{Matrix3, Quaternion, Rotation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Deserializer, Serialize, Serializer};

use super::{TINY_ANGLE, coeff_a, coeff_b, coeff_c};
use crate::error::{CoreError, CoreResult};

/// How far from unit norm a quaternion read from a document may be before it is rejected rather
/// than renormalised. Documents written by Caliper are unit to ~10⁻¹⁶; hand-typed values with four
/// decimals stay within 10⁻³.
const QUATERNION_NORM_TOLERANCE: f64 = 1e-3;

/// A rotation in 3-D, an element of the Lie group SO(3).
///
/// Stored as a unit quaternion (Hamilton convention, active rotation: `act(p) = q p q*`). The
/// tangent space is so(3) ≅ ℝ³ with the rotation vector θ = angle · axis; `exp`/`log` follow
/// Solà et al. (2018), Appendix B, in its unit-quaternion form.
///
/// Serialised as the quaternion `[w, x, y, z]`.
///
/// `PartialEq` compares the stored quaternions, so `q` and `−q` (the same rotation) compare
/// unequal; compare [`So3::matrix`] or use [`So3::left_minus`] for geometric equality.
#[derive(Clone, Copy, PartialEq)]
pub struct So3 {
    q: UnitQuaternion<f64>,
}

impl fmt::Debug for So3 {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let q = self.q.quaternion();
        write!(f, "So3(w={}, x={}, y={}, z={})", q.w, q.i, q.j, q.k)
    }
}

impl Default for So3 {
    fn default() -> Self {
        Self::identity()
    }
}

impl So3 {
    /// The identity rotation.
    pub fn identity() -> Self {
        Self {
            q: UnitQuaternion::identity(),
        }
    }

    /// Wraps a unit quaternion (renormalised, so accumulated drift is removed).
    pub fn from_quaternion(q: UnitQuaternion<f64>) -> Self {
        Self {
            q: UnitQuaternion::new_normalize(q.into_inner()),
        }
    }

    /// Builds a rotation from quaternion components `[w, x, y, z]`, renormalising them.
    ///
    /// Errors when a component is not finite or the norm is more than 10⁻³ away from 1: such a
    /// quaternion is a typo, not a rotation, and silently normalising it would hide that.
    pub fn from_wxyz(wxyz: [f64; 4]) -> CoreResult<Self> {
        let q = Quaternion::new(wxyz[0], wxyz[1], wxyz[2], wxyz[3]);
        let norm = q.norm();
        if !norm.is_finite() {
            return Err(CoreError::param(
                "rotation",
                "quaternion has non-finite components",
            ));
        }
        if (norm - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
            return Err(CoreError::param(
                "rotation",
                format!("quaternion norm {norm} is not 1"),
            ));
        }
        Ok(Self {
            q: UnitQuaternion::new_normalize(q),
        })
    }

    /// The quaternion components `[w, x, y, z]`.
    pub fn to_wxyz(&self) -> [f64; 4] {
        let q = self.q.quaternion();
        [q.w, q.i, q.j, q.k]
    }

    /// The underlying unit quaternion.
    pub fn quaternion(&self) -> &UnitQuaternion<f64> {
        &self.q
    }

    /// Exponential map so(3) → SO(3): the rotation by `|θ|` about `θ/|θ|`.
    ///
    /// `q = [cos(|θ|/2), sin(|θ|/2)·θ/|θ|]`; the ratio `sin(|θ|/2)/|θ|` uses its Taylor series
    /// near 0 so that tiny rotations are exact.
    pub fn exp(theta: &Vector3<f64>) -> Self {
        let t2 = theta.norm_squared();
        let t = t2.sqrt();
        let (w, s) = if t < TINY_ANGLE {
            (1.0 - t2 / 8.0 + t2 * t2 / 384.0, 0.5 - t2 / 48.0)
        } else {
            let h = 0.5 * t;
            (h.cos(), h.sin() / t)
        };
        let q = Quaternion::new(w, s * theta.x, s * theta.y, s * theta.z);
        Self {
            q: UnitQuaternion::new_normalize(q),
        }
    }

    /// Logarithmic map SO(3) → so(3): the rotation vector with angle in `[0, π]`.
    ///
    /// The quaternion is first brought to `w ≥ 0` (q and −q are the same rotation), then
    /// θ = 2·atan2(|v|, w). Using `atan2` of the half-angle sine and cosine keeps full precision
    /// both near 0 (where `acos` of the trace loses half the digits) and near π (where the axis
    /// from the skew part of R vanishes). Near 0 the ratio `2·atan2(n, w)/n` uses its series.
    pub fn log(&self) -> Vector3<f64> {
        let q = self.q.quaternion();
        let (w, v) = if q.w < 0.0 {
            (-q.w, -q.imag())
        } else {
            (q.w, q.imag())
        };
        let n = v.norm();
        let scale = if n < TINY_ANGLE {
            // atan(n/w)/n = (1/w)(1 − n²/(3w²) + …); w ≈ 1 here.
            2.0 / w * (1.0 - n * n / (3.0 * w * w))
        } else {
            2.0 * n.atan2(w) / n
        };
        v * scale
    }

    /// The rotation angle in `[0, π]`.
    pub fn angle(&self) -> f64 {
        let q = self.q.quaternion();
        2.0 * q.imag().norm().atan2(q.w.abs())
    }

    /// `hat`: ℝ³ → so(3), the skew-symmetric matrix `[θ]×` with `[θ]× p = θ × p`.
    pub fn hat(theta: &Vector3<f64>) -> Matrix3<f64> {
        Matrix3::new(
            0.0, -theta.z, theta.y, //
            theta.z, 0.0, -theta.x, //
            -theta.y, theta.x, 0.0,
        )
    }

    /// `vee`: so(3) → ℝ³, the inverse of [`So3::hat`]. Reads the skew-symmetric part
    /// `(M − Mᵀ)/2`, so a slightly non-skew input gives the nearest tangent vector.
    pub fn vee(m: &Matrix3<f64>) -> Vector3<f64> {
        Vector3::new(
            0.5 * (m[(2, 1)] - m[(1, 2)]),
            0.5 * (m[(0, 2)] - m[(2, 0)]),
            0.5 * (m[(1, 0)] - m[(0, 1)]),
        )
    }

    /// Group composition `self · other` (apply `other` first), renormalised.
    pub fn compose(&self, other: &So3) -> So3 {
        Self {
            q: UnitQuaternion::new_normalize(self.q.quaternion() * other.q.quaternion()),
        }
    }

    /// Group inverse (the conjugate quaternion).
    pub fn inverse(&self) -> So3 {
        Self {
            q: self.q.inverse(),
        }
    }

    /// Group action on a point: `R·p`.
    pub fn act(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.q.transform_vector(p)
    }

    /// Same as [`So3::act`] (Sophus/nalgebra naming).
    pub fn transform_point(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.act(p)
    }

    /// Adjoint `Ad_R = R`: `R·exp(θ)·R⁻¹ = exp(R·θ)`.
    pub fn adjoint(&self) -> Matrix3<f64> {
        self.matrix()
    }

    /// Right Jacobian `Jr(θ) = I − (1−cos θ)/θ² [θ]× + (θ−sin θ)/θ³ [θ]×²` (Solà et al. 2018, App. B):
    /// `exp(θ + δ) ≈ exp(θ)·exp(Jr(θ)·δ)`.
    pub fn jr(theta: &Vector3<f64>) -> Matrix3<f64> {
        let t = theta.norm();
        let k = Self::hat(theta);
        Matrix3::identity() - k * coeff_a(t) + k * k * coeff_b(t)
    }

    /// Left Jacobian `Jl(θ) = Jr(−θ) = Jr(θ)ᵀ` (Solà et al. 2018, App. B):
    /// `exp(θ + δ) ≈ exp(Jl(θ)·δ)·exp(θ)`.
    pub fn jl(theta: &Vector3<f64>) -> Matrix3<f64> {
        let t = theta.norm();
        let k = Self::hat(theta);
        Matrix3::identity() + k * coeff_a(t) + k * k * coeff_b(t)
    }

    /// Inverse right Jacobian `Jr⁻¹(θ) = I + ½[θ]× + (1/θ² − (1+cos θ)/(2θ sin θ)) [θ]×²`
    /// (Solà et al. 2018, App. B): `log(exp(θ)·exp(δ)) ≈ θ + Jr⁻¹(θ)·δ`. Finite for |θ| < 2π.
    pub fn jr_inv(theta: &Vector3<f64>) -> Matrix3<f64> {
        let t = theta.norm();
        let k = Self::hat(theta);
        Matrix3::identity() + k * 0.5 + k * k * coeff_c(t)
    }

    /// Inverse left Jacobian `Jl⁻¹(θ) = Jr⁻¹(θ)ᵀ` (Solà et al. 2018, App. B):
    /// `log(exp(δ)·exp(θ)) ≈ θ + Jl⁻¹(θ)·δ`.
    pub fn jl_inv(theta: &Vector3<f64>) -> Matrix3<f64> {
        let t = theta.norm();
        let k = Self::hat(theta);
        Matrix3::identity() - k * 0.5 + k * k * coeff_c(t)
    }

    /// The 3×3 rotation matrix.
    pub fn matrix(&self) -> Matrix3<f64> {
        self.q.to_rotation_matrix().into_inner()
    }

    /// The rotation nearest (in Frobenius norm) to `m`, found by SVD: `R = U·diag(1, 1, det(UVᵀ))·Vᵀ`.
    ///
    /// This re-orthonormalises matrices that drifted or were printed with few digits. Errors
    /// when `m` has non-finite entries or `det(m) ≤ 0` (a reflection or a singular matrix is not
    /// a noisy rotation, and the "nearest rotation" to it would be arbitrary).
    pub fn from_matrix(m: &Matrix3<f64>) -> CoreResult<So3> {
        if m.iter().any(|v| !v.is_finite()) {
            return Err(CoreError::param(
                "rotation",
                "matrix has non-finite entries",
            ));
        }
        let det = m.determinant();
        if det <= 0.0 {
            return Err(CoreError::param(
                "rotation",
                format!("matrix determinant {det} is not positive; not a rotation"),
            ));
        }
        let svd = m.svd(true, true);
        let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
            return Err(CoreError::param("rotation", "SVD of the matrix failed"));
        };
        let mut d = Matrix3::identity();
        if (u * v_t).determinant() < 0.0 {
            d[(2, 2)] = -1.0;
        }
        let r = u * d * v_t;
        let rot = Rotation3::from_matrix_unchecked(r);
        Ok(Self::from_quaternion(UnitQuaternion::from_rotation_matrix(
            &rot,
        )))
    }

    /// From a Rodrigues rotation vector (OpenCV `rvec`: axis · angle in radians). Same as
    /// [`So3::exp`].
    pub fn from_rotation_vector(rvec: &Vector3<f64>) -> So3 {
        Self::exp(rvec)
    }

    /// To a Rodrigues rotation vector (OpenCV `rvec`), angle in `[0, π]`. Same as [`So3::log`].
    pub fn to_rotation_vector(&self) -> Vector3<f64> {
        self.log()
    }

    /// Jacobian of `act(p) = R·p` with respect to the point: `R`.
    pub fn act_jacobian_point(&self, _p: &Vector3<f64>) -> Matrix3<f64> {
        self.matrix()
    }

    /// Jacobian of `act(p)` with respect to a **right** perturbation `R·exp(δ)` at δ = 0:
    /// `∂(R·exp(δ)·p)/∂δ = −R·[p]×`.
    pub fn act_jacobian_right(&self, p: &Vector3<f64>) -> Matrix3<f64> {
        -self.matrix() * Self::hat(p)
    }

    /// Jacobian of `act(p)` with respect to a **left** perturbation `exp(δ)·R` at δ = 0:
    /// `∂(exp(δ)·R·p)/∂δ = −[R·p]×`. Matches the optimiser update `R ← exp(δ)·R`.
    pub fn act_jacobian_left(&self, p: &Vector3<f64>) -> Matrix3<f64> {
        -Self::hat(&self.act(p))
    }

    /// Left update `exp(δ)·self` (Solà's `δ ⊕ X`), the update used by Caliper's optimisers.
    pub fn left_plus(&self, delta: &Vector3<f64>) -> So3 {
        Self::exp(delta).compose(self)
    }

    /// Right update `self·exp(δ)` (Solà's `X ⊕ δ`).
    pub fn right_plus(&self, delta: &Vector3<f64>) -> So3 {
        self.compose(&Self::exp(delta))
    }

    /// Left difference `log(self·other⁻¹)`, the inverse of [`So3::left_plus`].
    pub fn left_minus(&self, other: &So3) -> Vector3<f64> {
        self.compose(&other.inverse()).log()
    }

    /// Right difference `log(other⁻¹·self)`, the inverse of [`So3::right_plus`].
    pub fn right_minus(&self, other: &So3) -> Vector3<f64> {
        other.inverse().compose(self).log()
    }
}

impl Mul for So3 {
    type Output = So3;
    fn mul(self, rhs: So3) -> So3 {
        self.compose(&rhs)
    }
}

impl Mul<&So3> for &So3 {
    type Output = So3;
    fn mul(self, rhs: &So3) -> So3 {
        self.compose(rhs)
    }
}

impl Mul<Vector3<f64>> for So3 {
    type Output = Vector3<f64>;
    fn mul(self, rhs: Vector3<f64>) -> Vector3<f64> {
        self.act(&rhs)
    }
}

impl Serialize for So3 {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        self.to_wxyz().serialize(serializer)
    }
}

impl<'de> Deserialize<'de> for So3 {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        let wxyz = <[f64; 4]>::deserialize(deserializer)?;
        So3::from_wxyz(wxyz).map_err(serde::de::Error::custom)
    }
}

#[cfg(feature = "schema")]
impl utoipa::PartialSchema for So3 {
    fn schema() -> utoipa::openapi::RefOr<utoipa::openapi::schema::Schema> {
        utoipa::openapi::schema::ArrayBuilder::new()
            .items(
                utoipa::openapi::ObjectBuilder::new()
                    .schema_type(utoipa::openapi::schema::Type::Number)
                    .format(Some(utoipa::openapi::SchemaFormat::KnownFormat(
                        utoipa::openapi::KnownFormat::Double,
                    ))),
            )
            .min_items(Some(4))
            .max_items(Some(4))
            .description(Some(
                "Unit quaternion [w, x, y, z] (Hamilton, active rotation).",
            ))
            .into()
    }
}

#[cfg(feature = "schema")]
impl utoipa::ToSchema for So3 {
    fn name() -> std::borrow::Cow<'static, str> {
        std::borrow::Cow::Borrowed("So3")
    }
}
