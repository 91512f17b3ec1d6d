//! Multi-planar reformation on the CPU: axial, coronal and sagittal slices through a world point
//! and an oblique plane along the needle, resampled to square display pixels, in radiological
//! display convention (patient's right on the image's left; anterior up in axial views, superior
//! up in coronal and sagittal views, anterior on the left in sagittal views), with the label
//! overlay (docs/rendering.md "MPR").
//!
//! Every image is described by a [`SliceSpec`] (centre, unit right and down directions, pixel
//! size, size, window) and drawn by [`render_spec`] in `f32` index space with the formulas the
//! GPU's MPR shader repeats (docs/rendering.md "MPR"), so the two agree to a grey level.

use rayon::prelude::*;

use crate::scene::MotionHook;
use stylet_physics::deform::DeformField;
use stylet_physics::deform::resample::INVERSE_ITERATIONS;
use stylet_physics::glam::{DVec3, Vec3};
use stylet_physics::motion;
use stylet_physics::{AIR_HU, Grid, LabelId, PunctureAtlas};

/// Which plane.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Plane {
    Axial,
    Coronal,
    Sagittal,
}

impl Plane {
    pub fn name(self) -> &'static str {
        match self {
            Plane::Axial => "axial",
            Plane::Coronal => "coronal",
            Plane::Sagittal => "sagittal",
        }
    }

    /// World directions of the image's +column (right) and +row (down) axes.
    pub fn axes(self) -> (DVec3, DVec3) {
        match self {
            // Image right = patient left (−x); image down = posterior (−y).
            Plane::Axial => (DVec3::NEG_X, DVec3::NEG_Y),
            // Image right = patient left; image down = inferior.
            Plane::Coronal => (DVec3::NEG_X, DVec3::NEG_Z),
            // Image right = posterior; image down = inferior.
            Plane::Sagittal => (DVec3::NEG_Y, DVec3::NEG_Z),
        }
    }

    /// Orientation letters at the image's left, right, top and bottom edges.
    pub fn edge_letters(self) -> [&'static str; 4] {
        match self {
            Plane::Axial => ["R", "L", "A", "P"],
            Plane::Coronal => ["R", "L", "S", "I"],
            Plane::Sagittal => ["A", "P", "S", "I"],
        }
    }
}

/// CT display window.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Window {
    pub level_hu: f64,
    pub width_hu: f64,
}

impl Window {
    /// Abdominal soft-tissue window (L 40, W 400).
    pub const ABDOMEN: Window = Window {
        level_hu: 40.0,
        width_hu: 400.0,
    };

    #[inline]
    pub fn gray(&self, hu: f64) -> u8 {
        let t = (hu - (self.level_hu - self.width_hu / 2.0)) / self.width_hu;
        (t.clamp(0.0, 1.0) * 255.0).round() as u8
    }
}

/// A rendered slice: RGB pixels, the partial label of each pixel and the pixel size.
#[derive(Debug, Clone)]
pub struct Slice {
    pub plane: Plane,
    pub width: usize,
    pub height: usize,
    pub pixel_mm: f64,
    pub rgb: Vec<[u8; 3]>,
    pub labels: Vec<LabelId>,
    /// World position of the slice centre (the point it passes through).
    pub center: DVec3,
    /// World position of pixel (0, 0)'s centre.
    pub corner: DVec3,
    /// The slice's geometry and window (for the overlays of `annotate.rs`).
    pub spec: SliceSpec,
}

impl Slice {
    /// World position of a pixel centre.
    pub fn world(&self, col: f64, row: f64) -> DVec3 {
        let (u, v) = self.plane.axes();
        self.corner + u * (col * self.pixel_mm) + v * (row * self.pixel_mm)
    }

    /// Pixel (col, row) of a world point projected onto the slice.
    pub fn pixel(&self, world: DVec3) -> (f64, f64) {
        let (u, v) = self.plane.axes();
        let d = world - self.corner;
        (d.dot(u) / self.pixel_mm, d.dot(v) / self.pixel_mm)
    }
}

/// A slice description that cannot be drawn.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MprError {
    #[error("slice size {width} × {height} pixels must be 1 … {max} on each side")]
    Size { width: usize, height: usize, max: usize },
    #[error("pixel size {0} mm must be finite and positive")]
    PixelSize(f64),
    #[error("slice directions must be finite, unit and perpendicular (right {right:?}, down {down:?})")]
    Axes { right: DVec3, down: DVec3 },
    #[error("slice centre {0:?} is not finite")]
    Center(DVec3),
    #[error("needle tangent {0:?} is not a direction")]
    Tangent(DVec3),
}

