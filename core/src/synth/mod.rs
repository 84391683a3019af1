//! Synthetic renders of a chessboard with known parameters, for tests and benchmarks.
//!
//! [`render_chessboard`] draws a chessboard seen from a known pose `T_cam_board` through any
//! [`Camera`] by *inverse mapping*: every (sub)pixel is unprojected to a ray, the ray is
//! intersected with the board plane z = 0 and coloured by the parity of the square it hits.
//! Forward mapping (projecting the squares as polygons) would draw straight edges, which is
//! wrong under distortion; inverse mapping is exact for any central model, including fisheye
//! rays beyond 90°.
//!
//! Anti-aliasing: the board coordinates are computed exactly at the four corners of every
//! pixel (one unprojection per pixel corner) and interpolated bilinearly inside the pixel for
//! `supersample²` subsamples. Lens mappings are smooth on the scale of one pixel (the error of
//! the bilinear interpolation is far below 10⁻³ px), so this is as good as unprojecting every
//! subsample, at a fraction of the cost. Pixels whose four corners fall in the same square are
//! filled without subsampling.
//!
//! Then, in this order: an illumination ramp (uneven light), Gaussian blur, horizontal motion
//! blur, Gaussian noise from a seeded generator (SplitMix64 + Box-Muller, so renders are
//! bit-reproducible on every platform), rounding to 8 bits.
//!
//! Board convention (OpenCV's, see [`crate::calib`]): inner corner `(col, row)` sits at
//! `(col·square, row·square, 0)`; the square between inner corners 0, 1, `cols` and `cols + 1`
//! is black, and so is the outer square diagonally beyond corner 0. The board is drawn with
//! `(cols + 1) × (rows + 1)` squares and a white margin around it so that the outer corners are
//! real X-junctions.

use nalgebra::{Vector2, Vector3};
use serde::{Deserialize, Serialize};

use crate::board::filter::{ImageF, box_kernel, convolve_rows, gaussian_blur};
use crate::camera::{Camera, CameraModel};
use crate::error::{CoreError, CoreResult};
use crate::io::Gray;
use crate::lie::Se3;

/// How to render (every field has a default).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct RenderOptions {
    /// Subsamples per pixel side for anti-aliasing (1 = point sampling, 4 = 16 subsamples).
    pub supersample: u32,
    /// Standard deviation of an isotropic Gaussian blur (defocus), pixels; 0 = none.
    pub blur_sigma: f64,
    /// Length of a horizontal linear motion blur, pixels; 0 = none.
    pub motion_blur_px: f64,
    /// Standard deviation of additive Gaussian noise, grey levels; 0 = none.
    pub noise_sigma: f64,
    /// Seed of the noise generator.
    pub seed: u64,
    /// Grey level where no board is seen (and outside the field of view).
    pub background: f64,
    /// Grey level of the black squares.
    pub black: f64,
    /// Grey level of the white squares and of the margin.
    pub white: f64,
    /// Width of the white margin around the outer squares, in squares.
    pub margin: f64,
    /// Illumination ramp across the image: intensities are multiplied by
    /// `1 + light_gradient·(x/w − ½)` (uneven light); 0 = uniform.
    pub light_gradient: f64,
}

impl Default for RenderOptions {
    fn default() -> Self {
        Self {
            supersample: 4,
            blur_sigma: 0.0,
            motion_blur_px: 0.0,
            noise_sigma: 0.0,
            seed: 0,
            background: 110.0,
            black: 30.0,
            white: 220.0,
            margin: 0.75,
            light_gradient: 0.0,
        }
    }
}

/// A rendered view and its ground truth.
#[derive(Clone, Debug)]
pub struct SynthView {
    /// The image.
    pub image: Gray,
    /// True pixel position of every inner corner, row-major (`row·cols + col`); `None` when the
    /// corner does not project or falls outside the image.
    pub corners: Vec<Option<[f64; 2]>>,
}

impl SynthView {
    /// Whether every inner corner is inside the image.
    pub fn all_visible(&self) -> bool {
        self.corners.iter().all(Option::is_some)
    }
}

