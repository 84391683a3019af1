//! Tests of the TV, blind, gyro and colour paths against in-process ground truth.
//!
//! One file over 600 lines: every test here draws on the same generated scenes and blur
//! helpers at its top, and each test is short; split by solver, each part would import the
//! same helpers for a handful of tests.

use image::{DynamicImage, ImageBuffer, Luma, LumaA, Rgb, Rgba};

use super::tests::{add_noise, blur_reflect, scene};
use super::*;
use crate::error::CoreError;
use crate::progress::NoProgress;

#[test]
fn tv_beats_wiener_and_rl() {
    let sharp = scene(128, 112);
    let psf = Psf::motion(11.0, 30.0).expect("motion");
    let blurred = add_noise(&blur_reflect(&sharp, &psf), 0.01, 7);
    let before = psnr(&blurred, &sharp, 1.0).expect("psnr");
    let tv = tv_deconv(&blurred, &psf, &TvParams::default(), &NoProgress).expect("tv");
    let w = wiener(&blurred, &psf, None).expect("wiener");
    let r = richardson_lucy(&blurred, &psf, 30, &NoProgress).expect("rl");
    let (pt, pw, pr) = (
        psnr(&tv, &sharp, 1.0).expect("psnr"),
        psnr(&w, &sharp, 1.0).expect("psnr"),
        psnr(&r, &sharp, 1.0).expect("psnr"),
    );
    eprintln!("blurred {before:.2} dB, tv {pt:.2}, wiener {pw:.2}, rl30 {pr:.2}");
    assert!(pt > before + 5.0, "{before:.2} -> {pt:.2}");
    assert!(
        pt > pw + 0.5 && pt > pr + 0.5,
        "tv {pt:.2} wiener {pw:.2} rl {pr:.2}"
    );
    assert!(tv.data.iter().all(|v| (0.0..=1.0).contains(v)));
}

#[test]
fn tv_params_validate() {
    let bad = TvParams {
        lambda: Some(-1.0),
        ..TvParams::default()
    };
    assert!(
        matches!(bad.validate(), Err(CoreError::InvalidParam { field, .. }) if field == "lambda")
    );
    let bad = TvParams {
        iterations: 0,
        ..TvParams::default()
    };
    assert!(bad.validate().is_err());
    let p: TvParams = serde_json::from_str(r#"{"lambda": 0.001}"#).expect("json");
    assert_eq!(p.iterations, TvParams::default().iterations);
}

/// Procedural "natural" image: overlapping random discs and rotated rectangles of random grey
/// levels on a shaded background, so that edges run in every direction at many scales.
fn shapes(w: usize, h: usize, seed: u64) -> Plane {
    let mut s = seed | 1;
    let mut rnd = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        (s >> 11) as f32 / (1u64 << 53) as f32
    };
    let mut data: Vec<f32> = (0..w * h)
        .map(|i| 0.3 + 0.3 * (i % w) as f32 / w as f32 + 0.1 * (i / w) as f32 / h as f32)
        .collect();
    for _ in 0..60 {
        let (cx, cy) = (rnd() * w as f32, rnd() * h as f32);
        let size = 4.0 + rnd() * 0.15 * w as f32;
        let v = rnd();
        let ang = rnd() * std::f32::consts::PI;
        let (sn, cs) = ang.sin_cos();
        let disc = rnd() < 0.5;
        let aspect = 0.3 + rnd();
        for y in 0..h {
            for x in 0..w {
                let (dx, dy) = (x as f32 - cx, y as f32 - cy);
                let inside = if disc {
                    dx * dx + dy * dy < size * size
                } else {
                    let (u, t) = (cs * dx + sn * dy, -sn * dx + cs * dy);
                    u.abs() < size && t.abs() < size * aspect
                };
                if inside {
                    data[y * w + x] = v;
                }
            }
        }
    }
    // Fine texture, as in photos: TV with the true kernel is then not trivially exact.
    let waves: Vec<(f32, f32, f32)> = (0..6)
        .map(|_| {
            let a = rnd() * std::f32::consts::PI;
            let f = std::f32::consts::TAU / (4.0 + 12.0 * rnd());
            (f * a.cos(), f * a.sin(), rnd() * 6.0)
        })
        .collect();
    for (i, v) in data.iter_mut().enumerate() {
        let (x, y) = ((i % w) as f32, (i / w) as f32);
        let t: f32 = waves
            .iter()
            .map(|(fx, fy, p)| (fx * x + fy * y + p).sin())
            .sum();
        *v = (*v + 0.02 * t).clamp(0.0, 1.0);
    }
    Plane::new(w, h, data).expect("plane")
}

