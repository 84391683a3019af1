//! The joint rig problem as a [`SchurProblem`]: every camera's intrinsics and the extrinsics of
//! cameras 1..N in the shared block, one board pose `T_cam0_board` per frame.
//!
//! Extrinsics are parameterised on the manifold around a reference: `T_i = exp(ξᵢ)·T̄ᵢ`, with
//! ξᵢ ∈ se(3) in the shared vector (6 numbers per camera). The solver moves ξ additively; the
//! Jacobian through the exponential map carries the left Jacobian `Jl(ξ)` (Solà et al., "A
//! micro Lie theory for state estimation in robotics", 2018, §4), so it stays exact away from
//! ξ = 0; after each solve the references are moved to the estimate (ξ back to 0), where the
//! covariance of ξ is that of a left perturbation of `T_i`.

use nalgebra::{Matrix2xX, Vector2, Vector3, Vector6};

use crate::calib::ModelKind;
use crate::camera::{Camera, CameraModel};
use crate::lie::Se3;
use crate::optim::{Linearized, SchurProblem};

/// One corner observed by one camera in one frame.
#[derive(Clone, Copy, Debug)]
pub(super) struct Obs {
    pub camera: usize,
    /// Board index of the corner.
    pub index: usize,
    pub object: Vector3<f64>,
    pub pixel: Vector2<f64>,
}

/// Layout of the shared vector.
#[derive(Clone, Debug)]
pub(super) struct Layout {
    pub kinds: Vec<ModelKind>,
    /// Offset of camera i's intrinsics.
    pub intrinsics: Vec<usize>,
    /// Offset of camera i's ξ (None for camera 0).
    pub extrinsics: Vec<Option<usize>>,
    pub len: usize,
}

impl Layout {
    pub fn new(kinds: &[ModelKind]) -> Self {
        let mut off = 0;
        let mut intrinsics = Vec::new();
        for k in kinds {
            intrinsics.push(off);
            off += k.num_params();
        }
        let mut extrinsics = vec![None];
        for _ in 1..kinds.len() {
            extrinsics.push(Some(off));
            off += 6;
        }
        Self {
            kinds: kinds.to_vec(),
            intrinsics,
            extrinsics,
            len: off,
        }
    }

    pub fn camera_params<'a>(&self, shared: &'a [f64], i: usize) -> &'a [f64] {
        let o = self.intrinsics[i];
        &shared[o..o + self.kinds[i].num_params()]
    }

    pub fn xi(&self, shared: &[f64], i: usize) -> Vector6<f64> {
        match self.extrinsics[i] {
            Some(o) => Vector6::from_column_slice(&shared[o..o + 6]),
            None => Vector6::zeros(),
        }
    }
}

/// What an evaluation needs: the cameras, the extrinsics and the `Jl(ξ)` of each.
pub(super) struct Ctx {
    cameras: Vec<Camera>,
    extrinsics: Vec<Se3>,
    jl: Vec<nalgebra::Matrix6<f64>>,
}

pub(super) struct RigProblem<'a> {
    pub layout: &'a Layout,
    /// References `T̄ᵢ` (identity for camera 0).
    pub reference: &'a [Se3],
    /// Observations per frame block.
    pub blocks: &'a [Vec<Obs>],
}

impl RigProblem<'_> {
    /// The extrinsic `T_i` for the shared vector.
    pub fn extrinsic(&self, shared: &[f64], i: usize) -> Se3 {
        Se3::exp(&self.layout.xi(shared, i)).compose(&self.reference[i])
    }

    /// The cameras for the shared vector, or `None` outside a model's domain.
    pub fn cameras(&self, shared: &[f64]) -> Option<Vec<Camera>> {
        (0..self.layout.kinds.len())
            .map(|i| {
                self.layout.kinds[i]
                    .camera(self.layout.camera_params(shared, i))
                    .ok()
            })
            .collect()
    }
}

impl SchurProblem for RigProblem<'_> {
    type Context = Ctx;

    fn num_shared(&self) -> usize {
        self.layout.len
    }

    fn num_blocks(&self) -> usize {
        self.blocks.len()
    }

    fn num_observations(&self, block: usize) -> usize {
        self.blocks[block].len()
    }

    fn prepare(&self, shared: &[f64]) -> Option<Ctx> {
        let cameras = self.cameras(shared)?;
        let n = cameras.len();
        Some(Ctx {
            cameras,
            extrinsics: (0..n).map(|i| self.extrinsic(shared, i)).collect(),
            jl: (0..n)
                .map(|i| Se3::jl(&self.layout.xi(shared, i)))
                .collect(),
        })
    }

    fn residual(&self, ctx: &Ctx, block: usize, obs: usize, pose: &Se3) -> Option<Vector2<f64>> {
        let o = &self.blocks[block][obs];
        let p = ctx.extrinsics[o.camera].act(&pose.act(&o.object));
        Some(ctx.cameras[o.camera].project(&p)? - o.pixel)
    }

    fn linearize(&self, ctx: &Ctx, block: usize, obs: usize, pose: &Se3) -> Option<Linearized> {
        let o = &self.blocks[block][obs];
        let c = o.camera;
        let t = &ctx.extrinsics[c];
        let y = pose.act(&o.object);
        let (uv, d_point, d_params) = ctx.cameras[c].project_with_jacobians(&t.act(&y))?;
        // ∂/∂δ of T·exp(δ)·T_b·X = R·∂(exp(δ)·T_b·X)/∂δ.
        let d_pose = d_point * t.rotation.matrix() * pose.act_jacobian_left(&o.object);
        let mut d_shared = Matrix2xX::<f64>::zeros(self.layout.len);
        let io = self.layout.intrinsics[c];
        for k in 0..d_params.ncols() {
            d_shared.set_column(io + k, &d_params.column(k));
        }
        if let Some(eo) = self.layout.extrinsics[c] {
            let d_xi = d_point * t.act_jacobian_left(&y) * ctx.jl[c];
            for k in 0..6 {
                d_shared.set_column(eo + k, &d_xi.column(k));
            }
        }
        Some((uv - o.pixel, d_shared, d_pose))
    }
}
