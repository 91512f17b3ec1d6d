//! Tools as primitives (docs/rendering.md "Tools"): analytic ray hits, the nearest of several,
//! misses, rays from inside, Phong shading, the tool state of a simulation, and the tool shadows
//! of Alg. 3.1/3.2.

use std::sync::Arc;

use stylet_physics::glam::{DQuat, DVec3, Quat, Vec3};
use stylet_physics::{
    Affine, DeviceProfile, Gauge, Grid, ProbeKind, PunctureAtlas, Role, SimConfig, Simulation, TickInput, ToolSpec,
};
use stylet_render::scene::Light;
use stylet_render::shadow::Shadows;
use stylet_render::synthetic;
use stylet_render::tools::{
    FingerShape, MAX_PRIMITIVES, NeedleShape, Primitive, ProbeShape, ToolState, nearest_hit, shade,
};

const RGB: Vec3 = Vec3::new(0.5, 0.6, 0.7);

fn close(a: f32, b: f32, tol: f32) -> bool {
    (a - b).abs() <= tol
}

fn close3(a: Vec3, b: Vec3, tol: f32) -> bool {
    (a - b).abs().max_element() <= tol
}

#[test]
fn sphere_hit_distance_and_normal() {
    let s = Primitive::Sphere {
        center: Vec3::new(0.0, 0.0, 10.0),
        radius: 2.0,
        rgb: RGB,
    };
    let h = nearest_hit(&[s], Vec3::ZERO, Vec3::Z, 100.0).unwrap();
    assert!(close(h.t, 8.0, 1e-5), "{h:?}");
    assert!(close3(h.normal, -Vec3::Z, 1e-5));
    assert_eq!(h.rgb, RGB);
    // Off-centre: the ray at x = 1 meets the sphere where z = 10 − √3.
    let h = nearest_hit(&[s], Vec3::new(1.0, 0.0, 0.0), Vec3::Z, 100.0).unwrap();
    assert!(close(h.t, 10.0 - 3f32.sqrt(), 1e-4), "{h:?}");
    assert!(close3(h.normal, Vec3::new(0.5, 0.0, -(3f32.sqrt()) / 2.0), 1e-4));
    // Misses: beside it, behind the origin, beyond t_max.
    assert!(nearest_hit(&[s], Vec3::new(2.5, 0.0, 0.0), Vec3::Z, 100.0).is_none());
    assert!(nearest_hit(&[s], Vec3::ZERO, -Vec3::Z, 100.0).is_none());
    assert!(nearest_hit(&[s], Vec3::ZERO, Vec3::Z, 7.9).is_none());
    // From inside: the exit, normal outward.
    let h = nearest_hit(&[s], Vec3::new(0.0, 0.0, 10.0), Vec3::X, 100.0).unwrap();
    assert!(close(h.t, 2.0, 1e-5) && close3(h.normal, Vec3::X, 1e-5), "{h:?}");
}

