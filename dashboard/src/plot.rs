//! Line charts (plotters) for force curves and traces, as SVG or PNG: a title, axis labels with
//! units, a legend, and one colour per force component everywhere ([`palette`]). Used by the dashboard
//! pages, `stylet script run --plot` and the haptics tests.

use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

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
    /// The force a force-feedback device was sent, and the spans its guard zeroed or reduced.
    pub const SENT: RGBColor = RGBColor(106, 61, 154);
    pub const ZEROED: RGBColor = RGBColor(214, 39, 40);
    pub const REDUCED: RGBColor = RGBColor(230, 171, 2);
    /// The spans a two-handed session's needle tip was out of the live ultrasound image.
    pub const HIDDEN: RGBColor = RGBColor(120, 120, 170);
    /// A drainage session's steps after the puncture: the guide wire, the dilator, the catheter.
    pub const WIRE_STEP: RGBColor = RGBColor(90, 110, 130);
    pub const DILATOR_STEP: RGBColor = RGBColor(230, 120, 20);
    pub const CATHETER_STEP: RGBColor = RGBColor(40, 150, 80);
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
    /// Shaded spans of x (x0, x1, colour, legend label), under everything else: e.g. where a
    /// device's force guard zeroed or reduced the force.
    pub bands: Vec<(f64, f64, ChartColor, String)>,
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

/// The colour of instructors' comment notes (dashed lines and their labels).
const NOTE_COLOR: RGBColor = RGBColor(30, 90, 200);
/// Label font sizes (plotters' size; the SVG's font-size is this / 1.24).
const MARKER_FONT: i32 = 14;
const NOTE_FONT: i32 = 15;
const PEAK_FONT: i32 = 15;
/// The legend's font size and plotters' fixed parts of its box: the sample line's room, the
/// margin on each side, the gap from the plotting area's edge and one line's height (px).
const LEGEND_FONT: i32 = 16;
const LEGEND_SAMPLE_PX: f64 = 30.0;
const LEGEND_MARGIN_PX: f64 = 10.0;
pub(crate) const LEGEND_GAP_PX: f64 = 5.0;
const LEGEND_LINE_PX: f64 = 20.0;
/// Gap between stacked labels, and between a label and its line or dot (px).
const LABEL_GAP_PX: f64 = 2.0;

/// A rectangle in pixels of the picture (y grows downwards): a label's box, the legend, a dot.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct LabelBox {
    pub x0: f64,
    pub y0: f64,
    pub x1: f64,
    pub y1: f64,
}

impl LabelBox {
    /// A box of `(width, height)` px with its top-left corner at (`x0`, `y0`), on whole pixels:
    /// the text is drawn at the rounded corner, and the size is rounded up so the text stays
    /// inside.
    pub(crate) fn at(x0: f64, y0: f64, (width_px, height_px): (f64, f64)) -> LabelBox {
        let (x0, y0) = (x0.round(), y0.round());
        LabelBox {
            x0,
            y0,
            x1: x0 + width_px.ceil(),
            y1: y0 + height_px.ceil(),
        }
    }

    fn height(&self) -> f64 {
        self.y1 - self.y0
    }

    /// Whether the two share any area (touching edges do not count).
    pub(crate) fn overlaps(&self, o: &LabelBox) -> bool {
        self.x0 < o.x1 && o.x0 < self.x1 && self.y0 < o.y1 && o.y0 < self.y1
    }

    fn shifted(self, dy: f64) -> LabelBox {
        LabelBox {
            y0: self.y0 + dy,
            y1: self.y1 + dy,
            ..self
        }
    }
}

/// Pixels of an em per unit of plotters' font size: its SVG backend writes `font-size` as the
/// size / 1.24, its bitmap backend draws the size in pixels.
pub(crate) const SVG_EM_PER_SIZE: f64 = 1.0 / 1.24;
pub(crate) const BITMAP_EM_PER_SIZE: f64 = 1.0;

/// Width and height in px of `text` in a font of `em_px`: sans-serif characters average at most
/// 0.6 em wide (bold 0.65), and a line is 1.2 em tall.
pub(crate) fn text_box_px(text: &str, em_px: f64, bold: bool) -> (f64, f64) {
    let per_char = if bold { 0.65 } else { 0.6 };
    (text.chars().count() as f64 * per_char * em_px, 1.2 * em_px)
}

/// Places labels one at a time so that none overlaps another or a reserved box (the legend,
/// the peaks' dots) and each stays inside `area` (the plotting area): a label starts at its
/// wanted box and steps by `dy` until it is free; when it would leave the area that way, it
/// tries the other direction. A label with no free place anywhere keeps its wanted box.
pub(crate) struct Placer {
    placed: Vec<LabelBox>,
    area: LabelBox,
}

