//! Overlays on MPR images, drawn on the CPU after either renderer (the GPU returns the slice's
//! pixels): the needle's projected path and a tip marker, a scale bar with its length in text,
//! and the orientation letters at the edges (docs/rendering.md "MPR").

use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use stylet_physics::glam::DVec3;

use crate::RenderError;
use crate::fonts::{SANS, ensure_fonts};
use crate::image::Image;
use crate::mpr::SliceSpec;

/// The needle path's colour (as on the atlas figure).
pub const NEEDLE_RGB: [u8; 3] = [0, 230, 255];
/// The tip marker's colour.
pub const TIP_RGB: [u8; 3] = [255, 60, 40];
/// Scale bar and its text.
pub const BAR_RGB: [u8; 3] = [255, 255, 255];
/// Orientation letters.
pub const LETTER_RGB: [u8; 3] = [255, 220, 80];

/// Radius of the tip marker's ring (pixels).
pub const TIP_RING_PX: i32 = 9;
/// Distance of the scale bar from the image's right and bottom edges (pixels), and its thickness.
pub const BAR_MARGIN_PX: i32 = 12;
pub const BAR_THICKNESS_PX: i32 = 4;

/// What to draw on a slice.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Annotations {
    /// The needle's nodes (hub first, world mm): projected path, tip marker at the last node.
    pub needle_mm: Vec<DVec3>,
    pub scale_bar: bool,
    pub letters: bool,
}

/// The scale bar drawn for a pixel size: 50 mm when that fits in 40 % of the width, else 10 mm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ScaleBar {
    pub length_mm: f64,
    /// round(length_mm / pixel_mm).
    pub length_px: i32,
}

impl ScaleBar {
    pub fn for_slice(pixel_mm: f64, width_px: usize) -> ScaleBar {
        let fits = |mm: f64| mm / pixel_mm <= 0.4 * width_px as f64;
        let length_mm = if fits(50.0) { 50.0 } else { 10.0 };
        ScaleBar {
            length_mm,
            length_px: (length_mm / pixel_mm).round() as i32,
        }
    }

    /// Its label: "50 mm".
    pub fn text(&self) -> String {
        format!("{:.0} mm", self.length_mm)
    }
}