#[test]
fn capsule_hits_side_and_caps() {
    let c = Primitive::Capsule {
        a: Vec3::new(0.0, 0.0, 0.0),
        b: Vec3::new(0.0, 0.0, 20.0),
        radius: 1.0,
        rgb: RGB,
    };
    // Side: a ray along x at z = 10.
    let h = nearest_hit(&[c], Vec3::new(-10.0, 0.0, 10.0), Vec3::X, 100.0).unwrap();
    assert!(close(h.t, 9.0, 1e-5) && close3(h.normal, -Vec3::X, 1e-5), "{h:?}");
    // Cap at b: a ray down the axis from above meets the hemisphere's pole at z = 21.
    let h = nearest_hit(&[c], Vec3::new(0.0, 0.0, 30.0), -Vec3::Z, 100.0).unwrap();
    assert!(close(h.t, 9.0, 1e-5) && close3(h.normal, Vec3::Z, 1e-5), "{h:?}");
    // Cap at a from below, off axis by 0.6: the sphere around a at z = −0.8.
    let h = nearest_hit(&[c], Vec3::new(0.6, 0.0, -10.0), Vec3::Z, 100.0).unwrap();
    assert!(
        close(h.t, 9.2, 1e-4) && close3(h.normal, Vec3::new(0.6, 0.0, -0.8), 1e-4),
        "{h:?}"
    );
    // A slanted ray that passes the end: misses.
    assert!(nearest_hit(&[c], Vec3::new(-10.0, 0.0, 22.5), Vec3::X, 100.0).is_none());
    // Parallel to the axis, outside the radius.
    assert!(nearest_hit(&[c], Vec3::new(1.5, 0.0, -5.0), Vec3::Z, 100.0).is_none());
    // From inside the shaft: the exit on the far side.
    let h = nearest_hit(&[c], Vec3::new(0.0, 0.0, 10.0), Vec3::Y, 100.0).unwrap();
    assert!(close(h.t, 1.0, 1e-5) && close3(h.normal, Vec3::Y, 1e-5), "{h:?}");
    // A capsule along a diagonal: the analytic distance to the axis line.
    let d = Vec3::new(1.0, 1.0, 0.0).normalize();
    let c = Primitive::Capsule {
        a: Vec3::ZERO,
        b: d * 30.0,
        radius: 0.5,
        rgb: RGB,
    };
    let o = Vec3::new(10.0, 10.0, -10.0);
    let h = nearest_hit(&[c], o, Vec3::Z, 100.0).unwrap();
    assert!(close(h.t, 10.0 - 0.5, 1e-4), "{h:?}");
}

#[test]
fn oriented_box_hits() {
    let r = Quat::from_rotation_z(30f32.to_radians());
    let b = Primitive::Box {
        center: Vec3::new(5.0, 0.0, 0.0),
        axes: [r * Vec3::X, r * Vec3::Y, r * Vec3::Z],
        half_mm: Vec3::new(2.0, 3.0, 4.0),
        rgb: RGB,
    };
    // Down the box's local z through its centre: the top face at 4 mm.
    let h = nearest_hit(&[b], Vec3::new(5.0, 0.0, 10.0), -Vec3::Z, 100.0).unwrap();
    assert!(close(h.t, 6.0, 1e-5) && close3(h.normal, Vec3::Z, 1e-5), "{h:?}");
    // Along the box's local x toward the centre: the face at 2 mm, normal −local x.
    let ax = r * Vec3::X;
    let o = Vec3::new(5.0, 0.0, 0.0) - ax * 10.0;
    let h = nearest_hit(&[b], o, ax, 100.0).unwrap();
    assert!(close(h.t, 8.0, 1e-4) && close3(h.normal, -ax, 1e-4), "{h:?}");
    // Parallel to a face outside it: miss; from the centre: exit at 3 mm along local y.
    assert!(nearest_hit(&[b], Vec3::new(5.0, 0.0, 5.0), ax, 100.0).is_none());
    let ay = r * Vec3::Y;
    let h = nearest_hit(&[b], Vec3::new(5.0, 0.0, 0.0), ay, 100.0).unwrap();
    assert!(close(h.t, 3.0, 1e-4) && close3(h.normal, ay, 1e-4), "{h:?}");
}

