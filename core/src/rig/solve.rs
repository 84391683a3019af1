//! [`calibrate_rig`]: input checks, starting values (`init`), the joint solve with outlier
//! rejection, and the report (covariance, extrinsic σ, rectification and epipolar error).

use nalgebra::{DMatrix, Matrix3, Matrix3x6, Vector3};

use super::init::{CamView, CameraStart, extrinsics, start_camera};
use super::problem::{Layout, Obs, RigProblem};
use super::rectify::{epipolar_rms, stereo_rectify};
use super::types::*;
use crate::calib::{ModelKind, ParameterEstimate, PlanarTarget};
use crate::camera::CameraModel;
use crate::error::{CoreError, CoreResult};
use crate::lie::{Se3, So3};
use crate::optim::{LmOptions, Termination, marginal_shared_covariance, solve as lm_solve};
use crate::progress::Progress;

/// σ per coordinate from the median absolute residual component (Gaussian consistency).
const MAD_TO_SIGMA: f64 = 1.4826;

/// Calibrates a rig of 2..[`MAX_CAMERAS`] synchronised cameras from a planar target: each
/// camera alone first, then one joint Levenberg-Marquardt over every camera's intrinsics, the
/// extrinsics `T_cam_i_cam0` (on SE(3)) and one board pose per frame, with views where only some
/// cameras see the board (Zhang 2000 per camera; the joint stage is the bundle adjustment that
/// Kalibr and OpenCV `stereoCalibrate` solve, here with the Schur complement over the poses).
///
/// Errors: [`CoreError::InvalidInput`] / [`CoreError::InvalidParam`] for malformed input (cameras
/// with different frame counts, a corner outside the board…), [`CoreError::NoSolution`] when a
/// camera cannot be calibrated or never sees the board together with another camera,
/// [`CoreError::Canceled`].
pub fn calibrate_rig(
    inputs: &[RigCameraInput],
    board: &dyn PlanarTarget,
    options: &RigOptions,
    progress: &dyn Progress,
) -> CoreResult<RigCalibration> {
    board.validate()?;
    options.validate()?;
    if inputs.len() < 2 || inputs.len() > MAX_CAMERAS {
        return Err(CoreError::input(format!(
            "a rig needs 2 to {MAX_CAMERAS} cameras, got {}",
            inputs.len()
        )));
    }
    if options.camera.fix_aspect_ratio {
        return Err(CoreError::param(
            "options.camera.fix_aspect_ratio",
            "is not supported for rigs",
        ));
    }
    let frames = inputs[0].views.len();
    for c in inputs {
        if c.views.len() != frames {
            return Err(CoreError::input(format!(
                "cameras have different frame counts: `{}` has {}, `{}` has {frames}",
                c.name,
                c.views.len(),
                inputs[0].name
            )));
        }
        if c.image_size[0] == 0 || c.image_size[1] == 0 {
            return Err(CoreError::param(
                "image_size",
                "width and height must be positive",
            ));
        }
        let model = c.fixed.as_ref().map_or(c.model, ModelKind::of);
        options.camera.validate(model)?;
    }
    let names: Vec<String> = inputs.iter().map(|c| c.name.clone()).collect();
    let mut warnings = Vec::new();

    // 1. Each camera on its own.
    let mut starts: Vec<CameraStart> = Vec::with_capacity(inputs.len());
    for (i, c) in inputs.iter().enumerate() {
        progress.report("cameras", i as u64, inputs.len() as u64);
        starts.push(start_camera(i, c, board, options, progress)?);
    }
    // 2. Extrinsics (and consistent corner numbering across cameras).
    let mut reference = extrinsics(&mut starts, &names, board, &mut warnings)?;

    // 3. Frame blocks with a starting board pose in camera 0's frame.
    let mut frame_info: Vec<RigFrameResult> = Vec::with_capacity(frames);
    let mut block_frames = Vec::new();
    let mut blocks: Vec<Vec<Obs>> = Vec::new();
    let mut poses: Vec<Se3> = Vec::new();
    for f in 0..frames {
        let seen_by: Vec<usize> = (0..inputs.len())
            .filter(|&i| inputs[i].views[f].is_some())
            .collect();
        let usable: Vec<(usize, &CamView)> = starts
            .iter()
            .enumerate()
            .filter_map(|(i, s)| s.views[f].as_ref().ok().map(|v| (i, v)))
            .collect();
        let mut info = RigFrameResult {
            index: f,
            seen_by,
            used: false,
            reason: None,
            rvec: None,
            tvec: None,
            rms: None,
        };
        match usable.first() {
            None => {
                let reasons: Vec<String> = starts
                    .iter()
                    .enumerate()
                    .filter_map(|(i, s)| {
                        s.views[f]
                            .as_ref()
                            .err()
                            .map(|e| format!("{}: {e}", names[i]))
                    })
                    .collect();
                info.reason = Some(reasons.join("; "));
            }
            Some((i, v)) => {
                info.used = true;
                poses.push(reference[*i].inverse().compose(&v.pose));
                blocks.push(
                    usable
                        .iter()
                        .flat_map(|(_, v)| v.obs.iter().copied())
                        .collect(),
                );
                block_frames.push(f);
            }
        }
        frame_info.push(info);
    }

    // 4. Joint solve with rejection.
    let kinds: Vec<ModelKind> = starts.iter().map(|s| ModelKind::of(&s.camera)).collect();
    let layout = Layout::new(&kinds);
    let mut shared = vec![0.0; layout.len];
    let mut fixed = vec![false; layout.len];
    for (i, s) in starts.iter().enumerate() {
        let o = layout.intrinsics[i];
        shared[o..o + kinds[i].num_params()].copy_from_slice(s.camera.params());
        let names = s.camera.param_names();
        for (k, n) in names.iter().enumerate() {
            let opt = &options.camera;
            fixed[o + k] = inputs[i].fixed.is_some()
                || !options.refine_intrinsics
                || (opt.fix_principal_point && (*n == "cx" || *n == "cy"))
                || (opt.fix_k3 && *n == "k3")
                || (opt.zero_tangential && (*n == "p1" || *n == "p2"));
        }
    }
    let lm = LmOptions {
        max_iterations: options.max_iterations,
        loss: options.loss,
        ..LmOptions::default()
    };
    let mut iterations = 0;
    let mut termination = Termination::MaxIterations;
    let mut rejected = 0usize;
    let rounds = if options.reject_outliers {
        options.camera.max_rejection_rounds
    } else {
        0
    };
    for round in 0..=rounds {
        progress.report("joint solve", round as u64, rounds as u64 + 1);
        let problem = RigProblem {
            layout: &layout,
            reference: &reference,
            blocks: &blocks,
        };
        let summary = lm_solve(&problem, &mut shared, &fixed, &mut poses, &lm, progress)?;
        iterations += summary.iterations;
        termination = summary.termination;
        // Move the references to the estimate: ξ = 0 again.
        let moved: Vec<Se3> = (0..reference.len())
            .map(|i| problem.extrinsic(&shared, i))
            .collect();
        reference = moved;
        for o in layout.extrinsics.iter().flatten() {
            shared[*o..*o + 6].fill(0.0);
        }
        if round == rounds {
            break;
        }
        let dropped = reject(
            &layout,
            &reference,
            &shared,
            &poses,
            &mut blocks,
            &options.camera,
        )?;
        rejected += dropped;
        if dropped == 0 {
            break;
        }
    }

    // 5. Report.
    let problem = RigProblem {
        layout: &layout,
        reference: &reference,
        blocks: &blocks,
    };
    let cameras = problem
        .cameras(&shared)
        .ok_or_else(|| CoreError::NoSolution("the joint solution left a model's domain".into()))?;
    let mut sum = vec![0.0; inputs.len()];
    let mut count = vec![0usize; inputs.len()];
    let mut frames_used = vec![0usize; inputs.len()];
    for (b, obs) in blocks.iter().enumerate() {
        let (mut fs, mut fn_) = (0.0, 0usize);
        let mut cams_in = vec![false; inputs.len()];
        for o in obs {
            let p = reference[o.camera].act(&poses[b].act(&o.object));
            if let Some(px) = cameras[o.camera].project(&p) {
                let r2 = (px - o.pixel).norm_squared();
                sum[o.camera] += r2;
                count[o.camera] += 1;
                fs += r2;
                fn_ += 1;
            }
            cams_in[o.camera] = true;
        }
        for (i, c) in cams_in.iter().enumerate() {
            frames_used[i] += usize::from(*c);
        }
        let info = &mut frame_info[block_frames[b]];
        let (r, t) = poses[b].to_rvec_tvec();
        info.rvec = Some(r.into());
        info.tvec = Some(t.into());
        info.rms = (fn_ > 0).then(|| (fs / fn_ as f64).sqrt());
    }
    let n_obs: usize = count.iter().sum();
    let total: f64 = sum.iter().sum();
    let free = fixed.iter().filter(|f| !**f).count() + 6 * blocks.len();
    let dof = (2 * n_obs).saturating_sub(free);
    let sigma = if dof > 0 {
        (total / dof as f64).sqrt()
    } else {
        f64::NAN
    };
    let cov = match marginal_shared_covariance(&problem, &shared, &fixed, &poses) {
        Ok(c) => Some(c * (sigma * sigma)),
        Err(e) => {
            warnings.push(format!("no covariance: {e}"));
            None
        }
    };

    let mut camera_results = Vec::with_capacity(inputs.len());
    for (i, cam) in cameras.iter().enumerate() {
        let o = layout.intrinsics[i];
        let parameters = cam
            .param_names()
            .iter()
            .zip(cam.params())
            .enumerate()
            .map(|(k, (n, v))| ParameterEstimate {
                name: (*n).to_string(),
                value: *v,
                std_dev: if fixed[o + k] {
                    Some(0.0)
                } else {
                    cov.as_ref().map(|c| c[(o + k, o + k)].max(0.0).sqrt())
                },
                fixed: fixed[o + k],
            })
            .collect();
        camera_results.push(RigCameraResult {
            name: names[i].clone(),
            camera: cam.clone(),
            image_size: inputs[i].image_size,
            parameters,
            intrinsics_fixed: inputs[i].fixed.is_some(),
            rms: if count[i] > 0 {
                (sum[i] / count[i] as f64).sqrt()
            } else {
                f64::NAN
            },
            mono_rms: starts[i].mono_rms,
            frames_seen: inputs[i].views.iter().filter(|v| v.is_some()).count(),
            frames_used: frames_used[i],
            corners_used: count[i],
        });
    }
    let extrinsics_out: Vec<Extrinsic> = (0..inputs.len())
        .map(|i| {
            extrinsic_doc(
                i,
                &names[i],
                &reference[i],
                layout.extrinsics[i],
                cov.as_ref(),
            )
        })
        .collect();
    let mut pairs = Vec::new();
    for i in 1..inputs.len() {
        progress.check()?;
        let rect = stereo_rectify(
            &cameras[0],
            &cameras[i],
            &reference[i],
            inputs[0].image_size,
        )?;
        let (rms, n) = epipolar_rms(&cameras[0], &cameras[i], &rect, &blocks, 0, i);
        pairs.push(StereoPair {
            a: 0,
            b: i,
            rectification: rect,
            epipolar_rms_px: rms,
            epipolar_points: n,
        });
    }
    Ok(RigCalibration {
        cameras: camera_results,
        extrinsics: extrinsics_out,
        pairs,
        rms: if n_obs > 0 {
            (total / n_obs as f64).sqrt()
        } else {
            f64::NAN
        },
        sigma,
        corners_used: n_obs,
        corners_rejected: rejected,
        frames: frame_info,
        iterations,
        termination,
        warnings,
    })
}

