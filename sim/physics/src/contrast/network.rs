//! The duct network: every voxel of the atlas whose partial label belongs to the duct system,
//! kept sparse (a duct tree is a few thousand voxels of a CT's millions), with each voxel's duct
//! neighbours along the six axis directions.
//!
//! Slots number the duct voxels in the CT's voxel order (x fastest), so the diffusion's rows
//! along x are consecutive slots (see `diffusion`). A node's neighbours are found by binary
//! search among the sorted voxel indices.
//!
//! Path distances along the ducts (Dijkstra over the 6-neighbourhood, an edge as long as the
//! voxel spacing along its axis) order the nodes for the volume-driven filling (`filling`) and
//! measure how far the contrast reached (`ContrastAgent::filled_extent_mm`).

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use super::diffusion::DuctNeighbours;
use crate::{Grid, LabelId, PunctureAtlas};

/// No neighbour in that direction.
const NONE: u32 = u32::MAX;

/// The atlas' duct voxels and their adjacency.
#[derive(Debug, Clone)]
pub(super) struct DuctNetwork {
    /// The labels' (and the CT's) voxel grid.
    grid: Grid,
    /// CT linear voxel index of each slot (increasing).
    voxels: Vec<usize>,
    /// Each slot's neighbour slot along −x, +x, −y, +y, −z, +z (`NONE`: not a duct voxel, or
    /// outside the CT).
    adjacent: Vec<[u32; 6]>,
    /// The same neighbours grouped for the diffusion steps of eq. 3.3.2.
    pub(super) neighbours: DuctNeighbours,
    /// Edge length along x, y, z (mm): the CT's voxel spacing.
    spacing_mm: [f64; 3],
    /// Volume of one voxel (ml).
    pub(super) node_volume_ml: f64,
}

impl DuctNetwork {
    /// The voxels of `atlas` whose partial label is one of `duct_labels`.
    pub(super) fn build(atlas: &PunctureAtlas, duct_labels: &[LabelId]) -> DuctNetwork {
        let partial = atlas.partial_labels();
        let grid = partial.grid();
        let mut is_duct = vec![false; usize::from(LabelId::MAX) + 1];
        for &l in duct_labels {
            is_duct[usize::from(l)] = true;
        }
        let voxels: Vec<usize> = partial
            .data()
            .iter()
            .enumerate()
            .filter(|&(_, &l)| l != 0 && is_duct[usize::from(l)])
            .map(|(v, _)| v)
            .collect();
        let [nx, ny, nz] = grid.dims();
        let slot_of = |v: usize| voxels.binary_search(&v).ok().map_or(NONE, |s| s as u32);
        let adjacent: Vec<[u32; 6]> = voxels
            .iter()
            .map(|&v| {
                let [i, j, k] = grid.unlinear(v);
                let (sy, sz) = (nx, nx * ny);
                let at = |inside: bool, w: usize| if inside { slot_of(w) } else { NONE };
                [
                    at(i > 0, v.wrapping_sub(1)),
                    at(i + 1 < nx, v + 1),
                    at(j > 0, v.wrapping_sub(sy)),
                    at(j + 1 < ny, v + sy),
                    at(k > 0, v.wrapping_sub(sz)),
                    at(k + 1 < nz, v + sz),
                ]
            })
            .collect();
        let lists: Vec<Vec<u32>> = adjacent
            .iter()
            .map(|a| a.iter().copied().filter(|&s| s != NONE).collect())
            .collect();
        let neighbours = DuctNeighbours::new(lists.iter().map(Vec::as_slice));
        debug_assert_eq!(neighbours.len(), voxels.len());
        let spacing_mm = grid.spacing_mm();
        DuctNetwork {
            grid: *grid,
            voxels,
            adjacent,
            neighbours,
            spacing_mm,
            node_volume_ml: spacing_mm[0] * spacing_mm[1] * spacing_mm[2] / 1000.0,
        }
    }

    /// Number of duct voxels.
    pub(super) fn len(&self) -> usize {
        self.voxels.len()
    }

    /// CT voxel index [i, j, k] of a slot.
    pub(super) fn voxel(&self, slot: usize) -> [usize; 3] {
        self.grid.unlinear(self.voxels[slot])
    }

    /// The voxel grid the slots index.
    pub(super) fn grid(&self) -> &Grid {
        &self.grid
    }

    /// The slot of the CT voxel with linear index `voxel`, when it is a duct voxel.
    pub(super) fn slot_of(&self, voxel: usize) -> Option<usize> {
        self.voxels.binary_search(&voxel).ok()
    }

