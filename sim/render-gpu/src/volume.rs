//! The atlas volumes on the GPU, uploaded once per atlas (docs/rendering.md "Inputs"): the CT as
//! 16-bit integers when every value is an integer in i16 range (real CT), else as 32-bit floats;
//! the ray caster's records of value and central differences (`GradientVolume`, the CPU
//! reference's own, 4 × 16-bit integers or 4 × f32 a voxel), so a shaded sample reads 8 texels
//! instead of the 56 that differences formed on the fly need;
//! the rendered labels l(x) and the partial labels (MPR overlay) as 16-bit integers; the label
//! styles in a small buffer. Shaders read voxels with `textureLoad` (manual trilinear
//! interpolation), so they see exactly the CPU's values, with one exception chosen at upload
//! ([`RecordFilter`]): on a hardware GPU the ray caster may let the texture unit interpolate the
//! records, one filtered read instead of eight loads, with the weights at the hardware's
//! precision.

use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use crate::{GpuContext, GpuError};
use bytemuck::{Pod, Zeroable};
use stylet_physics::PunctureAtlas;
use stylet_render::raycast::gradient_volume::RecordSlice;
use stylet_render::raycast::occupancy::cell_ranges;
use stylet_render::volume::{CellRanges, RenderVolume, TagClass};

/// How the CT is stored on the GPU.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CtFormat {
    /// R16Sint: every value an integer in −32768 … 32767 (real CT, 2 bytes a voxel).
    Int16,
    /// R32Float: anything else (the procedural phantom's partial-volume values).
    Float32,
}

/// A label's style as the ray-casting shader reads it (32 bytes).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub(crate) struct GpuStyle {
    pub rgba: [f32; 4],
    /// 0 other, 1 target, 2 risk (eq. 3.2.4).
    pub class: u32,
    pub _pad: [u32; 3],
}

/// Where to put the CT. `Auto`: a storage buffer on software adapters (lavapipe fetches texels
/// through its general texture path; a buffer read is a plain load there) when it fits the
/// binding limit, else a 3D texture (tiled, cache friendly on hardware). The environment variable
/// STYLET_GPU_CT=texture|buffer overrides `Auto` for measuring.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CtPlacement {
    Auto,
    Texture,
    Buffer,
}

/// How the ray caster interpolates the gradient records (the trilinear read of a shaded sample,
/// docs/rendering.md "GPU on hardware").
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RecordFilter {
    /// `Hardware` where it can be and pays: 16-bit records in a texture on a hardware adapter
    /// with 16-bit normalised textures (`TEXTURE_FORMAT_16BIT_NORM`); else `Shader`.
    Auto,
    /// Eight texel loads blended in the shader in the CPU's order: the CPU's values up to f32
    /// rounding.
    Shader,
    /// One read filtered by the texture unit: the records as `Rgba16Snorm` (the same 16-bit
    /// integers, read as i/32767 and scaled back), clamp-to-edge addressing, which is the CPU's
    /// clamp of c into [0, n − 1]. The voxel values are exact; the trilinear weights have the
    /// hardware's precision (8 fractional bits on NVIDIA and AMD: 1/256 voxel), so a sample may
    /// differ from the CPU's by up to 1/512 of the step between neighbouring voxels.
    Hardware,
}

/// Choices made when the volumes are uploaded; the defaults pick what is fastest on the adapter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UploadOptions {
    pub placement: CtPlacement,
    pub records: RecordFilter,
}

impl Default for UploadOptions {
    fn default() -> Self {
        UploadOptions {
            placement: CtPlacement::Auto,
            records: RecordFilter::Auto,
        }
    }
}

/// Where the CT voxels live on the GPU (both read voxel by voxel, never filtered).
pub(crate) enum CtStore {
    Texture(wgpu::TextureView),
    /// Voxels in x-fastest order: i16 pairs packed in u32 words, or f32.
    Buffer(wgpu::Buffer),
}

