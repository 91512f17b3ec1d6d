//! MPR on the GPU (`shaders/mpr.wgsl`): any slice a `stylet_render::mpr::SliceSpec` describes
//! (axial, coronal, sagittal, the oblique plane along the needle), drawn with the CPU's formulas
//! (`mpr::render_spec`: f32 index frame, trilinear CT, window, nearest partial label, overlay
//! opaque on label boundaries). The tip marker and the scale bar are drawn afterwards on the CPU
//! by the shared annotate module, so this returns the slice pixels only.
//!
//! A moment with tissue deformation ([`GpuMpr::render_deformed`]) is drawn as
//! `mpr::render_spec_deformed` draws it: each pixel inside the deformation's lattice reads the CT
//! and the labels at its reference point (the fixed point X⁺ = x − u(X), in `f32` here, `f64` on
//! the CPU) and gets the displacement colour map. A breathing moment
//! ([`GpuMpr::render_moving`]) first takes each pixel's world point to the breathing patient's
//! reference (`motion.wgsl`), as `mpr::render_spec_moving` does.

use bytemuck::{Pod, Zeroable};
use stylet_physics::deform::DeformField;
use stylet_physics::deform::resample::INVERSE_ITERATIONS;
use stylet_render::mpr::{DISPLACEMENT_SHOWN_FROM_MM, MprImage, SliceSpec, displacement_scale_mm};
use stylet_render::scene::MotionHook;
use stylet_render::volume::IndexMap;

use crate::motion::GpuMotion;
use crate::pipeline::{Pipelines, dispatch, numbered, uniform_buffer};
use crate::raycast::ct_prelude;
use crate::volume::GpuVolume;
use crate::{GpuContext, GpuError};

/// The shader after the shared CT sampler.
const SHADER: &str = concat!(
    include_str!("../shaders/motion.wgsl"),
    include_str!("../shaders/ct_sample.wgsl"),
    include_str!("../shaders/mpr.wgsl")
);

/// Mirrors `Params` in mpr.wgsl (16-byte members).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct MprParams {
    origin: [f32; 4],
    col_step: [f32; 4],
    row_step: [f32; 4],
    dims: [u32; 4],
    size: [u32; 4],
    window: [f32; 4],
    w_origin: [f32; 4],
    w_col: [f32; 4],
    w_row: [f32; 4],
    to_index_o: [f32; 4],
    to_index_x: [f32; 4],
    to_index_y: [f32; 4],
    to_index_z: [f32; 4],
    lattice: [f32; 4],
    lattice_n: [u32; 4],
    deform: [f32; 4],
}

/// The MPR pipeline (one per CT storage format, built on first use).
pub struct GpuMpr {
    pipelines: Pipelines,
    params: wgpu::Buffer,
    motion: GpuMotion,
}

impl GpuMpr {
    pub fn new(ctx: &GpuContext) -> GpuMpr {
        let params = uniform_buffer(ctx, "mpr params", std::mem::size_of::<MprParams>());
        GpuMpr {
            pipelines: Pipelines::new("mpr.wgsl", SHADER),
            params,
            motion: GpuMotion::new(ctx),
        }
    }

    /// Draws the slice `spec` of the volume (pixels and each pixel's partial label).
    pub fn render(&mut self, ctx: &GpuContext, vol: &GpuVolume, spec: &SliceSpec) -> Result<MprImage, GpuError> {
        self.draw(ctx, vol, spec, None, None)
    }

    /// Draws the slice `spec` of the patient deformed by `field`, with its displacement colour
    /// map (the legend is the caller's, as on the CPU).
    pub fn render_deformed(
        &mut self,
        ctx: &GpuContext,
        vol: &GpuVolume,
        spec: &SliceSpec,
        field: &DeformField,
    ) -> Result<MprImage, GpuError> {
        self.draw(ctx, vol, spec, Some(field), None)
    }

    /// Draws the slice `spec` of a breathing (and possibly deformed) patient, as
    /// `stylet_render::mpr::render_spec_moving` does: each pixel's world point taken to the
    /// reference by the inverse of the breathing motion, then through the deformation's.
    pub fn render_moving(
        &mut self,
        ctx: &GpuContext,
        vol: &GpuVolume,
        spec: &SliceSpec,
        breathing: Option<&MotionHook>,
        field: Option<&DeformField>,
    ) -> Result<MprImage, GpuError> {
        self.draw(ctx, vol, spec, field, breathing)
    }

