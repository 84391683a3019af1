//! Tests of rig calibration on synthetic rigs with known truth: stereo and three-camera rigs,
//! pinhole and fisheye, partial views, reversed corner numbering, fixed intrinsics, σ against
//! the actual error, rectification, and bad input.

use nalgebra::{Vector2, Vector3};

use super::*;
use crate::calib::{BoardGeometry, CornerObservation, ModelKind, ViewObservations};
use crate::camera::{Camera, CameraModel, KannalaBrandt, PinholeRadTan};
use crate::error::CoreError;
use crate::lie::{Se3, So3};
use crate::photometric::synth::Rng;
use crate::progress::NoProgress;

const SIZE: [u32; 2] = [752, 480];

fn board() -> BoardGeometry {
    BoardGeometry {
        cols: 11,
        rows: 8,
        square: 0.03,
    }
}

fn pinhole(fx: f64, cx: f64, k1: f64) -> Camera {
    PinholeRadTan::new(fx, fx * 1.001, cx, 241.0, k1, 0.08, 0.0004, -0.0003, -0.02)
        .expect("valid")
        .into()
}

fn fisheye(fx: f64, cx: f64) -> Camera {
    KannalaBrandt::new(fx, fx, cx, 238.0, 0.02, -0.005, 0.001, -0.0002)
        .expect("valid")
        .into()
}

/// `T_cam0_board` for frame k: the board 0.35–0.7 m in front of the rig, turned up to ~35°,
/// its centre wandering over the common field of view.
fn board_poses(n: usize, seed: u64) -> Vec<Se3> {
    board_poses_at(n, seed, [0.35, 0.35], 1.0)
}

/// [`board_poses`] with the board `z[0] .. z[0] + z[1]` m in front of the rig and its centre
/// wandering `wander` times as far sideways.
fn board_poses_at(n: usize, seed: u64, z: [f64; 2], wander: f64) -> Vec<Se3> {
    let b = board();
    let centre = Vector3::new(
        0.5 * (b.cols - 1) as f64 * b.square,
        0.5 * (b.rows - 1) as f64 * b.square,
        0.0,
    );
    let mut rng = Rng::new(seed);
    (0..n)
        .map(|_| {
            let r = So3::exp(&Vector3::new(
                0.6 * (rng.uniform() - 0.5),
                0.6 * (rng.uniform() - 0.5),
                0.8 * (rng.uniform() - 0.5),
            ));
            let z = z[0] + z[1] * rng.uniform();
            let p = Vector3::new(
                wander * z * 0.5 * (rng.uniform() - 0.5) + 0.06,
                wander * z * 0.4 * (rng.uniform() - 0.5),
                z,
            );
            Se3::new(r, p - r.act(&centre))
        })
        .collect()
}

/// Corners of the board that camera `cam` (at `t_c0`) sees, inside the image, with N(0, σ²)
/// noise; `None` below 6 corners or when `keep` says the camera misses the frame.
fn observe(
    cam: &Camera,
    t_c0: &Se3,
    poses: &[Se3],
    sigma: f64,
    seed: u64,
    keep: impl Fn(usize) -> bool,
) -> Vec<Option<ViewObservations>> {
    let b = board();
    let mut rng = Rng::new(seed);
    poses
        .iter()
        .enumerate()
        .map(|(f, pose)| {
            let corners: Vec<CornerObservation> = (0..b.num_corners())
                .filter_map(|k| {
                    let x = b.object_point(k)?;
                    let p = cam.project(&t_c0.compose(pose).act(&x))?;
                    let inside = p.x >= 0.0
                        && p.y >= 0.0
                        && p.x <= f64::from(SIZE[0] - 1)
                        && p.y <= f64::from(SIZE[1] - 1);
                    inside.then(|| CornerObservation {
                        index: k,
                        pixel: [p.x + sigma * rng.normal(), p.y + sigma * rng.normal()],
                    })
                })
                .collect();
            (keep(f) && corners.len() >= 6).then(|| ViewObservations {
                name: format!("f{f:02}"),
                corners,
            })
        })
        .collect()
}

