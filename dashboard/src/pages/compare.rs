//! `GET /compare`: up to [`MAX_COMPARED`] sessions' force curves against insertion depth, aligned
//! at skin entry (depth 0 is where each needle entered the body, whenever that was in its
//! session), and a search (trainee, scenario, dates, outcome; 20 results a page) to pick them.
//!
//! Everything travels in the query, so a comparison is a link: `s=ID` once per session ticked
//! (`a=ID&b=ID` as before also works), `trainee=…&scenario=…&from=…&to=…&outcome=…&page=N`.

use std::sync::Arc;

use crate::plot::{ChartColor, ChartError};
use axum::extract::{Query, State};
use axum::http::StatusCode;
use axum::response::Html;
use maud::{Markup, PreEscaped, html};
use stylet_scoring::{Outcome, ReviewTrace};
use stylet_service::AppState;
use stylet_service::store::{CompareSearch, OutcomeFilter, ReviewLine, SEARCH_PAGE, SessionRow};
use stylet_service::traces::review_trace;

use crate::auth::{PageError, Viewer, encode_query, fail};
use crate::layout::{page, pager, score_text, short_time};
use crate::pages::instructors::outcome_badge;
use crate::session_access::{require_scored, visible_session};

/// Sessions on one chart at most (more lines cannot be told apart).
pub const MAX_COMPARED: usize = 4;

/// One colour per compared session (Okabe–Ito: told apart with colour-blindness too); the
/// total force is drawn solid, the cutting force dashed in the same colour.
const COLORS: [ChartColor; MAX_COMPARED] = [
    ChartColor(0, 114, 178),
    ChartColor(213, 94, 0),
    ChartColor(0, 158, 115),
    ChartColor(204, 121, 167),
];
const TAGS: [&str; MAX_COMPARED] = ["A", "B", "C", "D"];

pub const DEPTH_X_LABEL: &str = "insertion depth: needle length inside the body (mm), 0 = skin entry";
pub const FORCE_Y_LABEL: &str = "force along the needle (N)";

/// The comparison's query: the sessions ticked and the search.
#[derive(Debug, Default)]
struct CompareQuery {
    sessions: Vec<String>,
    trainee: String,
    scenario: String,
    from: String,
    to: String,
    outcome: String,
    page: i64,
}

impl CompareQuery {
    fn parse(pairs: Vec<(String, String)>) -> Result<CompareQuery, PageError> {
        let mut q = CompareQuery {
            page: 1,
            ..Default::default()
        };
        for (k, v) in pairs {
            let v = v.trim().to_string();
            match k.as_str() {
                "s" | "a" | "b" if !v.is_empty() && !q.sessions.contains(&v) => q.sessions.push(v),
                "trainee" => q.trainee = v,
                "scenario" => q.scenario = v,
                "from" => q.from = v,
                "to" => q.to = v,
                "outcome" => q.outcome = v,
                "page" => {
                    q.page = v
                        .parse::<i64>()
                        .map_err(|_| fail(StatusCode::BAD_REQUEST, format!("page '{v}' is not a number")))?
                        .max(1)
                }
                _ => {}
            }
        }
        if q.sessions.len() > MAX_COMPARED {
            return Err(fail(
                StatusCode::BAD_REQUEST,
                format!(
                    "{} sessions ticked: at most {MAX_COMPARED} can be compared at once; untick some",
                    q.sessions.len()
                ),
            ));
        }
        Ok(q)
    }

    /// The query string of the search and the ticked sessions (no page), for links.
    fn link_query(&self) -> String {
        let mut parts: Vec<String> = self
            .sessions
            .iter()
            .map(|id| format!("s={}", encode_query(id)))
            .collect();
        for (k, v) in [
            ("trainee", &self.trainee),
            ("scenario", &self.scenario),
            ("from", &self.from),
            ("to", &self.to),
            ("outcome", &self.outcome),
        ] {
            if !v.is_empty() {
                parts.push(format!("{k}={}", encode_query(v)));
            }
        }
        parts.join("&")
    }
}

