//! Starting values of the joint solve: each camera calibrated on its own (or its fixed
//! intrinsics), its board poses, and the extrinsics from a robust average of the relative poses
//! seen in shared frames, propagated along a spanning tree of the co-visibility graph so that a
//! camera that never sees the board together with camera 0 is still reached through another.
//!
//! A chessboard is symmetric under a half turn when its detector cannot tell the corners apart,
//! so two cameras may number the same board in opposite orders. Every shared frame therefore
//! offers two candidate relative poses (as numbered, and with one camera's numbering reversed);
//! the candidate most frames agree with wins, and each frame's numbering is made consistent with
//! it (OpenCV's stereo sample makes the same check on the first and last corners).

use nalgebra::{Vector2, Vector3};

use super::problem::Obs;
use super::types::{MIN_SHARED_FRAMES, RigCameraInput, RigOptions};
use crate::calib::{MIN_CORNERS_PER_VIEW, ModelKind, PlanarTarget, ViewObservations};
use crate::calib::{calibrate, estimate_pose};
use crate::camera::Camera;
use crate::error::{CoreError, CoreResult};
use crate::lie::{Se3, So3};

use crate::progress::Progress;

/// Rotation (radians) and relative translation within which two relative-pose candidates agree.
const AGREE_ROTATION: f64 = 3.0 * std::f64::consts::PI / 180.0;
const AGREE_TRANSLATION: f64 = 0.1;

/// One camera's view of one frame, as the solver will use it.
#[derive(Clone, Debug)]
pub(super) struct CamView {
    pub obs: Vec<Obs>,
    /// `T_cam_board` from this camera alone.
    pub pose: Se3,
}

/// The starting state of one camera.
pub(super) struct CameraStart {
    pub camera: Camera,
    pub mono_rms: Option<f64>,
    /// Per frame: the view, or why there is none.
    pub views: Vec<Result<CamView, String>>,
}

fn to_obs(camera: usize, board: &dyn PlanarTarget, v: &ViewObservations) -> CoreResult<Vec<Obs>> {
    let mut seen = vec![false; board.num_points()];
    v.corners
        .iter()
        .map(|c| {
            let object = board.object_point(c.index).ok_or_else(|| {
                CoreError::input(format!(
                    "view `{}`: corner index {} outside the {}",
                    v.name,
                    c.index,
                    board.describe()
                ))
            })?;
            if std::mem::replace(&mut seen[c.index], true) {
                return Err(CoreError::input(format!(
                    "view `{}`: corner {} given twice",
                    v.name, c.index
                )));
            }
            if !(c.pixel[0].is_finite() && c.pixel[1].is_finite()) {
                return Err(CoreError::input(format!(
                    "view `{}`: corner {} has a non-finite pixel",
                    v.name, c.index
                )));
            }
            Ok(Obs {
                camera,
                index: c.index,
                object,
                pixel: Vector2::new(c.pixel[0], c.pixel[1]),
            })
        })
        .collect()
}

/// Calibrates (or poses, with fixed intrinsics) one camera on its own views.
pub(super) fn start_camera(
    i: usize,
    input: &RigCameraInput,
    board: &dyn PlanarTarget,
    options: &RigOptions,
    progress: &dyn Progress,
) -> CoreResult<CameraStart> {
    let mut views: Vec<Result<CamView, String>> = Vec::with_capacity(input.views.len());
    let mut obs_per_frame = Vec::with_capacity(input.views.len());
    for v in &input.views {
        match v {
            None => obs_per_frame.push(None),
            Some(v) => obs_per_frame.push(Some(to_obs(i, board, v)?)),
        }
    }
    let (camera, mono_rms, poses): (Camera, Option<f64>, Vec<Option<Se3>>) = match &input.fixed {
        Some(cam) => {
            let mut poses = Vec::with_capacity(obs_per_frame.len());
            for o in &obs_per_frame {
                progress.check()?;
                poses.push(match o {
                    Some(o) if o.len() >= MIN_CORNERS_PER_VIEW => {
                        let b: Vec<Vector2<f64>> = o
                            .iter()
                            .map(|x| Vector2::new(x.object.x, x.object.y))
                            .collect();
                        let p: Vec<Vector2<f64>> = o.iter().map(|x| x.pixel).collect();
                        match estimate_pose(cam, &b, &p, progress) {
                            Ok(t) => Some(t),
                            Err(CoreError::Canceled) => return Err(CoreError::Canceled),
                            Err(_) => None,
                        }
                    }
                    _ => None,
                });
            }
            (cam.clone(), None, poses)
        }
        None => {
            let frames: Vec<usize> = (0..input.views.len())
                .filter(|&f| input.views[f].is_some())
                .collect();
            let observations: Vec<ViewObservations> = frames
                .iter()
                .filter_map(|&f| input.views[f].clone())
                .collect();
            let size = (input.image_size[0], input.image_size[1]);
            let calib = calibrate(
                &observations,
                board,
                input.model,
                size,
                &options.camera,
                progress,
            )
            .map_err(|e| match e {
                CoreError::NoSolution(m) => {
                    CoreError::NoSolution(format!("camera `{}` on its own: {m}", input.name))
                }
                other => other,
            })?;
            let mut poses = vec![None; input.views.len()];
            for (&f, vr) in frames.iter().zip(&calib.views) {
                if let (true, Some(r), Some(t)) = (vr.used, vr.rvec, vr.tvec) {
                    poses[f] = Some(Se3::from_rvec_tvec(&Vector3::from(r), &Vector3::from(t)));
                }
            }
            (calib.camera, Some(calib.rms), poses)
        }
    };
    for (o, p) in obs_per_frame.into_iter().zip(poses) {
        views.push(match (o, p) {
            (None, _) => Err("board not detected".into()),
            (Some(_), None) => Err(format!(
                "left out of camera `{}`'s own calibration (too few corners or an outlier view)",
                input.name
            )),
            (Some(obs), Some(pose)) => Ok(CamView { obs, pose }),
        });
    }
    if ModelKind::of(&camera) != input.model && input.fixed.is_none() {
        return Err(CoreError::input("camera model changed during calibration"));
    }
    Ok(CameraStart {
        camera,
        mono_rms,
        views,
    })
}

