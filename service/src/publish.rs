//! Publishing an atlas (`POST /api/atlases`; `stylet atlas publish`; docs/api.md "Atlases"): an
//! admin or instructor uploads a validated atlas as one tar archive; the service checks it as
//! fully as it can and only then keeps it, by content hash, in `DATA/atlases/<hash>/` and in the
//! catalogue, so that sessions on it are accepted and scored.
//!
//! Cheapest and most decisive first: who asks (before a byte of the body is read), the declared
//! size, one publication at a time, the catalogue's room; then the body is streamed to disk with
//! its limit; the archive is unpacked entry by entry (plain names, regular files, each kind of
//! file with its own size limit, extended headers bounded before they are read; measured
//! breathing motion under `motion/`, exactly the files atlas.toml names); the atlas is
//! loaded through the validating loader, its validation record must vouch for exactly this
//! content, and the server generates the example scripts of its guided path and runs them
//! itself. A refusal says why and leaves nothing behind.

use std::io::Read;
use std::path::{Path, PathBuf};

use axum::body::Body;
use axum::http::StatusCode;
use stylet_atlas::validation::{self, NotValidated, SCRIPTS_DIR, VALIDATION_FILE};
use stylet_atlas::{Atlas, store::MANIFEST_FILE};
use stylet_scoring::smoke::{self, SmokeOutcome};
use stylet_scoring::{Rubric, Scorer};
use tokio::io::AsyncWriteExt;

use super::error::{ApiError, err};
use super::intake::RatedBody;

/// The media type of an atlas upload.
pub const CONTENT_TYPE: &str = "application/x-tar";
/// Most entries an archive may hold (atlas.toml, validation.toml, two volumes, the scripts and
/// their folder, the measured breathing motion and its folder).
pub const MAX_ENTRIES: usize = 8 + validation::MAX_SCRIPTS + MAX_MOTION_FILES + 1;
/// The folder of an atlas' measured breathing motion (`stylet atlas attach-motion`).
pub const MOTION_DIR: &str = "motion";
/// Most files of measured motion: the fields a₁, a₂, a₃ and the surrogate signal.
const MAX_MOTION_FILES: usize = 4;
/// Largest `atlas.toml` accepted (the loader's own limit).
const MAX_MANIFEST_BYTES: u64 = 4 << 20;

/// Why an atlas was not published (422 unless said otherwise).
#[derive(Debug, thiserror::Error)]
pub enum Refusal {
    #[error("the archive is not valid: {0}")]
    Archive(String),
    #[error("the atlas is damaged: {0}")]
    Damaged(String),
    #[error("the atlas is not validated: {0}")]
    NotValidated(#[from] NotValidated),
    #[error("the server's own smoke test of the atlas failed: {0}")]
    SmokeFailed(String),
    #[error("the server cannot keep the atlas: {0}")]
    Storage(String),
    #[error("the atlas is too large for this server: {0}")]
    TooLarge(String),
}

impl From<Refusal> for ApiError {
    fn from(r: Refusal) -> ApiError {
        match r {
            Refusal::Storage(m) => {
                tracing::error!(error = %m, "publishing an atlas");
                err(
                    StatusCode::SERVICE_UNAVAILABLE,
                    "the server cannot store the atlas right now; try again later",
                )
            }
            r @ Refusal::TooLarge(_) => err(StatusCode::PAYLOAD_TOO_LARGE, r.to_string()),
            r => err(StatusCode::UNPROCESSABLE_ENTITY, r.to_string()),
        }
    }
}

/// A checked atlas, ready to keep.
pub struct Checked {
    pub atlas: Atlas,
    pub scorer: Scorer,
    pub smoke: Vec<SmokeOutcome>,
}

/// Streams `body` into `file`, refusing it (and stopping) past `limit` bytes or when it arrives
/// more slowly than `min_bytes_per_s` ([`crate::intake`]); returns its size.
pub async fn receive(body: Body, file: &Path, limit: u64, min_bytes_per_s: u64) -> Result<u64, ApiError> {
    let too_large = || {
        err(
            StatusCode::PAYLOAD_TOO_LARGE,
            format!("the atlas upload exceeds the limit of {limit} bytes"),
        )
    };
    let storage = |e: std::io::Error| super::intake::storage_error(file, &e);
    let mut out = tokio::fs::File::create(file).await.map_err(storage)?;
    out.set_max_buf_size(128 << 10);
    let mut body = RatedBody::new(body.into_data_stream(), min_bytes_per_s);
    while let Some(chunk) = body.next().await? {
        if body.received > limit {
            return Err(too_large());
        }
        out.write_all(&chunk).await.map_err(storage)?;
    }
    out.flush().await.map_err(storage)?;
    if body.received == 0 {
        return Err(err(
            StatusCode::BAD_REQUEST,
            "the request body is empty: send the atlas as a tar archive (stylet atlas publish does)",
        ));
    }
    Ok(body.received)
}

/// What an archive entry is, by its name.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Manifest,
    Record,
    Script,
    Volume,
    /// A measured breathing field (`motion/*.nii.gz`).
    MotionField,
    /// A surrogate breathing signal (`motion/*.csv`).
    MotionSignal,
    Folder,
}

