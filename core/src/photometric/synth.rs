//! Deterministic synthetic data for tests and demos: bracketed stacks, flat fields and an
//! auto-exposure video of a moving textured plane, all rendered with the full image formation
//! `O = round(max · f(clip(e · V(r) · L + n, 0, 1)))` with signal-dependent noise
//! `σ = √(shot · I + read²)`.

use super::PhotoImage;
use super::response::{ResponseModel, interp_table};
use super::vignette::VignetteModel;

/// SplitMix64 (Steele, Lea & Flood, OOPSLA 2014): a tiny deterministic generator.
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    /// Generator from a seed.
    pub fn new(seed: u64) -> Self {
        Self(seed ^ 0x5DEE_CE66_D1A4_F87B)
    }

    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in (0, 1].
    pub fn uniform(&mut self) -> f64 {
        ((self.next_u64() >> 11) as f64 + 1.0) / (1u64 << 53) as f64
    }

    /// Standard normal (Box-Muller, one of the pair).
    pub fn normal(&mut self) -> f64 {
        let r = (-2.0 * self.uniform().ln()).sqrt();
        r * (std::f64::consts::TAU * self.uniform()).cos()
    }
}

/// Camera and noise of a synthetic sequence.
#[derive(Debug, Clone)]
pub struct SynthCamera {
    /// Image width.
    pub width: usize,
    /// Image height.
    pub height: usize,
    /// Response `f`.
    pub response: ResponseModel,
    /// Vignetting coefficients (centred model, `r = 1` at the corners).
    pub vignette: [f64; 3],
    /// Shot-noise factor (variance per unit irradiance).
    pub shot: f64,
    /// Read-noise standard deviation (irradiance units).
    pub read: f64,
    /// 16-bit output instead of 8-bit.
    pub sixteen_bit: bool,
    /// Seed of texture and noise.
    pub seed: u64,
}

impl SynthCamera {
    /// The shared data's camera (EMoR c = (3, −0.8, 0.2, −0.05), V = 1 − 0.35r² + 0.1r⁴ −
    /// 0.1r⁶, noise 2e-4 / 1.5e-3) at the given size.
    pub fn reference(width: usize, height: usize, seed: u64) -> Self {
        Self {
            width,
            height,
            response: ResponseModel::Emor {
                c: [3.0, -0.8, 0.2, -0.05],
            },
            vignette: [-0.35, 0.1, -0.1],
            shot: 2e-4,
            read: 1.5e-3,
            sixteen_bit: false,
            seed,
        }
    }

    /// The vignetting model.
    pub fn vignette_model(&self) -> VignetteModel {
        VignetteModel::centered(self.width, self.height, self.vignette)
    }

    fn max_level(&self) -> u16 {
        if self.sixteen_bit { u16::MAX } else { 255 }
    }

    /// Form an image from an irradiance function (before vignetting, exposure included).
    fn form(&self, rng: &mut Rng, irr: impl Fn(f64, f64) -> f64) -> PhotoImage {
        let fwd = self.response.forward_table();
        let vm = self.vignette_model();
        let max = f64::from(self.max_level());
        let mut data = Vec::with_capacity(self.width * self.height);
        for y in 0..self.height {
            for x in 0..self.width {
                let (xf, yf) = (x as f64, y as f64);
                let e = irr(xf, yf) * vm.eval(xf, yf);
                let sigma = (self.shot * e.max(0.0) + self.read * self.read).sqrt();
                let e = (e + sigma * rng.normal()).clamp(0.0, 1.0);
                data.push((interp_table(&fwd, e) * max).round() as u16);
            }
        }
        PhotoImage {
            width: self.width,
            height: self.height,
            max_level: self.max_level(),
            data,
        }
    }
}

const TEX_MIN_WAVELENGTH: f64 = 16.0;

/// A smooth random radiance texture on the plane: a sum of sinusoids (wavelengths 8–80 units)
/// plus a large-scale brightness field, mapped to `mid · 2^(stops · (s − ½))`.
#[derive(Debug, Clone)]
pub struct Texture {
    waves: Vec<[f64; 4]>,
    mid: f64,
    stops: f64,
}

