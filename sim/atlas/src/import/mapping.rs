//! The user's corrections to the default PTCD mapping of `auto.rs` (`stylet atlas new
//! --map CSV`, docs/atlas.md "New patients"): per structure name, the atlas label it becomes (by
//! id or name: `liver`, `portal vein`, `kidney`, …), `heuristic` (left to the heuristic h(x, d))
//! or `heuristic-bone` (left to the heuristic and a bone the window search must not cross).
//! Structures the file does not name keep the default.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use stylet_physics::LabelId;

use super::classes::ClassTable;
use crate::AtlasError;
use crate::manifest::LabelToml;

/// Largest mapping file read (bytes).
pub const MAX_MAPPING_BYTES: u64 = 256 * 1024;
/// Most rows in a mapping file.
pub const MAX_MAPPING_ROWS: usize = 4096;

/// Why a mapping file is refused as written (before its rows are resolved against the class
/// table and the labels); lines count from 1.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum MappingError {
    #[error("mapping file is empty: expected a header with `structure` and `label` columns")]
    Empty,
    /// The header lacks a column (`column` as the message names it).
    #[error("mapping header has no {column} column")]
    MissingColumn { column: &'static str },
    #[error("more than {MAX_MAPPING_ROWS} rows")]
    TooManyRows,
    #[error("line {line}: fewer columns than the header")]
    FewerColumns { line: usize },
    #[error("line {line}: structure and label must be 1 … 64 characters")]
    FieldLength { line: usize },
    #[error("line {line}: structure '{structure}' is listed twice")]
    Duplicate { line: usize, structure: String },
    #[error("mapping file lists no structure")]
    NoStructures,
}

/// What one structure becomes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mapped {
    /// This atlas label.
    Label(LabelId),
    /// Left to the heuristic.
    Heuristic,
    /// Left to the heuristic, and bone for the window search.
    HeuristicBone,
}

/// A mapping file as read: structure name → what the user wrote, with its line (resolved
/// against the scenario's labels by [`MappingOverride::resolve`]).
#[derive(Debug, Clone, PartialEq)]
pub struct MappingOverride {
    pub path: PathBuf,
    rows: BTreeMap<String, (usize, String)>,
}

impl MappingOverride {
    /// Reads a CSV with `structure` and `label` columns (header first; blank lines ignored).
    pub fn read_csv(path: &Path) -> Result<MappingOverride, AtlasError> {
        let text = crate::read_small_text(path, "mapping file", MAX_MAPPING_BYTES)?;
        Self::parse_csv(&text, path).map_err(|error| AtlasError::Mapping {
            path: path.to_path_buf(),
            error,
        })
    }

