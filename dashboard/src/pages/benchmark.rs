//! The session review's "Against the expert benchmark" section (docs/dashboard.md): the
//! session's metrics beside the expert mean and spread of its scenario, whether the grade was
//! measured against them, the scenario's expert references, and for reviewers the form that
//! marks or unmarks this session as one (`POST /sessions/{id}/expert`).

use std::sync::Arc;

use axum::Form;
use axum::extract::{Path, State};
use axum::response::Redirect;
use maud::{Markup, html};
use stylet_scoring::benchmark::Comparison;
use stylet_scoring::reasons::metric_info;
use stylet_scoring::rubric::Level;
use stylet_scoring::{Benchmark, ScoreReport, metric_label};
use stylet_service::AppState;
use stylet_service::store::ExpertReference;

use crate::auth::{PageError, Viewer, check_csrf, fail};
use crate::layout::{csrf_field, short_time};

/// How many spreads from the expert mean a value may lie before the table marks it.
pub const MARK_SPREADS: f64 = 2.0;

/// What the section shows.
pub struct BenchmarkView<'a> {
    pub session_id: &'a str,
    pub report: &'a ScoreReport,
    pub benchmark: &'a Benchmark,
    pub references: &'a [ExpertReference],
    /// The level of the rubric that graded the session (its metrics are the rows), if known.
    pub level: Option<&'a Level>,
    /// May mark and unmark (the session's instructors, admins).
    pub reviewer: bool,
    /// The references the viewer may know by name (`None` for a trainee).
    pub listed: Option<&'a [ExpertReference]>,
    /// Whether the viewer sees the figures (a trainee only from
    /// `stylet_service::experts::MIN_SHOWN_TO_TRAINEES` references on).
    pub figures_shown: bool,
}

/// Whether a comparison lies far from the experts: more than [`MARK_SPREADS`] spreads from
/// their mean, or (when they all agree) anywhere but their value.
pub fn far_from_experts(c: &Comparison) -> bool {
    match c.spreads_from_mean() {
        Some(z) => z.abs() > MARK_SPREADS,
        None => (c.value - c.mean).abs() > 1e-6 * c.mean.abs().max(1.0),
    }
}

fn num(v: f64) -> String {
    if v.fract() == 0.0 && v.abs() < 1e12 {
        format!("{v:.0}")
    } else {
        format!("{v:.2}")
    }
}

pub fn block(v: &Viewer, b: &BenchmarkView) -> Markup {
    let this = b.references.iter().find(|r| r.session_id == b.session_id);
    let n = b.benchmark.experts.len();
    let cmp = b.benchmark.compare(&b.report.metrics);
    // The rows: the metrics the level grades by (in its order), else every metric.
    let rows: Vec<&Comparison> = match b.level {
        Some(level) => {
            let mut names: Vec<&str> = Vec::new();
            let used = level
                .require
                .iter()
                .map(|q| q.metric.as_str())
                .chain(level.deduct.iter().map(|d| d.metric.as_str()))
                .chain(level.relative.iter().map(|d| d.metric.as_str()));
            for name in used {
                if !names.contains(&name) {
                    names.push(name);
                }
            }
            names
                .iter()
                .filter_map(|m| cmp.iter().find(|c| c.metric == *m))
                .collect()
        }
        None => cmp.iter().collect(),
    };
    html! {
        section #benchmark {
            @if let Some(r) = this {
                p #expert-mark { span.badge.ok { "expert reference" } " This session is an expert reference of '" (b.report.scenario) "', marked by " (r.marked_by) " on " (short_time(&r.marked_at)) " UTC." }
            }
            @match &b.report.grade.benchmark {
                Some(g) if g.applied => p #benchmark-grading { "Graded against the expert benchmark: " (g.experts) " expert references when it was scored; the rubric's relative deductions applied (see the rubric table)." },
                Some(g) => p.muted #benchmark-grading { "The rubric grades this level against the expert benchmark once the scenario has " (g.min_experts) " expert references; it had " (g.experts) " when this session was scored, so no relative deduction applied." },
                None => {}
            }
            @if n > 0 && !b.figures_shown {
                p.muted #benchmark-none { "Scenario '" (b.report.scenario) "' has " (n) " expert reference" @if n != 1 { "s" } " so far; its benchmark is shown from " (stylet_service::experts::MIN_SHOWN_TO_TRAINEES) " on." }
            } @else if n == 0 {
                p.muted #benchmark-none { "No expert references for scenario '" (b.report.scenario) "' yet. An instructor marks sessions that show how experts do it; their mean and spread per metric become the benchmark." }
            } @else {
                p.muted { "Expert mean ± spread (sample standard deviation) of " (n) " expert reference" @if n != 1 { "s" } " of '" (b.report.scenario) "' on this atlas, now. The mean is the proficiency level; rows more than " (num(MARK_SPREADS)) " spreads from it are marked." }
                table #benchmark-table {
                    thead { tr { th { "Metric" } th.num { "This session" } th.num { "Expert mean" } th.num { "Spread" } th.num { "Spreads from the mean" } } }
                    tbody { @for c in rows {
                        tr class=(if far_from_experts(c) { "far" } else { "" }) data-metric=(c.metric) {
                            @let amount = |v: f64| metric_info(&c.metric).map_or_else(|| num(v), |i| i.amount(v));
                            td { (metric_label(&c.metric).unwrap_or(&c.metric)) }
                            td.num { (amount(c.value)) }
                            td.num { (amount(c.mean)) }
                            td.num { (amount(c.spread)) }
                            td.num { @match c.spreads_from_mean() {
                                Some(z) => { (format!("{z:+.1}")) @if z.abs() > MARK_SPREADS { " " span.badge.warn { "far" } } }
                                None => { @if far_from_experts(c) { span.badge.warn { "experts all " (metric_info(&c.metric).map_or_else(|| num(c.mean), |i| i.amount(c.mean))) } } @else { "–" } }
                            } }
                        }
                    } }
                }
                @if let Some(listed) = b.listed {
                    p.muted #expert-references { "Expert references: "
                        @for (k, r) in listed.iter().enumerate() {
                            @if k > 0 { ", " }
                            a href={ "/sessions/" (r.session_id) } { (r.trainee) " (" (short_time(&r.marked_at)) ")" }
                        }
                        @if listed.len() < n { @if !listed.is_empty() { "; " } (n - listed.len()) " of other cohorts" }
                    }
                }
            }
            // Marking is offered only where the service would accept it; unmarking always.
            @let problem = stylet_service::experts::report_reference_problem(b.report);
            @if b.reviewer {
                @if let (Some(problem), None) = (&problem, this) {
                    p.muted.noprint #expert-form-none { (sentence(problem)) }
                } @else {
                    form #expert-form.noprint method="post" action={ "/sessions/" (b.session_id) "/expert" } {
                        (csrf_field(v))
                        @if this.is_some() {
                            input type="hidden" name="expert" value="no";
                            button type="submit" { "Unmark as expert reference" }
                        } @else {
                            input type="hidden" name="expert" value="yes";
                            button type="submit" { "Mark as expert reference" }
                        }
                        span.muted { " (audited)" }
                    }
                }
            }
        }
    }
}

