//! The LTI 1.3 tool's pages (docs/integration.md "Launching from a learning management system";
//! the protocol is `stylet_service::lti`'s):
//!
//! - `GET|POST /lti/login`: OIDC login initiation from a registered platform; answers a redirect
//!   to the platform's authentication endpoint with a fresh state and nonce.
//! - `POST /lti/launch`: the platform's signed id_token. A checked launch logs the user in (an
//!   account made on the first launch) and shows their exercise — or, for an instructor's deep
//!   linking request, the exercises to pick from. A refused launch gets a page that says why.
//! - `POST /lti/deep-link`: the instructor's pick, answered with a page that posts the signed
//!   deep linking response back to the platform.
//! - `GET /lti/jwks`: the tool's public key set.
//!
//! The launch is a cross-site POST from the platform, so it is bound to the login it started by
//! the state (random, kept hashed in the database, used once, ten minutes) rather than by a
//! cookie: the SameSite cookies of the dashboard do not travel with it, and platforms open tools
//! in frames whose third-party cookies browsers block.

use std::net::IpAddr;
use std::sync::Arc;

use axum::extract::{Query, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Redirect, Response};
use axum::{Extension, Form, Json};
use maud::{Markup, html};
use stylet_atlas::Difficulty;
use stylet_service::lti::id_token::{self, CheckedLaunch, MessageType};
use stylet_service::lti::{self, DEEP_LINK_MINUTES, LAUNCH_MINUTES, claim, deep_link, roles};
use stylet_service::pairing::{Peer, client_address};
use stylet_service::store::{DeepLinkRequest, LaunchStateProblem, LtiIdentity, LtiPlatform, Role, StoreError};
use stylet_service::{AppState, auth};

use crate::auth::{PageError, encode_query, fail};
use crate::layout::page;

/// Longest value of a login initiation's parameter.
const MAX_PARAM_BYTES: usize = 2048;
/// Longest opaque `data` of a deep linking request (sent back with the response).
const MAX_DEEP_LINK_DATA_BYTES: usize = 4096;

/// The OIDC third-party login initiation (LTI 1.3 core §5.1.1; IMS Security Framework §5.1.1).
#[derive(Debug, serde::Deserialize)]
pub struct Initiation {
    iss: String,
    login_hint: String,
    target_link_uri: String,
    #[serde(default)]
    lti_message_hint: Option<String>,
    #[serde(default)]
    client_id: Option<String>,
    #[serde(default)]
    lti_deployment_id: Option<String>,
}

/// `GET /lti/login`.
pub async fn login_get(
    State(s): State<Arc<AppState>>,
    peer: Option<Extension<Peer>>,
    headers: HeaderMap,
    Query(q): Query<Initiation>,
) -> Result<Response, PageError> {
    initiate(&s, address(&s, peer, &headers), host(&headers), q).await
}

/// `POST /lti/login`.
pub async fn login_post(
    State(s): State<Arc<AppState>>,
    peer: Option<Extension<Peer>>,
    headers: HeaderMap,
    Form(q): Form<Initiation>,
) -> Result<Response, PageError> {
    initiate(&s, address(&s, peer, &headers), host(&headers), q).await
}

/// The request's Host header ("" without one).
fn host(headers: &HeaderMap) -> String {
    headers
        .get(header::HOST)
        .and_then(|h| h.to_str().ok())
        .unwrap_or("")
        .to_string()
}

/// The client's address as launches are counted: an IPv6 address as its /64 (one host commonly
/// holds a whole /64).
fn address(s: &AppState, peer: Option<Extension<Peer>>, headers: &HeaderMap) -> String {
    let peer: Option<IpAddr> = peer.map(|Extension(p)| p.0);
    match client_address(peer, headers, &s.config.limits.trusted_proxies) {
        Some(IpAddr::V6(a)) => {
            let s = a.segments();
            format!("{:x}:{:x}:{:x}:{:x}::/64", s[0], s[1], s[2], s[3])
        }
        Some(a) => a.to_string(),
        None => "unknown".into(),
    }
}