    /// Path distances along the ducts from slot `from` (mm; infinite where the ducts do not
    /// connect), and the connected slots in order of increasing distance (ties: the lower slot
    /// first). Deterministic: distances are sums of the spacings in the order the paths are
    /// settled, and the queue orders equal distances by slot.
    pub(super) fn paths_from(&self, from: usize) -> (Vec<f64>, Vec<u32>) {
        let mut distance = vec![f64::INFINITY; self.len()];
        let mut order = Vec::new();
        let mut settled = vec![false; self.len()];
        // Non-negative f64 order as their bits do.
        let mut queue = BinaryHeap::new();
        distance[from] = 0.0;
        queue.push(Reverse((0.0f64.to_bits(), from as u32)));
        while let Some(Reverse((bits, s))) = queue.pop() {
            let s = s as usize;
            if settled[s] {
                continue;
            }
            settled[s] = true;
            order.push(s as u32);
            let here = f64::from_bits(bits);
            for (direction, &t) in self.adjacent[s].iter().enumerate() {
                if t == NONE || settled[t as usize] {
                    continue;
                }
                let d = here + self.spacing_mm[direction / 2];
                if d < distance[t as usize] {
                    distance[t as usize] = d;
                    queue.push(Reverse((d.to_bits(), t)));
                }
            }
        }
        (distance, order)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Affine, PropertyTree, Role, TissueSpec, Volume, synthetic_atlas};
    use glam::DVec3;

    /// A 12 × 6 × 4 atlas (spacing 1 × 2 × 3 mm) with an L-shaped duct: along x at j = k = 1
    /// from i = 1 to 9, then along y at i = 9 up to j = 4; and one lone duct voxel apart.
    fn atlas() -> PunctureAtlas {
        let g = Grid::new([12, 6, 4], Affine::from_spacing([1.0, 2.0, 3.0], DVec3::ZERO)).unwrap();
        let mut labels = vec![0u16; g.len()];
        for i in 1..=9 {
            labels[g.linear(i, 1, 1)] = 20;
        }
        for j in 2..=4 {
            labels[g.linear(9, j, 1)] = 20;
        }
        labels[g.linear(3, 4, 3)] = 20;
        let table = synthetic_atlas::label_table(
            "body",
            &[
                (synthetic_atlas::RISK, "risk", Role::Risk, "body"),
                (20, "bile duct", Role::Target, "bile_duct"),
            ],
        )
        .unwrap();
        let tree = PropertyTree::new(vec![
            synthetic_atlas::body(synthetic_atlas::body_ramp()),
            TissueSpec {
                name: "bile_duct".into(),
                parent: Some("body".into()),
                params: Default::default(),
                color_rgba: None,
                complication: None,
            },
        ])
        .unwrap();
        PunctureAtlas::new(
            Volume::new(g, vec![0.0; g.len()]).unwrap(),
            Volume::new(g, labels).unwrap(),
            table,
            tree,
            synthetic_atlas::THRESHOLDS,
        )
        .unwrap()
    }

    #[test]
    fn the_network_is_the_duct_voxels_and_their_axis_neighbours() {
        let a = atlas();
        let n = DuctNetwork::build(&a, &[20]);
        assert_eq!(n.len(), 9 + 3 + 1);
        let g = a.partial_labels().grid();
        let corner = n.slot_of(g.linear(9, 1, 1)).unwrap();
        let left = n.slot_of(g.linear(8, 1, 1)).unwrap() as u32;
        let up = n.slot_of(g.linear(9, 2, 1)).unwrap() as u32;
        assert_eq!(n.adjacent[corner], [left, NONE, NONE, up, NONE, NONE]);
        assert_eq!(n.slot_of(g.linear(0, 1, 1)), None);
        assert!((n.node_volume_ml - 0.006).abs() < 1e-15);
    }

    #[test]
    fn path_distances_follow_the_duct_and_stop_where_it_ends() {
        let a = atlas();
        let n = DuctNetwork::build(&a, &[20]);
        let g = a.partial_labels().grid();
        let start = n.slot_of(g.linear(1, 1, 1)).unwrap();
        let (d, order) = n.paths_from(start);
        // 8 mm along x (1 mm steps), then 3 × 2 mm along y: 14 mm, not the 11.3 mm straight.
        assert_eq!(d[n.slot_of(g.linear(9, 4, 1)).unwrap()], 14.0);
        assert_eq!(d[n.slot_of(g.linear(3, 4, 3)).unwrap()], f64::INFINITY);
        assert_eq!(order.len(), 12, "the lone voxel is not connected");
        assert_eq!(order[0] as usize, start);
        assert!(order.windows(2).all(|w| d[w[0] as usize] <= d[w[1] as usize]));
    }
}