    pub fn parse_csv(text: &str, path: &Path) -> Result<MappingOverride, MappingError> {
        let mut lines = text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty());
        let Some((_, header)) = lines.next() else {
            return Err(MappingError::Empty);
        };
        let cols: Vec<&str> = header
            .split(',')
            .map(|c| c.trim().trim_start_matches('\u{feff}'))
            .collect();
        let find = |name: &str| cols.iter().position(|c| c.eq_ignore_ascii_case(name));
        let s_col = find("structure").ok_or(MappingError::MissingColumn { column: "`structure`" })?;
        let l_col = find("label").ok_or(MappingError::MissingColumn { column: "`label`" })?;
        let mut rows = BTreeMap::new();
        for (i, line) in lines {
            let n = i + 1;
            if rows.len() >= MAX_MAPPING_ROWS {
                return Err(MappingError::TooManyRows);
            }
            let fields: Vec<&str> = line.split(',').map(str::trim).collect();
            let (Some(&s), Some(&l)) = (fields.get(s_col), fields.get(l_col)) else {
                return Err(MappingError::FewerColumns { line: n });
            };
            if s.is_empty() || l.is_empty() || s.chars().count() > 64 || l.chars().count() > 64 {
                return Err(MappingError::FieldLength { line: n });
            }
            if rows.insert(s.to_string(), (n, l.to_string())).is_some() {
                return Err(MappingError::Duplicate {
                    line: n,
                    structure: s.to_string(),
                });
            }
        }
        if rows.is_empty() {
            return Err(MappingError::NoStructures);
        }
        Ok(MappingOverride {
            path: path.to_path_buf(),
            rows,
        })
    }

    /// Checks every row against the class table (a structure it names) and the labels a
    /// structure may become (`labels`: by id or name, case-insensitive; not the synthetic
    /// biliary tree's `reserved` ids), and returns the resolved mapping.
    pub fn resolve(
        &self,
        classes: &ClassTable,
        labels: &[LabelToml],
        reserved: &[LabelId],
    ) -> Result<BTreeMap<String, Mapped>, AtlasError> {
        let bad = |m: String| AtlasError::file(&self.path, m);
        let mut out = BTreeMap::new();
        for (structure, (line, value)) in &self.rows {
            if classes.id_of(structure).is_none() {
                return Err(bad(format!(
                    "line {line}: '{structure}' is not a structure of the class table ({})",
                    classes.source
                )));
            }
            let mapped = match value.to_ascii_lowercase().as_str() {
                "heuristic" => Mapped::Heuristic,
                "heuristic-bone" => Mapped::HeuristicBone,
                v => {
                    let found = labels
                        .iter()
                        .find(|l| l.id.to_string() == v || l.name.eq_ignore_ascii_case(v))
                        .filter(|l| !reserved.contains(&l.id));
                    let Some(l) = found else {
                        let names: Vec<String> = labels
                            .iter()
                            .filter(|l| !reserved.contains(&l.id))
                            .map(|l| format!("{} ({})", l.name, l.id))
                            .collect();
                        return Err(bad(format!(
                            "line {line}: '{value}' is not a label a structure can become: {}, heuristic or heuristic-bone",
                            names.join(", ")
                        )));
                    };
                    Mapped::Label(l.id)
                }
            };
            out.insert(structure.clone(), mapped);
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn labels() -> Vec<LabelToml> {
        let l = |id, name: &str| LabelToml {
            id,
            name: name.into(),
            role: "risk".into(),
            tissue: "viscus".into(),
            consequence: None,
        };
        vec![l(10, "liver"), l(11, "portal vein"), l(21, "right hepatic duct")]
    }

    #[test]
    fn rows_resolve_by_id_name_or_keyword() {
        let m = MappingOverride::parse_csv(
            "label,structure\n11,inferior_vena_cava\nPortal Vein,aorta\n\nheuristic,gallbladder\nheuristic-bone,trachea\n",
            Path::new("m.csv"),
        )
        .unwrap();
        let r = m.resolve(&ClassTable::totalsegmentator(), &labels(), &[21]).unwrap();
        assert_eq!(r["inferior_vena_cava"], Mapped::Label(11));
        assert_eq!(r["aorta"], Mapped::Label(11));
        assert_eq!(r["gallbladder"], Mapped::Heuristic);
        assert_eq!(r["trachea"], Mapped::HeuristicBone);
    }

    #[test]
    fn bad_rows_are_named() {
        let ts = ClassTable::totalsegmentator();
        let parse = |t: &str| MappingOverride::parse_csv(t, Path::new("m.csv"));
        let err = |t: &str| parse(t).unwrap_err().to_string();
        assert!(err("").contains("empty"));
        assert!(err("structure,role\nliver,10\n").contains("`label`"));
        assert!(err("structure,label\nliver,10\nliver,11\n").contains("line 3"));
        assert_eq!(
            parse("structure,label\nliver,10\nliver,11\n"),
            Err(MappingError::Duplicate {
                line: 3,
                structure: "liver".into()
            })
        );
        assert!(err("structure,label\nliver\n").contains("fewer columns"));
        let e = parse("structure,label\nlivr,10\n")
            .unwrap()
            .resolve(&ts, &labels(), &[21])
            .unwrap_err();
        assert!(e.to_string().contains("'livr' is not a structure"), "{e}");
        let e = parse("structure,label\nliver,brain\n")
            .unwrap()
            .resolve(&ts, &labels(), &[21])
            .unwrap_err();
        assert!(
            e.to_string().contains("'brain' is not a label") && e.to_string().contains("portal vein (11)"),
            "{e}"
        );
        // The synthetic target is not something a structure becomes.
        let e = parse("structure,label\nliver,21\n")
            .unwrap()
            .resolve(&ts, &labels(), &[21])
            .unwrap_err();
        assert!(e.to_string().contains("'21' is not a label"), "{e}");
    }
}
