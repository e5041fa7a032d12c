//! Plots of an evaluation: the top-down (x–y) trajectory with the estimate coloured by its APE,
//! a colour bar, and the APE over time with its rmse/mean/median.
//!
//! SVG is the fully labelled output. plotters is built without a font rasteriser (no `ttf`), so
//! bitmap backends cannot draw text: PNG output has the same curves and colours but no text.

use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::error::{EvalError, Result};
use crate::report::EvalReport;

const WIDTH: u32 = 1500;
const HEIGHT: u32 = 650;

/// Writes the evaluation plot; the format follows the extension (`.svg` or `.png`).
pub fn plot_report(report: &EvalReport, path: &Path) -> Result<()> {
    let plot_error = |message: String| EvalError::Plot {
        path: path.to_path_buf(),
        message,
    };
    let extension = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match extension.as_deref() {
        Some("svg") => {
            let root = SVGBackend::new(path, (WIDTH, HEIGHT)).into_drawing_area();
            draw(&root, report, true).map_err(plot_error)?;
            root.present().map_err(|e| plot_error(e.to_string()))
        }
        Some("png") => {
            let root = BitMapBackend::new(path, (WIDTH, HEIGHT)).into_drawing_area();
            draw(&root, report, false).map_err(plot_error)?;
            root.present().map_err(|e| plot_error(e.to_string()))
        }
        _ => Err(plot_error(
            "unsupported plot format: use a .svg or .png file name".into(),
        )),
    }
}

/// Maps `v` in `[lo, hi]` to a perceptually ordered blue → green → yellow → red ramp.
fn colour(v: f64, lo: f64, hi: f64) -> RGBColor {
    const STOPS: [(f64, [f64; 3]); 5] = [
        (0.0, [48.0, 18.0, 160.0]),
        (0.25, [30.0, 120.0, 230.0]),
        (0.5, [40.0, 190.0, 110.0]),
        (0.75, [245.0, 200.0, 30.0]),
        (1.0, [210.0, 30.0, 30.0]),
    ];
    let x = if hi > lo {
        ((v - lo) / (hi - lo)).clamp(0.0, 1.0)
    } else {
        0.0
    };
    let k = STOPS.iter().rposition(|(s, _)| *s <= x).unwrap_or(0).min(3);
    let (s0, c0) = STOPS[k];
    let (s1, c1) = STOPS[k + 1];
    let f = (x - s0) / (s1 - s0);
    let mix = |i: usize| (c0[i] + f * (c1[i] - c0[i])).round() as u8;
    RGBColor(mix(0), mix(1), mix(2))
}

/// Expands `(lo, hi)` by a margin and to at least `min_span`.
fn padded(lo: f64, hi: f64, min_span: f64) -> (f64, f64) {
    let span = (hi - lo).max(min_span);
    let mid = 0.5 * (lo + hi);
    (mid - 0.55 * span, mid + 0.55 * span)
}

