//! Detector tests on synthetic renders with known corners (fast, deterministic) and, ignored by
//! default, on the shared real image sets.

use nalgebra::{Vector2, Vector3};

use super::*;
use crate::NoProgress;
use crate::calib::{BoardGeometry, CalibOptions, ModelKind, calibrate};
use crate::camera::{Camera, CameraModel, KannalaBrandt, PinholeRadTan};
use crate::lie::{Se3, So3};
use crate::synth::{RenderOptions, SynthView, render_chessboard};

fn pinhole() -> Camera {
    PinholeRadTan::new(520.0, 515.0, 322.0, 238.0, -0.28, 0.09, 0.001, -0.0005, 0.0)
        .map(Camera::from)
        .expect("valid pinhole")
}

fn fisheye() -> Camera {
    KannalaBrandt::new(200.0, 200.0, 319.5, 319.5, 0.02, -0.01, 0.002, 0.0)
        .map(Camera::from)
        .expect("valid fisheye")
}

/// `T_cam_board` placing the board centre on the ray through pixel `centre`, `dist` away,
/// turned by the rotation vector `rot` from fronto-parallel to the optical axis.
fn look(
    camera: &Camera,
    board: (usize, usize, f64),
    centre: [f64; 2],
    dist: f64,
    rot: [f64; 3],
) -> Se3 {
    look_at(camera, board, centre, dist, rot, false)
}

/// As [`look`]; with `face`, `rot` is from facing the camera along the ray (so its angle is
/// the true viewing angle, wherever the board is in a fisheye image).
fn look_at(
    camera: &Camera,
    board: (usize, usize, f64),
    centre: [f64; 2],
    dist: f64,
    rot: [f64; 3],
    face: bool,
) -> Se3 {
    let ray = camera
        .unproject(&Vector2::new(centre[0], centre[1]))
        .expect("pixel has a ray");
    let mut r = So3::from_rotation_vector(&Vector3::new(rot[0], rot[1], rot[2]));
    if face {
        let z = Vector3::new(0.0, 0.0, 1.0);
        let axis = z.cross(&ray);
        let angle = z.dot(&ray).clamp(-1.0, 1.0).acos();
        let f = if axis.norm() > 1e-12 {
            So3::from_rotation_vector(&(axis.normalize() * angle))
        } else {
            So3::identity()
        };
        r = f * r;
    }
    let c = Vector3::new(
        (board.0 - 1) as f64 * board.2 / 2.0,
        (board.1 - 1) as f64 * board.2 / 2.0,
        0.0,
    );
    Se3::new(r, ray * dist - r.act(&c))
}

fn render(
    camera: &Camera,
    pose: &Se3,
    board: (usize, usize, f64),
    size: (u32, u32),
    opts: &RenderOptions,
) -> SynthView {
    let v = render_chessboard(camera, pose, board, size, opts).expect("render");
    assert!(
        v.all_visible(),
        "test setup: every corner must be in the image"
    );
    v
}