#[test]
fn cut_cylinder_is_a_circular_segment() {
    // Radius 10 around the y axis at the origin, 4 mm half length, keeping z ≥ 8.
    let c = Primitive::Cylinder {
        center: Vec3::ZERO,
        axis: Vec3::Y,
        radius: 10.0,
        half_length_mm: 4.0,
        cut_normal: Vec3::Z,
        cut_mm: 8.0,
        rgb: RGB,
    };
    // From above along −z at x = 0: the curved face at z = 10.
    let h = nearest_hit(&[c], Vec3::new(0.0, 0.0, 20.0), -Vec3::Z, 100.0).unwrap();
    assert!(close(h.t, 10.0, 1e-4) && close3(h.normal, Vec3::Z, 1e-4), "{h:?}");
    // At x = 6 the curved face is at z = 8: the ray from above meets it there (normal radial).
    let h = nearest_hit(&[c], Vec3::new(5.0, 0.0, 20.0), -Vec3::Z, 100.0).unwrap();
    let z = (100f32 - 25.0).sqrt();
    assert!(
        close(h.t, 20.0 - z, 1e-3) && close3(h.normal, Vec3::new(5.0, 0.0, z) / 10.0, 1e-3),
        "{h:?}"
    );
    // From below: the flat cut at z = 8, normal −z.
    let h = nearest_hit(&[c], Vec3::new(0.0, 0.0, 0.0), Vec3::Z, 100.0).unwrap();
    assert!(close(h.t, 8.0, 1e-4) && close3(h.normal, -Vec3::Z, 1e-5), "{h:?}");
    // Along the axis through the segment: the cap at y = −4.
    let h = nearest_hit(&[c], Vec3::new(0.0, -10.0, 9.0), Vec3::Y, 100.0).unwrap();
    assert!(close(h.t, 6.0, 1e-4) && close3(h.normal, -Vec3::Y, 1e-5), "{h:?}");
    // Below the cut, or past the rim: misses.
    assert!(nearest_hit(&[c], Vec3::new(-20.0, 0.0, 5.0), Vec3::X, 100.0).is_none());
    assert!(nearest_hit(&[c], Vec3::new(8.0, 0.0, 20.0), -Vec3::Z, 100.0).is_none());
}

#[test]
fn nearest_of_several_wins_with_its_colour() {
    let far = Primitive::Sphere {
        center: Vec3::new(0.0, 0.0, 30.0),
        radius: 5.0,
        rgb: Vec3::X,
    };
    let near = Primitive::Capsule {
        a: Vec3::new(-5.0, 0.0, 10.0),
        b: Vec3::new(5.0, 0.0, 10.0),
        radius: 1.0,
        rgb: Vec3::Y,
    };
    let off = Primitive::Sphere {
        center: Vec3::new(50.0, 0.0, 5.0),
        radius: 1.0,
        rgb: Vec3::Z,
    };
    for prims in [[far, near, off], [off, near, far], [near, off, far]] {
        let h = nearest_hit(&prims, Vec3::ZERO, Vec3::Z, 100.0).unwrap();
        assert!(close(h.t, 9.0, 1e-5), "{h:?}");
        assert_eq!(h.rgb, Vec3::Y);
    }
    // With the near one out of reach, the far sphere.
    let h = nearest_hit(&[far, off], Vec3::ZERO, Vec3::Z, 100.0).unwrap();
    assert!(close(h.t, 25.0, 1e-5) && h.rgb == Vec3::X);
    assert!(nearest_hit(&[], Vec3::ZERO, Vec3::Z, 100.0).is_none());
}

#[test]
fn phong_shading_of_a_hit() {
    let light = Light {
        toward_light: Vec3::Z,
        ambient: 0.2,
        diffuse: 0.6,
        specular: 0.3,
        shininess: 8.0,
        shadow_in: 0.4,
    };
    let hit = stylet_render::tools::ToolHit {
        t: 1.0,
        normal: Vec3::Z,
        rgb: Vec3::new(0.5, 0.5, 1.0),
    };
    // Light and view head-on: rgb·(0.2 + 0.6) + 0.3, clamped.
    let c = shade(&hit, &light, -Vec3::Z);
    assert!(close3(c, Vec3::new(0.7, 0.7, 1.0), 1e-5), "{c}");
    // Light behind the surface, viewer behind too: ambient only (N·L < 0 and N·H < 0).
    let back = Light {
        toward_light: -Vec3::Z,
        ..light
    };
    let c = shade(&hit, &back, Vec3::Z);
    assert!(close3(c, hit.rgb * 0.2, 1e-5), "{c}");
    // Light at 60° from the normal, viewer head-on: diffuse ½, H at 30°: cos^8 30°.
    let l = Vec3::new(3f32.sqrt() / 2.0, 0.0, 0.5);
    let c = shade(
        &hit,
        &Light {
            toward_light: l,
            ..light
        },
        -Vec3::Z,
    );
    let spec = 0.3 * (30f32.to_radians().cos()).powf(8.0);
    let want = (hit.rgb * (0.2 + 0.6 * 0.5) + Vec3::splat(spec)).min(Vec3::ONE);
    assert!(close3(c, want, 1e-4), "{c} vs {want}");
}

