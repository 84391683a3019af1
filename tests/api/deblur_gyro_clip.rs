//! `deblur` with method `gyro` on a clip: every chosen frame gets the kernel of its own
//! exposure, cut out of an IMU log uploaded as a second dataset (or given with `--gyro`
//! offline). The camera turns about its y axis for the first half of the clip and about its
//! x axis for the second, so a horizontal and a vertical streak must come back for frames of
//! the two halves, and each frame restored with its kernel must come out sharper.

use caliper_core::deconv::Psf;
use serde_json::{Value, json};

use crate::common::*;
use crate::deblur::{blur, extents, kernel_of, psnr, sharp_rgb};

const W: usize = 96;
const H: usize = 80;
/// Log-clock time (ns) at which the first frame's exposure starts.
const T0: i64 = 1_403_636_579_758_555_392;
const FPS: f64 = 10.0;
/// 0.5 rad/s for 20 ms at fx = 500 px: a 5 px streak.
const RATE: f64 = 0.5;
const EXPOSURE_MS: f64 = 20.0;
const FX: f64 = 500.0;

/// A 1 kHz EuRoC-style log over the clip: about y for the first 0.4 s, then about x.
fn imu_csv() -> String {
    let mut csv = String::from(
        "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],\
         a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n",
    );
    for i in -50i64..900 {
        let t = T0 + i * 1_000_000;
        let (wx, wy) = if i < 400 { (0.0, RATE) } else { (RATE, 0.0) };
        csv.push_str(&format!("{t},{wx},{wy},0.0,0.0,0.0,9.81\n"));
    }
    csv
}

fn grey(img: &[[f64; 3]]) -> image::GrayImage {
    image::GrayImage::from_fn(W as u32, H as u32, |x, y| {
        let p = img[y as usize * W + x as usize];
        image::Luma([(p[0].clamp(0.0, 1.0) * 255.0).round() as u8])
    })
}

fn as_rgb(g: &image::GrayImage) -> Vec<[f64; 3]> {
    g.pixels().map(|p| [f64::from(p[0]) / 255.0; 3]).collect()
}

/// The clip (8 frames at 10 fps: four smeared along x, four along y) and its sharp scene.
fn clip() -> (Vec<u8>, image::GrayImage, Vec<image::GrayImage>) {
    let sharp = sharp_rgb(W as u32, H as u32);
    // The smear of a steady 5 px sweep: `Psf::motion` counts the end points (n taps span
    // n − 1 px), so a 5 px sweep is its length 6.
    let sweep = RATE * EXPOSURE_MS * 1e-3 * FX + 1.0;
    let along_x = grey(&blur(&sharp, W, H, &Psf::motion(sweep, 0.0).expect("psf")));
    let along_y = grey(&blur(&sharp, W, H, &Psf::motion(sweep, 90.0).expect("psf")));
    let frames: Vec<image::GrayImage> = (0..8)
        .map(|i| {
            if i < 4 {
                along_x.clone()
            } else {
                along_y.clone()
            }
        })
        .collect();
    let mp4 = caliper_core::video::encode_h264_mp4(&frames, FPS).expect("encode");
    (mp4, grey(&sharp), frames)
}

/// PSNR against the truth at the best whole-pixel shift within ±4 px: a gyro kernel starts
/// where the exposure starts, so the restored frame sits where the camera pointed then,
/// not at the middle of the smear as the centred test kernel puts it.
fn aligned_psnr(img: &image::GrayImage, truth: &image::GrayImage) -> f64 {
    let shifted = |dx: i64, dy: i64| -> Vec<[f64; 3]> {
        image::GrayImage::from_fn(W as u32, H as u32, |x, y| {
            let sx = (i64::from(x) + dx).clamp(0, W as i64 - 1) as u32;
            let sy = (i64::from(y) + dy).clamp(0, H as i64 - 1) as u32;
            *img.get_pixel(sx, sy)
        })
        .pixels()
        .map(|p| [f64::from(p[0]) / 255.0; 3])
        .collect()
    };
    let t = as_rgb(truth);
    (-4..=4)
        .flat_map(|dy| (-4..=4).map(move |dx| (dx, dy)))
        .map(|(dx, dy)| psnr(&shifted(dx, dy), &t, W, H, 12))
        .fold(f64::MIN, f64::max)
}

