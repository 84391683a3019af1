//! Round trips, hand-computed values, domain checks and every Jacobian against central finite
//! differences.

use std::f64::consts::{FRAC_PI_2, PI};

use nalgebra::{DMatrix, Matrix2x3, Vector2, Vector3};
use proptest::prelude::*;

use super::*;

/// EuRoC MAV cam0 (pinhole-radtan), a typical mildly distorted lens.
fn euroc() -> PinholeRadTan {
    PinholeRadTan::new(
        458.654,
        457.296,
        367.215,
        248.375,
        -0.28340811,
        0.07395907,
        0.00019359,
        1.76187114e-05,
        0.0,
    )
    .expect("valid")
}

/// A stronger wide-angle pinhole with all five coefficients.
fn wide_pinhole() -> PinholeRadTan {
    PinholeRadTan::new(
        600.0, 605.0, 640.0, 360.0, -0.32, 0.12, 0.0012, -0.0008, -0.02,
    )
    .expect("valid")
}

/// TUM VI fisheye (Kannala-Brandt), a ~195° lens on a 512×512 sensor.
fn tumvi_kb() -> KannalaBrandt {
    KannalaBrandt::new(
        190.97847715128717,
        190.9733070521226,
        254.93170605935475,
        256.8974428996504,
        0.0034823894022493434,
        0.0007150348452162257,
        -0.0020532361418706202,
        0.00020293673591811182,
    )
    .expect("valid")
}

/// TUM VI fisheye (double sphere).
fn tumvi_ds() -> DoubleSphere {
    DoubleSphere::new(
        158.28600034966977,
        158.2743455478755,
        254.96116578191653,
        256.8894394501779,
        -0.17213086034353243,
        0.5931177593944744,
    )
    .expect("valid")
}

fn direction(theta: f64, phi: f64) -> Vector3<f64> {
    Vector3::new(
        theta.sin() * phi.cos(),
        theta.sin() * phi.sin(),
        theta.cos(),
    )
}

fn prop_err(e: impl std::fmt::Display) -> TestCaseError {
    TestCaseError::fail(e.to_string())
}

/// Checks the analytic Jacobians of `cam` at `p` against central differences. Returns
/// `Ok(false)` when the point or a perturbed evaluation leaves the valid domain.
fn check_jacobians(cam: &Camera, p: &Vector3<f64>) -> Result<bool, TestCaseError> {
    let Some((px, d_point, d_params)) = cam.project_with_jacobians(p) else {
        return Ok(false);
    };
    let plain = cam
        .project(p)
        .ok_or_else(|| prop_err("project disagrees"))?;
    prop_assert!((plain - px).norm() < 1e-9, "pixel {plain} vs {px}");

    let hp = 1e-6 * p.norm();
    let mut num_point = Matrix2x3::zeros();
    for k in 0..3 {
        let mut a = *p;
        let mut b = *p;
        a[k] += hp;
        b[k] -= hp;
        let (Some(fa), Some(fb)) = (cam.project(&a), cam.project(&b)) else {
            return Ok(false);
        };
        num_point.set_column(k, &((fa - fb) / (2.0 * hp)));
    }
    for (an, nu) in d_point.iter().zip(num_point.iter()) {
        prop_assert!(
            (an - nu).abs() <= 1e-5 * (1.0 + an.abs()),
            "{}: d/dpoint\n{d_point}\n{num_point}",
            cam.name()
        );
    }

    let n = cam.num_params();
    prop_assert_eq!(d_params.ncols(), n);
    let mut num_params = DMatrix::zeros(2, n);
    for k in 0..n {
        let h = 1e-6 * cam.params()[k].abs().max(1.0);
        let mut plus = cam.clone();
        let mut minus = cam.clone();
        let mut v = cam.params().to_vec();
        v[k] += h;
        plus.set_params(&v).map_err(prop_err)?;
        v[k] -= 2.0 * h;
        minus.set_params(&v).map_err(prop_err)?;
        let (Some(fa), Some(fb)) = (plus.project(p), minus.project(p)) else {
            return Ok(false);
        };
        let col: Vector2<f64> = (fa - fb) / (2.0 * h);
        num_params.set_column(k, &col);
    }
    for (an, nu) in d_params.iter().zip(num_params.iter()) {
        prop_assert!(
            (an - nu).abs() <= 1e-5 * (1.0 + an.abs()),
            "{}: d/dparams\n{d_params}\n{num_params}",
            cam.name()
        );
    }
    Ok(true)
}

// ------------------------------------------------------------------------ known values