/// Depth (mm) a needle must come back by before its curve counts as withdrawn (a pause or the
/// bucket's noise is not a withdrawal).
const WITHDRAW_MM: f64 = 0.5;

/// The advancing strokes of a session: runs of buckets (indices) over which the needle goes
/// deeper, from the bucket just before it enters the skin (depth 0, the skin's peak force) or the
/// turning point after a withdrawal. Withdrawals are left out: their force (friction backwards)
/// would draw the same depths again and hide the insertion curves.
pub fn advancing_strokes(trace: &ReviewTrace) -> Vec<Vec<usize>> {
    let d = &trace.inserted_mm;
    let mut strokes: Vec<Vec<usize>> = Vec::new();
    let mut current: Vec<usize> = Vec::new();
    let (mut deepest, mut lowest) = (0.0_f64, f64::INFINITY);
    let mut close = |current: &mut Vec<usize>| {
        // A stroke ends where it first reaches its depth: holding there, and the turn into a
        // withdrawal, are not advancing.
        let max = current.iter().map(|i| d[*i]).fold(f64::NEG_INFINITY, f64::max);
        if let Some(end) = current.iter().position(|i| d[*i] >= max) {
            current.truncate(end + 1);
        }
        if current.len() >= 2 {
            strokes.push(std::mem::take(current));
        }
        current.clear();
    };
    for i in 0..d.len() {
        let depth = d[i];
        let inside = depth > 0.0;
        let entering = !inside && d.get(i + 1).is_some_and(|n| *n > 0.0);
        if !inside && !entering {
            close(&mut current);
            lowest = f64::INFINITY;
            continue;
        }
        if !current.is_empty() {
            if depth >= deepest - WITHDRAW_MM {
                current.push(i);
                deepest = deepest.max(depth);
            } else {
                // Withdrawing: the stroke ends; a new one starts where the needle turns.
                close(&mut current);
                lowest = depth;
            }
        } else if lowest.is_finite() {
            if depth < lowest {
                lowest = depth;
            } else if depth > lowest + WITHDRAW_MM {
                current = vec![i - 1, i];
                deepest = depth;
                lowest = f64::INFINITY;
            }
        } else {
            current.push(i);
            deepest = depth;
        }
    }
    close(&mut current);
    strokes
}

pub const COMPARE_TITLE: &str = "Force against insertion depth, aligned at skin entry (advancing needle)";

