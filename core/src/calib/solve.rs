//! [`calibrate`]: input checks, the starting camera and poses, the parameterisation, and the
//! solve / reject / re-solve loop; the report is assembled by `finish`.

use nalgebra::Vector2;

use super::finish::finish;
use super::problem::{CalibProblem, ViewData};
use super::reject::reject;
use super::types::{
    CalibOptions, Calibration, MIN_CORNERS_PER_VIEW, MIN_VIEWS, ModelKind, PlanarTarget,
    ViewObservations,
};
use super::{init, pnp};
use crate::camera::{Camera, CameraModel};
use crate::error::{CoreError, CoreResult};
use crate::lie::Se3;
use crate::optim::{LmOptions, Termination, solve as lm_solve};
use crate::progress::Progress;

/// Working state of one input view.
pub(super) struct ViewState {
    pub(super) name: String,
    pub(super) indices: Vec<usize>,
    pub(super) data: ViewData,
    pub(super) inlier: Vec<bool>,
    pub(super) pose: Option<Se3>,
    pub(super) rejected: Option<String>,
}

impl ViewState {
    pub(super) fn active(&self) -> bool {
        self.rejected.is_none() && self.pose.is_some()
    }

    pub(super) fn inlier_data(&self) -> ViewData {
        let mut d = ViewData::default();
        for (k, ok) in self.inlier.iter().enumerate() {
            if *ok {
                d.object.push(self.data.object[k]);
                d.pixels.push(self.data.pixels[k]);
            }
        }
        d
    }
}

/// Validates and converts the input views.
fn parse_views(
    observations: &[ViewObservations],
    board: &dyn PlanarTarget,
) -> CoreResult<Vec<ViewState>> {
    let n = board.num_points();
    observations
        .iter()
        .map(|view| {
            let mut seen = vec![false; n];
            let mut st = ViewState {
                name: view.name.clone(),
                indices: Vec::with_capacity(view.corners.len()),
                data: ViewData::default(),
                inlier: Vec::with_capacity(view.corners.len()),
                pose: None,
                rejected: None,
            };
            for c in &view.corners {
                let Some(x) = board.object_point(c.index) else {
                    return Err(CoreError::input(format!(
                        "view `{}`: corner index {} outside the {}",
                        view.name,
                        c.index,
                        board.describe()
                    )));
                };
                if std::mem::replace(&mut seen[c.index], true) {
                    return Err(CoreError::input(format!(
                        "view `{}`: corner {} given twice",
                        view.name, c.index
                    )));
                }
                if !(c.pixel[0].is_finite() && c.pixel[1].is_finite()) {
                    return Err(CoreError::input(format!(
                        "view `{}`: corner {} has a non-finite pixel",
                        view.name, c.index
                    )));
                }
                st.indices.push(c.index);
                st.data.object.push(x);
                st.data.pixels.push(Vector2::new(c.pixel[0], c.pixel[1]));
                st.inlier.push(true);
            }
            if st.indices.len() < MIN_CORNERS_PER_VIEW {
                st.rejected = Some(format!(
                    "only {} corners (at least {MIN_CORNERS_PER_VIEW} needed)",
                    st.indices.len()
                ));
            }
            Ok(st)
        })
        .collect()
}

