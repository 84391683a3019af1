//! Point-spread functions: construction, parsing and validation.
//!
//! Every [`Psf`] is normalised (sums to 1), non-negative and odd-sized in both directions, with its
//! centre at `(width / 2, height / 2)`. Odd sizes make "the centre" unambiguous, which is what lets
//! the deconvolvers shift the kernel to the FFT origin without a half-pixel drift of the result.

use serde::{Deserialize, Serialize};

use crate::error::{CoreError, CoreResult};
use crate::io::Gray;

/// Largest accepted kernel side in pixels. Camera-shake kernels in the literature stay below ~100 px
/// (Levin et al. 2009 use up to 27 px on 255×255 crops); 255 leaves room for full-resolution photos
/// while bounding the padding (and so the memory) a kernel can force on the FFT domain.
pub const MAX_PSF_SIZE: usize = 255;

/// Values above `-NEG_TOLERANCE · max` are treated as round-off and clipped to zero; anything more
/// negative is rejected (a PSF is an energy distribution, negative lobes mean the file is not one).
const NEG_TOLERANCE: f64 = 1e-6;

/// A normalised, non-negative, odd-sized blur kernel, row-major.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct Psf {
    /// Kernel width (odd).
    pub width: usize,
    /// Kernel height (odd).
    pub height: usize,
    /// Weights, row after row, summing to 1.
    pub data: Vec<f64>,
}

impl Psf {
    /// Build from raw row-major weights: validates (finite, non-negative up to round-off, positive
    /// sum, at most [`MAX_PSF_SIZE`] per side), pads even sides to odd and normalises to sum 1.
    ///
    /// Even sides get a zero row/column appended at the bottom/right: that keeps the centre at
    /// index `size / 2`, the origin `scipy.ndimage.convolve` and MATLAB use for even kernels.
    pub fn from_weights(width: usize, height: usize, data: Vec<f64>) -> CoreResult<Self> {
        if width == 0 || height == 0 {
            return Err(CoreError::input("PSF is empty"));
        }
        if width > MAX_PSF_SIZE || height > MAX_PSF_SIZE {
            return Err(CoreError::input(format!(
                "PSF is {width}×{height}; at most {MAX_PSF_SIZE}×{MAX_PSF_SIZE} is accepted"
            )));
        }
        if data.len() != width * height {
            return Err(CoreError::input(format!(
                "PSF {width}×{height} needs {} values, got {}",
                width * height,
                data.len()
            )));
        }
        if let Some(i) = data.iter().position(|v| !v.is_finite()) {
            return Err(CoreError::input(format!(
                "PSF value at row {}, column {} is not finite",
                i / width,
                i % width
            )));
        }
        let max = data.iter().copied().fold(0.0_f64, f64::max);
        if max <= 0.0 {
            return Err(CoreError::input(
                "PSF has no positive value (its sum must be positive)",
            ));
        }
        if let Some(i) = data.iter().position(|&v| v < -NEG_TOLERANCE * max) {
            return Err(CoreError::input(format!(
                "PSF value {} at row {}, column {} is negative",
                data[i],
                i / width,
                i % width
            )));
        }
        let (ow, oh) = (width | 1, height | 1);
        let mut out = vec![0.0; ow * oh];
        for y in 0..height {
            for x in 0..width {
                out[y * ow + x] = data[y * width + x].max(0.0);
            }
        }
        let mut sum: f64 = out.iter().sum();
        if !sum.is_finite() {
            // Huge finite weights (1e308 each) overflow the sum: scale by the largest first
            // (the scaled sum is at most the value count). Only then, so that ordinary kernels
            // normalise bit for bit as before.
            for v in &mut out {
                *v /= max;
            }
            sum = out.iter().sum();
        }
        for v in &mut out {
            *v /= sum;
        }
        Ok(Self {
            width: ow,
            height: oh,
            data: out,
        })
    }

    /// The identity kernel (1×1): deconvolution with it returns the input.
    pub fn identity() -> Self {
        Self {
            width: 1,
            height: 1,
            data: vec![1.0],
        }
    }