/// Where the gradient records live (the CT's placement when they fit there too).
pub(crate) enum RecordsStore {
    Texture(wgpu::TextureView),
    /// [`RecordFilter::Hardware`]: `Rgba16Snorm` and its linear, clamp-to-edge sampler.
    Filtered(wgpu::TextureView, wgpu::Sampler),
    /// Records in x-fastest order: four i16 in two u32 words, or four f32.
    Buffer(wgpu::Buffer),
}

/// The records' declaration for the ray-casting shader (binding 9, and the sampler at 10 when
/// filtered): `ct_record(p)` is voxel p's (Δx, Δy, Δz, I); `ct_records(c)` their trilinear
/// interpolation at index c (`Records` of raycast.wgsl), by the shader's eight loads
/// (`ct_records_fixed` for 16-bit records, blended as the CPU blends them; `ct_records_exact`
/// for float ones) or by the texture unit.
pub(crate) fn records_prelude(store: &RecordsStore, int16: bool) -> &'static str {
    match (store, int16) {
        (RecordsStore::Texture(_), true) => {
            "@group(0) @binding(9) var records: texture_3d<i32>;\n\
             fn ct_record(p: vec3<i32>) -> vec4<f32> { return vec4<f32>(textureLoad(records, p, 0)); }\n\
             fn ct_records(c: vec3<f32>) -> Records { return ct_records_fixed(c); }\n"
        }
        (RecordsStore::Texture(_), false) => {
            "@group(0) @binding(9) var records: texture_3d<f32>;\n\
             fn ct_record(p: vec3<i32>) -> vec4<f32> { return textureLoad(records, p, 0); }\n\
             fn ct_records(c: vec3<f32>) -> Records { return ct_records_exact(c); }\n"
        }
        (RecordsStore::Buffer(_), true) => {
            "@group(0) @binding(9) var<storage, read> records: array<vec2<u32>>;\n\
             fn ct_record(p: vec3<i32>) -> vec4<f32> {\n\
                 let w = records[u32(p.x) + P.dims.x * (u32(p.y) + P.dims.y * u32(p.z))];\n\
                 return vec4<f32>(vec4<i32>(bitcast<i32>(w.x << 16u) >> 16u, bitcast<i32>(w.x) >> 16u,\n\
                                            bitcast<i32>(w.y << 16u) >> 16u, bitcast<i32>(w.y) >> 16u));\n\
             }\n\
             fn ct_records(c: vec3<f32>) -> Records { return ct_records_fixed(c); }\n"
        }
        (RecordsStore::Buffer(_), false) => {
            "@group(0) @binding(9) var<storage, read> records: array<vec4<f32>>;\n\
             fn ct_record(p: vec3<i32>) -> vec4<f32> {\n\
                 return records[u32(p.x) + P.dims.x * (u32(p.y) + P.dims.y * u32(p.z))];\n\
             }\n\
             fn ct_records(c: vec3<f32>) -> Records { return ct_records_exact(c); }\n"
        }
        // Texel centres sit at (i + 1/2)/n in normalised coordinates, so index c reads at
        // (c + 1/2)/n; the inside rule is lerp_setup's.
        (RecordsStore::Filtered(..), _) => {
            "@group(0) @binding(9) var records: texture_3d<f32>;\n\
             @group(0) @binding(10) var records_filter: sampler;\n\
             fn ct_record(p: vec3<i32>) -> vec4<f32> { return round(textureLoad(records, p, 0) * 32767.0); }\n\
             fn ct_records(c: vec3<f32>) -> Records {\n\
                 let n = vec3<f32>(P.dims.xyz);\n\
                 if !(all(c >= vec3<f32>(-0.5)) && all(c < n - vec3<f32>(0.5))) {\n\
                     return Records(false, vec4<f32>(0.0));\n\
                 }\n\
                 let r = textureSampleLevel(records, records_filter, (c + vec3<f32>(0.5)) / n, 0.0);\n\
                 return Records(true, r * 32767.0);\n\
             }\n"
        }
    }
}

static NEXT_ID: AtomicU64 = AtomicU64::new(1);

