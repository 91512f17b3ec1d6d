//! The breathing motion on the GPU (`shaders/motion.wgsl`, docs/breathing.md "On the GPU"), in
//! the two forms a GPU draws:
//! - one factored field u(X, t) = d(t) · w(X.z) · m(X) (stylet_physics `FactoredField`: the
//!   synthetic motion): the mobility map m uploaded once, d(t) and the profile's knots written
//!   per frame;
//! - weighted grid fields u(X, t) = g(t)·a₁(X) + g′(t)·a₂(X) + a₃(X) (stylet_physics
//!   `WeightedGrids`: measured motion, thesis eq. 5.3.6): the fields uploaded once, the weights
//!   written per frame.
//!
//! Each pipeline that warps (ray casting, MPR, X-ray, ultrasound) owns one [`GpuMotion`] and
//! binds it at 20 to 24.

use bytemuck::{Pod, Zeroable};
use stylet_physics::Grid;
use stylet_physics::glam::Vec3;
use stylet_physics::motion::{GridField, MotionModel};
use stylet_render::scene::MotionHook;
use stylet_render::volume::IndexMap;

use crate::pipeline::{uniform_buffer, v4};
use crate::volume::texture_3d;
use crate::{GpuContext, GpuError};

/// The largest measured field uploaded (bytes on the GPU, 16 per node); a larger one is drawn
/// on the CPU.
pub const MAX_FIELD_BYTES: u64 = 256 << 20;

/// Mirrors `FieldParams` in motion.wgsl (16-byte members).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct FieldParams {
    inv0: [f32; 4],
    inv1: [f32; 4],
    inv2: [f32; 4],
    /// w: the weight at this moment.
    origin: [f32; 4],
    /// w: 1 when the field is present.
    dims: [u32; 4],
}

/// Mirrors `Motion` in motion.wgsl (16-byte members).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct MotionParams {
    /// w: 0 still, 1 factored, 2 weighted grids.
    dir: [f32; 4],
    knot_z: [f32; 4],
    knot_w: [f32; 4],
    inv0: [f32; 4],
    inv1: [f32; 4],
    inv2: [f32; 4],
    origin: [f32; 4],
    dims: [u32; 4],
    fields: [FieldParams; 3],
}

/// A texture uploaded from a field or map, kept while its source (address, length) is the same.
struct Uploaded {
    key: (usize, usize),
    view: wgpu::TextureView,
}

/// One pipeline's breathing motion: its uniform, the mobility map and the measured fields.
pub(crate) struct GpuMotion {
    params: wgpu::Buffer,
    still: wgpu::TextureView,
    still_field: wgpu::TextureView,
    map: Option<Uploaded>,
    fields: [Option<Uploaded>; 3],
    /// What the last prepared frame binds: 0 still, 1 factored, 2 weighted grids.
    mode: u32,
    /// Which fields the last prepared frame has (weighted grids).
    present: [bool; 3],
}

/// Whether the GPU draws `model` at `t_s`: still, one factored field, or weighted grid fields
/// each within [`MAX_FIELD_BYTES`]. Otherwise a view is drawn on the CPU.
pub fn draws(model: &dyn MotionModel, t_s: f64) -> bool {
    model.max_displacement_mm() == 0.0
        || model.factored_at(t_s).is_some()
        || model.weighted_grids_at(t_s).is_some_and(|w| {
            w.terms
                .iter()
                .flatten()
                .all(|(f, _)| f.grid().len() as u64 * 16 <= MAX_FIELD_BYTES)
        })
}

/// The placement of `grid` as the shader reads it: rows, origin, dims.
fn placement(grid: &Grid) -> ([[f32; 4]; 3], [f32; 4], [u32; 4]) {
    let m = IndexMap::of(grid);
    (
        [v4(m.rows[0], 0.0), v4(m.rows[1], 0.0), v4(m.rows[2], 0.0)],
        v4(m.origin, 0.0),
        [m.dims[0], m.dims[1], m.dims[2], 0],
    )
}

