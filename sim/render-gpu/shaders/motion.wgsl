// The breathing motion u(X, t) on the GPU (docs/breathing.md "On the GPU"), in one of two forms
// the host picks per frame (M.dir.w):
// 1. one factored field u = d · w(X.z) · m(X) (stylet_physics `FactoredField`: the synthetic
//    motion, its direction scaled by the breathing signal at the frame's moment), m the mobility
//    map at binding 21 (R32Float);
// 2. weighted grid fields u = Σ wᵢ fᵢ(X) (stylet_physics `WeightedGrids`: measured a₁, a₂, a₃
//    of thesis eq. 5.3.6 weighted by g, g′ and 1), the fields at bindings 22, 23, 24 (Rgba32Float,
//    each on its own grid).
// Prepended by the host to raycast.wgsl, mpr.wgsl, xray.wgsl and ultrasound.wgsl; group 0,
// bindings 20 (these parameters) to 24. Every grid is read with textureLoad and blended as
// physics' `trilinear` does.

// One grid field's placement and weight. Mirrored by `FieldParams` in motion.rs.
struct FieldParams {
    inv0: vec4<f32>,     // the grid's IndexMap: c = rows . (x - origin)
    inv1: vec4<f32>,
    inv2: vec4<f32>,
    origin: vec4<f32>,   // w: the weight at this moment (0: no such field)
    dims: vec4<u32>,
}

// Mirrored by `MotionParams` in motion.rs.
struct Motion {
    dir: vec4<f32>,      // d at this moment (mm); w: 0 still, 1 factored, 2 weighted grids
    knot_z: vec4<f32>,   // the profile's knots: z (mm), ascending
    knot_w: vec4<f32>,   // the profile's knots: w
    inv0: vec4<f32>,     // the mobility grid's IndexMap: c = rows . (x - origin)
    inv1: vec4<f32>,
    inv2: vec4<f32>,
    origin: vec4<f32>,
    dims: vec4<u32>,
    fields: array<FieldParams, 3>,
}

@group(0) @binding(20) var<uniform> M: Motion;
@group(0) @binding(21) var mobility: texture_3d<f32>;
@group(0) @binding(22) var field_a1: texture_3d<f32>;
@group(0) @binding(23) var field_a2: texture_3d<f32>;
@group(0) @binding(24) var field_a3: texture_3d<f32>;

fn breathing() -> bool {
    return M.dir.w != 0.0;
}

// Trilinear in `t` at index c as physics' `trilinear` (inside when -1/2 <= c < n - 1/2, clamped
// to the nodes, base min(floor, n - 2)), 0 outside.
fn trilinear_in(t: texture_3d<f32>, c: vec3<f32>, n: vec3<u32>) -> vec4<f32> {
    let nf = vec3<f32>(n);
    if !(all(c >= vec3<f32>(-0.5)) && all(c < nf - vec3<f32>(0.5))) {
        return vec4<f32>(0.0);
    }
    let cl = clamp(c, vec3<f32>(0.0), nf - vec3<f32>(1.0));
    let two = n >= vec3<u32>(2u);
    let b = min(vec3<u32>(cl), select(vec3<u32>(0u), n - vec3<u32>(2u), two));
    let i0 = vec3<i32>(b);
    let i1 = vec3<i32>(b + select(vec3<u32>(0u), vec3<u32>(1u), n > vec3<u32>(1u)));
    let f = select(cl - vec3<f32>(b), vec3<f32>(0.0), n == vec3<u32>(1u));
    let c00 = textureLoad(t, vec3<i32>(i0.x, i0.y, i0.z), 0) * (1.0 - f.x) + textureLoad(t, vec3<i32>(i1.x, i0.y, i0.z), 0) * f.x;
    let c10 = textureLoad(t, vec3<i32>(i0.x, i1.y, i0.z), 0) * (1.0 - f.x) + textureLoad(t, vec3<i32>(i1.x, i1.y, i0.z), 0) * f.x;
    let c01 = textureLoad(t, vec3<i32>(i0.x, i0.y, i1.z), 0) * (1.0 - f.x) + textureLoad(t, vec3<i32>(i1.x, i0.y, i1.z), 0) * f.x;
    let c11 = textureLoad(t, vec3<i32>(i0.x, i1.y, i1.z), 0) * (1.0 - f.x) + textureLoad(t, vec3<i32>(i1.x, i1.y, i1.z), 0) * f.x;
    let c0 = c00 * (1.0 - f.y) + c10 * f.y;
    let c1 = c01 * (1.0 - f.y) + c11 * f.y;
    return c0 * (1.0 - f.z) + c1 * f.z;
}