/// The atlas on the GPU.
pub struct GpuVolume {
    /// Unique per upload: caches (occupancy, pipelines) are keyed by it.
    pub(crate) id: u64,
    pub(crate) atlas: Arc<PunctureAtlas>,
    pub(crate) format: CtFormat,
    pub(crate) ct: CtStore,
    pub(crate) records: RecordsStore,
    records_int16: bool,
    pub(crate) labels_view: wgpu::TextureView,
    pub(crate) partial_view: wgpu::TextureView,
    pub(crate) styles: wgpu::Buffer,
    pub(crate) style_count: u32,
    /// `RenderVolume::value_range_hu`: the span of the transfer table.
    pub(crate) value_range_hu: (f32, f32),
    /// MPR overlay colours by label id: (RGBA8 packed, 1 when the id is in the label table).
    pub(crate) mpr_colors: wgpu::Buffer,
    pub(crate) mpr_color_count: u32,
    ranges: Mutex<HashMap<u32, Arc<CellRanges>>>,
    bytes: u64,
}

impl GpuVolume {
    /// Uploads the CT, labels and styles (checks the device limits first), the CT where it is
    /// fastest for the adapter ([`CtPlacement::Auto`], [`RecordFilter::Auto`]).
    pub fn upload(ctx: &GpuContext, vol: &RenderVolume) -> Result<GpuVolume, GpuError> {
        Self::upload_with(ctx, vol, UploadOptions::default())
    }

