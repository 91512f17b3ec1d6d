//! The needle in the ultrasound image (docs/ultrasound.md "Needle"): steel reflects almost all
//! of the sound (Z ≈ 45 MRayl against 1.6 in tissue: amplitude 0.93) where a scan line meets
//! the shaft within the beam's thickness; the reflection is specular, so it fades as the needle
//! turns toward the beam; sound trapped in the lumen rings, and the ringing returns as a comet
//! tail of echoes one diameter apart below the shaft (reverberation); the tissue behind it lies
//! in the needle's acoustic shadow.
//!
//! The exchange's instruments echo the same way by their material: the guide wire is steel
//! (a solid core: no lumen to ring in), the dilator and catheter polymer, a weak reflector that
//! lets most of the sound through. Each scan line echoes at the first instrument it meets; what
//! lies behind it along the line is in its shadow.

use stylet_physics::glam::Vec3;

use crate::tools::{LineKind, Primitive};

/// Amplitude reflection of steel in tissue, (45 − 1.6)/(45 + 1.6).
pub const STEEL_REFLECTION: f32 = 0.93;
/// Half the beam's thickness across the image plane (mm): a shaft this far out of the plane
/// still echoes (a 3–5 MHz beam is 2–4 mm thick at its elevation focus).
pub const ELEVATION_HALF_MM: f32 = stylet_physics::probe_image::ELEVATION_HALF_MM as f32;
/// Share of the amplitude that passes the shaft (the rest is reflected or scattered).
pub const TRANSMISSION: f32 = 0.2;
/// Amplitude reflection of the dilator's and catheter's polymer in tissue: PTFE (Z ≈ 3.0 MRayl;
/// Selfridge, IEEE Trans. Sonics Ultrason. 1985) against 1.6, (3.0 − 1.6)/(3.0 + 1.6). Polyurethane
/// (≈ 1.9 MRayl) reflects less; PTFE-coated dilators and the catheter's radiopaque filler more.
pub const POLYMER_REFLECTION: f32 = 0.3;
/// Share of the amplitude that passes a polymer wall, 1 − r².
pub const POLYMER_TRANSMISSION: f32 = 0.91;
/// Each reverberation echo's amplitude relative to the one before, and how many are drawn.
pub const REVERB_DECAY: f32 = 0.55;
pub const REVERB_ECHOES: u32 = 6;

/// Where a scan line first meets the shaft.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NeedleHit {
    /// Distance along the line from its start (mm).
    pub depth_mm: f32,
    /// Specular strength: the sine of the angle between the beam and the shaft (1 across the
    /// beam, 0 along it).
    pub specular: f32,
}

/// How an instrument's material echoes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Echogenicity {
    /// Amplitude reflected back along a line across the shaft.
    pub reflection: f32,
    /// Share of the amplitude that goes on past it.
    pub transmission: f32,
    /// Spacing of the comet tail's echoes (mm; the lumen's ringing), 0 for none.
    pub ring_mm: f32,
}

impl Echogenicity {
    /// The needle: hollow steel that rings in its lumen, one diameter per echo.
    pub fn needle(diameter_mm: f32) -> Echogenicity {
        Echogenicity {
            reflection: STEEL_REFLECTION,
            transmission: TRANSMISSION,
            ring_mm: diameter_mm,
        }
    }

    /// An instrument of the exchange by its kind.
    pub fn of_line(kind: LineKind) -> Echogenicity {
        match kind {
            LineKind::GuideWire => Echogenicity {
                reflection: STEEL_REFLECTION,
                transmission: TRANSMISSION,
                ring_mm: 0.0,
            },
            LineKind::Dilator | LineKind::Catheter => Echogenicity {
                reflection: POLYMER_REFLECTION,
                transmission: POLYMER_TRANSMISSION,
                ring_mm: 0.0,
            },
        }
    }
}

/// A scan line's first meeting with an instrument, and how that instrument echoes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InstrumentHit {
    pub hit: NeedleHit,
    pub echo: Echogenicity,
}

/// The first meeting of the line (origin, unit dir, length) with the needle's shaft (nodes from
/// hub to tip, outer radius), widened by the beam's half thickness.
pub fn first_hit(origin: Vec3, dir: Vec3, length_mm: f32, nodes: &[Vec3], radius_mm: f32) -> Option<NeedleHit> {
    let mut best: Option<NeedleHit> = None;
    for w in nodes.windows(2) {
        let capsule = Primitive::Capsule {
            a: w[0],
            b: w[1],
            radius: radius_mm + ELEVATION_HALF_MM,
            rgb: Vec3::ZERO,
        };
        let t_max = best.map_or(length_mm, |b| b.depth_mm);
        if let Some((t, _)) = capsule.hit(origin, dir, t_max) {
            let axis = (w[1] - w[0]).normalize_or_zero();
            let c = axis.dot(dir);
            best = Some(NeedleHit {
                depth_mm: t,
                specular: (1.0 - c * c).max(0.0).sqrt(),
            });
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_shaft_across_the_beam_is_met_at_its_near_wall_and_fully_specular() {
        let nodes = [Vec3::new(-30.0, 0.0, 40.0), Vec3::new(30.0, 0.0, 40.0)];
        let hit = first_hit(Vec3::ZERO, Vec3::Z, 100.0, &nodes, 0.6).expect("hit");
        assert!((hit.depth_mm - (40.0 - 1.6)).abs() < 1e-3, "{hit:?}");
        assert!((hit.specular - 1.0).abs() < 1e-6);
        // Out of the beam's thickness: no echo.
        let off = [Vec3::new(-30.0, 2.0, 40.0), Vec3::new(30.0, 2.0, 40.0)];
        assert!(first_hit(Vec3::ZERO, Vec3::Z, 100.0, &off, 0.6).is_none());
        // Beyond the imaged depth: no echo.
        assert!(first_hit(Vec3::ZERO, Vec3::Z, 30.0, &nodes, 0.6).is_none());
    }

    #[test]
    fn a_steep_shaft_reflects_less() {
        let nodes = [Vec3::new(-10.0, 0.0, 30.0), Vec3::new(10.0, 0.0, 50.0)];
        let hit = first_hit(Vec3::ZERO, Vec3::Z, 100.0, &nodes, 0.6).expect("hit");
        assert!((hit.specular - std::f32::consts::FRAC_1_SQRT_2).abs() < 1e-5, "{hit:?}");
    }
}