fn input(name: &str, cam: &Camera, views: Vec<Option<ViewObservations>>) -> RigCameraInput {
    RigCameraInput {
        name: name.into(),
        model: crate::calib::ModelKind::of(cam),
        image_size: SIZE,
        views,
        fixed: None,
    }
}

fn stereo_truth() -> Se3 {
    Se3::new(
        So3::exp(&Vector3::new(0.004, -0.03, 0.006)),
        Vector3::new(-0.12, 0.002, 0.003),
    )
}

/// Errors of the estimated `T_cam_i_cam0` against the truth: translation (m), rotation (°).
fn extrinsic_error(e: &Extrinsic, truth: &Se3) -> (f64, f64) {
    let t = Vector3::from(e.t_cam_cam0.translation);
    let q = So3::from_wxyz(e.t_cam_cam0.quaternion_wxyz).expect("unit");
    let dr = q.compose(&truth.rotation.inverse()).angle().to_degrees();
    ((t - truth.translation).norm(), dr)
}

/// Every translation and rotation component of `e` is within `k` of its reported σ of the truth.
fn within_sigma(e: &Extrinsic, truth: &Se3, k: f64) {
    let s = e.sigma.as_ref().expect("covariance");
    let err = Vector3::from(e.t_cam_cam0.translation) - truth.translation;
    let q = So3::from_wxyz(e.t_cam_cam0.quaternion_wxyz).expect("unit");
    let rot_err = q.compose(&truth.rotation.inverse()).log();
    for c in 0..3 {
        assert!(
            err[c].abs() <= k * s.translation[c],
            "{} component {c}: {err:?} vs {s:?}",
            e.name
        );
        assert!(
            rot_err[c].to_degrees().abs() <= k * s.rotation_deg[c],
            "{} rotation {c}: {rot_err:?} vs {s:?}",
            e.name
        );
    }
}

/// σ is the spread of the estimate, not just a bound: over independent noise draws (same rig
/// and poses), the errors divided by their reported σ have an RMS near 1 (χ-consistency of the
/// covariance; 72 normalised errors, so 0.75–1.3 is wide enough for chance and narrow enough to
/// catch a σ off by a factor 1.5).
#[test]
fn sigma_matches_the_spread_of_the_error_over_noise_draws() {
    let poses = board_poses(30, 7);
    let (c0, c1) = (pinhole(600.0, 370.0, -0.28), pinhole(605.0, 380.0, -0.27));
    let t1 = stereo_truth();
    let mut z2 = Vec::new();
    for draw in 0..12u64 {
        let inputs = [
            input(
                "left",
                &c0,
                observe(&c0, &Se3::identity(), &poses, 0.3, 100 + 2 * draw, |_| true),
            ),
            input(
                "right",
                &c1,
                observe(&c1, &t1, &poses, 0.3, 101 + 2 * draw, |_| true),
            ),
        ];
        let rig =
            calibrate_rig(&inputs, &board(), &RigOptions::default(), &NoProgress).expect("solves");
        let e = &rig.extrinsics[1];
        let s = e.sigma.as_ref().expect("covariance");
        let err = Vector3::from(e.t_cam_cam0.translation) - t1.translation;
        let q = So3::from_wxyz(e.t_cam_cam0.quaternion_wxyz).expect("unit");
        let rot = q.compose(&t1.rotation.inverse()).log();
        for c in 0..3 {
            z2.push((err[c] / s.translation[c]).powi(2));
            z2.push((rot[c].to_degrees() / s.rotation_deg[c]).powi(2));
        }
    }
    let rms = (z2.iter().sum::<f64>() / z2.len() as f64).sqrt();
    eprintln!(
        "normalised error RMS over {} components: {rms:.3}",
        z2.len()
    );
    assert!((0.75..1.3).contains(&rms), "error/σ RMS {rms}");
}

