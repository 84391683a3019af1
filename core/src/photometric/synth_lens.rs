//! A soft lens for the synthetic renderer ([`super::synth`]): real cameras are not sharp at
//! the pixel scale, and optical blur acts on the irradiance, before the response.

/// The irradiance `irr` (a function of the continuous pixel position, pixel centres at
/// integers) seen through a Gaussian blur of `sigma` pixels, each pixel integrating its area:
/// 2 × 2 supersampling, the separable blur, then the box. Row-major, `width × height`. So a
/// soft edge is recorded as `f` of mixed irradiance, not as a mixture of recorded values.
pub(super) fn blurred_irradiance(
    width: usize,
    height: usize,
    sigma: f64,
    irr: impl Fn(f64, f64) -> f64,
) -> Vec<f64> {
    const SS: usize = 2;
    let s = sigma * SS as f64;
    let m = (3.0 * s).ceil() as usize;
    let (gw, gh) = (width * SS + 2 * m, height * SS + 2 * m);
    let at = |i: usize| (i as f64 - m as f64 + 0.5) / SS as f64 - 0.5;
    let mut grid: Vec<f64> = (0..gh)
        .flat_map(|gy| (0..gw).map(move |gx| (gx, gy)))
        .map(|(gx, gy)| irr(at(gx), at(gy)))
        .collect();
    let taps: Vec<f64> = {
        let t: Vec<f64> = (0..=2 * m)
            .map(|k| (-((k as f64 - m as f64) / s).powi(2) / 2.0).exp())
            .collect();
        let sum: f64 = t.iter().sum();
        t.iter().map(|v| v / sum).collect()
    };
    // Separable blur; rows then columns, each output only where the taps fit.
    let mut tmp = vec![0.0; gw * gh];
    for y in 0..gh {
        for x in m..gw - m {
            tmp[y * gw + x] = (0..taps.len())
                .map(|k| taps[k] * grid[y * gw + x + k - m])
                .sum();
        }
    }
    for y in m..gh - m {
        for x in m..gw - m {
            grid[y * gw + x] = (0..taps.len())
                .map(|k| taps[k] * tmp[(y + k - m) * gw + x])
                .sum();
        }
    }
    let mut out = Vec::with_capacity(width * height);
    for y in 0..height {
        for x in 0..width {
            let (x0, y0) = (m + x * SS, m + y * SS);
            let mut acc = 0.0;
            for dy in 0..SS {
                for dx in 0..SS {
                    acc += grid[(y0 + dy) * gw + x0 + dx];
                }
            }
            out.push(acc / (SS * SS) as f64);
        }
    }
    out
}
