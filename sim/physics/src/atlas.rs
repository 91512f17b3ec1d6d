//! The puncture atlas in memory: CT image + partial segmentation + property tree, with the derived
//! data the haptic algorithms need (thesis §6.1, §3.6; docs/atlas.md).
//!
//! Everything here lives in reference space X. Construction validates the pieces against each
//! other and derives the per-label materials and the skin and bone distance maps once.

use glam::DVec3;

use crate::distance::subvoxel_signed_distance;
use crate::masks::{body_mask, bone_mask};
use crate::{LabelId, LabelTable, Materials, Param, PhysicsError, PropertyTree, Thresholds, Volume};

/// CT value returned outside the volume: air.
pub const AIR_HU: f32 = -1000.0;

/// Default thickness of the skin layer the needle feels (mm): epidermis and dermis are 1.5–3 mm.
pub const DEFAULT_SKIN_LAYER_MM: f64 = 2.0;

/// The skin and bone signed distance maps (thesis §3.6), derived from the CT and the thresholds:
/// the costliest part of loading an atlas, hence cacheable.
#[derive(Debug, Clone, PartialEq)]
pub struct DistanceMaps {
    /// D_skin, mm, positive inside the body.
    pub skin_distance: Volume<f32>,
    /// D_bone, mm, positive inside bone.
    pub bone_distance: Volume<f32>,
}

impl DistanceMaps {
    /// Derives both maps: the body and bone masks at `thresholds`, then their sub-voxel signed
    /// distances, corrected near the surface by the CT's iso-surfaces at the thresholds (a slanted
    /// surface is otherwise a staircase of ledges).
    pub fn derive(ct: &Volume<f32>, thresholds: &Thresholds) -> DistanceMaps {
        let body = body_mask(ct, thresholds.air_skin_hu);
        let bone = bone_mask(ct, thresholds.fat_bone_hu, &body);
        let (skin_distance, bone_distance) = rayon::join(
            || subvoxel_signed_distance(ct, &body, thresholds.air_skin_hu),
            || subvoxel_signed_distance(ct, &bone, thresholds.fat_bone_hu),
        );
        DistanceMaps {
            skin_distance,
            bone_distance,
        }
    }
}

/// A validated puncture atlas.
#[derive(Debug, Clone)]
pub struct PunctureAtlas {
    ct: Volume<f32>,
    partial: Volume<LabelId>,
    labels: LabelTable,
    tree: PropertyTree,
    materials: Materials,
    thresholds: Thresholds,
    skin_distance: Volume<f32>,
    bone_distance: Volume<f32>,
    /// [`Volume::max_neighbour_steps`] of `skin_distance` (mm per index unit).
    skin_distance_steps_mm: [f64; 3],
    skin_layer_mm: f64,
    /// The breathing motion attached to the atlas (docs/breathing.md "Atlases"); `None`: this
    /// patient does not breathe.
    breathing: Option<crate::motion::AtlasMotion>,
    /// The bile ducts' lumen for a guide wire, built the first time a wire needs it.
    duct_channel: std::sync::OnceLock<Option<std::sync::Arc<crate::wire::DuctChannel>>>,
}

impl PunctureAtlas {
    /// Checks that CT and partial labels share one grid, that the CT is finite, that every label
    /// value is in the table, that thresholds are ordered and that every label's parameters resolve.
    pub fn new(
        ct: Volume<f32>,
        partial: Volume<LabelId>,
        labels: LabelTable,
        tree: PropertyTree,
        thresholds: Thresholds,
    ) -> Result<Self, PhysicsError> {
        Self::with_distance_maps(ct, partial, labels, tree, thresholds, None)
    }

