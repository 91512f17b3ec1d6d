//! Tool shadows for a directional light (thesis §3.2.3, Alg. 3.1 and 3.2): closed-form tests
//! instead of a shadow map, evaluated per sample by both renderers (docs/rendering.md "One ray",
//! step 6).
//!
//! The needle's shadow uses a straight approximation from the tip back along the tip tangent: a
//! shaft of length l̄ and diameter ⌀l, then the hub of length b̄ and diameter ⌀b. Spheres (the
//! fingertip, a probe head's bounding sphere) cast round shadows.
//!
//! Direction convention (the thesis leaves it implicit): `toward_light` points from the scene to
//! the light, and the needle runs from the tip *backwards* toward the hub. A point is shadowed
//! when the ray from it toward the light passes through the tool, so the shadow is cast away
//! from the light.

use stylet_physics::glam::Vec3;

use crate::tools::ToolState;

/// The straight needle of Alg. 3.1.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NeedleShadow {
    /// x: the needle tip.
    pub tip_mm: Vec3,
    /// Unit direction from the tip toward the hub (minus the tip tangent).
    pub back: Vec3,
    /// l̄ and ⌀l.
    pub length_mm: f32,
    pub diameter_mm: f32,
    /// b̄ and ⌀b.
    pub hub_length_mm: f32,
    pub hub_diameter_mm: f32,
}

/// A sphere of Alg. 3.2.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ShadowSphere {
    pub center_mm: Vec3,
    pub radius_mm: f32,
}

/// Everything that casts a shadow in one frame (at most one needle and two spheres).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Shadows {
    pub needle: Option<NeedleShadow>,
    pub spheres: Vec<ShadowSphere>,
}

impl NeedleShadow {
    /// Alg. 3.1 with `l` = unit toward the light, n = `back`, d = x_i − x:
    /// p = (l × n)/|l × n|, j = p × l, q = (l − n(n·l))/|l − n(n·l)|,
    /// d₁ = d·p (distance across the shadow), d₂ = q·d, d₃ = (j·d)/(j·n) (position along the
    /// needle of the point's light ray). In shadow when d₂ < 0 (the needle lies toward the light:
    /// the thesis' d₂ > 0 with l pointing from the light) and |d₁| < ⌀l/2, 0 < d₃ < l̄, or
    /// |d₁| < ⌀b/2, l̄ < d₃ < l̄ + b̄. When the light runs along the needle (|l × n| < 10⁻⁶) the
    /// shadow is the disc of the wider part behind the tip.
    pub fn contains(&self, x: Vec3, l: Vec3) -> bool {
        let n = self.back;
        let d = x - self.tip_mm;
        let p = l.cross(n);
        let pl = p.length();
        if pl < 1e-6 {
            let along = d.dot(l);
            let perp = (d - l * along).length();
            let (r_shaft, r_hub) = (0.5 * self.diameter_mm, 0.5 * self.hub_diameter_mm);
            return if n.dot(l) > 0.0 {
                // Hub toward the light: the wider of shaft and hub shades everything behind the tip.
                perp < r_shaft.max(r_hub) && along < 0.0
            } else {
                // Tip toward the light: the shaft behind the tip, the hub from l̄ on.
                (perp < r_shaft && along < 0.0) || (perp < r_hub && along < -self.length_mm)
            };
        }
        let p = p / pl;
        let j = p.cross(l);
        let q = (l - n * n.dot(l)).normalize();
        let d1 = d.dot(p);
        let d2 = q.dot(d);
        let d3 = j.dot(d) / j.dot(n);
        if d2 >= 0.0 {
            return false;
        }
        (d1.abs() < 0.5 * self.diameter_mm && d3 > 0.0 && d3 < self.length_mm)
            || (d1.abs() < 0.5 * self.hub_diameter_mm
                && d3 > self.length_mm
                && d3 < self.length_mm + self.hub_length_mm)
    }
}

impl ShadowSphere {
    /// Alg. 3.2 with `l` = unit toward the light: k = l·(x_i − c), d = |x_i − c − k·l|; in shadow
    /// when d < r and k < r (the thesis' k > −r with l pointing from the light).
    pub fn contains(&self, x: Vec3, l: Vec3) -> bool {
        let rel = x - self.center_mm;
        let k = l.dot(rel);
        let d = (rel - l * k).length();
        k < self.radius_mm && d < self.radius_mm
    }
}

impl Shadows {
    /// The shadow casters of a tool state: the needle (straight from its tip along the tip
    /// tangent, length = its length along the nodes), the fingertip sphere, the probe head's
    /// bounding sphere.
    pub fn from_tools(tools: &ToolState) -> Shadows {
        let needle = tools
            .needle
            .as_ref()
            .filter(|n| n.nodes_mm.len() >= 2)
            .map(|n| NeedleShadow {
                tip_mm: n.tip_mm(),
                back: -n.tip_tangent(),
                length_mm: n.length_mm(),
                diameter_mm: n.diameter_mm,
                hub_length_mm: n.hub_length_mm,
                hub_diameter_mm: n.hub_diameter_mm,
            });
        let mut spheres = Vec::new();
        if let Some(f) = &tools.finger {
            spheres.push(ShadowSphere {
                center_mm: f.center_mm,
                radius_mm: f.radius_mm,
            });
        }
        if let Some(p) = &tools.probe {
            let (center_mm, radius_mm) = p.head_sphere();
            spheres.push(ShadowSphere { center_mm, radius_mm });
        }
        Shadows { needle, spheres }
    }

    /// f_shadow at `x`: `shadow_in` inside any tool's shadow, else 1.
    pub fn factor(&self, x: Vec3, toward_light: Vec3, shadow_in: f32) -> f32 {
        let inside = self.needle.is_some_and(|n| n.contains(x, toward_light))
            || self.spheres.iter().any(|s| s.contains(x, toward_light));
        if inside { shadow_in } else { 1.0 }
    }
}
