//! The replay player on the session review (docs/dashboard.md "Player"): frames of the 3D view,
//! the axial slice through the tip, the ultrasound and the X-ray at any tick, drawn on the server
//! from the replay (so it works in any browser and on a tablet), a timeline with play, pause,
//! speed and key moments, and a cursor on the force chart.
//!
//! - [`states`]: snapshots of the replay, so a frame replays from the nearest one, not the start.
//! - [`frames`]: the views drawn as `stylet render` draws them, and their disk cache.
//! - `GET /sessions/{id}/frame?view=…&tick=…&w=…&h=…`: one frame (PNG).
//! - [`overview`]: the 3D overview of the whole attempt (a turntable) and the expert corridor.
//! - `GET /assets/player.js`: the player's script (the page works without it: key-moment
//!   frames are links).

pub mod frames;
pub mod overview;
mod shared_frames;
pub mod states;

use std::collections::{BTreeMap, VecDeque};
use std::sync::{Arc, Mutex};

use axum::extract::{Path, Query, State};
use axum::http::{StatusCode, header};
use axum::response::{IntoResponse, Response};
use maud::{Markup, html};
use stylet_scoring::ReviewTrace;
use stylet_service::AppState;
use stylet_service::store::SessionRow;

use crate::auth::{PageError, Viewer, fail};
use crate::session_access::{require_scored, visible_session};
use frames::{AtlasDrawing, FrameCache, FrameView};
use states::ReplayStates;