    fn draw(
        &mut self,
        ctx: &GpuContext,
        vol: &GpuVolume,
        spec: &SliceSpec,
        field: Option<&DeformField>,
        breathing: Option<&MotionHook>,
    ) -> Result<MprImage, GpuError> {
        spec.validate().map_err(|e| GpuError::Invalid(format!("slice: {e}")))?;
        let (w, h) = (spec.width as u32, spec.height as u32);
        let out_bytes = w as u64 * h as u64 * 8;
        ctx.check_storage_buffer("the slice", out_bytes)?;
        let grid = vol.atlas.ct().grid();
        let frame = spec.index_frame(grid);
        let [nx, ny, nz] = grid.dims();
        let v4 = |v: stylet_physics::glam::Vec3| [v.x, v.y, v.z, 0.0];
        let w4 = |v: stylet_physics::glam::DVec3| v4(v.as_vec3());
        let map = IndexMap::of(grid);
        let unit = |a: usize| {
            let mut e = stylet_physics::glam::Vec3::ZERO;
            e[a] = 1.0;
            v4(map.vector(e))
        };
        // u at the nodes as 16-byte texels; one zero node when there is no deformation.
        let nodes: Vec<[f32; 4]> = match field {
            Some(f) => f
                .displacements()
                .iter()
                .map(|u| [u.x as f32, u.y as f32, u.z as f32, 0.0])
                .collect(),
            None => vec![[0.0; 4]],
        };
        let field_bytes: &[u8] = bytemuck::cast_slice(&nodes);
        ctx.check_storage_buffer("the deformation", field_bytes.len() as u64)?;
        let lattice = field.map(|f| *f.lattice());
        let params = MprParams {
            origin: v4(frame.origin),
            col_step: v4(frame.col_step),
            row_step: v4(frame.row_step),
            dims: [nx as u32, ny as u32, nz as u32, vol.mpr_color_count],
            size: [w, h, 0, 0],
            window: [spec.window.level_hu as f32, spec.window.width_hu as f32, 0.0, 0.0],
            w_origin: w4(spec.world(0.0, 0.0)),
            w_col: w4(spec.world(1.0, 0.0) - spec.world(0.0, 0.0)),
            w_row: w4(spec.world(0.0, 1.0) - spec.world(0.0, 0.0)),
            to_index_o: v4(map.point(stylet_physics::glam::Vec3::ZERO)),
            to_index_x: unit(0),
            to_index_y: unit(1),
            to_index_z: unit(2),
            lattice: lattice.map_or([0.0; 4], |l| {
                let o = l.origin_mm.as_vec3();
                [o.x, o.y, o.z, l.h_mm as f32]
            }),
            lattice_n: match lattice {
                Some(l) => [l.n as u32, 1, INVERSE_ITERATIONS, 0],
                None => [2, 0, INVERSE_ITERATIONS, 0],
            },
            deform: [
                field.map_or(1.0, |f| displacement_scale_mm(f) as f32),
                vol.atlas.thresholds().air_skin_hu as f32,
                DISPLACEMENT_SHOWN_FROM_MM,
                0.0,
            ],
        };
        self.motion.prepare(ctx, breathing)?;
        ctx.queue.write_buffer(&self.params, 0, bytemuck::bytes_of(&params));
        let output = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("mpr image"),
            size: out_bytes,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let field_buffer = wgpu::util::DeviceExt::create_buffer_init(
            &ctx.device,
            &wgpu::util::BufferInitDescriptor {
                label: Some("mpr deformation"),
                contents: field_bytes,
                usage: wgpu::BufferUsages::STORAGE,
            },
        );
        let pipeline = self.pipelines.get(ctx, ct_prelude(vol.ct_key()));
        let mut entries = numbered([
            self.params.as_entire_binding(),
            vol.ct_binding(),
            wgpu::BindingResource::TextureView(&vol.partial_view),
            vol.mpr_colors.as_entire_binding(),
            output.as_entire_binding(),
            field_buffer.as_entire_binding(),
        ]);
        entries.extend(self.motion.entries());
        dispatch(ctx, &pipeline, &entries, (w.div_ceil(8), h.div_ceil(8)), None);
        let bytes = ctx.read_buffer(&output, out_bytes)?;
        let words: Vec<u32> = GpuContext::values(&bytes);
        let rgb = words.chunks_exact(2).map(|p| {
            let b = p[0].to_le_bytes();
            [b[0], b[1], b[2]]
        });
        let labels = words.chunks_exact(2).map(|p| p[1] as u16);
        Ok(MprImage {
            spec: *spec,
            rgb: rgb.collect(),
            labels: labels.collect(),
        })
    }
}
