//! The atlas figure: axial, coronal and sagittal slices through a point (by default the target's
//! centre) with the label overlay, orientation letters, scale bars and a colour legend, as PNG.

use std::path::Path;

use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use stylet_physics::glam::DVec3;
use stylet_physics::{PunctureAtlas, Role};

use crate::RenderError;
use crate::corridor::{CORRIDOR_ALPHA, CORRIDOR_RGB, Corridor, MIN_HALF_WIDTH_PX, band_polygon, clip_polygon};
use crate::fonts::{SANS, ensure_fonts};
use crate::mpr::{Plane, Slice, Window, render_slice};

const MARGIN: usize = 16;
const TITLE_H: usize = 64;
const PANEL_TITLE_H: usize = 26;
const LEGEND_ROW_H: usize = 22;
const MAX_PANEL_PX: usize = 480;

/// Centre of the target labels (voxel centroid), or the volume centre if there is no target.
pub fn default_center(atlas: &PunctureAtlas) -> DVec3 {
    let grid = atlas.ct().grid();
    let targets: Vec<u16> = atlas.label_table().with_role(Role::Target).map(|l| l.id).collect();
    let (mut sum, mut n) = (DVec3::ZERO, 0u64);
    for (idx, l) in atlas.partial_labels().data().iter().enumerate() {
        if targets.contains(l) {
            sum += grid.linear_to_world(idx);
            n += 1;
        }
    }
    if n > 0 {
        sum / n as f64
    } else {
        let (lo, hi) = grid.world_bounds();
        (lo + hi) * 0.5
    }
}

/// Writes the three-plane figure through the default centre, with straight `paths` (entry,
/// target in world mm) drawn on it.
pub fn atlas_figure(
    atlas: &PunctureAtlas,
    name: &str,
    paths: &[(DVec3, DVec3)],
    png: &Path,
) -> Result<(), RenderError> {
    let center = default_center(atlas);
    let lines: Vec<Vec<DVec3>> = paths.iter().map(|(a, b)| vec![*a, *b]).collect();
    atlas_figure_at(atlas, name, center, &lines, png)
}

/// Writes the three-plane figure through `center`; `polylines` (world mm) are drawn projected
/// onto every plane (insertion paths, needle tip paths).
pub fn atlas_figure_at(
    atlas: &PunctureAtlas,
    name: &str,
    center: DVec3,
    polylines: &[Vec<DVec3>],
    png: &Path,
) -> Result<(), RenderError> {
    let spec = FigureSpec {
        needle: polylines.to_vec(),
        ..FigureSpec::new(name, center)
    };
    figure(atlas, &spec, png)
}

/// The needle path's colour on figures.
pub const NEEDLE_RGB: [u8; 3] = [0, 230, 255];
/// The planned path's colour (drawn dashed).
pub const PLANNED_RGB: [u8; 3] = [255, 170, 0];
/// The marked point's colour (a ring with a white rim).
pub const MARK_RGB: [u8; 3] = [255, 40, 40];

/// A point marked on a figure, with its legend text ("right lung: first contact at 5.89 s").
#[derive(Debug, Clone, PartialEq)]
pub struct Mark {
    pub point_mm: DVec3,
    pub label: String,
}

/// What a figure shows: slices through `center` in `planes`, the needle's tip path(s), planned
/// paths and a marked point, each in the legend when present.
#[derive(Debug, Clone, PartialEq)]
pub struct FigureSpec {
    pub title: String,
    pub center: DVec3,
    pub planes: Vec<Plane>,
    /// Needle tip paths (world mm), solid cyan, projected onto every plane.
    pub needle: Vec<Vec<DVec3>>,
    /// Planned paths (entry, target in world mm), dashed orange, with their names.
    pub planned: Vec<(String, DVec3, DVec3)>,
    pub mark: Option<Mark>,
    /// The expert corridor, a translucent white band projected onto every plane.
    pub corridor: Option<Corridor>,
}

/// How a legend entry's line is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Stroke {
    Solid,
    Dashed,
    Band,
}

impl FigureSpec {
    /// Axial, coronal and sagittal slices through `center`, nothing drawn on them.
    pub fn new(title: &str, center: DVec3) -> FigureSpec {
        FigureSpec {
            title: title.to_string(),
            center,
            planes: vec![Plane::Axial, Plane::Coronal, Plane::Sagittal],
            needle: Vec::new(),
            planned: Vec::new(),
            mark: None,
            corridor: None,
        }
    }
}

