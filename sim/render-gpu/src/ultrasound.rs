//! Simulated ultrasound on the GPU (`shaders/ultrasound.wgsl`): the same per-line loop as
//! `stylet_render::ultrasound` (one workgroup per scan line: the samples' reads side by side, the
//! carried part in order), reading the frame tables, the
//! echo classes and the needle's per-line hits the CPU reference computes the same way, and the
//! vessels' flow axes on a dense grid (uploaded once per flow field). Returns the frame as the CPU
//! does: log compression over the beam's width runs on the CPU (`ultrasound::compress`), as does
//! scan conversion (`Sonogram::to_image`).

use std::sync::Arc;

use bytemuck::{Pod, Zeroable};
use stylet_render::consequences::{COLLECTION_MAX_HU, COLLECTION_MIN_HU};
use stylet_render::tools::{CONVEX_HALF_ANGLE_DEG, CONVEX_RADIUS_MM};
use stylet_render::ultrasound::EchoClass;
use stylet_render::ultrasound::acoustic::PLEURA_SCATTER;
use stylet_render::ultrasound::doppler::{self, CELL_MM, SCALE_M_S, WALL_FILTER_M_S};
use stylet_render::ultrasound::needle::{REVERB_DECAY, REVERB_ECHOES};
use stylet_render::ultrasound::{
    AIR_BELOW_HU, DOPPLER_MIN_SIGNAL, FLAG_DOPPLER, FLAG_TARGET, FlowField, FrameTables, GEL_MAX_MM, GEL_MRAYL,
    SCATTER_GAIN, SPECULAR_GAIN, ScanGeometry, Sonogram, UltrasoundScene, check_scene, compress, needle_hits, speckle,
};
use stylet_render::volume::IndexMap;

use crate::motion::GpuMotion;
use crate::pipeline::{Pipelines, dispatch, numbered, uniform_buffer, v4};
use crate::raycast::ct_prelude;
use crate::timer::PassTimer;
use crate::volume::{GpuVolume, storage};
use crate::{GpuContext, GpuError};

/// The shader after the shared breathing motion and CT sampler.
const SHADER: &str = concat!(
    include_str!("../shaders/motion.wgsl"),
    include_str!("../shaders/ct_sample.wgsl"),
    include_str!("../shaders/ultrasound.wgsl")
);

/// Mirrors `Params` in ultrasound.wgsl (16-byte members).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
struct UsParams {
    face: [f32; 4],
    lateral: [f32; 4],
    beam: [f32; 4],
    row0: [f32; 4],
    row1: [f32; 4],
    row2: [f32; 4],
    origin: [f32; 4],
    dims: [u32; 4],
    scan: [u32; 4],
    geo: [f32; 4],
    gains: [f32; 4],
    limits: [f32; 4],
    doppler: [f32; 4],
    reverb: [f32; 4],
    fluid: [f32; 4],
    blood: [f32; 4],
    flow_first: [i32; 4],
    flow_dims: [u32; 4],
    collect: [f32; 4],
}

/// A flow field on the GPU, kept while the scene holds the same field on the same volume.
struct UploadedFlow {
    field: Arc<FlowField>,
    volume: u64,
    first: [i32; 3],
    dims: [u32; 3],
    buffer: wgpu::Buffer,
}

/// The ultrasound pipeline (one per CT storage format, built on first use).
pub struct GpuUltrasound {
    pipelines: Pipelines,
    params: wgpu::Buffer,
    flow: Option<UploadedFlow>,
    motion: GpuMotion,
    timer: Option<PassTimer>,
    last_pass_ms: Option<f64>,
}

impl GpuUltrasound {
    pub fn new(ctx: &GpuContext) -> GpuUltrasound {
        GpuUltrasound {
            pipelines: Pipelines::new("ultrasound.wgsl", SHADER),
            params: uniform_buffer(ctx, "ultrasound params", std::mem::size_of::<UsParams>()),
            flow: None,
            motion: GpuMotion::new(ctx),
            timer: PassTimer::new(ctx),
            last_pass_ms: None,
        }
    }

