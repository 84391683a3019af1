//! The calibration problem as a [`SchurProblem`]: one camera, one pose per board view.

use nalgebra::{Vector2, Vector3};

use super::ModelKind;
use crate::camera::{Camera, CameraModel};
use crate::lie::Se3;
use crate::optim::{Linearized, SchurProblem};

/// The observations of one view used by the solver.
#[derive(Clone, Debug, Default)]
pub(crate) struct ViewData {
    /// Board points (z = 0), in board units.
    pub object: Vec<Vector3<f64>>,
    /// Measured pixels, same order.
    pub pixels: Vec<Vector2<f64>>,
}

/// Reprojection residuals `project(T·X) − x` of a set of views through one camera.
///
/// The solver's shared vector is the camera's parameter vector, except that with a tied aspect
/// ratio `fy = ratio·fx`: the solver's `fy` entry is then ignored (and must be marked fixed) and
/// the `fx` column carries `∂/∂fx + ratio·∂/∂fy`.
pub(crate) struct CalibProblem<'a> {
    pub kind: ModelKind,
    pub views: &'a [ViewData],
    pub aspect: Option<f64>,
    /// A camera already built for some parameters: [`SchurProblem::prepare`] clones it
    /// when asked for exactly those (building a camera validates its distortion, which costs
    /// far more than an evaluation of a small problem).
    pub known: Option<&'a Camera>,
}

impl CalibProblem<'_> {
    /// Camera parameters from the solver's shared vector.
    pub fn camera_params(&self, shared: &[f64]) -> Vec<f64> {
        let mut p = shared.to_vec();
        if let Some(ratio) = self.aspect {
            p[1] = ratio * p[0];
        }
        p
    }
}

impl SchurProblem for CalibProblem<'_> {
    type Context = Camera;

    fn num_shared(&self) -> usize {
        self.kind.num_params()
    }

    fn num_blocks(&self) -> usize {
        self.views.len()
    }

    fn num_observations(&self, block: usize) -> usize {
        self.views[block].object.len()
    }

    fn prepare(&self, shared: &[f64]) -> Option<Camera> {
        let params = self.camera_params(shared);
        if let Some(c) = self.known
            && ModelKind::of(c) == self.kind
            && c.params() == params.as_slice()
        {
            return Some(c.clone());
        }
        self.kind.camera(&params).ok()
    }

    fn residual(&self, cam: &Camera, block: usize, obs: usize, pose: &Se3) -> Option<Vector2<f64>> {
        let v = &self.views[block];
        Some(cam.project(&pose.act(&v.object[obs]))? - v.pixels[obs])
    }

    fn linearize(&self, cam: &Camera, block: usize, obs: usize, pose: &Se3) -> Option<Linearized> {
        let v = &self.views[block];
        let x = &v.object[obs];
        let (uv, d_point, mut d_params) = cam.project_with_jacobians(&pose.act(x))?;
        let d_pose = d_point * pose.act_jacobian_left(x);
        if let Some(ratio) = self.aspect {
            for r in 0..2 {
                d_params[(r, 0)] += ratio * d_params[(r, 1)];
                d_params[(r, 1)] = 0.0;
            }
        }
        Some((uv - v.pixels[obs], d_params, d_pose))
    }
}
