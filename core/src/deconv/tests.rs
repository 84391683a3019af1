use super::fft::C32;
use super::*;
use crate::error::CoreError;
use crate::io::Gray;
use crate::progress::NoProgress;

/// Deterministic "natural-ish" test image: smooth shading, hard-edged shapes, a textured patch.
pub(super) fn scene(w: usize, h: usize) -> Plane {
    let mut data = Vec::with_capacity(w * h);
    for y in 0..h {
        for x in 0..w {
            let (fx, fy) = (x as f32 / w as f32, y as f32 / h as f32);
            let mut v = 0.25 + 0.3 * fx + 0.15 * fy;
            if (x / 16 + y / 16) % 3 == 0 && x > w / 8 && y > h / 8 {
                v += 0.25;
            }
            let (dx, dy) = (fx - 0.62, fy - 0.4);
            if dx * dx + dy * dy < 0.04 {
                v = 0.9 - 0.5 * (dx * dx + dy * dy) * 10.0;
            }
            if x > w / 2 && y > 3 * h / 4 {
                v = 0.5 + 0.3 * ((x as f32 * 0.9).sin() * (y as f32 * 0.7).cos());
            }
            data.push(v.clamp(0.0, 1.0));
        }
    }
    Plane::new(w, h, data).expect("valid scene")
}