fn needle_shape(nodes: Vec<Vec3>) -> NeedleShape {
    NeedleShape {
        nodes_mm: nodes,
        diameter_mm: 1.27,
        hub_length_mm: 20.0,
        hub_diameter_mm: 4.0,
    }
}

#[test]
fn tool_state_primitives() {
    // A straight 150 mm needle of 31 nodes down −z: 30 shaft capsules and the hub behind node 0.
    let nodes: Vec<Vec3> = (0..31).map(|j| Vec3::new(0.0, 0.0, 150.0 - 5.0 * j as f32)).collect();
    let state = ToolState {
        needle: Some(needle_shape(nodes)),
        ..Default::default()
    };
    let prims = state.primitives();
    assert_eq!(prims.len(), 31);
    // A ray across the shaft meets it at the needle's radius; across the hub at 2 mm.
    let h = nearest_hit(&prims, Vec3::new(-10.0, 0.0, 50.0), Vec3::X, 100.0).unwrap();
    assert!(close(h.t, 10.0 - 0.635, 1e-4), "{h:?}");
    let h = nearest_hit(&prims, Vec3::new(-10.0, 0.0, 160.0), Vec3::X, 100.0).unwrap();
    assert!(close(h.t, 8.0, 1e-4) && h.rgb == stylet_render::tools::HUB_RGB, "{h:?}");
    // The hub ends 20 mm behind node 0 and the tip ends at the last node (plus the radius).
    assert!(nearest_hit(&prims, Vec3::new(-10.0, 0.0, 170.5), Vec3::X, 100.0).is_none());
    let h = nearest_hit(&prims, Vec3::new(0.0, 0.0, -10.0), Vec3::Z, 100.0).unwrap();
    assert!(close(h.t, 10.0 - 0.635, 1e-4), "{h:?}");
    // A needle with very many nodes is merged under the limit, still reaching the tip.
    let many: Vec<Vec3> = (0..1001).map(|j| Vec3::new(0.0, 0.0, 100.0 - 0.1 * j as f32)).collect();
    let state = ToolState {
        lines: Vec::new(),
        needle: Some(needle_shape(many)),
        finger: Some(FingerShape {
            center_mm: Vec3::new(50.0, 0.0, 0.0),
            radius_mm: 8.0,
        }),
        probe: Some(ProbeShape {
            kind: ProbeKind::Convex,
            position_mm: Vec3::new(-50.0, 0.0, 0.0),
            orientation: Quat::IDENTITY,
        }),
    };
    let prims = state.primitives();
    assert!(prims.len() <= MAX_PRIMITIVES, "{}", prims.len());
    let h = nearest_hit(&prims, Vec3::new(0.0, 0.0, -10.0), Vec3::Z, 100.0).unwrap();
    assert!(close(h.t, 10.0 - 0.635, 1e-3), "{h:?}");
}