impl Placer {
    pub(crate) fn new(area: LabelBox) -> Placer {
        Placer {
            placed: Vec::new(),
            area,
        }
    }

    /// Keeps `b` free of the labels placed after.
    pub(crate) fn reserve(&mut self, b: LabelBox) {
        self.placed.push(b);
    }

    /// The box where the label wanted at `want` goes, stepping by `dy` px (positive: down).
    pub(crate) fn place(&mut self, want: LabelBox, dy: f64) -> LabelBox {
        // At least a pixel a step (f64::signum gives 1 for zero).
        let step = if dy.abs() < 1.0 { dy.signum() } else { dy };
        // Enough steps to cross the whole area from anywhere inside it.
        let steps = ((self.area.height() + want.height()) / step.abs()).ceil() as usize + 1;
        let (area, placed) = (self.area, &self.placed);
        let found = (0..=steps)
            .map(|k| want.shifted(step * k as f64))
            .chain((1..=steps).map(|k| want.shifted(-step * k as f64)))
            .find(|b| b.y0 >= area.y0 && b.y1 <= area.y1 && !placed.iter().any(|q| q.overlaps(b)))
            .unwrap_or(want);
        self.placed.push(found);
        found
    }
}

/// A chart label placed in pixels: its box, text, font and colour, and the leader line from the
/// point it names when it had to move away from it.
#[derive(Debug, Clone, PartialEq)]
struct PlacedLabel {
    at: LabelBox,
    text: String,
    size: i32,
    bold: bool,
    color: RGBColor,
    leader: Option<((i32, i32), (i32, i32))>,
}

/// Width and height in px of plotters' legend box for `lines` series whose longest name has
/// `longest_chars` characters (at the legend's font size in plotters' pixels, the size plotters
/// measures it with), and its gap from the plotting area's edges.
pub(crate) fn legend_size_px(longest_chars: usize, lines: usize) -> (f64, f64) {
    let width = longest_chars as f64 * 0.6 * f64::from(LEGEND_FONT) + LEGEND_SAMPLE_PX + 2.0 * LEGEND_MARGIN_PX;
    let height = LEGEND_LINE_PX * lines.max(1) as f64 + 2.0 * LEGEND_MARGIN_PX + 4.0;
    (width, height)
}

/// The legend's box as plotters lays it out in the upper right corner of `area`.
fn legend_box(chart: &LineChart, area: LabelBox) -> LabelBox {
    let longest = chart.series.iter().map(|s| s.name.chars().count()).max().unwrap_or(0);
    let (width, height) = legend_size_px(longest, chart.series.len());
    LabelBox {
        x0: area.x1 - LEGEND_GAP_PX - width,
        y0: area.y0 + LEGEND_GAP_PX,
        x1: area.x1 - LEGEND_GAP_PX,
        y1: area.y0 + LEGEND_GAP_PX + height,
    }
}

/// Where the chart's peak names, event markers' and comment notes' labels go: inside `area`
/// (the plotting area, px), clear of the legend, the peaks' dots and each other. `to_px` maps
/// data coordinates to pixels, `y_top` is the top of the y range and `em_per_size` the em in px
/// per unit of font size of the backend ([`SVG_EM_PER_SIZE`]). Peaks first, each name
/// centred above its dot; then markers from the top down, each right of its line (left of it
/// near the right edge); then notes from the bottom up.
fn place_labels(
    chart: &LineChart,
    area: LabelBox,
    y_top: f64,
    to_px: &dyn Fn(f64, f64) -> (i32, i32),
    em_per_size: f64,
) -> Vec<PlacedLabel> {
    let em = |size: i32| f64::from(size) * em_per_size;
    let mut placer = Placer::new(area);
    placer.reserve(legend_box(chart, area));
    let dots: Vec<(i32, i32)> = chart.peaks.iter().map(|(x, y, _)| to_px(*x, *y)).collect();
    for (dx, dy) in &dots {
        let (dx, dy) = (f64::from(*dx), f64::from(*dy));
        placer.reserve(LabelBox {
            x0: dx - 5.0,
            y0: dy - 5.0,
            x1: dx + 5.0,
            y1: dy + 5.0,
        });
    }
    let mut out = Vec::new();
    for ((_, _, text), (dx, dy)) in chart.peaks.iter().zip(&dots) {
        let size = text_box_px(text, em(PEAK_FONT), true);
        let x0 = (f64::from(*dx) - size.0 / 2.0).min(area.x1 - size.0).max(area.x0);
        let want = LabelBox::at(x0, f64::from(*dy) - 6.0 - size.1, size);
        let at = placer.place(want, -(want.height() + LABEL_GAP_PX));
        // Moved away from its dot: a thin line from the dot to the nearest point of the box.
        let leader = (at != want).then(|| {
            let to_x = f64::from(*dx).clamp(at.x0, at.x1) as i32;
            let to_y = if at.y1 <= f64::from(*dy) { at.y1 } else { at.y0 };
            ((*dx, *dy), (to_x, to_y as i32))
        });
        out.push(PlacedLabel {
            at,
            text: text.clone(),
            size: PEAK_FONT,
            bold: true,
            color: BLACK,
            leader,
        });
    }
    // Right of the line, or left of it when it would run past the right edge.
    let beside = |line_px: i32, width_px: f64| {
        let right = f64::from(line_px) + 3.0;
        let x0 = if right + width_px <= area.x1 {
            right
        } else {
            f64::from(line_px) - 3.0 - width_px
        };
        x0.min(area.x1 - width_px).max(area.x0)
    };
    for (x, text) in &chart.markers {
        let size = text_box_px(text, em(MARKER_FONT), false);
        let want = LabelBox::at(beside(to_px(*x, y_top).0, size.0), area.y0 + 4.0, size);
        out.push(PlacedLabel {
            at: placer.place(want, want.height() + LABEL_GAP_PX),
            text: text.clone(),
            size: MARKER_FONT,
            bold: false,
            color: BLACK,
            leader: None,
        });
    }
    for (x, text) in &chart.notes {
        let size = text_box_px(text, em(NOTE_FONT), false);
        let want = LabelBox::at(beside(to_px(*x, y_top).0, size.0), area.y1 - 4.0 - size.1, size);
        out.push(PlacedLabel {
            at: placer.place(want, -(want.height() + LABEL_GAP_PX)),
            text: text.clone(),
            size: NOTE_FONT,
            bold: false,
            color: NOTE_COLOR,
            leader: None,
        });
    }
    out
}

