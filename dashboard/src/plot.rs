//! Line charts (plotters) for force curves and traces, as SVG or PNG: a title, axis labels with
//! units, a legend, and one colour per force component everywhere ([`palette`]). Used by the dashboard
//! pages, `stylet script run --plot` and the haptics tests.

use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;

use stylet_render::RenderError;

/// A chart colour (plotters' RGB).
pub use plotters::style::RGBColor as ChartColor;
use stylet_render::fonts::{SANS, ensure_fonts};

/// The colours of the force components, used by every chart.
pub mod palette {
    use plotters::style::RGBColor;
    pub const TOTAL: RGBColor = RGBColor(30, 30, 30);
    pub const CUTTING: RGBColor = RGBColor(214, 39, 40);
    pub const FRICTION: RGBColor = RGBColor(31, 119, 180);
    pub const BASE: RGBColor = RGBColor(44, 160, 44);
    pub const SKIN: RGBColor = RGBColor(255, 127, 14);
    pub const BONE: RGBColor = RGBColor(148, 103, 189);
    pub const OTHER: RGBColor = RGBColor(127, 127, 127);
    /// Not forces: insertion depth and difficulty levels.
    pub const INSERTED: RGBColor = RGBColor(23, 150, 170);
    pub const TIP_DEPTH: RGBColor = RGBColor(140, 86, 75);
    pub const BEGINNER: RGBColor = RGBColor(0, 128, 128);
    pub const ADVANCED: RGBColor = RGBColor(191, 144, 0);
    pub const EXPERT: RGBColor = RGBColor(199, 21, 133);
}

/// Why plotters could not draw a chart: its drawing backend failed (plotters' message). The
/// charts are drawn into memory or into a file the caller chose, so this is a fault of the
/// backend or its fonts, never of the data.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct ChartError(String);

impl<E: std::error::Error + Send + Sync> From<DrawingAreaErrorKind<E>> for ChartError {
    fn from(e: DrawingAreaErrorKind<E>) -> Self {
        ChartError(e.to_string())
    }
}

/// One curve.
#[derive(Debug, Clone)]
pub struct Series {
    pub name: String,
    pub color: RGBColor,
    pub points: Vec<(f64, f64)>,
    /// Drawn thicker (the total).
    pub bold: bool,
    /// Drawn dashed (the second session of a comparison).
    pub dashed: bool,
    /// A dot on every point (few points, each one a session).
    pub dots: bool,
}

impl Default for Series {
    fn default() -> Self {
        Series {
            name: String::new(),
            color: palette::OTHER,
            points: Vec::new(),
            bold: false,
            dashed: false,
            dots: false,
        }
    }
}

/// A chart: curves plus vertical event markers.
#[derive(Debug, Clone, Default)]
pub struct LineChart {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub series: Vec<Series>,
    /// Vertical markers (x, label), e.g. events.
    pub markers: Vec<(f64, String)>,
    /// Labelled points (x, y, label), e.g. force peaks named by the structure punctured.
    pub peaks: Vec<(f64, f64, String)>,
    /// Vertical notes (x, label), drawn dashed in blue, e.g. an instructor's timestamped comments.
    pub notes: Vec<(f64, String)>,
    /// A fixed y range (e.g. scores 0–100) instead of the data's.
    pub y_range: Option<(f64, f64)>,
    /// x is a count (session number): whole-number tick labels.
    pub x_whole: bool,
}

fn range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    let pad = ((hi - lo) * 0.05).max(1e-3);
    (lo - pad, hi + pad)
}

/// Where a chart's x axis lies in the picture: data values `x0 … x1` span pixels `px0 … px1`
/// (the player draws its cursor there and turns a click into a time).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct XAxis {
    pub x0: f64,
    pub x1: f64,
    pub px0: i32,
    pub px1: i32,
}

