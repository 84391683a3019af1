use nalgebra::{DMatrix, Matrix2x3, Matrix2xX, Vector2, Vector3, Vector6};

use super::*;
use crate::error::CoreError;
use crate::lie::Se3;
use crate::progress::{NoProgress, Progress};

/// A tiny pinhole problem: shared `[f, cx, cy]`, poses of a rigid 3-D point set, residual
/// `f·(x/z, y/z) + c − measured`.
struct Toy {
    points: Vec<Vector3<f64>>,
    meas: Vec<Vec<Vector2<f64>>>,
}

fn project(s: &[f64; 3], pose: &Se3, p: &Vector3<f64>) -> Option<Vector2<f64>> {
    let q = pose.act(p);
    (q.z > 1e-6).then(|| Vector2::new(s[0] * q.x / q.z + s[1], s[0] * q.y / q.z + s[2]))
}

impl SchurProblem for Toy {
    type Context = [f64; 3];
    fn num_shared(&self) -> usize {
        3
    }
    fn num_blocks(&self) -> usize {
        self.meas.len()
    }
    fn num_observations(&self, _block: usize) -> usize {
        self.points.len()
    }
    fn prepare(&self, shared: &[f64]) -> Option<[f64; 3]> {
        (shared[0] > 0.0).then(|| [shared[0], shared[1], shared[2]])
    }
    fn residual(&self, s: &[f64; 3], b: usize, o: usize, pose: &Se3) -> Option<Vector2<f64>> {
        Some(project(s, pose, &self.points[o])? - self.meas[b][o])
    }
    fn linearize(&self, s: &[f64; 3], b: usize, o: usize, pose: &Se3) -> Option<Linearized> {
        let r = self.residual(s, b, o, pose)?;
        let q = pose.act(&self.points[o]);
        let (x, y) = (q.x / q.z, q.y / q.z);
        let dq = Matrix2x3::new(
            s[0] / q.z,
            0.0,
            -s[0] * x / q.z,
            0.0,
            s[0] / q.z,
            -s[0] * y / q.z,
        );
        let jp = dq * pose.act_jacobian_left(&self.points[o]);
        let js = Matrix2xX::from_row_slice(&[x, 1.0, 0.0, y, 0.0, 1.0]);
        Some((r, js, jp))
    }
}

const TRUTH: [f64; 3] = [500.0, 320.0, 240.0];

fn truth_poses() -> Vec<Se3> {
    vec![
        Se3::from_rvec_tvec(&Vector3::new(0.1, -0.2, 0.05), &Vector3::new(0.1, 0.0, 2.0)),
        Se3::from_rvec_tvec(&Vector3::new(-0.3, 0.1, 0.2), &Vector3::new(-0.2, 0.1, 2.5)),
        Se3::from_rvec_tvec(&Vector3::new(0.2, 0.4, -0.1), &Vector3::new(0.0, -0.1, 1.8)),
    ]
}

fn toy() -> Toy {
    let points: Vec<Vector3<f64>> = (0..8)
        .map(|i| {
            let i = i as f64;
            Vector3::new(
                0.3 * (i * 1.3).sin(),
                0.3 * (i * 0.7).cos(),
                0.2 * (i * 2.1).sin(),
            )
        })
        .collect();
    let meas = truth_poses()
        .iter()
        .map(|t| {
            points
                .iter()
                .map(|p| project(&TRUTH, t, p).expect("in front"))
                .collect()
        })
        .collect();
    Toy { points, meas }
}

fn perturbed_poses() -> Vec<Se3> {
    truth_poses()
        .iter()
        .map(|t| t.left_plus(&Vector6::new(0.02, -0.01, 0.05, 0.03, -0.02, 0.01)))
        .collect()
}

#[test]
fn lm_recovers_tiny_problem() {
    let p = toy();
    let mut shared = [450.0, 330.0, 230.0];
    let mut poses = perturbed_poses();
    let s = solve(
        &p,
        &mut shared,
        &[false; 3],
        &mut poses,
        &LmOptions::default(),
        &NoProgress,
    )
    .expect("solves");
    assert!(s.termination.converged(), "{s:?}");
    assert!(s.final_cost < 1e-14, "{s:?}");
    for (a, b) in shared.iter().zip(TRUTH) {
        assert!((a - b).abs() < 1e-6, "{shared:?}");
    }
    for (a, b) in poses.iter().zip(truth_poses()) {
        assert!(a.left_minus(&b).norm() < 1e-9);
    }
}

#[test]
fn lm_keeps_fixed_parameters() {
    let p = toy();
    let mut shared = [450.0, 321.0, 240.0];
    let mut poses = perturbed_poses();
    let s = solve(
        &p,
        &mut shared,
        &[false, true, false],
        &mut poses,
        &LmOptions::default(),
        &NoProgress,
    )
    .expect("solves");
    assert_eq!(shared[1], 321.0);
    assert!(s.final_cost > 0.0 && s.final_cost < s.initial_cost);
}

