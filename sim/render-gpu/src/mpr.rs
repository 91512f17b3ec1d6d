//! MPR on the GPU (placeholder while the ray caster is brought up).
pub struct GpuMpr;
pub struct SliceGeometry;