/// The part of segment a–b inside the rectangle [0, w] × [0, h] (Liang–Barsky), if any.
fn clip(a: (f64, f64), b: (f64, f64), w: f64, h: f64) -> Option<((f64, f64), (f64, f64))> {
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    for (p, q) in [(-dx, a.0), (dx, w - a.0), (-dy, a.1), (dy, h - a.1)] {
        if !q.is_finite() {
            return None;
        }
        if p == 0.0 {
            if q < 0.0 {
                return None;
            }
        } else {
            let r = q / p;
            if p < 0.0 {
                t0 = t0.max(r);
            } else {
                t1 = t1.min(r);
            }
        }
    }
    (t0 <= t1).then_some(((a.0 + t0 * dx, a.1 + t0 * dy), (a.0 + t1 * dx, a.1 + t1 * dy)))
}

/// Segments of a polyline in panel pixels, clipped to the panel: a path projected from far
/// away must not spill onto the neighbouring panel.
fn clipped(pts: &[(f64, f64)], w: f64, h: f64) -> Vec<[(f64, f64); 2]> {
    pts.windows(2)
        .filter_map(|s| clip(s[0], s[1], w, h).map(|(a, b)| [a, b]))
        .collect()
}

/// Splits a pixel polyline into dashes of `on` pixels separated by `off` pixels.
fn dashes(pts: &[(f64, f64)], on: f64, off: f64) -> Vec<Vec<(i32, i32)>> {
    let mut out: Vec<Vec<(i32, i32)>> = Vec::new();
    let mut phase = 0.0; // distance into the current on+off period
    let px = |p: (f64, f64)| (p.0.round() as i32, p.1.round() as i32);
    for w in pts.windows(2) {
        let (a, b) = (w[0], w[1]);
        let len = ((b.0 - a.0).powi(2) + (b.1 - a.1).powi(2)).sqrt();
        if !len.is_finite() || len == 0.0 {
            continue;
        }
        let mut t = 0.0;
        while t < len {
            let at = |d: f64| (a.0 + (b.0 - a.0) * d / len, a.1 + (b.1 - a.1) * d / len);
            if phase < on {
                let step = (on - phase).min(len - t);
                out.push(vec![px(at(t)), px(at(t + step))]);
                t += step;
                phase += step;
            } else {
                let step = (on + off - phase).min(len - t);
                t += step;
                phase += step;
                if phase >= on + off {
                    phase = 0.0;
                }
            }
        }
    }
    out
}

