//! The scenario catalogue: every atlas this service knows, by content hash, with its scorer
//! (docs/api.md "Atlases"). Filled at start from the configured atlas directory and the atlases
//! published before (`DATA/atlases/<hash>/`); `POST /api/atlases` adds to it while the service
//! runs. Readers take an `Arc` of what they need and let go of the lock at once: no lock is held
//! across an `await` or a replay.

use std::collections::BTreeMap;
use std::sync::{Arc, RwLock};

use stylet_atlas::Atlas;
use stylet_scoring::Scorer;

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

/// One atlas of the catalogue.
pub struct Entry {
    pub atlas: Arc<Atlas>,
    pub scorer: Arc<Scorer>,
    pub origin: AtlasOrigin,
}

/// The catalogue (see the module doc).
#[derive(Default)]
pub struct Catalogue {
    entries: RwLock<BTreeMap<String, Arc<Entry>>>,
}

impl Catalogue {
    fn read(&self) -> std::sync::RwLockReadGuard<'_, BTreeMap<String, Arc<Entry>>> {
        // A panic while the lock was held cannot leave the map half-changed (inserts are one
        // call), so a poisoned lock is still sound to read.
        self.entries.read().unwrap_or_else(|e| e.into_inner())
    }

    /// The entry of `hash`.
    pub fn get(&self, hash: &str) -> Option<Arc<Entry>> {
        self.read().get(hash).cloned()
    }

    /// The scorer of the atlas of `hash`.
    pub fn scorer(&self, hash: &str) -> Option<Arc<Scorer>> {
        self.read().get(hash).map(|e| e.scorer.clone())
    }

    /// The atlas of `hash`.
    pub fn atlas(&self, hash: &str) -> Option<Arc<Atlas>> {
        self.read().get(hash).map(|e| e.atlas.clone())
    }

    pub fn contains(&self, hash: &str) -> bool {
        self.read().contains_key(hash)
    }

    pub fn len(&self) -> usize {
        self.read().len()
    }

    pub fn is_empty(&self) -> bool {
        self.read().is_empty()
    }

    /// Every entry, by content hash.
    pub fn entries(&self) -> Vec<(String, Arc<Entry>)> {
        self.read().iter().map(|(h, e)| (h.clone(), e.clone())).collect()
    }

    /// Adds an atlas under its content hash; an atlas already there is kept (same hash, same
    /// content) and `false` returned.
    pub fn insert(&self, atlas: Atlas, scorer: Scorer, origin: AtlasOrigin) -> bool {
        let hash = atlas.content_hash.clone();
        let mut map = self.entries.write().unwrap_or_else(|e| e.into_inner());
        if map.contains_key(&hash) {
            return false;
        }
        map.insert(
            hash,
            Arc::new(Entry {
                atlas: Arc::new(atlas),
                scorer: Arc::new(scorer),
                origin,
            }),
        );
        true
    }
}