/// Whether `url` is this tool's launch URL as the browser reaches it (`<scheme>://<host>/lti/launch`,
/// `host` the request's Host, no user, no query): the only place the platform may be asked to
/// post an id_token to.
fn is_launch_url(url: &str, host: &str) -> bool {
    lti::origin_of(url).is_some_and(|origin| {
        let authority = origin.split_once("://").map_or("", |(_, a)| a);
        authority.eq_ignore_ascii_case(host) && &url[origin.len()..] == "/lti/launch"
    })
}

async fn initiate(s: &AppState, address: String, host: String, q: Initiation) -> Result<Response, PageError> {
    let params = [
        Some(&q.iss),
        Some(&q.login_hint),
        Some(&q.target_link_uri),
        q.lti_message_hint.as_ref(),
        q.client_id.as_ref(),
        q.lti_deployment_id.as_ref(),
    ];
    if params.into_iter().flatten().any(|p| p.len() > MAX_PARAM_BYTES) {
        return Err(fail(
            StatusCode::BAD_REQUEST,
            format!("a login initiation parameter is over {MAX_PARAM_BYTES} bytes"),
        ));
    }
    let platforms = s.store.lti_platforms_of(&q.iss, q.client_id.as_deref()).await?;
    let platform = match platforms.as_slice() {
        [] => {
            return Err(fail(
                StatusCode::BAD_REQUEST,
                format!(
                    "no learning platform with issuer {} {}is registered in Stylet: an admin registers it on the page LTI platforms",
                    q.iss,
                    q.client_id
                        .as_deref()
                        .map(|c| format!("and client id {c} "))
                        .unwrap_or_default()
                ),
            ));
        }
        [one] => one,
        _ => {
            return Err(fail(
                StatusCode::BAD_REQUEST,
                "several registrations share this issuer: the platform must send its client_id with the login",
            ));
        }
    };
    if let Some(d) = &q.lti_deployment_id
        && !platform.deployment_ids.contains(d)
    {
        return Err(fail(
            StatusCode::BAD_REQUEST,
            format!("the deployment '{d}' is not registered for this platform in Stylet"),
        ));
    }
    if !is_launch_url(&q.target_link_uri, &host) {
        return Err(fail(
            StatusCode::BAD_REQUEST,
            format!("the launch's target is not Stylet's launch URL (…://{host}/lti/launch)"),
        ));
    }
    let (state, nonce) = (auth::random_token(), auth::random_token());
    match s
        .store
        .begin_lti_launch(
            &auth::sha256_hex(&state),
            &nonce,
            &platform.id,
            &address,
            std::time::Duration::from_secs(LAUNCH_MINUTES * 60),
        )
        .await
    {
        Ok(()) => {}
        Err(StoreError::TooManyLaunches) => {
            return Err(fail(
                StatusCode::TOO_MANY_REQUESTS,
                StoreError::TooManyLaunches.to_string(),
            ));
        }
        Err(e) => return Err(e.into()),
    }
    let mut query = vec![
        ("scope", "openid"),
        ("response_type", "id_token"),
        ("response_mode", "form_post"),
        ("prompt", "none"),
        ("client_id", platform.client_id.as_str()),
        ("redirect_uri", q.target_link_uri.as_str()),
        ("login_hint", q.login_hint.as_str()),
        ("state", state.as_str()),
        ("nonce", nonce.as_str()),
    ];
    if let Some(h) = &q.lti_message_hint {
        query.push(("lti_message_hint", h));
    }
    let joined = query
        .iter()
        .map(|(k, v)| format!("{k}={}", encode_query(v)))
        .collect::<Vec<_>>()
        .join("&");
    let sep = if platform.auth_url.contains('?') { '&' } else { '?' };
    Ok(Redirect::to(&format!("{}{sep}{joined}", platform.auth_url)).into_response())
}

/// The platform's answer to the authentication request.
#[derive(Debug, serde::Deserialize)]
pub struct LaunchForm {
    #[serde(default)]
    id_token: Option<String>,
    #[serde(default)]
    state: Option<String>,
    #[serde(default)]
    error: Option<String>,
    #[serde(default)]
    error_description: Option<String>,
}

/// A refused launch: a page that says why and what to do.
fn refused(status: StatusCode, why: impl std::fmt::Display) -> PageError {
    fail(status, format!("This launch from your course was refused: {why}."))
}

