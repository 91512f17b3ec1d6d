//! The suggested next difficulty for a trainee (docs/dashboard.md "Next step"): move up after
//! [`STREAK`] passes in a row at the current level, step back after [`STREAK`] failures in a row,
//! else stay. The current level is the highest level with a scored session. [`next_step`] adds
//! the scenario to practise at that level.

use stylet_scoring::Difficulty;
use stylet_service::store::ProgressPoint;

/// Sessions in a row that move a trainee up (all passed) or back (all failed).
pub const STREAK: usize = 3;

/// A suggestion and the reason, in words.
#[derive(Debug, Clone, PartialEq)]
pub struct Suggestion {
    pub level: Difficulty,
    pub reason: String,
}

/// `points`: the trainee's scored sessions in upload order (final grades).
pub fn suggest_next(points: &[ProgressPoint]) -> Suggestion {
    let Some(current) = Difficulty::ALL
        .iter()
        .rposition(|level| points.iter().any(|p| p.difficulty == level.as_str()))
    else {
        return Suggestion {
            level: Difficulty::Beginner,
            reason: "no scored sessions yet: start at beginner".into(),
        };
    };
    let at_level: Vec<bool> = points
        .iter()
        .filter(|p| p.difficulty == Difficulty::ALL[current].as_str())
        .map(|p| p.passed)
        .collect();
    let last = &at_level[at_level.len().saturating_sub(STREAK)..];
    let level = Difficulty::ALL[current];
    if last.len() == STREAK && last.iter().all(|p| *p) {
        match Difficulty::ALL.get(current + 1) {
            Some(&next) => Suggestion {
                level: next,
                reason: format!("the last {STREAK} {level} sessions all passed"),
            },
            None => Suggestion {
                level,
                reason: format!("the last {STREAK} expert sessions all passed: keep practising at expert"),
            },
        }
    } else if last.len() == STREAK && last.iter().all(|p| !*p) && current > 0 {
        Suggestion {
            level: Difficulty::ALL[current - 1],
            reason: format!("the last {STREAK} {level} sessions all failed: consolidate one level lower"),
        }
    } else {
        let passed = last.iter().filter(|p| **p).count();
        // One session is "your first", not "the last 1 sessions".
        let so_far = if last.len() == 1 {
            format!(
                "your first {level} session {}",
                if passed == 1 { "passed" } else { "failed" }
            )
        } else {
            format!("{passed} of the last {} {level} sessions passed", last.len())
        };
        Suggestion {
            level,
            reason: format!("{so_far}; {STREAK} passes in a row move you up"),
        }
    }
}

/// What a trainee should do next: the level of [`suggest_next`], the scenario to practise at it
/// and why.
#[derive(Debug, Clone, PartialEq)]
pub struct NextStep {
    pub level: Difficulty,
    /// `None` when no scenario is known (none offered, none practised).
    pub scenario: Option<String>,
    pub reason: String,
}

