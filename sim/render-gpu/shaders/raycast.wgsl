// Direct volume rendering by ray casting (thesis §3.2; docs/rendering.md "One ray").
//
// One invocation per pixel, 8 × 8 workgroups. This is a line-by-line port of the CPU reference
// (stylet-render: raycast/march.rs, sampler.rs, shading.rs, occupancy.rs; tools.rs; shadow.rs):
// f32, same formulas, same order; the numbered comments are the steps of docs/rendering.md.
// The CT declaration and `ct_voxel` are prepended by the host (R16Sint for integer CTs,
// R32Float otherwise; see raycast.rs). Voxels are read with textureLoad (manual trilinear
// interpolation), so the GPU sees the CPU's values; the one exception, chosen at upload, is the
// records of a shaded sample, which the texture unit may interpolate (volume.rs
// `RecordFilter::Hardware`: exact voxel values, weights at the hardware's precision).

const AIR_HU: f32 = -1000.0;
const OPAQUE: f32 = 0.99;          // Quality::OPAQUE
const MIN_GRADIENT: f32 = 1e-3;    // shading::MIN_GRADIENT (HU/mm)
const BIG: f32 = 1.0e30;           // tools.rs: no infinities
const MAX_TRAPEZOIDS: u32 = 8u;

// Switches (Params.image.z), mirrored in raycast.rs.
const F_JITTER: u32 = 1u;
const F_RAY_BOX: u32 = 2u;
const F_LEAPING: u32 = 4u;
const F_EARLY: u32 = 8u;
const F_CLIP: u32 = 16u;
const F_DEFORMED: u32 = 32u;
const F_NEEDLE_SHADOW: u32 = 64u;
const F_SAMPLE_OUTSIDE: u32 = 128u;

// Primitive kinds (tools::Primitive).
const P_CAPSULE: u32 = 0u;
const P_SPHERE: u32 = 1u;
const P_BOX: u32 = 2u;
const P_CYLINDER: u32 = 3u;

struct Trapezoid {
    hu: vec4<f32>,          // corners hu0 < hu1 <= hu2 < hu3
    rgb_opacity: vec4<f32>, // linear RGB, plateau opacity a_i (per mm)
    weight: vec4<f32>,      // x: alpha_i of eq. 3.2.2
}

// Mirrored by `Params` in raycast.rs (#[repr(C)], every member a 16-byte vector).
struct Params {
    eye: vec4<f32>,          // xyz eye (mm), w tan(fov/2)
    right: vec4<f32>,        // camera basis, w aspect (w/h)
    up: vec4<f32>,           // w step Δ (mm)
    forward: vec4<f32>,      // w t_far of the naive extent (mm)
    inv0: vec4<f32>,         // CT IndexMap: c = rows . (x - origin)
    inv1: vec4<f32>,
    inv2: vec4<f32>,
    origin: vec4<f32>,
    dims: vec4<u32>,         // CT voxels, w occupancy cells N
    occ_scale: vec4<f32>,    // N / n_a
    occ_size: vec4<f32>,     // n_a / N
    image: vec4<u32>,        // width, height, switches, trapezoid count
    modes: vec4<u32>,        // transfer kind (0 trapezoids, 1 window), tagging (0 off, 1 risk, 2 labels), primitives, styles
    window: vec4<f32>,       // level, width, opacity
    background: vec4<f32>,
    light: vec4<f32>,        // toward the light, w f_in (shadow factor)
    phong: vec4<f32>,        // ambient, diffuse, specular, shininess
    clip_point: vec4<f32>,
    clip_normal: vec4<f32>,
    def_inv0: vec4<f32>,     // deformed sub-volume J (hook of eq. 3.1.1): its IndexMap
    def_inv1: vec4<f32>,
    def_inv2: vec4<f32>,
    def_origin: vec4<f32>,
    def_dims: vec4<u32>,
    needle_tip: vec4<f32>,   // needle shadow (Alg. 3.1): tip
    needle_back: vec4<f32>,  // unit direction tip -> hub
    needle_dims: vec4<f32>,  // length along the nodes, diameter, hub length, hub diameter (mm)
    spheres: array<vec4<f32>, 2>, // sphere shadows (Alg. 3.2): centre, radius (0: none)
    traps: array<Trapezoid, 8>,
    table: vec4<f32>,        // transfer table: lo_hu, 1/step_hu, entries - 1
    margin: vec4<f32>,       // the motion's bound in CT index units per axis (0 when still)
}

struct Style {
    rgba: vec4<f32>,
    class_: u32, // 0 other, 1 target, 2 risk
    _p0: u32,
    _p1: u32,
    _p2: u32,
}

// A tool primitive (mirrored by `GpuPrimitive`):
// capsule  a = (a, r), b = (b, -)
// sphere   a = (centre, r)
// box      a = (centre, -), b/c/d = (unit axis e_i, half extent h_i)
// cylinder a = (centre, r), b = (unit axis, half length), c = (cut normal m, cut distance k)
struct Primitive {
    a: vec4<f32>,
    b: vec4<f32>,
    c: vec4<f32>,
    d: vec4<f32>,
    rgb: vec4<f32>,
    kind: vec4<u32>,
}

