//! A headless wgpu device: any adapter, the hardware one preferred, Mesa's lavapipe accepted.

use crate::GpuError;

/// What a report says about the adapter that drew.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AdapterSummary {
    pub name: String,
    /// "Vulkan", "Gl", "Metal", …
    pub backend: String,
    /// "DiscreteGpu", "Cpu" (lavapipe), …
    pub device_type: String,
    pub driver: String,
}

impl std::fmt::Display for AdapterSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} ({}, {}, {})",
            self.name, self.backend, self.device_type, self.driver
        )
    }
}

/// The device and queue every pipeline of this crate runs on.
pub struct GpuContext {
    pub(crate) device: wgpu::Device,
    pub(crate) queue: wgpu::Queue,
    pub(crate) limits: wgpu::Limits,
    adapter: AdapterSummary,
}

impl GpuContext {
    /// Opens the first adapter wgpu offers (high performance preferred, software accepted) with
    /// the adapter's own limits, so big CTs fit where the hardware allows. `WGPU_BACKEND` and
    /// `WGPU_ADAPTER_NAME` force a choice.
    pub fn new() -> Result<GpuContext, GpuError> {
        pollster::block_on(Self::open())
    }

    async fn open() -> Result<GpuContext, GpuError> {
        let desc = wgpu::InstanceDescriptor::new_without_display_handle().with_env();
        let instance = wgpu::Instance::new(desc);
        let adapter = instance
            .request_adapter(&wgpu::RequestAdapterOptions {
                power_preference: wgpu::PowerPreference::HighPerformance,
                ..Default::default()
            })
            .await
            .map_err(|e| GpuError::NoAdapter(e.to_string()))?;
        let info = adapter.get_info();
        let summary = AdapterSummary {
            name: info.name.clone(),
            backend: format!("{:?}", info.backend),
            device_type: format!("{:?}", info.device_type),
            driver: format!("{} {}", info.driver, info.driver_info).trim().to_string(),
        };
        let limits = adapter.limits();
        let (device, queue) = adapter
            .request_device(&wgpu::DeviceDescriptor {
                label: Some("stylet-render-gpu"),
                required_limits: limits.clone(),
                // GPU frame times (GpuRenderer::last_pass_ms) where the adapter has a clock;
                // filterable 16-bit records (volume::RecordFilter::Hardware) where it has them.
                required_features: adapter.features()
                    & (wgpu::Features::TIMESTAMP_QUERY | wgpu::Features::TEXTURE_FORMAT_16BIT_NORM),
                ..Default::default()
            })
            .await
            .map_err(|e| GpuError::RequestDevice {
                adapter: summary.name.clone(),
                message: e.to_string(),
            })?;
        Ok(GpuContext {
            device,
            queue,
            limits,
            adapter: summary,
        })
    }

    /// The adapter that draws (for reports and benchmarks).
    pub fn adapter(&self) -> &AdapterSummary {
        &self.adapter
    }

    /// Whether the GPU reports its own pass times (`GpuRenderer::last_pass_ms`).
    pub fn has_timestamps(&self) -> bool {
        self.device.features().contains(wgpu::Features::TIMESTAMP_QUERY)
    }

    /// Whether 16-bit normalised textures can be sampled with filtering
    /// (`volume::RecordFilter::Hardware`).
    pub fn has_16bit_norm(&self) -> bool {
        self.device
            .features()
            .contains(wgpu::Features::TEXTURE_FORMAT_16BIT_NORM)
    }

    /// The device's limits (the largest 3D texture, storage buffer, …).
    pub fn limits(&self) -> &wgpu::Limits {
        &self.limits
    }

    /// Checks a 3D texture of `dims` fits before allocating it.
    pub(crate) fn check_texture_3d(&self, what: &str, dims: [usize; 3]) -> Result<(), GpuError> {
        let limit = self.limits.max_texture_dimension_3d as u64;
        let needed = dims.iter().copied().max().unwrap_or(0) as u64;
        if needed > limit {
            return Err(GpuError::Limits {
                what: format!("{what}: 3D texture of {} × {} × {} voxels", dims[0], dims[1], dims[2]),
                needed,
                limit,
            });
        }
        Ok(())
    }

