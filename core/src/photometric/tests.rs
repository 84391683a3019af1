//! Tests against ground truth from the crate's own generator ([`super::synth`]).

use super::dso::{
    TimeEntry, read_pcalib, read_times, read_vignette_png, write_pcalib, write_times,
    write_vignette_png,
};
use super::metrics::{exposure_error_pct, gamma_align, inverse_rmse};
use super::synth::{SynthCamera, render_bracket, render_flats};
use super::*;
use crate::error::CoreError;
use crate::io::ImageLimits;
use crate::progress::NoProgress;

struct CancelNow;
impl crate::progress::Progress for CancelNow {
    fn report(&self, _: &str, _: u64, _: u64) {}
    fn is_canceled(&self) -> bool {
        true
    }
}

#[test]
fn emor_basis_is_a_response() {
    let b = emor_basis();
    assert_eq!(b.f0.len(), EMOR_SAMPLES);
    assert!(b.f0[0].abs() < 1e-9 && (b.f0[EMOR_SAMPLES - 1] - 1.0).abs() < 1e-9);
    assert!(b.f0.windows(2).all(|w| w[1] > w[0]));
    for h in &b.h {
        assert!(h[0].abs() < 1e-9 && h[EMOR_SAMPLES - 1].abs() < 1e-9);
    }
}

#[test]
fn inverse_inverts_forward() {
    for m in [
        ResponseModel::Gamma { gamma: 2.2 },
        ResponseModel::Emor {
            c: [3.0, -0.8, 0.2, -0.05],
        },
        ResponseModel::default(),
    ] {
        assert!(m.is_monotone());
        let inv = m.inverse(1024);
        for i in 1..100 {
            let x = f64::from(i) / 100.0;
            assert!((inv.eval(m.forward(x)) - x).abs() < 2e-3, "{m:?} at {x}");
        }
        assert!(InverseResponse::new(m.inverse(256).values).is_ok());
    }
    // Gamma has a closed-form inverse.
    let g = ResponseModel::Gamma { gamma: 2.0 }.inverse(256);
    assert!((g.values[128] - (128.0f64 / 255.0).powi(2)).abs() < 1e-3);
}

#[test]
fn non_monotone_emor_is_repaired() {
    let m = ResponseModel::Emor {
        c: [0.0, 0.0, 0.0, 8.0],
    };
    assert!(!m.is_monotone());
    assert!(m.forward_table().windows(2).all(|w| w[1] > w[0]));
    assert!(m.inverse(256).values.windows(2).all(|w| w[1] > w[0]));
}

fn bracket_exposures() -> Vec<f64> {
    (0..9).map(|k| 0.0625 * 2f64.powi(k)).collect()
}

#[test]
fn bracket_fit_recovers_response() {
    let cam = SynthCamera::reference(160, 120, 3);
    let exps = bracket_exposures();
    let imgs = render_bracket(&cam, &exps);
    let r = photometric_response(&imgs, &exps, &ResponseParams::default(), &NoProgress).unwrap();
    let truth = cam.response.inverse(256);
    let fit = InverseResponse::new(r.model.inverse_256.clone()).unwrap();
    let err = inverse_rmse(&fit, &truth);
    assert!(err < 0.005, "response RMSE {err}");
    assert!(r.diagnostics.monotone);
    assert!(r.diagnostics.points > 1000);
    assert!(r.diagnostics.residual_rms_levels < 3.0);
    assert_eq!(r.schema, PHOTOMETRIC_SCHEMA);
    // A gamma camera too, 16-bit.
    let mut cam = SynthCamera::reference(120, 90, 4);
    cam.response = ResponseModel::Gamma { gamma: 2.2 };
    cam.sixteen_bit = true;
    let imgs = render_bracket(&cam, &exps);
    let r = photometric_response(&imgs, &exps, &ResponseParams::default(), &NoProgress).unwrap();
    let fit = InverseResponse::new(r.model.inverse_256.clone()).unwrap();
    let err = inverse_rmse(&fit, &cam.response.inverse(256));
    // A pure power law is not exactly in the EMoR-4 span: ~0.01 is the representation limit.
    assert!(err < 0.02, "gamma response RMSE {err}");
}

