//! Per-sample colour: opacity correction for the step length, Phong shading from the gradient
//! (thesis eq. 3.2.3, two-sided) and the plane sample's tagging colours (eqs. 3.2.4–3.2.5).

use stylet_physics::glam::Vec3;

use crate::scene::{Light, Tagging};
use crate::volume::{LabelStyle, TagClass};

/// α = 1 − (1 − a)^Δ: opacity `a` per millimetre over a step of `step_mm`.
#[inline]
pub fn corrected_alpha(a: f32, step_mm: f32) -> f32 {
    1.0 - (1.0 - a).powf(step_mm)
}

/// Gradients shorter than this (HU/mm) give no normal: the sample is unshaded (f = 1).
pub const MIN_GRADIENT: f32 = 1e-3;

/// f of eq. 3.2.3: ambient + (diffuse·|N·L| + specular·|N·H|^shininess)·f_shadow with
/// N = −g/|g|, L toward the light, V = −r, H = normalize(L + V); 1 for a vanishing gradient.
#[inline]
pub fn phong(g: Vec3, ray_dir: Vec3, light: &Light, f_shadow: f32) -> f32 {
    let len = g.length();
    if len < MIN_GRADIENT {
        return 1.0;
    }
    phong_half(g, len, half_vector(ray_dir, light), light, f_shadow)
}

/// H = normalize(L + V) with V = −r: the same for every sample of a ray.
#[inline]
pub fn half_vector(ray_dir: Vec3, light: &Light) -> Vec3 {
    (light.toward_light - ray_dir).normalize()
}

/// [`phong`] with the ray's half vector `h` ([`half_vector`]) and |g| = `len` ≥ [`MIN_GRADIENT`]
/// already computed (the ray loop hoists them; same values).
#[inline]
pub fn phong_half(g: Vec3, len: f32, h: Vec3, light: &Light, f_shadow: f32) -> f32 {
    PhongTerms::new(light).shade(g, len, h, f_shadow)
}

/// The light's terms of eq. 3.2.3 prepared once per frame: the specular exponent is classified
/// here (whole numbers up to 256 are raised by squaring), not per sample.
#[derive(Debug, Clone, Copy)]
pub struct PhongTerms {
    pub(super) toward_light: Vec3,
    pub(super) ambient: f32,
    pub(super) diffuse: f32,
    pub(super) specular: f32,
    pub(super) exponent: Exponent,
}

#[derive(Debug, Clone, Copy)]
pub(super) enum Exponent {
    Whole(u32),
    Real(f32),
}

impl PhongTerms {
    pub fn new(light: &Light) -> PhongTerms {
        let e = light.shininess;
        PhongTerms {
            toward_light: light.toward_light,
            ambient: light.ambient,
            diffuse: light.diffuse,
            specular: light.specular,
            exponent: if (0.0..=256.0).contains(&e) && e == e.trunc() {
                Exponent::Whole(e as u32)
            } else {
                Exponent::Real(e)
            },
        }
    }

    /// f for a gradient `g` with |g| = `len` ≥ [`MIN_GRADIENT`] and half vector `h`.
    #[inline(always)]
    pub fn shade(&self, g: Vec3, len: f32, h: Vec3, f_shadow: f32) -> f32 {
        self.ambient + self.lit(g, len, h) * f_shadow
    }

    /// The part of f the shadow scales: diffuse·|N·L| + specular·|N·H|^shininess.
    #[inline(always)]
    pub fn lit(&self, g: Vec3, len: f32, h: Vec3) -> f32 {
        // N = −g/|g| as one reciprocal and three products (within an ulp of three quotients).
        let n = g * (-1.0 / len);
        let specular = if self.specular > 0.0 {
            let x = n.dot(h).abs();
            self.specular
                * match self.exponent {
                    Exponent::Whole(e) => power_whole(x, e),
                    Exponent::Real(e) => x.powf(e),
                }
        } else {
            0.0
        };
        self.diffuse * n.dot(self.toward_light).abs() + specular
    }
}

/// x^e by repeated squaring: a few multiplications instead of `powf`, equal to within rounding.
#[inline(always)]
pub(super) fn power_whole(x: f32, e: u32) -> f32 {
    let (mut base, mut n, mut r) = (x, e, 1.0f32);
    while n > 0 {
        if n & 1 == 1 {
            r *= base;
        }
        base *= base;
        n >>= 1;
    }
    r
}

/// Colour (straight RGBA) of the plane sample: v₁ = c(s) (off), v₂ of eq. 3.2.4 (risk), or
/// v₃ = c_label(l) of eq. 3.2.5 (labels).
#[inline]
pub fn plane_colour(tagging: Tagging, c: [f32; 4], style: LabelStyle) -> [f32; 4] {
    match tagging {
        Tagging::Off => c,
        Tagging::Risk => match style.class {
            TagClass::Target => [0.5 * c[0], 0.5 * c[1] + 0.5, 0.5 * c[2], 0.5 * c[3] + 0.5],
            TagClass::Risk => [0.5 * c[0] + 0.5, 0.5 * c[1], 0.5 * c[2] + 0.2, 0.5 * c[3] + 0.5],
            TagClass::Other => c,
        },
        Tagging::Labels => style.rgba,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn opacity_correction_is_exact_at_one_millimetre_and_compounds() {
        assert!((corrected_alpha(0.3, 1.0) - 0.3).abs() < 1e-6);
        let two = corrected_alpha(0.3, 2.0);
        assert!((two - (1.0 - 0.7 * 0.7)).abs() < 1e-6);
        assert_eq!(corrected_alpha(1.0, 0.5), 1.0);
        assert_eq!(corrected_alpha(0.0, 0.5), 0.0);
    }

    #[test]
    fn phong_is_two_sided_and_flat_without_a_gradient() {
        let light = Light {
            toward_light: Vec3::Z,
            ambient: 0.2,
            diffuse: 0.6,
            specular: 0.0,
            shininess: 8.0,
            shadow_in: 0.3,
        };
        let r = -Vec3::Z;
        assert_eq!(phong(Vec3::ZERO, r, &light, 1.0), 1.0);
        let up = phong(Vec3::Z * 100.0, r, &light, 1.0);
        let down = phong(-Vec3::Z * 100.0, r, &light, 1.0);
        assert!((up - 0.8).abs() < 1e-6 && (down - 0.8).abs() < 1e-6);
        assert!((phong(Vec3::Z, r, &light, 0.3) - (0.2 + 0.6 * 0.3)).abs() < 1e-6);
        assert!((phong(Vec3::X, r, &light, 1.0) - 0.2).abs() < 1e-6);
    }
}
