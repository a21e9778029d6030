//! The report's plots as SVG text, drawn by `plotters` (SVG backend, no font files: text is
//! SVG `<text>` in a generic family). Each function returns one `<svg>` element with a
//! `<title>`, or why it could not draw (non-finite data, nothing to draw).

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use crate::units::human::fmt_fixed;

/// Why a plot could not be drawn.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct PlotError(String);

fn failed(e: impl std::fmt::Display) -> PlotError {
    PlotError(e.to_string())
}

type Area<'a> = DrawingArea<SVGBackend<'a>, Shift>;

/// Colour of the nominal model's errors.
const BEFORE: RGBColor = RGBColor(214, 96, 77);
/// Colour of the identified model's errors.
const AFTER: RGBColor = RGBColor(33, 102, 172);
const GRID: RGBColor = RGBColor(225, 225, 225);
const FONT: &str = "sans-serif";

/// Draw with `draw` on a `w`×`h` SVG canvas; the SVG text with `title` as its `<title>`.
fn svg(
    w: u32,
    h: u32,
    title: &str,
    draw: impl FnOnce(&Area) -> Result<(), PlotError>,
) -> Result<String, PlotError> {
    let mut buf = String::new();
    {
        let root = SVGBackend::with_string(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(failed)?;
        draw(&root)?;
        root.present().map_err(failed)?;
    }
    Ok(with_title(&buf, title))
}

/// `svg` with a `<title>` child (escaped) and the `plot` class.
fn with_title(svg: &str, title: &str) -> String {
    match svg.find('>') {
        Some(i) if svg.starts_with("<svg") => format!(
            "{} class=\"plot\" role=\"img\">\n<title>{}</title>{}",
            &svg[..i],
            super::page::esc(title),
            &svg[i + 1..]
        ),
        _ => svg.to_owned(),
    }
}

/// The range `[lo, hi]` of `values` widened by 5 % (and to a non-empty span).
fn span(values: impl Iterator<Item = f64>, include_zero: bool) -> Result<(f64, f64), PlotError> {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values {
        if !v.is_finite() {
            return Err(PlotError(format!("a value is not finite ({v})")));
        }
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if lo > hi {
        return Err(PlotError("nothing to plot".into()));
    }
    if include_zero {
        lo = lo.min(0.0);
        hi = hi.max(0.0);
    }
    let pad = ((hi - lo) * 0.05).max(1e-12 * hi.abs().max(1.0));
    Ok((lo - pad, hi + pad))
}

/// Values of one series over pose numbers 1…n: the nominal model's and the identified one's.
pub struct BeforeAfter<'a> {
    /// Nominal model.
    pub before: &'a [f64],
    /// Identified model.
    pub after: &'a [f64],
}

/// A value axis label with the decimals its ~10 ticks over `span` need, never `-0.0`.
fn axis_label(v: f64, span: f64) -> String {
    let step = span / 10.0;
    let decimals = if step > 0.0 && step.is_finite() {
        (-step.log10().floor()).clamp(0.0, 9.0) as usize
    } else {
        3
    };
    fmt_fixed(v, decimals)
}

/// Per-pose errors before and after (x = pose number 1…n), like the paper's Figs. 8–13.
pub fn per_pose(title: &str, y_desc: &str, s: &BeforeAfter) -> Result<String, PlotError> {
    let n = s.before.len().max(s.after.len());
    let (lo, hi) = span(s.before.iter().chain(s.after).copied(), true)?;
    svg(520, 280, title, |root| {
        let mut chart = ChartBuilder::on(root)
            .caption(title, (FONT, 15))
            .margin(8)
            .x_label_area_size(32)
            .y_label_area_size(58)
            .build_cartesian_2d(0.5..(n as f64 + 0.5), lo..hi)
            .map_err(failed)?;
        chart
            .configure_mesh()
            .light_line_style(WHITE)
            .bold_line_style(GRID)
            .x_desc("pose")
            .x_label_formatter(&|v| format!("{v:.0}"))
            .y_label_formatter(&|v| axis_label(*v, hi - lo))
            .y_desc(y_desc)
            .label_style((FONT, 11))
            .draw()
            .map_err(failed)?;
        let markers = n <= 300;
        for (values, colour, label) in [(s.before, BEFORE, "before"), (s.after, AFTER, "after")] {
            let points = values.iter().enumerate().map(|(i, v)| ((i + 1) as f64, *v));
            chart
                .draw_series(LineSeries::new(points.clone(), colour.stroke_width(1)))
                .map_err(failed)?
                .label(label)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], colour));
            if markers {
                chart
                    .draw_series(points.map(|p| Circle::new(p, 2, colour.filled())))
                    .map_err(failed)?;
            }
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .label_font((FONT, 11))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK.mix(0.4))
            .draw()
            .map_err(failed)
    })
}