/// Gaussian noise from a fixed-seed xorshift + Box-Muller (no rand dependency).
pub(super) fn add_noise(img: &Plane, sigma: f32, seed: u64) -> Plane {
    let mut s = seed | 1;
    let mut uniform = move || {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        ((s >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    };
    let data = img
        .data
        .iter()
        .map(|&v| {
            let (u1, u2) = (uniform(), uniform());
            let n = (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos();
            (v + sigma * n as f32).clamp(0.0, 1.0)
        })
        .collect();
    Plane::new(img.width, img.height, data).expect("valid")
}

/// True convolution with reflect borders, as `scipy.ndimage.convolve(mode='reflect')`.
pub(super) fn blur_reflect(img: &Plane, psf: &Psf) -> Plane {
    let (cx, cy) = ((psf.width / 2) as isize, (psf.height / 2) as isize);
    let mut data = vec![0.0f32; img.data.len()];
    for y in 0..img.height {
        for x in 0..img.width {
            let mut acc = 0.0f64;
            for ky in 0..psf.height {
                let sy = reflect(y as isize + cy - ky as isize, img.height);
                for kx in 0..psf.width {
                    let k = psf.at(kx, ky);
                    if k != 0.0 {
                        let sx = reflect(x as isize + cx - kx as isize, img.width);
                        acc += k * f64::from(img.at(sx, sy));
                    }
                }
            }
            data[y * img.width + x] = acc as f32;
        }
    }
    Plane::new(img.width, img.height, data).expect("valid")
}

fn sum(psf: &Psf) -> f64 {
    psf.data.iter().sum()
}

#[test]
fn motion_psf_matches_peer_convention() {
    let k = Psf::motion(5.0, 30.0).expect("motion");
    assert_eq!((k.width, k.height), (7, 7));
    assert!((sum(&k) - 1.0).abs() < 1e-12);
    // Values printed by deconv_skimage.motion_psf(5, 30) (rows 2..4, columns 3..5 of 7×7).
    let expect = [
        (3, 2, 0.02749899020175834),
        (4, 2, 0.15554556915127013),
        (5, 2, 0.06948069317222406),
        (1, 3, 0.0107690330658333),
        (3, 3, 0.23072833693680128),
        (1, 4, 0.06948069317222401),
    ];
    for (x, y, v) in expect {
        assert!(
            (k.at(x, y) - v).abs() < 1e-12,
            "({x},{y}) {} vs {v}",
            k.at(x, y)
        );
    }
    // Counter-clockwise with y down: the far end at +30° is up and to the right.
    assert!(k.at(5, 2) > 0.0 && k.at(5, 4) == 0.0);
}

#[test]
fn motion_psf_support_and_identity() {
    let h = Psf::motion(15.0, 0.0).expect("motion");
    assert_eq!((h.width, h.height), (17, 17));
    for y in 0..17 {
        for x in 0..17 {
            let on = y == 8 && (1..=15).contains(&x);
            assert_eq!(h.at(x, y) > 1e-12, on, "({x},{y})");
        }
    }
    let v = Psf::motion(15.0, 90.0).expect("motion");
    assert!((v.at(8, 1) - h.at(1, 8)).abs() < 1e-9);
    assert_eq!(Psf::motion(1.0, 45.0).expect("motion"), Psf::identity());
    assert!(Psf::motion(f64::NAN, 0.0).is_err());
    assert!(Psf::motion(-3.0, 0.0).is_err());
    assert!(Psf::motion(1000.0, 0.0).is_err());
}

#[test]
fn disc_and_gaussian_psfs() {
    let d = Psf::disc(3.0).expect("disc");
    assert_eq!((d.width, d.height), (7, 7));
    assert!((sum(&d) - 1.0).abs() < 1e-12);
    assert_eq!(d.at(0, 0), 0.0);
    assert!((d.at(3, 0) - d.at(0, 3)).abs() < 1e-15 && d.at(3, 0) > 0.0);
    assert!((d.at(3, 3) - d.at(2, 3)).abs() < 1e-15); // flat inside
    let g = Psf::gaussian(1.0).expect("gaussian");
    assert_eq!((g.width, g.height), (7, 7));
    assert!((sum(&g) - 1.0).abs() < 1e-12);
    assert!((g.at(2, 3) / g.at(3, 3) - (-0.5f64).exp()).abs() < 1e-12);
    assert!(Psf::gaussian(-1.0).is_err() && Psf::disc(f64::INFINITY).is_err());
    assert_eq!(Psf::gaussian(0.0).expect("identity"), Psf::identity());
}

#[test]
fn psf_text_parsing() {
    let k = Psf::parse_text("# header\n0 1 0\n1,2,1\n 0\t1  0 \n\n").expect("text");
    assert_eq!((k.width, k.height), (3, 3));
    assert!((k.at(1, 1) - 1.0 / 3.0).abs() < 1e-12);
    // savetxt("%.10g") style with exponents; a round trip through to_text is exact.
    let m = Psf::motion(7.5, 17.0).expect("motion");
    assert_eq!(Psf::parse_text(&m.to_text()).expect("round trip"), m);
    // Even sizes are padded at the bottom/right, keeping the centre at size / 2.
    let e = Psf::parse_text("1 1\n1 1\n").expect("even");
    assert_eq!((e.width, e.height), (3, 3));
    assert_eq!(e.at(2, 2), 0.0);
    assert!((e.at(1, 1) - 0.25).abs() < 1e-12);
    for bad in [
        "",
        "# only a comment\n",
        "1 2\n3\n",
        "1 x 2\n",
        "0 0\n0 0\n",
        "1 -0.5\n",
        "nan 1\n",
    ] {
        match Psf::parse_text(bad) {
            Err(CoreError::InvalidInput(msg)) => assert!(!msg.is_empty()),
            other => panic!("{bad:?} gave {other:?}"),
        }
    }
    let big = "1 ".repeat(300);
    assert!(Psf::parse_text(&big).is_err());
    // Round-off negatives are clipped, not rejected.
    assert!(Psf::parse_text("1 -1e-12 1\n").is_ok());
}

#[test]
fn psf_json_parsing() {
    let k = Psf::parse_json("[[0, 1, 0], [1, 4, 1], [0, 1, 0]]").expect("json");
    assert!((k.at(1, 1) - 0.5).abs() < 1e-12);
    let m = Psf::gaussian(1.3).expect("gaussian");
    let text = m.to_json().to_string();
    let back = Psf::parse_json(&text).expect("round trip");
    assert!(
        back.data
            .iter()
            .zip(&m.data)
            .all(|(a, b)| (a - b).abs() < 1e-15)
    );
    for bad in [
        "[[1, 2], [3]]",
        "[1, 2, 3]",
        "{\"k\": [[1]]}",
        "[[1, \"a\"]]",
        "[[",
        "[]",
        "[[0]]",
    ] {
        assert!(
            matches!(Psf::parse_json(bad), Err(CoreError::InvalidInput(_))),
            "{bad} accepted"
        );
    }
}

#[test]
fn psf_from_gray_normalises() {
    let g = Gray::new(3, 1, vec![0, 255, 255]).expect("gray");
    let k = Psf::from_gray(&g).expect("psf");
    assert_eq!((k.width, k.height), (3, 1));
    assert!((k.at(1, 0) - 0.5).abs() < 1e-12);
    assert_eq!(Psf::from_gray(&k.to_gray()).expect("again"), k);
}

#[test]
fn fast_lengths_are_even_and_smooth() {
    assert_eq!(fast_len(1), 2);
    assert_eq!(fast_len(127), 128);
    assert_eq!(fast_len(211), 216);
    for n in 1..500 {
        let m = fast_len(n);
        assert!(m >= n && m.is_multiple_of(2) && is_smooth(m));
    }
}

#[test]
fn fft2_matches_direct_circular_convolution() {
    let (h, w) = (10, 12);
    let x: Vec<f32> = (0..h * w).map(|i| ((i * 37 % 11) as f32) / 11.0).collect();
    let psf = Psf::motion(4.0, 20.0).expect("motion");
    let fft = Fft2::new(h, w);
    let k = fft.kernel_spectrum(psf.width, psf.height, |a, b| psf.at(a, b));
    let s = fft.forward(&x);
    let prod: Vec<_> = s.iter().zip(&k).map(|(a, b)| a * b).collect();
    let y = fft.inverse(&prod);
    let n = (h * w) as f32;
    let (cx, cy) = (psf.width / 2, psf.height / 2);
    for r in 0..h {
        for c in 0..w {
            let mut acc = 0.0f64;
            for ky in 0..psf.height {
                for kx in 0..psf.width {
                    let sy = (r + h * 4 + cy - ky) % h;
                    let sx = (c + w * 4 + cx - kx) % w;
                    acc += psf.at(kx, ky) * f64::from(x[sy * w + sx]);
                }
            }
            assert!(
                (f64::from(y[r * w + c] / n) - acc).abs() < 1e-5,
                "({r},{c})"
            );
        }
    }
}

/// The `_into` transforms write every value of a dirty output buffer and give bit-for-bit the
/// allocating transforms' result, however often the spare buffers have been reused (the blind
/// estimator depends on exact repeatability).
#[test]
fn fft2_into_variants_reuse_buffers_exactly() {
    let (h, w) = (18, 22);
    let x: Vec<f32> = (0..h * w).map(|i| ((i * 53 % 17) as f32) / 17.0).collect();
    let fft = Fft2::new(h, w);
    let spec = fft.forward(&x);
    let back = fft.inverse(&spec);
    let mut spec_into = vec![C32::new(f32::NAN, 7.0); fft.spec_len()];
    let mut back_into = vec![f32::NAN; h * w];
    for _ in 0..3 {
        fft.forward_into(&x, &mut spec_into);
        fft.inverse_into(&spec_into, &mut back_into);
        assert_eq!(spec_into, spec);
        assert_eq!(back_into, back);
    }
    let psf = Psf::motion(5.0, 30.0).expect("motion");
    let mut plane = vec![f32::NAN; h * w];
    fft.kernel_spectrum_into(
        psf.width,
        psf.height,
        |a, b| psf.at(a, b),
        &mut plane,
        &mut spec_into,
    );
    assert_eq!(
        spec_into,
        fft.kernel_spectrum(psf.width, psf.height, |a, b| psf.at(a, b))
    );
}

#[test]
fn pad_crop_and_identity_round_trip() {
    let img = scene(37, 29);
    let layout = PadLayout::new(29, 37, 16, 16);
    assert!(layout.padded_height >= 61 && layout.padded_width >= 69);
    assert_eq!(layout.crop(&layout.pad_tapered(&img)), img.data);
    assert_eq!(layout.crop(&layout.pad_mirror(&img)), img.data);
    let w = wiener(&img, &Psf::identity(), Some(0.0)).expect("wiener");
    let err = w
        .data
        .iter()
        .zip(&img.data)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f32::max);
    assert!(err < 1e-5, "wiener identity error {err}");
    let r = richardson_lucy(&img, &Psf::identity(), 5, &NoProgress).expect("rl");
    let err = r
        .data
        .iter()
        .zip(&img.data)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f32::max);
    // Not exact: the small TV term of the RL update nudges edges by O(λ).
    assert!(err < 0.02, "rl identity error {err}");
}

#[test]
fn taper_is_continuous_across_the_wrap() {
    let img = scene(40, 30);
    let layout = PadLayout::new(30, 40, 20, 20);
    let p = layout.pad_tapered(&img);
    let pw = layout.padded_width;
    for y in 0..layout.padded_height {
        let row = &p[y * pw..(y + 1) * pw];
        let jump = (row[0] - row[pw - 1]).abs();
        assert!(jump < 0.05, "row {y}: seam jump {jump}");
    }
}

struct Case {
    sharp: Plane,
    blurred: Plane,
    psf: Psf,
}

fn motion_case() -> Case {
    let sharp = scene(128, 112);
    let psf = Psf::motion(11.0, 30.0).expect("motion");
    let blurred = add_noise(&blur_reflect(&sharp, &psf), 0.01, 7);
    Case {
        sharp,
        blurred,
        psf,
    }
}

#[test]
fn wiener_improves_psnr() {
    let c = motion_case();
    let before = psnr(&c.blurred, &c.sharp, 1.0).expect("psnr");
    let est = wiener(&c.blurred, &c.psf, None).expect("wiener");
    let after = psnr(&est, &c.sharp, 1.0).expect("psnr");
    eprintln!("wiener: {before:.2} dB -> {after:.2} dB");
    assert!(after > before + 1.5, "{before:.2} -> {after:.2}");
    let sigma = estimate_noise_sigma(&c.blurred);
    assert!((0.006..0.014).contains(&sigma), "noise estimate {sigma}");
    assert!(wiener(&c.blurred, &c.psf, Some(-1.0)).is_err());
}

#[test]
fn richardson_lucy_improves_and_does_not_diverge() {
    let c = motion_case();
    let before = psnr(&c.blurred, &c.sharp, 1.0).expect("psnr");
    let r30 = richardson_lucy(&c.blurred, &c.psf, 30, &NoProgress).expect("rl");
    let r60 = richardson_lucy(&c.blurred, &c.psf, 60, &NoProgress).expect("rl");
    let (p30, p60) = (
        psnr(&r30, &c.sharp, 1.0).expect("psnr"),
        psnr(&r60, &c.sharp, 1.0).expect("psnr"),
    );
    eprintln!("rl: {before:.2} dB -> 30 it {p30:.2} dB, 60 it {p60:.2} dB");
    assert!(p30 > before + 2.5, "{before:.2} -> {p30:.2}");
    assert!(p60 >= p30 - 0.05, "30 it {p30:.2} dB, 60 it {p60:.2} dB");
    assert!(r60.data.iter().all(|&v| (0.0..=1.0).contains(&v)));
}

#[test]
fn richardson_lucy_cancels() {
    struct Cancel;
    impl crate::progress::Progress for Cancel {
        fn report(&self, _: &str, _: u64, _: u64) {}
        fn is_canceled(&self) -> bool {
            true
        }
    }
    let img = scene(20, 20);
    let psf = Psf::gaussian(1.0).expect("gaussian");
    assert!(matches!(
        richardson_lucy(&img, &psf, 3, &Cancel),
        Err(CoreError::Canceled)
    ));
}

#[test]
fn metrics_known_values() {
    let a = scene(32, 24);
    let mut b = a.clone();
    for v in b.data.iter_mut() {
        *v += 0.1;
    }
    let p = psnr(&a, &b, 1.0).expect("psnr");
    assert!((p - 20.0).abs() < 1e-3, "{p}");
    assert!(psnr(&a, &a, 1.0).expect("psnr").is_infinite());
    assert!((ssim(&a, &a).expect("ssim") - 1.0).abs() < 1e-12);
    let n = add_noise(&a, 0.1, 3);
    let s = ssim(&a, &n).expect("ssim");
    assert!(s > 0.0 && s < 0.9, "{s}");
    assert!(psnr(&a, &scene(8, 8), 1.0).is_err());
    assert!(ssim(&scene(6, 6), &scene(6, 6)).is_err());
    let r = error_ratio(&a, &n, &b, 2).expect("ratio");
    assert!(r > 0.5 && r < 2.0, "{r}");
    assert!(error_ratio(&a, &n, &b, 12).is_err());
}

/// On constant images every window gives the luminance term alone, a closed form.
#[test]
fn ssim_matches_reference_formula_on_constant_offset() {
    // For b = a + d with a locally constant, SSIM = (2μa μb + C1)/(μa² + μb² + C1) per window.
    let a = Plane::new(9, 9, vec![0.5; 81]).expect("plane");
    let b = Plane::new(9, 9, vec![0.6; 81]).expect("plane");
    let c1 = 1e-4;
    let expect = (2.0 * 0.5 * 0.6 + c1) / (0.25 + 0.36 + c1);
    assert!((ssim(&a, &b).expect("ssim") - expect).abs() < 1e-6);
}

/// Issue D12: weights so large that their sum overflows still normalise (scaled by the peak).
#[test]
fn huge_finite_weights_normalise() {
    let k = Psf::from_weights(3, 1, vec![1e308; 3]).expect("huge weights");
    for v in &k.data {
        assert!((v - 1.0 / 3.0).abs() < 1e-15, "{k:?}");
    }
    assert!(Psf::from_weights(3, 1, vec![f64::MAX, 0.0, f64::MAX]).is_ok());
}