/// Force against insertion depth, one colour per session: the total force solid, the cutting
/// force dashed, each advancing stroke a line of its own, a marker at the skin (depth 0).
pub fn depth_aligned_svg(sessions: &[(&ReviewTrace, String)]) -> Result<String, ChartError> {
    use plotters::prelude::*;
    use stylet_render::fonts::{SANS, ensure_fonts};
    ensure_fonts();
    let strokes: Vec<Vec<Vec<usize>>> = sessions.iter().map(|(t, _)| advancing_strokes(t)).collect();
    let (mut x1, mut y0, mut y1) = (10.0_f64, 0.0_f64, 0.5_f64);
    for ((t, _), st) in sessions.iter().zip(&strokes) {
        for i in st.iter().flatten() {
            x1 = x1.max(t.inserted_mm[*i]);
            for v in [t.force_n[*i], t.cutting_n[*i]] {
                if v.is_finite() {
                    (y0, y1) = (y0.min(v), y1.max(v));
                }
            }
        }
    }
    let pad = (y1 - y0) * 0.08;
    let (x0, x1, y0, y1) = (-0.03 * x1, x1 * 1.03, y0 - pad, y1 + pad);
    let mut out = String::new();
    {
        let root = SVGBackend::with_string(&mut out, crate::charts::CHART_SIZE).into_drawing_area();
        root.fill(&WHITE)?;
        let mut c = ChartBuilder::on(&root)
            .caption(COMPARE_TITLE, (SANS, 24))
            .margin(16)
            .x_label_area_size(56)
            .y_label_area_size(72)
            .build_cartesian_2d(x0..x1, y0..y1)?;
        c.configure_mesh()
            .x_desc(DEPTH_X_LABEL)
            .y_desc(FORCE_Y_LABEL)
            .axis_desc_style((SANS, 20))
            .label_style((SANS, 16))
            .light_line_style(RGBColor(235, 235, 235))
            .draw()?;
        let grey = ShapeStyle::from(&RGBColor(150, 150, 150)).stroke_width(1);
        c.draw_series(std::iter::once(PathElement::new(vec![(0.0, y0), (0.0, y1)], grey)))?;
        c.draw_series(std::iter::once(Text::new(
            " skin entry",
            (0.0, y1 - (y1 - y0) * 0.03),
            (SANS, 14).into_font(),
        )))?;
        for (k, ((t, name), st)) in sessions.iter().zip(&strokes).enumerate() {
            let color = COLORS[k % COLORS.len()];
            let (bold, thin) = (
                ShapeStyle::from(&color).stroke_width(3),
                ShapeStyle::from(&color).stroke_width(2),
            );
            for (n, stroke) in st.iter().enumerate() {
                let pts = |v: &[f64]| stroke.iter().map(|i| (t.inserted_mm[*i], v[*i])).collect::<Vec<_>>();
                let total = c.draw_series(LineSeries::new(pts(&t.force_n), bold))?;
                if n == 0 {
                    total
                        .label(format!("total — {name}"))
                        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], bold));
                }
                let cutting = c.draw_series(DashedLineSeries::new(pts(&t.cutting_n), 8, 5, thin))?;
                if n == 0 {
                    cutting
                        .label(format!("cutting — {name}"))
                        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 9, y)], bold));
                }
            }
        }
        c.configure_series_labels()
            .background_style(WHITE.mix(0.9))
            .border_style(BLACK)
            .label_font((SANS, 16))
            .position(SeriesLabelPosition::UpperRight)
            .draw()?;
        root.present()?;
    }
    Ok(crate::trends::labelled_svg(&out, COMPARE_TITLE))
}

/// Deepest insertion (mm) and peak force (N) of a trace.
fn extremes(t: &ReviewTrace) -> (f64, f64) {
    let deepest = t.inserted_mm.iter().copied().fold(0.0, f64::max);
    let peak = t
        .force_n
        .iter()
        .copied()
        .fold(0.0, |a: f64, b| if b.abs() > a.abs() { b } else { a });
    (deepest, peak)
}

