//! Tests of camera calibration: synthetic boards with known truth, uncertainty, rejection, and
//! the shared real sets against OpenCV (over 600 lines: one file of tests for the module).

use nalgebra::{Matrix3, Vector2, Vector3};

use super::*;
use crate::camera::{Camera, CameraModel, KannalaBrandt, PinholeRadTan};
use crate::error::CoreError;
use crate::lie::{Se3, So3};
use crate::optim::RobustLoss;
use crate::progress::{NoProgress, Progress};

/// xorshift64* with Box-Muller: a deterministic Gaussian source for the synthetic sets.
struct Rng(u64);

impl Rng {
    /// Seeds through splitmix64 so that small seeds do not start in a low-entropy state.
    fn new(seed: u64) -> Self {
        let mut z = seed.wrapping_add(0x9E37_79B9_7F4A_7C15);
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        Self((z ^ (z >> 31)).max(1))
    }

    fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let x = self.0.wrapping_mul(0x2545_F491_4F6C_DD1D);
        ((x >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }

    fn gauss(&mut self) -> f64 {
        let (u1, u2) = (self.uniform(), self.uniform());
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }
}

/// A board pose putting the board centre on the ray `(dir.x, dir.y, 1)` at depth `depth`,
/// rotated by `rvec` about its centre.
fn board_pose(board: &BoardGeometry, rvec: [f64; 3], dir: [f64; 2], depth: f64) -> Se3 {
    let centre = Vector3::new(
        0.5 * (board.cols - 1) as f64 * board.square,
        0.5 * (board.rows - 1) as f64 * board.square,
        0.0,
    );
    let r = So3::exp(&Vector3::from(rvec));
    let p = Vector3::new(dir[0] * depth, dir[1] * depth, depth);
    Se3::new(r, p - r.act(&centre))
}

/// Projects every board corner, keeps those inside the image, adds N(0, σ²) noise.
fn synthesise(
    camera: &Camera,
    board: &BoardGeometry,
    poses: &[Se3],
    image_size: (u32, u32),
    sigma: f64,
    seed: u64,
) -> Vec<ViewObservations> {
    let mut rng = Rng::new(seed);
    let (w, h) = (f64::from(image_size.0), f64::from(image_size.1));
    poses
        .iter()
        .enumerate()
        .map(|(i, pose)| {
            let corners = (0..board.num_corners())
                .filter_map(|k| {
                    let x = board.object_point(k).expect("in board");
                    let p = camera.project(&pose.act(&x))?;
                    let inside = p.x >= 0.0 && p.x <= w - 1.0 && p.y >= 0.0 && p.y <= h - 1.0;
                    inside.then(|| CornerObservation {
                        index: k,
                        pixel: [p.x + sigma * rng.gauss(), p.y + sigma * rng.gauss()],
                    })
                })
                .collect();
            ViewObservations {
                name: format!("view{i:02}"),
                corners,
            }
        })
        .collect()
}

fn pinhole_truth() -> PinholeRadTan {
    PinholeRadTan::new(
        536.07, 536.02, 342.37, 235.54, -0.265, -0.0467, 0.00183, -0.000315, 0.2523,
    )
    .expect("valid")
}

fn pinhole_board() -> BoardGeometry {
    BoardGeometry {
        cols: 9,
        rows: 6,
        square: 0.025,
    }
}

/// Twelve views: tilted up to ~40°, board centre spread over the image so that the periphery
/// (where k2, k3 live) is covered.
fn pinhole_poses() -> Vec<Se3> {
    let b = pinhole_board();
    let spec: [([f64; 3], [f64; 2], f64); 12] = [
        ([0.0, 0.0, 0.0], [0.0, 0.0], 0.22),
        ([0.8, 0.0, 0.1], [-0.35, -0.25], 0.22),
        ([-0.8, 0.1, -0.1], [0.35, 0.25], 0.22),
        ([0.1, 0.8, 0.2], [0.35, -0.25], 0.22),
        ([0.0, -0.8, -0.2], [-0.35, 0.25], 0.22),
        ([0.6, 0.6, 0.0], [-0.45, 0.3], 0.25),
        ([-0.6, -0.6, 0.3], [0.45, -0.3], 0.25),
        ([0.5, -0.7, 0.5], [0.45, 0.3], 0.25),
        ([-0.5, 0.7, -0.5], [-0.45, -0.3], 0.25),
        ([0.5, 0.3, 1.2], [0.0, 0.35], 0.22),
        ([-0.3, 0.5, -1.0], [0.0, -0.35], 0.22),
        ([0.9, -0.2, 0.0], [0.0, 0.0], 0.2),
    ];
    spec.iter()
        .map(|(r, d, z)| board_pose(&b, *r, *d, *z))
        .collect()
}

fn assert_close(name: &str, got: f64, want: f64, tol: f64) {
    assert!(
        (got - want).abs() <= tol,
        "{name}: got {got}, want {want} ± {tol}"
    );
}

/// Accuracy checks of a synthetic solve. The statistical one is that every parameter is
/// within 3σ of the truth, σ from the solver's covariance (its calibration against repeated
/// noise draws was checked: normalised errors over 15 seeds look N(0, 1)). The absolute bounds
/// are what 12 views at σ = 0.1 px can support: σ(fx) ≈ 0.2 px, σ(cx, cy) ≈ 0.3 px,
/// σ(k1) ≈ 0.002, σ(k2, k3) ≈ 0.007, σ(p1, p2) ≈ 7·10⁻⁵; so fx, fy are held to 0.1 %, p1, p2
/// to 10⁻³, and c, k1..k3 only to about 4σ (0.2 % of c, 10⁻² and 3·10⁻²) — a tighter bound
/// would test the noise draw, not the solver.
fn check_accuracy(cal: &Calibration, truth: &Camera, tolerances: &[f64]) {
    let p = cal.camera.params();
    let t = truth.params();
    for (k, tol) in tolerances.iter().enumerate() {
        assert_close(cal.parameters[k].name.as_str(), p[k], t[k], *tol);
    }
    for (k, est) in cal.parameters.iter().enumerate() {
        let sd = est.std_dev.expect("covariance");
        assert!(
            (est.value - t[k]).abs() <= 3.0 * sd,
            "{}: {} vs truth {} is more than 3σ = {}",
            est.name,
            est.value,
            t[k],
            3.0 * sd
        );
    }
}

fn pinhole_tolerances(t: &PinholeRadTan) -> [f64; 9] {
    let [fx, fy, cx, cy] = t.intrinsics();
    [
        1e-3 * fx,
        1e-3 * fy,
        2e-3 * cx,
        2e-3 * cy,
        1e-2,
        3e-2,
        1e-3,
        1e-3,
        3e-2,
    ]
}

#[test]
fn pinhole_synthetic_recovers_truth() {
    let truth = pinhole_truth();
    let cam: Camera = truth.clone().into();
    let board = pinhole_board();
    let obs = synthesise(&cam, &board, &pinhole_poses(), (640, 480), 0.1, 7);
    let cal = calibrate(
        &obs,
        &board,
        ModelKind::PinholeRadTan,
        (640, 480),
        &CalibOptions::default(),
        &NoProgress,
    )
    .expect("calibrates");
    eprintln!(
        "pinhole: rms {:.4} params {:?} std {:?} iterations {} rejected {:?}",
        cal.rms,
        cal.camera.params(),
        cal.parameters.iter().map(|p| p.std_dev).collect::<Vec<_>>(),
        cal.iterations,
        cal.rejected_corners
    );
    assert!(cal.rejected_views.is_empty() && cal.rejected_corners.is_empty());
    check_accuracy(&cal, &cam, &pinhole_tolerances(&truth));
    // σ = 0.1 px per coordinate, so the RMS of the residual norm (OpenCV's definition) is
    // 0.1·√2 less what the fit absorbs.
    assert!((cal.sigma - 0.1).abs() < 0.01, "sigma {}", cal.sigma);
    assert!(
        (cal.rms - 0.1 * std::f64::consts::SQRT_2).abs() < 0.015,
        "rms {}",
        cal.rms
    );
    assert_eq!(cal.num_inliers, cal.num_corners);
    assert_eq!(cal.views.len(), 12);
    // Poses: the first view's translation.
    let t0 = pinhole_poses()[0].translation;
    let tv = cal.views[0].tvec.expect("pose");
    assert!((Vector3::from(tv) - t0).norm() < 1e-3);
    // Projection uncertainty is reported and small at the centre.
    let centre = &cal.projection_uncertainty[0];
    assert_eq!(centre.location, "centre");
    assert!(
        centre.std_major > 0.0 && centre.std_major < 0.5,
        "{centre:?}"
    );
    // The result is a serde document.
    let json = serde_json::to_string(&cal).expect("serialises");
    let back: Calibration = serde_json::from_str(&json).expect("deserialises");
    assert_eq!(back.camera, cal.camera);
}

#[test]
fn pinhole_outliers_are_rejected_with_reasons() {
    let truth = pinhole_truth();
    let cam: Camera = truth.clone().into();
    let board = pinhole_board();
    let mut obs = synthesise(&cam, &board, &pinhole_poses(), (640, 480), 0.1, 11);
    let corrupt = [(1usize, 3usize), (4, 10), (7, 20), (10, 0)];
    for &(v, k) in &corrupt {
        obs[v].corners[k].pixel[0] += 20.0;
    }
    let cal = calibrate(
        &obs,
        &board,
        ModelKind::PinholeRadTan,
        (640, 480),
        &CalibOptions::default(),
        &NoProgress,
    )
    .expect("calibrates");
    assert_eq!(
        cal.rejected_corners.len(),
        corrupt.len(),
        "{:?}",
        cal.rejected_corners
    );
    for &(v, k) in &corrupt {
        let index = obs[v].corners[k].index;
        let r = cal
            .rejected_corners
            .iter()
            .find(|r| r.view == v && r.index == index)
            .expect("rejected");
        assert!(r.reason.contains("residual"), "{}", r.reason);
    }
    assert!(cal.rejected_views.is_empty());
    check_accuracy(&cal, &cam, &pinhole_tolerances(&truth));
    assert!(cal.rms < 0.15, "inlier rms {}", cal.rms);
    assert!(cal.rms_all > 1.0, "all-corner rms {}", cal.rms_all);
    let outliers = cal.residuals.iter().filter(|r| !r.inlier).count();
    assert_eq!(outliers, corrupt.len());
}

#[test]
fn pinhole_fixed_parameter_options() {
    let truth =
        PinholeRadTan::new(530.0, 530.0, 319.5, 239.5, -0.2, 0.05, 0.0, 0.0, 0.0).expect("valid");
    let cam: Camera = truth.clone().into();
    let board = pinhole_board();
    let obs = synthesise(&cam, &board, &pinhole_poses()[..8], (640, 480), 0.1, 3);
    let options = CalibOptions {
        fix_aspect_ratio: true,
        fix_principal_point: true,
        fix_k3: true,
        zero_tangential: true,
        ..CalibOptions::default()
    };
    let cal = calibrate(
        &obs,
        &board,
        ModelKind::PinholeRadTan,
        (640, 480),
        &options,
        &NoProgress,
    )
    .expect("calibrates");
    let p = cal.camera.params();
    assert_eq!(p[0], p[1], "aspect ratio 1");
    assert_eq!((p[2], p[3]), (319.5, 239.5));
    assert_eq!((p[6], p[7], p[8]), (0.0, 0.0, 0.0));
    assert_close("fx", p[0], 530.0, 0.53);
    assert_close("k1", p[4], -0.2, 2e-3);
    let fixed: Vec<&str> = cal
        .parameters
        .iter()
        .filter(|e| e.fixed)
        .map(|e| e.name.as_str())
        .collect();
    assert_eq!(fixed, ["cx", "cy", "p1", "p2", "k3"]);
    let sd = |name: &str| {
        cal.parameters
            .iter()
            .find(|e| e.name == name)
            .and_then(|e| e.std_dev)
            .expect("std")
    };
    assert_eq!(sd("cx"), 0.0);
    assert_eq!(sd("k3"), 0.0);
    assert!(sd("fx") > 0.0 && (sd("fx") - sd("fy")).abs() < 1e-12);
}

fn kb_truth() -> KannalaBrandt {
    KannalaBrandt::new(190.0, 190.0, 319.3, 319.2, -0.0003, -0.003, 0.0013, -0.001).expect("valid")
}

/// A 4×6 board (unit squares) seen at wide angles: centres up to ~70° off-axis, tilts up to
/// ~60°.
fn kb_poses(board: &BoardGeometry) -> Vec<Se3> {
    let spec: [([f64; 3], [f64; 2], f64); 14] = [
        ([0.0, 0.0, 0.0], [0.0, 0.0], 6.0),
        ([0.3, 0.0, 0.2], [0.0, 0.0], 4.0),
        ([0.0, 0.8, 0.0], [1.2, 0.0], 4.0),
        ([0.0, -0.8, 0.3], [-1.2, 0.1], 4.0),
        ([-0.8, 0.0, 0.0], [0.0, 1.3], 4.0),
        ([0.8, 0.0, -0.3], [0.1, -1.3], 4.0),
        ([0.5, 0.6, 0.5], [1.5, -1.5], 3.0),
        ([-0.5, -0.6, 1.0], [-1.5, 1.5], 3.0),
        ([0.6, -0.6, -0.8], [-2.0, -1.5], 2.5),
        ([-0.6, 0.6, 0.4], [2.0, 1.5], 2.5),
        ([0.2, 0.3, 1.5], [0.5, 0.5], 3.5),
        ([-0.3, 0.2, -1.2], [-0.6, 0.4], 3.5),
        ([0.0, 1.0, 0.0], [2.5, 0.0], 2.5),
        ([1.0, 0.0, 0.0], [0.0, -2.5], 2.5),
    ];
    spec.iter()
        .map(|(r, d, z)| board_pose(board, *r, *d, *z))
        .collect()
}

#[test]
fn kannala_brandt_synthetic_without_guess() {
    let truth = kb_truth();
    let cam: Camera = truth.clone().into();
    let board = BoardGeometry {
        cols: 4,
        rows: 6,
        square: 1.0,
    };
    let obs = synthesise(&cam, &board, &kb_poses(&board), (640, 720), 0.1, 5);
    let cal = calibrate(
        &obs,
        &board,
        ModelKind::KannalaBrandt,
        (640, 720),
        &CalibOptions::default(),
        &NoProgress,
    )
    .expect("calibrates");
    eprintln!(
        "kb: rms {:.4} initial {:?} params {:?} std {:?} iterations {} rejected {:?} {:?}",
        cal.rms,
        cal.initial_camera.params(),
        cal.camera.params(),
        cal.parameters.iter().map(|p| p.std_dev).collect::<Vec<_>>(),
        cal.iterations,
        cal.rejected_corners,
        cal.rejected_views
    );
    assert!(cal.rejected_views.is_empty());
    let t = truth.params();
    // σ(fx) ≈ 0.3 px, σ(c) ≈ 0.1 px, σ(k1..k3) ≈ 0.002–0.003, σ(k4) ≈ 3·10⁻⁴ for 14 views of
    // 24 corners at 0.1 px: bounds at about 4σ (see `check_accuracy`).
    let tol = [
        6e-3 * t[0],
        6e-3 * t[1],
        2e-3 * t[2],
        2e-3 * t[3],
        1e-2,
        1.5e-2,
        1e-2,
        1.5e-3,
    ];
    check_accuracy(&cal, &cam, &tol);
    assert!((cal.sigma - 0.1).abs() < 0.015, "sigma {}", cal.sigma);
}

// ---------------------------------------------------------------- building blocks

fn grid() -> Vec<Vector2<f64>> {
    (0..24)
        .map(|k| Vector2::new((k % 6) as f64 * 0.03, (k / 6) as f64 * 0.03))
        .collect()
}

#[test]
fn homography_exact_and_refined() {
    let h_true = Matrix3::new(520.0, 40.0, 300.0, -30.0, 480.0, 200.0, 0.2, -0.3, 1.0);
    let src = grid();
    let dst: Vec<Vector2<f64>> = src
        .iter()
        .map(|p| transfer(&h_true, p).expect("finite"))
        .collect();
    let h = homography(&src, &dst).expect("solves");
    let h = h / h[(2, 2)];
    assert!((h - h_true).norm() < 1e-8 * h_true.norm(), "{h}");

    // With noise, the refinement does not increase the transfer error of the DLT.
    let mut rng = Rng::new(42);
    let noisy: Vec<Vector2<f64>> = dst
        .iter()
        .map(|p| p + Vector2::new(rng.gauss(), rng.gauss()) * 0.5)
        .collect();
    let err = |h: &Matrix3<f64>| -> f64 {
        src.iter()
            .zip(&noisy)
            .map(|(s, d)| (transfer(h, s).expect("finite") - d).norm_squared())
            .sum()
    };
    let dlt = homography_dlt(&src, &noisy).expect("dlt");
    let refined = refine_homography(&dlt, &src, &noisy).expect("refined");
    assert!(err(&refined) <= err(&dlt) + 1e-12);

    // Collinear points have no unique homography; too few points are rejected.
    let line: Vec<Vector2<f64>> = (0..6)
        .map(|k| Vector2::new(k as f64, 2.0 * k as f64))
        .collect();
    assert!(matches!(
        homography(&line, &line),
        Err(CoreError::NoSolution(_))
    ));
    assert!(matches!(
        homography(&src[..3], &dst[..3]),
        Err(CoreError::InvalidInput(_))
    ));
}

fn zhang_views(k: &Matrix3<f64>, rvecs: &[[f64; 3]]) -> Vec<Matrix3<f64>> {
    rvecs
        .iter()
        .map(|r| {
            let pose = Se3::new(
                So3::exp(&Vector3::from(*r)),
                Vector3::new(-0.05, -0.04, 0.4),
            );
            let rm = pose.rotation.matrix();
            let m = Matrix3::from_columns(&[
                rm.column(0).into_owned(),
                rm.column(1).into_owned(),
                pose.translation,
            ]);
            k * m
        })
        .collect()
}

#[test]
fn zhang_closed_form_recovers_k() {
    let k = Matrix3::new(536.0, 0.0, 342.0, 0.0, 530.0, 235.0, 0.0, 0.0, 1.0);
    let hs = zhang_views(
        &k,
        &[
            [0.4, 0.0, 0.1],
            [0.0, 0.5, -0.2],
            [-0.3, -0.3, 0.4],
            [0.2, -0.4, 0.0],
        ],
    );
    let est = zhang_intrinsics(&hs, (640, 480)).expect("solves");
    assert!(
        (est.fx - 536.0).abs() < 1e-6 && (est.fy - 530.0).abs() < 1e-6,
        "{est:?}"
    );
    assert!(
        (est.cx - 342.0).abs() < 1e-6 && (est.cy - 235.0).abs() < 1e-6,
        "{est:?}"
    );
    assert!(est.skew.abs() < 1e-6);

    // Two views: zero skew assumed.
    let est = zhang_intrinsics(&hs[..2], (640, 480)).expect("solves");
    assert!(
        (est.fx - 536.0).abs() < 1e-6 && (est.cy - 235.0).abs() < 1e-6,
        "{est:?}"
    );

    // Pose from H and K.
    let pose = pose_from_homography(&hs[2], &k).expect("pose");
    let want = So3::exp(&Vector3::new(-0.3, -0.3, 0.4));
    assert!(pose.rotation.left_minus(&want).norm() < 1e-9);
    assert!((pose.translation - Vector3::new(-0.05, -0.04, 0.4)).norm() < 1e-9);

    // Fixed-centre fallback.
    let est = intrinsics_fixed_centre(&hs, Vector2::new(342.0, 235.0), (640, 480)).expect("f");
    assert!(
        (est.fx - 536.0).abs() < 1e-6 && (est.fy - 530.0).abs() < 1e-6,
        "{est:?}"
    );

    // Degenerate: boards all parallel to the image plane.
    let flat = zhang_views(&k, &[[0.0, 0.0, 0.1], [0.0, 0.0, 0.5], [0.0, 0.0, -0.7]]);
    assert!(matches!(
        zhang_intrinsics(&flat, (640, 480)),
        Err(CoreError::NoSolution(_))
    ));
    assert!(matches!(
        zhang_intrinsics(&hs[..1], (640, 480)),
        Err(CoreError::NoSolution(_))
    ));
}

#[test]
fn pnp_with_distortion() {
    let cam: Camera = pinhole_truth().into();
    let board = pinhole_board();
    let pose = pinhole_poses()[5];
    let pts: Vec<Vector2<f64>> = (0..board.num_corners())
        .map(|k| board.object_point(k).expect("in board").xy())
        .collect();
    let px: Vec<Vector2<f64>> = pts
        .iter()
        .map(|p| {
            cam.project(&pose.act(&Vector3::new(p.x, p.y, 0.0)))
                .expect("projects")
        })
        .collect();
    let est = estimate_pose(&cam, &pts, &px, &NoProgress).expect("pose");
    assert!(est.left_minus(&pose).norm() < 1e-8, "{est:?} vs {pose:?}");
}

struct CancelAfter(std::sync::atomic::AtomicUsize);

impl Progress for CancelAfter {
    fn report(&self, _: &str, _: u64, _: u64) {}
    fn is_canceled(&self) -> bool {
        self.0.fetch_sub(1, std::sync::atomic::Ordering::SeqCst) == 0
    }
}

#[test]
fn cancel_is_honoured() {
    let cam: Camera = pinhole_truth().into();
    let board = pinhole_board();
    let obs = synthesise(&cam, &board, &pinhole_poses()[..6], (640, 480), 0.1, 1);
    for budget in [0, 30] {
        let r = calibrate(
            &obs,
            &board,
            ModelKind::PinholeRadTan,
            (640, 480),
            &CalibOptions::default(),
            &CancelAfter(std::sync::atomic::AtomicUsize::new(budget)),
        );
        assert!(
            matches!(r, Err(CoreError::Canceled)),
            "budget {budget}: {r:?}"
        );
    }
}

#[test]
fn invalid_inputs() {
    let board = pinhole_board();
    let run = |obs: &[ViewObservations], b: &BoardGeometry, o: &CalibOptions, m: ModelKind| {
        calibrate(obs, b, m, (640, 480), o, &NoProgress)
    };
    let pin = ModelKind::PinholeRadTan;
    let d = CalibOptions::default();
    let view = |corners: Vec<CornerObservation>| ViewObservations {
        name: "v".into(),
        corners,
    };
    let c = |index: usize| CornerObservation {
        index,
        pixel: [index as f64, 1.0],
    };
    let r = run(&[view(vec![c(54)])], &board, &d, pin);
    assert!(matches!(r, Err(CoreError::InvalidInput(_))), "{r:?}");
    let r = run(&[view(vec![c(1), c(1)])], &board, &d, pin);
    assert!(matches!(r, Err(CoreError::InvalidInput(_))), "{r:?}");
    let r = run(&[view((0..10).map(c).collect())], &board, &d, pin);
    assert!(matches!(r, Err(CoreError::NoSolution(_))), "{r:?}");
    let bad_board = BoardGeometry {
        square: 0.0,
        ..board
    };
    assert!(matches!(
        run(&[], &bad_board, &d, pin),
        Err(CoreError::InvalidParam { .. })
    ));
    let k3 = CalibOptions { fix_k3: true, ..d };
    assert!(matches!(
        run(&[], &board, &k3, ModelKind::KannalaBrandt),
        Err(CoreError::InvalidParam { .. })
    ));
    let dense = ViewObservations::from_dense("x", &[None, Some([1.0, 2.0]), None]);
    assert_eq!(
        dense.corners,
        vec![CornerObservation {
            index: 1,
            pixel: [1.0, 2.0]
        }]
    );
    let opts: CalibOptions = serde_json::from_str("{}").expect("defaults");
    assert_eq!(opts, CalibOptions::default());
}

// ---------------------------------------------------------------- real data (shared)

fn shared_data(rel: &str) -> Option<std::path::PathBuf> {
    crate::test_env::shared_data(rel)
}

/// Left camera of OpenCV's stereo sample, on the corners OpenCV refined, against OpenCV 4.14's
/// `calibrateCamera` with flags 0 (plain least squares, no rejection, as OpenCV does).
#[test]
fn calib_opencv_stereo_left_matches_opencv() {
    let (Some(corners), Some(reference)) = (
        shared_data("camera/corners/opencv_stereo.json"),
        shared_data("camera/reference/opencv_stereo.json"),
    ) else {
        return;
    };
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(corners).expect("read")).expect("json");
    let cols = doc["pattern"][0].as_u64().expect("cols") as usize;
    let rows = doc["pattern"][1].as_u64().expect("rows") as usize;
    let square = doc["square"].as_f64().expect("square");
    let board = BoardGeometry { cols, rows, square };
    let left = doc["corners"]["left"].as_object().expect("left");
    let mut names: Vec<&String> = left.keys().collect();
    names.sort();
    let obs: Vec<ViewObservations> = names
        .iter()
        .filter_map(|name| {
            let pts = left[*name].as_array()?;
            let dense: Vec<Option<[f64; 2]>> = pts
                .iter()
                .map(|p| Some([p[0].as_f64()?, p[1].as_f64()?]))
                .collect();
            Some(ViewObservations::from_dense(name.as_str(), &dense))
        })
        .collect();
    let options = CalibOptions {
        loss: RobustLoss::None,
        reject_outliers: false,
        ..CalibOptions::default()
    };
    let t = std::time::Instant::now();
    let cal = calibrate(
        &obs,
        &board,
        ModelKind::PinholeRadTan,
        (640, 480),
        &options,
        &NoProgress,
    )
    .expect("calibrates");
    let elapsed = t.elapsed();
    let refdoc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(reference).expect("read")).expect("json");
    let r = &refdoc["left"]["models"]["pinhole_k5"];
    let want = |k: &str| r[k].as_f64().expect("number");
    let p = cal.camera.params();
    eprintln!(
        "solve time {elapsed:?}, {} iterations, {:?}",
        cal.iterations, cal.termination
    );
    eprintln!(
        "{:>4} {:>14} {:>14} {:>10} {:>10}",
        "", "caliper", "opencv", "σ caliper", "σ opencv"
    );
    for (k, name) in ["fx", "fy", "cx", "cy"].iter().enumerate() {
        eprintln!(
            "{name:>4} {:>14.6} {:>14.6} {:>10.4} {:>10.4}",
            p[k],
            want(name),
            cal.parameters[k].std_dev.unwrap_or(f64::NAN),
            r["std_intrinsics"][name].as_f64().unwrap_or(f64::NAN)
        );
    }
    for (k, name) in ["k1", "k2", "p1", "p2", "k3"].iter().enumerate() {
        eprintln!(
            "{name:>4} {:>14.8} {:>14.8} {:>10.6} {:>10.6}",
            p[4 + k],
            r["dist"][name].as_f64().unwrap_or(f64::NAN),
            cal.parameters[4 + k].std_dev.unwrap_or(f64::NAN),
            r["std_intrinsics"][name].as_f64().unwrap_or(f64::NAN)
        );
    }
    eprintln!("rms  {:>14.6} {:>14.6}", cal.rms, want("rms"));
    for v in &cal.views {
        eprintln!(
            "  {} rms {:.4} (opencv {:.4})",
            v.name,
            v.rms.unwrap_or(f64::NAN),
            r["per_view_rms"][&v.name].as_f64().unwrap_or(f64::NAN)
        );
    }
    for (k, name) in ["fx", "fy", "cx", "cy"].iter().enumerate() {
        assert!(
            (p[k] - want(name)).abs() < 0.01,
            "{name}: {} vs {}",
            p[k],
            want(name)
        );
    }
    assert!(
        (cal.rms - want("rms")).abs() < 1e-4,
        "rms {} vs {}",
        cal.rms,
        want("rms")
    );
}