/// The LTI pages' Content-Security-Policy: the dashboard's, except that platforms may show the
/// page in a frame (Moodle and Canvas show content selection in one) and, with `form_to`, that
/// its form may post to that origin (the deep linking response). Nothing on these pages acts
/// on a click alone: the picker needs its one-use token, the rest are links.
fn lti_policy(mut r: Response, form_to: Option<&str>) -> Response {
    let mut csp =
        stylet_service::server::CONTENT_SECURITY_POLICY.replace("frame-ancestors 'none'", "frame-ancestors *");
    if let Some(origin) = form_to {
        csp = csp.replace("form-action 'self'", &format!("form-action 'self' {origin}"));
    }
    if let Ok(v) = HeaderValue::from_str(&csp) {
        r.headers_mut().insert(header::CONTENT_SECURITY_POLICY, v);
    }
    r
}

/// `POST /lti/launch`: the launch's page, which a platform may frame.
pub async fn launch(state: State<Arc<AppState>>, form: Form<LaunchForm>) -> Response {
    lti_policy(launch_page(state, form).await.into_response(), None)
}

async fn launch_page(State(s): State<Arc<AppState>>, Form(f): Form<LaunchForm>) -> Result<Response, PageError> {
    if let Some(e) = &f.error {
        // The platform's words only for a launch Stylet started: anyone can post this form.
        let started = match f.state.as_deref().filter(|st| st.len() <= MAX_PARAM_BYTES) {
            Some(st) => s.store.take_lti_launch(&auth::sha256_hex(st)).await?.is_ok(),
            None => false,
        };
        let text = if started {
            lti_text(&format!(
                "the platform answered {e}: {}",
                f.error_description.as_deref().unwrap_or("")
            ))
        } else {
            "the platform answered with an error".to_string()
        };
        return Err(refused(StatusCode::BAD_REQUEST, text));
    }
    let (Some(token), Some(state)) = (f.id_token.as_deref(), f.state.as_deref()) else {
        return Err(refused(StatusCode::BAD_REQUEST, "it carries no id_token and state"));
    };
    if state.len() > MAX_PARAM_BYTES {
        return Err(refused(StatusCode::BAD_REQUEST, "its state is too long"));
    }
    let started = match s.store.take_lti_launch(&auth::sha256_hex(state)).await? {
        Ok(started) => started,
        Err(problem) => {
            let why = match problem {
                LaunchStateProblem::Unknown => {
                    "Stylet did not start this launch (unknown state); open the activity again from your course"
                }
                LaunchStateProblem::Expired => {
                    "it took longer than the 10 minutes a launch may take; open the activity again from your course"
                }
                LaunchStateProblem::Used => {
                    "it was already used (each launch is accepted once: this one was replayed); open the activity again from your course"
                }
            };
            return Err(refused(StatusCode::BAD_REQUEST, why));
        }
    };
    let Some(platform) = s.store.lti_platform(&started.platform_id).await? else {
        return Err(refused(StatusCode::BAD_REQUEST, "its platform is no longer registered"));
    };
    let checked = id_token::check(token, &platform, &started.nonce, &s.lti.key_sets)
        .await
        .map_err(|e| refused(StatusCode::UNAUTHORIZED, e))?;
    let claims = &checked.claims;
    let Some(role) = roles::stylet_role(&claims.roles, &platform.instructor_roles) else {
        return Err(fail(
            StatusCode::FORBIDDEN,
            "Your role in this course gives no access to Stylet: learners train, instructors set exercises and review.",
        ));
    };
    let context = claims.context.as_ref().map(|c| {
        (
            c.id.as_str(),
            c.title.as_deref().or(c.label.as_deref()).unwrap_or("course"),
        )
    });
    let who = LtiIdentity {
        platform: &platform,
        subject: &checked.subject,
        name_hint: claims.email.as_deref().or(claims.name.as_deref()),
        role,
        context,
    };
    let Some(user) = s.store.provision_lti_user(&who).await? else {
        return Err(fail(
            StatusCode::FORBIDDEN,
            "Your Stylet account is disabled; ask an admin.",
        ));
    };
    let mut r = match checked.kind {
        MessageType::ResourceLink => resource_link(&s, &platform, &checked, &user).await?,
        MessageType::DeepLinking => deep_linking(&s, &platform, &checked, &user).await?,
    };
    // Logged in only once the page is there: a refused launch logs nobody in.
    let (login_token, _csrf) = s.store.create_login(&user, stylet_service::api::LOGIN_TTL_S).await?;
    r.headers_mut().append(
        header::SET_COOKIE,
        HeaderValue::from_str(&auth::login_cookie(
            &login_token,
            s.config.secure_cookies,
            stylet_service::api::LOGIN_TTL_S,
        ))
        .expect("a cookie is ASCII"),
    );
    Ok(r)
}