pub async fn compare(
    State(s): State<Arc<AppState>>,
    v: Viewer,
    Query(pairs): Query<Vec<(String, String)>>,
) -> Result<Html<String>, PageError> {
    let q = CompareQuery::parse(pairs)?;
    let mut rows: Vec<SessionRow> = Vec::with_capacity(q.sessions.len());
    for id in &q.sessions {
        let row = visible_session(&s, &v, id).await?;
        require_scored(&row)?;
        rows.push(row);
    }
    let chart = if rows.len() >= 2 {
        let mut traces = Vec::with_capacity(rows.len());
        for r in &rows {
            traces.push(
                review_trace(&s, &r.file_sha256, &r.atlas_hash)
                    .await
                    .map_err(|e| fail(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))?,
            );
        }
        let named: Vec<(&ReviewTrace, String)> = traces
            .iter()
            .zip(&rows)
            .enumerate()
            .map(|(k, (t, r))| (t, format!("{} {} {}", TAGS[k], r.trainee, r.scenario)))
            .collect();
        let svg = depth_aligned_svg(&named).map_err(|e| fail(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))?;
        Some((svg, traces.iter().map(extremes).collect::<Vec<_>>()))
    } else {
        None
    };
    let search = search_of(&s, &q).await?;
    let (results, total) = s
        .store
        .compare_search(&v.user, &search, SEARCH_PAGE, (q.page - 1).saturating_mul(SEARCH_PAGE))
        .await?;
    let scenarios = s.store.scenarios(&v.user, None).await?;
    Ok(page(
        "Compare sessions",
        Some(&v),
        html! {
            h1 { "Compare sessions" }
            @match &chart {
                Some((svg, extremes)) => {
                    div.chart-box #compare-chart { (PreEscaped(svg)) }
                    p.muted { "Each session's force is drawn against how far its needle is inside the body, so all curves start together at the skin whenever the needle entered. Solid: total force; dashed: cutting force; one colour per session. Only the advancing needle is drawn: each advance, from the skin or from where the needle turned after pulling back, is a line of its own, up to the depth it reached." }
                    (compared_table(&rows, extremes))
                }
                None => p.notice #compare-hint {
                    @if rows.is_empty() { "Find sessions below, tick two to " (MAX_COMPARED) " and press Compare." }
                    @else { "One session ticked: tick at least one more and press Compare." }
                }
            }
            h2 { "Find sessions" }
            form #compare-search method="get" action="/compare" {
                div.search-fields style="display:flex;flex-wrap:wrap;gap:.6rem;align-items:end" {
                    label { "Trainee (username)" input type="text" name="trainee" value=(q.trainee) size="14"; }
                    label { "Scenario"
                        select name="scenario" {
                            option value="" { "all" }
                            @for sc in &scenarios { option value=(sc) selected[q.scenario == *sc] { (sc) } }
                        }
                    }
                    label { "From" input type="date" name="from" value=(q.from); }
                    label { "To" input type="date" name="to" value=(q.to); }
                    label { "Outcome"
                        select name="outcome" {
                            @for o in OutcomeFilter::ALL { option value=(o.as_str()) selected[q.outcome == o.as_str()] { (o.words()) } }
                        }
                    }
                    button type="submit" name="search" value="1" { "Search" }
                }
                @if !rows.is_empty() {
                    h3 { "Ticked" }
                    ul #ticked {
                        @for (k, r) in rows.iter().enumerate() {
                            li { label.check {
                                input type="checkbox" name="s" value=(r.id) checked;
                                (TAGS[k]) ": " (r.trainee) " · " (r.scenario) " · " (r.difficulty) " · " (short_time(&r.uploaded_at))
                            } }
                        }
                    }
                }
                (results_table(&results, &q.sessions))
                p { button.primary type="submit" #compare-button { "Compare ticked sessions" } }
            }
            (pager(&q.link_query(), q.page, total, SEARCH_PAGE))
        },
    ))
}

/// The store's search of a query; a bad date or outcome is a 400 that says which.
async fn search_of(s: &AppState, q: &CompareQuery) -> Result<CompareSearch, PageError> {
    // The lists' own parsing of dates and trainees (an unknown trainee matches nothing).
    let list = stylet_service::api::ListQuery {
        from: Some(q.from.clone()),
        to: Some(q.to.clone()),
        trainee: Some(q.trainee.clone()),
        ..Default::default()
    };
    let f = list.filter(s).await?;
    let outcome = OutcomeFilter::parse(&q.outcome).map_err(|e| fail(StatusCode::BAD_REQUEST, e.to_string()))?;
    Ok(CompareSearch {
        trainee_id: f.trainee_id,
        scenario: Some(q.scenario.clone()).filter(|v| !v.is_empty()),
        uploaded_from: f.uploaded_from,
        uploaded_before: f.uploaded_before,
        outcome,
    })
}