/// Why an archive entry cannot be in an atlas upload, by its name (`shown`: quoted as [`shown`]
/// quotes it).
#[derive(Debug, thiserror::Error)]
enum EntryError {
    /// Not a name an atlas upload holds.
    #[error(
        "unexpected entry {shown}: an atlas upload holds {MANIFEST_FILE}, {VALIDATION_FILE}, the two NIfTI volumes atlas.toml names, {SCRIPTS_DIR}/*.txt and its measured breathing motion, {MOTION_DIR}/*.nii.gz and {MOTION_DIR}/*.csv"
    )]
    Unexpected { shown: String },
    /// A file under `scripts/` whose name is not a script's.
    #[error("entry {shown}: {}", bounded(&.source.to_string()))]
    ScriptName {
        shown: String,
        source: validation::RecordError,
    },
}

/// The kind of the entry named `name` (its path inside the archive), or the reason it cannot be
/// in an atlas upload.
fn kind_of(name: &str, is_dir: bool) -> Result<Kind, EntryError> {
    let name = name.trim_start_matches("./");
    let refuse = || EntryError::Unexpected { shown: shown(name) };
    if is_dir {
        return match name.trim_end_matches('/') {
            "" | "." | SCRIPTS_DIR | MOTION_DIR => Ok(Kind::Folder),
            _ => Err(refuse()),
        };
    }
    match name {
        MANIFEST_FILE => Ok(Kind::Manifest),
        VALIDATION_FILE => Ok(Kind::Record),
        _ => {
            if let Some(script) = name.strip_prefix(&format!("{SCRIPTS_DIR}/")) {
                validation::check_script_name(script).map_err(|source| EntryError::ScriptName {
                    shown: shown(name),
                    source,
                })?;
                return Ok(Kind::Script);
            }
            let plain = |n: &str| !n.is_empty() && !n.contains(['/', '\\', '\0']) && !n.starts_with('.');
            let nifti = |n: &str| n.ends_with(".nii") || n.ends_with(".nii.gz");
            if let Some(motion) = name.strip_prefix(&format!("{MOTION_DIR}/")) {
                return match (plain(motion), nifti(motion), motion.ends_with(".csv")) {
                    (true, true, _) => Ok(Kind::MotionField),
                    (true, _, true) => Ok(Kind::MotionSignal),
                    _ => Err(refuse()),
                };
            }
            if plain(name) && nifti(name) {
                Ok(Kind::Volume)
            } else {
                Err(refuse())
            }
        }
    }
}

/// Largest extended header (GNU long name, PAX record) accepted: the `tar` crate reads them whole
/// into memory.
const MAX_EXTENSION_BYTES: u64 = 4096;

/// Longest entry name quoted back in a refusal (characters): a refusal never echoes more of
/// what was sent.
const MAX_SHOWN_NAME_CHARS: usize = 120;

