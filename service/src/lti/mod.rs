//! Stylet as an LTI 1.3 tool with LTI Advantage (docs/integration.md "Launching from a learning
//! management system"): a course activity in Moodle, Canvas, Blackboard or Open edX launches
//! Stylet, provisions the learner, and gets the grade of their scored sessions back.
//!
//! - Launch (IMS LTI 1.3 core §5, OpenID Connect third-party initiated login): the platform calls
//!   `/lti/login`; the tool answers with a redirect to the platform's authentication endpoint
//!   carrying a fresh `state` and `nonce` (kept in the database, used once); the platform posts a
//!   signed `id_token` to `/lti/launch`, checked by [`id_token`] against the platform's key set
//!   ([`key_sets`]): signature, issuer, audience, expiry, nonce, deployment id, message type and
//!   version.
//! - Accounts: the learner is provisioned from the launch with a role mapped from the LTI roles
//!   ([`roles`]) and joins a cohort per course (context).
//! - Deep linking (LTI Deep Linking 2.0): an instructor picks the exercise (scenario and level);
//!   the tool answers a signed `LtiDeepLinkingResponse` ([`deep_link`]) with one
//!   `ltiResourceLink` whose custom parameters name the exercise and which asks for a line item.
//! - Grades (LTI Assignment and Grade Services 2.0): a scored session of a launched exercise is
//!   queued in the score's transaction and posted to the activity's line item by [`grades`]
//!   (OAuth 2 client credentials with a signed JWT assertion, RFC 7523).
//! - `/lti/jwks`: the tool's public key ([`keys`]), which the platform checks the tool's
//!   messages with.

pub mod deep_link;
pub mod grades;
pub mod id_token;
pub mod key_sets;
pub mod keys;
pub mod roles;

/// Minutes between a launch's login initiation and its id_token.
pub const LAUNCH_MINUTES: u64 = 10;
/// Minutes an instructor has to pick a deep linking activity.
pub const DEEP_LINK_MINUTES: u64 = 30;

/// Claim names (IMS LTI 1.3 core §5.3–5.4, Deep Linking 2.0 §4.4, AGS 2.0 §3.1).
pub mod claim {
    pub const MESSAGE_TYPE: &str = "https://purl.imsglobal.org/spec/lti/claim/message_type";
    pub const VERSION: &str = "https://purl.imsglobal.org/spec/lti/claim/version";
    pub const DEPLOYMENT_ID: &str = "https://purl.imsglobal.org/spec/lti/claim/deployment_id";
    pub const ROLES: &str = "https://purl.imsglobal.org/spec/lti/claim/roles";
    pub const CONTEXT: &str = "https://purl.imsglobal.org/spec/lti/claim/context";
    pub const RESOURCE_LINK: &str = "https://purl.imsglobal.org/spec/lti/claim/resource_link";
    pub const CUSTOM: &str = "https://purl.imsglobal.org/spec/lti/claim/custom";
    pub const TARGET_LINK_URI: &str = "https://purl.imsglobal.org/spec/lti/claim/target_link_uri";
    pub const AGS_ENDPOINT: &str = "https://purl.imsglobal.org/spec/lti-ags/claim/endpoint";
    pub const DEEP_LINKING_SETTINGS: &str = "https://purl.imsglobal.org/spec/lti-dl/claim/deep_linking_settings";
    pub const CONTENT_ITEMS: &str = "https://purl.imsglobal.org/spec/lti-dl/claim/content_items";
    pub const DATA: &str = "https://purl.imsglobal.org/spec/lti-dl/claim/data";
    /// The AGS scope that lets a tool post scores.
    pub const SCORE_SCOPE: &str = "https://purl.imsglobal.org/spec/lti-ags/scope/score";
}

/// What the tool keeps in memory between requests: the platforms' key sets and the access
/// tokens for their grade services.
#[derive(Default)]
pub struct LtiCache {
    pub key_sets: key_sets::KeySets,
    pub tokens: grades::AccessTokens,
    pub tool_key: tokio::sync::OnceCell<std::sync::Arc<keys::ToolKey>>,
}

/// The tool's key, loaded (or made) once per process.
pub async fn tool_key(state: &crate::AppState) -> Result<std::sync::Arc<keys::ToolKey>, keys::ToolKeyError> {
    state
        .lti
        .tool_key
        .get_or_try_init(|| async { keys::load_or_create(&state.store).await.map(std::sync::Arc::new) })
        .await
        .cloned()
}

/// Seconds since 1970 (JWT times).
pub fn unix_now_s() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs())
}

/// `scheme://authority` of a URL (for a page's Content-Security-Policy `form-action`).
pub fn origin_of(url: &str) -> Option<&str> {
    let rest = url.strip_prefix("https://").or_else(|| url.strip_prefix("http://"))?;
    let end = rest.find(['/', '?', '#']).unwrap_or(rest.len());
    let scheme_len = url.len() - rest.len();
    (end > 0).then(|| &url[..scheme_len + end])
}

/// A fetch from a platform that must be small and quick: at most `max_bytes`, 10 s.
pub(crate) fn http_agent() -> ureq::Agent {
    ureq::AgentBuilder::new()
        .timeout_connect(std::time::Duration::from_secs(5))
        .timeout(std::time::Duration::from_secs(10))
        .redirects(0)
        .build()
}

/// Reads at most `max_bytes` of a response body as text; an error past that.
pub(crate) fn read_bounded(r: ureq::Response, max_bytes: u64) -> Result<String, String> {
    use std::io::Read as _;
    let mut body = Vec::new();
    r.into_reader()
        .take(max_bytes + 1)
        .read_to_end(&mut body)
        .map_err(|e| e.to_string())?;
    if body.len() as u64 > max_bytes {
        return Err(format!("an answer over {max_bytes} bytes"));
    }
    String::from_utf8(body).map_err(|_| "an answer that is not UTF-8".to_string())
}

#[cfg(test)]
mod tests {
    #[test]
    fn origins_are_scheme_and_authority() {
        assert_eq!(
            super::origin_of("https://lms.example.org/mod/lti/x.php?a=1"),
            Some("https://lms.example.org")
        );
        assert_eq!(super::origin_of("http://127.0.0.1:8000"), Some("http://127.0.0.1:8000"));
        assert_eq!(super::origin_of("javascript:alert(1)"), None);
        assert_eq!(super::origin_of("https://"), None);
    }
}