#[test]
fn bracket_fit_estimates_wrong_exposures() {
    let cam = SynthCamera::reference(120, 90, 5);
    let exps = bracket_exposures();
    let imgs = render_bracket(&cam, &exps);
    // Nominal times off by up to 15 %.
    let nominal: Vec<f64> = exps
        .iter()
        .enumerate()
        .map(|(i, e)| e * (1.0 + 0.15 * ((i as f64) * 1.7).sin()))
        .collect();
    let p = ResponseParams {
        estimate_exposures: true,
        ..ResponseParams::default()
    };
    let r = photometric_response(&imgs, &nominal, &p, &NoProgress).unwrap();
    let fit = InverseResponse::new(r.model.inverse_256.clone()).unwrap();
    let (alpha, err) = gamma_align(&fit, &cam.response.inverse(256));
    assert!(err < 0.01, "aligned response RMSE {err}");
    let e = exposure_error_pct(&r.exposure_ratios, &exps, alpha);
    assert!(e < 3.0, "exposure error {e} %");
    let e_nominal = exposure_error_pct(&nominal, &exps, 1.0);
    assert!(e < e_nominal);
}

#[test]
fn bracket_rejects_bad_input() {
    let cam = SynthCamera::reference(40, 30, 1);
    let imgs = render_bracket(&cam, &[1.0, 2.0]);
    let p = ResponseParams::default();
    assert!(matches!(
        photometric_response(&imgs, &[1.0], &p, &NoProgress),
        Err(CoreError::InvalidInput(_))
    ));
    assert!(matches!(
        photometric_response(&imgs, &[1.0, -2.0], &p, &NoProgress),
        Err(CoreError::InvalidInput(_))
    ));
    let bad = ResponseParams {
        low_cut: 0.9,
        high_cut: 0.5,
        ..p.clone()
    };
    assert!(matches!(
        photometric_response(&imgs, &[1.0, 2.0], &bad, &NoProgress),
        Err(CoreError::InvalidParam { .. })
    ));
    assert!(matches!(
        photometric_response(&imgs, &[1.0, 2.0], &p, &CancelNow),
        Err(CoreError::Canceled)
    ));
}

#[test]
fn flat_field_recovers_vignetting() {
    // The polynomial coefficients are strongly correlated (r², r⁴, r⁶ and the scale): with the
    // reference noise (2.4 % per pixel) reaching 1e-3 takes a few million samples, i.e. a stack
    // of flats as a real protocol would average.
    let cam = SynthCamera::reference(640, 480, 7);
    let levels: Vec<f64> = (0..16).map(|i| 0.3 + 0.02 * f64::from(i)).collect();
    let flats = render_flats(&cam, &levels);
    let inv = cam.response.inverse(4096);
    let p = VignettingParams {
        stride: 1,
        ..VignettingParams::default()
    };
    let r = vignetting(&flats, &inv, &p, &NoProgress).unwrap();
    for k in 0..3 {
        assert!(
            (r.vignette.v[k] - cam.vignette[k]).abs() < 1e-3,
            "v{} = {} vs {}",
            k + 1,
            r.vignette.v[k],
            cam.vignette[k]
        );
    }
    // Linear camera, fitted centre.
    let mut lin = SynthCamera::reference(160, 120, 8);
    lin.response = ResponseModel::Gamma { gamma: 1.0 };
    let flats = render_flats(&lin, &[0.6]);
    let p = VignettingParams {
        fit_center: true,
        stride: 1,
        ..VignettingParams::default()
    };
    let r = vignetting(&flats, &InverseResponse::linear(256), &p, &NoProgress).unwrap();
    assert!((r.vignette.center[0] - 80.0).abs() < 0.5 && (r.vignette.center[1] - 60.0).abs() < 0.5);
    assert!((r.vignette.v[0] - lin.vignette[0]).abs() < 5e-3);
    let map = r.vignette.map();
    assert_eq!(map.len(), 160 * 120);
}

#[test]
fn pcalib_round_trip_and_validation() {
    let inv = ResponseModel::Emor {
        c: [1.0, 0.2, 0.0, 0.0],
    }
    .inverse(256);
    let text = write_pcalib(&inv);
    assert_eq!(text.lines().count(), 1);
    assert_eq!(text.split_whitespace().count(), 256);
    let back = read_pcalib(&text).unwrap();
    for (a, b) in back.values.iter().zip(&inv.values) {
        assert!((a - b).abs() < 1e-7);
    }
    let mut vals: Vec<String> = text.split_whitespace().map(str::to_string).collect();
    vals[100] = vals[99].clone();
    let err = read_pcalib(&vals.join(" ")).unwrap_err().to_string();
    assert!(err.contains("index 100"), "{err}");
    assert!(
        read_pcalib("0 1 2")
            .unwrap_err()
            .to_string()
            .contains("256")
    );
    assert!(read_pcalib(&text.replace(' ', " x ")).is_err());
}

