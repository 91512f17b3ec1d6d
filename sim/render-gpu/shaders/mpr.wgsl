// Multi-planar reformation (docs/rendering.md "MPR"): one invocation per pixel, 8 × 8
// workgroups. A port of stylet-render's mpr.rs `draw` and `overlay_labels`: the CT under a
// window (grey) and the partial labels blended in their property-tree colours, opaque on a
// label's boundary. The CT declaration and `ct_voxel` are prepended by the host, as for
// raycast.wgsl. The tip marker and the scale bar are drawn afterwards on the CPU (annotate).
// With a tissue deformation (mpr.rs `render_spec_deformed`), each pixel inside the deformation's
// lattice reads the CT and the labels at its reference point X (X + u(X) = x by the fixed point
// X⁺ = x − u(X), trilinear u) and gets the displacement colour map |u(X)| over tissue. A
// breathing patient (mpr.rs `render_spec_moving`): each pixel's world point is first taken to
// the breathing patient's reference by `invert_breathing` (motion.wgsl), then as above.

const AIR_HU: f32 = -1000.0;

// Mirrored by `MprParams` in mpr.rs.
struct Params {
    origin: vec4<f32>,   // CT index of pixel (0, 0)'s centre
    col_step: vec4<f32>, // index step per column
    row_step: vec4<f32>, // index step per row
    dims: vec4<u32>,     // CT voxels, w number of label colours
    size: vec4<u32>,     // width, height
    window: vec4<f32>,   // level, width (HU)
    // The deformation (used when lattice_n.y = 1):
    w_origin: vec4<f32>, // world position (mm) of pixel (0, 0)'s centre
    w_col: vec4<f32>,    // world step per column
    w_row: vec4<f32>,    // world step per row
    to_index_o: vec4<f32>, // CT index of the world origin, and of each world axis' unit step:
    to_index_x: vec4<f32>, // c = o + X.x·x + X.y·y + X.z·z
    to_index_y: vec4<f32>,
    to_index_z: vec4<f32>,
    lattice: vec4<f32>,    // origin (mm), spacing h (mm)
    lattice_n: vec4<u32>,  // nodes per axis, deformed flag, fixed-point iterations (both inverses)
    deform: vec4<f32>,     // colour scale (mm), air threshold (HU), coloured from (mm)
}

@group(0) @binding(0) var<uniform> P: Params;
// binding 1: the CT (prepended by the host)
@group(0) @binding(2) var partial: texture_3d<u32>;
// Per label id: (RGBA8 colour, 1 when the label is in the table).
@group(0) @binding(3) var<storage, read> colors: array<vec2<u32>>;
// Per pixel: (RGBA8, partial label).
@group(0) @binding(4) var<storage, read_write> out_px: array<vec2<u32>>;
// u at the lattice's nodes (mm; w unused), x fastest (one dummy node without a deformation).
@group(0) @binding(5) var<storage, read> field_u: array<vec4<f32>>;

// sample_ct: ct_sample.wgsl (prepended by the host).

fn index_of(col: i32, row: i32) -> vec3<f32> {
    return P.origin.xyz + P.col_step.xyz * f32(col) + P.row_step.xyz * f32(row);
}

// Lattice::sample_with: trilinear u at world point x, 0 outside the lattice.
fn u_at(x: vec3<f32>) -> vec3<f32> {
    let n = P.lattice_n.x;
    let c = (x - P.lattice.xyz) / P.lattice.w;
    let m = f32(n - 1u);
    if !(all(c >= vec3<f32>(0.0)) && all(c <= vec3<f32>(m))) {
        return vec3<f32>(0.0);
    }
    let i = min(vec3<u32>(c), vec3<u32>(n - 2u));
    let f = c - vec3<f32>(i);
    let o = i.x + n * (i.y + n * i.z);
    let sy = n;
    let sz = n * n;
    let x00 = field_u[o].xyz * (1.0 - f.x) + field_u[o + 1u].xyz * f.x;
    let x10 = field_u[o + sy].xyz * (1.0 - f.x) + field_u[o + sy + 1u].xyz * f.x;
    let x01 = field_u[o + sz].xyz * (1.0 - f.x) + field_u[o + sz + 1u].xyz * f.x;
    let x11 = field_u[o + sz + sy].xyz * (1.0 - f.x) + field_u[o + sz + sy + 1u].xyz * f.x;
    let y0 = x00 * (1.0 - f.y) + x10 * f.y;
    let y1 = x01 * (1.0 - f.y) + x11 * f.y;
    return y0 * (1.0 - f.z) + y1 * f.z;
}

// Where pixel (col, row) reads the CT (index c) and how far its tissue moved (mm).
struct Reading {
    c: vec3<f32>,
    moved_mm: f32,
}

fn world_to_index(x: vec3<f32>) -> vec3<f32> {
    return P.to_index_o.xyz + P.to_index_x.xyz * x.x + P.to_index_y.xyz * x.y + P.to_index_z.xyz * x.z;
}