    /// As [`PunctureAtlas::new`], with the skin and bone distance maps given when `maps` is
    /// `Some` (read from a cache of this very atlas, docs/atlas.md "Derived-data cache"), derived
    /// from the CT otherwise. Given maps must lie on the CT's grid; that they are the maps this
    /// CT and these thresholds derive is the cache's promise (its key and checksum), not checked
    /// here.
    pub fn with_distance_maps(
        ct: Volume<f32>,
        partial: Volume<LabelId>,
        labels: LabelTable,
        tree: PropertyTree,
        thresholds: Thresholds,
        maps: Option<DistanceMaps>,
    ) -> Result<Self, PhysicsError> {
        let (gc, gl) = (*ct.grid(), *partial.grid());
        if gc.dims() != gl.dims() {
            return Err(PhysicsError::Mismatch(format!(
                "CT has dimensions {:?} but the label map has {:?}",
                gc.dims(),
                gl.dims()
            )));
        }
        let diff = gc.affine().max_abs_diff(gl.affine());
        if diff > 1e-3 {
            return Err(PhysicsError::Mismatch(format!(
                "CT and label map affines differ by up to {diff:.4} mm (CT {:?}, labels {:?})",
                gc.affine().rows(),
                gl.affine().rows()
            )));
        }
        // Within that tolerance the label map is taken to lie on the CT's grid exactly, so every
        // lookup uses one continuous index (see `needle_label_at`).
        let partial = if gl == gc {
            partial
        } else {
            Volume::new(gc, partial.into_data())?
        };
        if let Some(pos) = ct.data().iter().position(|v| !v.is_finite()) {
            let [i, j, k] = gc.unlinear(pos);
            return Err(PhysicsError::NotFinite(format!(
                "CT value at voxel ({i}, {j}, {k}) is {}",
                ct.data()[pos]
            )));
        }
        let mut seen = vec![0u64; u16::MAX as usize + 1];
        for &l in partial.data() {
            seen[l as usize] += 1;
        }
        for (id, &n) in seen.iter().enumerate().skip(1) {
            if n > 0 && labels.get(id as LabelId).is_none() {
                return Err(PhysicsError::InvalidLabels(format!(
                    "label map uses label {id} ({n} voxels) which is not in the label table"
                )));
            }
        }
        thresholds.validate()?;
        let materials = Materials::resolve(&labels, &tree)?;
        let DistanceMaps {
            skin_distance,
            bone_distance,
        } = match maps {
            Some(maps) => {
                for (what, map) in [("skin", &maps.skin_distance), ("bone", &maps.bone_distance)] {
                    if map.grid() != &gc {
                        return Err(PhysicsError::Mismatch(format!(
                            "the given {what} distance map does not lie on the CT's grid"
                        )));
                    }
                }
                maps
            }
            None => DistanceMaps::derive(&ct, &thresholds),
        };
        let skin_distance_steps_mm = skin_distance.max_neighbour_steps();
        Ok(PunctureAtlas {
            skin_distance_steps_mm,
            ct,
            partial,
            labels,
            tree,
            materials,
            thresholds,
            skin_distance,
            bone_distance,
            skin_layer_mm: DEFAULT_SKIN_LAYER_MM,
            breathing: Some(crate::motion::AtlasMotion::Synthetic(Default::default())),
            duct_channel: std::sync::OnceLock::new(),
        })
    }

    pub fn ct(&self) -> &Volume<f32> {
        &self.ct
    }
    pub fn partial_labels(&self) -> &Volume<LabelId> {
        &self.partial
    }
    pub fn label_table(&self) -> &LabelTable {
        &self.labels
    }
    pub fn property_tree(&self) -> &PropertyTree {
        &self.tree
    }
    pub fn materials(&self) -> &Materials {
        &self.materials
    }
    pub fn thresholds(&self) -> &Thresholds {
        &self.thresholds
    }
    /// D_skin: signed distance to the skin surface, mm, positive inside the body (§3.6).
    pub fn skin_distance(&self) -> &Volume<f32> {
        &self.skin_distance
    }
    /// How far (mm) from `from` along the unit vector `dir` the skin is: 0 under the skin, `None`
    /// when nothing is met within `max_mm`. Sphere tracing on D_skin (a distance: no step of
    /// |D_skin| passes the surface), at least 0.25 mm a step; outside the CT grid 1 mm steps, as
    /// a start in the air beyond a tightly cropped CT may lie there. For hints to people (the
    /// tool's distance to the skin), not for physics.
    pub fn skin_distance_along(&self, from: DVec3, dir: DVec3, max_mm: f64) -> Option<f64> {
        let mut t = 0.0;
        while t <= max_mm {
            let d = f64::from(self.skin_distance.sample(from + dir * t, f32::NAN));
            if d >= 0.0 {
                return Some(t);
            }
            t += if d.is_nan() { 1.0 } else { (-d).max(0.25) };
        }
        None
    }

