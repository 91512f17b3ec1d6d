//! Learning records of scored sessions for a Learning Record Store (xAPI 1.0.3;
//! docs/integration.md "Learning records (xAPI)").
//!
//! Each scored session yields `attempted`, then `completed` and `passed` or `failed` (an
//! incomplete recording, which is never graded: `attempted` only), with the scenario and level as
//! the activity, the score, success and duration as the result, and the key metrics as result
//! extensions. Verbs are ADL's (`http://adlnet.gov/expapi/verbs/…`, those cmi5 uses for
//! completed, passed and failed). The statements are written to an outbox in the database in the
//! transaction that stores the score ([`crate::store::Store::finish_job`]) and delivered from
//! there by [`run`]: retried with back-off while the LRS is down, never lost; each statement's id
//! is derived from the session and the verb, so a statement sent twice (a replica dying between
//! sending and marking it, two replicas at once) is one statement at the LRS, which answers the
//! second with 409.

use std::sync::Arc;
use std::time::Duration;

use serde_json::{Value, json};
use sha2::{Digest, Sha256};

use super::AppState;

/// Where the statements go (`stylet serve --lrs-url … --lrs-username …`, the password from
/// `STYLET_LRS_PASSWORD`), and the service's public address, the home of its accounts and
/// activities in the statements (`--public-url`).
#[derive(Debug, Clone)]
pub struct LrsConfig {
    /// The LRS's endpoint, e.g. `https://lrs.example.org/xAPI` (statements go to
    /// `…/statements`).
    pub url: String,
    pub username: String,
    pub password: String,
    pub public_url: String,
}

/// What a statement says the trainee did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verb {
    Attempted,
    Completed,
    Passed,
    Failed,
}

impl Verb {
    pub fn name(self) -> &'static str {
        match self {
            Verb::Attempted => "attempted",
            Verb::Completed => "completed",
            Verb::Passed => "passed",
            Verb::Failed => "failed",
        }
    }

    /// ADL's verb IRI.
    pub fn iri(self) -> String {
        format!("http://adlnet.gov/expapi/verbs/{}", self.name())
    }
}

/// The stored facts of a scored session a statement is made of.
pub struct ScoredSession<'a> {
    pub session_id: &'a str,
    pub trainee: &'a str,
    pub scenario: &'a str,
    pub difficulty: &'a str,
    /// The simulator's clock when recording started.
    pub recorded_at: &'a str,
    pub duration_s: f64,
    pub report: &'a stylet_scoring::ScoreReport,
}

/// The statement id of `verb` for session `session_id`: a UUID (version 8, RFC 9562) from the
/// SHA-256 of both, the same every time.
pub fn statement_id(session_id: &str, verb: Verb) -> String {
    let h = Sha256::digest(format!("stylet xapi statement\n{session_id}\n{}", verb.name()));
    let mut b = [0u8; 16];
    b.copy_from_slice(&h[..16]);
    b[6] = (b[6] & 0x0f) | 0x80;
    b[8] = (b[8] & 0x3f) | 0x80;
    let hex: String = b.iter().map(|x| format!("{x:02x}")).collect();
    format!(
        "{}-{}-{}-{}-{}",
        &hex[..8],
        &hex[8..12],
        &hex[12..16],
        &hex[16..20],
        &hex[20..]
    )
}

/// The key metrics a statement's result carries, as extensions under
/// `<public url>/xapi/extensions/<name>`.
const METRICS: [&str; 10] = [
    "attempts",
    "redirections",
    "risk_hits",
    "bone_contacts",
    "target_reached",
    "time_to_target_s",
    "path_length_mm",
    "max_force_n",
    "fluoro_time_s",
    "xray_shots",
];