#[test]
fn blind_recovers_motion_kernel() {
    let sharp = shapes(192, 192, 9);
    let truth = Psf::motion(13.0, 40.0).expect("motion");
    let blurred = add_noise(&blur_reflect(&sharp, &truth), 0.01, 11);
    let params = BlindParams {
        kernel_size: Some(21),
        ..BlindParams::default()
    };
    let t = std::time::Instant::now();
    let out = blind_deconv(&blurred, &params, &NoProgress).expect("blind");
    eprintln!("blind took {:?}", t.elapsed());
    assert_eq!((out.psf.width, out.psf.height), (21, 21));
    assert!((out.psf.data.iter().sum::<f64>() - 1.0).abs() < 1e-9);
    let with_truth = tv_deconv(&blurred, &truth, &params.final_tv, &NoProgress).expect("tv");
    let ratio = error_ratio_aligned(&sharp, &out.image, &with_truth, 16, 6).expect("ratio");
    eprintln!("blind error ratio {ratio:.2}");
    assert!(ratio <= 3.0, "error ratio {ratio:.2}");
}

/// On a photo larger than `kernel_region` the kernel comes from a region of that side, is
/// reported with it, and restores the whole photo within the benchmark's error ratio; the
/// region is at least 16 kernel windows wide.
#[test]
fn blind_estimates_on_a_region_of_a_larger_photo() {
    let sharp = shapes(320, 240, 5);
    let truth = Psf::motion(7.0, 120.0).expect("motion");
    let blurred = add_noise(&blur_reflect(&sharp, &truth), 0.01, 13);
    let params = BlindParams {
        kernel_size: Some(11),
        kernel_region: 128,
        ..BlindParams::default()
    };
    let est = estimate_kernel_restored(&blurred, &params, &NoProgress).expect("blind");
    let r = est.region.expect("a region");
    // 16 × 11 px, more than the 128 asked for.
    assert_eq!((r.width, r.height), (176, 176));
    assert!(r.x + r.width <= 320 && r.y + r.height <= 240, "{r:?}");
    // The restoration of a region is not the photo's: the caller restores the whole.
    assert!(est.restored.is_none());
    let image = tv_deconv(&blurred, &est.psf, &params.final_tv, &NoProgress).expect("tv");
    let with_truth = tv_deconv(&blurred, &truth, &params.final_tv, &NoProgress).expect("tv");
    let ratio = error_ratio_aligned(&sharp, &image, &with_truth, 16, 6).expect("ratio");
    assert!(ratio <= 3.0, "error ratio {ratio:.2}");
    // The whole photo when the region is at least its longer side.
    let whole = BlindParams {
        kernel_region: 320,
        kernel_threshold: Some(0.1),
        ..params
    };
    let est = estimate_kernel_restored(&blurred, &whole, &NoProgress).expect("blind");
    assert!(est.region.is_none());
}

/// `kernel_threshold` is the cleaning every level applies: no entry of the estimate is below
/// that fraction of its peak, and a lower threshold keeps more entries.
#[test]
fn blind_kernel_threshold_sets_the_cleaning() {
    let sharp = shapes(160, 160, 9);
    let truth = Psf::motion(11.0, 30.0).expect("motion");
    let blurred = add_noise(&blur_reflect(&sharp, &truth), 0.01, 17);
    let support = |t: f64| {
        let params = BlindParams {
            kernel_size: Some(17),
            kernel_threshold: Some(t),
            ..BlindParams::default()
        };
        let k = estimate_kernel(&blurred, &params, &NoProgress).expect("kernel");
        let peak = k.data.iter().copied().fold(0.0, f64::max);
        // Each level's cleaning drops below `t·max`, then normalises: the ratio survives.
        assert!(
            k.data
                .iter()
                .all(|&v| v == 0.0 || v >= t * peak * (1.0 - 1e-9)),
            "an entry below {t} of the peak survived"
        );
        k.data.iter().filter(|&&v| v > 0.0).count()
    };
    let (low, high) = (support(0.02), support(0.4));
    assert!(low > high, "support at 2 %: {low}, at 40 %: {high}");
}