/// The exchange's instruments are drawn as capsules of their diameter in their colours; with a
/// needle and many-noded lines, all of them reach their tips under the limit.
#[test]
fn the_wire_and_catheter_are_drawn_like_the_needle() {
    use stylet_render::tools::{CATHETER_RGB, LineKind, LineShape, WIRE_RGB};
    let straight =
        |x: f32, n: usize| -> Vec<Vec3> { (0..n).map(|j| Vec3::new(x, 0.0, 100.0 - 0.5 * j as f32)).collect() };
    let state = ToolState {
        needle: Some(needle_shape(straight(0.0, 201))),
        lines: vec![
            LineShape {
                kind: LineKind::GuideWire,
                nodes_mm: straight(10.0, 256),
                diameter_mm: 0.889,
            },
            LineShape {
                kind: LineKind::Catheter,
                nodes_mm: straight(20.0, 256),
                diameter_mm: 2.67,
            },
        ],
        ..Default::default()
    };
    let prims = state.primitives();
    assert!(prims.len() <= MAX_PRIMITIVES, "{}", prims.len());
    // Across each: its radius and its colour.
    let h = nearest_hit(&prims, Vec3::new(5.0, -10.0, 50.0) + Vec3::X * 5.0, Vec3::Y, 100.0).unwrap();
    assert!(close(h.t, 10.0 - 0.4445, 1e-4) && h.rgb == WIRE_RGB, "{h:?}");
    let h = nearest_hit(&prims, Vec3::new(20.0, -10.0, 50.0), Vec3::Y, 100.0).unwrap();
    assert!(close(h.t, 10.0 - 1.335, 1e-4) && h.rgb == CATHETER_RGB, "{h:?}");
    // Each reaches its tip (z = 100 − 0.5 · 255 = −27.5 for the lines, 0 for the needle).
    for (x, tip_z, r) in [(0.0, 0.0, 0.635), (10.0, -27.5, 0.4445), (20.0, -27.5, 1.335)] {
        let h = nearest_hit(&prims, Vec3::new(x, 0.0, -40.0), Vec3::Z, 100.0).unwrap();
        assert!(close(h.t, 40.0 + tip_z - r, 1e-3), "x {x}: {h:?}");
    }
}

#[test]
fn probes_are_posed_as_physics_presses_them() {
    // A linear probe pressing down (+z of the probe = −z of the world), array along world +y.
    let q = Quat::from_rotation_arc(Vec3::Z, -Vec3::Z);
    let q = Quat::from_rotation_arc(q * Vec3::X, Vec3::Y) * q;
    let p = ProbeShape {
        kind: ProbeKind::Linear,
        position_mm: Vec3::new(0.0, 0.0, 10.0),
        orientation: q,
    };
    let prims = p.primitives();
    // From below, the face at the device position: z = 10, normal −z (toward the skin).
    let h = nearest_hit(&prims, Vec3::ZERO, Vec3::Z, 100.0).unwrap();
    assert!(close(h.t, 10.0, 1e-4) && close3(h.normal, -Vec3::Z, 1e-4), "{h:?}");
    // The array runs along world y: 40 mm long (hit at ±19 mm, not at ±21 mm), 10 mm across x.
    assert!(nearest_hit(&prims, Vec3::new(0.0, 19.0, 0.0), Vec3::Z, 100.0).is_some());
    assert!(nearest_hit(&prims, Vec3::new(0.0, 21.0, 0.0), Vec3::Z, 12.0).is_none());
    assert!(nearest_hit(&prims, Vec3::new(6.0, 0.0, 0.0), Vec3::Z, 12.0).is_none());
    // The handle rises 60 mm and more above the face.
    let h = nearest_hit(&prims, Vec3::new(-50.0, 0.0, 70.0), Vec3::X, 100.0).unwrap();
    assert!(close(h.t, 50.0 - 4.5, 1e-3), "{h:?}");
    // A convex probe's face bulges: its apex at the device position, the rim 6.7 mm back.
    let c = ProbeShape {
        kind: ProbeKind::Convex,
        ..p
    };
    let prims = c.primitives();
    let h = nearest_hit(&prims, Vec3::ZERO, Vec3::Z, 100.0).unwrap();
    assert!(close(h.t, 10.0, 1e-3) && close3(h.normal, -Vec3::Z, 1e-3), "{h:?}");
    let h = nearest_hit(&prims, Vec3::new(0.0, 24.0, 0.0), Vec3::Z, 100.0).unwrap();
    let sag = 50.0 - (50f32 * 50.0 - 24.0 * 24.0).sqrt();
    assert!(close(h.t, 10.0 + sag, 1e-3), "{h:?} {sag}");
}

/// A 128 mm cube of 2 mm voxels: a ball of soft tissue (r 40 mm) in fat (to r 55 mm) in air.
fn ball_atlas() -> PunctureAtlas {
    let g = Grid::new([64; 3], Affine::from_spacing([2.0; 3], DVec3::splat(-63.0))).unwrap();
    let ct: Vec<f32> = (0..g.len())
        .map(|i| {
            let [a, b, c] = g.unlinear(i);
            let r = g.voxel_to_world(a, b, c).length();
            if r < 40.0 {
                60.0
            } else if r < 55.0 {
                -100.0
            } else {
                -1000.0
            }
        })
        .collect();
    let labels: Vec<u16> = ct.iter().map(|&v| if v == 60.0 { 10 } else { 0 }).collect();
    synthetic::atlas_with(g, ct, labels, &[(10, "liver", Role::Organ)])
}

