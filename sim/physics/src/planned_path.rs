//! A planned insertion path of an atlas (thesis §6.2.2: "puncture along predefined insertion paths"): where the needle should
//! enter the skin and the target it should reach in a straight line. Scripts pose the needle
//! along it, scoring measures how far a trainee's needle stayed from it, and the review draws it.

use glam::DVec3;

/// One named planned path, in patient millimetres.
#[derive(Debug, Clone, PartialEq)]
pub struct PlannedPath {
    pub name: String,
    pub entry_mm: DVec3,
    pub target_mm: DVec3,
}

impl PlannedPath {
    /// The unit direction from entry to target (`None` when the two points coincide).
    pub fn direction(&self) -> Option<DVec3> {
        (self.target_mm - self.entry_mm).try_normalize()
    }

    /// Length from entry to target (mm).
    pub fn length_mm(&self) -> f64 {
        self.entry_mm.distance(self.target_mm)
    }
}