/// The fixed-point diagnostics: from the truth, on a scene with edges in every direction, both
/// the finest level and the whole pyramid stay at the truth; a start that is not square is
/// refused.
#[test]
fn blind_keeps_the_true_kernel_as_a_start() {
    let sharp = shapes(160, 160, 9);
    let truth = Psf::motion(9.0, 40.0).expect("motion");
    let blurred = add_noise(&blur_reflect(&sharp, &truth), 0.01, 13);
    let params = BlindParams::default();
    let with_truth = tv_deconv(&blurred, &truth, &params.final_tv, &NoProgress).expect("tv");
    let start = Psf::from_weights(15, 15, truth.centred_weights(15)).expect("psf");
    for mode in [KernelStart::Finest, KernelStart::Pyramid] {
        let k = estimate_kernel_from(&blurred, &params, &start, mode).expect("from truth");
        assert_eq!((k.width, k.height), (15, 15));
        let img = tv_deconv(&blurred, &k, &params.final_tv, &NoProgress).expect("tv");
        let ratio = error_ratio_aligned(&sharp, &img, &with_truth, 16, 6).expect("ratio");
        eprintln!("{mode:?}: error ratio {ratio:.2}");
        assert!(ratio <= 2.0, "{mode:?}: error ratio {ratio:.2}");
    }
    let oblong = Psf::from_weights(5, 3, vec![1.0; 15]).expect("psf");
    assert!(estimate_kernel_from(&blurred, &params, &oblong, KernelStart::Finest).is_err());
}

#[test]
fn blind_rl_runs_and_normalises() {
    let sharp = scene(96, 96);
    let truth = Psf::motion(7.0, 0.0).expect("motion");
    let blurred = blur_reflect(&sharp, &truth);
    let (img, k) = blind_richardson_lucy(&blurred, 11, 10, &NoProgress).expect("blind rl");
    assert_eq!((k.width, k.height, img.width), (11, 11, 96));
    assert!((k.data.iter().sum::<f64>() - 1.0).abs() < 1e-9);
    assert!(blind_richardson_lucy(&blurred, 10, 10, &NoProgress).is_err());
}

fn gyro_params(rate: [f64; 3], exposure: f64) -> GyroPsfParams {
    GyroPsfParams {
        samples: (0..=100)
            .map(|i| GyroSample {
                t: i as f64 * 0.001,
                w: rate,
            })
            .collect(),
        exposure_start_s: 0.02,
        exposure_s: exposure,
        fx: 800.0,
        fy: 780.0,
        cx: 320.0,
        cy: 240.0,
        gyro_to_camera_wxyz: None,
    }
}

/// Extent of the kernel's support along x and y (px between the outermost non-zero columns/rows,
/// weighted ends excluded by the anti-aliasing: measured between centroids of the end columns).
fn support(p: &Psf) -> (Vec<usize>, Vec<usize>) {
    let cols = (0..p.width)
        .filter(|&x| (0..p.height).any(|y| p.at(x, y) > 1e-9))
        .collect();
    let rows = (0..p.height)
        .filter(|&y| (0..p.width).any(|x| p.at(x, y) > 1e-9))
        .collect();
    (cols, rows)
}

#[test]
fn gyro_constant_yaw_draws_horizontal_line() {
    // 0.5 rad/s about y for 40 ms at fx = 800: 800 · 0.02 = 16 px of travel.
    let p = gyro_params([0.0, 0.5, 0.0], 0.04);
    let k = gyro_psf(&p).expect("psf");
    let (cols, rows) = support(&k);
    assert_eq!(rows, vec![k.height / 2], "vertical spread");
    let expected = p.fx * (0.5 * 0.02f64).tan() * 2.0;
    // Bilinear splatting touches one extra column at each end.
    let span = (cols[cols.len() - 1] - cols[0]) as f64;
    assert!((span - expected).abs() <= 2.0, "span {span} vs {expected}");
    // Mass spread evenly along the line (constant rate): the centre column holds ~1/16.
    let c = k.at(k.width / 2, k.height / 2);
    assert!((c - 1.0 / expected).abs() < 0.3 / expected, "centre {c}");
    // Centroid at the centre (mid-exposure reference).
    let mx: f64 = k
        .data
        .iter()
        .enumerate()
        .map(|(i, v)| v * (i % k.width) as f64)
        .sum();
    assert!((mx - (k.width / 2) as f64).abs() < 0.05, "centroid {mx}");
    // Pitch (about x) moves vertically with fy.
    let v = gyro_psf(&gyro_params([0.5, 0.0, 0.0], 0.04)).expect("psf");
    let (cols, rows) = support(&v);
    assert_eq!(cols, vec![v.width / 2]);
    let span = (rows[rows.len() - 1] - rows[0]) as f64;
    assert!(
        (span - 780.0 * 0.01f64.tan() * 2.0).abs() <= 2.0,
        "pitch span {span}"
    );
    // Roll about the optical axis does not blur the principal point, but blurs the corners.
    let r = gyro_params([0.0, 0.0, 1.0], 0.04);
    let still = gyro_psf(&r).expect("psf");
    assert!(
        still.at(still.width / 2, still.height / 2) > 0.999,
        "{still:?}"
    );
    let grid = gyro_psf_grid(&r, 640, 480, 3, 3).expect("grid");
    assert_eq!(grid.len(), 9);
    assert!(grid[0].2.width > 9, "corner kernel {}", grid[0].2.width);
    // Traces that do not cover the exposure are refused.
    let mut short = gyro_params([0.0, 0.5, 0.0], 0.04);
    short.exposure_start_s = 0.09;
    assert!(gyro_psf(&short).is_err());
}