/// Why a frame or an overview picture could not be drawn: the view refused the moment, or the
/// picture could not be encoded as PNG. Answered with a 500 and the message.
#[derive(Debug, thiserror::Error)]
pub enum DrawError {
    #[error(transparent)]
    View(#[from] stylet_render::views::ViewError),
    #[error(transparent)]
    Png(#[from] stylet_render::RenderError),
}

/// Sessions whose replay snapshots stay in memory (the least recently used goes first). Each
/// holds its decoded ticks (about 130 bytes a tick: 75 MiB for ten minutes at 1 kHz, and the
/// upload limits bound a session's ticks) and its snapshots (`states::MAX_SNAPSHOTS` clones of
/// the simulation, the contrast grid the largest part once contrast flows).
pub const CACHED_SESSIONS: usize = 3;
/// Atlases kept prepared for drawing (the least recently used goes first): each holds its
/// atlas and the renderer's acceleration structures, so they are not kept for every atlas.
pub const CACHED_DRAWINGS: usize = 2;
/// Disk the frame cache may use (`DATA/frames/`).
pub const FRAME_CACHE_BYTES: u64 = 512 << 20;
/// The frame size the page asks for.
pub const FRAME_SIZE: (u32, u32) = (480, 360);
/// The frame sizes the route draws: a few, so that frames are shared between viewers and a
/// client cannot make every request a new drawing.
pub const FRAME_SIZES: [(u32, u32); 4] = [(320, 240), (480, 360), (640, 480), (960, 720)];
/// Longest a frame request waits for its turn to draw before the server says it is busy.
pub const DRAW_WAIT: std::time::Duration = std::time::Duration::from_secs(10);

/// Frames drawn at once (each uses every core through rayon); more requests wait their turn, at
/// most [`DRAW_WAIT`]. A permit moves into the drawing thread: a client that goes away does not
/// free it while its frame is still being drawn.
static DRAWING: std::sync::LazyLock<Arc<tokio::sync::Semaphore>> =
    std::sync::LazyLock::new(|| Arc::new(tokio::sync::Semaphore::new(1)));
/// Replays building snapshots at once (held by the replaying thread, as above).
static REPLAYING: std::sync::LazyLock<Arc<tokio::sync::Semaphore>> =
    std::sync::LazyLock::new(|| Arc::new(tokio::sync::Semaphore::new(1)));
/// Atlases being prepared for drawing at once.
static PREPARING: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

/// The player's caches, kept with the server's state.
#[derive(Default)]
struct Caches {
    /// Replay snapshots by session file hash, most recently used last.
    states: VecDeque<(String, Arc<ReplayStates>)>,
    /// Sessions whose snapshots a page view started building.
    warming: std::collections::BTreeSet<String>,
    /// Prepared atlases by content hash, most recently used last.
    drawings: VecDeque<(String, Arc<AtlasDrawing>)>,
    /// The frame cache of each data folder (one per server).
    frames: BTreeMap<std::path::PathBuf, Arc<FrameCache>>,
}

static CACHES: Mutex<Option<Caches>> = Mutex::new(None);

fn with_caches<T>(f: impl FnOnce(&mut Caches) -> T) -> T {
    let mut c = CACHES.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    f(c.get_or_insert_with(Caches::default))
}

fn frame_cache(s: &AppState) -> Arc<FrameCache> {
    with_caches(|c| {
        Arc::clone(
            c.frames
                .entry(s.config.data_dir.clone())
                .or_insert_with(|| Arc::new(FrameCache::new(&s.config.data_dir, FRAME_CACHE_BYTES))),
        )
    })
}

/// The session's replay snapshots in memory, if they are there (and marks them recently used).
fn cached_states(sha: &str) -> Option<Arc<ReplayStates>> {
    with_caches(|c| {
        let i = c.states.iter().position(|(k, _)| k == sha)?;
        let entry = c.states.remove(i)?;
        let states = Arc::clone(&entry.1);
        c.states.push_back(entry);
        Some(states)
    })
}

/// The session's replay snapshots: from memory, else replayed once (one replay at a time). The
/// replay runs on a blocking thread that holds the turn and stores its result itself, so a
/// client that goes away neither frees the turn early nor wastes the replay.
async fn replay_states(s: &AppState, row: &SessionRow) -> Result<Arc<ReplayStates>, PageError> {
    let sha = row.file_sha256.clone();
    if let Some(st) = cached_states(&sha) {
        return Ok(st);
    }
    let turn = Arc::clone(&REPLAYING)
        .acquire_owned()
        .await
        .map_err(|e| internal(e.to_string()))?;
    let scorer = atlas_of(s, &row.atlas_hash).await?.scorer;
    let file = s.session_copy(&sha).await.map_err(|e| {
        tracing::warn!(session = %row.id, error = %e, "cannot fetch a session file for the player");
        internal("the session file cannot be read")
    })?;
    let id = row.id.clone();
    tokio::task::spawn_blocking(move || -> Result<Arc<ReplayStates>, PageError> {
        let _turn = turn;
        // Whoever held the turn before may have replayed this very session.
        if let Some(st) = cached_states(&sha) {
            return Ok(st);
        }
        let session = stylet_recorder::reader::recover(&file).map_err(|e| {
            tracing::warn!(session = %id, error = %e, "cannot read a session file for the player");
            internal("the session file cannot be read")
        })?;
        let built = ReplayStates::build(session, Arc::clone(scorer.atlas()))
            .map_err(|e| internal(format!("the session cannot be replayed: {e}")))?
            .ok_or_else(|| fail(StatusCode::NOT_FOUND, "the recording has no moment to show"))?;
        let built = Arc::new(built);
        with_caches(|c| {
            c.states.push_back((sha, Arc::clone(&built)));
            while c.states.len() > CACHED_SESSIONS {
                c.states.pop_front();
            }
        });
        Ok(built)
    })
    .await
    .map_err(|e| internal(e.to_string()))?
}

/// Starts replaying the session for its snapshots in the background (the review page does, so
/// that its first frames need not wait for the whole replay).
pub fn warm(s: &Arc<AppState>, row: &SessionRow) {
    let sha = row.file_sha256.clone();
    let start = with_caches(|c| {
        let known = c.states.iter().any(|(k, _)| *k == sha) || c.warming.contains(&sha);
        // At most a few sessions wait to be warmed; more page views just skip it.
        let room = c.warming.len() < CACHED_SESSIONS;
        if !known && room {
            c.warming.insert(sha.clone());
        }
        !known && room
    });
    if !start {
        return;
    }
    let (s, row) = (Arc::clone(s), row.clone());
    tokio::spawn(async move {
        if let Err(e) = replay_states(&s, &row).await {
            tracing::warn!(session = %row.id, error = ?e, "cannot prepare the replay for the player");
        }
        with_caches(|c| c.warming.remove(&row.file_sha256));
    });
}

fn internal(e: impl Into<String>) -> PageError {
    fail(StatusCode::INTERNAL_SERVER_ERROR, e)
}

/// The session's atlas and its scorer, loaded if the catalogue's cache let it go; 404 when the
/// server does not know it.
pub async fn atlas_of(s: &AppState, atlas_hash: &str) -> Result<stylet_service::catalogue::Loaded, PageError> {
    use stylet_service::catalogue::LoadError;
    stylet_service::shared_atlases::loaded(s, atlas_hash)
        .await
        .map_err(|e| match e {
            LoadError::Unknown(_) => fail(StatusCode::NOT_FOUND, "the session's atlas is not known to this server"),
            LoadError::Failed { .. } => {
                tracing::error!(error = %e, "loading an atlas for the player");
                fail(
                    StatusCode::SERVICE_UNAVAILABLE,
                    "the session's atlas cannot be loaded right now; try again later",
                )
            }
        })
}

/// The atlas prepared for drawing (kept for the [`CACHED_DRAWINGS`] most recently drawn).
async fn drawing(s: &AppState, atlas_hash: &str) -> Result<Arc<AtlasDrawing>, PageError> {
    let cached = || {
        with_caches(|c| {
            let i = c.drawings.iter().position(|(h, _)| h == atlas_hash)?;
            let entry = c.drawings.remove(i)?;
            let d = Arc::clone(&entry.1);
            c.drawings.push_back(entry);
            Some(d)
        })
    };
    if let Some(d) = cached() {
        return Ok(d);
    }
    let _one = PREPARING.lock().await;
    if let Some(d) = cached() {
        return Ok(d);
    }
    let atlas = atlas_of(s, atlas_hash).await?.atlas;
    let d = tokio::task::spawn_blocking(move || Arc::new(AtlasDrawing::new(atlas)))
        .await
        .map_err(|e| internal(e.to_string()))?;
    with_caches(|c| {
        c.drawings.push_back((atlas_hash.to_string(), Arc::clone(&d)));
        while c.drawings.len() > CACHED_DRAWINGS {
            c.drawings.pop_front();
        }
    });
    Ok(d)
}

#[derive(Debug, serde::Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct FrameQuery {
    /// 3d, axial, ultrasound or xray.
    view: String,
    /// The tick (0 = the session's start).
    tick: u64,
    /// Width: 320, 480, 640 or 960 (with the matching height; default 480 × 360).
    w: Option<u32>,
    h: Option<u32>,
}

/// `GET /sessions/{id}/frame?view=3d|axial|ultrasound|xray&tick=N[&w=W&h=H]`: the view at tick N
/// of a scored session the viewer may see (404 otherwise, 409 while it is being scored), drawn
/// from the replay; W × H one of [`FRAME_SIZES`] (default 480 × 360). Everything that can be
/// refused is refused before a replay or a drawing starts; a server busy drawing for
/// [`DRAW_WAIT`] answers 503.
#[utoipa::path(get, path = "/sessions/{id}/frame", tag = "player",
    summary = "A frame of the replay player: a view of a scored session at a tick (PNG)",
    params(("id" = String, Path, description = "session id"), FrameQuery),
    responses(
        (status = 200, description = "the frame", content_type = "image/png", body = Vec<u8>),
        (status = 303, description = "not logged in: to the login page"),
        (status = 400, description = "an unknown view, a tick past the session's end, or a size not offered", content_type = "text/html", body = String),
        (status = 404, description = "no such session, or not yours to see", content_type = "text/html", body = String),
        (status = 409, description = "the session is being scored", content_type = "text/html", body = String),
    ),
    security(("cookie" = [])))]
