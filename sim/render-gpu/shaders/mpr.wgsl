// Multi-planar reformation (docs/rendering.md "MPR"): one invocation per pixel, 8 × 8
// workgroups. A port of stylet-render's mpr.rs `draw` and `overlay_labels`: the CT under a
// window (grey) and the partial labels blended in their property-tree colours, opaque on a
// label's boundary. The CT declaration and `ct_voxel` are prepended by the host, as for
// raycast.wgsl. The tip marker and the scale bar are drawn afterwards on the CPU (annotate).

const AIR_HU: f32 = -1000.0;

// Mirrored by `MprParams` in mpr.rs.
struct Params {
    origin: vec4<f32>,   // CT index of pixel (0, 0)'s centre
    col_step: vec4<f32>, // index step per column
    row_step: vec4<f32>, // index step per row
    dims: vec4<u32>,     // CT voxels, w number of label colours
    size: vec4<u32>,     // width, height
    window: vec4<f32>,   // level, width (HU)
}

@group(0) @binding(0) var<uniform> P: Params;
// binding 1: the CT (prepended by the host)
@group(0) @binding(2) var partial: texture_3d<u32>;
// Per label id: (RGBA8 colour, 1 when the label is in the table).
@group(0) @binding(3) var<storage, read> colors: array<vec2<u32>>;
// Per pixel: (RGBA8, partial label).
@group(0) @binding(4) var<storage, read_write> out_px: array<vec2<u32>>;

// sample_ct: ct_sample.wgsl (prepended by the host).

fn index_of(col: i32, row: i32) -> vec3<f32> {
    return P.origin.xyz + P.col_step.xyz * f32(col) + P.row_step.xyz * f32(row);
}

// mpr::nearest_voxel_f32 then the partial label; 0 outside.
fn label_at(col: i32, row: i32) -> u32 {
    let c = index_of(col, row);
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
    let hu = sample_ct(index_of(col, row));
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
    out_px[gid.y * w + gid.x] = vec2<u32>(px.x | (px.y << 8u) | (px.z << 16u) | (255u << 24u), l);
}