#[test]
fn pinhole_matches_hand_computed_values() {
    // fx=500 fy=490 cx=320 cy=240, k1=−0.2 k2=0.05 p1=0.001 p2=−0.002 k3=0.01, P=(0.2, −0.1, 2):
    // x=0.1, y=−0.05, r²=0.0125, radial = 1 − 0.0025 + 0.0000078125 + 0.00000001953125
    //   = 0.99750783203125
    // x″ = 0.099750783203125 + 2·0.001·0.1·(−0.05) + (−0.002)(0.0125 + 0.02) = 0.099675783203125
    // y″ = −0.0498753916015625 + 0.001(0.0125 + 0.005) + 2(−0.002)(0.1)(−0.05) = −0.0498378916015625
    // u = 500·x″ + 320 = 369.8378916015625, v = 490·y″ + 240 = 215.579433115234375
    let cam = PinholeRadTan::new(500.0, 490.0, 320.0, 240.0, -0.2, 0.05, 0.001, -0.002, 0.01)
        .expect("valid");
    let px = cam
        .project(&Vector3::new(0.2, -0.1, 2.0))
        .expect("in front");
    assert!((px.x - 369.8378916015625).abs() < 1e-10, "{px}");
    assert!((px.y - 215.579_433_115_234_37).abs() < 1e-10, "{px}");
    // The principal ray hits the principal point.
    let c = cam.project(&Vector3::new(0.0, 0.0, 3.0)).expect("in front");
    assert_eq!(c, Vector2::new(320.0, 240.0));
    assert_eq!(cam.distortion(), [-0.2, 0.05, 0.001, -0.002, 0.01]);
    assert_eq!(cam.intrinsics(), [500.0, 490.0, 320.0, 240.0]);
}

#[test]
fn kannala_brandt_equidistant_and_known_value() {
    // With k = 0 the model is equidistant: pixel radius = f·θ.
    let cam = KannalaBrandt::new(300.0, 300.0, 400.0, 300.0, 0.0, 0.0, 0.0, 0.0).expect("valid");
    let px = cam.project(&direction(1.2, 0.0)).expect("valid");
    assert!((px - Vector2::new(400.0 + 300.0 * 1.2, 300.0)).norm() < 1e-10);
    // Beyond 90°: θ = 2 rad straight down.
    let px = cam.project(&direction(2.0, FRAC_PI_2)).expect("valid");
    assert!((px - Vector2::new(400.0, 300.0 + 600.0)).norm() < 1e-10);
    // θd = θ(1 + k1θ²) with k1 = 0.1 at θ = 0.5: 0.5·1.025 = 0.5125.
    let cam = KannalaBrandt::new(300.0, 300.0, 0.0, 0.0, 0.1, 0.0, 0.0, 0.0).expect("valid");
    let px = cam.project(&direction(0.5, 0.0)).expect("valid");
    assert!((px.x - 300.0 * 0.5125).abs() < 1e-10);
}

#[test]
fn double_sphere_reduces_to_pinhole() {
    // ξ = 0, α = 0: u = fx X/Z + cx.
    let cam = DoubleSphere::new(400.0, 410.0, 320.0, 240.0, 0.0, 0.0).expect("valid");
    let px = cam.project(&Vector3::new(0.3, -0.2, 1.5)).expect("valid");
    assert!((px - Vector2::new(320.0 + 400.0 * 0.2, 240.0 - 410.0 * 0.2 / 1.5)).norm() < 1e-10);
}

// ------------------------------------------------------------------------ domains

#[test]
fn behind_camera_and_degenerate_points_are_none() {
    let cams: Vec<Camera> = vec![euroc().into(), tumvi_kb().into(), tumvi_ds().into()];
    for cam in &cams {
        for p in [
            Vector3::new(0.0, 0.0, -1.0),
            Vector3::zeros(),
            Vector3::new(f64::NAN, 0.0, 1.0),
        ] {
            assert!(cam.project(&p).is_none(), "{} {p}", cam.name());
            assert!(
                cam.project_with_jacobians(&p).is_none(),
                "{} {p}",
                cam.name()
            );
        }
        assert!(cam.unproject(&Vector2::new(f64::NAN, 1.0)).is_none());
    }
    // The pinhole also rejects the image plane and anything behind it.
    assert!(euroc().project(&Vector3::new(1.0, 0.0, 0.0)).is_none());
    assert!(euroc().project(&Vector3::new(0.1, -0.2, -5.0)).is_none());
    // Kannala-Brandt is valid wherever θd is monotonic and θ < π: the TUM VI polynomial is
    // monotonic up to π, so only the exact backward axis is excluded; a lens whose polynomial
    // folds earlier rejects everything beyond the fold.
    assert!(tumvi_kb().project(&Vector3::new(0.1, -0.2, -5.0)).is_some());
    let kb = KannalaBrandt::new(300.0, 300.0, 0.0, 0.0, -0.1, 0.0, 0.0, 0.0).expect("valid");
    assert!(kb.project(&Vector3::new(0.1, -0.2, -5.0)).is_none());
    // The double sphere rejects rays past its cone (≈126° for TUM VI).
    assert!(
        tumvi_ds()
            .project(&direction(130f64.to_radians(), 0.3))
            .is_none()
    );
    assert!(
        tumvi_ds()
            .project(&direction(120f64.to_radians(), 0.3))
            .is_some()
    );
}

