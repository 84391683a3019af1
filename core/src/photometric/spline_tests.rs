//! Tests of the spline vignetting model on rendered flat fields: a standard camera (the
//! polynomial must still be chosen, unchanged), a fisheye family the spline was tuned on
//! (cos⁴ × logistic border) and a held-out family with other shapes (squared-quadratic falloff
//! × raised-cosine border that reaches 0, off-centre), all with shot + read noise and 8-bit
//! rounding.

use super::synth::Rng;
use super::{
    InverseResponse, PhotoImage, VignetteKind, VignetteModel, VignettingParams, correct, vignetting,
};
use crate::progress::NoProgress;

/// Flats of a linear camera: `round(255 · clip(level · V + n))`, σ² = 2e-4 I + 1.5e-3².
fn render(
    w: usize,
    h: usize,
    v: &dyn Fn(f64, f64) -> f64,
    levels: &[f64],
    seed: u64,
) -> Vec<PhotoImage> {
    let mut rng = Rng::new(seed);
    levels
        .iter()
        .map(|&l| {
            let mut data = Vec::with_capacity(w * h);
            for y in 0..h {
                for x in 0..w {
                    let i = l * v(x as f64, y as f64);
                    let n = (2e-4 * i + 1.5e-3f64.powi(2)).sqrt() * rng.normal();
                    data.push(((i + n).clamp(0.0, 1.0) * 255.0).round() as u16);
                }
            }
            PhotoImage {
                width: w,
                height: h,
                max_level: 255,
                data,
            }
        })
        .collect()
}

/// Tuning family: cos⁴ falloff times a logistic image-circle border, ~3 % at the corners.
fn fisheye_a(cx: f64, cy: f64, r: f64, sigma: f64) -> impl Fn(f64, f64) -> f64 {
    move |x, y| {
        let d = (x - cx).hypot(y - cy);
        (0.6 * d / 362.0).cos().powi(4) / (1.0 + ((d - r) / sigma).exp())
    }
}

/// Held-out family: (1 − a (d/R)²)² falloff, flat up to `r1`, then a raised-cosine border that
/// reaches exactly 0 at `r2` (black corners), off-centre.
fn fisheye_b(cx: f64, cy: f64, a: f64, r1: f64, r2: f64) -> impl Fn(f64, f64) -> f64 {
    move |x, y| {
        let d = (x - cx).hypot(y - cy);
        let base = (1.0 - a * (d / r2).powi(2)).powi(2);
        let border = if d <= r1 {
            1.0
        } else if d >= r2 {
            0.0
        } else {
            0.5 * (1.0 + (std::f64::consts::PI * (d - r1) / (r2 - r1)).cos())
        };
        base * border
    }
}

/// RMSE of the fitted dense map against the truth over the pixels where the truth is at least
/// `inside` (the image circle), and the share of those pixels the fit masked.
fn map_rmse(m: &VignetteModel, truth: &dyn Fn(f64, f64) -> f64, inside: f64) -> (f64, f64) {
    let map = m.map();
    let (mut ss, mut n, mut masked) = (0.0, 0usize, 0usize);
    for y in 0..m.height {
        for x in 0..m.width {
            let t = truth(x as f64, y as f64);
            if t >= inside {
                let f = f64::from(map[y * m.width + x]);
                ss += (f - t).powi(2);
                n += 1;
                masked += usize::from(f == 0.0);
            }
        }
    }
    (
        (ss / n.max(1) as f64).sqrt(),
        masked as f64 / n.max(1) as f64,
    )
}

const LEVELS: [f64; 3] = [0.45, 0.7, 0.95];