pub async fn frame(
    State(s): State<Arc<AppState>>,
    v: Viewer,
    Path(id): Path<String>,
    Query(q): Query<FrameQuery>,
) -> Result<Response, PageError> {
    let row = visible_session(&s, &v, &id).await?;
    require_scored(&row)?;
    let view = FrameView::parse(&q.view).ok_or_else(|| {
        let names: Vec<&str> = FrameView::ALL.iter().map(|v| v.name()).collect();
        fail(
            StatusCode::BAD_REQUEST,
            format!("unknown view '{}' (views: {})", q.view, names.join(", ")),
        )
    })?;
    let (w, h) = (q.w.unwrap_or(FRAME_SIZE.0), q.h.unwrap_or(FRAME_SIZE.1));
    if !FRAME_SIZES.contains(&(w, h)) {
        let sizes: Vec<String> = FRAME_SIZES.iter().map(|(w, h)| format!("{w}x{h}")).collect();
        return Err(fail(
            StatusCode::BAD_REQUEST,
            format!("frame size {w} × {h}: the player draws {}", sizes.join(", ")),
        ));
    }
    // The score says how many ticks were replayed: a tick beyond them costs nothing.
    let ticks = row.score.as_ref().and_then(|r| r["ticks"].as_u64()).unwrap_or(0);
    if q.tick >= ticks {
        let rate = rate_or_default(&s, &row).await;
        return Err(fail(
            StatusCode::NOT_FOUND,
            no_moment_text(q.tick, 0, ticks.saturating_sub(1), rate),
        ));
    }
    let cache = frame_cache(&s);
    let path = cache.path(&row.file_sha256, view, q.tick, w, h);
    if let Ok(png) = tokio::fs::read(&path).await {
        return Ok(png_response(png));
    }
    if let Some(png) = shared_frames::fetch(&s, &cache, &path).await {
        return Ok(png_response(png));
    }
    let states = replay_states(&s, &row).await?;
    if !(states.first_tick..=states.last_tick).contains(&q.tick) {
        let rate = rate_or_default(&s, &row).await;
        return Err(fail(
            StatusCode::NOT_FOUND,
            no_moment_text(q.tick, states.first_tick, states.last_tick, rate),
        ));
    }
    let drawing = drawing(&s, &row.atlas_hash).await?;
    let turn = match draw_turn().await? {
        Ok(turn) => turn,
        Err(busy) => return Ok(busy),
    };
    let tick = q.tick;
    let drawn_path = path.clone();
    let png = tokio::task::spawn_blocking(move || -> Result<Option<Vec<u8>>, DrawError> {
        let _turn = turn;
        // Another request may have drawn it while this one waited.
        if let Some(png) = cache.get(&path) {
            return Ok(Some(png));
        }
        let Some(moment) = states.moment_at(tick) else {
            return Ok(None);
        };
        let image = drawing.draw(view, &moment, w, h)?;
        let png = image.to_png()?;
        cache.put(&path, &png);
        Ok(Some(png))
    })
    .await
    .map_err(|e| internal(e.to_string()))?
    .map_err(|e| internal(e.to_string()))?;
    match png {
        Some(png) => {
            shared_frames::share(&s, &row.file_sha256, &drawn_path, png.clone());
            Ok(png_response(png))
        }
        None => {
            let rate = rate_or_default(&s, &row).await;
            Err(fail(
                StatusCode::NOT_FOUND,
                format!("the moment at {} cannot be replayed", time_text(tick, rate)),
            ))
        }
    }
}