/// Per-corner errors against the truth, in the detector's order.
fn errors(found: &[[f64; 2]], truth: &[Option<[f64; 2]>]) -> Vec<f64> {
    found
        .iter()
        .zip(truth)
        .map(|(a, b)| {
            let b = b.expect("visible");
            (a[0] - b[0]).hypot(a[1] - b[1])
        })
        .collect()
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Detects every view and returns all corner errors; asserts detection and order.
fn run_views(
    camera: &Camera,
    board: (usize, usize, f64),
    size: (u32, u32),
    views: &[([f64; 2], f64, [f64; 3])],
    opts: &RenderOptions,
    face: bool,
) -> Vec<f64> {
    let mut all = Vec::new();
    for (k, (centre, dist, rot)) in views.iter().enumerate() {
        let pose = look_at(camera, board, *centre, *dist, *rot, face);
        let ro = RenderOptions {
            seed: opts.seed + k as u64,
            ..opts.clone()
        };
        let v = render(camera, &pose, board, size, &ro);
        let d = detect_chessboard(&v.image, board.0, board.1, &DetectOptions::default());
        let Detection::Found { corners, .. } = &d else {
            let path = std::env::temp_dir().join(format!("caliper_fail_{}_{k}.png", opts.seed));
            let _ = image::GrayImage::from_raw(v.image.width, v.image.height, v.image.data.clone())
                .map(|im| im.save(&path));
            panic!("view {k}: {d:?} (image saved to {})", path.display());
        };
        let e = errors(corners, &v.corners);
        let worst = e.iter().copied().fold(0.0, f64::max);
        assert!(
            worst < 0.5,
            "view {k}: wrong order or corner, worst error {worst:.3} px"
        );
        all.extend(e);
    }
    all
}

fn summary(label: &str, e: &[f64]) -> (f64, f64) {
    let med = median(e.to_vec());
    let max = e.iter().copied().fold(0.0, f64::max);
    println!(
        "{label}: {} corners, median error {med:.4} px, max {max:.4} px",
        e.len()
    );
    (med, max)
}

const B96: (usize, usize, f64) = (9, 6, 0.03);

fn pinhole_views() -> Vec<([f64; 2], f64, [f64; 3])> {
    vec![
        ([320.0, 240.0], 0.45, [0.1, -0.1, 0.05]),
        ([200.0, 150.0], 0.5, [0.6, 0.3, 0.2]),
        ([450.0, 330.0], 0.5, [-0.5, 0.6, -0.3]),
        ([330.0, 250.0], 0.6, [0.0, 0.9, 1.2]),
        ([160.0, 330.0], 0.55, [0.8, -0.2, 2.0]),
        ([480.0, 140.0], 0.6, [-0.3, -0.7, -0.4]),
        ([320.0, 240.0], 0.4, [0.5, 0.5, 3.0]),
        ([250.0, 260.0], 0.7, [-0.8, 0.1, 0.8]),
        ([400.0, 200.0], 0.45, [0.2, 0.5, -1.5]),
        ([300.0, 280.0], 0.5, [0.4, -0.6, 0.3]),
    ]
}

#[test]
fn pinhole_with_distortion_noise_and_blur() {
    let opts = RenderOptions {
        noise_sigma: 1.0,
        blur_sigma: 0.6,
        ..RenderOptions::default()
    };
    let e = run_views(&pinhole(), B96, (640, 480), &pinhole_views(), &opts, false);
    let (med, max) = summary("pinhole σn=1 σb=0.6", &e);
    assert!(med < 0.05, "median {med}");
    assert!(max < 0.25, "max {max}");
}

#[test]
fn strong_fisheye_near_the_border_tilted() {
    // Boards seen 50–60° from face-on, centred 45–65° off the axis, near the image border,
    // and one at the centre.
    let views = vec![
        ([130.0, 320.0], 0.3, [0.0, 0.95, 0.0]),
        ([520.0, 170.0], 0.3, [0.8, -0.5, 0.3]),
        ([320.0, 530.0], 0.28, [-1.0, 0.0, 0.5]),
        ([170.0, 150.0], 0.32, [0.6, 0.7, -0.4]),
        ([500.0, 470.0], 0.3, [-0.6, -0.7, 1.2]),
        ([320.0, 320.0], 0.25, [0.0, 1.0, 0.0]),
        ([110.0, 420.0], 0.3, [0.9, 0.4, 2.0]),
        ([540.0, 330.0], 0.3, [0.3, -0.9, -1.0]),
    ];
    let opts = RenderOptions {
        noise_sigma: 2.0,
        blur_sigma: 0.8,
        background: 60.0,
        ..RenderOptions::default()
    };
    let e = run_views(&fisheye(), B96, (640, 640), &views, &opts, true);
    let (med, max) = summary("fisheye KB σn=2 σb=0.8", &e);
    assert!(med < 0.1, "median {med}");
    assert!(max < 0.4, "max {max}");
}

#[test]
fn motion_blur_gaussian_blur_and_uneven_light() {
    let cam = pinhole();
    let views = &pinhole_views()[..4];
    for (label, opts) in [
        (
            "motion 9 px",
            RenderOptions {
                motion_blur_px: 9.0,
                noise_sigma: 1.0,
                ..RenderOptions::default()
            },
        ),
        (
            "gauss σ=3",
            RenderOptions {
                blur_sigma: 3.0,
                noise_sigma: 1.0,
                ..RenderOptions::default()
            },
        ),
        (
            "light ramp ×0.6..×1.4",
            RenderOptions {
                light_gradient: 0.8,
                white: 180.0,
                noise_sigma: 0.5,
                ..RenderOptions::default()
            },
        ),
    ] {
        let e = run_views(&cam, B96, (640, 480), views, &opts, false);
        let (med, _) = summary(label, &e);
        assert!(med < 0.1, "{label}: median {med}");
    }
}

/// Under a light ramp (×0.6 … ×1.4 across the image) the saddle points drift with the mean
/// grey level times the ramp; `light_correction` measures the ramp on the white squares and
/// divides it out.
#[test]
fn light_correction_keeps_corners_on_the_junction_under_a_light_ramp() {
    let cam = pinhole();
    let opts = RenderOptions {
        light_gradient: 0.8,
        white: 180.0,
        noise_sigma: 0.5,
        ..RenderOptions::default()
    };
    let lit = DetectOptions {
        light_correction: true,
        ..DetectOptions::default()
    };
    let (mut plain, mut fixed) = (Vec::new(), Vec::new());
    for (k, (centre, dist, rot)) in pinhole_views()[..6].iter().enumerate() {
        let pose = look_at(&cam, B96, *centre, *dist, *rot, false);
        let ro = RenderOptions {
            seed: 40 + k as u64,
            ..opts.clone()
        };
        let v = render(&cam, &pose, B96, (640, 480), &ro);
        for (o, out) in [
            (DetectOptions::default(), &mut plain),
            (lit.clone(), &mut fixed),
        ] {
            let Detection::Found { corners, .. } = detect_chessboard(&v.image, B96.0, B96.1, &o)
            else {
                panic!("view {k} not found");
            };
            out.extend(errors(&corners, &v.corners));
        }
    }
    let rms = |e: &[f64]| (e.iter().map(|x| x * x).sum::<f64>() / e.len() as f64).sqrt();
    let (a, b) = (rms(&plain), rms(&fixed));
    println!("light ramp: RMS {a:.4} px uncorrected, {b:.4} px corrected");
    assert!(b < 0.75 * a && b < 0.04, "uncorrected {a}, corrected {b}");
}

#[test]
fn no_board_partial_board_and_wrong_size_are_not_found() {
    let opts = DetectOptions::default();
    // Noise and a few flat rectangles.
    let mut data = vec![0u8; 640 * 480];
    let mut s = 12345u64;
    for (k, v) in data.iter_mut().enumerate() {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        let (x, y) = (k % 640, k / 640);
        let base = if (100..300).contains(&x) && (50..200).contains(&y) {
            200
        } else {
            80
        };
        *v = (base + (s >> 60) as i32) as u8;
    }
    let noise = Gray::new(640, 480, data).expect("gray");
    assert!(!detect_chessboard(&noise, 9, 6, &opts).is_found());

    let cam = pinhole();
    // Half the board outside the image.
    let pose = look(&cam, B96, [600.0, 240.0], 0.45, [0.0, 0.0, 0.0]);
    let v =
        render_chessboard(&cam, &pose, B96, (640, 480), &RenderOptions::default()).expect("render");
    assert!(!v.all_visible());
    let d = detect_chessboard(&v.image, 9, 6, &opts);
    assert!(!d.is_found(), "partial board: {d:?}");
    println!("partial: {d:?}");

    // A whole board, but asked for other sizes.
    let pose = look(&cam, B96, [320.0, 240.0], 0.45, [0.2, 0.1, 0.1]);
    let v = render(&cam, &pose, B96, (640, 480), &RenderOptions::default());
    for (c, r) in [(8, 5), (9, 5), (10, 6), (7, 4)] {
        let d = detect_chessboard(&v.image, c, r, &opts);
        assert!(!d.is_found(), "{c}×{r}: {d:?}");
        println!("{c}×{r}: {d:?}");
    }
    // …and the right size either way round gives the same board.
    let a = detect_chessboard(&v.image, 9, 6, &opts);
    assert!(a.is_found());
    let b = detect_chessboard(&v.image, 6, 9, &opts);
    assert!(b.is_found(), "{b:?}");
}

#[test]
fn symmetric_board_orders_deterministically() {
    // 4×6 inner corners (5×7 squares): symmetric under a half turn; check it is found and
    // ordered with positive handedness and the last row below the first.
    let board = (4, 6, 0.04);
    let cam = pinhole();
    for (k, rot) in [[0.1, 0.2, 0.0], [0.2, -0.3, 3.1], [0.0, 0.4, 1.5]]
        .iter()
        .enumerate()
    {
        let pose = look(&cam, board, [320.0, 240.0], 0.5, *rot);
        let v = render(&cam, &pose, board, (640, 480), &RenderOptions::default());
        let d = detect_chessboard(&v.image, 4, 6, &DetectOptions::default());
        let c = d.corners().unwrap_or_else(|| panic!("view {k}: {d:?}"));
        let (a, b) = (sub(c[1], c[0]), sub(c[4], c[0]));
        assert!(a[0] * b[1] - a[1] * b[0] > 0.0, "view {k}: handedness");
        let e = errors(c, &v.corners);
        let mut rotated = v.corners.clone();
        rotated.reverse();
        let e2 = errors(c, &rotated);
        assert!(median(e).min(median(e2)) < 0.1, "view {k}");
    }
}

fn sub(a: [f64; 2], b: [f64; 2]) -> [f64; 2] {
    [a[0] - b[0], a[1] - b[1]]
}

#[test]
fn calibration_on_detected_corners_recovers_the_camera() {
    let cam = pinhole();
    let opts = RenderOptions {
        noise_sigma: 1.0,
        blur_sigma: 0.5,
        ..RenderOptions::default()
    };
    let mut obs = Vec::new();
    for (k, (centre, dist, rot)) in pinhole_views().iter().enumerate() {
        let pose = look(&cam, B96, *centre, *dist, *rot);
        let v = render(
            &cam,
            &pose,
            B96,
            (640, 480),
            &RenderOptions {
                seed: k as u64,
                ..opts.clone()
            },
        );
        let d = detect_chessboard(&v.image, 9, 6, &DetectOptions::default());
        obs.push(d.to_observations(format!("view{k}")).expect("found"));
    }
    let board = BoardGeometry {
        cols: 9,
        rows: 6,
        square: B96.2,
    };
    let cal = calibrate(
        &obs,
        &board,
        ModelKind::PinholeRadTan,
        (640, 480),
        &CalibOptions::default(),
        &NoProgress,
    )
    .expect("calibrates");
    let p = cal.camera.params();
    let t = cam.params();
    println!(
        "rms {:.4} px; fx {:.3} fy {:.3} cx {:.3} cy {:.3} k1 {:.4} (truth {t:?})",
        cal.rms, p[0], p[1], p[2], p[3], p[4]
    );
    assert_eq!(cal.rejected_views.len(), 0);
    assert!(cal.rms < 0.1, "rms {}", cal.rms);
    assert!((p[0] / t[0] - 1.0).abs() < 1e-3, "fx {} vs {}", p[0], t[0]);
    assert!((p[1] / t[1] - 1.0).abs() < 1e-3, "fy {} vs {}", p[1], t[1]);
    assert!((p[2] - t[2]).abs() < 1.0 && (p[3] - t[3]).abs() < 1.0);
}

// ---- Shared real data (`CALIPER_SHARED_DATA`, or the project's sibling `../shared/data`) ----

/// The shared data's `camera/` folder (see [`crate::test_env::shared_data`]).
fn shared_camera_dir() -> Option<std::path::PathBuf> {
    crate::test_env::shared_data("camera")
}

fn detect_set(
    dir: &std::path::Path,
    names: &[String],
    cols: usize,
    rows: usize,
) -> Vec<(String, Detection, (u32, u32))> {
    names
        .iter()
        .map(|n| {
            let bytes = std::fs::read(dir.join(n)).expect("readable image");
            let img = crate::io::decode_gray8(&bytes, &crate::io::ImageLimits::default())
                .expect("decodes");
            let d = detect_chessboard(&img, cols, rows, &DetectOptions::default());
            (n.clone(), d, (img.width, img.height))
        })
        .collect()
}

fn opencv_corners(json: &serde_json::Value, name: &str) -> Option<Vec<[f64; 2]>> {
    let arr = json.get(name)?.as_array()?;
    arr.iter()
        .map(|p| Some([p.get(0)?.as_f64()?, p.get(1)?.as_f64()?]))
        .collect()
}

#[test]
fn shared_opencv_stereo() {
    let Some(root) = shared_camera_dir() else {
        return;
    };
    let json: serde_json::Value = serde_json::from_slice(
        &std::fs::read(root.join("corners/opencv_stereo.json")).expect("corners json"),
    )
    .expect("json");
    for side in ["left", "right"] {
        let names: Vec<String> = [1, 2, 3, 4, 5, 6, 7, 8, 9, 11, 12, 13, 14]
            .iter()
            .map(|k| format!("{side}{k:02}.jpg"))
            .collect();
        let res = detect_set(&root.join("opencv_stereo"), &names, 9, 6);
        let mut obs = Vec::new();
        for (n, d, _) in &res {
            match d.corners() {
                Some(c) => {
                    let cv = opencv_corners(&json["corners"][side], n).expect("opencv corners");
                    let e: Vec<f64> = c
                        .iter()
                        .zip(&cv)
                        .map(|(a, b)| (a[0] - b[0]).hypot(a[1] - b[1]))
                        .collect();
                    println!(
                        "{n}: found; vs OpenCV median {:.3} max {:.3} px",
                        median(e.clone()),
                        e.iter().copied().fold(0.0, f64::max)
                    );
                    obs.push(d.to_observations(n.clone()).expect("found"));
                }
                None => println!("{n}: {d:?}"),
            }
        }
        let board = BoardGeometry {
            cols: 9,
            rows: 6,
            square: 1.0,
        };
        let cal = calibrate(
            &obs,
            &board,
            ModelKind::PinholeRadTan,
            res[0].2,
            &CalibOptions::default(),
            &NoProgress,
        )
        .expect("calibrates");
        println!(
            "{side}: {}/13 found, RMS {:.4} px, params {:?}, rejected {:?}",
            obs.len(),
            cal.rms,
            cal.camera.params(),
            cal.rejected_views
        );
        assert_eq!(obs.len(), 13);
        assert!(cal.rms < 0.25, "{side} rms {}", cal.rms);
    }
}

#[test]
fn shared_boofcv_fisheye() {
    let Some(root) = shared_camera_dir() else {
        return;
    };
    let names: Vec<String> = (1..=26).map(|k| format!("{k}.jpg")).collect();
    let res = detect_set(&root.join("boofcv_fisheye_chessboard"), &names, 4, 6);
    let json: serde_json::Value = serde_json::from_slice(
        &std::fs::read(root.join("corners/boofcv_fisheye_chessboard.json")).expect("corners json"),
    )
    .expect("json");
    let mut obs = Vec::new();
    for (n, d, _) in &res {
        match d.corners() {
            Some(c) => {
                let cv = opencv_corners(&json["corners"], n).expect("opencv corners");
                let e: Vec<f64> = c
                    .iter()
                    .zip(&cv)
                    .map(|(a, b)| (a[0] - b[0]).hypot(a[1] - b[1]))
                    .collect();
                let er: Vec<f64> = c
                    .iter()
                    .zip(cv.iter().rev())
                    .map(|(a, b)| (a[0] - b[0]).hypot(a[1] - b[1]))
                    .collect();
                let (m, mr) = (median(e), median(er));
                println!(
                    "{n}: found; vs OpenCV median {:.3} px{}",
                    m.min(mr),
                    if mr < m { " (half turn)" } else { "" }
                );
                obs.push(d.to_observations(n.clone()).expect("found"));
            }
            None => println!("{n}: {d:?}"),
        }
    }
    let board = BoardGeometry {
        cols: 4,
        rows: 6,
        square: 1.0,
    };
    let cal = calibrate(
        &obs,
        &board,
        ModelKind::KannalaBrandt,
        res[0].2,
        &CalibOptions::default(),
        &NoProgress,
    )
    .expect("calibrates");
    println!(
        "fisheye: {}/26 found, RMS {:.4} px, params {:?}, rejected {:?}",
        obs.len(),
        cal.rms,
        cal.camera.params(),
        cal.rejected_views
    );
    // All 26, including 26.jpg (the far end of the board, squares of ~8 px under strong
    // foreshortening).
    assert_eq!(obs.len(), 26);
    assert!(cal.rejected_views.is_empty());
    assert!(cal.rms <= 0.71, "rms {}", cal.rms);
}
