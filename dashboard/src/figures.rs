//! Figures of a session over CT slices of its atlas with the label overlay (PNG, rendered on the
//! server by `stylet_render::figure`), cached beside the review traces (`DATA/figures/`), derived
//! data like them:
//! - the tip path: axial, coronal and sagittal slices through the deepest tip position, the
//!   needle's path and the planned path its guided metrics were measured against, with a legend;
//! - one figure per risk hit: axial and coronal slices through the point where the tip first
//!   touched the structure, the point marked.

use std::path::{Path, PathBuf};

use stylet_physics::glam::DVec3;
use stylet_render::corridor::Corridor;
use stylet_render::figure::{FigureSpec, Mark};
use stylet_render::mpr::Plane;
use stylet_scoring::{ReviewTrace, ScoreReport, Scorer};
use stylet_service::AppState;
use stylet_service::catalogue::LoadError;
use stylet_service::traces::{TraceError, review_trace};

/// Why a session's figure cannot be had: its trace or its atlas cannot be had, drawing it
/// failed, or the figure folder cannot be written or read. Answered with a 500 and the message.
#[derive(Debug, thiserror::Error)]
pub enum FigureError {
    #[error(transparent)]
    Trace(#[from] TraceError),
    #[error(transparent)]
    Atlas(#[from] LoadError),
    #[error(transparent)]
    Draw(#[from] stylet_render::RenderError),
    /// Creating the folder, placing the drawn figure or reading it back.
    #[error(transparent)]
    Io(#[from] std::io::Error),
    /// The drawing task panicked or was cancelled.
    #[error(transparent)]
    Task(#[from] tokio::task::JoinError),
}

/// Which figure of a session.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Figure {
    /// The tip path through the deepest tip.
    TipPath,
    /// Slices through the `n`th risk hit of the score (0-based).
    Hit(usize),
}

/// Where a figure of the session file `sha` is cached (the trace and physics versions are in
/// the name: a new version draws a new figure; so is the key of the expert references whose
/// corridor the tip path's figure shows).
pub fn figure_path(data_dir: &Path, sha: &str, figure: Figure, corridor_key: &str) -> PathBuf {
    let which = match figure {
        Figure::TipPath => format!("-e{corridor_key}"),
        Figure::Hit(n) => format!("-hit{n}"),
    };
    data_dir.join("figures").join(&sha[..2.min(sha.len())]).join(format!(
        "{sha}{which}-t{}-p{}.png",
        stylet_scoring::trace::TRACE_VERSION,
        stylet_physics::PHYSICS_VERSION
    ))
}

/// Where the tip first touched the `n`th risk structure: the score's point (reports written
/// without one hold [0, 0, 0]), else the review trace's.
pub fn hit_point(report: &ScoreReport, trace: &ReviewTrace, n: usize) -> Option<DVec3> {
    let hit = report.metrics.risk_hits.get(n)?;
    if hit.point_mm != [0.0; 3] {
        return Some(DVec3::from_array(hit.point_mm));
    }
    trace
        .risk_points
        .iter()
        .find(|p| p.label == hit.label)
        .map(|p| DVec3::from_array(p.point_mm))
}

/// The planned path the session's guided metrics were measured against, if the atlas has it.
fn planned(scorer: &Scorer, report: &ScoreReport) -> Vec<(String, DVec3, DVec3)> {
    let Some(g) = &report.metrics.guided else {
        return Vec::new();
    };
    scorer
        .paths()
        .iter()
        .filter(|p| p.name == g.path)
        .map(|p| (p.name.clone(), p.entry_mm, p.target_mm))
        .collect()
}

/// What the figure shows.
fn spec(
    scorer: &Scorer,
    report: &ScoreReport,
    trace: &ReviewTrace,
    figure: Figure,
    title: &str,
    corridor: Option<&Corridor>,
) -> Option<FigureSpec> {
    let mut spec = FigureSpec {
        needle: trace.tip_paths(),
        planned: planned(scorer, report),
        ..FigureSpec::new(title, DVec3::ZERO)
    };
    match figure {
        Figure::TipPath => {
            spec.corridor = corridor.cloned();
            spec.center = trace
                .deepest_tip()
                .unwrap_or_else(|| stylet_render::figure::default_center(scorer.atlas()));
        }
        Figure::Hit(n) => {
            let hit = report.metrics.risk_hits.get(n)?;
            let point = hit_point(report, trace, n)?;
            spec.center = point;
            spec.planes = vec![Plane::Axial, Plane::Coronal];
            spec.mark = Some(Mark {
                point_mm: point,
                label: format!("{}: first contact at {:.2} s (ring)", hit.structure, hit.t_s),
            });
        }
    }
    Some(spec)
}

/// The PNG bytes of a session's figure: from the cache, else drawn (and cached). `corridor`: the
/// expert corridor the tip path's figure shows and its key (`player::overview::expert_corridor`).
/// `Ok(None)`: the session has no such risk hit (or no point for it).
pub async fn session_figure(
    s: &AppState,
    file_sha256: &str,
    atlas_hash: &str,
    report: &ScoreReport,
    figure: Figure,
    title: &str,
    (corridor, key): (Option<std::sync::Arc<Corridor>>, String),
) -> Result<Option<Vec<u8>>, FigureError> {
    if let Figure::Hit(n) = figure
        && n >= report.metrics.risk_hits.len()
    {
        return Ok(None);
    }
    let path = figure_path(&s.config.data_dir, file_sha256, figure, &key);
    if let Ok(bytes) = tokio::fs::read(&path).await {
        return Ok(Some(bytes));
    }
    let trace = review_trace(s, file_sha256, atlas_hash).await?;
    let scorer = stylet_service::shared_atlases::loaded(s, atlas_hash).await?.scorer;
    let Some(spec) = spec(&scorer, report, &trace, figure, title, corridor.as_deref()) else {
        return Ok(None);
    };
    tokio::task::spawn_blocking(move || {
        // A name of its own: two requests may draw the same figure at once.
        static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
        let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let tmp = path.with_extension(format!("{}-{n}.partial.png", std::process::id()));
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir)?;
        }
        stylet_render::figure::figure(scorer.atlas(), &spec, &tmp)?;
        std::fs::rename(&tmp, &path)?;
        if figure == Figure::TipPath {
            remove_older_tip_paths(&path);
        }
        Ok(Some(std::fs::read(&path)?))
    })
    .await?
}

/// Removes the tip-path figures of the same session drawn with another expert corridor (before a
/// marking or unmarking): one figure per session stays, so the folder grows with the sessions,
/// not with the markings.
fn remove_older_tip_paths(kept: &Path) {
    let (Some(dir), Some(name)) = (kept.parent(), kept.file_name().and_then(|n| n.to_str())) else {
        return;
    };
    let Some((sha, _)) = name.split_once("-e") else { return };
    let prefix = format!("{sha}-e");
    for entry in std::fs::read_dir(dir).into_iter().flatten().flatten() {
        let other = entry.file_name();
        let other = other.to_string_lossy();
        if other.starts_with(&prefix) && other.ends_with(".png") && !other.contains(".partial") && *other != *name {
            let _ = std::fs::remove_file(entry.path());
        }
    }
}