    /// The most D_skin changes between neighbouring voxels along each index axis (mm): a bound
    /// on the interpolated map's slope (the contact tools use it to pass nodes certainly off the
    /// skin without reading it).
    pub fn skin_distance_steps_mm(&self) -> [f64; 3] {
        self.skin_distance_steps_mm
    }
    /// D_bone: signed distance to the bone surface, mm, positive inside bone (§3.6).
    pub fn bone_distance(&self) -> &Volume<f32> {
        &self.bone_distance
    }

    /// I(x): trilinear CT value at a reference-space position (mm), air outside.
    #[inline]
    pub fn hu_at(&self, x: DVec3) -> f64 {
        self.ct.sample(x, AIR_HU) as f64
    }

    /// p(x): the partial label by nearest-neighbour lookup, 0 outside.
    #[inline]
    pub fn partial_label_at(&self, x: DVec3) -> LabelId {
        self.partial.nearest(x, 0)
    }

    /// l(x, d) of eq. 6.1.2 at insertion depth `depth_mm` (use 0 for rendering).
    #[inline]
    pub fn label_at(&self, x: DVec3, depth_mm: f64) -> LabelId {
        self.labels
            .label(self.partial_label_at(x), self.hu_at(x), depth_mm, &self.thresholds)
    }

    /// Sets the skin layer the needle feels (mm, ≥ 0; see [`PunctureAtlas::needle_label_at`]).
    pub fn with_skin_layer_mm(mut self, mm: f64) -> Result<Self, PhysicsError> {
        if !(mm.is_finite() && (0.0..=20.0).contains(&mm)) {
            return Err(PhysicsError::InvalidThresholds(format!(
                "skin_layer_mm {mm} must be 0 … 20"
            )));
        }
        self.skin_layer_mm = mm;
        Ok(self)
    }

    pub fn skin_layer_mm(&self) -> f64 {
        self.skin_layer_mm
    }

    /// The atlas with `motion` attached (`None`: it does not breathe); a synthetic motion out of
    /// range is refused.
    pub fn with_breathing(mut self, motion: Option<crate::motion::AtlasMotion>) -> Result<Self, PhysicsError> {
        if let Some(crate::motion::AtlasMotion::Synthetic(m)) = &motion {
            m.validate().map_err(PhysicsError::InvalidBreathing)?;
        }
        self.breathing = motion;
        Ok(self)
    }

    /// The bile ducts' lumen a guide wire follows (labels whose tissue is `bile_duct` or descends
    /// from it), built once, the first time it is asked for; `None`: the atlas has no ducts.
    pub fn duct_channel(&self) -> Option<std::sync::Arc<crate::wire::DuctChannel>> {
        self.duct_channel
            .get_or_init(|| crate::wire::DuctChannel::of_tissue(self, "bile_duct").map(std::sync::Arc::new))
            .clone()
    }

    /// The breathing motion attached to the atlas (the default synthetic motion unless the
    /// atlas says otherwise).
    pub fn breathing(&self) -> Option<&crate::motion::AtlasMotion> {
        self.breathing.as_ref()
    }

    /// The label the needle tip feels: l(x, d) of eq. 6.1.2, except that unlabelled tissue within
    /// `skin_layer_mm` under the skin surface (0 ≤ D_skin < layer) at depth d ≤ δ counts as skin.
    /// On CT the dermis is as dense as muscle, so eq. 6.1.1 alone calls only partial-volume surface
    /// voxels skin and misses the skin where the surface voxel is nearly full; the distance map
    /// gives every entry point the same skin thickness, so every puncture meets the skin's
    /// cutting threshold.
    #[inline]
    pub fn needle_label_at(&self, x: DVec3, depth_mm: f64) -> (LabelId, f64) {
        // CT, labels and distance maps share one grid (checked in `new`): one index for all.
        let c = self.ct.grid().world_to_index(x);
        let hu = self.ct.sample_index(c, AIR_HU) as f64;
        let partial = match self.ct.grid().nearest_voxel_of_index(c) {
            Some([i, j, k]) => self.partial.get(i, j, k),
            None => 0,
        };
        if partial != 0 {
            return (partial, hu);
        }
        let t = &self.thresholds;
        if depth_mm <= t.risk_depth_mm && hu < t.fat_bone_hu {
            let d = self.skin_distance.sample_index(c, -1.0) as f64;
            if d >= 0.0 && d < self.skin_layer_mm {
                return (self.labels.heuristic().skin, hu);
            }
        }
        (self.labels.heuristic().label(t.classify(hu, depth_mm)), hu)
    }