@group(0) @binding(0) var<uniform> P: Params;
// binding 1: the CT (prepended by the host)
@group(0) @binding(2) var labels: texture_3d<u32>;
@group(0) @binding(3) var<storage, read> styles: array<Style>;
@group(0) @binding(4) var<storage, read> occupancy: array<u32>;
@group(0) @binding(5) var<storage, read> prims: array<Primitive>;
@group(0) @binding(6) var deformed: texture_3d<f32>;
@group(0) @binding(7) var<storage, read_write> out_px: array<u32>;
@group(0) @binding(8) var<storage, read> tf_table: array<vec4<f32>>;
// Binding 9, the gradient records, is declared by the host's prelude (volume.rs `records_prelude`).
// Bindings 20 and 21, the breathing motion, are declared by motion.wgsl.

// --- Step 1: jitter (raycast/jitter.rs) -----------------------------------------------------

fn hash(x: u32) -> u32 {
    var v = x;
    v ^= v >> 16u;
    v *= 0x7feb352du;
    v ^= v >> 15u;
    v *= 0x846ca68bu;
    v ^= v >> 16u;
    return v;
}

fn jitter(col: u32, row: u32) -> f32 {
    return f32(hash(col + row * 65536u) >> 8u) / 16777216.0;
}

// --- Sampling (raycast/sampler.rs) ----------------------------------------------------------

fn map_vector(r0: vec4<f32>, r1: vec4<f32>, r2: vec4<f32>, v: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(dot(r0.xyz, v), dot(r1.xyz, v), dot(r2.xyz, v));
}

// Trilinear as Volume::sample_index: inside when -1/2 <= c < n - 1/2, clamp into [0, n-1],
// base min(floor, n-2), fraction from it; a one-voxel axis reads its voxel.
struct Lerp {
    ok: bool,
    i0: vec3<i32>,
    i1: vec3<i32>,
    f: vec3<f32>,
}

// Written with whole-vector operations (no per-axis loop): dynamic component indexing makes
// software rasterisers spill to memory in the hottest function of the shader.
fn lerp_setup(c: vec3<f32>, n: vec3<u32>) -> Lerp {
    var l: Lerp;
    let nf = vec3<f32>(n);
    // !(x >= -1/2 && x < n - 1/2) on any axis (NaN included) -> outside.
    l.ok = all(c >= vec3<f32>(-0.5)) && all(c < nf - vec3<f32>(0.5));
    let x = clamp(c, vec3<f32>(0.0), nf - vec3<f32>(1.0));
    let two = n >= vec3<u32>(2u);
    let b = min(vec3<u32>(x), select(vec3<u32>(0u), n - vec3<u32>(2u), two));
    l.i0 = vec3<i32>(b);
    l.i1 = vec3<i32>(b + select(vec3<u32>(0u), vec3<u32>(1u), n > vec3<u32>(1u)));
    l.f = select(x - vec3<f32>(b), vec3<f32>(0.0), n == vec3<u32>(1u));
    return l;
}

struct Val {
    ok: bool,
    v: f32,
}

fn ct_trilinear(c: vec3<f32>) -> Val {
    let l = lerp_setup(c, P.dims.xyz);
    if !l.ok {
        return Val(false, 0.0);
    }
    let fx = l.f.x;
    let fy = l.f.y;
    let fz = l.f.z;
    let c00 = ct_voxel(vec3<i32>(l.i0.x, l.i0.y, l.i0.z)) * (1.0 - fx) + ct_voxel(vec3<i32>(l.i1.x, l.i0.y, l.i0.z)) * fx;
    let c10 = ct_voxel(vec3<i32>(l.i0.x, l.i1.y, l.i0.z)) * (1.0 - fx) + ct_voxel(vec3<i32>(l.i1.x, l.i1.y, l.i0.z)) * fx;
    let c01 = ct_voxel(vec3<i32>(l.i0.x, l.i0.y, l.i1.z)) * (1.0 - fx) + ct_voxel(vec3<i32>(l.i1.x, l.i0.y, l.i1.z)) * fx;
    let c11 = ct_voxel(vec3<i32>(l.i0.x, l.i1.y, l.i1.z)) * (1.0 - fx) + ct_voxel(vec3<i32>(l.i1.x, l.i1.y, l.i1.z)) * fx;
    let c0 = c00 * (1.0 - fy) + c10 * fy;
    let c1 = c01 * (1.0 - fy) + c11 * fy;
    return Val(true, c0 * (1.0 - fz) + c1 * fz);
}

fn def_voxel(p: vec3<i32>) -> f32 {
    return textureLoad(deformed, p, 0).x;
}

fn def_trilinear(c: vec3<f32>) -> Val {
    let l = lerp_setup(c, P.def_dims.xyz);
    if !l.ok {
        return Val(false, 0.0);
    }
    let fx = l.f.x;
    let fy = l.f.y;
    let fz = l.f.z;
    let c00 = def_voxel(vec3<i32>(l.i0.x, l.i0.y, l.i0.z)) * (1.0 - fx) + def_voxel(vec3<i32>(l.i1.x, l.i0.y, l.i0.z)) * fx;
    let c10 = def_voxel(vec3<i32>(l.i0.x, l.i1.y, l.i0.z)) * (1.0 - fx) + def_voxel(vec3<i32>(l.i1.x, l.i1.y, l.i0.z)) * fx;
    let c01 = def_voxel(vec3<i32>(l.i0.x, l.i0.y, l.i1.z)) * (1.0 - fx) + def_voxel(vec3<i32>(l.i1.x, l.i0.y, l.i1.z)) * fx;
    let c11 = def_voxel(vec3<i32>(l.i0.x, l.i1.y, l.i1.z)) * (1.0 - fx) + def_voxel(vec3<i32>(l.i1.x, l.i1.y, l.i1.z)) * fx;
    let c0 = c00 * (1.0 - fy) + c10 * fy;
    let c1 = c01 * (1.0 - fy) + c11 * fy;
    return Val(true, c0 * (1.0 - fz) + c1 * fz);
}

