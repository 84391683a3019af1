//! Target descriptions: JSON, Kalibr yaml, OpenCV ChArUco parameters, validation, ids and
//! board positions (OpenCV's and Kalibr's conventions).

use caliper_core::CoreError;
use caliper_core::board::TargetSpec;
use caliper_core::board::markers::Dictionary;

fn field(e: CoreError) -> String {
    match e {
        CoreError::InvalidParam { field, .. } => field,
        other => panic!("expected a parameter error, got {other}"),
    }
}

#[test]
fn json_round_trip_with_type_tag() {
    let text = r#"{"type": "charuco", "squares_x": 5, "squares_y": 7, "square": 0.04, "marker": 0.02, "dictionary": "DICT_6X6_250"}"#;
    let spec: TargetSpec = serde_json::from_str(text).expect("parse");
    assert_eq!(
        spec,
        TargetSpec::Charuco {
            squares_x: 5,
            squares_y: 7,
            square: 0.04,
            marker: 0.02,
            dictionary: "DICT_6X6_250".into(),
            legacy: false
        }
    );
    let back: TargetSpec =
        serde_json::from_str(&serde_json::to_string(&spec).expect("json")).expect("parse");
    assert_eq!(back, spec);
    let grid: TargetSpec = serde_json::from_str(
        r#"{"type": "aprilgrid", "tag_rows": 6, "tag_cols": 6, "tag_size": 0.088, "tag_spacing": 0.3}"#,
    )
    .expect("aprilgrid");
    assert_eq!(grid.num_corners(), 144);
    let chess: TargetSpec =
        serde_json::from_str(r#"{"type": "chessboard", "cols": 9, "rows": 6, "square": 0.025}"#)
            .expect("chess");
    assert_eq!(chess.num_corners(), 54);
    assert!(
        serde_json::from_str::<TargetSpec>(
            r#"{"type": "chessboard", "cols": 9, "rows": 6, "square": 1, "x": 1}"#
        )
        .is_err()
    );
}

#[test]
fn charuco_ids_and_positions_follow_opencv() {
    let spec = TargetSpec::Charuco {
        squares_x: 5,
        squares_y: 7,
        square: 0.04,
        marker: 0.02,
        dictionary: "DICT_6X6_250".into(),
        legacy: false,
    };
    assert_eq!(spec.num_corners(), 24);
    // OpenCV: id -> ((id % (sx-1)) + 1)·square, ((id / (sx-1)) + 1)·square.
    for id in 0..24 {
        let p = spec.object_point(id).expect("corner");
        assert!((p.x - ((id % 4) + 1) as f64 * 0.04).abs() < 1e-12);
        assert!((p.y - ((id / 4) + 1) as f64 * 0.04).abs() < 1e-12);
        assert_eq!(p.z, 0.0);
    }
    assert!(spec.object_point(24).is_none());
    // Square (0, 0) is black; legacy with an even number of rows starts white.
    assert_eq!(spec.is_black(0.001, 0.001), Some(true));
    let legacy = TargetSpec::Charuco {
        squares_x: 5,
        squares_y: 6,
        square: 0.04,
        marker: 0.02,
        dictionary: "DICT_6X6_250".into(),
        legacy: true,
    };
    assert_eq!(legacy.is_black(0.001, 0.001), Some(false));
}

#[test]
fn aprilgrid_ids_and_positions_follow_kalibr() {
    // Kalibr's 2×2 example: ids 0..15, tag 0 at the bottom-left, y up.
    let spec = TargetSpec::Aprilgrid {
        tag_rows: 2,
        tag_cols: 2,
        tag_size: 1.0,
        tag_spacing: 0.5,
        tag_family: "tag36h11".into(),
    };
    let want = [
        (0, 0.0, 0.0),
        (1, 1.0, 0.0),
        (2, 1.5, 0.0),
        (3, 2.5, 0.0),
        (4, 0.0, 1.0),
        (7, 2.5, 1.0),
        (8, 0.0, 1.5),
        (13, 1.0, 2.5),
        (15, 2.5, 2.5),
    ];
    for (id, x, y) in want {
        let p = spec.object_point(id).expect("corner");
        assert!(
            (p.x - x).abs() < 1e-12 && (p.y - y).abs() < 1e-12,
            "{id}: {p:?}"
        );
    }
    assert!(spec.object_point(16).is_none());
    // Black corner squares between the tags; white gaps.
    assert_eq!(spec.is_black(1.25, 1.25), Some(true));
    assert_eq!(spec.is_black(1.25, 0.5), Some(false));
    assert_eq!(spec.is_black(0.05, 0.05), Some(true));
}

#[test]
fn impossible_boards_name_the_field() {
    let ch = |sx, sy, square, marker, dict: &str| TargetSpec::Charuco {
        squares_x: sx,
        squares_y: sy,
        square,
        marker,
        dictionary: dict.into(),
        legacy: false,
    };
    assert_eq!(
        field(ch(5, 7, 0.04, 0.04, "DICT_4X4_50").validate().unwrap_err()),
        "marker"
    );
    assert_eq!(
        field(ch(1, 7, 0.04, 0.02, "DICT_4X4_50").validate().unwrap_err()),
        "squares_x"
    );
    assert_eq!(
        field(
            ch(5, 7, f64::NAN, 0.02, "DICT_4X4_50")
                .validate()
                .unwrap_err()
        ),
        "square"
    );
    assert_eq!(
        field(ch(5, 7, 0.04, -0.02, "DICT_4X4_50").validate().unwrap_err()),
        "marker"
    );
    assert_eq!(
        field(ch(5, 7, 0.04, 0.02, "DICT_9X9_1").validate().unwrap_err()),
        "dictionary"
    );
    // 12×12 squares need 72 markers; DICT_4X4_50 has 50.
    let e = ch(12, 12, 0.04, 0.02, "DICT_4X4_50")
        .validate()
        .unwrap_err();
    assert!(e.to_string().contains("72"), "{e}");
    assert!(ch(12, 12, 0.04, 0.02, "DICT_4X4_100").validate().is_ok());
    let ag = |rows, cols, size, spacing, fam: &str| TargetSpec::Aprilgrid {
        tag_rows: rows,
        tag_cols: cols,
        tag_size: size,
        tag_spacing: spacing,
        tag_family: fam.into(),
    };
    assert_eq!(
        field(ag(0, 6, 0.08, 0.3, "tag36h11").validate().unwrap_err()),
        "tag_rows"
    );
    assert_eq!(
        field(ag(6, 6, 0.0, 0.3, "tag36h11").validate().unwrap_err()),
        "tag_size"
    );
    assert_eq!(
        field(ag(6, 6, 0.08, 1.5, "tag36h11").validate().unwrap_err()),
        "tag_spacing"
    );
    assert_eq!(
        field(ag(6, 6, 0.08, 0.3, "tag25h9").validate().unwrap_err()),
        "tag_family"
    );
    assert_eq!(
        field(ag(30, 30, 0.08, 0.3, "tag36h11").validate().unwrap_err()),
        "tag_cols"
    );
    let cb = TargetSpec::Chessboard {
        cols: 1,
        rows: 6,
        square: 0.02,
    };
    assert_eq!(field(cb.validate().unwrap_err()), "cols");
    assert_eq!(cb.num_corners(), 0);
    assert!(cb.object_point(0).is_none());
}

#[test]
fn kalibr_yaml_as_kalibr_writes_it() {
    let april = "target_type: 'aprilgrid' #gridtype\ntagCols: 6               #number of apriltags\ntagRows: 7               #number of apriltags\ntagSize: 0.088           #size of apriltag, edge to edge [m]\ntagSpacing: 0.3          #ratio of space between tags to tagSize\n";
    assert_eq!(
        TargetSpec::from_kalibr_yaml(april).expect("aprilgrid"),
        TargetSpec::Aprilgrid {
            tag_rows: 7,
            tag_cols: 6,
            tag_size: 0.088,
            tag_spacing: 0.3,
            tag_family: "tag36h11".into()
        }
    );
    let checker = "target_type: 'checkerboard' #gridtype\ntargetCols: 6\ntargetRows: 7\nrowSpacingMeters: 0.06\ncolSpacingMeters: 0.06\n";
    assert_eq!(
        TargetSpec::from_kalibr_yaml(checker).expect("checkerboard"),
        TargetSpec::Chessboard {
            cols: 6,
            rows: 7,
            square: 0.06
        }
    );
    for (bad, key) in [
        (
            "target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 7\ntagSize: 0.088\n",
            "tagSpacing",
        ),
        (
            "target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 7\ntagSize: 0.088\ntagSpacing: 0.3\ntagSpace: 1\n",
            "tagSpace",
        ),
        ("target_type: 'circlegrid'\n", "target_type"),
        (
            "target_type: 'checkerboard'\ntargetCols: 6\ntargetRows: 7\nrowSpacingMeters: 0.06\ncolSpacingMeters: 0.05\n",
            "rowSpacingMeters",
        ),
        (
            "target_type: 'aprilgrid'\ntagCols: six\ntagRows: 7\ntagSize: 0.088\ntagSpacing: 0.3\n",
            "tagCols",
        ),
        (
            "target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 7\ntagSize: -1\ntagSpacing: 0.3\n",
            "tag_size",
        ),
    ] {
        assert_eq!(
            field(TargetSpec::from_kalibr_yaml(bad).unwrap_err()),
            key,
            "{bad}"
        );
    }
    assert!(TargetSpec::from_kalibr_yaml("target_type: 'aprilgrid'\n  nested: 1\n").is_err());
}

#[test]
fn opencv_charuco_parameters() {
    let text = "%YAML:1.0\n---\nsquaresX: 5\nsquaresY: 7\nsquareLength: 0.04\nmarkerLength: 0.02\ndictionary: 10\n";
    assert_eq!(
        TargetSpec::from_opencv_charuco(text).expect("params"),
        TargetSpec::Charuco {
            squares_x: 5,
            squares_y: 7,
            square: 0.04,
            marker: 0.02,
            dictionary: "DICT_6X6_250".into(),
            legacy: false
        }
    );
    let named = "squaresX: 6\nsquaresY: 8\nsquareLength: 30\nmarkerLength: 22\ndictionary: DICT_4X4_50\nlegacyPattern: true\n";
    assert!(matches!(
        TargetSpec::from_opencv_charuco(named).expect("named"),
        TargetSpec::Charuco { legacy: true, .. }
    ));
    let bad =
        "squaresX: 6\nsquaresY: 8\nsquareLength: 30\nmarkerLength: 32\ndictionary: DICT_4X4_50\n";
    assert_eq!(
        field(TargetSpec::from_opencv_charuco(bad).unwrap_err()),
        "marker"
    );
}

#[test]
fn dictionaries_are_opencv_tables() {
    // First codes of OpenCV's tables (bits row-major, 1 = white), checked against
    // cv2.aruco.getPredefinedDictionary(...).bytesList.
    let d = Dictionary::from_name("DICT_4X4_50").expect("4x4");
    assert_eq!(d.code(0), Some(0xb532));
    let t = Dictionary::from_name("DICT_APRILTAG_36h11").expect("36h11");
    assert_eq!(t.len(), 587);
    assert_eq!(t.code(0), Some(0x21a146bab));
}