impl Texture {
    /// A texture spanning `stops` stops around `mid`.
    pub fn new(seed: u64, mid: f64, stops: f64) -> Self {
        let mut rng = Rng::new(seed.wrapping_mul(31).wrapping_add(7));
        let mut waves = Vec::new();
        for i in 0..24 {
            let lambda = if i < 4 {
                300.0 + 300.0 * rng.uniform()
            } else {
                TEX_MIN_WAVELENGTH + 50.0 * rng.uniform()
            };
            let th = std::f64::consts::TAU * rng.uniform();
            let k = std::f64::consts::TAU / lambda;
            let amp = if i < 4 { 3.0 } else { 1.0 };
            waves.push([
                k * th.cos(),
                k * th.sin(),
                std::f64::consts::TAU * rng.uniform(),
                amp,
            ]);
        }
        Self { waves, mid, stops }
    }

    /// Radiance at world point `(u, v)`.
    pub fn radiance(&self, u: f64, v: f64) -> f64 {
        let norm: f64 = self.waves.iter().map(|w| w[3] * w[3]).sum::<f64>().sqrt();
        let s: f64 = self
            .waves
            .iter()
            .map(|w| w[3] * (w[0] * u + w[1] * v + w[2]).sin())
            .sum::<f64>()
            / norm;
        // s is roughly N(0, 1/2); squash to (0, 1).
        let q = 0.5 + 0.5 * (1.2 * s).tanh();
        self.mid * (self.stops * (q - 0.5)).exp2()
    }
}

/// A bracketed stack of a static textured scene: one image per exposure factor (the texture
/// has mid irradiance 0.25 at exposure 1, 6 stops of contrast).
pub fn render_bracket(cam: &SynthCamera, exposures: &[f64]) -> Vec<PhotoImage> {
    let tex = Texture::new(cam.seed, 0.25, 6.0);
    let mut rng = Rng::new(cam.seed ^ 0xB7AC);
    exposures
        .iter()
        .map(|&e| cam.form(&mut rng, |x, y| e * tex.radiance(x, y)))
        .collect()
}

/// Flat fields: a uniform target at the given irradiance levels (before vignetting).
pub fn render_flats(cam: &SynthCamera, levels: &[f64]) -> Vec<PhotoImage> {
    let mut rng = Rng::new(cam.seed ^ 0xF1A7);
    levels
        .iter()
        .map(|&l| cam.form(&mut rng, |_, _| l))
        .collect()
}

/// Exposure of the first frame of [`render_ae_sequence`], near the controller's steady state.
const E_START: f64 = 10.0;

/// An auto-exposure video and its ground truth.
#[derive(Debug, Clone)]
pub struct AeSequence {
    /// Frames.
    pub frames: Vec<PhotoImage>,
    /// True exposure of each frame relative to frame 0.
    pub exposures: Vec<f64>,
    /// Timestamps in seconds (20 fps).
    pub timestamps: Vec<f64>,
}

/// A camera gliding over a textured plane (translation ~2 px/frame, slow rotation and zoom)
/// with a proportional auto-exposure controller aiming at mid grey, plus a 5 % exposure
/// flicker, like the shared `ae_seq_seed0` data.
pub fn render_ae_sequence(cam: &SynthCamera, frames: usize) -> AeSequence {
    let tex = Texture::new(cam.seed, 0.0625, 7.0);
    let mut rng = Rng::new(cam.seed ^ 0xAE5E);
    let (cx, cy) = (cam.width as f64 / 2.0, cam.height as f64 / 2.0);
    let mut e = E_START;
    let mut out = AeSequence {
        frames: Vec::with_capacity(frames),
        exposures: Vec::with_capacity(frames),
        timestamps: Vec::with_capacity(frames),
    };
    for k in 0..frames {
        let t = k as f64;
        let (tx, ty) = (200.0 + 2.0 * t, 300.0 + 25.0 * (0.02 * t).sin());
        let th = 0.15 * (0.013 * t).sin();
        let sc = 1.0 + 0.15 * (0.017 * t).sin();
        let (c, s) = (th.cos() * sc, th.sin() * sc);
        let img = cam.form(&mut rng, |x, y| {
            let (px, py) = (x - cx, y - cy);
            e * tex.radiance(c * px - s * py + tx, s * px + c * py + ty)
        });
        // Auto exposure on the mean of the frame just taken.
        let mean = img.data.iter().map(|&v| f64::from(v)).sum::<f64>()
            / (img.data.len() as f64 * f64::from(img.max_level));
        out.frames.push(img);
        out.exposures.push(e / E_START);
        out.timestamps.push(t / 20.0);
        let target = 0.43;
        let ratio = (target / mean.max(1e-3)).powf(0.6);
        e = (e * ratio * (1.0 + 0.05 * rng.normal())).clamp(0.05, 40.0);
    }
    out
}