/// An entry's name as a refusal quotes it: escaped, and cut after [`MAX_SHOWN_NAME_CHARS`].
fn shown(name: &str) -> String {
    let count = name.chars().count();
    if count <= MAX_SHOWN_NAME_CHARS {
        return format!("{name:?}");
    }
    let head: String = name.chars().take(MAX_SHOWN_NAME_CHARS).collect();
    format!("{head:?}… ({count} characters)")
}

/// Walks the archive's 512-byte headers exactly as the `tar` crate will read them, without
/// reading any entry's data, and refuses what would make the crate read much, or read another
/// archive than this walk sees, before it reads anything:
/// - every entry's size must fit in what is left of the archive;
/// - extended headers (GNU long names, PAX records) hold at most [`MAX_EXTENSION_BYTES`];
/// - a PAX record's `size` must equal the header's size of the entry it describes (otherwise the
///   crate would take the PAX size, this walk the header's, and the two would part ways);
/// - kinds other than files, folders, long names and PAX records (links, sparse files with their
///   extension blocks, global PAX headers, …) are refused here.
fn check_headers(archive: &Path) -> Result<(), Refusal> {
    use std::io::{Seek, SeekFrom};
    let storage = |e: std::io::Error| Refusal::Storage(format!("{}: {e}", archive.display()));
    let bad = |m: String| Refusal::Archive(m);
    let mut f = std::fs::File::open(archive).map_err(storage)?;
    let len = f.metadata().map_err(storage)?.len();
    let mut at = 0u64;
    let mut block = [0u8; 512];
    // The size a PAX record gave the next entry that is not itself an extended header.
    let mut pax_size: Option<u64> = None;
    for _ in 0..4 * MAX_ENTRIES {
        if at + 512 > len {
            return Ok(());
        }
        f.seek(SeekFrom::Start(at)).map_err(storage)?;
        f.read_exact(&mut block).map_err(storage)?;
        if block.iter().all(|&b| b == 0) {
            return Ok(());
        }
        let header = tar::Header::from_byte_slice(&block);
        let not_tar = |e: std::io::Error| bad(format!("not a tar archive ({e})"));
        let sum: u32 = block[..148]
            .iter()
            .chain(&block[156..])
            .map(|&b| u32::from(b))
            .sum::<u32>()
            + 8 * 32;
        if header.cksum().map_err(not_tar)? != sum {
            return Err(bad("not a tar archive (a header's checksum does not match)".into()));
        }
        let size = header.entry_size().map_err(not_tar)?;
        let left = len - at - 512;
        if size > left {
            return Err(bad(format!(
                "an entry of {size} bytes runs past the end of the archive ({left} bytes left)"
            )));
        }
        let kind = header.entry_type();
        let extension = kind.is_gnu_longname() || kind.is_pax_local_extensions();
        if extension && size > MAX_EXTENSION_BYTES {
            return Err(bad(format!(
                "an extended header (long name or PAX record) of {size} bytes, more than the {MAX_EXTENSION_BYTES} accepted"
            )));
        }
        if kind.is_pax_local_extensions() {
            if pax_size.is_some() {
                return Err(bad("two PAX records describe one entry".into()));
            }
            let mut records = vec![0u8; size as usize];
            f.read_exact(&mut records).map_err(storage)?;
            for record in tar::PaxExtensions::new(&records) {
                let record = record.map_err(|e| bad(format!("a PAX record is malformed ({e})")))?;
                if record.key_bytes() == b"size" {
                    let value = record
                        .value()
                        .ok()
                        .and_then(|v| v.parse::<u64>().ok())
                        .ok_or_else(|| bad("a PAX size is not a number".into()))?;
                    pax_size = Some(value);
                }
            }
        } else if !extension {
            if !(kind.is_file() || kind.is_dir()) {
                let name = String::from_utf8_lossy(&header.path_bytes()).into_owned();
                return Err(bad(format!(
                    "entry {} is not a regular file (links and special files are refused)",
                    shown(&name)
                )));
            }
            if let Some(pax) = pax_size.take()
                && pax != size
            {
                return Err(bad(format!(
                    "a PAX record gives an entry {pax} bytes, its header {size}: the archive reads two ways"
                )));
            }
        }
        at = at
            .saturating_add(512)
            .saturating_add(size.div_ceil(512).saturating_mul(512));
    }
    Err(Refusal::Archive(format!("more than {MAX_ENTRIES} entries")))
}

