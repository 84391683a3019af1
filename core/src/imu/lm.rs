//! A small dense Levenberg-Marquardt for the 9-parameter IMU models (the crate's `optim::lm` is
//! shaped for bundle adjustment with Schur complements). Central-difference Jacobian, columns
//! evaluated in parallel; Marquardt's diagonal scaling.

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

use crate::error::CoreResult;
use crate::progress::Progress;

/// Outcome of [`solve`].
#[derive(Debug, Clone)]
pub(crate) struct LmResult {
    pub x: Vec<f64>,
    pub residuals: Vec<f64>,
    /// ½ Σ r² (Ceres convention, as the peer reports).
    pub cost: f64,
    pub iterations: usize,
    pub converged: bool,
    /// Inverse of JᵀJ at the solution (parameter covariance up to the residual variance).
    pub jtj_inv: Option<DMatrix<f64>>,
}

fn half_sq(r: &[f64]) -> f64 {
    0.5 * r.iter().map(|v| v * v).sum::<f64>()
}

fn jacobian<F>(f: &F, x: &[f64], m: usize) -> DMatrix<f64>
where
    F: Fn(&[f64]) -> Vec<f64> + Sync,
{
    let cols: Vec<Vec<f64>> = (0..x.len())
        .into_par_iter()
        .map(|j| {
            let h = 1e-6 * x[j].abs().max(1e-2);
            let mut xp = x.to_vec();
            xp[j] += h;
            let rp = f(&xp);
            xp[j] = x[j] - h;
            let rm = f(&xp);
            rp.iter()
                .zip(&rm)
                .map(|(a, b)| (a - b) / (2.0 * h))
                .collect()
        })
        .collect();
    DMatrix::from_fn(m, x.len(), |i, j| cols[j].get(i).copied().unwrap_or(0.0))
}

/// Minimise ½‖f(x)‖² from `x0`.
pub(crate) fn solve<F>(
    x0: &[f64],
    f: F,
    max_iter: usize,
    progress: &dyn Progress,
) -> CoreResult<LmResult>
where
    F: Fn(&[f64]) -> Vec<f64> + Sync,
{
    let mut x = x0.to_vec();
    let mut r = f(&x);
    let m = r.len();
    let mut cost = half_sq(&r);
    let mut lambda = 1e-3;
    let mut converged = false;
    let mut it = 0;
    let mut jtj = DMatrix::<f64>::zeros(x.len(), x.len());
    while it < max_iter {
        it += 1;
        progress.check()?;
        let j = jacobian(&f, &x, m);
        jtj = j.transpose() * &j;
        let g = j.transpose() * DVector::from_column_slice(&r);
        if g.amax() < 1e-15 {
            converged = true;
            break;
        }
        let mut improved = false;
        for _ in 0..12 {
            let mut a = jtj.clone();
            for k in 0..x.len() {
                a[(k, k)] += lambda * jtj[(k, k)].max(1e-12);
            }
            let Some(ch) = a.cholesky() else {
                lambda *= 10.0;
                continue;
            };
            let delta = ch.solve(&(-&g));
            let xn: Vec<f64> = x.iter().zip(delta.iter()).map(|(a, d)| a + d).collect();
            let rn = f(&xn);
            let cn = half_sq(&rn);
            if cn.is_finite() && cn < cost {
                let rel = (cost - cn) / cost.max(1e-300);
                let step = delta.norm() / (x.iter().map(|v| v * v).sum::<f64>().sqrt() + 1e-12);
                x = xn;
                r = rn;
                cost = cn;
                lambda = (lambda / 3.0).max(1e-12);
                improved = true;
                if rel < 1e-14 || step < 1e-13 {
                    converged = true;
                }
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            converged = true; // no descent possible from here: a (local) minimum
            break;
        }
        if converged {
            break;
        }
    }
    let jtj_inv = jtj.try_inverse();
    Ok(LmResult {
        x,
        residuals: r,
        cost,
        iterations: it,
        converged,
        jtj_inv,
    })
}
