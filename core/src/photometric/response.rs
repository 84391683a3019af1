//! Camera response models: gamma and EMoR, their monotone forward tables and the inverse
//! response as a table (DSO's `pcalib.txt`).
//!
//! Intensities and irradiances are normalised to `[0, 1]`: `f(0) = 0`, `f(1) = 1`, and an
//! `n`-bit pixel value `O` is read as `O / (2ⁿ − 1)`.

use serde::{Deserialize, Serialize};

use super::emor::{EMOR_DIM, EMOR_SAMPLES, EmorBasis, emor_basis};
use crate::error::{CoreError, CoreResult};

/// Smallest step between neighbouring table entries after monotone repair: DSO rejects a
/// `pcalib.txt` that is not strictly increasing.
const MIN_STEP: f64 = 1e-7;

/// A camera response function `f`: normalised irradiance → normalised intensity.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub enum ResponseModel {
    /// `f(x) = x^(1/γ)` (display gamma, a special case of a response).
    Gamma {
        /// γ > 0 (2.2 for sRGB-like cameras).
        gamma: f64,
    },
    /// EMoR (Grossberg & Nayar 2004): `f = f0 + Σ c_k h_k`, four components.
    Emor {
        /// Coefficients c1..c4.
        c: [f64; EMOR_DIM],
    },
}

impl Default for ResponseModel {
    fn default() -> Self {
        Self::Emor { c: [0.0; EMOR_DIM] }
    }
}

impl ResponseModel {
    /// Check the parameters.
    pub fn validate(&self) -> CoreResult<()> {
        match self {
            Self::Gamma { gamma } if !(gamma.is_finite() && *gamma > 0.0) => {
                Err(CoreError::param("response.gamma", "must be finite and > 0"))
            }
            Self::Emor { c } if c.iter().any(|v| !v.is_finite()) => Err(CoreError::param(
                "response.c",
                "coefficients must be finite",
            )),
            _ => Ok(()),
        }
    }

    /// The forward response sampled at `E = j / 1023`, made monotone (a running maximum plus
    /// a tiny step) and pinned to `f(0) = 0`, `f(1) = 1`. Fitting keeps the curve monotone
    /// with a penalty; this repair only removes what rounding could leave.
    pub fn forward_table(&self) -> Vec<f64> {
        let raw: Vec<f64> = match self {
            Self::Gamma { gamma } => (0..EMOR_SAMPLES)
                .map(|j| (j as f64 / (EMOR_SAMPLES - 1) as f64).powf(1.0 / gamma))
                .collect(),
            Self::Emor { c } => emor_basis().curve(c),
        };
        monotone_unit(raw)
    }

    /// `f(x)` for `x` in `[0, 1]` (clamped), from the monotone table.
    pub fn forward(&self, x: f64) -> f64 {
        interp_table(&self.forward_table(), x)
    }

    /// Whether the raw (unrepaired) curve is strictly increasing.
    pub fn is_monotone(&self) -> bool {
        match self {
            Self::Gamma { gamma } => gamma.is_finite() && *gamma > 0.0,
            Self::Emor { c } => emor_basis().curve(c).windows(2).all(|w| w[1] > w[0]),
        }
    }

    /// Inverse response as `levels` values `f⁻¹(i / (levels − 1))` (256 for DSO).
    pub fn inverse(&self, levels: usize) -> InverseResponse {
        let fwd = self.forward_table();
        let n = EMOR_SAMPLES - 1;
        let mut values = Vec::with_capacity(levels);
        let mut j = 0usize;
        for i in 0..levels {
            let y = i as f64 / (levels - 1).max(1) as f64;
            while j < n - 1 && fwd[j + 1] < y {
                j += 1;
            }
            let (a, b) = (fwd[j], fwd[j + 1]);
            let t = if b > a {
                ((y - a) / (b - a)).clamp(0.0, 1.0)
            } else {
                0.0
            };
            values.push((j as f64 + t) / n as f64);
        }
        InverseResponse {
            values: monotone_unit(values),
        }
    }
}

/// Make a curve on `[0, 1]` start at 0, end at 1 and increase strictly.
fn monotone_unit(mut v: Vec<f64>) -> Vec<f64> {
    let n = v.len();
    if n < 2 {
        return v;
    }
    v[0] = 0.0;
    for i in 1..n {
        let lo = v[i - 1] + MIN_STEP;
        if v[i].is_nan() || v[i] < lo {
            v[i] = lo;
        }
    }
    let top = v[n - 1];
    if top > 0.0 {
        for x in &mut v {
            *x /= top;
        }
    }
    v
}

