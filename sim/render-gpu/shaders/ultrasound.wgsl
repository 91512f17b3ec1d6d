// Simulated ultrasound (docs/ultrasound.md): one workgroup per scan line (see `main`). A port of stylet-render's ultrasound module `Frame::scan_line`: the line's samples
// front to back (trilinear CT, nearest partial label, the label's echo class, impedance /
// attenuation / scatter from the frame tables, reflection and transmission, coupling gel, the
// tissue's speckle by the same 32-bit hash), the needle's echo, shadow and comet tail at the
// sample the host found, Doppler colour over vessels from the dense flow-axis grid, then time-gain
// compensation. A breathing patient: each sample reads the CT, the labels, the speckle and the
// flow at its reference point (motion.wgsl's `reference_of` along the line). The CT declaration
// and `ct_voxel` are prepended by the host. Output per sample:
// the envelope and the colour | flags << 24; the host compresses and scan-converts.

// Mirrored by `UsParams` in ultrasound.rs.
struct Params {
    face: vec4<f32>,       // face centre, world mm
    lateral: vec4<f32>,    // unit axes of the probe
    beam: vec4<f32>,
    row0: vec4<f32>,       // rows of the CT's inverse affine (index units per mm)
    row1: vec4<f32>,
    row2: vec4<f32>,
    origin: vec4<f32>,     // world position of voxel (0, 0, 0)
    dims: vec4<u32>,       // CT voxels; w: label ids in `classes`
    scan: vec4<u32>,       // lines, samples, 1 convex / 0 linear, 1 Doppler on
    geo: vec4<f32>,        // depth (mm), sample spacing (mm), convex radius (mm), half angle (rad)
    gains: vec4<f32>,      // specular gain, scatter gain, gel impedance, gel layer (mm)
    limits: vec4<f32>,     // air below (HU), Doppler min signal, vein speed, artery speed (m/s)
    doppler: vec4<f32>,    // cell (mm), wall filter, scale (m/s); w unused
    reverb: vec4<f32>,     // comet tail: each echo's share of the one before, echoes; zw unused
    fluid: vec4<f32>,      // z, loss, scatter
    blood: vec4<f32>,
    flow_first: vec4<i32>, // first cell of the dense flow grid
    flow_dims: vec4<u32>,  // cells per axis; w: speckle seed
    collect: vec4<f32>,    // fluid collections: count, soft tissue from / below (HU); w: pleura scatter
}

@group(0) @binding(0) var<uniform> P: Params;
// binding 1: the CT (prepended by the host)
@group(0) @binding(2) var partial: texture_3d<u32>;
@group(0) @binding(3) var<storage, read> classes: array<u32>;
@group(0) @binding(4) var<storage, read> tissue: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read> tgc: array<f32>;
// Two per line: (depth mm, specular, hit sample, 1 when hit) of the first instrument the line
// meets, and (reflection, transmission, comet tail spacing mm or 0) of its material.
@group(0) @binding(6) var<storage, read> hits: array<vec4<f32>>;
@group(0) @binding(7) var<storage, read> flow: array<vec4<f32>>;
@group(0) @binding(8) var<storage, read_write> out_env: array<f32>;
@group(0) @binding(9) var<storage, read_write> out_col: array<u32>;
// Fluid collections, two entries each: (centre, radius²), (z, loss, scatter) of what they hold.
@group(0) @binding(10) var<storage, read> collections: array<vec4<f32>>;

const AIR_HU: f32 = -1000.0;
const LUT_LOW_HU: i32 = -1024;
const LUT_LEN: i32 = 4096;
const LATTICE_MM: f32 = 0.5;
const FLAG_TARGET: u32 = 1u;
const FLAG_DOPPLER: u32 = 2u;

// sample_ct: ct_sample.wgsl (prepended by the host).

// sampler.rs `nearest_voxel` and the partial label there; 0 outside.
fn label_at(c: vec3<f32>) -> u32 {
    var v = vec3<i32>(0);
    for (var a = 0; a < 3; a++) {
        let r = c[a] + 0.5;
        if !(r >= 0.0 && r < f32(P.dims[a])) {
            return 0u;
        }
        v[a] = i32(r);
    }
    return textureLoad(partial, v, 0).x;
}

// speckle.rs `hash32` (lowbias32).
fn hash32(x0: u32) -> u32 {
    var x = x0;
    x ^= x >> 16u;
    x *= 0x7feb352du;
    x ^= x >> 15u;
    x *= 0x846ca68bu;
    return x ^ (x >> 16u);
}

fn node(i: i32, j: i32, k: i32, seed: u32) -> f32 {
    let h = hash32(bitcast<u32>(i) ^ hash32(bitcast<u32>(j) ^ hash32(bitcast<u32>(k) ^ seed)));
    let u = (f32(h >> 8u) + 1.0) * (1.0 / 16777216.0);
    return sqrt(-log(u)) * (2.0 / sqrt(3.14159265358979));
}