    /// The GPU's own time for the last frame's pass (ms), where the adapter has timestamps.
    pub fn last_pass_ms(&self) -> Option<f64> {
        self.last_pass_ms
    }

    /// One frame of `scene` (before scan conversion), as `stylet_render::ultrasound::render`.
    pub fn render(&mut self, ctx: &GpuContext, vol: &GpuVolume, scene: &UltrasoundScene) -> Result<Sonogram, GpuError> {
        let atlas = &vol.atlas;
        check_scene(scene, atlas).map_err(|e| GpuError::Invalid(e.to_string()))?;
        let s = scene.settings;
        let geometry = ScanGeometry::new(&scene.probe, s.lines, s.samples, s.depth_mm);
        let n = s.lines as u64 * s.samples as u64;
        ctx.check_storage_buffer("the ultrasound frame", n * 4)?;
        let tables = FrameTables::new(&s);
        // Two per line: where and how squarely the line meets an instrument, and how that
        // instrument echoes.
        let hits: Vec<[f32; 4]> = needle_hits(scene, &geometry)
            .into_iter()
            .flat_map(|h| match h {
                Some((h, j)) => [
                    [h.hit.depth_mm, h.hit.specular, j as f32, 1.0],
                    [h.echo.reflection, h.echo.transmission, h.echo.ring_mm, 0.0],
                ],
                None => [[0.0; 4]; 2],
            })
            .collect();
        let classes = {
            let c = scene.echo.packed(&scene.consequences.air_in_pleura);
            if c.is_empty() { vec![0] } else { c }
        };
        let grid = atlas.ct().grid();
        let map = IndexMap::of(grid);
        let (flow_first, flow_dims) = match &scene.doppler {
            Some(field) => {
                let (first, dims) = self.upload_flow(ctx, field, vol)?;
                ([first[0], first[1], first[2], 0], dims)
            }
            None => ([0; 4], [1, 1, 1]),
        };
        let props = |p: stylet_render::ultrasound::SampleProps| [p.z, p.loss, p.scatter, 0.0];
        let speed = |k: EchoClass| doppler::speed_m_s(doppler::pressure_pa(k, scene.time_s));
        let params = UsParams {
            face: v4(geometry.face_mm, 0.0),
            lateral: v4(geometry.lateral, 0.0),
            beam: v4(geometry.beam, 0.0),
            row0: v4(map.rows[0], 0.0),
            row1: v4(map.rows[1], 0.0),
            row2: v4(map.rows[2], 0.0),
            origin: v4(map.origin, 0.0),
            dims: [map.dims[0], map.dims[1], map.dims[2], classes.len() as u32],
            scan: [
                s.lines,
                s.samples,
                (scene.probe.kind == stylet_physics::ProbeKind::Convex) as u32,
                scene.doppler.is_some() as u32,
            ],
            geo: [
                s.depth_mm,
                geometry.sample_mm(),
                CONVEX_RADIUS_MM,
                CONVEX_HALF_ANGLE_DEG.to_radians(),
            ],
            gains: [SPECULAR_GAIN, SCATTER_GAIN, GEL_MRAYL, GEL_MAX_MM],
            limits: [
                AIR_BELOW_HU,
                DOPPLER_MIN_SIGNAL,
                speed(EchoClass::Vein),
                speed(EchoClass::Artery),
            ],
            doppler: [CELL_MM as f32, WALL_FILTER_M_S, SCALE_M_S, 0.0],
            reverb: [REVERB_DECAY, REVERB_ECHOES as f32, 0.0, 0.0],
            fluid: props(tables.fluid),
            blood: props(tables.blood),
            flow_first,
            flow_dims: [
                flow_dims[0],
                flow_dims[1],
                flow_dims[2],
                speckle::lattice_seed(scene.seed),
            ],
            collect: [
                scene.consequences.collections.len() as f32,
                COLLECTION_MIN_HU,
                COLLECTION_MAX_HU,
                PLEURA_SCATTER,
            ],
        };
        ctx.queue.write_buffer(&self.params, 0, bytemuck::bytes_of(&params));
        let lut: Vec<[f32; 4]> = tables.tissue.iter().map(|&p| props(p)).collect();
        let classes = storage(ctx, "echo classes", bytemuck::cast_slice(&classes));
        let lut = storage(ctx, "tissue table", bytemuck::cast_slice(&lut));
        let tgc = storage(ctx, "tgc", bytemuck::cast_slice(&tables.tgc));
        let hits = storage(ctx, "needle hits", bytemuck::cast_slice(&hits));
        let mut fluid: Vec<[f32; 4]> = scene
            .consequences
            .collections
            .iter()
            .flat_map(|c| [v4(c.centre_mm, c.radius_mm * c.radius_mm), props(tables.collection(c))])
            .collect();
        if fluid.is_empty() {
            fluid.push([0.0; 4]);
        }
        let fluid = storage(ctx, "fluid collections", bytemuck::cast_slice(&fluid));
        let empty_flow;
        let flow = match (&self.flow, &scene.doppler) {
            (Some(f), Some(_)) => &f.buffer,
            _ => {
                empty_flow = storage(ctx, "no flow", bytemuck::cast_slice(&[[0.0f32; 4]]));
                &empty_flow
            }
        };
        let out = |label: &str| {
            ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: n * 4,
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            })
        };
        let (env, col) = (out("ultrasound envelope"), out("ultrasound colour"));
        let pipeline = self.pipelines.get(ctx, ct_prelude(vol.ct_key()));
        self.motion.prepare(ctx, scene.breathing.as_ref())?;
        let mut entries = numbered([
            self.params.as_entire_binding(),
            vol.ct_binding(),
            wgpu::BindingResource::TextureView(&vol.partial_view),
            classes.as_entire_binding(),
            lut.as_entire_binding(),
            tgc.as_entire_binding(),
            hits.as_entire_binding(),
            flow.as_entire_binding(),
            env.as_entire_binding(),
            col.as_entire_binding(),
            fluid.as_entire_binding(),
        ]);
        entries.extend(self.motion.entries());
        // One workgroup per scan line (ultrasound.wgsl).
        dispatch(ctx, &pipeline, &entries, (s.lines, 1), self.timer.as_ref());
        let [envelope, packed] = ctx.read_buffers([(&env, n * 4), (&col, n * 4)])?;
        self.last_pass_ms = self.timer.as_ref().and_then(|t| t.read_ms(ctx));
        let envelope: Vec<f32> = GpuContext::values(&envelope);
        let packed: Vec<u32> = GpuContext::values(&packed);
        let colour = packed
            .iter()
            .map(|&p| [p as u8, (p >> 8) as u8, (p >> 16) as u8])
            .collect();
        let flags = packed
            .iter()
            .map(|&p| ((p >> 24) as u8) & (FLAG_TARGET | FLAG_DOPPLER))
            .collect();
        Ok(Sonogram {
            geometry,
            bmode: compress(&envelope, &s),
            colour,
            flags,
            guide_mm: scene.guide_mm,
            outline_target: scene.outline_target,
        })
    }

    /// Uploads `field` on a dense grid over the CT's box (once per field and volume).
    fn upload_flow(
        &mut self,
        ctx: &GpuContext,
        field: &Arc<FlowField>,
        vol: &GpuVolume,
    ) -> Result<([i32; 3], [u32; 3]), GpuError> {
        if let Some(f) = &self.flow
            && Arc::ptr_eq(&f.field, field)
            && f.volume == vol.id
        {
            return Ok((f.first, f.dims));
        }
        let (lo, hi) = vol.atlas.ct().grid().world_bounds();
        let dense = field.dense(lo, hi);
        ctx.check_storage_buffer("the flow axes", dense.axes.len() as u64 * 16)?;
        let buffer = storage(ctx, "flow axes", bytemuck::cast_slice(&dense.axes));
        self.flow = Some(UploadedFlow {
            field: field.clone(),
            volume: vol.id,
            first: dense.first_cell,
            dims: dense.dims,
            buffer,
        });
        Ok((dense.first_cell, dense.dims))
    }
}