// m(X): the mobility map, 0 outside its grid.
fn mobility_at(x: vec3<f32>) -> f32 {
    let q = x - M.origin.xyz;
    let c = vec3<f32>(dot(M.inv0.xyz, q), dot(M.inv1.xyz, q), dot(M.inv2.xyz, q));
    return trilinear_in(mobility, c, M.dims.xyz).x;
}

// The index of world point x on field i's grid.
fn field_index(p: FieldParams, x: vec3<f32>) -> vec3<f32> {
    let q = x - p.origin.xyz;
    return vec3<f32>(dot(p.inv0.xyz, q), dot(p.inv1.xyz, q), dot(p.inv2.xyz, q));
}

// Σ wᵢ fᵢ(X) over the fields present, in the order a₁, a₂, a₃ (models.rs `Surrogate::combine`).
fn weighted_grids_at(x: vec3<f32>) -> vec3<f32> {
    var u = vec3<f32>(0.0);
    let p1 = M.fields[0];
    if p1.dims.w != 0u {
        u += trilinear_in(field_a1, field_index(p1, x), p1.dims.xyz).xyz * p1.origin.w;
    }
    let p2 = M.fields[1];
    if p2.dims.w != 0u {
        u += trilinear_in(field_a2, field_index(p2, x), p2.dims.xyz).xyz * p2.origin.w;
    }
    let p3 = M.fields[2];
    if p3.dims.w != 0u {
        u += trilinear_in(field_a3, field_index(p3, x), p3.dims.xyz).xyz * p3.origin.w;
    }
    return u;
}

// w(z): linear between the four knots, constant beyond the ends (synthetic.rs `piecewise_linear`).
fn breath_profile(z: f32) -> f32 {
    let zs = M.knot_z;
    let ws = M.knot_w;
    if z <= zs.x {
        return ws.x;
    }
    if z >= zs.w {
        return ws.w;
    }
    if z <= zs.y {
        return ws.x + (ws.y - ws.x) * (z - zs.x) / (zs.y - zs.x);
    }
    if z <= zs.z {
        return ws.y + (ws.z - ws.y) * (z - zs.y) / (zs.z - zs.y);
    }
    return ws.z + (ws.w - ws.z) * (z - zs.z) / (zs.w - zs.z);
}

// u(X, t) at reference point X (mm).
fn breath_u(x_ref: vec3<f32>) -> vec3<f32> {
    if M.dir.w == 2.0 {
        return weighted_grids_at(x_ref);
    }
    let m = mobility_at(x_ref);
    if m == 0.0 {
        return vec3<f32>(0.0);
    }
    return M.dir.xyz * (breath_profile(x_ref.z) * m);
}

// The fixed point of one ray (eqs. 5.4.1-5.4.2): the last warped sample's world and reference
// positions.
struct Warp {
    has_prev: bool,
    x: vec3<f32>,
    big_x: vec3<f32>,
}

fn no_warp() -> Warp {
    return Warp(false, vec3<f32>(0.0), vec3<f32>(0.0));
}

// X of world sample x: one fixed-point step X = x - u(X_prev + (x - x_prev)) continuing from the
// ray's previous sample, or from X = x (raycast/march.rs `Warp::reference_of`).
fn reference_of(w: ptr<function, Warp>, x: vec3<f32>) -> vec3<f32> {
    var xp = x;
    var bp = x;
    if (*w).has_prev {
        xp = (*w).x;
        bp = (*w).big_x;
    }
    let big_x = x - breath_u(bp + (x - xp));
    *w = Warp(true, x, big_x);
    return big_x;
}

// X of world point x by `iterations` fixed-point steps from X = x (motion::invert).
fn invert_breathing(x: vec3<f32>, iterations: u32) -> vec3<f32> {
    var r = x;
    for (var i = 0u; i < iterations; i++) {
        r = x - breath_u(r);
    }
    return r;
}