#[test]
fn needle_from_a_simulation_ends_at_the_tip() {
    let atlas = Arc::new(ball_atlas());
    let tool = ToolSpec::Needle {
        gauge: Gauge::G18,
        length_mm: 150.0,
        stylet_in: true,
    };
    let mut sim = Simulation::new(atlas, SimConfig::new(DeviceProfile::IDEAL, tool)).unwrap();
    // Tilted 10° from straight down, entering the ball from above.
    let q = DQuat::from_rotation_x(170f64.to_radians());
    let axis = q * DVec3::Z;
    let start = DVec3::new(0.0, 0.0, 70.0);
    // Before any tick: the needle lies on the device ray.
    let input = TickInput::pose(start, q);
    let before = ToolState::from_simulation(&sim, &input);
    let n = before.needle.as_ref().unwrap();
    assert!(close3(n.tip_mm(), start.as_vec3(), 1e-4));
    assert!(close(n.length_mm(), 150.0, 1e-2));
    assert!(close3(n.tip_tangent(), axis.as_vec3(), 1e-5));
    let mut inside = 0;
    for k in 0..3000 {
        let x = start + axis * (k as f64 * 0.015);
        let input = TickInput::pose(x, q);
        let out = sim.step(&input);
        let state = ToolState::from_simulation(&sim, &input);
        let n = state.needle.as_ref().unwrap();
        assert!(state.finger.is_none() && state.probe.is_none());
        assert!(
            close3(n.tip_mm(), out.tip_mm.as_vec3(), 1e-3),
            "tick {k}: {} vs {}",
            n.tip_mm(),
            out.tip_mm
        );
        assert!(close(n.diameter_mm, 1.27, 1e-6));
        inside += usize::from(out.inserted_mm > 1.0);
        if k % 500 == 0 || k == 2999 {
            // The tip tangent follows the insertion direction.
            assert!(n.tip_tangent().dot(out.insertion_dir.as_vec3()) > 0.99, "tick {k}");
        }
    }
    assert!(inside > 100, "the needle never went in ({inside} ticks)");
}

#[test]
fn contact_tools_from_a_simulation() {
    let atlas = Arc::new(ball_atlas());
    let q = DQuat::from_rotation_x(std::f64::consts::PI); // pressing down
    let pos = DVec3::new(0.0, 0.0, 56.0);
    let input = TickInput::pose(pos, q);
    for (spec, finger, probe) in [
        (ToolSpec::Finger, true, None),
        (ToolSpec::Probe(ProbeKind::Linear), false, Some(ProbeKind::Linear)),
        (ToolSpec::Probe(ProbeKind::Convex), false, Some(ProbeKind::Convex)),
    ] {
        let mut sim = Simulation::new(atlas.clone(), SimConfig::new(DeviceProfile::IDEAL, spec)).unwrap();
        sim.step(&input);
        let s = ToolState::from_simulation(&sim, &input);
        assert!(s.needle.is_none());
        assert_eq!(s.finger.is_some(), finger);
        if let Some(f) = s.finger {
            // The pad's apex at the device position, the sphere behind it.
            assert!(close3(f.center_mm, Vec3::new(0.0, 0.0, 64.0), 1e-4), "{f:?}");
            let h = nearest_hit(&s.primitives(), Vec3::ZERO, Vec3::Z, 100.0).unwrap();
            assert!(close(h.t, 56.0, 1e-3));
        }
        assert_eq!(s.probe.map(|p| p.kind), probe);
        if let Some(p) = s.probe {
            assert!(close3(p.position_mm, pos.as_vec3(), 1e-5));
            let h = nearest_hit(&s.primitives(), Vec3::ZERO, Vec3::Z, 100.0).unwrap();
            assert!(close(h.t, 56.0, 1e-3), "{h:?}");
        }
    }
    // A glitching device draws no contact tool.
    let sim = Simulation::new(atlas, SimConfig::new(DeviceProfile::IDEAL, ToolSpec::Finger)).unwrap();
    let bad = TickInput::pose(DVec3::splat(f64::NAN), q);
    assert_eq!(ToolState::from_simulation(&sim, &bad), ToolState::default());
}