#[test]
fn stereo_pinhole_recovers_extrinsics_within_a_tenth_of_a_millimetre() {
    let poses = board_poses(80, 1);
    let (c0, c1) = (pinhole(600.0, 370.0, -0.28), pinhole(605.0, 380.0, -0.27));
    let t1 = stereo_truth();
    let inputs = [
        input(
            "left",
            &c0,
            observe(&c0, &Se3::identity(), &poses, 0.1, 11, |_| true),
        ),
        input("right", &c1, observe(&c1, &t1, &poses, 0.1, 12, |_| true)),
    ];
    let rig =
        calibrate_rig(&inputs, &board(), &RigOptions::default(), &NoProgress).expect("solves");
    let (dt, dr) = extrinsic_error(&rig.extrinsics[1], &t1);
    eprintln!(
        "stereo: Δt {:.4} mm, Δr {:.5}°, σ {:?}, rms {:.4}, epipolar {:.4}",
        dt * 1e3,
        dr,
        rig.extrinsics[1].sigma,
        rig.rms,
        rig.pairs[0].epipolar_rms_px
    );
    assert!(dt < 1e-4, "translation off by {dt} m");
    assert!(dr < 0.01, "rotation off by {dr}°");
    assert!((rig.extrinsics[1].baseline - t1.translation.norm()).abs() < 1e-4);
    // σ consistent with the error: every translation component within 4σ, and σ not absurdly
    // large (the error bound above is then a real test).
    let s = rig.extrinsics[1].sigma.as_ref().expect("covariance");
    let err = Vector3::from(rig.extrinsics[1].t_cam_cam0.translation) - t1.translation;
    for k in 0..3 {
        assert!(
            err[k].abs() <= 4.0 * s.translation[k],
            "component {k}: {err:?} vs σ {s:?}"
        );
        assert!(s.translation[k] < 1e-4, "σ {s:?}");
    }
    assert!(s.baseline > 0.0 && s.baseline < 1e-4);
    // RMS of the residual norm: σ·√2 for N(0, σ²) per coordinate.
    assert!(
        (rig.rms - 0.1 * 2f64.sqrt()).abs() < 0.03,
        "rms {}",
        rig.rms
    );
    // Epipolar error of the rectified corners: the noise level (0.1 px per image → ≈ 0.14 px
    // across two), not more.
    assert!(
        rig.pairs[0].epipolar_rms_px < 0.2,
        "{}",
        rig.pairs[0].epipolar_rms_px
    );
    assert!(rig.pairs[0].epipolar_points > 500);
    for (c, truth) in rig.cameras.iter().zip([&c0, &c1]) {
        let (p, t) = (c.camera.params(), truth.params());
        assert!((p[0] - t[0]).abs() < 0.5, "fx {} vs {}", p[0], t[0]);
        assert!(
            c.parameters
                .iter()
                .all(|e| e.std_dev.is_some_and(|s| s > 0.0))
        );
    }
}

#[test]
fn noise_free_rig_is_exact_and_rectified_rows_agree() {
    let poses = board_poses(12, 2);
    let (c0, c1) = (pinhole(600.0, 370.0, -0.28), pinhole(605.0, 380.0, -0.27));
    let t1 = stereo_truth();
    let inputs = [
        input(
            "left",
            &c0,
            observe(&c0, &Se3::identity(), &poses, 0.0, 1, |_| true),
        ),
        input("right", &c1, observe(&c1, &t1, &poses, 0.0, 2, |_| true)),
    ];
    let rig =
        calibrate_rig(&inputs, &board(), &RigOptions::default(), &NoProgress).expect("solves");
    let (dt, dr) = extrinsic_error(&rig.extrinsics[1], &t1);
    assert!(dt < 1e-8 && dr < 1e-6, "Δt {dt}, Δr {dr}");
    assert!(rig.rms < 1e-6 && rig.pairs[0].epipolar_rms_px < 1e-6);
    // Bouguet: R2·R = R1 and the rectified baseline lies along x.
    let rect = &rig.pairs[0].rectification;
    let r = nalgebra::Matrix3::from_fn(|i, j| rect.r[i][j]);
    assert!((rect.rotation(true) * r - rect.rotation(false)).norm() < 1e-9);
    let t_rect = rect.rotation(true) * Vector3::from(rect.t);
    assert!(t_rect.y.abs() < 1e-9 && t_rect.z.abs() < 1e-9 && !rect.vertical);
    assert!((rect.p2[0][3] - rect.p1[0][0] * t_rect.x).abs() < 1e-9);
    // A 3-D point triangulated back through Q: disparity d = x_a − x_b gives depth.
    let x = Vector3::new(0.1, -0.05, 1.5);
    let qa = rectify_pixel(
        &c0,
        &rect.rotation(false),
        &rect.projection(false),
        &c0.project(&x).expect("in view"),
    )
    .expect("rectifies");
    let qb = rectify_pixel(
        &c1,
        &rect.rotation(true),
        &rect.projection(true),
        &c1.project(&t1.act(&x)).expect("in view"),
    )
    .expect("rectifies");
    assert!((qa.y - qb.y).abs() < 1e-6);
    let d = qa.x - qb.x;
    let w = rect.q[3][2] * d + rect.q[3][3];
    let z = rect.q[2][3] / w;
    let depth_rect = (rect.rotation(false) * x).z;
    assert!((z - depth_rect).abs() < 1e-6, "Q depth {z} vs {depth_rect}");
    // The fundamental matrix of a pinhole pair annihilates undistorted correspondences.
    let f = rect.f.expect("pinhole pair");
    let und = |c: &Camera, p: Vector3<f64>| {
        let k = c.params();
        Vector3::new(k[0] * p.x / p.z + k[2], k[1] * p.y / p.z + k[3], 1.0)
    };
    let (ua, ub) = (und(&c0, x), und(&c1, t1.act(&x)));
    let fm = nalgebra::Matrix3::from_fn(|i, j| f[i][j]);
    let scale = rig.cameras[0].camera.params()[0];
    assert!((ub.transpose() * fm * ua)[0].abs() < 1e-6 * scale);
}