/// The geometry and window of one MPR image: pixel (col, row)'s centre lies at
/// center + right·(col − (w − 1)/2)·pixel_mm + down·(row − (h − 1)/2)·pixel_mm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SliceSpec {
    /// World position of the image centre (mm).
    pub center_mm: DVec3,
    /// Unit world direction of the image's +column axis.
    pub right: DVec3,
    /// Unit world direction of the image's +row axis (perpendicular to `right`).
    pub down: DVec3,
    pub pixel_mm: f64,
    pub width: usize,
    pub height: usize,
    pub window: Window,
}

/// Largest MPR side (pixels).
pub const MAX_SLICE_PX: usize = 8192;

/// Pixel (col, row) samples the CT at continuous index origin + col·col_step + row·row_step
/// (`f32`, the CT grid's index space): what both renderers compute per pixel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IndexFrame {
    pub origin: Vec3,
    pub col_step: Vec3,
    pub row_step: Vec3,
}

/// Orientation letter of a world direction (RAS: +x right, +y anterior, +z superior) by its
/// largest component.
fn letter(d: DVec3) -> &'static str {
    let a = d.abs();
    if a.x >= a.y && a.x >= a.z {
        if d.x > 0.0 { "R" } else { "L" }
    } else if a.y >= a.z {
        if d.y > 0.0 { "A" } else { "P" }
    } else if d.z > 0.0 {
        "S"
    } else {
        "I"
    }
}

impl SliceSpec {
    /// The geometry [`render_slice`] draws: `plane` through `center`, covering the atlas' extent
    /// with `max_px` pixels along the longer side.
    pub fn plane(atlas: &PunctureAtlas, plane: Plane, center: DVec3, window: Window, max_px: usize) -> SliceSpec {
        let (corner, pixel_mm, width, height) = plane_layout(atlas, plane, center, max_px);
        let (u, v) = plane.axes();
        SliceSpec {
            center_mm: corner
                + u * (pixel_mm * (width as f64 - 1.0) * 0.5)
                + v * (pixel_mm * (height as f64 - 1.0) * 0.5),
            right: u,
            down: v,
            pixel_mm,
            width,
            height,
            window,
        }
    }

    /// The oblique plane along the needle: through the tip, spanned by the tip tangent and the
    /// direction closest to inferior, centred on the tip. Superior is up (down = −z) and the
    /// horizontal part of the tangent runs along the rows, pointing to the patient's left when it
    /// is mostly left–right (as in coronal views) or posterior when mostly anterior–posterior (as
    /// in sagittal views). When the needle is within about 6° of vertical (horizontal part under
    /// 0.1) the plane is spanned by the tangent and posterior instead: down = the tangent's
    /// inferior sense, right = posterior. Either way the plane contains the tip tangent.
    pub fn oblique_along_needle(
        tip: DVec3,
        tangent: DVec3,
        pixel_mm: f64,
        width: usize,
        height: usize,
        window: Window,
    ) -> Result<SliceSpec, MprError> {
        let t = tangent.normalize_or_zero();
        if t == DVec3::ZERO || !t.is_finite() {
            return Err(MprError::Tangent(tangent));
        }
        let horizontal = DVec3::new(t.x, t.y, 0.0);
        let (right, down) = if horizontal.length() >= 0.1 {
            let mut right = horizontal.normalize();
            let flip = if right.x.abs() >= right.y.abs() {
                right.x > 0.0
            } else {
                right.y > 0.0
            };
            if flip {
                right = -right;
            }
            (right, DVec3::NEG_Z)
        } else {
            let down = if t.z <= 0.0 { t } else { -t };
            let right = (DVec3::NEG_Y - down * DVec3::NEG_Y.dot(down)).normalize();
            (right, down)
        };
        let spec = SliceSpec {
            center_mm: tip,
            right,
            down,
            pixel_mm,
            width,
            height,
            window,
        };
        spec.validate()?;
        Ok(spec)
    }