/// Drops corners whose residual norm exceeds `max(outlier_sigmas·σ, outlier_min_px)` (σ from the
/// MAD of all residual components); returns how many.
fn reject(
    layout: &Layout,
    reference: &[Se3],
    shared: &[f64],
    poses: &[Se3],
    blocks: &mut [Vec<Obs>],
    opt: &crate::calib::CalibOptions,
) -> CoreResult<usize> {
    let problem = RigProblem {
        layout,
        reference,
        blocks,
    };
    let cameras = problem
        .cameras(shared)
        .ok_or_else(|| CoreError::NoSolution("the joint solution left a model's domain".into()))?;
    let residual = |b: usize, o: &Obs| {
        let p = reference[o.camera].act(&poses[b].act(&o.object));
        cameras[o.camera].project(&p).map(|px| px - o.pixel)
    };
    let mut comps: Vec<f64> = Vec::new();
    for (b, obs) in blocks.iter().enumerate() {
        for o in obs {
            if let Some(r) = residual(b, o) {
                comps.push(r.x.abs());
                comps.push(r.y.abs());
            }
        }
    }
    if comps.is_empty() {
        return Ok(0);
    }
    comps.sort_by(f64::total_cmp);
    let sigma = MAD_TO_SIGMA * comps[comps.len() / 2];
    let threshold = (opt.outlier_sigmas * sigma).max(opt.outlier_min_px);
    let mut dropped = 0;
    for (b, obs) in blocks.iter_mut().enumerate() {
        let before = obs.len();
        let keep: Vec<Obs> = obs
            .iter()
            .filter(|o| residual(b, o).is_some_and(|r| r.norm() <= threshold))
            .copied()
            .collect();
        // A block must keep enough corners to hold its pose.
        if keep.len() >= crate::calib::MIN_CORNERS_PER_VIEW {
            dropped += before - keep.len();
            *obs = keep;
        }
    }
    Ok(dropped)
}

