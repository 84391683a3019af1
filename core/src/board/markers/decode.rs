//! Reading markers inside dark quads.
//!
//! For every quad ([`super::quads`]) the cell grid of the marker (its data bits plus a black
//! border of `border` cells, as in Garrido-Jurado et al. 2014 and Olson 2011) is mapped onto the
//! quad by the homography of the unit square (Heckbert, "Fundamentals of texture mapping and
//! image warping", 1989, §2.2.3). Each cell's grey level is the mean of five samples around
//! its centre (within ±0.15 cell, where blur has taken the least); the threshold between black and white is the midpoint between the border cells (black
//! by construction) and the white ring just outside the marker. The border must be black (a
//! few wrong cells are tolerated: blur and glare); the data bits are then looked up in the
//! dictionary in all four rotations with the dictionary's error correction, which gives the
//! id and which corner of the quad is the marker's top-left.

use super::Dictionary;
use super::quads::{Quad, find_quads};
use crate::io::Gray;

/// A decoded marker.
#[derive(Clone, Debug, PartialEq)]
pub struct Marker {
    /// Marker id: the index of its code in the dictionary.
    pub id: usize,
    /// Pixel corners of the outer black border, in the marker's own order (OpenCV's): its
    /// top-left, top-right, bottom-right, bottom-left as printed.
    pub corners: [[f64; 2]; 4],
    /// Bits corrected by the dictionary's error correction; `u32::MAX` for a marker that was
    /// not read but placed by its neighbours (see `predict_missing`).
    pub bit_errors: u32,
}

impl Marker {
    /// Whether the marker was placed by its decoded neighbours rather than read.
    pub fn is_predicted(&self) -> bool {
        self.bit_errors == u32::MAX
    }
}

/// Everything [`detect_markers`] saw in one image.
#[derive(Clone, Debug, Default)]
pub struct MarkerScan {
    /// Markers decoded once (ids seen twice are left out: see `duplicates`).
    pub markers: Vec<Marker>,
    /// Dark quads in the image.
    pub quads: usize,
    /// Quads with a black border and mixed bits that no code matched (a wrong dictionary
    /// when there are many and `markers` is empty).
    pub undecoded: usize,
    /// Ids decoded more than once in the image (dropped).
    pub duplicates: Vec<usize>,
}

/// The homography of the unit square onto quad `q` (`(0,0)→q0, (1,0)→q1, (1,1)→q2,
/// (0,1)→q3`).
#[derive(Clone, Copy, Debug)]
pub(crate) struct SquareMap {
    m: [f64; 8],
}

impl SquareMap {
    pub(crate) fn new(q: &[[f64; 2]; 4]) -> Option<Self> {
        let [p0, p1, p2, p3] = *q;
        let sx = p0[0] - p1[0] + p2[0] - p3[0];
        let sy = p0[1] - p1[1] + p2[1] - p3[1];
        let (g, h) = if sx.abs() < 1e-12 && sy.abs() < 1e-12 {
            (0.0, 0.0)
        } else {
            let (dx1, dx2) = (p1[0] - p2[0], p3[0] - p2[0]);
            let (dy1, dy2) = (p1[1] - p2[1], p3[1] - p2[1]);
            let den = dx1 * dy2 - dx2 * dy1;
            if den.abs() < 1e-12 {
                return None;
            }
            ((sx * dy2 - dx2 * sy) / den, (dx1 * sy - sx * dy1) / den)
        };
        let m = [
            p1[0] - p0[0] + g * p1[0],
            p3[0] - p0[0] + h * p3[0],
            p0[0],
            p1[1] - p0[1] + g * p1[1],
            p3[1] - p0[1] + h * p3[1],
            p0[1],
            g,
            h,
        ];
        m.iter().all(|v| v.is_finite()).then_some(Self { m })
    }

    /// Image point of `(u, v)`.
    #[inline]
    pub(crate) fn map(&self, u: f64, v: f64) -> [f64; 2] {
        let m = &self.m;
        let z = m[6] * u + m[7] * v + 1.0;
        [
            (m[0] * u + m[1] * v + m[2]) / z,
            (m[3] * u + m[4] * v + m[5]) / z,
        ]
    }
}

/// Bilinear grey level of `img` at `(x, y)`, `None` outside.
#[inline]
fn sample(img: &Gray, x: f64, y: f64) -> Option<f64> {
    let (w, h) = (img.width as usize, img.height as usize);
    if !(x >= 0.0 && y >= 0.0 && x < (w - 1) as f64 && y < (h - 1) as f64) {
        return None;
    }
    let (x0, y0) = (x as usize, y as usize);
    let (fx, fy) = (x - x0 as f64, y - y0 as f64);
    let i = y0 * w + x0;
    let d = &img.data;
    let a = f64::from(d[i]) + fx * (f64::from(d[i + 1]) - f64::from(d[i]));
    let b = f64::from(d[i + w]) + fx * (f64::from(d[i + w + 1]) - f64::from(d[i + w]));
    Some(a + fy * (b - a))
}

