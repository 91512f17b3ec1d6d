//! The ray-casting pipeline (`shaders/raycast.wgsl`): one compute invocation per pixel in 8 × 8
//! workgroups. Per frame only the uniforms and the tool primitives are written; the volumes stay
//! on the GPU, the occupancy grid is rewritten only when the transfer function or N changes.

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use stylet_physics::AIR_HU;
use stylet_physics::glam::Vec3;
use stylet_render::image::Image;
use stylet_render::raycast::march::farthest_corner_mm;
use stylet_render::raycast::occupancy::Occupancy;
use stylet_render::scene::{ClipPlane, Scene, Tagging};
use stylet_render::shadow::Shadows;
use stylet_render::tools::{MAX_PRIMITIVES, Primitive};
use stylet_render::transfer::{MAX_TRAPEZOIDS, TransferFunction};
use stylet_render::transfer_table::TransferTable;
use stylet_render::volume::IndexMap;

use crate::motion::{GpuMotion, index_margin};
use crate::pipeline::{Pipelines, dispatch, numbered, uniform_buffer, v4};
use crate::timer::PassTimer;
use crate::volume::{CtFormat, GpuVolume, storage, texture_3d};
use crate::{GpuContext, GpuError};

/// The shader after the shared breathing motion.
const SHADER: &str = concat!(
    include_str!("../shaders/motion.wgsl"),
    include_str!("../shaders/raycast.wgsl")
);

/// The CT declaration the shaders are compiled with (binding 1) and `ct_voxel`, which both
/// raycast.wgsl and mpr.wgsl call; the buffer variants index with `P.dims` (both shaders' CT size).
pub(crate) fn ct_prelude((format, buffer): (CtFormat, bool)) -> &'static str {
    match (format, buffer) {
        (CtFormat::Int16, false) => {
            "@group(0) @binding(1) var ct: texture_3d<i32>;\n\
             fn ct_voxel(p: vec3<i32>) -> f32 { return f32(textureLoad(ct, p, 0).x); }\n"
        }
        (CtFormat::Float32, false) => {
            "@group(0) @binding(1) var ct: texture_3d<f32>;\n\
             fn ct_voxel(p: vec3<i32>) -> f32 { return textureLoad(ct, p, 0).x; }\n"
        }
        (CtFormat::Int16, true) => {
            "@group(0) @binding(1) var<storage, read> ct: array<u32>;\n\
             fn ct_voxel(p: vec3<i32>) -> f32 {\n\
                 let i = u32(p.x) + P.dims.x * (u32(p.y) + P.dims.y * u32(p.z));\n\
                 let w = ct[i >> 1u];\n\
                 let half = select(w << 16u, w & 0xffff0000u, (i & 1u) == 1u);\n\
                 return f32(bitcast<i32>(half) >> 16u);\n\
             }\n"
        }
        (CtFormat::Float32, true) => {
            "@group(0) @binding(1) var<storage, read> ct: array<f32>;\n\
             fn ct_voxel(p: vec3<i32>) -> f32 {\n\
                 return ct[u32(p.x) + P.dims.x * (u32(p.y) + P.dims.y * u32(p.z))];\n\
             }\n"
        }
    }
}

// Switches of Params.image.z (mirrored in raycast.wgsl).
const F_JITTER: u32 = 1;
const F_RAY_BOX: u32 = 2;
const F_LEAPING: u32 = 4;
const F_EARLY: u32 = 8;
const F_CLIP: u32 = 16;
const F_DEFORMED: u32 = 32;
const F_NEEDLE_SHADOW: u32 = 64;
const F_SAMPLE_OUTSIDE: u32 = 128;

#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct GpuTrapezoid {
    hu: [f32; 4],
    rgb_opacity: [f32; 4],
    weight: [f32; 4],
}

