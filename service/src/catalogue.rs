//! The scenario catalogue: every atlas this service knows, by content hash (docs/api.md
//! "Atlases"). Filled at start from the configured atlas directory and the atlases published
//! before (`DATA/atlases/<hash>/`); `POST /api/atlases` adds to it while the service runs and
//! `DELETE /api/atlases/{hash}` withdraws from it.
//!
//! What every listing and upload check needs of an atlas (its name, scenarios, paths, grid) is
//! kept for every atlas: a [`Summary`], a few kilobytes. The loaded atlas and its scorer (the CT,
//! its distance maps, about 18 bytes a voxel: 1.2 GB for a 512² × 256 CT) are kept in a cache
//! bounded by bytes ([`Catalogue::new`]'s budget), the least recently used going first, and
//! loaded again on demand from the atlas' folder, whose derived-data cache makes a load cheap.
//! A withdrawn atlas takes no new sessions, but stays known, so that the sessions recorded on it
//! can still be read, replayed and scored.
//!
//! Readers take an `Arc` of what they need and let go of the locks at once: no lock is held
//! across an `await` or a replay; a load holds only its own atlas' load lock.

use std::collections::{BTreeMap, HashMap};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, RwLock};

use stylet_atlas::Atlas;
use stylet_atlas::manifest::ScenarioKind;
use stylet_scoring::{Rubric, Scorer};

/// Where an atlas came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AtlasOrigin {
    /// The `--atlases` directory given at start.
    Configured,
    /// Published through the API (now or at an earlier run).
    Published,
}

impl AtlasOrigin {
    pub fn as_str(self) -> &'static str {
        match self {
            AtlasOrigin::Configured => "configured",
            AtlasOrigin::Published => "published",
        }
    }
}

/// What the catalogue keeps of every atlas, loaded or not.
#[derive(Debug, Clone)]
pub struct Summary {
    pub name: String,
    pub description: String,
    /// Declared scenarios (empty: the atlas declares none and takes any name).
    pub scenarios: Vec<String>,
    /// The declared scenarios offered to trainees (kind training, not the scripted examples and
    /// grading fixtures), in the atlas' order.
    pub training: Vec<String>,
    /// Planned insertion paths `(name, description)`, the guided one first.
    pub paths: Vec<(String, String)>,
    /// The exercise each declared scenario practises.
    pub exercises: BTreeMap<String, stylet_scoring::Exercise>,
    /// Labelled structures.
    pub structures: usize,
    pub dims: [usize; 3],
    pub spacing_mm: [f64; 3],
    /// Memory the loaded atlas and its scorer take (estimated from their volumes).
    pub resident_bytes: u64,
}

impl Summary {
    fn of(atlas: &Atlas, scorer: &Scorer) -> Summary {
        let m = &atlas.manifest;
        let guided = atlas.guided_path().map(|p| p.name.as_str());
        let mut paths: Vec<&stylet_atlas::manifest::InsertionPath> = m.paths.iter().collect();
        paths.sort_by_key(|p| Some(p.name.as_str()) != guided);
        let grid = atlas.model.ct().grid();
        Summary {
            name: m.name.clone(),
            description: m.description.clone(),
            scenarios: scorer.scenario_names().to_vec(),
            training: m
                .scenarios
                .iter()
                .filter(|sc| sc.kind() == ScenarioKind::Training)
                .map(|sc| sc.name.clone())
                .collect(),
            exercises: scorer
                .scenario_names()
                .iter()
                .map(|n| (n.clone(), scorer.exercise_of(n)))
                .collect(),
            paths: paths
                .into_iter()
                .map(|p| (p.name.clone(), p.description.clone()))
                .collect(),
            structures: m.labels.len(),
            dims: grid.dims(),
            spacing_mm: grid.spacing_mm(),
            resident_bytes: resident_bytes(atlas),
        }
    }

    /// The exercise a scenario practises (a scenario the atlas does not declare: puncture).
    pub fn exercise_of(&self, scenario: &str) -> stylet_scoring::Exercise {
        self.exercises.get(scenario).copied().unwrap_or_default()
    }

    /// Whether sessions may be recorded in `scenario` on this atlas.
    pub fn knows_scenario(&self, scenario: &str) -> bool {
        self.scenarios.is_empty() || self.scenarios.iter().any(|s| s == scenario)
    }
}

/// Bytes per CT voxel of a loaded atlas and its scorer: the CT (f32), the partial labels (u16),
/// the skin and bone distance maps (f32 each) and the scorer's target distance map (f32).
const BYTES_PER_VOXEL: u64 = 4 + 2 + 4 + 4 + 4;
/// Bytes per voxel of a measured breathing field (three f32 components).
const BYTES_PER_FIELD_VOXEL: u64 = 12;

