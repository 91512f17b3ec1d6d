// The CT's trilinear value in f32 (`stylet_render::mpr::sample_ct_f32`, `Grid3::trilinear`): air
// outside -1/2 <= c < n - 1/2, clamped to the voxel centres inside; an axis of one voxel reads it
// with weight 1. Shared by mpr.wgsl and ultrasound.wgsl (the host prepends it); the shader
// declares `P.dims` and `AIR_HU`, and the CT prelude `ct_voxel`.
fn sample_ct(c: vec3<f32>) -> f32 {
    var i0 = vec3<i32>(0);
    var i1 = vec3<i32>(0);
    var f = vec3<f32>(0.0);
    for (var a = 0; a < 3; a++) {
        let na = P.dims[a];
        let n = f32(na);
        let x0 = c[a];
        if !(x0 >= -0.5 && x0 < n - 0.5) {
            return AIR_HU;
        }
        let x = clamp(x0, 0.0, n - 1.0);
        let b = min(u32(x), select(0u, na - 2u, na >= 2u));
        i0[a] = i32(b);
        i1[a] = i32(b + select(0u, 1u, na > 1u));
        f[a] = select(x - f32(b), 0.0, na == 1u);
    }
    let fx = f.x;
    let fy = f.y;
    let fz = f.z;
    let c00 = ct_voxel(vec3<i32>(i0.x, i0.y, i0.z)) * (1.0 - fx) + ct_voxel(vec3<i32>(i1.x, i0.y, i0.z)) * fx;
    let c10 = ct_voxel(vec3<i32>(i0.x, i1.y, i0.z)) * (1.0 - fx) + ct_voxel(vec3<i32>(i1.x, i1.y, i0.z)) * fx;
    let c01 = ct_voxel(vec3<i32>(i0.x, i0.y, i1.z)) * (1.0 - fx) + ct_voxel(vec3<i32>(i1.x, i0.y, i1.z)) * fx;
    let c11 = ct_voxel(vec3<i32>(i0.x, i1.y, i1.z)) * (1.0 - fx) + ct_voxel(vec3<i32>(i1.x, i1.y, i1.z)) * fx;
    let c0 = c00 * (1.0 - fy) + c10 * fy;
    let c1 = c01 * (1.0 - fy) + c11 * fy;
    return c0 * (1.0 - fz) + c1 * fz;
}
