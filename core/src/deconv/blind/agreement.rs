//! How far two blind kernel estimates of the same photo agree: a warning sign, not a fix.
//!
//! The default blind estimate runs twice, at two cleaning thresholds (`select.rs`). Where
//! the photo pins the kernel down, both runs land on the same path and differ only in its
//! faint ends; where it does not (a repetitive texture, a board whose lattice admits shifted
//! copies, a window too small for the blur), the two runs wander to different kernels, and
//! the one kept is then usually wrong as well. Measured on the tuning splits of
//! `examples/blind_eval.rs` (TUNE, TREMOR, TEXTURE and Levin et al.'s two sets, 188 cases):
//! with agreement below [`UNCERTAIN_AGREEMENT`] 34 cases, 8 of them (24 %) at error ratio ≤ 3;
//! at or above it 154 cases, 103 (67 %) at ratio ≤ 3, against 59 % over all. On the eight
//! held-out splits (EVAL to EVAL8; 384 cases) 85 are flagged, 19 of them at ratio ≤ 3,
//! against 192 of the other 299. The sign misses the failures where both runs collapse onto
//! the same wrong kernel (all of Levin et al.'s captured failures), so a kernel that passes
//! is not thereby right.
//!
//! Tried and not kept: a third estimate for flagged photos only, with a 45 px window (the
//! texture photos' windows are too small, `size.rs`), all candidates chosen by the same
//! score: TUNE 23 → 24, TREMOR 19 → 20, TEXTURE 17 → 17 of 44 / 44 / 36 at ratio ≤ 3, too
//! little for 1.5× the time on those photos. On flagged photos both candidates usually fail
//! (the better of the two passes on 8 of 34), so the flag cannot steer the choice either.
//! A second sign, the kept restoration's re-blur residual over the photo's noise variance,
//! caught 3 more held-out failures at σ = 0.01 but fired on good restorations of cleaner
//! photos (σ = 0.003) as often as on bad ones; with a signal term in the denominator it
//! flagged no passing case on the tuning splits at three noise levels but held out added 2
//! caught failures and 1 false alarm over 192 cases, so it is not shipped either
//! (`core/benches/deconv_set.md`).

use super::super::Psf;

/// Agreement below which a blind kernel is reported as uncertain (`deblur` documents:
/// `kernel.uncertain`). Chosen on the tuning splits above (0.7: 26 flagged, 7 at ratio ≤ 3;
/// 0.85: 43 flagged, 14; 0.9: 70, 25).
pub const UNCERTAIN_AGREEMENT: f64 = 0.8;

/// The agreement below which a kernel is uncertain for a photo of noise σ̂ (normalised
/// intensity, `estimate_noise_sigma`). Noise makes the two candidates differ even where the
/// photo pins the kernel down: with TUNE regenerated at σ = 0.02 (`examples/blind_eval.rs`,
/// `BLIND_NOISE`) passing cases agree at 0.26–0.85 and a fixed 0.8 flags 43 of 44 cases, 21
/// of them passing. So the threshold is [`UNCERTAIN_AGREEMENT`] up to σ̂ = 0.01 (the level it
/// was chosen at) and falls by `AGREEMENT_NOISE_SLOPE` (35) per unit of σ̂ above, to 0.45 at
/// σ̂ = 0.02; beyond the noise it was measured at it is not extrapolated. Chosen on TUNE at
/// σ = 0.015 and TUNE and TREMOR at σ = 0.02; on EVAL5, held out and regenerated at
/// σ = 0.02, it flags 16 of 48 cases, 4 of them at error ratio ≤ 3 (the others: 26 of 32),
/// where 0.8 flagged 41, 24 passing (`core/benches/deconv_set.md`).
pub fn uncertain_agreement(noise_sigma: f64) -> f64 {
    let excess = noise_sigma.clamp(NOISE_CHOSEN_AT, NOISE_MEASURED_TO) - NOISE_CHOSEN_AT;
    UNCERTAIN_AGREEMENT - AGREEMENT_NOISE_SLOPE * excess
}

/// Fall of [`uncertain_agreement`] per unit of noise σ̂ above [`NOISE_CHOSEN_AT`].
const AGREEMENT_NOISE_SLOPE: f64 = 35.0;

/// Noise σ of the splits [`UNCERTAIN_AGREEMENT`] was chosen on.
const NOISE_CHOSEN_AT: f64 = 0.01;

