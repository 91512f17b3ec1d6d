//! The derived-data cache of an atlas (docs/atlas.md "Derived-data cache"): the skin and bone
//! distance maps and the thresholds they were derived at, which cost most of a load, kept in
//! `.stylet-cache/` inside the atlas directory under the atlas' content hash.
//!
//! A cache file is trusted only when everything in it checks: magic, cache format, physics
//! version, content hash, grid dimensions, exact size, and a SHA-256 of each map. Anything else
//! (damaged, truncated, from another version or other content) is refused with the reason, and
//! the loader derives the maps again and rewrites the file. Writing goes through a temporary file
//! renamed into place; a cache that cannot be written costs the next load its time, nothing else.

use std::fs;
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::thread::JoinHandle;
use std::time::Duration;

use sha2::{Digest, Sha256};
use stylet_physics::{DistanceMaps, Grid, PHYSICS_VERSION, PhysicsError, Thresholds, Volume};

/// The cache folder inside an atlas directory.
pub const CACHE_DIR: &str = ".stylet-cache";
const MAGIC: &[u8; 16] = b"STYLET-DERIVED\0\0";
/// Bumped when the file layout changes.
const CACHE_FORMAT: u32 = 1;
/// Header bytes: magic, format, physics version, content hash (64 hex), dims (3 × u64),
/// thresholds (4 × f64), then the two 32-byte map digests.
const HEADER_BYTES: usize = 16 + 4 + 4 + 64 + 24 + 32 + 64;
/// A temporary file older than this is taken for the leftover of a crash and removed.
const STALE_PARTIAL: Duration = Duration::from_secs(600);

/// Why a cache file is not trusted, or not written. Never fails a load: the maps are derived
/// again, and [`CacheStatus`] tells why.
#[derive(Debug, thiserror::Error)]
pub enum CacheError {
    /// Reading, creating, writing or renaming a file failed; `context` says what and where.
    #[error("{context}: {error}")]
    Io { context: String, error: std::io::Error },
    #[error("{} is not a regular file", path.display())]
    NotAFile { path: PathBuf },
    /// Truncated or grown: the size does not fit the CT's grid.
    #[error("{actual} bytes where {expected} were expected")]
    WrongSize { actual: u64, expected: u64 },
    #[error("not a Stylet cache file (bad magic)")]
    BadMagic,
    #[error("cache format {found}, this Stylet writes {CACHE_FORMAT}")]
    OtherFormat { found: u32 },
    /// Derived by another physics version, whose maps may differ.
    #[error("derived by physics version {found}, this is {PHYSICS_VERSION}")]
    OtherPhysics { found: u32 },
    #[error("derived from other atlas content")]
    OtherContent,
    #[error("grid {cached:?} differs from the CT's {ct:?}")]
    OtherGrid { cached: Vec<u64>, ct: [usize; 3] },
    #[error("its thresholds are invalid: {0}")]
    InvalidThresholds(PhysicsError),
    #[error("the maps do not match their checksums (the file is damaged)")]
    Checksum,
    /// The maps read do not make volumes on the CT's grid.
    #[error(transparent)]
    Volume(PhysicsError),
    /// The CT on disk changed between its header read and its load.
    #[error("the CT changed while it was read")]
    CtChanged,
    /// The cache holds maps derived at thresholds other than the atlas' own.
    #[error("derived at other thresholds ({0:?})")]
    OtherThresholds(Thresholds),
    #[error("{hash:?} is not a content hash")]
    NotAContentHash { hash: String },
    #[error("the skin and bone maps have different dimensions")]
    MapDimensions,
}

fn io(context: impl Into<String>) -> impl FnOnce(std::io::Error) -> CacheError {
    let context = context.into();
    move |error| CacheError::Io { context, error }
}

/// What a load did with the cache, for `stylet atlas inspect` and the tests.
#[derive(Debug, Clone, PartialEq)]
pub enum CacheStatus {
    /// The distance maps and thresholds came from the cache.
    Hit,
    /// There was no cache for this content: derived, and written.
    Written,
    /// A cache file was there but was refused (why): derived again, and rewritten.
    Rebuilt { refused: String },
    /// Derived; the cache could not be written (why). The atlas works; the next load derives.
    NotWritten { error: String },
    /// The load was asked not to use the cache.
    Disabled,
}

