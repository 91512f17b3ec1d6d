//! The platforms' public keys (their JWKS at the registered keyset URL), fetched when a launch
//! needs them and kept for [`FRESH`]; a key id not in the kept set fetches the set again (a
//! platform rotating its key), at most once per [`REFETCH_AFTER`] so that tokens naming made-up
//! key ids cannot make the tool hammer the platform.

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

/// Kept key sets, by platform id.
#[derive(Default)]
pub struct KeySets {
    kept: Mutex<HashMap<String, (Instant, JwkSet)>>,
}

impl KeySets {
    /// The key `kid` of `platform`.
    pub async fn key(&self, platform: &LtiPlatform, kid: &str) -> Result<DecodingKey, KeyError> {
        // Not locked while fetching: a slow platform does not hold up the others' launches
        // (two launches at once may both fetch).
        let cached = self.kept.lock().await.get(&platform.id).cloned();
        let set = match cached {
            Some((at, set)) if at.elapsed() < FRESH && (set.find(kid).is_some() || at.elapsed() < REFETCH_AFTER) => set,
            _ => {
                let set = fetch(&platform.keyset_url).await?;
                self.kept
                    .lock()
                    .await
                    .insert(platform.id.clone(), (Instant::now(), set.clone()));
                set
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
