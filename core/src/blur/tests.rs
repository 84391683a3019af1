use super::laplacian::laplacian_sums;
use super::svd::{Route, beta_from_sorted, singular_values};
use super::*;
use crate::io::Gray;
use crate::progress::NoProgress;
use faer::Par;
use std::sync::atomic::AtomicBool;

/// Small deterministic PRNG (xorshift64*), so tests need no extra crate.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn image(&mut self, w: u32, h: u32) -> Gray {
        let data = (0..w * h).map(|_| (self.next() >> 56) as u8).collect();
        Gray::new(w, h, data).unwrap()
    }
}

/// Naive f64 reference with explicit reflect-101 (OpenCV uses the pixel itself when the side
/// is 1 pixel long: checked with cv2 on 1×1, 1×5, 5×1, 2×2, 2×3, 3×1).
fn naive_laplacian_variance(img: &Gray) -> f64 {
    let (w, h) = (img.width as i64, img.height as i64);
    let refl = |i: i64, n: i64| -> i64 {
        if n == 1 {
            0
        } else if i < 0 {
            -i
        } else if i >= n {
            2 * (n - 1) - i
        } else {
            i
        }
    };
    let p = |x: i64, y: i64| f64::from(img.data[(refl(y, h) * w + refl(x, w)) as usize]);
    let mut r = Vec::new();
    for y in 0..h {
        for x in 0..w {
            r.push(p(x - 1, y) + p(x + 1, y) + p(x, y - 1) + p(x, y + 1) - 4.0 * p(x, y));
        }
    }
    let n = r.len() as f64;
    let mean = r.iter().sum::<f64>() / n;
    r.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n
}

#[test]
fn laplacian_matches_naive_reference() {
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let sizes = [
        (1, 1),
        (1, 5),
        (5, 1),
        (2, 2),
        (2, 3),
        (3, 2),
        (3, 3),
        (4, 7),
        (17, 9),
        (64, 48),
        (4100, 3),
        (5000, 2),
        (9000, 4),
    ];
    for (w, h) in sizes {
        for _ in 0..3 {
            let img = rng.image(w, h);
            let fast = laplacian_variance(&img);
            let slow = naive_laplacian_variance(&img);
            let tol = 1e-9 * slow.abs().max(1e-300);
            assert!((fast - slow).abs() <= tol, "{w}×{h}: {fast} vs {slow}");
        }
    }
}

/// Values printed by `cv2.Laplacian(x, cv2.CV_64F, ksize=1)` for tiny images.
#[test]
fn laplacian_tiny_images_match_opencv() {
    let cases: [(u32, u32, Vec<u8>, Vec<i64>); 4] = [
        (1, 1, vec![232], vec![0]),
        (
            5,
            1,
            vec![112, 56, 246, 245, 193],
            vec![-112, 246, -191, -51, 104],
        ),
        (
            1,
            5,
            vec![130, 3, 206, 161, 155],
            vec![-254, 330, -248, 39, 12],
        ),
        (2, 2, vec![23, 228, 90, 29], vec![544, -808, -256, 520]),
    ];
    for (w, h, data, resp) in cases {
        let img = Gray::new(w, h, data).unwrap();
        let (s, q) = laplacian_sums(&img);
        assert_eq!(s, resp.iter().sum::<i64>());
        assert_eq!(q, resp.iter().map(|r| (r * r) as u64).sum::<u64>());
    }
    assert_eq!(laplacian_variance(&Gray::new(0, 0, vec![]).unwrap()), 0.0);
}

/// Slow reference: nalgebra's SVD of the image in [0, 1].
fn reference_beta(img: &Gray, k: usize) -> f64 {
    let m = nalgebra::DMatrix::from_fn(img.height as usize, img.width as usize, |i, j| {
        f64::from(img.data[i * img.width as usize + j]) / 255.0
    });
    let mut s: Vec<f64> = m.singular_values().iter().copied().collect();
    s.sort_by(|a, b| b.total_cmp(a));
    beta_from_sorted(&s, k)
}

#[test]
fn svd_beta_matches_reference() {
    let mut rng = Rng(42);
    for (w, h) in [
        (1, 1),
        (1, 7),
        (7, 1),
        (3, 3),
        (12, 9),
        (9, 12),
        (40, 30),
        (31, 64),
    ] {
        let img = rng.image(w, h);
        for k in [1, 2, 5, 10, 64] {
            let fast = svd_beta(&img, k).unwrap();
            let slow = reference_beta(&img, k);
            assert!(
                (fast - slow).abs() < 1e-9,
                "{w}×{h} k={k}: {fast} vs {slow}"
            );
        }
    }
}