// ---------------------------------------------------------------------------------------------
// Shadows (Alg. 3.1, 3.2)

/// A straight 100 mm needle along +x ending at the origin (tip), light from above (+z).
fn needle_along_x() -> ToolState {
    let nodes: Vec<Vec3> = (0..11).map(|j| Vec3::new(-100.0 + 10.0 * j as f32, 0.0, 0.0)).collect();
    ToolState {
        needle: Some(NeedleShape {
            nodes_mm: nodes,
            diameter_mm: 2.0,
            hub_length_mm: 20.0,
            hub_diameter_mm: 6.0,
        }),
        ..Default::default()
    }
}

#[test]
fn needle_shadow_falls_away_from_the_light() {
    let s = Shadows::from_tools(&needle_along_x());
    let up = Vec3::Z;
    let f = |x: Vec3| s.factor(x, up, 0.3);
    for depth in [0.5, 5.0, 30.0, 200.0] {
        // Below the shaft and below the hub: in shadow.
        assert_eq!(f(Vec3::new(-50.0, 0.0, -depth)), 0.3, "below shaft at {depth}");
        assert_eq!(f(Vec3::new(-50.0, 0.9, -depth)), 0.3);
        assert_eq!(f(Vec3::new(-110.0, 2.9, -depth)), 0.3, "below hub at {depth}");
        // Above (on the light's side): lit.
        assert_eq!(f(Vec3::new(-50.0, 0.0, depth)), 1.0, "above at {depth}");
        // Beside the shaft (wider than its radius), beside the hub, past the tip, past the hub.
        assert_eq!(f(Vec3::new(-50.0, 1.1, -depth)), 1.0);
        assert_eq!(f(Vec3::new(-110.0, 3.1, -depth)), 1.0);
        assert_eq!(f(Vec3::new(1.0, 0.0, -depth)), 1.0);
        assert_eq!(f(Vec3::new(-121.0, 0.0, -depth)), 1.0);
    }
    // The hub is wider than the shaft only behind node 0.
    assert_eq!(f(Vec3::new(-50.0, 2.9, -5.0)), 1.0);
}

#[test]
fn needle_shadow_matches_the_projection_along_the_light() {
    // A slanted needle and a slanted light: project the needle along the light onto the plane
    // z = −40 and check points on and off that projection.
    let tip = Vec3::new(10.0, 5.0, 0.0);
    let dir = Vec3::new(0.3, -0.2, -1.0).normalize(); // insertion direction (hub → tip)
    let nodes: Vec<Vec3> = (0..16).map(|j| tip - dir * (150.0 - 10.0 * j as f32)).collect();
    let state = ToolState {
        needle: Some(NeedleShape {
            nodes_mm: nodes,
            diameter_mm: 1.5,
            hub_length_mm: 20.0,
            hub_diameter_mm: 4.0,
        }),
        ..Default::default()
    };
    let s = Shadows::from_tools(&state);
    let l = Vec3::new(-0.5, 0.4, 1.0).normalize();
    let plane_z = -200.0f32;
    // A needle point a projects to a + l·k with (a + l·k).z = plane_z.
    let project = |a: Vec3| a + l * ((plane_z - a.z) / l.z);
    let (tip_p, hub_p) = (project(tip), project(tip - dir * 150.0));
    let along = (hub_p - tip_p).normalize();
    // The in-plane direction across the shadow line.
    let across = Vec3::Z.cross(along).normalize();
    // The perpendicular distance (in the plane) that corresponds to the needle's radius: the
    // shadow cylinder's cross-section in the plane is 0.75 mm / |across·p̂| wide.
    let p_hat = l.cross(-dir).normalize();
    let half_width = 0.75 / across.dot(p_hat).abs();
    let mut checked = 0;
    for k in 1..10 {
        let c = tip_p + (hub_p - tip_p) * (k as f32 / 10.0);
        assert_eq!(s.factor(c, l, 0.5), 0.5, "on the projected shaft at {k}/10");
        assert_eq!(s.factor(c + across * (half_width * 0.8), l, 0.5), 0.5);
        assert_eq!(s.factor(c + across * (half_width * 1.2), l, 0.5), 1.0);
        assert_eq!(s.factor(c - across * (half_width * 1.2), l, 0.5), 1.0);
        // The same spot lit from the opposite side is not shadowed by this needle.
        assert_eq!(s.factor(c, -l, 0.5), 1.0);
        checked += 1;
    }
    assert_eq!(checked, 9);
    // Beyond the projected tip the plane is lit.
    assert_eq!(s.factor(tip_p - along * 3.0, l, 0.5), 1.0);
}

