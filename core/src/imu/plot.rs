//! SVG plots: the Allan deviation (log-log, with the fitted model and the −½/+½ slope lines)
//! and the thermal bias curves. Text is limited to tick labels and axis captions (the build has
//! no font files; the SVG viewer renders `<text>` with its own fonts).

use plotters::prelude::*;

use super::allan::{FLICKER_FACTOR, ImuNoiseReport};
use super::thermal::ImuThermalReport;

const AXIS_COLOURS: [RGBColor; 3] = [
    RGBColor(0xd6, 0x27, 0x28),
    RGBColor(0x2c, 0xa0, 0x2c),
    RGBColor(0x1f, 0x77, 0xb4),
];

type DrawErr = DrawingAreaErrorKind<std::io::Error>;

/// Log-log Allan deviation of every axis: gyroscope on the left, accelerometer on the right,
/// x red, y green, z blue. Measured points joined by solid lines, the fitted
/// √(N²/τ + (0.6643 B)² + K²τ/3) dashed, the −½ slope line through N at τ = 1 s and the +½ slope
/// line through K at τ = 3 s dotted-thin. Returns the SVG document (a chart error leaves a
/// partial document rather than failing the job over a picture).
pub fn allan_svg(report: &ImuNoiseReport) -> String {
    let mut out = String::new();
    let _ = draw_allan(&mut out, report);
    out
}

fn draw_allan(out: &mut String, report: &ImuNoiseReport) -> Result<(), DrawErr> {
    let root = SVGBackend::with_string(out, (1100, 480)).into_drawing_area();
    root.fill(&WHITE)?;
    let panels = root.split_evenly((1, 2));
    for (pi, (sensor, unit)) in [("gyro", "ADEV [rad/s]"), ("accel", "ADEV [m/s^2]")]
        .iter()
        .enumerate()
    {
        let axes: Vec<_> = report.axes.iter().filter(|a| a.sensor == *sensor).collect();
        let pts = axes
            .iter()
            .flat_map(|a| a.curve.iter())
            .filter(|p| p.adev > 0.0 && p.adev.is_finite());
        let (mut tlo, mut thi, mut alo, mut ahi) = (f64::INFINITY, 0.0f64, f64::INFINITY, 0.0f64);
        for p in pts {
            tlo = tlo.min(p.tau_s);
            thi = thi.max(p.tau_s);
            alo = alo.min(p.ci_low.unwrap_or(p.adev).max(p.adev * 0.1));
            ahi = ahi.max(p.ci_high.unwrap_or(p.adev).min(p.adev * 10.0));
        }
        if !(tlo.is_finite() && thi > tlo && alo.is_finite() && ahi > alo) {
            continue;
        }
        let (tlo, thi) = crate::plot_axis::log(tlo / 1.5, thi * 1.5);
        let (alo, ahi) = crate::plot_axis::log(alo / 2.0, ahi * 2.0);
        let mut chart = ChartBuilder::on(&panels[pi])
            .margin(16)
            .x_label_area_size(36)
            .y_label_area_size(64)
            .build_cartesian_2d((tlo..thi).log_scale(), (alo..ahi).log_scale())?;
        chart
            .configure_mesh()
            .x_desc("tau [s]")
            .y_desc(*unit)
            .y_label_formatter(&|v| format!("{v:.0e}"))
            .x_label_formatter(&|v| format!("{v:.0e}"))
            .draw()?;
        let taus: Vec<f64> = (0..=60)
            .map(|i| tlo * (thi / tlo).powf(f64::from(i) / 60.0))
            .collect();
        let clip = |v: f64| v.clamp(alo, ahi);
        for a in &axes {
            let col = AXIS_COLOURS[["x", "y", "z"]
                .iter()
                .position(|x| *x == a.axis)
                .unwrap_or(0)];
            let curve: Vec<(f64, f64)> = a
                .curve
                .iter()
                .filter(|p| p.adev > 0.0 && p.adev.is_finite())
                .map(|p| (p.tau_s, clip(p.adev)))
                .collect();
            chart.draw_series(LineSeries::new(curve.clone(), col.stroke_width(2)))?;
            chart.draw_series(
                curve
                    .iter()
                    .map(|&(t, v)| Circle::new((t, v), 2, col.filled())),
            )?;
            // Confidence bars.
            chart.draw_series(a.curve.iter().filter_map(|p| {
                Some(PathElement::new(
                    vec![(p.tau_s, clip(p.ci_low?)), (p.tau_s, clip(p.ci_high?))],
                    col.mix(0.5).stroke_width(1),
                ))
            }))?;
            let [n, b, k] = a.fit.raw;
            if a.fit.taus_used > 0 {
                let model: Vec<(f64, f64)> = taus
                    .iter()
                    .map(|&t| {
                        (
                            t,
                            clip(
                                (n * n / t + (FLICKER_FACTOR * b).powi(2) + k * k * t / 3.0).sqrt(),
                            ),
                        )
                    })
                    .collect();
                chart.draw_series(DashedLineSeries::new(
                    model,
                    6,
                    4,
                    col.mix(0.8).stroke_width(1),
                ))?;
            }
            if let Some(n) = a.fit.n {
                let l: Vec<(f64, f64)> = taus.iter().map(|&t| (t, clip(n / t.sqrt()))).collect();
                chart.draw_series(DashedLineSeries::new(l, 2, 4, col.mix(0.4).stroke_width(1)))?;
            }
            if let Some(k) = a.fit.k {
                let l: Vec<(f64, f64)> = taus
                    .iter()
                    .map(|&t| (t, clip(k * (t / 3.0).sqrt())))
                    .collect();
                chart.draw_series(DashedLineSeries::new(l, 2, 4, col.mix(0.4).stroke_width(1)))?;
            }
        }
    }
    root.present()?;
    Ok(())
}

