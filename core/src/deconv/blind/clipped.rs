//! The clipped-pixel mask of the kernel estimate: where the sensor saturated, the linear blur
//! model does not hold, so those gradients are left out of the kernel step.

use super::super::Plane;

/// 1 where a pixel or one of its 8 neighbours is at or above `level`, 0 elsewhere; `None`
/// when nothing is clipped. A clipped pixel breaks the linear blur model the kernel step fits
/// (its gradient is flat where the blurred light was not), so its gradients are left out, as
/// in the outlier masks of S. Cho, J. Wang, S. Lee, "Handling outliers in non-blind image
/// deconvolution", ICCV 2011 and J. Pan, Z. Lin, Z. Su, M.-H. Yang, "Robust kernel
/// estimation with outliers handling for image deblurring", CVPR 2016; the neighbours go too
/// because a gradient is a difference with the next pixel.
///
/// Measured (`blind_eval -- tune`, mean PSNR of the aligned restoration over 44 cases, final
/// TV one-sided in both): with 1–6 % of each scene over-exposed (`BLIND_SAT=1`) 19.57 dB
/// without the mask, 19.58 with it; with small light sources 3–30× white (`BLIND_SAT=2`,
/// the streaks of night shots) 18.69 → 18.93 dB (18.95 once the window estimate also skips
/// clipped pixels, [`super::gradient_autocorrelation`]). That is all it buys: the L0 latent is still
/// solved from the clipped data, so near a highlight it is wrong and the kernel step sees it
/// through every unclipped pixel within the kernel's reach. Growing the mask by that reach
/// (half or all of the window) to hide them was worse, 18.32 and 17.91 dB: it leaves the
/// kernel step too few edges. Solving the latent with the same one-sided term (majorise-minimise:
/// clipped `y` replaced by `max(y, k ⊛ x)` at every splitting step) gave 18.82 dB against
/// 18.93, so it is not done.
pub(super) fn clipped_map(img: &Plane, level: f32) -> Option<Vec<f64>> {
    let (w, h) = (img.width, img.height);
    if !img.data.iter().any(|&v| v >= level) {
        return None;
    }
    let mut out = vec![0.0f64; w * h];
    for y in 0..h {
        for x in 0..w {
            if img.data[y * w + x] >= level {
                for ny in y.saturating_sub(1)..(y + 2).min(h) {
                    for nx in x.saturating_sub(1)..(x + 2).min(w) {
                        out[ny * w + nx] = 1.0;
                    }
                }
            }
        }
    }
    Some(out)
}
