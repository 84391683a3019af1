//! SVG plots (plotters) of a photometric calibration: the response curve, the vignette radial
//! profile and the exposures over time. Like the IMU plots, a chart error yields a partial
//! document instead of failing a job over a picture.

use plotters::prelude::*;

use super::response::ResponseModel;
use super::vignette::VignetteModel;

type DrawErr = DrawingAreaErrorKind<std::io::Error>;

const FIT: RGBColor = RGBColor(0x1f, 0x77, 0xb4);
const REF: RGBColor = RGBColor(0xd6, 0x27, 0x28);

/// Forward response `f` (irradiance → intensity, both normalised), the fitted curve solid
/// blue, an optional reference (e.g. ground truth or a previous calibration) dashed red.
pub fn response_svg(model: &ResponseModel, reference: Option<&ResponseModel>) -> String {
    let mut out = String::new();
    let _ = draw_curves(
        &mut out,
        "irradiance (normalised)",
        "intensity (normalised)",
        (0.0, 1.0),
        (0.0, 1.0),
        &curve(|x| model.forward(x), 0.0, 1.0),
        reference
            .map(|r| curve(|x| r.forward(x), 0.0, 1.0))
            .as_deref(),
    );
    out
}

/// Vignetting `V(r)` over `r ∈ [0, r_corner]` (r = 1 at the corners of a centred model), with
/// an optional reference.
pub fn vignette_profile_svg(model: &VignetteModel, reference: Option<&VignetteModel>) -> String {
    let fit = curve(|r| model.eval_r2(r * r), 0.0, 1.0);
    let rf = reference.map(|m| curve(|r| m.eval_r2(r * r), 0.0, 1.0));
    let lo = fit
        .iter()
        .chain(rf.iter().flatten())
        .map(|p| p.1)
        .fold(1.0f64, f64::min);
    let hi = fit
        .iter()
        .chain(rf.iter().flatten())
        .map(|p| p.1)
        .fold(1.0f64, f64::max);
    let mut out = String::new();
    let _ = draw_curves(
        &mut out,
        "r (1 = corner)",
        "V(r)",
        (0.0, 1.0),
        (lo.min(0.0), hi * 1.05),
        &fit,
        rf.as_deref(),
    );
    out
}

/// Exposure of each frame relative to frame 0 against time (seconds; frame index if
/// `timestamps` is `None` or of the wrong length), with optional reference exposures.
pub fn exposure_svg(
    exposures: &[f64],
    timestamps: Option<&[f64]>,
    reference: Option<&[f64]>,
) -> String {
    let t: Vec<f64> = match timestamps {
        Some(ts) if ts.len() == exposures.len() => ts.to_vec(),
        _ => (0..exposures.len()).map(|i| i as f64).collect(),
    };
    let fit: Vec<(f64, f64)> = t.iter().copied().zip(exposures.iter().copied()).collect();
    let rf: Option<Vec<(f64, f64)>> =
        reference.map(|r| t.iter().copied().zip(r.iter().copied()).collect());
    let ymax = fit
        .iter()
        .chain(rf.iter().flatten())
        .map(|p| p.1)
        .filter(|v| v.is_finite())
        .fold(0.0f64, f64::max);
    let tmax = t.last().copied().unwrap_or(1.0).max(1e-9);
    let mut out = String::new();
    let _ = draw_curves(
        &mut out,
        if timestamps.is_some() {
            "time [s]"
        } else {
            "frame"
        },
        "exposure / exposure[0]",
        (t.first().copied().unwrap_or(0.0), tmax),
        (0.0, (ymax * 1.1).max(1e-9)),
        &fit,
        rf.as_deref(),
    );
    out
}

fn curve(f: impl Fn(f64) -> f64, a: f64, b: f64) -> Vec<(f64, f64)> {
    (0..=256)
        .map(|i| {
            let x = a + (b - a) * f64::from(i) / 256.0;
            (x, f(x))
        })
        .collect()
}

fn draw_curves(
    out: &mut String,
    xdesc: &str,
    ydesc: &str,
    xr: (f64, f64),
    yr: (f64, f64),
    fit: &[(f64, f64)],
    reference: Option<&[(f64, f64)]>,
) -> Result<(), DrawErr> {
    let xr = crate::plot_axis::linear(xr.0, xr.1);
    let yr = crate::plot_axis::linear(yr.0, yr.1);
    let root = SVGBackend::with_string(out, (640, 480)).into_drawing_area();
    root.fill(&WHITE)?;
    let mut chart = ChartBuilder::on(&root)
        .margin(16)
        .x_label_area_size(36)
        .y_label_area_size(56)
        .build_cartesian_2d(xr.0..xr.1, yr.0..yr.1)?;
    chart.configure_mesh().x_desc(xdesc).y_desc(ydesc).draw()?;
    if let Some(r) = reference {
        chart.draw_series(DashedLineSeries::new(
            r.iter().copied(),
            6,
            4,
            REF.stroke_width(2),
        ))?;
    }
    chart.draw_series(LineSeries::new(fit.iter().copied(), FIT.stroke_width(2)))?;
    root.present()?;
    Ok(())
}
