//! Difficulty presets of one patient (docs/atlas.md "New patients"). The scenario's presets (thesis
//! §6.3: the level changes the visual aids) are the starting point; the patient's ranked
//! intercostal windows adapt them:
//!
//! - **beginner**: guided along the chosen window (the space asked for, else the best ranked:
//!   [`WindowReport::found`]) when it leaves at least [`BEGINNER_CLEARANCE_MM`] to bone and risk
//!   structures, else along the widest window;
//! - **advanced**: unguided; when even the widest window leaves less than
//!   [`BEGINNER_CLEARANCE_MM`] (tight anatomy), the risk structures stay highlighted;
//! - **expert**: unguided, the scenario's aids (none in PTCD).
//!
//! Each level gets a sentence for the report and the import notes.

use super::classes::ClassTable;
use super::window::{Choice, WindowFound, WindowReport, space_name, window_path};
use crate::manifest::{DifficultyPreset, DifficultyPresets};

/// Clearance (mm, the nearer of bone and risk structures) a beginner's guided window must leave;
/// tighter windows are for trainees who choose their own.
pub const BEGINNER_CLEARANCE_MM: f64 = 5.0;

/// What the presets were set to, level by level, in words.
#[derive(Debug, Clone, PartialEq)]
pub struct PresetNotes {
    pub beginner: String,
    pub advanced: String,
    pub expert: String,
}

impl PresetNotes {
    pub fn lines(&self) -> [(&'static str, &str); 3] {
        [
            ("beginner", &self.beginner),
            ("advanced", &self.advanced),
            ("expert", &self.expert),
        ]
    }
}

fn aids(p: &DifficultyPreset) -> String {
    let mut shown = Vec::new();
    if p.target_overlay {
        shown.push("the target");
    }
    if p.risk_overlay {
        shown.push("the risk structures");
    }
    if p.needle_guide {
        shown.push("the needle guide");
    }
    if shown.is_empty() {
        "no visual aids".into()
    } else {
        format!("shows {}", shown.join(", "))
    }
}

/// Adapts `presets` to the windows of `report` (their planned paths named as
/// [`WindowReport::paths`] names them, by `classes`). Without a window the presets are left as
/// they are.
pub fn adapt(presets: &mut DifficultyPresets, report: &WindowReport, classes: &ClassTable) -> Option<PresetNotes> {
    let chosen = report.found.as_ref()?;
    let widest = report
        .ranked
        .iter()
        .max_by(|a, b| a.clearance_mm().total_cmp(&b.clearance_mm()))
        .unwrap_or(chosen);
    let describe = |w: &WindowFound| {
        format!(
            "{} ({:.1} mm clear)",
            space_name(classes, w.upper, w.lower),
            w.clearance_mm()
        )
    };
    let (guide, why) = if chosen.clearance_mm() >= BEGINNER_CLEARANCE_MM {
        let why = match report.choice() {
            Choice::Requested => "the standard space leaves enough room",
            Choice::RequestedTranspleural => {
                "the space asked for passes through the pleural recess, so the best-ranked window"
            }
            Choice::RequestedMissing | Choice::None => "the space asked for has no window, so the best-ranked one",
        };
        (chosen, why.to_string())
    } else {
        (
            widest,
            format!(
                "the {} leaves only {:.1} mm, less than {BEGINNER_CLEARANCE_MM} mm, so the widest window",
                if report.choice() == Choice::Requested {
                    "space asked for"
                } else {
                    "best-ranked window"
                },
                chosen.clearance_mm()
            ),
        )
    };
    presets.beginner.guided_path = Some(window_path(classes, guide, None).name);
    let tight = widest.clearance_mm() < BEGINNER_CLEARANCE_MM;
    if tight {
        presets.advanced.risk_overlay = true;
    }
    presets.advanced.guided_path = None;
    presets.expert.guided_path = None;
    Some(PresetNotes {
        beginner: format!(
            "guided along the {} — {why}; {}",
            describe(guide),
            aids(&presets.beginner)
        ),
        advanced: format!(
            "chooses the window{}; {}",
            if tight {
                format!(
                    " (tight anatomy: the widest window leaves {:.1} mm, so the risk structures stay shown)",
                    widest.clearance_mm()
                )
            } else {
                String::new()
            },
            aids(&presets.advanced)
        ),
        expert: format!("chooses the window; {}", aids(&presets.expert)),
    })
}

#[cfg(test)]
mod tests {
    use stylet_physics::glam::DVec3;