/// An image with many exactly-zero singular values (duplicated rows) is where the Gram route
/// loses accuracy; the error bound must switch to the direct SVD and stay within 1e-9.
#[test]
fn svd_beta_rank_deficient_falls_back() {
    let mut rng = Rng(7);
    let (w, h) = (48u32, 40u32);
    let base = rng.image(w, 3);
    let mut data = Vec::new();
    for y in 0..h {
        let src = (y % 3) as usize * w as usize;
        let row: Vec<u8> = base.data[src..src + w as usize]
            .iter()
            .map(|&v| v / (1 + (y as u8 % 2)))
            .collect();
        data.extend(row);
    }
    let img = Gray::new(w, h, data).unwrap();
    let (_, route) = singular_values(&img, Par::Seq).unwrap();
    assert_eq!(route, Route::Svd);
    let fast = svd_beta(&img, 2).unwrap();
    let slow = reference_beta(&img, 2);
    assert!((fast - slow).abs() < 1e-9, "{fast} vs {slow}");

    // A full-rank random image takes the fast route.
    let img = rng.image(64, 48);
    assert_eq!(singular_values(&img, Par::Seq).unwrap().1, Route::Gram);
}

#[test]
fn clip_beta_is_the_beta_of_the_box_reduced_frame() {
    assert_eq!(clip_reduction_factor(640, 480), 1);
    assert_eq!(clip_reduction_factor(1280, 720), 2);
    assert_eq!(clip_reduction_factor(1920, 1080), 3);
    assert_eq!(clip_reduction_factor(1080, 1920), 3);
    let img = sharp_scene(150, 96);
    // Reduced by hand: the mean of each 3×3 block (β is scale-invariant, so sums or means
    // give the same value).
    let (rw, rh) = (150 / 3, 96 / 3);
    let mut small = Vec::with_capacity(rw * rh);
    for y in 0..rh {
        for x in 0..rw {
            let mut acc = 0u32;
            for yy in 3 * y..3 * y + 3 {
                for xx in 3 * x..3 * x + 3 {
                    acc += u32::from(img.data[yy * 150 + xx]);
                }
            }
            small.push(acc);
        }
    }
    // Compare against the exact reference on the block sums (as f64: they exceed u8).
    let m = nalgebra::DMatrix::from_fn(rh, rw, |i, j| f64::from(small[i * rw + j]));
    let sv = m.singular_values();
    let mut sv: Vec<f64> = sv.iter().copied().collect();
    sv.sort_by(|a, b| b.total_cmp(a));
    let want = sv.iter().take(4).sum::<f64>() / sv.iter().sum::<f64>();
    let got = svd_beta_reduced(&img, 4, 3).unwrap();
    assert!((got - want).abs() < 1e-9, "{got} vs {want}");
    assert_eq!(
        svd_beta_reduced(&img, 4, 1).unwrap(),
        svd_beta(&img, 4).unwrap()
    );
    assert!(svd_beta_reduced(&img, 4, 200).is_err());
}

#[test]
fn svd_beta_edge_cases() {
    let black = Gray::new(8, 8, vec![0; 64]).unwrap();
    assert_eq!(svd_beta(&black, 3).unwrap(), 1.0);
    let flat = Gray::new(8, 5, vec![77; 40]).unwrap();
    assert!((svd_beta(&flat, 1).unwrap() - 1.0).abs() < 1e-12);
    assert!(matches!(
        svd_beta(&flat, 0),
        Err(CoreError::InvalidParam { .. })
    ));
    assert!(svd_beta(&Gray::new(0, 3, vec![]).unwrap(), 1).is_err());
}

/// Sharp synthetic scene: checkerboard plus a fine deterministic texture.
fn sharp_scene(w: u32, h: u32) -> Gray {
    let mut data = Vec::with_capacity((w * h) as usize);
    for y in 0..h {
        for x in 0..w {
            let check = if ((x / 8) + (y / 8)) % 2 == 0 {
                200
            } else {
                40
            };
            let texture = ((x * 37 + y * 91) ^ (x * y)) % 23;
            data.push((check + texture) as u8);
        }
    }
    Gray::new(w, h, data).unwrap()
}

/// Horizontal box blur of length `len` (motion blur), clamped at the borders.
fn box_blur(img: &Gray, len: i64) -> Gray {
    let (w, h) = (img.width as i64, img.height as i64);
    let mut data = Vec::with_capacity(img.data.len());
    for y in 0..h {
        for x in 0..w {
            let mut s = 0i64;
            for d in -(len / 2)..=(len / 2) {
                let xx = (x + d).clamp(0, w - 1);
                s += i64::from(img.data[(y * w + xx) as usize]);
            }
            data.push(((s + len / 2) / len) as u8);
        }
    }
    Gray::new(img.width, img.height, data).unwrap()
}

