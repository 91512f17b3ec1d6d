//! A small PDF writer for reports (`pdf-writer`, typst's low-level crate: no system libraries,
//! four tiny dependencies). Text is set in the standard Helvetica faces with WinAnsi encoding, so
//! nothing is embedded and the text stays selectable and searchable; charts are vector paths.
//! A4 portrait, pages added as the content flows, tables repeat their header on a new page, and
//! every page carries a footer with the document's title and its page number.

use pdf_writer::{Content, Finish, Name, Pdf, Rect, Ref, Str, TextStr};

/// A4 in points.
pub const PAGE_W: f32 = 595.0;
pub const PAGE_H: f32 = 842.0;
pub const MARGIN: f32 = 42.0;
/// The width text and tables may take.
pub const TEXT_W: f32 = PAGE_W - 2.0 * MARGIN;

const REGULAR: Name<'static> = Name(b"F1");
const BOLD: Name<'static> = Name(b"F2");

/// Pages at most: a report longer than this ends with a line saying it was cut.
pub const PAGES_MAX: usize = 200;

/// Helvetica advance widths (1/1000 em) of ASCII 32–126 (Adobe's core-14 AFM).
const HELVETICA: [u16; 95] = [
    278, 278, 355, 556, 556, 889, 667, 191, 333, 333, 389, 584, 278, 333, 278, 278, // space … /
    556, 556, 556, 556, 556, 556, 556, 556, 556, 556, // 0 … 9
    278, 278, 584, 584, 584, 556, 1015, // : … @
    667, 667, 722, 722, 667, 611, 778, 722, 278, 500, 667, 556, 833, 722, 778, 667, 778, 722, 667, 611, 722, 667, 944,
    667, 667, 611, // A … Z
    278, 278, 278, 469, 556, 333, // [ … `
    556, 556, 500, 556, 556, 278, 556, 556, 222, 222, 500, 222, 833, 556, 556, 556, 556, 333, 500, 278, 556, 500, 722,
    500, 500, 500, // a … z
    334, 260, 334, 584, // { … ~
];

/// The WinAnsi byte of a character (`?` for what the standard fonts cannot show).
fn win_ansi(c: char) -> u8 {
    match c {
        ' '..='~' => c as u8,
        '\u{a0}'..='\u{ff}' => c as u32 as u8,
        '–' => 0x96,
        '—' => 0x97,
        '…' => 0x85,
        '’' => 0x92,
        '‘' => 0x91,
        '“' => 0x93,
        '”' => 0x94,
        '•' => 0x95,
        '−' => b'-',
        '€' => 0x80,
        _ => b'?',
    }
}

/// The width of `text` in points at `size` (bold faces are a little wider).
pub fn text_width(text: &str, size: f32, bold: bool) -> f32 {
    let units: u32 = text
        .chars()
        .map(|c| match win_ansi(c) {
            b @ 32..=126 => u32::from(HELVETICA[usize::from(b - 32)]),
            0x96 => 556,
            0x97 | 0x85 => 1000,
            _ => 556,
        })
        .sum();
    units as f32 / 1000.0 * size * if bold { 1.06 } else { 1.0 }
}

/// `text` cut with an ellipsis to fit `width` points.
pub fn fit(text: &str, size: f32, bold: bool, width: f32) -> String {
    if text_width(text, size, bold) <= width {
        return text.to_string();
    }
    let mut out = String::new();
    for c in text.chars() {
        out.push(c);
        if text_width(&out, size, bold) + text_width("…", size, bold) > width {
            out.pop();
            break;
        }
    }
    out.push('…');
    out
}

/// A column of a table.
pub struct Col {
    pub title: &'static str,
    /// Points.
    pub width: f32,
    /// Numbers: right-aligned.
    pub right: bool,
}

/// A document being laid out top to bottom.
pub struct Doc {
    title: String,
    pages: Vec<Content>,
    page: Content,
    /// Distance of the next line's top from the page's top.
    y: f32,
    /// More than [`PAGES_MAX`] pages were asked for: further content is dropped.
    full: bool,
}