/// A message as a sentence: its first letter capitalised, a full stop at the end.
fn sentence(text: &str) -> String {
    let mut chars = text.chars();
    match chars.next() {
        Some(first) => format!("{}{}.", first.to_uppercase(), chars.as_str().trim_end_matches('.')),
        None => String::new(),
    }
}

#[derive(serde::Deserialize)]
pub struct ExpertForm {
    csrf: String,
    expert: String,
}

/// `POST /sessions/{id}/expert`: mark (`expert=yes`) or unmark (`expert=no`).
pub async fn mark(
    State(s): State<Arc<AppState>>,
    v: Viewer,
    Path(id): Path<String>,
    Form(f): Form<ExpertForm>,
) -> Result<Redirect, PageError> {
    check_csrf(&v, &f.csrf)?;
    let expert = match f.expert.as_str() {
        "yes" => true,
        "no" => false,
        other => {
            return Err(fail(
                axum::http::StatusCode::BAD_REQUEST,
                format!("expert must be yes or no, not '{other}'"),
            ));
        }
    };
    stylet_service::experts::set_expert(&s, &v.user, &id, expert).await?;
    Ok(Redirect::to(&format!("/sessions/{id}#benchmark")))
}

#[cfg(test)]
mod tests {
    use super::*;
    use stylet_scoring::{Exercise, Outcome};
    use stylet_service::store::{Role, User};

    /// A stored score report (complete, replay verified, failed at expert level) with `outcome`.
    fn report(outcome: Outcome) -> ScoreReport {
        let mut r: ScoreReport = serde_json::from_str(include_str!("../../../service/tests/data/report.json")).unwrap();
        r.outcome = outcome;
        r
    }

    fn instructor() -> Viewer {
        Viewer {
            user: User {
                id: "u-ivan".into(),
                username: "ivan".into(),
                role: Role::Instructor,
            },
            csrf: "token".into(),
        }
    }

    /// The section as the session's instructor sees it, with `references` marked.
    fn section(report: &ScoreReport, references: &[ExpertReference]) -> String {
        let benchmark = Benchmark::from_sessions("success-intercostal", Exercise::Puncture, &[]);
        block(
            &instructor(),
            &BenchmarkView {
                session_id: "s-1",
                report,
                benchmark: &benchmark,
                references,
                level: None,
                reviewer: true,
                listed: Some(references),
                figures_shown: true,
            },
        )
        .into_string()
    }

    #[test]
    fn only_a_passed_session_is_offered_as_an_expert_reference() {
        let failed = section(&report(Outcome::Failed), &[]);
        assert!(!failed.contains("Mark as expert reference"), "{failed}");
        assert!(failed.contains("id=\"expert-form-none\""), "{failed}");
        assert!(
            failed.contains("The session failed its grade: only a passed session can be an expert reference."),
            "{failed}"
        );
        let passed = section(&report(Outcome::Passed), &[]);
        assert!(
            passed.contains("Mark as expert reference") && !passed.contains("expert-form-none"),
            "{passed}"
        );
    }

    #[test]
    fn a_reference_can_always_be_unmarked() {
        let marked = [ExpertReference {
            session_id: "s-1".into(),
            trainee: "eve".into(),
            marked_by: "ivan".into(),
            marked_at: "2026-11-23T14:05:09Z".into(),
            file_sha256: "ab".into(),
        }];
        let html = section(&report(Outcome::Failed), &marked);
        assert!(
            html.contains("Unmark as expert reference") && !html.contains("expert-form-none"),
            "{html}"
        );
    }
}