/// The reported σ of every parameter is calibrated: over repeated noise draws, the errors
/// normalised by their σ have an RMS near 1 (an overconfident σ gives ≫ 1, a timid one ≪ 1).
#[test]
fn reported_sigmas_match_the_spread_over_noise_draws() {
    let board = pinhole_board();
    let kb_board = BoardGeometry {
        cols: 4,
        rows: 6,
        square: 1.0,
    };
    type Case = (Camera, BoardGeometry, Vec<Se3>, (u32, u32), ModelKind);
    let cases: [Case; 2] = [
        (
            pinhole_truth().into(),
            board,
            pinhole_poses(),
            (640, 480),
            ModelKind::PinholeRadTan,
        ),
        (
            kb_truth().into(),
            kb_board,
            kb_poses(&kb_board),
            (640, 720),
            ModelKind::KannalaBrandt,
        ),
    ];
    for (cam, board, poses, size, kind) in cases {
        let mut zs = Vec::new();
        for seed in 1..16 {
            let obs = synthesise(&cam, &board, &poses, size, 0.1, seed);
            let cal = calibrate(
                &obs,
                &board,
                kind,
                size,
                &CalibOptions::default(),
                &NoProgress,
            )
            .expect("calibrates");
            zs.extend(
                cal.parameters
                    .iter()
                    .zip(cam.params())
                    .map(|(e, t)| (e.value - t) / e.std_dev.unwrap_or(f64::NAN)),
            );
        }
        let rms = (zs.iter().map(|z| z * z).sum::<f64>() / zs.len() as f64).sqrt();
        eprintln!(
            "{kind:?}: RMS of normalised errors {rms:.2} over {} values",
            zs.len()
        );
        assert!(
            (0.5..2.0).contains(&rms),
            "{kind:?}: σ miscalibrated, RMS z = {rms}"
        );
    }
}