/// The level of [`suggest_next`] and the scenario to practise at it: the scenario of the last
/// session at that level again if it failed (and is one of `scenarios`); else the first of
/// `scenarios` not yet passed at that level; else (all passed) the first of `scenarios`; else
/// the latest scenario practised. `points`: the trainee's graded punctures in upload order;
/// `scenarios`: the puncture scenarios offered to trainees, in the catalogue's order (empty when
/// none is known).
pub fn next_step(points: &[ProgressPoint], scenarios: &[String]) -> NextStep {
    let s = suggest_next(points);
    let at_level: Vec<&ProgressPoint> = points.iter().filter(|p| p.difficulty == s.level.as_str()).collect();
    let offered = |name: &str| scenarios.is_empty() || scenarios.iter().any(|sc| sc == name);
    let scenario = match at_level.last() {
        Some(p) if !p.passed && offered(&p.scenario) => Some(p.scenario.clone()),
        _ => scenarios
            .iter()
            .find(|sc| !at_level.iter().any(|p| p.passed && p.scenario == **sc))
            .or_else(|| scenarios.first())
            .cloned()
            .or_else(|| points.last().map(|p| p.scenario.clone())),
    };
    NextStep {
        level: s.level,
        scenario,
        reason: s.reason,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(level: &str, passed: bool) -> ProgressPoint {
        p_sc(level, "", passed)
    }

    fn p_sc(level: &str, scenario: &str, passed: bool) -> ProgressPoint {
        ProgressPoint {
            session_id: String::new(),
            uploaded_at: String::new(),
            scenario: scenario.into(),
            difficulty: level.into(),
            score: if passed { 80.0 } else { 20.0 },
            passed,
            overridden: false,
        }
    }

    #[test]
    fn moves_up_after_three_passes_back_after_three_failures() {
        assert_eq!(suggest_next(&[]).level, Difficulty::Beginner);
        let b = |v: &[bool]| v.iter().map(|x| p("beginner", *x)).collect::<Vec<_>>();
        assert_eq!(suggest_next(&b(&[true, true])).level, Difficulty::Beginner);
        assert_eq!(suggest_next(&b(&[false, true, true, true])).level, Difficulty::Advanced);
        assert_eq!(suggest_next(&b(&[true, true, false])).level, Difficulty::Beginner);
        assert_eq!(suggest_next(&b(&[false, false, false])).level, Difficulty::Beginner);
        let mut v = b(&[true, true, true]);
        v.extend([p("advanced", false), p("advanced", false), p("advanced", false)]);
        let s = suggest_next(&v);
        assert_eq!(s.level, Difficulty::Beginner, "{s:?}");
        v.push(p("expert", true));
        assert_eq!(suggest_next(&v).level, Difficulty::Expert);
        v.extend([p("expert", true), p("expert", true)]);
        assert!(suggest_next(&v).reason.contains("keep practising at expert"));
    }

    #[test]
    fn the_next_step_names_a_scenario_and_a_level() {
        let offered = ["success-intercostal".to_string(), "breath-hold".to_string()];
        // Nothing yet: the first scenario offered, at beginner.
        let first = next_step(&[], &offered);
        assert_eq!(
            (first.level, first.scenario.as_deref()),
            (Difficulty::Beginner, Some("success-intercostal"))
        );
        // A failed session: its scenario again.
        let again = next_step(&[p_sc("beginner", "breath-hold", false)], &offered);
        assert_eq!(again.scenario.as_deref(), Some("breath-hold"));
        // A failed example the trainee is not offered: the first scenario offered instead.
        let example = next_step(&[p_sc("beginner", "lung-hit", false)], &offered);
        assert_eq!(example.scenario.as_deref(), Some("success-intercostal"));
        // Without a catalogue, the failed scenario is all there is to go on.
        let unknown = next_step(&[p_sc("beginner", "lung-hit", false)], &[]);
        assert_eq!(unknown.scenario.as_deref(), Some("lung-hit"));
        // Passed: the first scenario offered not yet passed at the level.
        let passed = next_step(&[p_sc("beginner", "success-intercostal", true)], &offered);
        assert_eq!(passed.scenario.as_deref(), Some("breath-hold"));
        // Three passes move up: the first scenario at the new level.
        let up = next_step(
            &[
                p_sc("beginner", "success-intercostal", true),
                p_sc("beginner", "breath-hold", true),
                p_sc("beginner", "success-intercostal", true),
            ],
            &offered,
        );
        assert_eq!(
            (up.level, up.scenario.as_deref()),
            (Difficulty::Advanced, Some("success-intercostal"))
        );
        // Every scenario passed at the level: keep practising the first.
        let all = next_step(
            &[
                p_sc("beginner", "success-intercostal", true),
                p_sc("beginner", "breath-hold", true),
            ],
            &offered,
        );
        assert_eq!(all.scenario.as_deref(), Some("success-intercostal"));
        assert_eq!(next_step(&[], &[]).scenario, None);
    }

    #[test]
    fn one_session_is_not_counted_as_the_last_one_sessions() {
        let one = suggest_next(&[p("beginner", true)]).reason;
        assert!(!one.contains("last 1 beginner sessions"), "{one}");
        assert!(one.starts_with("your first beginner session passed"), "{one}");
        let failed = suggest_next(&[p("beginner", false)]).reason;
        assert!(failed.starts_with("your first beginner session failed"), "{failed}");
        let two = suggest_next(&[p("beginner", true), p("beginner", false)]).reason;
        assert!(two.starts_with("1 of the last 2 beginner sessions passed"), "{two}");
    }
}
