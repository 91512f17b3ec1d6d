//! The atlas volumes as the renderers need them, prepared once per atlas: the CT, the label of
//! every voxel l(x) (partial segmentation, else the heuristic of eq. 6.1.1 at the voxel's skin
//! depth), each label's tagging class and colour (eqs. 3.2.4–3.2.5), and the per-cell CT value
//! ranges behind the occupancy grid of empty-space leaping (thesis §3.2.1).

use std::sync::Arc;

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

/// The atlas prepared for rendering.
pub struct RenderVolume {
    pub atlas: Arc<PunctureAtlas>,
    /// l(x) of every voxel, in the CT's voxel order.
    pub labels: Vec<LabelId>,
    /// Style of every label id 0 ..= max id (ids not in the table: `Other`, transparent).
    pub styles: Vec<LabelStyle>,
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
        RenderVolume { atlas, labels, styles }
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
