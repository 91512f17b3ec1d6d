//! What the ray-casting and MPR passes share: one compute pipeline per CT storage (the CT
//! declaration, `raycast::ct_prelude`, is prepended to the shader), built on first use, and
//! binding resources 0 … n − 1 in order then dispatching a grid of 8 × 8 workgroups.

use crate::GpuContext;
use crate::raycast::ct_prelude;
use crate::volume::CtFormat;

/// One shader's compute pipelines, one per CT storage (format, in a storage buffer or not).
pub(crate) struct Pipelines {
    label: &'static str,
    shader: &'static str,
    built: Vec<((CtFormat, bool), wgpu::ComputePipeline)>,
}

impl Pipelines {
    pub(crate) fn new(label: &'static str, shader: &'static str) -> Pipelines {
        Pipelines {
            label,
            shader,
            built: Vec::new(),
        }
    }

    /// The pipeline for a CT stored as `format` (entry point `main`).
    pub(crate) fn get(&mut self, ctx: &GpuContext, format: (CtFormat, bool)) -> wgpu::ComputePipeline {
        if let Some((_, p)) = self.built.iter().find(|(f, _)| *f == format) {
            return p.clone();
        }
        let source = format!("{}{}", ct_prelude(format), self.shader);
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
        self.built.push((format, p.clone()));
        p
    }
}

/// Binds `resources` at bindings 0, 1, 2, … of group 0 and runs `groups` (x, y) workgroups.
pub(crate) fn dispatch(
    ctx: &GpuContext,
    pipeline: &wgpu::ComputePipeline,
    resources: &[wgpu::BindingResource],
    groups: (u32, u32),
) {
    let entries: Vec<wgpu::BindGroupEntry> = resources
        .iter()
        .enumerate()
        .map(|(i, r)| wgpu::BindGroupEntry {
            binding: i as u32,
            resource: r.clone(),
        })
        .collect();
    let bind = ctx.device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: None,
        layout: &pipeline.get_bind_group_layout(0),
        entries: &entries,
    });
    let mut enc = ctx.device.create_command_encoder(&Default::default());
    {
        let mut pass = enc.begin_compute_pass(&Default::default());
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, &bind, &[]);
        pass.dispatch_workgroups(groups.0, groups.1, 1);
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