/// The part of segment a–b inside [x0, x1] × [y0, y1] (Liang–Barsky), if any.
fn clip(a: (f64, f64), b: (f64, f64), lo: (f64, f64), hi: (f64, f64)) -> Option<((f64, f64), (f64, f64))> {
    let (dx, dy) = (b.0 - a.0, b.1 - a.1);
    let (mut t0, mut t1) = (0.0f64, 1.0f64);
    for (p, q) in [(-dx, a.0 - lo.0), (dx, hi.0 - a.0), (-dy, a.1 - lo.1), (dy, hi.1 - a.1)] {
        if !q.is_finite() || !p.is_finite() {
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

/// Draws `ann` on `img`, whose pixels are the slice `spec` (sizes must match).
pub fn annotate(img: &mut Image, spec: &SliceSpec, ann: &Annotations) -> Result<(), RenderError> {
    if img.width as usize != spec.width || img.height as usize != spec.height {
        return Err(RenderError::Draw(format!(
            "image of {} × {} pixels is not the slice's {} × {}",
            img.width, img.height, spec.width, spec.height
        )));
    }
    ensure_fonts();
    let (w, h) = (img.width, img.height);
    let mut buf: Vec<u8> = img.rgba.iter().flat_map(|p| [p[0], p[1], p[2]]).collect();
    let bar = ScaleBar::for_slice(spec.pixel_mm, spec.width);
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        let draw = |r: Result<(), DrawingAreaErrorKind<_>>| r.map_err(|e| RenderError::Draw(e.to_string()));
        let rgb = |c: [u8; 3]| RGBColor(c[0], c[1], c[2]);
        let (wi, hi) = (w as i32, h as i32);
        if ann.needle_mm.len() >= 2 {
            let pts: Vec<(f64, f64)> = ann.needle_mm.iter().map(|p| spec.pixel(*p)).collect();
            // Clipped a little outside the image: far-away projections stay cheap to draw.
            let (lo, hi_c) = ((-8.0, -8.0), (w as f64 + 8.0, h as f64 + 8.0));
            let px = |p: (f64, f64)| (p.0.round() as i32, p.1.round() as i32);
            for s in pts.windows(2) {
                if let Some((a, b)) = clip(s[0], s[1], lo, hi_c) {
                    draw(root.draw(&PathElement::new(
                        vec![px(a), px(b)],
                        ShapeStyle::from(&rgb(NEEDLE_RGB)).stroke_width(2),
                    )))?;
                }
            }
        }
        if let Some(tip) = ann.needle_mm.last() {
            let (c, r) = spec.pixel(*tip);
            if c.is_finite()
                && r.is_finite()
                && (-0.5..w as f64 - 0.5).contains(&c)
                && (-0.5..h as f64 - 0.5).contains(&r)
            {
                let at = (c.round() as i32, r.round() as i32);
                let style = ShapeStyle::from(&rgb(TIP_RGB)).stroke_width(2);
                draw(root.draw(&Circle::new(at, TIP_RING_PX, style)))?;
                let arm = TIP_RING_PX + 6;
                for (a, b) in [
                    ((at.0 - arm, at.1), (at.0 - TIP_RING_PX + 3, at.1)),
                    ((at.0 + TIP_RING_PX - 3, at.1), (at.0 + arm, at.1)),
                    ((at.0, at.1 - arm), (at.0, at.1 - TIP_RING_PX + 3)),
                    ((at.0, at.1 + TIP_RING_PX - 3), (at.0, at.1 + arm)),
                ] {
                    draw(root.draw(&PathElement::new(vec![a, b], style)))?;
                }
            }
        }
        // Text with a dark outline, legible on bone and on the label overlay too.
        let text = |t: &str, size: i32, color: [u8; 3], hp: HPos, vp: VPos, at: (i32, i32)| {
            let font = (SANS, size).into_font();
            let shadow = RGBColor(0, 0, 0);
            let fill = rgb(color);
            let st = TextStyle::from(font.clone()).color(&shadow).pos(Pos::new(hp, vp));
            for (dx, dy) in [(-1, 0), (1, 0), (0, -1), (0, 1), (1, 1)] {
                draw(root.draw_text(t, &st, (at.0 + dx, at.1 + dy)))?;
            }
            let st = TextStyle::from(font).color(&fill).pos(Pos::new(hp, vp));
            draw(root.draw_text(t, &st, at))
        };
        if ann.letters {
            let size = (hi.min(wi) / 20).clamp(12, 22);
            let [l, r, t, b] = spec.edge_letters();
            text(l, size, LETTER_RGB, HPos::Left, VPos::Center, (6, hi / 2))?;
            text(r, size, LETTER_RGB, HPos::Right, VPos::Center, (wi - 6, hi / 2))?;
            text(t, size, LETTER_RGB, HPos::Center, VPos::Top, (wi / 2, 6))?;
            text(b, size, LETTER_RGB, HPos::Center, VPos::Bottom, (wi / 2, hi - 6))?;
        }
        if ann.scale_bar {
            let size = (hi.min(wi) / 24).clamp(11, 18);
            let (x0, y0) = bar_origin(&bar, wi, hi);
            text(
                &bar.text(),
                size,
                BAR_RGB,
                HPos::Center,
                VPos::Bottom,
                (x0 + bar.length_px / 2, y0 - 3),
            )?;
        }
        root.present().map_err(|e| RenderError::Draw(e.to_string()))?;
    }
    for (p, q) in img.rgba.iter_mut().zip(buf.chunks_exact(3)) {
        *p = [q[0], q[1], q[2], 255];
    }
    if ann.scale_bar {
        // The bar itself pixel-exact: length_px columns from x0.
        let (x0, y0) = bar_origin(&bar, w as i32, h as i32);
        for y in y0.max(0)..(y0 + BAR_THICKNESS_PX).min(h as i32) {
            for x in x0.max(0)..(x0 + bar.length_px).min(w as i32) {
                img.set(x as u32, y as u32, [BAR_RGB[0], BAR_RGB[1], BAR_RGB[2], 255]);
            }
        }
    }
    Ok(())
}

/// Height and width of the displacement colour bar (pixels).
const LEGEND_BAR_PX: (i32, i32) = (120, 12);

/// The displacement colour map's legend in the top-left corner: a vertical bar from 0 (bottom) to
/// `scale_mm` (top), labelled in mm.
pub fn displacement_legend(img: &mut Image, scale_mm: f64) -> Result<(), RenderError> {
    let (w, h) = (img.width as i32, img.height as i32);
    let (bar_h, bar_w) = LEGEND_BAR_PX;
    let (x0, y0) = (14, 40);
    if w < x0 + bar_w + 80 || h < y0 + bar_h + 20 {
        return Ok(()); // too small a view for a legend
    }
    for dy in 0..bar_h {
        let t = 1.0 - dy as f32 / (bar_h - 1) as f32;
        let c = crate::mpr::displacement_rgb(t);
        for dx in 0..bar_w {
            img.set((x0 + dx) as u32, (y0 + dy) as u32, [c[0], c[1], c[2], 255]);
        }
    }
    ensure_fonts();
    let mut buf: Vec<u8> = img.rgba.iter().flat_map(|p| [p[0], p[1], p[2]]).collect();
    {
        let root = BitMapBackend::with_buffer(&mut buf, (img.width, img.height)).into_drawing_area();
        let draw = |r: Result<(), DrawingAreaErrorKind<_>>| r.map_err(|e| RenderError::Draw(e.to_string()));
        let text = |t: &str, vp: VPos, at: (i32, i32)| {
            let font = (SANS, 13).into_font();
            let st = TextStyle::from(font.clone())
                .color(&RGBColor(0, 0, 0))
                .pos(Pos::new(HPos::Left, vp));
            for (dx, dy) in [(-1, 0), (1, 0), (0, -1), (0, 1)] {
                draw(root.draw_text(t, &st, (at.0 + dx, at.1 + dy)))?;
            }
            let st = TextStyle::from(font)
                .color(&RGBColor(255, 255, 255))
                .pos(Pos::new(HPos::Left, vp));
            draw(root.draw_text(t, &st, at))
        };
        text("tissue displacement", VPos::Bottom, (x0, y0 - 4))?;
        text(&format!("{scale_mm:.0} mm"), VPos::Top, (x0 + bar_w + 5, y0))?;
        text("0", VPos::Bottom, (x0 + bar_w + 5, y0 + bar_h))?;
        root.present().map_err(|e| RenderError::Draw(e.to_string()))?;
    }
    for (p, q) in img.rgba.iter_mut().zip(buf.chunks_exact(3)) {
        *p = [q[0], q[1], q[2], 255];
    }
    Ok(())
}

/// Left end and top row of the scale bar: in the bottom-right corner, clear of the bottom letter.
pub fn bar_origin(bar: &ScaleBar, width: i32, height: i32) -> (i32, i32) {
    (
        width - BAR_MARGIN_PX - bar.length_px,
        height - BAR_MARGIN_PX - BAR_THICKNESS_PX - 14,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clipping_keeps_the_inside_part() {
        assert_eq!(
            clip((-10.0, 5.0), (20.0, 5.0), (0.0, 0.0), (10.0, 10.0)),
            Some(((0.0, 5.0), (10.0, 5.0)))
        );
        assert_eq!(clip((-5.0, -5.0), (-1.0, 20.0), (0.0, 0.0), (10.0, 10.0)), None);
        assert_eq!(clip((f64::NAN, 0.0), (1.0, 1.0), (0.0, 0.0), (10.0, 10.0)), None);
    }

    #[test]
    fn scale_bar_length_follows_the_pixel_size() {
        let b = ScaleBar::for_slice(0.5, 512);
        assert_eq!((b.length_mm, b.length_px, b.text().as_str()), (50.0, 100, "50 mm"));
        // 50 mm would take 200 of 256 pixels: 10 mm instead.
        let b = ScaleBar::for_slice(0.25, 256);
        assert_eq!((b.length_mm, b.length_px), (10.0, 40));
        let b = ScaleBar::for_slice(0.7, 480);
        assert_eq!(b.length_px, (50.0f64 / 0.7).round() as i32);
    }
}