/// Counts of `values` in `bins` equal bins over `[0, max]`.
fn bin_counts(values: &[f64], bins: usize, max: f64) -> Vec<usize> {
    let mut counts = vec![0; bins];
    for v in values {
        let b = ((v / max) * bins as f64).floor().max(0.0) as usize;
        counts[b.min(bins - 1)] += 1;
    }
    counts
}

/// Histogram of non-negative `values` (e.g. comprehensive errors, mm) in `colour`.
pub fn histogram(
    title: &str,
    x_desc: &str,
    values: &[f64],
    after: bool,
) -> Result<String, PlotError> {
    let (_, hi) = span(values.iter().copied(), true)?;
    let bins = ((values.len() as f64).sqrt().ceil() as usize).clamp(5, 30);
    let counts = bin_counts(values, bins, hi);
    let top = counts.iter().copied().max().unwrap_or(1).max(1) as f64 * 1.1;
    let colour = if after { AFTER } else { BEFORE };
    svg(400, 260, title, |root| {
        let mut chart = ChartBuilder::on(root)
            .caption(title, (FONT, 15))
            .margin(8)
            .x_label_area_size(32)
            .y_label_area_size(44)
            .build_cartesian_2d(0.0..hi, 0.0..top)
            .map_err(failed)?;
        chart
            .configure_mesh()
            .light_line_style(WHITE)
            .bold_line_style(GRID)
            .x_desc(x_desc)
            .y_desc("poses")
            .y_label_formatter(&|v| format!("{v:.0}"))
            .label_style((FONT, 11))
            .draw()
            .map_err(failed)?;
        let w = hi / bins as f64;
        chart
            .draw_series(counts.iter().enumerate().map(|(i, c)| {
                let x0 = i as f64 * w;
                Rectangle::new([(x0, 0.0), (x0 + w, *c as f64)], colour.mix(0.75).filled())
            }))
            .map_err(failed)?;
        Ok(())
    })
}

/// Bars of `values` over the labelled categories `labels` (e.g. significance indices).
pub fn bars(
    title: &str,
    y_desc: &str,
    labels: &[String],
    values: &[f64],
) -> Result<String, PlotError> {
    let (lo, hi) = span(values.iter().copied(), true)?;
    let k = labels.len();
    svg(720, 260, title, |root| {
        let mut chart = ChartBuilder::on(root)
            .caption(title, (FONT, 15))
            .margin(8)
            .x_label_area_size(44)
            .y_label_area_size(58)
            .build_cartesian_2d((0..k).into_segmented(), lo..hi)
            .map_err(failed)?;
        chart
            .configure_mesh()
            .light_line_style(WHITE)
            .bold_line_style(GRID)
            .disable_x_mesh()
            .label_style((FONT, 11))
            .x_labels(k + 1)
            .x_label_formatter(&|v| segment_label(labels, v))
            .x_label_style(
                (FONT, 10)
                    .into_font()
                    .transform(FontTransform::Rotate90)
                    .into_text_style(root)
                    .pos(Pos::new(HPos::Left, VPos::Center)),
            )
            .y_desc(y_desc)
            .draw()
            .map_err(failed)?;
        chart
            .draw_series(values.iter().enumerate().map(|(i, v)| {
                Rectangle::new(
                    [
                        (SegmentValue::Exact(i), 0.0),
                        (SegmentValue::Exact(i + 1), *v),
                    ],
                    AFTER.mix(0.8).filled(),
                )
            }))
            .map_err(failed)?;
        Ok(())
    })
}

fn segment_label(labels: &[String], v: &SegmentValue<usize>) -> String {
    match v {
        SegmentValue::CenterOf(i) => labels.get(*i).cloned().unwrap_or_default(),
        _ => String::new(),
    }
}

/// Colour of a correlation ρ ∈ [−1, 1]: blue (−1) through white (0) to red (+1); grey for NaN.
fn diverging(rho: f64) -> RGBColor {
    if !rho.is_finite() {
        return RGBColor(160, 160, 160);
    }
    let t = rho.clamp(-1.0, 1.0);
    let (end, w) = if t < 0.0 { (AFTER, -t) } else { (BEFORE, t) };
    let mix = |c: u8| (255.0 + (f64::from(c) - 255.0) * w).round() as u8;
    RGBColor(mix(end.0), mix(end.1), mix(end.2))
}