fn gyro_clip(imu: Option<&str>, start: i64) -> Value {
    let mut g = json!({"clip_start_ns": start, "exposure_s": EXPOSURE_MS * 1e-3,
                       "fx": FX, "fy": FX, "cx": W as f64 / 2.0, "cy": H as f64 / 2.0});
    if let Some(id) = imu {
        g["imu_dataset"] = json!(id);
    }
    g
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn gyro_deblur_of_a_clip_gives_each_frame_the_kernel_of_its_exposure() {
    let (mp4, truth, frames) = tokio::task::spawn_blocking(clip).await.expect("join");
    let s = start().await;
    let video = s.dataset(vec![("shake.mp4", mp4.clone())]).await;
    let imu = s.dataset(vec![("imu0.csv", imu_csv().into_bytes())]).await;
    let params = json!({"method": "gyro", "frames": {"times": [0.1, 0.5]},
                        "gyro_clip": gyro_clip(Some(&imu), T0)});
    let id = s
        .job(json!({"kind": "deblur", "dataset": video, "params": params}))
        .await;
    // The log cannot be deleted while the job may still read it.
    let r = s
        .client
        .delete(s.url(&format!("/v1/datasets/{imu}")))
        .send()
        .await
        .expect("delete");
    let deleted_early = r.status().as_u16();
    let (_, job_then) = s.get_json(&format!("/v1/jobs/{id}")).await;
    match deleted_early {
        409 => {}
        // Only a job that had already ended lets its log go.
        204 => assert!(
            ["succeeded", "failed", "canceled"]
                .contains(&job_then["status"].as_str().unwrap_or("")),
            "the log was deleted under a live job: {job_then}"
        ),
        other => panic!("delete answered {other}"),
    }
    let done = s.wait_terminal(&id).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    let imu = if deleted_early == 204 {
        s.dataset(vec![("imu0.csv", imu_csv().into_bytes())]).await
    } else {
        imu
    };
    let (_, doc) = s.get_json(&format!("/v1/jobs/{id}/result")).await;
    let restored = doc["parameters"]["images"].as_array().expect("images");
    let starts: Vec<i64> = restored
        .iter()
        .filter_map(|i| i["exposure_start_ns"].as_i64())
        .collect();
    assert_eq!(
        starts,
        vec![T0 + 100_000_000, T0 + 500_000_000],
        "each frame's exposure on the log's clock: {doc}"
    );
    for (index, horizontal) in [(1usize, true), (5, false)] {
        let stem = format!("frame_{index:06}");
        let (ex, ey) = extents(&kernel_of(&s, &id, &stem).await);
        let (along, across) = if horizontal { (ex, ey) } else { (ey, ex) };
        assert!(
            (4..=7).contains(&along) && across <= 1,
            "frame {index}: kernel {ex}×{ey} px, expected a 5 px streak along {}",
            if horizontal { "x" } else { "y" }
        );
        let bytes = s
            .client
            .get(s.url(&format!("/v1/jobs/{id}/artifacts/{stem}.png")))
            .send()
            .await
            .expect("get")
            .bytes()
            .await
            .expect("bytes");
        let out = image::load_from_memory(&bytes).expect("png").to_luma8();
        let before = aligned_psnr(&frames[index], &truth);
        let after = aligned_psnr(&out, &truth);
        assert!(
            after > before + 2.0,
            "frame {index}: PSNR {before:.1} → {after:.1} dB"
        );
    }

    // Bad references are refused before queueing, naming the parameter.
    let missing = "01930000-0000-7000-8000-00000000beef".to_string();
    for (g, code) in [
        (gyro_clip(None, T0), "invalid_param"),
        (gyro_clip(Some(&missing), T0), "unknown_dataset"),
        (gyro_clip(Some(&video), T0), "dataset_kind_mismatch"),
        (gyro_clip(Some("not-a-uuid"), T0), "invalid_param"),
    ] {
        let (st, body) = s
            .post_json(
                "/v1/jobs",
                &json!({"kind": "deblur", "dataset": video,
                        "params": {"method": "gyro", "frames": {"every": 4}, "gyro_clip": g}}),
            )
            .await;
        assert_eq!(st, 422, "{body}");
        assert_eq!(body["code"], code, "{body}");
        assert_eq!(body["field"], "params.gyro_clip.imu_dataset", "{body}");
    }
    // A single-exposure trace is refused for a clip; gyro_clip is refused for stills.
    let (st, body) = s
        .post_json(
            "/v1/jobs",
            &json!({"kind": "deblur", "dataset": video,
                    "params": {"method": "tv", "psf": Psf::motion(5.0, 0.0).expect("psf"),
                               "frames": {"every": 4}, "gyro_clip": gyro_clip(Some(&imu), T0)}}),
        )
        .await;
    assert_eq!(
        (st, body["field"].as_str()),
        (422, Some("params.gyro_clip"))
    );
    // A clip the log does not cover: the job fails naming the frame and the log's span.
    let id = s
        .job(json!({"kind": "deblur", "dataset": video,
                    "params": {"method": "gyro", "frames": {"times": [0.5]},
                               "gyro_clip": gyro_clip(Some(&imu), T0 + 600_000_000)}}))
        .await;
    let done = s.wait_terminal(&id).await;
    assert_eq!(done["status"], "failed", "{done}");
    let err = done["error"]["message"].as_str().unwrap_or_default();
    assert!(err.contains("frame 5") && err.contains("covers"), "{done}");
    s.stop().await;

    // Offline: the same clip and log give the same per-frame kernels.
    let dir = tempfile::tempdir().expect("tmp");
    let (clip_path, log, cam, out) = (
        dir.path().join("shake.mp4"),
        dir.path().join("imu0.csv"),
        dir.path().join("cam.json"),
        dir.path().join("out"),
    );
    std::fs::write(&clip_path, &mp4).expect("write");
    std::fs::write(&log, imu_csv()).expect("write");
    std::fs::write(
        &cam,
        format!(
            r#"{{"parameters": {{"camera": {{"fx": {FX}, "fy": {FX}, "cx": {}, "cy": {}}}}}}}"#,
            W as f64 / 2.0,
            H as f64 / 2.0
        ),
    )
    .expect("write");
    let o = std::process::Command::new(caliper_bin())
        .args(["run", "deblur", "--method", "gyro", "--gyro"])
        .arg(&log)
        .arg("--camera")
        .arg(&cam)
        .args(["--clip-start-ns", &T0.to_string(), "--exposure-ms", "20"])
        .args(["--frames", "times:0.1,0.5", "--out"])
        .arg(&out)
        .arg(&clip_path)
        .output()
        .expect("run caliper");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let k1 = Psf::parse_json(
        &std::fs::read_to_string(out.join("frame_000001.kernel.json")).expect("kernel"),
    )
    .expect("kernel");
    let k5 = Psf::parse_json(
        &std::fs::read_to_string(out.join("frame_000005.kernel.json")).expect("kernel"),
    )
    .expect("kernel");
    let ((x1, y1), (x5, y5)) = (extents(&k1), extents(&k5));
    assert!(
        x1 >= 4 && y1 <= 1 && y5 >= 4 && x5 <= 1,
        "{x1}×{y1}, {x5}×{y5}"
    );
}