/// Writes a figure: the slices of `spec.planes` through `spec.center` side by side with the label
/// overlay, orientation letters and scale bars; the needle path, planned paths and the marked
/// point drawn on each; a legend of the lines and the labels present.
pub fn figure(atlas: &PunctureAtlas, spec: &FigureSpec, png: &Path) -> Result<(), RenderError> {
    ensure_fonts();
    let center = spec.center;
    let name = spec.title.as_str();
    let slices: Vec<Slice> = spec
        .planes
        .iter()
        .map(|p| render_slice(atlas, *p, center, Window::ABDOMEN, MAX_PANEL_PX))
        .collect();
    // Legend: the lines drawn, then the partial labels present in any slice.
    let table = atlas.label_table();
    let mut present: Vec<u16> = slices
        .iter()
        .flat_map(|s| s.labels.iter().copied())
        .filter(|&l| l != 0)
        .collect();
    present.sort_unstable();
    present.dedup();
    let mut line_entries: Vec<(String, [u8; 3], Stroke)> = Vec::new();
    if !spec.needle.is_empty() {
        line_entries.push(("needle tip path".into(), NEEDLE_RGB, Stroke::Solid));
    }
    for (path_name, _, _) in &spec.planned {
        line_entries.push((format!("planned path '{path_name}'"), PLANNED_RGB, Stroke::Dashed));
    }
    if let Some(c) = &spec.corridor {
        let plural = if c.experts == 1 { "" } else { "s" };
        line_entries.push((
            format!("expert corridor ({} path{plural})", c.experts),
            CORRIDOR_RGB,
            Stroke::Band,
        ));
    }
    let width = (slices.iter().map(|s| s.width).sum::<usize>() + MARGIN * (slices.len() + 1)).max(2 * 260 + 2 * MARGIN);
    // Legend columns 260 px wide, wider when a name needs it (≈ 8 px a character at 16 px).
    let longest = present
        .iter()
        .filter_map(|id| table.get(*id))
        .map(|l| l.name.chars().count() + l.role.as_str().len() + 3)
        .max()
        .unwrap_or(0);
    let column_px = (22 + longest * 8 + 12).clamp(260, width - 2 * MARGIN);
    let per_row = ((width - 2 * MARGIN) / column_px).max(1);
    let line_rows = usize::from(!line_entries.is_empty()) + usize::from(spec.mark.is_some());
    let legend_rows = line_rows + present.len().div_ceil(per_row).max(1);
    let panel_h = slices.iter().map(|s| s.height).max().unwrap_or(0);
    let height = TITLE_H + PANEL_TITLE_H + panel_h + MARGIN + legend_rows * LEGEND_ROW_H + MARGIN;

    let mut buf = vec![20u8; width * height * 3];
    // Blit the slices.
    let mut x0 = MARGIN;
    let y0 = TITLE_H + PANEL_TITLE_H;
    let mut origins = Vec::new();
    for s in &slices {
        for row in 0..s.height {
            for col in 0..s.width {
                let o = ((y0 + row) * width + x0 + col) * 3;
                buf[o..o + 3].copy_from_slice(&s.rgb[row * s.width + col]);
            }
        }
        origins.push((x0, y0));
        x0 += s.width + MARGIN;
    }
    {
        let root = BitMapBackend::with_buffer(&mut buf, (width as u32, height as u32)).into_drawing_area();
        let draw = |r: Result<(), DrawingAreaErrorKind<_>>| r.map_err(|e| RenderError::Draw(e.to_string()));
        let white = TextStyle::from((SANS, 24).into_font()).color(&WHITE);
        let small = TextStyle::from((SANS, 16).into_font()).color(&WHITE);
        let letters = TextStyle::from((SANS, 20).into_font()).color(&RGBColor(255, 220, 80));
        let rgb = |c: [u8; 3]| RGBColor(c[0], c[1], c[2]);
        let grid = atlas.ct().grid();
        let sp = grid.spacing_mm();
        let d = grid.dims();
        draw(root.draw_text(
            &format!(
                "{name} — {}×{}×{} voxels of {:.2}×{:.2}×{:.2} mm",
                d[0], d[1], d[2], sp[0], sp[1], sp[2]
            ),
            &white,
            (MARGIN as i32, 8),
        ))?;
        let lines_note = if spec.needle.is_empty() && spec.planned.is_empty() {
            ""
        } else {
            ", paths projected onto each plane"
        };
        draw(root.draw_text(
            &format!(
                "slices through ({:.0}, {:.0}, {:.0}) mm RAS (crosshair), CT window L 40 / W 400 HU, partial labels in colour{lines_note}",
                center.x, center.y, center.z
            ),
            &small,
            (MARGIN as i32, 36),
        ))?;
        for (s, &(ox, oy)) in slices.iter().zip(&origins) {
            let (ox, oy) = (ox as i32, oy as i32);
            let along = match s.plane {
                Plane::Axial => format!("z = {:.1} mm", center.z),
                Plane::Coronal => format!("y = {:.1} mm", center.y),
                Plane::Sagittal => format!("x = {:.1} mm", center.x),
            };
            draw(root.draw_text(&format!("{} ({along})", s.plane.name()), &small, (ox, oy - 22)))?;
            let [l, r, t, b] = s.plane.edge_letters();
            let (w, h) = (s.width as i32, s.height as i32);
            let mid = |st: &TextStyle<'static>, hp, vp| st.pos(Pos::new(hp, vp));
            draw(root.draw_text(l, &mid(&letters, HPos::Left, VPos::Center), (ox + 4, oy + h / 2)))?;
            draw(root.draw_text(r, &mid(&letters, HPos::Right, VPos::Center), (ox + w - 4, oy + h / 2)))?;
            // Thin panels (a short series seen from the side) keep only the side letters.
            if h >= 120 {
                draw(root.draw_text(t, &mid(&letters, HPos::Center, VPos::Top), (ox + w / 2, oy + 4)))?;
                draw(root.draw_text(b, &mid(&letters, HPos::Center, VPos::Bottom), (ox + w / 2, oy + h - 4)))?;
                // 50 mm scale bar.
                let bar = (50.0 / s.pixel_mm).round() as i32;
                let (bx, by) = (ox + w - bar - 10, oy + h - 30);
                draw(root.draw(&Rectangle::new([(bx, by), (bx + bar, by + 4)], WHITE.filled())))?;
                draw(root.draw_text(
                    "50 mm",
                    &small.pos(Pos::new(HPos::Center, VPos::Bottom)),
                    (bx + bar / 2, by - 2),
                ))?;
            }
            // Crosshair at the centre point.
            let (cc, cr) = s.pixel(center);
            let (cx, cy) = (ox + cc.round() as i32, oy + cr.round() as i32);
            let cross = RGBColor(255, 220, 80);
            draw(root.draw(&PathElement::new(vec![(cx - 12, cy), (cx - 4, cy)], cross)))?;
            draw(root.draw(&PathElement::new(vec![(cx + 4, cy), (cx + 12, cy)], cross)))?;
            draw(root.draw(&PathElement::new(vec![(cx, cy - 12), (cx, cy - 4)], cross)))?;
            draw(root.draw(&PathElement::new(vec![(cx, cy + 4), (cx, cy + 12)], cross)))?;
            let to_px = |p: DVec3| {
                let (c, r) = s.pixel(p);
                (ox as f64 + c, oy as f64 + r)
            };
            let local = |p: DVec3| {
                let (x, y) = to_px(p);
                (x - ox as f64, y - oy as f64)
            };
            let at = |p: (f64, f64)| (ox + p.0.round() as i32, oy + p.1.round() as i32);
            let (wf, hf) = (w as f64 - 1.0, h as f64 - 1.0);
            // The expert corridor under every line: a band as wide as the corridor.
            if let Some(c) = &spec.corridor {
                let centre: Vec<(f64, f64)> = c.centre_mm.iter().map(|p| local(*p)).collect();
                let radius: Vec<f64> = c
                    .radius_mm
                    .iter()
                    .map(|r| (r / s.pixel_mm).max(MIN_HALF_WIDTH_PX))
                    .collect();
                let band = clip_polygon(&band_polygon(&centre, &radius), (0.0, 0.0), (wf, hf));
                if band.len() >= 3 {
                    let pts: Vec<(i32, i32)> = band.iter().map(|p| at(*p)).collect();
                    draw(root.draw(&Polygon::new(pts, rgb(CORRIDOR_RGB).mix(CORRIDOR_ALPHA).filled())))?;
                }
            }
            // Clipped to the panel: a path projected from far away must not spill onto the next.
            for line in &spec.needle {
                let pts: Vec<(f64, f64)> = line.iter().map(|p| local(*p)).collect();
                for [a, b] in clipped(&pts, wf, hf) {
                    draw(root.draw(&PathElement::new(
                        vec![at(a), at(b)],
                        ShapeStyle::from(&rgb(NEEDLE_RGB)).stroke_width(2),
                    )))?;
                }
            }
            // The planned path over the needle's: dashed, so a needle that followed it shows between.
            for (_, a, b) in &spec.planned {
                let style = ShapeStyle::from(&rgb(PLANNED_RGB)).stroke_width(3);
                for [a, b] in clipped(&[local(*a), local(*b)], wf, hf) {
                    for dash in dashes(&[a, b], 10.0, 7.0) {
                        let dash: Vec<(i32, i32)> = dash.iter().map(|p| (ox + p.0, oy + p.1)).collect();
                        draw(root.draw(&PathElement::new(dash, style)))?;
                    }
                }
            }
            if let Some(m) = &spec.mark {
                let (x, y) = local(m.point_mm);
                if (0.0..=wf).contains(&x) && (0.0..=hf).contains(&y) {
                    let c = at((x, y));
                    draw(root.draw(&Circle::new(c, 11, ShapeStyle::from(&WHITE).stroke_width(5))))?;
                    draw(root.draw(&Circle::new(c, 11, ShapeStyle::from(&rgb(MARK_RGB)).stroke_width(3))))?;
                    draw(root.draw(&Circle::new(c, 2, rgb(MARK_RGB).filled())))?;
                }
            }
        }
        // Legend: lines and the mark, then the labels.
        let mut ly = (TITLE_H + PANEL_TITLE_H + panel_h + MARGIN) as i32;
        if !line_entries.is_empty() {
            for (n, (text, color, stroke)) in line_entries.iter().enumerate() {
                let x = (MARGIN + n * 300) as i32;
                let style = ShapeStyle::from(&rgb(*color)).stroke_width(3);
                if *stroke == Stroke::Band {
                    draw(root.draw(&Rectangle::new(
                        [(x, ly + 3), (x + 30, ly + 17)],
                        rgb(*color).mix(CORRIDOR_ALPHA + 0.2).filled(),
                    )))?;
                } else if *stroke == Stroke::Dashed {
                    for dash in dashes(
                        &[(x as f64, (ly + 10) as f64), ((x + 30) as f64, (ly + 10) as f64)],
                        8.0,
                        5.0,
                    ) {
                        draw(root.draw(&PathElement::new(dash, style)))?;
                    }
                } else {
                    draw(root.draw(&PathElement::new(vec![(x, ly + 10), (x + 30, ly + 10)], style)))?;
                }
                draw(root.draw_text(text, &small, (x + 38, ly + 2)))?;
            }
            ly += LEGEND_ROW_H as i32;
        }
        if let Some(m) = &spec.mark {
            let x = MARGIN as i32;
            draw(root.draw(&Circle::new(
                (x + 15, ly + 10),
                7,
                ShapeStyle::from(&WHITE).stroke_width(4),
            )))?;
            draw(root.draw(&Circle::new(
                (x + 15, ly + 10),
                7,
                ShapeStyle::from(&rgb(MARK_RGB)).stroke_width(2),
            )))?;
            draw(root.draw_text(&m.label, &small, (x + 38, ly + 2)))?;
            ly += LEGEND_ROW_H as i32;
        }
        for (n, id) in present.iter().enumerate() {
            let Some(label) = table.get(*id) else {
                continue;
            };
            let pos = table.position(*id).expect("label exists");
            let c = atlas.materials().color(pos);
            let x = (MARGIN + (n % per_row) * column_px) as i32;
            let y = ly + (n / per_row) as i32 * LEGEND_ROW_H as i32;
            draw(root.draw(&Rectangle::new(
                [(x, y + 3), (x + 16, y + 17)],
                RGBColor(c[0], c[1], c[2]).filled(),
            )))?;
            draw(root.draw_text(
                &format!("{} ({})", label.name, label.role.as_str()),
                &small,
                (x + 22, y + 2),
            ))?;
        }
        root.present().map_err(|e| RenderError::Draw(e.to_string()))?;
    }
    write_rgb_png(png, width, height, &buf)
}

