//! Property tests of the group axioms, exp/log and every Jacobian against central finite
//! differences, with angles drawn near 0 and near π where closed forms break down.

use std::f64::consts::PI;

use nalgebra::{Matrix3, Matrix4, SMatrix, SVector, Vector3, Vector6};
use proptest::prelude::*;

use super::*;

const CASES: u32 = 256;
const FD_STEP: f64 = 1e-6;

/// Central-difference Jacobian of `f` at `x`.
fn num_jac<const M: usize, const N: usize>(
    f: impl Fn(&SVector<f64, N>) -> SVector<f64, M>,
    x: &SVector<f64, N>,
) -> SMatrix<f64, M, N> {
    let mut j = SMatrix::<f64, M, N>::zeros();
    for k in 0..N {
        let mut xp = *x;
        let mut xm = *x;
        xp[k] += FD_STEP;
        xm[k] -= FD_STEP;
        j.set_column(k, &((f(&xp) - f(&xm)) / (2.0 * FD_STEP)));
    }
    j
}

fn assert_close<const M: usize, const N: usize>(
    a: &SMatrix<f64, M, N>,
    b: &SMatrix<f64, M, N>,
    tol: f64,
    what: &str,
) -> Result<(), TestCaseError> {
    let err = (a - b).abs().max();
    prop_assert!(err <= tol, "{what}: max error {err:e} > {tol:e}\n{a}\n{b}");
    Ok(())
}

/// Angles in [0, π): uniform, tiny (10⁻⁹…10⁻⁵), exactly 0, and within 10⁻⁹…10⁻⁶ of π.
fn angle() -> impl Strategy<Value = f64> {
    prop_oneof![
        4 => 0.0..PI,
        2 => (-9.0f64..-5.0).prop_map(|e| 10f64.powf(e)),
        1 => Just(0.0),
        2 => (-9.0f64..-6.0).prop_map(|e| PI - 10f64.powf(e)),
    ]
}

/// Angles where the inverse Jacobians are tested against finite differences of `log`, which
/// wraps at π.
fn angle_below_pi() -> impl Strategy<Value = f64> {
    prop_oneof![
        3 => 0.0..(PI - 0.1),
        1 => (-9.0f64..-5.0).prop_map(|e| 10f64.powf(e)),
        1 => Just(PI - 0.1),
    ]
}

fn axis() -> impl Strategy<Value = Vector3<f64>> {
    (-1.0f64..1.0, -1.0f64..1.0, -1.0f64..1.0)
        .prop_map(|(x, y, z)| Vector3::new(x, y, z))
        .prop_filter("axis too short", |v| v.norm() > 0.1)
        .prop_map(|v| v.normalize())
}

fn so3_tangent() -> impl Strategy<Value = Vector3<f64>> {
    (axis(), angle()).prop_map(|(a, t)| a * t)
}

fn so3_tangent_below_pi() -> impl Strategy<Value = Vector3<f64>> {
    (axis(), angle_below_pi()).prop_map(|(a, t)| a * t)
}

fn so3() -> impl Strategy<Value = So3> {
    so3_tangent().prop_map(|v| So3::exp(&v))
}

fn vec3(scale: f64) -> impl Strategy<Value = Vector3<f64>> {
    (-scale..scale, -scale..scale, -scale..scale).prop_map(|(x, y, z)| Vector3::new(x, y, z))
}

fn join(rho: &Vector3<f64>, theta: &Vector3<f64>) -> Vector6<f64> {
    Vector6::new(rho.x, rho.y, rho.z, theta.x, theta.y, theta.z)
}

fn se3_tangent() -> impl Strategy<Value = Vector6<f64>> {
    (vec3(5.0), so3_tangent()).prop_map(|(r, t)| join(&r, &t))
}

fn se3_tangent_below_pi() -> impl Strategy<Value = Vector6<f64>> {
    (vec3(5.0), so3_tangent_below_pi()).prop_map(|(r, t)| join(&r, &t))
}

fn se3() -> impl Strategy<Value = Se3> {
    (so3(), vec3(10.0)).prop_map(|(r, t)| Se3::new(r, t))
}