impl Doc {
    pub fn new(title: &str) -> Doc {
        Doc {
            title: title.to_string(),
            pages: Vec::new(),
            page: Content::new(),
            y: MARGIN,
            full: false,
        }
    }

    /// Room left on the page in points.
    fn room(&self) -> f32 {
        PAGE_H - MARGIN - 16.0 - self.y
    }

    /// Starts a new page unless `height` points still fit on this one; false once the document
    /// is full.
    pub fn need(&mut self, height: f32) -> bool {
        if self.full {
            return false;
        }
        if self.room() >= height {
            return true;
        }
        if self.pages.len() + 1 >= PAGES_MAX {
            self.text(
                MARGIN,
                10.0,
                false,
                "The report is longer than the PDF allows; the rest is left out.",
            );
            self.full = true;
            return false;
        }
        let done = std::mem::replace(&mut self.page, Content::new());
        self.pages.push(done);
        self.y = MARGIN;
        true
    }

    /// Text at `x` on the current line (its top at `self.y`), `size` points.
    fn text(&mut self, x: f32, size: f32, bold: bool, text: &str) {
        let bytes: Vec<u8> = text.chars().map(win_ansi).collect();
        let baseline = PAGE_H - self.y - size * 0.8;
        self.page
            .begin_text()
            .set_font(if bold { BOLD } else { REGULAR }, size)
            .next_line(x, baseline)
            .show(Str(&bytes))
            .end_text();
    }

    /// Text at absolute page coordinates (points from the bottom left).
    fn text_at(&mut self, x: f32, baseline: f32, size: f32, bold: bool, text: &str) {
        let bytes: Vec<u8> = text.chars().map(win_ansi).collect();
        self.page
            .begin_text()
            .set_font(if bold { BOLD } else { REGULAR }, size)
            .next_line(x, baseline)
            .show(Str(&bytes))
            .end_text();
    }

    fn rgb(&mut self, (r, g, b): (u8, u8, u8), stroke: bool) {
        let f = |v: u8| f32::from(v) / 255.0;
        if stroke {
            self.page.set_stroke_rgb(f(r), f(g), f(b));
        } else {
            self.page.set_fill_rgb(f(r), f(g), f(b));
        }
    }

    fn line(&mut self, (x0, y0): (f32, f32), (x1, y1): (f32, f32), width: f32, color: (u8, u8, u8)) {
        self.rgb(color, true);
        self.page.set_line_width(width).move_to(x0, y0).line_to(x1, y1).stroke();
    }

    /// A heading with some room above it.
    pub fn heading(&mut self, text: &str) {
        if !self.need(44.0) {
            return;
        }
        self.y += 10.0;
        self.text(MARGIN, 13.0, true, text);
        self.y += 18.0;
    }

    /// A title line in large bold type.
    pub fn title(&mut self, text: &str) {
        for line in wrap(text, 17.0, true, TEXT_W) {
            if !self.need(24.0) {
                return;
            }
            self.text(MARGIN, 17.0, true, &line);
            self.y += 23.0;
        }
        self.y += 4.0;
    }

    /// A paragraph wrapped to the text width.
    pub fn paragraph(&mut self, text: &str, size: f32) {
        for line in wrap(text, size, false, TEXT_W) {
            if !self.need(size * 1.4) {
                return;
            }
            self.text(MARGIN, size, false, &line);
            self.y += size * 1.35;
        }
        self.y += size * 0.5;
    }

