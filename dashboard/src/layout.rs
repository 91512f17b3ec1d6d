//! The page shell (head, style sheet, role-aware navigation) and small pieces every page uses:
//! dates, scores, pass/fail badges, the sessions table, forms' CSRF field.

use axum::http::header;
use axum::response::{Html, IntoResponse, Response};
use maud::{DOCTYPE, Markup, PreEscaped, html};
use stylet_service::store::{Role, SessionLine, SessionStatus};

use crate::auth::Viewer;

/// Readable on a projector and on paper: large type, high contrast, no colour-only meaning
/// (badges carry words), print hides navigation and forms.
const STYLE: &str = r#"
:root { --ink:#1b1b1b; --muted:#555; --line:#d0d0d0; --bg:#fafafa; --ok:#1b7a33; --bad:#b3261e; --warn:#8a5a00; --accent:#1f5fa8; }
* { box-sizing: border-box; }
body { margin:0; font: 17px/1.45 system-ui, -apple-system, "Segoe UI", Roboto, Ubuntu, sans-serif; color:var(--ink); background:var(--bg); }
header.top { display:flex; align-items:center; gap:1.5rem; padding:.6rem 1.5rem; background:#16324f; color:white; }
header.top a { color:white; text-decoration:none; font-weight:600; }
header.top .brand { font-size:1.25rem; letter-spacing:.02em; }
header.top nav { display:flex; gap:1.1rem; flex:1; }
header.top .who { opacity:.9; }
header.top form { margin:0; }
header.top button { background:transparent; color:white; border:1px solid #ffffff88; border-radius:4px; padding:.2rem .7rem; cursor:pointer; font-size:.95rem; }
main { max-width:1280px; margin:0 auto; padding:1rem 1.5rem 3rem; }
h1 { font-size:1.7rem; margin:.6rem 0 1rem; }
h2 { font-size:1.3rem; margin:1.8rem 0 .6rem; border-bottom:2px solid var(--line); padding-bottom:.2rem; }
table { border-collapse:collapse; width:100%; background:white; }
th, td { text-align:left; padding:.35rem .6rem; border-bottom:1px solid var(--line); vertical-align:top; }
th { background:#eef2f6; font-weight:600; }
td.num, th.num { text-align:right; font-variant-numeric: tabular-nums; }
a { color:var(--accent); }
.badge { display:inline-block; padding:.05rem .5rem; border-radius:999px; font-size:.85rem; font-weight:600; border:1px solid; }
.badge.ok { color:var(--ok); border-color:var(--ok); background:#e8f5ec; }
.badge.bad { color:var(--bad); border-color:var(--bad); background:#fbeaea; }
.badge.warn { color:var(--warn); border-color:var(--warn); background:#fff4dc; }
.badge.muted { color:var(--muted); border-color:var(--line); background:#f2f2f2; }
.cards { display:flex; flex-wrap:wrap; gap:1rem; }
.card { background:white; border:1px solid var(--line); border-radius:6px; padding:.8rem 1rem; min-width:14rem; }
.card .big { font-size:2rem; font-weight:700; }
/* The trainee's next step leads the home page; the counts below it are smaller. */
#suggestion { border-left:4px solid var(--accent); margin:0 0 1rem; max-width:48rem; }
#suggestion p.next { font-size:1.4rem; font-weight:600; margin:.3rem 0; }
.cards.counts .big { font-size:1.5rem; }
.chart { width:100%; height:auto; max-width:1100px; background:white; border:1px solid var(--line); }
img.figure { width:100%; max-width:1100px; border:1px solid var(--line); background:black; }
form.inline { display:flex; flex-wrap:wrap; gap:.6rem; align-items:end; }
label { display:flex; flex-direction:column; font-size:.9rem; color:var(--muted); gap:.15rem; }
label.check { flex-direction:row; align-items:center; gap:.5rem; }
input, select, textarea, button { font: inherit; padding:.3rem .5rem; }
button.primary { background:var(--accent); color:white; border:none; border-radius:4px; padding:.4rem 1rem; cursor:pointer; }
.error { color:var(--bad); font-weight:600; }
.notice { background:#fff4dc; border:1px solid #e0c080; padding:.5rem .8rem; border-radius:4px; }
#pairing-code { font:700 2.6rem/1.2 ui-monospace, monospace; letter-spacing:.12em; margin:.4rem 0; }
.muted { color:var(--muted); }
td.result .reason { font-size:.85em; min-width:14em; max-width:28em; white-space:normal; margin-top:.15em; }
div.reason { font-size:.85em; margin-top:.15em; }
.reason a { white-space:nowrap; }
.grid2 { display:grid; grid-template-columns: 1fr 1fr; gap:1.5rem; }
@media (max-width: 900px) { .grid2 { grid-template-columns: 1fr; } }
/* Phones and tablets (390 px and up): the page never scrolls sideways; the navigation wraps, wide
   tables scroll inside their own box, charts and images scale, long words break. */
header.top { flex-wrap:wrap; }
header.top nav { flex-wrap:wrap; row-gap:.3rem; }
body { overflow-wrap:break-word; }
img, svg, video { max-width:100%; }
/* Charts carry only a viewBox and scale with their box. On a phone a chart is drawn 760 px wide,
   so that its labels stay about 9 px tall, and scrolls sideways inside its .chart-box. */
svg.chart { display:block; width:100%; height:auto; aspect-ratio: 1100 / 440; }
.chart-box { overflow-x:auto; max-width:100%; }
@media (max-width: 700px) { .chart-box > svg.chart { width:760px; max-width:none; } }
input, select, textarea { max-width:100%; }
.scroll { overflow-x:auto; max-width:100%; }
/* A grid cell may shrink below its content's width (a textarea's cols would widen the page). */
.grid2 > * { min-width:0; }
@media (max-width: 900px) { .grid2 { grid-template-columns: minmax(0, 1fr); } }
@media (max-width: 700px) {
  header.top { gap:.4rem .9rem; padding:.5rem .8rem; }
  header.top nav { gap:.3rem .9rem; flex-basis:100%; order:3; }
  main { padding:.6rem .7rem 2rem; }
  h1 { font-size:1.4rem; }
  table { display:block; overflow-x:auto; max-width:100%; }
  .card { min-width:0; flex:1 1 9rem; }
  form.inline > * { max-width:100%; }
  pre { white-space:pre-wrap; }
}
/* The replay player: four views in a 2 × 2 grid (one column on phones), controls, key moments. */
#player [hidden] { display:none !important; }
#player .frames { display:grid; grid-template-columns: repeat(2, minmax(0, 1fr)); gap:.6rem; max-width:1100px; }
#player figure { margin:0; background:black; border:1px solid var(--line); }
#player figure img { display:block; width:100%; height:auto; }
#player figcaption { background:#16324f; color:white; padding:.15rem .5rem; font-size:.9rem; }
#player .controls { display:flex; flex-wrap:wrap; align-items:center; gap:.6rem; margin:.6rem 0 .2rem; max-width:1100px; }
#player #timeline { flex:1 1 16rem; min-height:2rem; }
#player #clock { font-variant-numeric: tabular-nums; min-width:5.5rem; font-weight:600; }
#player label.speed { flex-direction:row; align-items:center; gap:.3rem; color:var(--ink); }
#player .moments { display:flex; flex-wrap:wrap; gap:.4rem; max-width:1100px; }
#player a.moment { border:1px solid var(--accent); border-radius:999px; padding:.15rem .7rem; text-decoration:none; font-size:.9rem; background:white; }
#player a.moment[data-kind="risk hit"] { border-color:var(--bad); color:var(--bad); }
#player a.moment[data-kind="target reached"] { border-color:var(--ok); color:var(--ok); }
#player a.moment[data-kind="comment"] { border-style:dashed; border-color:#1e5ac8; color:#1e5ac8; }
@media (max-width: 600px) { #player .frames { grid-template-columns: minmax(0, 1fr); } }
#overview { display:flex; flex-wrap:wrap; gap:1rem; align-items:flex-start; }
#overview figure { margin:0; background:black; border:1px solid var(--line); max-width:480px; width:100%; }
#overview figure img { display:block; width:100%; height:auto; cursor:grab; touch-action:pan-y; }
#overview figcaption { background:#16324f; color:white; padding:.2rem .5rem; font-size:.9rem; text-align:center; }
#overview a.turn { color:white; text-decoration:none; font-size:1.2rem; padding:0 .6rem; }
#overview .legend { list-style:none; padding:0; margin:0; max-width:26rem; }
#overview .legend li { margin:.2rem 0; }
.swatch { display:inline-block; width:1.6rem; height:.8rem; margin-right:.4rem; vertical-align:middle; border-radius:2px; }
#benchmark-table tr.far td { background:#fff4e0; }
@media print {
  header.top, form, .noprint { display:none !important; }
  body { background:white; font-size:12pt; }
  main { max-width:none; padding:0; }
  .chart { border:none; }
}
"#;

/// A whole page.
pub fn page(title: &str, viewer: Option<&Viewer>, body: Markup) -> Html<String> {
    let markup = html! {
        (DOCTYPE)
        html lang="en" {
            head {
                meta charset="utf-8";
                meta name="viewport" content="width=device-width, initial-scale=1";
                title { (title) " — Stylet" }
                style { (PreEscaped(STYLE)) }
                link rel="icon" type="image/svg+xml" href="/assets/favicon.svg";
                script src="/assets/dashboard.js" defer {}
            }
            body {
                @if let Some(v) = viewer { (navigation(v)) }
                main { (body) }
            }
        }
    };
    Html(markup.into_string())
}

/// A static asset: its content type, cached five minutes by anyone (no login needed: the login
/// and error pages use them too).
pub fn asset(content_type: &'static str, body: &'static str) -> Response {
    (
        [
            (header::CONTENT_TYPE, content_type),
            (header::CACHE_CONTROL, "public, max-age=300"),
        ],
        body,
    )
        .into_response()
}

/// `GET /assets/dashboard.js`: binds the buttons named by `data-action` (the pages'
/// Content-Security-Policy allows no inline handler).
pub async fn script() -> Response {
    asset("text/javascript; charset=utf-8", include_str!("dashboard.js"))
}

/// `GET /assets/favicon.svg`: the tab icon, a needle.
pub async fn favicon() -> Response {
    asset("image/svg+xml", include_str!("favicon.svg"))
}

/// A page that refreshes itself every `seconds` (a session being scored).
pub fn refreshing_page(title: &str, viewer: &Viewer, seconds: u32, body: Markup) -> Html<String> {
    let Html(text) = page(title, Some(viewer), body);
    Html(text.replacen(
        "<meta charset=\"utf-8\">",
        &format!("<meta charset=\"utf-8\"><meta http-equiv=\"refresh\" content=\"{seconds}\">"),
        1,
    ))
}

fn navigation(v: &Viewer) -> Markup {
    let role = v.user.role;
    html! {
        header.top {
            a.brand href="/" { "Stylet" }
            nav {
                a href="/" { "Home" }
                a href="/sessions" { "Sessions" }
                a href="/atlases" { "Catalogue" }
                @if role == Role::Trainee { a href={ "/trainees/" (crate::auth::encode_query(&v.user.username)) } { "My progress" } }
                @if matches!(role, Role::Instructor | Role::Admin) { a #nav-review-queue href="/review-queue" { "Needs review" } }
                @if role != Role::Trainee { a href="/cohorts" { "Cohorts" } }
                @if role != Role::Trainee { a href="/compare" { "Compare" } }
                @if matches!(role, Role::Curriculum | Role::Admin) { a href="/reports" { "Reports" } }
                @if role == Role::Admin { a href="/admin/users" { "Accounts" } }
                @if role == Role::Admin { a #nav-atlases href="/admin/atlases" { "Atlases" } }
                @if role == Role::Admin { a #nav-lti href="/admin/lti" { "LTI platforms" } }
                a #nav-pair href="/pair" { "Pair a simulator" }
                a href="/tokens" { "API tokens" }
            }
            span.who { (v.user.username) " (" (role) ")" }
            form method="post" action="/logout" {
                (csrf_field(v))
                button type="submit" { "Log out" }
            }
        }
    }
}

/// The hidden CSRF field every form posts (checked against the login's token).
pub fn csrf_field(v: &Viewer) -> Markup {
    html! { input type="hidden" name="csrf" value=(v.csrf); }
}

/// `2026-11-23T14:05:09.123456Z` → `2026-11-23 14:05` (UTC).
pub fn short_time(rfc3339: &str) -> String {
    // The simulator's `recorded_at` comes from the uploaded file: any text, not only ASCII.
    match (rfc3339.get(..10), rfc3339.get(10..11), rfc3339.get(11..16)) {
        (Some(date), Some("T"), Some(time)) => format!("{date} {time}"),
        _ => rfc3339.to_string(),
    }
}

/// A number with its noun in the right number: "1 session", "2 sessions", "0 sessions".
pub fn count<N: std::fmt::Display + PartialEq + From<u8>>(n: N, one: &str, many: &str) -> String {
    let noun = if n == N::from(1u8) { one } else { many };
    format!("{n} {noun}")
}

pub fn score_text(score: Option<f64>) -> String {
    score.map_or_else(|| "–".into(), |s| format!("{s:.1}"))
}

/// Pass/fail in words and colour; "overridden" marked.
pub fn result_badge(passed: Option<bool>, overridden: bool) -> Markup {
    html! {
        @match passed {
            Some(true) => span.badge.ok { "passed" },
            Some(false) => span.badge.bad { "failed" },
            None => span.badge.muted { "not scored" },
        }
        @if overridden { " " span.badge.warn title="grade overridden by an instructor" { "overridden" } }
    }
}

/// The outcome of a listed session: an instructor's override decides passed/failed; an
/// incomplete recording is "not gradeable", never failed.
pub fn outcome_badge(outcome: Option<stylet_scoring::Outcome>, passed: Option<bool>, overridden: bool) -> Markup {
    match outcome {
        Some(stylet_scoring::Outcome::NotGradeable) if !overridden => {
            html! { span.badge.warn title="the recording is incomplete: no grade is given" { "not gradeable" } }
        }
        _ => result_badge(passed, overridden),
    }
}

pub fn status_badge(status: SessionStatus) -> Markup {
    html! {
        @match status {
            SessionStatus::Scored => span.badge.ok { "scored" },
            SessionStatus::Failed => span.badge.bad { "scoring failed" },
            SessionStatus::Queued | SessionStatus::Scoring => span.badge.muted { (status) },
        }
    }
}

pub fn verified_badge(verified: Option<bool>) -> Markup {
    html! {
        @match verified {
            Some(true) => span.badge.ok title="the replay reproduced every recorded output bit for bit" { "replay verified" },
            Some(false) => span.badge.bad title="the replay diverged from the recording" { "replay diverged" },
            None => span.badge.muted { "–" },
        }
    }
}

/// Longest reason a list row shows, in characters (the session page has every reason whole).
pub const SHORT_REASON_CHARS: usize = 90;

/// A reason's first clause for a list row: the text up to the first ". ", ": −" (where the list
/// of deductions starts) or " (" (a parenthesis), each only after 20 characters or more, ended
/// with a full stop; longer than [`SHORT_REASON_CHARS`], it is cut at a word and ends with "…".
pub fn short_reason(reason: &str) -> String {
    let cut = [". ", ": −", " ("]
        .iter()
        .filter_map(|p| reason.find(p))
        .filter(|&k| k >= 20)
        .min()
        .unwrap_or(reason.len());
    let clause = reason[..cut].trim_end_matches(['.', ' ', ':', ',', ';']);
    if clause.chars().count() > SHORT_REASON_CHARS {
        let head: String = clause.chars().take(SHORT_REASON_CHARS).collect();
        let words = head.rfind(' ').map_or(head.as_str(), |k| &head[..k]);
        format!("{}…", words.trim_end_matches([',', ';', ':']))
    } else {
        format!("{clause}.")
    }
}

/// The reasons of a list row: the first one short (whole on hover), and a link to the others
/// on the session's page ("+2 more"); nothing when there is none.
pub fn reason_cell(id: &str, reasons: &[String]) -> Markup {
    html! {
        @if let Some(first) = reasons.first() {
            div.reason.muted title=(first) {
                (short_reason(first))
                @if reasons.len() > 1 {
                    " " a href={ "/sessions/" (id) "#reasons" } { "+" (reasons.len() - 1) " more" }
                }
            }
        }
    }
}

/// The sessions table (newest first as given); `show_trainee` for instructors and staff.
pub fn sessions_table(lines: &[SessionLine], show_trainee: bool) -> Markup {
    html! {
        @if lines.is_empty() {
            p.muted { "No sessions yet." }
        } @else {
            table.sessions {
                thead { tr {
                    th { "Uploaded (UTC)" }
                    @if show_trainee { th { "Trainee" } }
                    th { "Scenario" } th { "Difficulty" } th { "Status" }
                    th.num { "Score" } th { "Result" } th.num { "Attempts" } th.num { "Risk hits" } th { "Replay" }
                } }
                tbody {
                    @for l in lines {
                        tr {
                            td { a href={ "/sessions/" (l.id) } { (short_time(&l.uploaded_at)) } }
                            @if show_trainee { td { (l.trainee) } }
                            td { (l.scenario) } td { (l.difficulty) } td { (status_badge(l.status)) }
                            td.num { (score_text(l.score)) }
                            td.result {
                                (outcome_badge(l.outcome, l.passed, l.overridden))
                                @if l.exercise != stylet_scoring::Exercise::Puncture {
                                    " " span.badge.muted { (l.exercise.label()) }
                                }
                                // Why, in words, where it failed or cannot be graded: the first
                                // reason short, the others on the session's page.
                                @if l.outcome.is_some_and(|o| o != stylet_scoring::Outcome::Passed) || l.passed == Some(false) {
                                    (reason_cell(&l.id, &l.reasons))
                                }
                            }
                            td.num { (l.attempts.map_or("–".into(), |v| v.to_string())) }
                            td.num { (l.risk_hits.map_or("–".into(), |v| v.to_string())) }
                            td { (verified_badge(l.replay_verified)) }
                        }
                    }
                }
            }
        }
    }
}

/// "Page 2 of 7" with previous/next links keeping the other query parameters.
pub fn pager(base_query: &str, page: i64, total: i64, page_size: i64) -> Markup {
    let pages = ((total + page_size - 1) / page_size).max(1);
    let link = |p: i64| {
        if base_query.is_empty() {
            format!("?page={p}")
        } else {
            format!("?{base_query}&page={p}")
        }
    };
    html! {
        p.pager.noprint {
            @if page > 1 { a href=(link(page - 1)) { "← newer" } " " }
            "Page " (page) " of " (pages) " (" (count(total, "session", "sessions")) ")"
            @if page < pages { " " a href=(link(page + 1)) { "older →" } }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn charts_scale_with_their_box_and_stay_readable_on_phones() {
        // Sized by the style sheet with the charts' proportions (they carry only a viewBox).
        let (w, h) = crate::charts::CHART_SIZE;
        assert!(STYLE.contains(&format!(
            "svg.chart {{ display:block; width:100%; height:auto; aspect-ratio: {w} / {h}; }}"
        )));
        // On a phone: 760 px wide, scrolled sideways inside the chart's own box; the axis labels
        // (plotters' size 16, an SVG font-size of 16 / 1.24) are then 8.9 px, which
        // tests/integration/phone.rs measures in a browser.
        assert!(STYLE.contains(".chart-box { overflow-x:auto; max-width:100%; }"));
        assert!(
            STYLE.contains("@media (max-width: 700px) { .chart-box > svg.chart { width:760px; max-width:none; } }")
        );
    }

    #[test]
    fn short_times_never_split_a_character() {
        assert_eq!(short_time("2026-11-23T14:05:09.123456Z"), "2026-11-23 14:05");
        // A file may carry any text as its recording time.
        assert_eq!(short_time("2025-01-01T00:0é"), "2025-01-01T00:0é");
        assert_eq!(short_time("2025-01-0éT00:00:00Z"), "2025-01-0éT00:00:00Z");
        assert_eq!(short_time("soon"), "soon");
    }

    /// A scored line of `/sessions` that is not gradeable, with three long reasons.
    fn line(reasons: &[&str]) -> SessionLine {
        SessionLine {
            id: "s-1".into(),
            trainee: "tina".into(),
            scenario: "success-intercostal".into(),
            difficulty: "beginner".into(),
            status: SessionStatus::Scored,
            uploaded_at: "2026-11-23T14:05:09Z".into(),
            recorded_at: "2026-11-23T14:00:00Z".into(),
            duration_s: 20.0,
            error: None,
            score: None,
            passed: None,
            overridden: false,
            attempts: Some(1),
            risk_hits: Some(1),
            replay_verified: Some(true),
            rubric_version: Some(6),
            physics_version: 1,
            exercise: stylet_scoring::Exercise::Puncture,
            outcome: Some(stylet_scoring::Outcome::NotGradeable),
            reasons: reasons.iter().map(|r| r.to_string()).collect(),
        }
    }

    #[test]
    fn a_list_row_shows_one_short_reason_and_links_to_the_others() {
        let l = line(&[
            "Not gradeable: the recording is incomplete (the file is damaged at byte 81920: a chunk's CRC does not match). Record the exercise again; `stylet session recover` keeps the intact part.",
            "The needle entered the right lung at 3.2 s, 4.1 mm deep (pneumothorax risk).",
            "Score 42 is below the pass mark of 70 for beginner: −15 for 2 attempts (1 free), −40 because the target was not reached.",
        ]);
        let html = sessions_table(&[l], false).into_string();
        assert_eq!(html.matches("class=\"reason").count(), 1, "{html}");
        assert!(
            html.contains(">Not gradeable: the recording is incomplete. <"),
            "{html}"
        );
        assert!(
            html.contains("href=\"/sessions/s-1#reasons\"") && html.contains("+2 more"),
            "{html}"
        );
        assert!(!html.contains("pneumothorax"), "{html}");
        // One reason: no link.
        let one = sessions_table(&[line(&["2 attempts: at most 1 allowed."])], false).into_string();
        assert!(
            one.contains(">2 attempts: at most 1 allowed.<") && !one.contains("more</a>"),
            "{one}"
        );
    }

    #[test]
    fn short_reasons_keep_the_first_clause() {
        assert_eq!(
            short_reason("Score 42 is below the pass mark of 70 for beginner: −15 for 2 attempts (1 free)."),
            "Score 42 is below the pass mark of 70 for beginner."
        );
        assert_eq!(
            short_reason("The needle entered the right lung at 3.2 s, 4.1 mm deep (pneumothorax risk)."),
            "The needle entered the right lung at 3.2 s, 4.1 mm deep."
        );
        assert_eq!(
            short_reason(
                "Score 90 (pass mark 60 for beginner): −5 because there was no palpation before the puncture."
            ),
            "Score 90 (pass mark 60 for beginner)."
        );
        assert_eq!(
            short_reason("2 attempts: at most 1 allowed."),
            "2 attempts: at most 1 allowed."
        );
        // A clause longer than the limit is cut at a word, whatever its characters.
        let long = "Ä".repeat(10) + &" wörter".repeat(30);
        let short = short_reason(&long);
        assert!(
            short.ends_with('…') && short.chars().count() <= SHORT_REASON_CHARS + 1,
            "{short}"
        );
        assert!(short.trim_end_matches('…').ends_with("wörter"), "{short}");
    }

    #[test]
    fn counts_name_one_thing_in_the_singular() {
        assert_eq!(count(1_i64, "session", "sessions"), "1 session");
        assert_eq!(count(0_i64, "session", "sessions"), "0 sessions");
        assert_eq!(count(2_usize, "X-ray shot", "X-ray shots"), "2 X-ray shots");
        assert_eq!(count(1_u32, "X-ray shot", "X-ray shots"), "1 X-ray shot");
        let one = pager("", 1, 1, 100).into_string();
        assert!(one.contains("(1 session)") && !one.contains("1 sessions"), "{one}");
        assert!(pager("", 1, 7, 100).into_string().contains("(7 sessions)"));
    }
}