impl CacheStatus {
    /// One line for people.
    pub fn describe(&self) -> String {
        match self {
            CacheStatus::Hit => "read from the cache".into(),
            CacheStatus::Written => "derived and cached".into(),
            CacheStatus::Rebuilt { refused } => format!("derived again (the cache was refused: {refused}) and cached"),
            CacheStatus::NotWritten { error } => format!("derived; the cache could not be written: {error}"),
            CacheStatus::Disabled => "derived (cache not used)".into(),
        }
    }
}

/// A load's cache status, settled or still being written.
///
/// A load that derives the maps hands the cache write to a thread of its own and returns: the
/// caller's work (a summary, a scoring run, the first frames) overlaps the write instead of
/// waiting for ≈ 100 MB to be hashed and written. [`Self::status`] waits for the write; so does
/// dropping the last clone of the atlas, so a process that ends normally leaves a whole cache
/// file (one killed mid-write leaves a temporary file, removed by a later write).
#[derive(Debug)]
pub struct CacheWork(Mutex<CacheState>);

#[derive(Debug)]
enum CacheState {
    Settled(CacheStatus),
    Writing(JoinHandle<CacheStatus>),
}

impl CacheWork {
    /// A status known at load time.
    pub(crate) fn settled(status: CacheStatus) -> Self {
        CacheWork(Mutex::new(CacheState::Settled(status)))
    }

    /// Runs `write` on a thread of its own. When no thread can be started the cache is not
    /// written (the next load derives again), which never fails the load.
    pub(crate) fn spawn(write: impl FnOnce() -> CacheStatus + Send + 'static) -> Self {
        match std::thread::Builder::new()
            .name("atlas-cache-write".into())
            .spawn(write)
        {
            Ok(handle) => CacheWork(Mutex::new(CacheState::Writing(handle))),
            Err(e) => CacheWork::settled(CacheStatus::NotWritten {
                error: format!("no thread to write it: {e}"),
            }),
        }
    }

    /// The status, once the write (if any) has finished.
    pub fn status(&self) -> CacheStatus {
        let mut state = self.0.lock().unwrap_or_else(|e| e.into_inner());
        let settled = match std::mem::replace(&mut *state, CacheState::Settled(CacheStatus::Disabled)) {
            CacheState::Writing(handle) => handle.join().unwrap_or_else(|_| CacheStatus::NotWritten {
                error: "the cache writer panicked".into(),
            }),
            CacheState::Settled(status) => status,
        };
        *state = CacheState::Settled(settled.clone());
        settled
    }
}

impl Drop for CacheWork {
    fn drop(&mut self) {
        // Waits for a write still running, so that it finishes before the process ends.
        let _ = self.status();
    }
}

/// Whether a load reads and writes the cache.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CacheMode {
    Use,
    Off,
}

/// The derived data of one atlas.
#[derive(Debug, Clone, PartialEq)]
pub struct Derived {
    pub thresholds: Thresholds,
    pub maps: DistanceMaps,
}

/// The cache file of the atlas in `dir` with this content hash.
pub fn cache_file(dir: &Path, content_hash: &str) -> PathBuf {
    let short: String = content_hash.chars().take(16).collect();
    dir.join(CACHE_DIR).join(format!("derived-{short}.bin"))
}