// speckle.rs `amplitude`.
fn speckle(x: vec3<f32>, seed: u32) -> f32 {
    let g = x * (1.0 / LATTICE_MM);
    let b = floor(g);
    let f = g - b;
    let i = i32(b.x);
    let j = i32(b.y);
    let k = i32(b.z);
    let r00 = mix(node(i, j, k, seed), node(i + 1, j, k, seed), f.x);
    let r10 = mix(node(i, j + 1, k, seed), node(i + 1, j + 1, k, seed), f.x);
    let r01 = mix(node(i, j, k + 1, seed), node(i + 1, j, k + 1, seed), f.x);
    let r11 = mix(node(i, j + 1, k + 1, seed), node(i + 1, j + 1, k + 1, seed), f.x);
    return mix(mix(r00, r10, f.y), mix(r01, r11, f.y), f.z);
}

// doppler.rs `FlowField::axis_at` on the dense grid; zero without a vessel.
fn flow_axis(x: vec3<f32>) -> vec3<f32> {
    let c = vec3<i32>(floor(x / P.doppler.x)) - P.flow_first.xyz;
    let d = vec3<i32>(P.flow_dims.xyz);
    if any(c < vec3<i32>(0)) || any(c >= d) {
        return vec3<f32>(0.0);
    }
    return flow[u32(c.x) + P.flow_dims.x * (u32(c.y) + P.flow_dims.y * u32(c.z))].xyz;
}

// doppler.rs `colour`, packed RGB; 0xffffffff: none.
fn doppler_colour(artery: bool, v: f32) -> u32 {
    if v < P.doppler.y {
        return 0xffffffffu;
    }
    let ramp = u32(floor(255.0 * min(v / P.doppler.z, 1.0) + 0.5));
    if artery {
        return 255u | (ramp << 8u);
    }
    return (ramp << 8u) | (255u << 16u);
}

// One workgroup per scan line. The line's samples go in chunks of CHUNK: the invocations read
// the CT, labels, speckle and flow of a chunk's samples side by side (what each sample needs that
// does not depend on the samples before it), then invocation 0 walks the chunk in order for what
// carries from sample to sample (transmission, coupling gel, impedance step, needle), with the
// same arithmetic as the CPU's `Frame::scan_line`. A breathing patient's reference points carry
// too (each fixed-point step starts from the previous sample's): invocation 0 finds a chunk's
// first. Then the comet tail, then time-gain compensation side by side.
const LANES: u32 = 64u;
const CHUNK: u32 = 256u;
// Bits of `s_code` above the candidate Doppler colour (24 bits).
const HAS_COLOUR: u32 = 0x1000000u;
const IS_TARGET: u32 = 0x2000000u;
const GEL_CANDIDATE: u32 = 0x4000000u;
const AIR: u32 = 0x8000000u;

var<workgroup> s_x: array<vec3<f32>, CHUNK>;
var<workgroup> s_z: array<f32, CHUNK>;
var<workgroup> s_loss: array<f32, CHUNK>;
var<workgroup> s_scatter: array<f32, CHUNK>;
var<workgroup> s_code: array<u32, CHUNK>;