fn compared_table(rows: &[SessionRow], extremes: &[(f64, f64)]) -> Markup {
    html! {
        div.scroll { table #compared {
            thead { tr {
                th { "" } th { "Trainee" } th { "Scenario" } th { "Difficulty" } th { "Uploaded (UTC)" }
                th.num { "Computed score" } th { "Computed result" } th.num { "Deepest insertion (mm)" } th.num { "Peak force (N)" }
            } }
            tbody {
                @for (k, (r, (deepest, peak))) in rows.iter().zip(extremes).enumerate() {
                    @let c = COLORS[k % COLORS.len()];
                    @let grade = r.score.as_ref().map(|s| &s["grade"]);
                    tr {
                        td { span style={ "display:inline-block;width:1.6em;height:.35em;vertical-align:middle;background:rgb(" (c.0) "," (c.1) "," (c.2) ")" } {} " " a href={ "/sessions/" (r.id) } { (TAGS[k]) } }
                        td { (r.trainee) } td { (r.scenario) } td { (r.difficulty) } td { (short_time(&r.uploaded_at)) }
                        td.num { (score_text(grade.and_then(|g| g["score"].as_f64()))) }
                        td { @match r.outcome {
                            Some(Outcome::Passed) => span.badge.ok { "passed" },
                            Some(Outcome::Failed) => span.badge.bad { "failed" },
                            Some(Outcome::NotGradeable) => span.badge.warn { "not gradeable" },
                            None => span.badge.muted { "–" },
                        } }
                        td.num { (format!("{deepest:.1}")) } td.num { (format!("{peak:.2}")) }
                    }
                }
            }
        } }
    }
}