/// The memory a loaded atlas and its scorer take, from their volumes' sizes.
pub fn resident_bytes(atlas: &Atlas) -> u64 {
    let mut bytes = atlas.model.ct().data().len() as u64 * BYTES_PER_VOXEL;
    if let Some(stylet_physics::motion::AtlasMotion::Measured(m)) = atlas.model.breathing() {
        for field in [Some(&m.a1), m.a2.as_ref(), m.a3.as_ref()].into_iter().flatten() {
            bytes += field.grid().len() as u64 * BYTES_PER_FIELD_VOXEL;
        }
    }
    bytes
}

/// An atlas ready for a replay or a view: shared, so a scorer and a view hold one CT.
#[derive(Clone)]
pub struct Loaded {
    pub atlas: Arc<Atlas>,
    pub scorer: Arc<Scorer>,
}

/// One atlas of the catalogue.
pub struct Entry {
    pub summary: Summary,
    /// Its folder (loaded again from there when the cache let it go).
    pub dir: PathBuf,
    pub origin: AtlasOrigin,
    withdrawn: AtomicBool,
    /// Held while the atlas is being loaded, so that two requests do not load it twice.
    load_lock: Mutex<()>,
}

impl Entry {
    /// Withdrawn: no new sessions; the old ones stay replayable.
    pub fn withdrawn(&self) -> bool {
        self.withdrawn.load(Ordering::SeqCst)
    }
}

/// Why an atlas could not be had.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LoadError {
    #[error("the atlas {0} is not known to this server")]
    Unknown(String),
    #[error("the atlas {hash} cannot be loaded: {reason}")]
    Failed { hash: String, reason: String },
}

/// The loaded atlases kept (`V`: [`Loaded`]), least recently used first out.
struct Resident<V> {
    loaded: HashMap<String, (V, u64)>,
    /// Hashes from the least to the most recently used.
    order: Vec<String>,
    bytes: u64,
}

impl<V> Default for Resident<V> {
    fn default() -> Self {
        Resident {
            loaded: HashMap::new(),
            order: Vec::new(),
            bytes: 0,
        }
    }
}

impl<V> Resident<V> {
    fn touch(&mut self, hash: &str) {
        if let Some(i) = self.order.iter().position(|h| h == hash) {
            let h = self.order.remove(i);
            self.order.push(h);
        }
    }

    /// Keeps `loaded`, then lets the least recently used others go while over `budget` (the
    /// newest is kept even alone over it: it is being used).
    fn put(&mut self, hash: &str, loaded: V, bytes: u64, budget: u64) {
        if self.loaded.insert(hash.to_string(), (loaded, bytes)).is_none() {
            self.order.push(hash.to_string());
            self.bytes += bytes;
        } else {
            self.touch(hash);
        }
        while self.bytes > budget && self.order.len() > 1 {
            let oldest = self.order.remove(0);
            if let Some((_, b)) = self.loaded.remove(&oldest) {
                self.bytes -= b;
                tracing::info!(atlas = %oldest, bytes = b, "atlas let go of by the cache (loaded again when needed)");
            }
        }
    }
}

/// The catalogue (see the module doc).
pub struct Catalogue {
    entries: RwLock<BTreeMap<String, Arc<Entry>>>,
    resident: Mutex<Resident<Loaded>>,
    budget_bytes: u64,
}

impl Catalogue {
    /// A catalogue whose loaded atlases take at most `budget_bytes` (one more when a single one
    /// is larger).
    pub fn new(budget_bytes: u64) -> Catalogue {
        Catalogue {
            entries: RwLock::new(BTreeMap::new()),
            resident: Mutex::new(Resident::default()),
            budget_bytes,
        }
    }