    /// Checks sizes, pixel size and axes.
    pub fn validate(&self) -> Result<(), MprError> {
        if !(1..=MAX_SLICE_PX).contains(&self.width) || !(1..=MAX_SLICE_PX).contains(&self.height) {
            return Err(MprError::Size {
                width: self.width,
                height: self.height,
                max: MAX_SLICE_PX,
            });
        }
        if !(self.pixel_mm.is_finite() && self.pixel_mm > 0.0) {
            return Err(MprError::PixelSize(self.pixel_mm));
        }
        if !self.center_mm.is_finite() {
            return Err(MprError::Center(self.center_mm));
        }
        let unit = |d: DVec3| d.is_finite() && (d.length() - 1.0).abs() < 1e-6;
        if !(unit(self.right) && unit(self.down) && self.right.dot(self.down).abs() < 1e-6) {
            return Err(MprError::Axes {
                right: self.right,
                down: self.down,
            });
        }
        Ok(())
    }

    /// World position of pixel (0, 0)'s centre.
    pub fn corner(&self) -> DVec3 {
        self.center_mm
            - self.right * (self.pixel_mm * (self.width as f64 - 1.0) * 0.5)
            - self.down * (self.pixel_mm * (self.height as f64 - 1.0) * 0.5)
    }

    /// World position of a pixel centre.
    pub fn world(&self, col: f64, row: f64) -> DVec3 {
        self.corner() + self.right * (col * self.pixel_mm) + self.down * (row * self.pixel_mm)
    }

    /// Pixel (col, row) of a world point projected onto the slice.
    pub fn pixel(&self, world: DVec3) -> (f64, f64) {
        let d = world - self.corner();
        (d.dot(self.right) / self.pixel_mm, d.dot(self.down) / self.pixel_mm)
    }

    /// Unit normal right × down (toward the viewer for the standard planes' right-handedness).
    pub fn normal(&self) -> DVec3 {
        self.right.cross(self.down)
    }

    /// Signed distance (mm) of a world point from the slice plane.
    pub fn distance_mm(&self, world: DVec3) -> f64 {
        (world - self.center_mm).dot(self.normal())
    }

    /// Orientation letters at the image's left, right, top and bottom edges (the dominant RAS
    /// axis of −right, right, −down, down): [`Plane::edge_letters`] for the standard planes.
    pub fn edge_letters(&self) -> [&'static str; 4] {
        [
            letter(-self.right),
            letter(self.right),
            letter(-self.down),
            letter(self.down),
        ]
    }

    /// The `f32` index-space frame of the CT grid: computed in `f64`, then rounded.
    pub fn index_frame(&self, grid: &Grid) -> IndexFrame {
        let c0 = self.corner();
        let i0 = grid.world_to_index(c0);
        let iu = grid.world_to_index(c0 + self.right * self.pixel_mm) - i0;
        let iv = grid.world_to_index(c0 + self.down * self.pixel_mm) - i0;
        IndexFrame {
            origin: i0.as_vec3(),
            col_step: iu.as_vec3(),
            row_step: iv.as_vec3(),
        }
    }
}

/// An MPR image: RGB pixels (window grey with the label overlay) and each pixel's partial label.
#[derive(Debug, Clone, PartialEq)]
pub struct MprImage {
    pub spec: SliceSpec,
    pub rgb: Vec<[u8; 3]>,
    pub labels: Vec<LabelId>,
}

impl MprImage {
    /// The pixels as an opaque RGBA image (for annotation and PNG output).
    pub fn to_image(&self) -> crate::image::Image {
        crate::image::Image {
            width: self.spec.width as u32,
            height: self.spec.height as u32,
            rgba: self.rgb.iter().map(|p| [p[0], p[1], p[2], 255]).collect(),
        }
    }
}

