//! SVG scatter of the two blur scores, for a quick visual check of where the thresholds sit.

use plotters::prelude::*;

use super::{BlurParams, BlurReport};

const SHARP: RGBColor = RGBColor(0x1f, 0x77, 0xb4);
const BLURRED: RGBColor = RGBColor(0xd6, 0x27, 0x28);
const THRESHOLD: RGBColor = RGBColor(0xff, 0x7f, 0x0e);

/// Scatter plot of Laplacian variance (x, log scale) against β (y), one dot per image, blue for
/// sharp and red for blurred, with the two thresholds of `params` as grey lines. Returns the SVG
/// document. Text is limited to axis tick labels: the build has no font files, and the SVG
/// backend writes `<text>` elements that the viewer renders with its own fonts.
pub fn render_svg(report: &BlurReport, params: &BlurParams) -> String {
    let mut out = String::new();
    // Drawing into a String cannot fail for I/O reasons; if plotters reports an error anyway
    // we still return whatever was produced rather than failing the whole job over a chart.
    let _ = draw(&mut out, report, params);
    out
}

fn draw(out: &mut String, report: &BlurReport, params: &BlurParams) -> Result<(), String> {
    let e = |e: DrawingAreaErrorKind<std::io::Error>| e.to_string();
    // Log axis: clamp zero variances (flat images) to a small positive floor.
    const FLOOR: f64 = 1e-2;
    let xs = report
        .images
        .iter()
        .map(|s| s.laplacian_variance.max(FLOOR))
        .chain(std::iter::once(params.laplacian_threshold.max(FLOOR)));
    let (lo, hi) = xs.fold((f64::INFINITY, 0.0f64), |(lo, hi), v| {
        (lo.min(v), hi.max(v))
    });
    let (lo, hi) = if lo.is_finite() && hi > 0.0 {
        (lo / 2.0, hi * 2.0)
    } else {
        (FLOOR, 1e4)
    };

    let root = SVGBackend::with_string(out, (640, 480)).into_drawing_area();
    root.fill(&WHITE).map_err(e)?;
    let mut chart = ChartBuilder::on(&root)
        .margin(16)
        .x_label_area_size(32)
        .y_label_area_size(40)
        .build_cartesian_2d((lo..hi).log_scale(), 0.0f64..1.0f64)
        .map_err(e)?;
    chart
        .configure_mesh()
        .x_desc("Laplacian variance")
        .y_desc("SVD beta")
        .draw()
        .map_err(e)?;

    let t = params.laplacian_threshold.max(FLOOR);
    chart
        .draw_series(LineSeries::new(
            vec![(t, 0.0), (t, 1.0)],
            THRESHOLD.stroke_width(2),
        ))
        .map_err(e)?;
    chart
        .draw_series(LineSeries::new(
            vec![(lo, params.beta_threshold), (hi, params.beta_threshold)],
            THRESHOLD.stroke_width(2),
        ))
        .map_err(e)?;
    chart
        .draw_series(report.images.iter().map(|s| {
            let colour = if s.blurred { BLURRED } else { SHARP };
            Circle::new(
                (s.laplacian_variance.max(FLOOR), s.svd_beta.clamp(0.0, 1.0)),
                4,
                colour.filled(),
            )
        }))
        .map_err(e)?;
    root.present().map_err(e)?;
    Ok(())
}