/// SplitMix64 (Steele, Lea, Flood, "Fast splittable pseudorandom number generators", OOPSLA
/// 2014): tiny, fast and good enough for image noise; no dependency needed.
struct SplitMix64(u64);

impl SplitMix64 {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in (0, 1].
    fn uniform(&mut self) -> f64 {
        ((self.next_u64() >> 11) as f64 + 1.0) / (1u64 << 53) as f64
    }

    /// Two independent standard normal samples (Box-Muller).
    fn normal_pair(&mut self) -> (f64, f64) {
        let r = (-2.0 * self.uniform().ln()).sqrt();
        let t = std::f64::consts::TAU * self.uniform();
        (r * t.cos(), r * t.sin())
    }
}

/// Where a ray hits the board: board coordinates in squares, or `None` (no ray, ray parallel
/// to or pointing away from the plane).
fn board_hit(camera: &Camera, inv: &Se3, px: f64, py: f64, square: f64) -> Option<[f64; 2]> {
    let d_cam = camera.unproject(&Vector2::new(px, py))?;
    let d = inv.rotation.act(&d_cam);
    let o = inv.translation;
    if d.z.abs() < 1e-12 {
        return None;
    }
    let lambda = -o.z / d.z;
    if lambda <= 0.0 {
        return None;
    }
    Some([(o.x + lambda * d.x) / square, (o.y + lambda * d.y) / square])
}

/// Region of the board a point (in squares) falls in: a square index with its colour, the
/// margin, or the background.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Region {
    Square(i64, i64),
    Margin,
    Background,
}

struct Colours {
    cols: f64,
    rows: f64,
    margin: f64,
    black: f64,
    white: f64,
    background: f64,
}

impl Colours {
    fn region(&self, p: Option<[f64; 2]>) -> Region {
        let Some([u, v]) = p else {
            return Region::Background;
        };
        if u >= -1.0 && u < self.cols && v >= -1.0 && v < self.rows {
            Region::Square(u.floor() as i64 + 1, v.floor() as i64 + 1)
        } else if u >= -1.0 - self.margin
            && u < self.cols + self.margin
            && v >= -1.0 - self.margin
            && v < self.rows + self.margin
        {
            Region::Margin
        } else {
            Region::Background
        }
    }

    fn value(&self, r: Region) -> f64 {
        match r {
            // Square (i, j) spans [i − 1, i) × [j − 1, j) in squares: (0, 0) is the outer
            // square beyond corner 0, black; colours alternate.
            Region::Square(i, j) => {
                if (i + j).rem_euclid(2) == 0 {
                    self.black
                } else {
                    self.white
                }
            }
            Region::Margin => self.white,
            Region::Background => self.background,
        }
    }
}

