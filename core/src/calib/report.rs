//! Diagnostics that OpenCV does not give, derived from a finished calibration: how much of the
//! image the observed corners cover, and SVG plots of residual vectors, per-view RMS and
//! coverage (artifacts of the `camera_calibration` job).
//!
//! Coverage matters because a calibration is only trustworthy where it saw corners: distortion
//! far from any observation is extrapolated (mrcal makes the same point with its uncertainty
//! maps; the projection uncertainty in [`super::Calibration`] quantifies it at a few points).

use plotters::prelude::*;
use serde::{Deserialize, Serialize};

use super::{Calibration, ViewObservations};

/// Which image cells hold inlier corners.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(utoipa::ToSchema))]
pub struct Coverage {
    /// Grid cells across.
    pub grid_cols: u32,
    /// Grid cells down.
    pub grid_rows: u32,
    /// Inlier corners per cell, row-major (`row · grid_cols + col`).
    pub counts: Vec<u32>,
    /// Share of cells holding at least one inlier corner, 0–1.
    pub fraction: f64,
}

/// Count inlier corners of the used views in a `grid_cols × grid_rows` grid over the image.
pub fn coverage(
    observations: &[ViewObservations],
    calibration: &Calibration,
    grid_cols: u32,
    grid_rows: u32,
) -> Coverage {
    let [w, h] = calibration.image_size;
    let (gc, gr) = (grid_cols.max(1), grid_rows.max(1));
    let mut counts = vec![0u32; (gc * gr) as usize];
    for (px, _) in inlier_points(observations, calibration) {
        let cx = ((px[0] / w.max(1) as f64) * gc as f64).floor();
        let cy = ((px[1] / h.max(1) as f64) * gr as f64).floor();
        if cx >= 0.0 && cy >= 0.0 && (cx as u32) < gc && (cy as u32) < gr {
            counts[(cy as u32 * gc + cx as u32) as usize] += 1;
        }
    }
    let covered = counts.iter().filter(|&&c| c > 0).count();
    Coverage {
        grid_cols: gc,
        grid_rows: gr,
        fraction: covered as f64 / counts.len() as f64,
        counts,
    }
}

/// (observed pixel, residual) of every inlier corner of a used view.
fn inlier_points<'a>(
    observations: &'a [ViewObservations],
    calibration: &'a Calibration,
) -> impl Iterator<Item = ([f64; 2], [f64; 2])> + 'a {
    calibration.residuals.iter().filter_map(move |r| {
        let res = r.residual?;
        if !r.inlier {
            return None;
        }
        let view = observations.get(r.view)?;
        let obs = view.corners.iter().find(|c| c.index == r.index)?;
        Some((obs.pixel, res))
    })
}

type DrawResult = Result<(), String>;

fn err(e: DrawingAreaErrorKind<std::io::Error>) -> String {
    e.to_string()
}

/// Residual vectors over the image, magnified so that the median residual is ~2 % of the
/// image width; outliers (rejected corners) in red.
pub fn residuals_svg(observations: &[ViewObservations], calibration: &Calibration) -> String {
    let mut out = String::new();
    let _ = draw_residuals(&mut out, observations, calibration);
    out
}

fn draw_residuals(
    out: &mut String,
    observations: &[ViewObservations],
    calibration: &Calibration,
) -> DrawResult {
    let [w, h] = calibration.image_size;
    let (w, h) = (w.max(1) as f64, h.max(1) as f64);
    let mut lens: Vec<f64> = inlier_points(observations, calibration)
        .map(|(_, r)| r[0].hypot(r[1]))
        .collect();
    lens.sort_by(f64::total_cmp);
    let median = lens.get(lens.len() / 2).copied().unwrap_or(0.0);
    let scale = if median > 0.0 { 0.02 * w / median } else { 1.0 };
    let size = (800u32, (800.0 * h / w).round().clamp(100.0, 1600.0) as u32);
    let root = SVGBackend::with_string(out, size).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let mut chart = ChartBuilder::on(&root)
        .margin(12)
        .x_label_area_size(28)
        .y_label_area_size(40)
        .caption(format!("residuals × {scale:.0}"), ("sans-serif", 16))
        .build_cartesian_2d(0.0..w, h..0.0)
        .map_err(err)?;
    chart.configure_mesh().disable_mesh().draw().map_err(err)?;
    let blue = RGBColor(0x1f, 0x77, 0xb4);
    for (p, r) in inlier_points(observations, calibration) {
        let q = (p[0] + scale * r[0], p[1] + scale * r[1]);
        chart
            .draw_series(LineSeries::new(vec![(p[0], p[1]), q], blue.stroke_width(1)))
            .map_err(err)?;
    }
    let red = RGBColor(0xd6, 0x27, 0x28);
    let rejected = calibration.rejected_corners.iter().filter_map(|rc| {
        let obs = observations.get(rc.view)?;
        obs.corners
            .iter()
            .find(|c| c.index == rc.index)
            .map(|c| c.pixel)
    });
    chart
        .draw_series(rejected.map(|p| Cross::new((p[0], p[1]), 4, red.stroke_width(2))))
        .map_err(err)?;
    root.present().map_err(err)?;
    Ok(())
}