/// Reads the cache of `content_hash` for a CT on `grid`: `Ok(None)` when there is none,
/// `Err(reason)` when there is one that must not be trusted.
pub fn read(dir: &Path, content_hash: &str, grid: &Grid) -> Result<Option<Derived>, CacheError> {
    let path = cache_file(dir, content_hash);
    let meta = match fs::symlink_metadata(&path) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(io(format!("cannot read {}", path.display()))(e)),
    };
    if !meta.is_file() {
        return Err(CacheError::NotAFile { path });
    }
    let n = grid.len();
    let expected = HEADER_BYTES as u64 + 2 * 4 * n as u64;
    if meta.len() != expected {
        return Err(CacheError::WrongSize {
            actual: meta.len(),
            expected,
        });
    }
    let mut file = fs::File::open(&path).map_err(io("cannot open"))?;
    let mut header = [0u8; HEADER_BYTES];
    file.read_exact(&mut header).map_err(io("cannot read the header"))?;
    let h = parse_header(&header, content_hash, grid)?;
    let mut skin = vec![0f32; n];
    let mut bone = vec![0f32; n];
    for map in [&mut skin, &mut bone] {
        file.read_exact(bytemuck::cast_slice_mut(map.as_mut_slice()))
            .map_err(io("cannot read the maps"))?;
    }
    let (skin_digest, bone_digest) = rayon::join(|| digest(&skin), || digest(&bone));
    if skin_digest != h.skin_digest || bone_digest != h.bone_digest {
        return Err(CacheError::Checksum);
    }
    for map in [&mut skin, &mut bone] {
        from_little_endian(map);
    }
    let volume = |data| Volume::new(*grid, data).map_err(CacheError::Volume);
    Ok(Some(Derived {
        thresholds: h.thresholds,
        maps: DistanceMaps {
            skin_distance: volume(skin)?,
            bone_distance: volume(bone)?,
        },
    }))
}

struct Header {
    thresholds: Thresholds,
    skin_digest: [u8; 32],
    bone_digest: [u8; 32],
}

fn parse_header(b: &[u8; HEADER_BYTES], content_hash: &str, grid: &Grid) -> Result<Header, CacheError> {
    let mut at = 0usize;
    let mut take = |n: usize| {
        let s = &b[at..at + n];
        at += n;
        s
    };
    if take(16) != MAGIC {
        return Err(CacheError::BadMagic);
    }
    let u32_at = |s: &[u8]| u32::from_le_bytes(s.try_into().expect("4 bytes"));
    let format = u32_at(take(4));
    if format != CACHE_FORMAT {
        return Err(CacheError::OtherFormat { found: format });
    }
    let physics = u32_at(take(4));
    if physics != PHYSICS_VERSION {
        return Err(CacheError::OtherPhysics { found: physics });
    }
    if take(64) != content_hash.as_bytes() {
        return Err(CacheError::OtherContent);
    }
    let dims: Vec<u64> = (0..3)
        .map(|_| u64::from_le_bytes(take(8).try_into().expect("8 bytes")))
        .collect();
    if dims.iter().zip(grid.dims()).any(|(&a, b)| a != b as u64) {
        return Err(CacheError::OtherGrid {
            cached: dims,
            ct: grid.dims(),
        });
    }
    let mut f = || f64::from_le_bytes(take(8).try_into().expect("8 bytes"));
    let thresholds = Thresholds {
        air_skin_hu: f(),
        skin_fat_hu: f(),
        fat_bone_hu: f(),
        risk_depth_mm: f(),
    };
    thresholds.validate().map_err(CacheError::InvalidThresholds)?;
    let skin_digest = take(32).try_into().expect("32 bytes");
    let bone_digest = take(32).try_into().expect("32 bytes");
    Ok(Header {
        thresholds,
        skin_digest,
        bone_digest,
    })
}

/// The maps and thresholds to cache, borrowed from the atlas they were derived for.
#[derive(Debug, Clone, Copy)]
pub struct DerivedRef<'a> {
    pub thresholds: &'a Thresholds,
    pub skin_distance: &'a Volume<f32>,
    pub bone_distance: &'a Volume<f32>,
}

/// Writes the cache of `content_hash` (temporary file, then rename) and removes the caches of
/// other content and leftovers of crashed writes.
pub fn write(dir: &Path, content_hash: &str, derived: DerivedRef<'_>) -> Result<(), CacheError> {
    if content_hash.len() != 64 || !content_hash.bytes().all(|c| c.is_ascii_hexdigit()) {
        return Err(CacheError::NotAContentHash {
            hash: content_hash.to_string(),
        });
    }
    let folder = dir.join(CACHE_DIR);
    fs::create_dir_all(&folder).map_err(io(format!("cannot create {}", folder.display())))?;
    let path = cache_file(dir, content_hash);
    let tmp = folder.join(format!(
        ".{}.{}.{:?}.partial",
        path.file_name().expect("a file name").to_string_lossy(),
        std::process::id(),
        std::thread::current().id()
    ));
    let result = write_file(&tmp, content_hash, derived)
        .and_then(|()| fs::rename(&tmp, &path).map_err(io(format!("cannot move {} into place", path.display()))));
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result?;
    remove_others(&folder, &path);
    Ok(())
}