    /// Checks a storage buffer of `bytes` fits before allocating it.
    pub(crate) fn check_storage_buffer(&self, what: &str, bytes: u64) -> Result<(), GpuError> {
        let limit = self
            .limits
            .max_storage_buffer_binding_size
            .min(self.limits.max_buffer_size);
        if bytes > limit {
            return Err(GpuError::Limits {
                what: format!("{what}: storage buffer of {bytes} bytes"),
                needed: bytes,
                limit,
            });
        }
        Ok(())
    }

    /// Copies `bytes` of a storage buffer back to the CPU (blocking).
    pub(crate) fn read_buffer(&self, src: &wgpu::Buffer, bytes: u64) -> Result<Vec<u8>, GpuError> {
        let [data] = self.read_buffers([(src, bytes)])?;
        Ok(data)
    }

    /// Read-back bytes as values of `T`, copied into a `Vec<T>` so the values are aligned
    /// (a `Vec<u8>` need not be, and casting it in place could panic); trailing bytes that make
    /// no whole value are dropped (bytemuck's collect would pad them into one).
    pub(crate) fn values<T: bytemuck::Pod>(bytes: &[u8]) -> Vec<T> {
        let whole = bytes.len() - bytes.len() % std::mem::size_of::<T>().max(1);
        bytemuck::pod_collect_to_vec(&bytes[..whole])
    }

    /// The first bytes of several buffers, copied into one staging buffer and mapped once (one
    /// wait for the GPU instead of one per buffer).
    pub(crate) fn read_buffers<const N: usize>(
        &self,
        sources: [(&wgpu::Buffer, u64); N],
    ) -> Result<[Vec<u8>; N], GpuError> {
        // Copies start at multiples of 4 bytes (wgpu::COPY_BUFFER_ALIGNMENT).
        let mut offsets = [0u64; N];
        let mut total = 0u64;
        for (offset, (_, bytes)) in offsets.iter_mut().zip(&sources) {
            *offset = total;
            total += bytes.div_ceil(wgpu::COPY_BUFFER_ALIGNMENT) * wgpu::COPY_BUFFER_ALIGNMENT;
        }
        let staging = self.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: total.max(wgpu::COPY_BUFFER_ALIGNMENT),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let mut enc = self.device.create_command_encoder(&Default::default());
        for ((src, bytes), &offset) in sources.iter().zip(&offsets) {
            enc.copy_buffer_to_buffer(src, 0, &staging, offset, *bytes);
        }
        self.queue.submit([enc.finish()]);
        let (tx, rx) = std::sync::mpsc::channel();
        staging.slice(..).map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        rx.recv()
            .map_err(|e| GpuError::Readback(e.to_string()))?
            .map_err(|e| GpuError::Readback(e.to_string()))?;
        let data = {
            let view = staging
                .slice(..)
                .get_mapped_range()
                .map_err(|e| GpuError::Readback(e.to_string()))?;
            std::array::from_fn(|k| view[offsets[k] as usize..(offsets[k] + sources[k].1) as usize].to_vec())
        };
        staging.unmap();
        Ok(data)
    }
}

#[cfg(test)]
mod tests {
    use super::GpuContext;

    /// Values come back whatever the bytes' address: from a slice starting at an odd byte, and
    /// with trailing bytes that make no whole value.
    #[test]
    fn read_back_bytes_become_values_at_any_alignment() {
        let want = [1.5f32, -2.25, f32::MAX];
        let mut bytes = vec![0u8];
        bytes.extend(want.iter().flat_map(|v| v.to_le_bytes()));
        bytes.push(7);
        let got: Vec<f32> = GpuContext::values(&bytes[1..]);
        assert_eq!(got, want);
        assert!(GpuContext::values::<u32>(&[1, 2, 3]).is_empty());
    }
}
