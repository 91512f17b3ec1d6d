//! The simulated X-ray on the GPU (`shaders/xray.wgsl`): the same per-ray loop as
//! `stylet_render::xray` (Joseph's line integral through the CT and the contrast overlay, the
//! instruments' chords: the needle, guide wire, dilator, catheter), one invocation per detector pixel. Returns the attenuation a per
//! pixel; the window is applied on the CPU (`Radiograph::to_image`), as for the CPU image.
//! A breathing moment ([`GpuXray::render_moving`]) reads each plane's sample at its reference
//! point, as `xray::render_moving` does.

use bytemuck::{Pod, Zeroable};
use stylet_render::scene::MotionHook;
use stylet_render::volume::IndexMap;
use stylet_render::xray::attenuation::MU_WATER_PER_MM;
use stylet_render::xray::{MAX_SIDE_PX, Radiograph, XrayScene, check_instruments, check_scene_fits, segments};

use crate::motion::GpuMotion;
use crate::pipeline::{Pipelines, dispatch, numbered, uniform_buffer, v4};
use crate::raycast::ct_prelude;
use crate::volume::{GpuVolume, storage};
use crate::{GpuContext, GpuError};

/// The shader after the shared breathing motion.
const SHADER: &str = concat!(
    include_str!("../shaders/motion.wgsl"),
    include_str!("../shaders/xray.wgsl")
);

/// Mirrors `Params` in xray.wgsl (16-byte members).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct XrayParams {
    source: [f32; 4],
    pixel00: [f32; 4],
    col_step: [f32; 4],
    row_step: [f32; 4],
    row0: [f32; 4],
    row1: [f32; 4],
    row2: [f32; 4],
    origin: [f32; 4],
    dims: [u32; 4],
    size: [u32; 4],
    c_origin: [f32; 4],
    c_dims: [u32; 4],
    consts: [f32; 4],
}

/// The X-ray pipeline (one per CT storage format, built on first use).
pub struct GpuXray {
    pipelines: Pipelines,
    params: wgpu::Buffer,
    motion: GpuMotion,
}

impl GpuXray {
    pub fn new(ctx: &GpuContext) -> GpuXray {
        let params = uniform_buffer(ctx, "xray params", std::mem::size_of::<XrayParams>());
        GpuXray {
            pipelines: Pipelines::new("xray.wgsl", SHADER),
            params,
            motion: GpuMotion::new(ctx),
        }
    }

    /// The radiograph of `scene` at `width` × `height` detector pixels.
    pub fn render(
        &mut self,
        ctx: &GpuContext,
        vol: &GpuVolume,
        scene: &XrayScene,
        width: u32,
        height: u32,
    ) -> Result<Radiograph, GpuError> {
        self.render_moving(ctx, vol, scene, None, width, height)
    }

    /// The radiograph of a breathing patient (`breathing`; `None`: [`Self::render`]).
    pub fn render_moving(
        &mut self,
        ctx: &GpuContext,
        vol: &GpuVolume,
        scene: &XrayScene,
        breathing: Option<&MotionHook>,
        width: u32,
        height: u32,
    ) -> Result<Radiograph, GpuError> {
        if !(1..=MAX_SIDE_PX).contains(&width) || !(1..=MAX_SIDE_PX).contains(&height) {
            return Err(GpuError::Invalid(format!(
                "X-ray image {width} × {height}: each side must be 1 … {MAX_SIDE_PX} pixels"
            )));
        }
        scene.c_arm.validate().map_err(|e| GpuError::Invalid(e.to_string()))?;
        check_instruments(scene).map_err(|e| GpuError::Invalid(e.to_string()))?;
        // Two words per segment: (a, r'), (b, μ').
        let segment_words: Vec<[f32; 4]> = segments(scene, width, height)
            .iter()
            .flat_map(|s| [v4(s.a, s.radius_mm), v4(s.b, s.mu_per_mm)])
            .collect();
        let segment_count = segment_words.len() / 2;
        let grid = vol.atlas.ct().grid();
        check_scene_fits(scene, grid).map_err(|e| GpuError::Invalid(e.to_string()))?;
        let map = IndexMap::of(grid);
        let dims = map.dims;
        let (c_origin, c_dims, c_values) = match &scene.contrast {
            Some(c) => {
                ctx.check_storage_buffer("the contrast overlay", c.mu_per_mm.len() as u64 * 4)?;
                (c.origin.map(|v| v as f32), c.dims, c.mu_per_mm.as_slice())
            }
            None => ([0.0; 3], [1, 1, 1], &[0.0f32][..]),
        };
        let out_bytes = width as u64 * height as u64 * 4;
        ctx.check_storage_buffer("the X-ray image", out_bytes)?;
        let proj = scene.c_arm.projection(width, height);
        let params = XrayParams {
            source: v4(proj.source_mm, 0.0),
            pixel00: v4(proj.pixel00_mm, 0.0),
            col_step: v4(proj.col_mm, 0.0),
            row_step: v4(proj.row_mm, 0.0),
            row0: v4(map.rows[0], 0.0),
            row1: v4(map.rows[1], 0.0),
            row2: v4(map.rows[2], 0.0),
            origin: v4(map.origin, 0.0),
            dims: [dims[0], dims[1], dims[2], 0],
            size: [width, height, segment_count as u32, scene.contrast.is_some() as u32],
            c_origin: [c_origin[0], c_origin[1], c_origin[2], 0.0],
            c_dims: [c_dims[0], c_dims[1], c_dims[2], 0],
            consts: [MU_WATER_PER_MM / 1000.0, 0.0, 0.0, 0.0],
        };
        self.motion.prepare(ctx, breathing)?;
        ctx.queue.write_buffer(&self.params, 0, bytemuck::bytes_of(&params));
        let contrast = storage(ctx, "contrast overlay", bytemuck::cast_slice(c_values));
        let segment_words = if segment_words.is_empty() {
            vec![[0.0; 4]]
        } else {
            segment_words
        };
        let instruments = storage(ctx, "instrument segments", bytemuck::cast_slice(&segment_words));
        let output = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("xray image"),
            size: out_bytes,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let pipeline = self.pipelines.get(ctx, ct_prelude(vol.ct_key()));
        let mut entries = numbered([
            self.params.as_entire_binding(),
            vol.ct_binding(),
            contrast.as_entire_binding(),
            instruments.as_entire_binding(),
            output.as_entire_binding(),
        ]);
        entries.extend(self.motion.entries());
        dispatch(ctx, &pipeline, &entries, (width.div_ceil(8), height.div_ceil(8)), None);
        let bytes = ctx.read_buffer(&output, out_bytes)?;
        Ok(Radiograph {
            width,
            height,
            attenuation: GpuContext::values(&bytes),
        })
    }
}
