//! The platforms' public keys (their JWKS at the registered keyset URL), fetched when a launch
//! needs them and kept for [`FRESH`]; a key id not in the kept set fetches the set again (a
//! platform rotating its key), at most once per [`REFETCH_AFTER`] so that tokens naming made-up
//! key ids cannot make the tool hammer the platform. A failed fetch is kept as long, and a
//! platform's key set is fetched by one request at a time.

use std::collections::HashMap;
use std::time::{Duration, Instant};

use jsonwebtoken::DecodingKey;
use jsonwebtoken::jwk::JwkSet;
use tokio::sync::Mutex;

use crate::store::LtiPlatform;

/// How long a fetched key set is used without asking again.
pub const FRESH: Duration = Duration::from_secs(300);
/// The shortest time between two fetches of one platform's key set.
pub const REFETCH_AFTER: Duration = Duration::from_secs(10);
/// The largest key set taken.
pub const MAX_KEY_SET_BYTES: u64 = 256 * 1024;

/// Why no key was found for a token.
#[derive(Debug, Clone, thiserror::Error, PartialEq, Eq)]
pub enum KeyError {
    #[error("the platform's key set ({url}) could not be read: {why}")]
    Unreadable { url: String, why: String },
    #[error("the platform's key set does not hold the key '{kid}' this launch was signed with")]
    NotInKeySet { kid: String },
    #[error("the platform's key '{kid}' is not an RSA signing key")]
    Unusable { kid: String },
}

/// A platform's key set as last fetched, or why the last fetch failed.
#[derive(Clone)]
enum Kept {
    Set(JwkSet),
    Failed(KeyError),
}

/// Kept key sets, by platform id; one fetch per platform at a time.
#[derive(Default)]
pub struct KeySets {
    kept: Mutex<HashMap<String, (Instant, Kept)>>,
    fetching: Mutex<HashMap<String, std::sync::Arc<Mutex<()>>>>,
}

impl KeySets {
    /// The key `kid` of `platform`.
    pub async fn key(&self, platform: &LtiPlatform, kid: &str) -> Result<DecodingKey, KeyError> {
        let usable = |kept: &Option<(Instant, Kept)>| match kept {
            Some((at, Kept::Set(set)))
                if at.elapsed() < FRESH && (set.find(kid).is_some() || at.elapsed() < REFETCH_AFTER) =>
            {
                Some(Ok(set.clone()))
            }
            // A failed fetch is not repeated for REFETCH_AFTER.
            Some((at, Kept::Failed(e))) if at.elapsed() < REFETCH_AFTER => Some(Err(e.clone())),
            _ => None,
        };
        // (The cache's guard must not live through the match: the fetch below takes it again.)
        let cached = self.kept.lock().await.get(&platform.id).cloned();
        let set = match usable(&cached) {
            Some(found) => found?,
            None => {
                // One fetch at a time per platform (the others wait for it, then use what it
                // got); not under the cache's lock, so a slow platform holds up no other's.
                let gate = self
                    .fetching
                    .lock()
                    .await
                    .entry(platform.id.clone())
                    .or_default()
                    .clone();
                let _one = gate.lock().await;
                let cached = self.kept.lock().await.get(&platform.id).cloned();
                match usable(&cached) {
                    Some(found) => found?,
                    None => {
                        let fetched = fetch(&platform.keyset_url).await;
                        let kept = match &fetched {
                            Ok(set) => Kept::Set(set.clone()),
                            Err(e) => Kept::Failed(e.clone()),
                        };
                        self.kept
                            .lock()
                            .await
                            .insert(platform.id.clone(), (Instant::now(), kept));
                        fetched?
                    }
                }
            }
        };
        let jwk = set
            .find(kid)
            .ok_or_else(|| KeyError::NotInKeySet { kid: kid.to_string() })?;
        DecodingKey::from_jwk(jwk).map_err(|_| KeyError::Unusable { kid: kid.to_string() })
    }
}

/// GETs a key set (bounded in size and time).
async fn fetch(url: &str) -> Result<JwkSet, KeyError> {
    let owned = url.to_string();
    let text = tokio::task::spawn_blocking(move || {
        let r = super::http_agent().get(&owned).call().map_err(|e| e.to_string())?;
        super::read_bounded(r, MAX_KEY_SET_BYTES)
    })
    .await
    .map_err(|e| e.to_string())
    .and_then(|r| r);
    let unreadable = |why: String| KeyError::Unreadable {
        url: url.to_string(),
        why,
    };
    let text = text.map_err(unreadable)?;
    // Keys of kinds this crate does not know are skipped, not fatal (a platform may publish an
    // EC key beside its RSA one).
    let raw: serde_json::Value = serde_json::from_str(&text).map_err(|e| unreadable(format!("not JSON: {e}")))?;
    let keys = raw
        .get("keys")
        .and_then(|k| k.as_array())
        .ok_or_else(|| unreadable("no \"keys\" list".into()))?;
    Ok(JwkSet {
        keys: keys
            .iter()
            .filter_map(|k| serde_json::from_value(k.clone()).ok())
            .collect(),
    })
}