#[test]
fn three_fisheye_cameras_with_partial_views_and_a_chained_camera() {
    let poses = board_poses(120, 3);
    let cams = [
        fisheye(300.0, 376.0),
        fisheye(305.0, 370.0),
        fisheye(298.0, 380.0),
    ];
    let t1 = stereo_truth();
    let t2 = Se3::new(
        So3::exp(&Vector3::new(0.01, 0.05, -0.02)),
        Vector3::new(-0.05, 0.1, 0.01),
    );
    let truths = [Se3::identity(), t1, t2];
    // Camera 2 never shares a frame with camera 0: its extrinsics come through camera 1.
    let keep: [&dyn Fn(usize) -> bool; 3] = [&|f| f % 3 != 2, &|_| true, &|f| f % 3 == 2];
    let inputs: Vec<RigCameraInput> = (0..3)
        .map(|i| {
            input(
                &format!("cam{i}"),
                &cams[i],
                observe(&cams[i], &truths[i], &poses, 0.1, 20 + i as u64, keep[i]),
            )
        })
        .collect();
    let rig =
        calibrate_rig(&inputs, &board(), &RigOptions::default(), &NoProgress).expect("solves");
    for (i, truth) in truths.iter().enumerate().skip(1) {
        let (dt, dr) = extrinsic_error(&rig.extrinsics[i], truth);
        eprintln!(
            "fisheye cam{i}: Δt {:.4} mm, Δr {:.5}°, σ {:?}",
            dt * 1e3,
            dr,
            rig.extrinsics[i].sigma
        );
        // A small board 0.35–0.7 m from f = 300 px fisheyes, each camera seeing it in only
        // some frames, camera 2 reached only through camera 1: the data determine the
        // rotation to σ ≈ 0.02° per axis (0.025° for camera 2), so the error is held to its σ
        // and to 0.2 mm / 0.1°; the close-board capture below reaches 0.01°.
        assert!(dt < 2e-4 && dr < 0.1, "cam{i}: Δt {dt} m, Δr {dr}°");
        within_sigma(&rig.extrinsics[i], truth, 4.0);
    }
    assert!(rig.pairs.len() == 2);
    // No shared frame between cameras 0 and 2: no epipolar pairs either.
    assert_eq!(rig.pairs[1].epipolar_points, 0);
    assert!(rig.frames.iter().all(|f| f.used));
    // One OpenCV stereo file per camera beyond the first, each paired with camera 0.
    let yaml = crate::export::rig_opencv_stereo_yaml(&rig, 2, None).expect("pair 0-2");
    let fx2 = rig.cameras[2].camera.params()[0];
    let m2 = &yaml[yaml.find("\nM2:").expect("M2")..];
    let data = &m2[m2.find("data: [").expect("data") + 7..];
    let first: f64 = data[..data.find(',').expect("comma")]
        .trim()
        .parse()
        .expect("number");
    assert!((first - fx2).abs() < 1e-9 * fx2, "{yaml}");
    assert!(crate::export::rig_opencv_stereo_yaml(&rig, 3, None).is_err());
}

