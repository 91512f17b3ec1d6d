//! The 3D overview of a whole attempt (docs/dashboard.md "3D overview"): the patient ray-cast from
//! an angle of a turntable, cut along the needle's path with the target and the risk structures
//! tagged (thesis §3.2.2, eq. 3.2.4), and drawn over it the needle tip's path through the
//! anatomy coloured by what the tip was in, the planned path and the expert corridor.
//!
//! The lines are drawn over the picture, not into the volume: the whole path stays visible from
//! every angle, as on a radiograph.

use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use stylet_atlas::Atlas;
use stylet_physics::glam::DVec3;
use stylet_physics::{PunctureAtlas, Role};

use crate::RenderError;
use crate::corridor::{CORRIDOR_ALPHA, CORRIDOR_RGB, Corridor, MIN_HALF_WIDTH_PX, band_polygon, clip_polygon};
use crate::fonts::{SANS, ensure_fonts};
use crate::image::Image;
use crate::presets::Preset;
use crate::scene::{Camera, Tagging};
use crate::views::{self, ViewError};
use crate::volume::RenderVolume;

/// Turntable frames: one every [`STEP_DEG`] of azimuth.
pub const FRAMES: u32 = 12;
pub const STEP_DEG: f32 = 360.0 / FRAMES as f32;
/// The turntable's elevation: a little from above, so the path's depth reads.
pub const ELEVATION_DEG: f32 = 20.0;
/// Space framed around the paths (mm): enough anatomy around them to find one's way.
pub const MARGIN_MM: f64 = 60.0;

/// What the tip was in, for the path's colour.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PathRegion {
    /// Skin, fat, muscle, organs the needle may cross: cyan.
    Tissue,
    /// A risk structure: red.
    Risk,
    /// The target: green.
    Target,
    /// Bone: white.
    Bone,
}

impl PathRegion {
    /// The region of the tip at `point_mm`, `depth_mm` under the skin (the label of thesis eq.
    /// 6.1.2, its role from the atlas' label table).
    pub fn at(atlas: &PunctureAtlas, point_mm: DVec3, depth_mm: f64) -> PathRegion {
        let label = atlas.label_at(point_mm, depth_mm.max(0.0));
        match atlas.label_table().get(label).map(|l| l.role) {
            Some(Role::Risk) => PathRegion::Risk,
            Some(Role::Target) => PathRegion::Target,
            Some(Role::Bone) => PathRegion::Bone,
            _ => PathRegion::Tissue,
        }
    }

    pub fn rgb(self) -> [u8; 3] {
        match self {
            PathRegion::Tissue => crate::figure::NEEDLE_RGB,
            PathRegion::Risk => [255, 50, 50],
            PathRegion::Target => [60, 255, 60],
            PathRegion::Bone => [255, 255, 255],
        }
    }
}

/// What an overview frame shows.
#[derive(Debug, Clone, PartialEq)]
pub struct OverviewSpec {
    /// The tip's path, one polyline per stay in the body, each point with its region and its
    /// depth under the skin (mm).
    pub tip_paths: Vec<Vec<(DVec3, PathRegion, f64)>>,
    /// The planned path (entry, target), if the scenario has one.
    pub planned: Option<(DVec3, DVec3)>,
    pub corridor: Option<Corridor>,
    /// Frame of the turntable, 0 … [`FRAMES`] − 1 (azimuth = frame × [`STEP_DEG`]).
    pub frame: u32,
}

impl OverviewSpec {
    pub fn azimuth_deg(&self) -> f32 {
        (self.frame % FRAMES) as f32 * STEP_DEG
    }

    /// Where the volume is cut: along the path from the skin entry of the deepest stay to the
    /// deepest point, else along the planned path, else the atlas' default.
    fn cut(&self, atlas: &Atlas) -> (DVec3, DVec3) {
        if let Some(deepest) = self.deepest()
            && let Some(stay) = self.tip_paths.iter().find(|p| p.iter().any(|q| q.0 == deepest))
            && let Some(axis) = (deepest - stay[0].0).try_normalize()
        {
            return (deepest, axis);
        }
        if let Some((entry, target)) = self.planned
            && let Some(axis) = (target - entry).try_normalize()
        {
            return (target, axis);
        }
        views::focus(atlas, None)
    }