    use super::*;

    fn window(upper: u16, clearance_mm: f64, x: f64) -> WindowFound {
        WindowFound {
            upper,
            lower: upper + 1,
            upper_distance_mm: 5.0,
            lower_distance_mm: 5.0,
            wall_mm: DVec3::new(x - 20.0, 0.0, 0.0),
            entry_mm: DVec3::new(x, 0.0, 0.0),
            target_mm: DVec3::ZERO,
            length_mm: x,
            bone_clearance_mm: clearance_mm,
            vessel_clearance_mm: 20.0,
            lung_clearance_mm: 50.0,
            tilt_deg: 0.0,
            lateral_deg: Some(0.0),
        }
    }

    fn ribs() -> ClassTable {
        ClassTable::totalsegmentator()
    }

    fn presets() -> DifficultyPresets {
        let p = |t, r, g| DifficultyPreset {
            target_overlay: t,
            risk_overlay: r,
            needle_guide: g,
            guided_path: None,
        };
        DifficultyPresets {
            beginner: p(true, true, true),
            advanced: p(true, false, true),
            expert: p(false, false, false),
        }
    }

    #[test]
    fn beginners_follow_the_standard_space_when_it_leaves_room_else_the_widest() {
        let (std_ok, wide) = (window(113, 6.7, 100.0), window(110, 9.9, 90.0));
        let report = |chosen: &WindowFound| WindowReport {
            requested: (113, 114),
            found: Some(chosen.clone()),
            requested_found: true,
            ranked: vec![wide.clone(), chosen.clone()],
        };
        let mut p = presets();
        let notes = adapt(&mut p, &report(&std_ok), &ribs()).unwrap();
        assert_eq!(p.beginner.guided_path.as_deref(), Some("intercostal-right-10-11"));
        assert!(!p.advanced.risk_overlay, "roomy anatomy keeps the scenario's aids");
        assert!(
            notes
                .beginner
                .starts_with("guided along the right 10th–11th intercostal space (6.7 mm clear)"),
            "{}",
            notes.beginner
        );

        let tight_std = window(113, 3.2, 100.0);
        let mut p = presets();
        let notes = adapt(&mut p, &report(&tight_std), &ribs()).unwrap();
        assert_eq!(p.beginner.guided_path.as_deref(), Some("intercostal-right-7-8"));
        assert!(notes.beginner.contains("leaves only 3.2 mm"), "{}", notes.beginner);
        assert!(!p.advanced.risk_overlay, "the widest window leaves room");

        // No window in the space asked for: the widest one, said so.
        let mut missing = report(&wide);
        missing.requested_found = false;
        let mut p = presets();
        let notes = adapt(&mut p, &missing, &ribs()).unwrap();
        assert_eq!(p.beginner.guided_path.as_deref(), Some("intercostal-right-7-8"));
        assert!(
            notes.beginner.contains("the space asked for has no window"),
            "{}",
            notes.beginner
        );
    }

    #[test]
    fn tight_anatomy_keeps_the_risk_structures_shown_to_advanced_trainees() {
        let only = window(113, 3.0, 100.0);
        let report = WindowReport {
            requested: (113, 114),
            found: Some(only.clone()),
            requested_found: true,
            ranked: vec![only.clone()],
        };
        let mut p = presets();
        let notes = adapt(&mut p, &report, &ribs()).unwrap();
        assert_eq!(p.beginner.guided_path.as_deref(), Some("intercostal-right-10-11"));
        assert!(p.advanced.risk_overlay);
        assert!(notes.advanced.contains("tight anatomy"), "{}", notes.advanced);
        assert_eq!(notes.expert, "chooses the window; no visual aids");
    }
}
