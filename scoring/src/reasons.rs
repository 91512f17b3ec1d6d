//! The reasons of a result in plain words (the `reasons` of a report, which the CLI, the API and
//! the dashboard show), phrased from the metric table of [`crate::metric_words`], and whether a
//! session passed, failed or could not be graded.

use crate::metric_words::num;
use crate::metrics::Metrics;
use crate::rubric::Grade;
use stylet_atlas::Exercise;

/// The metric table's look-ups, also under this module's name.
pub use crate::metric_words::{metric_info, metric_label};

/// Whether a session can be graded, and how it came out.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Outcome {
    Passed,
    Failed,
    /// The recording is incomplete (cut, damaged, dropped ticks): a grade would judge what is
    /// missing, so none is given.
    NotGradeable,
}

impl Outcome {
    /// From the report's flags: an incomplete recording is never graded.
    pub fn of(incomplete: bool, passed: bool) -> Outcome {
        match (incomplete, passed) {
            (true, _) => Outcome::NotGradeable,
            (false, true) => Outcome::Passed,
            (false, false) => Outcome::Failed,
        }
    }

    /// The identifier as stored ("passed", "failed", "not_gradeable").
    pub fn as_str(self) -> &'static str {
        match self {
            Outcome::Passed => "passed",
            Outcome::Failed => "failed",
            Outcome::NotGradeable => "not_gradeable",
        }
    }

    pub fn parse(s: &str) -> Option<Outcome> {
        [Outcome::Passed, Outcome::Failed, Outcome::NotGradeable]
            .into_iter()
            .find(|o| o.as_str() == s)
    }

    /// For people: "passed", "failed", "not gradeable".
    pub fn label(self) -> &'static str {
        match self {
            Outcome::Passed => "passed",
            Outcome::Failed => "failed",
            Outcome::NotGradeable => "not gradeable",
        }
    }
}

impl std::fmt::Display for Outcome {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.label())
    }
}

/// The reasons of a result in plain words: why it is not gradeable, or why it failed (unmet
/// requirements, the score against the pass mark with every deduction), the risk structures hit
/// with their consequence, and for a pass what still cost points.
pub fn reasons(exercise: Exercise, grade: &Grade, metrics: &Metrics, incomplete_reason: Option<&str>) -> Vec<String> {
    let mut out = Vec::new();
    if let Some(why) = incomplete_reason {
        out.push(format!(
            "Not gradeable: the recording is incomplete ({why}). Record the exercise again; `stylet session recover` \
             keeps what was saved for review."
        ));
        return out;
    }
    if !grade.attempted {
        out.push(crate::rubric_metrics::not_attempted_text(exercise).to_string());
        return out;
    }
    for u in &grade.unmet {
        if metric_info(&u.metric).is_some() {
            out.push(unmet_text(&u.metric, u.value, u.min, u.max, metrics));
        }
    }
    if matches!(exercise, Exercise::Puncture | Exercise::Drainage) {
        for h in &metrics.risk_hits {
            let consequence = h
                .consequence
                .as_deref()
                .map(|c| format!(" ({c} risk)"))
                .unwrap_or_default();
            out.push(format!(
                "The needle entered the {} at {:.1} s, {:.1} mm deep{consequence}.",
                h.structure, h.t_s, h.depth_mm
            ));
        }
    }
    if let Some(d) = &metrics.drainage {
        out.extend(crate::drainage::findings(d));
    }
    let deductions: Vec<String> = grade
        .deductions
        .iter()
        .filter_map(|d| {
            let info = metric_info(&d.metric)?;
            // A deduction against the expert benchmark says where its free amount came from
            // (also when that amount is 0, which a plain deduction does not mention).
            Some(match (&d.relative, d.free) {
                (Some(r), Some(free)) => format!(
                    "−{} for {} ({} free: the experts' mean + {} spread{})",
                    num(d.points),
                    info.phrase(d.value),
                    info.amount(free),
                    num(r.spreads),
                    if r.spreads == 1.0 { "" } else { "s" }
                ),
                _ => info.deduction(d.value, d.points, d.free),
            })
        })
        .collect();
    let pass = grade.pass_score.map(num);
    let level = &grade.difficulty;
    let costs = if deductions.is_empty() {
        String::new()
    } else {
        format!(": {}", deductions.join(", "))
    };
    match pass {
        Some(p) if grade.score < grade.pass_score.unwrap_or(0.0) => out.push(format!(
            "Score {} is below the pass mark of {p} for {level}{costs}.",
            num(grade.score)
        )),
        Some(p) if !deductions.is_empty() => out.push(format!(
            "Score {} (pass mark {p} for {level}){costs}.",
            num(grade.score)
        )),
        None if !deductions.is_empty() => out.push(format!("Score {}{costs}.", num(grade.score))),
        _ => {}
    }
    if !grade.passed && out.is_empty() {
        out.push(format!("Score {} did not pass at {level}.", num(grade.score)));
    }
    out
}

/// A requirement `min ≤ value ≤ max` of `metric` that the session missed, as a sentence; the risk
/// structures hit are named ("1 risk structure hit: right lung (none allowed).").
pub fn unmet_text(metric: &str, value: f64, min: Option<f64>, max: Option<f64>, metrics: &Metrics) -> String {
    let info = metric_info(metric).expect("every rubric metric has words (tested)");
    if metric != "risk_hits" || metrics.risk_hits.is_empty() {
        return info.unmet(value, min, max);
    }
    let names: Vec<&str> = metrics.risk_hits.iter().map(|h| h.structure.as_str()).collect();
    let allowed = match max {
        Some(hi) if hi > 0.0 => format!("at most {} allowed", num(hi)),
        _ => "none allowed".to_string(),
    };
    let phrase = info.phrase(value);
    let mut c = phrase.chars();
    let capitalised = c
        .next()
        .map(|f| f.to_uppercase().collect::<String>() + c.as_str())
        .unwrap_or_default();
    format!("{capitalised}: {} ({allowed}).", names.join(", "))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn outcomes_read_as_words() {
        assert_eq!(Outcome::of(true, true), Outcome::NotGradeable);
        assert_eq!(Outcome::parse("not_gradeable"), Some(Outcome::NotGradeable));
        assert_eq!(Outcome::NotGradeable.to_string(), "not gradeable");
    }
}
