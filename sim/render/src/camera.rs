//! The pinhole camera both renderers look through (docs/rendering.md): its basis, the ray through
//! each pixel and the inverse projection, and cameras that orbit or frame a region. `f32`, like
//! the rest of the scene, so the CPU and the GPU follow the same rays.

use stylet_physics::glam::Vec3;

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
