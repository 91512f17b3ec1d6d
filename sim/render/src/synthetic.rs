//! Small synthetic atlases built from functions of position: what the tests of both renderers
//! (and quick experiments) draw when a real CT would be too slow or too opaque to reason about.
//! Labels: 1 air, 2 skin, 3 fat, 4 bone, [`RISK`] (risk), [`TARGET`] (target, tissue "tumour"
//! coloured [`TUMOUR_RGBA`]); heuristic thresholds air/skin −500, skin/fat −300, fat/bone 200 HU.

use stylet_physics::glam::DVec3;
use stylet_physics::{
    Affine, Grid, HeuristicLabels, Label, LabelTable, Param, ParamValue, PropertyTree, PunctureAtlas, Role, Thresholds,
    TissueSpec, Volume,
};

/// Label id of the target structure.
pub const TARGET: u16 = 10;
/// Label id of the risk structure.
pub const RISK: u16 = 5;
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
    let table = label_table(
        "bone",
        &[
            (RISK, "risk", Role::Risk, "body"),
            (TARGET, "target", Role::Target, "tumour"),
        ],
    );
    let params = body_params();
    let tissue = |name: &str, color| TissueSpec {
        name: name.into(),
        parent: Some("body".into()),
        params: Default::default(),
        color_rgba: Some(color),
    };
    let tree = PropertyTree::new(vec![
        TissueSpec {
            name: "body".into(),
            parent: None,
            params,
            color_rgba: Some([200, 120, 90, 255]),
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
        THRESHOLDS,
    )
    .expect("the synthetic atlas is consistent")
}

/// An atlas on `grid` with the given CT and partial labels (one value per voxel, x fastest):
/// the heuristic labels 1 air, 2 skin, 3 fat, 4 bone, 5 risk, then `extra` labels (id, name,
/// role), all of one tissue "body" without a colour; the thresholds of [`atlas`].
pub fn atlas_with(grid: Grid, ct: Vec<f32>, labels: Vec<u16>, extra: &[(u16, &str, Role)]) -> PunctureAtlas {
    let rest: Vec<(u16, &str, Role, &str)> = std::iter::once((RISK, "risk", Role::Risk, "body"))
        .chain(extra.iter().map(|&(id, name, role)| (id, name, role, "body")))
        .collect();
    let table = label_table("body", &rest);
    let tree = PropertyTree::new(vec![TissueSpec {
        name: "body".into(),
        parent: None,
        params: body_params(),
        color_rgba: None,
    }])
    .expect("the synthetic property tree is consistent");
    PunctureAtlas::new(
        Volume::new(grid, ct).expect("one value per voxel"),
        Volume::new(grid, labels).expect("one label per voxel"),
        table,
        tree,
        THRESHOLDS,
    )
    .expect("the synthetic atlas is consistent")
}

/// Labels 1 air, 2 skin, 3 fat (tissue "body"), 4 bone (tissue `bone_tissue`), then `rest`
/// (id, name, role, tissue), which must hold the heuristic's risk label [`RISK`].
fn label_table(bone_tissue: &str, rest: &[(u16, &str, Role, &str)]) -> LabelTable {
    let lab = |id, name: &str, role, tissue: &str| Label {
        id,
        name: name.into(),
        role,
        tissue: tissue.into(),
    };
    let mut all = vec![
        lab(1, "air", Role::Neutral, "body"),
        lab(2, "skin", Role::Neutral, "body"),
        lab(3, "fat", Role::Neutral, "body"),
        lab(4, "bone", Role::Bone, bone_tissue),
    ];
    all.extend(rest.iter().map(|&(id, name, role, tissue)| lab(id, name, role, tissue)));
    LabelTable::new(
        all,
        HeuristicLabels {
            air: 1,
            skin: 2,
            fat: 3,
            bone: 4,
            risk: RISK,
        },
    )
    .expect("the synthetic label table is consistent")
}

/// Every material parameter as one ramp over −100 … 50 HU.
fn body_params() -> std::collections::BTreeMap<Param, ParamValue> {
    Param::ALL
        .into_iter()
        .map(|p| {
            (
                p,
                ParamValue::PiecewiseLinear {
                    hu: vec![-100.0, 50.0],
                    value: vec![0.3, 0.8],
                },
            )
        })
        .collect()
}

/// Heuristic thresholds of every synthetic atlas.
const THRESHOLDS: Thresholds = Thresholds {
    air_skin_hu: -500.0,
    skin_fat_hu: -300.0,
    fat_bone_hu: 200.0,
    risk_depth_mm: 15.0,
};
