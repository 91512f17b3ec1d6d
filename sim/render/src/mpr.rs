//! Multi-planar reformation on the CPU: axial, coronal and sagittal slices through a world point,
//! resampled to square display pixels, in radiological display convention (patient's right on
//! the image's left; anterior up in axial views, superior up in coronal and sagittal views,
//! anterior on the left in sagittal views).

use stylet_physics::glam::DVec3;
use stylet_physics::{AIR_HU, LabelId, PunctureAtlas};

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

/// Renders one plane through `center`, covering the atlas' extent, with the partial labels
/// blended in their property-tree colours (boundaries drawn opaque so thin structures stay
/// visible).
pub fn render_slice(atlas: &PunctureAtlas, plane: Plane, center: DVec3, window: Window, max_px: usize) -> Slice {
    let grid = atlas.ct().grid();
    let (lo, hi) = grid.world_bounds();
    let s = grid.spacing_mm();
    let (lo, hi) = (lo - DVec3::from_array(s) * 0.5, hi + DVec3::from_array(s) * 0.5);
    let (u, v) = plane.axes();
    let extent = |axis: DVec3| (hi - lo).dot(axis.abs());
    let (eu, ev) = (extent(u), extent(v));
    // Fill `max_px` along the longer side (upsampling with trilinear interpolation when needed).
    let pixel_mm = eu.max(ev) / max_px as f64;
    let width = (eu / pixel_mm).round().max(1.0) as usize;
    let height = (ev / pixel_mm).round().max(1.0) as usize;
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
    let mut slice = Slice {
        plane,
        width,
        height,
        pixel_mm,
        rgb: vec![[0; 3]; width * height],
        labels: vec![0; width * height],
        center,
        corner,
    };
    for row in 0..height {
        for col in 0..width {
            let p = slice.world(col as f64, row as f64);
            let hu = atlas.ct().sample(p, AIR_HU) as f64;
            let g = window.gray(hu);
            slice.rgb[row * width + col] = [g, g, g];
            slice.labels[row * width + col] = atlas.partial_label_at(p);
        }
    }
    overlay_labels(atlas, &mut slice);
    slice
}

fn overlay_labels(atlas: &PunctureAtlas, slice: &mut Slice) {
    let (w, h) = (slice.width, slice.height);
    let table = atlas.label_table();
    let labels = slice.labels.clone();
    for row in 0..h {
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
            let alpha = if edge { 1.0 } else { c[3] as f64 / 255.0 * 0.6 };
            let px = &mut slice.rgb[row * w + col];
            for ch in 0..3 {
                px[ch] = (px[ch] as f64 * (1.0 - alpha) + c[ch] as f64 * alpha).round() as u8;
            }
        }
    }
}
