//! Grades to the platforms' gradebooks (LTI Assignment and Grade Services 2.0 §3.4, the Score
//! service): a scored session of an exercise a learner launched is queued with its score in the
//! score's transaction ([`crate::store::Store::finish_job`]) and posted from there to the
//! activity's line item (`<line item>/scores`) — retried with back-off while the platform is
//! unreachable, never lost. The bearer token comes from the platform's token endpoint by the
//! OAuth 2 client credentials grant with a JWT assertion signed by the tool's key (IMS Security
//! Framework 1.0 §4.1, RFC 7523), and is kept until shortly before it expires.
//!
//! The score is out of 100, `gradingProgress` `FullyGraded`, `activityProgress` `Completed`; the
//! comment says passed or not passed with the reasons. An incomplete recording is never graded
//! (docs/metrics.md), so it posts nothing.

use std::collections::HashMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

use serde_json::json;
use tokio::sync::Mutex;

use super::claim;
use super::keys::ToolKey;
use crate::AppState;
use crate::store::{DueGrade, LtiPlatform};

/// Grades posted per look at the outbox.
const BATCH: usize = 20;
/// How often the outbox is looked at.
const EVERY: Duration = Duration::from_secs(2);
/// The largest token answer taken.
const MAX_TOKEN_ANSWER_BYTES: u64 = 64 * 1024;
/// A kept token is not used in its last minute.
const TOKEN_MARGIN: Duration = Duration::from_secs(60);

/// The AGS score body of a session's `report` for LTI user `subject`, scored at `scored_at`.
pub fn score_json(subject: &str, report: &stylet_scoring::ScoreReport, scored_at: &str) -> String {
    let grade = &report.grade;
    let comment = if grade.passed {
        "Passed.".to_string()
    } else if report.reasons.is_empty() {
        "Not passed.".to_string()
    } else {
        let reasons: Vec<&str> = report.reasons.iter().map(|r| r.trim_end_matches('.')).collect();
        format!("Not passed: {}.", reasons.join("; "))
    };
    json!({
        "userId": subject,
        "scoreGiven": grade.score.clamp(0.0, 100.0),
        "scoreMaximum": 100,
        "comment": comment,
        "timestamp": scored_at,
        "activityProgress": "Completed",
        "gradingProgress": "FullyGraded",
    })
    .to_string()
}

/// `<line item>/scores`, keeping a query string after the path (AGS 2.0 §3.4.1).
pub fn scores_url(lineitem: &str) -> String {
    match lineitem.split_once('?') {
        Some((path, query)) => format!("{}/scores?{query}", path.trim_end_matches('/')),
        None => format!("{}/scores", lineitem.trim_end_matches('/')),
    }
}

/// Access tokens for the score service, by platform id.
#[derive(Default)]
pub struct AccessTokens {
    kept: Mutex<HashMap<String, (Instant, String)>>,
}

/// The client assertion of a token request: the tool's client id as issuer and subject, the
/// token endpoint as audience, valid five minutes, a fresh `jti`.
pub fn assertion_claims(platform: &LtiPlatform, now_s: u64) -> serde_json::Value {
    json!({
        "iss": platform.client_id,
        "sub": platform.client_id,
        "aud": platform.token_url,
        "iat": now_s,
        "exp": now_s + 300,
        "jti": crate::auth::random_token(),
    })
}

impl AccessTokens {
    /// A token for `platform`'s score service: kept, or asked for.
    async fn get(&self, platform: &LtiPlatform, key: &ToolKey) -> Result<String, String> {
        let mut kept = self.kept.lock().await;
        if let Some((until, token)) = kept.get(&platform.id)
            && Instant::now() < *until
        {
            return Ok(token.clone());
        }
        let assertion = key
            .sign(&assertion_claims(platform, super::unix_now_s()))
            .map_err(|e| e.to_string())?;
        let url = platform.token_url.clone();
        let answer = tokio::task::spawn_blocking(move || {
            let r = super::http_agent()
                .post(&url)
                .send_form(&[
                    ("grant_type", "client_credentials"),
                    (
                        "client_assertion_type",
                        "urn:ietf:params:oauth:client-assertion-type:jwt-bearer",
                    ),
                    ("client_assertion", &assertion),
                    ("scope", claim::SCORE_SCOPE),
                ])
                .map_err(|e| format!("the token endpoint: {e}"))?;
            super::read_bounded(r, MAX_TOKEN_ANSWER_BYTES)
        })
        .await
        .map_err(|e| e.to_string())??;
        let v: serde_json::Value =
            serde_json::from_str(&answer).map_err(|e| format!("the token answer is not JSON: {e}"))?;
        let token = v["access_token"]
            .as_str()
            .filter(|t| !t.is_empty() && t.len() <= 8192)
            .ok_or("the token answer has no access_token")?
            .to_string();
        let life = Duration::from_secs(v["expires_in"].as_u64().unwrap_or(3600).min(86_400));
        kept.insert(
            platform.id.clone(),
            (Instant::now() + life.saturating_sub(TOKEN_MARGIN), token.clone()),
        );
        Ok(token)
    }

