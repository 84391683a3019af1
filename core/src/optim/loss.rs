//! Robust losses applied to the squared norm of one residual block.

use serde::{Deserialize, Serialize};

use crate::error::{CoreError, CoreResult};

/// Robust loss ρ(s) on the squared residual norm `s = ‖r‖²` of one observation, with a scale
/// `c` in the residual's unit (pixels for reprojection errors).
///
/// Like Ceres' `LossFunction`, the loss acts on the whole 2-D block rather than per coordinate,
/// so it is invariant to the orientation of the image axes. The optimiser uses it by iteratively
/// re-weighted least squares (IRLS): each linearisation weights the block by `ρ′(s)`, which is
/// the classic M-estimator scheme (Huber 1964; Zhang, "Parameter estimation techniques: a tutorial
/// with application to conic fitting", 1997; Triggs et al., "Bundle adjustment — a modern
/// synthesis", 2000, §3.4).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub enum RobustLoss {
    /// Plain least squares, ρ(s) = s.
    #[default]
    None,
    /// Huber: quadratic up to `scale`, linear beyond (ρ(s) = 2c√s − c² for s > c²). Bounded
    /// influence but every observation still pulls; the usual choice for calibration.
    Huber {
        /// Residual norm (pixels) where the loss turns linear.
        scale: f64,
    },
    /// Cauchy: ρ(s) = c² log(1 + s/c²). Redescending-ish influence: far outliers barely pull,
    /// at the cost of a non-convex cost (needs a good start).
    Cauchy {
        /// Residual norm (pixels) where the influence peaks.
        scale: f64,
    },
}

impl RobustLoss {
    /// Errors when the scale is not a positive finite number.
    pub fn validate(&self) -> CoreResult<()> {
        match self {
            RobustLoss::None => Ok(()),
            RobustLoss::Huber { scale } | RobustLoss::Cauchy { scale } => {
                if scale.is_finite() && *scale > 0.0 {
                    Ok(())
                } else {
                    Err(CoreError::param(
                        "loss.scale",
                        format!("must be positive and finite, got {scale}"),
                    ))
                }
            }
        }
    }

    /// ρ(s) for the squared norm `s`, normalised so that ρ(s) ≈ s for small s.
    pub fn rho(&self, s: f64) -> f64 {
        match *self {
            RobustLoss::None => s,
            RobustLoss::Huber { scale } => {
                let c2 = scale * scale;
                if s <= c2 {
                    s
                } else {
                    2.0 * scale * s.sqrt() - c2
                }
            }
            RobustLoss::Cauchy { scale } => {
                let c2 = scale * scale;
                c2 * (s / c2).ln_1p()
            }
        }
    }

    /// The IRLS weight ρ′(s) ∈ (0, 1].
    pub fn weight(&self, s: f64) -> f64 {
        match *self {
            RobustLoss::None => 1.0,
            RobustLoss::Huber { scale } => {
                if s <= scale * scale {
                    1.0
                } else {
                    scale / s.sqrt()
                }
            }
            RobustLoss::Cauchy { scale } => 1.0 / (1.0 + s / (scale * scale)),
        }
    }
}