    /// What the camera frames: the paths, the planned path and the corridor with [`MARGIN_MM`]
    /// around them, within the volume; the whole volume when there is nothing to show.
    fn frame_box(&self, atlas: &Atlas) -> (DVec3, DVec3) {
        let (vlo, vhi) = atlas.model.ct().grid().world_bounds();
        let points = self
            .tip_paths
            .iter()
            .flatten()
            .map(|p| p.0)
            .chain(self.planned.iter().flat_map(|(a, b)| [*a, *b]))
            .chain(self.corridor.iter().flat_map(|c| c.centre_mm.iter().copied()))
            .filter(|p| p.is_finite());
        let bounds = points.fold(None, |acc: Option<(DVec3, DVec3)>, p| match acc {
            Some((lo, hi)) => Some((lo.min(p), hi.max(p))),
            None => Some((p, p)),
        });
        match bounds {
            Some((lo, hi)) => (
                (lo - DVec3::splat(MARGIN_MM)).max(vlo),
                (hi + DVec3::splat(MARGIN_MM)).min(vhi),
            ),
            None => (vlo, vhi),
        }
    }

    /// The deepest point of the tip's path (the largest depth under the skin), if it entered.
    fn deepest(&self) -> Option<DVec3> {
        self.tip_paths
            .iter()
            .flatten()
            .fold(None, |best: Option<(DVec3, f64)>, p| match best {
                Some((_, d)) if d >= p.2 => best,
                _ => Some((p.0, p.2)),
            })
            .map(|b| b.0)
    }
}

/// Draws an overview frame at `width` × `height` on the CPU reference ray caster.
pub fn render(
    atlas: &Atlas,
    volume: &RenderVolume,
    spec: &OverviewSpec,
    width: u32,
    height: u32,
) -> Result<Image, ViewError> {
    // The skin preset paints −300 … 3000 HU one opaque colour: cut through the patient it is a
    // flat plane of skin colour. The cut reads as anatomy with the soft-tissue preset and every
    // label in its colour on the cut, as on the atlas report's 3D views and the review's slices.
    let scene = views::scene_3d_orbit(
        atlas,
        Preset::Soft,
        Tagging::Labels,
        spec.cut(atlas),
        views::default_step_mm(atlas),
        (spec.azimuth_deg(), ELEVATION_DEG),
        spec.frame_box(atlas),
    )?;
    let mut image = crate::raycast::render(volume, &scene, width, height).image;
    draw_lines(&mut image, &scene.camera, spec)?;
    Ok(image)
}

