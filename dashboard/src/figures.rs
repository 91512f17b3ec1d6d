//! The tip path over CT slices of the atlas with the label overlay (PNG, rendered on the
//! server by `stylet_render::figure`): axial, coronal and sagittal slices through the deepest
//! tip position, the path of every puncture drawn on each. Cached beside the review traces
//! (`DATA/figures/`), derived data like them.

use std::path::{Path, PathBuf};

use stylet_service::AppState;
use stylet_service::traces::review_trace;

/// Where the figure of the session file `sha` is cached (the trace and physics versions are in
/// the name: a new version draws a new figure).
pub fn figure_path(data_dir: &Path, sha: &str) -> PathBuf {
    data_dir.join("figures").join(&sha[..2.min(sha.len())]).join(format!(
        "{sha}-t{}-p{}.png",
        stylet_scoring::trace::TRACE_VERSION,
        stylet_physics::PHYSICS_VERSION
    ))
}

/// The PNG bytes of a session's figure: from the cache, else drawn (and cached).
pub async fn session_figure(s: &AppState, file_sha256: &str, atlas_hash: &str, title: &str) -> Result<Vec<u8>, String> {
    let path = figure_path(&s.config.data_dir, file_sha256);
    if let Ok(bytes) = tokio::fs::read(&path).await {
        return Ok(bytes);
    }
    let trace = review_trace(s, file_sha256, atlas_hash).await?;
    let scorer = s
        .scorers
        .get(atlas_hash)
        .cloned()
        .ok_or("the session's atlas is not loaded on this server")?;
    let title = title.to_string();
    tokio::task::spawn_blocking(move || {
        let atlas = scorer.atlas();
        let center = trace
            .deepest_tip()
            .unwrap_or_else(|| stylet_render::figure::default_center(atlas));
        // A name of its own: two requests may draw the same figure at once.
        static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
        let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let tmp = path.with_extension(format!("{}-{n}.partial.png", std::process::id()));
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir).map_err(|e| e.to_string())?;
        }
        stylet_render::figure::atlas_figure_at(atlas, &title, center, &trace.tip_paths(), &tmp)
            .map_err(|e| e.to_string())?;
        std::fs::rename(&tmp, &path).map_err(|e| e.to_string())?;
        std::fs::read(&path).map_err(|e| e.to_string())
    })
    .await
    .map_err(|e| e.to_string())?
}
