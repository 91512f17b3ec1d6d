//! The pieces of small hand-built atlases: the label table, property tree and thresholds that
//! every test and benchmark atlas shares, so that a test states only its geometry (CT and
//! partial labels as functions of position) and the labels it adds.
//!
//! Labels 1 air, 2 skin, 3 fat, 4 bone and [`RISK`] are the heuristic's (docs/atlas.md "Labels");
//! thresholds air/skin −500, skin/fat −300, fat/bone 200 HU, risk depth 15 mm.

use std::collections::BTreeMap;

use crate::{
    Grid, HeuristicLabels, Label, LabelId, LabelTable, Param, ParamValue, PhysicsError, PropertyTree, PunctureAtlas,
    Role, Thresholds, TissueSpec, Volume,
};

/// The heuristic's risk label (air cavities inside the body).
pub const RISK: LabelId = 5;

/// The heuristic thresholds of every synthetic atlas.
pub const THRESHOLDS: Thresholds = Thresholds {
    air_skin_hu: -500.0,
    skin_fat_hu: -300.0,
    fat_bone_hu: 200.0,
    risk_depth_mm: 15.0,
};

/// Labels 1 air, 2 skin, 3 fat (tissue "body"), 4 bone (tissue `bone_tissue`), then `rest`
/// (id, name, role, tissue), which must hold the heuristic's risk label [`RISK`].
pub fn label_table(bone_tissue: &str, rest: &[(LabelId, &str, Role, &str)]) -> Result<LabelTable, PhysicsError> {
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
}

/// Every material parameter set to `value`.
pub fn every_param(value: ParamValue) -> BTreeMap<Param, ParamValue> {
    Param::ALL.into_iter().map(|p| (p, value.clone())).collect()
}

/// A ramp over −100 … 50 HU from 0.3 to 0.8: parameters that differ between fat and soft tissue.
pub fn body_ramp() -> ParamValue {
    ParamValue::PiecewiseLinear {
        hu: vec![-100.0, 50.0],
        value: vec![0.3, 0.8],
    }
}

/// The root tissue "body" without a colour, every parameter `value`.
pub fn body(value: ParamValue) -> TissueSpec {
    TissueSpec {
        name: "body".into(),
        parent: None,
        params: every_param(value),
        color_rgba: None,
        complication: None,
    }
}

/// An atlas on `grid` with the given CT and partial labels (one value per voxel, x fastest):
/// the heuristic labels, then `extra` labels (id, name, role), all of the one tissue "body"
/// whose parameters are `params`.
pub fn atlas_with(
    grid: Grid,
    ct: Vec<f32>,
    labels: Vec<LabelId>,
    extra: &[(LabelId, &str, Role)],
    params: ParamValue,
) -> Result<PunctureAtlas, PhysicsError> {
    let rest: Vec<(LabelId, &str, Role, &str)> = std::iter::once((RISK, "risk", Role::Risk, "body"))
        .chain(extra.iter().map(|&(id, name, role)| (id, name, role, "body")))
        .collect();
    PunctureAtlas::new(
        Volume::new(grid, ct)?,
        Volume::new(grid, labels)?,
        label_table("body", &rest)?,
        PropertyTree::new(vec![body(params)])?,
        THRESHOLDS,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Affine;
    use glam::DVec3;

    #[test]
    fn a_label_the_table_lacks_is_an_error_not_a_panic() {
        let g = Grid::new([4; 3], Affine::from_spacing([1.0; 3], DVec3::ZERO)).unwrap();
        let ok = atlas_with(
            g,
            vec![40.0; 64],
            vec![0; 64],
            &[(10, "liver", Role::Organ)],
            body_ramp(),
        );
        assert!(ok.is_ok());
        let unknown = atlas_with(
            g,
            vec![40.0; 64],
            vec![11; 64],
            &[(10, "liver", Role::Organ)],
            body_ramp(),
        );
        assert!(unknown.is_err());
        let short = atlas_with(g, vec![40.0; 63], vec![0; 64], &[], body_ramp());
        assert!(short.is_err());
        let twice = atlas_with(
            g,
            vec![40.0; 64],
            vec![0; 64],
            &[(RISK, "again", Role::Risk)],
            body_ramp(),
        );
        assert!(twice.is_err());
    }
}