#[test]
fn standard_camera_keeps_the_polynomial_unchanged() {
    // 752×480, cos⁴ law with 0.66 at the corners (not exactly a polynomial).
    let (w, h) = (752usize, 480usize);
    let half_diag = (376.0f64).hypot(240.0);
    let k = (0.66f64.powf(-0.5) - 1.0).sqrt();
    let truth = move |x: f64, y: f64| {
        let r = (x - 376.0).hypot(y - 240.0) / half_diag;
        1.0 / (1.0 + k * k * r * r).powi(2)
    };
    let flats = render(w, h, &truth, &LEVELS, 1);
    let inv = InverseResponse::linear(256);
    let auto = vignetting(&flats, &inv, &VignettingParams::default(), &NoProgress).expect("auto");
    let poly_only = VignettingParams {
        vignette_model: VignetteKind::Polynomial,
        ..VignettingParams::default()
    };
    let poly = vignetting(&flats, &inv, &poly_only, &NoProgress).expect("polynomial");
    assert_eq!(
        auto.model,
        VignetteKind::Polynomial,
        "{}",
        auto.model_choice
    );
    // Bit for bit the polynomial fit: same coefficients, scales, RMS, no mask, no spline.
    assert_eq!(auto.vignette, poly.vignette);
    assert_eq!(auto.scales, poly.scales);
    assert_eq!(auto.relative_rms, poly.relative_rms);
    assert!(auto.vignette.spline.is_none() && auto.vignette.mask_radius.is_none());
    let json = serde_json::to_string(&auto.vignette).unwrap_or_default();
    assert!(!json.contains("spline") && !json.contains("mask"), "{json}");
    let (rmse, _) = map_rmse(&auto.vignette, &truth, 0.0);
    println!(
        "standard 752×480: {} ; map RMSE {rmse:.5}; spline alone RMS {:?}",
        auto.model_choice, auto.spline_rms
    );
    assert!(rmse < 0.005, "polynomial map RMSE {rmse}");
    // The spline, when asked for, also fits this lens (and finds no image circle).
    let sp = VignettingParams {
        vignette_model: VignetteKind::Spline,
        ..VignettingParams::default()
    };
    let s = vignetting(&flats, &inv, &sp, &NoProgress).expect("spline");
    assert!(s.mask_radius_px.is_none());
    let (rmse, _) = map_rmse(&s.vignette, &truth, 0.0);
    println!("standard 752×480, spline: map RMSE {rmse:.5}");
    assert!(rmse < 0.005, "spline map RMSE {rmse}");
}

fn fisheye_case(name: &str, truth: &dyn Fn(f64, f64) -> f64, seed: u64, fit_center: bool) -> f64 {
    let flats = render(512, 512, truth, &LEVELS, seed);
    let inv = InverseResponse::linear(256);
    // The polynomial alone fails the way the issue describes (or fits badly).
    let poly_only = VignettingParams {
        vignette_model: VignetteKind::Polynomial,
        fit_center,
        ..VignettingParams::default()
    };
    let poly = vignetting(&flats, &inv, &poly_only, &NoProgress);
    let params = VignettingParams {
        fit_center,
        ..VignettingParams::default()
    };
    let r = vignetting(&flats, &inv, &params, &NoProgress).expect("auto");
    assert_eq!(r.model, VignetteKind::Spline, "{}", r.model_choice);
    let (rmse, masked) = map_rmse(&r.vignette, truth, 0.05);
    let poly_rmse = poly
        .as_ref()
        .map(|p| map_rmse(&p.vignette, truth, 0.05).0)
        .ok();
    println!(
        "{name}: {}; knots {}; mask radius {:?} px; centre {:?}; dense-map RMSE inside the \
         circle (truth ≥ 0.05) {rmse:.5}, masked there {:.3} %; polynomial: {:?}",
        r.model_choice,
        r.vignette.spline.as_ref().map_or(0, |s| s.knots.len()),
        r.mask_radius_px,
        r.vignette.center,
        100.0 * masked,
        poly_rmse.map_or_else(
            || format!("{:?}", poly.err()),
            |v| format!("map RMSE {v:.4}")
        ),
    );
    assert!(masked < 0.01, "{name}: {masked} of the circle masked");
    rmse
}

#[test]
fn fisheye_tuning_family_meets_the_target() {
    for (i, (r, sigma)) in [(330.0, 12.0), (320.0, 8.0)].iter().enumerate() {
        let truth = fisheye_a(256.0, 256.0, *r, *sigma);
        let rmse = fisheye_case(&format!("tuning A{i}"), &truth, 10 + i as u64, false);
        assert!(rmse < 0.005, "A{i}: {rmse}");
    }
}

#[test]
fn fisheye_held_out_family_meets_the_target() {
    // Off-centre by (+5, −3) px: the centre is estimated.
    let truth = fisheye_b(261.0, 253.0, 0.45, 250.0, 340.0);
    let rmse = fisheye_case("held-out B0", &truth, 31, true);
    assert!(rmse < 0.005, "B0: {rmse}");
    let truth = fisheye_b(256.0, 256.0, 0.3, 200.0, 300.0);
    let rmse = fisheye_case("held-out B1", &truth, 32, false);
    assert!(rmse < 0.005, "B1: {rmse}");
}

