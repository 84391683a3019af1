//! Which recorded levels the fit actually measured.
//!
//! An auto-exposure video rarely shows a point just below white unclipped: the samples at the
//! clip and the cuts are bounds, not measurements ([`super::super::joint::Censor`]). Where no
//! sample was measured, the response comes from the EMoR-4 model's shape alone
//! (extrapolation), and a strongly concave camera puts much of its irradiance range there:
//! on the sweep's `tuning#6` (f(0.5) = 0.95, `examples/photometric_sweep.rs`) levels 250–254
//! alone hold irradiances 0.70–0.91 of full scale, and the measured samples stop at level 213
//! (99.9 % quantile), with 75 % of the normalised irradiance range above. The document says
//! so, so that a user who linearises bright pixels with the response knows which part of it
//! was seen.

use serde::{Deserialize, Serialize};

use super::super::joint::Obs;

/// Share of measured samples left out at each end, so that a handful of outliers does not
/// stretch the range.
const TAIL: f64 = 0.001;

/// The range of 8-bit levels in which the fit saw measured samples (the 0.1 % and 99.9 %
/// quantiles of the unclipped samples' values).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct MeasuredLevels {
    /// Darkest measured level (0–255).
    pub low: f64,
    /// Brightest measured level (0–255); above it the response is extrapolated.
    pub high: f64,
}

/// The measured range of `obs`; `None` without a measured sample.
pub(super) fn measured_levels(obs: &[Obs]) -> Option<MeasuredLevels> {
    let mut v: Vec<f32> = obs
        .iter()
        .filter(|o| o.measured())
        .map(|o| o.value)
        .collect();
    if v.is_empty() {
        return None;
    }
    v.sort_by(f32::total_cmp);
    let last = v.len() - 1;
    let at = |q: f64| f64::from(v[((q * last as f64).round() as usize).min(last)]) * 255.0;
    Some(MeasuredLevels {
        low: at(TAIL),
        high: at(1.0 - TAIL),
    })
}

#[cfg(test)]
mod tests {
    use super::super::super::joint::Censor;
    use super::*;

    fn obs(value: f32, censor: Censor) -> Obs {
        Obs {
            point: 0,
            frame: 0,
            r2: 0.0,
            value,
            weight: 1.0,
            censor,
        }
    }

    #[test]
    fn range_of_measured_samples_without_bounds_or_outliers() {
        // 2000 measured samples over levels 51–204, one bright outlier, and bounds at the cuts
        // that must not count.
        let mut o: Vec<Obs> = (0..2000)
            .map(|i| obs(0.2 + 0.6 * i as f32 / 1999.0, Censor::Exact))
            .collect();
        o.push(obs(0.99, Censor::Exact));
        o.push(obs(250.0 / 255.0, Censor::AtLeast));
        o.push(obs(3.0 / 255.0, Censor::AtMost));
        let r = measured_levels(&o).expect("measured samples");
        assert!((r.low - 51.0).abs() < 0.5, "{r:?}");
        assert!((r.high - 204.0).abs() < 0.5, "{r:?}");
        assert!(measured_levels(&[obs(1.0, Censor::AtLeast)]).is_none());
    }
}