/// Mirrors `Params` in raycast.wgsl: every member a 16-byte vector, so the WGSL uniform layout
/// and repr(C) agree without hidden padding.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct Params {
    eye: [f32; 4],
    right: [f32; 4],
    up: [f32; 4],
    forward: [f32; 4],
    inv0: [f32; 4],
    inv1: [f32; 4],
    inv2: [f32; 4],
    origin: [f32; 4],
    dims: [u32; 4],
    occ_scale: [f32; 4],
    occ_size: [f32; 4],
    image: [u32; 4],
    modes: [u32; 4],
    window: [f32; 4],
    background: [f32; 4],
    light: [f32; 4],
    phong: [f32; 4],
    clip_point: [f32; 4],
    clip_normal: [f32; 4],
    def_inv0: [f32; 4],
    def_inv1: [f32; 4],
    def_inv2: [f32; 4],
    def_origin: [f32; 4],
    def_dims: [u32; 4],
    needle_tip: [f32; 4],
    needle_back: [f32; 4],
    needle_dims: [f32; 4],
    spheres: [[f32; 4]; 2],
    traps: [GpuTrapezoid; MAX_TRAPEZOIDS],
    /// The transfer table: lo_hu, 1/step_hu, entries − 1.
    table: [f32; 4],
    /// The breathing motion's bound in CT index units per axis (0 when still).
    margin: [f32; 4],
}

/// A tool primitive as the shader reads it (mirrors `Primitive` in raycast.wgsl).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable, PartialEq)]
struct GpuPrimitive {
    a: [f32; 4],
    b: [f32; 4],
    c: [f32; 4],
    d: [f32; 4],
    rgb: [f32; 4],
    kind: [u32; 4],
}

/// `tools::Primitive` in the shader's layout.
fn gpu_primitive(p: &Primitive) -> GpuPrimitive {
    let z = [0.0; 4];
    let (a, b, c, d, rgb, kind) = match *p {
        Primitive::Capsule { a, b, radius, rgb } => (v4(a, radius), v4(b, 0.0), z, z, rgb, 0),
        Primitive::Sphere { center, radius, rgb } => (v4(center, radius), z, z, z, rgb, 1),
        Primitive::Box {
            center,
            axes,
            half_mm,
            rgb,
        } => (
            v4(center, 0.0),
            v4(axes[0], half_mm.x),
            v4(axes[1], half_mm.y),
            v4(axes[2], half_mm.z),
            rgb,
            2,
        ),
        Primitive::Cylinder {
            center,
            axis,
            radius,
            half_length_mm,
            cut_normal,
            cut_mm,
            rgb,
        } => (
            v4(center, radius),
            v4(axis, half_length_mm),
            v4(cut_normal, cut_mm),
            z,
            rgb,
            3,
        ),
    };
    GpuPrimitive {
        a,
        b,
        c,
        d,
        rgb: v4(rgb, 1.0),
        kind: [kind, 0, 0, 0],
    }
}

/// The transfer table and the occupancy of one (volume, N, transfer function, step, J) on the
/// GPU.
struct OccupancyCache {
    volume: u64,
    cells: u32,
    transfer: TransferFunction,
    step_mm: f32,
    deformed: Option<usize>,
    /// The motion's bound the cells were dilated by (index units per axis).
    margin: Option<[u32; 3]>,
    scale: Vec3,
    size: Vec3,
    buffer: wgpu::Buffer,
    /// `TransferTable` entries, and (lo_hu, 1/step_hu, entries − 1, α at air).
    table: wgpu::Buffer,
    table_params: [f32; 4],
}

/// J of the deformation hook on the GPU, kept while the scene holds the same `Arc`.
struct DeformedCache {
    key: usize,
    map: IndexMap,
    view: wgpu::TextureView,
}

/// The ray-casting pipeline and its per-frame buffers.
pub struct GpuRenderer {
    pipelines: Pipelines,
    params: wgpu::Buffer,
    prims: wgpu::Buffer,
    dummy_deformed: wgpu::TextureView,
    occupancy: Option<OccupancyCache>,
    deformed: Option<DeformedCache>,
    motion: GpuMotion,
    output: Option<(u64, wgpu::Buffer)>,
    timer: Option<PassTimer>,
    last_pass_ms: Option<f64>,
}

impl GpuRenderer {
    pub fn new(ctx: &GpuContext) -> GpuRenderer {
        let params = uniform_buffer(ctx, "raycast params", std::mem::size_of::<Params>());
        let prims = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("tool primitives"),
            size: (MAX_PRIMITIVES * std::mem::size_of::<GpuPrimitive>()) as u64,
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let dummy_deformed = texture_3d(
            ctx,
            "no deformed region",
            [1, 1, 1],
            wgpu::TextureFormat::R32Float,
            4,
            bytemuck::bytes_of(&0.0f32),
        );
        GpuRenderer {
            pipelines: Pipelines::new("raycast.wgsl", SHADER),
            params,
            prims,
            dummy_deformed,
            motion: GpuMotion::new(ctx),
            occupancy: None,
            deformed: None,
            output: None,
            timer: PassTimer::new(ctx),
            last_pass_ms: None,
        }
    }

