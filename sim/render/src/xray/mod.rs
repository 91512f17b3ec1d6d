//! Simulated X-ray with contrast agent (thesis §3.3; docs/xray.md): a digitally reconstructed
//! radiograph through the CT, the contrast medium and the needle, in the cone-beam geometry of
//! a C-arm. Beer–Lambert: I/I₀ = e^{−a} with a = ∫ (μ_tissue + μ_c) dl + μ_steel·(chord through
//! the needle). The CPU reference here, rayon over rows (every pixel a pure function of the
//! inputs: bit-identical on any number of threads); `stylet-render-gpu` runs the same per-ray
//! loop in `xray.wgsl`.
//!
//! Modules: [`c_arm`] (geometry), [`attenuation`] (μ of tissue, iodine, steel; the contrast
//! overlay), [`joseph`] (the line integral through a grid), [`needle`] (the chord through a
//! shaft segment), [`display`] (the windowed log image).

pub mod attenuation;
pub mod c_arm;
pub mod display;
pub mod joseph;
pub mod needle;

use rayon::prelude::*;
use stylet_physics::PunctureAtlas;
use stylet_physics::glam::Vec3;

pub use attenuation::ContrastOverlay;
pub use c_arm::{CArm, Projection};
pub use display::{Radiograph, XrayWindow};

use crate::RenderError;
use crate::tools::NeedleShape;
use crate::volume::IndexMap;
use attenuation::{MU_STEEL_PER_MM, MU_WATER_PER_MM, water_relative};
use joseph::{IndexRay, integrate};

/// The largest detector image side (pixels).
pub const MAX_SIDE_PX: u32 = 4096;

/// Everything one radiograph depends on besides the CT.
#[derive(Debug, Clone, PartialEq)]
pub struct XrayScene {
    pub c_arm: CArm,
    /// The needle's shaft (its hub is plastic and left out).
    pub needle: Option<NeedleShape>,
    pub contrast: Option<ContrastOverlay>,
}

/// One ray of the radiograph: from the source to the centre of a detector pixel, in world
/// space (unit direction) and in the CT's index space.
#[derive(Debug, Clone, Copy)]
struct Ray {
    origin_mm: Vec3,
    dir: Vec3,
    length_mm: f32,
    index: IndexRay,
}

/// Renders the radiograph of `atlas`'s CT at `width` × `height` detector pixels.
pub fn render(atlas: &PunctureAtlas, scene: &XrayScene, width: u32, height: u32) -> Result<Radiograph, RenderError> {
    if !(1..=MAX_SIDE_PX).contains(&width) || !(1..=MAX_SIDE_PX).contains(&height) {
        return Err(RenderError::Invalid(format!(
            "X-ray image {width} × {height}: each side must be 1 … {MAX_SIDE_PX} pixels"
        )));
    }
    scene.c_arm.validate().map_err(RenderError::Invalid)?;
    if let Some(n) = &scene.needle
        && !(n.diameter_mm.is_finite() && n.diameter_mm > 0.0 && n.nodes_mm.iter().all(|p| p.is_finite()))
    {
        return Err(RenderError::Invalid(
            "the needle's nodes and diameter must be finite".into(),
        ));
    }
    let ct = atlas.ct();
    let map = IndexMap::of(ct.grid());
    let data = ct.data();
    let proj = scene.c_arm.projection(width, height);
    let mut attenuation = vec![0.0f32; width as usize * height as usize];
    attenuation
        .par_chunks_mut(width as usize)
        .enumerate()
        .for_each(|(row, out)| {
            for (col, a) in out.iter_mut().enumerate() {
                let ray = ray(&proj, &map, col as u32, row as u32);
                *a = line_integral(&ray, map.dims, data, scene);
            }
        });
    Ok(Radiograph {
        width,
        height,
        attenuation,
    })
}

fn ray(proj: &Projection, map: &IndexMap, col: u32, row: u32) -> Ray {
    let to = proj.pixel_mm(col, row) - proj.source_mm;
    let length_mm = to.length();
    let dir = to / length_mm;
    Ray {
        origin_mm: proj.source_mm,
        dir,
        length_mm,
        index: IndexRay {
            start: map.point(proj.source_mm),
            dir: map.vector(dir),
            t_max_mm: length_mm,
        },
    }
}

/// a of one ray: tissue, then contrast, then the needle's segments.
fn line_integral(ray: &Ray, dims: [u32; 3], ct: &[f32], scene: &XrayScene) -> f32 {
    let tissue = integrate(dims, &ray.index, |i| water_relative(ct[i]));
    let mut a = MU_WATER_PER_MM / 1000.0 * tissue;
    if let Some(c) = &scene.contrast {
        let o = Vec3::new(c.origin[0] as f32, c.origin[1] as f32, c.origin[2] as f32);
        let local = IndexRay {
            start: ray.index.start - o,
            ..ray.index
        };
        a += integrate(c.dims, &local, |i| c.mu_per_mm[i]);
    }
    if let Some(n) = &scene.needle {
        let r = 0.5 * n.diameter_mm;
        for w in n.nodes_mm.windows(2) {
            a += MU_STEEL_PER_MM * needle::chord_mm(ray.origin_mm, ray.dir, ray.length_mm, w[0], w[1], r);
        }
    }
    a
}
