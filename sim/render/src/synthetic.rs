//! Small synthetic atlases built from functions of position: what the tests of both renderers
//! (and quick experiments) draw when a real CT would be too slow or too opaque to reason about.
//! Labels: 1 air, 2 skin, 3 fat, 4 bone, [`RISK`] (risk), [`TARGET`] (target, tissue "tumour"
//! coloured [`TUMOUR_RGBA`]); the label table, parameters and thresholds of
//! `stylet_physics::synthetic_atlas`.

use stylet_physics::glam::DVec3;
use stylet_physics::{Affine, Grid, PropertyTree, PunctureAtlas, Role, TissueSpec, Volume, synthetic_atlas};

/// Label id of the target structure.
pub const TARGET: u16 = 10;
/// Label id of the risk structure (the heuristic's).
pub const RISK: u16 = synthetic_atlas::RISK;
/// Property-tree colour of the target's tissue (its label colour, eq. 3.2.5).
pub const TUMOUR_RGBA: [u8; 4] = [0, 200, 40, 255];

/// An n³ atlas at `spacing` mm centred on the origin, CT and partial labels from functions of
/// the voxel centre (mm).
pub fn atlas(n: usize, spacing: f64, ct: impl Fn(DVec3) -> f32, partial: impl Fn(DVec3) -> u16) -> PunctureAtlas {
    let half = (n as f64 - 1.0) * spacing / 2.0;
    let g = Grid::new([n; 3], Affine::from_spacing([spacing; 3], DVec3::splat(-half)))
        .expect("a synthetic grid of positive size and spacing");
    let centre = |i: usize| {
        let [a, b, c] = g.unlinear(i);
        g.voxel_to_world(a, b, c)
    };
    let hu: Vec<f32> = (0..g.len()).map(|i| ct(centre(i))).collect();
    let labels: Vec<u16> = (0..g.len()).map(|i| partial(centre(i))).collect();
    let table = synthetic_atlas::label_table(
        "bone",
        &[
            (RISK, "risk", Role::Risk, "body"),
            (TARGET, "target", Role::Target, "tumour"),
        ],
    )
    .expect("the synthetic label table is consistent");
    let params = synthetic_atlas::every_param(synthetic_atlas::body_ramp());
    let tissue = |name: &str, color| TissueSpec {
        name: name.into(),
        parent: Some("body".into()),
        params: Default::default(),
        color_rgba: Some(color),
        complication: None,
    };
    let tree = PropertyTree::new(vec![
        TissueSpec {
            name: "body".into(),
            parent: None,
            params,
            color_rgba: Some([200, 120, 90, 255]),
            complication: None,
        },
        tissue("tumour", TUMOUR_RGBA),
        tissue("bone", [240, 240, 230, 255]),
    ])
    .expect("the synthetic property tree is consistent");
    PunctureAtlas::new(
        Volume::new(g, hu).expect("one value per voxel"),
        Volume::new(g, labels).expect("one label per voxel"),
        table,
        tree,
        synthetic_atlas::THRESHOLDS,
    )
    .expect("the synthetic atlas is consistent")
}

/// An atlas on `grid` with the given CT and partial labels (one value per voxel, x fastest):
/// the heuristic labels 1 air, 2 skin, 3 fat, 4 bone, 5 risk, then `extra` labels (id, name,
/// role), all of one tissue "body" without a colour; the thresholds of [`atlas`].
pub fn atlas_with(grid: Grid, ct: Vec<f32>, labels: Vec<u16>, extra: &[(u16, &str, Role)]) -> PunctureAtlas {
    synthetic_atlas::atlas_with(grid, ct, labels, extra, synthetic_atlas::body_ramp())
        .expect("the synthetic atlas is consistent")
}
