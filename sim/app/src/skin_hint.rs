//! The tool and the skin, in words for the status bar: before entry how far the tool's tip is
//! from the skin along its axis (and so how many wheel notches), on the skin how deep it presses,
//! after entry how deep the needle's tip is. Read from the tick's output and the atlas' skin
//! distance (D_skin); a hint to the trainee that changes nothing in the physics or the score.

use stylet_physics::{PunctureAtlas, TickOutput};

use crate::controls::WHEEL_MM_PER_NOTCH;

/// How far along the tool the skin is looked for (mm).
pub const REACH_MM: f64 = 400.0;

/// The hint for `tool` ("needle", "probe", "finger") at the tick `o`.
pub fn skin_hint(tool: &str, o: &TickOutput, atlas: &PunctureAtlas) -> String {
    if tool == "needle" && o.inserted_mm > 0.0 {
        return format!(
            "needle tip {:.1} mm under the skin, {:.1} mm inserted",
            o.tip_depth_mm.max(0.0),
            o.inserted_mm
        );
    }
    if tool != "needle" && o.contacts > 0 {
        return format!("{tool} on the skin, pressing {:.1} mm", o.indentation_mm);
    }
    match atlas.skin_distance_along(o.tip_mm, o.insertion_dir, REACH_MM) {
        Some(mm) => {
            let notches = (mm / WHEEL_MM_PER_NOTCH).round();
            let plural = if notches == 1.0 { "" } else { "es" };
            format!("{tool} tip {mm:.0} mm from the skin ({notches:.0} wheel notch{plural})")
        }
        None => format!("the {tool} does not point at the patient"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use stylet_physics::glam::DVec3;

    fn phantom() -> PunctureAtlas {
        let p = stylet_atlas::phantom::generate(&stylet_atlas::phantom::PhantomConfig {
            dims: [64, 64, 50],
            spacing_mm: [6.0; 3],
            ..Default::default()
        })
        .unwrap();
        let dir = tempfile::tempdir().unwrap();
        stylet_atlas::write(dir.path(), &p.manifest, &p.ct, &p.partial).unwrap();
        let atlas = stylet_atlas::load(dir.path()).unwrap();
        std::sync::Arc::try_unwrap(atlas.model).unwrap_or_else(|m| (*m).clone())
    }

    #[test]
    fn the_hint_gives_the_distance_before_entry_and_the_depth_after() {
        let atlas = phantom();
        let (lo, hi) = atlas.ct().grid().world_bounds();
        let top = (lo + hi) * 0.5 + DVec3::new(0.0, 0.0, (hi.z - lo.z) * 0.5);
        let to_skin = atlas.skin_distance_along(top, DVec3::NEG_Z, REACH_MM).unwrap();
        let start = top + DVec3::NEG_Z * (to_skin - 30.0);
        let out = |tip_mm: DVec3, dir: DVec3| TickOutput {
            tip_mm,
            insertion_dir: dir,
            ..TickOutput::default()
        };
        let hint = skin_hint("needle", &out(start, DVec3::NEG_Z), &atlas);
        let mm: f64 = hint
            .strip_prefix("needle tip ")
            .and_then(|r| r.split(' ').next())
            .and_then(|n| n.parse().ok())
            .unwrap_or_else(|| panic!("{hint}"));
        assert!((mm - 30.0).abs() <= 6.0, "{hint}");
        assert!(hint.ends_with("wheel notches)"), "{hint}");
        assert_eq!(
            skin_hint("needle", &out(start, DVec3::Z), &atlas),
            "the needle does not point at the patient"
        );
        let inside = TickOutput {
            inserted_mm: 41.0,
            tip_depth_mm: 23.44,
            ..out(start, DVec3::NEG_Z)
        };
        assert_eq!(
            skin_hint("needle", &inside, &atlas),
            "needle tip 23.4 mm under the skin, 41.0 mm inserted"
        );
        let pressing = TickOutput {
            contacts: 12,
            indentation_mm: 2.06,
            ..out(start, DVec3::NEG_Z)
        };
        assert_eq!(
            skin_hint("probe", &pressing, &atlas),
            "probe on the skin, pressing 2.1 mm"
        );
    }
}