/// The capture a fisheye rig is calibrated with in practice: the board close (0.2–0.4 m), so
/// it fills much of each view and often runs out of it (partial views), every camera in every
/// frame it can see. At 0.1 px noise the extrinsics come within 0.1 mm / 0.01° of the truth.
#[test]
fn three_fisheye_cameras_with_a_close_board_reach_a_hundredth_of_a_degree() {
    let poses = board_poses_at(120, 5, [0.2, 0.2], 3.0);
    let cams = [
        fisheye(300.0, 376.0),
        fisheye(305.0, 370.0),
        fisheye(298.0, 380.0),
    ];
    let truths = [
        Se3::identity(),
        stereo_truth(),
        Se3::new(
            So3::exp(&Vector3::new(0.01, 0.05, -0.02)),
            Vector3::new(-0.05, 0.1, 0.01),
        ),
    ];
    let full = 11 * 8;
    let mut partial = 0;
    let inputs: Vec<RigCameraInput> = (0..3)
        .map(|i| {
            let views = observe(&cams[i], &truths[i], &poses, 0.1, 40 + i as u64, |_| true);
            partial += views
                .iter()
                .flatten()
                .filter(|v| v.corners.len() < full)
                .count();
            input(&format!("cam{i}"), &cams[i], views)
        })
        .collect();
    assert!(partial > 30, "only {partial} partial views");
    let rig =
        calibrate_rig(&inputs, &board(), &RigOptions::default(), &NoProgress).expect("solves");
    for (i, truth) in truths.iter().enumerate().skip(1) {
        let (dt, dr) = extrinsic_error(&rig.extrinsics[i], truth);
        let s = rig.extrinsics[i].sigma.as_ref().expect("covariance");
        eprintln!(
            "close fisheye cam{i}: Δt {:.4} mm, Δr {dr:.5}°, σ {s:?}",
            dt * 1e3
        );
        assert!(dt < 1e-4 && dr < 0.01, "cam{i}: Δt {dt} m, Δr {dr}°");
        within_sigma(&rig.extrinsics[i], truth, 4.0);
    }
}

#[test]
fn reversed_corner_numbering_in_one_camera_is_detected_and_undone() {
    let poses = board_poses(40, 4);
    let (c0, c1) = (pinhole(600.0, 370.0, -0.28), pinhole(605.0, 380.0, -0.27));
    let t1 = stereo_truth();
    let mut right = observe(&c1, &t1, &poses, 0.05, 5, |_| true);
    let last = board().num_corners() - 1;
    for v in right.iter_mut().step_by(3).flatten() {
        for c in &mut v.corners {
            c.index = last - c.index;
        }
    }
    let inputs = [
        input(
            "left",
            &c0,
            observe(&c0, &Se3::identity(), &poses, 0.05, 6, |_| true),
        ),
        input("right", &c1, right),
    ];
    let rig =
        calibrate_rig(&inputs, &board(), &RigOptions::default(), &NoProgress).expect("solves");
    let (dt, dr) = extrinsic_error(&rig.extrinsics[1], &t1);
    assert!(dt < 1e-4 && dr < 0.02, "Δt {dt}, Δr {dr}");
    assert!(rig.rms < 0.1, "rms {}", rig.rms);
    assert_eq!(rig.frames.iter().filter(|f| f.used).count(), 40);
}

