//! Tests of the exports: every format written and read back, OpenCV's and PyYAML's readings of
//! our files, and OpenCV's own files read (over 600 lines: one file of tests for the module).

use std::path::{Path, PathBuf};
use std::process::Command;

use nalgebra::Vector3;

use super::yaml::{self, NanStyle};
use super::*;
use crate::calib::{
    CalibOptions, CornerObservation, ModelKind, ParameterEstimate, ViewObservations, ViewResult,
    calibrate,
};
use crate::camera::{CameraModel, DoubleSphere, KannalaBrandt, PinholeRadTan};
use crate::lie::{Se3, So3};
use crate::optim::Termination;
use crate::progress::NoProgress;

// ---------------------------------------------------------------------------------------------
// Fixtures

fn pinhole(k3: f64) -> Camera {
    PinholeRadTan::new(
        812.345_678_901_234_5,
        810.987_654_321_098_7,
        639.123_456_789,
        481.000_000_000_000_1,
        -0.281_234_567_890_123_4,
        0.071_234_567_890_123_4,
        1.234_567_890_123_4e-4,
        -3.141_592_653_589_793e-5,
        k3,
    )
    .expect("valid pinhole")
    .into()
}

fn kannala_brandt() -> Camera {
    KannalaBrandt::new(
        380.123_456_789_012_3,
        380.987_654_321_098_7,
        752.5,
        480.333_333_333_333_3,
        -0.013_456_789_012_345_6,
        0.001_234_567_890_123_4,
        -7.654_321e-4,
        1.0e-20,
    )
    .expect("valid kb")
    .into()
}

fn double_sphere() -> Camera {
    DoubleSphere::new(
        349.123_456_789,
        348.987_654_321,
        640.25,
        511.75,
        -0.201_234_567_890_123_4,
        0.589_012_345_678_901_2,
    )
    .expect("valid ds")
    .into()
}

/// A calibration built by hand: three used views and one rejected, awkward numbers throughout.
fn calibration(camera: Camera) -> Calibration {
    let parameters = camera
        .param_names()
        .iter()
        .zip(camera.params())
        .map(|(name, value)| ParameterEstimate {
            name: (*name).to_string(),
            value: *value,
            std_dev: Some(value.abs() * 1e-3 + 1e-9),
            fixed: false,
        })
        .collect();
    let view = |i: usize, used: bool| ViewResult {
        name: format!("img{i:02}.png"),
        used,
        rvec: Some([0.1 * i as f64 + 1e-17, -0.0, 2.0 / 3.0]),
        tvec: Some([-0.123_456_789_012_345_67, 1e-300, 1.5 + i as f64]),
        rms: Some(0.1 + 0.123_456_789 * i as f64),
        num_corners: 54,
        num_inliers: if used { 54 } else { 0 },
    };
    Calibration {
        initial_camera: camera.clone(),
        camera,
        image_size: [1280, 962],
        parameters,
        rms: 0.234_567_890_123_456_78,
        rms_all: 0.3,
        sigma: 0.17,
        num_inliers: 162,
        num_corners: 216,
        views: vec![view(0, true), view(1, true), view(2, false), view(3, true)],
        residuals: Vec::new(),
        rejected_corners: Vec::new(),
        rejected_views: Vec::new(),
        projection_uncertainty: Vec::new(),
        iterations: 17,
        termination: Termination::FunctionTolerance,
        warnings: vec!["a \"quoted\" warning".to_string()],
    }
}

const BOARD: BoardGeometry = BoardGeometry {
    cols: 9,
    rows: 6,
    square: 0.025_000_000_372_529_03,
};

fn input(c: &Calibration) -> ExportInput<'_> {
    ExportInput {
        board: Some(BOARD),
        camera_name: "left \"cam\"",
        rostopic: Some("/stereo/left/image_raw"),
        calibration_time: Some("Tue 16 Apr 2024 10:00:00 AM CEST"),
        ..ExportInput::new(c)
    }
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

fn assert_same_camera(a: &Camera, b: &Camera) {
    assert_eq!(a.name(), b.name());
    assert_eq!(bits(a.params()), bits(b.params()), "{a:?} vs {b:?}");
    assert_eq!(a, b);
}

fn expect_input_error<T: std::fmt::Debug>(r: CoreResult<T>, needle: &str) {
    match r {
        Err(CoreError::InvalidInput(m)) => {
            assert!(
                m.contains(needle),
                "message {m:?} does not mention {needle:?}"
            )
        }
        other => panic!("expected InvalidInput mentioning {needle:?}, got {other:?}"),
    }
}

fn expect_param_error<T: std::fmt::Debug>(r: CoreResult<T>, needle: &str) {
    match r {
        Err(CoreError::InvalidParam { field, message }) => assert!(
            message.contains(needle) || field.contains(needle),
            "{field}: {message:?} does not mention {needle:?}"
        ),
        other => panic!("expected InvalidParam mentioning {needle:?}, got {other:?}"),
    }
}

// ---------------------------------------------------------------------------------------------
// Formats and numbers

#[test]
fn format_names_parse_and_print() {
    for f in ExportFormat::ALL {
        assert_eq!(f.as_str().parse::<ExportFormat>().ok(), Some(f));
        assert_eq!(f.to_string(), f.as_str());
        let json = serde_json::to_string(&f).expect("serialise");
        assert_eq!(json, format!("\"{}\"", f.as_str()));
    }
    expect_param_error("yaml".parse::<ExportFormat>(), "unknown export format");
    expect_param_error(
        "OpenCV-YAML".parse::<ExportFormat>(),
        "unknown export format",
    );
    assert_eq!(ExportFormat::Json.media_type(), "application/json");
    assert_eq!(ExportFormat::OpencvYaml.media_type(), "application/yaml");
    assert_eq!(ExportFormat::RosYaml.media_type(), "application/yaml");
    assert_eq!(ExportFormat::KalibrYaml.file_extension(), "yaml");
}

fn tricky_f64() -> Vec<f64> {
    vec![
        0.0,
        -0.0,
        1.0,
        -1.0,
        640.0,
        0.1,
        1.0 / 3.0,
        -2.0 / 3.0,
        5.359_157_339_616_32e2,
        1e-5,
        1e15,
        1e16,
        123_456_789.012_345_67,
        f64::MIN_POSITIVE,
        5e-324,
        f64::MAX,
        -f64::MAX,
        f64::EPSILON,
        9_007_199_254_740_993.0,
        2.5e-2,
    ]
}

