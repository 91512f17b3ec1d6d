//! What wrong punctures did to the patient, as the views draw it (docs/complications.md
//! "What the views show"). The physics says where each leak began and how much came out
//! (`stylet_physics::complications`); this module turns that into what a clinician looks for:
//!
//! - a haematoma or a bile leak is a fluid collection, a sphere of the leaked volume around the
//!   puncture: on ultrasound it replaces the soft tissue's echo with a fresh haematoma's
//!   (hypoechoic, faint speckle) or bile's (anechoic); on the X-ray its CT value replaces the tissue's
//!   (fresh blood 55 HU, bile 10 HU: barely different from liver, as on a real fluoroscopy);
//! - a pneumothorax is air between the chest wall and the lung: on ultrasound the lung's surface
//!   loses the texture that slides with it under the chest wall (lung sliding lost); on the X-ray
//!   the punctured lung's outer layers turn to air, layer by layer from its surface all round (the lung retracting evenly,
//!   as on an upright film), until they hold the leaked volume; the lung tissue they held is laid on the next two layers, the denser edge of
//!   the retracted lung (the visceral pleural line the radiologist looks for).
//!
//! Everything is in reference space, like the CT: the views' breathing warp applies to it as to
//! the CT. Pure functions of the atlas and the sites, so a replayed moment draws the same.

use std::collections::BTreeMap;

use stylet_physics::complications::Site;
use stylet_physics::glam::{DVec3, Vec3};
use stylet_physics::{Consequence, LabelId, PunctureAtlas};

use crate::xray::attenuation::{MU_WATER_PER_MM, water_relative};

/// CT value of fresh (unclotted) blood and of bile (HU).
pub const BLOOD_HU: f32 = 55.0;
pub const BILE_HU: f32 = 10.0;
/// A collection replaces tissue between these CT values: soft tissue and fat, not air or bone.
pub const COLLECTION_MIN_HU: f32 = -200.0;
pub const COLLECTION_MAX_HU: f32 = 300.0;
/// Layers of lung voxels that take the retracted lung's tissue (the pleural line).
pub const PLEURAL_LINE_LAYERS: usize = 2;

/// A fluid collection: a haematoma or a bile leak.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FluidCollection {
    pub kind: Consequence,
    /// Its centre: the puncture (reference space, mm).
    pub centre_mm: Vec3,
    pub radius_mm: f32,
}

impl FluidCollection {
    /// Whether the reference point `x` lies inside.
    #[inline]
    pub fn contains(&self, x: Vec3) -> bool {
        (x - self.centre_mm).length_squared() <= self.radius_mm * self.radius_mm
    }

    /// The CT value of what it holds.
    pub fn hu(&self) -> f32 {
        match self.kind {
            Consequence::BileLeak => BILE_HU,
            _ => BLOOD_HU,
        }
    }
}

/// What the ultrasound draws of a moment's consequences.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ConsequenceScene {
    /// Haematomas and bile leaks: soft tissue inside one echoes as blood or bile; the first
    /// that holds a sample wins.
    pub collections: Vec<FluidCollection>,
    /// The lungs with air in their pleural space: their surface no longer slides under the chest
    /// wall (`ultrasound::acoustic::PLEURA_SCATTER`).
    pub air_in_pleura: Vec<LabelId>,
}

impl ConsequenceScene {
    pub fn of_sites(sites: &[Site]) -> ConsequenceScene {
        let mut air_in_pleura: Vec<LabelId> = sites
            .iter()
            .filter(|s| s.volume_ml > 0.0 && s.kind.consequence() == Consequence::Pneumothorax)
            .map(|s| s.label)
            .collect();
        air_in_pleura.sort_unstable();
        air_in_pleura.dedup();
        ConsequenceScene {
            collections: fluid_collections(sites),
            air_in_pleura,
        }
    }

    /// Whether lung `label` has air in its pleural space.
    #[inline]
    pub fn air_in_pleura_of(&self, label: LabelId) -> bool {
        self.air_in_pleura.contains(&label)
    }
}

/// The radius of a sphere of `volume_ml`: r = ∛(3V / 4π), V in mm³.
pub fn sphere_radius_mm(volume_ml: f64) -> f64 {
    (3.0 * volume_ml * 1000.0 / (4.0 * std::f64::consts::PI)).cbrt()
}

/// The fluid collections of the sites that have leaked (haematomas and bile leaks, in the order
/// they began).
pub fn fluid_collections(sites: &[Site]) -> Vec<FluidCollection> {
    sites
        .iter()
        .filter(|s| s.volume_ml > 0.0 && s.kind.consequence() != Consequence::Pneumothorax)
        .map(|s| FluidCollection {
            kind: s.kind.consequence(),
            centre_mm: s.site_mm.as_vec3(),
            radius_mm: sphere_radius_mm(s.volume_ml) as f32,
        })
        .collect()
}