    /// Linear motion blur of `length` px at `angle_deg` degrees, counter-clockwise from +x with the
    /// image y axis pointing down — the `motion:LENGTH,ANGLE` kernel of the scikit-image peer
    /// (`deconv_skimage.py`), reproduced sample for sample so that kernel files are interchangeable.
    ///
    /// The segment is sampled at `⌊20·length⌋` evenly spaced points centred on the kernel centre
    /// and each point is splatted bilinearly onto its four neighbours, which anti-aliases
    /// sub-pixel lengths and arbitrary angles (like MATLAB `fspecial('motion')`). The kernel is
    /// `(⌈length⌉ rounded down to even) + 3` px square. `length <= 1` gives the identity.
    pub fn motion(length: f64, angle_deg: f64) -> CoreResult<Self> {
        if !length.is_finite() || !angle_deg.is_finite() || length < 0.0 {
            return Err(CoreError::param(
                "length",
                format!("motion length {length} / angle {angle_deg} must be finite, length ≥ 0"),
            ));
        }
        if length <= 1.0 {
            return Ok(Self::identity());
        }
        let size = (length.ceil() as usize) / 2 * 2 + 3;
        if size > MAX_PSF_SIZE {
            return Err(CoreError::param(
                "length",
                format!(
                    "motion length {length} px needs a {size} px kernel; at most {MAX_PSF_SIZE}"
                ),
            ));
        }
        let c = (size / 2) as f64;
        let (sin, cos) = angle_deg.to_radians().sin_cos();
        let n = (length * 20.0) as usize;
        let half = (length - 1.0) / 2.0;
        let mut k = vec![0.0; size * size];
        for i in 0..n {
            // numpy.linspace(-half, half, n): endpoints included.
            let t = -half + 2.0 * half * i as f64 / (n - 1) as f64;
            let (xs, ys) = (c + t * cos, c - t * sin);
            let (x0, y0) = (xs.floor(), ys.floor());
            let (fx, fy) = (xs - x0, ys - y0);
            let (x0, y0) = (x0 as usize, y0 as usize);
            k[y0 * size + x0] += (1.0 - fx) * (1.0 - fy);
            k[y0 * size + x0 + 1] += fx * (1.0 - fy);
            k[(y0 + 1) * size + x0] += (1.0 - fx) * fy;
            k[(y0 + 1) * size + x0 + 1] += fx * fy;
        }
        Self::from_weights(size, size, k)
    }

    /// Defocus: a uniform disc of `radius` px, anti-aliased by the exact-ish pixel coverage
    /// (16×16 supersampling), like MATLAB `fspecial('disk')`. `radius < 0.5` gives the identity.
    pub fn disc(radius: f64) -> CoreResult<Self> {
        if !radius.is_finite() || radius < 0.0 {
            return Err(CoreError::param(
                "radius",
                format!("disc radius {radius} must be finite and ≥ 0"),
            ));
        }
        if radius < 0.5 {
            return Ok(Self::identity());
        }
        let size = 2 * radius.ceil() as usize + 1;
        if size > MAX_PSF_SIZE {
            return Err(CoreError::param(
                "radius",
                format!("disc radius {radius} px needs a {size} px kernel; at most {MAX_PSF_SIZE}"),
            ));
        }
        const SUB: usize = 16;
        let c = (size / 2) as f64;
        let r2 = radius * radius;
        let mut k = vec![0.0; size * size];
        for y in 0..size {
            for x in 0..size {
                let mut inside = 0usize;
                for sy in 0..SUB {
                    let py = y as f64 - c - 0.5 + (sy as f64 + 0.5) / SUB as f64;
                    for sx in 0..SUB {
                        let px = x as f64 - c - 0.5 + (sx as f64 + 0.5) / SUB as f64;
                        inside += usize::from(px * px + py * py <= r2);
                    }
                }
                k[y * size + x] = inside as f64;
            }
        }
        Self::from_weights(size, size, k)
    }

    /// Isotropic Gaussian of standard deviation `sigma` px, truncated at 3σ (side `2⌈3σ⌉ + 1`).
    /// `sigma` below 0.1 px is indistinguishable from no blur and gives the identity.
    pub fn gaussian(sigma: f64) -> CoreResult<Self> {
        if !sigma.is_finite() || sigma < 0.0 {
            return Err(CoreError::param(
                "sigma",
                format!("Gaussian sigma {sigma} must be finite and ≥ 0"),
            ));
        }
        if sigma < 0.1 {
            return Ok(Self::identity());
        }
        let r = (3.0 * sigma).ceil() as usize;
        let size = 2 * r + 1;
        if size > MAX_PSF_SIZE {
            return Err(CoreError::param(
                "sigma",
                format!(
                    "Gaussian sigma {sigma} px needs a {size} px kernel; at most {MAX_PSF_SIZE}"
                ),
            ));
        }
        let g: Vec<f64> = (0..size)
            .map(|i| {
                let d = i as f64 - r as f64;
                (-d * d / (2.0 * sigma * sigma)).exp()
            })
            .collect();
        let k = (0..size * size)
            .map(|i| g[i / size] * g[i % size])
            .collect();
        Self::from_weights(size, size, k)
    }

    /// Parse a text matrix as `numpy.savetxt` writes it: one row per line, values separated by
    /// whitespace and/or commas; blank lines and `#` comments are skipped.
    pub fn parse_text(text: &str) -> CoreResult<Self> {
        let mut rows: Vec<Vec<f64>> = Vec::new();
        for (lineno, line) in text.lines().enumerate() {
            let line = line.split('#').next().unwrap_or("").trim();
            if line.is_empty() {
                continue;
            }
            let row = line
                .split(|c: char| c == ',' || c.is_whitespace())
                .filter(|t| !t.is_empty())
                .map(|t| {
                    t.parse::<f64>().map_err(|_| {
                        CoreError::input(format!(
                            "PSF text line {}: `{t}` is not a number",
                            lineno + 1
                        ))
                    })
                })
                .collect::<CoreResult<Vec<f64>>>()?;
            if row.is_empty() {
                return Err(CoreError::input(format!(
                    "PSF text line {} has no values",
                    lineno + 1
                )));
            }
            if let Some(first) = rows.first()
                && first.len() != row.len()
            {
                return Err(CoreError::input(format!(
                    "PSF text line {} has {} values, the first row has {}",
                    lineno + 1,
                    row.len(),
                    first.len()
                )));
            }
            if rows.len() >= MAX_PSF_SIZE || row.len() > MAX_PSF_SIZE {
                return Err(CoreError::input(format!(
                    "PSF text is larger than {MAX_PSF_SIZE}×{MAX_PSF_SIZE}"
                )));
            }
            rows.push(row);
        }
        Self::from_rows(rows)
    }

