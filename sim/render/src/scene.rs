//! The scene description both renderers draw (docs/rendering.md): camera, transfer function, light,
//! clip plane and tagging, quality switches, the tools taken from a simulation snapshot, and the
//! two hooks for the deformed tissue and the breathing motion (thesis eq. 3.1.1, eqs. 5.4.1–5.4.2).
//!
//! Everything is `f32`: the CPU reference and the GPU shader run the same arithmetic in the same
//! precision, so their images agree to a few grey levels.

use std::sync::Arc;

use stylet_physics::glam::Vec3;
use stylet_physics::motion::MotionModel;

use crate::tools::ToolState;
use crate::transfer::TransferFunction;

/// The camera, its rays and the light, also under this module's name.
pub use crate::camera::{Camera, ImageRays};
pub use crate::light::Light;

/// What the samples on the clipping plane show (thesis §3.2.2, eqs. 3.2.4–3.2.5).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Tagging {
    /// v₁ = c(s(x)): the plain transfer function.
    #[default]
    Off,
    /// v₂ of eq. 3.2.4: target green, risk structures magenta, over half the transfer function.
    Risk,
    /// v₃ = c_label(l(x)) of eq. 3.2.5: every label in its property-tree colour.
    Labels,
}

impl Tagging {
    pub const ALL: [Tagging; 3] = [Tagging::Off, Tagging::Risk, Tagging::Labels];

    pub fn as_str(self) -> &'static str {
        match self {
            Tagging::Off => "off",
            Tagging::Risk => "risk",
            Tagging::Labels => "labels",
        }
    }

    pub fn parse(s: &str) -> Option<Tagging> {
        Tagging::ALL.into_iter().find(|t| t.as_str() == s)
    }
}

/// A clipping plane (thesis §3.2.2): samples with (x − point)·normal < 0 are hidden.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClipPlane {
    pub point_mm: Vec3,
    /// Unit normal pointing into the half that stays visible.
    pub normal: Vec3,
}

impl ClipPlane {
    /// The plane through a tool at `position_mm` that contains the tool axis and faces the
    /// camera: it hides the half in front of the tool, so the cut shows the tool's path.
    /// normal = normalize(f − a(a·f)) with f the camera's forward direction and a the tool axis;
    /// when the axis points along the view, the plane is perpendicular to the view.
    pub fn through_tool(position_mm: Vec3, axis: Vec3, camera: &Camera) -> ClipPlane {
        let (_, _, forward) = camera.basis();
        let a = axis.normalize_or_zero();
        let n = forward - a * a.dot(forward);
        let normal = if n.length() < 1e-3 { forward } else { n.normalize() };
        ClipPlane {
            point_mm: position_mm,
            normal,
        }
    }
}

/// Speed switches. None of them may change the picture beyond the stated tolerance
/// (docs/rendering.md "Acceptance"); they exist to be measured (the thesis' Table 3.1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Quality {
    /// Distance between samples along a ray (mm).
    pub step_mm: f32,
    /// Start and end rays where they enter and leave the volume's box.
    pub ray_box: bool,
    /// Skip cells of the occupancy grid the transfer function makes transparent.
    pub leaping: bool,
    /// Cells per axis of the occupancy grid (16 … 128; 64 was the thesis' knee).
    pub occupancy_cells: u32,
    /// Stop a ray once its accumulated opacity reaches [`Quality::OPAQUE`].
    pub early_termination: bool,
    /// Offset each ray's samples by a per-pixel hash (no wood-grain banding).
    pub jitter: bool,
    /// Render at half the width and height and upscale (for interaction).
    pub half_resolution: bool,
}

impl Quality {
    /// Accumulated opacity at which early termination stops a ray.
    pub const OPAQUE: f32 = 0.99;

    /// Everything on: what the simulator uses.
    pub fn fast(step_mm: f32) -> Quality {
        Quality {
            step_mm,
            ray_box: true,
            leaping: true,
            occupancy_cells: 64,
            early_termination: true,
            jitter: true,
            half_resolution: false,
        }
    }

    /// Everything off: rays from the eye through the whole scene (the thesis' "unimproved").
    pub fn naive(step_mm: f32) -> Quality {
        Quality {
            ray_box: false,
            leaping: false,
            early_termination: false,
            ..Quality::fast(step_mm)
        }
    }
}

/// Hook of eq. 3.1.1: a deformed sub-image J on its own grid Ω_J, sampled instead of the CT
/// inside Ω_J. [`Scene::deformed`] is None when no tissue is deformed.
#[derive(Debug, Clone)]
pub struct DeformedRegion {
    pub volume: Arc<stylet_physics::Volume<f32>>,
}

/// Hook of eqs. 5.4.1–5.4.2: rays warped by the breathing motion u(X, t). [`Scene::motion`] is
/// None when the patient does not breathe.
#[derive(Clone)]
pub struct MotionHook {
    pub model: Arc<dyn MotionModel>,
    pub t_s: f64,
}

impl std::fmt::Debug for MotionHook {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MotionHook")
            .field("t_s", &self.t_s)
            .finish_non_exhaustive()
    }
}

/// Everything one 3D frame depends on besides the atlas volumes.
#[derive(Debug, Clone)]
pub struct Scene {
    pub camera: Camera,
    pub transfer: TransferFunction,
    pub light: Light,
    pub clip: Option<ClipPlane>,
    pub tagging: Tagging,
    pub quality: Quality,
    pub tools: ToolState,
    /// Background colour behind the volume (linear RGB 0 … 1).
    pub background: Vec3,
    pub deformed: Option<DeformedRegion>,
    pub motion: Option<MotionHook>,
}