fn write_file(tmp: &Path, content_hash: &str, derived: DerivedRef<'_>) -> Result<(), CacheError> {
    let (skin, bone) = (derived.skin_distance.data(), derived.bone_distance.data());
    let dims = derived.skin_distance.grid().dims();
    if derived.bone_distance.grid().dims() != dims {
        return Err(CacheError::MapDimensions);
    }
    let t = derived.thresholds;
    let mut header = Vec::with_capacity(HEADER_BYTES);
    header.extend_from_slice(MAGIC);
    header.extend_from_slice(&CACHE_FORMAT.to_le_bytes());
    header.extend_from_slice(&PHYSICS_VERSION.to_le_bytes());
    header.extend_from_slice(content_hash.as_bytes());
    for d in dims {
        header.extend_from_slice(&(d as u64).to_le_bytes());
    }
    for v in [t.air_skin_hu, t.skin_fat_hu, t.fat_bone_hu, t.risk_depth_mm] {
        header.extend_from_slice(&v.to_le_bytes());
    }
    let digests_at = header.len() as u64;
    // The digests' place stays zero until they are known: the maps are hashed while written.
    header.resize(HEADER_BYTES, 0);
    let io = |error: std::io::Error| CacheError::Io {
        context: format!("cannot write {}", tmp.display()),
        error,
    };
    // One pass over each map: every chunk is hashed and written while it is in the cache.
    // Sequential on purpose: the write runs on its own thread beside the caller's work.
    let mut f = fs::File::create(tmp).map_err(io)?;
    f.write_all(&header).map_err(io)?;
    let mut digests = Vec::with_capacity(64);
    for map in [skin, bone] {
        let mut hash = Sha256::new();
        for chunk in map.chunks(CHUNK_VALUES) {
            let bytes = le_bytes(chunk);
            hash.update(&bytes);
            f.write_all(&bytes).map_err(io)?;
        }
        digests.extend_from_slice(&hash.finalize());
    }
    f.seek(SeekFrom::Start(digests_at)).map_err(io)?;
    f.write_all(&digests).map_err(io)?;
    // No fsync: a cache half on disk after a power cut fails its checksums and is rebuilt.
    f.flush().map_err(io)
}

/// Removes cache files of other content (the atlas changed) and temporary files of writes that
/// crashed; best effort.
fn remove_others(folder: &Path, keep: &Path) {
    let Ok(entries) = fs::read_dir(folder) else { return };
    for entry in entries.flatten() {
        let path = entry.path();
        let name = entry.file_name().to_string_lossy().into_owned();
        let stale_partial = name.ends_with(".partial")
            && entry
                .metadata()
                .and_then(|m| m.modified())
                .is_ok_and(|t| t.elapsed().is_ok_and(|age| age > STALE_PARTIAL));
        let other = name.starts_with("derived-") && name.ends_with(".bin") && path != keep;
        if stale_partial || other {
            let _ = fs::remove_file(&path);
        }
    }
}

/// SHA-256 of the map's little-endian bytes, as they are in memory after [`from_little_endian`].
fn digest(map: &[f32]) -> [u8; 32] {
    // `map` still holds the file's bytes.
    Sha256::digest(bytemuck::cast_slice::<f32, u8>(map)).into()
}

/// Values per chunk of a map written to the cache (256 KiB: hashed while still in the cache).
const CHUNK_VALUES: usize = 1 << 16;

/// The values' little-endian bytes (borrowed on little-endian machines).
fn le_bytes(values: &[f32]) -> std::borrow::Cow<'_, [u8]> {
    if cfg!(target_endian = "little") {
        std::borrow::Cow::Borrowed(bytemuck::cast_slice(values))
    } else {
        std::borrow::Cow::Owned(values.iter().flat_map(|v| v.to_le_bytes()).collect())
    }
}

fn from_little_endian(map: &mut [f32]) {
    if cfg!(target_endian = "big") {
        for v in map {
            *v = f32::from_bits(u32::from_le(v.to_bits()));
        }
    }
}
