// The breathing motion u(X, t) = d · w(X.z) · m(X) of one factored field (stylet_physics
// `FactoredField`: the synthetic motion, its direction scaled by the breathing signal at the
// frame's moment; docs/breathing.md "On the GPU"). Prepended by the host to raycast.wgsl,
// mpr.wgsl and xray.wgsl; group 0, bindings 20 (these parameters) and 21 (the mobility map m,
// R32Float, read with textureLoad and blended as `Volume::sample` does).

// Mirrored by `MotionParams` in motion.rs.
struct Motion {
    dir: vec4<f32>,      // d at this moment (mm); w 1 when the patient breathes, else 0
    knot_z: vec4<f32>,   // the profile's knots: z (mm), ascending
    knot_w: vec4<f32>,   // the profile's knots: w
    inv0: vec4<f32>,     // the mobility grid's IndexMap: c = rows . (x - origin)
    inv1: vec4<f32>,
    inv2: vec4<f32>,
    origin: vec4<f32>,
    dims: vec4<u32>,
}

@group(0) @binding(20) var<uniform> M: Motion;
@group(0) @binding(21) var mobility: texture_3d<f32>;

fn breathing() -> bool {
    return M.dir.w != 0.0;
}

fn mob_voxel(p: vec3<i32>) -> f32 {
    return textureLoad(mobility, p, 0).x;
}

// m(X): trilinear in the mobility map as physics' `trilinear` (inside when -1/2 <= c < n - 1/2,
// clamped to the nodes, base min(floor, n - 2)), 0 outside.
fn mobility_at(x: vec3<f32>) -> f32 {
    let q = x - M.origin.xyz;
    let c = vec3<f32>(dot(M.inv0.xyz, q), dot(M.inv1.xyz, q), dot(M.inv2.xyz, q));
    let n = M.dims.xyz;
    let nf = vec3<f32>(n);
    if !(all(c >= vec3<f32>(-0.5)) && all(c < nf - vec3<f32>(0.5))) {
        return 0.0;
    }
    let cl = clamp(c, vec3<f32>(0.0), nf - vec3<f32>(1.0));
    let two = n >= vec3<u32>(2u);
    let b = min(vec3<u32>(cl), select(vec3<u32>(0u), n - vec3<u32>(2u), two));
    let i0 = vec3<i32>(b);
    let i1 = vec3<i32>(b + select(vec3<u32>(0u), vec3<u32>(1u), n > vec3<u32>(1u)));
    let f = select(cl - vec3<f32>(b), vec3<f32>(0.0), n == vec3<u32>(1u));
    let c00 = mob_voxel(vec3<i32>(i0.x, i0.y, i0.z)) * (1.0 - f.x) + mob_voxel(vec3<i32>(i1.x, i0.y, i0.z)) * f.x;
    let c10 = mob_voxel(vec3<i32>(i0.x, i1.y, i0.z)) * (1.0 - f.x) + mob_voxel(vec3<i32>(i1.x, i1.y, i0.z)) * f.x;
    let c01 = mob_voxel(vec3<i32>(i0.x, i0.y, i1.z)) * (1.0 - f.x) + mob_voxel(vec3<i32>(i1.x, i0.y, i1.z)) * f.x;
    let c11 = mob_voxel(vec3<i32>(i0.x, i1.y, i1.z)) * (1.0 - f.x) + mob_voxel(vec3<i32>(i1.x, i1.y, i1.z)) * f.x;
    let c0 = c00 * (1.0 - f.y) + c10 * f.y;
    let c1 = c01 * (1.0 - f.y) + c11 * f.y;
    return c0 * (1.0 - f.z) + c1 * f.z;
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