fn is_rotation(r: &So3) -> Result<(), TestCaseError> {
    let q = r.quaternion().quaternion().norm();
    prop_assert!((q - 1.0).abs() < 1e-14, "quaternion norm {q}");
    let m = r.matrix();
    assert_close(&(m.transpose() * m), &Matrix3::identity(), 1e-14, "RᵀR")?;
    prop_assert!((m.determinant() - 1.0).abs() < 1e-14);
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(CASES))]

    // ---------------------------------------------------------------- SO(3) group axioms

    #[test]
    fn so3_closure(a in so3(), b in so3()) {
        is_rotation(&(a * b))?;
        is_rotation(&a.inverse())?;
    }

    #[test]
    fn so3_associativity(a in so3(), b in so3(), c in so3()) {
        assert_close(&((a * b) * c).matrix(), &(a * (b * c)).matrix(), 1e-14, "assoc")?;
    }

    #[test]
    fn so3_identity_and_inverse(a in so3()) {
        let e = So3::identity();
        assert_close(&(a * e).matrix(), &a.matrix(), 1e-15, "a·e")?;
        assert_close(&(e * a).matrix(), &a.matrix(), 1e-15, "e·a")?;
        assert_close(&(a * a.inverse()).matrix(), &Matrix3::identity(), 1e-14, "a·a⁻¹")?;
        assert_close(&(a.inverse() * a).matrix(), &Matrix3::identity(), 1e-14, "a⁻¹·a")?;
    }

    #[test]
    fn so3_exp_log(v in so3_tangent(), a in so3()) {
        // exp∘log = id on the group (compare matrices: q and −q are the same rotation).
        assert_close(&So3::exp(&a.log()).matrix(), &a.matrix(), 1e-14, "exp(log X)")?;
        // log∘exp = id on |θ| < π.
        let back = So3::exp(&v).log();
        assert_close(&back, &v, 1e-15 + 1e-12 * v.norm(), "log(exp v)")?;
        prop_assert!((So3::exp(&v).angle() - v.norm()).abs() < 1e-12);
    }

    #[test]
    fn so3_hat_vee(v in vec3(4.0), p in vec3(4.0)) {
        assert_close(&So3::vee(&So3::hat(&v)), &v, 0.0, "vee(hat v)")?;
        assert_close(&(So3::hat(&v) * p), &v.cross(&p), 1e-14, "hat is cross")?;
    }

    #[test]
    fn so3_adjoint(a in so3(), v in so3_tangent()) {
        let lhs = a * So3::exp(&v) * a.inverse();
        let rhs = So3::exp(&(a.adjoint() * v));
        assert_close(&lhs.matrix(), &rhs.matrix(), 1e-13, "X·exp(v)·X⁻¹")?;
    }

    #[test]
    fn so3_rodrigues_matches_matrix(v in so3_tangent(), p in vec3(3.0)) {
        // Rodrigues' formula R = I + sin θ K + (1 − cos θ) K², K the unit-axis hat.
        let t = v.norm();
        let r = So3::from_rotation_vector(&v);
        let expected = if t > 0.0 {
            let k = So3::hat(&(v / t));
            Matrix3::identity() + k * t.sin() + k * k * (1.0 - t.cos())
        } else {
            Matrix3::identity()
        };
        assert_close(&r.matrix(), &expected, 1e-14, "Rodrigues")?;
        assert_close(&r.act(&p), &(expected * p), 1e-13, "act")?;
        assert_close(&(r * p), &r.transform_point(&p), 0.0, "Mul<Vector3>")?;
    }

    #[test]
    fn so3_from_matrix_roundtrip(a in so3(), noise in vec3(1e-6)) {
        let back = So3::from_matrix(&a.matrix()).map_err(|e| TestCaseError::fail(e.to_string()))?;
        assert_close(&back.matrix(), &a.matrix(), 1e-14, "from_matrix")?;
        // A slightly perturbed (non-orthogonal) matrix is projected back onto SO(3).
        let noisy = a.matrix() + Matrix3::from_diagonal(&noise);
        let fixed = So3::from_matrix(&noisy).map_err(|e| TestCaseError::fail(e.to_string()))?;
        is_rotation(&fixed)?;
        assert_close(&fixed.matrix(), &a.matrix(), 1e-5, "re-orthonormalised")?;
    }

    #[test]
    fn so3_serde_roundtrip(a in so3()) {
        let json = serde_json::to_string(&a).map_err(|e| TestCaseError::fail(e.to_string()))?;
        let back: So3 = serde_json::from_str(&json).map_err(|e| TestCaseError::fail(e.to_string()))?;
        assert_close(&back.matrix(), &a.matrix(), 1e-14, "serde")?;
    }

    // ---------------------------------------------------------------- SO(3) Jacobians

    #[test]
    fn so3_jr_jl_finite_differences(v in so3_tangent()) {
        let x_inv = So3::exp(&v).inverse();
        let x = So3::exp(&v);
        // exp(v + δ) = exp(v)·exp(Jr δ) ⇒ Jr = ∂ log(exp(v)⁻¹ exp(v+δ)) / ∂δ.
        let jr = num_jac(|d: &Vector3<f64>| (x_inv * So3::exp(&(v + d))).log(), &Vector3::zeros());
        assert_close(&So3::jr(&v), &jr, 1e-8, "Jr")?;
        let jl = num_jac(|d: &Vector3<f64>| (So3::exp(&(v + d)) * x_inv).log(), &Vector3::zeros());
        assert_close(&So3::jl(&v), &jl, 1e-8, "Jl")?;
        prop_assert!((So3::jl(&v) - So3::jr(&v).transpose()).abs().max() < 1e-15);
        let _ = x;
    }

    #[test]
    fn so3_inverse_jacobians_are_inverses(v in so3_tangent()) {
        assert_close(&(So3::jr_inv(&v) * So3::jr(&v)), &Matrix3::identity(), 1e-12, "Jr⁻¹Jr")?;
        assert_close(&(So3::jl_inv(&v) * So3::jl(&v)), &Matrix3::identity(), 1e-12, "Jl⁻¹Jl")?;
    }

    #[test]
    fn so3_inverse_jacobians_finite_differences(v in so3_tangent_below_pi()) {
        let x = So3::exp(&v);
        // log(exp(v)·exp(δ)) ≈ v + Jr⁻¹ δ and log(exp(δ)·exp(v)) ≈ v + Jl⁻¹ δ.
        let jri = num_jac(|d: &Vector3<f64>| (x * So3::exp(d)).log(), &Vector3::zeros());
        assert_close(&So3::jr_inv(&v), &jri, 1e-8, "Jr⁻¹")?;
        let jli = num_jac(|d: &Vector3<f64>| (So3::exp(d) * x).log(), &Vector3::zeros());
        assert_close(&So3::jl_inv(&v), &jli, 1e-8, "Jl⁻¹")?;
    }

    #[test]
    fn so3_act_jacobians(a in so3(), p in vec3(5.0)) {
        let jp = num_jac(|q: &Vector3<f64>| a.act(q), &p);
        assert_close(&a.act_jacobian_point(&p), &jp, 1e-8, "∂/∂p")?;
        let jr = num_jac(|d: &Vector3<f64>| a.right_plus(d).act(&p), &Vector3::zeros());
        assert_close(&a.act_jacobian_right(&p), &jr, 1e-8, "right")?;
        let jl = num_jac(|d: &Vector3<f64>| a.left_plus(d).act(&p), &Vector3::zeros());
        assert_close(&a.act_jacobian_left(&p), &jl, 1e-8, "left")?;
    }

    #[test]
    fn so3_plus_minus(a in so3(), b in so3(), d in so3_tangent()) {
        let back = a.left_plus(&d).left_minus(&a);
        assert_close(&back, &d, 1e-12 + 1e-10 * d.norm(), "left ⊖ ⊕")?;
        let back = a.right_plus(&d).right_minus(&a);
        assert_close(&back, &d, 1e-12 + 1e-10 * d.norm(), "right ⊖ ⊕")?;
        assert_close(&b.left_plus(&a.left_minus(&b)).matrix(), &a.matrix(), 1e-13, "⊕ ⊖")?;
    }

    // ---------------------------------------------------------------- SE(3) group axioms

    #[test]
    fn se3_closure_and_axioms(a in se3(), b in se3(), c in se3()) {
        is_rotation(&(a * b).rotation)?;
        let lhs = ((a * b) * c).matrix();
        let rhs = (a * (b * c)).matrix();
        assert_close(&lhs, &rhs, 1e-12, "assoc")?;
        let e = Se3::identity();
        assert_close(&(a * e).matrix(), &a.matrix(), 1e-15, "a·e")?;
        assert_close(&(e * a).matrix(), &a.matrix(), 1e-15, "e·a")?;
        assert_close(&(a * a.inverse()).matrix(), &Matrix4::identity(), 1e-13, "a·a⁻¹")?;
        assert_close(&(a.inverse() * a).matrix(), &Matrix4::identity(), 1e-13, "a⁻¹·a")?;
        // Composition agrees with 4×4 matrix products and actions.
        assert_close(&(a * b).matrix(), &(a.matrix() * b.matrix()), 1e-12, "matrix product")?;
    }

    #[test]
    fn se3_exp_log(v in se3_tangent(), a in se3()) {
        assert_close(&Se3::exp(&a.log()).matrix(), &a.matrix(), 1e-12, "exp(log X)")?;
        let back = Se3::exp(&v).log();
        assert_close(&back, &v, 1e-12 + 1e-11 * v.norm(), "log(exp v)")?;
    }

    #[test]
    fn se3_exp_is_matrix_exponential(v in se3_tangent()) {
        // Truncated power series of the 4×4 hat; scaled down so 30 terms converge fully.
        let m = Se3::hat(&v) / 8.0;
        let mut term = Matrix4::<f64>::identity();
        let mut sum = Matrix4::<f64>::identity();
        for k in 1..30 {
            term = term * m / k as f64;
            sum += term;
        }
        let expm = sum * sum * sum * sum * sum * sum * sum * sum;
        assert_close(&Se3::exp(&v).matrix(), &expm, 1e-11, "exp vs expm")?;
        assert_close(&Se3::vee(&Se3::hat(&v)), &v, 0.0, "vee(hat v)")?;
    }

    #[test]
    fn se3_adjoint(a in se3(), v in se3_tangent()) {
        let lhs = a * Se3::exp(&v) * a.inverse();
        let rhs = Se3::exp(&(a.adjoint() * v));
        assert_close(&lhs.matrix(), &rhs.matrix(), 1e-11, "X·exp(v)·X⁻¹")?;
    }

    #[test]
    fn se3_from_matrix_and_serde(a in se3()) {
        let back = Se3::from_matrix(&a.matrix()).map_err(|e| TestCaseError::fail(e.to_string()))?;
        assert_close(&back.matrix(), &a.matrix(), 1e-14, "from_matrix")?;
        let json = serde_json::to_string(&a).map_err(|e| TestCaseError::fail(e.to_string()))?;
        let back: Se3 = serde_json::from_str(&json).map_err(|e| TestCaseError::fail(e.to_string()))?;
        // serde_json's default float parser may be off by an ulp.
        assert_close(&back.matrix(), &a.matrix(), 1e-14, "serde")?;
        let (r, t) = a.to_rvec_tvec();
        assert_close(&Se3::from_rvec_tvec(&r, &t).matrix(), &a.matrix(), 1e-14, "rvec/tvec")?;
    }

    // ---------------------------------------------------------------- SE(3) Jacobians

    #[test]
    fn se3_jr_jl_finite_differences(v in se3_tangent()) {
        let x_inv = Se3::exp(&v).inverse();
        let jr = num_jac(|d: &Vector6<f64>| (x_inv * Se3::exp(&(v + d))).log(), &Vector6::zeros());
        let tol = 1e-7 * (1.0 + v.norm());
        assert_close(&Se3::jr(&v), &jr, tol, "Jr")?;
        let jl = num_jac(|d: &Vector6<f64>| (Se3::exp(&(v + d)) * x_inv).log(), &Vector6::zeros());
        assert_close(&Se3::jl(&v), &jl, tol, "Jl")?;
    }

    #[test]
    fn se3_inverse_jacobians_are_inverses(v in se3_tangent()) {
        let tol = 1e-11 * (1.0 + v.norm());
        assert_close(&(Se3::jr_inv(&v) * Se3::jr(&v)), &SMatrix::<f64, 6, 6>::identity(), tol, "Jr⁻¹Jr")?;
        assert_close(&(Se3::jl_inv(&v) * Se3::jl(&v)), &SMatrix::<f64, 6, 6>::identity(), tol, "Jl⁻¹Jl")?;
    }

    #[test]
    fn se3_inverse_jacobians_finite_differences(v in se3_tangent_below_pi()) {
        let x = Se3::exp(&v);
        let tol = 1e-7 * (1.0 + v.norm());
        let jri = num_jac(|d: &Vector6<f64>| (x * Se3::exp(d)).log(), &Vector6::zeros());
        assert_close(&Se3::jr_inv(&v), &jri, tol, "Jr⁻¹")?;
        let jli = num_jac(|d: &Vector6<f64>| (Se3::exp(d) * x).log(), &Vector6::zeros());
        assert_close(&Se3::jl_inv(&v), &jli, tol, "Jl⁻¹")?;
    }

    #[test]
    fn se3_act_jacobians(a in se3(), p in vec3(5.0)) {
        let tol = 1e-7;
        let jp = num_jac(|q: &Vector3<f64>| a.act(q), &p);
        assert_close(&a.act_jacobian_point(&p), &jp, tol, "∂/∂p")?;
        let jr = num_jac(|d: &Vector6<f64>| a.right_plus(d).act(&p), &Vector6::zeros());
        assert_close(&a.act_jacobian_right(&p), &jr, tol, "right")?;
        let jl = num_jac(|d: &Vector6<f64>| a.left_plus(d).act(&p), &Vector6::zeros());
        assert_close(&a.act_jacobian_left(&p), &jl, tol, "left")?;
    }

    #[test]
    fn se3_plus_minus(a in se3(), d in se3_tangent()) {
        let tol = 1e-11 * (1.0 + d.norm() + a.translation.norm());
        assert_close(&a.left_plus(&d).left_minus(&a), &d, tol, "left ⊖ ⊕")?;
        assert_close(&a.right_plus(&d).right_minus(&a), &d, tol, "right ⊖ ⊕")?;
    }
}