#[test]
fn distortion_fold_limits_the_domain() {
    // 1 + 3k1 r² = 0 at r² = 1/1.2 for k1 = −0.4: the radial map folds back there.
    let cam = PinholeRadTan::new(500.0, 500.0, 0.0, 0.0, -0.4, 0.0, 0.0, 0.0, 0.0).expect("valid");
    assert!((cam.max_radius_squared() - 1.0 / 1.2).abs() < 1e-9);
    assert!(cam.project(&Vector3::new(0.95, 0.0, 1.0)).is_none());
    assert!(cam.project(&Vector3::new(0.85, 0.0, 1.0)).is_some());
    // Pixels beyond the fold's image radius have no ray.
    let r_max = (1.0f64 / 1.2).sqrt();
    let fold_px = 500.0 * r_max * (1.0 - 0.4 * r_max * r_max);
    assert!(cam.unproject(&Vector2::new(fold_px + 1.0, 0.0)).is_none());
    assert!(cam.unproject(&Vector2::new(fold_px - 1.0, 0.0)).is_some());
    assert!(euroc().max_radius_squared().is_infinite());

    // Kannala-Brandt with k1 = −0.1: dθd/dθ = 1 − 0.3θ² vanishes at θ = 1.826.
    let kb = KannalaBrandt::new(300.0, 300.0, 0.0, 0.0, -0.1, 0.0, 0.0, 0.0).expect("valid");
    assert!((kb.max_angle() - (1.0f64 / 0.3).sqrt()).abs() < 1e-9);
    assert!(kb.project(&direction(1.9, 0.0)).is_none());
    assert!(kb.project(&direction(1.7, 0.0)).is_some());
    assert!((tumvi_kb().max_angle() - PI).abs() < 1e-12);
}

// ------------------------------------------------------------------------ round trips

/// unproject → project over a pixel grid, and project → unproject over a grid of rays.
fn round_trip(cam: &Camera, size: (f64, f64), max_angle: f64) -> (usize, usize) {
    let mut pixels = 0;
    let mut v = 0.0;
    while v <= size.1 {
        let mut u = 0.0;
        while u <= size.0 {
            let px = Vector2::new(u, v);
            if let Some(b) = cam.unproject(&px) {
                assert!(
                    (b.norm() - 1.0).abs() < 1e-12,
                    "{} bearing not unit",
                    cam.name()
                );
                let back = cam.project(&b).expect("unprojected ray must project");
                assert!(
                    (back - px).norm() < 1e-6,
                    "{} {px} → {b} → {back}",
                    cam.name()
                );
                pixels += 1;
            }
            u += 8.0;
        }
        v += 8.0;
    }
    let mut rays = 0;
    let steps = 40;
    for i in 0..=steps {
        let theta = max_angle * i as f64 / steps as f64;
        for j in 0..24 {
            let phi = 2.0 * PI * j as f64 / 24.0;
            let d = direction(theta, phi);
            let px = cam.project(&(d * 3.7)).unwrap_or_else(|| {
                panic!(
                    "{}: θ = {:.1}° must project",
                    cam.name(),
                    theta.to_degrees()
                )
            });
            let b = cam.unproject(&px).expect("projected pixel must unproject");
            assert!(
                (b - d).norm() < 1e-9,
                "{} θ={theta} φ={phi}: {d} vs {b}",
                cam.name()
            );
            rays += 1;
        }
    }
    (pixels, rays)
}

#[test]
fn pinhole_round_trip() {
    let (pixels, _) = round_trip(&euroc().into(), (752.0, 480.0), 40f64.to_radians());
    assert_eq!(pixels, 95 * 61, "every EuRoC pixel has a ray");
    let (pixels, _) = round_trip(&wide_pinhole().into(), (1280.0, 720.0), 45f64.to_radians());
    assert!(pixels > 0);
}