#[test]
fn blur_lowers_laplacian_and_raises_beta() {
    let sharp = sharp_scene(96, 64);
    let mut prev_lap = laplacian_variance(&sharp);
    let mut prev_beta = svd_beta(&sharp, 10).unwrap();
    for len in [3, 7, 15] {
        let b = box_blur(&sharp, len);
        let lap = laplacian_variance(&b);
        let beta = svd_beta(&b, 10).unwrap();
        assert!(lap < prev_lap, "len {len}: lap {lap} ≥ {prev_lap}");
        assert!(beta > prev_beta, "len {len}: beta {beta} ≤ {prev_beta}");
        prev_lap = lap;
        prev_beta = beta;
    }
}

fn png_bytes(img: &Gray) -> Vec<u8> {
    use image::ImageEncoder;
    let mut out = Vec::new();
    image::codecs::png::PngEncoder::new(&mut out)
        .write_image(
            &img.data,
            img.width,
            img.height,
            image::ExtendedColorType::L8,
        )
        .unwrap();
    out
}

fn batch() -> (Vec<String>, Vec<Vec<u8>>) {
    let sharp = sharp_scene(80, 60);
    let imgs = [box_blur(&sharp, 9), sharp.clone(), box_blur(&sharp, 3)];
    let names = vec!["blur9.png".into(), "sharp.png".into(), "blur3.png".into()];
    (names, imgs.iter().map(png_bytes).collect())
}

#[test]
fn score_images_ranks_and_summarises() {
    let (names, files) = batch();
    let params = BlurParams {
        laplacian_threshold: 1.0,
        beta_threshold: 1.0,
        rule: BlurRule::Laplacian,
        ..BlurParams::default()
    };
    let r = score_images(
        &names,
        |i| Ok(files[i].clone()),
        &params,
        &ImageLimits::default(),
        &NoProgress,
    )
    .unwrap();
    assert_eq!(r.ranking, vec!["sharp.png", "blur3.png", "blur9.png"]);
    let ranks: Vec<usize> = r.images.iter().map(|s| s.rank).collect();
    assert_eq!(ranks, vec![3, 1, 2]);
    assert_eq!(r.images[0].name, "blur9.png");
    assert_eq!(r.summary.count, 3);
    assert_eq!(r.summary.blurred_count, 0);
    assert_eq!(r.summary.laplacian.median, r.images[2].laplacian_variance);

    // Threshold between the sharp image and the blurred ones.
    let cut = 0.5 * (r.images[1].laplacian_variance + r.images[2].laplacian_variance);
    let params = BlurParams {
        laplacian_threshold: cut,
        ..params
    };
    let r2 = score_images(
        &names,
        |i| Ok(files[i].clone()),
        &params,
        &ImageLimits::default(),
        &NoProgress,
    )
    .unwrap();
    let blurred: Vec<bool> = r2.images.iter().map(|s| s.blurred).collect();
    assert_eq!(blurred, vec![true, false, true]);

    let svg = render_svg(&r2, &params);
    assert!(svg.starts_with("<svg") && svg.contains("circle"), "{svg}");
    assert_eq!(svg.matches("<circle").count(), 3);
}

#[test]
fn score_images_names_bad_file() {
    let (names, mut files) = batch();
    files[2].truncate(40);
    let e = score_images(
        &names,
        |i| Ok(files[i].clone()),
        &BlurParams::default(),
        &ImageLimits::default(),
        &NoProgress,
    )
    .unwrap_err();
    match e {
        CoreError::InvalidInput(m) => assert!(m.contains("blur3.png"), "{m}"),
        other => panic!("{other:?}"),
    }
}

struct CancelAfter {
    reports: AtomicU64,
    canceled: AtomicBool,
}
impl Progress for CancelAfter {
    fn report(&self, _step: &str, done: u64, _total: u64) {
        self.reports.fetch_add(1, Ordering::SeqCst);
        if done >= 1 {
            self.canceled.store(true, Ordering::SeqCst);
        }
    }
    fn is_canceled(&self) -> bool {
        self.canceled.load(Ordering::SeqCst)
    }
}

