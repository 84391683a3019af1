//! Tests of the combined score and the blur map on synthetic scenes (no shared data needed).

use super::*;
use crate::io::Gray;
use crate::progress::NoProgress;

/// splitmix64, for deterministic scenes and noise.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    fn uniform(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
    fn normal(&mut self) -> f64 {
        let (a, b) = (self.uniform().max(1e-300), self.uniform());
        (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
    }
}

/// A piecewise-constant scene of random rectangles and disks (sizes relative to the frame, so
/// the same scene at two resolutions) over a gentle gradient, in 0..255 as f64.
fn scene(w: u32, h: u32, seed: u64) -> Vec<f64> {
    let mut rng = Rng(seed);
    let (wf, hf) = (f64::from(w), f64::from(h));
    let mut img: Vec<f64> = (0..w * h)
        .map(|i| 90.0 + 40.0 * f64::from(i % w) / wf)
        .collect();
    for s in 0..60 {
        let (cx, cy) = (rng.uniform() * wf, rng.uniform() * hf);
        let r = (0.02 + 0.1 * rng.uniform()) * wf;
        let v = 20.0 + 215.0 * rng.uniform();
        for y in 0..h {
            for x in 0..w {
                let (dx, dy) = (f64::from(x) - cx, f64::from(y) - cy);
                let inside = if s % 2 == 0 {
                    dx * dx + dy * dy < r * r
                } else {
                    dx.abs() < r && dy.abs() < 0.6 * r
                };
                if inside {
                    img[(y * w + x) as usize] = v;
                }
            }
        }
    }
    img
}

/// Quantise with additive Gaussian noise of `sigma` grey levels.
fn to_gray(w: u32, h: u32, img: &[f64], sigma: f64, seed: u64) -> Gray {
    let mut rng = Rng(seed);
    let data = img
        .iter()
        .map(|&v| (v + sigma * rng.normal()).round().clamp(0.0, 255.0) as u8)
        .collect();
    Gray::new(w, h, data).expect("size")
}

/// Horizontal box blur of `len` pixels (motion blur), clamped borders.
fn motion(w: u32, h: u32, img: &[f64], len: usize) -> Vec<f64> {
    let (w, h) = (w as usize, h as usize);
    let mut out = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            let s: f64 = (0..len)
                .map(|k| img[y * w + (x + k).saturating_sub(len / 2).min(w - 1)])
                .sum();
            out[y * w + x] = s / len as f64;
        }
    }
    out
}

/// Disk (defocus) blur of radius `r` pixels, clamped borders.
fn defocus(w: u32, h: u32, img: &[f64], r: i64) -> Vec<f64> {
    let (wi, hi) = (i64::from(w), i64::from(h));
    let taps: Vec<(i64, i64)> = (-r..=r)
        .flat_map(|dy| (-r..=r).map(move |dx| (dx, dy)))
        .filter(|(dx, dy)| dx * dx + dy * dy <= r * r)
        .collect();
    let mut out = vec![0.0; img.len()];
    for y in 0..hi {
        for x in 0..wi {
            let s: f64 = taps
                .iter()
                .map(|&(dx, dy)| {
                    img[((y + dy).clamp(0, hi - 1) * wi + (x + dx).clamp(0, wi - 1)) as usize]
                })
                .sum();
            out[(y * wi + x) as usize] = s / taps.len() as f64;
        }
    }
    out
}