// Where a sample is read: CT index and J index (both stepped along the ray in index space).
struct At {
    ct: vec3<f32>,
    j: vec3<f32>,
}

// s(x) of eq. 3.1.1: J inside Omega_J, else the CT, else air.
fn s(at: At) -> f32 {
    if (P.image.z & F_DEFORMED) != 0u {
        let v = def_trilinear(at.j);
        if v.ok {
            return v.v;
        }
    }
    let v = ct_trilinear(at.ct);
    return select(AIR_HU, v.v, v.ok);
}

// --- Gradient (sampler.rs `Sampler::gradient`, gradient_volume.rs) --------------------------
// The central differences D_a = I(p + e_a) - I(p - e_a) of the eight voxels a trilinear read
// uses, blended in the trilinear order, then grad s = sum_a D_a (rows_a / 2) in the world. The CT's
// differences are the CPU's own precomputed records (`ct_record`, air beyond the grid), read
// with the value in one trilinear pass; J's are formed on the fly (J changes with the tissue).

struct Records {
    ok: bool,
    r: vec4<f32>,
}

// The CT's records (dx, dy, dz, I) trilinearly interpolated, all four lanes in ct_trilinear's
// order. The prelude's ct_records(c) is this (float records), ct_records_fixed below (16-bit
// records) or the texture unit's filtered read (volume.rs `RecordFilter::Hardware`).
fn ct_records_exact(c: vec3<f32>) -> Records {
    let l = lerp_setup(c, P.dims.xyz);
    if !l.ok {
        return Records(false, vec4<f32>(0.0));
    }
    let fx = l.f.x;
    let fy = l.f.y;
    let fz = l.f.z;
    let c00 = ct_record(vec3<i32>(l.i0.x, l.i0.y, l.i0.z)) * (1.0 - fx) + ct_record(vec3<i32>(l.i1.x, l.i0.y, l.i0.z)) * fx;
    let c10 = ct_record(vec3<i32>(l.i0.x, l.i1.y, l.i0.z)) * (1.0 - fx) + ct_record(vec3<i32>(l.i1.x, l.i1.y, l.i0.z)) * fx;
    let c01 = ct_record(vec3<i32>(l.i0.x, l.i0.y, l.i1.z)) * (1.0 - fx) + ct_record(vec3<i32>(l.i1.x, l.i0.y, l.i1.z)) * fx;
    let c11 = ct_record(vec3<i32>(l.i0.x, l.i1.y, l.i1.z)) * (1.0 - fx) + ct_record(vec3<i32>(l.i1.x, l.i1.y, l.i1.z)) * fx;
    let c0 = c00 * (1.0 - fy) + c10 * fy;
    let c1 = c01 * (1.0 - fy) + c11 * fy;
    return Records(true, c0 * (1.0 - fz) + c1 * fz);
}

// One slice (z index k) of a fixed-point blend: the four records of the slice weighted by
// w_x * w_y, summed exactly in i32.
fn ct_slice_fixed(l: Lerp, k: i32, wx: vec2<i32>, wy: vec2<i32>) -> vec4<i32> {
    let r00 = vec4<i32>(ct_record(vec3<i32>(l.i0.x, l.i0.y, k)));
    let r10 = vec4<i32>(ct_record(vec3<i32>(l.i1.x, l.i0.y, k)));
    let r01 = vec4<i32>(ct_record(vec3<i32>(l.i0.x, l.i1.y, k)));
    let r11 = vec4<i32>(ct_record(vec3<i32>(l.i1.x, l.i1.y, k)));
    return r00 * (wx.x * wy.x) + r10 * (wx.y * wy.x) + r01 * (wx.x * wy.y) + r11 * (wx.y * wy.y);
}

// The CT's 16-bit records as the CPU blends them (gradient_volume.rs `fixed_point`): each slice
// in fixed point, the fractions across it rounded to 1/128 (ties to even, as WGSL's round and
// the CPU's lanes), the sums exact in i32; then along z in f32; then times 2^-14. A CT with a
// one-voxel axis takes ct_records_exact, as the CPU's general path.
fn ct_records_fixed(c: vec3<f32>) -> Records {
    if any(P.dims.xyz < vec3<u32>(2u)) {
        return ct_records_exact(c);
    }
    let l = lerp_setup(c, P.dims.xyz);
    if !l.ok {
        return Records(false, vec4<f32>(0.0));
    }
    let q = vec2<i32>(round(l.f.xy * 128.0));
    let wx = vec2<i32>(128 - q.x, q.x);
    let wy = vec2<i32>(128 - q.y, q.y);
    let c0 = vec4<f32>(ct_slice_fixed(l, l.i0.z, wx, wy));
    let c1 = vec4<f32>(ct_slice_fixed(l, l.i1.z, wx, wy));
    let fz = l.f.z;
    return Records(true, (c0 * (1.0 - fz) + c1 * fz) * (1.0 / 16384.0));
}

// J's voxel p, the nearest voxel beyond its grid (Edge::Clamp: J continues into the CT).
fn def_clamped(p: vec3<i32>) -> f32 {
    return def_voxel(clamp(p, vec3<i32>(0), vec3<i32>(P.def_dims.xyz) - vec3<i32>(1)));
}