#[test]
fn numbers_round_trip_bit_for_bit_and_look_like_yaml_floats() {
    for v in tricky_f64() {
        for style in [NanStyle::OpenCv, NanStyle::Yaml] {
            let s = yaml::fmt_f64(v, style);
            let back = yaml::parse_f64("t", "k", &s).expect("parses");
            assert_eq!(back.to_bits(), v.to_bits(), "{v:e} → {s}");
            // YAML 1.1 (PyYAML) only types a scalar as float with a dot and a signed exponent.
            assert!(s.contains('.'), "{s} lacks a dot");
            if let Some((_, e)) = s.split_once('e') {
                assert!(
                    e.starts_with('+') || e.starts_with('-'),
                    "{s}: unsigned exponent"
                );
            }
        }
        let f = v as f32;
        let s = yaml::fmt_f32(f, NanStyle::OpenCv);
        let back = yaml::parse_f32("t", "k", &s).expect("parses");
        assert_eq!(back.to_bits(), f.to_bits(), "{f:e} → {s}");
    }
    assert_eq!(yaml::fmt_f64(535.0, NanStyle::OpenCv), "535.0");
    assert_eq!(yaml::fmt_f64(0.025, NanStyle::Yaml), "2.5e-02");
    assert_eq!(yaml::fmt_f64(f64::NAN, NanStyle::OpenCv), ".Nan");
    assert_eq!(yaml::fmt_f64(f64::NEG_INFINITY, NanStyle::Yaml), "-.inf");
    assert!(yaml::parse_f64("t", "k", ".NaN").expect("nan").is_nan());
    assert_eq!(
        yaml::parse_f64("t", "k", "-.Inf").ok(),
        Some(f64::NEG_INFINITY)
    );
    assert_eq!(yaml::parse_f64("t", "k", "1.").ok(), Some(1.0));
    for bad in [
        "inf", "nan", "0x10", "1_000", "", ".", "e5", "1e", "1.2.3", "--1",
    ] {
        assert!(yaml::parse_f64("t", "k", bad).is_err(), "{bad:?} accepted");
    }
}

// ---------------------------------------------------------------------------------------------
// OpenCV

#[test]
fn opencv_round_trip_pinhole_and_fisheye() {
    for camera in [pinhole(0.123_456_789_012_345_6), kannala_brandt()] {
        let c = calibration(camera);
        let text = export(&input(&c), ExportFormat::OpencvYaml).expect("export");
        assert!(text.starts_with("%YAML:1.0\n---\n"), "{text}");
        let r = read_opencv_yaml(&text).expect("read back");
        assert_same_camera(&r.camera, &c.camera);
        assert_eq!(r.image_size, c.image_size);
        assert_eq!(r.board, Some(BOARD));
        assert_eq!(
            r.calibration_time.as_deref(),
            Some("Tue 16 Apr 2024 10:00:00 AM CEST")
        );
        assert_eq!(
            r.avg_reprojection_error.map(f64::to_bits),
            Some(c.rms.to_bits())
        );
        let used: Vec<&ViewResult> = c.views.iter().filter(|v| v.used).collect();
        assert_eq!(r.num_frames, Some(used.len()));
        let expected_errors: Vec<f64> = used
            .iter()
            .map(|v| f64::from(v.rms.expect("rms") as f32))
            .collect();
        assert_eq!(
            bits(&r.per_view_reprojection_errors),
            bits(&expected_errors)
        );
        assert_eq!(r.extrinsics.len(), used.len());
        for (pose, v) in r.extrinsics.iter().zip(&used) {
            assert_eq!(bits(&pose.rvec), bits(&v.rvec.expect("rvec")));
            assert_eq!(bits(&pose.tvec), bits(&v.tvec.expect("tvec")));
        }
        let fisheye = matches!(c.camera, Camera::KannalaBrandt(_));
        assert_eq!(r.flags, Some(if fisheye { 8 } else { 0 }));
        assert!(text.contains(&format!("fisheye_model: {}\n", i32::from(fisheye))));
        assert!(text.contains("# flags: "));
    }
}

#[test]
fn opencv_key_order_matches_save_camera_params() {
    let c = calibration(pinhole(0.0));
    let text = export(&input(&c), ExportFormat::OpencvYaml).expect("export");
    let keys: Vec<&str> = text
        .lines()
        .filter(|l| !l.starts_with(' ') && !l.starts_with('#') && !l.starts_with('%'))
        .filter_map(|l| l.split_once(':').map(|(k, _)| k))
        .collect();
    assert_eq!(
        keys,
        [
            "calibration_time",
            "nr_of_frames",
            "image_width",
            "image_height",
            "board_width",
            "board_height",
            "square_size",
            "flags",
            "fisheye_model",
            "camera_matrix",
            "distortion_coefficients",
            "avg_reprojection_error",
            "per_view_reprojection_errors",
            "extrinsic_parameters",
        ]
    );
    assert!(text.contains("distortion_coefficients: !!opencv-matrix\n   rows: 5\n   cols: 1\n"));
    assert!(text.contains(
        "per_view_reprojection_errors: !!opencv-matrix\n   rows: 3\n   cols: 1\n   dt: f\n"
    ));
    assert!(
        text.contains("extrinsic_parameters: !!opencv-matrix\n   rows: 3\n   cols: 6\n   dt: d\n")
    );
    assert!(text.lines().all(|l| l.len() <= 90), "{text}");
}

#[test]
fn opencv_flags_follow_the_options() {
    let c = calibration(pinhole(0.0));
    let options = CalibOptions {
        fix_aspect_ratio: true,
        fix_principal_point: true,
        fix_k3: true,
        zero_tangential: true,
        ..CalibOptions::default()
    };
    let inp = ExportInput {
        options: Some(&options),
        ..input(&c)
    };
    let text = export(&inp, ExportFormat::OpencvYaml).expect("export");
    assert!(
        text.contains(
            "# flags: +fix_aspectRatio +fix_principal_point +zero_tangent_dist +fix_k3\nflags: 142\n"
        ),
        "{text}"
    );
    let r = read_opencv_yaml(&text).expect("read");
    assert_eq!(r.flags, Some(2 | 4 | 8 | 128));
    let p = c.camera.params();
    assert_eq!(
        r.fixed_aspect_ratio.map(f64::to_bits),
        Some((p[0] / p[1]).to_bits())
    );

    // Without options, fixed parameters are recognised.
    let mut c2 = c.clone();
    for p in &mut c2.parameters {
        p.fixed = matches!(p.name.as_str(), "cx" | "cy" | "k3");
    }
    let text = export(&input(&c2), ExportFormat::OpencvYaml).expect("export");
    assert!(
        text.contains("# flags: +fix_principal_point +fix_k3\nflags: 132\n"),
        "{text}"
    );
}

