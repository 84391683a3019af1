//! Corner accuracy of the chessboard detector under strong barrel distortion with small
//! squares: renders a 4×6-corner board (30 mm squares) through a 640×480 pinhole with
//! k1 ≈ −0.37 along random poses (blur, noise, optional JPEG), detects, and reports the error
//! against the true corners by image radius. Writes the renders and the truth to a folder so
//! the same images can be handed to OpenCV's `cornerSubPix` for comparison.
//!
//! `cargo run --release -p caliper-core --example corner_bias -- OUT_DIR [SEED] [JPEG_QUALITY]`
//! (`CB_Z0`: nearest board distance, default 0.22 m; `CB_LIGHT`: illumination ramp across the
//! image, as `RenderOptions::light_gradient`; `CB_LIGHT_CORRECTION` set: detect with
//! `DetectOptions::light_correction`)

use caliper_core::board::{DetectOptions, Detection, detect_chessboard};
use caliper_core::camera::{Camera, PinholeRadTan};
use caliper_core::lie::{Se3, So3};
use caliper_core::photometric::synth::Rng;
use caliper_core::synth::{RenderOptions, render_chessboard};
use nalgebra::Vector3;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let out = std::path::PathBuf::from(
        args.get(1)
            .cloned()
            .unwrap_or_else(|| "/tmp/corner_bias".into()),
    );
    let seed: u64 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(1);
    let quality: u8 = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(0);
    std::fs::create_dir_all(&out).expect("out dir");
    let cam: Camera = PinholeRadTan::new(410.0, 410.0, 322.0, 238.0, -0.37, 0.14, 0.0, 0.0, -0.025)
        .expect("camera")
        .into();
    let (cols, rows, sq) = (4usize, 6usize, 0.03);
    let centre = Vector3::new(
        (cols - 1) as f64 * sq / 2.0,
        (rows - 1) as f64 * sq / 2.0,
        0.0,
    );
    let mut rng = Rng::new(seed);
    let mut truth_json = Vec::new();
    let mut bins = [(0.0f64, 0usize, nalgebra::Vector2::<f64>::zeros()); 4];
    let (mut all, mut n, mut found) = (0.0, 0usize, 0usize);
    let mut k = 0;
    while k < 24 {
        let r = So3::exp(&Vector3::new(
            0.9 * (rng.uniform() - 0.5),
            0.9 * (rng.uniform() - 0.5),
            1.0 * (rng.uniform() - 0.5),
        ));
        let z = std::env::var("CB_Z0")
            .ok()
            .and_then(|s| s.parse().ok())
            .unwrap_or(0.22)
            + 0.2 * rng.uniform();
        let p = Vector3::new(
            z * 1.0 * (rng.uniform() - 0.5),
            z * 0.75 * (rng.uniform() - 0.5),
            z,
        );
        let pose = Se3::new(r, p - r.act(&centre));
        let opts = RenderOptions {
            blur_sigma: 0.6,
            noise_sigma: 1.5,
            seed: seed * 100 + k,
            light_gradient: std::env::var("CB_LIGHT")
                .ok()
                .and_then(|s| s.parse().ok())
                .unwrap_or(0.0),
            ..RenderOptions::default()
        };
        let Ok(view) = render_chessboard(&cam, &pose, (cols, rows, sq), (640, 480), &opts) else {
            continue;
        };
        if !view.all_visible() {
            continue;
        }
        let mut img = image::GrayImage::from_raw(640, 480, view.image.data.clone()).expect("image");
        if quality > 0 {
            let mut buf = Vec::new();
            image::codecs::jpeg::JpegEncoder::new_with_quality(&mut buf, quality)
                .encode_image(&img)
                .expect("jpeg");
            img = image::load_from_memory(&buf).expect("decode").to_luma8();
        }
        let name = format!("v{k:02}.png");
        img.save(out.join(&name)).expect("save");
        let gray = caliper_core::io::Gray {
            width: 640,
            height: 480,
            data: img.into_raw(),
        };
        let truth: Vec<[f64; 2]> = view.corners.iter().map(|c| c.expect("visible")).collect();
        truth_json.push(format!(
            "\"{name}\": {}",
            serde_json::to_string(&truth).expect("json")
        ));
        k += 1;
        if let Detection::Found { corners, .. } = detect_chessboard(
            &gray,
            cols,
            rows,
            &DetectOptions {
                light_correction: std::env::var_os("CB_LIGHT_CORRECTION").is_some(),
                ..DetectOptions::default()
            },
        ) {
            found += 1;
            // Same corner order or reversed (symmetric board).
            let d_same: f64 = corners
                .iter()
                .zip(&truth)
                .map(|(a, b)| (a[0] - b[0]).hypot(a[1] - b[1]))
                .sum();
            let d_rev: f64 = corners
                .iter()
                .rev()
                .zip(&truth)
                .map(|(a, b)| (a[0] - b[0]).hypot(a[1] - b[1]))
                .sum();
            let det: Vec<[f64; 2]> = if d_rev < d_same {
                corners.iter().rev().copied().collect()
            } else {
                corners
            };
            for (a, b) in det.iter().zip(&truth) {
                let e = nalgebra::Vector2::new(a[0] - b[0], a[1] - b[1]);
                let rad = (b[0] - 322.0).hypot(b[1] - 238.0) / 400.0;
                let bin = ((rad * 4.0) as usize).min(3);
                bins[bin].0 += e.norm_squared();
                bins[bin].1 += 1;
                // Radial component of the error (positive = outward).
                let u = nalgebra::Vector2::new(b[0] - 322.0, b[1] - 238.0).normalize();
                bins[bin].2 += nalgebra::Vector2::new(e.dot(&u), e.norm());
                all += e.norm_squared();
                n += 1;
            }
        }
    }
    std::fs::write(
        out.join("truth.json"),
        format!("{{{}}}", truth_json.join(",")),
    )
    .expect("truth");
    println!(
        "found {found}/24, corner RMS vs truth {:.4} px over {n}",
        (all / n.max(1) as f64).sqrt()
    );
    for (i, (s, c, v)) in bins.iter().enumerate() {
        if *c > 0 {
            println!(
                "  radius {:.2}–{:.2} of 400 px: RMS {:.4} px, mean radial error {:+.4} px, n {c}",
                i as f64 / 4.0,
                (i + 1) as f64 / 4.0,
                (s / *c as f64).sqrt(),
                v.x / *c as f64
            );
        }
    }
}