/// Heat map of a symmetric correlation matrix with the parameter names on both axes.
pub fn heat_map(title: &str, names: &[String], matrix: &[Vec<f64>]) -> Result<String, PlotError> {
    let k = names.len();
    if k == 0 || matrix.len() != k || matrix.iter().any(|r| r.len() != k) {
        return Err(PlotError(format!(
            "the correlation matrix is not {k} × {k}"
        )));
    }
    let side = (16 * k as u32).clamp(240, 620) + 70;
    svg(side + 70, side + 30, title, |root| {
        let (plot, legend) = root.split_horizontally(side);
        let mut chart = ChartBuilder::on(&plot)
            .caption(title, (FONT, 15))
            .margin(6)
            .x_label_area_size(60)
            .y_label_area_size(60)
            .build_cartesian_2d((0..k).into_segmented(), (0..k).into_segmented())
            .map_err(failed)?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_labels(k + 1)
            .y_labels(k + 1)
            .x_label_formatter(&|v| segment_label(names, v))
            .y_label_formatter(&|v| segment_label(names, &flip(v, k)))
            .x_label_style(
                (FONT, 10)
                    .into_font()
                    .transform(FontTransform::Rotate90)
                    .into_text_style(&plot)
                    .pos(Pos::new(HPos::Left, VPos::Center)),
            )
            .y_label_style((FONT, 10))
            .draw()
            .map_err(failed)?;
        let cells = (0..k).flat_map(|i| (0..k).map(move |j| (i, j)));
        chart
            .draw_series(cells.map(|(i, j)| {
                // row i from the top
                let (y0, y1) = (k - 1 - i, k - i);
                Rectangle::new(
                    [
                        (SegmentValue::Exact(j), SegmentValue::Exact(y0)),
                        (SegmentValue::Exact(j + 1), SegmentValue::Exact(y1)),
                    ],
                    diverging(matrix[i][j]).filled(),
                )
            }))
            .map_err(failed)?;
        colour_scale(&legend)
    })
}

/// Segment `v` counted from the top (row order) instead of from the bottom.
fn flip(v: &SegmentValue<usize>, k: usize) -> SegmentValue<usize> {
    match v {
        SegmentValue::CenterOf(i) if *i < k => SegmentValue::CenterOf(k - 1 - i),
        _ => SegmentValue::Last,
    }
}

/// The heat map's colour scale, −1 (bottom) … +1 (top).
fn colour_scale(area: &Area) -> Result<(), PlotError> {
    let mut chart = ChartBuilder::on(area)
        .margin_top(40)
        .margin_bottom(66)
        .margin_right(30)
        .y_label_area_size(30)
        .build_cartesian_2d(0.0..1.0, -1.0..1.0)
        .map_err(failed)?;
    chart
        .configure_mesh()
        .disable_mesh()
        .disable_x_axis()
        .y_labels(5)
        .y_label_style((FONT, 10))
        .draw()
        .map_err(failed)?;
    let steps = 40;
    chart
        .draw_series((0..steps).map(|s| {
            let y0 = -1.0 + 2.0 * s as f64 / steps as f64;
            let y1 = y0 + 2.0 / steps as f64;
            Rectangle::new([(0.0, y0), (1.0, y1)], diverging((y0 + y1) / 2.0).filled())
        }))
        .map_err(failed)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn axis_labels_have_the_ticks_decimals_and_no_negative_zero() {
        assert_eq!(axis_label(-1e-17, 2.0), "0.0");
        assert_eq!(axis_label(0.4, 2.0), "0.4");
        assert_eq!(axis_label(0.005, 0.05), "0.005");
        assert_eq!(axis_label(12.0, 100.0), "12");
    }

    #[test]
    fn bins_cover_the_maximum_and_count_every_value() {
        let c = bin_counts(&[0.0, 0.5, 1.0, 0.99], 4, 1.0);
        assert_eq!(c, vec![1, 0, 1, 2]);
    }

    #[test]
    fn non_finite_data_is_refused_not_drawn() {
        let s = BeforeAfter {
            before: &[1.0, f64::NAN],
            after: &[0.1, 0.2],
        };
        assert!(per_pose("t", "mm", &s).is_err());
    }

    #[test]
    fn category_labels_are_rotated_not_overlapping() {
        let labels: Vec<String> = (0..30).map(|i| format!("theta{i}")).collect();
        let values: Vec<f64> = (0..30).map(f64::from).collect();
        let svg = bars("t", "mm", &labels, &values).expect("drawn");
        // every category label (and the empty one past the last category) turned by 90°
        assert_eq!(svg.matches("rotate(90").count(), 31, "{svg:.2000}");
    }

    #[test]
    fn correlation_colours_run_from_blue_through_white_to_red() {
        assert_eq!(diverging(0.0), RGBColor(255, 255, 255));
        assert_eq!(diverging(1.0), BEFORE);
        assert_eq!(diverging(-1.0), AFTER);
    }
}