fn draw<DB: DrawingBackend>(chart: &LineChart, root: &DrawingArea<DB, Shift>) -> Result<XAxis, ChartError> {
    root.fill(&WHITE)?;
    let (mut x0, mut x1) = range(chart.series.iter().flat_map(|s| s.points.iter().map(|p| p.0)));
    if chart.x_whole {
        // Counts: half a step of room on each side of the first and last.
        let xs = chart.series.iter().flat_map(|s| s.points.iter().map(|p| p.0));
        let (lo, hi) = xs.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
        if lo.is_finite() {
            (x0, x1) = (lo - 0.5, hi + 0.5);
        }
    }
    let (y0, y1) = chart
        .y_range
        .unwrap_or_else(|| range(chart.series.iter().flat_map(|s| s.points.iter().map(|p| p.1))));
    let mut c = ChartBuilder::on(root)
        .caption(&chart.title, (SANS, 26))
        .margin(16)
        .x_label_area_size(56)
        .y_label_area_size(72)
        .build_cartesian_2d(x0..x1, y0..y1)?;
    let (px, _) = c.plotting_area().get_pixel_range();
    let axis = XAxis {
        x0,
        x1,
        px0: px.start,
        px1: px.end,
    };
    // Whole numbers only (a tick between two sessions gets no label).
    let whole = |x: &f64| {
        if (x - x.round()).abs() < 1e-9 {
            format!("{x:.0}")
        } else {
            String::new()
        }
    };
    let mut mesh = c.configure_mesh();
    if chart.x_whole {
        mesh.x_label_formatter(&whole)
            .x_labels(((x1 - x0).round() as usize + 1).clamp(2, 12));
    }
    mesh.x_desc(&chart.x_label)
        .y_desc(&chart.y_label)
        .axis_desc_style((SANS, 20))
        .label_style((SANS, 16))
        .light_line_style(RGBColor(235, 235, 235))
        .draw()?;
    for (n, (x, label)) in chart.markers.iter().enumerate() {
        let style = ShapeStyle::from(&RGBColor(150, 150, 150)).stroke_width(1);
        c.draw_series(std::iter::once(PathElement::new(vec![(*x, y0), (*x, y1)], style)))?;
        // Staggered so labels of close events do not overlap.
        let y = y1 - (y1 - y0) * (0.03 + 0.05 * (n % 4) as f64);
        c.draw_series(std::iter::once(Text::new(
            format!(" {label}"),
            (*x, y),
            (SANS, 14).into_font(),
        )))?;
    }
    let note_color = RGBColor(30, 90, 200);
    for (n, (x, label)) in chart.notes.iter().enumerate() {
        let style = ShapeStyle::from(&note_color).stroke_width(2);
        c.draw_series(DashedLineSeries::new([(*x, y0), (*x, y1)], 6, 4, style))?;
        let y = y0 + (y1 - y0) * (0.1 + 0.06 * (n % 3) as f64);
        c.draw_series(std::iter::once(Text::new(
            format!(" {label}"),
            (*x, y),
            (SANS, 15).into_font().color(&note_color),
        )))?;
    }
    for s in &chart.series {
        let style = ShapeStyle::from(&s.color).stroke_width(if s.bold { 3 } else { 2 });
        let color = s.color;
        if s.dots {
            c.draw_series(
                s.points
                    .iter()
                    .map(|p| Circle::new(*p, 4, ShapeStyle::from(&color).filled())),
            )?;
        }
        let drawn = if s.dashed {
            c.draw_series(DashedLineSeries::new(s.points.iter().copied(), 10, 6, style))
        } else {
            c.draw_series(LineSeries::new(s.points.iter().copied(), style))
        };
        let dashed = s.dashed;
        drawn?.label(&s.name).legend(move |(x, y)| {
            let style = ShapeStyle::from(&color).stroke_width(3);
            if dashed {
                PathElement::new(vec![(x, y), (x + 9, y)], style)
            } else {
                PathElement::new(vec![(x, y), (x + 24, y)], style)
            }
        });
    }
    for (x, y, label) in &chart.peaks {
        c.draw_series(std::iter::once(Circle::new(
            (*x, *y),
            4,
            ShapeStyle::from(&BLACK).filled(),
        )))?;
        c.draw_series(std::iter::once(Text::new(
            label.clone(),
            (*x, *y),
            (SANS, 15)
                .into_font()
                .style(FontStyle::Bold)
                .color(&BLACK)
                .pos(plotters::style::text_anchor::Pos::new(
                    plotters::style::text_anchor::HPos::Center,
                    plotters::style::text_anchor::VPos::Bottom,
                )),
        )))?;
    }
    c.configure_series_labels()
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK)
        .label_font((SANS, 16))
        .position(SeriesLabelPosition::UpperRight)
        .draw()?;
    root.present()?;
    Ok(axis)
}

/// Writes the chart to `path`: SVG if it ends in `.svg`, else PNG.
pub fn write_chart(chart: &LineChart, path: &Path, size: (u32, u32)) -> Result<(), RenderError> {
    ensure_fonts();
    let err = |m: String| RenderError::Write {
        path: path.display().to_string(),
        message: m,
    };
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| err(e.to_string()))?;
    }
    let svg = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("svg"));
    if svg {
        let root = SVGBackend::new(path, size).into_drawing_area();
        draw(chart, &root).map(|_| ()).map_err(|e| err(e.to_string()))
    } else {
        let mut rgb = vec![0u8; size.0 as usize * size.1 as usize * 3];
        {
            let root = BitMapBackend::with_buffer(&mut rgb, size).into_drawing_area();
            draw(chart, &root).map_err(|e| err(e.to_string()))?;
            root.present().map_err(|e| err(e.to_string()))?;
        }
        stylet_render::figure::write_rgb_png(path, size.0 as usize, size.1 as usize, &rgb)
    }
}

/// The chart as an SVG string (for pages and tests).
pub fn chart_svg(chart: &LineChart, size: (u32, u32)) -> Result<String, RenderError> {
    chart_svg_axis(chart, size).map(|(svg, _)| svg)
}

/// [`chart_svg`] and where its x axis lies.
pub fn chart_svg_axis(chart: &LineChart, size: (u32, u32)) -> Result<(String, XAxis), RenderError> {
    ensure_fonts();
    let mut out = String::new();
    let axis = {
        let root = SVGBackend::with_string(&mut out, size).into_drawing_area();
        draw(chart, &root).map_err(|e| RenderError::Draw(e.to_string()))?
    };
    Ok((out, axis))
}