    /// Forgets `platform`'s token (the platform refused it).
    async fn forget(&self, platform_id: &str) {
        self.kept.lock().await.remove(platform_id);
    }
}

/// How a platform answered one grade.
enum Posted {
    /// Taken (2xx).
    Taken,
    /// Answered for good without taking it: 409, the platform holds a later score (AGS 2.0 §3.4).
    Superseded(String),
    /// Refused (another 4xx): this grade waits, the platform's others go on.
    Refused(String),
    /// No answer, a server error, or no access token: the platform's grades all wait.
    Unreachable(String),
}

/// Posts one grade.
async fn post(state: &AppState, key: &ToolKey, platform: &LtiPlatform, grade: &DueGrade) -> Posted {
    let token = match state.lti.tokens.get(platform, key).await {
        Ok(t) => t,
        Err(why) => return Posted::Unreachable(why),
    };
    let (url, body) = (scores_url(&grade.lineitem_url), grade.score_json.clone());
    let answer = tokio::task::spawn_blocking(move || {
        super::http_agent()
            .post(&url)
            .set("Authorization", &format!("Bearer {token}"))
            .set("Content-Type", "application/vnd.ims.lis.v1.score+json")
            .send_string(&body)
            .map(|_| ())
            .map_err(|e| match e {
                ureq::Error::Status(code, r) => {
                    let text: String = r.into_string().unwrap_or_default().chars().take(300).collect();
                    (Some(code), format!("{code}: {text}"))
                }
                e => (None, e.to_string()),
            })
    })
    .await;
    match answer {
        Err(e) => Posted::Unreachable(e.to_string()),
        Ok(Ok(())) => Posted::Taken,
        Ok(Err((Some(401), why))) => {
            state.lti.tokens.forget(&platform.id).await;
            Posted::Unreachable(why)
        }
        Ok(Err((Some(409), why))) => Posted::Superseded(why),
        Ok(Err((Some(code), why))) if (400..500).contains(&code) => Posted::Refused(why),
        Ok(Err((_, why))) => Posted::Unreachable(why),
    }
}

/// Posts what is due in the grade outbox; returns the grades delivered. A platform that cannot
/// be reached holds back its own grades only: they all wait for its next try, out of the next
/// rounds' batches.
pub async fn deliver_due(state: &AppState) -> usize {
    let due = match state.store.due_grades(BATCH).await {
        Ok(due) => due,
        Err(e) => {
            tracing::warn!(error = %e, "cannot read the LTI grade outbox");
            return 0;
        }
    };
    if due.is_empty() {
        return 0;
    }
    let key = match super::tool_key(state).await {
        Ok(k) => k,
        Err(e) => {
            tracing::warn!(error = %e, "no LTI tool key; grades wait");
            return 0;
        }
    };
    let mut delivered = 0;
    let mut down: Vec<String> = Vec::new();
    for grade in due {
        if down.contains(&grade.platform_id) {
            continue;
        }
        let posted = match state.store.lti_platform(&grade.platform_id).await {
            Ok(Some(platform)) => post(state, &key, &platform, &grade).await,
            Ok(None) => Posted::Unreachable("the platform is no longer registered".to_string()),
            Err(e) => Posted::Unreachable(e.to_string()),
        };
        let wait = crate::xapi::backoff(grade.attempts);
        let marked = match posted {
            Posted::Taken => {
                delivered += 1;
                state.store.grade_delivered(&grade.id, None).await
            }
            Posted::Superseded(why) => state.store.grade_delivered(&grade.id, Some(&why)).await,
            Posted::Refused(why) => {
                tracing::warn!(grade = %grade.id, error = %why, "the platform refused a grade; trying again later");
                state.store.grade_refused(&grade.id, &why, wait).await
            }
            Posted::Unreachable(why) => {
                tracing::warn!(platform = %grade.platform_id, error = %why, "cannot post grades to a platform; trying again later");
                down.push(grade.platform_id.clone());
                state.store.platform_unreachable(&grade.platform_id, &why, wait).await
            }
        };
        if let Err(e) = marked {
            tracing::warn!(error = %e, "cannot mark an LTI grade");
            return delivered;
        }
    }
    delivered
}

/// Delivers the grade outbox every few seconds until the server stops.
pub fn run(state: Arc<AppState>) {
    tokio::spawn(async move {
        loop {
            if state.stopping.load(std::sync::atomic::Ordering::SeqCst) {
                return;
            }
            deliver_due(&state).await;
            tokio::time::sleep(EVERY).await;
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scores_go_under_the_line_item_keeping_its_query() {
        assert_eq!(
            scores_url("https://lms.example.org/li/7"),
            "https://lms.example.org/li/7/scores"
        );
        assert_eq!(
            scores_url("https://lms.example.org/mod/lti/services.php/2/lineitems/7/lineitem?type_id=1"),
            "https://lms.example.org/mod/lti/services.php/2/lineitems/7/lineitem/scores?type_id=1"
        );
    }
}