/// Corner (pixel (0, 0)'s centre), pixel size and size of a standard plane covering the atlas.
fn plane_layout(atlas: &PunctureAtlas, plane: Plane, center: DVec3, max_px: usize) -> (DVec3, f64, usize, usize) {
    let grid = atlas.ct().grid();
    let (lo, hi) = grid.world_bounds();
    let s = grid.spacing_mm();
    let (lo, hi) = (lo - DVec3::from_array(s) * 0.5, hi + DVec3::from_array(s) * 0.5);
    let (u, v) = plane.axes();
    let extent = |axis: DVec3| (hi - lo).dot(axis.abs());
    let (eu, ev) = (extent(u), extent(v));
    // Fill `max_px` along the longer side (upsampling with trilinear interpolation when needed).
    let pixel_mm = eu.max(ev) / max_px.clamp(1, MAX_SLICE_PX) as f64;
    let width = ((eu / pixel_mm).round().max(1.0) as usize).min(MAX_SLICE_PX);
    let height = ((ev / pixel_mm).round().max(1.0) as usize).min(MAX_SLICE_PX);
    // Pixel (0, 0) sits at the volume's corner where u and v are smallest along their directions.
    let start = |axis: DVec3, lo_c: f64, hi_c: f64| {
        if axis.dot(DVec3::ONE) < 0.0 { hi_c } else { lo_c }
    };
    let mut corner = center;
    for a in 0..3 {
        let e = DVec3::AXES[a];
        if u.dot(e) != 0.0 {
            corner[a] = start(u, lo[a], hi[a]) + u[a] * pixel_mm * 0.5;
        }
        if v.dot(e) != 0.0 {
            corner[a] = start(v, lo[a], hi[a]) + v[a] * pixel_mm * 0.5;
        }
    }
    (corner, pixel_mm, width, height)
}

/// Renders one plane through `center`, covering the atlas' extent, with the partial labels
/// blended in their property-tree colours (boundaries drawn opaque so thin structures stay
/// visible).
pub fn render_slice(atlas: &PunctureAtlas, plane: Plane, center: DVec3, window: Window, max_px: usize) -> Slice {
    let (corner, pixel_mm, width, height) = plane_layout(atlas, plane, center, max_px);
    let spec = SliceSpec::plane(atlas, plane, center, window, max_px);
    let img = draw(atlas, &spec);
    Slice {
        plane,
        width,
        height,
        pixel_mm,
        rgb: img.rgb,
        labels: img.labels,
        center,
        corner,
        spec,
    }
}

/// Draws any slice (docs/rendering.md "MPR").
pub fn render_spec(atlas: &PunctureAtlas, spec: &SliceSpec) -> Result<MprImage, MprError> {
    spec.validate()?;
    Ok(draw(atlas, spec))
}

/// Trilinear CT value at a continuous index in `f32`: inside when −½ ≤ c_k < n_k − ½ on every
/// axis, clamped to [0, n_k − 1], else air (`Volume::sample_index` in `f32`).
#[inline]
pub fn sample_ct_f32(data: &[f32], dims: [usize; 3], c: Vec3) -> f32 {
    let mut base = [0usize; 3];
    let mut frac = [0.0f32; 3];
    for a in 0..3 {
        let n = dims[a] as f32;
        let x = c[a];
        if !(x >= -0.5 && x < n - 0.5) {
            return AIR_HU;
        }
        let x = x.clamp(0.0, n - 1.0);
        let b = (x as usize).min(dims[a].saturating_sub(2));
        base[a] = b;
        frac[a] = if dims[a] == 1 { 0.0 } else { x - b as f32 };
    }
    let step = |a: usize| usize::from(dims[a] > 1);
    let (i0, j0, k0) = (base[0], base[1], base[2]);
    let (i1, j1, k1) = (i0 + step(0), j0 + step(1), k0 + step(2));
    let v = |i: usize, j: usize, k: usize| data[(k * dims[1] + j) * dims[0] + i];
    let (fx, fy, fz) = (frac[0], frac[1], frac[2]);
    let c00 = v(i0, j0, k0) * (1.0 - fx) + v(i1, j0, k0) * fx;
    let c10 = v(i0, j1, k0) * (1.0 - fx) + v(i1, j1, k0) * fx;
    let c01 = v(i0, j0, k1) * (1.0 - fx) + v(i1, j0, k1) * fx;
    let c11 = v(i0, j1, k1) * (1.0 - fx) + v(i1, j1, k1) * fx;
    let c0 = c00 * (1.0 - fy) + c10 * fy;
    let c1 = c01 * (1.0 - fy) + c11 * fy;
    c0 * (1.0 - fz) + c1 * fz
}

/// Nearest voxel of a continuous index (floor(c + ½) inside −½ ≤ c < n − ½), as a linear index.
#[inline]
pub fn nearest_voxel_f32(dims: [usize; 3], c: Vec3) -> Option<usize> {
    let mut ijk = [0usize; 3];
    for a in 0..3 {
        let r = c[a] + 0.5;
        if !(r >= 0.0 && r < dims[a] as f32) {
            return None;
        }
        ijk[a] = r as usize;
    }
    Some((ijk[2] * dims[1] + ijk[1]) * dims[0] + ijk[0])
}

