//! The validation record of an atlas (`validation.toml`, docs/atlas.md "Validation record"): which
//! example scripts in `scripts/` the scenario was smoke-tested with, what each must do, and what
//! it did, for the atlas of one content hash. `stylet atlas new` and `stylet atlas validate`
//! write it once every script passed; the scoring service refuses to publish an atlas without one
//! that matches its content, and runs the scripts again itself before it accepts the atlas.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::AtlasError;

/// The record's file name inside an atlas directory.
pub const VALIDATION_FILE: &str = "validation.toml";
/// The folder of the example scripts inside an atlas directory.
pub const SCRIPTS_DIR: &str = "scripts";
/// This Stylet writes and reads records of this version.
pub const VALIDATION_FORMAT_VERSION: u32 = 1;
/// Largest record read (bytes).
pub const MAX_RECORD_BYTES: u64 = 256 << 10;
/// Largest example script read (bytes).
pub const MAX_SCRIPT_BYTES: u64 = 256 << 10;
/// Most scripts one record may name.
pub const MAX_SCRIPTS: usize = 32;

/// What an example script must do when it is recorded and scored.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Expect {
    /// Reach the target and confirm it, with no risk hit and no bone contact.
    Success,
    /// Hit this risk structure (its label name) before any other.
    Hit { structure: String },
}

impl Expect {
    /// What the script must do, in words.
    pub fn describe(&self) -> String {
        match self {
            Expect::Success => "reaches and confirms the target, no risk hit, no bone contact".into(),
            Expect::Hit { structure } => format!("hits the {structure} first"),
        }
    }
}

/// One smoke-tested script.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SmokeEntry {
    /// File name inside `scripts/` (a plain `*.txt` name).
    pub script: String,
    pub expect: Expect,
    pub passed: bool,
    /// What the recorded, replayed and scored session did.
    pub got: String,
}

/// The record (see the module doc).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ValidationRecord {
    pub format_version: u32,
    /// The atlas content hash the scripts ran on (docs/atlas.md "Content hash").
    pub atlas_hash: String,
    /// The physics version that ran them.
    pub physics_version: u32,
    pub smoke: Vec<SmokeEntry>,
}

/// Why a validation record's text is refused (or a script name it may not name): a record that
/// fails these checks vouches for nothing, and a hostile one must not make Stylet read outside
/// `scripts/`.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RecordError {
    /// Not TOML of the record's format (the parser's message).
    #[error("{0}")]
    Syntax(String),
    #[error("format_version {found} is not supported (this Stylet reads version {VALIDATION_FORMAT_VERSION})")]
    UnsupportedVersion { found: u32 },
    #[error("atlas_hash must be 64 lower-case hexadecimal digits (a SHA-256)")]
    BadHash,
    #[error("it names {count} scripts, more than the {MAX_SCRIPTS} accepted")]
    TooManyScripts { count: usize },
    #[error("script name {name:?} is not a plain file name ending in .txt (letters, digits, '-', '_', '.')")]
    ScriptName { name: String },
    #[error("script {script} is named twice")]
    DuplicateScript { script: String },
    #[error("script {script}: a hit expectation needs a structure name")]
    HitWithoutStructure { script: String },
}

/// Why a record does not vouch for an atlas.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum NotValidated {
    #[error("it has no {VALIDATION_FILE}: run `stylet atlas validate DIR` (or make it with `stylet atlas new`)")]
    Missing,
    #[error(
        "its {VALIDATION_FILE} was written for atlas content {recorded}, but the atlas is now {actual}: it changed after it was validated; run `stylet atlas validate DIR` again"
    )]
    Stale { recorded: String, actual: String },
    #[error("its {VALIDATION_FILE} names no script that reaches the target (a `success` expectation)")]
    NoSuccessScript,
    #[error("its smoke test failed: scripts/{script} should: {expected}; got: {got}")]
    Failed {
        script: String,
        expected: String,
        got: String,
    },
}

impl ValidationRecord {
    /// Whether this record vouches for the atlas of content hash `actual`: written for it, with a
    /// success script, every script passed.
    pub fn vouches_for(&self, actual: &str) -> Result<(), NotValidated> {
        if self.atlas_hash != actual {
            return Err(NotValidated::Stale {
                recorded: self.atlas_hash.clone(),
                actual: actual.to_string(),
            });
        }
        if !self.smoke.iter().any(|s| s.expect == Expect::Success) {
            return Err(NotValidated::NoSuccessScript);
        }
        match self.smoke.iter().find(|s| !s.passed) {
            Some(s) => Err(NotValidated::Failed {
                script: s.script.clone(),
                expected: s.expect.describe(),
                got: s.got.clone(),
            }),
            None => Ok(()),
        }
    }
}

/// A script file name a record may name: a plain `*.txt` name of letters, digits, `-`, `_`, `.`.
pub fn check_script_name(name: &str) -> Result<(), RecordError> {
    let ok = name.len() <= 100
        && name.ends_with(".txt")
        && name.len() > 4
        && !name.starts_with('.')
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'));
    if ok {
        Ok(())
    } else {
        Err(RecordError::ScriptName { name: name.to_string() })
    }
}

