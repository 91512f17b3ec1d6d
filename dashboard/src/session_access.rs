//! Which sessions a page may show: the viewer must be allowed to see the session, and the pages
//! drawn from its replay (review figures, the player, the overview, the comparison) need its
//! score.

use axum::http::StatusCode;
use stylet_service::AppState;
use stylet_service::api::may_see;
use stylet_service::store::{SessionRow, SessionStatus};

use crate::auth::{PageError, Viewer, fail};

/// The session `id` if the viewer may see it (404 otherwise: whether it exists is private).
pub async fn visible_session(s: &AppState, v: &Viewer, id: &str) -> Result<SessionRow, PageError> {
    let not_found = || fail(StatusCode::NOT_FOUND, format!("no session {id}"));
    let (row, trainee_id) = s.store.session(id).await?.ok_or_else(not_found)?;
    if !may_see(s, &v.user, &trainee_id).await? {
        return Err(not_found());
    }
    Ok(row)
}

/// Figures come from the scoring replay; until it is done (or when it failed) there are none,
/// and a page must not start another replay of its own.
pub fn require_scored(row: &SessionRow) -> Result<(), PageError> {
    if row.status == SessionStatus::Scored {
        Ok(())
    } else {
        Err(fail(
            StatusCode::CONFLICT,
            format!("session {} is {}: its figures come with its score", row.id, row.status),
        ))
    }
}
