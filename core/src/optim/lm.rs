//! Levenberg-Marquardt with a Schur complement over independent pose blocks.

use nalgebra::{DMatrix, DVector, Matrix2x6, Matrix2xX, Matrix6, Matrix6xX, Vector2, Vector6};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::RobustLoss;
use crate::error::{CoreError, CoreResult};
use crate::lie::Se3;
use crate::progress::Progress;

/// Lower and upper clamps of the Marquardt diagonal `diag(JᵀJ)`, as in Ceres: a parameter that
/// no residual sees still gets a finite, positive damping, and a huge one cannot freeze the rest.
const DIAG_MIN: f64 = 1e-6;
const DIAG_MAX: f64 = 1e32;
/// λ beyond which no step can decrease the cost any more: the solver stops there.
const LAMBDA_MAX: f64 = 1e16;

/// One linearised observation: residual `r` (prediction − measurement, 2 values), `∂r/∂shared`
/// (2 × number of shared parameters) and `∂r/∂δ` for the left pose update `exp(δ)·T`.
pub type Linearized = (Vector2<f64>, Matrix2xX<f64>, Matrix2x6<f64>);

/// A bundle-adjustment-shaped least-squares problem: a small vector of shared parameters
/// (camera intrinsics and distortion) and many 6-DoF pose blocks, each with its own set of
/// 2-D observations that depend on the shared parameters and on that one pose only.
///
/// This is the layout of Ceres' calibration problems and of mrcal (Agarwal et al., Ceres Solver;
/// Kogan, mrcal): the Hessian is "arrow-shaped", with a block-diagonal pose part, which the
/// solver exploits through the Schur complement (Triggs et al., "Bundle adjustment — a modern
/// synthesis", 2000, §6.1).
pub trait SchurProblem: Sync {
    /// What [`SchurProblem::residual`] and [`SchurProblem::linearize`] need, built once per
    /// evaluation from the shared parameters (for cameras: the validated model, whose
    /// construction is too costly to repeat per observation).
    type Context: Sync;

    /// Number of shared parameters.
    fn num_shared(&self) -> usize;

    /// Number of pose blocks.
    fn num_blocks(&self) -> usize;

    /// Number of 2-D observations in a block.
    fn num_observations(&self, block: usize) -> usize;

    /// The context for these shared parameters, or `None` when they are outside the domain
    /// (the step that led there is then rejected).
    fn prepare(&self, shared: &[f64]) -> Option<Self::Context>;

    /// Residual of one observation, or `None` if it cannot be evaluated (e.g. the point does
    /// not project).
    fn residual(
        &self,
        ctx: &Self::Context,
        block: usize,
        obs: usize,
        pose: &Se3,
    ) -> Option<Vector2<f64>>;

    /// Residual and Jacobians of one observation, or `None` like [`SchurProblem::residual`].
    fn linearize(
        &self,
        ctx: &Self::Context,
        block: usize,
        obs: usize,
        pose: &Se3,
    ) -> Option<Linearized>;
}

/// Settings of [`solve`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LmOptions {
    /// Maximum number of step attempts (accepted or not), each one a linear solve.
    pub max_iterations: usize,
    /// Stop when an accepted step decreases the cost by less than this fraction of it.
    pub function_tolerance: f64,
    /// Stop when the step is smaller than this fraction of the parameter norm.
    pub parameter_tolerance: f64,
    /// Stop when the largest gradient component is below this.
    pub gradient_tolerance: f64,
    /// Initial damping relative to the Marquardt diagonal.
    pub initial_lambda: f64,
    /// Robust loss on each observation's squared residual norm.
    pub loss: RobustLoss,
}

impl Default for LmOptions {
    fn default() -> Self {
        Self {
            max_iterations: 100,
            function_tolerance: 1e-12,
            parameter_tolerance: 1e-12,
            gradient_tolerance: 1e-12,
            initial_lambda: 1e-4,
            loss: RobustLoss::None,
        }
    }
}

/// Why [`solve`] stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub enum Termination {
    /// Relative cost decrease below `function_tolerance`.
    FunctionTolerance,
    /// Step below `parameter_tolerance`.
    ParameterTolerance,
    /// Gradient below `gradient_tolerance`.
    GradientTolerance,
    /// The damping grew until no step could decrease the cost: a (local) minimum to round-off.
    NoFurtherDecrease,
    /// `max_iterations` reached before any convergence test passed.
    MaxIterations,
}