#[test]
fn combined_verdict_separates_sharp_and_blurred_across_resolution_and_noise() {
    let params = BlurParams {
        rule: BlurRule::Combined,
        ..BlurParams::default()
    };
    for (w, h) in [(320u32, 240u32), (1280, 960)] {
        // Blur in proportion to the frame: 3 % of the width for motion, 1 % radius for defocus.
        let scale = w as usize / 320;
        let base = scene(w, h, 7);
        let blurred = [
            motion(w, h, &base, 9 * scale),
            defocus(w, h, &base, 3 * scale as i64),
        ];
        for sigma in [1.0, 6.0] {
            let s = combined_score(&to_gray(w, h, &base, sigma, 1));
            assert!(
                !params.is_blurred(0.0, 0.0, s.score),
                "{w}×{h} σ={sigma}: sharp scored {s:?}"
            );
            for (k, b) in blurred.iter().enumerate() {
                let c = combined_score(&to_gray(w, h, b, sigma, 2));
                assert!(
                    params.is_blurred(0.0, 0.0, c.score),
                    "{w}×{h} σ={sigma} blur {k}: scored {c:?}"
                );
                assert!(c.score > s.score + 0.1, "{c:?} vs {s:?}");
            }
            // The noise estimate follows the added noise (quantisation adds 1/12).
            let factor = f64::from(w.div_ceil(1024));
            let expect = (sigma * sigma + 1.0f64 / 12.0).sqrt() / factor;
            assert!(
                (s.noise_sigma - expect).abs() < 0.35 * expect + 0.3,
                "{w}×{h} σ={sigma}: estimated {}",
                s.noise_sigma
            );
        }
    }
}

#[test]
fn motion_blur_is_anisotropic_along_its_direction() {
    let (w, h) = (320, 240);
    let base = scene(w, h, 11);
    let m = combined_score(&to_gray(w, h, &motion(w, h, &base, 11), 1.0, 3));
    let d = combined_score(&to_gray(w, h, &defocus(w, h, &base, 4), 1.0, 3));
    assert_eq!(m.blur_direction_deg, 0.0, "{m:?}");
    assert!(m.anisotropy > d.anisotropy + 0.1, "{m:?} vs {d:?}");
}

#[test]
fn combined_score_ignores_brightness_scaling() {
    let (w, h) = (320, 240);
    let base = scene(w, h, 5);
    for img in [base.clone(), motion(w, h, &base, 7)] {
        let dim: Vec<f64> = img.iter().map(|v| 0.5 * v).collect();
        let a = combined_score(&to_gray(w, h, &img, 2.0, 9)).score;
        let b = combined_score(&to_gray(w, h, &dim, 1.0, 9)).score;
        assert!((a - b).abs() < 0.04, "{a} vs {b}");
    }
}

#[test]
fn tiny_and_flat_images_never_panic() {
    for (w, h) in [(1, 1), (2, 7), (5, 5), (7, 3), (40, 1), (3000, 2)] {
        let g = Gray::new(w, h, (0..w * h).map(|i| (i * 37 % 251) as u8).collect()).expect("g");
        let s = combined_score(&g);
        assert!((0.0..=1.0).contains(&s.score), "{w}×{h}: {s:?}");
        let m = blur_map(&g, 8).expect("map");
        assert_eq!(m.values.len(), (m.cols * m.rows) as usize);
        // Images reduced to nothing (3000×2) have no heat map; none may panic.
        let png = render_map_png(&g, &m);
        assert_eq!(png.is_ok(), (w, h) != (3000, 2), "{w}×{h}");
    }
    let flat = Gray::new(64, 48, vec![128; 64 * 48]).expect("flat");
    let s = combined_score(&flat);
    assert_eq!((s.score, s.textured_share), (1.0, 0.0));
    let m = blur_map(&flat, 16).expect("map");
    assert!(m.flat.iter().all(|&f| f));
    assert_eq!(m.summary.extent, BlurExtent::Undetermined);
    let empty = Gray::new(0, 0, vec![]).expect("empty");
    assert_eq!(combined_score(&empty).score, 1.0);
    assert!(blur_map(&empty, 16).is_err());
}

