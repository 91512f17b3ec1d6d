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

/// A pinhole camera. Rays start at `eye_mm` (see [`Camera::ray`] for the exact pixel mapping).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    pub eye_mm: Vec3,
    pub target_mm: Vec3,
    /// Approximate up direction (re-orthogonalised against the view direction).
    pub up: Vec3,
    /// Vertical field of view in degrees.
    pub fov_y_deg: f32,
}

impl Camera {
    /// Right-handed orthonormal basis (right, up, forward) of the view.
    pub fn basis(&self) -> (Vec3, Vec3, Vec3) {
        let forward = (self.target_mm - self.eye_mm).normalize();
        let right = forward.cross(self.up).normalize();
        let up = right.cross(forward);
        (right, up, forward)
    }

    /// The ray through the centre of pixel (`col`, `row`) of a `width` × `height` image: origin
    /// and unit direction. Row 0 is the top of the image.
    ///
    /// x_ndc = (2(col + ½)/w − 1)·tan(fov/2)·w/h, y_ndc = (1 − 2(row + ½)/h)·tan(fov/2),
    /// d = normalize(forward + x_ndc·right + y_ndc·up).
    pub fn ray(&self, col: u32, row: u32, width: u32, height: u32) -> (Vec3, Vec3) {
        self.rays(width, height).ray(col, row)
    }

    /// What [`Camera::ray`] works out that is the same for every pixel of a `width` × `height`
    /// image (the basis, tan(fov/2), the aspect), prepared once for a frame's rays.
    pub fn rays(&self, width: u32, height: u32) -> ImageRays {
        let (right, up, forward) = self.basis();
        ImageRays {
            eye_mm: self.eye_mm,
            right,
            up,
            forward,
            tan_half: (self.fov_y_deg.to_radians() * 0.5).tan(),
            aspect: width as f32 / height as f32,
            width: width as f32,
            height: height as f32,
        }
    }

    /// Where a world point lands in a `width` × `height` image: (column, row) in pixels (the
    /// inverse of [`Camera::ray`]: pixel centres at +½) and its depth along the view direction
    /// (mm); `None` behind the eye.
    pub fn project(&self, world_mm: Vec3, width: u32, height: u32) -> Option<(f32, f32, f32)> {
        let (right, up, forward) = self.basis();
        let v = world_mm - self.eye_mm;
        let depth = v.dot(forward);
        if !(depth > 1e-3) {
            return None;
        }
        let tan_half = (self.fov_y_deg.to_radians() * 0.5).tan();
        let aspect = width as f32 / height as f32;
        let x = v.dot(right) / depth / (tan_half * aspect);
        let y = v.dot(up) / depth / tan_half;
        let col = (x + 1.0) * 0.5 * width as f32 - 0.5;
        let row = (1.0 - y) * 0.5 * height as f32 - 0.5;
        Some((col, row, depth))
    }

    /// Pixels per millimetre at `depth_mm` in front of the eye, in an image `height` pixels high.
    pub fn pixels_per_mm(&self, depth_mm: f32, height: u32) -> f32 {
        let tan_half = (self.fov_y_deg.to_radians() * 0.5).tan();
        0.5 * height as f32 / (tan_half * depth_mm.max(1e-3))
    }

    /// A camera on a sphere around `center_mm`, looking at it. Azimuth 0° looks from anterior
    /// (+y in RAS) with the patient's right on the image's left (radiological convention);
    /// azimuth 90° looks from the patient's left (−x; RAS+, x to the patient's right); elevation lifts the eye toward superior.
    pub fn orbit(center_mm: Vec3, distance_mm: f32, azimuth_deg: f32, elevation_deg: f32, fov_y_deg: f32) -> Camera {
        let (az, el) = (azimuth_deg.to_radians(), elevation_deg.to_radians());
        let dir = Vec3::new(-az.sin() * el.cos(), az.cos() * el.cos(), el.sin());
        Camera {
            eye_mm: center_mm + dir * distance_mm,
            target_mm: center_mm,
            up: Vec3::Z,
            fov_y_deg,
        }
    }

    /// A camera that frames a box (world bounds, mm) from `azimuth_deg`/`elevation_deg` with a
    /// 30° field of view: the bounding sphere fits the shorter image side.
    pub fn framing(lo_mm: Vec3, hi_mm: Vec3, azimuth_deg: f32, elevation_deg: f32) -> Camera {
        let fov_y_deg = 30.0f32;
        let center = (lo_mm + hi_mm) * 0.5;
        let radius = (hi_mm - lo_mm).length() * 0.5;
        let distance = radius / (fov_y_deg.to_radians() * 0.5).sin();
        Camera::orbit(center, distance, azimuth_deg, elevation_deg, fov_y_deg)
    }
}

/// A directional light and the Phong coefficients of eq. 3.2.3.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Light {
    /// Unit vector from the scene toward the light (the light is infinitely far away).
    pub toward_light: Vec3,
    pub ambient: f32,
    pub diffuse: f32,
    pub specular: f32,
    pub shininess: f32,
    /// f_in of Alg. 3.1/3.2: the factor on diffuse + specular inside a tool's shadow.
    pub shadow_in: f32,
}

impl Light {
    /// A light above the viewer's right shoulder: toward the light = normalize(−forward + ½·up + ¼·right).
    pub fn over_shoulder(camera: &Camera) -> Light {
        let (right, up, forward) = camera.basis();
        Light {
            toward_light: (-forward + up * 0.5 + right * 0.25).normalize(),
            ambient: 0.35,
            diffuse: 0.6,
            specular: 0.25,
            shininess: 24.0,
            shadow_in: 0.35,
        }
    }
}

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

/// The rays of one image ([`Camera::rays`]): [`Camera::ray`]'s formulas with the per-frame
/// parts prepared, the same numbers bit for bit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImageRays {
    eye_mm: Vec3,
    right: Vec3,
    up: Vec3,
    forward: Vec3,
    tan_half: f32,
    aspect: f32,
    width: f32,
    height: f32,
}

impl ImageRays {
    /// The ray through the centre of pixel (`col`, `row`): origin and unit direction.
    #[inline(always)]
    pub fn ray(&self, col: u32, row: u32) -> (Vec3, Vec3) {
        let x = (2.0 * (col as f32 + 0.5) / self.width - 1.0) * self.tan_half * self.aspect;
        let y = (1.0 - 2.0 * (row as f32 + 0.5) / self.height) * self.tan_half;
        (self.eye_mm, (self.forward + self.right * x + self.up * y).normalize())
    }
}
