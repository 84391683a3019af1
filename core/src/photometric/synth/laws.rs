//! The true vignetting laws of the synthetic auto-exposure videos: the model's own
//! polynomial and laws it can only approximate (cos⁴, Gaussian, mechanical, fisheye image
//! circles), kept apart from the renderer that applies them.

use super::super::vignette::VignetteModel;

/// The true vignetting law.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum VignetteForm {
    /// The camera's even polynomial ([`SynthCamera::vignette`]).
    Polynomial,
    /// Natural cos⁴ fall-off, `V = cos⁴(atan(r · tan θ))` with `θ` the half-angle at the
    /// corner (not a polynomial: the model can only approximate it).
    Cos4 {
        /// Corner half-angle in degrees.
        corner_deg: f64,
    },
    /// Gaussian fall-off `V = corner^{r²}` (`r` = 1 at the corner): another law that is not
    /// the model's polynomial.
    Gaussian {
        /// Attenuation at the corner, in (0, 1].
        corner: f64,
    },
    /// Mechanical vignetting (a hood, a filter ring or a lens too small for the sensor): flat
    /// out to `r² = start`, then a smoothstep down to `1 − depth` at the corner. A plateau
    /// with a steep shoulder, which the even polynomial follows worst of the three.
    Mechanical {
        /// `r²` where the fall-off begins, in [0, 1).
        start: f64,
        /// Loss at the corner, in [0, 1).
        depth: f64,
    },
    /// A fisheye's image circle: cos⁴ fall-off (`corner_deg` the half-angle a ray at `r = 1`
    /// would have) times a logistic border at `r = radius` of width `width` (in `r`), so the
    /// corners outside the circle are nearly black (the lens of the offline fisheye tests).
    FisheyeLogistic {
        /// Half-angle at `r = 1`, degrees.
        corner_deg: f64,
        /// Radius of the image circle (`r` = 1 at the corner).
        radius: f64,
        /// Width of the border (logistic scale, in `r`).
        width: f64,
    },
    /// A third image circle, for a held-out split: an equidistant fisheye's `cos³ θ` fall-off
    /// (`θ = r · θ_corner`, linear in the radius, unlike the other laws' `atan`) times the
    /// border of a defocused field stop, `½ erfc((r − radius) / (√2 width))`: a Gaussian
    /// edge, with longer tails on both sides than the logistic or the raised cosine.
    FisheyeErf {
        /// Field angle at `r = 1`, degrees.
        corner_deg: f64,
        /// Radius of the image circle (`r` = 1 at the corner): where the border is at half.
        radius: f64,
        /// Width of the border (the edge's standard deviation, in `r`).
        width: f64,
    },
    /// Another image circle: `(1 − a r²)²` fall-off, flat border factor up to `inner`, then a
    /// raised cosine that reaches exactly 0 at `outer` (black beyond).
    FisheyeRaised {
        /// Fall-off coefficient.
        a: f64,
        /// Where the border begins (`r`).
        inner: f64,
        /// Where the border reaches 0 (`r`).
        outer: f64,
    },
}

impl VignetteForm {
    /// `V` at pixel `(x, y)`, with `vm` giving the centre, the radius normalisation and (for
    /// [`Self::Polynomial`]) the coefficients.
    pub(super) fn eval(&self, vm: &VignetteModel, x: f64, y: f64) -> f64 {
        match *self {
            Self::Polynomial => vm.eval(x, y),
            Self::Cos4 { corner_deg } => {
                let t = vm.r2(x, y).sqrt() * corner_deg.to_radians().tan();
                t.atan().cos().powi(4)
            }
            Self::Gaussian { corner } => corner.powf(vm.r2(x, y)),
            Self::Mechanical { start, depth } => {
                let t = ((vm.r2(x, y) - start) / (1.0 - start)).clamp(0.0, 1.0);
                1.0 - depth * t * t * (3.0 - 2.0 * t)
            }
            Self::FisheyeLogistic {
                corner_deg,
                radius,
                width,
            } => {
                let r = vm.r2(x, y).sqrt();
                let t = r * corner_deg.to_radians().tan();
                t.atan().cos().powi(4) / (1.0 + ((r - radius) / width).exp())
            }
            Self::FisheyeErf {
                corner_deg,
                radius,
                width,
            } => {
                let r = vm.r2(x, y).sqrt();
                let theta = (r * corner_deg.to_radians()).min(std::f64::consts::FRAC_PI_2);
                let edge = (r - radius) / (std::f64::consts::SQRT_2 * width);
                theta.cos().powi(3) * 0.5 * erfc(edge)
            }
            Self::FisheyeRaised { a, inner, outer } => {
                let r = vm.r2(x, y).sqrt();
                let border = if r <= inner {
                    1.0
                } else if r >= outer {
                    0.0
                } else {
                    0.5 * (1.0 + (std::f64::consts::PI * (r - inner) / (outer - inner)).cos())
                };
                (1.0 - a * r * r).max(0.0).powi(2) * border
            }
        }
    }
}

/// The complementary error function, to ~1.2·10⁻⁷ (W. H. Press et al., *Numerical Recipes*,
/// 3rd ed., §6.2.2, the Chebyshev-fitted `erfcc`): enough for a synthetic edge.
fn erfc(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let poly = -z * z - 1.265_512_23
        + t * (1.000_023_68
            + t * (0.374_091_96
                + t * (0.096_784_18
                    + t * (-0.186_288_06
                        + t * (0.278_868_07
                            + t * (-1.135_203_98
                                + t * (1.488_515_87 + t * (-0.822_152_23 + t * 0.170_872_77))))))));
    let r = t * poly.exp();
    if x >= 0.0 { r } else { 2.0 - r }
}

#[cfg(test)]
mod tests {
    use super::erfc;

    /// Reference values of erfc (Abramowitz & Stegun, Table 7.1).
    #[test]
    fn erfc_matches_tabulated_values() {
        for (x, want) in [
            (0.0, 1.0),
            (0.5, 0.479_500_122),
            (1.0, 0.157_299_207),
            (2.0, 0.004_677_735),
            (-1.0, 1.842_700_793),
        ] {
            assert!((erfc(x) - want).abs() < 1e-6, "erfc({x}) = {}", erfc(x));
        }
    }
}