    /// A table: a bold header row (repeated on a new page) and rows cut to their columns.
    pub fn table(&mut self, cols: &[Col], rows: &[Vec<String>]) {
        const SIZE: f32 = 9.0;
        const ROW: f32 = 13.0;
        let total: f32 = cols.iter().map(|c| c.width).sum();
        let scale = if total > TEXT_W { TEXT_W / total } else { 1.0 };
        let header = |doc: &mut Doc| {
            let mut x = MARGIN;
            for c in cols {
                let w = c.width * scale;
                let t = fit(c.title, SIZE, true, w - 4.0);
                let tx = if c.right {
                    x + w - 2.0 - text_width(&t, SIZE, true)
                } else {
                    x + 2.0
                };
                doc.text(tx, SIZE, true, &t);
                x += w;
            }
            let yl = PAGE_H - doc.y - ROW + 2.0;
            doc.line((MARGIN, yl), (MARGIN + total * scale, yl), 0.8, (60, 60, 60));
            doc.y += ROW;
        };
        if !self.need(2.0 * ROW) {
            return;
        }
        header(self);
        for row in rows {
            if self.room() < ROW {
                if !self.need(2.0 * ROW) {
                    return;
                }
                header(self);
            }
            let mut x = MARGIN;
            for (c, cell) in cols.iter().zip(row) {
                let w = c.width * scale;
                let t = fit(cell, SIZE, false, w - 4.0);
                let tx = if c.right {
                    x + w - 2.0 - text_width(&t, SIZE, false)
                } else {
                    x + 2.0
                };
                self.text(tx, SIZE, false, &t);
                x += w;
            }
            let yl = PAGE_H - self.y - ROW + 2.0;
            self.line((MARGIN, yl), (MARGIN + total * scale, yl), 0.3, (200, 200, 200));
            self.y += ROW;
        }
        self.y += 6.0;
    }

    /// A line chart of percentages 0–100 over x (any unit): axes with ticks every 20 %, the x
    /// tick labels given, one coloured line with dots per series, a legend, axis titles.
    pub fn percent_chart(&mut self, spec: &PercentChart) {
        const HEIGHT: f32 = 250.0;
        if !self.need(HEIGHT + 10.0) {
            return;
        }
        let top = PAGE_H - self.y;
        self.text(MARGIN, 11.0, true, &spec.title);
        // Plot area.
        let (left, right) = (MARGIN + 46.0, MARGIN + TEXT_W - 8.0);
        let (bottom, upper) = (top - HEIGHT + 40.0, top - 26.0);
        let (x0, x1) = spec.x_range;
        let px = |x: f64| left + ((x - x0) / (x1 - x0).max(1e-9)) as f32 * (right - left);
        let py = |p: f64| bottom + (p.clamp(0.0, 100.0) / 100.0) as f32 * (upper - bottom);
        for k in 0..=5 {
            let p = f64::from(k) * 20.0;
            let y = py(p);
            self.line((left, y), (right, y), 0.3, (215, 215, 215));
            let label = format!("{p:.0}");
            self.text_at(left - 4.0 - text_width(&label, 8.0, false), y - 3.0, 8.0, false, &label);
        }
        self.line((left, bottom), (right, bottom), 0.8, (40, 40, 40));
        self.line((left, bottom), (left, upper), 0.8, (40, 40, 40));
        for (x, label) in &spec.x_ticks {
            let xp = px(*x);
            self.line((xp, bottom), (xp, bottom - 3.0), 0.6, (40, 40, 40));
            let w = text_width(label, 7.5, false);
            self.text_at(xp - w / 2.0, bottom - 12.0, 7.5, false, label);
        }
        let w = text_width(&spec.x_label, 9.0, false);
        self.text_at((left + right - w) / 2.0, bottom - 26.0, 9.0, false, &spec.x_label);
        // The y title, turned a quarter to the left.
        let bytes: Vec<u8> = spec.y_label.chars().map(win_ansi).collect();
        let wy = text_width(&spec.y_label, 9.0, false);
        self.page
            .begin_text()
            .set_font(REGULAR, 9.0)
            .set_text_matrix([0.0, 1.0, -1.0, 0.0, MARGIN + 10.0, (bottom + upper - wy) / 2.0])
            .show(Str(&bytes))
            .end_text();
        for (name, color, points) in &spec.series {
            self.rgb(*color, true);
            self.page.set_line_width(1.8);
            for (k, (x, p)) in points.iter().enumerate() {
                if k == 0 {
                    self.page.move_to(px(*x), py(*p));
                } else {
                    self.page.line_to(px(*x), py(*p));
                }
            }
            if points.len() > 1 {
                self.page.stroke();
            } else {
                self.page.end_path();
            }
            self.rgb(*color, false);
            for (x, p) in points {
                self.page.rect(px(*x) - 2.2, py(*p) - 2.2, 4.4, 4.4).fill_nonzero();
            }
            let _ = name;
        }
        // Legend, top right inside the plot, or top left where fewer points lie under it.
        let mut points: Vec<(f32, f32)> = Vec::new();
        for (_, _, pts) in &spec.series {
            points.extend(pts.iter().map(|(x, p)| (px(*x), py(*p))));
        }
        let lx = legend_left(&points, (left, right), upper, spec.series.len());
        let mut ly = upper - 12.0;
        for (name, color, _) in &spec.series {
            self.line((lx, ly + 3.0), (lx + 20.0, ly + 3.0), 2.5, *color);
            self.rgb((0, 0, 0), false);
            self.text_at(lx + 26.0, ly, 9.0, false, name);
            ly -= 13.0;
        }
        self.rgb((0, 0, 0), false);
        self.y += HEIGHT;
    }

