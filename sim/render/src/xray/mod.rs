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
use stylet_physics::glam::{DVec3, Vec3};

pub use attenuation::ContrastOverlay;
pub use c_arm::{CArm, Projection};
pub use display::{Radiograph, XrayWindow};

use crate::RenderError;

/// A C-arm, window or scene neither X-ray renderer draws: what is out of range or does not fit
/// the CT.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum XrayError {
    #[error("C-arm isocenter {0:?} must be finite")]
    Isocenter(Vec3),
    /// A C-arm value outside what a C-arm can be set to (the scenario format's limits).
    #[error(transparent)]
    CArm(stylet_atlas::manifest::CArmError),
    #[error("X-ray window low {low} / high {high} must be finite with 0 ≤ low < high")]
    Window { low: f32, high: f32 },
    /// The contrast overlay lies outside the CT or does not hold one value per voxel of its box.
    #[error("the contrast overlay does not fit the CT")]
    ContrastOverlay,
    /// The isocentre is farther than the source-to-detector distance from the CT.
    #[error(
        "the C-arm's isocentre {isocenter_mm:?} mm is farther than the source-to-detector distance ({reach_mm} mm) from the CT"
    )]
    OutOfReach { isocenter_mm: Vec3, reach_mm: f64 },
}
use crate::scene::MotionHook;
use crate::tools::{LineShape, NeedleShape};
use crate::volume::IndexMap;
use attenuation::{MU_STEEL_PER_MM, MU_WATER_PER_MM, water_relative};
use joseph::{IndexRay, integrate, integrate_warped, trilinear_zero_outside};

/// The largest detector image side (pixels).
pub const MAX_SIDE_PX: u32 = 4096;

/// Everything one radiograph depends on besides the CT.
#[derive(Debug, Clone, PartialEq)]
pub struct XrayScene {
    pub c_arm: CArm,
    /// The needle's shaft (its hub is plastic and left out).
    pub needle: Option<NeedleShape>,
    /// The guide wire, dilator and catheter (radiopaque, [`attenuation::mu_of_line`]).
    pub lines: Vec<LineShape>,
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
    render_moving(atlas, scene, None, width, height)
}

/// [`render`] of a breathing patient (docs/breathing.md): with `breathing`, each ray's samples
/// read the CT and the contrast at the reference point X = x − u(X, t) of their world point x,
/// found by one fixed-point step per sample from the previous sample's X (eqs. 5.4.1–5.4.2, as
/// the ray caster warps its rays; [`joseph::integrate_warped`]). The needle is already in the
/// world. Without `breathing` it is [`render`], bit for bit.
pub fn render_moving(
    atlas: &PunctureAtlas,
    scene: &XrayScene,
    breathing: Option<&MotionHook>,
    width: u32,
    height: u32,
) -> Result<Radiograph, RenderError> {
    if !(1..=MAX_SIDE_PX).contains(&width) || !(1..=MAX_SIDE_PX).contains(&height) {
        return Err(RenderError::Invalid(format!(
            "X-ray image {width} × {height}: each side must be 1 … {MAX_SIDE_PX} pixels"
        )));
    }
    scene.c_arm.validate()?;
    check_instruments(scene)?;
    let ct = atlas.ct();
    check_scene_fits(scene, ct.grid())?;
    let map = IndexMap::of(ct.grid());
    let data = ct.data();
    let proj = scene.c_arm.projection(width, height);
    let segments = segments(scene, width, height);
    let u_at = breathing.map(|b| b.model.at_time(b.t_s));
    let warp = u_at.as_deref().map(|u| (u, &map));
    let mut attenuation = vec![0.0f32; width as usize * height as usize];
    attenuation
        .par_chunks_mut(width as usize)
        .enumerate()
        .for_each(|(row, out)| {
            for (col, a) in out.iter_mut().enumerate() {
                let ray = ray(&proj, &map, col as u32, row as u32);
                *a = line_integral(&ray, map.dims, data, scene.contrast.as_ref(), &segments, warp);
            }
        });
    Ok(Radiograph {
        width,
        height,
        attenuation,
    })
}

/// A straight piece of an instrument as the detector resolves it: from `a` to `b`, radius r' and
/// μ' ([`needle::resolved_radius_and_mu`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    pub a: Vec3,
    pub b: Vec3,
    pub radius_mm: f32,
    pub mu_per_mm: f32,
}

/// The most instrument segments a radiograph draws (the needle's and the lines').
pub const MAX_SEGMENTS: usize = 1024;

