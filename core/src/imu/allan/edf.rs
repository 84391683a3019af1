//! Equivalent degrees of freedom of the overlapping AVAR and the χ² confidence intervals they
//! give (Howe, Allan & Barnes 1981; NIST SP 1065), with the normal quantile they need.

/// Equivalent degrees of freedom of the overlapping AVAR for white frequency (rate) noise with
/// `n_phase` phase points and cluster size m (Howe, Allan & Barnes 1981; NIST SP 1065 §5.3):
/// edf = (3(N−1)/(2m) − 2(N−2)/N) · 4m²/(4m² + 5). White rate noise dominates the short τ where
/// the fit's weight lies; for the long τ (random walk) the true EDF is smaller, so those
/// intervals are somewhat optimistic.
pub fn edf_white_fm(n_phase: usize, m: usize) -> f64 {
    let nn = n_phase as f64;
    let m = m as f64;
    let e =
        (3.0 * (nn - 1.0) / (2.0 * m) - 2.0 * (nn - 2.0) / nn) * 4.0 * m * m / (4.0 * m * m + 5.0);
    e.max(0.0)
}

/// EDF of the overlapping AVAR for the dominant noise type (0 white FM, 1 flicker FM, 2 random
/// walk FM), the simple approximations of Howe, Allan & Barnes (1981) tabulated in NIST SP 1065
/// (Riley 2008), Table 5; `n_phase` phase points, cluster size m.
pub fn edf_for(kind: usize, n_phase: usize, m: usize) -> f64 {
    let nn = n_phase as f64;
    let mf = m as f64;
    let e = match kind {
        1 => {
            if m == 1 {
                2.0 * (nn - 2.0).powi(2) / (2.3 * nn - 4.9)
            } else {
                5.0 * nn * nn / (4.0 * mf * (nn + 3.0 * mf))
            }
        }
        2 => {
            (nn - 2.0) / mf * ((nn - 1.0).powi(2) - 3.0 * mf * (nn - 1.0) + 4.0 * mf * mf)
                / (nn - 3.0).powi(2)
        }
        _ => return edf_white_fm(n_phase, m),
    };
    if e.is_finite() { e.max(0.0) } else { 0.0 }
}

/// χ² confidence interval of an AVAR with `edf` degrees of freedom: [avar·ν/χ²_hi, avar·ν/χ²_lo]
/// with Wilson-Hilferty quantiles χ²_p(ν) ≈ ν (1 − 2/(9ν) + z_p √(2/(9ν)))³.
pub(super) fn avar_interval(avar: f64, edf: f64, z: f64) -> (Option<f64>, Option<f64>) {
    if edf.is_nan() || edf <= 0.5 || !avar.is_finite() {
        return (None, None);
    }
    let q = |zp: f64| {
        let a = 2.0 / (9.0 * edf);
        let base = 1.0 - a + zp * a.sqrt();
        if base > 0.0 {
            Some(edf * base.powi(3))
        } else {
            None
        }
    };
    let lo = q(z).map(|c| avar * edf / c);
    let hi = q(-z).map(|c| avar * edf / c);
    (lo, hi)
}

/// Standard normal quantile (Acklam's rational approximation, |error| < 1.2·10⁻⁹).
pub(crate) fn normal_quantile(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969_683_028_665_376e1,
        2.209_460_984_245_205e2,
        -2.759_285_104_469_687e2,
        1.383_577_518_672_69e2,
        -3.066_479_806_614_716e1,
        2.506_628_277_459_239,
    ];
    const B: [f64; 5] = [
        -5.447_609_879_822_406e1,
        1.615_858_368_580_409e2,
        -1.556_989_798_598_866e2,
        6.680_131_188_771_972e1,
        -1.328_068_155_288_572e1,
    ];
    const C: [f64; 6] = [
        -7.784_894_002_430_293e-3,
        -3.223_964_580_411_365e-1,
        -2.400_758_277_161_838,
        -2.549_732_539_343_734,
        4.374_664_141_464_968,
        2.938_163_982_698_783,
    ];
    const D: [f64; 4] = [
        7.784_695_709_041_462e-3,
        3.224_671_290_700_398e-1,
        2.445_134_137_142_996,
        3.754_408_661_907_416,
    ];
    let p = p.clamp(1e-300, 1.0 - 1e-16);
    let pl = 0.02425;
    if p < pl {
        let q = (-2.0 * p.ln()).sqrt();
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    } else if p <= 1.0 - pl {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    } else {
        let q = (-2.0 * (1.0 - p).ln()).sqrt();
        -(((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    }
}
