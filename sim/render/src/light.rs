//! The directional light of the 3D view and its Phong coefficients (thesis eq. 3.2.3), which the
//! volume and the tools are shaded with.

use stylet_physics::glam::Vec3;

use crate::camera::Camera;

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
