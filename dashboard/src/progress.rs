//! The suggested next difficulty for a trainee (docs/dashboard.md "Suggested difficulty"):
//! move up after [`STREAK`] passes in a row at the current level, step back after [`STREAK`]
//! failures in a row, else stay. The current level is the highest level with a scored session.

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

#[cfg(test)]
mod tests {
    use super::*;

    fn p(level: &str, passed: bool) -> ProgressPoint {
        ProgressPoint {
            session_id: String::new(),
            uploaded_at: String::new(),
            scenario: String::new(),
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