#[test]
fn map_marks_the_blurred_half_and_the_flat_blocks() {
    let (w, h) = (384u32, 256u32);
    let base = scene(w, h, 3);
    let blurred = defocus(w, h, &base, 4);
    // Left half sharp, right half blurred, bottom row of blocks flat.
    let img: Vec<f64> = (0..(w * h) as usize)
        .map(|i| {
            let (x, y) = (i as u32 % w, i as u32 / w);
            if y >= h - 64 {
                100.0
            } else if x < w / 2 {
                base[i]
            } else {
                blurred[i]
            }
        })
        .collect();
    let g = to_gray(w, h, &img, 1.0, 4);
    let m = blur_map(&g, 32).expect("map");
    assert_eq!((m.cols, m.rows, m.block_px), (12, 8, 32));
    assert_eq!(m.values.len(), 96);
    assert!(m.values.iter().all(|v| (0.0..=1.0).contains(v)));
    let mean = |x0: u32, x1: u32| {
        let v: Vec<f64> = (0..6)
            .flat_map(|r| (x0..x1).map(move |c| (r * 12 + c) as usize))
            .filter(|&b| !m.flat[b])
            .map(|b| m.values[b])
            .collect();
        v.iter().sum::<f64>() / v.len().max(1) as f64
    };
    let (left, right) = (mean(0, 5), mean(7, 12));
    assert!(left > right + 0.15, "left {left}, right {right}");
    for c in 0..12 {
        assert!(
            m.flat[(7 * 12 + c) as usize],
            "block (7, {c}) should be flat"
        );
    }
    assert_eq!(m.summary.extent, BlurExtent::Local, "{:?}", m.summary);
    let png = render_map_png(&g, &m).expect("png");
    let back = image::load_from_memory(&png).expect("decodes");
    assert_eq!((back.width(), back.height()), (w, h));
    // A map from another image is refused.
    let other = blur_map(&to_gray(200, 100, &vec![0.0; 20_000], 0.0, 1), 32).expect("map");
    assert!(render_map_png(&g, &other).is_err());
}

#[test]
fn map_and_score_params_are_validated() {
    let g = to_gray(64, 64, &scene(64, 64, 1), 0.0, 1);
    for b in [0, 7, 1025] {
        assert!(blur_map(&g, b).is_err(), "{b}");
    }
    for t in [f64::NAN, -0.1, 1.1] {
        assert!(blur_map_at(&g, 16, t).is_err(), "{t}");
        let p = BlurParams {
            blur_threshold: t,
            ..BlurParams::default()
        };
        assert!(
            matches!(p.validate(), Err(CoreError::InvalidParam { field, .. }) if field == "blur_threshold")
        );
    }
    for b in [1, 7, 2000] {
        let p = BlurParams {
            map_block: b,
            ..BlurParams::default()
        };
        assert!(
            matches!(p.validate(), Err(CoreError::InvalidParam { field, .. }) if field == "map_block")
        );
    }
    let p: BlurParams = serde_json::from_str(r#"{"rule": "either"}"#).expect("old rule");
    assert_eq!(p.rule, BlurRule::Either);
    // The combined score decides by default (its threshold holds on a held-out split).
    assert_eq!(BlurParams::default().rule, BlurRule::Combined);
}

#[test]
fn score_images_reports_combined_score_and_map() {
    use image::ImageEncoder;
    let (w, h) = (160u32, 120u32);
    let base = scene(w, h, 2);
    let imgs = [
        to_gray(w, h, &base, 1.0, 1),
        to_gray(w, h, &defocus(w, h, &base, 4), 1.0, 2),
    ];
    let files: Vec<Vec<u8>> = imgs
        .iter()
        .map(|g| {
            let mut out = Vec::new();
            image::codecs::png::PngEncoder::new(&mut out)
                .write_image(&g.data, g.width, g.height, image::ExtendedColorType::L8)
                .expect("png");
            out
        })
        .collect();
    let names = vec!["sharp.png".to_string(), "soft.png".to_string()];
    let r = score_images(
        &names,
        |i| Ok(files[i].clone()),
        &BlurParams {
            rule: BlurRule::Combined,
            ..BlurParams::default()
        },
        &ImageLimits::default(),
        &NoProgress,
    )
    .expect("scores");
    let blurred: Vec<bool> = r.images.iter().map(|s| s.blurred).collect();
    assert_eq!(blurred, vec![false, true]);
    for s in &r.images {
        assert_eq!(s.blur_score, s.combined.score);
        let m = s.map.as_ref().expect("map by default");
        assert_eq!((m.cols, m.rows), (5, 4));
    }
    assert_eq!(r.summary.blurred_count, 1);
    let json = serde_json::to_value(&r).expect("serialises");
    assert!(json["images"][0]["map"]["values"].is_array());
}