impl Termination {
    /// Whether the solver stopped on a convergence test (not on the iteration budget).
    pub fn converged(&self) -> bool {
        !matches!(self, Termination::MaxIterations)
    }
}

/// What [`solve`] did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LmSummary {
    /// Step attempts made (accepted or rejected).
    pub iterations: usize,
    /// Accepted steps.
    pub accepted: usize,
    /// Robust cost ½Σρ(‖r‖²) at the start.
    pub initial_cost: f64,
    /// Robust cost at the end.
    pub final_cost: f64,
    /// Why it stopped.
    pub termination: Termination,
}

/// The normal equations `JᵀWJ`, `JᵀWr` in arrow form.
struct Normal {
    /// Shared-shared block (S×S).
    v: DMatrix<f64>,
    /// Shared gradient (S).
    gs: DVector<f64>,
    /// Per block: pose-pose (6×6), shared-pose (6×S, stored transposed as Wᵀ) and pose gradient.
    blocks: Vec<(Matrix6<f64>, Matrix6xX<f64>, Vector6<f64>)>,
    /// Robust cost at the linearisation point.
    cost: f64,
}

/// Robust cost ½Σρ(‖r‖²), or `None` when the shared parameters or any observation cannot be
/// evaluated.
pub fn cost<P: SchurProblem>(
    problem: &P,
    shared: &[f64],
    poses: &[Se3],
    loss: &RobustLoss,
) -> Option<f64> {
    let ctx = problem.prepare(shared)?;
    cost_with(problem, &ctx, poses, loss)
}

/// Observations below which the blocks are evaluated on the calling thread: handing a small
/// evaluation to the thread pool (and waking it) costs more than it saves.
const PARALLEL_MIN_OBSERVATIONS: usize = 4096;

/// `f(b)` for every block, in block order; across the thread pool only for large problems.
fn map_blocks<P: SchurProblem, T: Send>(
    problem: &P,
    f: impl Fn(usize) -> Option<T> + Sync + Send,
) -> Option<Vec<T>> {
    let nb = problem.num_blocks();
    let total: usize = (0..nb).map(|b| problem.num_observations(b)).sum();
    if nb > 1 && total >= PARALLEL_MIN_OBSERVATIONS {
        (0..nb).into_par_iter().map(f).collect()
    } else {
        (0..nb).map(f).collect()
    }
}

/// [`cost`] with a prepared context.
fn cost_with<P: SchurProblem>(
    problem: &P,
    ctx: &P::Context,
    poses: &[Se3],
    loss: &RobustLoss,
) -> Option<f64> {
    let per_block = map_blocks(problem, |b| {
        let mut c = 0.0;
        for o in 0..problem.num_observations(b) {
            let r = problem.residual(ctx, b, o, &poses[b])?;
            c += loss.rho(r.norm_squared());
        }
        Some(c)
    });
    // Summed in block order so the result does not depend on the thread schedule.
    let total = 0.5 * per_block?.iter().sum::<f64>();
    total.is_finite().then_some(total)
}