/// Writes 8-bit RGB pixels (rows top to bottom, no padding) as a PNG file, creating its folder.
pub fn write_rgb_png(path: &Path, width: usize, height: usize, rgb: &[u8]) -> Result<(), RenderError> {
    let err = |m: String| RenderError::Write {
        path: path.display().to_string(),
        message: m,
    };
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| err(e.to_string()))?;
    }
    let file = std::fs::File::create(path).map_err(|e| err(e.to_string()))?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), width as u32, height as u32);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut w = enc.write_header().map_err(|e| err(e.to_string()))?;
    w.write_image_data(rgb).map_err(|e| err(e.to_string()))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn segments_are_clipped_to_the_panel() {
        assert_eq!(
            clip((-10.0, 5.0), (20.0, 5.0), 10.0, 10.0),
            Some(((0.0, 5.0), (10.0, 5.0)))
        );
        assert_eq!(clip((2.0, 2.0), (3.0, 4.0), 10.0, 10.0), Some(((2.0, 2.0), (3.0, 4.0))));
        assert_eq!(clip((-5.0, -5.0), (-1.0, 20.0), 10.0, 10.0), None);
        assert_eq!(clip((f64::NAN, 0.0), (1.0, 1.0), 10.0, 10.0), None);
        assert_eq!(clipped(&[(-5.0, 5.0), (5.0, 5.0), (5.0, 50.0)], 10.0, 10.0).len(), 2);
    }

    #[test]
    fn dashes_alternate_along_the_line() {
        let d = dashes(&[(0.0, 0.0), (40.0, 0.0)], 10.0, 5.0);
        let spans: Vec<(i32, i32)> = d.iter().map(|s| (s[0].0, s[1].0)).collect();
        assert_eq!(spans, vec![(0, 10), (15, 25), (30, 40)]);
        // The pattern carries on across a corner.
        let d = dashes(&[(0.0, 0.0), (8.0, 0.0), (8.0, 10.0)], 10.0, 5.0);
        assert_eq!(d[0], vec![(0, 0), (8, 0)]);
        assert_eq!(d[1], vec![(8, 0), (8, 2)]);
        assert_eq!(d[2], vec![(8, 7), (8, 10)]);
    }
}
