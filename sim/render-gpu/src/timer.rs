//! GPU time of one compute pass, from two timestamps the GPU itself writes (wgpu's
//! `TIMESTAMP_QUERY`), so a frame time excludes the upload of the uniforms, the submission and
//! the copy of the image back to the CPU. Absent where the adapter has no timestamps.

use crate::GpuContext;

/// Two timestamps around a pass and the buffers that bring them back.
pub(crate) struct PassTimer {
    queries: wgpu::QuerySet,
    resolved: wgpu::Buffer,
    readback: wgpu::Buffer,
    /// Nanoseconds per timestamp tick (`Queue::get_timestamp_period`).
    period_ns: f64,
}

impl PassTimer {
    /// A timer when the device was opened with `TIMESTAMP_QUERY`, else `None`.
    pub(crate) fn new(ctx: &GpuContext) -> Option<PassTimer> {
        if !ctx.device.features().contains(wgpu::Features::TIMESTAMP_QUERY) {
            return None;
        }
        let queries = ctx.device.create_query_set(&wgpu::QuerySetDescriptor {
            label: Some("pass timestamps"),
            ty: wgpu::QueryType::Timestamp,
            count: 2,
        });
        let buffer = |label, usage| {
            ctx.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: 2 * wgpu::QUERY_SIZE as u64,
                usage,
                mapped_at_creation: false,
            })
        };
        Some(PassTimer {
            queries,
            resolved: buffer(
                "resolved timestamps",
                wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
            ),
            readback: buffer(
                "timestamps readback",
                wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            ),
            period_ns: ctx.queue.get_timestamp_period() as f64,
        })
    }

    /// Where the pass writes its start (0) and end (1).
    pub(crate) fn writes(&self) -> wgpu::ComputePassTimestampWrites<'_> {
        wgpu::ComputePassTimestampWrites {
            query_set: &self.queries,
            beginning_of_pass_write_index: Some(0),
            end_of_pass_write_index: Some(1),
        }
    }

    /// Records, after the pass, the copy of its timestamps to the mappable buffer.
    pub(crate) fn resolve(&self, enc: &mut wgpu::CommandEncoder) {
        enc.resolve_query_set(&self.queries, 0..2, &self.resolved, 0);
        enc.copy_buffer_to_buffer(&self.resolved, 0, &self.readback, 0, 2 * wgpu::QUERY_SIZE as u64);
    }

    /// The last pass' duration in milliseconds (blocks until the GPU has written it); `None` if
    /// the mapping fails or the clock went backwards.
    pub(crate) fn read_ms(&self, ctx: &GpuContext) -> Option<f64> {
        let (tx, rx) = std::sync::mpsc::channel();
        self.readback.slice(..).map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        ctx.device.poll(wgpu::PollType::wait_indefinitely()).ok()?;
        rx.recv().ok()?.ok()?;
        let ticks: [u64; 2] = {
            let view = self.readback.slice(..).get_mapped_range().ok()?;
            let t: &[u64] = bytemuck::cast_slice(&view);
            [t[0], t[1]]
        };
        self.readback.unmap();
        let elapsed = ticks[1].checked_sub(ticks[0])?;
        Some(elapsed as f64 * self.period_ns * 1e-6)
    }
}