fn def_diff(p: vec3<i32>) -> vec3<f32> {
    let ex = vec3<i32>(1, 0, 0);
    let ey = vec3<i32>(0, 1, 0);
    let ez = vec3<i32>(0, 0, 1);
    return vec3<f32>(
        def_clamped(p + ex) - def_clamped(p - ex),
        def_clamped(p + ey) - def_clamped(p - ey),
        def_clamped(p + ez) - def_clamped(p - ez),
    );
}

struct Diff {
    ok: bool,
    d: vec3<f32>,
}

fn def_differences(c: vec3<f32>) -> Diff {
    let l = lerp_setup(c, P.def_dims.xyz);
    if !l.ok {
        return Diff(false, vec3<f32>(0.0));
    }
    let g = vec3<f32>(1.0) - l.f;
    let c00 = def_diff(vec3<i32>(l.i0.x, l.i0.y, l.i0.z)) * g.x + def_diff(vec3<i32>(l.i1.x, l.i0.y, l.i0.z)) * l.f.x;
    let c10 = def_diff(vec3<i32>(l.i0.x, l.i1.y, l.i0.z)) * g.x + def_diff(vec3<i32>(l.i1.x, l.i1.y, l.i0.z)) * l.f.x;
    let c01 = def_diff(vec3<i32>(l.i0.x, l.i0.y, l.i1.z)) * g.x + def_diff(vec3<i32>(l.i1.x, l.i0.y, l.i1.z)) * l.f.x;
    let c11 = def_diff(vec3<i32>(l.i0.x, l.i1.y, l.i1.z)) * g.x + def_diff(vec3<i32>(l.i1.x, l.i1.y, l.i1.z)) * l.f.x;
    let c0 = c00 * g.y + c10 * l.f.y;
    let c1 = c01 * g.y + c11 * l.f.y;
    return Diff(true, c0 * g.z + c1 * l.f.z);
}

// A lattice sample: s(x) of eq. 3.1.1 and where its gradient comes from (SRC_*); the CT's
// interpolated differences ride along.
const SRC_AIR: u32 = 0u;
const SRC_CT: u32 = 1u;
const SRC_J: u32 = 2u;

struct Sample {
    v: f32,
    src: u32,
    d: vec3<f32>,
}

fn sample(at: At) -> Sample {
    if (P.image.z & F_DEFORMED) != 0u {
        let v = def_trilinear(at.j);
        if v.ok {
            return Sample(v.v, SRC_J, vec3<f32>(0.0));
        }
    }
    let r = ct_records(at.ct);
    if !r.ok {
        return Sample(AIR_HU, SRC_AIR, vec3<f32>(0.0));
    }
    return Sample(r.r.w, SRC_CT, r.r.xyz);
}

// grad s (HU/mm): J's differences inside Omega_J, else the CT's, else 0 (unshaded).
fn gradient(at: At, smp: Sample) -> vec3<f32> {
    if smp.src == SRC_J {
        let d = def_differences(at.j);
        return (P.def_inv0.xyz * 0.5) * d.d.x + (P.def_inv1.xyz * 0.5) * d.d.y + (P.def_inv2.xyz * 0.5) * d.d.z;
    }
    if smp.src == SRC_CT {
        return (P.inv0.xyz * 0.5) * smp.d.x + (P.inv1.xyz * 0.5) * smp.d.y + (P.inv2.xyz * 0.5) * smp.d.z;
    }
    return vec3<f32>(0.0);
}

// l(x): the label of the CT voxel nearest the sample, 0 outside (never interpolated).
fn label(at: At) -> u32 {
    let r = at.ct + vec3<f32>(0.5);
    if !(all(r >= vec3<f32>(0.0)) && all(r < vec3<f32>(P.dims.xyz))) {
        return 0u;
    }
    return textureLoad(labels, vec3<i32>(vec3<u32>(r)), 0).x;
}

fn style(id: u32) -> Style {
    if id < P.modes.w {
        return styles[id];
    }
    var none: Style;
    return none;
}

// --- Breathing: rays warped by u(X, t) (motion.wgsl, prepended by the host) ----------------

// Where reference point X is read (Sampler::at_world).
fn at_world(x: vec3<f32>) -> At {
    return At(
        map_vector(P.inv0, P.inv1, P.inv2, x - P.origin.xyz),
        map_vector(P.def_inv0, P.def_inv1, P.def_inv2, x - P.def_origin.xyz),
    );
}

// --- Transfer function c(v), eq. 3.2.2 (transfer.rs) ----------------------------------------

fn transfer(v: f32) -> vec4<f32> {
    if P.modes.x == 1u {
        let g = clamp((v - (P.window.x - P.window.y * 0.5)) / P.window.y, 0.0, 1.0);
        return vec4<f32>(g, g, g, g * P.window.z);
    }
    var r = 0.0;
    var gg = 0.0;
    var b = 0.0;
    var a = 0.0;
    for (var i = 0u; i < min(P.image.w, MAX_TRAPEZOIDS); i++) {
        let t = P.traps[i];
        var shape = 0.0;
        if v <= t.hu.x || v >= t.hu.w {
            shape = 0.0;
        } else if v < t.hu.y {
            shape = (v - t.hu.x) / (t.hu.y - t.hu.x);
        } else if v <= t.hu.z {
            shape = 1.0;
        } else {
            shape = (t.hu.w - v) / (t.hu.w - t.hu.z);
        }
        let w = t.weight.x * (shape * t.rgb_opacity.w);
        r += w * t.rgb_opacity.x;
        gg += w * t.rgb_opacity.y;
        b += w * t.rgb_opacity.z;
        a += w;
    }
    if a <= 0.0 {
        return vec4<f32>(0.0);
    }
    return vec4<f32>(r / a, gg / a, b / a, min(a, 1.0));
}