/// What both renderers check of the instruments: finite nodes and diameters, at most
/// [`MAX_SEGMENTS`] segments.
pub fn check_instruments(scene: &XrayScene) -> Result<(), RenderError> {
    let finite = |nodes: &[Vec3], d: f32| d.is_finite() && d > 0.0 && nodes.iter().all(|p| p.is_finite());
    if let Some(n) = &scene.needle
        && !finite(&n.nodes_mm, n.diameter_mm)
    {
        return Err(RenderError::Invalid(
            "the needle's nodes and diameter must be finite".into(),
        ));
    }
    if scene.lines.iter().any(|l| !finite(&l.nodes_mm, l.diameter_mm)) {
        return Err(RenderError::Invalid(
            "a guide wire's, dilator's or catheter's nodes and diameter must be finite".into(),
        ));
    }
    let count = scene.needle.as_ref().map_or(0, |n| n.nodes_mm.len().saturating_sub(1))
        + scene
            .lines
            .iter()
            .map(|l| l.nodes_mm.len().saturating_sub(1))
            .sum::<usize>();
    if count > MAX_SEGMENTS {
        return Err(RenderError::Invalid(format!(
            "{count} instrument segments (at most {MAX_SEGMENTS})"
        )));
    }
    Ok(())
}

/// The instruments' segments of a `width` × `height` radiograph: the needle's steel shaft, then
/// each line of its material.
pub fn segments(scene: &XrayScene, width: u32, height: u32) -> Vec<Segment> {
    let pixel_mm = scene.c_arm.pixel_at_isocenter_mm(width, height);
    let mut out = Vec::new();
    let mut add = |nodes: &[Vec3], diameter_mm: f32, mu: f32| {
        let (r, mu) = needle::resolved_radius_and_mu(diameter_mm, pixel_mm, mu);
        out.extend(nodes.windows(2).map(|w| Segment {
            a: w[0],
            b: w[1],
            radius_mm: r,
            mu_per_mm: mu,
        }));
    };
    if let Some(n) = &scene.needle {
        add(&n.nodes_mm, n.diameter_mm, MU_STEEL_PER_MM);
    }
    for l in &scene.lines {
        add(&l.nodes_mm, l.diameter_mm, attenuation::mu_of_line(l.kind));
    }
    out
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

/// What both renderers check before drawing: the contrast overlay lies inside the CT and holds
/// one value per voxel of its box, and the isocentre is within the source-to-detector distance of
/// the CT (farther, the patient would not be in the beam).
pub fn check_scene_fits(scene: &XrayScene, grid: &stylet_physics::Grid) -> Result<(), XrayError> {
    let dims = grid.dims();
    if let Some(c) = &scene.contrast {
        let inside = (0..3).all(|a| c.origin[a] as u64 + c.dims[a] as u64 <= dims[a] as u64);
        let n = c.dims.iter().map(|&d| d as u64).product::<u64>();
        if !inside || n != c.mu_per_mm.len() as u64 || n == 0 {
            return Err(XrayError::ContrastOverlay);
        }
    }
    let (lo, hi) = grid.world_bounds();
    let reach = scene.c_arm.source_to_detector_mm as f64;
    let iso = scene.c_arm.isocenter_mm.as_dvec3();
    if (iso - iso.clamp(lo, hi)).length() > reach {
        return Err(XrayError::OutOfReach {
            isocenter_mm: scene.c_arm.isocenter_mm,
            reach_mm: reach,
        });
    }
    Ok(())
}

/// u(·, t) of a breathing moment and the CT's index map (world → index of a reference point).
type Warp<'a> = (&'a (dyn Fn(DVec3) -> DVec3 + Send + Sync), &'a IndexMap);

/// a of one ray: tissue, then contrast, then the instruments' segments; with a warp, tissue and
/// contrast are read at each sample's reference point.
fn line_integral(
    ray: &Ray,
    dims: [u32; 3],
    ct: &[f32],
    contrast: Option<&ContrastOverlay>,
    segments: &[Segment],
    warp: Option<Warp>,
) -> f32 {
    let mut a = if let Some((u, map)) = warp {
        let mu_c = |c: Vec3| contrast.map_or(0.0, |o| o.mu_at_index(c));
        let mu =
            |c: Vec3| MU_WATER_PER_MM / 1000.0 * trilinear_zero_outside(dims, c, |i| water_relative(ct[i])) + mu_c(c);
        integrate_warped(&ray.index, ray.origin_mm, ray.dir, dims, u, map, mu)
    } else {
        let tissue = integrate(dims, &ray.index, |i| water_relative(ct[i]));
        let mut a = MU_WATER_PER_MM / 1000.0 * tissue;
        if let Some(c) = contrast {
            let o = Vec3::new(c.origin[0] as f32, c.origin[1] as f32, c.origin[2] as f32);
            let local = IndexRay {
                start: ray.index.start - o,
                ..ray.index
            };
            a += integrate(c.dims, &local, |i| c.mu_per_mm[i]);
        }
        a
    };
    for s in segments {
        a += s.mu_per_mm * needle::chord_mm(ray.origin_mm, ray.dir, ray.length_mm, s.a, s.b, s.radius_mm);
    }
    a
}