/// Window grey level in `f32`: round(clamp((v − (L − W/2))/W, 0, 1)·255).
#[inline]
pub fn window_gray_f32(window: &Window, hu: f32) -> u8 {
    let (level, width) = (window.level_hu as f32, window.width_hu as f32);
    let t = (hu - (level - width * 0.5)) / width;
    (t.clamp(0.0, 1.0) * 255.0).round() as u8
}

fn draw(atlas: &PunctureAtlas, spec: &SliceSpec) -> MprImage {
    let grid = atlas.ct().grid();
    let dims = grid.dims();
    let ct = atlas.ct().data();
    let partial = atlas.partial_labels().data();
    let frame = spec.index_frame(grid);
    let (w, h) = (spec.width, spec.height);
    let mut rgb = vec![[0u8; 3]; w * h];
    let mut labels: Vec<LabelId> = vec![0; w * h];
    rgb.par_chunks_mut(w)
        .zip(labels.par_chunks_mut(w))
        .enumerate()
        .for_each(|(row, (rgb_row, label_row))| {
            for col in 0..w {
                let c = frame.origin + frame.col_step * col as f32 + frame.row_step * row as f32;
                let g = window_gray_f32(&spec.window, sample_ct_f32(ct, dims, c));
                rgb_row[col] = [g, g, g];
                label_row[col] = nearest_voxel_f32(dims, c).map_or(0, |i| partial[i]);
            }
        });
    let mut img = MprImage {
        spec: *spec,
        rgb,
        labels,
    };
    overlay_labels(atlas, &mut img);
    img
}

/// Draws a slice of the deformed patient (thesis §5.4.1 "MPR inverts u per pixel"): inside the
/// deformation's lattice each pixel's world point x is mapped to the reference point X with
/// X + u(X) = x by the fixed point X⁺ = x − u(X), and the CT and the labels are read there, so the
/// labels move with the tissue; then the displacement colour map |u(X)| is blended on top of
/// tissue (CT at X above the atlas' air threshold; [`displacement_rgb`], up to
/// [`displacement_scale_mm`]).
pub fn render_spec_deformed(
    atlas: &PunctureAtlas,
    spec: &SliceSpec,
    field: &DeformField,
) -> Result<MprImage, MprError> {
    render_spec_moving(atlas, spec, None, Some(field))
}

/// Draws a slice of a breathing and possibly deformed patient: each pixel's world point x is first
/// mapped into the breathing patient's reference by [`motion::invert`] (8 fixed-point steps
/// X⁺ = x − u(X, t), thesis §5.4.1), then through the deformation's inverse as
/// [`render_spec_deformed`] does (the deformation lives in reference space), and the CT and the
/// labels are read there. Without breathing it is [`render_spec_deformed`], bit for bit.
pub fn render_spec_moving(
    atlas: &PunctureAtlas,
    spec: &SliceSpec,
    breathing: Option<&MotionHook>,
    field: Option<&DeformField>,
) -> Result<MprImage, MprError> {
    spec.validate()?;
    let grid = atlas.ct().grid();
    let dims = grid.dims();
    let ct = atlas.ct().data();
    let partial = atlas.partial_labels().data();
    let frame = spec.index_frame(grid);
    let bounds = field.map(|f| f.lattice().bounds());
    let air_hu = atlas.thresholds().air_skin_hu as f32;
    let (w, h) = (spec.width, spec.height);
    let mut rgb = vec![[0u8; 3]; w * h];
    let mut labels: Vec<LabelId> = vec![0; w * h];
    let mut moved_mm = vec![0.0f32; w * h];
    rgb.par_chunks_mut(w)
        .zip(labels.par_chunks_mut(w))
        .zip(moved_mm.par_chunks_mut(w))
        .enumerate()
        .for_each(|(row, ((rgb_row, label_row), moved_row))| {
            for col in 0..w {
                let x = spec.world(col as f64, row as f64);
                let x = match breathing {
                    Some(b) => motion::invert(b.model.as_ref(), x, b.t_s, INVERSE_ITERATIONS),
                    None => x,
                };
                let (c, moved) = match (field, bounds) {
                    (Some(field), Some((lo, hi))) if x.cmpge(lo).all() && x.cmple(hi).all() => {
                        let x_ref = field.to_reference(x, INVERSE_ITERATIONS);
                        (
                            grid.world_to_index(x_ref).as_vec3(),
                            field.displacement(x_ref).length() as f32,
                        )
                    }
                    _ if breathing.is_some() => (grid.world_to_index(x).as_vec3(), 0.0),
                    _ => (
                        frame.origin + frame.col_step * col as f32 + frame.row_step * row as f32,
                        0.0,
                    ),
                };
                let hu = sample_ct_f32(ct, dims, c);
                // Tissue only: air moving with the skin is not shown.
                moved_row[col] = if hu >= air_hu { moved } else { 0.0 };
                let g = window_gray_f32(&spec.window, hu);
                rgb_row[col] = [g, g, g];
                label_row[col] = nearest_voxel_f32(dims, c).map_or(0, |i| partial[i]);
            }
        });
    let mut img = MprImage {
        spec: *spec,
        rgb,
        labels,
    };
    overlay_labels(atlas, &mut img);
    let Some(field) = field else {
        return Ok(img);
    };
    let scale = displacement_scale_mm(field) as f32;
    img.rgb.par_iter_mut().zip(moved_mm.par_iter()).for_each(|(px, &m)| {
        if m < DISPLACEMENT_SHOWN_FROM_MM {
            return;
        }
        let c = displacement_rgb(m / scale);
        let alpha = 0.6 * ((m - DISPLACEMENT_SHOWN_FROM_MM) / DISPLACEMENT_SHOWN_FROM_MM).min(1.0);
        for ch in 0..3 {
            px[ch] = (px[ch] as f32 * (1.0 - alpha) + c[ch] as f32 * alpha).round() as u8;
        }
    });
    Ok(img)
}