/// Bars of per-view RMS (used views blue, rejected views red at their last RMS).
pub fn view_rms_svg(calibration: &Calibration) -> String {
    let mut out = String::new();
    let _ = draw_view_rms(&mut out, calibration);
    out
}

fn draw_view_rms(out: &mut String, calibration: &Calibration) -> DrawResult {
    let n = calibration.views.len().max(1);
    let top = calibration
        .views
        .iter()
        .filter_map(|v| v.rms)
        .fold(0.0f64, f64::max)
        .max(calibration.rms)
        .max(1e-3)
        * 1.1;
    let root = SVGBackend::with_string(out, ((40 + 24 * n).clamp(320, 1600) as u32, 360))
        .into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let mut chart = ChartBuilder::on(&root)
        .margin(12)
        .x_label_area_size(28)
        .y_label_area_size(44)
        .caption("RMS per view (px)", ("sans-serif", 16))
        .build_cartesian_2d(
            0.0..(n as f64).max(1.0),
            0.0..crate::plot_axis::linear(0.0, top).1,
        )
        .map_err(err)?;
    chart
        .configure_mesh()
        .disable_x_mesh()
        .draw()
        .map_err(err)?;
    let blue = RGBColor(0x1f, 0x77, 0xb4);
    let red = RGBColor(0xd6, 0x27, 0x28);
    chart
        .draw_series(calibration.views.iter().enumerate().filter_map(|(i, v)| {
            let rms = v.rms?;
            let colour = if v.used { blue } else { red };
            Some(Rectangle::new(
                [(i as f64 + 0.15, 0.0), (i as f64 + 0.85, rms)],
                colour.filled(),
            ))
        }))
        .map_err(err)?;
    let grey = RGBColor(0x55, 0x55, 0x55);
    chart
        .draw_series(LineSeries::new(
            vec![(0.0, calibration.rms), (n as f64, calibration.rms)],
            grey.stroke_width(1),
        ))
        .map_err(err)?;
    root.present().map_err(err)?;
    Ok(())
}

/// The coverage grid as a heat map (white = no corner seen there).
pub fn coverage_svg(cov: &Coverage, image_size: [u32; 2]) -> String {
    let mut out = String::new();
    let _ = draw_coverage(&mut out, cov, image_size);
    out
}

fn draw_coverage(out: &mut String, cov: &Coverage, image_size: [u32; 2]) -> DrawResult {
    let (w, h) = (image_size[0].max(1) as f64, image_size[1].max(1) as f64);
    let size = (640u32, (640.0 * h / w).round().clamp(100.0, 1280.0) as u32);
    let root = SVGBackend::with_string(out, size).into_drawing_area();
    root.fill(&WHITE).map_err(err)?;
    let mut chart = ChartBuilder::on(&root)
        .margin(12)
        .x_label_area_size(28)
        .y_label_area_size(40)
        .caption(
            format!("coverage {:.0} %", 100.0 * cov.fraction),
            ("sans-serif", 16),
        )
        .build_cartesian_2d(0.0..w, h..0.0)
        .map_err(err)?;
    chart.configure_mesh().disable_mesh().draw().map_err(err)?;
    let max = cov.counts.iter().copied().max().unwrap_or(0).max(1) as f64;
    let (cw, ch) = (w / cov.grid_cols as f64, h / cov.grid_rows as f64);
    chart
        .draw_series(
            cov.counts
                .iter()
                .enumerate()
                .filter(|(_, c)| **c > 0)
                .map(|(i, &c)| {
                    let (col, row) = (i as u32 % cov.grid_cols, i as u32 / cov.grid_cols);
                    let t = (c as f64 / max).sqrt();
                    let shade = (255.0 * (1.0 - 0.8 * t)) as u8;
                    Rectangle::new(
                        [
                            (col as f64 * cw, row as f64 * ch),
                            ((col + 1) as f64 * cw, (row + 1) as f64 * ch),
                        ],
                        RGBColor(shade, shade, 255).filled(),
                    )
                }),
        )
        .map_err(err)?;
    root.present().map_err(err)?;
    Ok(())
}