/// Builds the IRLS-weighted normal equations at (shared, poses); columns of `fixed` shared
/// parameters are dropped (zeroed).
fn normal_equations<P: SchurProblem>(
    problem: &P,
    ctx: &P::Context,
    fixed: &[bool],
    poses: &[Se3],
    loss: &RobustLoss,
) -> Option<Normal> {
    let ns = problem.num_shared();
    // Only the free shared columns are accumulated: those of fixed parameters stay zero (for a
    // pose-only problem, e.g. PnP, the shared part costs nothing).
    let free: Vec<usize> = (0..ns).filter(|&k| !fixed[k]).collect();
    let per_block: Option<Vec<_>> = map_blocks(problem, |b| {
        let mut u = Matrix6::<f64>::zeros();
        let mut wt = Matrix6xX::<f64>::zeros(ns);
        let mut gp = Vector6::<f64>::zeros();
        let mut v = DMatrix::<f64>::zeros(ns, ns);
        let mut gs = DVector::<f64>::zeros(ns);
        let mut c = 0.0;
        for o in 0..problem.num_observations(b) {
            let (r, js, jp) = problem.linearize(ctx, b, o, &poses[b])?;
            let s = r.norm_squared();
            c += loss.rho(s);
            let w = loss.weight(s);
            let jpw = jp.transpose() * w;
            u += jpw * jp;
            gp += jpw * r;
            if free.is_empty() {
                continue;
            }
            // Plain loops over column-major storage: S is small and this is the innermost
            // accumulation (no temporaries on the heap).
            let jss = js.as_slice();
            let wts = wt.as_mut_slice();
            let vs = v.as_mut_slice();
            for (fi, &i) in free.iter().enumerate() {
                let (b0, b1) = (jss[2 * i], jss[2 * i + 1]);
                for (k, x) in wts[6 * i..6 * i + 6].iter_mut().enumerate() {
                    *x += jpw[(k, 0)] * b0 + jpw[(k, 1)] * b1;
                }
                let (a0, a1) = (w * b0, w * b1);
                gs[i] += a0 * r.x + a1 * r.y;
                // Upper triangle, v[(i, j)] for j ≥ i.
                for &j in &free[fi..] {
                    vs[j * ns + i] += a0 * jss[2 * j] + a1 * jss[2 * j + 1];
                }
            }
        }
        Some((u, wt, gp, v, gs, c))
    });
    let mut v = DMatrix::<f64>::zeros(ns, ns);
    let mut gs = DVector::<f64>::zeros(ns);
    let mut cost = 0.0;
    let mut blocks = Vec::with_capacity(problem.num_blocks());
    for (u, wt, gp, vb, gsb, c) in per_block? {
        v += vb;
        gs += gsb;
        cost += c;
        blocks.push((u, wt, gp));
    }
    for i in 0..ns {
        for j in 0..i {
            v[(i, j)] = v[(j, i)];
        }
    }
    // A fixed parameter gets an identity row so that its step is exactly zero.
    for (k, f) in fixed.iter().enumerate() {
        if *f {
            v[(k, k)] = 1.0;
            gs[k] = 0.0;
        }
    }
    let cost = 0.5 * cost;
    cost.is_finite().then_some(Normal {
        v,
        gs,
        blocks,
        cost,
    })
}

/// The damped step `(A + λ·D)·h = −g` by the Schur complement over the pose blocks, or `None`
/// when a factorisation fails (the caller then raises λ).
///
/// Each 6×6 pose block is factored on its own; the reduced system over the shared parameters,
/// `(V − Σ Wᵢ Uᵢ⁻¹ Wᵢᵀ)·δs = −gs + Σ Wᵢ Uᵢ⁻¹ gᵢ`, is small and dense (Cholesky); the pose
/// steps follow by back-substitution `δᵢ = −Uᵢ⁻¹(gᵢ + Wᵢᵀ δs)`.
fn damped_step(
    n: &Normal,
    fixed: &[bool],
    lambda: f64,
) -> Option<(DVector<f64>, Vec<Vector6<f64>>)> {
    let ns = n.v.nrows();
    let mut s = n.v.clone();
    for k in 0..ns {
        if !fixed[k] {
            s[(k, k)] += lambda * s[(k, k)].clamp(DIAG_MIN, DIAG_MAX);
        }
    }
    let mut b = -&n.gs;
    let mut back = Vec::with_capacity(n.blocks.len());
    for (u, wt, gp) in &n.blocks {
        let mut ud = *u;
        for k in 0..6 {
            ud[(k, k)] += lambda * u[(k, k)].clamp(DIAG_MIN, DIAG_MAX);
        }
        let chol = ud.cholesky()?;
        let uinv_wt = chol.solve(wt);
        let uinv_g = chol.solve(gp);
        s -= wt.transpose() * &uinv_wt;
        b += wt.transpose() * uinv_g;
        back.push((uinv_wt, uinv_g));
    }
    let ds = s.cholesky()?.solve(&b);
    let dp = back
        .iter()
        .map(|(uinv_wt, uinv_g)| -uinv_g - uinv_wt * &ds)
        .collect();
    Some((ds, dp))
}

