//! Distance from a point to the nearest target voxel: an exact Euclidean distance transform of
//! the atlas' target labels (docs/atlas.md "Distance maps"), computed once per atlas and sampled
//! trilinearly per tick.

use stylet_physics::{PunctureAtlas, Role, Volume};

use crate::probe_view::SurveyPoints;

/// Distance (mm) to the nearest voxel centre labelled with a target role.
pub struct TargetDistance {
    map: Option<Volume<f32>>,
    /// Target voxel centres (world mm), at most [`MAX_TARGET_POINTS`] (evenly thinned): what an
    /// ultrasound image plane is tested against.
    points: SurveyPoints,
}

/// Bounds the per-tick cost of the ultrasound view test.
pub const MAX_TARGET_POINTS: usize = 4096;

impl TargetDistance {
    pub fn new(atlas: &PunctureAtlas) -> Self {
        let labels = atlas.partial_labels();
        let table = atlas.label_table();
        let target: Vec<bool> = labels
            .data()
            .iter()
            .map(|&l| l != 0 && table.get(l).is_some_and(|x| x.role == Role::Target))
            .collect();
        if !target.iter().any(|&t| t) {
            return TargetDistance {
                map: None,
                points: SurveyPoints::default(),
            };
        }
        let grid = *labels.grid();
        let d: Vec<f32> = stylet_physics::distance::squared_edt(&grid, &target)
            .into_iter()
            .map(f32::sqrt)
            .collect();
        let all: Vec<usize> = (0..target.len()).filter(|&i| target[i]).collect();
        let stride = all.len().div_ceil(MAX_TARGET_POINTS).max(1);
        let points = SurveyPoints::new(all.iter().step_by(stride).map(|&i| grid.linear_to_world(i)).collect());
        TargetDistance {
            map: Some(Volume::new(grid, d).expect("same grid")),
            points,
        }
    }

    /// Target voxel centres (world mm; thinned evenly to at most [`MAX_TARGET_POINTS`]), blocked
    /// for the ultrasound survey's test.
    pub fn survey_points(&self) -> &SurveyPoints {
        &self.points
    }

    /// `None` when the atlas has no target voxels or `p` lies outside the CT grid.
    pub fn distance_mm(&self, p: stylet_physics::glam::DVec3) -> Option<f64> {
        let v = self.map.as_ref()?.sample(p, f32::NAN);
        (!v.is_nan()).then_some(v as f64)
    }
}