#[test]
fn spline_model_writes_a_masked_dso_map_and_corrects() {
    let truth = fisheye_b(256.0, 256.0, 0.3, 200.0, 300.0);
    let flats = render(512, 512, &truth, &LEVELS, 5);
    let inv = InverseResponse::linear(256);
    let r = vignetting(&flats, &inv, &VignettingParams::default(), &NoProgress).expect("fit");
    let m = &r.vignette;
    let mask = r.mask_radius_px.expect("an image circle");
    // The truth falls below circle_fraction (0.05) at ~280 px, before its border reaches 0.
    let edge = (0..400)
        .map(|d| f64::from(d) / 2.0 + 200.0)
        .find(|&d| truth(256.0 + d, 256.0) < 0.05)
        .unwrap_or(0.0);
    assert!((mask - edge).abs() < 4.0, "mask radius {mask} vs {edge}");
    // vignette.png: 0 outside the circle, the maximum inside.
    let png = super::dso::write_vignette_png(m).expect("png");
    let img = image::load_from_memory(&png)
        .expect("decodes")
        .into_luma16();
    assert_eq!(img.get_pixel(0, 0)[0], 0);
    assert!(img.get_pixel(256, 256)[0] > 60_000);
    // Correction: masked pixels are 0, not infinite; inside, the flat becomes flat.
    let model = super::PhotometricModel {
        response: super::ResponseModel::Gamma { gamma: 1.0 },
        inverse_256: inv.values.clone(),
        vignette: Some(m.clone()),
    };
    let out = correct(
        &flats[1],
        &model,
        &super::CorrectParams::default(),
        &NoProgress,
    )
    .expect("correct");
    assert!(out.data.iter().all(|v| v.is_finite()));
    assert_eq!(out.data[0], 0.0);
    let c = out.data[256 * 512 + 256];
    let e = out.data[256 * 512 + 256 + 150];
    assert!((e / c - 1.0).abs() < 0.1, "centre {c} vs r=150 {e}");
    // The JSON round-trips and validation rejects a broken spline.
    let json = serde_json::to_string(m).expect("json");
    let back: VignetteModel = serde_json::from_str(&json).expect("back");
    assert_eq!(&back, m);
    let mut bad = m.clone();
    if let Some(s) = bad.spline.as_mut() {
        s.knots[1] = s.knots[2];
    }
    assert!(bad.validate().is_err());
}

#[test]
fn spline_params_are_validated() {
    for p in [
        VignettingParams {
            knots: 2,
            ..VignettingParams::default()
        },
        VignettingParams {
            circle_fraction: f64::NAN,
            ..VignettingParams::default()
        },
        VignettingParams {
            smoothing: -1.0,
            ..VignettingParams::default()
        },
    ] {
        assert!(p.validate().is_err());
    }
}

/// Evaluation sweep (not run by default: ~1 min): both fisheye families over several seeds and
/// shapes, printing the dense-map RMSE inside the circle. `cargo test -p caliper-core
/// fisheye_sweep -- --ignored --nocapture`.
#[test]
#[ignore]
fn fisheye_sweep() {
    let inv = InverseResponse::linear(256);
    let mut worst = [0.0f64; 2];
    for seed in 0..4u64 {
        let s = seed as f64;
        let a = fisheye_a(256.0 + s, 256.0 - s, 315.0 + 6.0 * s, 6.0 + 3.0 * s);
        let b = fisheye_b(
            256.0 - 2.0 * s,
            256.0 + s,
            0.25 + 0.07 * s,
            190.0 + 20.0 * s,
            290.0 + 15.0 * s,
        );
        for (fam, truth) in [(0usize, &a as &dyn Fn(f64, f64) -> f64), (1, &b)] {
            let flats = render(512, 512, truth, &LEVELS, 100 + seed);
            let p = VignettingParams {
                fit_center: true,
                ..VignettingParams::default()
            };
            let Ok(r) = vignetting(&flats, &inv, &p, &NoProgress) else {
                println!("family {fam} seed {seed}: fit failed");
                worst[fam] = f64::INFINITY;
                continue;
            };
            let (rmse, masked) = map_rmse(&r.vignette, truth, 0.05);
            println!(
                "family {} seed {seed}: {:?}, centre {:.1?}, mask {:.1?} px, RMSE {rmse:.5}, \
                 masked {:.3} %",
                ["A (tuning)", "B (held-out)"][fam],
                r.model,
                r.vignette.center,
                r.mask_radius_px,
                100.0 * masked
            );
            worst[fam] = worst[fam].max(rmse);
        }
    }
    println!(
        "worst RMSE: tuning {:.5}, held-out {:.5}",
        worst[0], worst[1]
    );
    assert!(worst.iter().all(|&w| w < 0.005));
}
