// Simulated X-ray (docs/xray.md): one invocation per detector pixel, 8 × 8 workgroups. A port
// of stylet-render's xray module: Joseph's line integral through the CT (joseph.rs `integrate`,
// the same plane order and bilinear sums), the contrast overlay on the same planes, and the
// needle's steel chords (needle.rs `chord_mm`). The CT declaration and `ct_voxel` are
// prepended by the host, as for raycast.wgsl. Output: a = −ln(I/I₀) per pixel.

// Mirrored by `XrayParams` in xray.rs.
struct Params {
    source: vec4<f32>,    // world mm
    pixel00: vec4<f32>,   // centre of pixel (0, 0), world mm
    col_step: vec4<f32>,  // world mm per column
    row_step: vec4<f32>,  // world mm per row
    row0: vec4<f32>,      // rows of the CT's inverse affine (index units per mm)
    row1: vec4<f32>,
    row2: vec4<f32>,
    origin: vec4<f32>,    // world position of voxel (0, 0, 0)
    dims: vec4<u32>,      // CT voxels
    size: vec4<u32>,      // width, height, needle nodes, 1 when there is contrast
    c_origin: vec4<f32>,  // contrast box: first CT voxel
    c_dims: vec4<u32>,    // contrast box: voxels per axis
    consts: vec4<f32>,    // μ_water/1000 per mm, the needle's μ' and r' (needle.rs `resolved_radius_and_mu`)
}

@group(0) @binding(0) var<uniform> P: Params;
// binding 1: the CT (prepended by the host)
@group(0) @binding(2) var<storage, read> contrast: array<f32>;
@group(0) @binding(3) var<storage, read> needle: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> out_a: array<f32>;

// attenuation.rs `water_relative`: HU + 1000, air and below as 0.
fn water_relative(hu: f32) -> f32 {
    return max(hu, -1000.0) + 1000.0;
}

// Voxel `p` of source `src`: 0 the CT (water-relative), 1 the contrast box (μ_c per mm).
fn voxel(src: u32, p: vec3<i32>) -> f32 {
    if src == 0u {
        return water_relative(ct_voxel(p));
    }
    let d = P.c_dims.xyz;
    return contrast[u32(p.x) + d.x * (u32(p.y) + d.y * u32(p.z))];
}

// joseph.rs `integrate`: ∫ v(c(t)) dt for c(t) = c0 + t·d, t ∈ [0, t_max], on a grid of `n`.
fn integrate(src: u32, n_u: vec3<u32>, c0: vec3<f32>, d: vec3<f32>, t_max: f32) -> f32 {
    let m = abs(d);
    var a = 2;
    var u = 0;
    var v = 1;
    if m.x >= m.y && m.x >= m.z {
        a = 0; u = 1; v = 2;
    } else if m.y >= m.z {
        a = 1; u = 0; v = 2;
    }
    if abs(d[a]) < 1e-12 {
        return 0.0;
    }
    let n = vec3<f32>(n_u);
    var t_lo = 0.0;
    var t_hi = t_max;
    for (var q = 0; q < 2; q++) {
        let b = select(v, u, q == 0);
        if d[b] == 0.0 {
            if c0[b] <= -1.0 || c0[b] >= n[b] {
                return 0.0;
            }
        } else {
            let ta = (-1.0 - c0[b]) / d[b];
            let tb = (n[b] - c0[b]) / d[b];
            t_lo = max(t_lo, min(ta, tb));
            t_hi = min(t_hi, max(ta, tb));
        }
    }
    if t_lo > t_hi {
        return 0.0;
    }
    let ca = c0[a] + t_lo * d[a];
    let cb = c0[a] + t_hi * d[a];
    let k_first_f = max(ceil(min(ca, cb)), 0.0);
    let k_last_f = min(floor(max(ca, cb)), n[a] - 1.0);
    if k_first_f > k_last_f {
        return 0.0;
    }
    let k_first = i32(k_first_f);
    let k_last = i32(k_last_f);
    let nu = i32(n_u[u]);
    let nv = i32(n_u[v]);
    let inv = 1.0 / d[a];
    var sum = 0.0;
    let count = k_last - k_first + 1;
    for (var step = 0; step < count; step++) {
        let k = select(k_last - step, k_first + step, d[a] > 0.0);
        let t = (f32(k) - c0[a]) * inv;
        let pu = c0[u] + t * d[u];
        let pv = c0[v] + t * d[v];
        // joseph.rs `floor_above_minus_one`: ⌊x⌋ by truncation for x > −1.
        let fu0 = f32(i32(pu + 1.0)) - 1.0;
        let fv0 = f32(i32(pv + 1.0)) - 1.0;
        let fu = pu - fu0;
        let fv = pv - fv0;
        let iu = i32(fu0);
        let iv = i32(fv0);
        let w = vec4<f32>((1.0 - fu) * (1.0 - fv), fu * (1.0 - fv), (1.0 - fu) * fv, fu * fv);
        var s = 0.0;
        for (var q = 0; q < 4; q++) {
            let cu = iu + (q & 1);
            let cv = iv + (q >> 1u);
            if cu >= 0 && cu < nu && cv >= 0 && cv < nv {
                var p = vec3<i32>(0);
                p[a] = k;
                p[u] = cu;
                p[v] = cv;
                s += w[q] * voxel(src, p);
            }
        }
        sum += s;
    }
    return sum * abs(inv);
}