fn gradient_image(w: u32, h: u32) -> Vec<f32> {
    (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            ((x * 7 + y * 3) % 97) as f32 / 96.0
        })
        .collect()
}

#[test]
fn colour_and_16_bit_round_trip_keeps_format() {
    let (w, h) = (24u32, 20u32);
    let g = gradient_image(w, h);
    let to16 = |v: f32| (v * 65535.0).round() as u16;
    let to8 = |v: f32| (v * 255.0).round() as u8;
    let rgb16: Vec<u16> = g
        .iter()
        .flat_map(|&v| [to16(v), to16(1.0 - v), to16(v * 0.5)])
        .collect();
    let rgba8: Vec<u8> = g
        .iter()
        .flat_map(|&v| [to8(v), to8(1.0 - v), 7, to8(v * 0.3)])
        .collect();
    let la16: Vec<u16> = g.iter().flat_map(|&v| [to16(v), 1234]).collect();
    let l8: Vec<u8> = g.iter().map(|&v| to8(v)).collect();
    let images = [
        DynamicImage::ImageRgb16(ImageBuffer::<Rgb<u16>, _>::from_raw(w, h, rgb16).expect("buf")),
        DynamicImage::ImageRgba8(ImageBuffer::<Rgba<u8>, _>::from_raw(w, h, rgba8).expect("buf")),
        DynamicImage::ImageLumaA16(
            ImageBuffer::<LumaA<u16>, _>::from_raw(w, h, la16).expect("buf"),
        ),
        DynamicImage::ImageLuma8(ImageBuffer::<Luma<u8>, _>::from_raw(w, h, l8).expect("buf")),
    ];
    for img in &images {
        let s = split_image(img).expect("split");
        let back = merge_image(&s, &s.color).expect("merge");
        assert_eq!(&back, img, "{:?}", img.color());
        // Through the entry point with an identity kernel: same format, same pixels up to the
        // solver's clipping (Wiener with the identity is exact).
        let params = DeblurParams {
            method: DeblurMethod::Wiener,
            psf: Some(Psf::identity()),
            nsr: Some(0.0),
            ..DeblurParams::default()
        };
        let out = deblur_image(img, &params, &NoProgress).expect("deblur");
        assert_eq!(out.image.color(), img.color());
        assert_eq!((out.image.width(), out.image.height()), (w, h));
        let (a, b) = (out.image.to_rgba16(), img.to_rgba16());
        let worst = a
            .as_raw()
            .iter()
            .zip(b.as_raw())
            .map(|(x, y)| (i32::from(*x) - i32::from(*y)).abs())
            .max()
            .unwrap_or(0);
        assert!(worst <= 300, "{:?}: max error {worst}", img.color());
    }
}

