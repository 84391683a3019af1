//! The EMoR basis of camera response functions.
//!
//! Grossberg & Nayar ("Modeling the Space of Camera Response Functions", IEEE Trans. PAMI
//! 26(10):1272–1282, 2004) ran PCA over 201 measured response curves (DoRF): any real response
//! is well approximated by the mean curve `f0` plus a few principal components `h_k`. We carry
//! our own copy of the mean and the first four components, sampled at 1024 irradiance values
//! `E = j / 1023` (`emor_first4.csv`, columns `E,f0,h1,h2,h3,h4`), so the crate never reads
//! data at run time. The same numbers (rounded to 5 digits) are published in the BSD-licensed
//! tum-vision/online_photometric_calibration.

use std::sync::OnceLock;

/// Number of irradiance samples of the basis.
pub const EMOR_SAMPLES: usize = 1024;

/// Number of principal components carried (c1..c4).
pub const EMOR_DIM: usize = 4;

const EMOR_CSV: &str = include_str!("emor_first4.csv");

/// The mean response `f0` and the components `h1..h4`, each sampled at `E = j / 1023`.
#[derive(Debug, Clone)]
pub struct EmorBasis {
    /// Mean response.
    pub f0: Vec<f64>,
    /// Principal components.
    pub h: [Vec<f64>; EMOR_DIM],
}

impl EmorBasis {
    /// Response `f0 + Σ c_k h_k` sampled on the basis grid (not made monotone).
    pub fn curve(&self, c: &[f64; EMOR_DIM]) -> Vec<f64> {
        (0..EMOR_SAMPLES)
            .map(|j| self.f0[j] + (0..EMOR_DIM).map(|k| c[k] * self.h[k][j]).sum::<f64>())
            .collect()
    }

    /// Interpolation cell of irradiance `e` (clamped to `[0, 1]`): index and fraction.
    pub fn cell(e: f64) -> (usize, f64) {
        let x = e.clamp(0.0, 1.0) * (EMOR_SAMPLES - 1) as f64;
        let j = (x.floor() as usize).min(EMOR_SAMPLES - 2);
        (j, x - j as f64)
    }
}

fn parse(text: &str) -> Result<EmorBasis, String> {
    let mut f0 = Vec::with_capacity(EMOR_SAMPLES);
    let mut h: [Vec<f64>; EMOR_DIM] = Default::default();
    for (n, line) in text.lines().skip(1).enumerate() {
        let vals: Vec<f64> = line
            .split(',')
            .map(|s| s.trim().parse::<f64>())
            .collect::<Result<_, _>>()
            .map_err(|e| format!("EMoR table line {}: {e}", n + 2))?;
        if vals.len() != 2 + EMOR_DIM {
            return Err(format!("EMoR table line {}: {} columns", n + 2, vals.len()));
        }
        f0.push(vals[1]);
        for k in 0..EMOR_DIM {
            h[k].push(vals[2 + k]);
        }
    }
    if f0.len() != EMOR_SAMPLES {
        return Err(format!(
            "EMoR table has {} rows, not {EMOR_SAMPLES}",
            f0.len()
        ));
    }
    Ok(EmorBasis { f0, h })
}

/// The basis, parsed once from the embedded table.
pub fn emor_basis() -> &'static EmorBasis {
    static BASIS: OnceLock<EmorBasis> = OnceLock::new();
    BASIS.get_or_init(|| match parse(EMOR_CSV) {
        Ok(b) => b,
        // The table is compiled in and checked by a unit test: a failure is a build defect.
        Err(e) => panic!("embedded EMoR table is malformed: {e}"),
    })
}
