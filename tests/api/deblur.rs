//! `deblur` end to end: a 16-bit RGB image blurred by a known motion kernel comes back sharper,
//! in the same pixel format; bad parameters are refused before queueing; the offline command
//! writes the deblurred file under the input's name.

use std::io::Cursor;

use caliper_core::deconv::Psf;
use image::{DynamicImage, ImageBuffer, ImageFormat, Rgb};
use serde_json::{Value, json};

use crate::common::*;

/// A sharp colour scene: checkerboard plus deterministic texture, one pattern per channel.
pub(crate) fn sharp_rgb(w: u32, h: u32) -> Vec<[f64; 3]> {
    let grey = sharp_image(w, h);
    (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| {
            let v = f64::from(grey.get_pixel(x, y)[0]) / 255.0;
            [v, 0.3 + 0.5 * v, 1.0 - 0.8 * v]
        })
        .collect()
}

/// Convolve with `psf`, clamping at the borders (the service's boundary model must cope).
pub(crate) fn blur(img: &[[f64; 3]], w: usize, h: usize, psf: &Psf) -> Vec<[f64; 3]> {
    let (rx, ry) = (psf.width / 2, psf.height / 2);
    let mut out = vec![[0.0; 3]; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut acc = [0.0; 3];
            for ky in 0..psf.height {
                for kx in 0..psf.width {
                    let k = psf.at(kx, ky);
                    if k == 0.0 {
                        continue;
                    }
                    let sx = (x + rx).saturating_sub(kx).min(w - 1);
                    let sy = (y + ry).saturating_sub(ky).min(h - 1);
                    for c in 0..3 {
                        acc[c] += k * img[sy * w + sx][c];
                    }
                }
            }
            out[y * w + x] = acc;
        }
    }
    out
}

fn to_png16(img: &[[f64; 3]], w: u32, h: u32) -> Vec<u8> {
    let buf: ImageBuffer<Rgb<u16>, Vec<u16>> = ImageBuffer::from_fn(w, h, |x, y| {
        let p = img[(y * w + x) as usize];
        Rgb(p.map(|v| (v.clamp(0.0, 1.0) * 65535.0).round() as u16))
    });
    let mut out = Cursor::new(Vec::new());
    DynamicImage::ImageRgb16(buf)
        .write_to(&mut out, ImageFormat::Png)
        .expect("png");
    out.into_inner()
}

