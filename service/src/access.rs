//! Who may see and review which sessions: trainees their own, instructors their cohorts',
//! curriculum staff and admins all (reading); instructors and admins review. A session that may
//! not be seen answers 404, not 403: whether it exists is itself private.

use axum::http::StatusCode;

use super::AppState;
use super::error::{ApiError, err};
use super::store::{Role, SessionRow, User};

/// The session `id` if `user` may see it: their own (trainees), their cohorts' (instructors),
/// every session (curriculum, admins). 404 otherwise, not 403: whether a session exists is
/// itself private.
pub async fn visible_session(s: &AppState, user: &User, id: &str) -> Result<SessionRow, ApiError> {
    let not_found = || err(StatusCode::NOT_FOUND, format!("no session {id}"));
    let (row, trainee_id) = s.store.session(id).await?.ok_or_else(not_found)?;
    let allowed = match user.role {
        Role::Trainee => trainee_id == user.id,
        Role::Instructor => s.store.teaches(&user.id, &trainee_id).await?,
        Role::Curriculum | Role::Admin => true,
    };
    if allowed { Ok(row) } else { Err(not_found()) }
}

/// Whether `user` may see the sessions of `trainee_id`.
pub async fn may_see(s: &AppState, user: &User, trainee_id: &str) -> Result<bool, ApiError> {
    Ok(match user.role {
        Role::Trainee => trainee_id == user.id,
        Role::Instructor => s.store.teaches(&user.id, trainee_id).await?,
        Role::Curriculum | Role::Admin => true,
    })
}

/// Whether `user` may comment on and override grades of `trainee_id`'s sessions: their
/// instructors and admins (curriculum staff read everything and change nothing).
pub async fn may_review(s: &AppState, user: &User, trainee_id: &str) -> Result<bool, ApiError> {
    Ok(match user.role {
        Role::Instructor => s.store.teaches(&user.id, trainee_id).await?,
        Role::Admin => true,
        Role::Trainee | Role::Curriculum => false,
    })
}

/// The session `id` for a reviewer, or 404/403.
pub async fn reviewable(s: &AppState, user: &User, id: &str) -> Result<(), ApiError> {
    let (_, trainee_id) = s
        .store
        .session(id)
        .await?
        .ok_or_else(|| err(StatusCode::NOT_FOUND, format!("no session {id}")))?;
    if !may_see(s, user, &trainee_id).await? {
        return Err(err(StatusCode::NOT_FOUND, format!("no session {id}")));
    }
    if !may_review(s, user, &trainee_id).await? {
        return Err(err(
            StatusCode::FORBIDDEN,
            format!("{} ({}) may not change this session's review", user.username, user.role),
        ));
    }
    Ok(())
}
