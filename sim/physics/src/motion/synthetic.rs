//! A synthetic breathing motion for atlases without a 4D CT (docs/breathing.md "Synthetic
//! motion"): the displacement a₁(X) at end-inspiration, relative to the CT (taken as the
//! end-expiration reference), built from the atlas' own maps, and driven by the breathing signal
//! through the surrogate model (eq. 5.3.6 with a₂ = a₃ = 0).
//!
//!   a₁(X) = A · w(z) · m(X) · (0, r_ap, −1)
//!
//! - A: the cranio-caudal amplitude of the liver (default 12 mm; Eccles et al. 2011 measured a
//!   mean of 11.7 mm, 4.8–23.3 mm, in 60 patients); r_ap: the anterior share (0.3).
//!   Inspiration moves the liver caudally (−z, RAS) and anteriorly (+y).
//! - w(z): the diaphragm as a piston. 1 from the liver's dome down to 150 mm below it, then
//!   falling linearly to 0.4 at 300 mm below (the lower abdomen moves less); above the dome the
//!   lungs follow, falling linearly to 0 at 150 mm above it (the apex hardly moves).
//! - m(X) ∈ [0, 1]: what may move. 0 in the body wall (less than `wall_mm` under the skin), in
//!   bone and within `bone_margin_mm` of it, and outside the body; 1 deeper inside, reached over
//!   a ramp of [`RAMP_MM`]. Bone is the atlas' bone map (CT above the bone threshold) outside
//!   the segmented soft structures: a contrast-filled vessel is as dense as bone but moves with
//!   its organ, and an organ's voxel next to a rib moves fully. The step from the wall and the
//!   ribs to the cavity is the sliding interface: liver and lung slide along the inside of the
//!   ribs while the ribs stay.

use std::sync::Arc;

use glam::DVec3;

use super::field::SpatialField;
use crate::PunctureAtlas;
use crate::labels::Role;

/// Width of the transition from still to moving tissue (mm).
pub const RAMP_MM: f64 = 4.0;
/// Above the liver's dome, the motion falls to 0 over this height (mm).
pub const LUNG_FALL_MM: f64 = 150.0;
/// Below the dome, full motion over this height, then a fall to [`PELVIS_WEIGHT`] over as much again.
pub const ABDOMEN_FULL_MM: f64 = 150.0;
pub const PELVIS_WEIGHT: f64 = 0.4;

/// The synthetic motion's parameters (part of the world model in the session header).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SyntheticMotion {
    /// Cranio-caudal displacement of the liver at an average end-inspiration (mm).
    pub amplitude_mm: f64,
    /// Anterior displacement as a share of the cranio-caudal one.
    pub anterior_ratio: f64,
    /// Depth under the skin that stays still: the body wall (mm).
    pub wall_mm: f64,
    /// Tissue this close to bone stays with it (mm).
    pub bone_margin_mm: f64,
}

impl Default for SyntheticMotion {
    fn default() -> Self {
        SyntheticMotion {
            amplitude_mm: 12.0,
            anterior_ratio: 0.3,
            wall_mm: 12.0,
            bone_margin_mm: 3.0,
        }
    }
}

impl SyntheticMotion {
    /// The documented ranges (docs/breathing.md).
    pub fn validate(&self) -> Result<(), String> {
        let check = |what: &str, v: f64, lo: f64, hi: f64| {
            if v.is_finite() && (lo..=hi).contains(&v) {
                Ok(())
            } else {
                Err(format!("breathing {what} {v} must be {lo} … {hi}"))
            }
        };
        check("amplitude (mm)", self.amplitude_mm, 0.0, 50.0)?;
        check("anterior ratio", self.anterior_ratio, 0.0, 1.0)?;
        check("body wall (mm)", self.wall_mm, 0.0, 60.0)?;
        check("bone margin (mm)", self.bone_margin_mm, 0.0, 20.0)
    }
}

