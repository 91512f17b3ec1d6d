//! Label table and the labelling function l(x, d) (thesis §6.1.2; docs/atlas.md
//! "Labels and the heuristic").
//!
//! A partial segmentation p(x) labels only the key structures (0 = not segmented). Everything else
//! is classified at run time by the threshold heuristic h(x, d) of eq. 6.1.1, which also depends on
//! the current needle insertion depth d: low CT values deep inside the body are risk structures
//! (lung, bowel gas, cavities), near the surface they are skin.

use std::collections::BTreeMap;

use crate::PhysicsError;

/// A label number as stored in the partial label map. 0 means "not segmented".
pub type LabelId = u16;

/// What a label means for a puncture scenario.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Role {
    /// The structure the needle must reach (the right hepatic duct in PTCD).
    Target,
    /// Must not be touched (lung, vessels, gallbladder, cavities …).
    Risk,
    /// Hard tissue: the needle cannot pass; counted separately from risk hits.
    Bone,
    /// An organ the needle may traverse (liver, bile ducts that are not the target).
    Organ,
    /// Everything else (air, skin, fat, muscle, fascia).
    Neutral,
}

impl Role {
    pub const ALL: [Role; 5] = [Role::Target, Role::Risk, Role::Bone, Role::Organ, Role::Neutral];

    pub fn as_str(self) -> &'static str {
        match self {
            Role::Target => "target",
            Role::Risk => "risk",
            Role::Bone => "bone",
            Role::Organ => "organ",
            Role::Neutral => "neutral",
        }
    }

    pub fn parse(s: &str) -> Option<Role> {
        Role::ALL.into_iter().find(|r| r.as_str() == s)
    }
}

/// One row of the label table.
#[derive(Debug, Clone, PartialEq)]
pub struct Label {
    pub id: LabelId,
    pub name: String,
    pub role: Role,
    /// The property-tree node that holds this label's material parameters.
    pub tissue: String,
}

/// The five classes of the heuristic h(x, d), eq. 6.1.1.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum HeuristicClass {
    Air,
    Skin,
    /// Soft tissue and fat.
    Fat,
    Bone,
    /// Low CT value deeper than δ: lung, bowel gas, cavities.
    Risk,
}

impl HeuristicClass {
    pub const ALL: [HeuristicClass; 5] = [
        HeuristicClass::Air,
        HeuristicClass::Skin,
        HeuristicClass::Fat,
        HeuristicClass::Bone,
        HeuristicClass::Risk,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            HeuristicClass::Air => "air",
            HeuristicClass::Skin => "skin",
            HeuristicClass::Fat => "fat",
            HeuristicClass::Bone => "bone",
            HeuristicClass::Risk => "risk",
        }
    }
}

/// HU thresholds of the heuristic and the risk depth δ (eq. 6.1.1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Thresholds {
    /// t_air→skin: below it is air (at depth ≤ δ).
    pub air_skin_hu: f64,
    /// t_skin→fat: between t_air→skin and it, skin near the surface.
    pub skin_fat_hu: f64,
    /// t_fat→bone: at or above it, bone.
    pub fat_bone_hu: f64,
    /// δ: insertion depth beyond which low CT values are classified as risk structures.
    pub risk_depth_mm: f64,
}

impl Thresholds {
    /// Checks t_air→skin < t_skin→fat < t_fat→bone, all finite, and δ ≥ 0.
    pub fn validate(&self) -> Result<(), PhysicsError> {
        let all = [self.air_skin_hu, self.skin_fat_hu, self.fat_bone_hu, self.risk_depth_mm];
        if all.iter().any(|v| !v.is_finite()) {
            return Err(PhysicsError::InvalidThresholds(format!(
                "thresholds must be finite numbers: {self:?}"
            )));
        }
        if !(self.air_skin_hu < self.skin_fat_hu && self.skin_fat_hu < self.fat_bone_hu) {
            return Err(PhysicsError::InvalidThresholds(format!(
                "thresholds out of order: need air_skin ({}) < skin_fat ({}) < fat_bone ({}) HU",
                self.air_skin_hu, self.skin_fat_hu, self.fat_bone_hu
            )));
        }
        if self.risk_depth_mm < 0.0 {
            return Err(PhysicsError::InvalidThresholds(format!(
                "risk_depth_mm must be ≥ 0, got {}",
                self.risk_depth_mm
            )));
        }
        Ok(())
    }