    /// Parse JSON: either a matrix `[[...], ...]` or an object with such a matrix under `kernel`
    /// or `psf` (what [`Psf::to_json`] writes).
    pub fn parse_json(text: &str) -> CoreResult<Self> {
        let value: serde_json::Value = serde_json::from_str(text)
            .map_err(|e| CoreError::input(format!("PSF JSON does not parse: {e}")))?;
        let matrix = match &value {
            serde_json::Value::Object(map) => map
                .get("kernel")
                .or_else(|| map.get("psf"))
                .ok_or_else(|| {
                    CoreError::input("PSF JSON object has no `kernel` or `psf` matrix")
                })?,
            other => other,
        };
        let rows: Vec<Vec<f64>> = serde_json::from_value(matrix.clone()).map_err(|e| {
            CoreError::input(format!(
                "PSF JSON must be an array of arrays of numbers: {e}"
            ))
        })?;
        if rows.len() > MAX_PSF_SIZE || rows.iter().any(|r| r.len() > MAX_PSF_SIZE) {
            return Err(CoreError::input(format!(
                "PSF JSON is larger than {MAX_PSF_SIZE}×{MAX_PSF_SIZE}"
            )));
        }
        if let Some((i, r)) = rows
            .iter()
            .enumerate()
            .find(|(_, r)| r.len() != rows[0].len())
        {
            return Err(CoreError::input(format!(
                "PSF JSON row {i} has {} values, row 0 has {}",
                r.len(),
                rows[0].len()
            )));
        }
        Self::from_rows(rows)
    }

    /// From an 8-bit image (e.g. a PNG kernel scaled to max 255): pixel values are the weights.
    pub fn from_gray(img: &Gray) -> CoreResult<Self> {
        Self::from_weights(
            img.width as usize,
            img.height as usize,
            img.data.iter().map(|&v| f64::from(v)).collect(),
        )
    }

    /// As an 8-bit image scaled so the largest weight is 255 (lossy; for previews and PNG export).
    pub fn to_gray(&self) -> Gray {
        let max = self
            .data
            .iter()
            .copied()
            .fold(0.0_f64, f64::max)
            .max(f64::MIN_POSITIVE);
        Gray {
            width: self.width as u32,
            height: self.height as u32,
            data: self
                .data
                .iter()
                .map(|v| (v / max * 255.0).round().clamp(0.0, 255.0) as u8)
                .collect(),
        }
    }

    /// As a text matrix `numpy.loadtxt` reads back exactly: Rust's shortest round-trip formatting
    /// rather than the peer's `%.10g`, so a kernel survives a save/load cycle bit for bit.
    pub fn to_text(&self) -> String {
        let mut s = String::new();
        for row in self.data.chunks(self.width) {
            let line: Vec<String> = row.iter().map(|v| format!("{v:e}")).collect();
            s.push_str(&line.join(" "));
            s.push('\n');
        }
        s
    }

    /// As JSON `{"width", "height", "kernel": [[...]]}`, readable by [`Psf::parse_json`].
    pub fn to_json(&self) -> serde_json::Value {
        let rows: Vec<&[f64]> = self.data.chunks(self.width).collect();
        serde_json::json!({ "width": self.width, "height": self.height, "kernel": rows })
    }

    /// Weight at column `x`, row `y`.
    pub fn at(&self, x: usize, y: usize) -> f64 {
        self.data[y * self.width + x]
    }

    /// The weights centred in a `side × side` window (row-major): a zero border around them,
    /// or cropped when the window is smaller (the cropped weight is dropped, not renormalised).
    pub fn centred_weights(&self, side: usize) -> Vec<f64> {
        let mut out = vec![0.0; side * side];
        let (oc, pcx, pcy) = (
            side as isize / 2,
            self.width as isize / 2,
            self.height as isize / 2,
        );
        for y in 0..self.height {
            for x in 0..self.width {
                let (tx, ty) = (x as isize - pcx + oc, y as isize - pcy + oc);
                if (0..side as isize).contains(&tx) && (0..side as isize).contains(&ty) {
                    out[ty as usize * side + tx as usize] += self.at(x, y);
                }
            }
        }
        out
    }

    fn from_rows(rows: Vec<Vec<f64>>) -> CoreResult<Self> {
        let height = rows.len();
        let width = rows.first().map_or(0, Vec::len);
        if height == 0 || width == 0 {
            return Err(CoreError::input("PSF matrix is empty"));
        }
        Self::from_weights(width, height, rows.into_iter().flatten().collect())
    }
}