#[test]
fn vignette_png_round_trip() {
    let m = VignetteModel::centered(64, 48, [-0.35, 0.1, -0.1]);
    let png = write_vignette_png(&m).unwrap();
    let back = read_vignette_png(&png, &ImageLimits::default(), Some((64, 48))).unwrap();
    let map = m.map();
    let max = map.iter().copied().fold(0.0f32, f32::max);
    for (a, b) in back.data.iter().zip(&map) {
        assert!((a - b / max).abs() < 2e-5);
    }
    assert!(read_vignette_png(&png, &ImageLimits::default(), Some((32, 48))).is_err());
    let img = PhotoImage::decode(&png, &ImageLimits::default()).unwrap();
    assert_eq!(img.max_level, u16::MAX);
}

#[test]
fn times_round_trip_and_validation() {
    let e = vec![
        TimeEntry {
            id: "00000".into(),
            timestamp: 0.0,
            exposure_ms: 4.0,
        },
        TimeEntry {
            id: "00001".into(),
            timestamp: 0.05,
            exposure_ms: 6.044868,
        },
    ];
    let text = write_times(&e);
    assert_eq!(read_times(&text).unwrap(), e);
    assert!(
        read_times("0 0.0 -1")
            .unwrap_err()
            .to_string()
            .contains("line 1")
    );
    assert!(read_times("0 0.0").is_err());
    assert!(read_times("").is_err());
}

#[test]
fn correction_equalises_exposures() {
    let cam = SynthCamera::reference(80, 60, 9);
    let exps = [0.5, 1.0, 2.0];
    let imgs = render_bracket(&cam, &exps);
    let model = PhotometricModel::new(cam.response.clone(), Some(cam.vignette_model()));
    let planes: Vec<_> = imgs
        .iter()
        .zip(exps)
        .map(|(im, e)| {
            correct(
                im,
                &model,
                &CorrectParams {
                    exposure: e,
                    gain: 1.0,
                },
                &NoProgress,
            )
            .unwrap()
        })
        .collect();
    let tex = synth::Texture::new(9, 0.25, 6.0);
    let (mut err, mut n) = (0.0, 0);
    for p in &planes {
        for y in 0..60 {
            for x in 0..80 {
                let l = tex.radiance(x as f64, y as f64);
                let v = f64::from(p.data[y * 80 + x]);
                let irr = l * cam.vignette_model().eval(x as f64, y as f64);
                if irr * 0.5 > 0.05 && irr * 2.0 < 0.9 {
                    err += (v / l - 1.0).powi(2);
                    n += 1;
                }
            }
        }
    }
    let rel = (err / f64::from(n)).sqrt();
    assert!(rel < 0.06, "relative radiance error {rel}");
}

#[test]
fn plots_are_svg() {
    let m = ResponseModel::Emor {
        c: [3.0, -0.8, 0.2, -0.05],
    };
    let s = plot::response_svg(&m, Some(&ResponseModel::default()));
    assert!(s.starts_with("<svg") && s.contains("polyline"));
    let v = VignetteModel::centered(64, 48, [-0.35, 0.1, -0.1]);
    assert!(plot::vignette_profile_svg(&v, None).contains("polyline"));
    assert!(
        plot::exposure_svg(&[1.0, 1.2, 0.9], Some(&[0.0, 0.05, 0.1]), None).contains("polyline")
    );
}