/// The outcome of reading one quad.
enum Read {
    Marker(Marker),
    /// Black border and mixed bits, but no code.
    Unknown,
    /// Not a marker.
    Nothing,
}

fn read_quad(img: &Gray, q: &Quad, dict: &Dictionary, border: usize, min_contrast: f64) -> Read {
    let Some(map) = SquareMap::new(&q.corners) else {
        return Read::Nothing;
    };
    let n = dict.bits() + 2 * border;
    let cell = 1.0 / n as f64;
    let mut cells = vec![0.0f64; n * n];
    for r in 0..n {
        for c in 0..n {
            let (u, v) = ((c as f64 + 0.5) * cell, (r as f64 + 0.5) * cell);
            let mut acc = 0.0;
            for (du, dv) in [
                (0.0, 0.0),
                (-0.15, -0.15),
                (0.15, -0.15),
                (-0.15, 0.15),
                (0.15, 0.15),
            ] {
                let p = map.map(u + du * cell, v + dv * cell);
                let Some(g) = sample(img, p[0], p[1]) else {
                    return Read::Nothing;
                };
                acc += g;
            }
            cells[r * n + c] = acc / 5.0;
        }
    }
    let is_border =
        |r: usize, c: usize| r < border || c < border || r >= n - border || c >= n - border;
    let mut black = 0.0;
    let mut nb = 0usize;
    for r in 0..n {
        for c in 0..n {
            if is_border(r, c) {
                black += cells[r * n + c];
                nb += 1;
            }
        }
    }
    black /= nb as f64;
    // The white ring outside, half a cell beyond the border, away from the corners.
    let mut outside: Vec<f64> = Vec::with_capacity(16);
    for t in [0.3, 0.45, 0.55, 0.7] {
        for (u, v) in [
            (t, -0.5 * cell),
            (t, 1.0 + 0.5 * cell),
            (-0.5 * cell, t),
            (1.0 + 0.5 * cell, t),
        ] {
            let p = map.map(u, v);
            if let Some(g) = sample(img, p[0], p[1]) {
                outside.push(g);
            }
        }
    }
    let inner_max = (0..n * n)
        .filter(|&k| !is_border(k / n, k % n))
        .map(|k| cells[k])
        .fold(f64::MIN, f64::max);
    let white = if outside.len() >= 8 {
        outside.sort_by(f64::total_cmp);
        outside[outside.len() / 2]
    } else {
        inner_max
    };
    if white - black < min_contrast {
        return Read::Nothing;
    }
    let thr = 0.5 * (white + black);
    let border_errors = (0..n * n)
        .filter(|&k| is_border(k / n, k % n) && cells[k] > thr)
        .count();
    if inner_max <= thr {
        // All black: a chessboard square, not a marker.
        return Read::Nothing;
    }
    if border_errors * 5 > nb {
        // Dark outline, white inside, but no border of this dictionary's cell size: a
        // marker of another dictionary, or not a marker at all.
        return Read::Unknown;
    }
    let mut code = 0u64;
    for r in border..n - border {
        for c in border..n - border {
            code = (code << 1) | u64::from(cells[r * n + c] > thr);
        }
    }
    match dict.identify(code) {
        Some((id, k, bit_errors)) => Read::Marker(Marker {
            id,
            corners: std::array::from_fn(|m| q.corners[(m + k) % 4]),
            bit_errors,
        }),
        None => Read::Unknown,
    }
}

/// Finds and decodes the markers of `dict` with a black border of `border` cells in `img`.
///
/// `min_contrast`: least grey-level difference between a marker's black border and the white
/// around it; `min_side`: least width and height of a marker in pixels. Ids found more than
/// once are dropped and listed in [`MarkerScan::duplicates`] (a second board, or a stray
/// marker in the scene: either would give wrong correspondences).
pub fn detect_markers(
    img: &Gray,
    dict: &Dictionary,
    border: usize,
    min_contrast: f64,
    min_side: f64,
) -> MarkerScan {
    let (w, h) = (img.width as usize, img.height as usize);
    if img.data.len() != w * h || w < 8 || h < 8 {
        return MarkerScan::default();
    }
    // Borders of two cells (AprilGrid) stay solid at a lower level, which keeps the tags apart
    // from the squares touching their corners when the board is tilted.
    let level = if border >= 2 { 0.25 } else { 0.4 };
    let quads = find_quads(img, min_contrast, min_side, level);
    let mut scan = MarkerScan {
        quads: quads.len(),
        ..MarkerScan::default()
    };
    let mut found: Vec<Marker> = Vec::new();
    for q in &quads {
        match read_quad(img, q, dict, border.max(1), min_contrast) {
            Read::Marker(m) => found.push(m),
            Read::Unknown => scan.undecoded += 1,
            Read::Nothing => {}
        }
    }
    found.sort_by_key(|m| m.id);
    let mut i = 0;
    while i < found.len() {
        let mut j = i + 1;
        while j < found.len() && found[j].id == found[i].id {
            j += 1;
        }
        if j - i == 1 {
            scan.markers.push(found[i].clone());
        } else {
            scan.duplicates.push(found[i].id);
        }
        i = j;
    }
    scan
}