    /// [`GpuVolume::upload`] with the CT's placement and the records' filtering chosen (tests
    /// cover every shader variant; the timing example compares them). Asking for
    /// [`RecordFilter::Hardware`] where it cannot be had is an error, not a silent fallback.
    pub fn upload_with(ctx: &GpuContext, vol: &RenderVolume, options: UploadOptions) -> Result<GpuVolume, GpuError> {
        let placement = options.placement;
        let atlas = vol.atlas.clone();
        let ct = atlas.ct();
        let dims = ct.grid().dims();
        ctx.check_texture_3d("the CT", dims)?;
        if vol.labels.len() != ct.data().len() {
            return Err(GpuError::Invalid(format!(
                "{} labels for {} CT voxels",
                vol.labels.len(),
                ct.data().len()
            )));
        }
        let int16 = ct
            .data()
            .iter()
            .all(|&v| v.fract() == 0.0 && (i16::MIN as f32..=i16::MAX as f32).contains(&v));
        let (format, ct_bytes): (CtFormat, Vec<u8>) = if int16 {
            let v: Vec<i16> = ct.data().iter().map(|&v| v as i16).collect();
            (CtFormat::Int16, bytemuck::cast_slice(&v).to_vec())
        } else {
            (CtFormat::Float32, bytemuck::cast_slice(ct.data()).to_vec())
        };
        let (tex_format, texel) = match format {
            CtFormat::Int16 => (wgpu::TextureFormat::R16Sint, 2),
            CtFormat::Float32 => (wgpu::TextureFormat::R32Float, 4),
        };
        let buffer = match placement {
            CtPlacement::Texture => false,
            CtPlacement::Buffer => {
                ctx.check_storage_buffer("the CT", ct_bytes.len().next_multiple_of(4) as u64)?;
                true
            }
            CtPlacement::Auto => {
                let fits = ctx
                    .check_storage_buffer("the CT", ct_bytes.len().next_multiple_of(4) as u64)
                    .is_ok();
                match std::env::var("STYLET_GPU_CT").as_deref() {
                    Ok("texture") => false,
                    Ok("buffer") => fits,
                    _ => fits && ctx.adapter().device_type == "Cpu",
                }
            }
        };
        let ct = if buffer {
            let mut bytes = ct_bytes.clone();
            bytes.resize(bytes.len().next_multiple_of(4), 0);
            CtStore::Buffer(storage(ctx, "ct", &bytes))
        } else {
            CtStore::Texture(texture_3d(ctx, "ct", dims, tex_format, texel, &ct_bytes))
        };
        let grads = vol.gradient_volume();
        let (records_int16, record_bytes): (bool, &[u8]) = match grads.records() {
            RecordSlice::Int16(r) => (true, bytemuck::cast_slice(r)),
            RecordSlice::Float32(r) => (false, bytemuck::cast_slice(r)),
        };
        let records_in_buffer = buffer
            && ctx
                .check_storage_buffer("the records", record_bytes.len() as u64)
                .is_ok();
        let can_filter = records_int16 && !records_in_buffer && ctx.has_16bit_norm();
        let filtered = match options.records {
            RecordFilter::Shader => false,
            RecordFilter::Auto => can_filter && ctx.adapter().device_type != "Cpu",
            RecordFilter::Hardware if can_filter => true,
            RecordFilter::Hardware => {
                return Err(GpuError::Invalid(format!(
                    "hardware filtering of the records needs 16-bit records ({}) in a texture ({}) \
                     and an adapter with 16-bit normalised textures ({})",
                    if records_int16 {
                        "yes"
                    } else {
                        "no: the CT has fractional values"
                    },
                    if records_in_buffer {
                        "no: in a storage buffer"
                    } else {
                        "yes"
                    },
                    if ctx.has_16bit_norm() { "yes" } else { "no" },
                )));
            }
        };
        let records = if records_in_buffer {
            RecordsStore::Buffer(storage(ctx, "gradient records", record_bytes))
        } else if filtered {
            let view = texture_3d(
                ctx,
                "gradient records (filtered)",
                dims,
                wgpu::TextureFormat::Rgba16Snorm,
                8,
                record_bytes,
            );
            let sampler = ctx.device.create_sampler(&wgpu::SamplerDescriptor {
                label: Some("gradient records"),
                address_mode_u: wgpu::AddressMode::ClampToEdge,
                address_mode_v: wgpu::AddressMode::ClampToEdge,
                address_mode_w: wgpu::AddressMode::ClampToEdge,
                mag_filter: wgpu::FilterMode::Linear,
                min_filter: wgpu::FilterMode::Linear,
                ..Default::default()
            });
            RecordsStore::Filtered(view, sampler)
        } else {
            let (format, texel) = if records_int16 {
                (wgpu::TextureFormat::Rgba16Sint, 8)
            } else {
                (wgpu::TextureFormat::Rgba32Float, 16)
            };
            RecordsStore::Texture(texture_3d(ctx, "gradient records", dims, format, texel, record_bytes))
        };
        let labels_view = texture_3d(
            ctx,
            "labels",
            dims,
            wgpu::TextureFormat::R16Uint,
            2,
            bytemuck::cast_slice(&vol.labels),
        );
        let partial_view = texture_3d(
            ctx,
            "partial labels",
            dims,
            wgpu::TextureFormat::R16Uint,
            2,
            bytemuck::cast_slice(atlas.partial_labels().data()),
        );
        let mut styles: Vec<GpuStyle> = vol
            .styles
            .iter()
            .map(|s| GpuStyle {
                rgba: s.rgba,
                class: match s.class {
                    TagClass::Other => 0,
                    TagClass::Target => 1,
                    TagClass::Risk => 2,
                },
                _pad: [0; 3],
            })
            .collect();
        if styles.is_empty() {
            styles.push(GpuStyle::zeroed());
        }
        let table = atlas.label_table();
        let max_id = table.labels().iter().map(|l| l.id).max().unwrap_or(0) as usize;
        // (RGBA8, 1 when the id is in the label table): mpr.rs skips ids without a position.
        let mut colors = vec![[0u32; 2]; max_id + 1];
        for (pos, label) in table.labels().iter().enumerate() {
            colors[label.id as usize] = [u32::from_le_bytes(atlas.materials().color(pos)), 1];
        }
        let color_count = colors.len() as u32;
        ctx.check_storage_buffer("label styles", (styles.len() * 32) as u64)?;
        let style_count = styles.len() as u32;
        let styles = storage(ctx, "label styles", bytemuck::cast_slice(&styles));
        let mpr_colors = storage(ctx, "label colours", bytemuck::cast_slice(colors.as_flattened()));
        let bytes = ct_bytes.len() as u64 + record_bytes.len() as u64 + 4 * dims.iter().product::<usize>() as u64;
        Ok(GpuVolume {
            id: NEXT_ID.fetch_add(1, Ordering::Relaxed),
            atlas,
            format,
            ct,
            records,
            records_int16,
            labels_view,
            partial_view,
            styles,
            style_count,
            value_range_hu: vol.value_range_hu,
            mpr_colors,
            mpr_color_count: color_count,
            ranges: Mutex::new(HashMap::new()),
            bytes,
        })
    }

