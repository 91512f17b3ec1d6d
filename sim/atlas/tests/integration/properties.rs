//! Material parameters resolve through the PTCD property tree as docs/atlas.md describes
//! (thesis §6.1.3–6.1.4): a node's own value, else its nearest ancestor's; functions of HU are
//! evaluated at the CT value.

use stylet_atlas::manifest::{ScenarioFile, property_tree};
use stylet_physics::glam::DVec3;
use stylet_physics::{Param, ParamValue};

fn resolved(tissue: &str, p: Param) -> (ParamValue, String) {
    let s = ScenarioFile::ptcd();
    let tree = property_tree(&s.tissues).unwrap();
    let (v, at) = tree.resolve(tissue, p).unwrap();
    (v.clone(), at.to_string())
}

#[test]
fn values_come_from_the_nearest_definition() {
    // The target duct defines nothing but its colour: cutting threshold (a function of HU: the
    // wall resists, the bile does not) and friction come from bile_duct, stiffness and the
    // pre-puncture spring from liver, the quadratic spring from body.
    let duct = ParamValue::PiecewiseLinear {
        hu: vec![15.0, 40.0],
        value: vec![0.05, 0.6],
    };
    assert_eq!(
        resolved("target_duct", Param::CutThresholdN),
        (duct, "bile_duct".into())
    );
    assert_eq!(
        resolved("target_duct", Param::FrictionMaxNPerMm),
        (ParamValue::Scalar(0.005), "bile_duct".into())
    );
    assert_eq!(
        resolved("target_duct", Param::StiffnessNPerMm),
        (ParamValue::Scalar(0.05), "liver".into())
    );
    assert_eq!(
        resolved("target_duct", Param::CutSpringNPerMm),
        (ParamValue::Scalar(0.3), "liver".into())
    );
    assert_eq!(
        resolved("target_duct", Param::CutSpringNPerMm2),
        (ParamValue::Scalar(0.0), "body".into())
    );
    // Bone: threshold on the node, friction from hard_tissue.
    assert_eq!(
        resolved("bone", Param::CutThresholdN),
        (ParamValue::Scalar(500.0), "bone".into())
    );
    assert_eq!(
        resolved("bone", Param::FrictionMaxNPerMm),
        (ParamValue::Scalar(0.05), "hard_tissue".into())
    );
    // Portal vein inherits the vessel wall's threshold.
    assert_eq!(resolved("portal_vein", Param::CutThresholdN).1, "vessel");
    let s = ScenarioFile::ptcd();
    let tree = property_tree(&s.tissues).unwrap();
    assert_eq!(
        tree.lineage("target_duct").unwrap(),
        ["target_duct", "bile_duct", "liver", "soft_tissue", "body"]
    );
    assert_eq!(tree.resolve_color("portal_vein"), Some([200, 60, 150, 180]));
}

#[test]
fn functions_of_hu_are_evaluated_at_the_ct_value() {
    let (f, at) = resolved("soft_tissue", Param::CutThresholdN);
    assert_eq!(at, "soft_tissue");
    assert_eq!(f.eval(-100.0), 0.3); // fat
    assert_eq!(f.eval(50.0), 0.8); // muscle
    assert!((f.eval(-25.0) - 0.55).abs() < 1e-12); // halfway
    assert_eq!(f.eval(-500.0), 0.3); // clamped below
    assert_eq!(f.eval(400.0), 0.8); // clamped above
}

/// On a loaded atlas, l(x, d) picks the tree node and the HU picks the value (§6.1.4).
#[test]
fn parameters_at_positions_of_an_atlas() {
    let d = tempfile::tempdir().unwrap();
    crate::common::write_tiny(d.path());
    let a = stylet_atlas::load(d.path()).unwrap();
    let m = &a.model;
    // Liver (partial label 10) at x = 20: the liver's own threshold.
    let liver = DVec3::new(22.0, 10.0, 0.0);
    assert_eq!(m.label_at(liver, 0.0), 10);
    assert_eq!(m.param_at(liver, 0.0, Param::CutThresholdN), 0.2);
    // Target (label 21, bile at 10 HU): inherited from bile_duct, its function at the CT value.
    let target = DVec3::new(14.0, 2.0, 0.0);
    assert_eq!(m.label_at(target, 0.0), 21);
    assert_eq!(m.param_at(target, 0.0, Param::CutThresholdN), 0.05);
    // Unlabelled soft tissue at 45 HU: heuristic "fat" class → soft_tissue's function of HU.
    let soft = DVec3::new(-30.0, 14.0, 0.0);
    assert_eq!(m.label_at(soft, 0.0), 3);
    let expect = 0.3 + (45.0 + 100.0) / 150.0 * 0.5;
    assert!((m.param_at(soft, 0.0, Param::CutThresholdN) - expect).abs() < 1e-6);
    // Outside the body: air, no resistance.
    let air = DVec3::new(-46.0, -38.0, 0.0);
    assert_eq!(m.label_at(air, 0.0), 1);
    assert_eq!(m.param_at(air, 0.0, Param::CutThresholdN), 0.0);
    // The same air-like value deep inside counts as a risk structure (eq. 6.1.1, d > δ).
    assert_eq!(m.label_at(air, 20.0), 5);
}