/// Renders a `cols × rows` inner-corner chessboard (squares of side `square`) seen from
/// `pose = T_cam_board` through `camera` into a `size = (width, height)` image, and returns it
/// with the true corner positions (see the module docs for the method).
///
/// Errors: an empty image, fewer than 2×2 corners, a non-positive square or supersampling,
/// negative blur or noise.
pub fn render_chessboard(
    camera: &Camera,
    pose: &Se3,
    board: (usize, usize, f64),
    size: (u32, u32),
    opts: &RenderOptions,
) -> CoreResult<SynthView> {
    let (cols, rows, square) = board;
    let (w, h) = (size.0 as usize, size.1 as usize);
    if w < 2 || h < 2 {
        return Err(CoreError::param("size", "image must be at least 2×2"));
    }
    if cols < 2 || rows < 2 || !(square.is_finite() && square > 0.0) {
        return Err(CoreError::param(
            "board",
            "needs at least 2×2 corners and a positive square",
        ));
    }
    if opts.supersample == 0 || opts.supersample > 16 {
        return Err(CoreError::param("supersample", "must be in 1..=16"));
    }
    for (name, v) in [
        ("blur_sigma", opts.blur_sigma),
        ("motion_blur_px", opts.motion_blur_px),
        ("noise_sigma", opts.noise_sigma),
        ("margin", opts.margin),
    ] {
        if !(v.is_finite() && v >= 0.0) {
            return Err(CoreError::param(name, "must be finite and ≥ 0"));
        }
    }
    let inv = pose.inverse();
    let colours = Colours {
        cols: cols as f64,
        rows: rows as f64,
        margin: opts.margin,
        black: opts.black,
        white: opts.white,
        background: opts.background,
    };

    // Board coordinates at the pixel corners (x − ½, y − ½).
    let gw = w + 1;
    let grid: Vec<Option<[f64; 2]>> = (0..(h + 1) * gw)
        .map(|k| {
            let (gx, gy) = (k % gw, k / gw);
            board_hit(camera, &inv, gx as f64 - 0.5, gy as f64 - 0.5, square)
        })
        .collect();

    let s = opts.supersample as usize;
    let mut img = ImageF::filled(w, h, 0.0);
    for y in 0..h {
        for x in 0..w {
            let c = [
                grid[y * gw + x],
                grid[y * gw + x + 1],
                grid[(y + 1) * gw + x],
                grid[(y + 1) * gw + x + 1],
            ];
            let regions = c.map(|p| colours.region(p));
            let value = if regions.iter().all(|r| *r == regions[0]) {
                colours.value(regions[0])
            } else {
                let mut acc = 0.0;
                for sy in 0..s {
                    let fy = (sy as f64 + 0.5) / s as f64;
                    for sx in 0..s {
                        let fx = (sx as f64 + 0.5) / s as f64;
                        let p = match c {
                            [Some(a), Some(b), Some(cc), Some(d)] => Some([0, 1].map(|k| {
                                (1.0 - fy) * ((1.0 - fx) * a[k] + fx * b[k])
                                    + fy * ((1.0 - fx) * cc[k] + fx * d[k])
                            })),
                            // Near the edge of the field of view: unproject the subsample.
                            _ => board_hit(
                                camera,
                                &inv,
                                x as f64 - 0.5 + fx,
                                y as f64 - 0.5 + fy,
                                square,
                            ),
                        };
                        acc += colours.value(colours.region(p));
                    }
                }
                acc / (s * s) as f64
            };
            let light = 1.0 + opts.light_gradient * ((x as f64 + 0.5) / w as f64 - 0.5);
            img.data[y * w + x] = (value * light) as f32;
        }
    }

    if opts.blur_sigma > 0.0 {
        img = gaussian_blur(&img, opts.blur_sigma);
    }
    if opts.motion_blur_px > 1.0 {
        img = convolve_rows(&img, &box_kernel(opts.motion_blur_px));
    }
    if opts.noise_sigma > 0.0 {
        let mut rng = SplitMix64(opts.seed);
        let mut pairs = img.data.chunks_mut(2);
        for pair in &mut pairs {
            let (a, b) = rng.normal_pair();
            pair[0] += (opts.noise_sigma * a) as f32;
            if pair.len() > 1 {
                pair[1] += (opts.noise_sigma * b) as f32;
            }
        }
    }

    let corners = (0..cols * rows)
        .map(|k| {
            let xb = Vector3::new((k % cols) as f64 * square, (k / cols) as f64 * square, 0.0);
            let p = camera.project(&pose.act(&xb))?;
            let inside = p.x >= 0.0 && p.y >= 0.0 && p.x <= (w - 1) as f64 && p.y <= (h - 1) as f64;
            inside.then_some([p.x, p.y])
        })
        .collect();
    Ok(SynthView {
        image: img.to_gray(),
        corners,
    })
}

/// Gaussian blur of an 8-bit image (σ in pixels), mirrored borders, rounded back to 8 bits.
/// Used to make blurred copies of real images for robustness tests.
pub fn blur_gray(img: &Gray, sigma: f64) -> Gray {
    gaussian_blur(&ImageF::from_gray(img), sigma).to_gray()
}

/// Horizontal linear motion blur of `len` pixels (a centred box, OpenCV's `filter2D` with a
/// `1 × len` kernel of `1/len` for an odd integer `len`), mirrored borders, rounded to 8 bits.
pub fn motion_blur_gray(img: &Gray, len: f64) -> Gray {
    if len <= 1.0 {
        return img.clone();
    }
    convolve_rows(&ImageF::from_gray(img), &box_kernel(len)).to_gray()
}

#[cfg(test)]
mod tests;