/// Linear interpolation of a table sampled uniformly on `[0, 1]`.
pub(crate) fn interp_table(t: &[f64], x: f64) -> f64 {
    let n = t.len() - 1;
    let p = x.clamp(0.0, 1.0) * n as f64;
    let j = (p.floor() as usize).min(n.saturating_sub(1));
    let f = p - j as f64;
    t[j] + f * (t[(j + 1).min(n)] - t[j])
}

/// An inverse response `g = f⁻¹` tabulated at `levels` evenly spaced intensities in `[0, 1]`:
/// `values[i] = g(i / (levels − 1))`, strictly increasing from 0 to 1 (DSO's `pcalib.txt`
/// divided by 255).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct InverseResponse {
    /// Irradiance per intensity level, strictly increasing.
    pub values: Vec<f64>,
}

impl InverseResponse {
    /// Wrap a table after checking it: ≥ 2 finite values, strictly increasing (the index of
    /// the first violation is named).
    pub fn new(values: Vec<f64>) -> CoreResult<Self> {
        if values.len() < 2 {
            return Err(CoreError::input("inverse response needs at least 2 values"));
        }
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            return Err(CoreError::input(format!(
                "inverse response value {i} is not a finite number"
            )));
        }
        if let Some(i) = values.windows(2).position(|w| w[1] <= w[0]) {
            return Err(CoreError::input(format!(
                "inverse response is not strictly increasing: value {} ({}) ≤ value {i} ({})",
                i + 1,
                values[i + 1],
                values[i]
            )));
        }
        Ok(Self { values })
    }

    /// The identity (linear camera) with `levels` entries.
    pub fn linear(levels: usize) -> Self {
        let n = (levels.max(2) - 1) as f64;
        Self {
            values: (0..levels.max(2)).map(|i| i as f64 / n).collect(),
        }
    }

    /// `g(y)` for a normalised intensity `y` (linear interpolation, so 16-bit input works).
    pub fn eval(&self, y: f64) -> f64 {
        interp_table(&self.values, y)
    }

    /// Resample to `levels` entries (e.g. 256 for DSO from a finer table).
    pub fn resample(&self, levels: usize) -> Self {
        let n = (levels.max(2) - 1) as f64;
        Self {
            values: (0..levels.max(2))
                .map(|i| self.eval(i as f64 / n))
                .collect(),
        }
    }

    /// The 256-level table normalised so that level 1 → 0 and level 254 → 1: the comparison
    /// convention of the OpenCV peer (levels 0 and 255 are clipped bins), which also removes
    /// the irradiance scale. Returns levels 1..=254.
    pub fn normalized_1_254(&self) -> Vec<f64> {
        let t = self.resample(256).values;
        let (a, b) = (t[1], t[254]);
        t[1..=254].iter().map(|v| (v - a) / (b - a)).collect()
    }
}

/// The basis cell of irradiance `e` and the position in it, continued past 1 (see
/// [`emor_eval`]).
#[inline]
fn emor_cell(e: f64) -> (usize, f64) {
    let (j, t) = EmorBasis::cell(e);
    let t = if e > 1.0 {
        (e * (EMOR_SAMPLES - 1) as f64 - j as f64).max(t)
    } else {
        t
    };
    (j, t)
}

/// `f(E)` alone, as [`emor_eval`] gives it: the robust cost needs no derivatives, and it is
/// evaluated once per sample for every damping step tried.
#[inline]
pub(crate) fn emor_value(curve: &[f64], e: f64) -> f64 {
    let (j, t) = emor_cell(e);
    curve[j] + t * (curve[j + 1] - curve[j])
}

/// Raw EMoR evaluation for the fitters: `f(E)`, `f'(E)` and `∂f/∂c_k = h_k(E)`. Irradiance
/// above 1 continues the last segment linearly so that over-estimated radiances still get a
/// gradient back into range.
pub(crate) struct EmorEval {
    pub f: f64,
    pub df: f64,
    pub dc: [f64; EMOR_DIM],
}

pub(crate) fn emor_eval(curve: &[f64], e: f64) -> EmorEval {
    let b = emor_basis();
    let n = (EMOR_SAMPLES - 1) as f64;
    let (j, t) = emor_cell(e);
    let df = (curve[j + 1] - curve[j]) * n;
    let mut dc = [0.0; EMOR_DIM];
    for (k, d) in dc.iter_mut().enumerate() {
        *d = b.h[k][j] + t * (b.h[k][j + 1] - b.h[k][j]);
    }
    EmorEval {
        f: curve[j] + t * (curve[j + 1] - curve[j]),
        df,
        dc,
    }
}
