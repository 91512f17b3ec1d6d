//! The tools as the renderers see them (thesis §3.2.4: drawn with correct depth against the
//! volume): the bent needle as a tube along its nodes with a hub, the fingertip, the linear and
//! the convex probe. Taken from a `Simulation` snapshot at a tick; turned into a short list of
//! analytic primitives (capsules, spheres, boxes) that both renderers intersect with the same
//! formulas (docs/rendering.md "Tools").

use stylet_physics::glam::{Quat, Vec3};
use stylet_physics::ProbeKind;

/// The needle: nodes from hub to tip (mm, world space), outer diameter and the hub's size.
#[derive(Debug, Clone, PartialEq)]
pub struct NeedleShape {
    pub nodes_mm: Vec<Vec3>,
    pub diameter_mm: f32,
    /// The hub (handle) continues the shaft backwards from the first node.
    pub hub_length_mm: f32,
    pub hub_diameter_mm: f32,
}

/// The fingertip: a sphere at the device position.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FingerShape {
    pub center_mm: Vec3,
    pub radius_mm: f32,
}

/// An ultrasound probe at the device pose: it presses along its +z axis, its transducer array
/// runs along +x (physics' contact patterns, thesis Fig. 3.8).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProbeShape {
    pub kind: ProbeKind,
    pub position_mm: Vec3,
    pub orientation: Quat,
}

/// The tools in the scene at one moment.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ToolState {
    pub needle: Option<NeedleShape>,
    pub finger: Option<FingerShape>,
    pub probe: Option<ProbeShape>,
}

/// The most primitives a scene's tools may produce (the GPU keeps them in a fixed buffer).
pub const MAX_PRIMITIVES: usize = 128;
