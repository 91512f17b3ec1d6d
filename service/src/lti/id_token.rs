//! Checking a launch's `id_token` (IMS Security Framework 1.0 §5.1.3, LTI 1.3 core §5): an RS256
//! JWT signed with a key of the platform's key set, issued by the platform for Stylet's client
//! id (with several audiences, `azp` must be Stylet's), not expired (60 s of clock skew), issued
//! no later than now, carrying the nonce of this launch's login, a registered deployment id, LTI
//! version 1.3.0 and a message type Stylet handles. Each failure is named, for the error page.

use std::collections::HashMap;

use jsonwebtoken::errors::ErrorKind;
use jsonwebtoken::{Algorithm, Validation};
use serde::Deserialize;
use serde_json::Value;

use super::key_sets::{KeyError, KeySets};
use crate::store::LtiPlatform;

/// Seconds of clock skew allowed between the platform and Stylet.
pub const LEEWAY_S: u64 = 60;
/// The longest id_token taken.
pub const MAX_ID_TOKEN_BYTES: usize = 64 * 1024;

/// The messages Stylet handles.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MessageType {
    /// A learner (or instructor) opens an activity.
    ResourceLink,
    /// An instructor adds an activity to the course.
    DeepLinking,
}

/// Why a launch was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LaunchError {
    #[error("the id_token is not a signed JWT Stylet can read ({0})")]
    Malformed(String),
    #[error("the id_token is signed with {0}; LTI 1.3 launches are signed with RS256")]
    Algorithm(String),
    #[error("{0}")]
    Key(#[from] KeyError),
    #[error("the id_token's signature does not match the platform's key")]
    Signature,
    #[error("the id_token has expired (its exp has passed): launch again from the course")]
    Expired,
    #[error("the id_token was issued in the future (check the platform's clock)")]
    IssuedInFuture,
    #[error("the id_token is for another tool (its audience is not Stylet's client id at this platform)")]
    Audience,
    #[error("the id_token was issued by another platform than this launch started at")]
    Issuer,
    #[error("the id_token does not carry this launch's nonce")]
    Nonce,
    #[error("the deployment '{0}' is not registered for this platform in Stylet")]
    Deployment(String),
    #[error("LTI version '{0}' is not 1.3.0")]
    Version(String),
    #[error("Stylet does not handle '{0}' messages")]
    MessageType(String),
    #[error("the launch lacks {0}")]
    Missing(&'static str),
}

#[derive(Debug, Clone, Deserialize)]
pub struct Context {
    pub id: String,
    #[serde(default)]
    pub title: Option<String>,
    #[serde(default)]
    pub label: Option<String>,
}

#[derive(Debug, Clone, Deserialize)]
pub struct ResourceLink {
    pub id: String,
    #[serde(default)]
    pub title: Option<String>,
}

/// The AGS endpoint claim: the line item of this link, if the platform made one.
#[derive(Debug, Clone, Deserialize)]
pub struct AgsEndpoint {
    #[serde(default)]
    pub scope: Vec<String>,
    #[serde(default)]
    pub lineitem: Option<String>,
}

#[derive(Debug, Clone, Deserialize)]
pub struct DeepLinkingSettings {
    pub deep_link_return_url: String,
    #[serde(default)]
    pub accept_types: Vec<String>,
    /// Opaque to the tool, sent back with the response.
    #[serde(default)]
    pub data: Option<Value>,
}

/// What Stylet reads of a launch.
#[derive(Debug, Clone, Deserialize)]
pub struct Launch {
    pub sub: Option<String>,
    #[serde(default)]
    pub aud: Value,
    #[serde(default)]
    pub azp: Option<String>,
    #[serde(default)]
    pub iat: Option<i64>,
    #[serde(default)]
    pub nonce: Option<String>,
    #[serde(default)]
    pub name: Option<String>,
    #[serde(default)]
    pub email: Option<String>,
    #[serde(rename = "https://purl.imsglobal.org/spec/lti/claim/message_type", default)]
    pub message_type: Option<String>,
    #[serde(rename = "https://purl.imsglobal.org/spec/lti/claim/version", default)]
    pub version: Option<String>,
    #[serde(rename = "https://purl.imsglobal.org/spec/lti/claim/deployment_id", default)]
    pub deployment_id: Option<String>,
    #[serde(rename = "https://purl.imsglobal.org/spec/lti/claim/roles", default)]
    pub roles: Vec<String>,
    #[serde(rename = "https://purl.imsglobal.org/spec/lti/claim/context", default)]
    pub context: Option<Context>,
    #[serde(rename = "https://purl.imsglobal.org/spec/lti/claim/resource_link", default)]
    pub resource_link: Option<ResourceLink>,
    #[serde(rename = "https://purl.imsglobal.org/spec/lti/claim/custom", default)]
    pub custom: HashMap<String, Value>,
    #[serde(rename = "https://purl.imsglobal.org/spec/lti-ags/claim/endpoint", default)]
    pub ags: Option<AgsEndpoint>,
    #[serde(
        rename = "https://purl.imsglobal.org/spec/lti-dl/claim/deep_linking_settings",
        default
    )]
    pub deep_linking: Option<DeepLinkingSettings>,
}