/// Text from the platform, bounded, for a page.
fn lti_text(s: &str) -> String {
    s.chars().take(300).collect()
}

/// The exercises an instructor may pick: every training scenario of the atlases in the
/// catalogue (not withdrawn) at every level, `(scenario, level)`.
fn exercises(s: &AppState) -> Vec<(String, Difficulty)> {
    let mut scenarios: Vec<String> = s
        .catalogue
        .entries()
        .into_iter()
        .filter(|(_, e)| !e.withdrawn())
        .flat_map(|(_, e)| e.summary.training.clone())
        .collect();
    scenarios.sort();
    scenarios.dedup();
    scenarios
        .into_iter()
        .flat_map(|sc| Difficulty::ALL.map(|d| (sc.clone(), d)))
        .collect()
}

async fn resource_link(
    s: &AppState,
    platform: &LtiPlatform,
    launch: &CheckedLaunch,
    user: &stylet_service::store::User,
) -> Result<Response, PageError> {
    let c = &launch.claims;
    let link = c
        .resource_link
        .as_ref()
        .expect("checked: a resource link launch has one");
    let scenario = c.custom_text("scenario");
    let level = c.custom_text("level").and_then(|l| l.parse::<Difficulty>().ok());
    let (Some(scenario), Some(level)) = (scenario, level) else {
        let body = html! {
            h1 { "Stylet" }
            p.error role="alert" #lti-no-exercise {
                "This course activity names no Stylet exercise. Your instructor adds one with the course's "
                "content selection (LTI deep linking), which sets the scenario and the level."
            }
            p { a href="/" { "Go to your Stylet dashboard" } }
        };
        return Ok((StatusCode::OK, page("Stylet", None, body)).into_response());
    };
    let lineitem = c
        .ags
        .as_ref()
        .filter(|a| a.scope.iter().any(|sc| sc == claim::SCORE_SCOPE))
        .and_then(|a| a.lineitem.clone())
        .filter(|l| l.len() <= 1024 && lti::origin_of(l).is_some());
    s.store
        .record_lti_link(
            &platform.id,
            &link.id,
            &user.id,
            &launch.subject,
            &scenario,
            level.as_str(),
            lineitem.as_deref(),
        )
        .await?;
    let known = exercises(s).iter().any(|(sc, _)| *sc == scenario);
    let title = link
        .title
        .clone()
        .unwrap_or_else(|| deep_link::title_of(&scenario, level));
    let body = html! {
        h1 #lti-exercise { (title) }
        p { "Signed in to Stylet as " strong #lti-username { (user.username) } " (" (user.role) ")." }
        @if !known { p.error role="alert" { "The scenario " code { (scenario) } " is not in this server's catalogue; tell your instructor." } }
        h2 { "Your exercise" }
        p { "Scenario " strong { (scenario) } " at the " strong { (level.as_str()) } " level." }
        ol.steps {
            li { "Start the Stylet simulator. If it is not paired with your account yet, " a href="/pair" { "show a pairing code" } " and type it on its start screen." }
            li { "Choose the scenario " strong { (scenario) } " at the " strong { (level.as_str()) } " level, and do the puncture." }
            li { "Your session is uploaded and scored by replay. "
                @if lineitem.is_some() { "Your score, and whether you passed and why, go to your course's gradebook." }
                @else { "This activity has no gradebook column; your scores are on your Stylet dashboard." } }
        }
        p { a href="/" { "Open your Stylet dashboard" } }
    };
    Ok(page("Stylet exercise", None, body).into_response())
}