// The lattice samples' c(v): the transfer table (transfer_table.rs), (alpha rgb, alpha) with the
// opacity correction applied, linear between entries.
fn table_lookup(v: f32) -> vec4<f32> {
    let last = P.table.z;
    let x = min(max((v - P.table.x) * P.table.y, 0.0), last);
    let i = min(u32(x), u32(last) - 1u);
    let f = x - f32(i);
    return tf_table[i] * (1.0 - f) + tf_table[i + 1u] * f;
}

// --- Shading (raycast/shading.rs) -----------------------------------------------------------

// Eq. 3.2.3, two-sided: ambient + (diffuse |N.L| + specular |N.H|^shininess) f_shadow.
fn phong(g: vec3<f32>, rd: vec3<f32>, f_shadow: f32) -> f32 {
    let len = length(g);
    if len < MIN_GRADIENT {
        return 1.0;
    }
    let n = -g / len;
    let l = P.light.xyz;
    let h = normalize(l - rd);
    return P.phong.x + (P.phong.y * abs(dot(n, l)) + P.phong.z * pow(abs(dot(n, h)), P.phong.w)) * f_shadow;
}

// The plane sample's colour: v1 (off), v2 of eq. 3.2.4 (risk), v3 of eq. 3.2.5 (labels).
fn plane_colour(c: vec4<f32>, st: Style) -> vec4<f32> {
    let tagging = P.modes.y;
    if tagging == 1u {
        if st.class_ == 1u {
            return vec4<f32>(0.5 * c.x, 0.5 * c.y + 0.5, 0.5 * c.z, 0.5 * c.w + 0.5);
        } else if st.class_ == 2u {
            return vec4<f32>(0.5 * c.x + 0.5, 0.5 * c.y, 0.5 * c.z + 0.2, 0.5 * c.w + 0.5);
        }
        return c;
    } else if tagging == 2u {
        return st.rgba;
    }
    return c;
}

// --- Shadows, Alg. 3.1 and 3.2 (shadow.rs; l toward the light) ------------------------------

fn in_needle_shadow(x: vec3<f32>, l: vec3<f32>) -> bool {
    let n = P.needle_back.xyz;
    let len = P.needle_dims.x;
    let dia = P.needle_dims.y;
    let hub_len = P.needle_dims.z;
    let hub_dia = P.needle_dims.w;
    let d = x - P.needle_tip.xyz;
    let p0 = cross(l, n);
    let pl = length(p0);
    if pl < 1e-6 {
        let along = dot(d, l);
        let perp = length(d - l * along);
        let r_shaft = 0.5 * dia;
        let r_hub = 0.5 * hub_dia;
        if dot(n, l) > 0.0 {
            return perp < max(r_shaft, r_hub) && along < 0.0;
        }
        return (perp < r_shaft && along < 0.0) || (perp < r_hub && along < -len);
    }
    let p = p0 / pl;
    let j = cross(p, l);
    let q = normalize(l - n * dot(n, l));
    let d1 = dot(d, p);
    let d2 = dot(q, d);
    let d3 = dot(j, d) / dot(j, n);
    if d2 >= 0.0 {
        return false;
    }
    return (abs(d1) < 0.5 * dia && d3 > 0.0 && d3 < len)
        || (abs(d1) < 0.5 * hub_dia && d3 > len && d3 < len + hub_len);
}

fn shadow_factor(x: vec3<f32>) -> f32 {
    let l = P.light.xyz;
    var inside = (P.image.z & F_NEEDLE_SHADOW) != 0u && in_needle_shadow(x, l);
    for (var i = 0; i < 2; i++) {
        let sp = P.spheres[i];
        if sp.w > 0.0 {
            let rel = x - sp.xyz;
            let k = dot(l, rel);
            let d = length(rel - l * k);
            inside = inside || (k < sp.w && d < sp.w);
        }
    }
    return select(1.0, P.light.w, inside);
}

// --- Tools (tools.rs: closed-form f32 hits) -------------------------------------------------

struct Span {
    ok: bool,
    t_in: f32,
    n_in: vec3<f32>,
    t_out: f32,
    n_out: vec3<f32>,
}

fn span_all() -> Span {
    return Span(true, -BIG, vec3<f32>(0.0), BIG, vec3<f32>(0.0));
}

fn span_clip(s0: Span, t_in: f32, n_in: vec3<f32>, t_out: f32, n_out: vec3<f32>) -> Span {
    var s = s0;
    if t_in > s.t_in {
        s.t_in = t_in;
        s.n_in = n_in;
    }
    if t_out < s.t_out {
        s.t_out = t_out;
        s.n_out = n_out;
    }
    s.ok = s.ok && s.t_in <= s.t_out;
    return s;
}

fn span_slab(s: Span, o_rel: vec3<f32>, d: vec3<f32>, axis: vec3<f32>, half: f32) -> Span {
    let o = dot(o_rel, axis);
    let v = dot(d, axis);
    if abs(v) < 1e-12 {
        var r = s;
        r.ok = s.ok && abs(o) <= half;
        return r;
    }
    let t1 = (-half - o) / v;
    let t2 = (half - o) / v;
    let near = select(t2, t1, t1 < t2);
    let far = select(t1, t2, t1 < t2);
    let n_enter = select(axis, -axis, v > 0.0);
    return span_clip(s, near, n_enter, far, -n_enter);
}