#[test]
fn lm_robust_loss_converges_with_an_outlier() {
    let mut p = toy();
    p.meas[1][3] += Vector2::new(30.0, -20.0);
    let mut shared = [480.0, 325.0, 235.0];
    let mut poses = perturbed_poses();
    let options = LmOptions {
        loss: RobustLoss::Cauchy { scale: 1.0 },
        ..LmOptions::default()
    };
    solve(
        &p,
        &mut shared,
        &[false; 3],
        &mut poses,
        &options,
        &NoProgress,
    )
    .expect("solves");
    for (a, b) in shared.iter().zip(TRUTH) {
        assert!((a - b).abs() < 0.5, "{shared:?}");
    }
}

struct Cancelled;
impl Progress for Cancelled {
    fn report(&self, _: &str, _: u64, _: u64) {}
    fn is_canceled(&self) -> bool {
        true
    }
}

#[test]
fn lm_cancel() {
    let p = toy();
    let mut shared = [450.0, 330.0, 230.0];
    let mut poses = perturbed_poses();
    let r = solve(
        &p,
        &mut shared,
        &[false; 3],
        &mut poses,
        &LmOptions::default(),
        &Cancelled,
    );
    assert!(matches!(r, Err(CoreError::Canceled)));
}

#[test]
fn lm_rejects_bad_sizes_and_bad_start() {
    let p = toy();
    let mut poses = perturbed_poses();
    let r = solve(
        &p,
        &mut [1.0, 2.0],
        &[false; 2],
        &mut poses,
        &LmOptions::default(),
        &NoProgress,
    );
    assert!(matches!(r, Err(CoreError::InvalidInput(_))));
    let r = solve(
        &p,
        &mut [-1.0, 2.0, 3.0],
        &[false; 3],
        &mut poses,
        &LmOptions::default(),
        &NoProgress,
    );
    assert!(matches!(r, Err(CoreError::NoSolution(_))));
}

/// The Schur-complement covariance equals the shared block of the dense `(JᵀJ)⁻¹`, with J
/// taken by central differences.
#[test]
fn marginal_covariance_matches_dense_inverse() {
    let mut p = toy();
    // Some noise so the point is a true minimum with non-zero residuals; irrelevant to JᵀJ.
    for (b, m) in p.meas.iter_mut().enumerate() {
        for (o, v) in m.iter_mut().enumerate() {
            *v += Vector2::new(
                ((b * 7 + o) as f64).sin() * 0.3,
                ((b + o * 3) as f64).cos() * 0.3,
            );
        }
    }
    let shared = TRUTH;
    let poses = truth_poses();
    let cov = marginal_shared_covariance(&p, &shared, &[false; 3], &poses).expect("cov");

    let nb = poses.len();
    let n = 3 + 6 * nb;
    let rows = 2 * p.points.len() * nb;
    let residuals = |x: &[f64]| -> Vec<f64> {
        let s = [x[0], x[1], x[2]];
        let mut out = Vec::with_capacity(rows);
        for (b, pose) in poses.iter().enumerate() {
            let d = Vector6::from_column_slice(&x[3 + 6 * b..9 + 6 * b]);
            let t = pose.left_plus(&d);
            for o in 0..p.points.len() {
                let r = p.residual(&s, b, o, &t).expect("projects");
                out.extend([r.x, r.y]);
            }
        }
        out
    };
    let mut x0 = vec![0.0; n];
    x0[..3].copy_from_slice(&shared);
    let mut j = DMatrix::<f64>::zeros(rows, n);
    for k in 0..n {
        let h = if k < 3 { 1e-4 } else { 1e-7 };
        let (mut xp, mut xm) = (x0.clone(), x0.clone());
        xp[k] += h;
        xm[k] -= h;
        let (rp, rm) = (residuals(&xp), residuals(&xm));
        for i in 0..rows {
            j[(i, k)] = (rp[i] - rm[i]) / (2.0 * h);
        }
    }
    let dense = (j.transpose() * &j).try_inverse().expect("invertible");
    for a in 0..3 {
        for b in 0..3 {
            let rel =
                (cov[(a, b)] - dense[(a, b)]).abs() / dense[(a, a)].sqrt() / dense[(b, b)].sqrt();
            assert!(
                rel < 1e-5,
                "({a},{b}): {} vs {}",
                cov[(a, b)],
                dense[(a, b)]
            );
        }
    }
}

#[test]
fn losses() {
    let h = RobustLoss::Huber { scale: 2.0 };
    assert_eq!(h.rho(1.0), 1.0);
    assert_eq!(h.weight(1.0), 1.0);
    assert!((h.rho(16.0) - (2.0 * 2.0 * 4.0 - 4.0)).abs() < 1e-12);
    assert!((h.weight(16.0) - 0.5).abs() < 1e-12);
    let c = RobustLoss::Cauchy { scale: 1.0 };
    assert!((c.rho(1e-8) - 1e-8).abs() < 1e-15);
    assert!((c.weight(3.0) - 0.25).abs() < 1e-12);
    assert!(RobustLoss::Huber { scale: 0.0 }.validate().is_err());
    assert!(RobustLoss::Cauchy { scale: f64::NAN }.validate().is_err());
    assert!(RobustLoss::None.validate().is_ok());
}