/// Displacements below this are not coloured (mm).
pub const DISPLACEMENT_SHOWN_FROM_MM: f32 = 0.1;

/// The top of the displacement colour scale: the field's largest |u| rounded up to a whole mm
/// (at least 1 mm).
pub fn displacement_scale_mm(field: &DeformField) -> f64 {
    field.max_displacement_mm().ceil().max(1.0)
}

/// The displacement colour map at `t` = |u| / scale in 0 … 1: dark blue → cyan → yellow → red
/// (monotone in lightness up to yellow, so small and large displacements read apart in grey too).
pub fn displacement_rgb(t: f32) -> [u8; 3] {
    const STOPS: [(f32, [f32; 3]); 4] = [
        (0.0, [40.0, 40.0, 200.0]),
        (0.35, [0.0, 200.0, 230.0]),
        (0.7, [255.0, 230.0, 0.0]),
        (1.0, [230.0, 30.0, 20.0]),
    ];
    let t = t.clamp(0.0, 1.0);
    let i = STOPS
        .iter()
        .rposition(|(s, _)| *s <= t)
        .unwrap_or(0)
        .min(STOPS.len() - 2);
    let (t0, c0) = STOPS[i];
    let (t1, c1) = STOPS[i + 1];
    let f = (t - t0) / (t1 - t0);
    [0, 1, 2].map(|k| (c0[k] + (c1[k] - c0[k]) * f).round() as u8)
}

/// The label overlay: a labelled pixel is blended with its label's colour c (RGBA 0 … 255) at
/// α = 1 on the label's boundary (a 4-neighbour with another label, or the image edge), else
/// α = 0.6·c.a/255: round(grey·(1 − α) + c·α) in `f32`.
fn overlay_labels(atlas: &PunctureAtlas, img: &mut MprImage) {
    let (w, h) = (img.spec.width, img.spec.height);
    let table = atlas.label_table();
    let labels = &img.labels;
    img.rgb.par_chunks_mut(w).enumerate().for_each(|(row, rgb_row)| {
        for col in 0..w {
            let l = labels[row * w + col];
            if l == 0 {
                continue;
            }
            let Some(pos) = table.position(l) else {
                continue;
            };
            let c = atlas.materials().color(pos);
            let edge = [(0i64, 1i64), (1, 0), (0, -1), (-1, 0)].iter().any(|&(dc, dr)| {
                let (cc, rr) = (col as i64 + dc, row as i64 + dr);
                cc < 0 || rr < 0 || cc >= w as i64 || rr >= h as i64 || labels[rr as usize * w + cc as usize] != l
            });
            let alpha = if edge { 1.0f32 } else { c[3] as f32 / 255.0 * 0.6 };
            let px = &mut rgb_row[col];
            for ch in 0..3 {
                px[ch] = (px[ch] as f32 * (1.0 - alpha) + c[ch] as f32 * alpha).round() as u8;
            }
        }
    });
}