    /// How the CT is stored.
    pub fn ct_format(&self) -> CtFormat {
        self.format
    }

    /// Whether the CT lives in a storage buffer (software adapters) rather than a 3D texture.
    pub fn ct_in_buffer(&self) -> bool {
        matches!(self.ct, CtStore::Buffer(_))
    }

    /// The shader variant this volume needs: (format, in a buffer).
    pub(crate) fn ct_key(&self) -> (CtFormat, bool) {
        (self.format, self.ct_in_buffer())
    }

    /// How the ray caster interpolates the records of this upload (`Shader` or `Hardware`).
    pub fn record_filter(&self) -> RecordFilter {
        match self.records {
            RecordsStore::Filtered(..) => RecordFilter::Hardware,
            _ => RecordFilter::Shader,
        }
    }

    /// The ray-casting shader's declarations of the CT and the records.
    pub(crate) fn raycast_prelude(&self) -> String {
        format!(
            "{}{}",
            crate::raycast::ct_prelude(self.ct_key()),
            records_prelude(&self.records, self.records_int16)
        )
    }

    /// The records' bindings (9, and the sampler at 10 when filtered).
    pub(crate) fn records_bindings(&self) -> Vec<wgpu::BindingResource<'_>> {
        match &self.records {
            RecordsStore::Texture(v) => vec![wgpu::BindingResource::TextureView(v)],
            RecordsStore::Buffer(b) => vec![b.as_entire_binding()],
            RecordsStore::Filtered(v, sampler) => vec![
                wgpu::BindingResource::TextureView(v),
                wgpu::BindingResource::Sampler(sampler),
            ],
        }
    }

    pub(crate) fn ct_binding(&self) -> wgpu::BindingResource<'_> {
        match &self.ct {
            CtStore::Texture(v) => wgpu::BindingResource::TextureView(v),
            CtStore::Buffer(b) => b.as_entire_binding(),
        }
    }

    /// Bytes of volume textures on the GPU.
    pub fn texture_bytes(&self) -> u64 {
        self.bytes
    }

    /// Per-cell CT ranges of an N³ grid (the CPU reference's `cell_ranges`), once per N.
    pub(crate) fn cell_ranges(&self, cells: u32) -> Arc<CellRanges> {
        let mut map = self.ranges.lock().unwrap_or_else(|e| e.into_inner());
        map.entry(cells)
            .or_insert_with(|| Arc::new(cell_ranges(self.atlas.ct(), cells)))
            .clone()
    }
}

pub(crate) fn texture_3d(
    ctx: &GpuContext,
    label: &str,
    dims: [usize; 3],
    format: wgpu::TextureFormat,
    texel_bytes: u32,
    data: &[u8],
) -> wgpu::TextureView {
    let size = wgpu::Extent3d {
        width: dims[0] as u32,
        height: dims[1] as u32,
        depth_or_array_layers: dims[2] as u32,
    };
    let tex = ctx.device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size,
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D3,
        format,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    ctx.queue.write_texture(
        wgpu::TexelCopyTextureInfo {
            texture: &tex,
            mip_level: 0,
            origin: wgpu::Origin3d::ZERO,
            aspect: wgpu::TextureAspect::All,
        },
        data,
        wgpu::TexelCopyBufferLayout {
            offset: 0,
            bytes_per_row: Some(dims[0] as u32 * texel_bytes),
            rows_per_image: Some(dims[1] as u32),
        },
        size,
    );
    tex.create_view(&Default::default())
}

pub(crate) fn storage(ctx: &GpuContext, label: &str, data: &[u8]) -> wgpu::Buffer {
    use wgpu::util::DeviceExt;
    ctx.device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some(label),
        contents: data,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
    })
}