// (t, normal.xyz) packed in a vec4; t < 0 for no hit.
fn span_first(s: Span, t_max: f32) -> vec4<f32> {
    if !s.ok {
        return vec4<f32>(-1.0, 0.0, 0.0, 0.0);
    }
    if s.t_in > 0.0 && s.t_in < t_max {
        return vec4<f32>(s.t_in, s.n_in);
    } else if s.t_in <= 0.0 && s.t_out > 0.0 && s.t_out < t_max {
        return vec4<f32>(s.t_out, s.n_out);
    }
    return vec4<f32>(-1.0, 0.0, 0.0, 0.0);
}

// Keeps the smaller positive t below the current best (tools.rs `take`).
fn take(best: vec4<f32>, t: f32, n: vec3<f32>, t_max: f32) -> vec4<f32> {
    if t > 0.0 && t < t_max && (best.x < 0.0 || t < best.x) {
        return vec4<f32>(t, n);
    }
    return best;
}

fn hit_primitive(p: Primitive, o: vec3<f32>, d: vec3<f32>, t_max: f32) -> vec4<f32> {
    var best = vec4<f32>(-1.0, 0.0, 0.0, 0.0);
    let kind = p.kind.x;
    if kind == P_SPHERE {
        let center = p.a.xyz;
        let radius = p.a.w;
        let oc = o - center;
        let b = dot(oc, d);
        let h = b * b - (dot(oc, oc) - radius * radius);
        if h >= 0.0 {
            let sq = sqrt(h);
            for (var i = 0; i < 2; i++) {
                let t = select(-b + sq, -b - sq, i == 0);
                best = take(best, t, (o + d * t - center) / radius, t_max);
            }
        }
    } else if kind == P_CAPSULE {
        let a = p.a.xyz;
        let bb = p.b.xyz;
        let radius = p.a.w;
        let ab = bb - a;
        let len = length(ab);
        let u = select(vec3<f32>(0.0, 0.0, 1.0), ab / len, len > 1e-12);
        let oa = o - a;
        let dp = d - u * dot(d, u);
        let op = oa - u * dot(oa, u);
        let qa = dot(dp, dp);
        if qa > 1e-12 && len > 1e-12 {
            let h = dot(op, dp) * dot(op, dp) - qa * (dot(op, op) - radius * radius);
            if h >= 0.0 {
                let sq = sqrt(h);
                for (var i = 0; i < 2; i++) {
                    let t = select((-dot(op, dp) + sq) / qa, (-dot(op, dp) - sq) / qa, i == 0);
                    let y = dot(oa, u) + t * dot(d, u);
                    if y > 0.0 && y < len {
                        let x = o + d * t;
                        best = take(best, t, (x - (a + u * y)) / radius, t_max);
                    }
                }
            }
        }
        for (var e = 0; e < 2; e++) {
            let at_a = e == 0;
            let c = select(bb, a, at_a);
            let oc = o - c;
            let b = dot(oc, d);
            let h = b * b - (dot(oc, oc) - radius * radius);
            if h >= 0.0 {
                let sq = sqrt(h);
                for (var i = 0; i < 2; i++) {
                    let t = select(-b + sq, -b - sq, i == 0);
                    let y = dot(oa, u) + t * dot(d, u);
                    if (at_a && y <= 0.0) || (!at_a && y >= len) {
                        best = take(best, t, (o + d * t - c) / radius, t_max);
                    }
                }
            }
        }
    } else if kind == P_BOX {
        let rel = o - p.a.xyz;
        var sp = span_slab(span_all(), rel, d, p.b.xyz, p.b.w);
        sp = span_slab(sp, rel, d, p.c.xyz, p.c.w);
        sp = span_slab(sp, rel, d, p.d.xyz, p.d.w);
        best = span_first(sp, t_max);
    } else if kind == P_CYLINDER {
        let center = p.a.xyz;
        let radius = p.a.w;
        let axis = p.b.xyz;
        let cut_normal = p.c.xyz;
        let cut_mm = p.c.w;
        let rel = o - center;
        var sp = span_slab(span_all(), rel, d, axis, p.b.w);
        // Side: |rel_perp + t d_perp| <= r.
        let dp = d - axis * dot(d, axis);
        let op = rel - axis * dot(rel, axis);
        let qa = dot(dp, dp);
        if qa < 1e-12 {
            sp.ok = sp.ok && dot(op, op) <= radius * radius;
        } else {
            let b = dot(op, dp);
            let h = b * b - qa * (dot(op, op) - radius * radius);
            if h < 0.0 {
                sp.ok = false;
            } else {
                let sq = sqrt(h);
                let t0 = (-b - sq) / qa;
                let t1 = (-b + sq) / qa;
                sp = span_clip(sp, t0, (op + dp * t0) / radius, t1, (op + dp * t1) / radius);
            }
        }
        // Cut: (rel + t d).m >= k, outward normal -m.
        let on = dot(rel, cut_normal);
        let dn = dot(d, cut_normal);
        if abs(dn) < 1e-12 {
            sp.ok = sp.ok && on >= cut_mm;
        } else {
            let tc = (cut_mm - on) / dn;
            if dn > 0.0 {
                sp = span_clip(sp, tc, -cut_normal, BIG, vec3<f32>(0.0));
            } else {
                sp = span_clip(sp, -BIG, vec3<f32>(0.0), tc, -cut_normal);
            }
        }
        best = span_first(sp, t_max);
    }
    return best;
}