#[test]
fn opencv_refuses_double_sphere() {
    let c = calibration(double_sphere());
    expect_param_error(
        export(&input(&c), ExportFormat::OpencvYaml),
        "double-sphere",
    );
}

#[test]
fn opencv_minimal_file_without_board_views_or_time() {
    let mut c = calibration(pinhole(0.0));
    c.views.clear();
    let text = export(&ExportInput::new(&c), ExportFormat::OpencvYaml).expect("export");
    assert!(!text.contains("nr_of_frames") && !text.contains("board_width"));
    assert!(!text.contains("calibration_time") && !text.contains("extrinsic_parameters"));
    let r = read_opencv_yaml(&text).expect("read");
    assert_same_camera(&r.camera, &c.camera);
    assert_eq!(
        (r.board, r.num_frames, r.calibration_time),
        (None, None, None)
    );
    assert!(r.extrinsics.is_empty() && r.per_view_reprojection_errors.is_empty());
}

#[test]
fn opencv_reads_old_spellings_and_short_distortion() {
    let text = r#"%YAML:1.0
calibration_Time: "Thu Jan  1 00:00:00 2015"
nrOfFrames: 2
image_Width: 640
image_Height: 480
board_Width: 9
board_Height: 6
square_Size: 50.
FixAspectRatio: 1.
flagValue: 2
Camera_Matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 6.5e+02, 0., 3.2e+02, 0., 6.5e+02, 2.4e+02, 0., 0., 1. ]
Distortion_Coefficients: !!opencv-matrix
   rows: 1
   cols: 4
   dt: f
   data: [ -0.25, 0.125, 0., 0. ]
Avg_Reprojection_Error: 0.5
Per_View_Reprojection_Errors: !!opencv-matrix
   rows: 2
   cols: 1
   dt: f
   data: [ 0.25, 0.75 ]
"#;
    let r = read_opencv_yaml(text).expect("read");
    let expected: Camera =
        PinholeRadTan::new(650.0, 650.0, 320.0, 240.0, -0.25, 0.125, 0.0, 0.0, 0.0)
            .expect("camera")
            .into();
    assert_same_camera(&r.camera, &expected);
    assert_eq!(r.image_size, [640, 480]);
    assert_eq!(r.num_frames, Some(2));
    assert_eq!(r.flags, Some(2));
    assert_eq!(r.fixed_aspect_ratio, Some(1.0));
    assert_eq!(
        r.board.map(|b| (b.cols, b.rows, b.square)),
        Some((9, 6, 50.0))
    );
    assert_eq!(r.per_view_reprojection_errors, [0.25, 0.75]);
}

/// A file of OpenCV's stereo sample (`left_intrinsics.yml` as written by OpenCV's
/// `samples/cpp/calibration.cpp`) from the shared data.
fn shared_file(name: &str) -> Option<PathBuf> {
    crate::test_env::shared_data(&format!("camera/opencv_stereo/{name}"))
}

#[test]
fn reads_opencv_left_intrinsics_when_present() {
    let Some(path) = shared_file("left_intrinsics.yml") else {
        return;
    };
    let text = std::fs::read_to_string(&path).expect("readable");
    let r = read_opencv_yaml(&text).expect("OpenCV's own file reads");
    let Camera::PinholeRadTan(m) = &r.camera else {
        panic!("expected a pinhole, got {:?}", r.camera);
    };
    // The decimals exactly as OpenCV printed them (`%.16e`), parsed like any reader would.
    let num = |s: &str| -> f64 { s.parse().expect("test literal") };
    let k = ["5.3591573396163199e+02", "5.3591573396163199e+02"];
    let c = ["3.4228315473308373e+02", "2.3557082909788173e+02"];
    assert_eq!(m.intrinsics(), [num(k[0]), num(k[1]), num(c[0]), num(c[1])]);
    let d = [
        "-2.6637260909660682e-01",
        "-3.8588898922304653e-02",
        "1.7831947042852964e-03",
        "-2.8122100441115472e-04",
        "2.3839153080878486e-01",
    ];
    assert_eq!(m.distortion().to_vec(), d.map(num).to_vec());
    assert_eq!(r.image_size, [640, 480]);
    assert_eq!(r.num_frames, Some(13));
    assert_eq!(r.flags, Some(2));
    assert_eq!(r.fixed_aspect_ratio, Some(1.0));
    assert_eq!(
        r.board.map(|b| (b.cols, b.rows, b.square)),
        Some((9, 6, num("2.5000000372529030e-02")))
    );
    assert_eq!(
        r.avg_reprojection_error,
        Some(num("3.9259098975581364e-01"))
    );
    assert_eq!(r.per_view_reprojection_errors.len(), 13);
    let e: f32 = "1.18204820e+00".parse().expect("test literal");
    assert_eq!(r.per_view_reprojection_errors[1], f64::from(e));
    assert_eq!(r.extrinsics.len(), 13);
    assert_eq!(r.extrinsics[0].rvec[0], num("1.6866673097722978e-01"));
    assert_eq!(r.extrinsics[12].tvec[2], num("3.1243767202759759e-01"));

    // Write it out again and read it back: same camera.
    let mut c = calibration(r.camera.clone());
    c.image_size = r.image_size;
    let text = export(&input(&c), ExportFormat::OpencvYaml).expect("export");
    assert_same_camera(&read_opencv_yaml(&text).expect("read").camera, &r.camera);
}

#[test]
fn parser_handles_block_sequences_like_opencv_calibration_yml() {
    if let Some(path) = shared_file("calibration.yml") {
        let text = std::fs::read_to_string(path).expect("readable");
        let root = yaml::parse(&text).expect("parses");
        let images = root
            .iter()
            .find(|(k, _)| k == "images")
            .map(|(_, v)| v)
            .expect("images key");
        let yaml::Node::Seq(items) = images else {
            panic!("images is {images:?}");
        };
        assert_eq!(items.len(), 13);
    }
    let root = yaml::parse("a:\n- x\n- 'y # not a comment'\nb:\n  - [1, [2, 3]]\n").expect("ok");
    assert_eq!(root.len(), 2);
    assert_eq!(
        root[0].1,
        yaml::Node::Seq(vec![
            yaml::Node::Scalar {
                text: "x".into(),
                quoted: false
            },
            yaml::Node::Scalar {
                text: "y # not a comment".into(),
                quoted: true
            },
        ])
    );
}