/// Uploads `field` as an Rgba32Float 3D texture (x, y, z, 0 per node).
fn upload_field(ctx: &GpuContext, field: &GridField) -> Result<wgpu::TextureView, GpuError> {
    let dims = field.grid().dims();
    ctx.check_texture_3d("a measured breathing field", dims)?;
    let bytes = field.grid().len() as u64 * 16;
    if bytes > MAX_FIELD_BYTES {
        return Err(GpuError::Limits {
            what: format!(
                "a measured breathing field of {} × {} × {} nodes",
                dims[0], dims[1], dims[2]
            ),
            needed: bytes,
            limit: MAX_FIELD_BYTES,
        });
    }
    let texels: Vec<[f32; 4]> = field.values().iter().map(|v| [v[0], v[1], v[2], 0.0]).collect();
    Ok(texture_3d(
        ctx,
        "breathing field",
        dims,
        wgpu::TextureFormat::Rgba32Float,
        16,
        bytemuck::cast_slice(&texels),
    ))
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
        let still_field = texture_3d(
            ctx,
            "no motion field",
            [1, 1, 1],
            wgpu::TextureFormat::Rgba32Float,
            16,
            bytemuck::bytes_of(&[0.0f32; 4]),
        );
        GpuMotion {
            params: uniform_buffer(ctx, "motion params", std::mem::size_of::<MotionParams>()),
            still,
            still_field,
            map: None,
            fields: [None, None, None],
            mode: 0,
            present: [false; 3],
        }
    }

    /// Writes the frame's motion (`None`: a still patient) and returns the bound on |u| (mm)
    /// when the patient breathes. A motion the GPU does not draw ([`draws`]), or without a
    /// bound, is refused with the reason.
    pub(crate) fn prepare(&mut self, ctx: &GpuContext, hook: Option<&MotionHook>) -> Result<Option<f32>, GpuError> {
        self.mode = 0;
        self.present = [false; 3];
        // No motion, or one that never moves (`Static`): a still patient.
        let Some(hook) = hook.filter(|h| h.model.max_displacement_mm() != 0.0) else {
            ctx.queue
                .write_buffer(&self.params, 0, bytemuck::bytes_of(&MotionParams::zeroed()));
            return Ok(None);
        };
        let bound_mm = hook.model.max_displacement_mm() as f32;
        if !bound_mm.is_finite() {
            return Err(GpuError::Unsupported("a breathing motion without a bound"));
        }
        let mut params = MotionParams::zeroed();
        if let Some(f) = hook.model.factored_at(hook.t_s) {
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
                self.map = Some(Uploaded { key, view });
            }
            let ([inv0, inv1, inv2], origin, dims) = placement(f.map.grid());
            params = MotionParams {
                dir: v4(f.direction_mm.as_vec3(), 1.0),
                knot_z: f.profile.map(|k| k.0 as f32),
                knot_w: f.profile.map(|k| k.1 as f32),
                inv0,
                inv1,
                inv2,
                origin,
                dims,
                ..params
            };
            self.mode = 1;
        } else if let Some(w) = hook.model.weighted_grids_at(hook.t_s) {
            for (i, term) in w.terms.iter().enumerate() {
                let Some((field, weight)) = term else { continue };
                let key = (field.values().as_ptr() as usize, field.values().len());
                if self.fields[i].as_ref().is_none_or(|u| u.key != key) {
                    self.fields[i] = Some(Uploaded {
                        key,
                        view: upload_field(ctx, field)?,
                    });
                }
                let ([inv0, inv1, inv2], mut origin, mut dims) = placement(field.grid());
                origin[3] = *weight as f32;
                dims[3] = 1;
                params.fields[i] = FieldParams {
                    inv0,
                    inv1,
                    inv2,
                    origin,
                    dims,
                };
                self.present[i] = true;
            }
            params.dir[3] = 2.0;
            self.mode = 2;
        } else {
            return Err(GpuError::Unsupported(
                "a breathing motion that is neither one factored field nor weighted grid fields",
            ));
        }
        ctx.queue.write_buffer(&self.params, 0, bytemuck::bytes_of(&params));
        Ok(Some(bound_mm))
    }

    /// Bindings 20 to 24 of the last prepared frame.
    pub(crate) fn entries(&self) -> [wgpu::BindGroupEntry<'_>; 5] {
        let map = match (&self.map, self.mode) {
            (Some(m), 1) => &m.view,
            _ => &self.still,
        };
        let field = |i: usize| match (&self.fields[i], self.mode == 2 && self.present[i]) {
            (Some(f), true) => &f.view,
            _ => &self.still_field,
        };
        [
            wgpu::BindGroupEntry {
                binding: 20,
                resource: self.params.as_entire_binding(),
            },
            texture(21, map),
            texture(22, field(0)),
            texture(23, field(1)),
            texture(24, field(2)),
        ]
    }
}

fn texture(binding: u32, view: &wgpu::TextureView) -> wgpu::BindGroupEntry<'_> {
    wgpu::BindGroupEntry {
        binding,
        resource: wgpu::BindingResource::TextureView(view),
    }
}

/// The bound `bound_mm` in CT index units per axis: the length of each row of the index map
/// times the bound bounds |Δc_a| for any |Δx| ≤ bound (the CPU reference's `motion_margin`).
pub(crate) fn index_margin(map: &IndexMap, bound_mm: f32) -> Vec3 {
    let (ex, ey, ez) = (map.vector(Vec3::X), map.vector(Vec3::Y), map.vector(Vec3::Z));
    let row = |a: usize| Vec3::new(ex[a], ey[a], ez[a]).length();
    Vec3::new(row(0), row(1), row(2)) * bound_mm
}