/// Unpacks the tar archive `archive` into the new folder `out`: regular files with the names an
/// atlas has, each within its kind's limit; anything else (links, devices, paths that climb out,
/// unknown files, repeated names, too many entries) refuses the whole archive.
pub fn unpack(archive: &Path, out: &Path) -> Result<(), Refusal> {
    let storage = |e: std::io::Error| Refusal::Storage(format!("{}: {e}", out.display()));
    let bad = |m: String| Refusal::Archive(m);
    check_headers(archive)?;
    std::fs::create_dir(out).map_err(storage)?;
    std::fs::create_dir(out.join(SCRIPTS_DIR)).map_err(storage)?;
    std::fs::create_dir(out.join(MOTION_DIR)).map_err(storage)?;
    let file = std::fs::File::open(archive).map_err(storage)?;
    let mut tar = tar::Archive::new(std::io::BufReader::new(file));
    let entries = tar.entries().map_err(|e| bad(e.to_string()))?;
    let mut seen = std::collections::BTreeSet::new();
    let mut volumes = 0;
    let mut motion_files = 0;
    for (i, entry) in entries.enumerate() {
        if i >= MAX_ENTRIES {
            return Err(bad(format!("more than {MAX_ENTRIES} entries")));
        }
        let mut entry = entry.map_err(|e| match i {
            0 => bad(format!("not a tar archive ({e})")),
            _ => bad(e.to_string()),
        })?;
        let kind_byte = entry.header().entry_type();
        let name = String::from_utf8(entry.path_bytes().into_owned())
            .map_err(|_| bad("an entry's name is not UTF-8".into()))?;
        let is_dir = kind_byte.is_dir();
        if !(is_dir || kind_byte.is_file()) {
            return Err(bad(format!(
                "entry {} is not a regular file (links and special files are refused)",
                shown(&name)
            )));
        }
        let kind = kind_of(&name, is_dir).map_err(|e| bad(e.to_string()))?;
        if kind == Kind::Folder {
            continue;
        }
        let name = name.trim_start_matches("./").to_string();
        if !seen.insert(name.clone()) {
            return Err(bad(format!("entry {} appears twice", shown(&name))));
        }
        let limit = match kind {
            Kind::Manifest => MAX_MANIFEST_BYTES,
            Kind::Record => validation::MAX_RECORD_BYTES,
            Kind::Script => validation::MAX_SCRIPT_BYTES,
            Kind::MotionSignal => stylet_atlas::motion::MAX_SIGNAL_BYTES,
            // Volumes and fields: bounded by the upload's own limit.
            Kind::Volume | Kind::MotionField | Kind::Folder => u64::MAX,
        };
        if matches!(kind, Kind::MotionField | Kind::MotionSignal) {
            motion_files += 1;
            if motion_files > MAX_MOTION_FILES {
                return Err(bad(format!(
                    "more than {MAX_MOTION_FILES} files of breathing motion (a₁, a₂, a₃ and a signal)"
                )));
            }
        }
        if kind == Kind::Volume {
            volumes += 1;
            if volumes > 2 {
                return Err(bad(
                    "more than two NIfTI volumes (an atlas has a CT and a label map)".into()
                ));
            }
        }
        let size = entry.size();
        if size > limit {
            return Err(bad(format!(
                "{} is {size} bytes, more than the {limit} accepted",
                shown(&name)
            )));
        }
        let target = out.join(&name);
        let mut dest = std::fs::File::create_new(&target).map_err(storage)?;
        let copied = std::io::copy(&mut (&mut entry).take(size), &mut dest)
            .map_err(|e| bad(format!("{}: {e}", shown(&name))))?;
        if copied != size {
            return Err(bad(format!("{} is cut short ({copied} of {size} bytes)", shown(&name))));
        }
    }
    for required in [MANIFEST_FILE, VALIDATION_FILE] {
        if !seen.contains(required) {
            return Err(match required {
                VALIDATION_FILE => Refusal::NotValidated(NotValidated::Missing),
                _ => bad(format!("it has no {required}")),
            });
        }
    }
    Ok(())
}