    /// The heuristic h(x, d) of eq. 6.1.1 for a CT value `hu` = I(x) at insertion depth `depth_mm`.
    #[inline]
    pub fn classify(&self, hu: f64, depth_mm: f64) -> HeuristicClass {
        if hu < self.skin_fat_hu && depth_mm > self.risk_depth_mm {
            HeuristicClass::Risk
        } else if hu >= self.air_skin_hu && hu < self.skin_fat_hu {
            HeuristicClass::Skin
        } else if hu >= self.skin_fat_hu && hu < self.fat_bone_hu {
            HeuristicClass::Fat
        } else if hu >= self.fat_bone_hu {
            HeuristicClass::Bone
        } else {
            HeuristicClass::Air
        }
    }
}

/// Which label each heuristic class produces.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HeuristicLabels {
    pub air: LabelId,
    pub skin: LabelId,
    pub fat: LabelId,
    pub bone: LabelId,
    pub risk: LabelId,
}

impl HeuristicLabels {
    #[inline]
    pub fn label(&self, class: HeuristicClass) -> LabelId {
        match class {
            HeuristicClass::Air => self.air,
            HeuristicClass::Skin => self.skin,
            HeuristicClass::Fat => self.fat,
            HeuristicClass::Bone => self.bone,
            HeuristicClass::Risk => self.risk,
        }
    }
}

/// What people read for a label id the table does not name: words, never a bare class number.
/// (A validated atlas names every id its label map uses, so this only guards the fallbacks.)
/// Without an article, as texts put one before a structure's name ("entered the …").
pub const UNNAMED_STRUCTURE: &str = "unnamed structure";

/// The validated label table: unique ids ≥ 1, unique names, heuristic labels present.
#[derive(Debug, Clone, PartialEq)]
pub struct LabelTable {
    labels: Vec<Label>,
    /// Dense index: label id → position in `labels`, or `u16::MAX` for unknown ids.
    slot: Vec<u16>,
    heuristic: HeuristicLabels,
}

impl LabelTable {
    pub fn new(mut labels: Vec<Label>, heuristic: HeuristicLabels) -> Result<Self, PhysicsError> {
        labels.sort_by_key(|l| l.id);
        if labels.len() >= u16::MAX as usize {
            return Err(PhysicsError::InvalidLabels("too many labels".into()));
        }
        let mut names = BTreeMap::new();
        let mut slot = vec![u16::MAX; u16::MAX as usize + 1];
        for (pos, l) in labels.iter().enumerate() {
            if l.id == 0 {
                return Err(PhysicsError::InvalidLabels(format!(
                    "label '{}' uses id 0, which is reserved for 'not segmented'",
                    l.name
                )));
            }
            if l.name.trim().is_empty() {
                return Err(PhysicsError::InvalidLabels(format!("label {} has an empty name", l.id)));
            }
            if slot[l.id as usize] != u16::MAX {
                return Err(PhysicsError::InvalidLabels(format!(
                    "label id {} is defined twice",
                    l.id
                )));
            }
            if let Some(other) = names.insert(l.name.clone(), l.id) {
                return Err(PhysicsError::InvalidLabels(format!(
                    "label name '{}' is used by ids {} and {}",
                    l.name, other, l.id
                )));
            }
            slot[l.id as usize] = pos as u16;
        }
        let table = LabelTable {
            labels,
            slot,
            heuristic,
        };
        for class in HeuristicClass::ALL {
            let id = heuristic.label(class);
            if table.get(id).is_none() {
                return Err(PhysicsError::InvalidLabels(format!(
                    "heuristic class '{}' maps to label {} which is not in the label table",
                    class.as_str(),
                    id
                )));
            }
        }
        Ok(table)
    }

    pub fn labels(&self) -> &[Label] {
        &self.labels
    }
    pub fn heuristic(&self) -> &HeuristicLabels {
        &self.heuristic
    }

    #[inline]
    pub fn get(&self, id: LabelId) -> Option<&Label> {
        match self.slot[id as usize] {
            u16::MAX => None,
            pos => Some(&self.labels[pos as usize]),
        }
    }

    /// The name of label `id` for people: its name in the table, else [`UNNAMED_STRUCTURE`].
    pub fn name_of(&self, id: LabelId) -> &str {
        self.get(id).map_or(UNNAMED_STRUCTURE, |l| l.name.as_str())
    }

    /// Position of a label in [`LabelTable::labels`] (dense, for per-label tables).
    #[inline]
    pub fn position(&self, id: LabelId) -> Option<usize> {
        match self.slot[id as usize] {
            u16::MAX => None,
            pos => Some(pos as usize),
        }
    }

