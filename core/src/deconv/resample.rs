//! Separable resampling with a triangle (bilinear) filter widened when shrinking, so that
//! downsampling averages instead of aliasing — the pyramid of the blind solver.

/// Weights of one output sample: source indices and normalised weights.
fn taps(n_in: usize, n_out: usize) -> Vec<Vec<(usize, f64)>> {
    let f = n_out as f64 / n_in as f64;
    let support = if f < 1.0 { 1.0 / f } else { 1.0 };
    (0..n_out)
        .map(|o| {
            let s = (o as f64 + 0.5) / f - 0.5;
            let lo = (s - support).floor() as isize;
            let hi = (s + support).ceil() as isize;
            let mut t: Vec<(usize, f64)> = Vec::new();
            for i in lo..=hi {
                let wgt = 1.0 - ((i as f64 - s) / support).abs();
                if wgt > 0.0 {
                    let j = i.clamp(0, n_in as isize - 1) as usize;
                    t.push((j, wgt));
                }
            }
            let sum: f64 = t.iter().map(|(_, w)| w).sum();
            if sum > 0.0 {
                for (_, w) in &mut t {
                    *w /= sum;
                }
            } else {
                t.push((s.round().clamp(0.0, n_in as f64 - 1.0) as usize, 1.0));
            }
            t
        })
        .collect()
}

/// Resizes a row-major `w × h` array to `nw × nh`.
pub fn resize(data: &[f64], w: usize, h: usize, nw: usize, nh: usize) -> Vec<f64> {
    let tx = taps(w, nw);
    let ty = taps(h, nh);
    let mut rows = vec![0.0f64; h * nw];
    for y in 0..h {
        let src = &data[y * w..(y + 1) * w];
        for (x, t) in tx.iter().enumerate() {
            rows[y * nw + x] = t.iter().map(|&(i, wt)| wt * src[i]).sum();
        }
    }
    let mut out = vec![0.0f64; nh * nw];
    for (y, t) in ty.iter().enumerate() {
        for x in 0..nw {
            out[y * nw + x] = t.iter().map(|&(i, wt)| wt * rows[i * nw + x]).sum();
        }
    }
    out
}