fn draw<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    report: &EvalReport,
    text: bool,
) -> std::result::Result<(), String> {
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    root.fill(&WHITE).map_err(err)?;
    let (left, rest) = root.split_horizontally(650);
    let (bar, right) = rest.split_horizontally(110);

    let errors = &report.ape_translation.errors;
    let (lo, hi) = (
        report.ape_translation.stats.min,
        report.ape_translation.stats.max,
    );
    let ref_xy: Vec<(f64, f64)> = report
        .reference
        .positions()
        .iter()
        .map(|p| (p.x, p.y))
        .collect();
    let est_xy: Vec<(f64, f64)> = report
        .aligned_estimate
        .positions()
        .iter()
        .map(|p| (p.x, p.y))
        .collect();

    // Top view with equal axis scales.
    let all = ref_xy.iter().chain(&est_xy);
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for &(x, y) in all {
        (x0, x1, y0, y1) = (x0.min(x), x1.max(x), y0.min(y), y1.max(y));
    }
    let span = (x1 - x0).max(y1 - y0).max(1e-6);
    let (x0, x1) = padded(x0, x1, span);
    let (y0, y1) = padded(y0, y1, span);
    let mut builder = ChartBuilder::on(&left);
    builder.margin(15);
    if text {
        builder
            .caption(
                "Top view (x-y): estimate coloured by APE",
                ("sans-serif", 20),
            )
            .x_label_area_size(40)
            .y_label_area_size(60);
    }
    let mut chart = builder.build_cartesian_2d(x0..x1, y0..y1).map_err(err)?;
    if text {
        chart
            .configure_mesh()
            .x_desc("x [m]")
            .y_desc("y [m]")
            .light_line_style(WHITE)
            .draw()
            .map_err(err)?;
    } else {
        chart
            .plotting_area()
            .draw(&Rectangle::new([(x0, y0), (x1, y1)], BLACK.stroke_width(1)))
            .map_err(err)?;
    }
    chart
        .draw_series(
            est_xy
                .windows(2)
                .zip(errors)
                .map(|(w, e)| PathElement::new([w[0], w[1]], colour(*e, lo, hi).stroke_width(2))),
        )
        .map_err(err)?;
    chart
        .draw_series(
            est_xy
                .iter()
                .zip(errors)
                .map(|(p, e)| Circle::new(*p, 3, colour(*e, lo, hi).filled())),
        )
        .map_err(err)?
        .label("estimate (aligned)")
        .legend(|(x, y)| Circle::new((x + 10, y), 4, colour(hi, lo, hi).filled()));
    // Ground truth on top, so that it stays visible under a dense estimate.
    let grey = RGBColor(80, 80, 80);
    chart
        // Segment by segment: plotters' bitmap backend renders wide polylines with gaps.
        .draw_series(
            ref_xy
                .windows(2)
                .map(|w| PathElement::new([w[0], w[1]], grey.stroke_width(2))),
        )
        .map_err(err)?
        .label("ground truth")
        .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], grey.stroke_width(2)));
    if text {
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .position(SeriesLabelPosition::LowerRight)
            .draw()
            .map_err(err)?;
    }

    // Colour bar of the APE scale.
    let (b0, b1) = if hi > lo { (lo, hi) } else { (lo, lo + 1e-9) };
    let mut builder = ChartBuilder::on(&bar);
    builder.margin_top(50).margin_bottom(55).margin_right(10);
    if text {
        builder.y_label_area_size(70);
    }
    let mut chart = builder.build_cartesian_2d(0.0..1.0, b0..b1).map_err(err)?;
    if text {
        chart
            .configure_mesh()
            .disable_x_mesh()
            .disable_x_axis()
            .y_desc("APE [m]")
            .y_labels(8)
            .y_label_style(("sans-serif", 12))
            .axis_desc_style(("sans-serif", 14))
            .light_line_style(WHITE)
            .bold_line_style(WHITE)
            .draw()
            .map_err(err)?;
    }
    let steps = 100;
    chart
        .draw_series((0..steps).map(|i| {
            let v0 = b0 + (b1 - b0) * i as f64 / steps as f64;
            let v1 = b0 + (b1 - b0) * (i + 1) as f64 / steps as f64;
            Rectangle::new([(0.0, v0), (1.0, v1)], colour(v0, b0, b1).filled())
        }))
        .map_err(err)?;

    // APE over time with rmse / mean / median.
    let t0 = report
        .ape_translation
        .timestamps
        .first()
        .copied()
        .unwrap_or(0.0);
    let series: Vec<(f64, f64)> = report
        .ape_translation
        .timestamps
        .iter()
        .zip(errors)
        .map(|(t, e)| (t - t0, *e))
        .collect();
    let t_end = series.last().map_or(1.0, |p| p.0).max(1e-6);
    let mut builder = ChartBuilder::on(&right);
    builder.margin(15);
    if text {
        builder
            .caption("APE (translation) over time", ("sans-serif", 20))
            .x_label_area_size(40)
            .y_label_area_size(70);
    }
    let mut chart = builder
        .build_cartesian_2d(0.0..t_end, 0.0..(hi * 1.1).max(1e-9))
        .map_err(err)?;
    if text {
        chart
            .configure_mesh()
            .x_desc("time since start [s]")
            .y_desc("APE [m]")
            .light_line_style(WHITE)
            .draw()
            .map_err(err)?;
    } else {
        chart
            .plotting_area()
            .draw(&Rectangle::new(
                [(0.0, 0.0), (t_end, hi * 1.1)],
                BLACK.stroke_width(1),
            ))
            .map_err(err)?;
    }
    chart
        .draw_series(LineSeries::new(series, BLUE.stroke_width(1)))
        .map_err(err)?
        .label("APE")
        .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], BLUE));
    let stats = &report.ape_translation.stats;
    for (name, value, colour) in [
        ("rmse", stats.rmse, RED),
        ("mean", stats.mean, GREEN),
        ("median", stats.median, MAGENTA),
    ] {
        chart
            .draw_series(LineSeries::new(
                [(0.0, value), (t_end, value)],
                colour.stroke_width(2),
            ))
            .map_err(err)?
            .label(format!("{name} = {value:.4} m"))
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], colour.stroke_width(2)));
    }
    if text {
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .position(SeriesLabelPosition::UpperRight)
            .draw()
            .map_err(err)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colour_ramp_is_continuous_and_clamped() {
        assert_eq!(colour(-1.0, 0.0, 1.0), colour(0.0, 0.0, 1.0));
        assert_eq!(colour(2.0, 0.0, 1.0), RGBColor(210, 30, 30));
        for i in 0..100 {
            let a = colour(i as f64 / 100.0, 0.0, 1.0);
            let b = colour((i + 1) as f64 / 100.0, 0.0, 1.0);
            let d = (a.0 as i32 - b.0 as i32).abs()
                + (a.1 as i32 - b.1 as i32).abs()
                + (a.2 as i32 - b.2 as i32).abs();
            assert!(d < 30, "jump at {i}");
        }
        assert_eq!(colour(5.0, 5.0, 5.0), colour(0.0, 0.0, 1.0));
    }
}