struct Hit {
    t: f32,
    normal: vec3<f32>,
    rgb: vec3<f32>,
}

// tools::nearest_hit: the nearest tool surface with t in (0, t_max); t = BIG for none.
fn nearest_hit(o: vec3<f32>, d: vec3<f32>, t_max: f32) -> Hit {
    var best = Hit(BIG, vec3<f32>(0.0), vec3<f32>(0.0));
    var found = false;
    for (var i = 0u; i < P.modes.z; i++) {
        let limit = select(t_max, best.t, found);
        let h = hit_primitive(prims[i], o, d, limit);
        if h.x >= 0.0 {
            best = Hit(h.x, h.yzw, prims[i].rgb.xyz);
            found = true;
        }
    }
    return best;
}

// tools::shade: rgb (ambient + diffuse max(N.L, 0)) + specular max(N.H, 0)^shininess, clamped.
fn shade_tool(hit: Hit, rd: vec3<f32>) -> vec3<f32> {
    let n = hit.normal;
    let l = P.light.xyz;
    let hv = l - rd;
    let hl = length(hv);
    let h = select(vec3<f32>(0.0), hv / hl, hl > 0.0);
    let diffuse = max(dot(n, l), 0.0);
    let spec = pow(max(dot(n, h), 0.0), P.phong.w);
    return clamp(hit.rgb * (P.phong.x + P.phong.y * diffuse) + vec3<f32>(P.phong.z * spec), vec3<f32>(0.0), vec3<f32>(1.0));
}

// --- The ray (raycast/march.rs) -------------------------------------------------------------

fn inside(c: vec3<f32>) -> bool {
    let n = vec3<f32>(P.dims.xyz);
    return all(c >= vec3<f32>(-0.5)) && all(c < n - vec3<f32>(0.5));
}

// Inside the CT's box widened by the motion's bound (march.rs `inside_by`).
fn inside_by_margin(c: vec3<f32>) -> bool {
    let n = vec3<f32>(P.dims.xyz);
    let m = P.margin.xyz;
    return all(c >= vec3<f32>(-0.5) - m) && all(c < n - vec3<f32>(0.5) + m);
}

fn lattice(k: u32, j: f32, step: f32) -> f32 {
    return (f32(k) + j) * step;
}

fn lattice_ok(k: u32, t: f32, strict: bool, j: f32, step: f32) -> bool {
    let tk = lattice(k, j, step);
    return select(tk >= t, tk > t, strict);
}

// The first k with t_k >= t (> t when strict).
fn first_lattice(t: f32, strict: bool, j: f32, step: f32) -> u32 {
    var k = u32(max(ceil(t / step - j), 0.0));
    while k > 0u && lattice_ok(k - 1u, t, strict, j, step) {
        k -= 1u;
    }
    while !lattice_ok(k, t, strict, j, step) {
        k += 1u;
    }
    return k;
}

fn cell_of(c: vec3<f32>) -> vec3<u32> {
    let last = f32(P.dims.w - 1u);
    let q = clamp(floor((c + vec3<f32>(0.5)) * P.occ_scale.xyz), vec3<f32>(0.0), vec3<f32>(last));
    return vec3<u32>(q);
}

// Ray parameter where c(t) = ce + t dc leaves cell q (BIG when parallel to every face).
fn exit_t(q: vec3<u32>, ce: vec3<f32>, dc: vec3<f32>) -> f32 {
    let moving = dc != vec3<f32>(0.0);
    let face = select(q, q + vec3<u32>(1u), dc > vec3<f32>(0.0));
    let bound = vec3<f32>(face) * P.occ_size.xyz - vec3<f32>(0.5);
    // Axes the ray does not move along never bound the cell (their quotient is discarded).
    let ta = select(vec3<f32>(BIG), (bound - ce) / select(vec3<f32>(1.0), dc, moving), moving);
    return min(BIG, min(ta.x, min(ta.y, ta.z)));
}