#[test]
fn params_serde_and_validation() {
    let p: OnlineParams = serde_json::from_str(r#"{"max_features": 200}"#).unwrap();
    assert_eq!(p.max_features, 200);
    assert!(serde_json::from_str::<OnlineParams>(r#"{"nope": 1}"#).is_err());
    let bad = OnlineParams {
        gamma_gauge: Some(1.5),
        ..OnlineParams::default()
    };
    assert!(bad.validate().is_err());
    let m = PhotometricModel::new(ResponseModel::Gamma { gamma: 2.2 }, None);
    let j = serde_json::to_string(&m).unwrap();
    assert!(j.contains("\"kind\":\"gamma\""));
    let back: PhotometricModel = serde_json::from_str(&j).unwrap();
    assert_eq!(back, m);
}

/// The new generator forms of the saturated tuning split: the walk stays within its range and
/// moves, the Gaussian law is `corner` at the corner and 1 at the centre, the Mondrian spans
/// the scene's contrast with flat blocks.
#[test]
fn walk_gaussian_and_blocks_generators() {
    use super::synth::{AeVideo, ExposureProgram, SceneForm, VignetteForm, render_ae_video};
    let cam = SynthCamera::reference(64, 48, 3);
    let video = AeVideo {
        program: ExposureProgram::Walk {
            stops: 1.0,
            step: 0.3,
        },
        scene: SceneForm::Blocks,
        vignette: VignetteForm::Gaussian { corner: 0.4 },
        ..AeVideo::default()
    };
    let seq = render_ae_video(&cam, 60, &video);
    let logs: Vec<f64> = seq.exposures.iter().map(|e| e.log2()).collect();
    assert!(logs.iter().all(|l| l.abs() <= 1.0 + 1e-9), "{logs:?}");
    let (lo, hi) = logs
        .iter()
        .fold((f64::MAX, f64::MIN), |a, &l| (a.0.min(l), a.1.max(l)));
    assert!(hi - lo > 0.5, "the walk barely moved: {lo}..{hi}");
    let v = &seq.vignette_map;
    let centre = v[24 * 64 + 32];
    assert!((centre - 1.0).abs() < 1e-3, "centre {centre}");
    assert!((v[0] - 0.4).abs() < 0.02, "corner {}", v[0]);
    // Flat blocks: most horizontal neighbours in a frame are (nearly) equal, a few differ a lot.
    let f = &seq.frames[0];
    let steps: Vec<i32> = f
        .data
        .chunks(64)
        .flat_map(|row| {
            row.windows(2)
                .map(|p| (i32::from(p[1]) - i32::from(p[0])).abs())
        })
        .collect();
    let flat = steps.iter().filter(|&&d| d <= 3).count() as f64 / steps.len() as f64;
    assert!(flat > 0.7, "flat fraction {flat}");
    assert!(steps.iter().any(|&d| d > 20), "no block edge");
}

/// The lens blur of the renderer softens edges (less energy in the differences between
/// neighbours on a Mondrian) without moving the pixel grid, the exposure program or the mean
/// level.
#[test]
fn optics_blur_softens_edges_only() {
    use super::synth::{AeVideo, SceneForm, render_ae_video};
    // Noiseless, so that the differences between neighbours are the scene's edges.
    let cam = SynthCamera {
        shot: 0.0,
        read: 0.0,
        ..SynthCamera::reference(64, 48, 5)
    };
    // One stop of contrast: nothing clipped, so blur moves no light into clipped areas.
    let sharp = AeVideo {
        scene: SceneForm::Blocks,
        stops: 1.0,
        ..AeVideo::default()
    };
    let soft = AeVideo {
        optics_blur: 2.0,
        ..sharp.clone()
    };
    let a = render_ae_video(&cam, 3, &sharp);
    let b = render_ae_video(&cam, 3, &soft);
    // A negligible blur lands on the same pixel grid (the supersamples are centred on the
    // pixels): only the area integration of the ramps differs.
    let tiny = render_ae_video(
        &cam,
        1,
        &AeVideo {
            optics_blur: 0.01,
            ..sharp.clone()
        },
    );
    let off = a.frames[0]
        .data
        .iter()
        .zip(&tiny.frames[0].data)
        .map(|(&p, &q)| (i32::from(p) - i32::from(q)).abs())
        .max()
        .unwrap_or(0);
    assert!(off <= 4, "a 0.01 px blur moved a pixel by {off} levels");
    // Blur keeps a monotone edge's total rise and spreads it, so the energy of the
    // neighbour differences falls (by about 2σ√π for a step).
    let step_energy = |f: &PhotoImage| -> f64 {
        f.data
            .chunks(64)
            .flat_map(|row| {
                row.windows(2)
                    .map(|p| (f64::from(p[1]) - f64::from(p[0])).powi(2))
            })
            .sum()
    };
    let mean = |f: &PhotoImage| f.data.iter().map(|&v| f64::from(v)).sum::<f64>() / 3072.0;
    let (sa, sb) = (step_energy(&a.frames[0]), step_energy(&b.frames[0]));
    // The scene's block edges are ramps of a few pixels already, so σ = 2 px widens them by
    // about half; σ = 4 px by more.
    let softer = render_ae_video(
        &cam,
        1,
        &AeVideo {
            optics_blur: 4.0,
            ..sharp.clone()
        },
    );
    let sc = step_energy(&softer.frames[0]);
    assert!(
        sb < 0.75 * sa && sc < 0.8 * sb,
        "neighbour-difference energy sharp {sa}, σ 2 px {sb}, σ 4 px {sc}"
    );
    let (ma, mb) = (mean(&a.frames[0]), mean(&b.frames[0]));
    assert!(
        (ma - mb).abs() < 0.05 * ma,
        "mean level sharp {ma}, blurred {mb}"
    );
    assert_eq!(a.exposures[0], b.exposures[0]);
}
