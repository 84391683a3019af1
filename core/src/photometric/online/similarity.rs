//! The roll and zoom of the video, measured once per frame from all tracks and chained, so
//! that each track's birth template and samples follow the scene ([`Similarity`]).

/// The rotation-and-scale part of an image motion, `x ↦ (c + i·s)·x` on offsets written as
/// complex numbers.
///
/// Why: a track is re-aligned to the patch where it was born. As the camera rolls and zooms
/// over the track's life, a translation-only match of that patch slides by a growing fraction
/// of a pixel, and the samples taken off the track centre no longer land on the same scene
/// points (diagnostic video, `diag_tests.rs`: median drift 0.26 px after 30 frames with roll
/// and zoom, 0.09 px without). Fitting a warp per patch is too noisy on 9×9 patches (median
/// drift doubled on the video without roll). The roll and zoom are instead measured once per
/// frame from all tracks ([`Similarity::fit`]), chained over the video, and each track uses
/// the ratio of the chain at the current frame to the chain at its birth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Similarity {
    pub c: f32,
    pub s: f32,
}

impl Similarity {
    pub const IDENTITY: Self = Self { c: 1.0, s: 0.0 };

    /// `self · o` applied to an offset.
    #[inline]
    pub fn apply(self, o: [f32; 2]) -> [f32; 2] {
        [self.c * o[0] - self.s * o[1], self.s * o[0] + self.c * o[1]]
    }

    /// Composition (complex product).
    pub fn then(self, o: Self) -> Self {
        Self {
            c: self.c * o.c - self.s * o.s,
            s: self.c * o.s + self.s * o.c,
        }
    }

    /// `self / o` (the motion from `o`'s frame to `self`'s).
    pub fn since(self, o: Self) -> Self {
        let n = o.c * o.c + o.s * o.s;
        Self {
            c: (self.c * o.c + self.s * o.s) / n,
            s: (self.s * o.c - self.c * o.s) / n,
        }
    }

    /// Least-squares rotation and scale mapping the points `from` to `to` (each set taken about
    /// its centroid), refitted once without the pairs whose residual exceeds three times the
    /// median (lost or jumping tracks). `None` with fewer than 8 pairs or a degenerate spread.
    pub fn fit(from: &[[f32; 2]], to: &[[f32; 2]]) -> Option<Self> {
        let all: Vec<usize> = (0..from.len().min(to.len())).collect();
        let first = CentredFit::new(from, to, &all)?;
        let res: Vec<f64> = all.iter().map(|&i| first.residual(from, to, i)).collect();
        let mut sorted = res.clone();
        sorted.sort_by(f64::total_cmp);
        // The upper middle value (not `stats::median`'s mean of the two for an even count):
        // the sweep numbers in the README were measured with it.
        let cut = 3.0 * sorted[sorted.len() / 2] + 1e-3;
        let inliers: Vec<usize> = all.into_iter().filter(|&i| res[i] <= cut).collect();
        CentredFit::new(from, to, &inliers).map(|f| Similarity {
            c: f.c as f32,
            s: f.s as f32,
        })
    }
}

/// A similarity fitted to the pairs `idx`, with the centroids it was fitted about.
struct CentredFit {
    c: f64,
    s: f64,
    from_mean: [f64; 2],
    to_mean: [f64; 2],
}

impl CentredFit {
    fn new(from: &[[f32; 2]], to: &[[f32; 2]], idx: &[usize]) -> Option<Self> {
        if idx.len() < 8 {
            return None;
        }
        let n = idx.len() as f64;
        let mean = |p: &[[f32; 2]]| {
            idx.iter().fold([0.0f64; 2], |a, &i| {
                [a[0] + f64::from(p[i][0]) / n, a[1] + f64::from(p[i][1]) / n]
            })
        };
        let mut fit = Self {
            c: 0.0,
            s: 0.0,
            from_mean: mean(from),
            to_mean: mean(to),
        };
        let (mut num_c, mut num_s, mut den) = (0.0f64, 0.0f64, 0.0f64);
        for &i in idx {
            let ([px, py], [qx, qy]) = fit.centred(from, to, i);
            // conj(p)·q
            num_c += px * qx + py * qy;
            num_s += px * qy - py * qx;
            den += px * px + py * py;
        }
        if den < 1e-6 {
            return None;
        }
        (fit.c, fit.s) = (num_c / den, num_s / den);
        Some(fit)
    }

    /// Pair `i` about the centroids.
    fn centred(&self, from: &[[f32; 2]], to: &[[f32; 2]], i: usize) -> ([f64; 2], [f64; 2]) {
        let (f, t) = (self.from_mean, self.to_mean);
        (
            [f64::from(from[i][0]) - f[0], f64::from(from[i][1]) - f[1]],
            [f64::from(to[i][0]) - t[0], f64::from(to[i][1]) - t[1]],
        )
    }

    /// Distance of pair `i` from the fit.
    fn residual(&self, from: &[[f32; 2]], to: &[[f32; 2]], i: usize) -> f64 {
        let ([px, py], [qx, qy]) = self.centred(from, to, i);
        (qx - (self.c * px - self.s * py)).hypot(qy - (self.s * px + self.c * py))
    }
}

#[cfg(test)]
mod tests {
    use super::Similarity;

    #[test]
    fn fit_recovers_rotation_and_scale_despite_outliers() {
        let truth = Similarity {
            c: 1.02 * 0.03f32.cos(),
            s: 1.02 * 0.03f32.sin(),
        };
        let from: Vec<[f32; 2]> = (0..40)
            .map(|i| [(i * 37 % 300) as f32, (i * 53 % 220) as f32])
            .collect();
        let mut to: Vec<[f32; 2]> = from
            .iter()
            .map(|&p| {
                let [x, y] = truth.apply(p);
                [x + 5.0, y - 3.0]
            })
            .collect();
        to[3][0] += 40.0;
        to[17][1] -= 25.0;
        let fit = Similarity::fit(&from, &to).expect("fit");
        assert!((fit.c - truth.c).abs() < 1e-4 && (fit.s - truth.s).abs() < 1e-4);
        let back = fit.then(truth).since(truth);
        assert!((back.c - fit.c).abs() < 1e-6 && (back.s - fit.s).abs() < 1e-6);
    }
}