/// Minimises ½Σρ(‖rᵢ‖²) over the free shared parameters and all poses by Levenberg-Marquardt.
///
/// * Poses are updated on the manifold, `T ← exp(δ)·T` (Solà et al., "A micro Lie theory for
///   state estimation in robotics", 2018), with the Jacobians of [`SchurProblem::linearize`]
///   taken with respect to that δ.
/// * Damping: Marquardt's scaled diagonal `A + λ·diag(A)` (Marquardt 1963), which makes the
///   step invariant to the very different scales of focal lengths and distortion coefficients;
///   λ is updated by Nielsen's rule (Nielsen, "Damping parameter in Marquardt's method", IMM
///   1999; Madsen, Nielsen, Tingleff, "Methods for non-linear least squares problems", 2004):
///   after an accepted step with gain ratio ϱ, λ ← λ·max(⅓, 1 − (2ϱ − 1)³); after a rejected
///   one λ ← λ·ν, ν ← 2ν.
/// * The robust loss enters as IRLS weights (see [`RobustLoss`]).
///
/// `fixed[k]` keeps shared parameter k at its current value. `progress.check()` is called before
/// every step attempt. Errors: [`CoreError::NoSolution`] when the starting point cannot be
/// evaluated, [`CoreError::InvalidInput`] on inconsistent sizes, [`CoreError::Canceled`].
pub fn solve<P: SchurProblem>(
    problem: &P,
    shared: &mut [f64],
    fixed: &[bool],
    poses: &mut [Se3],
    options: &LmOptions,
    progress: &dyn Progress,
) -> CoreResult<LmSummary> {
    let ns = problem.num_shared();
    if shared.len() != ns || fixed.len() != ns || poses.len() != problem.num_blocks() {
        return Err(CoreError::input(format!(
            "problem has {ns} shared parameters and {} blocks, got {} parameters, {} fixed flags, {} poses",
            problem.num_blocks(),
            shared.len(),
            fixed.len(),
            poses.len()
        )));
    }
    options.loss.validate()?;
    let loss = options.loss;
    let start_error = || {
        CoreError::NoSolution("the starting point of the optimisation cannot be evaluated".into())
    };
    // The context of the current shared parameters; rebuilt only when a step moves them.
    let mut ctx = problem.prepare(shared).ok_or_else(start_error)?;
    let mut normal =
        normal_equations(problem, &ctx, fixed, poses, &loss).ok_or_else(start_error)?;
    let initial_cost = normal.cost;
    let mut lambda = options.initial_lambda;
    let mut nu = 2.0;
    let mut iterations = 0;
    let mut accepted = 0;
    let termination = loop {
        let gmax = normal
            .gs
            .iter()
            .chain(normal.blocks.iter().flat_map(|(_, _, g)| g.iter()))
            .fold(0.0_f64, |m, g| m.max(g.abs()));
        if gmax <= options.gradient_tolerance {
            break Termination::GradientTolerance;
        }
        if iterations >= options.max_iterations {
            break Termination::MaxIterations;
        }
        if lambda > LAMBDA_MAX {
            break Termination::NoFurtherDecrease;
        }
        progress.check()?;
        iterations += 1;

        let Some((ds, dp)) = damped_step(&normal, fixed, lambda) else {
            lambda *= nu;
            nu *= 2.0;
            continue;
        };

        // Predicted decrease of the quadratic model: ½·hᵀ(λ·D·h − g).
        let mut predicted = 0.0;
        for k in 0..ns {
            if !fixed[k] {
                let d = normal.v[(k, k)].clamp(DIAG_MIN, DIAG_MAX);
                predicted += ds[k] * (lambda * d * ds[k] - normal.gs[k]);
            }
        }
        for ((u, _, g), d) in normal.blocks.iter().zip(&dp) {
            for k in 0..6 {
                let dd = u[(k, k)].clamp(DIAG_MIN, DIAG_MAX);
                predicted += d[k] * (lambda * dd * d[k] - g[k]);
            }
        }
        predicted *= 0.5;

        let new_shared: Vec<f64> = shared.iter().zip(ds.iter()).map(|(x, d)| x + d).collect();
        let new_poses: Vec<Se3> = poses.iter().zip(&dp).map(|(t, d)| t.left_plus(d)).collect();

        let step_sq = ds.norm_squared() + dp.iter().map(|d| d.norm_squared()).sum::<f64>();
        let x_sq = shared
            .iter()
            .zip(fixed)
            .filter(|(_, f)| !**f)
            .map(|(x, _)| x * x)
            .sum::<f64>()
            + poses.iter().map(|t| t.log().norm_squared()).sum::<f64>();
        let small_step = step_sq.sqrt()
            <= options.parameter_tolerance * (x_sq.sqrt() + options.parameter_tolerance);

        // `None`: the shared parameters did not move (all fixed, or a zero step), keep `ctx`.
        let new_ctx = if new_shared.as_slice() == &*shared {
            None
        } else {
            Some(problem.prepare(&new_shared))
        };
        let new_cost = match &new_ctx {
            None => cost_with(problem, &ctx, &new_poses, &loss),
            Some(Some(c)) => cost_with(problem, c, &new_poses, &loss),
            Some(None) => None,
        };
        match new_cost {
            Some(c) if predicted > 0.0 && c < normal.cost => {
                let rho = (normal.cost - c) / predicted;
                let decrease = normal.cost - c;
                let old_cost = normal.cost;
                let step_ctx = match &new_ctx {
                    Some(Some(c)) => c,
                    _ => &ctx,
                };
                let Some(n) = normal_equations(problem, step_ctx, fixed, &new_poses, &loss) else {
                    // Evaluable without Jacobians but not with them: treat as a failed step.
                    lambda *= nu;
                    nu *= 2.0;
                    continue;
                };
                shared.copy_from_slice(&new_shared);
                poses.copy_from_slice(&new_poses);
                if let Some(Some(c)) = new_ctx {
                    ctx = c;
                }
                normal = n;
                accepted += 1;
                lambda *= (1.0 - (2.0 * rho - 1.0).powi(3)).max(1.0 / 3.0);
                nu = 2.0;
                if decrease <= options.function_tolerance * old_cost {
                    break Termination::FunctionTolerance;
                }
                if small_step {
                    break Termination::ParameterTolerance;
                }
            }
            _ => {
                if small_step {
                    break Termination::ParameterTolerance;
                }
                lambda *= nu;
                nu *= 2.0;
            }
        }
    };
    Ok(LmSummary {
        iterations,
        accepted,
        initial_cost,
        final_cost: normal.cost,
        termination,
    })
}