/// Parses and checks a record's text: version, hash form, script names (unique, plain), count.
pub fn parse_record(text: &str) -> Result<ValidationRecord, RecordError> {
    let r: ValidationRecord =
        toml::from_str(text).map_err(|e| RecordError::Syntax(e.to_string().trim_end().to_string()))?;
    if r.format_version != VALIDATION_FORMAT_VERSION {
        return Err(RecordError::UnsupportedVersion {
            found: r.format_version,
        });
    }
    if r.atlas_hash.len() != 64
        || !r
            .atlas_hash
            .chars()
            .all(|c| c.is_ascii_hexdigit() && !c.is_ascii_uppercase())
    {
        return Err(RecordError::BadHash);
    }
    if r.smoke.len() > MAX_SCRIPTS {
        return Err(RecordError::TooManyScripts { count: r.smoke.len() });
    }
    let mut seen = std::collections::BTreeSet::new();
    for s in &r.smoke {
        check_script_name(&s.script)?;
        if !seen.insert(s.script.as_str()) {
            return Err(RecordError::DuplicateScript {
                script: s.script.clone(),
            });
        }
        if let Expect::Hit { structure } = &s.expect
            && structure.trim().is_empty()
        {
            return Err(RecordError::HitWithoutStructure {
                script: s.script.clone(),
            });
        }
    }
    Ok(r)
}

/// Reads `dir/validation.toml`; `Ok(None)` when there is none.
pub fn read_record(dir: &Path) -> Result<Option<ValidationRecord>, AtlasError> {
    let path = dir.join(VALIDATION_FILE);
    if !path.exists() {
        return Ok(None);
    }
    let text = crate::read_small_text(&path, "validation record", MAX_RECORD_BYTES)?;
    parse_record(&text)
        .map(Some)
        .map_err(|error| AtlasError::Record { path, error })
}

/// Writes `dir/validation.toml` beside its place and renames it into it.
pub fn write_record(dir: &Path, record: &ValidationRecord) -> Result<(), AtlasError> {
    let path = dir.join(VALIDATION_FILE);
    let text = toml::to_string_pretty(record).map_err(|e| AtlasError::file(&path, e.to_string()))?;
    let tmp = dir.join(format!(".{VALIDATION_FILE}.partial"));
    std::fs::write(&tmp, text).map_err(|e| AtlasError::file(&tmp, format!("cannot write: {e}")))?;
    std::fs::rename(&tmp, &path).map_err(|e| AtlasError::file(&path, format!("cannot move into place: {e}")))
}

/// Removes a record (an atlas re-validated that failed must not keep an old approval).
pub fn remove_record(dir: &Path) -> Result<(), AtlasError> {
    let path = dir.join(VALIDATION_FILE);
    match std::fs::remove_file(&path) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            Err(AtlasError::file(&path, format!("cannot remove: {e}")))
        }
        _ => Ok(()),
    }
}

/// Reads `dir/scripts/NAME` (a name [`check_script_name`] accepts), at most [`MAX_SCRIPT_BYTES`].
pub fn read_script(dir: &Path, name: &str) -> Result<String, AtlasError> {
    let path = dir.join(SCRIPTS_DIR).join(name);
    check_script_name(name).map_err(|error| AtlasError::Record {
        path: path.clone(),
        error,
    })?;
    crate::read_small_text(&path, "script", MAX_SCRIPT_BYTES)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record() -> ValidationRecord {
        ValidationRecord {
            format_version: VALIDATION_FORMAT_VERSION,
            atlas_hash: "ab".repeat(32),
            physics_version: 1,
            smoke: vec![
                SmokeEntry {
                    script: "success.txt".into(),
                    expect: Expect::Success,
                    passed: true,
                    got: "target reached true".into(),
                },
                SmokeEntry {
                    script: "risk-portal-vein.txt".into(),
                    expect: Expect::Hit {
                        structure: "portal vein".into(),
                    },
                    passed: true,
                    got: "risk hits [portal vein]".into(),
                },
            ],
        }
    }

    #[test]
    fn a_record_round_trips_through_its_file() {
        let dir = tempfile::tempdir().unwrap();
        assert_eq!(read_record(dir.path()).unwrap(), None);
        write_record(dir.path(), &record()).unwrap();
        assert_eq!(read_record(dir.path()).unwrap(), Some(record()));
        remove_record(dir.path()).unwrap();
        assert_eq!(read_record(dir.path()).unwrap(), None);
    }

    #[test]
    fn a_record_vouches_only_for_its_own_passing_atlas() {
        let r = record();
        assert_eq!(r.vouches_for(&"ab".repeat(32)), Ok(()));
        assert!(matches!(
            r.vouches_for(&"cd".repeat(32)),
            Err(NotValidated::Stale { .. })
        ));
        let mut failed = record();
        failed.smoke[1].passed = false;
        let e = failed.vouches_for(&"ab".repeat(32)).unwrap_err();
        assert!(
            e.to_string()
                .contains("scripts/risk-portal-vein.txt should: hits the portal vein first"),
            "{e}"
        );
        let mut no_success = record();
        no_success.smoke.remove(0);
        assert_eq!(
            no_success.vouches_for(&"ab".repeat(32)),
            Err(NotValidated::NoSuccessScript)
        );
    }

    #[test]
    fn hostile_records_are_refused_with_the_reason() {
        let text = toml::to_string(&record()).unwrap();
        for (bad, why) in [
            (
                text.replace("success.txt", "../etc/passwd.txt"),
                "not a plain file name",
            ),
            (text.replace("success.txt", "risk-portal-vein.txt"), "named twice"),
            (
                text.replace("format_version = 1", "format_version = 9"),
                "format_version 9",
            ),
            (text.replace(&"ab".repeat(32), "xyz"), "64 lower-case"),
            (text.replace("passed = true", "passed = \"yes\""), "invalid type"),
            (format!("extra = 1\n{text}"), "unknown field"),
            (format!("{text}\nextra = 1\n"), "unknown field"),
        ] {
            let e = parse_record(&bad).unwrap_err().to_string();
            assert!(e.contains(why), "{why}: {e}");
        }
    }
}