#[test]
fn deblur_image_colour_tv_improves_every_channel() {
    let (w, h) = (96usize, 80usize);
    let base = scene(w, h);
    let psf = Psf::motion(7.0, 10.0).expect("motion");
    // Three different channels: the scene, its negative, a shifted copy.
    let chans: Vec<Plane> = [
        base.clone(),
        Plane::new(w, h, base.data.iter().map(|v| 1.0 - v).collect()).expect("plane"),
        Plane::new(w, h, base.data.iter().map(|v| 0.5 * v + 0.2).collect()).expect("plane"),
    ]
    .into_iter()
    .collect();
    let blurred: Vec<Plane> = chans.iter().map(|c| blur_reflect(c, &psf)).collect();
    let raw: Vec<u16> = (0..w * h)
        .flat_map(|i| {
            blurred
                .iter()
                .map(move |c| (c.data[i] * 65535.0).round() as u16)
        })
        .collect();
    let img = DynamicImage::ImageRgb16(
        ImageBuffer::<Rgb<u16>, _>::from_raw(w as u32, h as u32, raw).expect("buf"),
    );
    let params = DeblurParams {
        method: DeblurMethod::Tv,
        psf: Some(psf.clone()),
        ..DeblurParams::default()
    };
    let out = deblur_image(&img, &params, &NoProgress).expect("deblur");
    assert_eq!(out.psf, psf);
    let s = split_image(&out.image).expect("split");
    for (c, (est, (sharp, blur))) in s.color.iter().zip(chans.iter().zip(&blurred)).enumerate() {
        let (a, b) = (
            psnr(blur, sharp, 1.0).expect("psnr"),
            psnr(est, sharp, 1.0).expect("psnr"),
        );
        assert!(b > a + 3.0, "channel {c}: {a:.2} -> {b:.2}");
    }
}

