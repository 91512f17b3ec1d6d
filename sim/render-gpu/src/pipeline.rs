//! What the GPU passes share: one compute pipeline per storage of the volumes (their
//! declarations, `raycast::ct_prelude` and for ray casting `volume::records_prelude`, are
//! prepended to the shader), built on first use, and binding resources 0 … n − 1 in order then
//! dispatching a grid of 8 × 8 workgroups.

use crate::GpuContext;
use crate::timer::PassTimer;

/// One shader's compute pipelines, one per prelude (the volumes' declarations).
pub(crate) struct Pipelines {
    label: &'static str,
    shader: &'static str,
    built: Vec<(String, wgpu::ComputePipeline)>,
}

impl Pipelines {
    pub(crate) fn new(label: &'static str, shader: &'static str) -> Pipelines {
        Pipelines {
            label,
            shader,
            built: Vec::new(),
        }
    }

    /// The pipeline for volumes declared by `prelude` (entry point `main`).
    pub(crate) fn get(&mut self, ctx: &GpuContext, prelude: &str) -> wgpu::ComputePipeline {
        if let Some((_, p)) = self.built.iter().find(|(f, _)| f == prelude) {
            return p.clone();
        }
        let source = format!("{prelude}{}", self.shader);
        let module = ctx.device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some(self.label),
            source: wgpu::ShaderSource::Wgsl(source.into()),
        });
        let p = ctx.device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
            label: Some(self.label),
            layout: None,
            module: &module,
            entry_point: Some("main"),
            compilation_options: Default::default(),
            cache: None,
        });
        self.built.push((prelude.to_string(), p.clone()));
        p
    }
}

/// `resources` at bindings 0, 1, 2, …
pub(crate) fn numbered<'a>(
    resources: impl IntoIterator<Item = wgpu::BindingResource<'a>>,
) -> Vec<wgpu::BindGroupEntry<'a>> {
    resources
        .into_iter()
        .enumerate()
        .map(|(i, resource)| wgpu::BindGroupEntry {
            binding: i as u32,
            resource,
        })
        .collect()
}

/// Binds `entries` in group 0 ([`numbered`] for bindings 0, 1, 2, …; the breathing motion adds
/// 20 and 21) and runs `groups` (x, y) workgroups, with the pass timed by `timer` when given.
pub(crate) fn dispatch(
    ctx: &GpuContext,
    pipeline: &wgpu::ComputePipeline,
    entries: &[wgpu::BindGroupEntry],
    groups: (u32, u32),
    timer: Option<&PassTimer>,
) {
    let bind = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: None,
        layout: &pipeline.get_bind_group_layout(0),
        entries,
    });
    let mut enc = ctx.device.create_command_encoder(&Default::default());
    {
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: None,
            timestamp_writes: timer.map(PassTimer::writes),
        });
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, &bind, &[]);
        pass.dispatch_workgroups(groups.0, groups.1, 1);
    }
    if let Some(t) = timer {
        t.resolve(&mut enc);
    }
    ctx.queue.submit([enc.finish()]);
}

/// A uniform buffer of `size` bytes the host rewrites each frame.
pub(crate) fn uniform_buffer(ctx: &GpuContext, label: &str, size: usize) -> wgpu::Buffer {
    ctx.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: size as u64,
        usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

/// A vector as a 16-byte WGSL vec4 (`w` in the fourth lane).
pub(crate) fn v4(v: stylet_physics::glam::Vec3, w: f32) -> [f32; 4] {
    [v.x, v.y, v.z, w]
}
