//! The deep linking response (LTI Deep Linking 2.0 §4.2): the exercise an instructor picked, as
//! one `ltiResourceLink` content item whose custom parameters (`scenario`, `level`) come back in
//! every launch of the activity, with a line item (score out of 100) for its grades. Signed with
//! the tool's key; the platform checks it against `/lti/jwks`.

use serde_json::{Value, json};

use super::claim;
use crate::store::LtiPlatform;

/// Seconds a response is valid (the browser posts it at once).
pub const RESPONSE_S: u64 = 300;

/// An exercise as a course activity.
#[derive(Debug, Clone)]
pub struct Activity {
    pub scenario: String,
    pub difficulty: stylet_atlas::Difficulty,
    pub title: String,
}

/// The activity's label in the course and the gradebook.
pub fn title_of(scenario: &str, difficulty: stylet_atlas::Difficulty) -> String {
    format!("Stylet: {scenario} ({})", difficulty.as_str())
}

/// The response's claims for `platform` and deployment `deployment_id`; `data` is the request's,
/// sent back unchanged. `now_s`: seconds since 1970.
pub fn response_claims(
    platform: &LtiPlatform,
    deployment_id: &str,
    data: Option<Value>,
    activity: &Activity,
    now_s: u64,
) -> Value {
    let item = json!({
        "type": "ltiResourceLink",
        "title": activity.title,
        "text": format!("A PTCD puncture on the Stylet simulator, scored at the {} level.", activity.difficulty.as_str()),
        "custom": {"scenario": activity.scenario, "level": activity.difficulty.as_str()},
        "lineItem": {
            "scoreMaximum": 100,
            "label": activity.title,
            "resourceId": format!("{}/{}", activity.scenario, activity.difficulty.as_str()),
            "tag": "stylet-score",
        },
        "window": {"targetName": "stylet"},
    });
    let mut claims = json!({
        "iss": platform.client_id,
        "aud": platform.issuer,
        "iat": now_s,
        "exp": now_s + RESPONSE_S,
        "nonce": crate::auth::random_token(),
        claim::MESSAGE_TYPE: "LtiDeepLinkingResponse",
        claim::VERSION: "1.3.0",
        claim::DEPLOYMENT_ID: deployment_id,
        claim::CONTENT_ITEMS: [item],
    });
    if let Some(d) = data {
        claims[claim::DATA] = d;
    }
    claims
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_response_names_the_exercise_and_asks_for_a_line_item() {
        let p = LtiPlatform {
            id: "p".into(),
            issuer: "https://lms.example.org".into(),
            client_id: "stylet-client".into(),
            deployment_ids: vec!["d1".into()],
            keyset_url: String::new(),
            auth_url: String::new(),
            token_url: String::new(),
            instructor_roles: vec![],
            created_at: String::new(),
        };
        let a = Activity {
            scenario: "success-intercostal".into(),
            difficulty: stylet_atlas::Difficulty::Advanced,
            title: title_of("success-intercostal", stylet_atlas::Difficulty::Advanced),
        };
        let c = response_claims(&p, "d1", Some(json!("opaque")), &a, 1000);
        assert_eq!(c["iss"], "stylet-client");
        assert_eq!(c["aud"], "https://lms.example.org");
        assert_eq!(c["exp"], 1300);
        assert_eq!(c[claim::DATA], "opaque");
        assert_eq!(c[claim::DEPLOYMENT_ID], "d1");
        let item = &c[claim::CONTENT_ITEMS][0];
        assert_eq!(item["custom"]["scenario"], "success-intercostal");
        assert_eq!(item["custom"]["level"], "advanced");
        assert_eq!(item["lineItem"]["scoreMaximum"], 100);
        assert!(response_claims(&p, "d1", None, &a, 1000).get(claim::DATA).is_none());
    }
}