    /// The finished file: catalog, page tree, the two fonts, the pages with their footers, and
    /// the document information (title, producer).
    pub fn finish(mut self) -> Vec<u8> {
        let last = std::mem::replace(&mut self.page, Content::new());
        self.pages.push(last);
        let n = self.pages.len();
        let catalog = Ref::new(1);
        let tree = Ref::new(2);
        let (regular, bold, info) = (Ref::new(3), Ref::new(4), Ref::new(5));
        let page_ref = |k: usize| Ref::new(10 + 2 * k as i32);
        let content_ref = |k: usize| Ref::new(11 + 2 * k as i32);
        let mut pdf = Pdf::new();
        pdf.catalog(catalog).pages(tree);
        pdf.pages(tree).kids((0..n).map(page_ref)).count(n as i32);
        for (font, name) in [(regular, &b"Helvetica"[..]), (bold, &b"Helvetica-Bold"[..])] {
            pdf.type1_font(font)
                .base_font(Name(name))
                .encoding_predefined(Name(b"WinAnsiEncoding"));
        }
        pdf.document_info(info)
            .title(TextStr(&self.title))
            .producer(TextStr("Stylet"));
        let title = self.title.clone();
        for (k, mut content) in std::mem::take(&mut self.pages).into_iter().enumerate() {
            // Footer.
            let footer = format!("{} — page {} of {n}", fit(&title, 8.0, false, TEXT_W - 60.0), k + 1);
            let bytes: Vec<u8> = footer.chars().map(win_ansi).collect();
            content
                .set_fill_rgb(0.35, 0.35, 0.35)
                .begin_text()
                .set_font(REGULAR, 8.0)
                .next_line(MARGIN, MARGIN / 2.0)
                .show(Str(&bytes))
                .end_text();
            let mut page = pdf.page(page_ref(k));
            page.media_box(Rect::new(0.0, 0.0, PAGE_W, PAGE_H))
                .parent(tree)
                .contents(content_ref(k));
            page.resources().fonts().pair(REGULAR, regular).pair(BOLD, bold);
            page.finish();
            pdf.stream(content_ref(k), &content.finish());
        }
        pdf.finish()
    }
}

/// What [`Doc::percent_chart`] draws.
pub struct PercentChart {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub x_range: (f64, f64),
    pub x_ticks: Vec<(f64, String)>,
    /// Name, colour, points (x, percent).
    pub series: Vec<Series>,
}

/// One line of a chart: name, colour (RGB), points (x, percent).
pub type Series = (String, (u8, u8, u8), Vec<(f64, f64)>);