/// The statements of a scored session: (verb, id, statement).
pub fn statements(public_url: &str, s: &ScoredSession<'_>) -> Vec<(Verb, String, Value)> {
    let base = public_url.trim_end_matches('/');
    let ext = |name: &str| format!("{base}/xapi/extensions/{name}");
    let report = s.report;
    let actor = json!({
        "objectType": "Agent",
        "name": s.trainee,
        "account": {"homePage": base, "name": s.trainee},
    });
    let object = json!({
        "objectType": "Activity",
        "id": format!("{base}/xapi/activities/{}/{}", s.scenario, s.difficulty),
        "definition": {
            "name": {"en": format!("PTCD simulation: {} ({})", s.scenario, s.difficulty)},
            "description": {"en": "A percutaneous transhepatic cholangiodrainage puncture on the Stylet simulator, scored by replaying the recorded session."},
            "type": "http://adlnet.gov/expapi/activities/simulation",
        },
    });
    let context = json!({
        "platform": "Stylet",
        "language": "en",
        "extensions": {
            ext("session-id"): s.session_id,
            ext("level"): s.difficulty,
            ext("physics-version"): report.physics_version,
            ext("rubric"): format!("{} v{}", report.grade.rubric, report.grade.rubric_version),
        },
    });
    let metrics = serde_json::to_value(&report.metrics).unwrap_or(Value::Null);
    let mut extensions = serde_json::Map::new();
    for name in METRICS {
        if let Some(v) = metrics.get(name).filter(|v| !v.is_null()) {
            extensions.insert(ext(name), v.clone());
        }
    }
    extensions.insert(ext("reasons"), json!(report.reasons));
    let score = report.grade.score;
    let result = json!({
        "score": {"scaled": (score / 100.0).clamp(0.0, 1.0), "raw": score, "min": 0, "max": 100},
        "success": report.grade.passed,
        "completion": true,
        "duration": format!("PT{:.3}S", s.duration_s.max(0.0)),
        "extensions": extensions,
    });
    let mut verbs = vec![Verb::Attempted];
    if !report.incomplete {
        verbs.push(Verb::Completed);
        verbs.push(if report.grade.passed {
            Verb::Passed
        } else {
            Verb::Failed
        });
    }
    verbs
        .into_iter()
        .map(|verb| {
            let id = statement_id(s.session_id, verb);
            let mut st = json!({
                "id": id,
                "actor": actor,
                "verb": {"id": verb.iri(), "display": {"en": verb.name()}},
                "object": object,
                "context": context,
                "timestamp": s.recorded_at,
            });
            if verb != Verb::Attempted {
                st["result"] = result.clone();
            }
            (verb, id, st)
        })
        .collect()
}

/// Statements sent in one request.
const BATCH: usize = 50;
/// Longest wait between tries of a statement the LRS did not take.
pub const MAX_BACKOFF: Duration = Duration::from_secs(30);
/// How often the outbox is looked at.
const EVERY: Duration = Duration::from_secs(2);

/// The wait before try `attempts + 1` of a statement: 1 s, 2 s, 4 s … at most [`MAX_BACKOFF`].
pub fn backoff(attempts: i64) -> Duration {
    let exp = attempts.clamp(0, 10) as u32;
    Duration::from_secs(1u64 << exp).min(MAX_BACKOFF)
}

/// How the LRS answered one POST of statements.
enum Sent {
    /// Stored (200), or already there under the same ids (409).
    Taken,
    /// The LRS answered with another status: this batch, or a statement in it, is refused.
    Refused(String),
    /// No answer (down, unreachable, timed out): nothing in the batch can be judged.
    Unreachable(String),
}

/// POSTs `statements` (a JSON array) to the LRS.
fn post(lrs: &LrsConfig, agent: &ureq::Agent, body: &str) -> Sent {
    let url = format!("{}/statements", lrs.url.trim_end_matches('/'));
    let answer = agent
        .post(&url)
        .set("X-Experience-API-Version", "1.0.3")
        .set("Content-Type", "application/json")
        .set("Authorization", &basic(&lrs.username, &lrs.password))
        .send_string(body);
    match answer {
        Ok(_) | Err(ureq::Error::Status(409, _)) => Sent::Taken,
        Err(ureq::Error::Status(code, r)) => {
            let text = r.into_string().unwrap_or_default();
            Sent::Refused(format!("{code}: {}", text.chars().take(300).collect::<String>()))
        }
        Err(e) => Sent::Unreachable(e.to_string()),
    }
}

/// HTTP Basic credentials (RFC 7617): `Basic base64(user:password)`.
fn basic(user: &str, password: &str) -> String {
    use base64::Engine as _;
    format!(
        "Basic {}",
        base64::engine::general_purpose::STANDARD.encode(format!("{user}:{password}"))
    )
}