async fn deep_linking(
    s: &AppState,
    platform: &LtiPlatform,
    launch: &CheckedLaunch,
    user: &stylet_service::store::User,
) -> Result<Response, PageError> {
    if user.role < Role::Instructor {
        return Err(fail(
            StatusCode::FORBIDDEN,
            format!(
                "Only instructors add Stylet exercises to a course, and your Stylet account ({}) is a {} account: \
                 an account keeps the role of its first launch; a Stylet admin changes it.",
                user.username, user.role
            ),
        ));
    }
    let settings = launch
        .claims
        .deep_linking
        .as_ref()
        .expect("checked: a deep linking launch has settings");
    if !settings.accept_types.is_empty() && !settings.accept_types.iter().any(|t| t == "ltiResourceLink") {
        return Err(refused(
            StatusCode::BAD_REQUEST,
            "the platform does not accept LTI resource links here",
        ));
    }
    if lti::origin_of(&settings.deep_link_return_url).is_none() || settings.deep_link_return_url.len() > 1024 {
        return Err(refused(
            StatusCode::BAD_REQUEST,
            "its deep linking return URL is not an http(s) URL",
        ));
    }
    let data = settings.data.as_ref().map(|d| d.to_string());
    if data.as_ref().is_some_and(|d| d.len() > MAX_DEEP_LINK_DATA_BYTES) {
        return Err(refused(
            StatusCode::BAD_REQUEST,
            format!("its deep linking data is over {MAX_DEEP_LINK_DATA_BYTES} bytes"),
        ));
    }
    let token = auth::random_token();
    s.store
        .save_deep_link(
            &auth::sha256_hex(&token),
            &DeepLinkRequest {
                platform_id: platform.id.clone(),
                deployment_id: launch.deployment_id.clone(),
                return_url: settings.deep_link_return_url.clone(),
                data,
                user_id: user.id.clone(),
            },
            std::time::Duration::from_secs(DEEP_LINK_MINUTES * 60),
        )
        .await?;
    let options = exercises(s);
    let body = html! {
        h1 { "Add a Stylet exercise to the course" }
        p.muted { "Pick the scenario and the level; the course gets an activity that opens it, with a gradebook column (score out of 100)." }
        form #lti-pick method="post" action="/lti/deep-link" {
            input type="hidden" name="token" value=(token);
            p { label { "Exercise "
                select #lti-exercise-choice name="exercise" required {
                    @for (sc, d) in &options {
                        option value=(format!("{sc}/{}", d.as_str())) { (sc) " — " (d.as_str()) }
                    }
                }
            } }
            p { label { "Title in the course (optional) " input #lti-title name="title" maxlength="100"; } }
            p { button.primary type="submit" { "Add to the course" } }
        }
    };
    Ok(page("Add a Stylet exercise", None, body).into_response())
}

#[derive(Debug, serde::Deserialize)]
pub struct PickForm {
    token: String,
    exercise: String,
    #[serde(default)]
    title: String,
}

/// `POST /lti/deep-link`: the signed response, posted to the platform by the page (which a
/// platform may frame).
pub async fn pick(state: State<Arc<AppState>>, form: Form<PickForm>) -> Response {
    match sending_page(state, form).await {
        Ok((r, return_url)) => lti_policy(r, lti::origin_of(&return_url)),
        Err(e) => lti_policy(e.into_response(), None),
    }
}