fn to8(v: f32) -> u32 {
    return u32(floor(clamp(v, 0.0, 1.0) * 255.0 + 0.5));
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let width = P.image.x;
    let height = P.image.y;
    if gid.x >= width || gid.y >= height {
        return;
    }
    let flags = P.image.z;
    let col = gid.x;
    let row = gid.y;
    // Camera::ray.
    let tan_half = P.eye.w;
    let aspect = P.right.w;
    let xn = (2.0 * (f32(col) + 0.5) / f32(width) - 1.0) * tan_half * aspect;
    let yn = (1.0 - 2.0 * (f32(row) + 0.5) / f32(height)) * tan_half;
    let origin = P.eye.xyz;
    let dir = normalize(P.forward.xyz + P.right.xyz * xn + P.up.xyz * yn);
    let step = P.up.w;

    // 1. Sample lattice.
    var j = 0.0;
    if (flags & F_JITTER) != 0u {
        j = jitter(col, row);
    }
    let ce = map_vector(P.inv0, P.inv1, P.inv2, origin - P.origin.xyz);
    let dc = map_vector(P.inv0, P.inv1, P.inv2, dir);
    var je = vec3<f32>(0.0);
    var dj = vec3<f32>(0.0);
    if (flags & F_DEFORMED) != 0u {
        je = map_vector(P.def_inv0, P.def_inv1, P.def_inv2, origin - P.def_origin.xyz);
        dj = map_vector(P.def_inv0, P.def_inv1, P.def_inv2, dir);
    }
    var acc_c = vec3<f32>(0.0);
    var acc_t = 1.0; // transmittance T = 1 − A (the CPU's Accum)

    // 4. Tools: the nearest hit ends the march.
    let tool = nearest_hit(origin, dir, BIG);
    let t_tool = tool.t;

    // 2. Extent: ray/box (slabs on [-1/2, n - 1/2]^3 in index space, widened by the motion's
    // bound) or naive [0, t_far].
    var has_extent = true;
    var t0 = 0.0;
    var t1 = P.forward.w;
    if (flags & F_RAY_BOX) != 0u {
        t1 = BIG;
        for (var a = 0; a < 3; a++) {
            let lo = -0.5 - P.margin[a];
            let hi = f32(P.dims[a]) - 0.5 + P.margin[a];
            if dc[a] == 0.0 {
                if ce[a] < lo || ce[a] > hi {
                    has_extent = false;
                }
            } else {
                let inv = 1.0 / dc[a];
                let ta = (lo - ce[a]) * inv;
                let tb = (hi - ce[a]) * inv;
                t0 = max(t0, min(ta, tb));
                t1 = min(t1, max(ta, tb));
            }
        }
        if t0 > t1 {
            has_extent = false;
        }
    }

    // 3. Clip plane: the visible part of the extent and the plane sample where the ray enters it.
    var lat = false;      // lattice_from is Some
    var lat_lo = 0.0;
    var lat_strict = false;
    var lat_hi = 0.0;
    var has_plane = false;
    var plane_t = 0.0;
    if has_extent {
        if (flags & F_CLIP) == 0u {
            lat = true;
            lat_lo = t0;
            lat_hi = t1;
        } else {
            let s0 = dot(origin - P.clip_point.xyz, P.clip_normal.xyz);
            let rn = dot(dir, P.clip_normal.xyz);
            if rn > 0.0 {
                let tc = -s0 / rn;
                if tc < t0 {
                    lat = true;
                    lat_lo = t0;
                    lat_hi = t1;
                } else if tc <= t1 {
                    has_plane = true;
                    plane_t = tc;
                    lat = true;
                    lat_lo = tc;
                    lat_strict = true;
                    lat_hi = t1;
                }
            } else if rn < 0.0 {
                let tc = -s0 / rn;
                if tc >= t0 {
                    lat = true;
                    lat_lo = t0;
                    lat_hi = min(t1, tc);
                }
            } else if s0 >= 0.0 {
                lat = true;
                lat_lo = t0;
                lat_hi = t1;
            }
        }
    }

    let warping = breathing();
    var warp = no_warp();
    // The plane sample: no shading, no shadow, opacity as is.
    if has_plane && plane_t < t_tool {
        var at = At(ce + dc * plane_t, je + dj * plane_t);
        if warping {
            at = at_world(reference_of(&warp, origin + dir * plane_t));
            warp.has_prev = false;
        }
        let c = transfer(s(at));
        var st = style(0u);
        if P.modes.y != 0u {
            st = style(label(at));
        }
        let v = plane_colour(c, st);
        if v.w > 0.0 {
            let a = min(v.w, 1.0);
            acc_c += acc_t * a * v.xyz;
            acc_t *= 1.0 - a;
        }
    }

    // 5.-8. The lattice samples.
    let early = (flags & F_EARLY) != 0u;
    if lat && !(early && acc_t <= 1.0 - OPAQUE) {
        var k = first_lattice(lat_lo, lat_strict, j, step);
        loop {
            let t = lattice(k, j, step);
            if t > lat_hi || t >= t_tool {
                break;
            }
            var at = At(ce + dc * t, je + dj * t);
            // 8. Empty-space leaping, at the world point (cells dilated by the motion's bound).
            if (flags & F_LEAPING) != 0u {
                if inside(at.ct) {
                    let cell = cell_of(at.ct);
                    let n = P.dims.w;
                    if occupancy[cell.x + n * (cell.y + n * cell.z)] == 0u {
                        let t_exit = exit_t(cell, ce, dc);
                        let k_exit = ceil(t_exit / step - j - 1e-3);
                        var next = k + 1u;
                        if t_exit < BIG && k_exit > f32(k + 1u) {
                            next = u32(min(k_exit, 2147483647.0));
                        }
                        k = next;
                        continue;
                    }
                } else if (flags & F_SAMPLE_OUTSIDE) == 0u && !inside_by_margin(at.ct) {
                    k += 1u;
                    continue;
                }
            }
            if warping {
                at = at_world(reference_of(&warp, origin + dir * t));
            }
            // 5. Sample.
            let smp = sample(at);
            let c = table_lookup(smp.v);
            if c.w > 0.0 {
                // 6. Shadow, at the sample's world position.
                let f_shadow = shadow_factor(origin + dir * t);
                let shade = phong(gradient(at, smp), dir, f_shadow);
                acc_c += acc_t * (c.xyz * shade);
                acc_t *= 1.0 - c.w;
                // 7. Early termination.
                if early && acc_t <= 1.0 - OPAQUE {
                    break;
                }
            }
            k += 1u;
        }
    }

    // 4. (end) The tool behind what was accumulated.
    if t_tool < BIG {
        acc_c += acc_t * shade_tool(tool, dir);
        acc_t = 0.0;
    }

    // 9. Finish.
    let rgb = acc_c + acc_t * P.background.xyz;
    out_px[row * width + col] = to8(rgb.x) | (to8(rgb.y) << 8u) | (to8(rgb.z) << 16u) | (255u << 24u);
}
