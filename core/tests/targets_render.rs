//! Synthetic views of any [`TargetSpec`] through a pinhole camera, with ground truth: shared by
//! the target tests (`targets_detect.rs`) and the ChArUco benchmark, which include this file
//! as a module. As its own test crate it has no tests.
//!
//! Inverse mapping: every pixel corner is mapped to the board plane by the inverse of the
//! board-to-image homography `K·[r1 r2 t]`, and the board's printed colour
//! ([`TargetSpec::is_black`]) is averaged over 4×4 subsamples where the pixel's corners
//! disagree (exact for a pinhole). Then an optional board-space occluder, Gaussian blur in
//! floating point and seeded Gaussian noise, rounded to 8 bits.
#![allow(dead_code)]

use caliper_core::board::TargetSpec;
use caliper_core::io::Gray;
use nalgebra::{Matrix3, Rotation3, Vector3};

/// A rendered view with the true pixel of every corner id inside the image.
pub struct View {
    pub image: Gray,
    /// `(id, [x, y])` of every corner that projects inside the image.
    pub truth: Vec<(usize, [f64; 2])>,
    /// Board → image homography.
    pub h: Matrix3<f64>,
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
    /// Rotation vector of the board (tilt), radians.
    pub rot: [f64; 3],
    /// Image offset of the board centre from the principal point, pixels.
    pub shift: [f64; 2],
    pub blur: f64,
    pub noise: f64,
    pub seed: u64,
    /// Board-space rectangle `[x0, y0, x1, y1]` painted mid-grey (a hand on the board).
    pub occluder: Option<[f64; 4]>,
    /// The board's y axis points up in the image (a half turn about x before `rot`): boards
    /// whose frame has y up (Kalibr's AprilGrid), seen from the printed side.
    pub y_up: bool,
}

impl Default for Scene {
    fn default() -> Self {
        Self {
            size: (800, 600),
            f: 800.0,
            centre: [0.0, 0.0],
            dist: 1.0,
            rot: [0.0; 3],
            shift: [0.0, 0.0],
            blur: 0.0,
            noise: 0.0,
            seed: 1,
            occluder: None,
            y_up: false,
        }
    }
}

impl Scene {
    pub fn homography(&self) -> Matrix3<f64> {
        let (w, h) = self.size;
        let k = Matrix3::new(
            self.f,
            0.0,
            (w as f64 - 1.0) / 2.0 + self.shift[0],
            0.0,
            self.f,
            (h as f64 - 1.0) / 2.0 + self.shift[1],
            0.0,
            0.0,
            1.0,
        );
        let mut r = Rotation3::new(Vector3::new(self.rot[0], self.rot[1], self.rot[2]));
        if self.y_up {
            r *= Rotation3::new(Vector3::new(std::f64::consts::PI, 0.0, 0.0));
        }
        let rm = r.matrix();
        let c = Vector3::new(self.centre[0], self.centre[1], 0.0);
        let t = Vector3::new(0.0, 0.0, self.dist) - rm * c;
        let m = Matrix3::from_columns(&[rm.column(0).into_owned(), rm.column(1).into_owned(), t]);
        k * m
    }
}

pub fn project(h: &Matrix3<f64>, x: f64, y: f64) -> [f64; 2] {
    let p = h * Vector3::new(x, y, 1.0);
    [p.x / p.z, p.y / p.z]
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

const BLACK: f64 = 30.0;
const WHITE: f64 = 220.0;
const BACKGROUND: f64 = 90.0;
const OCCLUDER: f64 = 128.0;

fn colour(spec: &TargetSpec, scene: &Scene, margin: f64, p: [f64; 2]) -> f64 {
    if let Some([x0, y0, x1, y1]) = scene.occluder
        && p[0] >= x0
        && p[0] <= x1
        && p[1] >= y0
        && p[1] <= y1
    {
        return OCCLUDER;
    }
    match spec.is_black(p[0], p[1]) {
        Some(true) => BLACK,
        Some(false) => WHITE,
        None => {
            // A white margin around the pattern, `margin` board units wide.
            let near = [[-margin, 0.0], [margin, 0.0], [0.0, -margin], [0.0, margin]]
                .iter()
                .any(|d| spec.is_black(p[0] + d[0], p[1] + d[1]).is_some());
            if near { WHITE } else { BACKGROUND }
        }
    }
}

fn blur(img: &mut [f64], w: usize, h: usize, sigma: f64) {
    let r = (3.0 * sigma).ceil() as isize;
    let k: Vec<f64> = (-r..=r)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let s: f64 = k.iter().sum();
    let k: Vec<f64> = k.iter().map(|v| v / s).collect();
    let mirror = |i: isize, n: usize| -> usize {
        let n = n as isize;
        let p = 2 * (n - 1);
        let mut i = i.rem_euclid(p);
        if i >= n {
            i = p - i;
        }
        i as usize
    };
    let mut tmp = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            tmp[y * w + x] = (-r..=r)
                .map(|d| k[(d + r) as usize] * img[y * w + mirror(x as isize + d, w)])
                .sum();
        }
    }
    for y in 0..h {
        for x in 0..w {
            img[y * w + x] = (-r..=r)
                .map(|d| k[(d + r) as usize] * tmp[mirror(y as isize + d, h) * w + x])
                .sum();
        }
    }
}

/// Renders `spec` as seen in `scene`; `margin` is the white border around the pattern in
/// board units.
pub fn render(spec: &TargetSpec, scene: &Scene, margin: f64) -> View {
    let (w, h) = scene.size;
    let hm = scene.homography();
    let inv = hm.try_inverse().expect("invertible homography");
    let gw = w + 1;
    let corner: Vec<[f64; 2]> = (0..(h + 1) * gw)
        .map(|k| project(&inv, (k % gw) as f64 - 0.5, (k / gw) as f64 - 0.5))
        .collect();
    let mut img = vec![0.0; w * h];
    let ss = 4;
    for y in 0..h {
        for x in 0..w {
            let c = [
                corner[y * gw + x],
                corner[y * gw + x + 1],
                corner[(y + 1) * gw + x],
                corner[(y + 1) * gw + x + 1],
            ];
            let v: Vec<f64> = c.iter().map(|&p| colour(spec, scene, margin, p)).collect();
            img[y * w + x] = if v.iter().all(|&a| a == v[0]) {
                v[0]
            } else {
                let mut acc = 0.0;
                for sy in 0..ss {
                    for sx in 0..ss {
                        let (fx, fy) =
                            ((sx as f64 + 0.5) / ss as f64, (sy as f64 + 0.5) / ss as f64);
                        let p = project(&inv, x as f64 - 0.5 + fx, y as f64 - 0.5 + fy);
                        acc += colour(spec, scene, margin, p);
                    }
                }
                acc / (ss * ss) as f64
            };
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
            let p = project(&hm, o.x, o.y);
            (p[0] >= 0.0 && p[1] >= 0.0 && p[0] <= (w - 1) as f64 && p[1] <= (h - 1) as f64)
                .then_some((id, p))
        })
        .collect();
    View {
        image,
        truth,
        h: hm,
    }
}
