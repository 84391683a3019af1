//! Synthetic views of circle grids with exact ground truth, shared by the circle-grid tests
//! (`targets_circles.rs`) and the OpenCV comparison bench, which include this file as a module.
//! As its own test crate it has no tests.
//!
//! A pinhole camera with optional radial distortion (`k1`, on normalised coordinates). Every
//! pixel corner is mapped back to the board (undistorted by fixed-point iteration, then the
//! inverse board-to-image homography); pixels whose corners disagree in colour are averaged
//! over 8×8 subsamples, so edges are exact to about 1/64 of a pixel's area. Then optional dark
//! discs in the image (clutter), a left-to-right lighting gradient, Gaussian blur and seeded
//! Gaussian noise, rounded to 8 bits.
//!
//! The truth is the projection of each circle's centre (distorted when `k1 ≠ 0`), not the
//! centre of the imaged ellipse.
#![allow(dead_code)]

use caliper_core::board::TargetSpec;
use caliper_core::io::Gray;
use nalgebra::{Matrix3, Rotation3, Vector3};

/// A rendered view with the true pixel of every circle id.
pub struct View {
    pub image: Gray,
    /// `(id, [x, y])` of every circle.
    pub truth: Vec<(usize, [f64; 2])>,
    /// Board → normalised-camera homography `[r1 r2 t]`.
    pub hn: Matrix3<f64>,
}

/// How to render.
#[derive(Clone, Debug)]
pub struct Scene {
    pub size: (usize, usize),
    /// Focal length, pixels.
    pub f: f64,
    /// Board point placed on the optical axis.
    pub centre: [f64; 2],
    /// Distance of that point from the camera.
    pub dist: f64,
    /// Rotation vector of the board, radians.
    pub rot: [f64; 3],
    /// Radial distortion `x_d = x·(1 + k1·r²)` on normalised coordinates.
    pub k1: f64,
    pub blur: f64,
    pub noise: f64,
    pub seed: u64,
    /// Image-space dark discs `[x, y, radius]` drawn over the view.
    pub clutter: Vec<[f64; 3]>,
    /// Relative brightness change from the left edge to the right edge (0 = even).
    pub gradient: f64,
}

impl Default for Scene {
    fn default() -> Self {
        Self {
            size: (1280, 960),
            f: 1100.0,
            centre: [0.0, 0.0],
            dist: 0.5,
            rot: [0.0; 3],
            k1: 0.0,
            blur: 0.0,
            noise: 0.0,
            seed: 1,
            clutter: Vec::new(),
            gradient: 0.0,
        }
    }
}

const BLACK: f64 = 30.0;
const WHITE: f64 = 220.0;
const BACKGROUND: f64 = 90.0;

impl Scene {
    /// Board → normalised camera coordinates.
    pub fn hn(&self) -> Matrix3<f64> {
        let r = Rotation3::new(Vector3::new(self.rot[0], self.rot[1], self.rot[2]));
        let rm = r.matrix();
        let c = Vector3::new(self.centre[0], self.centre[1], 0.0);
        let t = Vector3::new(0.0, 0.0, self.dist) - rm * c;
        Matrix3::from_columns(&[rm.column(0).into_owned(), rm.column(1).into_owned(), t])
    }

    fn principal(&self) -> [f64; 2] {
        [
            (self.size.0 as f64 - 1.0) / 2.0,
            (self.size.1 as f64 - 1.0) / 2.0,
        ]
    }

    /// Pixel of board point `(x, y)`.
    pub fn project(&self, x: f64, y: f64) -> [f64; 2] {
        let p = self.hn() * Vector3::new(x, y, 1.0);
        let (u, v) = (p.x / p.z, p.y / p.z);
        let s = 1.0 + self.k1 * (u * u + v * v);
        let c = self.principal();
        [c[0] + self.f * u * s, c[1] + self.f * v * s]
    }

    /// Board point seen at pixel `p`, given the inverse of [`Scene::hn`].
    fn to_board(&self, inv: &Matrix3<f64>, p: [f64; 2]) -> [f64; 2] {
        let c = self.principal();
        let (xd, yd) = ((p[0] - c[0]) / self.f, (p[1] - c[1]) / self.f);
        let (mut x, mut y) = (xd, yd);
        let rounds = if self.k1 == 0.0 { 0 } else { 20 };
        for _ in 0..rounds {
            let s = 1.0 + self.k1 * (x * x + y * y);
            x = xd / s;
            y = yd / s;
        }
        let b = inv * Vector3::new(x, y, 1.0);
        [b.x / b.z, b.y / b.z]
    }
}

struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn normal(&mut self) -> f64 {
        let u = ((self.next() >> 11) as f64 + 1.0) / (1u64 << 53) as f64;
        let v = (self.next() >> 11) as f64 / (1u64 << 53) as f64;
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }
}

fn colour(spec: &TargetSpec, scene: &Scene, inv: &Matrix3<f64>, p: [f64; 2]) -> f64 {
    if scene
        .clutter
        .iter()
        .any(|d| (p[0] - d[0]).hypot(p[1] - d[1]) <= d[2])
    {
        return BLACK;
    }
    let b = scene.to_board(inv, p);
    match spec.is_black(b[0], b[1]) {
        Some(true) => BLACK,
        Some(false) => WHITE,
        None => BACKGROUND,
    }
}

fn blur(img: &mut [f64], w: usize, h: usize, sigma: f64) {
    let r = (3.5 * sigma).ceil() as isize;
    let k: Vec<f64> = (-r..=r)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let s: f64 = k.iter().sum();
    let k: Vec<f64> = k.iter().map(|v| v / s).collect();
    let clamp = |i: isize, n: usize| i.clamp(0, n as isize - 1) as usize;
    let mut tmp = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            tmp[y * w + x] = (-r..=r)
                .map(|d| k[(d + r) as usize] * img[y * w + clamp(x as isize + d, w)])
                .sum();
        }
    }
    for y in 0..h {
        for x in 0..w {
            img[y * w + x] = (-r..=r)
                .map(|d| k[(d + r) as usize] * tmp[clamp(y as isize + d, h) * w + x])
                .sum();
        }
    }
}

/// Renders the circle grid `spec` as seen in `scene`.
pub fn render(spec: &TargetSpec, scene: &Scene) -> View {
    let (w, h) = scene.size;
    let hn = scene.hn();
    let inv = hn.try_inverse().expect("invertible homography");
    let gw = w + 1;
    let corner: Vec<f64> = (0..(h + 1) * gw)
        .map(|k| {
            let p = [(k % gw) as f64 - 0.5, (k / gw) as f64 - 0.5];
            colour(spec, scene, &inv, p)
        })
        .collect();
    let ss = 8;
    let mut img = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            let c = [
                corner[y * gw + x],
                corner[y * gw + x + 1],
                corner[(y + 1) * gw + x],
                corner[(y + 1) * gw + x + 1],
            ];
            img[y * w + x] = if c.iter().all(|&a| a == c[0]) {
                c[0]
            } else {
                let mut acc = 0.0;
                for sy in 0..ss {
                    for sx in 0..ss {
                        let p = [
                            x as f64 - 0.5 + (sx as f64 + 0.5) / ss as f64,
                            y as f64 - 0.5 + (sy as f64 + 0.5) / ss as f64,
                        ];
                        acc += colour(spec, scene, &inv, p);
                    }
                }
                acc / (ss * ss) as f64
            };
        }
    }
    if scene.gradient != 0.0 {
        for (k, v) in img.iter_mut().enumerate() {
            *v *= 1.0 + scene.gradient * ((k % w) as f64 / w as f64 - 0.5);
        }
    }
    if scene.blur > 0.0 {
        blur(&mut img, w, h, scene.blur);
    }
    if scene.noise > 0.0 {
        let mut rng = Rng(scene.seed);
        for v in &mut img {
            *v += scene.noise * rng.normal();
        }
    }
    let image = Gray {
        width: w as u32,
        height: h as u32,
        data: img
            .iter()
            .map(|v| v.round().clamp(0.0, 255.0) as u8)
            .collect(),
    };
    let truth = (0..spec.num_corners())
        .filter_map(|id| {
            let o = spec.object_point(id)?;
            Some((id, scene.project(o.x, o.y)))
        })
        .collect();
    View { image, truth, hn }
}

/// Width and height spanned by the circle centres of `spec` (board units).
pub fn span(spec: &TargetSpec) -> [f64; 2] {
    let n = spec.num_corners();
    let (mut x, mut y) = (0.0f64, 0.0f64);
    for id in 0..n {
        if let Some(o) = spec.object_point(id) {
            x = x.max(o.x);
            y = y.max(o.y);
        }
    }
    [x, y]
}

/// A scene looking at the middle of `spec`, tilted by `tilt_deg` about the board's x axis
/// (plus a little yaw so nothing is axis-aligned), at distance `dist`.
pub fn tilted(spec: &TargetSpec, tilt_deg: f64, dist: f64) -> Scene {
    let [sx, sy] = span(spec);
    let t = tilt_deg.to_radians();
    Scene {
        centre: [sx / 2.0, sy / 2.0],
        dist,
        rot: [t, 0.12, 0.05],
        ..Scene::default()
    }
}