async fn sending_page(
    State(s): State<Arc<AppState>>,
    Form(f): Form<PickForm>,
) -> Result<(Response, String), PageError> {
    let chosen = f
        .exercise
        .split_once('/')
        .and_then(|(sc, d)| Some((sc.to_string(), d.parse::<Difficulty>().ok()?)))
        .filter(|c| exercises(&s).contains(c));
    let Some((scenario, difficulty)) = chosen else {
        return Err(fail(StatusCode::BAD_REQUEST, "pick one of the exercises offered"));
    };
    let title = f.title.trim();
    if title.chars().count() > 100 || title.chars().any(char::is_control) {
        return Err(fail(
            StatusCode::BAD_REQUEST,
            "a title is at most 100 characters on one line",
        ));
    }
    let Some(request) = s.store.take_deep_link(&auth::sha256_hex(&f.token)).await? else {
        return Err(fail(
            StatusCode::BAD_REQUEST,
            "this choice has expired or was already sent; start again from the course's content selection",
        ));
    };
    let Some(platform) = s.store.lti_platform(&request.platform_id).await? else {
        return Err(fail(StatusCode::BAD_REQUEST, "the platform is no longer registered"));
    };
    let activity = deep_link::Activity {
        title: if title.is_empty() {
            deep_link::title_of(&scenario, difficulty)
        } else {
            title.to_string()
        },
        scenario,
        difficulty,
    };
    let data = request.data.as_deref().and_then(|d| serde_json::from_str(d).ok());
    let claims = deep_link::response_claims(&platform, &request.deployment_id, data, &activity, lti::unix_now_s());
    let key = lti::tool_key(&s).await.map_err(|e| {
        tracing::error!(error = %e, "no LTI tool key");
        fail(
            StatusCode::INTERNAL_SERVER_ERROR,
            "Stylet cannot sign the response (its LTI key); see the server log",
        )
    })?;
    let jwt = key
        .sign(&claims)
        .map_err(|e| fail(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))?;
    let body = html! {
        h1 { "Sending the exercise to your course…" }
        p { strong { (activity.title) } }
        form #lti-return method="post" action=(request.return_url) {
            input type="hidden" name="JWT" value=(jwt);
            button.primary type="submit" { "Back to the course" }
        }
        script src="/lti/submit.js" {}
    };
    Ok((
        page("Sending to the course", None, body).into_response(),
        request.return_url,
    ))
}

/// `GET /lti/submit.js`: posts the page's form (the deep linking response) at once.
pub async fn submit_js() -> Response {
    crate::layout::asset("text/javascript", "document.getElementById('lti-return').submit();\n")
}

/// `GET /lti/jwks`: the tool's public key set.
#[utoipa::path(get, path = "/lti/jwks", tag = "lti",
    summary = "The tool's public keys (JWKS) for LTI 1.3 platforms",
    responses(
        (status = 200, description = "the key set (RFC 7517)", content_type = "application/json", body = Object),
        (status = 500, description = "the key could not be loaded or made", content_type = "application/json", body = Object),
    ))]
pub async fn jwks(State(s): State<Arc<AppState>>) -> Response {
    match lti::tool_key(&s).await {
        Ok(key) => {
            let mut r = Json(key.key_set()).into_response();
            r.headers_mut()
                .insert(header::CACHE_CONTROL, HeaderValue::from_static("public, max-age=300"));
            r
        }
        Err(e) => {
            tracing::error!(error = %e, "no LTI tool key");
            (
                StatusCode::INTERNAL_SERVER_ERROR,
                Json(serde_json::json!({"error": "the LTI key is not available"})),
            )
                .into_response()
        }
    }
}

/// The values a platform's tool registration asks for, from this server's address.
pub fn tool_values(base: &str) -> Vec<(&'static str, String)> {
    vec![
        (
            "Tool URL / target link URI / redirection URI",
            format!("{base}/lti/launch"),
        ),
        (
            "Initiate login URL (OIDC login initiation)",
            format!("{base}/lti/login"),
        ),
        ("Public keyset URL (JWKS)", format!("{base}/lti/jwks")),
        ("Deep linking (content selection) URL", format!("{base}/lti/launch")),
    ]
}

/// `GET /lti/…` shown on the admin page and in the docs, for `markup`.
pub fn tool_values_table(base: &str) -> Markup {
    html! {
        table #lti-tool-values {
            tbody { @for (what, v) in tool_values(base) { tr { th { (what) } td { code { (v) } } } } }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_the_launch_url_is_a_redirect_target() {
        let host = "stylet.example.org";
        assert!(is_launch_url("https://stylet.example.org/lti/launch", host));
        assert!(is_launch_url("http://127.0.0.1:8080/lti/launch", "127.0.0.1:8080"));
        assert!(!is_launch_url("https://stylet.example.org/lti/launch?x=1", host));
        assert!(!is_launch_url("https://evil.example/lti/launch", host), "another host");
        assert!(
            !is_launch_url("https://x@stylet.example.org/lti/launch", host),
            "a user"
        );
        assert!(
            !is_launch_url("https://stylet.example.org:8443/lti/launch", host),
            "another port"
        );
        assert!(!is_launch_url("https://evil.example/steal", host));
        assert!(!is_launch_url("/lti/launch", host));
    }
}