const GOOD_OPENCV: &str = r#"%YAML:1.0
---
image_width: 640
image_height: 480
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 500., 0., 320., 0., 500., 240., 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 5
   cols: 1
   dt: d
   data: [ 0.1, -0.2, 0., 0., 0. ]
"#;

#[test]
fn opencv_reader_is_strict() {
    read_opencv_yaml(GOOD_OPENCV).expect("the base case reads");
    let cases: &[(&str, &str, &str)] = &[
        ("image_width: 640\n", "", "missing key `image_width`"),
        ("image_height: 480\n", "image_height: 0\n", "image_height"),
        (
            "image_height: 480\n",
            "image_height: \"480\"\n",
            "quoted string",
        ),
        (
            "image_height: 480\n",
            "image_height: 480\nimage_Width: 640\n",
            "both",
        ),
        (
            "   rows: 3\n   cols: 3\n",
            "   rows: 2\n   cols: 3\n",
            "camera_matrix",
        ),
        ("0., 0., 1. ]", "0., 0. ]", "needs 9 data entries"),
        ("0., 0., 1. ]", "0., 0., 2. ]", "not a camera matrix"),
        ("[ 500., 0., 320.", "[ 500., 1., 320.", "skew"),
        (
            "dt: d\n   data: [ 500.",
            "dt: q\n   data: [ 500.",
            "unknown element type",
        ),
        (
            "dt: d\n   data: [ 500.",
            "dt: 2d\n   data: [ 500.",
            "multi-channel",
        ),
        (
            "[ 0.1, -0.2, 0., 0., 0. ]",
            "[ 0.1, -0.2, 0., 0., abc ]",
            "expected a number",
        ),
        (
            "rows: 5\n   cols: 1\n   dt: d\n   data: [ 0.1, -0.2, 0., 0., 0. ]",
            "rows: 3\n   cols: 1\n   dt: d\n   data: [ 0.1, -0.2, 0. ]",
            "expected 4, 5, 8, 12 or 14",
        ),
        (
            "camera_matrix: !!opencv-matrix",
            "camera_matrix: !!opencv-nd-matrix",
            "tag",
        ),
        (
            "camera_matrix: !!opencv-matrix",
            "Camera_Matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 1., 0., 0., 0., 1., 0., 0., 0., 1. ]\ncamera_matrix: !!opencv-matrix",
            "both",
        ),
        ("0., 0., 1. ]\n", "0., 0., 1.\n", "unterminated"),
        (
            "image_height: 480\n",
            "image_height: 480\nimage_height: 480\n",
            "duplicate key",
        ),
        ("image_height: 480\n", "image_height:\t480\n", "key: value"),
        ("image_height: 480\n", "\timage_height: 480\n", "tab"),
        (
            "image_height: 480\n",
            "image_height: 480\n  stray: 1\n",
            "unexpected indentation",
        ),
        ("image_height: 480\n", "image_height: &a 480\n", "anchors"),
        (
            "image_height: 480\n",
            "image_height: {a: 1}\n",
            "flow mappings",
        ),
        ("---\n", "---\n---\n", "several YAML documents"),
        ("%YAML:1.0\n", "%TAG ! tag:x\n", "directive"),
        (
            "   dt: d\n   data: [ 0.1",
            "   dt: d\n   extra: 1\n   data: [ 0.1",
            "unexpected field `extra`",
        ),
        (
            "image_height: 480\n",
            "image_height: 480\nfisheye_model: 2\n",
            "fisheye_model",
        ),
    ];
    for (from, to, needle) in cases {
        assert!(GOOD_OPENCV.contains(from), "bad test case: {from:?}");
        let text = GOOD_OPENCV.replacen(from, to, 1);
        expect_input_error(read_opencv_yaml(&text), needle);
    }
    expect_input_error(read_opencv_yaml(""), "empty document");
    expect_input_error(
        read_opencv_yaml("%YAML:1.0\n---\n- a\n"),
        "root must be a mapping",
    );
    let fisheye_with_5 =
        GOOD_OPENCV.replace("image_width: 640", "fisheye_model: 1\nimage_width: 640");
    expect_input_error(
        read_opencv_yaml(&fisheye_with_5),
        "fisheye model has 4 coefficients",
    );
    let rational = GOOD_OPENCV
        .replace("rows: 5", "rows: 8")
        .replace("0., 0., 0. ]", "0., 0., 0., 0., 0.5, 0. ]");
    expect_input_error(read_opencv_yaml(&rational), "coefficient 7");
    let rational_zero = GOOD_OPENCV
        .replace("rows: 5", "rows: 8")
        .replace("0., 0., 0. ]", "0., 0., 0., 0., 0., 0. ]");
    read_opencv_yaml(&rational_zero).expect("zero rational terms are fine");
    let partial_board = GOOD_OPENCV.replace("image_width: 640", "image_width: 640\nboard_width: 9");
    expect_input_error(read_opencv_yaml(&partial_board), "board_height");
}

// ---------------------------------------------------------------------------------------------
// ROS

