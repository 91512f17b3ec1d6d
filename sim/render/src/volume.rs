//! The atlas volumes as the renderers need them, prepared once per atlas: the CT, the label of
//! every voxel l(x) (partial segmentation, else the heuristic of eq. 6.1.1 at the voxel's skin
//! depth), each label's tagging class and colour (eqs. 3.2.4–3.2.5), and the per-cell CT value
//! ranges behind the occupancy grid of empty-space leaping (thesis §3.2.1).

use std::sync::{Arc, Mutex, OnceLock};

use stylet_physics::atlas::AIR_HU;

pub use crate::index_map::IndexMap;
use crate::raycast::cube_mask::CubeMask;
use crate::raycast::gradient_volume::GradientVolume;
pub use crate::raycast::occupancy::CellRanges;
use crate::transfer_table::{TransferTable, VisibilityKey};
use stylet_physics::{LabelId, PunctureAtlas, Role};

/// How a label is tagged on the clipping plane (eq. 3.2.4).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TagClass {
    Target,
    Risk,
    Other,
}

/// A label's tagging class and its property-tree colour (straight RGBA, 0 … 1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LabelStyle {
    pub class: TagClass,
    pub rgba: [f32; 4],
}

/// Cube masks a [`RenderVolume`] keeps (1 bit per voxel each).
pub const CUBE_MASKS_KEPT: usize = 3;

/// The atlas prepared for rendering.
pub struct RenderVolume {
    pub atlas: Arc<PunctureAtlas>,
    /// l(x) of every voxel, in the CT's voxel order.
    pub labels: Vec<LabelId>,
    /// Style of every label id 0 ..= max id (ids not in the table: `Other`, transparent).
    pub styles: Vec<LabelStyle>,
    /// Lowest and highest value a sample can read: the CT's range widened to air (outside the
    /// CT), the span of the per-frame transfer table.
    pub value_range_hu: (f32, f32),
    /// Per-cell CT ranges of the occupancy grid, computed once per cell count N.
    cell_cache: Mutex<Vec<Arc<CellRanges>>>,
    /// Cube masks of the last few transfer-table visibilities (most recent last).
    cube_cache: Mutex<Vec<(VisibilityKey, Arc<CubeMask>)>>,
    /// The CT's value and central differences per voxel, built by the first 3D frame.
    gradients: OnceLock<Arc<GradientVolume>>,
}

impl RenderVolume {
    /// Labels every voxel (rayon over slices) and collects the label styles.
    pub fn new(atlas: Arc<PunctureAtlas>) -> RenderVolume {
        use rayon::prelude::*;
        let grid = *atlas.ct().grid();
        let [nx, ny, nz] = grid.dims();
        let table = atlas.label_table();
        let thresholds = atlas.thresholds();
        let ct = atlas.ct().data();
        let partial = atlas.partial_labels().data();
        let skin = atlas.skin_distance().data();
        let mut labels = vec![0 as LabelId; ct.len()];
        labels.par_chunks_mut(nx * ny).enumerate().for_each(|(k, slab)| {
            for (o, l) in slab.iter_mut().enumerate() {
                let idx = k * nx * ny + o;
                let depth_mm = (skin[idx] as f64).max(0.0);
                *l = table.label(partial[idx], ct[idx] as f64, depth_mm, thresholds);
            }
        });
        let _ = nz;
        let max_id = table.labels().iter().map(|l| l.id).max().unwrap_or(0);
        let mut styles = vec![
            LabelStyle {
                class: TagClass::Other,
                rgba: [0.0; 4],
            };
            max_id as usize + 1
        ];
        for (pos, label) in table.labels().iter().enumerate() {
            let c = atlas.materials().color(pos);
            styles[label.id as usize] = LabelStyle {
                class: match label.role {
                    Role::Target => TagClass::Target,
                    Role::Risk | Role::Bone => TagClass::Risk,
                    Role::Organ | Role::Neutral => TagClass::Other,
                },
                rgba: c.map(|v| v as f32 / 255.0),
            };
        }
        let value_range_hu = ct
            .par_iter()
            .fold(
                || (AIR_HU, AIR_HU),
                |(lo, hi), &v| {
                    if v.is_finite() {
                        (lo.min(v), hi.max(v))
                    } else {
                        (lo, hi)
                    }
                },
            )
            .reduce(|| (AIR_HU, AIR_HU), |a, b| (a.0.min(b.0), a.1.max(b.1)));
        RenderVolume {
            atlas,
            labels,
            styles,
            value_range_hu,
            cell_cache: Mutex::new(Vec::new()),
            cube_cache: Mutex::new(Vec::new()),
            gradients: OnceLock::new(),
        }
    }

    /// The occupancy grid's CT ranges for `cells` per axis (clamped to 16 … 128), computed on
    /// first use and cached (a few per atlas at most).
    pub fn cell_ranges(&self, cells: u32) -> Arc<CellRanges> {
        let cells = cells.clamp(16, 128);
        let mut cache = self.cell_cache.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(r) = cache.iter().find(|r| r.cells == cells) {
            return r.clone();
        }
        let r = Arc::new(crate::raycast::occupancy::cell_ranges(self.atlas.ct(), cells));
        cache.push(r.clone());
        r
    }

    /// The cube mask of the CT under `table` (CT axes of ≥ 2 voxels), built on first use and
    /// cached for the last [`CUBE_MASKS_KEPT`] visibilities (a preset switch rebuilds it once).
    pub fn cube_mask(&self, table: &TransferTable) -> Arc<CubeMask> {
        let key = table.visibility_key();
        let mut cache = self.cube_cache.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(pos) = cache.iter().position(|(k, _)| *k == key) {
            let hit = cache.remove(pos);
            let mask = hit.1.clone();
            cache.push(hit);
            return mask;
        }
        let ct = self.atlas.ct();
        let dims = IndexMap::of(ct.grid()).dims;
        let mask = Arc::new(CubeMask::new(ct.data(), dims, table));
        if cache.len() >= CUBE_MASKS_KEPT {
            cache.remove(0);
        }
        cache.push((key, mask.clone()));
        mask
    }

    /// The CT's records of value and central differences (the ray caster's samples and
    /// gradients), built on first use: 8 bytes a voxel for an integer CT, else 16 (≈ 0.3 s and
    /// 280 MB for a 512 × 512 × 133 CT on 2 cores). Slices, X-ray and ultrasound never build it.
    pub fn gradient_volume(&self) -> Arc<GradientVolume> {
        self.gradients
            .get_or_init(|| {
                let ct = self.atlas.ct();
                Arc::new(GradientVolume::new(ct.data(), IndexMap::of(ct.grid()).dims))
            })
            .clone()
    }

    /// The style of a label id (unknown ids: `Other`, transparent).
    #[inline]
    pub fn style(&self, id: LabelId) -> LabelStyle {
        self.styles.get(id as usize).copied().unwrap_or(LabelStyle {
            class: TagClass::Other,
            rgba: [0.0; 4],
        })
    }
}