#[test]
fn fixed_intrinsics_stay_fixed() {
    let poses = board_poses(12, 5);
    let (c0, c1) = (pinhole(600.0, 370.0, -0.28), pinhole(605.0, 380.0, -0.27));
    let t1 = stereo_truth();
    let mut inputs = [
        input(
            "left",
            &c0,
            observe(&c0, &Se3::identity(), &poses, 0.1, 7, |_| true),
        ),
        input("right", &c1, observe(&c1, &t1, &poses, 0.1, 8, |_| true)),
    ];
    inputs[0].fixed = Some(c0.clone());
    inputs[1].fixed = Some(c1.clone());
    let rig =
        calibrate_rig(&inputs, &board(), &RigOptions::default(), &NoProgress).expect("solves");
    assert_eq!(rig.cameras[0].camera, c0);
    assert_eq!(rig.cameras[1].camera, c1);
    assert!(
        rig.cameras
            .iter()
            .all(|c| c.intrinsics_fixed && c.mono_rms.is_none())
    );
    let (dt, dr) = extrinsic_error(&rig.extrinsics[1], &t1);
    assert!(dt < 2e-4 && dr < 0.02, "Δt {dt}, Δr {dr}");
}

#[test]
fn intrinsics_can_stay_at_each_cameras_own_calibration() {
    let poses = board_poses(16, 7);
    let (c0, c1) = (pinhole(600.0, 370.0, -0.28), pinhole(605.0, 380.0, -0.27));
    let t1 = stereo_truth();
    let inputs = [
        input(
            "left",
            &c0,
            observe(&c0, &Se3::identity(), &poses, 0.1, 13, |_| true),
        ),
        input("right", &c1, observe(&c1, &t1, &poses, 0.1, 14, |_| true)),
    ];
    let options = RigOptions {
        refine_intrinsics: false,
        ..RigOptions::default()
    };
    let rig = calibrate_rig(&inputs, &board(), &options, &NoProgress).expect("solves");
    let refined =
        calibrate_rig(&inputs, &board(), &RigOptions::default(), &NoProgress).expect("solves");
    for c in &rig.cameras {
        assert!(
            c.parameters
                .iter()
                .all(|p| p.fixed && p.std_dev == Some(0.0))
        );
        // The joint solve, free to move them, fits the corners at least as well.
        let r = refined
            .cameras
            .iter()
            .find(|r| r.name == c.name)
            .expect("camera");
        assert!(r.rms <= c.rms + 1e-9, "{} vs {}", r.rms, c.rms);
    }
    let (dt, dr) = extrinsic_error(&rig.extrinsics[1], &t1);
    // Errors of the monocular intrinsics carry into the extrinsics: looser than the joint solve.
    assert!(dt < 3e-3 && dr < 0.1, "Δt {dt}, Δr {dr}");
}

#[test]
fn bad_rigs_are_refused_with_the_reason() {
    let poses = board_poses(8, 6);
    let (c0, c1) = (pinhole(600.0, 370.0, -0.28), pinhole(605.0, 380.0, -0.27));
    let t1 = stereo_truth();
    let left = observe(&c0, &Se3::identity(), &poses, 0.1, 9, |_| true);
    // Different frame counts.
    let mut short = observe(&c1, &t1, &poses, 0.1, 10, |_| true);
    short.pop();
    let e = calibrate_rig(
        &[input("left", &c0, left.clone()), input("right", &c1, short)],
        &board(),
        &RigOptions::default(),
        &NoProgress,
    )
    .expect_err("refused");
    assert!(
        matches!(e, CoreError::InvalidInput(ref m) if m.contains("frame counts")),
        "{e}"
    );
    // A camera that never sees the board with the other.
    let a = observe(&c0, &Se3::identity(), &poses, 0.1, 9, |f| f < 4);
    let b = observe(&c1, &t1, &poses, 0.1, 10, |f| f >= 4);
    let e = calibrate_rig(
        &[input("left", &c0, a), input("right", &c1, b)],
        &board(),
        &RigOptions::default(),
        &NoProgress,
    )
    .expect_err("refused");
    assert!(
        matches!(e, CoreError::NoSolution(ref m) if m.contains("never sees the board")),
        "{e}"
    );
    // One camera alone.
    let e = calibrate_rig(
        &[input("left", &c0, left)],
        &board(),
        &RigOptions::default(),
        &NoProgress,
    )
    .expect_err("refused");
    assert!(e.to_string().contains("2 to"), "{e}");
    let _ = (ModelKind::PinholeRadTan, Vector2::<f64>::zeros());
}