/// BoofCV's fisheye chessboard set (26 views, 640×720) through Kannala-Brandt from the no-guess
/// start, beside OpenCV 4.14's `fisheye.calibrate` (which needs f0 = max(w,h)/π and drops views
/// 4, 5, 6 as ill-conditioned). Prints both; asserts only that every view is kept and the fit
/// is sane.
#[test]
fn calib_boofcv_fisheye_kannala_brandt() {
    let (Some(corners), Some(reference)) = (
        shared_data("camera/corners/boofcv_fisheye_chessboard.json"),
        shared_data("camera/reference/boofcv_fisheye_chessboard.json"),
    ) else {
        return;
    };
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(corners).expect("read")).expect("json");
    let board = BoardGeometry {
        cols: doc["pattern"][0].as_u64().expect("cols") as usize,
        rows: doc["pattern"][1].as_u64().expect("rows") as usize,
        square: doc["square"].as_f64().expect("square"),
    };
    let files = doc["corners"].as_object().expect("corners");
    let mut names: Vec<&String> = files.keys().collect();
    names.sort_by_key(|n| {
        n.trim_end_matches(".jpg")
            .parse::<u32>()
            .unwrap_or(u32::MAX)
    });
    let obs: Vec<ViewObservations> = names
        .iter()
        .filter_map(|name| {
            let pts = files[*name].as_array()?;
            let dense: Vec<Option<[f64; 2]>> = pts
                .iter()
                .map(|p| Some([p[0].as_f64()?, p[1].as_f64()?]))
                .collect();
            Some(ViewObservations::from_dense(name.as_str(), &dense))
        })
        .collect();
    let refdoc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(reference).expect("read")).expect("json");
    let r = &refdoc["models"]["fisheye_kb4"];
    eprintln!(
        "opencv  fx {} fy {} cx {} cy {} k {} rms {} dropped {}",
        r["fx"], r["fy"], r["cx"], r["cy"], r["dist_vector"], r["rms"], r["views_dropped"]
    );
    for (label, options) in [
        (
            "least squares, no rejection",
            CalibOptions {
                loss: RobustLoss::None,
                reject_outliers: false,
                ..CalibOptions::default()
            },
        ),
        ("defaults (Huber 1 px, rejection)", CalibOptions::default()),
    ] {
        let t = std::time::Instant::now();
        let cal = calibrate(
            &obs,
            &board,
            ModelKind::KannalaBrandt,
            (640, 720),
            &options,
            &NoProgress,
        )
        .expect("calibrates");
        eprintln!(
            "caliper [{label}] {:?}: params {:?}\n  std {:?}\n  rms {:.4} (all {:.4}), {} iterations, initial f {:.2}, rejected views {:?}, {} corners rejected",
            t.elapsed(),
            cal.camera.params(),
            cal.parameters
                .iter()
                .map(|p| p.std_dev.unwrap_or(f64::NAN))
                .collect::<Vec<_>>(),
            cal.rms,
            cal.rms_all,
            cal.iterations,
            cal.initial_camera.params()[0],
            cal.rejected_views
                .iter()
                .map(|v| (&v.name, &v.reason))
                .collect::<Vec<_>>(),
            cal.rejected_corners.len()
        );
        let worst = cal
            .views
            .iter()
            .filter_map(|v| Some((v.rms?, &v.name)))
            .max_by(|a, b| a.0.total_cmp(&b.0));
        eprintln!("  worst view {worst:?}");
        assert!(cal.rms < 1.0);
    }
}