/// The change of μ (per mm) the sites make to CT voxels, for the X-ray's overlay: fluid
/// collections and pneumothoraces. Voxels may repeat (their changes add).
pub fn xray_voxels(atlas: &PunctureAtlas, sites: &[Site]) -> Vec<([usize; 3], f32)> {
    let mut out = Vec::new();
    for c in fluid_collections(sites) {
        collection_voxels(atlas, &c, &mut out);
    }
    // One pleural space per punctured lung: its air is all its sites' together.
    let mut lungs: BTreeMap<LabelId, f64> = BTreeMap::new();
    for s in sites
        .iter()
        .filter(|s| s.kind.consequence() == Consequence::Pneumothorax)
    {
        *lungs.entry(s.label).or_default() += s.volume_ml;
    }
    for (label, volume_ml) in lungs {
        if volume_ml > 0.0 {
            pneumothorax_voxels(atlas, label, volume_ml, &mut out);
        }
    }
    out
}

/// μ per mm of a CT value.
fn mu_of(hu: f32) -> f32 {
    MU_WATER_PER_MM / 1000.0 * water_relative(hu)
}

fn collection_voxels(atlas: &PunctureAtlas, c: &FluidCollection, out: &mut Vec<([usize; 3], f32)>) {
    let ct = atlas.ct();
    let grid = ct.grid();
    for v in voxels_within(atlas, c.centre_mm.as_dvec3(), f64::from(c.radius_mm)) {
        let hu = ct.data()[grid.linear(v[0], v[1], v[2])];
        if (COLLECTION_MIN_HU..COLLECTION_MAX_HU).contains(&hu) {
            out.push((v, mu_of(c.hu()) - mu_of(hu)));
        }
    }
}

/// The voxels whose centres lie within `radius_mm` of `centre_mm`, in index order.
fn voxels_within(atlas: &PunctureAtlas, centre_mm: DVec3, radius_mm: f64) -> Vec<[usize; 3]> {
    let grid = atlas.ct().grid();
    let dims = grid.dims();
    let c = grid.world_to_index(centre_mm);
    let reach = radius_mm / grid.spacing_mm().into_iter().fold(f64::INFINITY, f64::min);
    let range = |a: usize| {
        let lo = (c[a] - reach).floor().max(0.0) as usize;
        let hi = ((c[a] + reach).ceil().max(0.0) as usize).min(dims[a].saturating_sub(1));
        lo..=hi
    };
    let mut out = Vec::new();
    if !c.is_finite() {
        return out;
    }
    for k in range(2) {
        for j in range(1) {
            for i in range(0) {
                if grid.voxel_to_world(i, j, k).distance(centre_mm) <= radius_mm {
                    out.push([i, j, k]);
                }
            }
        }
    }
    out
}

/// Air for `volume_ml` in the outer layers of lung `label`, and the retracted lung's tissue on
/// the [`PLEURAL_LINE_LAYERS`] beneath.
fn pneumothorax_voxels(atlas: &PunctureAtlas, label: LabelId, volume_ml: f64, out: &mut Vec<([usize; 3], f32)>) {
    let labels = atlas.partial_labels();
    let grid = labels.grid();
    let dims = grid.dims();
    let Some((lo, hi)) = bounding_box(labels.data(), dims, label) else {
        return;
    };
    let box_dims = [hi[0] - lo[0] + 1, hi[1] - lo[1] + 1, hi[2] - lo[2] + 1];
    let at = |b: usize| {
        let (i, j, k) = (
            b % box_dims[0],
            (b / box_dims[0]) % box_dims[1],
            b / (box_dims[0] * box_dims[1]),
        );
        [lo[0] + i, lo[1] + j, lo[2] + k]
    };
    let inside: Vec<bool> = (0..box_dims.iter().product())
        .map(|b| {
            let v = at(b);
            labels.data()[grid.linear(v[0], v[1], v[2])] == label
        })
        .collect();
    let voxel_mm3: f64 = grid.spacing_mm().iter().product();
    let ct = atlas.ct().data();
    let mut left_mm3 = volume_ml * 1000.0;
    let mut removed = 0.0f32;
    let mut beneath: Vec<usize> = Vec::new();
    let mut line_layers = 0;
    for layer in Layers::new(&inside, box_dims) {
        if left_mm3 > 0.0 {
            let layer_mm3 = layer.len() as f64 * voxel_mm3;
            let fraction = (left_mm3 / layer_mm3).min(1.0) as f32;
            left_mm3 -= layer_mm3;
            for &b in &layer {
                let v = at(b);
                let mu = fraction * mu_of(ct[grid.linear(v[0], v[1], v[2])]);
                out.push((v, -mu));
                removed += mu;
            }
        } else {
            beneath.extend(layer);
            line_layers += 1;
            if line_layers == PLEURAL_LINE_LAYERS {
                break;
            }
        }
    }
    if !beneath.is_empty() {
        let each = removed / beneath.len() as f32;
        out.extend(beneath.into_iter().map(|b| (at(b), each)));
    }
}