#[test]
fn light_along_the_needle_shades_a_disc_behind_it() {
    let s = Shadows::from_tools(&needle_along_x());
    // Light from behind the hub (−x): the hub's disc behind the tip.
    let from_hub = -Vec3::X;
    assert_eq!(s.factor(Vec3::new(20.0, 2.5, 0.0), from_hub, 0.2), 0.2);
    assert_eq!(s.factor(Vec3::new(20.0, 3.5, 0.0), from_hub, 0.2), 1.0);
    assert_eq!(s.factor(Vec3::new(-150.0, 0.0, 0.0), from_hub, 0.2), 1.0);
    // Light from ahead of the tip (+x): the shaft's disc, then the hub's beyond l̄.
    assert_eq!(s.factor(Vec3::new(-50.0, 0.5, 0.0), Vec3::X, 0.2), 0.2);
    assert_eq!(s.factor(Vec3::new(-150.0, 2.5, 0.0), Vec3::X, 0.2), 0.2);
    assert_eq!(s.factor(Vec3::new(5.0, 0.0, 0.0), Vec3::X, 0.2), 1.0);
}

#[test]
fn sphere_shadows_of_finger_and_probe() {
    let state = ToolState {
        finger: Some(FingerShape {
            center_mm: Vec3::new(0.0, 0.0, 20.0),
            radius_mm: 8.0,
        }),
        ..Default::default()
    };
    let s = Shadows::from_tools(&state);
    let l = Vec3::new(0.0, 0.6, 0.8);
    for depth in [1.0, 10.0, 100.0] {
        // The centre's projection along −l, and a point just inside and outside the disc.
        let c = Vec3::new(0.0, 0.0, 20.0) - l * (8.0 + depth);
        let across = Vec3::X;
        assert_eq!(s.factor(c, l, 0.4), 0.4, "below at {depth}");
        assert_eq!(s.factor(c + across * 7.9, l, 0.4), 0.4);
        assert_eq!(s.factor(c + across * 8.1, l, 0.4), 1.0);
        // On the light's side: lit.
        assert_eq!(s.factor(Vec3::new(0.0, 0.0, 20.0) + l * (8.0 + depth), l, 0.4), 1.0);
    }
    // A probe head casts one too, no needle.
    let state = ToolState {
        probe: Some(ProbeShape {
            kind: ProbeKind::Linear,
            position_mm: Vec3::new(0.0, 0.0, 50.0),
            orientation: Quat::from_rotation_x(std::f32::consts::PI),
        }),
        ..Default::default()
    };
    let s = Shadows::from_tools(&state);
    assert!(s.needle.is_none() && s.spheres.len() == 1);
    assert_eq!(s.factor(Vec3::new(0.0, 0.0, 0.0), Vec3::Z, 0.4), 0.4);
    assert_eq!(s.factor(Vec3::new(40.0, 0.0, 0.0), Vec3::Z, 0.4), 1.0);
    assert_eq!(s.factor(Vec3::new(0.0, 0.0, 100.0), Vec3::Z, 0.4), 1.0);
}
