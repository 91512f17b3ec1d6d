//! The atlas figure: axial, coronal and sagittal slices through a point (by default the target's
//! centre) with the label overlay, orientation letters, scale bars and a colour legend, as PNG.

use std::path::Path;

use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use stylet_physics::glam::DVec3;
use stylet_physics::{PunctureAtlas, Role};

use crate::RenderError;
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
    ensure_fonts();
    let slices: Vec<Slice> = [Plane::Axial, Plane::Coronal, Plane::Sagittal]
        .into_iter()
        .map(|p| render_slice(atlas, p, center, Window::ABDOMEN, MAX_PANEL_PX))
        .collect();
    // Legend: partial labels present in any slice.
    let table = atlas.label_table();
    let mut present: Vec<u16> = slices
        .iter()
        .flat_map(|s| s.labels.iter().copied())
        .filter(|&l| l != 0)
        .collect();
    present.sort_unstable();
    present.dedup();
    let width = slices.iter().map(|s| s.width).sum::<usize>() + MARGIN * (slices.len() + 1);
    let per_row = ((width - 2 * MARGIN) / 260).max(1);
    let legend_rows = present.len().div_ceil(per_row).max(1);
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
        draw(root.draw_text(
            &format!(
                "slices through ({:.0}, {:.0}, {:.0}) mm RAS (crosshair), CT window L 40 / W 400 HU, partial labels in colour",
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
            for line in polylines {
                let pts: Vec<(i32, i32)> = line
                    .iter()
                    .map(|p| {
                        let (c, r) = s.pixel(*p);
                        ((ox as f64 + c).round() as i32, (oy as f64 + r).round() as i32)
                    })
                    .collect();
                draw(root.draw(&PathElement::new(
                    pts,
                    ShapeStyle::from(&RGBColor(0, 230, 255)).stroke_width(2),
                )))?;
            }
        }
        // Legend.
        let ly = (TITLE_H + PANEL_TITLE_H + panel_h + MARGIN) as i32;
        for (n, id) in present.iter().enumerate() {
            let Some(label) = table.get(*id) else {
                continue;
            };
            let pos = table.position(*id).expect("label exists");
            let c = atlas.materials().color(pos);
            let x = (MARGIN + (n % per_row) * 260) as i32;
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
    write_png(png, width, height, &buf)
}

fn write_png(path: &Path, width: usize, height: usize, rgb: &[u8]) -> Result<(), RenderError> {
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