/// A tick of a session as a time for people: "4.30 s" (`rate_hz` ticks a second).
pub fn time_text(tick: u64, rate_hz: u32) -> String {
    format!("{:.2} s", tick as f64 / f64::from(rate_hz.max(1)))
}

/// Why a frame at `tick` cannot be shown when the session's ticks run from `first` to `last`,
/// in seconds.
fn no_moment_text(tick: u64, first: u64, last: u64, rate_hz: u32) -> String {
    format!(
        "no moment at {} in this session (it can be shown from {} to {})",
        time_text(tick, rate_hz),
        time_text(first, rate_hz),
        time_text(last, rate_hz)
    )
}

/// The session's tick rate, else the one rate the upload accepts (for messages only).
async fn rate_or_default(s: &AppState, row: &SessionRow) -> u32 {
    tick_rate_hz(s, row)
        .await
        .unwrap_or(stylet_physics::DEFAULT_TICK_RATE_HZ)
}

/// A turn to draw a frame, waited for at most [`DRAW_WAIT`]; `Err` holds the 503 to answer when
/// the server stayed busy.
async fn draw_turn() -> Result<Result<tokio::sync::OwnedSemaphorePermit, Response>, PageError> {
    match tokio::time::timeout(DRAW_WAIT, Arc::clone(&DRAWING).acquire_owned()).await {
        Ok(turn) => Ok(Ok(turn.map_err(|e| internal(e.to_string()))?)),
        Err(_) => Ok(Err((
            StatusCode::SERVICE_UNAVAILABLE,
            [(header::RETRY_AFTER, "2")],
            "the server is busy drawing frames; try again in a moment",
        )
            .into_response())),
    }
}

fn png_response(png: Vec<u8>) -> Response {
    (
        [
            (header::CONTENT_TYPE, "image/png"),
            (header::CACHE_CONTROL, "private, max-age=3600"),
        ],
        png,
    )
        .into_response()
}

/// `GET /assets/player.js`.
pub async fn script() -> Response {
    crate::layout::asset("text/javascript; charset=utf-8", include_str!("player.js"))
}

/// The session's tick rate, from its header (the first 64 KiB of the file: nothing else is read).
pub async fn tick_rate_hz(s: &AppState, row: &SessionRow) -> Option<u32> {
    use tokio::io::AsyncReadExt;
    let file = tokio::fs::File::open(s.session_copy(&row.file_sha256).await.ok()?)
        .await
        .ok()?;
    let mut head = Vec::with_capacity(64 << 10);
    file.take(64 << 10).read_to_end(&mut head).await.ok()?;
    stylet_recorder::reader::read_header(&head)
        .ok()
        .map(|h| h.tick_rate_hz)
        .filter(|&r| r > 0)
}