    /// A parameter of `label` at CT value `hu` (§6.1.4 step 3 after the label is known).
    #[inline]
    pub fn param_of(&self, label: LabelId, param: Param, hu: f64) -> f64 {
        let pos = self.labels.position(label).expect("labels validated at construction");
        self.materials.eval(pos, param, hu)
    }

    /// A material parameter at x for insertion depth d (§6.1.4): label, tree node, value at I(x).
    #[inline]
    pub fn param_at(&self, x: DVec3, depth_mm: f64, param: Param) -> f64 {
        let hu = self.hu_at(x);
        let label = self
            .labels
            .label(self.partial_label_at(x), hu, depth_mm, &self.thresholds);
        let pos = self.labels.position(label).expect("labels validated at construction");
        self.materials.eval(pos, param, hu)
    }

    /// Voxel counts of the labelling at depth 0, per label id in table order (heuristic included).
    pub fn label_voxel_counts(&self) -> Vec<(LabelId, u64)> {
        let mut counts = vec![0u64; self.labels.labels().len()];
        for (&p, &hu) in self.partial.data().iter().zip(self.ct.data()) {
            let l = self.labels.label(p, hu as f64, 0.0, &self.thresholds);
            counts[self.labels.position(l).expect("validated")] += 1;
        }
        self.labels.labels().iter().map(|l| l.id).zip(counts).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::properties::ParamValue;
    use crate::{Affine, Grid, synthetic_atlas};

    /// A body filling z < 0 of a 40 × 40 × 40 mm box of 1 mm voxels, air above.
    fn slab() -> PunctureAtlas {
        let g = Grid::new(
            [40, 40, 40],
            Affine::from_spacing([1.0; 3], DVec3::new(-20.0, -20.0, -20.0)),
        )
        .unwrap();
        let ct = (0..g.len())
            .map(|i| {
                let [a, b, c] = g.unlinear(i);
                if g.voxel_to_world(a, b, c).z < 0.0 {
                    40.0
                } else {
                    -1000.0
                }
            })
            .collect();
        synthetic_atlas::atlas_with(g, ct, vec![0; g.len()], &[], ParamValue::Scalar(0.5)).unwrap()
    }

    #[test]
    fn the_skin_is_found_along_a_ray_from_inside_and_outside_the_grid() {
        let a = slab();
        // From 12 mm above the skin, straight down: 12 mm, to within the surface's voxel.
        let d = a
            .skin_distance_along(DVec3::new(0.0, 0.0, 12.0), DVec3::NEG_Z, 100.0)
            .unwrap();
        assert!((d - 12.0).abs() <= 1.0, "{d}");
        // Slanted at 60° from the normal: twice as far.
        let dir = DVec3::new(libm::sin(60f64.to_radians()), 0.0, -0.5).normalize();
        let d = a.skin_distance_along(DVec3::new(-15.0, 0.0, 6.0), dir, 100.0).unwrap();
        assert!((d - 12.0).abs() <= 1.5, "{d}");
        // From 30 mm above the box (outside the CT): still found.
        let d = a
            .skin_distance_along(DVec3::new(0.0, 0.0, 50.0), DVec3::NEG_Z, 100.0)
            .unwrap();
        assert!((d - 50.0).abs() <= 1.0, "{d}");
        // Under the skin: 0; pointing away, or too short a reach: none.
        assert_eq!(
            a.skin_distance_along(DVec3::new(0.0, 0.0, -5.0), DVec3::Z, 100.0),
            Some(0.0)
        );
        assert_eq!(a.skin_distance_along(DVec3::new(0.0, 0.0, 12.0), DVec3::Z, 100.0), None);
        assert_eq!(
            a.skin_distance_along(DVec3::new(0.0, 0.0, 12.0), DVec3::NEG_Z, 5.0),
            None
        );
    }
}