fn reading_of(col: i32, row: i32) -> Reading {
    let moving = breathing();
    if P.lattice_n.y == 0u && !moving {
        return Reading(index_of(col, row), 0.0);
    }
    var x = P.w_origin.xyz + P.w_col.xyz * f32(col) + P.w_row.xyz * f32(row);
    if moving {
        x = invert_breathing(x, P.lattice_n.z);
    }
    let lo = P.lattice.xyz;
    let hi = lo + vec3<f32>(P.lattice.w * f32(P.lattice_n.x - 1u));
    if P.lattice_n.y == 0u || !(all(x >= lo) && all(x <= hi)) {
        if moving {
            return Reading(world_to_index(x), 0.0);
        }
        return Reading(index_of(col, row), 0.0);
    }
    var r = x;
    for (var it = 0u; it < P.lattice_n.z; it++) {
        r = x - u_at(r);
    }
    return Reading(world_to_index(r), length(u_at(r)));
}

// mpr::displacement_rgb: dark blue → cyan → yellow → red over t in 0 … 1.
fn displacement_rgb(t_in: f32) -> vec3<f32> {
    let t = clamp(t_in, 0.0, 1.0);
    var t0 = 0.0;
    var t1 = 0.35;
    var c0 = vec3<f32>(40.0, 40.0, 200.0);
    var c1 = vec3<f32>(0.0, 200.0, 230.0);
    if t >= 0.7 {
        t0 = 0.7;
        t1 = 1.0;
        c0 = vec3<f32>(255.0, 230.0, 0.0);
        c1 = vec3<f32>(230.0, 30.0, 20.0);
    } else if t >= 0.35 {
        t0 = 0.35;
        t1 = 0.7;
        c0 = vec3<f32>(0.0, 200.0, 230.0);
        c1 = vec3<f32>(255.0, 230.0, 0.0);
    }
    let f = (t - t0) / (t1 - t0);
    return floor(c0 + (c1 - c0) * f + 0.5);
}

// mpr::nearest_voxel_f32 then the partial label; 0 outside.
fn label_at(col: i32, row: i32) -> u32 {
    let c = reading_of(col, row).c;
    var v = vec3<i32>(0);
    for (var a = 0; a < 3; a++) {
        let r = c[a] + 0.5;
        if !(r >= 0.0 && r < f32(P.dims[a])) {
            return 0u;
        }
        v[a] = i32(u32(r));
    }
    return textureLoad(partial, v, 0).x;
}

fn round8(v: f32) -> u32 {
    return u32(floor(v + 0.5));
}

@compute @workgroup_size(8, 8, 1)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let w = P.size.x;
    let h = P.size.y;
    if gid.x >= w || gid.y >= h {
        return;
    }
    let col = i32(gid.x);
    let row = i32(gid.y);
    // mpr::window_gray_f32.
    let reading = reading_of(col, row);
    let hu = sample_ct(reading.c);
    let t = (hu - (P.window.x - P.window.y * 0.5)) / P.window.y;
    let g = round8(clamp(t, 0.0, 1.0) * 255.0);
    var px = vec3<u32>(g, g, g);
    let l = label_at(col, row);
    if l != 0u && l < P.dims.w && colors[l].y == 1u {
        let packed = colors[l].x;
        let c = vec4<f32>(f32(packed & 255u), f32((packed >> 8u) & 255u), f32((packed >> 16u) & 255u), f32(packed >> 24u));
        // Boundary: a 4-neighbour with another label, or the image edge.
        var edge = false;
        let offs = array<vec2<i32>, 4>(vec2<i32>(0, 1), vec2<i32>(1, 0), vec2<i32>(0, -1), vec2<i32>(-1, 0));
        for (var i = 0; i < 4; i++) {
            let cc = col + offs[i].x;
            let rr = row + offs[i].y;
            if cc < 0 || rr < 0 || cc >= i32(w) || rr >= i32(h) || label_at(cc, rr) != l {
                edge = true;
            }
        }
        var alpha = 1.0;
        if !edge {
            alpha = c.w / 255.0 * 0.6;
        }
        let blended = vec3<f32>(px) * (1.0 - alpha) + c.xyz * alpha;
        px = vec3<u32>(round8(blended.x), round8(blended.y), round8(blended.z));
    }
    // The displacement colour map over tissue (air moving with the skin is not shown).
    let moved = select(0.0, reading.moved_mm, hu >= P.deform.y);
    let shown_from = P.deform.z;
    if moved >= shown_from {
        let c = displacement_rgb(moved / P.deform.x);
        let alpha = 0.6 * min((moved - shown_from) / shown_from, 1.0);
        let blended = vec3<f32>(px) * (1.0 - alpha) + c * alpha;
        px = vec3<u32>(round8(blended.x), round8(blended.y), round8(blended.z));
    }
    out_px[gid.y * w + gid.x] = vec2<u32>(px.x | (px.y << 8u) | (px.z << 16u) | (255u << 24u), l);
}
