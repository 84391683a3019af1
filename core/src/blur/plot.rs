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
    // Log axis: clamp zero variances (flat images) to a small positive floor, and every value
    // to a ceiling far above any real variance, so that the axis bounds stay finite whatever
    // the inputs (an infinite bound makes the plotting library's tick search never end).
    const FLOOR: f64 = 1e-2;
    const CEILING: f64 = 1e12;
    let clamp = |v: f64| {
        if v.is_finite() {
            v.clamp(FLOOR, CEILING)
        } else {
            CEILING
        }
    };
    let xs = report
        .images
        .iter()
        .map(|s| clamp(s.laplacian_variance))
        .chain(std::iter::once(clamp(params.laplacian_threshold)));
    let (lo, hi) = xs.fold((CEILING, FLOOR), |(lo, hi), v| (lo.min(v), hi.max(v)));
    let (lo, hi) = crate::plot_axis::log(lo / 2.0, (hi * 2.0).max(lo * 4.0));
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

    let t = clamp(params.laplacian_threshold);
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
                (clamp(s.laplacian_variance), s.svd_beta.clamp(0.0, 1.0)),
                4,
                colour.filled(),
            )
        }))
        .map_err(e)?;
    root.present().map_err(e)?;
    Ok(())
}