    pub fn by_name(&self, name: &str) -> Option<&Label> {
        self.labels.iter().find(|l| l.name == name)
    }

    /// Labels with a given role, in id order.
    pub fn with_role(&self, role: Role) -> impl Iterator<Item = &Label> {
        self.labels.iter().filter(move |l| l.role == role)
    }

    /// The labelling function l(x, d) of eq. 6.1.2 given p(x) and I(x).
    #[inline]
    pub fn label(&self, partial: LabelId, hu: f64, depth_mm: f64, thresholds: &Thresholds) -> LabelId {
        if partial != 0 {
            partial
        } else {
            self.heuristic.label(thresholds.classify(hu, depth_mm))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn t() -> Thresholds {
        Thresholds {
            air_skin_hu: -500.0,
            skin_fat_hu: -250.0,
            fat_bone_hu: 200.0,
            risk_depth_mm: 10.0,
        }
    }

    #[test]
    fn heuristic_follows_eq_6_1_1() {
        let t = t();
        use HeuristicClass::*;
        assert_eq!(t.classify(-1000.0, 0.0), Air);
        assert_eq!(t.classify(-500.0, 0.0), Skin);
        assert_eq!(t.classify(-250.1, 10.0), Skin);
        assert_eq!(t.classify(-250.0, 10.0), Fat);
        assert_eq!(t.classify(40.0, 50.0), Fat);
        assert_eq!(t.classify(200.0, 0.0), Bone);
        assert_eq!(t.classify(900.0, 80.0), Bone);
        // Low values deeper than δ are risk structures, air included (the interval is [−∞, t_skin→fat)).
        assert_eq!(t.classify(-850.0, 10.1), Risk);
        assert_eq!(t.classify(-1000.0, 30.0), Risk);
        assert_eq!(t.classify(-300.0, 30.0), Risk);
        assert_eq!(t.classify(-100.0, 30.0), Fat);
    }

    #[test]
    fn thresholds_must_be_ordered_and_finite() {
        let mut bad = t();
        bad.skin_fat_hu = -600.0;
        let e = bad.validate().unwrap_err().to_string();
        assert!(e.contains("out of order"), "{e}");
        let mut nan = t();
        nan.fat_bone_hu = f64::NAN;
        assert!(nan.validate().unwrap_err().to_string().contains("finite"));
        assert!(t().validate().is_ok());
    }

    fn lab(id: LabelId, name: &str, role: Role) -> Label {
        Label {
            id,
            name: name.into(),
            role,
            tissue: name.into(),
        }
    }

    #[test]
    fn partial_label_wins_over_heuristic() {
        let h = HeuristicLabels {
            air: 1,
            skin: 2,
            fat: 3,
            bone: 4,
            risk: 5,
        };
        let table = LabelTable::new(
            vec![
                lab(1, "air", Role::Neutral),
                lab(2, "skin", Role::Neutral),
                lab(3, "fat", Role::Neutral),
                lab(4, "bone", Role::Bone),
                lab(5, "cavity", Role::Risk),
                lab(10, "liver", Role::Organ),
            ],
            h,
        )
        .unwrap();
        assert_eq!(table.label(10, 900.0, 0.0, &t()), 10);
        assert_eq!(table.label(0, 900.0, 0.0, &t()), 4);
        assert_eq!(table.label(0, -900.0, 50.0, &t()), 5);
        assert_eq!(table.get(10).unwrap().name, "liver");
        assert!(table.get(11).is_none());
        // Names for people: a known label's name; an unknown one in words, not its number.
        assert_eq!(table.name_of(10), "liver");
        assert_eq!(table.name_of(118), "unnamed structure");
    }

    #[test]
    fn table_rejects_duplicates_and_missing_heuristic_labels() {
        let h = HeuristicLabels {
            air: 1,
            skin: 2,
            fat: 3,
            bone: 4,
            risk: 5,
        };
        let e = LabelTable::new(vec![lab(1, "a", Role::Neutral), lab(1, "b", Role::Neutral)], h).unwrap_err();
        assert!(e.to_string().contains("defined twice"));
        let e = LabelTable::new(vec![lab(1, "a", Role::Neutral)], h).unwrap_err();
        assert!(e.to_string().contains("heuristic class 'skin'"), "{e}");
        let e = LabelTable::new(vec![lab(0, "a", Role::Neutral)], h).unwrap_err();
        assert!(e.to_string().contains("reserved"));
    }
}
