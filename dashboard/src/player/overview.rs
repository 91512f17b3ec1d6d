//! The 3D overview of the whole attempt on the review (docs/dashboard.md "3D overview"): a
//! turntable of [`stylet_render::overview::FRAMES`] server-drawn frames, the tip's path through
//! the anatomy coloured by what the tip was in, the planned path and the expert corridor, and
//! the expert corridor the review's slices show too.
//!
//! - `GET /sessions/{id}/overview?frame=N`: one turntable frame (PNG, cached with the player's
//!   frames; the corridor's references are in the name, so marking draws new frames).
//! - [`expert_corridor`]: the corridor of a scenario's expert references, from their review
//!   traces (kept in memory per set of references).

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};

use axum::extract::{Path, Query, State};
use axum::http::StatusCode;
use axum::response::Response;
use maud::{Markup, html};
use stylet_render::corridor::Corridor;
use stylet_render::overview::{self, OverviewSpec, PathRegion};
use stylet_scoring::{ReviewTrace, ScoreReport};
use stylet_service::AppState;
use stylet_service::store::SessionRow;
use stylet_service::traces::review_trace;

use super::{DrawError, draw_turn, drawing, frame_cache, internal, png_response};
use crate::auth::{PageError, Viewer, fail};
use crate::session_access::{require_scored, visible_session};

/// The overview's frame size.
pub const OVERVIEW_SIZE: (u32, u32) = (480, 360);
/// Corridors kept in memory (one per scenario and set of references).
const CACHED_CORRIDORS: usize = 32;

type CorridorCache = BTreeMap<String, Option<Arc<Corridor>>>;
static CORRIDORS: Mutex<CorridorCache> = Mutex::new(BTreeMap::new());

/// The expert corridor of `scenario` on the atlas `atlas_hash` as `user` may see it, and the key
/// of what it was drawn from (`"none"`: no corridor): the final approaches of the benchmark's
/// references (`stylet_service::experts::benchmark`, the list the review uses), from their review
/// traces on disk. A trace missing from disk is rebuilt in the background (one page replay at a
/// time) and the corridor drawn without it meanwhile, under a key of its own that is neither
/// kept in memory nor reused once the trace is back: a request never waits for replays.
pub async fn expert_corridor(
    s: &Arc<AppState>,
    user: &stylet_service::store::User,
    atlas_hash: &str,
    scenario: &str,
) -> Result<(Option<Arc<Corridor>>, String), PageError> {
    let (_, references) = stylet_service::experts::benchmark(s, atlas_hash, scenario).await?;
    if references.is_empty() || !stylet_service::experts::figures_shown(user, references.len()) {
        return Ok((None, "none".into()));
    }
    let key = stylet_service::experts::references_key(&references);
    let cache_key = format!("{atlas_hash}|{scenario}|{key}");
    if let Some(c) = CORRIDORS
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
        .get(&cache_key)
    {
        return Ok((c.clone(), key));
    }
    let mut paths = Vec::new();
    for r in &references {
        let file = stylet_service::traces::trace_path(&s.config.data_dir, &r.file_sha256);
        let trace = tokio::task::spawn_blocking(move || stylet_service::traces::read_trace(&file))
            .await
            .map_err(|e| internal(e.to_string()))?;
        match trace {
            Some(trace) => paths.extend(trace.final_approach()),
            None => {
                tracing::info!(session = %r.session_id, "an expert reference's trace is rebuilt; the corridor is drawn without it meanwhile");
                let (s, sha, atlas) = (Arc::clone(s), r.file_sha256.clone(), atlas_hash.to_string());
                tokio::spawn(async move {
                    if let Err(e) = review_trace(&s, &sha, &atlas).await {
                        tracing::warn!(error = %e, "cannot rebuild an expert reference's trace");
                    }
                });
            }
        }
    }
    let corridor = Corridor::from_paths(&paths).map(Arc::new);
    if paths.len() < references.len() {
        return Ok((corridor, format!("{key}-partial{}", paths.len())));
    }
    let mut cache = CORRIDORS.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    if cache.len() >= CACHED_CORRIDORS {
        cache.clear();
    }
    cache.insert(cache_key, corridor.clone());
    Ok((corridor, key))
}

/// What a frame shows: the session's tip path (each point's region from the atlas), its planned
/// path (the one its guided metrics were measured against, else the atlas' first), the corridor.
pub fn spec(
    atlas: &stylet_physics::PunctureAtlas,
    paths: &[stylet_physics::PlannedPath],
    report: &ScoreReport,
    trace: &ReviewTrace,
    corridor: Option<&Corridor>,
    frame: u32,
) -> OverviewSpec {
    let tip_paths = trace
        .tip_stays()
        .iter()
        .map(|stay| stay.iter().map(|&(p, d)| (p, PathRegion::at(atlas, p, d), d)).collect())
        .collect();
    // The path its guided metrics were measured against, else the atlas' first.
    let guided = report.metrics.guided.as_ref().map(|g| g.path.as_str());
    let planned = paths
        .iter()
        .find(|p| Some(p.name.as_str()) == guided)
        .or_else(|| paths.first())
        .map(|p| (p.entry_mm, p.target_mm));
    OverviewSpec {
        tip_paths,
        planned,
        corridor: corridor.cloned(),
        frame,
    }
}

#[derive(Debug, serde::Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct OverviewQuery {
    /// 0 … 11, 30° apart.
    #[serde(default)]
    frame: u32,
}