/// Words of `text` in lines no wider than `width` (a word wider than a line is cut).
pub fn wrap(text: &str, size: f32, bold: bool, width: f32) -> Vec<String> {
    let mut lines = Vec::new();
    let mut line = String::new();
    for word in text.split_whitespace() {
        let candidate = if line.is_empty() {
            word.to_string()
        } else {
            format!("{line} {word}")
        };
        if text_width(&candidate, size, bold) <= width || line.is_empty() {
            line = candidate;
        } else {
            lines.push(std::mem::take(&mut line));
            line = word.to_string();
        }
    }
    if !line.is_empty() {
        lines.push(line);
    }
    lines.into_iter().map(|l| fit(&l, size, bold, width)).collect()
}

/// Width of a percent chart's legend (its sample line and the names), in points.
const LEGEND_W: f32 = 110.0;
/// Height of one legend row, in points.
const LEGEND_ROW: f32 = 13.0;

/// The left edge of a percent chart's legend of `rows` names at the top of the plot spanning
/// `left … right` below `upper`: at the right, unless more of the `points` (in page
/// coordinates) lie under it there than at the left (the weekly chart ends at its latest week,
/// so the latest points lie at the right edge).
fn legend_left(points: &[(f32, f32)], (left, right): (f32, f32), upper: f32, rows: usize) -> f32 {
    let bottom = upper - LEGEND_ROW * rows as f32 - 2.0;
    let under = |lx: f32| {
        points
            .iter()
            .filter(|(x, y)| *x + 3.0 > lx && *x - 3.0 < lx + LEGEND_W && *y + 3.0 > bottom && *y - 3.0 < upper)
            .count()
    };
    let (at_right, at_left) = (right - LEGEND_W, left + 6.0);
    if under(at_right) > under(at_left) {
        at_left
    } else {
        at_right
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_chart_legend_moves_left_off_the_latest_points() {
        let (left, right, upper) = (100.0, 500.0, 700.0);
        // Nothing under it: at the right.
        assert_eq!(
            legend_left(&[(120.0, 690.0), (480.0, 500.0)], (left, right), upper, 2),
            390.0
        );
        // The latest week's high pass rate under it at the right: at the left.
        assert_eq!(
            legend_left(&[(300.0, 500.0), (495.0, 695.0)], (left, right), upper, 2),
            106.0
        );
        // Points under both places: the right, unless the left has fewer.
        assert_eq!(
            legend_left(&[(120.0, 690.0), (495.0, 695.0)], (left, right), upper, 1),
            390.0
        );
    }

    #[test]
    fn widths_fit_and_wrap() {
        // "Hello" in Helvetica: 722 + 556 + 222 + 222 + 556 = 2278 units.
        assert!((text_width("Hello", 10.0, false) - 22.78).abs() < 1e-3);
        let cut = fit("a very long trainee name indeed", 9.0, false, 60.0);
        assert!(cut.ends_with('…') && text_width(&cut, 9.0, false) <= 60.0, "{cut}");
        let lines = wrap("one two three four five six seven eight nine ten", 10.0, false, 80.0);
        assert!(lines.len() > 1);
        assert!(lines.iter().all(|l| text_width(l, 10.0, false) <= 80.0));
        assert_eq!(lines.join(" "), "one two three four five six seven eight nine ten");
        assert_eq!(win_ansi('é'), 0xe9);
        assert_eq!(win_ansi('–'), 0x96);
        assert_eq!(win_ansi('漢'), b'?');
    }

    #[test]
    fn a_document_is_a_pdf_with_its_pages() {
        let mut d = Doc::new("Test — report");
        d.title("A title");
        let rows: Vec<Vec<String>> = (0..200).map(|k| vec![format!("row {k}"), k.to_string()]).collect();
        d.table(
            &[
                Col {
                    title: "name",
                    width: 200.0,
                    right: false,
                },
                Col {
                    title: "n",
                    width: 60.0,
                    right: true,
                },
            ],
            &rows,
        );
        let bytes = d.finish();
        assert!(bytes.starts_with(b"%PDF-"));
        let text = String::from_utf8_lossy(&bytes);
        assert!(text.contains("/BaseFont /Helvetica"));
        // 200 rows of 13 pt do not fit on one A4 page.
        assert!(text.contains("/Count 4") || text.contains("/Count 5"), "page count");
        assert!(text.contains("(row 199)"));
    }
}