/// Highest noise σ the threshold was measured at; above it [`uncertain_agreement`] stays put.
const NOISE_MEASURED_TO: f64 = 0.02;

/// Integer shifts, in px, over which [`kernel_agreement`] aligns the two kernels: both are
/// re-centred on their centroid, so their paths can differ in position only by the mass
/// their faint ends add.
pub const AGREEMENT_SHIFT: usize = 4;

/// Largest normalised correlation `⟨a, shift(b)⟩ / (‖a‖‖b‖)` over integer shifts of up to
/// `max_shift` px, both kernels centred on their windows: 1 for the same kernel anywhere
/// within reach, 0 for supports that never overlap.
pub fn kernel_agreement(a: &Psf, b: &Psf, max_shift: usize) -> f64 {
    let norm = |k: &Psf| k.data.iter().map(|v| v * v).sum::<f64>().sqrt();
    let (na, nb) = (norm(a), norm(b));
    if na <= 0.0 || nb <= 0.0 {
        return 0.0;
    }
    let ms = max_shift as isize;
    // Offset of b's window in a's frame for a zero shift (centres aligned).
    let ox = (b.width / 2) as isize - (a.width / 2) as isize;
    let oy = (b.height / 2) as isize - (a.height / 2) as isize;
    let mut best = 0.0f64;
    for dy in -ms..=ms {
        for dx in -ms..=ms {
            let mut s = 0.0;
            for (y, row) in a.data.chunks(a.width).enumerate() {
                let by = y as isize + oy + dy;
                if by < 0 || by >= b.height as isize {
                    continue;
                }
                let brow = &b.data[by as usize * b.width..(by as usize + 1) * b.width];
                for (x, &v) in row.iter().enumerate() {
                    let bx = x as isize + ox + dx;
                    if v != 0.0 && bx >= 0 && bx < b.width as isize {
                        s += v * brow[bx as usize];
                    }
                }
            }
            best = best.max(s);
        }
    }
    (best / (na * nb)).clamp(0.0, 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The threshold is the chosen one up to σ̂ = 0.01, falls linearly above, and is not
    /// extrapolated past σ̂ = 0.02.
    #[test]
    fn the_threshold_falls_with_the_noise_within_the_measured_range() {
        assert_eq!(uncertain_agreement(0.0), UNCERTAIN_AGREEMENT);
        assert_eq!(uncertain_agreement(0.01), UNCERTAIN_AGREEMENT);
        assert!((uncertain_agreement(0.015) - 0.625).abs() < 1e-12);
        assert!((uncertain_agreement(0.02) - 0.45).abs() < 1e-12);
        assert_eq!(uncertain_agreement(0.05), uncertain_agreement(0.02));
        assert!(uncertain_agreement(0.012) > uncertain_agreement(0.018));
    }

    fn kernel(ks: usize, points: &[(usize, usize)]) -> Psf {
        let mut data = vec![0.0; ks * ks];
        for &(x, y) in points {
            data[y * ks + x] = 1.0;
        }
        Psf::from_weights(ks, ks, data).expect("psf")
    }

    /// Same kernel: 1, also shifted within reach; disjoint: 0; partial overlap in between;
    /// symmetric; windows of different sizes are compared centre to centre.
    #[test]
    fn agreement_is_a_normalised_aligned_correlation() {
        let line = kernel(15, &[(5, 7), (6, 7), (7, 7), (8, 7)]);
        assert!((kernel_agreement(&line, &line, 4) - 1.0).abs() < 1e-12);
        let moved = kernel(15, &[(9, 11), (10, 11), (11, 11), (12, 11)]);
        assert!((kernel_agreement(&line, &moved, 4) - 1.0).abs() < 1e-12);
        assert!(kernel_agreement(&line, &moved, 2) < 0.01);
        let vertical = kernel(15, &[(7, 5), (7, 6), (7, 7), (7, 8)]);
        let a = kernel_agreement(&line, &vertical, 0);
        assert!((a - 0.25).abs() < 1e-12, "one of four taps shared: {a}");
        assert!((a - kernel_agreement(&vertical, &line, 0)).abs() < 1e-12);
        let wide = kernel(21, &[(8, 10), (9, 10), (10, 10), (11, 10)]);
        assert!((kernel_agreement(&line, &wide, 0) - 1.0).abs() < 1e-12);
        let far = kernel(15, &[(0, 0)]);
        assert_eq!(kernel_agreement(&line, &far, 4), 0.0);
    }
}
