//! Resampling a volume to an isotropic spacing over the same field of view: CT trilinear, labels
//! nearest neighbour (labels are never interpolated: docs/atlas.md "Geometry").

use rayon::prelude::*;
use stylet_physics::glam::DVec3;
use stylet_physics::{AIR_HU, Affine, Grid, LabelId, Volume};

/// The grid covering the same box (voxel edges) as `grid` with voxels of `spacing_mm`.
pub fn isotropic_grid(grid: &Grid, spacing_mm: f64) -> Grid {
    let old = grid.spacing_mm();
    let a = grid.affine();
    let mut dims = [0usize; 3];
    let mut axes = [DVec3::ZERO; 3];
    let mut origin = a.origin;
    for k in 0..3 {
        let extent = grid.dims()[k] as f64 * old[k];
        dims[k] = (extent / spacing_mm).round().max(1.0) as usize;
        let dir = a.axes[k] / old[k];
        axes[k] = dir * spacing_mm;
        // Move from the old first centre to the box edge, then to the new first centre.
        origin += dir * (-0.5 * old[k] + 0.5 * spacing_mm);
    }
    Grid::new(dims, Affine { axes, origin }).expect("a finer grid of a valid grid is valid")
}

fn centres(grid: &Grid) -> impl IndexedParallelIterator<Item = DVec3> + '_ {
    (0..grid.len()).into_par_iter().map(|idx| grid.linear_to_world(idx))
}

pub fn resample_ct(ct: &Volume<f32>, grid: &Grid) -> Volume<f32> {
    let data = centres(grid).map(|p| ct.sample(p, AIR_HU)).collect();
    Volume::new(*grid, data).expect("sized to the grid")
}

pub fn resample_labels(labels: &Volume<LabelId>, grid: &Grid) -> Volume<LabelId> {
    let data = centres(grid).map(|p| labels.nearest(p, 0)).collect();
    Volume::new(*grid, data).expect("sized to the grid")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn isotropic_grid_keeps_the_field_of_view() {
        let g = Grid::new(
            [10, 20, 5],
            Affine::from_spacing([3.0, 3.0, 3.0], DVec3::new(-10.0, 5.0, 100.0)),
        )
        .unwrap();
        let n = isotropic_grid(&g, 1.5);
        assert_eq!(n.dims(), [20, 40, 10]);
        // Old first centre −10; its box starts at −11.5; the new first centre is at −10.75.
        assert_eq!(n.affine().origin, DVec3::new(-10.75, 4.25, 99.25));
        let (lo, hi) = n.world_bounds();
        assert_eq!(lo.x - 0.75, -11.5);
        assert_eq!(hi.x + 0.75, -10.0 + 9.0 * 3.0 + 1.5);
    }
}