/// The content hash of the unpacked atlas in `dir`, from its files (none is loaded).
pub fn content_of(dir: &Path) -> Result<String, Refusal> {
    let damaged = |e: stylet_atlas::AtlasError| Refusal::Damaged(strip_dir(&e.to_string(), dir));
    let manifest = stylet_atlas::store::read_manifest(dir).map_err(damaged)?;
    stylet_atlas::store::content_hash(dir, &manifest).map_err(damaged)
}

/// Checks the unpacked atlas in `dir` (see the module doc), running its smoke test in `work`.
/// The validation record first: it must vouch for exactly this content (hashed from the files),
/// before a volume is read.
pub fn check(dir: &Path, work: &Path, max_voxels: u64) -> Result<Checked, Refusal> {
    let hash = content_of(dir)?;
    let record = validation::read_record(dir)
        .map_err(|e| Refusal::Archive(strip_dir(&e.to_string(), dir)))?
        .ok_or(NotValidated::Missing)?;
    record.vouches_for(&hash)?;
    // The load's memory and its derived-data cache grow with the voxels: bounded from the
    // headers before any volume is read.
    let voxels = stylet_atlas::store::voxel_count(dir).map_err(|e| Refusal::Damaged(strip_dir(&e.to_string(), dir)))?;
    if voxels > max_voxels {
        return Err(Refusal::TooLarge(format!(
            "it holds {voxels} voxels (CT and breathing fields), more than the limit of {max_voxels} (stylet serve --max-atlas-voxels)"
        )));
    }
    let atlas = stylet_atlas::load(dir).map_err(|e| Refusal::Damaged(strip_dir(&e.to_string(), dir)))?;
    // Every motion file travels under the name atlas.toml gives it (the content hash covers it),
    // and nothing else does.
    let breathing = atlas.manifest.breathing_or_default();
    let motion_named = breathing.measured_files();
    if let Some(outside) = motion_named.iter().find(|n| !n.starts_with(&format!("{MOTION_DIR}/"))) {
        return Err(Refusal::Archive(format!(
            "atlas.toml names the breathing file {outside} outside {MOTION_DIR}/ (stylet atlas attach-motion puts them there)"
        )));
    }
    for entry in std::fs::read_dir(dir.join(MOTION_DIR)).map_err(|e| Refusal::Storage(e.to_string()))? {
        let name = entry.map_err(|e| Refusal::Storage(e.to_string()))?.file_name();
        let name = format!("{MOTION_DIR}/{}", name.to_string_lossy());
        if !motion_named.contains(&name.as_str()) {
            return Err(Refusal::Archive(format!(
                "{} is not a breathing file atlas.toml names",
                shown(&name)
            )));
        }
    }
    for entry in std::fs::read_dir(dir).map_err(|e| Refusal::Storage(e.to_string()))? {
        let name = entry.map_err(|e| Refusal::Storage(e.to_string()))?.file_name();
        let name = name.to_string_lossy();
        let named = [&atlas.manifest.volumes.ct, &atlas.manifest.volumes.labels]
            .iter()
            .any(|v| v.as_str() == name);
        if (name.ends_with(".nii") || name.ends_with(".nii.gz")) && !named {
            return Err(Refusal::Archive(format!(
                "{} is not one of the volumes atlas.toml names",
                shown(&name)
            )));
        }
    }
    if atlas.content_hash != hash {
        return Err(Refusal::Damaged("its files changed while it was being checked".into()));
    }
    // The record's scripts must be in the archive (the published folder is complete), but the
    // server runs its own: the example scripts of the guided path, generated from the atlas whose
    // content the hash covers, as `stylet atlas validate` does (bounded: a push of at most 400 mm
    // at 12 mm/s each).
    smoke::scripts_of(dir, &record).map_err(|e| {
        Refusal::Archive(format!(
            "a script the validation record names is missing or unreadable: {}",
            strip_dir(&e.to_string(), dir)
        ))
    })?;
    let scripts = smoke::smoke_scripts(&smoke::example_scripts(&atlas));
    if !scripts.iter().any(|s| s.expect == validation::Expect::Success) {
        return Err(Refusal::SmokeFailed(
            "the atlas has no planned path to generate a success script along".into(),
        ));
    }
    let scorer = Scorer::new(&atlas, Rubric::default_rubric(), None).map_err(|e| Refusal::Damaged(e.to_string()))?;
    std::fs::create_dir_all(work).map_err(|e| Refusal::Storage(e.to_string()))?;
    let outcomes = smoke::run_with(&atlas, &scorer, &scripts, work).map_err(|e| Refusal::SmokeFailed(e.to_string()))?;
    if let Some(failure) = smoke::first_failure(&outcomes) {
        return Err(Refusal::SmokeFailed(failure));
    }
    // The folder is renamed into place next: its derived-data cache must be written by then.
    let _ = atlas.cache_status();
    Ok(Checked {
        atlas,
        scorer,
        smoke: outcomes,
    })
}