#[test]
fn ros_round_trip_pinhole_and_equidistant() {
    for (camera, model) in [
        (pinhole(0.123_456_789_012_345_6), "plumb_bob"),
        (kannala_brandt(), "equidistant"),
    ] {
        let c = calibration(camera);
        let text = export(&input(&c), ExportFormat::RosYaml).expect("export");
        assert!(
            text.contains(&format!("distortion_model: {model}\n")),
            "{text}"
        );
        let keys: Vec<&str> = text
            .lines()
            .filter(|l| !l.starts_with(' '))
            .filter_map(|l| l.split_once(':').map(|(k, _)| k))
            .collect();
        assert_eq!(
            keys,
            [
                "image_width",
                "image_height",
                "camera_name",
                "camera_matrix",
                "distortion_model",
                "distortion_coefficients",
                "rectification_matrix",
                "projection_matrix"
            ]
        );
        let r = read_ros_yaml(&text).expect("read back");
        assert_same_camera(&r.camera, &c.camera);
        assert_eq!(r.image_size, c.image_size);
        assert_eq!(r.camera_name.as_deref(), Some("left \"cam\""));
        assert_eq!(
            r.rectification_matrix,
            Some([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
        );
        let p = c.camera.params();
        assert_eq!(
            r.projection_matrix,
            Some([
                [p[0], 0.0, p[2], 0.0],
                [0.0, p[1], p[3], 0.0],
                [0.0, 0.0, 1.0, 0.0]
            ])
        );
    }
    let c = calibration(double_sphere());
    expect_param_error(export(&input(&c), ExportFormat::RosYaml), "double-sphere");
}

const GOOD_ROS: &str = "image_width: 752
image_height: 480
camera_name: cam0
camera_matrix:
  rows: 3
  cols: 3
  data: [458.654, 0, 367.215, 0, 457.296, 248.375, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0.0]
";

#[test]
fn ros_reader_defaults_and_strictness() {
    let r = read_ros_yaml(GOOD_ROS).expect("reads");
    assert_eq!(r.camera.params()[0], 458.654);
    assert_eq!(r.camera.params()[7], 1.761_871_14e-5);
    assert_eq!(r.projection_matrix, None);
    let r = read_ros_yaml(
        &GOOD_ROS
            .replace("camera_name: cam0\n", "")
            .replace("distortion_model: plumb_bob\n", ""),
    )
    .expect("defaults");
    assert_eq!(r.camera_name.as_deref(), Some("unknown"));
    assert!(matches!(r.camera, Camera::PinholeRadTan(_)));
    let empty_d = GOOD_ROS.replace("cols: 5\n", "cols: 0\n").replace(
        "[-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0.0]",
        "[]",
    );
    let r = read_ros_yaml(&empty_d).expect("empty D is no distortion");
    assert!(r.camera.params()[4..].iter().all(|v| *v == 0.0));
    let cases: &[(&str, &str, &str)] = &[
        ("image_width: 752\n", "", "missing key `image_width`"),
        (
            "  rows: 3\n  cols: 3\n",
            "  rows: 3\n  cols: 4\n",
            "needs 12 data entries",
        ),
        ("  rows: 3\n  cols: 3\n", "  cols: 3\n", "missing `rows`"),
        ("plumb_bob", "fisheye", "unsupported model `fisheye`"),
        ("plumb_bob", "equidistant", "takes 4 coefficients"),
        ("cols: 5", "cols: 4", "needs 4 data entries"),
        ("0.0]\n", "0.0, 0.0, 0.0, 0.0]\n", "needs 5 data entries"),
        (
            "camera_name: cam0\n",
            "camera_name: [a]\n",
            "expected a string",
        ),
    ];
    for (from, to, needle) in cases {
        assert!(GOOD_ROS.contains(from), "bad test case: {from:?}");
        expect_input_error(read_ros_yaml(&GOOD_ROS.replacen(from, to, 1)), needle);
    }
    let rational = GOOD_ROS
        .replace("plumb_bob", "rational_polynomial")
        .replace("cols: 5", "cols: 8")
        .replace("0.0]\n", "0.0, 0.5, 0.0, 0.0]\n");
    expect_input_error(read_ros_yaml(&rational), "k4 = 0.5");
    let rational = rational.replace("0.5", "0.0");
    read_ros_yaml(&rational).expect("zero k4..k6 are fine");
}

// ---------------------------------------------------------------------------------------------
// Kalibr

#[test]
fn kalibr_round_trip_every_model() {
    for camera in [pinhole(0.0), kannala_brandt(), double_sphere()] {
        let c = calibration(camera);
        let text = export(&input(&c), ExportFormat::KalibrYaml).expect("export");
        let r = read_kalibr_yaml(&text).expect("read back");
        assert_same_camera(&r.camera, &c.camera);
        assert_eq!(r.image_size, c.image_size);
        assert_eq!(r.rostopic.as_deref(), Some("/stereo/left/image_raw"));
        assert!(r.cam_overlaps.is_empty());
        let all = read_kalibr_camchain(&text).expect("camchain");
        assert_eq!(all.len(), 1);
    }
    let ds = export(
        &input(&calibration(double_sphere())),
        ExportFormat::KalibrYaml,
    )
    .expect("export");
    assert!(ds.contains("  camera_model: ds\n  intrinsics: [-2.012345678901234e-01, 5.890123456789012e-01, 3.49123456789e+02"), "{ds}");
    assert!(
        ds.contains("  distortion_model: none\n  distortion_coeffs: []\n"),
        "{ds}"
    );
    let c = calibration(pinhole(0.0));
    let text = export(&ExportInput::new(&c), ExportFormat::KalibrYaml).expect("export");
    assert!(text.contains("rostopic: \"/cam0/image_raw\""), "{text}");
}

#[test]
fn kalibr_refuses_k3() {
    let c = calibration(pinhole(1e-3));
    expect_param_error(export(&input(&c), ExportFormat::KalibrYaml), "k3 = 0.001");
}

/// The shape of a real two-camera Kalibr result (PyYAML's block style, sorted keys).
const KALIBR_CHAIN: &str = "cam0:
  cam_overlaps: [1]
  camera_model: pinhole
  distortion_coeffs: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
  distortion_model: radtan
  intrinsics: [458.654, 457.296, 367.215, 248.375]
  resolution: [752, 480]
  rostopic: /cam0/image_raw
  T_cam_imu:
  - [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975]
  - [0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768]
  - [-0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949]
  - [0.0, 0.0, 0.0, 1.0]
  timeshift_cam_imu: 5.63e-05
cam1:
  T_cn_cnm1:
  - [0.999997256477, 0.002312067192, 0.000376008102, -0.110073808127]
  - [-0.002317135723, 0.999898048506, 0.014089835846, 0.000399121547]
  - [-0.000343393121, -0.014090668452, 0.999900662637, -0.000853702503]
  - [0.0, 0.0, 0.0, 1.0]
  cam_overlaps: [0]
  camera_model: pinhole
  distortion_coeffs: [-0.28368365, 0.07451284, -0.00010473, -3.55590700e-05]
  distortion_model: radtan
  intrinsics: [457.587, 456.134, 379.999, 255.238]
  resolution: [752, 480]
  rostopic: /cam1/image_raw
";

#[test]
fn kalibr_reads_a_two_camera_chain() {
    let cams = read_kalibr_camchain(KALIBR_CHAIN).expect("reads");
    assert_eq!(cams.len(), 2);
    assert_eq!(cams[0].cam_overlaps, [1]);
    assert_eq!(cams[0].timeshift_cam_imu, Some(5.63e-5));
    assert_eq!(cams[0].t_cam_imu.map(|t| t[3]), Some([0.0, 0.0, 0.0, 1.0]));
    assert_eq!(cams[1].t_cn_cnm1.map(|t| t[0][3]), Some(-0.110_073_808_127));
    assert_eq!(cams[1].rostopic.as_deref(), Some("/cam1/image_raw"));
    assert_eq!(cams[1].camera.params()[2], 379.999);
    assert_eq!(read_kalibr_yaml(KALIBR_CHAIN).expect("cam0"), cams[0]);

    let cases: &[(&str, &str, &str)] = &[
        ("cam0:", "camA:", "missing key `cam0`"),
        (
            "camera_model: pinhole\n  distortion_coeffs: [-0.28340811",
            "camera_model: omni\n  distortion_coeffs: [-0.28340811",
            "`omni` is not supported",
        ),
        (
            "distortion_model: radtan\n  intrinsics: [458",
            "distortion_model: fov\n  intrinsics: [458",
            "`fov` is not supported",
        ),
        (
            "[458.654, 457.296, 367.215, 248.375]",
            "[458.654, 457.296, 367.215]",
            "takes 4 values, got 3",
        ),
        (
            "1.76187114e-05]",
            "1.76187114e-05, 0.1]",
            "takes 4 values, got 5",
        ),
        (
            "resolution: [752, 480]\n  rostopic: /cam0",
            "resolution: [752]\n  rostopic: /cam0",
            "expected [width, height]",
        ),
        (
            "resolution: [752, 480]\n  rostopic: /cam0",
            "rostopic: /cam0",
            "missing key `cam0.resolution`",
        ),
        (
            "  - [0.0, 0.0, 0.0, 1.0]\n  timeshift",
            "  timeshift",
            "expected 4 rows, got 3",
        ),
        ("cam1:", "cam2:", "missing key `cam1`"),
    ];
    for (from, to, needle) in cases {
        assert!(KALIBR_CHAIN.contains(from), "bad test case: {from:?}");
        expect_input_error(
            read_kalibr_camchain(&KALIBR_CHAIN.replacen(from, to, 1)),
            needle,
        );
    }
    let ds = "cam0:\n  camera_model: ds\n  intrinsics: [-0.2, 0.6, 350.0, 350.0, 640.0, 512.0]\n  \
              distortion_model: radtan\n  distortion_coeffs: [0.0, 0.0, 0.0, 0.0]\n  \
              resolution: [1280, 1024]\n";
    expect_input_error(read_kalibr_yaml(ds), "not supported with camera_model ds");
    let bad_xi = "cam0:\n  camera_model: ds\n  intrinsics: [-2.0, 0.6, 350.0, 350.0, 640.0, 512.0]\n  \
              distortion_model: none\n  distortion_coeffs: []\n  resolution: [1280, 1024]\n";
    expect_input_error(read_kalibr_yaml(bad_xi), "cam0.intrinsics");
}

// ---------------------------------------------------------------------------------------------
// JSON

#[test]
fn json_round_trip_every_model() {
    let options = CalibOptions {
        fix_k3: true,
        ..CalibOptions::default()
    };
    for camera in [
        pinhole(0.123_456_789_012_345_6),
        kannala_brandt(),
        double_sphere(),
    ] {
        let c = calibration(camera);
        let inp = ExportInput {
            options: Some(&options),
            ..input(&c)
        };
        let text = export(&inp, ExportFormat::Json).expect("export");
        let doc = read_json(&text).expect("read back");
        assert_eq!(doc.format, CALIBRATION_DOCUMENT_FORMAT);
        assert_eq!(doc.format_version, CALIBRATION_DOCUMENT_VERSION);
        assert_eq!(doc.calibration, c);
        assert_same_camera(&doc.calibration.camera, &c.camera);
        assert_eq!(doc.board, Some(BOARD));
        assert_eq!(doc.options, Some(options));
        assert_eq!(doc.camera_name, "left \"cam\"");
        assert_eq!(
            doc.calibration_time.as_deref(),
            Some("Tue 16 Apr 2024 10:00:00 AM CEST")
        );
        // Bit-for-bit, including -0.0 and subnormal-adjacent values in the views.
        for (a, b) in doc.calibration.views.iter().zip(&c.views) {
            assert_eq!(bits(&a.rvec.expect("r")), bits(&b.rvec.expect("r")));
            assert_eq!(bits(&a.tvec.expect("t")), bits(&b.tvec.expect("t")));
        }
    }
    let c = calibration(pinhole(0.0));
    let text = export(&ExportInput::new(&c), ExportFormat::Json).expect("export");
    expect_input_error(
        read_json(&text.replace("caliper-calibration", "other")),
        "format",
    );
    expect_input_error(
        read_json(&text.replace("\"format_version\": 1", "\"format_version\": 2")),
        "format_version",
    );
    expect_input_error(
        read_json(&text.replacen('{', "{\"extra\": 1,", 1)),
        "unknown field",
    );
    expect_input_error(read_json("{"), "json");
}

#[test]
fn export_validates_its_input() {
    let c = calibration(pinhole(0.0));
    let bad_board = ExportInput {
        board: Some(BoardGeometry {
            cols: 1,
            rows: 6,
            square: 0.02,
        }),
        ..ExportInput::new(&c)
    };
    expect_param_error(export(&bad_board, ExportFormat::OpencvYaml), "board");
    let bad_name = ExportInput {
        camera_name: "a\nb",
        ..ExportInput::new(&c)
    };
    expect_param_error(export(&bad_name, ExportFormat::RosYaml), "control");
    let empty_topic = ExportInput {
        rostopic: Some(""),
        ..ExportInput::new(&c)
    };
    expect_param_error(export(&empty_topic, ExportFormat::KalibrYaml), "rostopic");
}

// ---------------------------------------------------------------------------------------------
// End to end: a real solve, exported and read back in every applicable format

/// Corners of a 9×6 board seen from a few poses through `camera`, noise-free.
fn synthetic_views(camera: &Camera, board: &BoardGeometry) -> Vec<ViewObservations> {
    let poses = [
        ([0.2, -0.1, 0.05], [-0.05, -0.02, 0.5]),
        ([-0.25, 0.15, -0.1], [0.02, -0.05, 0.55]),
        ([0.1, 0.3, 0.2], [-0.1, 0.0, 0.6]),
        ([-0.3, -0.2, 0.0], [0.0, 0.03, 0.45]),
        ([0.05, -0.35, -0.2], [-0.08, -0.06, 0.65]),
        ([0.35, 0.05, 0.1], [0.01, -0.04, 0.5]),
    ];
    poses
        .iter()
        .enumerate()
        .map(|(i, (r, t))| {
            let pose = Se3::new(So3::exp(&Vector3::from(*r)), Vector3::from(*t));
            let corners = (0..board.num_corners())
                .filter_map(|k| {
                    let p = camera.project(&pose.act(&board.object_point(k)?))?;
                    Some(CornerObservation {
                        index: k,
                        pixel: [p.x, p.y],
                    })
                })
                .collect();
            ViewObservations {
                name: format!("v{i}"),
                corners,
            }
        })
        .collect()
}

#[test]
fn solved_calibrations_round_trip_through_every_format() {
    let board = BoardGeometry {
        cols: 9,
        rows: 6,
        square: 0.03,
    };
    let cases: [(Camera, ModelKind, CalibOptions); 2] = [
        (
            PinholeRadTan::new(600.0, 602.0, 320.5, 240.5, -0.2, 0.05, 1e-3, -5e-4, 0.0)
                .expect("camera")
                .into(),
            ModelKind::PinholeRadTan,
            CalibOptions {
                fix_k3: true,
                ..CalibOptions::default()
            },
        ),
        (
            KannalaBrandt::new(300.0, 300.5, 320.0, 240.0, 0.02, -0.01, 0.003, -0.0005)
                .expect("camera")
                .into(),
            ModelKind::KannalaBrandt,
            CalibOptions::default(),
        ),
    ];
    for (truth, kind, options) in cases {
        let views = synthetic_views(&truth, &board);
        let c =
            calibrate(&views, &board, kind, (640, 480), &options, &NoProgress).expect("calibrates");
        let inp = ExportInput {
            board: Some(board),
            options: Some(&options),
            ..ExportInput::new(&c)
        };
        for format in ExportFormat::ALL {
            let text = export(&inp, format).expect("export");
            let camera = match format {
                ExportFormat::OpencvYaml => read_opencv_yaml(&text).map(|r| r.camera),
                ExportFormat::RosYaml => read_ros_yaml(&text).map(|r| r.camera),
                ExportFormat::KalibrYaml => read_kalibr_yaml(&text).map(|r| r.camera),
                ExportFormat::Json => read_json(&text).map(|d| d.calibration.camera),
            }
            .expect("reads back");
            assert_same_camera(&camera, &c.camera);
        }
        let r = read_opencv_yaml(&export(&inp, ExportFormat::OpencvYaml).expect("export"))
            .expect("read");
        assert_eq!(r.num_frames, Some(views.len()));
        assert_eq!(r.extrinsics.len(), views.len());
    }
}

// ---------------------------------------------------------------------------------------------
// Other readers: OpenCV (cv2.FileStorage) and PyYAML, through python3

/// A temp file removed on drop.
struct TempFile(PathBuf);

impl TempFile {
    fn new(name: &str, text: &str) -> Self {
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos())
            .unwrap_or(0);
        let path = std::env::temp_dir().join(format!(
            "caliper-export-{}-{nanos}-{name}",
            std::process::id()
        ));
        std::fs::write(&path, text).expect("temp file written");
        Self(path)
    }

    fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for TempFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

/// Runs `<python> -c script args…`; `None` (after a loud message) when no Python with
/// `modules` is available (see [`crate::test_env::python`]).
fn python(script: &str, args: &[&Path], modules: &str) -> Option<String> {
    let py = crate::test_env::python(modules)?;
    let out = Command::new(py)
        .arg("-c")
        .arg(script)
        .args(args)
        .output()
        .expect("python runs");
    assert!(
        out.status.success(),
        "python failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    Some(String::from_utf8_lossy(&out.stdout).into_owned())
}

const CV2_READ: &str = r#"
import cv2, json, sys
fs = cv2.FileStorage(sys.argv[1], cv2.FILE_STORAGE_READ)
assert fs.isOpened(), "cv2 could not open the file"
def mat(k):
    m = fs.getNode(k).mat()
    return None if m is None else [[float(x) for x in row] for row in m.tolist()]
out = {
    "camera_matrix": mat("camera_matrix"),
    "distortion_coefficients": mat("distortion_coefficients"),
    "per_view_reprojection_errors": mat("per_view_reprojection_errors"),
    "extrinsic_parameters": mat("extrinsic_parameters"),
    "image_width": int(fs.getNode("image_width").real()),
    "image_height": int(fs.getNode("image_height").real()),
    "nr_of_frames": int(fs.getNode("nr_of_frames").real()),
    "fisheye_model": int(fs.getNode("fisheye_model").real()),
    "flags": int(fs.getNode("flags").real()),
    "square_size": fs.getNode("square_size").real(),
    "avg_reprojection_error": fs.getNode("avg_reprojection_error").real(),
    "calibration_time": fs.getNode("calibration_time").string(),
    "cv2": cv2.__version__,
}
print(json.dumps(out))
"#;

/// OpenCV writes a calibration its own way; our reader must take it.
const CV2_WRITE: &str = r#"
import cv2, numpy as np, sys
fs = cv2.FileStorage(sys.argv[1], cv2.FILE_STORAGE_WRITE)
fs.write("calibration_time", "Mon Jan  1 00:00:00 2024")
fs.write("nr_of_frames", 2)
fs.write("image_width", 1280)
fs.write("image_height", 720)
fs.writeComment("flags: +fix_k3")
fs.write("flags", 128)
fs.write("fisheye_model", 0)
K = np.array([[1.0/3.0*3000, 0, 640.123456789], [0, 1001.0000000001, 359.5], [0, 0, 1]])
fs.write("camera_matrix", K)
fs.write("distortion_coefficients", np.array([[-0.1], [0.01], [1e-4], [-2e-5], [0.0]]))
fs.write("avg_reprojection_error", 0.25)
fs.write("per_view_reprojection_errors", np.array([[0.2], [0.3]], dtype=np.float32))
fs.write("extrinsic_parameters", np.arange(12, dtype=np.float64).reshape(2, 6) / 7.0)
fs.release()
"#;

#[test]
fn opencv_itself_reads_our_yaml_and_we_read_its() {
    for camera in [pinhole(0.123_456_789_012_345_6), kannala_brandt()] {
        let c = calibration(camera);
        let text = export(&input(&c), ExportFormat::OpencvYaml).expect("export");
        let file = TempFile::new("cv2.yml", &text);
        let Some(stdout) = python(CV2_READ, &[file.path()], "cv2, numpy") else {
            return;
        };
        let v: serde_json::Value = serde_json::from_str(stdout.trim()).expect("json from python");
        eprintln!("cv2 {} read {}", v["cv2"], c.camera.name());
        let p = c.camera.params();
        let k = [[p[0], 0.0, p[2]], [0.0, p[1], p[3]], [0.0, 0.0, 1.0]];
        let cv_k: Vec<Vec<f64>> =
            serde_json::from_value(v["camera_matrix"].clone()).expect("camera_matrix");
        for (row, cv_row) in k.iter().zip(&cv_k) {
            for (a, b) in row.iter().zip(cv_row) {
                assert!((a - b).abs() <= 1e-12 * a.abs().max(1.0), "K: {a} vs {b}");
                assert_eq!(a.to_bits(), b.to_bits(), "K not bit-exact: {a} vs {b}");
            }
        }
        let dist: Vec<f64> = match &c.camera {
            Camera::PinholeRadTan(m) => m.distortion().to_vec(),
            _ => p[4..8].to_vec(),
        };
        let cv_d: Vec<Vec<f64>> = serde_json::from_value(v["distortion_coefficients"].clone())
            .expect("distortion_coefficients");
        assert_eq!(cv_d.len(), dist.len());
        for (a, row) in dist.iter().zip(&cv_d) {
            assert!(
                (a - row[0]).abs() <= 1e-12 * a.abs().max(1.0),
                "D: {a} vs {}",
                row[0]
            );
            assert_eq!(
                a.to_bits(),
                row[0].to_bits(),
                "D not bit-exact: {a} vs {}",
                row[0]
            );
        }
        let fisheye = matches!(c.camera, Camera::KannalaBrandt(_));
        assert_eq!(v["fisheye_model"], i32::from(fisheye));
        assert_eq!(v["image_width"], c.image_size[0]);
        assert_eq!(v["image_height"], c.image_size[1]);
        assert_eq!(v["nr_of_frames"], 3);
        assert_eq!(v["square_size"].as_f64(), Some(BOARD.square));
        assert_eq!(v["avg_reprojection_error"].as_f64(), Some(c.rms));
        assert_eq!(v["calibration_time"], "Tue 16 Apr 2024 10:00:00 AM CEST");
        let ext: Vec<Vec<f64>> =
            serde_json::from_value(v["extrinsic_parameters"].clone()).expect("extrinsics");
        assert_eq!((ext.len(), ext[0].len()), (3, 6));
        assert_eq!(ext[2][4].to_bits(), 1e-300f64.to_bits());
        let errs: Vec<Vec<f64>> =
            serde_json::from_value(v["per_view_reprojection_errors"].clone()).expect("errs");
        assert_eq!(errs.len(), 3);
    }

    // And the other direction: a file written by cv2.FileStorage.
    let file = TempFile::new("cv2-written.yml", "");
    if python(CV2_WRITE, &[file.path()], "cv2, numpy").is_none() {
        return;
    }
    let text = std::fs::read_to_string(file.path()).expect("cv2 wrote");
    eprintln!("cv2 wrote:\n{text}");
    let r = read_opencv_yaml(&text).expect("we read cv2's file");
    let p = r.camera.params();
    assert_eq!(p[0], 1.0 / 3.0 * 3000.0);
    assert_eq!(p[1], 1_001.000_000_000_1);
    assert_eq!(p[2], 640.123_456_789);
    assert_eq!(&p[4..], &[-0.1, 0.01, 1e-4, -2e-5, 0.0]);
    assert_eq!(r.image_size, [1280, 720]);
    assert_eq!(r.flags, Some(128));
    assert_eq!(
        r.per_view_reprojection_errors,
        [f64::from(0.2f32), f64::from(0.3f32)]
    );
    assert_eq!(r.extrinsics[1].tvec[2], 11.0 / 7.0);
    assert_eq!(
        r.calibration_time.as_deref(),
        Some("Mon Jan  1 00:00:00 2024")
    );
}

const PYYAML_READ: &str = r#"
import json, sys, yaml
with open(sys.argv[1]) as f:
    doc = yaml.safe_load(f)
def check(x):
    if isinstance(x, dict):
        for v in x.values(): check(v)
    elif isinstance(x, list):
        for v in x: check(v)
    elif isinstance(x, str) and x[:1] in "-.0123456789" and x not in ("-",):
        raise SystemExit("number typed as string: %r" % x)
check(doc)
print(json.dumps(doc))
"#;

#[test]
fn pyyaml_reads_our_ros_and_kalibr_files_as_numbers() {
    for camera in [pinhole(0.0), kannala_brandt(), double_sphere()] {
        let c = calibration(camera);
        for format in [ExportFormat::RosYaml, ExportFormat::KalibrYaml] {
            let Ok(text) = export(&input(&c), format) else {
                continue; // double sphere has no ROS form
            };
            let file = TempFile::new("pyyaml.yaml", &text);
            let Some(stdout) = python(PYYAML_READ, &[file.path()], "yaml") else {
                return;
            };
            let v: serde_json::Value = serde_json::from_str(stdout.trim()).expect("json");
            let p = c.camera.params();
            let fx = match format {
                ExportFormat::RosYaml => v["camera_matrix"]["data"][0].as_f64(),
                _ if matches!(c.camera, Camera::DoubleSphere(_)) => {
                    v["cam0"]["intrinsics"][2].as_f64()
                }
                _ => v["cam0"]["intrinsics"][0].as_f64(),
            };
            assert_eq!(
                fx.map(f64::to_bits),
                Some(p[0].to_bits()),
                "{format}: {text}"
            );
            if format == ExportFormat::KalibrYaml {
                assert_eq!(v["cam0"]["resolution"], serde_json::json!(c.image_size));
                assert_eq!(v["cam0"]["rostopic"], "/stereo/left/image_raw");
            } else {
                assert_eq!(v["camera_name"], "left \"cam\"");
            }
        }
    }
}