/// The first and last voxel index per axis of `label`'s voxels (`None`: it has none).
fn bounding_box(data: &[LabelId], dims: [usize; 3], label: LabelId) -> Option<([usize; 3], [usize; 3])> {
    let mut lo = [usize::MAX; 3];
    let mut hi = [0; 3];
    for (n, _) in data.iter().enumerate().filter(|(_, l)| **l == label) {
        let v = [n % dims[0], (n / dims[0]) % dims[1], n / (dims[0] * dims[1])];
        for a in 0..3 {
            lo[a] = lo[a].min(v[a]);
            hi[a] = hi[a].max(v[a]);
        }
    }
    (lo[0] != usize::MAX).then_some((lo, hi))
}

/// A region's voxels (`inside`, on a box, x fastest) in layers by their 6-connected steps from
/// its surface: layer 0 has a neighbour outside the region or the box, layer n + 1 the unvisited
/// region voxels beside layer n. Computed one layer at a time, as far as asked.
struct Layers<'a> {
    inside: &'a [bool],
    dims: [usize; 3],
    seen: Vec<bool>,
    current: Vec<usize>,
}

impl<'a> Layers<'a> {
    fn new(inside: &'a [bool], dims: [usize; 3]) -> Layers<'a> {
        let mut layers = Layers {
            inside,
            dims,
            seen: inside.iter().map(|i| !i).collect(),
            current: Vec::new(),
        };
        let surface: Vec<usize> = (0..inside.len())
            .filter(|&b| inside[b] && layers.neighbours(b).iter().any(|n| n.is_none_or(|n| !inside[n])))
            .collect();
        for &b in &surface {
            layers.seen[b] = true;
        }
        layers.current = surface;
        layers
    }

    /// The six neighbours of box voxel `b` (`None`: beyond the box).
    fn neighbours(&self, b: usize) -> [Option<usize>; 6] {
        let d = self.dims;
        let v = [b % d[0], (b / d[0]) % d[1], b / (d[0] * d[1])];
        let stride = [1, d[0], d[0] * d[1]];
        let mut n = [None; 6];
        for a in 0..3 {
            n[2 * a] = (v[a] > 0).then(|| b - stride[a]);
            n[2 * a + 1] = (v[a] + 1 < d[a]).then(|| b + stride[a]);
        }
        n
    }
}

impl Iterator for Layers<'_> {
    type Item = Vec<usize>;

    fn next(&mut self) -> Option<Vec<usize>> {
        if self.current.is_empty() {
            return None;
        }
        let mut next = Vec::new();
        for &b in &self.current {
            for n in self.neighbours(b).into_iter().flatten() {
                if self.inside[n] && !self.seen[n] {
                    self.seen[n] = true;
                    next.push(n);
                }
            }
        }
        Some(std::mem::replace(&mut self.current, next))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_sphere_holds_its_volume() {
        let r = sphere_radius_mm(8.0);
        let v_ml = 4.0 / 3.0 * std::f64::consts::PI * r * r * r / 1000.0;
        assert!((v_ml - 8.0).abs() < 1e-9);
        assert!((r - 12.4).abs() < 0.1, "{r}");
    }

    #[test]
    fn layers_peel_a_cube_from_its_faces_inwards() {
        let dims = [7, 7, 7];
        let inside: Vec<bool> = (0..343)
            .map(|b: usize| [b % 7, (b / 7) % 7, b / 49].iter().all(|&c| (1..6).contains(&c)))
            .collect();
        let sizes: Vec<usize> = Layers::new(&inside, dims).map(|l| l.len()).collect();
        assert_eq!(sizes, vec![125 - 27, 27 - 1, 1]);
        // A region filling its box: the box's faces are its surface.
        let full = vec![true; 27];
        let sizes: Vec<usize> = Layers::new(&full, [3, 3, 3]).map(|l| l.len()).collect();
        assert_eq!(sizes, vec![26, 1]);
    }

    #[test]
    fn a_bounding_box_spans_a_labels_voxels() {
        let mut data = vec![0; 4 * 3 * 2];
        data[1 + 4 * (2 + 3)] = 7;
        data[3] = 7;
        assert_eq!(bounding_box(&data, [4, 3, 2], 7), Some(([1, 0, 0], [3, 2, 1])));
        assert_eq!(bounding_box(&data, [4, 3, 2], 8), None);
    }
}