#[test]
fn deblur_params_serde_and_validation() {
    let p: DeblurParams =
        serde_json::from_str(r#"{"method": "blind_rl", "kernel_size": 15}"#).expect("json");
    assert_eq!(p.method, DeblurMethod::BlindRl);
    p.validate().expect("valid");
    for name in [
        "wiener",
        "richardson_lucy",
        "tv",
        "blind",
        "blind_rl",
        "gyro",
    ] {
        let m: DeblurMethod = serde_json::from_str(&format!("\"{name}\"")).expect("method");
        assert_eq!(
            serde_json::to_string(&m).expect("ser"),
            format!("\"{name}\"")
        );
    }
    let field = |p: DeblurParams| match p.validate() {
        Err(CoreError::InvalidParam { field, .. }) => field,
        other => panic!("{other:?}"),
    };
    assert_eq!(field(DeblurParams::default()), "psf"); // tv without a kernel
    let with_psf = DeblurParams {
        psf: Some(Psf::identity()),
        ..DeblurParams::default()
    };
    with_psf.validate().expect("valid");
    assert_eq!(
        field(DeblurParams {
            method: DeblurMethod::Blind,
            ..with_psf.clone()
        }),
        "psf"
    );
    assert_eq!(
        field(DeblurParams {
            method: DeblurMethod::Gyro,
            ..DeblurParams::default()
        }),
        "gyro"
    );
    assert_eq!(
        field(DeblurParams {
            iterations: Some(0),
            ..with_psf.clone()
        }),
        "iterations"
    );
    assert_eq!(
        field(DeblurParams {
            tv_lambda: Some(f64::NAN),
            ..with_psf.clone()
        }),
        "tv_lambda"
    );
    assert_eq!(
        field(DeblurParams {
            method: DeblurMethod::Blind,
            kernel_size: Some(4),
            ..DeblurParams::default()
        }),
        "kernel_size"
    );
    for bad in [0.0, 0.005, 0.6, f64::NAN, f64::INFINITY] {
        assert_eq!(
            field(DeblurParams {
                method: DeblurMethod::Blind,
                kernel_threshold: Some(bad),
                ..DeblurParams::default()
            }),
            "kernel_threshold",
            "{bad}"
        );
    }
    // Only `blind` cleans an estimated kernel.
    assert_eq!(
        field(DeblurParams {
            kernel_threshold: Some(0.05),
            ..with_psf.clone()
        }),
        "kernel_threshold"
    );
    DeblurParams {
        method: DeblurMethod::Blind,
        kernel_threshold: Some(0.05),
        ..DeblurParams::default()
    }
    .validate()
    .expect("blind with a threshold");
    assert!(serde_json::from_str::<DeblurParams>(r#"{"methd": "tv"}"#).is_err());
}

#[test]
fn psf_png_decodes_to_scaled_kernel() {
    let k = Psf::motion(9.0, 0.0).expect("motion");
    let png = psf_png(&k).expect("png");
    let img = image::load_from_memory(&png).expect("decode").to_luma8();
    assert_eq!(
        (img.width() as usize, img.height() as usize),
        (k.width, k.height)
    );
    assert_eq!(img.as_raw().iter().copied().max(), Some(255));
    let back = Psf::from_gray(
        &crate::io::Gray::new(img.width(), img.height(), img.into_raw()).expect("gray"),
    )
    .expect("psf");
    assert!(
        back.data
            .iter()
            .zip(&k.data)
            .all(|(a, b)| (a - b).abs() < 0.01)
    );
}

#[test]
fn tv_cancels() {
    struct Cancel;
    impl crate::progress::Progress for Cancel {
        fn report(&self, _: &str, _: u64, _: u64) {}
        fn is_canceled(&self) -> bool {
            true
        }
    }
    let img = scene(40, 40);
    let psf = Psf::gaussian(1.0).expect("gaussian");
    assert!(matches!(
        tv_deconv(&img, &psf, &TvParams::default(), &Cancel),
        Err(CoreError::Canceled)
    ));
    assert!(matches!(
        blind_deconv(
            &img,
            &BlindParams {
                kernel_size: Some(5),
                ..BlindParams::default()
            },
            &Cancel
        ),
        Err(CoreError::Canceled)
    ));
}

/// Small lights far above white, blurred and then clipped by the sensor: the one-sided data
/// term must restore the scene around them better than treating the clipped streaks as the
/// true brightness (which rings and darkens their surroundings).
#[test]
fn tv_clipped_highlights_are_one_sided() {
    let (w, h) = (128, 112);
    let base = scene(w, h);
    let mut bright = base.data.clone();
    for &(cx, cy) in &[
        (30.0f32, 30.0f32),
        (90.0, 25.0),
        (60.0, 80.0),
        (100.0, 95.0),
    ] {
        for y in 0..h {
            for x in 0..w {
                if (x as f32 - cx).hypot(y as f32 - cy) <= 1.5 {
                    bright[y * w + x] = 12.0;
                }
            }
        }
    }
    let scene_light = Plane::new(w, h, bright).expect("plane");
    let psf = Psf::motion(11.0, 30.0).expect("motion");
    let blurred = add_noise(&blur_reflect(&scene_light, &psf), 0.005, 3);
    let clipped = blurred.data.iter().filter(|&&v| v >= 0.99).count();
    assert!(clipped > 50, "the streaks must clip ({clipped} px)");
    let sharp =
        Plane::new(w, h, scene_light.data.iter().map(|v| v.min(1.0)).collect()).expect("plane");
    let solve = |saturation| {
        let p = TvParams {
            saturation,
            ..TvParams::default()
        };
        let x = tv_deconv(&blurred, &psf, &p, &NoProgress).expect("tv");
        psnr(&x, &sharp, 1.0).expect("psnr")
    };
    let (linear, one_sided) = (solve(None), solve(Some(0.99)));
    eprintln!("clipped lights: linear {linear:.2} dB, one-sided {one_sided:.2} dB");
    assert!(one_sided > linear + 1.0, "{linear:.2} -> {one_sided:.2}");
    // Without clipped pixels the level changes nothing.
    let plain = add_noise(&blur_reflect(&base, &psf), 0.005, 3);
    assert!(plain.data.iter().all(|&v| v < 0.99));
    let a = tv_deconv(&plain, &psf, &TvParams::default(), &NoProgress).expect("tv");
    let p = TvParams {
        saturation: None,
        ..TvParams::default()
    };
    let b = tv_deconv(&plain, &psf, &p, &NoProgress).expect("tv");
    assert_eq!(a.data, b.data);
}

#[test]
fn saturation_level_is_validated_and_nullable() {
    for bad in [0.2, 1.5, f64::NAN] {
        let p = TvParams {
            saturation: Some(bad),
            ..TvParams::default()
        };
        assert!(
            matches!(p.validate(), Err(CoreError::InvalidParam { field, .. }) if field == "saturation"),
            "{bad}"
        );
    }
    let p: TvParams = serde_json::from_str("{}").expect("json");
    assert_eq!(p.saturation, Some(0.99));
    let p: TvParams = serde_json::from_str(r#"{"saturation": null}"#).expect("json");
    assert_eq!(p.saturation, None);
    // Through the service's parameters: the field is named as the request names it.
    let d: DeblurParams =
        serde_json::from_str(r#"{"method": "blind", "saturation": 2.0}"#).expect("json");
    assert!(
        matches!(d.validate(), Err(CoreError::InvalidParam { field, .. }) if field == "saturation")
    );
    let d: DeblurParams =
        serde_json::from_str(r#"{"method": "blind", "saturation": null}"#).expect("json");
    assert!(d.validate().is_ok());
    assert_eq!(d.saturation, None);
}