// -------------------------------------------------------------------- fixed cases

#[test]
fn series_and_closed_forms_agree_at_the_switch() {
    for &(f, t) in &[
        (coeff_b as fn(f64) -> f64, SMALL_ANGLE),
        (coeff_c, SMALL_ANGLE),
        (coeff_q2, SMALL_ANGLE_Q),
        (coeff_q3, SMALL_ANGLE_Q),
        (coeff_a, TINY_ANGLE),
    ] {
        let below = f(t * (1.0 - 1e-12));
        let above = f(t * (1.0 + 1e-12));
        assert!(
            ((below - above) / above).abs() < 1e-9,
            "discontinuity at {t}: {below} vs {above}"
        );
    }
}

#[test]
fn known_rotation() {
    let r = So3::from_rotation_vector(&Vector3::new(0.0, 0.0, PI / 2.0));
    let p = r.act(&Vector3::new(1.0, 0.0, 0.0));
    assert!((p - Vector3::new(0.0, 1.0, 0.0)).norm() < 1e-15);
    let half = std::f64::consts::FRAC_1_SQRT_2;
    let q = r.to_wxyz();
    assert!((q[0] - half).abs() < 1e-15 && (q[3] - half).abs() < 1e-15);
}

#[test]
fn log_at_exactly_pi_and_negative_w() {
    // 180° about x, stored with either quaternion sign.
    for s in [1.0, -1.0] {
        let r = So3::from_wxyz([0.0, s, 0.0, 0.0]).expect("unit quaternion");
        let v = r.log();
        assert!((v.norm() - PI).abs() < 1e-15);
        assert!((So3::exp(&v).matrix() - r.matrix()).abs().max() < 1e-15);
    }
    // Just past the w = 0 sign flip: the angle stays in [0, π].
    let r = So3::from_wxyz([-1e-12, 1.0, 0.0, 0.0]).expect("unit quaternion");
    assert!(r.log().norm() <= PI);
    assert!((So3::exp(&r.log()).matrix() - r.matrix()).abs().max() < 1e-15);
}

#[test]
fn from_matrix_rejects_non_rotations() {
    let reflection = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, -1.0));
    assert!(So3::from_matrix(&reflection).is_err());
    assert!(So3::from_matrix(&Matrix3::zeros()).is_err());
    let mut nan = Matrix3::identity();
    nan[(0, 1)] = f64::NAN;
    assert!(So3::from_matrix(&nan).is_err());
    let mut bad = Matrix4::identity();
    bad[(3, 0)] = 0.5;
    assert!(Se3::from_matrix(&bad).is_err());
}

#[test]
fn serde_formats() {
    let t = Se3::new(So3::identity(), Vector3::new(1.0, 2.0, 3.0));
    let json = serde_json::to_string(&t).expect("serialise");
    assert_eq!(
        json,
        r#"{"rotation":[1.0,0.0,0.0,0.0],"translation":[1.0,2.0,3.0]}"#
    );
    assert!(serde_json::from_str::<So3>("[2.0, 0.0, 0.0, 0.0]").is_err());
    assert!(serde_json::from_str::<So3>("[0.99995, 0.01, 0.0, 0.0]").is_ok());
    assert!(serde_json::from_str::<Se3>(r#"{"rotation":[1,0,0,0],"translation":[1,2]}"#).is_err());
}
