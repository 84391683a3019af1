//! Deconvolution vs the scikit-image peer (`shared/peers/deconv_skimage.py`): PSNR of Wiener,
//! Richardson-Lucy (30 and 60 iterations) and TV with the true kernel, blind error ratios, and
//! 1920×1080 timings.
//!
//! `cargo bench -p caliper-core --bench deconv_vs_skimage`
//! Env: `CALIPER_PYTHON` (the peer's interpreter, default `python3`),
//! `CALIPER_DECONV_DATA` (default `<workspace>/../shared/data/blur/skimage`),
//! `CALIPER_BENCH_NO_PEER=1` (skip the peer), `CALIPER_BENCH_IMAGES` (comma-separated file stems,
//! default `camera,astronaut,coffee,chelsea`), `CALIPER_BENCH_TIMING_ONLY=1` (only the 1920×1080
//! timings, skipping the quality set), `CALIPER_BENCH_ONLY` (comma-separated subset of
//! `wiener,rl,tv,blind,timing`; the others print NaN), `CALIPER_BENCH_CROP=native` (centre
//! crops at the photos' own resolution instead of the photo shrunk to the crop size). The
//! benchmark set is built deterministically in
//! this run; the recipe is in `core/benches/deconv_set.md`.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use caliper_core::NoProgress;
use caliper_core::deconv::{
    BlindParams, Plane, Psf, TvParams, blind_deconv, error_ratio_aligned, psnr, resize,
    richardson_lucy, tv_deconv, wiener,
};

mod common;
use common::{median, timed};

/// Side of the benchmark crops (Levin et al. 2009 use 255×255).
const SIDE: usize = 255;
/// Extra context around a crop so that the blur near its border sees real pixels ('valid' blur).
const CONTEXT: usize = 16;
/// Noise σ on the [0, 1] scale.
const NOISE: f64 = 0.01;

fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// Deterministic xorshift64* generator with Box-Muller normals (no rand dependency).
struct Rng(u64);