/// a₁(X) of the synthetic motion on one atlas.
pub struct SyntheticField {
    atlas: Arc<PunctureAtlas>,
    params: SyntheticMotion,
    /// The liver's dome: the highest z of an organ or target voxel (mm).
    dome_z_mm: f64,
    /// By label id: a segmented soft structure (organ, target or risk), never bone.
    soft: Vec<bool>,
}

impl SyntheticField {
    /// Needs an organ (the liver) in the atlas' labels to place the diaphragm.
    pub fn new(atlas: Arc<PunctureAtlas>, params: SyntheticMotion) -> Result<SyntheticField, String> {
        params.validate()?;
        let dome_z_mm = dome_z_mm(&atlas).ok_or_else(|| {
            "the synthetic breathing motion needs an organ or target label (the liver) to place the diaphragm"
                .to_string()
        })?;
        let table = atlas.label_table();
        let max_id = table.labels().iter().map(|l| l.id as usize).max().unwrap_or(0);
        let mut soft = vec![false; max_id + 1];
        for l in table.labels() {
            soft[l.id as usize] = matches!(l.role, Role::Organ | Role::Target | Role::Risk);
        }
        Ok(SyntheticField {
            atlas,
            params,
            dome_z_mm,
            soft,
        })
    }

    /// The z of the liver's dome (mm).
    pub fn dome_z_mm(&self) -> f64 {
        self.dome_z_mm
    }

    /// w(z): the share of the full motion at height z.
    pub fn weight(&self, z_mm: f64) -> f64 {
        let above = z_mm - self.dome_z_mm;
        if above >= 0.0 {
            return (1.0 - above / LUNG_FALL_MM).max(0.0);
        }
        let below = -above - ABDOMEN_FULL_MM;
        if below <= 0.0 {
            1.0
        } else {
            (1.0 - (1.0 - PELVIS_WEIGHT) * below / ABDOMEN_FULL_MM).max(PELVIS_WEIGHT)
        }
    }

    /// m(X): 0 in the body wall, bone and its margin and outside the body; 1 deep inside.
    pub fn mobility(&self, x_ref: DVec3) -> f64 {
        let ramp = |d: f64| (d / RAMP_MM).clamp(0.0, 1.0);
        let depth = self.atlas.skin_distance().sample(x_ref, -1000.0) as f64;
        if depth <= self.params.wall_mm {
            return 0.0;
        }
        let wall = ramp(depth - self.params.wall_mm);
        let label = self.atlas.partial_label_at(x_ref) as usize;
        if self.soft.get(label).copied().unwrap_or(false) {
            return wall;
        }
        // Positive inside bone; far from any bone outside the map.
        let bone = self.atlas.bone_distance().sample(x_ref, -1000.0) as f64;
        wall * ramp(-bone - self.params.bone_margin_mm)
    }
}

impl SpatialField for SyntheticField {
    /// A · |(0, r_ap, −1)|: w and m never exceed 1.
    fn max_length_mm(&self) -> f64 {
        self.params.amplitude_mm * (1.0 + self.params.anterior_ratio * self.params.anterior_ratio).sqrt()
    }

    fn at(&self, x_ref: DVec3) -> DVec3 {
        let m = self.mobility(x_ref);
        if m == 0.0 {
            return DVec3::ZERO;
        }
        let p = &self.params;
        DVec3::new(0.0, p.anterior_ratio, -1.0) * (p.amplitude_mm * self.weight(x_ref.z) * m)
    }
}

/// The highest world z of a voxel labelled with an organ or target role (the liver's dome).
fn dome_z_mm(atlas: &PunctureAtlas) -> Option<f64> {
    let table = atlas.label_table();
    let moving = |id: u16| {
        id != 0
            && table
                .get(id)
                .is_some_and(|l| matches!(l.role, Role::Organ | Role::Target))
    };
    let labels = atlas.partial_labels();
    let grid = labels.grid();
    labels
        .data()
        .iter()
        .enumerate()
        .filter(|&(_, &id)| moving(id))
        .map(|(i, _)| grid.linear_to_world(i).z)
        .fold(None, |m: Option<f64>, z| Some(m.map_or(z, |m| m.max(z))))
}