fn rows3(m: &Matrix3<f64>) -> [[f64; 3]; 3] {
    [
        [m[(0, 0)], m[(0, 1)], m[(0, 2)]],
        [m[(1, 0)], m[(1, 1)], m[(1, 2)]],
        [m[(2, 0)], m[(2, 1)], m[(2, 2)]],
    ]
}

/// A pose as documents carry it.
pub(crate) fn pose_doc(t: &Se3) -> PoseDoc {
    let (rvec, _) = t.to_rvec_tvec();
    PoseDoc {
        quaternion_wxyz: t.rotation.to_wxyz(),
        rvec: rvec.into(),
        rotation_matrix: rows3(&t.rotation.matrix()),
        translation: t.translation.into(),
    }
}

/// The document of camera i's extrinsics with σ propagated from the covariance of ξ (a left
/// perturbation `exp(ξ)·T`: to first order `t' = t + ρ + θ × t`).
fn extrinsic_doc(
    i: usize,
    name: &str,
    t: &Se3,
    offset: Option<usize>,
    cov: Option<&DMatrix<f64>>,
) -> Extrinsic {
    let sigma = offset.zip(cov).map(|(o, c)| {
        let s = c.view((o, o), (6, 6)).into_owned();
        let mut jt = Matrix3x6::<f64>::zeros();
        jt.fixed_view_mut::<3, 3>(0, 0)
            .copy_from(&Matrix3::identity());
        jt.fixed_view_mut::<3, 3>(0, 3)
            .copy_from(&(-So3::hat(&t.translation)));
        let st = jt * &s * jt.transpose();
        let b = t.translation.norm().max(1e-300);
        let u: Vector3<f64> = t.translation / b;
        let jb = u.transpose() * jt;
        let sb = (jb * &s * jb.transpose())[(0, 0)];
        ExtrinsicSigma {
            translation: [0, 1, 2].map(|k| st[(k, k)].max(0.0).sqrt()),
            rotation_deg: [3, 4, 5].map(|k| s[(k, k)].max(0.0).sqrt().to_degrees()),
            baseline: sb.max(0.0).sqrt(),
        }
    });
    Extrinsic {
        camera: i,
        name: name.to_string(),
        t_cam_cam0: pose_doc(t),
        baseline: t.translation.norm(),
        rotation_deg: t.rotation.angle().to_degrees(),
        sigma,
    }
}