/// A checked launch.
#[derive(Debug, Clone)]
pub struct CheckedLaunch {
    pub kind: MessageType,
    pub subject: String,
    pub deployment_id: String,
    pub claims: Launch,
}

impl Launch {
    /// A custom parameter as text (platforms send them as strings).
    pub fn custom_text(&self, name: &str) -> Option<String> {
        match self.custom.get(name)? {
            Value::String(s) => Some(s.clone()),
            Value::Number(n) => Some(n.to_string()),
            _ => None,
        }
    }
}

/// Checks `token` as a launch of `platform` whose login gave `nonce`.
pub async fn check(
    token: &str,
    platform: &LtiPlatform,
    nonce: &str,
    keys: &KeySets,
) -> Result<CheckedLaunch, LaunchError> {
    if token.len() > MAX_ID_TOKEN_BYTES {
        return Err(LaunchError::Malformed(format!("over {MAX_ID_TOKEN_BYTES} bytes")));
    }
    let header = jsonwebtoken::decode_header(token).map_err(|e| LaunchError::Malformed(e.to_string()))?;
    if header.alg != Algorithm::RS256 {
        return Err(LaunchError::Algorithm(format!("{:?}", header.alg)));
    }
    let kid = header.kid.ok_or(LaunchError::Missing("a key id (kid) in its header"))?;
    let key = keys.key(platform, &kid).await?;
    let mut v = Validation::new(Algorithm::RS256);
    v.leeway = LEEWAY_S;
    v.set_issuer(&[&platform.issuer]);
    v.set_audience(&[&platform.client_id]);
    v.set_required_spec_claims(&["exp", "iss", "aud", "sub"]);
    let data = jsonwebtoken::decode::<Launch>(token, &key, &v).map_err(|e| match e.kind() {
        ErrorKind::ExpiredSignature => LaunchError::Expired,
        ErrorKind::InvalidAudience => LaunchError::Audience,
        ErrorKind::InvalidIssuer => LaunchError::Issuer,
        ErrorKind::InvalidSignature => LaunchError::Signature,
        ErrorKind::MissingRequiredClaim(c) => LaunchError::Malformed(format!("no '{c}' claim")),
        _ => LaunchError::Malformed(e.to_string()),
    })?;
    let claims = data.claims;
    // The authorised party, when named (it must be with several audiences), is Stylet
    // (IMS Security Framework 1.0 §5.1.3).
    let azp_ok = match claims.azp.as_deref() {
        Some(azp) => azp == platform.client_id,
        None => !claims.aud.is_array(),
    };
    if !azp_ok {
        return Err(LaunchError::Audience);
    }
    let now_s = super::unix_now_s() as i64;
    match claims.iat {
        None => return Err(LaunchError::Missing("its issue time (iat)")),
        Some(iat) if iat > now_s + LEEWAY_S as i64 => return Err(LaunchError::IssuedInFuture),
        Some(_) => {}
    }
    if claims.nonce.as_deref() != Some(nonce) {
        return Err(LaunchError::Nonce);
    }
    let deployment_id = claims
        .deployment_id
        .clone()
        .ok_or(LaunchError::Missing("a deployment id"))?;
    if !platform.deployment_ids.contains(&deployment_id) {
        return Err(LaunchError::Deployment(deployment_id));
    }
    let version = claims.version.clone().unwrap_or_default();
    if version != "1.3.0" {
        return Err(LaunchError::Version(version));
    }
    let kind = match claims.message_type.as_deref() {
        Some("LtiResourceLinkRequest") => MessageType::ResourceLink,
        Some("LtiDeepLinkingRequest") => MessageType::DeepLinking,
        other => return Err(LaunchError::MessageType(other.unwrap_or("").to_string())),
    };
    match kind {
        MessageType::ResourceLink if claims.resource_link.is_none() => {
            return Err(LaunchError::Missing("a resource link"));
        }
        MessageType::DeepLinking if claims.deep_linking.is_none() => {
            return Err(LaunchError::Missing("deep linking settings"));
        }
        _ => {}
    }
    let subject = claims.sub.clone().filter(|s| !s.is_empty() && s.len() <= 255);
    let subject = subject.ok_or(LaunchError::Missing("a user (sub of at most 255 characters)"))?;
    Ok(CheckedLaunch {
        kind,
        subject,
        deployment_id,
        claims,
    })
}