@compute @workgroup_size(64)
fn main(@builtin(workgroup_id) wid: vec3<u32>, @builtin(local_invocation_index) lane: u32) {
    let i = wid.x;
    let lines = P.scan.x;
    let samples = P.scan.y;
    // probe.rs `ScanGeometry::line`.
    let f = (f32(i) + 0.5) / f32(lines);
    var origin = P.face.xyz + P.lateral.xyz * ((f - 0.5) * 40.0);
    var dir = P.beam.xyz;
    // probe.rs `gel_allowance_mm`: the gel layer beyond the face centre's tangent plane.
    var gel_max = P.gains.w;
    if P.scan.z == 1u {
        let theta = (2.0 * f - 1.0) * P.geo.w;
        dir = P.beam.xyz * cos(theta) + P.lateral.xyz * sin(theta);
        origin = (P.face.xyz - P.beam.xyz * P.geo.z) + dir * P.geo.z;
        gel_max = P.gains.w + P.geo.z * (1.0 / cos(theta) - 1.0);
    }
    let dz = P.geo.y;
    let hit = hits[2u * i];
    let material = hits[2u * i + 1u];
    let hit_sample = select(-1, i32(hit.z), hit.w > 0.5);
    let seed = P.flow_dims.w;
    let base = i * samples;
    let moving = breathing();
    // Invocation 0's state along the line.
    var travelling = 1.0;
    var z_prev = P.gains.z;
    var in_gel = true;
    var ring = 0.0;
    var rang = false;
    var warp = no_warp();
    for (var first = 0u; first < samples; first += CHUNK) {
        let count = min(CHUNK, samples - first);
        if moving && lane == 0u {
            for (var k = 0u; k < count; k++) {
                let depth = (f32(first + k) + 0.5) * dz;
                s_x[k] = reference_of(&warp, origin + dir * depth);
            }
        }
        workgroupBarrier();
        for (var k = lane; k < count; k += LANES) {
            let j = first + k;
            let depth = (f32(j) + 0.5) * dz;
            var x = origin + dir * depth;
            if moving {
                x = s_x[k];
            }
            let p = x - P.origin.xyz;
            // Beyond the CT's box: the voxel on its face (mod.rs `scan_line`).
            let c = clamp(
                vec3<f32>(dot(P.row0.xyz, p), dot(P.row1.xyz, p), dot(P.row2.xyz, p)),
                vec3<f32>(0.0),
                vec3<f32>(P.dims.xyz) - vec3<f32>(1.0),
            );
            let hu = sample_ct(c);
            let label = label_at(c);
            var code = 0u;
            if label < P.dims.w {
                code = classes[label];
            }
            let kind = code & 255u;
            var bits = 0u;
            if hu < P.limits.x {
                bits |= AIR;
                if depth <= gel_max {
                    bits |= GEL_CANDIDATE;
                }
            }
            if (code & 256u) != 0u {
                bits |= IS_TARGET;
            }
            var props = P.fluid.xyz;
            if kind == 0u {
                let h = clamp(i32(floor(hu + 0.5)) - LUT_LOW_HU, 0, LUT_LEN - 1);
                props = tissue[h].xyz;
                // mod.rs `collection_at`: the first collection holding soft tissue here.
                var in_collection = false;
                if hu >= P.collect.y && hu < P.collect.z {
                    for (var m = 0u; m < u32(P.collect.x); m++) {
                        let c = collections[2u * m];
                        let d = x - c.xyz;
                        if dot(d, d) <= c.w {
                            props = collections[2u * m + 1u].xyz;
                            in_collection = true;
                            break;
                        }
                    }
                }
                // mod.rs `slides`: the surface of a lung that slides under the chest wall.
                if !in_collection && (code & 512u) != 0u {
                    props.z = P.collect.w;
                }
            } else if kind >= 2u {
                props = P.blood.xyz;
            }
            var scatter = 0.0;
            if props.z > 0.0 {
                scatter = P.gains.y * props.z * speckle(x, seed);
            }
            if P.scan.w == 1u && kind >= 2u {
                let axis = flow_axis(x);
                if any(axis != vec3<f32>(0.0)) {
                    let speed = select(P.limits.z, P.limits.w, kind == 3u);
                    let rgb = doppler_colour(kind == 3u, speed * abs(dot(axis, dir)));
                    if rgb != 0xffffffffu {
                        bits |= HAS_COLOUR | rgb;
                    }
                }
            }
            s_z[k] = props.x;
            s_loss[k] = props.y;
            s_scatter[k] = scatter;
            s_code[k] = bits;
        }
        workgroupBarrier();
        if lane == 0u {
            for (var k = 0u; k < count; k++) {
                let j = first + k;
                let bits = s_code[k];
                let gel = in_gel && (bits & GEL_CANDIDATE) != 0u;
                if in_gel && !gel && (bits & AIR) != 0u {
                    travelling = 0.0;
                }
                in_gel = gel;
                if in_gel {
                    out_env[base + j] = 0.0;
                    out_col[base + j] = 0u;
                    continue;
                }
                let z = s_z[k];
                let r = (z - z_prev) / (z + z_prev);
                var echo = travelling * (P.gains.x * abs(r) + s_scatter[k]);
                travelling *= (1.0 - r * r) * s_loss[k];
                z_prev = z;
                if i32(j) == hit_sample {
                    let e = travelling * material.x * hit.y;
                    echo += e;
                    travelling *= material.y;
                    ring = e;
                    rang = material.z > 0.0;
                }
                out_env[base + j] = echo;
                var flags = 0u;
                var colour = 0u;
                if (bits & IS_TARGET) != 0u {
                    flags |= FLAG_TARGET;
                }
                if (bits & HAS_COLOUR) != 0u && travelling * tgc[j] >= P.limits.y {
                    colour = bits & 0xffffffu;
                    flags |= FLAG_DOPPLER;
                }
                out_col[base + j] = colour | (flags << 24u);
            }
        }
        workgroupBarrier();
    }
    // The comet tail.
    if lane == 0u && rang {
        var a = ring;
        for (var k = 1u; k <= u32(P.reverb.y); k++) {
            a *= P.reverb.x;
            let j = u32((hit.x + f32(k) * material.z) / dz);
            if j < samples {
                out_env[base + j] += a;
            }
        }
    }
    storageBarrier();
    for (var j = lane; j < samples; j += LANES) {
        out_env[base + j] *= tgc[j];
    }
}