/// A message of another part (a script name check) cut to a few hundred characters.
fn bounded(message: &str) -> String {
    super::error::bounded(message, 512)
}

/// Messages name files by the server's temporary folder; the publisher knows them by name.
fn strip_dir(message: &str, dir: &Path) -> String {
    message.replace(&format!("{}/", dir.display()), "")
}

/// The folder of the published atlases cannot be listed: the server does not start without them.
#[derive(Debug, thiserror::Error)]
#[error("{}: {source}", path.display())]
pub struct AtlasStoreError {
    pub path: PathBuf,
    pub source: std::io::Error,
}

/// Whether `name` is a content hash (a published atlas' folder name).
pub fn is_hash(name: &str) -> bool {
    name.len() == 64 && name.chars().all(|c| c.is_ascii_digit() || ('a'..='f').contains(&c))
}

/// The folders of the atlases published before, from `root` (`DATA/atlases`): each folder named
/// by a content hash with an atlas in it, that `is_published` (the database holds its
/// publication); a folder without its publication record is logged and left out (never served
/// unaudited). Leftovers of publications cut short (`.incoming-*`) are removed.
pub fn published_dirs(root: &Path, is_published: impl Fn(&str) -> bool) -> Result<Vec<PathBuf>, AtlasStoreError> {
    if !root.exists() {
        return Ok(Vec::new());
    }
    let unreadable = |source| AtlasStoreError {
        path: root.to_path_buf(),
        source,
    };
    let mut dirs: Vec<PathBuf> = Vec::new();
    for entry in std::fs::read_dir(root).map_err(unreadable)? {
        let path = entry.map_err(unreadable)?.path();
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        if name.starts_with(".incoming-") {
            let _ = std::fs::remove_dir_all(&path);
        } else if is_hash(&name) && path.join(MANIFEST_FILE).is_file() {
            if is_published(&name) {
                dirs.push(path);
            } else {
                tracing::warn!(dir = %path.display(), "a folder of the atlas store has no publication record; not served");
            }
        }
    }
    dirs.sort();
    Ok(dirs)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_archive_cannot_carry_a_derived_data_cache() {
        // The loader trusts a cache whose header and checksums agree; only this machine writes one.
        for (name, is_dir) in [
            (".stylet-cache", true),
            ("./.stylet-cache/", true),
            (".stylet-cache/derived-0123456789abcdef.bin", false),
            ("./.stylet-cache/derived-0123456789abcdef.bin", false),
        ] {
            assert!(kind_of(name, is_dir).is_err(), "{name} accepted");
        }
        assert!(matches!(kind_of("ct.nii.gz", false), Ok(Kind::Volume)));
    }
}
