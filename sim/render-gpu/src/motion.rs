//! The breathing motion on the GPU (`shaders/motion.wgsl`, docs/breathing.md "On the GPU"):
//! a motion that is one factored field u(X, t) = d(t) · w(X.z) · m(X) (stylet_physics
//! `FactoredField`: the synthetic motion) is drawn with its mobility map m uploaded once and
//! d(t) and the profile's knots written per frame. Each pipeline that warps (ray casting, MPR,
//! X-ray) owns one [`GpuMotion`] and binds it at 20 and 21.

use bytemuck::{Pod, Zeroable};
use stylet_physics::glam::Vec3;
use stylet_render::scene::MotionHook;
use stylet_render::volume::IndexMap;

use crate::pipeline::{uniform_buffer, v4};
use crate::volume::texture_3d;
use crate::{GpuContext, GpuError};

/// Mirrors `Motion` in motion.wgsl (16-byte members).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct MotionParams {
    dir: [f32; 4],
    knot_z: [f32; 4],
    knot_w: [f32; 4],
    inv0: [f32; 4],
    inv1: [f32; 4],
    inv2: [f32; 4],
    origin: [f32; 4],
    dims: [u32; 4],
}

/// The mobility map on the GPU, kept while the motion's map is the same.
struct MobilityMap {
    key: (usize, usize),
    view: wgpu::TextureView,
}

/// One pipeline's breathing motion: its uniform and the mobility map.
pub(crate) struct GpuMotion {
    params: wgpu::Buffer,
    still: wgpu::TextureView,
    map: Option<MobilityMap>,
    breathing: bool,
}

impl GpuMotion {
    pub(crate) fn new(ctx: &GpuContext) -> GpuMotion {
        let still = texture_3d(
            ctx,
            "no motion",
            [1, 1, 1],
            wgpu::TextureFormat::R32Float,
            4,
            bytemuck::bytes_of(&0.0f32),
        );
        GpuMotion {
            params: uniform_buffer(ctx, "motion params", std::mem::size_of::<MotionParams>()),
            still,
            map: None,
            breathing: false,
        }
    }

    /// Writes the frame's motion (`None`: a still patient) and returns the bound on |u| (mm)
    /// when the patient breathes. A motion that is not one factored field, or has no bound, is
    /// refused with the reason.
    pub(crate) fn prepare(&mut self, ctx: &GpuContext, hook: Option<&MotionHook>) -> Result<Option<f32>, GpuError> {
        // No motion, or one that never moves (`Static`): a still patient.
        let Some(hook) = hook.filter(|h| h.model.max_displacement_mm() != 0.0) else {
            self.breathing = false;
            ctx.queue
                .write_buffer(&self.params, 0, bytemuck::bytes_of(&MotionParams::zeroed()));
            return Ok(None);
        };
        let f = hook.model.factored_at(hook.t_s).ok_or(GpuError::Unsupported(
            "a breathing motion that is not one factored field (only the synthetic motion is drawn on the GPU)",
        ))?;
        let bound_mm = hook.model.max_displacement_mm() as f32;
        if !bound_mm.is_finite() {
            return Err(GpuError::Unsupported("a breathing motion without a bound"));
        }
        let key = (f.map.data().as_ptr() as usize, f.map.data().len());
        if self.map.as_ref().is_none_or(|m| m.key != key) {
            let dims = f.map.grid().dims();
            ctx.check_texture_3d("the breathing mobility map", dims)?;
            let view = texture_3d(
                ctx,
                "breathing mobility",
                dims,
                wgpu::TextureFormat::R32Float,
                4,
                bytemuck::cast_slice(f.map.data()),
            );
            self.map = Some(MobilityMap { key, view });
        }
        let m = IndexMap::of(f.map.grid());
        let params = MotionParams {
            dir: v4(f.direction_mm.as_vec3(), 1.0),
            knot_z: f.profile.map(|k| k.0 as f32),
            knot_w: f.profile.map(|k| k.1 as f32),
            inv0: v4(m.rows[0], 0.0),
            inv1: v4(m.rows[1], 0.0),
            inv2: v4(m.rows[2], 0.0),
            origin: v4(m.origin, 0.0),
            dims: [m.dims[0], m.dims[1], m.dims[2], 0],
        };
        ctx.queue.write_buffer(&self.params, 0, bytemuck::bytes_of(&params));
        self.breathing = true;
        Ok(Some(bound_mm))
    }

    /// Bindings 20 and 21 of the last prepared frame.
    pub(crate) fn entries(&self) -> [wgpu::BindGroupEntry<'_>; 2] {
        let view = match (&self.map, self.breathing) {
            (Some(m), true) => &m.view,
            _ => &self.still,
        };
        [
            wgpu::BindGroupEntry {
                binding: 20,
                resource: self.params.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 21,
                resource: wgpu::BindingResource::TextureView(view),
            },
        ]
    }
}

/// The bound `bound_mm` in CT index units per axis: the length of each row of the index map
/// times the bound bounds |Δc_a| for any |Δx| ≤ bound (the CPU reference's `motion_margin`).
pub(crate) fn index_margin(map: &IndexMap, bound_mm: f32) -> Vec3 {
    let (ex, ey, ez) = (map.vector(Vec3::X), map.vector(Vec3::Y), map.vector(Vec3::Z));
    let row = |a: usize| Vec3::new(ex[a], ey[a], ez[a]).length();
    Vec3::new(row(0), row(1), row(2)) * bound_mm
}