/// `GET /sessions/{id}/overview?frame=N` (0 … 11, 30° apart): a frame of the turntable of a
/// scored session the viewer may see (404 otherwise, 409 while it is being scored; 503 when the
/// server has been busy drawing for [`super::DRAW_WAIT`]).
#[utoipa::path(get, path = "/sessions/{id}/overview", tag = "player",
    summary = "A frame of the turntable 3D overview of a scored session (PNG)",
    params(("id" = String, Path, description = "session id"), OverviewQuery),
    responses(
        (status = 200, description = "the frame", content_type = "image/png", body = Vec<u8>),
        (status = 303, description = "not logged in: to the login page"),
        (status = 400, description = "a frame number out of range", content_type = "text/html", body = String),
        (status = 404, description = "no such session, or not yours to see", content_type = "text/html", body = String),
        (status = 409, description = "the session is being scored", content_type = "text/html", body = String),
    ),
    security(("cookie" = [])))]
pub async fn frame(
    State(s): State<Arc<AppState>>,
    v: Viewer,
    Path(id): Path<String>,
    Query(q): Query<OverviewQuery>,
) -> Result<Response, PageError> {
    let row = visible_session(&s, &v, &id).await?;
    require_scored(&row)?;
    if q.frame >= overview::FRAMES {
        return Err(fail(
            StatusCode::BAD_REQUEST,
            format!(
                "frame {} of the overview: frames are 0 … {}",
                q.frame,
                overview::FRAMES - 1
            ),
        ));
    }
    let (corridor, key) = expert_corridor(&s, &v.user, &row.atlas_hash, &row.scenario).await?;
    let cache = frame_cache(&s);
    let (w, h) = OVERVIEW_SIZE;
    let path = cache.overview_path(&row.file_sha256, q.frame, &key, w, h);
    if let Ok(png) = tokio::fs::read(&path).await {
        return Ok(png_response(png));
    }
    if let Some(png) = super::shared_frames::fetch(&s, &cache, &path).await {
        return Ok(png_response(png));
    }
    let report = report_of(&row)?;
    let trace = review_trace(&s, &row.file_sha256, &row.atlas_hash)
        .await
        .map_err(|e| internal(e.to_string()))?;
    let drawing = drawing(&s, &row.atlas_hash).await?;
    let scorer = super::atlas_of(&s, &row.atlas_hash).await?.scorer;
    let turn = match draw_turn().await? {
        Ok(turn) => turn,
        Err(busy) => return Ok(busy),
    };
    let frame = q.frame;
    let drawn_path = path.clone();
    let png = tokio::task::spawn_blocking(move || -> Result<Vec<u8>, DrawError> {
        let _turn = turn;
        if let Some(png) = cache.get(&path) {
            return Ok(png);
        }
        let spec = spec(
            scorer.atlas(),
            scorer.paths(),
            &report,
            &trace,
            corridor.as_deref(),
            frame,
        );
        let image = overview::render(&drawing.atlas, &drawing.volume, &spec, w, h)?;
        let png = image.to_png()?;
        cache.put(&path, &png);
        Ok(png)
    })
    .await
    .map_err(|e| internal(e.to_string()))?
    .map_err(|e| internal(e.to_string()))?;
    super::shared_frames::share(&s, &row.file_sha256, &drawn_path, png.clone());
    Ok(png_response(png))
}

fn report_of(row: &SessionRow) -> Result<ScoreReport, PageError> {
    row.score
        .clone()
        .and_then(|r| serde_json::from_value(r).ok())
        .ok_or_else(|| internal("the stored score report cannot be read"))
}

/// The overview's block on the review: frame `turn` (the page's `?turn=`, default 0) with links
/// to the neighbouring frames (without JavaScript), buttons and dragging to turn it (with it).
/// `key` names the corridor's references, so a browser does not show a frame drawn before a
/// marking.
pub fn block(row: &SessionRow, turn: u32, key: &str, experts: usize) -> Markup {
    let n = overview::FRAMES;
    let turn = turn % n;
    let (w, h) = OVERVIEW_SIZE;
    let src = |f: u32| format!("/sessions/{}/overview?frame={f}&e={key}", row.id);
    let link = |f: u32| format!("/sessions/{}?turn={f}#overview", row.id);
    let step = overview::STEP_DEG;
    html! {
        section #overview data-session=(row.id) data-frames=(n) data-frame=(turn) data-key=(key) {
            figure.frame {
                img #overview-frame src=(src(turn)) width=(w) height=(h) draggable="false"
                    alt={ "3D overview of the whole attempt from azimuth " (format!("{:.0}", turn as f32 * step)) "°: the needle tip's path, the planned path and the expert corridor" };
                figcaption {
                    a.turn #turn-left href=(link((turn + n - 1) % n)) aria-label="Turn left" { "◀" }
                    " Turn (drag the picture, or ← → on it) "
                    a.turn #turn-right href=(link((turn + 1) % n)) aria-label="Turn right" { "▶" }
                }
            }
            ul.muted.legend {
                li { span.swatch style="background:#00e6ff" {} "tip path in tissue" }
                li { span.swatch style="background:#ff3232" {} "in a risk structure" }
                li { span.swatch style="background:#3cff3c" {} "in the target" }
                li { span.swatch style="background:#ffaa00" {} "planned path (dashed)" }
                li { span.swatch style="background:rgba(255,255,255,.6);outline:1px solid #888" {} "expert corridor, a white band"
                    @if experts == 0 { " (no expert references yet)" } @else { " (" (experts) " reference" @if experts != 1 { "s" } ")" } }
                li { "cut along the needle: every structure in its colour, as on the slices below (target green, bone ivory, liver brown); white dots: skin entries, red ring: the deepest point" }
            }
        }
    }
}