#[test]
fn kannala_brandt_round_trip_beyond_90_degrees() {
    let (pixels, rays) = round_trip(&tumvi_kb().into(), (512.0, 512.0), 100f64.to_radians());
    assert!(pixels > 3000 && rays > 900);
    // The whole 195° field of view of that lens.
    round_trip(&tumvi_kb().into(), (0.0, 0.0), 97.5f64.to_radians());
}

#[test]
fn double_sphere_round_trip_beyond_90_degrees() {
    let (pixels, rays) = round_trip(&tumvi_ds().into(), (512.0, 512.0), 120f64.to_radians());
    assert!(pixels > 3000 && rays > 900);
}

#[test]
fn double_sphere_unprojection_domain() {
    // α > ½: pixels with r² > 1/(2α − 1) have no ray.
    let cam = DoubleSphere::new(100.0, 100.0, 0.0, 0.0, 0.0, 0.75).expect("valid");
    let r_max = (1.0f64 / 0.5).sqrt() * 100.0;
    assert!(cam.unproject(&Vector2::new(r_max + 1.0, 0.0)).is_none());
    assert!(cam.unproject(&Vector2::new(r_max - 1.0, 0.0)).is_some());
}

// ------------------------------------------------------------------------ Jacobians

#[test]
fn jacobians_at_realistic_parameters_over_the_field_of_view() {
    let cases: Vec<(Camera, f64)> = vec![
        (euroc().into(), 40f64.to_radians()),
        (wide_pinhole().into(), 45f64.to_radians()),
        (tumvi_kb().into(), 100f64.to_radians()),
        (tumvi_ds().into(), 120f64.to_radians()),
    ];
    for (cam, max_angle) in &cases {
        for i in 0..=20 {
            let theta = max_angle * i as f64 / 20.0;
            for j in 0..12 {
                let phi = 2.0 * PI * (j as f64 + 0.3) / 12.0;
                let p = direction(theta, phi) * (0.5 + i as f64 * 0.3);
                let ok = check_jacobians(cam, &p).expect("Jacobians agree");
                assert!(ok, "{} θ={theta}: must be in the domain", cam.name());
            }
        }
        // Exactly on the optical axis.
        assert!(check_jacobians(cam, &Vector3::new(0.0, 0.0, 2.0)).expect("on axis"));
    }
}

fn any_pinhole() -> impl Strategy<Value = Camera> {
    (
        (300.0..800.0, 300.0..800.0, 200.0..400.0, 200.0..400.0),
        (-0.3..0.1, -0.05..0.1, -1e-3..1e-3, -1e-3..1e-3, -0.01..0.01),
    )
        .prop_map(|((fx, fy, cx, cy), (k1, k2, p1, p2, k3))| {
            PinholeRadTan::new(fx, fy, cx, cy, k1, k2, p1, p2, k3)
                .expect("valid")
                .into()
        })
}

fn any_kb() -> impl Strategy<Value = Camera> {
    (
        (150.0..400.0, 150.0..400.0, 200.0..400.0, 200.0..400.0),
        (-0.02..0.05, -0.01..0.01, -2e-3..2e-3, -3e-4..3e-4),
    )
        .prop_map(|((fx, fy, cx, cy), (k1, k2, k3, k4))| {
            KannalaBrandt::new(fx, fy, cx, cy, k1, k2, k3, k4)
                .expect("valid")
                .into()
        })
}

fn any_ds() -> impl Strategy<Value = Camera> {
    (
        (100.0..400.0, 100.0..400.0, 200.0..400.0, 200.0..400.0),
        (-0.5..0.5, 0.3..0.8),
    )
        .prop_map(|((fx, fy, cx, cy), (xi, alpha))| {
            DoubleSphere::new(fx, fy, cx, cy, xi, alpha)
                .expect("valid")
                .into()
        })
}

fn point(max_angle: f64) -> impl Strategy<Value = Vector3<f64>> {
    (0.0..max_angle, 0.0..(2.0 * PI), 0.2..20.0).prop_map(|(t, f, d)| direction(t, f) * d)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn pinhole_jacobians(cam in any_pinhole(), p in point(40f64.to_radians())) {
        check_jacobians(&cam, &p)?;
    }

    #[test]
    fn kannala_brandt_jacobians(cam in any_kb(), p in point(95f64.to_radians())) {
        check_jacobians(&cam, &p)?;
    }

    #[test]
    fn double_sphere_jacobians(cam in any_ds(), p in point(110f64.to_radians())) {
        check_jacobians(&cam, &p)?;
    }

    #[test]
    fn random_models_round_trip(
        cam in prop_oneof![any_pinhole(), any_kb(), any_ds()],
        p in point(80f64.to_radians()),
    ) {
        if let Some(px) = cam.project(&p) {
            let b = cam.unproject(&px).ok_or_else(|| prop_err("no ray for a projected pixel"))?;
            prop_assert!((b - p.normalize()).norm() < 1e-8, "{}: {p} → {px} → {b}", cam.name());
        }
    }
}