    /// The GPU time of the last frame's ray-casting pass in milliseconds, measured by the GPU's
    /// own timestamps (no upload, submission or readback); `None` on adapters without them.
    pub fn last_pass_ms(&self) -> Option<f64> {
        self.last_pass_ms
    }

    /// Draws the scene at `width` × `height` (half resolution: ⌈w/2⌉ × ⌈h/2⌉, then
    /// [`Image::upscale`]).
    pub fn render(
        &mut self,
        ctx: &GpuContext,
        vol: &GpuVolume,
        scene: &Scene,
        width: u32,
        height: u32,
    ) -> Result<Image, GpuError> {
        if width == 0 || height == 0 || width > 16384 || height > 16384 {
            return Err(GpuError::Invalid(format!("image size {width} × {height}")));
        }
        scene
            .transfer
            .validate()
            .map_err(|e| GpuError::Invalid(format!("transfer function: {e}")))?;
        let q = scene.quality;
        if !(q.step_mm.is_finite() && q.step_mm > 0.0) {
            return Err(GpuError::Invalid(format!("step {} mm", q.step_mm)));
        }
        if q.half_resolution {
            let small = self.render_full(ctx, vol, scene, width.div_ceil(2), height.div_ceil(2))?;
            return Ok(small.upscale(width, height));
        }
        self.render_full(ctx, vol, scene, width, height)
    }