/// Draws `chart` on `root`; `em_per_size` is the backend's em in px per unit of font size
/// ([`SVG_EM_PER_SIZE`], [`BITMAP_EM_PER_SIZE`]), to keep its labels apart.
fn draw<DB: DrawingBackend>(
    chart: &LineChart,
    root: &DrawingArea<DB, Shift>,
    em_per_size: f64,
) -> Result<XAxis, ChartError> {
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
    let (px, py) = c.plotting_area().get_pixel_range();
    let area = LabelBox {
        x0: px.start as f64,
        y0: py.start as f64,
        x1: px.end as f64,
        y1: py.end as f64,
    };
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
    // Shaded spans first, under the lines; one legend entry per label.
    let mut legend_done: Vec<&str> = Vec::new();
    for (bx0, bx1, color, label) in &chart.bands {
        let fill = color.mix(0.18).filled();
        let drawn = c.draw_series(std::iter::once(Rectangle::new([(*bx0, y0), (*bx1, y1)], fill)))?;
        if !legend_done.contains(&label.as_str()) {
            legend_done.push(label);
            let color = *color;
            drawn
                .label(label)
                .legend(move |(x, y)| Rectangle::new([(x, y - 6), (x + 24, y + 6)], color.mix(0.35).filled()));
        }
    }
    // Event and comment lines under the curves; their labels are placed after the curves.
    for (x, _) in &chart.markers {
        let style = ShapeStyle::from(&RGBColor(150, 150, 150)).stroke_width(1);
        c.draw_series(std::iter::once(PathElement::new(vec![(*x, y0), (*x, y1)], style)))?;
    }
    for (x, _) in &chart.notes {
        let style = ShapeStyle::from(&NOTE_COLOR).stroke_width(2);
        c.draw_series(DashedLineSeries::new([(*x, y0), (*x, y1)], 6, 4, style))?;
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
    for (x, y, _) in &chart.peaks {
        c.draw_series(std::iter::once(Circle::new(
            (*x, *y),
            4,
            ShapeStyle::from(&BLACK).filled(),
        )))?;
    }
    let to_px = |x: f64, y: f64| c.backend_coord(&(x, y));
    let labels = place_labels(chart, area, y1, &to_px, em_per_size);
    // Leader lines first, so that a label's background covers a line passing behind it.
    for l in &labels {
        if let Some((from, to)) = l.leader {
            root.draw(&PathElement::new(vec![from, to], RGBColor(120, 120, 120)))?;
        }
    }
    for l in &labels {
        let (bx0, by0, bx1, by1) = (l.at.x0 as i32, l.at.y0 as i32, l.at.x1 as i32, l.at.y1 as i32);
        // A light background keeps the text readable over the curves.
        root.draw(&Rectangle::new([(bx0, by0), (bx1, by1)], WHITE.mix(0.75).filled()))?;
        let font = (SANS, l.size).into_font();
        let font = if l.bold { font.style(FontStyle::Bold) } else { font };
        let style = font.color(&l.color).pos(Pos::new(HPos::Left, VPos::Top));
        root.draw(&Text::new(l.text.clone(), (bx0, by0), style))?;
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
        draw(chart, &root, SVG_EM_PER_SIZE)
            .map(|_| ())
            .map_err(|e| err(e.to_string()))
    } else {
        let mut rgb = vec![0u8; size.0 as usize * size.1 as usize * 3];
        {
            let root = BitMapBackend::with_buffer(&mut rgb, size).into_drawing_area();
            draw(chart, &root, BITMAP_EM_PER_SIZE).map_err(|e| err(e.to_string()))?;
            root.present().map_err(|e| err(e.to_string()))?;
        }
        stylet_render::figure::write_rgb_png(path, size.0 as usize, size.1 as usize, &rgb)
    }
}

/// `svg`, plotters' SVG of `size`, without its fixed width and height but with its viewBox: the
/// page's style sheet sizes it (to the page's width, or wider in a box that scrolls sideways on
/// a phone), and the drawing keeps its proportions.
pub fn scalable_svg(svg: &str, size: (u32, u32)) -> String {
    svg.replacen(&format!("width=\"{}\" height=\"{}\" ", size.0, size.1), "", 1)
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
        draw(chart, &root, SVG_EM_PER_SIZE).map_err(|e| RenderError::Draw(e.to_string()))?
    };
    Ok((out, axis))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn b(x0: f64, y0: f64, x1: f64, y1: f64) -> LabelBox {
        LabelBox { x0, y0, x1, y1 }
    }

    #[test]
    fn the_placer_stacks_labels_that_want_one_place_and_keeps_them_in_the_area() {
        let area = b(0.0, 0.0, 200.0, 100.0);
        let mut p = Placer::new(area);
        // The legend in the upper right corner.
        p.reserve(b(150.0, 0.0, 200.0, 30.0));
        let want = b(10.0, 4.0, 60.0, 18.0);
        let first = p.place(want, 16.0);
        let second = p.place(want, 16.0);
        let third = p.place(want.shifted(-2.0), 16.0);
        assert_eq!(first, want);
        assert_eq!(second, want.shifted(16.0));
        // Stepped past both, never onto them.
        assert_eq!(third, want.shifted(30.0));
        // A label wanted under the legend steps down past it.
        let under = p.place(b(140.0, 4.0, 190.0, 18.0), 16.0);
        assert_eq!(under, b(140.0, 36.0, 190.0, 50.0));
        // Wanted at the bottom and stepping down would leave the area: it goes up instead.
        let low = p.place(b(10.0, 80.0, 60.0, 94.0), 16.0);
        assert_eq!(low, b(10.0, 80.0, 60.0, 94.0));
        let lower = p.place(b(10.0, 80.0, 60.0, 94.0), 16.0);
        assert_eq!(lower, b(10.0, 64.0, 60.0, 78.0));
        let all = [first, second, third, under, low, lower];
        for (i, a) in all.iter().enumerate() {
            assert!(a.y0 >= area.y0 && a.y1 <= area.y1, "{a:?} leaves the area");
            for c in &all[i + 1..] {
                assert!(!a.overlaps(c), "{a:?} overlaps {c:?}");
            }
        }
    }

    #[test]
    fn boxes_sit_on_whole_pixels_and_hold_their_text() {
        // Plotters' size 12.4 is a 10 px em in SVG: 10 characters of 0.6 em, a line of 1.2 em.
        let (w, h) = text_box_px("0123456789", 12.4 * SVG_EM_PER_SIZE, false);
        assert!((w - 60.0).abs() < 1e-9 && (h - 12.0).abs() < 1e-9, "{w} {h}");
        let (wb, _) = text_box_px("0123456789", 10.0, true);
        assert!((wb - 65.0).abs() < 1e-9, "{wb}");
        let at = LabelBox::at(10.4, 20.6, (30.2, 12.1));
        assert_eq!(at, b(10.0, 21.0, 41.0, 34.0));
        // Touching edges do not overlap.
        assert!(!b(0.0, 0.0, 10.0, 10.0).overlaps(&b(10.0, 0.0, 20.0, 10.0)));
        assert!(b(0.0, 0.0, 10.0, 10.0).overlaps(&b(9.0, 9.0, 20.0, 20.0)));
    }

    #[test]
    fn the_legend_box_covers_the_longest_name_and_every_line() {
        let chart = LineChart {
            series: vec![
                Series {
                    name: "total".into(),
                    ..Default::default()
                },
                Series {
                    name: "tip depth under the skin".into(),
                    ..Default::default()
                },
            ],
            ..Default::default()
        };
        let l = legend_box(&chart, b(100.0, 50.0, 1000.0, 400.0));
        assert_eq!(l.x1, 995.0);
        assert_eq!(l.y0, 55.0);
        assert!(l.x1 - l.x0 >= 24.0 * 8.0 + 30.0, "{l:?}");
        assert!(l.y1 - l.y0 >= 2.0 * 20.0 + 20.0, "{l:?}");
    }
}