fn results_table(results: &[ReviewLine], ticked: &[String]) -> Markup {
    html! {
        @if results.is_empty() {
            p.muted #search-results { "No scored session matches." }
        } @else {
            div.scroll { table #search-results {
                thead { tr {
                    th { "Tick" } th { "Uploaded (UTC)" } th { "Trainee" } th { "Scenario" } th { "Difficulty" }
                    th.num { "Score" } th { "Result" } th.num { "Risk hits" }
                } }
                tbody {
                    @for l in results {
                        tr {
                            td { @if ticked.contains(&l.id) { "ticked" } @else { input type="checkbox" name="s" value=(l.id) aria-label={ "compare the session of " (l.trainee) " uploaded " (short_time(&l.uploaded_at)) }; } }
                            td { a href={ "/sessions/" (l.id) } { (short_time(&l.uploaded_at)) } }
                            td { (l.trainee) } td { (l.scenario) } td { (l.difficulty) }
                            td.num { (score_text(l.score)) }
                            td { (outcome_badge(l)) }
                            td.num { (l.risk_hits.map_or("–".into(), |n| n.to_string())) }
                        }
                    }
                }
            } }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn trace(entry_bucket: usize) -> ReviewTrace {
        let n = 60;
        let inserted: Vec<f64> = (0..n)
            .map(|k| {
                if k < entry_bucket {
                    0.0
                } else {
                    (k - entry_bucket) as f64 * 2.0
                }
            })
            .collect();
        ReviewTrace {
            version: stylet_scoring::trace::TRACE_VERSION,
            physics_version: 2,
            bucket_s: 0.02,
            t_s: (0..n).map(|k| k as f64 * 0.02).collect(),
            force_n: inserted.iter().map(|d| 0.1 * d).collect(),
            cutting_n: inserted.iter().map(|d| if *d == 10.0 { 3.0 } else { 0.0 }).collect(),
            friction_n: vec![0.0; n],
            base_n: vec![0.0; n],
            tip_depth_mm: inserted.clone(),
            inserted_mm: inserted,
            tip_mm: vec![None; n],
            events: Vec::new(),
            punctures: Vec::new(),
            risk_points: Vec::new(),
            sent_n: Vec::new(),
            guard: Vec::new(),
            tip_hidden: Vec::new(),
            phases: Vec::new(),
        }
    }

    #[test]
    fn curves_start_together_at_the_skin_whenever_the_needle_entered() {
        // The same insertion, entering 0.2 s and 0.8 s into the session.
        let (early, late) = (trace(10), trace(40));
        let (a, b) = (advancing_strokes(&early), advancing_strokes(&late));
        assert_eq!((a.len(), b.len()), (1, 1));
        // Each starts at the bucket before the entry: depth 0, the skin.
        assert_eq!((a[0][0], b[0][0]), (10, 40));
        let curve =
            |t: &ReviewTrace, s: &[usize]| s.iter().map(|i| (t.inserted_mm[*i], t.force_n[*i])).collect::<Vec<_>>();
        let (ca, cb) = (curve(&early, &a[0]), curve(&late, &b[0]));
        assert_eq!(ca[0], (0.0, 0.0));
        // Aligned: the same depth has the same force in both, although their times differ.
        assert_eq!(ca[..20], cb[..20]);
        let svg = depth_aligned_svg(&[(&early, "A tina".into()), (&late, "B tom".into())]).unwrap();
        for want in [
            COMPARE_TITLE,
            DEPTH_X_LABEL,
            FORCE_Y_LABEL,
            "total — A tina",
            "cutting — B tom",
            "skin entry",
        ] {
            assert!(svg.contains(want), "{want}");
        }
        // One legend entry per session and component.
        assert_eq!(svg.matches("total — A tina").count(), 1);
        assert!(svg.starts_with("<svg class=\"chart\" role=\"img\""));
        let tag = &svg[..svg.find('>').unwrap()];
        assert!(
            tag.contains("viewBox=\"0 0 1100 440\"") && !tag.contains("width="),
            "{tag}"
        );
        assert_eq!(extremes(&early).0, 98.0);
    }

    #[test]
    fn withdrawals_are_left_out_and_a_new_advance_is_a_stroke_of_its_own() {
        // In to 40 mm, back to 10 mm, in again to 60 mm, out; a pause at 40 mm is no withdrawal.
        let mut depths = vec![0.0, 0.0];
        depths.extend((1..=20).map(|k| 2.0 * k as f64));
        depths.extend([40.0, 39.8, 40.0]);
        depths.extend((1..=15).map(|k| 40.0 - 2.0 * k as f64));
        depths.extend((1..=25).map(|k| 10.0 + 2.0 * k as f64));
        depths.extend((0..30).map(|k| (60.0 - 2.0 * k as f64).max(0.0)));
        depths.extend([0.0, 0.0]);
        let mut t = trace(0);
        let n = depths.len();
        t.t_s = (0..n).map(|k| k as f64 * 0.02).collect();
        t.force_n = depths.clone();
        t.cutting_n = vec![0.0; n];
        t.inserted_mm = depths;
        let strokes = advancing_strokes(&t);
        assert_eq!(strokes.len(), 2, "{strokes:?}");
        let span = |s: &Vec<usize>| (t.inserted_mm[s[0]], t.inserted_mm[*s.last().unwrap()]);
        assert_eq!(span(&strokes[0]), (0.0, 40.0));
        assert_eq!(span(&strokes[1]), (10.0, 60.0));
        for s in &strokes {
            assert!(
                s.windows(2)
                    .all(|w| t.inserted_mm[w[1]] >= t.inserted_mm[w[0]] - WITHDRAW_MM)
            );
        }
    }

    #[test]
    fn the_query_keeps_up_to_four_sessions_and_says_when_there_are_more() {
        let pair = |k: &str, v: &str| (k.to_string(), v.to_string());
        let q = CompareQuery::parse(vec![
            pair("a", "x"),
            pair("b", "y"),
            pair("s", "x"),
            pair("trainee", "tina"),
        ])
        .unwrap();
        assert_eq!(q.sessions, vec!["x", "y"]);
        assert_eq!(q.link_query(), "s=x&s=y&trainee=tina");
        let five: Vec<_> = ["1", "2", "3", "4", "5"].iter().map(|v| pair("s", v)).collect();
        match CompareQuery::parse(five) {
            Err(PageError::Status(status, msg)) => {
                assert_eq!(status, StatusCode::BAD_REQUEST);
                assert!(msg.contains("at most 4"), "{msg}");
            }
            _ => panic!("five sessions accepted"),
        }
        assert!(CompareQuery::parse(vec![pair("page", "two")]).is_err());
    }
}
