//! The CPU reference ray caster (thesis §3.2.1–3.2.3; docs/rendering.md "One ray"): front-to-back
//! emission–absorption with ray/box clipping, empty-space leaping, early termination, jitter,
//! Phong shading, the clipping plane and its tagging. Rayon over 16 × 16 pixel tiles; every pixel is a pure
//! function of the inputs, so the image is bit-identical on any number of threads.

pub mod appearance;
pub mod avx2;
pub mod batch;
pub mod brick_distance;
pub mod cell;
pub mod cube_mask;
pub mod gradient_volume;
pub mod jitter;
pub mod kernel;
pub mod march;
pub mod occupancy;
pub mod placer;
pub mod sampler;
pub mod shading;
pub mod window;

use rayon::prelude::*;

use crate::image::Image;
use crate::scene::{ImageRays, Scene};
use crate::transfer_table::TransferTable;
use crate::volume::{IndexMap, RenderVolume};
use avx2::Avx2;
use march::{Frame, farthest_corner_mm, march, march_pair};
use occupancy::Occupancy;
use sampler::{Grid3, Sampler};

/// A rendered frame and the work it took.
#[derive(Debug, Clone, PartialEq)]
pub struct RenderOutput {
    pub image: Image,
    /// Volume samples actually taken (lattice and plane samples; not the gradient's): what
    /// ray/box clipping, leaping and early termination reduce.
    pub samples: u64,
}

/// Renders `scene` at `width` × `height` (half resolution: ⌈w/2⌉ × ⌈h/2⌉, upscaled).
pub fn render(volume: &RenderVolume, scene: &Scene, width: u32, height: u32) -> RenderOutput {
    render_with(volume, scene, width, height, Lanes::Auto)
}

/// [`render`] with a choice of sample evaluation: [`Lanes::OneAtATime`] is the reference the SIMD
/// lanes are tested against (the same pixels, bit for bit).
pub fn render_with(volume: &RenderVolume, scene: &Scene, width: u32, height: u32, lanes: Lanes) -> RenderOutput {
    if width == 0 || height == 0 {
        return RenderOutput {
            image: Image::new(width, height),
            samples: 0,
        };
    }
    if scene.quality.half_resolution {
        let (w, h) = (width.div_ceil(2), height.div_ceil(2));
        let out = render_full(volume, scene, w, h, lanes);
        return RenderOutput {
            image: out.image.upscale(width, height),
            samples: out.samples,
        };
    }
    render_full(volume, scene, width, height, lanes)
}

/// Which evaluation the ray caster may use.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Lanes {
    /// SIMD lanes where the CPU and the records allow, and the rays of two pixels marched in
    /// turn (the same pixels, faster).
    Auto,
    /// One sample at a time, one ray after the other: the reference the lanes are tested
    /// against.
    OneAtATime,
    /// The rays of two pixels marched in turn, one sample at a time: what [`Lanes::Auto`] runs
    /// on a CPU without AVX2, here on any CPU, so that path is tested where AVX2 is present.
    PairsWithoutSimd,
}

impl Lanes {
    /// Whether pixels' rays are marched two by two ([`Lanes::Auto`],
    /// [`Lanes::PairsWithoutSimd`]).
    pub fn pairs(self) -> bool {
        self != Lanes::OneAtATime
    }
}

/// Side of the square pixel tiles rendered as one task (pixels).
const TILE: u32 = 16;

/// Shortest step the ray caster takes (mm): bounds the samples per ray.
pub const MIN_STEP_MM: f32 = 0.01;

/// The step actually used: `step_mm` clamped to [`MIN_STEP_MM`], 1 mm when it is not a
/// positive finite number (a bad step must not hang or overflow the march).
pub fn usable_step_mm(step_mm: f32) -> f32 {
    if step_mm.is_finite() && step_mm > 0.0 {
        step_mm.max(MIN_STEP_MM)
    } else {
        1.0
    }
}

/// The pixels of columns `cols[0]` … `cols[1]` − 1 and rows `rows[0]` … `rows[1]` − 1, row by
/// row, and the samples they took. With the SIMD lanes the whole tile (rays, their set-up and
/// march) is compiled for AVX2, so that rounding and ⌈·⌉ are instructions rather than libm
/// calls and the lanes' kernels are inlined into the march; the numbers are the same (the
/// lanes' tests compare the images).
fn draw_tile(frame: &Frame, rays: &ImageRays, cols: [u32; 2], rows: [u32; 2]) -> (Vec<[u8; 4]>, u64) {
    #[cfg(target_arch = "x86_64")]
    if frame.avx2.is_some() {
        #[target_feature(enable = "avx2")]
        fn compiled_for_avx2(frame: &Frame, rays: &ImageRays, cols: [u32; 2], rows: [u32; 2]) -> (Vec<[u8; 4]>, u64) {
            each_pixel(frame, rays, cols, rows)
        }
        // SAFETY: an `Avx2` exists only when the CPU has AVX2 (`Avx2::detect`).
        return unsafe { compiled_for_avx2(frame, rays, cols, rows) };
    }
    each_pixel(frame, rays, cols, rows)
}

/// [`draw_tile`]'s loop: pixels two by two (their marches interleaved) when `frame.pairs`, the
/// last alone in an odd row. Always inlined, so that the AVX2 build of a tile compiles it whole
/// for AVX2.
#[inline(always)]
fn each_pixel(frame: &Frame, rays: &ImageRays, cols: [u32; 2], rows: [u32; 2]) -> (Vec<[u8; 4]>, u64) {
    let mut px = Vec::with_capacity(((cols[1] - cols[0]) * (rows[1] - rows[0])) as usize);
    let mut n = 0u64;
    for row in rows[0]..rows[1] {
        let mut col = cols[0];
        while frame.pairs && col + 1 < cols[1] {
            let (oa, da) = rays.ray(col, row);
            let (ob, db) = rays.ray(col + 1, row);
            for (rgba, s) in march_pair(frame, (col, row, oa, da), (col + 1, row, ob, db)) {
                px.push(rgba);
                n += s;
            }
            col += 2;
        }
        for col in col..cols[1] {
            let (origin, dir) = rays.ray(col, row);
            let (rgba, s) = march(frame, col, row, origin, dir);
            px.push(rgba);
            n += s;
        }
    }
    (px, n)
}