/// Calibrates one camera from the corners of a planar target (see the module docs for the
/// method).
///
/// Errors: [`CoreError::InvalidInput`] / [`CoreError::InvalidParam`] for malformed input or
/// options, [`CoreError::NoSolution`] when fewer than [`MIN_VIEWS`] views are usable or the
/// views do not determine the camera, [`CoreError::Canceled`].
pub fn calibrate(
    observations: &[ViewObservations],
    board: &dyn PlanarTarget,
    model: ModelKind,
    image_size: (u32, u32),
    options: &CalibOptions,
    progress: &dyn Progress,
) -> CoreResult<Calibration> {
    board.validate()?;
    options.validate(model)?;
    if image_size.0 == 0 || image_size.1 == 0 {
        return Err(CoreError::param(
            "image_size",
            "width and height must be positive",
        ));
    }
    let mut views = parse_views(observations, board)?;
    let usable = |views: &[ViewState]| views.iter().filter(|v| v.rejected.is_none()).count();
    if usable(&views) < MIN_VIEWS {
        return Err(CoreError::NoSolution(format!(
            "{} usable views (with at least {MIN_CORNERS_PER_VIEW} corners); at least {MIN_VIEWS} needed",
            usable(&views)
        )));
    }
    progress.check()?;

    // 1. Initial camera.
    let start_data: Vec<ViewData> = views
        .iter()
        .filter(|v| v.rejected.is_none())
        .map(|v| v.data.clone())
        .collect();
    let mut initial = match model {
        ModelKind::PinholeRadTan => {
            let k = init::pinhole_start(&start_data, image_size, options.fix_principal_point)?;
            let (mut fx, mut fy) = (k.fx, k.fy);
            if options.fix_aspect_ratio {
                fx = 0.5 * (fx + fy);
                fy = fx;
            }
            model.camera(&[fx, fy, k.cx, k.cy, 0.0, 0.0, 0.0, 0.0, 0.0])?
        }
        _ => init::focal_sweep(model, image_size, &start_data, progress)?,
    };
    if options.fix_principal_point {
        let c = init::image_centre(image_size);
        let mut p = initial.params().to_vec();
        p[2] = c.x;
        p[3] = c.y;
        initial = model.camera(&p)?;
    }

    // 2. Initial poses.
    for v in views.iter_mut().filter(|v| v.rejected.is_none()) {
        match pnp::pose_for_view(&initial, &v.data, 50, progress) {
            Ok((pose, _)) => v.pose = Some(pose),
            Err(CoreError::Canceled) => return Err(CoreError::Canceled),
            Err(e) => v.rejected = Some(format!("no initial pose: {e}")),
        }
    }
    if usable(&views) < MIN_VIEWS {
        return Err(CoreError::NoSolution(format!(
            "only {} views could be posed with the initial camera; at least {MIN_VIEWS} needed",
            usable(&views)
        )));
    }

    // 3. Parameterisation.
    let names = initial.param_names();
    let mut fixed = vec![false; names.len()];
    let mut fix = |name: &str| {
        if let Some(k) = names.iter().position(|n| *n == name) {
            fixed[k] = true;
        }
    };
    if options.fix_principal_point {
        fix("cx");
        fix("cy");
    }
    if options.fix_k3 {
        fix("k3");
    }
    if options.zero_tangential {
        fix("p1");
        fix("p2");
    }
    let aspect = if options.fix_aspect_ratio {
        fix("fy");
        let p = initial.params();
        Some(p[1] / p[0])
    } else {
        None
    };
    let mut shared = initial.params().to_vec();
    let lm_options = LmOptions {
        max_iterations: options.max_iterations,
        loss: options.loss,
        ..LmOptions::default()
    };

    // 4. Solve, reject, re-solve.
    let mut iterations = 0;
    let mut termination = Termination::MaxIterations;
    let mut rejected_corners = Vec::new();
    // The camera of the current `shared`, when built (saves rebuilding it, see `known`).
    let mut current: Option<Camera> = Some(initial.clone());
    for round in 0..=options.max_rejection_rounds {
        progress.report(
            "calibrate",
            round as u64,
            options.max_rejection_rounds as u64 + 1,
        );
        let active: Vec<usize> = (0..views.len()).filter(|&i| views[i].active()).collect();
        let data: Vec<ViewData> = active.iter().map(|&i| views[i].inlier_data()).collect();
        let mut poses: Vec<Se3> = active.iter().filter_map(|&i| views[i].pose).collect();
        let problem = CalibProblem {
            kind: model,
            views: &data,
            aspect,
            known: current.as_ref(),
        };
        let summary = lm_solve(
            &problem,
            &mut shared,
            &fixed,
            &mut poses,
            &lm_options,
            progress,
        )?;
        iterations += summary.iterations;
        termination = summary.termination;
        for (&i, p) in active.iter().zip(&poses) {
            views[i].pose = Some(*p);
        }
        if !options.reject_outliers || round == options.max_rejection_rounds {
            break;
        }
        let camera = model.camera(&problem.camera_params(&shared))?;
        let changed = reject(&mut views, &active, &camera, options, &mut rejected_corners);
        current = Some(camera);
        if !changed {
            break;
        }
    }

    // 5. Report.
    let params = CalibProblem {
        kind: model,
        views: &[],
        aspect,
        known: None,
    }
    .camera_params(&shared);
    let camera = match current {
        Some(c) if c.params() == params.as_slice() => c,
        _ => model.camera(&params)?,
    };
    finish(
        views,
        camera,
        initial,
        model,
        image_size,
        &shared,
        &fixed,
        aspect,
        iterations,
        termination,
        rejected_corners,
        progress,
    )
}