/// `(JᵀJ)⁻¹` restricted to the shared parameters, i.e. the inverse of the Schur complement
/// `V − Σ Wᵢ Uᵢ⁻¹ Wᵢᵀ`: the Gauss-Newton covariance of the shared parameters marginalised over
/// all poses (Triggs et al. 2000, §6.1; this is also what OpenCV's `stdDeviationsIntrinsics` and
/// mrcal compute). Multiply by the residual variance σ² to get a covariance.
///
/// Built from the plain (unweighted) Jacobian at the given point; rows and columns of fixed
/// parameters are zero. Errors with [`CoreError::NoSolution`] when the point cannot be
/// evaluated or the information matrix is singular (a parameter the data do not constrain).
pub fn marginal_shared_covariance<P: SchurProblem>(
    problem: &P,
    shared: &[f64],
    fixed: &[bool],
    poses: &[Se3],
) -> CoreResult<DMatrix<f64>> {
    let unevaluable =
        || CoreError::NoSolution("covariance: the solution cannot be evaluated".into());
    let ctx = problem.prepare(shared).ok_or_else(unevaluable)?;
    let n =
        normal_equations(problem, &ctx, fixed, poses, &RobustLoss::None).ok_or_else(unevaluable)?;
    let ns = n.v.nrows();
    let mut s = n.v.clone();
    for (u, wt, _) in &n.blocks {
        let chol = u.cholesky().ok_or_else(|| {
            CoreError::NoSolution(
                "covariance: a pose is not constrained by its observations".into(),
            )
        })?;
        s -= wt.transpose() * chol.solve(wt);
    }
    let inv = s
        .cholesky()
        .ok_or_else(|| {
            CoreError::NoSolution(
                "covariance: the intrinsics are not constrained by the data (singular information matrix)"
                    .into(),
            )
        })?
        .inverse();
    let mut cov = DMatrix::<f64>::zeros(ns, ns);
    for i in 0..ns {
        for j in 0..ns {
            if !fixed[i] && !fixed[j] {
                cov[(i, j)] = inv[(i, j)];
            }
        }
    }
    Ok(cov)
}