/// The tick a time of the trace falls on.
fn tick_at(t_s: f64, rate_hz: u32, first: u64, last: u64) -> u64 {
    ((t_s * f64::from(rate_hz)).round().max(0.0) as u64).clamp(first, last)
}

/// The player's block on the review: the four views at `at` (the page's `?tick=`), else at the
/// first key moment, else at the start; the timeline, the controls and the key moments (and the
/// instructors' comments at a moment). Without JavaScript the controls stay hidden and the key
/// moments are links to the review at their tick, which draws the four views there.
pub fn block(
    row: &SessionRow,
    trace: &ReviewTrace,
    tick_rate_hz: u32,
    ticks: u64,
    at: Option<u64>,
    comments: &[(f64, String)],
) -> Markup {
    if ticks == 0 {
        return html! { p.muted { "The recording is empty: there is nothing to replay." } };
    }
    let last = ticks - 1;
    let moments = trace.key_moments();
    let start = at
        .map(|t| t.min(last))
        .or_else(|| moments.first().map(|m| tick_at(m.t_s, tick_rate_hz, 0, last)))
        .unwrap_or(0);
    let (w, h) = FRAME_SIZE;
    let src = |view: FrameView, tick: u64| {
        format!(
            "/sessions/{}/frame?view={}&tick={tick}&w={w}&h={h}",
            row.id,
            view.name()
        )
    };
    let seconds = |tick: u64| time_text(tick, tick_rate_hz);
    let link = |tick: u64| format!("/sessions/{}?tick={tick}#player", row.id);
    html! {
        section #player data-session=(row.id) data-rate=(tick_rate_hz) data-last=(last) data-tick=(start) data-w=(w) data-h=(h) {
            div.frames {
                @for view in FrameView::ALL {
                    figure.frame {
                        img id={ "frame-" (view.name()) } data-view=(view.name()) src=(src(view, start)) width=(w) height=(h)
                            alt={ (view.title()) " at " (seconds(start)) };
                        figcaption { (view.title()) }
                    }
                }
            }
            div.controls.noprint hidden {
                button.primary #play type="button" aria-pressed="false" aria-keyshortcuts="Space" { "Play" }
                input #timeline type="range" min="0" max=(last) step="1" value=(start) aria-label="Time in the session"
                    aria-valuetext=(seconds(start));
                output #clock aria-live="off" { (seconds(start)) }
                label.speed { "Speed "
                    select #speed {
                        @for (x, label) in [(0.25, "0.25×"), (0.5, "0.5×"), (1.0, "1×"), (2.0, "2×"), (4.0, "4×"), (8.0, "8×")] {
                            option value=(x) selected[x == 1.0] { (label) }
                        }
                    }
                }
            }
            p.muted.noprint.keys hidden { "Keys (in the player): Space play/pause · ← → one second · [ ] slower/faster · Home/End. Click the force chart to go to that moment." }
            p.muted.noscript-only { "Showing " (seconds(start)) ". The moments below open the review at their time." }
            @if !moments.is_empty() || !comments.is_empty() {
                div.moments {
                    @for m in &moments {
                        @let tick = tick_at(m.t_s, tick_rate_hz, 0, last);
                        a.moment data-tick=(tick) data-kind=(m.kind.name()) href=(link(tick)) {
                            (m.label) " · " (format!("{:.2} s", m.t_s))
                        }
                    }
                    @for (t_s, label) in comments {
                        @let tick = tick_at(*t_s, tick_rate_hz, 0, last);
                        a.moment data-tick=(tick) data-kind="comment" href=(link(tick)) {
                            (label) " · " (format!("{t_s:.2} s"))
                        }
                    }
                }
            }
        }
        script src="/assets/player.js" defer {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_moment_outside_the_session_is_named_in_seconds() {
        let text = no_moment_text(4304, 0, 3990, 1000);
        assert_eq!(
            text,
            "no moment at 4.30 s in this session (it can be shown from 0.00 s to 3.99 s)"
        );
        assert!(!text.contains("tick"), "{text}");
        assert_eq!(time_text(250, 1000), "0.25 s");
        // An unreadable rate never divides by zero.
        assert_eq!(time_text(3, 0), "3.00 s");
    }
}