/// Delivers what is due in the outbox, batch by batch; a batch the LRS refuses is tried
/// statement by statement, so one bad statement does not hold back the others (a batch that
/// gets no answer is not: the LRS is down, and every statement waits for its next try). Returns the
/// statements delivered.
pub async fn deliver_due(state: &AppState, lrs: &LrsConfig) -> usize {
    let mut delivered = 0;
    loop {
        let due = match state.store.due_statements(BATCH).await {
            Ok(due) if !due.is_empty() => due,
            Ok(_) => return delivered,
            Err(e) => {
                tracing::warn!(error = %e, "cannot read the xAPI outbox");
                return delivered;
            }
        };
        let (lrs_owned, batch) = (lrs.clone(), due.clone());
        let outcomes = tokio::task::spawn_blocking(move || {
            let agent = ureq::AgentBuilder::new()
                .timeout_connect(Duration::from_secs(5))
                .timeout(Duration::from_secs(30))
                .build();
            let all = format!(
                "[{}]",
                batch.iter().map(|(_, j, _)| j.as_str()).collect::<Vec<_>>().join(",")
            );
            match post(&lrs_owned, &agent, &all) {
                Sent::Taken => batch.iter().map(|(id, _, _)| (id.clone(), None)).collect::<Vec<_>>(),
                // Down: one try for the whole batch, not one a statement.
                Sent::Unreachable(why) => batch.iter().map(|(id, _, _)| (id.clone(), Some(why.clone()))).collect(),
                Sent::Refused(_) => batch
                    .iter()
                    .map(|(id, json, _)| match post(&lrs_owned, &agent, &format!("[{json}]")) {
                        Sent::Taken => (id.clone(), None),
                        Sent::Refused(why) | Sent::Unreachable(why) => (id.clone(), Some(why)),
                    })
                    .collect(),
            }
        })
        .await;
        let Ok(outcomes) = outcomes else { return delivered };
        let mut refused = 0;
        for ((id, why), (_, _, attempts)) in outcomes.into_iter().zip(&due) {
            let marked = match why {
                None => {
                    delivered += 1;
                    state.store.statement_delivered(&id).await
                }
                Some(why) => {
                    refused += 1;
                    tracing::warn!(statement = %id, error = %why, "the LRS did not take an xAPI statement; trying again later");
                    state.store.statement_refused(&id, &why, backoff(*attempts)).await
                }
            };
            if let Err(e) = marked {
                tracing::warn!(error = %e, "cannot mark an xAPI statement");
                return delivered;
            }
        }
        if refused > 0 {
            return delivered;
        }
    }
}

/// Delivers the outbox every few seconds, and at once after a score, until the server stops.
pub fn run(state: Arc<AppState>, lrs: LrsConfig) {
    tokio::spawn(async move {
        loop {
            if state.stopping.load(std::sync::atomic::Ordering::SeqCst) {
                return;
            }
            deliver_due(&state, &lrs).await;
            tokio::time::sleep(EVERY).await;
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_are_uuids_derived_from_the_session_and_the_verb() {
        let a = statement_id("5b0c…", Verb::Passed);
        assert_eq!(a, statement_id("5b0c…", Verb::Passed));
        assert_ne!(a, statement_id("5b0c…", Verb::Failed));
        assert_ne!(a, statement_id("5b0d…", Verb::Passed));
        let parts: Vec<&str> = a.split('-').collect();
        assert_eq!(parts.iter().map(|p| p.len()).collect::<Vec<_>>(), vec![8, 4, 4, 4, 12]);
        assert!(parts[2].starts_with('8'), "version 8: {a}");
        assert!(matches!(&parts[3][..1], "8" | "9" | "a" | "b"), "RFC 9562 variant: {a}");
    }

    #[test]
    fn basic_credentials_are_rfc_7617() {
        // RFC 7617 §2's example.
        assert_eq!(basic("Aladdin", "open sesame"), "Basic QWxhZGRpbjpvcGVuIHNlc2FtZQ==");
    }

    #[test]
    fn the_backoff_doubles_to_its_cap() {
        assert_eq!(backoff(0), Duration::from_secs(1));
        assert_eq!(backoff(3), Duration::from_secs(8));
        assert_eq!(backoff(5), MAX_BACKOFF);
        assert_eq!(backoff(i64::MAX), MAX_BACKOFF);
    }
}