fn render_full(volume: &RenderVolume, scene: &Scene, width: u32, height: u32, lanes: Lanes) -> RenderOutput {
    let ct = volume.atlas.ct();
    let grid = *ct.grid();
    let ct_map = IndexMap::of(&grid);
    let grads = volume.gradient_volume();
    let deformed = scene.deformed.as_ref().map(|d| {
        (
            Grid3::new(d.volume.data(), IndexMap::of(d.volume.grid()).dims),
            IndexMap::of(d.volume.grid()),
        )
    });
    let sampler = Sampler::new(
        Grid3::new(ct.data(), ct_map.dims),
        ct_map,
        &grads,
        deformed,
        &volume.labels,
    );
    let mut quality = scene.quality;
    quality.step_mm = usable_step_mm(quality.step_mm);
    // With the breathing motion a world point x samples X = x − u(X, t), within |u| ≤ U of x:
    // the ray/box extent and the leaping cells are widened by U (index units per axis: U times
    // the length of the index map's row, which bounds |Δc_a| for any |Δx| ≤ U, oblique grids
    // included). An unbounded motion visits every sample.
    let (lo_hu, hi_hu) = volume.value_range_hu;
    let table = TransferTable::new(&scene.transfer, lo_hu, hi_hu, quality.step_mm);
    let motion_margin = scene.motion.as_ref().map(|m| {
        use stylet_physics::glam::Vec3;
        let u_mm = m.model.max_displacement_mm() as f32;
        let (ex, ey, ez) = (ct_map.vector(Vec3::X), ct_map.vector(Vec3::Y), ct_map.vector(Vec3::Z));
        let row = |a: usize| Vec3::new(ex[a], ey[a], ez[a]).length();
        Vec3::new(row(0), row(1), row(2)) * u_mm
    });
    let bounded = motion_margin.is_none_or(|m| m.is_finite());
    // The finest leaping level: per-cube skip bits, for the common frame (no hooks).
    let cubes = (quality.leaping && scene.motion.is_none() && scene.deformed.is_none() && sampler.ct.is_fast())
        .then(|| volume.cube_mask(&table));
    let mut frame = Frame {
        cubes,
        volume,
        sampler,
        transfer: &scene.transfer,
        light: scene.light,
        phong: shading::PhongTerms::new(&scene.light),
        clip: scene.clip,
        tagging: scene.tagging,
        quality,
        occupancy: None,
        sample_outside: scene.deformed.is_some() || table.lookup(stylet_physics::AIR_HU)[3] > 0.0,
        table,
        t_far: farthest_corner_mm(&grid, scene.camera.eye_mm),
        background: scene.background,
        motion: scene.motion.as_ref(),
        motion_at: scene.motion.as_ref().map(|m| m.model.at_time(m.t_s)),
        motion_margin: motion_margin.filter(|m| m.is_finite()),
        primitives: scene.tools.primitives(),
        shadows: crate::shadow::Shadows::from_tools(&scene.tools),
        has_shadows: scene.tools.needle.is_some() || scene.tools.finger.is_some() || scene.tools.probe.is_some(),
        avx2: Avx2::detect(lanes),
        pairs: lanes.pairs(),
    };
    // The cells of the general path, built only when some ray takes it (N³ look-ups a frame).
    if frame.quality.leaping && bounded && !frame.every_ray_on_bricks() {
        let ranges = volume.cell_ranges(quality.occupancy_cells);
        let occ = Occupancy::new(
            &ranges,
            &frame.table,
            ct_map.dims,
            scene.deformed.as_ref().map(|d| (&*d.volume, &ct_map)),
        );
        frame.occupancy = Some(match motion_margin {
            Some(m) => occ.dilated(m),
            None => occ,
        });
    }
    let mut image = Image::new(width, height);
    let rays = scene.camera.rays(width, height);
    // Square tiles: neighbouring rays read neighbouring voxels, so a tile's rays share cache
    // lines in both image directions (rows alone share them in one).
    let tiles_x = width.div_ceil(TILE);
    let tiles_y = height.div_ceil(TILE);
    let tiles: Vec<(Vec<[u8; 4]>, u64)> = (0..tiles_x * tiles_y)
        .into_par_iter()
        .map(|t| {
            let (x0, y0) = ((t % tiles_x) * TILE, (t / tiles_x) * TILE);
            let (x1, y1) = ((x0 + TILE).min(width), (y0 + TILE).min(height));
            draw_tile(&frame, &rays, [x0, x1], [y0, y1])
        })
        .collect();
    let mut samples = 0u64;
    for (t, (px, n)) in tiles.into_iter().enumerate() {
        let t = t as u32;
        let (x0, y0) = ((t % tiles_x) * TILE, (t / tiles_x) * TILE);
        let tw = ((x0 + TILE).min(width) - x0) as usize;
        // The tile's rows, each copied whole into the image's row.
        for (r, tile_row) in px.chunks_exact(tw).enumerate() {
            let start = ((y0 as usize + r) * width as usize) + x0 as usize;
            image.rgba[start..start + tw].copy_from_slice(tile_row);
        }
        samples += n;
    }
    RenderOutput { image, samples }
}