// ------------------------------------------------------------------------ parameters & serde

#[test]
fn set_params_validates_and_keeps_the_model_on_error() {
    let mut cam: Camera = euroc().into();
    let before = cam.clone();
    assert!(cam.set_params(&[1.0, 2.0]).is_err());
    assert!(
        cam.set_params(&[0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
            .is_err()
    );
    assert!(
        cam.set_params(&[1.0, 1.0, f64::NAN, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
            .is_err()
    );
    assert_eq!(cam, before);
    let mut p = cam.params().to_vec();
    p[4] = -0.1;
    cam.set_params(&p).expect("valid");
    assert_eq!(cam.params()[4], -0.1);
    assert_eq!(cam.num_params(), 9);
    assert_eq!(cam.param_names()[8], "k3");

    let mut ds: Camera = tumvi_ds().into();
    assert!(ds.set_params(&[100.0, 100.0, 0.0, 0.0, 0.0, 1.5]).is_err());
    assert!(ds.set_params(&[100.0, 100.0, 0.0, 0.0, -1.5, 0.5]).is_err());
    assert_eq!(ds.num_params(), 6);
    assert_eq!(tumvi_kb().num_params(), 8);
}

#[test]
fn camera_documents() {
    let cams: Vec<Camera> = vec![euroc().into(), tumvi_kb().into(), tumvi_ds().into()];
    for cam in &cams {
        let json = serde_json::to_value(cam).expect("serialise");
        assert_eq!(json["model"], cam.name());
        let back: Camera = serde_json::from_value(json).expect("deserialise");
        for (a, b) in back.params().iter().zip(cam.params()) {
            assert!((a - b).abs() <= 1e-12 * b.abs().max(1.0));
        }
    }
    let json = serde_json::to_string(&Camera::from(
        DoubleSphere::new(1.0, 2.0, 3.0, 4.0, 0.5, 0.25).expect("valid"),
    ))
    .expect("serialise");
    assert_eq!(
        json,
        r#"{"model":"double_sphere","fx":1.0,"fy":2.0,"cx":3.0,"cy":4.0,"xi":0.5,"alpha":0.25}"#
    );

    // Distortion defaults to zero; unknown fields, unknown models and bad values are rejected.
    let cam: Camera =
        serde_json::from_str(r#"{"model":"pinhole_radtan","fx":500,"fy":500,"cx":320,"cy":240}"#)
            .expect("defaults");
    assert_eq!(&cam.params()[4..], &[0.0; 5]);
    for bad in [
        r#"{"model":"pinhole_radtan","fx":500,"fy":500,"cx":320,"cy":240,"k4":0.1}"#,
        r#"{"model":"pinhole_radtan","fx":-500,"fy":500,"cx":320,"cy":240}"#,
        r#"{"model":"double_sphere","fx":1,"fy":1,"cx":0,"cy":0,"xi":0,"alpha":2}"#,
        r#"{"model":"omni","fx":1,"fy":1,"cx":0,"cy":0}"#,
        r#"{"fx":1,"fy":1,"cx":0,"cy":0}"#,
    ] {
        assert!(serde_json::from_str::<Camera>(bad).is_err(), "{bad}");
    }
}

#[cfg(feature = "schema")]
#[test]
fn openapi_schema_describes_the_documents() {
    use utoipa::{PartialSchema, ToSchema};
    let schema = serde_json::to_string(&Camera::schema()).expect("serialise schema");
    for needle in ["pinhole_radtan", "kannala_brandt", "double_sphere", "model"] {
        assert!(schema.contains(needle), "{needle} missing from {schema}");
    }
    let mut deps = Vec::new();
    Camera::schemas(&mut deps);
    let all = serde_json::to_string(&deps).expect("serialise schemas");
    for needle in ["\"fx\"", "\"k3\"", "\"k4\"", "\"alpha\""] {
        assert!(all.contains(needle), "{needle} missing from {all}");
    }
    let pose = serde_json::to_string(&crate::lie::Se3::schema()).expect("serialise schema");
    assert!(pose.contains("rotation") && pose.contains("translation"));
}