    fn render_full(
        &mut self,
        ctx: &GpuContext,
        vol: &GpuVolume,
        scene: &Scene,
        width: u32,
        height: u32,
    ) -> Result<Image, GpuError> {
        let out_bytes = width as u64 * height as u64 * 4;
        ctx.check_storage_buffer("the image", out_bytes)?;
        let groups = (width.div_ceil(8), height.div_ceil(8));
        let max_groups = ctx.limits.max_compute_workgroups_per_dimension;
        if groups.0 > max_groups || groups.1 > max_groups {
            return Err(GpuError::Limits {
                what: "workgroups per dimension".into(),
                needed: groups.0.max(groups.1) as u64,
                limit: max_groups as u64,
            });
        }
        let prims: Vec<GpuPrimitive> = scene.tools.primitives().iter().map(gpu_primitive).collect();
        if prims.len() > MAX_PRIMITIVES {
            return Err(GpuError::Invalid(format!(
                "the tools make {} primitives; the GPU buffer holds {MAX_PRIMITIVES}",
                prims.len()
            )));
        }
        self.update_deformed(ctx, scene)?;
        let margin = self
            .motion
            .prepare(ctx, scene.motion.as_ref())?
            .map(|bound_mm| index_margin(&IndexMap::of(vol.atlas.ct().grid()), bound_mm));
        self.update_occupancy(ctx, vol, scene, margin)?;
        let mut params = self.params(vol, scene, width, height, prims.len() as u32);
        params.margin = v4(margin.unwrap_or(Vec3::ZERO), 0.0);
        ctx.queue.write_buffer(&self.params, 0, bytemuck::bytes_of(&params));
        if !prims.is_empty() {
            ctx.queue.write_buffer(&self.prims, 0, bytemuck::cast_slice(&prims));
        }
        let output = match &self.output {
            Some((size, buf)) if *size >= out_bytes => buf.clone(),
            _ => {
                let buf = ctx.device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some("raycast image"),
                    size: out_bytes,
                    usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
                    mapped_at_creation: false,
                });
                self.output = Some((out_bytes, buf.clone()));
                buf
            }
        };
        let pipeline = self.pipelines.get(ctx, &vol.raycast_prelude());
        let deformed_view = self.deformed.as_ref().map(|d| &d.view).unwrap_or(&self.dummy_deformed);

        let cache = self.occupancy.as_ref().expect("occupancy set above");
        let mut resources = vec![
            self.params.as_entire_binding(),
            vol.ct_binding(),
            wgpu::BindingResource::TextureView(&vol.labels_view),
            vol.styles.as_entire_binding(),
            cache.buffer.as_entire_binding(),
            self.prims.as_entire_binding(),
            wgpu::BindingResource::TextureView(deformed_view),
            output.as_entire_binding(),
            cache.table.as_entire_binding(),
        ];
        resources.extend(vol.records_bindings());
        // Bindings 0–8, the records at 9 (and their sampler at 10), the motion at 20 and 21.
        let mut entries = numbered(resources);
        entries.extend(self.motion.entries());
        dispatch(ctx, &pipeline, &entries, groups, self.timer.as_ref());
        let bytes = ctx.read_buffer(&output, out_bytes)?;
        self.last_pass_ms = self.timer.as_ref().and_then(|t| t.read_ms(ctx));
        let rgba = bytes.chunks_exact(4).map(|p| [p[0], p[1], p[2], p[3]]).collect();
        Ok(Image { width, height, rgba })
    }

    fn update_deformed(&mut self, ctx: &GpuContext, scene: &Scene) -> Result<(), GpuError> {
        let Some(d) = &scene.deformed else {
            self.deformed = None;
            return Ok(());
        };
        let key = Arc::as_ptr(&d.volume) as usize;
        if self.deformed.as_ref().is_some_and(|c| c.key == key) {
            return Ok(());
        }
        let dims = d.volume.grid().dims();
        ctx.check_texture_3d("the deformed sub-volume", dims)?;
        let view = texture_3d(
            ctx,
            "deformed sub-volume",
            dims,
            wgpu::TextureFormat::R32Float,
            4,
            bytemuck::cast_slice(d.volume.data()),
        );
        self.deformed = Some(DeformedCache {
            key,
            map: IndexMap::of(d.volume.grid()),
            view,
        });
        Ok(())
    }

    /// The occupancy bits of `raycast::occupancy::Occupancy` (the CPU reference's own grid and
    /// rule, Ω_J marked occupied, dilated by a motion's bound), rebuilt when the volume, N, the
    /// transfer function, J or the bound change.
    fn update_occupancy(
        &mut self,
        ctx: &GpuContext,
        vol: &GpuVolume,
        scene: &Scene,
        margin: Option<Vec3>,
    ) -> Result<(), GpuError> {
        // The CPU reference clamps N the same way (RenderVolume::cell_ranges).
        let cells = scene.quality.occupancy_cells.clamp(16, 128);
        let deformed = self.deformed.as_ref().map(|d| d.key);
        let margin_key = margin.map(|m| m.to_array().map(f32::to_bits));
        if let Some(c) = &self.occupancy
            && c.volume == vol.id
            && c.cells == cells
            && c.transfer == scene.transfer
            && c.step_mm == scene.quality.step_mm
            && c.deformed == deformed
            && c.margin == margin_key
        {
            return Ok(());
        }
        ctx.check_storage_buffer("the occupancy grid", 4 * (cells as u64).pow(3))?;
        let (lo_hu, hi_hu) = vol.value_range_hu;
        let table = TransferTable::new(&scene.transfer, lo_hu, hi_hu, scene.quality.step_mm);
        ctx.check_storage_buffer("the transfer table", 16 * table.entries().len() as u64)?;
        let ranges = vol.cell_ranges(cells);
        let ct_map = IndexMap::of(vol.atlas.ct().grid());
        let occ = Occupancy::new(
            &ranges,
            &table,
            ct_map.dims,
            scene.deformed.as_ref().map(|d| (&*d.volume, &ct_map)),
        );
        let occ = match margin {
            Some(m) => occ.dilated(m),
            None => occ,
        };
        let bits: Vec<u32> = occ.occupied.iter().map(|&b| b as u32).collect();
        let buffer = storage(ctx, "occupancy", bytemuck::cast_slice(&bits));
        let table_params = [
            table.lo_hu,
            table.inv_step,
            (table.entries().len() - 1) as f32,
            table.lookup(AIR_HU)[3],
        ];
        let table = storage(ctx, "transfer table", bytemuck::cast_slice(table.entries()));
        self.occupancy = Some(OccupancyCache {
            volume: vol.id,
            cells,
            transfer: scene.transfer.clone(),
            step_mm: scene.quality.step_mm,
            table,
            table_params,
            deformed,
            margin: margin_key,
            scale: occ.scale,
            size: occ.size,
            buffer,
        });
        Ok(())
    }

    fn params(&self, vol: &GpuVolume, scene: &Scene, width: u32, height: u32, n_prims: u32) -> Params {
        let cam = &scene.camera;
        let (right, up, forward) = cam.basis();
        let tan_half = (cam.fov_y_deg.to_radians() * 0.5).tan();
        let aspect = width as f32 / height as f32;
        let q = scene.quality;
        let grid = vol.atlas.ct().grid();
        let m = IndexMap::of(grid);
        let t_far = farthest_corner_mm(grid, cam.eye_mm);
        let occ = self.occupancy.as_ref().expect("occupancy is set before the parameters");
        let shadows = Shadows::from_tools(&scene.tools);
        let mut flags = 0;
        for (on, f) in [
            (q.jitter, F_JITTER),
            (q.ray_box, F_RAY_BOX),
            (q.leaping, F_LEAPING),
            (q.early_termination, F_EARLY),
            (scene.clip.is_some(), F_CLIP),
            (self.deformed.is_some(), F_DEFORMED),
            (shadows.needle.is_some(), F_NEEDLE_SHADOW),
            (scene.deformed.is_some() || occ.table_params[3] > 0.0, F_SAMPLE_OUTSIDE),
        ] {
            if on {
                flags |= f;
            }
        }
        let mut traps = [GpuTrapezoid::zeroed(); MAX_TRAPEZOIDS];
        let (kind, n_traps, window) = match &scene.transfer {
            TransferFunction::Trapezoids(ts) => {
                for (dst, t) in traps.iter_mut().zip(ts) {
                    *dst = GpuTrapezoid {
                        hu: t.hu,
                        rgb_opacity: [t.rgb[0], t.rgb[1], t.rgb[2], t.opacity],
                        weight: [t.weight, 0.0, 0.0, 0.0],
                    };
                }
                (0, ts.len().min(MAX_TRAPEZOIDS) as u32, [0.0; 4])
            }
            TransferFunction::Window {
                level_hu,
                width_hu,
                opacity,
            } => (1, 0, [*level_hu, *width_hu, *opacity, 0.0]),
        };
        let tagging = match scene.tagging {
            Tagging::Off => 0,
            Tagging::Risk => 1,
            Tagging::Labels => 2,
        };
        let z = [0.0; 4];
        let (def_inv, def_origin, def_dims) = match &self.deformed {
            Some(d) => (
                d.map.rows.map(|r| v4(r, 0.0)),
                v4(d.map.origin, 0.0),
                [d.map.dims[0], d.map.dims[1], d.map.dims[2], 1],
            ),
            None => ([z; 3], z, [1, 1, 1, 0]),
        };
        let (needle_tip, needle_back, needle_dims) = match &shadows.needle {
            Some(n) => (
                v4(n.tip_mm, 0.0),
                v4(n.back, 0.0),
                [n.length_mm, n.diameter_mm, n.hub_length_mm, n.hub_diameter_mm],
            ),
            None => (z, z, z),
        };
        let mut spheres = [z; 2];
        for (dst, sp) in spheres.iter_mut().zip(&shadows.spheres) {
            *dst = v4(sp.center_mm, sp.radius_mm);
        }
        let clip = scene.clip.unwrap_or(ClipPlane {
            point_mm: Vec3::ZERO,
            normal: Vec3::Z,
        });
        let l = &scene.light;
        Params {
            eye: v4(cam.eye_mm, tan_half),
            right: v4(right, aspect),
            up: v4(up, q.step_mm),
            forward: v4(forward, t_far),
            inv0: v4(m.rows[0], 0.0),
            inv1: v4(m.rows[1], 0.0),
            inv2: v4(m.rows[2], 0.0),
            origin: v4(m.origin, 0.0),
            dims: [m.dims[0], m.dims[1], m.dims[2], occ.cells],
            occ_scale: v4(occ.scale, 0.0),
            occ_size: v4(occ.size, 0.0),
            image: [width, height, flags, n_traps],
            modes: [kind, tagging, n_prims, vol.style_count],
            window,
            background: v4(scene.background, 1.0),
            light: v4(l.toward_light, l.shadow_in),
            phong: [l.ambient, l.diffuse, l.specular, l.shininess],
            clip_point: v4(clip.point_mm, 0.0),
            clip_normal: v4(clip.normal, 0.0),
            def_inv0: def_inv[0],
            def_inv1: def_inv[1],
            def_inv2: def_inv[2],
            def_origin,
            def_dims,
            needle_tip,
            needle_back,
            needle_dims,
            spheres,
            traps,
            table: occ.table_params,
            margin: z,
        }
    }
}