/// Relative pose candidates agree.
fn agree(a: &Se3, b: &Se3) -> bool {
    let d = a.inverse().compose(b);
    let scale = a.translation.norm().max(b.translation.norm()).max(1e-12);
    d.rotation.angle() < AGREE_ROTATION
        && (a.translation - b.translation).norm() < AGREE_TRANSLATION * scale
}

/// Mean of rigid transforms that agree: the normalised sum of sign-aligned quaternions (the
/// chordal L2 mean of nearby rotations; Hartley et al., "Rotation averaging", IJCV 2013, §5.3)
/// and the mean translation.
fn mean_pose(poses: &[Se3]) -> Se3 {
    let q0 = poses[0].rotation.to_wxyz();
    let mut q = [0.0; 4];
    let mut t = Vector3::zeros();
    for p in poses {
        let qi = p.rotation.to_wxyz();
        let s = if qi.iter().zip(&q0).map(|(a, b)| a * b).sum::<f64>() < 0.0 {
            -1.0
        } else {
            1.0
        };
        for k in 0..4 {
            q[k] += s * qi[k];
        }
        t += p.translation;
    }
    let r = So3::from_wxyz(q).unwrap_or(poses[0].rotation);
    Se3::new(r, t / poses.len() as f64)
}

/// Extrinsics `T_i_0` for every camera from the per-camera poses; reverses a camera's corner
/// numbering in the frames where that is what makes it agree with the rig, and drops views that
/// agree with neither numbering (returned as warnings).
pub(super) fn extrinsics(
    starts: &mut [CameraStart],
    names: &[String],
    board: &dyn PlanarTarget,
    warnings: &mut Vec<String>,
) -> CoreResult<Vec<Se3>> {
    let n = starts.len();
    let frames = starts[0].views.len();
    // Targets with unambiguous ids offer one candidate per frame.
    let flip_inv = board.half_turn().map(|f| f.inverse());
    let mut known: Vec<Option<Se3>> = vec![None; n];
    known[0] = Some(Se3::identity());
    loop {
        // The unknown camera with the most frames shared with a known one.
        let mut best: Option<(usize, usize, usize)> = None;
        for i in (0..n).filter(|&i| known[i].is_none()) {
            for j in (0..n).filter(|&j| known[j].is_some()) {
                let shared = (0..frames)
                    .filter(|&f| starts[i].views[f].is_ok() && starts[j].views[f].is_ok())
                    .count();
                if shared > 0 && best.is_none_or(|(_, _, s)| shared > s) {
                    best = Some((i, j, shared));
                }
            }
        }
        let Some((i, j, shared)) = best else { break };
        let t_j0 = known[j].unwrap_or_else(Se3::identity);
        // Candidates T_i_j per shared frame, as numbered and with i's numbering reversed.
        let mut cands: Vec<(usize, Se3, Option<Se3>)> = Vec::new();
        for f in 0..frames {
            if let (Ok(vi), Ok(vj)) = (&starts[i].views[f], &starts[j].views[f]) {
                let inv_j = vj.pose.inverse();
                let direct = vi.pose.compose(&inv_j);
                cands.push((
                    f,
                    direct,
                    flip_inv.map(|fi| vi.pose.compose(&fi).compose(&inv_j)),
                ));
            }
        }
        let support = |c: &Se3| {
            cands
                .iter()
                .filter(|(_, a, b)| agree(c, a) || b.as_ref().is_some_and(|b| agree(c, b)))
                .count()
        };
        let mut winner = cands[0].1;
        let mut top = 0;
        for (_, a, b) in &cands {
            for c in std::iter::once(a).chain(b.as_ref()) {
                let s = support(c);
                if s > top {
                    top = s;
                    winner = *c;
                }
            }
        }
        let mut inliers = Vec::new();
        for (f, a, b) in &cands {
            if agree(&winner, a) {
                inliers.push(*a);
            } else if let (Some(b), Some(fi)) = (b, flip_inv)
                && agree(&winner, b)
            {
                inliers.push(*b);
                // Renumber camera i's corners in this frame to match the rig.
                if let Ok(v) = &mut starts[i].views[*f] {
                    let last = board.num_points() - 1;
                    for o in &mut v.obs {
                        o.index = last - o.index;
                        o.object = board.object_point(o.index).unwrap_or(o.object);
                    }
                    v.pose = v.pose.compose(&fi);
                }
            } else {
                starts[i].views[*f] = Err(format!(
                    "its pose disagrees with the rest of the rig (more than {:.0}° or {:.0} % off the consensus of {} frames)",
                    AGREE_ROTATION.to_degrees(),
                    100.0 * AGREE_TRANSLATION,
                    top
                ));
            }
        }
        let t_ij = mean_pose(&inliers);
        known[i] = Some(t_ij.compose(&t_j0));
        if shared < MIN_SHARED_FRAMES {
            warnings.push(format!(
                "camera `{}` shares only {shared} frames with camera `{}`: its extrinsics rest on little data",
                names[i], names[j]
            ));
        }
    }
    known
        .into_iter()
        .enumerate()
        .map(|(i, k)| {
            k.ok_or_else(|| {
                CoreError::NoSolution(format!(
                    "camera `{}` never sees the board in the same frame as another camera of the rig",
                    names[i]
                ))
            })
        })
        .collect()
}
