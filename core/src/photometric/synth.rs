//! Deterministic synthetic data for tests and demos: bracketed stacks, flat fields and an
//! auto-exposure video of a moving textured plane, all rendered with the full image formation
//! `O = round(max · f(clip(e · V(r) · L + n, 0, 1)))` with signal-dependent noise
//! `σ = √(shot · I + read²)`.

use super::PhotoImage;
use super::response::{ResponseModel, interp_table};
use super::vignette::VignetteModel;

mod laws;
mod scenes;
pub use laws::VignetteForm;
use scenes::{DeadLeaves, blocks, patches};

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
        let vm = self.vignette_model();
        self.form_with(rng, irr, |x, y| vm.eval(x, y))
    }

    /// [`Self::form`] with any vignetting function of the pixel position.
    fn form_with(
        &self,
        rng: &mut Rng,
        irr: impl Fn(f64, f64) -> f64,
        vig: impl Fn(f64, f64) -> f64,
    ) -> PhotoImage {
        self.form_from(rng, |x, y| irr(x as f64, y as f64), vig)
    }

    /// [`Self::form_with`] through a lens that blurs the irradiance by a Gaussian of `sigma`
    /// pixels ([`super::synth_lens::blurred_irradiance`]); 0 is [`Self::form_with`].
    fn form_blurred(
        &self,
        rng: &mut Rng,
        irr: impl Fn(f64, f64) -> f64,
        vig: impl Fn(f64, f64) -> f64,
        sigma: f64,
    ) -> PhotoImage {
        if sigma <= 0.0 {
            return self.form_with(rng, irr, vig);
        }
        let e = super::synth_lens::blurred_irradiance(self.width, self.height, sigma, irr);
        self.form_from(rng, |x, y| e[y * self.width + x], vig)
    }

    /// Response, noise and quantisation of the irradiance `irr` at pixel `(x, y)` (exposure
    /// included, before vignetting).
    fn form_from(
        &self,
        rng: &mut Rng,
        irr: impl Fn(usize, usize) -> f64,
        vig: impl Fn(f64, f64) -> f64,
    ) -> PhotoImage {
        let fwd = self.response.forward_table();
        let max = f64::from(self.max_level());
        let mut data = Vec::with_capacity(self.width * self.height);
        for y in 0..self.height {
            for x in 0..self.width {
                let (xf, yf) = (x as f64, y as f64);
                let e = irr(x, y) * vig(xf, yf);
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
    /// True attenuation map (row after row, maximum 1 at the centre).
    pub vignette_map: Vec<f32>,
}

/// A camera gliding over a textured plane (translation ~2 px/frame, slow rotation and zoom)
/// with a proportional auto-exposure controller aiming at mid grey, plus a 5 % exposure
/// flicker, like the shared `ae_seq_seed0` data.
pub fn render_ae_sequence(cam: &SynthCamera, frames: usize) -> AeSequence {
    render_ae_video(cam, frames, &AeVideo::default())
}

/// How the exposure of [`render_ae_video`] evolves.
#[derive(Debug, Clone, PartialEq)]
pub enum ExposureProgram {
    /// Proportional controller on the mean of the previous frame: `e ← e · (target / mean)^gain`
    /// times a log-normal flicker of relative size `flicker`.
    AutoExposure {
        /// Target mean intensity (normalised).
        target: f64,
        /// Controller exponent.
        gain: f64,
        /// Relative flicker (standard deviation).
        flicker: f64,
    },
    /// Scripted: `log₂ e` follows a sine of `stops` amplitude and `period` frames, plus flicker.
    Sweep {
        /// Amplitude in stops.
        stops: f64,
        /// Period in frames.
        period: f64,
        /// Relative flicker (standard deviation).
        flicker: f64,
    },
    /// Scripted: a new exposure, uniform within `±stops` of the start, every `hold` frames.
    Steps {
        /// Half range in stops.
        stops: f64,
        /// Frames per step.
        hold: usize,
    },
    /// Scripted: `log₂ e` takes a Gaussian step of `step` stops per frame, reflected at
    /// `±stops` from the start (a manual exposure drifting without regard to the scene).
    Walk {
        /// Half range in stops.
        stops: f64,
        /// Standard deviation of a frame's step, in stops.
        step: f64,
    },
}

/// The scene's radiance pattern.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SceneForm {
    /// Smooth sum of sinusoids ([`Texture`]).
    Waves,
    /// Soft-edged Voronoi patches of random radiance: flat regions with corners, unlike the
    /// smooth waves.
    Patches,
    /// A Mondrian of axis-aligned blocks (bands of random height offsets, cells of random
    /// width per band): flat regions with straight edges and T-junctions.
    Blocks,
    /// Dead leaves: overlapping discs of random radiance with power-law radii (4–32 units),
    /// the occlusion model of natural scenes (G. Matheron 1968; A. B. Lee, D. Mumford,
    /// J. Huang, "Occlusion models for natural images", IJCV 2001): curved edges at every
    /// scale, unlike the other three.
    Discs,
}

/// Scene, exposure program and vignetting of an AE video.
#[derive(Debug, Clone, PartialEq)]
pub struct AeVideo {
    /// Exposure program.
    pub program: ExposureProgram,
    /// Scene pattern.
    pub scene: SceneForm,
    /// Mid radiance at the start exposure divided by `E_START` (the scene's grey level).
    pub mid: f64,
    /// Scene contrast in stops.
    pub stops: f64,
    /// Motion speed factor (1 = ~2 px/frame).
    pub speed: f64,
    /// Vignetting law.
    pub vignette: VignetteForm,
    /// Offset of the optical (vignetting) centre from the image centre, pixels: real lenses
    /// are rarely centred on the sensor (the online fit may estimate it).
    pub vignette_shift: [f64; 2],
    /// Factor on the amplitude of the slow rotation and zoom (1 = the default motion); more
    /// rotation and zoom is what makes the vignetting centre observable.
    pub turn: f64,
    /// Standard deviation in pixels of a Gaussian lens blur on the irradiance (before the
    /// response), with each pixel integrating its area; 0 point-samples the scene at the pixel
    /// centres (sharp, as every split rendered before 2026-12-06). Real cameras are soft at the
    /// pixel scale, and the tracker's patches then see less structure.
    pub optics_blur: f64,
}

impl Default for AeVideo {
    /// The shared `ae_seq_seed0`-like video.
    fn default() -> Self {
        Self {
            program: ExposureProgram::AutoExposure {
                target: 0.43,
                gain: 0.6,
                flicker: 0.05,
            },
            scene: SceneForm::Waves,
            mid: 0.0625,
            stops: 7.0,
            speed: 1.0,
            vignette: VignetteForm::Polynomial,
            vignette_shift: [0.0; 2],
            turn: 1.0,
            optics_blur: 0.0,
        }
    }
}

/// Fraction of the pixels of `frames` within two levels of full scale (clipped): how
/// saturated a rendered video is.
pub fn clipped_fraction(frames: &[PhotoImage]) -> f64 {
    let clipped: usize = frames
        .iter()
        .map(|f| f.data.iter().filter(|&&v| v >= f.max_level - 2).count())
        .sum();
    clipped as f64 / frames.iter().map(|f| f.data.len()).sum::<usize>().max(1) as f64
}

/// A video that cuts between two scenes: `frames` frames of [`SynthCamera::reference`] with
/// `seeds[0]`, then as many with `seeds[1]` (no scene point crosses the cut), default program.
pub fn render_ae_cut(
    width: usize,
    height: usize,
    seeds: [u64; 2],
    frames: usize,
) -> Vec<PhotoImage> {
    seeds
        .iter()
        .flat_map(|&seed| {
            let cam = SynthCamera::reference(width, height, seed);
            render_ae_video(&cam, frames, &AeVideo::default()).frames
        })
        .collect()
}

/// A camera gliding over a plane (translation ~2·speed px/frame, slow rotation and zoom)
/// under the given exposure program, scene and vignetting law.
pub fn render_ae_video(cam: &SynthCamera, frames: usize, video: &AeVideo) -> AeSequence {
    let (mut planes, rest) = render_planes(cam, &[(cam.response.clone(), 1.0)], 0, frames, video);
    AeSequence {
        frames: planes.pop().unwrap_or_default(),
        ..rest
    }
}

/// A colour auto-exposure video and its ground truth.
#[derive(Debug, Clone)]
pub struct AeSequenceRgb {
    /// Frames as `[R, G, B]` planes.
    pub frames: Vec<[PhotoImage; 3]>,
    /// True exposure of each frame relative to frame 0 (shared by the channels).
    pub exposures: Vec<f64>,
    /// Timestamps in seconds (20 fps).
    pub timestamps: Vec<f64>,
    /// True attenuation map (shared by the channels).
    pub vignette_map: Vec<f32>,
}

/// [`render_ae_video`] for a colour camera: one response per channel (`[R, G, B]`), the scene
/// radiance times a per-channel `gain` (a tinted scene), and exposure and vignetting shared by
/// the channels; the exposure controller meters the green plane. Noise is independent per
/// channel.
pub fn render_ae_video_rgb(
    cam: &SynthCamera,
    responses: &[ResponseModel; 3],
    gains: [f64; 3],
    frames: usize,
    video: &AeVideo,
) -> AeSequenceRgb {
    let channels: Vec<(ResponseModel, f64)> = responses.iter().cloned().zip(gains).collect();
    let (planes, rest) = render_planes(cam, &channels, 1, frames, video);
    let mut it = planes.into_iter();
    let (r, g, b) = (
        it.next().unwrap_or_default(),
        it.next().unwrap_or_default(),
        it.next().unwrap_or_default(),
    );
    AeSequenceRgb {
        frames: r
            .into_iter()
            .zip(g)
            .zip(b)
            .map(|((r, g), b)| [r, g, b])
            .collect(),
        exposures: rest.exposures,
        timestamps: rest.timestamps,
        vignette_map: rest.vignette_map,
    }
}

/// Render one plane sequence per `(response, radiance gain)` channel; the exposure controller
/// meters channel `meter`. Returns the planes and the ground truth (with empty `frames`). With
/// one channel the random streams are exactly those of the single-channel renderer.
fn render_planes(
    cam: &SynthCamera,
    channels: &[(ResponseModel, f64)],
    meter: usize,
    frames: usize,
    video: &AeVideo,
) -> (Vec<Vec<PhotoImage>>, AeSequence) {
    let tex = Texture::new(cam.seed, video.mid, video.stops);
    let mut rng = Rng::new(cam.seed ^ 0xAE5E);
    let mut prog_rng = Rng::new(cam.seed ^ 0x5EED);
    let (cx, cy) = (cam.width as f64 / 2.0, cam.height as f64 / 2.0);
    let mut vm = cam.vignette_model();
    vm.center = [cx + video.vignette_shift[0], cy + video.vignette_shift[1]];
    let cams: Vec<SynthCamera> = channels
        .iter()
        .map(|(resp, _)| SynthCamera {
            response: resp.clone(),
            ..cam.clone()
        })
        .collect();
    let vig = |x: f64, y: f64| video.vignette.eval(&vm, x, y);
    let vignette_map: Vec<f32> = (0..cam.height)
        .flat_map(|y| (0..cam.width).map(move |x| (x as f64, y as f64)))
        .map(|(x, y)| vig(x, y) as f32)
        .collect();
    let leaves = DeadLeaves::new(cam.seed);
    let radiance = |u: f64, v: f64| match video.scene {
        SceneForm::Waves => tex.radiance(u, v),
        SceneForm::Patches => video.mid * (video.stops * (patches(cam.seed, u, v) - 0.5)).exp2(),
        SceneForm::Blocks => video.mid * (video.stops * (blocks(cam.seed, u, v) - 0.5)).exp2(),
        SceneForm::Discs => video.mid * (video.stops * (leaves.at(u, v) - 0.5)).exp2(),
    };
    let mut e = E_START;
    let mut out = AeSequence {
        frames: Vec::new(),
        exposures: Vec::with_capacity(frames),
        timestamps: Vec::with_capacity(frames),
        vignette_map,
    };
    let mut planes: Vec<Vec<PhotoImage>> = vec![Vec::with_capacity(frames); channels.len()];
    for k in 0..frames {
        let t = k as f64;
        let (tx, ty) = (
            200.0 + 2.0 * video.speed * t,
            300.0 + 25.0 * (0.02 * video.speed * t).sin(),
        );
        let th = 0.15 * video.turn * (0.013 * t).sin();
        let sc = 1.0 + 0.15 * video.turn * (0.017 * t).sin();
        let (c, s) = (th.cos() * sc, th.sin() * sc);
        let mut mean = 0.5;
        for (ch, ((_, gain), ccam)) in channels.iter().zip(&cams).enumerate() {
            let img = ccam.form_blurred(
                &mut rng,
                |x, y| {
                    let (px, py) = (x - cx, y - cy);
                    e * gain * radiance(c * px - s * py + tx, s * px + c * py + ty)
                },
                vig,
                video.optics_blur,
            );
            if ch == meter {
                mean = img.data.iter().map(|&v| f64::from(v)).sum::<f64>()
                    / (img.data.len() as f64 * f64::from(img.max_level));
            }
            planes[ch].push(img);
        }
        out.exposures.push(e / E_START);
        out.timestamps.push(t / 20.0);
        e = match &video.program {
            ExposureProgram::AutoExposure {
                target,
                gain,
                flicker,
            } => {
                let ratio = (target / mean.max(1e-3)).powf(*gain);
                (e * ratio * (1.0 + flicker * rng.normal())).clamp(0.05, 40.0)
            }
            ExposureProgram::Sweep {
                stops,
                period,
                flicker,
            } => {
                let phase = std::f64::consts::TAU * (t + 1.0) / period.max(2.0);
                E_START
                    * (stops * phase.sin()).exp2()
                    * (1.0 + flicker * prog_rng.normal()).max(0.5)
            }
            ExposureProgram::Steps { stops, hold } => {
                if (k + 1) % (*hold).max(1) == 0 {
                    E_START * (stops * (2.0 * prog_rng.uniform() - 1.0)).exp2()
                } else {
                    e
                }
            }
            ExposureProgram::Walk { stops, step } => {
                let mut l = (e / E_START).log2() + step * prog_rng.normal();
                if l > *stops {
                    l = 2.0 * stops - l;
                }
                if l < -stops {
                    l = -2.0 * stops - l;
                }
                E_START * l.clamp(-stops, *stops).exp2()
            }
        };
    }
    (planes, out)
}
