//! Cross-check against OpenCV (runs only with `CALIPER_PYTHON` set to a Python with cv2 ≥ 4.7;
//! says loudly when skipped): OpenCV's own board image has our layout, and OpenCV's
//! `CharucoDetector` finds the same ids at the same places as we do on our renders.

#[path = "targets_render.rs"]
mod render;

use std::path::PathBuf;
use std::process::Command;

use caliper_core::board::{TargetOptions, TargetSpec, detect_target};
use render::{Scene, render};

fn python() -> Option<(std::ffi::OsString, PathBuf)> {
    let Some(py) = std::env::var_os("CALIPER_PYTHON") else {
        eprintln!("SKIPPED: set CALIPER_PYTHON to a Python with cv2 to cross-check against OpenCV");
        return None;
    };
    let script = [
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/peers/charuco_opencv.py"),
        PathBuf::from("/work/shared/peers/charuco_opencv.py"),
    ]
    .into_iter()
    .find(|p| p.is_file());
    let Some(script) = script else {
        eprintln!("SKIPPED: charuco_opencv.py not found");
        return None;
    };
    Some((py, script))
}

const ARGS: [&str; 8] = [
    "--squares",
    "7x6",
    "--square",
    "0.04",
    "--marker",
    "0.03",
    "--dict",
    "DICT_5X5_100",
];

fn spec(legacy: bool) -> TargetSpec {
    TargetSpec::Charuco {
        squares_x: 7,
        squares_y: 6,
        square: 0.04,
        marker: 0.03,
        dictionary: "DICT_5X5_100".into(),
        legacy,
    }
}

#[test]
fn opencv_board_image_matches_our_layout() {
    let Some((py, script)) = python() else { return };
    let dir = std::env::temp_dir().join(format!("caliper-targets-ocv-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    for legacy in [false, true] {
        let out = dir.join(format!("board{legacy}.png"));
        let mut cmd = Command::new(&py);
        cmd.arg(&script)
            .arg("render")
            .args(ARGS)
            .args(["--px", "700x600", "--out"])
            .arg(&out);
        if legacy {
            cmd.arg("--legacy");
        }
        let st = cmd.output().expect("run the peer");
        assert!(
            st.status.success(),
            "{}",
            String::from_utf8_lossy(&st.stderr)
        );
        let img = image::open(&out).expect("png").to_luma8();
        // 100 px per square: compare at pixel centres away from the edges.
        let s = spec(legacy);
        let (mut n, mut bad) = (0, 0);
        for y in 0..600u32 {
            for x in 0..700u32 {
                let (bx, by) = (
                    (x as f64 + 0.5) / 100.0 * 0.04,
                    (y as f64 + 0.5) / 100.0 * 0.04,
                );
                let Some(black) = s.is_black(bx, by) else {
                    continue;
                };
                // OpenCV rounds marker cells to whole pixels: skip pixels within 1.5 px of
                // one of our cell edges.
                let d = 1.5 / 100.0 * 0.04;
                let uniform = [(-d, -d), (d, -d), (-d, d), (d, d)]
                    .iter()
                    .all(|(dx, dy)| s.is_black(bx + dx, by + dy) == Some(black));
                if !uniform {
                    continue;
                }
                let v = img.get_pixel(x, y).0[0];
                if v > 64 && v < 192 {
                    continue;
                }
                n += 1;
                if black != (v < 128) {
                    bad += 1;
                }
            }
        }
        println!("legacy {legacy}: {bad} of {n} pixels differ from OpenCV's board image");
        assert!(
            bad * 1000 < n,
            "legacy {legacy}: {bad} of {n} pixels differ"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn opencv_finds_our_ids_at_our_positions() {
    let Some((py, script)) = python() else { return };
    let dir = std::env::temp_dir().join(format!("caliper-targets-ocv2-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let s = spec(false);
    let scenes = [
        Scene {
            centre: [0.14, 0.12],
            dist: 0.5,
            rot: [0.5, 0.3, 0.2],
            blur: 1.0,
            noise: 1.0,
            ..Scene::default()
        },
        Scene {
            centre: [0.14, 0.12],
            dist: 0.45,
            rot: [-0.2, 0.9, -0.3],
            shift: [250.0, 0.0],
            blur: 1.0,
            noise: 1.0,
            ..Scene::default()
        },
    ];
    let mut ours = Vec::new();
    for (k, sc) in scenes.iter().enumerate() {
        let v = render(&s, sc, 0.02);
        image::GrayImage::from_raw(v.image.width, v.image.height, v.image.data.clone())
            .expect("image")
            .save(dir.join(format!("v{k}.png")))
            .expect("png");
        ours.push((
            detect_target(&v.image, &s, &TargetOptions::default()),
            v.truth,
        ));
    }
    let out = Command::new(&py)
        .arg(&script)
        .arg("detect")
        .args(ARGS)
        .arg("--images")
        .arg(dir.join("v*.png"))
        .output()
        .expect("run the peer");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let doc: serde_json::Value = serde_json::from_slice(&out.stdout).expect("json");
    for (k, (det, truth)) in ours.iter().enumerate() {
        let im = &doc["images"][k];
        let ids: Vec<usize> = im["ids"]
            .as_array()
            .expect("ids")
            .iter()
            .filter_map(|v| v.as_u64())
            .map(|v| v as usize)
            .collect();
        let cs = im["corners"].as_array().expect("corners");
        let (mut both, mut sd, mut se_ocv, mut se_ours) = (0, 0.0, 0.0, 0.0);
        for (id, c) in ids.iter().zip(cs) {
            let q = [c[0].as_f64().expect("x"), c[1].as_f64().expect("y")];
            let t = truth
                .iter()
                .find(|(i, _)| i == id)
                .map(|(_, p)| *p)
                .expect("OpenCV id on the board");
            se_ocv += (q[0] - t[0]).powi(2) + (q[1] - t[1]).powi(2);
            if let Some(p) = det.corners.iter().find(|c| c.index == *id) {
                both += 1;
                sd += (p.pixel[0] - q[0]).powi(2) + (p.pixel[1] - q[1]).powi(2);
                se_ours += (p.pixel[0] - t[0]).powi(2) + (p.pixel[1] - t[1]).powi(2);
            }
        }
        let n = both.max(1) as f64;
        println!(
            "view {k}: OpenCV {} corners, ours {}, {both} in both; RMS ours−OpenCV {:.3} px; vs truth: ours {:.3}, OpenCV {:.3} px",
            ids.len(),
            det.corners.len(),
            (sd / n).sqrt(),
            (se_ours / n).sqrt(),
            (se_ocv / ids.len().max(1) as f64).sqrt()
        );
        // Every corner OpenCV finds, we find too, within a fraction of a pixel.
        assert_eq!(both, ids.len(), "view {k}: OpenCV found ids we did not");
        assert!((sd / n).sqrt() < 0.3);
    }
    let _ = std::fs::remove_dir_all(&dir);
}
