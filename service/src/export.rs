//! The sessions CSV (docs/api.md "Sessions CSV"): one row per session, for curriculum staff's
//! spreadsheets, and its route, `GET /api/export/sessions.csv`. The API and the dashboard serve
//! the same text.

use std::sync::Arc;

use axum::extract::{Query, State};
use axum::http::{StatusCode, header};
use axum::response::{IntoResponse, Response};

use super::AppState;
use super::error::{ApiError, err};
use super::extract::Reader;
use super::list_query::ListQuery;
use super::store::{ExportRow, Role};

/// GET /api/export/sessions.csv: one row per session the caller may see (curriculum staff and
/// admins: all; instructors: their cohorts'), oldest first, filtered like the lists. Trainees use
/// their progress instead.
#[utoipa::path(get, path = "/api/export/sessions.csv", tag = "review",
    summary = "One CSV row per visible session (columns in docs/api.md)",
    params(ListQuery),
    responses(
        (status = 200, description = "the sessions", content_type = "text/csv", body = String),
        (status = 400, description = "a bad filter", body = super::openapi::ErrorBody),
        (status = 403, description = "trainees have no export, or an upload-scoped token", body = super::openapi::ErrorBody),
    ),
    security(("cookie" = []), ("token" = [])))]
pub async fn export_csv(
    State(s): State<Arc<AppState>>,
    Reader(user): Reader,
    Query(q): Query<ListQuery>,
) -> Result<Response, ApiError> {
    if user.role == Role::Trainee {
        return Err(err(
            StatusCode::FORBIDDEN,
            "the export is for instructors and curriculum staff",
        ));
    }
    let filter = q.filter(&s).await?;
    let rows = s.store.export_rows(&user, &filter).await?;
    Ok((
        [
            (header::CONTENT_TYPE, "text/csv; charset=utf-8"),
            (
                header::CONTENT_DISPOSITION,
                "attachment; filename=\"stylet-sessions.csv\"",
            ),
        ],
        sessions_csv(&rows),
    )
        .into_response())
}

/// The header line; the columns are documented in docs/api.md.
pub const SESSIONS_CSV_HEADER: &str = "session_id,trainee,cohorts,scenario,difficulty,status,recorded_at,uploaded_at,\
duration_s,score,passed,overridden,attempts,risk_hits,replay_verified,rubric_version,physics_version,\
exercise,target_reached,structures_hit,outcome,reasons,skill_z";

/// A field quoted when it holds a comma, quote or line break (RFC 4180). Text that a spreadsheet
/// would run as a formula (`=`, `+`, `-`, `@`, tab or carriage return first) gets a leading
/// apostrophe (OWASP, CSV injection).
fn field(s: &str) -> String {
    let s = if s.starts_with(['=', '+', '-', '@', '\t', '\r']) {
        format!("'{s}")
    } else {
        s.to_string()
    };
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s
    }
}

fn opt<T: ToString>(v: Option<T>) -> String {
    v.map(|v| v.to_string()).unwrap_or_default()
}

/// The CSV text of `rows` (header first, `\n` line ends).
pub fn sessions_csv(rows: &[ExportRow]) -> String {
    let mut out = String::with_capacity(200 * (rows.len() + 1));
    out += SESSIONS_CSV_HEADER;
    out.push('\n');
    for r in rows {
        let l = &r.line;
        let cells = [
            field(&l.id),
            field(&l.trainee),
            field(&r.cohorts),
            field(&l.scenario),
            field(&l.difficulty),
            field(l.status.as_str()),
            field(&l.recorded_at),
            field(&l.uploaded_at),
            l.duration_s.to_string(),
            opt(l.score),
            opt(l.passed),
            l.overridden.to_string(),
            opt(l.attempts),
            opt(l.risk_hits),
            opt(l.replay_verified),
            opt(l.rubric_version),
            l.physics_version.to_string(),
            r.outcome.exercise.as_str().to_string(),
            opt(r.outcome.target_reached),
            field(&r.outcome.risk_structures.join(";")),
            r.outcome.outcome.map(|o| o.as_str().to_string()).unwrap_or_default(),
            // Reasons are sentences for people; " | " keeps them on one line.
            field(&r.outcome.reasons.join(" | ")),
            opt(r.outcome.skill_z),
        ];
        out += &cells.join(",");
        out.push('\n');
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fields_are_quoted_and_formulas_defused() {
        assert_eq!(field("plain"), "plain");
        assert_eq!(field("a,b"), "\"a,b\"");
        assert_eq!(field("say \"hi\""), "\"say \"\"hi\"\"\"");
        assert_eq!(field("=HYPERLINK(1)"), "'=HYPERLINK(1)");
        assert_eq!(field("\t=1+2"), "'\t=1+2");
        assert_eq!(field("\r=1+2"), "\"'\r=1+2\"");
        assert_eq!(field("-1,2"), "\"'-1,2\"");
        assert_eq!(SESSIONS_CSV_HEADER.split(',').count(), 23);
    }
}