#[test]
fn cancel_returns_canceled() {
    let (_, files) = batch();
    let names: Vec<String> = (0..30).map(|i| format!("{i}.png")).collect();
    let p = CancelAfter {
        reports: AtomicU64::new(0),
        canceled: AtomicBool::new(false),
    };
    let loads = AtomicU64::new(0);
    let e = score_images(
        &names,
        |i| {
            loads.fetch_add(1, Ordering::SeqCst);
            Ok(files[i % 3].clone())
        },
        &BlurParams::default(),
        &ImageLimits::default(),
        &p,
    )
    .unwrap_err();
    assert!(matches!(e, CoreError::Canceled));
    assert!(loads.load(Ordering::SeqCst) < 30);

    let pre = CancelAfter {
        reports: AtomicU64::new(0),
        canceled: AtomicBool::new(true),
    };
    let e = score_images(
        &names,
        |_| panic!("must not load after cancel"),
        &BlurParams::default(),
        &ImageLimits::default(),
        &pre,
    )
    .unwrap_err();
    assert!(matches!(e, CoreError::Canceled));
}

#[test]
fn params_validate_and_deserialize() {
    assert!(BlurParams::default().validate().is_ok());
    let bad = BlurParams {
        k: 0,
        ..BlurParams::default()
    };
    assert!(matches!(bad.validate(), Err(CoreError::InvalidParam { field, .. }) if field == "k"));
    let bad = BlurParams {
        beta_threshold: 1.5,
        ..BlurParams::default()
    };
    assert!(
        matches!(bad.validate(), Err(CoreError::InvalidParam { field, .. }) if field == "beta_threshold")
    );
    let p: BlurParams = serde_json::from_str(r#"{"k": 5, "rule": "both"}"#).unwrap();
    assert_eq!((p.k, p.rule, p.beta_threshold), (5, BlurRule::Both, 0.6));
    assert!(serde_json::from_str::<BlurParams>(r#"{"kk": 5}"#).is_err());
}

/// Issue D1: a threshold of 1e308 doubled the plot's axis bound to infinity and the chart
/// never finished. Validation refuses it now, and the chart stays finite even when asked.
#[test]
fn extreme_thresholds_are_refused_and_never_hang_the_plot() {
    for t in [1e308, f64::MAX, 1e10, f64::INFINITY, f64::NAN, -1.0] {
        let p = BlurParams {
            laplacian_threshold: t,
            ..BlurParams::default()
        };
        assert!(p.validate().is_err(), "{t} accepted");
    }
    assert!(
        BlurParams {
            laplacian_threshold: MAX_LAPLACIAN_THRESHOLD,
            ..BlurParams::default()
        }
        .validate()
        .is_ok()
    );
    let (names, files) = batch();
    let mut r = score_images(
        &names,
        |i| Ok(files[i].clone()),
        &BlurParams::default(),
        &ImageLimits::default(),
        &NoProgress,
    )
    .unwrap();
    r.images[0].laplacian_variance = f64::MAX;
    r.images[1].laplacian_variance = f64::NAN;
    for t in [1e308, f64::MAX, f64::INFINITY, 0.0] {
        let params = BlurParams {
            laplacian_threshold: t,
            ..BlurParams::default()
        };
        let svg = render_svg(&r, &params);
        assert!(svg.starts_with("<svg"), "{t}: {svg}");
        assert_eq!(svg.matches("<circle").count(), 3);
    }
}

/// Issue D7: β's cost is cubic in the short side, so large frames are box-reduced first. A
/// frame made of constant 2×2 blocks reduces to exactly the frame of its block values.
#[test]
fn beta_of_a_large_frame_is_that_of_its_box_reduction() {
    assert_eq!(reduction_factor(3840, 2160), 1);
    assert_eq!(reduction_factor(5000, 5000), 3);
    assert_eq!(reduction_factor(16_384, 16_384), 8);
    let (sw, sh) = (1160u32, 1153u32);
    let small: Vec<u8> = (0..sw * sh)
        .map(|i| {
            let (x, y) = (i % sw, i / sw);
            ((x * 7 + y * 13 + (x * y) % 31) % 256) as u8
        })
        .collect();
    let (bw, bh) = (sw * 2, sh * 2);
    let big: Vec<u8> = (0..bw * bh)
        .map(|i| small[((i / bw / 2) * sw + (i % bw) / 2) as usize])
        .collect();
    assert!(bw.min(bh) as usize > MAX_BETA_SIDE);
    let small = Gray::new(sw, sh, small).unwrap();
    let big = Gray::new(bw, bh, big).unwrap();
    let (a, b) = (svd_beta(&small, 10).unwrap(), svd_beta(&big, 10).unwrap());
    assert!((a - b).abs() < 1e-9, "{a} vs {b}");
}
