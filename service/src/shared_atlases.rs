//! Published atlases among replicas. With object storage, a publication puts the atlas' files
//! into it (`atlases/<content hash>/…`) before its row commits; every other replica fetches them
//! into its own `DATA/atlases/<hash>/` when it first needs the atlas (an upload or a job on it)
//! or at its next catalogue sync, loads it and checks that its files still have the content hash
//! it was published with. A withdrawal at one replica reaches the others at the same sync.

use std::sync::Arc;

use super::AppState;
use super::catalogue::{AtlasOrigin, LoadError, Loaded};

/// How often a replica compares its catalogue with the database's publications.
pub const SYNC_EVERY: std::time::Duration = std::time::Duration::from_secs(30);

/// The atlas of `hash`, loaded; one published at another replica since this one started is
/// adopted first ([`adopt`]).
pub async fn loaded(state: &AppState, hash: &str) -> Result<Loaded, LoadError> {
    match state.catalogue.loaded(hash).await {
        Err(LoadError::Unknown(_)) if adopt(state, hash).await => state.catalogue.loaded(hash).await,
        other => other,
    }
}

/// Adds to the catalogue the atlas `hash` if the database records its publication and this
/// replica does not know it yet: fetched from the object storage (unless this data directory
/// has it), loaded, its content hash checked. Whether the catalogue has it now; what failed is
/// logged.
pub async fn adopt(state: &AppState, hash: &str) -> bool {
    if state.catalogue.get(hash).is_some() {
        return true;
    }
    if !super::publish::is_hash(hash) {
        return false;
    }
    let row = match state.store.atlas_rows().await {
        Ok(rows) => rows
            .into_iter()
            .find(|r| r.content_hash == hash && r.published_at.is_some()),
        Err(e) => {
            tracing::warn!(error = %e, "cannot read the atlas publications");
            return false;
        }
    };
    let Some(row) = row else {
        return false;
    };
    let max_bytes = state.config.limits.max_atlas_bytes.saturating_mul(4);
    let dir = match state.storage.fetch_folder(&format!("atlases/{hash}"), max_bytes).await {
        Ok(dir) => dir,
        Err(e) => {
            tracing::error!(atlas = %hash, error = %e, "a published atlas cannot be fetched from the storage");
            return false;
        }
    };
    let shown = dir.display().to_string();
    let loaded = tokio::task::spawn_blocking(move || super::load_atlas(&dir)).await;
    let (atlas, scorer) = match loaded {
        Ok(Ok(pair)) => pair,
        Ok(Err(e)) => {
            tracing::error!(dir = %shown, error = %e, "a published atlas cannot be loaded; not served");
            return false;
        }
        Err(e) => {
            tracing::error!(dir = %shown, error = %e, "loading a published atlas panicked");
            return false;
        }
    };
    if atlas.content_hash != hash {
        tracing::error!(dir = %shown, hash = %atlas.content_hash, "a published atlas no longer has the content hash it was published with; not served");
        return false;
    }
    tracing::info!(atlas = %atlas.manifest.name, hash = %hash, "atlas published at another replica, now served here");
    state
        .catalogue
        .insert(atlas, scorer, AtlasOrigin::Published, row.withdrawn_at.is_some());
    true
}

/// Brings the catalogue in line with the database: publications made at other replicas are
/// adopted, withdrawals (and publications again) made there are applied.
pub async fn sync(state: &Arc<AppState>) {
    let rows = match state.store.atlas_rows().await {
        Ok(rows) => rows,
        Err(e) => {
            tracing::warn!(error = %e, "catalogue sync: cannot read the atlas publications");
            return;
        }
    };
    for row in rows {
        if state.catalogue.get(&row.content_hash).is_some() {
            state
                .catalogue
                .set_withdrawn(&row.content_hash, row.withdrawn_at.is_some());
        } else if row.published_at.is_some() {
            adopt(state, &row.content_hash).await;
        }
    }
}