/// PSNR over the interior (the outer `margin` pixels depend on the unknown boundary).
pub(crate) fn psnr(a: &[[f64; 3]], b: &[[f64; 3]], w: usize, h: usize, margin: usize) -> f64 {
    let mut se = 0.0;
    let mut n = 0usize;
    for y in margin..h - margin {
        for x in margin..w - margin {
            for c in 0..3 {
                let d = a[y * w + x][c] - b[y * w + x][c];
                se += d * d;
                n += 1;
            }
        }
    }
    10.0 * (n as f64 / se).log10()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn deblur_sharpens_a_16_bit_rgb_image_and_keeps_its_format() {
    let (w, h) = (160u32, 120u32);
    let sharp = sharp_rgb(w, h);
    let psf = Psf::motion(11.0, 30.0).expect("psf");
    let blurred = blur(&sharp, w as usize, h as usize, &psf);
    let s = start().await;
    let ds = s
        .dataset(vec![("shot.png", to_png16(&blurred, w, h))])
        .await;
    let id = s
        .job(json!({"kind": "deblur", "dataset": ds, "params": {"method": "tv", "psf": psf}}))
        .await;
    let done = s.wait_terminal(&id).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    let (_, doc) = s.get_json(&format!("/v1/jobs/{id}/result")).await;
    assert_eq!(doc["schema"], "caliper.deblur/v1");
    assert_eq!(doc["parameters"]["images"][0]["artifact"], "shot.png");

    let bytes = reqwest::get(s.url(&format!("/v1/jobs/{id}/artifacts/shot.png")))
        .await
        .expect("artifact")
        .bytes()
        .await
        .expect("body");
    let out = image::load_from_memory(&bytes).expect("decodes");
    let DynamicImage::ImageRgb16(out) = out else {
        panic!("expected 16-bit RGB back, got {:?}", out.color());
    };
    let restored: Vec<[f64; 3]> = out
        .pixels()
        .map(|p| p.0.map(|v| f64::from(v) / 65535.0))
        .collect();
    let before = psnr(&blurred, &sharp, w as usize, h as usize, 8);
    let after = psnr(&restored, &sharp, w as usize, h as usize, 8);
    assert!(
        after > before + 5.0,
        "deblurring must gain > 5 dB: {before:.2} → {after:.2} dB"
    );

    // The kernel used comes back exactly (JSON) and as a picture.
    let kj: Value = reqwest::get(s.url(&format!("/v1/jobs/{id}/artifacts/shot.kernel.json")))
        .await
        .expect("kernel")
        .json()
        .await
        .expect("json");
    assert_eq!(kj["width"], psf.width);
    let resp = reqwest::get(s.url(&format!("/v1/jobs/{id}/artifacts/shot.preview.png")))
        .await
        .expect("preview");
    assert_eq!(resp.status(), 200);
    s.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn deblur_refuses_inconsistent_params_before_queueing() {
    let s = start().await;
    let ds = s.dataset(vec![("a.png", png(&sharp_image(64, 48)))]).await;
    // Each params object is refused with 422 naming the offending field (None: any field).
    let cases = [
        // A non-blind method without a kernel.
        (json!({"method": "wiener"}), Some("params.psf")),
        // A kernel that is not normalisable.
        (
            json!({"method": "tv", "psf": {"width": 3, "height": 3, "data": [0,0,0,0,-1,0,0,0,0]}}),
            Some("params.psf"),
        ),
        // A grid for a method that draws no gyro kernels.
        (
            json!({"method": "tv", "psf": {"width": 1, "height": 1, "data": [1]}, "gyro_grid": [4, 4]}),
            Some("params.gyro_grid"),
        ),
        // A saturation level outside [0.5, 1].
        (
            json!({"method": "blind", "saturation": 1.5}),
            Some("params.saturation"),
        ),
        // A kernel threshold out of range, and one for a method that estimates no kernel.
        (
            json!({"method": "blind", "kernel_threshold": 0.9}),
            Some("params.kernel_threshold"),
        ),
        (
            json!({"method": "tv", "psf": {"width": 1, "height": 1, "data": [1]}, "kernel_threshold": 0.05}),
            Some("params.kernel_threshold"),
        ),
        // A region below 128 px, and one for a method that estimates no kernel.
        (
            json!({"method": "blind", "kernel_region": 64}),
            Some("params.kernel_region"),
        ),
        (
            json!({"method": "tv", "psf": {"width": 1, "height": 1, "data": [1]}, "kernel_region": 512}),
            Some("params.kernel_region"),
        ),
        // Unknown method.
        (json!({"method": "magic"}), None),
    ];
    for (params, field) in cases {
        let (status, p) = s
            .post_json(
                "/v1/jobs",
                &json!({"kind": "deblur", "dataset": ds, "params": params}),
            )
            .await;
        assert_eq!(status, 422, "{p}");
        if let Some(field) = field {
            assert_eq!(p["field"], field, "{p}");
        }
    }
    s.stop().await;
}

#[test]
fn offline_deblur_writes_the_image_under_its_name_and_the_kernel() {
    let dir = tempfile::tempdir().expect("tmp");
    let img = box_blur(&sharp_image(96, 72), 5);
    let input = dir.path().join("blurred.png");
    std::fs::write(&input, png(&img)).expect("write");
    // A 5×5 box kernel as numpy.savetxt writes it.
    let kernel = dir.path().join("kernel.txt");
    let row = ["4.000000000000000083e-02"; 5].join(" ");
    std::fs::write(&kernel, format!("{row}\n").repeat(5)).expect("write");
    let out = dir.path().join("out");
    // `caliper run deblur FLAGS --psf kernel.txt [--out out/] blurred.png`.
    let run = |flags: &[&str], with_out: bool| {
        let mut c = std::process::Command::new(caliper_bin());
        c.args(["run", "deblur"])
            .args(flags)
            .arg("--psf")
            .arg(&kernel);
        if with_out {
            c.arg("--out").arg(&out);
        }
        c.arg(&input).output().expect("run caliper")
    };
    let o = run(&["--method", "wiener"], true);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let doc: Value = serde_json::from_slice(&o.stdout).expect("document");
    assert_eq!(doc["schema"], "caliper.deblur/v1");
    let back = image::open(out.join("blurred.png")).expect("deblurred image");
    assert_eq!(back.color(), image::ColorType::L8);
    assert_eq!((back.width(), back.height()), (96, 72));
    assert!(out.join("blurred.kernel.png").exists());
    assert!(out.join("blurred.kernel.json").exists());
    // The clipped-highlight level: `off` is accepted, a level outside [0.5, 1] is named.
    for (level, ok) in [("off", true), ("0.98", true), ("1.7", false)] {
        let o = run(&["--method", "tv", "--saturation", level], true);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.success(), ok, "{level}: {err}");
        if !ok {
            assert!(err.contains("saturation"), "{err}");
        }
    }
    // Blind offline: the printed document carries the candidates' agreement as the service's
    // does, and a fixed cleaning threshold (one candidate) carries none.
    let blind = |extra: &[&str]| -> Value {
        let o = std::process::Command::new(caliper_bin())
            .args(["run", "deblur", "--method", "blind", "--kernel-size", "9"])
            .args(extra)
            .arg(&input)
            .output()
            .expect("run caliper");
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        serde_json::from_slice(&o.stdout).expect("document")
    };
    let doc = blind(&[]);
    let k = &doc["parameters"]["images"][0]["kernel"];
    let a = k["agreement"].as_f64().expect("agreement");
    assert!((0.0..=1.0).contains(&a), "{doc}");
    // A clean photo gets the threshold chosen at low noise.
    assert_eq!(k["uncertain_below"], json!(0.8), "{doc}");
    assert_eq!(k["uncertain"], json!(a < 0.8), "{doc}");
    assert_eq!(
        doc["quality"]["uncertain_kernels"],
        json!(usize::from(a < 0.8)),
        "{doc}"
    );
    let doc = blind(&["--kernel-threshold", "0.1"]);
    let k = &doc["parameters"]["images"][0]["kernel"];
    assert_eq!(k["cleaning_threshold"], json!(0.1), "{doc}");
    assert!(
        k["agreement"].is_null() && k["uncertain"].is_null() && k["uncertain_below"].is_null(),
        "{doc}"
    );
    // A photo larger than `--kernel-region` (and 16 kernel windows): the document names the
    // region the kernel came from, inside the photo.
    let wide = dir.path().join("wide.png");
    std::fs::write(&wide, png(&box_blur(&sharp_image(200, 150), 5))).expect("write");
    let o = std::process::Command::new(caliper_bin())
        .args(["run", "deblur", "--method", "blind", "--kernel-size", "9"])
        .args(["--kernel-threshold", "0.1", "--kernel-region", "128"])
        .arg(&wide)
        .output()
        .expect("run caliper");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let doc: Value = serde_json::from_slice(&o.stdout).expect("document");
    let r = &doc["parameters"]["images"][0]["kernel"]["region"];
    // 16 windows of 9 px: more than the 128 px asked for.
    assert_eq!(
        (&r["width"], &r["height"]),
        (&json!(144), &json!(144)),
        "{doc}"
    );
    let (x, y) = (r["x"].as_u64().expect("x"), r["y"].as_u64().expect("y"));
    assert!(x + 144 <= 200 && y + 144 <= 150, "{doc}");
    // The photo that fits the default region has none.
    assert!(k["region"].is_null(), "{k}");
    // A kernel file that is not a kernel: clear error, non-zero exit.
    std::fs::write(&kernel, "1 2\n3\n").expect("write");
    let o = run(&["--method", "wiener"], false);
    assert!(!o.status.success());
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("kernel.txt"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
}

/// Grey version of the colour helpers above (the blind estimate runs on luma anyway).
fn grey_png(img: &[[f64; 3]], w: u32, h: u32) -> Vec<u8> {
    let buf: ImageBuffer<image::Luma<u8>, Vec<u8>> = ImageBuffer::from_fn(w, h, |x, y| {
        image::Luma([(img[(y * w + x) as usize][0].clamp(0.0, 1.0) * 255.0).round() as u8])
    });
    png(&buf)
}

/// The kernel a job used, from its JSON artifact (`{width, height, kernel: rows}`).
/// Extent of the kernel's support (weights over 1e-3) along x and y, px.
pub(crate) fn extents(k: &Psf) -> (usize, usize) {
    let cols: Vec<usize> = (0..k.width)
        .filter(|&x| (0..k.height).any(|y| k.at(x, y) > 1e-3))
        .collect();
    let rows: Vec<usize> = (0..k.height)
        .filter(|&y| (0..k.width).any(|x| k.at(x, y) > 1e-3))
        .collect();
    let span = |v: &[usize]| v.last().unwrap_or(&0) - v.first().unwrap_or(&0);
    (span(&cols), span(&rows))
}

pub(crate) async fn kernel_of(s: &TestServer, job: &str, stem: &str) -> Psf {
    let text = reqwest::get(s.url(&format!("/v1/jobs/{job}/artifacts/{stem}.kernel.json")))
        .await
        .expect("kernel")
        .text()
        .await
        .expect("text");
    Psf::parse_json(&text).expect("a valid kernel")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn blind_and_gyro_deblur_return_their_kernels() {
    let (w, h) = (128u32, 128u32);
    let sharp = sharp_rgb(w, h);
    let psf = Psf::motion(9.0, 0.0).expect("psf");
    let blurred = blur(&sharp, w as usize, h as usize, &psf);
    let s = start().await;
    let ds = s.dataset(vec![("b.png", grey_png(&blurred, w, h))]).await;

    // Blind: the estimated kernel is a horizontal streak about as long as the true one.
    let id = s
        .job(json!({"kind": "deblur", "dataset": ds, "params": {"method": "blind", "kernel_size": 15}}))
        .await;
    let done = s.wait_terminal(&id).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    // The document says which cleaning threshold the blind choice kept.
    let (_, doc) = s.get_json(&format!("/v1/jobs/{id}/result")).await;
    let t = doc["parameters"]["images"][0]["kernel"]["cleaning_threshold"].as_f64();
    assert!(matches!(t, Some(v) if v == 0.1 || v == 0.05), "{doc}");
    // And how far the two candidate kernels agree: on a clean 9 px streak they agree, so the
    // kernel is not flagged and the quality block counts no uncertain kernel.
    let kernel = &doc["parameters"]["images"][0]["kernel"];
    let agreement = kernel["agreement"].as_f64().expect("agreement");
    assert!((0.0..=1.0).contains(&agreement), "{doc}");
    assert_eq!(kernel["uncertain_below"], json!(0.8), "{doc}");
    assert_eq!(kernel["uncertain"], json!(agreement < 0.8), "{doc}");
    assert_eq!(doc["quality"]["uncertain_kernels"], json!(0), "{doc}");
    let k = kernel_of(&s, &id, "b").await;
    let (mut sx, mut sy) = (0.0, 0.0);
    let (cx, cy) = ((k.width / 2) as f64, (k.height / 2) as f64);
    for y in 0..k.height {
        for x in 0..k.width {
            sx += k.at(x, y) * (x as f64 - cx).powi(2);
            sy += k.at(x, y) * (y as f64 - cy).powi(2);
        }
    }
    // A 9 px box along x has variance (9² − 1) / 12 ≈ 6.7 px².
    assert!(
        sx > 3.0 && sx > 3.0 * sy,
        "kernel spread x {sx:.2}, y {sy:.2}"
    );

    // Gyro: 0.5 rad/s about the camera's y axis for 20 ms at fx = 500 px is a 5 px streak.
    let samples: Vec<Value> = (0..=30)
        .map(|i| json!({"t": i as f64 * 0.001, "w": [0.0, 0.5, 0.0]}))
        .collect();
    let gyro = json!({"samples": samples, "exposure_start_s": 0.005, "exposure_s": 0.02,
                      "fx": 500.0, "fy": 500.0, "cx": 64.0, "cy": 64.0});
    let id = s
        .job(json!({"kind": "deblur", "dataset": ds, "params": {"method": "gyro", "gyro": gyro}}))
        .await;
    let done = s.wait_terminal(&id).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    // Only the blind method has a cleaning threshold to report.
    let (_, doc) = s.get_json(&format!("/v1/jobs/{id}/result")).await;
    assert!(
        doc["parameters"]["images"][0]["kernel"]["cleaning_threshold"].is_null(),
        "{doc}"
    );
    // Nor an agreement between candidates.
    assert!(
        doc["parameters"]["images"][0]["kernel"]["agreement"].is_null()
            && doc["quality"]["uncertain_kernels"].is_null(),
        "{doc}"
    );
    let k = kernel_of(&s, &id, "b").await;
    let (extent_x, extent_y) = extents(&k);
    assert!(
        (4..=7).contains(&extent_x),
        "gyro streak {extent_x} px wide, kernel {k:?}"
    );
    assert!(extent_y <= 1, "gyro streak {extent_y} px tall");

    // The same trace on a 2×2 grid of kernels (restored tile by tile and blended): the image
    // comes back whole, at full size (the core tests measure the grid's accuracy).
    let id = s
        .job(json!({"kind": "deblur", "dataset": ds,
                    "params": {"method": "gyro", "gyro": gyro, "gyro_grid": [2, 2]}}))
        .await;
    let done = s.wait_terminal(&id).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    let bytes = reqwest::get(s.url(&format!("/v1/jobs/{id}/artifacts/b.png")))
        .await
        .expect("artifact")
        .bytes()
        .await
        .expect("bytes");
    let img = image::load_from_memory(&bytes).expect("a PNG").to_luma8();
    assert_eq!((img.width(), img.height()), (w, h));
    s.stop().await;
}

#[test]
fn offline_gyro_deblur_reads_an_imu_log() {
    let dir = tempfile::tempdir().expect("tmp");
    let input = dir.path().join("frame.png");
    std::fs::write(&input, png(&box_blur(&sharp_image(96, 72), 3))).expect("write");
    // One second of a 200 Hz EuRoC log turning at 0.5 rad/s about the camera's y axis.
    let t0: i64 = 1_403_636_579_758_555_392;
    let mut csv = String::from(
        "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],\
         a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n",
    );
    for i in 0..200 {
        csv.push_str(&format!(
            "{},0.0,0.5,0.0,0.0,0.0,9.81\n",
            t0 + i * 5_000_000
        ));
    }
    let log = dir.path().join("imu0.csv");
    std::fs::write(&log, csv).expect("write");
    let cam = dir.path().join("cam.json");
    std::fs::write(
        &cam,
        r#"{"parameters": {"camera": {"fx": 500.0, "fy": 500.0, "cx": 48.0, "cy": 36.0}}}"#,
    )
    .expect("write");
    let out = dir.path().join("out");
    let run = |start: i64| {
        std::process::Command::new(caliper_bin())
            .args(["run", "deblur", "--method", "gyro", "--gyro"])
            .arg(&log)
            .arg("--camera")
            .arg(&cam)
            .args([
                "--exposure-start-ns",
                &start.to_string(),
                "--exposure-ms",
                "20",
            ])
            .arg("--out")
            .arg(&out)
            .arg(&input)
            .output()
            .expect("run caliper")
    };
    let o = run(t0 + 300_000_000);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // 0.5 rad/s for 20 ms at fx = 500 px: a horizontal streak of about 5 px.
    let text = std::fs::read_to_string(out.join("frame.kernel.json")).expect("kernel");
    let k = Psf::parse_json(&text).expect("a valid kernel");
    let cols: Vec<usize> = (0..k.width)
        .filter(|&x| (0..k.height).any(|y| k.at(x, y) > 1e-3))
        .collect();
    let rows = (0..k.height)
        .filter(|&y| (0..k.width).any(|x| k.at(x, y) > 1e-3))
        .count();
    let extent_x = cols.last().unwrap_or(&0) - cols.first().unwrap_or(&0);
    assert!((4..=7).contains(&extent_x), "streak {extent_x} px, {k:?}");
    assert!(rows <= 2, "streak {rows} rows tall");
    // An exposure the log does not cover: a clear error naming the log.
    let o = run(t0 + 990_000_000);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("imu0.csv") && err.contains("exposure"),
        "{err}"
    );
}

/// A clip whose frames are one scene, blurred by a known kernel in every frame: the frames
/// chosen by time come back sharper, as `frame_NNNNNN.png` with their kernels; a clip without
/// a frame choice, a frame choice on images and too many frames are refused by name.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn deblur_restores_chosen_frames_of_a_clip() {
    let (w, h) = (96usize, 80usize);
    let psf = Psf::motion(9.0, 0.0).expect("psf");
    let sharp = sharp_rgb(w as u32, h as u32);
    let grey = |img: &[[f64; 3]]| -> image::GrayImage {
        image::GrayImage::from_fn(w as u32, h as u32, |x, y| {
            let p = img[y as usize * w + x as usize];
            image::Luma([(p[0].clamp(0.0, 1.0) * 255.0).round() as u8])
        })
    };
    let blurred = grey(&blur(&sharp, w, h, &psf));
    let frames = vec![blurred.clone(); 12];
    let mp4 = caliper_core::video::encode_h264_mp4(&frames, 10.0).expect("encode");
    let s = start().await;
    let ds = s.dataset(vec![("shake.mp4", mp4)]).await;
    let id = s
        .job(json!({"kind": "deblur", "dataset": ds,
            "params": {"method": "tv", "psf": psf, "frames": {"times": [0.0, 0.5]}}}))
        .await;
    let done = s.wait_terminal(&id).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    let (_, doc) = s.get_json(&format!("/v1/jobs/{id}/result")).await;
    let restored = doc["parameters"]["images"].as_array().expect("images");
    let indices: Vec<u64> = restored
        .iter()
        .filter_map(|i| i["index"].as_u64())
        .collect();
    assert_eq!(indices, vec![0, 5], "{doc}");
    let r = reqwest::get(s.url(&format!("/v1/jobs/{id}/artifacts/frame_000005.png")))
        .await
        .expect("get");
    assert_eq!(r.status(), 200);
    let out = image::load_from_memory(&r.bytes().await.expect("bytes"))
        .expect("png")
        .to_luma8();
    let truth = grey(&sharp);
    let as_rgb = |g: &image::GrayImage| -> Vec<[f64; 3]> {
        g.pixels().map(|p| [f64::from(p[0]) / 255.0; 3]).collect()
    };
    let before = psnr(&as_rgb(&blurred), &as_rgb(&truth), w, h, 12);
    let after = psnr(&as_rgb(&out), &as_rgb(&truth), w, h, 12);
    assert!(after > before + 3.0, "PSNR {before:.1} → {after:.1} dB");
    let k = reqwest::get(s.url(&format!("/v1/jobs/{id}/artifacts/frame_000005.kernel.json")))
        .await
        .expect("get");
    assert_eq!(k.status(), 200);

    // A clip needs a frame choice; images refuse one; too many frames are refused.
    for (params, dataset, needle) in [
        (
            json!({"method": "tv", "psf": psf}),
            ds.clone(),
            "params.frames",
        ),
        (
            json!({"method": "tv", "psf": psf, "frames": {"every": 1}}),
            s.dataset(vec![("a.png", png(&truth))]).await,
            "video datasets",
        ),
    ] {
        let id = s
            .job(json!({"kind": "deblur", "dataset": dataset, "params": params}))
            .await;
        let done = s.wait_terminal(&id).await;
        assert_eq!(done["status"], "failed", "{done}");
        assert!(done["error"].to_string().contains(needle), "{done}");
    }
    let (st, body) = s
        .post_json(
            "/v1/jobs",
            &json!({"kind": "deblur", "dataset": ds, "params": {"method": "tv", "psf": psf, "frames": {"every": 0}}}),
        )
        .await;
    assert_eq!(st, 422, "{body}");
    assert_eq!(body["field"], "params.frames.every", "{body}");
    s.stop().await;
}