/// The corridor, the planned path, the tip's path and a legend over `image`.
fn draw_lines(image: &mut Image, camera: &Camera, spec: &OverviewSpec) -> Result<(), RenderError> {
    ensure_fonts();
    let (w, h) = (image.width, image.height);
    let project = |p: DVec3| camera.project(p.as_vec3(), w, h);
    let mut buf: Vec<u8> = image.rgba.iter().flat_map(|p| [p[0], p[1], p[2]]).collect();
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        let draw = |r: Result<(), DrawingAreaErrorKind<_>>| r.map_err(|e| RenderError::Draw(e.to_string()));
        let rgb = |c: [u8; 3]| RGBColor(c[0], c[1], c[2]);
        let px = |p: (f64, f64)| (p.0.round() as i32, p.1.round() as i32);
        let (lo, hi) = ((-4.0, -4.0), (f64::from(w) + 4.0, f64::from(h) + 4.0));
        if let Some(c) = &spec.corridor {
            let projected: Option<Vec<(f32, f32, f32)>> = c.centre_mm.iter().map(|p| project(*p)).collect();
            if let Some(projected) = projected {
                let centre: Vec<(f64, f64)> = projected.iter().map(|q| (f64::from(q.0), f64::from(q.1))).collect();
                let radius: Vec<f64> = projected
                    .iter()
                    .zip(&c.radius_mm)
                    .map(|(q, r)| (r * f64::from(camera.pixels_per_mm(q.2, h))).max(MIN_HALF_WIDTH_PX))
                    .collect();
                let band = clip_polygon(&band_polygon(&centre, &radius), lo, hi);
                if band.len() >= 3 {
                    let pts: Vec<(i32, i32)> = band.iter().map(|p| px(*p)).collect();
                    draw(root.draw(&Polygon::new(
                        pts.clone(),
                        rgb(CORRIDOR_RGB).mix(CORRIDOR_ALPHA).filled(),
                    )))?;
                    let mut outline = pts;
                    outline.push(outline[0]);
                    draw(root.draw(&PathElement::new(outline, rgb(CORRIDOR_RGB).stroke_width(1))))?;
                }
            }
        }
        if let Some((entry, target)) = spec.planned
            && let (Some(a), Some(b)) = (project(entry), project(target))
        {
            let (a, b) = ((f64::from(a.0), f64::from(a.1)), (f64::from(b.0), f64::from(b.1)));
            let len = ((b.0 - a.0).powi(2) + (b.1 - a.1).powi(2)).sqrt();
            let dashes = (len / 12.0).ceil().max(1.0) as usize;
            for k in (0..dashes).step_by(2) {
                let at = |t: f64| (a.0 + (b.0 - a.0) * t, a.1 + (b.1 - a.1) * t);
                let (t0, t1) = (k as f64 / dashes as f64, ((k + 1) as f64 / dashes as f64).min(1.0));
                draw(root.draw(&PathElement::new(
                    vec![px(at(t0)), px(at(t1))],
                    rgb(crate::figure::PLANNED_RGB).stroke_width(3),
                )))?;
            }
        }
        for path in &spec.tip_paths {
            for seg in path.windows(2) {
                if let (Some(a), Some(b)) = (project(seg[0].0), project(seg[1].0)) {
                    // A segment takes the colour of where it ends: the step into a structure is
                    // drawn in the structure's colour.
                    draw(root.draw(&PathElement::new(
                        vec![
                            px((f64::from(a.0), f64::from(a.1))),
                            px((f64::from(b.0), f64::from(b.1))),
                        ],
                        rgb(seg[1].1.rgb()).stroke_width(3),
                    )))?;
                }
            }
            if let Some(first) = path.first().and_then(|p| project(p.0)) {
                let at = px((f64::from(first.0), f64::from(first.1)));
                draw(root.draw(&Circle::new(at, 4, WHITE.filled())))?;
            }
        }
        // The deepest point: a ring, as on the slices.
        if let Some(tip) = spec.deepest().and_then(project) {
            let at = px((f64::from(tip.0), f64::from(tip.1)));
            draw(root.draw(&Circle::new(at, 7, rgb(crate::annotate::TIP_RGB).stroke_width(2))))?;
        }
        let small = TextStyle::from((SANS, 14).into_font()).color(&WHITE);
        draw(root.draw_text(
            &format!("azimuth {:.0}°, elevation {:.0}°", spec.azimuth_deg(), ELEVATION_DEG),
            &small.pos(Pos::new(HPos::Left, VPos::Top)),
            (6, 6),
        ))?;
        if let Some(c) = &spec.corridor {
            draw(root.draw_text(
                &format!(
                    "expert corridor: {} path{}",
                    c.experts,
                    if c.experts == 1 { "" } else { "s" }
                ),
                &small.pos(Pos::new(HPos::Left, VPos::Bottom)),
                (6, h as i32 - 6),
            ))?;
        }
        root.present().map_err(|e| RenderError::Draw(e.to_string()))?;
    }
    for (px, rgb) in image.rgba.iter_mut().zip(buf.chunks_exact(3)) {
        px[..3].copy_from_slice(rgb);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use stylet_physics::glam::Vec3;

    #[test]
    fn projection_inverts_the_ray_of_a_pixel() {
        let cam = Camera::orbit(Vec3::new(10.0, -20.0, 5.0), 400.0, 30.0, 20.0, 30.0);
        for (col, row) in [(0u32, 0u32), (123, 45), (319, 239), (160, 120)] {
            let (o, d) = cam.ray(col, row, 320, 240);
            let (c, r, depth) = cam.project(o + d * 250.0, 320, 240).unwrap();
            assert!(
                (c - col as f32).abs() < 1e-2 && (r - row as f32).abs() < 1e-2,
                "{col},{row}: {c},{r}"
            );
            assert!(depth > 0.0 && depth <= 250.0);
        }
        assert_eq!(cam.project(cam.eye_mm - (cam.target_mm - cam.eye_mm), 320, 240), None);
    }

    #[test]
    fn frames_go_round_the_turntable() {
        let spec = |frame| OverviewSpec {
            tip_paths: Vec::new(),
            planned: None,
            corridor: None,
            frame,
        };
        assert_eq!(spec(0).azimuth_deg(), 0.0);
        assert_eq!(spec(3).azimuth_deg(), 90.0);
        assert_eq!(spec(FRAMES + 1).azimuth_deg(), STEP_DEG);
    }
}
