//! The channel a guide wire follows: the bile ducts' lumen as a signed distance map (positive
//! inside, mm; `distance::signed_distance_map`), its gradient pointing away from the wall, into
//! the lumen. The wire's tip is in the lumen while the distance there exceeds its radius. Along
//! with it, each duct voxel's distance from the hilum through the ducts ([`HilumDistance`]).

use glam::DVec3;

use super::branches::HilumDistance;
use crate::distance::signed_distance_map;
use crate::gradient::GradientSampler;
use crate::grid::Grid;
use crate::volume::Volume;

/// The ducts' lumen, ready to be sampled.
#[derive(Debug, Clone)]
pub struct DuctChannel {
    distance: Volume<f32>,
    from_hilum: HilumDistance,
}

/// Distance read outside the grid (mm): far outside any duct.
const OUTSIDE_MM: f32 = -1.0e3;

impl DuctChannel {
    /// The channel of the voxels `lumen` marks (the duct labels' voxels).
    pub fn new(grid: &Grid, lumen: &[bool]) -> DuctChannel {
        let distance = signed_distance_map(grid, lumen);
        let from_hilum = HilumDistance::from_widest(grid, lumen, &distance);
        DuctChannel { distance, from_hilum }
    }

    /// The channel of `lumen` with the hilum at the voxel nearest `hilum_mm` (which must be in
    /// the lumen) rather than at the widest point.
    pub fn with_hilum_at(grid: &Grid, lumen: &[bool], hilum_mm: DVec3) -> DuctChannel {
        let hilum = grid.nearest_voxel(hilum_mm).map_or(0, |[i, j, k]| grid.linear(i, j, k));
        DuctChannel {
            distance: signed_distance_map(grid, lumen),
            from_hilum: HilumDistance::from_voxel(grid, lumen, hilum),
        }
    }

    /// The channel of an atlas' ducts: the voxels whose partial label's tissue is `tissue` or
    /// descends from it (`bile_duct` takes the target duct too); `None` when no label is.
    pub fn of_tissue(atlas: &crate::PunctureAtlas, tissue: &str) -> Option<DuctChannel> {
        let tree = atlas.property_tree();
        let ducts: Vec<crate::LabelId> = atlas
            .label_table()
            .labels()
            .iter()
            .filter(|l| tree.is_a(&l.tissue, tissue))
            .map(|l| l.id)
            .collect();
        if ducts.is_empty() {
            return None;
        }
        let labels = atlas.partial_labels();
        let lumen: Vec<bool> = labels.data().iter().map(|l| ducts.contains(l)).collect();
        Some(DuctChannel::new(labels.grid(), &lumen))
    }

    /// Signed distance to the duct wall at `x` (mm; positive inside the lumen).
    pub fn depth_mm(&self, x: DVec3) -> f64 {
        f64::from(self.distance.sample(x, OUTSIDE_MM))
    }

    /// Distance from the hilum along the ducts at `x` (mm), `None` outside the ducts.
    pub fn from_hilum_mm(&self, x: DVec3) -> Option<f64> {
        self.from_hilum.at(x)
    }

    /// The unit direction away from the nearest wall, into the lumen (zero where the field is
    /// flat).
    pub fn inward(&self, x: DVec3) -> DVec3 {
        let g =
            GradientSampler::new(&self.distance).gradient_at_index(self.distance.grid().world_to_index(x), OUTSIDE_MM);
        g.try_normalize().unwrap_or(DVec3::ZERO)
    }
}