impl Rng {
    fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let v = self.0.wrapping_mul(0x2545_f491_4f6c_dd1d);
        ((v >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }

    fn normal(&mut self) -> f64 {
        let (a, b) = (self.uniform(), self.uniform());
        (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
    }
}

/// Grey image in [0, 1] (Rec. 601 luma for colour).
fn load_luma(path: &Path) -> Option<(usize, usize, Vec<f64>)> {
    let img = image::open(path).ok()?.to_luma16();
    let (w, h) = (img.width() as usize, img.height() as usize);
    Some((
        w,
        h,
        img.as_raw()
            .iter()
            .map(|&v| f64::from(v) / 65535.0)
            .collect(),
    ))
}

/// Camera-shake kernel from a random walk with inertia (in the spirit of Boracchi & Foi,
/// "Modeling the performance of image restoration from motion blur", IEEE TIP 2012): the
/// velocity turns by a random angle each step and the speed drifts, the path is scaled so its
/// larger extent is `extent` px, then splatted bilinearly with 40 samples per px of path.
fn shake_kernel(seed: u64, extent: f64) -> Psf {
    let mut rng = Rng(seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1);
    for _ in 0..8 {
        rng.uniform();
    }
    let steps = 64;
    let mut heading = rng.uniform() * std::f64::consts::TAU;
    let mut turn = 0.0;
    let mut speed = 1.0;
    let mut pts = vec![(0.0f64, 0.0f64)];
    for _ in 0..steps {
        turn = 0.7 * turn + 0.35 * rng.normal();
        heading += turn;
        speed = (speed + 0.3 * rng.normal()).clamp(0.2, 2.0);
        let (x, y) = pts[pts.len() - 1];
        pts.push((x + speed * heading.cos(), y + speed * heading.sin()));
    }
    let (minx, maxx) = pts
        .iter()
        .fold((f64::MAX, f64::MIN), |a, p| (a.0.min(p.0), a.1.max(p.0)));
    let (miny, maxy) = pts
        .iter()
        .fold((f64::MAX, f64::MIN), |a, p| (a.0.min(p.1), a.1.max(p.1)));
    let s = (extent - 1.0) / (maxx - minx).max(maxy - miny);
    let size = (extent.ceil() as usize) | 1;
    let size = size + 2;
    let (ox, oy) = (
        (size as f64 - 1.0 - (maxx - minx) * s) / 2.0,
        (size as f64 - 1.0 - (maxy - miny) * s) / 2.0,
    );
    let mut k = vec![0.0; size * size];
    for seg in pts.windows(2) {
        let (a, b) = (seg[0], seg[1]);
        let len = ((b.0 - a.0).powi(2) + (b.1 - a.1).powi(2)).sqrt() * s;
        let n = (len * 40.0).ceil().max(1.0) as usize;
        for i in 0..n {
            let t = (i as f64 + 0.5) / n as f64;
            let x = ox + (a.0 + t * (b.0 - a.0) - minx) * s;
            let y = oy + (a.1 + t * (b.1 - a.1) - miny) * s;
            let (x0, y0) = (x.floor(), y.floor());
            let (fx, fy) = (x - x0, y - y0);
            let (x0, y0) = (x0 as usize, y0 as usize);
            let w = len / n as f64;
            k[y0 * size + x0] += w * (1.0 - fx) * (1.0 - fy);
            k[y0 * size + x0 + 1] += w * fx * (1.0 - fy);
            k[(y0 + 1) * size + x0] += w * (1.0 - fx) * fy;
            k[(y0 + 1) * size + x0 + 1] += w * fx * fy;
        }
    }
    Psf::from_weights(size, size, k).expect("kernel")
}

/// The benchmark kernels: four camera-shake paths and four linear motions, 13–27 px.
fn kernels() -> Vec<(String, Psf)> {
    let mut out = Vec::new();
    for (i, extent) in [13.0, 17.0, 21.0, 27.0].into_iter().enumerate() {
        out.push((
            format!("shake{}_{extent}", i + 1),
            shake_kernel(i as u64 + 1, extent),
        ));
    }
    for (len, ang) in [(13.0, 20.0), (17.0, 75.0), (21.0, 135.0), (27.0, 0.0)] {
        out.push((
            format!("line{len}_{ang}"),
            Psf::motion(len, ang).expect("motion"),
        ));
    }
    out
}

struct Case {
    name: String,
    sharp: Plane,
    blurred: Plane,
    psf: Psf,
}

/// Sharp crop: shorter side scaled to SIDE + 2·CONTEXT, centre square; blurred: 'valid'
/// convolution of that square, centre SIDE×SIDE, + N(0, σ²), clipped and quantised to 8 bits.
fn make_case(
    name: &str,
    img: &(usize, usize, Vec<f64>),
    psf: &Psf,
    seed: u64,
    native: bool,
) -> Case {
    let (w, h, data) = img;
    let big = SIDE + 2 * CONTEXT;
    // Native: a centre crop at the photo's own resolution (Levin et al.'s 255×255 crops).
    let f = if native {
        1.0
    } else {
        big as f64 / (*w).min(*h) as f64
    };
    let (nw, nh) = (
        ((*w as f64 * f).round() as usize).max(big),
        ((*h as f64 * f).round() as usize).max(big),
    );
    let scaled = resize(data, *w, *h, nw, nh);
    let (x0, y0) = ((nw - big) / 2, (nh - big) / 2);
    let at = |x: usize, y: usize| scaled[(y0 + y) * nw + x0 + x];
    let mut rng = Rng(seed);
    let (cx, cy) = (psf.width / 2, psf.height / 2);
    let mut sharp = Vec::with_capacity(SIDE * SIDE);
    let mut blurred = Vec::with_capacity(SIDE * SIDE);
    for y in CONTEXT..CONTEXT + SIDE {
        for x in CONTEXT..CONTEXT + SIDE {
            sharp.push(((at(x, y) * 255.0).round() / 255.0) as f32);
            let mut acc = 0.0;
            for ky in 0..psf.height {
                for kx in 0..psf.width {
                    let k = psf.at(kx, ky);
                    if k > 0.0 {
                        acc += k * at(x + cx - kx, y + cy - ky);
                    }
                }
            }
            let v = (acc + NOISE * rng.normal()).clamp(0.0, 1.0);
            blurred.push(((v * 255.0).round() / 255.0) as f32);
        }
    }
    Case {
        name: name.to_string(),
        sharp: Plane::new(SIDE, SIDE, sharp).expect("plane"),
        blurred: Plane::new(SIDE, SIDE, blurred).expect("plane"),
        psf: psf.clone(),
    }
}

fn save_png(p: &Plane, path: &Path) {
    let g = p.to_gray();
    image::GrayImage::from_raw(g.width, g.height, g.data)
        .expect("buffer")
        .save(path)
        .expect("write png");
}

/// Runs the peer; returns (PSNR dB, deconvolve ms).
fn peer(
    blurred: &Path,
    psf: &Path,
    sharp: Option<&Path>,
    method: &str,
    iters: usize,
    pad: usize,
    runs: usize,
) -> Option<(f64, f64)> {
    let script = workspace_root().join("../shared/peers/deconv_skimage.py");
    let mut cmd = Command::new(common::python());
    cmd.arg(&script)
        .arg("--blurred")
        .arg(blurred)
        .arg("--psf")
        .arg(psf)
        .args(["--method", method, "--iters", &iters.to_string()])
        .args(["--pad", &pad.to_string(), "--runs", &runs.to_string()]);
    if let Some(s) = sharp {
        cmd.arg("--sharp").arg(s);
    }
    let out = cmd.output().ok()?;
    if !out.status.success() {
        eprintln!("peer failed: {}", String::from_utf8_lossy(&out.stderr));
        return None;
    }
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).ok()?;
    let p = v["metrics"]["restored"]["psnr_db"]
        .as_f64()
        .unwrap_or(f64::NAN);
    let t = v["timings"]["deconvolve_ms"].as_f64()?;
    Some((p, t))
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len().max(1) as f64
}

fn main() {
    let dir = std::env::var("CALIPER_DECONV_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|_| workspace_root().join("../shared/data/blur/skimage"));
    if !dir.is_dir() {
        println!(
            "SKIPPED: benchmark images not found at {} (set CALIPER_DECONV_DATA)",
            dir.display()
        );
        return;
    }
    let use_peer = std::env::var("CALIPER_BENCH_NO_PEER").as_deref() != Ok("1");
    let stems = std::env::var("CALIPER_BENCH_IMAGES")
        .unwrap_or_else(|_| "camera,astronaut,coffee,chelsea".to_string());
    let tmp = std::env::temp_dir().join(format!("caliper_deconv_bench_{}", std::process::id()));
    std::fs::create_dir_all(&tmp).expect("temp dir");
    let timing_only = std::env::var("CALIPER_BENCH_TIMING_ONLY").as_deref() == Ok("1");
    if timing_only {
        timing_1080(&dir, &tmp, use_peer);
        let _ = std::fs::remove_dir_all(&tmp);
        return;
    }
    let only = std::env::var("CALIPER_BENCH_ONLY").ok();
    let want = |m: &str| {
        only.as_deref()
            .is_none_or(|o| o.split(',').any(|x| x.trim() == m))
    };
    let native = std::env::var("CALIPER_BENCH_CROP").as_deref() == Ok("native");
    let ks = kernels();
    let mut cases = Vec::new();
    for (ii, stem) in stems.split(',').enumerate() {
        let path = dir.join(format!("{stem}.png"));
        let Some(img) = load_luma(&path) else {
            println!("SKIPPED image {} (missing or unreadable)", path.display());
            continue;
        };
        for (ki, (kname, psf)) in ks.iter().enumerate() {
            let seed = 1000 + (ii * 100 + ki) as u64;
            cases.push(make_case(
                &format!("{stem}/{kname}"),
                &img,
                psf,
                seed,
                native,
            ));
        }
    }
    if cases.is_empty() {
        println!("SKIPPED: no benchmark images");
        return;
    }
    println!(
        "{} cases ({} images × {} kernels), {SIDE}×{SIDE} {}, noise σ {NOISE}, peer: {}",
        cases.len(),
        cases.len() / ks.len(),
        ks.len(),
        if native {
            "native-resolution crops"
        } else {
            "downscaled photos"
        },
        if use_peer { "yes" } else { "no" }
    );
    println!(
        "{:<24} {:>6} | {:>6} {:>6} | {:>6} {:>6} | {:>6} {:>6} | {:>6} | {:>7} {:>6}",
        "case", "blur", "wien", "sk", "rl30", "sk", "rl60", "sk", "tv", "blindER", "s"
    );
    let mut rows: Vec<[f64; 12]> = Vec::new();
    for (ci, c) in cases.iter().enumerate() {
        let p = |x: &Plane| psnr(x, &c.sharp, 1.0).expect("psnr");
        let before = p(&c.blurred);
        let nan = f64::NAN;
        let w = if want("wiener") {
            p(&wiener(&c.blurred, &c.psf, None).expect("wiener"))
        } else {
            nan
        };
        let (r30, r60) = if want("rl") {
            (
                p(&richardson_lucy(&c.blurred, &c.psf, 30, &NoProgress).expect("rl")),
                p(&richardson_lucy(&c.blurred, &c.psf, 60, &NoProgress).expect("rl")),
            )
        } else {
            (nan, nan)
        };
        let (tv, er, bt) = if want("tv") || want("blind") {
            let tv_img =
                tv_deconv(&c.blurred, &c.psf, &TvParams::default(), &NoProgress).expect("tv");
            let (er, bt) = if want("blind") {
                let t0 = Instant::now();
                let blind =
                    blind_deconv(&c.blurred, &BlindParams::default(), &NoProgress).expect("blind");
                let bt = t0.elapsed().as_secs_f64();
                let er =
                    error_ratio_aligned(&c.sharp, &blind.image, &tv_img, 20, 6).expect("ratio");
                (er, bt)
            } else {
                (nan, nan)
            };
            (p(&tv_img), er, bt)
        } else {
            (nan, nan, nan)
        };
        let (mut sw, mut s30, mut s60) = (nan, nan, nan);
        // The peer as shipped (no padding: periodic Wiener, zero-padded RL).
        let (mut sw0, mut s300) = (nan, nan);
        if use_peer {
            let b = tmp.join(format!("b{ci}.png"));
            let s = tmp.join(format!("s{ci}.png"));
            let k = tmp.join(format!("k{ci}.txt"));
            save_png(&c.blurred, &b);
            save_png(&c.sharp, &s);
            std::fs::write(&k, c.psf.to_text()).expect("psf");
            let pad = c.psf.width;
            if want("wiener") {
                sw = peer(&b, &k, Some(&s), "wiener", 30, pad, 1).map_or(nan, |x| x.0);
                sw0 = peer(&b, &k, Some(&s), "wiener", 30, 0, 1).map_or(nan, |x| x.0);
            }
            if want("rl") {
                s30 = peer(&b, &k, Some(&s), "richardson_lucy", 30, pad, 1).map_or(nan, |x| x.0);
                s60 = peer(&b, &k, Some(&s), "richardson_lucy", 60, pad, 1).map_or(nan, |x| x.0);
                s300 = peer(&b, &k, Some(&s), "richardson_lucy", 30, 0, 1).map_or(nan, |x| x.0);
            }
        }
        println!(
            "{:<24} {before:>6.2} | {w:>6.2} {sw:>6.2} | {r30:>6.2} {s30:>6.2} | {r60:>6.2} {s60:>6.2} | {tv:>6.2} | {er:>7.2} {bt:>6.2}",
            c.name
        );
        rows.push([before, w, sw, r30, s30, r60, s60, tv, er, bt, sw0, s300]);
    }
    let col = |i: usize| rows.iter().map(|r| r[i]).collect::<Vec<_>>();
    println!(
        "{:<24} {:>6.2} | {:>6.2} {:>6.2} | {:>6.2} {:>6.2} | {:>6.2} {:>6.2} | {:>6.2} | {:>7.2} {:>6.2}",
        "mean (ER: median)",
        mean(&col(0)),
        mean(&col(1)),
        mean(&col(2)),
        mean(&col(3)),
        mean(&col(4)),
        mean(&col(5)),
        mean(&col(6)),
        mean(&col(7)),
        median(col(8)),
        mean(&col(9)),
    );
    println!(
        "skimage as shipped (no padding): wiener {:.2} dB (ours {:+.2}), RL-30 {:.2} dB (ours {:+.2}); \
         with mirror padding (columns above): wiener ours {:+.2}, RL-30 ours {:+.2}",
        mean(&col(10)),
        mean(&col(1)) - mean(&col(10)),
        mean(&col(11)),
        mean(&col(3)) - mean(&col(11)),
        mean(&col(1)) - mean(&col(2)),
        mean(&col(3)) - mean(&col(4)),
    );
    let ok = col(8).iter().filter(|&&e| e <= 3.0).count();
    println!(
        "blind: error ratio ≤ 3 on {ok}/{} ({:.0} %), worst {:.2}, max time {:.2} s",
        rows.len(),
        100.0 * ok as f64 / rows.len() as f64,
        col(8).iter().copied().fold(0.0, f64::max),
        col(9).iter().copied().fold(0.0, f64::max)
    );
    println!(
        "TV ≥ 30 dB on {}/{} cases",
        col(7).iter().filter(|&&v| v >= 30.0).count(),
        rows.len()
    );

    if want("timing") {
        timing_1080(&dir, &tmp, use_peer);
    }
    let _ = std::fs::remove_dir_all(&tmp);
}

/// 1920×1080 timings of Wiener, RL-30 and TV-80 (and the peer's Wiener and RL-30).
fn timing_1080(dir: &Path, tmp: &Path, use_peer: bool) {
    let src = load_luma(&dir.join("astronaut.png")).or_else(|| load_luma(&dir.join("camera.png")));
    if let Some((w, h, d)) = src {
        // Timing only: the content (a resized photo) does not change the work done.
        let (bw, bh) = (1920usize, 1080usize);
        let big = resize(&d, w, h, bw, bh);
        let psf = Psf::motion(15.0, 30.0).expect("motion");
        let blurred = Plane::new(bw, bh, big.iter().map(|&v| v as f32).collect()).expect("plane");
        let runs = 5;
        let (_, tw) = timed(runs, || wiener(&blurred, &psf, None).expect("wiener"));
        let (_, tr) = timed(3, || {
            richardson_lucy(&blurred, &psf, 30, &NoProgress).expect("rl")
        });
        let (_, tt) = timed(1, || {
            tv_deconv(&blurred, &psf, &TvParams::default(), &NoProgress).expect("tv")
        });
        let (mut pw, mut pr) = (f64::NAN, f64::NAN);
        if use_peer {
            let b = tmp.join("big.png");
            let k = tmp.join("big.txt");
            save_png(&blurred, &b);
            std::fs::write(&k, psf.to_text()).expect("psf");
            pw = peer(&b, &k, None, "wiener", 30, 0, 5).map_or(f64::NAN, |x| x.1);
            pr = peer(&b, &k, None, "richardson_lucy", 30, 0, 1).map_or(f64::NAN, |x| x.1);
        }
        println!(
            "1920×1080, motion 15 px: wiener {tw:.1} ms (skimage {pw:.1} ms, ×{:.1}); RL-30 {tr:.0} ms (skimage {pr:.0} ms, ×{:.1}); TV-80 {tt:.0} ms",
            pw / tw,
            pr / tr
        );
    }
}