/// Bias vs temperature per axis (gyroscope left, accelerometer right; x red, y green, z blue):
/// binned means of the data as dots, the fitted polynomial as a line over the valid range.
pub fn thermal_svg(report: &ImuThermalReport) -> String {
    let mut out = String::new();
    let _ = draw_thermal(&mut out, report);
    out
}

fn draw_thermal(out: &mut String, report: &ImuThermalReport) -> Result<(), DrawErr> {
    let root = SVGBackend::with_string(out, (1100, 480)).into_drawing_area();
    root.fill(&WHITE)?;
    let panels = root.split_evenly((1, 2));
    let [t0, t1] = report.valid_range_c;
    if !(t0.is_finite() && t1 > t0) {
        root.present()?;
        return Ok(());
    }
    let ts: Vec<f64> = (0..=100)
        .map(|i| t0 + (t1 - t0) * f64::from(i) / 100.0)
        .collect();
    for (pi, (sensor, unit)) in [("gyro", "bias [rad/s]"), ("accel", "bias [m/s^2]")]
        .iter()
        .enumerate()
    {
        let axes: Vec<_> = report.axes.iter().filter(|a| a.sensor == *sensor).collect();
        let eval = |c: &[f64], t: f64| {
            c.iter()
                .rev()
                .fold(0.0, |acc, &ci| acc * (t - report.t_ref_c) + ci)
        };
        let mut lo = f64::INFINITY;
        let mut hi = f64::NEG_INFINITY;
        for a in &axes {
            for b in &a.binned {
                lo = lo.min(b[1]);
                hi = hi.max(b[1]);
            }
            for &t in &ts {
                let v = eval(&a.coeffs, t);
                lo = lo.min(v);
                hi = hi.max(v);
            }
        }
        if !(lo.is_finite() && hi.is_finite()) {
            continue;
        }
        let pad = ((hi - lo) * 0.08).max(1e-9);
        let xr = crate::plot_axis::linear(t0, t1);
        let yr = crate::plot_axis::linear(lo - pad, hi + pad);
        let mut chart = ChartBuilder::on(&panels[pi])
            .margin(16)
            .x_label_area_size(36)
            .y_label_area_size(64)
            .build_cartesian_2d(xr.0..xr.1, yr.0..yr.1)?;
        chart
            .configure_mesh()
            .x_desc("temperature [degC]")
            .y_desc(*unit)
            .y_label_formatter(&|v| format!("{v:.2e}"))
            .draw()?;
        for a in &axes {
            let col = AXIS_COLOURS[["x", "y", "z"]
                .iter()
                .position(|x| *x == a.axis)
                .unwrap_or(0)];
            chart.draw_series(
                a.binned
                    .iter()
                    .map(|b| Circle::new((b[0], b[1]), 2, col.filled())),
            )?;
            chart.draw_series(LineSeries::new(
                ts.iter().map(|&t| (t, eval(&a.coeffs, t))),
                col.stroke_width(2),
            ))?;
        }
    }
    root.present()?;
    Ok(())
}