    fn read(&self) -> std::sync::RwLockReadGuard<'_, BTreeMap<String, Arc<Entry>>> {
        // A panic while the lock was held cannot leave the map half-changed (inserts are one
        // call), so a poisoned lock is still sound to read.
        self.entries.read().unwrap_or_else(|e| e.into_inner())
    }

    fn resident(&self) -> std::sync::MutexGuard<'_, Resident<Loaded>> {
        self.resident.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The entry of `hash` (withdrawn ones too).
    pub fn get(&self, hash: &str) -> Option<Arc<Entry>> {
        self.read().get(hash).cloned()
    }

    pub fn contains(&self, hash: &str) -> bool {
        self.read().contains_key(hash)
    }

    /// Atlases that take sessions (not withdrawn).
    pub fn active_len(&self) -> usize {
        self.read().values().filter(|e| !e.withdrawn()).count()
    }

    /// Every entry, withdrawn ones too, by content hash.
    pub fn entries(&self) -> Vec<(String, Arc<Entry>)> {
        self.read().iter().map(|(h, e)| (h.clone(), e.clone())).collect()
    }

    /// Adds a loaded atlas under its content hash (kept in the cache while there is room); an
    /// atlas already there is kept (same hash, same content) and `false` returned.
    pub fn insert(&self, atlas: Atlas, scorer: Scorer, origin: AtlasOrigin, withdrawn: bool) -> bool {
        let hash = atlas.content_hash.clone();
        let entry = Entry {
            summary: Summary::of(&atlas, &scorer),
            dir: atlas.dir.clone(),
            origin,
            withdrawn: AtomicBool::new(withdrawn),
            load_lock: Mutex::new(()),
        };
        let bytes = entry.summary.resident_bytes;
        {
            let mut map = self.entries.write().unwrap_or_else(|e| e.into_inner());
            if map.contains_key(&hash) {
                return false;
            }
            map.insert(hash.clone(), Arc::new(entry));
        }
        let loaded = Loaded {
            atlas: Arc::new(atlas),
            scorer: Arc::new(scorer),
        };
        self.resident().put(&hash, loaded, bytes, self.budget_bytes);
        true
    }

    /// Marks the atlas of `hash` withdrawn (or not); `false` if it is not known.
    pub fn set_withdrawn(&self, hash: &str, withdrawn: bool) -> bool {
        match self.get(hash) {
            Some(e) => {
                e.withdrawn.store(withdrawn, Ordering::SeqCst);
                true
            }
            None => false,
        }
    }

    /// The atlas of `hash` and its scorer: from the cache, else loaded from its folder (on this
    /// thread: call it where blocking is allowed, or use [`Catalogue::loaded`]).
    pub fn load_blocking(&self, hash: &str) -> Result<Loaded, LoadError> {
        if let Some(l) = self.cached(hash) {
            return Ok(l);
        }
        let entry = self.get(hash).ok_or_else(|| LoadError::Unknown(hash.to_string()))?;
        let _loading = entry.load_lock.lock().unwrap_or_else(|e| e.into_inner());
        // Another request may have loaded it while this one waited.
        if let Some(l) = self.cached(hash) {
            return Ok(l);
        }
        let failed = |reason: String| LoadError::Failed {
            hash: hash.to_string(),
            reason,
        };
        let started = std::time::Instant::now();
        let atlas = stylet_atlas::load(&entry.dir).map_err(|e| failed(e.to_string()))?;
        if atlas.content_hash != hash {
            return Err(failed(format!(
                "its folder {} now holds other content ({})",
                entry.dir.display(),
                atlas.content_hash
            )));
        }
        let scorer = Scorer::new(&atlas, Rubric::default_rubric(), None).map_err(|e| failed(e.to_string()))?;
        let loaded = Loaded {
            atlas: Arc::new(atlas),
            scorer: Arc::new(scorer),
        };
        tracing::info!(atlas = %hash, ms = started.elapsed().as_secs_f64() * 1e3, "atlas loaded into the cache");
        self.resident()
            .put(hash, loaded.clone(), entry.summary.resident_bytes, self.budget_bytes);
        Ok(loaded)
    }

    /// [`Catalogue::load_blocking`] on a blocking thread.
    pub async fn loaded(self: &Arc<Self>, hash: &str) -> Result<Loaded, LoadError> {
        if let Some(l) = self.cached(hash) {
            super::telemetry::count(super::telemetry::ATLAS_CACHE, "hit");
            return Ok(l);
        }
        super::telemetry::count(super::telemetry::ATLAS_CACHE, "miss");
        let (me, h) = (self.clone(), hash.to_string());
        tokio::task::spawn_blocking(move || me.load_blocking(&h))
            .await
            .unwrap_or_else(|e| {
                Err(LoadError::Failed {
                    hash: hash.to_string(),
                    reason: e.to_string(),
                })
            })
    }

    /// The atlas of `hash` if it is in the cache now (marked as just used).
    pub fn cached(&self, hash: &str) -> Option<Loaded> {
        let mut r = self.resident();
        let loaded = r.loaded.get(hash).map(|(l, _)| l.clone());
        if loaded.is_some() {
            r.touch(hash);
        }
        loaded
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cache_lets_the_least_recently_used_go_first() {
        let mut r = Resident::<u32>::default();
        r.put("a", 1, 400, 1000);
        r.put("b", 2, 400, 1000);
        // "a" used again: "b" is now the least recently used.
        r.touch("a");
        r.put("c", 3, 400, 1000);
        assert!(r.loaded.contains_key("a") && r.loaded.contains_key("c"));
        assert!(!r.loaded.contains_key("b"));
        assert_eq!(r.bytes, 800);
        // One atlas larger than the budget is kept alone: it is being used.
        r.put("huge", 4, 5000, 1000);
        assert_eq!(r.order, ["huge"]);
        assert_eq!(r.bytes, 5000);
        // Putting one that is there already counts it once.
        r.put("huge", 4, 5000, 1000);
        assert_eq!(r.bytes, 5000);
    }
}
