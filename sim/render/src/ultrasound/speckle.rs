//! Speckle attached to the tissue (docs/ultrasound.md "Speckle"): the diffuse backscatter of
//! unresolved scatterers, modelled as a random amplitude on a fixed lattice in *reference*
//! space (the patient, not the probe), seeded from the session seed, and read with trilinear
//! interpolation. The same tissue point always returns the same value, so a moved probe shows
//! the same speckle shifted, not new noise; a session replayed shows the same speckle. Lattice
//! amplitudes follow a Rayleigh distribution (the envelope of many random phasors), normalised
//! to a mean of 1.

use stylet_physics::glam::Vec3;

/// Lattice spacing (mm): about the axial resolution of a 3–7 MHz probe.
pub const LATTICE_MM: f32 = 0.5;

/// A 32-bit integer hash (Wellons' "lowbias32"): good avalanche, and exactly the same in WGSL,
/// which has no 64-bit integers, so the GPU draws the same speckle.
#[inline(always)]
pub fn hash32(mut x: u32) -> u32 {
    x ^= x >> 16;
    x = x.wrapping_mul(0x7feb_352d);
    x ^= x >> 15;
    x = x.wrapping_mul(0x846c_a68b);
    x ^ (x >> 16)
}

/// Rayleigh amplitude (mean 1) of lattice node (i, j, k) under a mixed seed.
#[inline(always)]
fn node(i: i32, j: i32, k: i32, seed: u32) -> f32 {
    let h = hash32(i as u32 ^ hash32(j as u32 ^ hash32(k as u32 ^ seed)));
    // u in (0, 1]: 24 random bits.
    let u = ((h >> 8) as f32 + 1.0) * (1.0 / 16_777_216.0);
    // Rayleigh with σ² = 1/2 has mean √π/2; scaled to mean 1.
    (-u.ln()).sqrt() * (2.0 / std::f32::consts::PI.sqrt())
}

/// The session seed as the lattice uses it (mixed once per frame).
pub fn lattice_seed(session_seed: u64) -> u32 {
    hash32(session_seed as u32 ^ hash32((session_seed >> 32) as u32 ^ 0x9e37_79b9))
}

/// The speckle amplitude at reference-space point `x_mm` (trilinear between lattice nodes);
/// `seed` from [`lattice_seed`].
#[inline]
pub fn amplitude(x_mm: Vec3, seed: u32) -> f32 {
    let g = x_mm * (1.0 / LATTICE_MM);
    let b = g.floor();
    let f = g - b;
    let (i, j, k) = (b.x as i32, b.y as i32, b.z as i32);
    let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
    let row = |j: i32, k: i32| lerp(node(i, j, k, seed), node(i + 1, j, k, seed), f.x);
    let plane = |k: i32| lerp(row(j, k), row(j + 1, k), f.y);
    lerp(plane(k), plane(k + 1), f.z)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn speckle_is_a_function_of_the_point_and_the_seed() {
        let x = Vec3::new(12.3, -45.6, 78.9);
        assert_eq!(
            amplitude(x, lattice_seed(7)).to_bits(),
            amplitude(x, lattice_seed(7)).to_bits()
        );
        assert_ne!(amplitude(x, lattice_seed(7)), amplitude(x, lattice_seed(8)));
        // Mean about 1, and spread like speckle (not a constant).
        let n = 20_000;
        let v: Vec<f32> = (0..n)
            .map(|i| amplitude(Vec3::new(i as f32 * 0.37, 1.0, 2.0), lattice_seed(3)))
            .collect();
        let mean = v.iter().sum::<f32>() / n as f32;
        let sd = (v.iter().map(|a| (a - mean).powi(2)).sum::<f32>() / n as f32).sqrt();
        assert!((mean - 1.0).abs() < 0.05, "{mean}");
        assert!(sd > 0.15, "{sd}");
    }
}
