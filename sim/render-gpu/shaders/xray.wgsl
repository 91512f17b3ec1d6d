// Simulated X-ray (docs/xray.md): one invocation per detector pixel, 8 × 8 workgroups. A port
// of stylet-render's xray module: Joseph's line integral through the CT (joseph.rs `integrate`,
// the same plane order and bilinear sums), the contrast overlay on the same planes, and the
// needle's steel chords (needle.rs `chord_mm`). The CT declaration and `ct_voxel` are
// prepended by the host, as for raycast.wgsl. Output: a = −ln(I/I₀) per pixel. A breathing
// patient (xray/mod.rs `render_moving`): the samples on the planes are read at their reference
// points (joseph.rs `integrate_warped`; the motion is motion.wgsl's).

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
    size: vec4<u32>,      // width, height, instrument segments, 1 when there is contrast
    c_origin: vec4<f32>,  // contrast box: first CT voxel
    c_dims: vec4<u32>,    // contrast box: voxels per axis
    consts: vec4<f32>,    // μ_water/1000 per mm, unused ×3
}

@group(0) @binding(0) var<uniform> P: Params;
// binding 1: the CT (prepended by the host)
@group(0) @binding(2) var<storage, read> contrast: array<f32>;
// The instruments' segments (xray/mod.rs `segments`), two words each: (a, r'), (b, μ').
@group(0) @binding(3) var<storage, read> segments: array<vec4<f32>>;
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

// joseph.rs `planes`: the planes of the dominant axis a a ray c(t) = c0 + t·d, t ∈ [0, t_max],
// crosses where its in-plane coordinates can touch a grid of `n` (u, v the other axes).
struct Planes {
    ok: bool,
    a: i32,
    u: i32,
    v: i32,
    k_first: i32,
    k_last: i32,
}

fn planes(n_u: vec3<u32>, c0: vec3<f32>, d: vec3<f32>, t_max: f32) -> Planes {
    var p = Planes(false, 2, 0, 1, 0, -1);
    let m = abs(d);
    if m.x >= m.y && m.x >= m.z {
        p.a = 0; p.u = 1; p.v = 2;
    } else if m.y >= m.z {
        p.a = 1; p.u = 0; p.v = 2;
    }
    let a = p.a;
    if abs(d[a]) < 1e-12 {
        return p;
    }
    let n = vec3<f32>(n_u);
    var t_lo = 0.0;
    var t_hi = t_max;
    for (var q = 0; q < 2; q++) {
        let b = select(p.v, p.u, q == 0);
        if d[b] == 0.0 {
            if c0[b] <= -1.0 || c0[b] >= n[b] {
                return p;
            }
        } else {
            let ta = (-1.0 - c0[b]) / d[b];
            let tb = (n[b] - c0[b]) / d[b];
            t_lo = max(t_lo, min(ta, tb));
            t_hi = min(t_hi, max(ta, tb));
        }
    }
    if t_lo > t_hi {
        return p;
    }
    let ca = c0[a] + t_lo * d[a];
    let cb = c0[a] + t_hi * d[a];
    let k_first_f = max(ceil(min(ca, cb)), 0.0);
    let k_last_f = min(floor(max(ca, cb)), n[a] - 1.0);
    if k_first_f > k_last_f {
        return p;
    }
    p.ok = true;
    p.k_first = i32(k_first_f);
    p.k_last = i32(k_last_f);
    return p;
}

// joseph.rs `integrate`: ∫ v(c(t)) dt for c(t) = c0 + t·d, t ∈ [0, t_max], on a grid of `n`.
fn integrate(src: u32, n_u: vec3<u32>, c0: vec3<f32>, d: vec3<f32>, t_max: f32) -> f32 {
    let pl = planes(n_u, c0, d, t_max);
    if !pl.ok {
        return 0.0;
    }
    let a = pl.a;
    let u = pl.u;
    let v = pl.v;
    let nu = i32(n_u[u]);
    let nv = i32(n_u[v]);
    let inv = 1.0 / d[a];
    var sum = 0.0;
    let count = pl.k_last - pl.k_first + 1;
    for (var step = 0; step < count; step++) {
        let k = select(pl.k_last - step, pl.k_first + step, d[a] > 0.0);
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

// joseph.rs `trilinear_zero_outside`: the trilinear field of source `src` (a grid of `n`) at
// index c, zero outside the voxels.
fn trilinear_zero(src: u32, n_u: vec3<u32>, c: vec3<f32>) -> f32 {
    let n = vec3<i32>(n_u);
    if !(all(c > vec3<f32>(-1.0)) && all(c < vec3<f32>(n_u))) {
        return 0.0;
    }
    let base = vec3<f32>(vec3<i32>(c + vec3<f32>(1.0))) - vec3<f32>(1.0);
    let f = c - base;
    let ib = vec3<i32>(base);
    var sum = 0.0;
    for (var corner = 0; corner < 8; corner++) {
        let o = vec3<i32>(corner & 1, (corner >> 1u) & 1, (corner >> 2u) & 1);
        let idx = ib + o;
        if any(idx < vec3<i32>(0)) || any(idx >= n) {
            continue;
        }
        let w3 = select(vec3<f32>(1.0) - f, f, o == vec3<i32>(1));
        sum += w3.x * w3.y * w3.z * voxel(src, idx);
    }
    return sum;
}

// μ at CT index c of a reference point: tissue, and the contrast when there is some.
fn mu_at(c: vec3<f32>) -> f32 {
    var mu = P.consts.x * trilinear_zero(0u, P.dims.xyz, c);
    if P.size.w == 1u {
        mu += trilinear_zero(1u, P.c_dims.xyz, c - P.c_origin.xyz);
    }
    return mu;
}

// joseph.rs `integrate_warped`: the CT's planes of the straight world ray x(t) = src + t·dir,
// each sample read at its reference point X (one fixed-point step from the previous one).
fn integrate_warped(c0: vec3<f32>, d: vec3<f32>, t_max: f32, src: vec3<f32>, dir: vec3<f32>) -> f32 {
    let pl = planes(P.dims.xyz, c0, d, t_max);
    if !pl.ok {
        return 0.0;
    }
    let a = pl.a;
    let inv = 1.0 / d[a];
    var warp = no_warp();
    var sum = 0.0;
    let count = pl.k_last - pl.k_first + 1;
    for (var step = 0; step < count; step++) {
        let k = select(pl.k_last - step, pl.k_first + step, d[a] > 0.0);
        let t = (f32(k) - c0[a]) * inv;
        let x = reference_of(&warp, src + dir * t) - P.origin.xyz;
        sum += mu_at(vec3<f32>(dot(P.row0.xyz, x), dot(P.row1.xyz, x), dot(P.row2.xyz, x)));
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
    var a = 0.0;
    if breathing() {
        a = integrate_warped(c0, dc, len, src, dir);
    } else {
        a = P.consts.x * integrate(0u, P.dims.xyz, c0, dc, len);
        if P.size.w == 1u {
            a += integrate(1u, P.c_dims.xyz, c0 - P.c_origin.xyz, dc, len);
        }
    }
    let count = P.size.z;
    for (var i = 0u; i < count; i++) {
        let sa = segments[2u * i];
        let sb = segments[2u * i + 1u];
        a += sb.w * chord_mm(src, dir, len, sa.xyz, sb.xyz, sa.w);
    }
    out_a[gid.y * w + gid.x] = a;
}