// needle.rs `chord_mm`: length of the ray inside the cylinder of radius r around a–b.
fn chord_mm(origin: vec3<f32>, dir: vec3<f32>, t_max: f32, a: vec3<f32>, b: vec3<f32>, r: f32) -> f32 {
    let t_near = dot(a - origin, dir);
    let p = origin + dir * t_near;
    let w = b - a;
    let ww = dot(w, w);
    if ww <= 0.0 {
        return 0.0;
    }
    let o = p - a;
    let wd = dot(w, dir);
    let wo = dot(w, o);
    let k2 = ww - wd * wd;
    let k1 = ww * dot(o, dir) - wo * wd;
    let k0 = ww * dot(o, o) - wo * wo - r * r * ww;
    var s_lo = -3.0e38;
    var s_hi = 3.0e38;
    if abs(wd) > 1e-12 {
        let s1 = -wo / wd;
        let s2 = (ww - wo) / wd;
        s_lo = min(s1, s2);
        s_hi = max(s1, s2);
    } else if !(wo >= 0.0 && wo <= ww) {
        return 0.0;
    }
    if k2 > 1e-9 * ww {
        let h = k1 * k1 - k2 * k0;
        if h <= 0.0 {
            return 0.0;
        }
        let hs = sqrt(h);
        s_lo = max(s_lo, (-k1 - hs) / k2);
        s_hi = min(s_hi, (-k1 + hs) / k2);
    } else if k0 > 0.0 {
        return 0.0;
    }
    s_lo = max(s_lo, -t_near);
    s_hi = min(s_hi, t_max - t_near);
    return max(s_hi - s_lo, 0.0);
}

@compute @workgroup_size(8, 8)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let w = P.size.x;
    let h = P.size.y;
    if gid.x >= w || gid.y >= h {
        return;
    }
    let src = P.source.xyz;
    let to = P.pixel00.xyz + P.col_step.xyz * f32(gid.x) + P.row_step.xyz * f32(gid.y) - src;
    let len = length(to);
    let dir = to / len;
    // IndexMap::point / vector.
    let q = src - P.origin.xyz;
    let c0 = vec3<f32>(dot(P.row0.xyz, q), dot(P.row1.xyz, q), dot(P.row2.xyz, q));
    let dc = vec3<f32>(dot(P.row0.xyz, dir), dot(P.row1.xyz, dir), dot(P.row2.xyz, dir));
    var a = P.consts.x * integrate(0u, P.dims.xyz, c0, dc, len);
    if P.size.w == 1u {
        a += integrate(1u, P.c_dims.xyz, c0 - P.c_origin.xyz, dc, len);
    }
    let nodes = P.size.z;
    for (var i = 1u; i < nodes; i++) {
        a += P.consts.y * chord_mm(src, dir, len, needle[i - 1u].xyz, needle[i].xyz, P.consts.z);
    }
    out_a[gid.y * w + gid.x] = a;
}
