//! Lie groups SO(3) (rotations) and SE(3) (rigid motions) for pose estimation.
//!
//! Every pose in every Caliper optimiser lives on one of these manifolds. The conventions follow
//! Solà, Deray, Atchuthan, "A micro Lie theory for state estimation in robotics" (2018,
//! arXiv:1812.01537), with Sophus and manif as API models:
//!
//! * Rotations are stored as unit quaternions ([`So3`]), renormalised after every composition so
//!   that round-off never accumulates into a non-rotation.
//! * Tangent vectors: so(3) is the rotation vector θ (axis · angle, the same as OpenCV's `rvec`);
//!   se(3) is the 6-vector `[ρ, θ]`, **translation part first** (Solà's ordering).
//! * `exp`/`log` map between the tangent space at the identity and the group; `log` returns angles
//!   in `[0, π]`, is exact near θ = 0 (Taylor series) and stable near θ = π (half-angle `atan2`).
//! * Right and left Jacobians (`jr`, `jl`) and their inverses give first-order perturbations:
//!   `exp(τ + δ) ≈ exp(τ)·exp(Jr(τ)·δ) ≈ exp(Jl(τ)·δ)·exp(τ)` and
//!   `log(exp(τ)·exp(δ)) ≈ τ + Jr⁻¹(τ)·δ`, `log(exp(δ)·exp(τ)) ≈ τ + Jl⁻¹(τ)·δ`.
//! * Optimisers update on the manifold with the **left** update `T ← exp(δ)·T`
//!   ([`Se3::left_plus`]); the matching point Jacobian is [`Se3::act_jacobian_left`].
//!   Right-perturbation Jacobians are provided as well for callers that prefer `T ← T·exp(δ)`.

mod se3;
mod so3;

#[cfg(test)]
mod tests;

pub use se3::Se3;
pub use so3::So3;

/// Below this angle (radians) the closed-form Jacobian coefficients are replaced by their Taylor
/// series. The closed forms lose about `ε/θ²` relative precision to cancellation, the truncated
/// series (kept to θ⁴) about `θ⁶/5040`, so 10⁻² keeps both below 10⁻¹¹.
const SMALL_ANGLE: f64 = 1e-2;

/// Below this angle the `exp`/`log` ratios `sin(θ/2)/θ` and `atan2(n, w)/n` switch to Taylor
/// series; they have no cancellation, the switch only avoids `0/0`.
const TINY_ANGLE: f64 = 1e-6;

/// Coefficient `(1 − cos θ)/θ²` of `[θ]×` in the SO(3) Jacobians, computed as `2 sin²(θ/2)/θ²`
/// which has no cancellation at small angles.
fn coeff_a(t: f64) -> f64 {
    if t < TINY_ANGLE {
        let t2 = t * t;
        0.5 - t2 / 24.0
    } else {
        let h = 0.5 * t;
        let s = h.sin() / h;
        0.5 * s * s
    }
}

/// Coefficient `(θ − sin θ)/θ³` of `[θ]×²` in the SO(3) Jacobians.
fn coeff_b(t: f64) -> f64 {
    let t2 = t * t;
    if t < SMALL_ANGLE {
        1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0
    } else {
        (t - t.sin()) / (t2 * t)
    }
}

/// Coefficient `1/θ² − (1 + cos θ)/(2θ sin θ)` of `[θ]×²` in the inverse SO(3) Jacobians,
/// evaluated as `1/θ² − cot(θ/2)/(2θ)` which stays finite at θ = π (it is singular only at 2π).
fn coeff_c(t: f64) -> f64 {
    let t2 = t * t;
    if t < SMALL_ANGLE {
        1.0 / 12.0 + t2 / 720.0 + t2 * t2 / 30240.0
    } else {
        let h = 0.5 * t;
        1.0 / t2 - h.cos() / (2.0 * t * h.sin())
    }
}

/// Threshold for the SE(3) `Q` coefficients, whose closed forms cancel like `ε/θ⁴`; their series
/// are kept to θ⁶ so the truncation error at 0.1 is below 10⁻¹⁶.
const SMALL_ANGLE_Q: f64 = 0.1;

/// Coefficient `(θ² + 2 cos θ − 2)/(2θ⁴)` of the SE(3) `Q` matrix.
fn coeff_q2(t: f64) -> f64 {
    let t2 = t * t;
    if t < SMALL_ANGLE_Q {
        1.0 / 24.0 - t2 / 720.0 + t2 * t2 / 40320.0 - t2 * t2 * t2 / 3_628_800.0
    } else {
        (t2 + 2.0 * t.cos() - 2.0) / (2.0 * t2 * t2)
    }
}

/// Coefficient `(2θ − 3 sin θ + θ cos θ)/(2θ⁵)` of the SE(3) `Q` matrix.
fn coeff_q3(t: f64) -> f64 {
    let t2 = t * t;
    if t < SMALL_ANGLE_Q {
        1.0 / 120.0 - t2 / 2520.0 + t2 * t2 / 120_960.0 - t2 * t2 * t2 / 9_979_200.0
    } else {
        (2.0 * t - 3.0 * t.sin() + t * t.cos()) / (2.0 * t2 * t2 * t)
    }
}
