//! LTI 1.3 records (migration 0017; [`crate::lti`]): registered platforms, the tool's key,
//! launches in progress, the accounts and cohorts launches made, the activities learners
//! launched, deep linking requests and the grade outbox.

use std::time::Duration;

use sqlx::Row;

use super::accounts::{audit_opt, cohort_id_or_create, insert_user};
use super::{Role, Store, StoreError, User, audit_in, from_now, new_id, now};

/// A platform (learning management system) an admin registered.
#[derive(Debug, Clone, serde::Serialize, utoipa::ToSchema)]
pub struct LtiPlatform {
    pub id: String,
    /// Its issuer (`iss` of its id_tokens), e.g. `https://canvas.instructure.com`.
    pub issuer: String,
    /// The client id it gave Stylet.
    pub client_id: String,
    pub deployment_ids: Vec<String>,
    /// Its public keys (JWKS).
    pub keyset_url: String,
    /// Its OIDC authentication endpoint (where a launch's login goes).
    pub auth_url: String,
    /// Its OAuth 2 token endpoint (for grades).
    pub token_url: String,
    /// The LTI roles that make an instructor (short names such as `Instructor`, or full URIs).
    pub instructor_roles: Vec<String>,
    pub created_at: String,
}

/// A platform to register ([`NewLtiPlatform::check`] says what is wrong with one).
#[derive(Debug, Clone, serde::Deserialize, utoipa::ToSchema)]
pub struct NewLtiPlatform {
    pub issuer: String,
    pub client_id: String,
    pub deployment_ids: Vec<String>,
    pub keyset_url: String,
    pub auth_url: String,
    pub token_url: String,
    /// Default: [`DEFAULT_INSTRUCTOR_ROLES`].
    #[serde(default)]
    pub instructor_roles: Vec<String>,
}

/// The LTI context roles that make an instructor unless a platform says otherwise.
pub const DEFAULT_INSTRUCTOR_ROLES: [&str; 3] = ["Instructor", "TeachingAssistant", "ContentDeveloper"];
/// Longest issuer, client id, deployment id or role.
const MAX_ID_CHARS: usize = 255;
/// Longest URL.
const MAX_URL_CHARS: usize = 1024;
/// Most deployment ids (or instructor roles) of a platform.
const MAX_LIST: usize = 50;

impl NewLtiPlatform {
    /// Every problem of the registration, in words; empty when it is good. URLs must be
    /// absolute http(s) (https in production: docs/integration.md).
    pub fn check(&self) -> Vec<String> {
        let mut problems = Vec::new();
        for (what, url) in [
            ("the issuer", &self.issuer),
            ("the keyset URL", &self.keyset_url),
            ("the authentication URL", &self.auth_url),
            ("the access token URL", &self.token_url),
        ] {
            let scheme_ok = url.starts_with("https://") || url.starts_with("http://");
            if !scheme_ok || url.len() > MAX_URL_CHARS || url.chars().any(|c| c.is_control() || c.is_whitespace()) {
                problems.push(format!(
                    "{what} must be an http(s) URL of at most {MAX_URL_CHARS} characters"
                ));
            }
        }
        problems.extend(id_problem("the client id", &self.client_id));
        problems.extend(deployment_problems(&self.deployment_ids));
        if self.instructor_roles.len() > MAX_LIST {
            problems.push(format!("give at most {MAX_LIST} instructor roles"));
        }
        problems.extend(
            self.instructor_roles
                .iter()
                .filter_map(|r| id_problem("an instructor role", r)),
        );
        problems.dedup();
        problems
    }
}

/// What is wrong with an id (client id, deployment id, role), if anything.
fn id_problem(what: &str, v: &str) -> Option<String> {
    (v.is_empty() || v.chars().count() > MAX_ID_CHARS || v.chars().any(|c| c.is_control() || c.is_whitespace()))
        .then(|| format!("{what} must be 1–{MAX_ID_CHARS} characters without spaces"))
}

/// What is wrong with a platform's deployment ids.
pub fn deployment_problems(ids: &[String]) -> Vec<String> {
    let mut problems = Vec::new();
    if ids.is_empty() || ids.len() > MAX_LIST {
        problems.push(format!("give 1–{MAX_LIST} deployment ids"));
    }
    problems.extend(ids.iter().filter_map(|d| id_problem("a deployment id", d)));
    problems.dedup();
    problems
}

/// Why a launch's state was not accepted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LaunchStateProblem {
    /// No launch of that state (never started here, or long gone).
    Unknown,
    Expired,
    /// Its id_token came already (a replayed launch).
    Used,
}

/// A launch between login initiation and id_token.
#[derive(Debug, Clone)]
pub struct LaunchState {
    pub platform_id: String,
    pub nonce: String,
}

/// Launches begun (login initiated) in the last [`crate::lti::LAUNCH_MINUTES`] allowed from one
/// client address (an IPv6 address counts as its /64).
pub const MAX_PENDING_LAUNCHES_PER_ADDRESS: i64 = 30;
/// Launches begun in the last [`crate::lti::LAUNCH_MINUTES`] allowed from all addresses together.
pub const MAX_PENDING_LAUNCHES: i64 = 20_000;

/// Who a launch is about, for [`Store::provision_lti_user`].
#[derive(Debug, Clone)]
pub struct LtiIdentity<'a> {
    pub platform: &'a LtiPlatform,
    pub subject: &'a str,
    /// A name to derive the username from (the email, else the name), if any.
    pub name_hint: Option<&'a str>,
    pub role: Role,
    /// The course: (context id, title).
    pub context: Option<(&'a str, &'a str)>,
}

/// A deep linking request waiting for the instructor's choice.
#[derive(Debug, Clone)]
pub struct DeepLinkRequest {
    pub platform_id: String,
    pub deployment_id: String,
    pub return_url: String,
    pub data: Option<String>,
    pub user_id: String,
}

/// A grade due for a platform's line item.
#[derive(Debug, Clone)]
pub struct DueGrade {
    pub id: String,
    pub platform_id: String,
    pub lineitem_url: String,
    pub score_json: String,
    pub attempts: i64,
}

fn lines(v: &[String]) -> String {
    v.join("\n")
}

fn unlines(v: &str) -> Vec<String> {
    v.lines().filter(|l| !l.is_empty()).map(str::to_string).collect()
}

fn platform_of(r: &sqlx::any::AnyRow) -> Result<LtiPlatform, sqlx::Error> {
    Ok(LtiPlatform {
        id: r.try_get("id")?,
        issuer: r.try_get("issuer")?,
        client_id: r.try_get("client_id")?,
        deployment_ids: unlines(&r.try_get::<String, _>("deployment_ids")?),
        keyset_url: r.try_get("keyset_url")?,
        auth_url: r.try_get("auth_url")?,
        token_url: r.try_get("token_url")?,
        instructor_roles: unlines(&r.try_get::<String, _>("instructor_roles")?),
        created_at: r.try_get("created_at")?,
    })
}

/// `SELECT <every column> FROM lti_platforms <rest>`, as one literal.
macro_rules! select_platforms {
    ($rest:literal) => {
        concat!(
            "SELECT id, issuer, client_id, deployment_ids, keyset_url, auth_url, token_url, instructor_roles, created_at \
             FROM lti_platforms ",
            $rest
        )
    };
}

/// A username from `hint` (an email or a name): the allowed characters, lower case, at most
/// 40; None when nothing is left.
fn username_from(hint: &str) -> Option<String> {
    let name: String = hint
        .trim()
        .to_lowercase()
        .chars()
        .map(|c| if c.is_whitespace() { '.' } else { c })
        .filter(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-' | '@'))
        .take(40)
        .collect();
    (!name.is_empty()).then_some(name)
}

/// The first 8 bytes of the SHA-256 of `parts`, in hex.
fn short_hash(parts: &[&str]) -> String {
    use sha2::{Digest, Sha256};
    let h = Sha256::digest(parts.join("\n"));
    h[..8].iter().map(|b| format!("{b:02x}")).collect()
}

impl Store {
    /// Registers a platform (already [`NewLtiPlatform::check`]ed); audited. A platform of the
    /// same issuer and client id is refused.
    pub async fn add_lti_platform(&self, p: &NewLtiPlatform, actor: Option<&str>) -> Result<LtiPlatform, StoreError> {
        let problems = p.check();
        if !problems.is_empty() {
            return Err(StoreError::Invalid(problems.join("; ")));
        }
        let roles: Vec<String> = if p.instructor_roles.is_empty() {
            DEFAULT_INSTRUCTOR_ROLES.iter().map(|r| r.to_string()).collect()
        } else {
            p.instructor_roles.clone()
        };
        let id = new_id();
        let mut tx = self.begin_write().await?;
        let exists = sqlx::query("SELECT id FROM lti_platforms WHERE issuer = $1 AND client_id = $2")
            .bind(p.issuer.clone())
            .bind(p.client_id.clone())
            .fetch_optional(&mut *tx)
            .await?;
        if exists.is_some() {
            return Err(StoreError::LtiPlatformExists {
                issuer: p.issuer.clone(),
                client_id: p.client_id.clone(),
            });
        }
        sqlx::query(
            "INSERT INTO lti_platforms (id, issuer, client_id, deployment_ids, keyset_url, auth_url, token_url, instructor_roles, created_at) \
             VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9)",
        )
        .bind(id.clone())
        .bind(p.issuer.clone())
        .bind(p.client_id.clone())
        .bind(lines(&p.deployment_ids))
        .bind(p.keyset_url.clone())
        .bind(p.auth_url.clone())
        .bind(p.token_url.clone())
        .bind(lines(&roles))
        .bind(now())
        .execute(&mut *tx)
        .await?;
        audit_opt(
            &mut tx,
            actor,
            "lti.platform.add",
            &id,
            &format!("{} (client id {})", p.issuer, p.client_id),
        )
        .await?;
        tx.commit().await?;
        Ok(self.lti_platform(&id).await?.expect("just added"))
    }

    /// Adds a deployment id to platform `platform_id` (a platform gives each installation of the
    /// tool its own); audited. Invalid: the id is malformed, there already, or one too many.
    pub async fn add_lti_deployment(
        &self,
        platform_id: &str,
        deployment_id: &str,
        actor: Option<&str>,
    ) -> Result<Option<LtiPlatform>, StoreError> {
        let mut tx = self.begin_write().await?;
        let row = sqlx::query("SELECT deployment_ids FROM lti_platforms WHERE id = $1")
            .bind(platform_id.to_string())
            .fetch_optional(&mut *tx)
            .await?;
        let Some(row) = row else { return Ok(None) };
        let mut ids = unlines(&row.try_get::<String, _>("deployment_ids")?);
        if ids.iter().any(|d| d == deployment_id) {
            return Err(StoreError::Invalid(format!(
                "the deployment id {deployment_id} is registered already"
            )));
        }
        ids.push(deployment_id.to_string());
        let problems = deployment_problems(&ids);
        if !problems.is_empty() {
            return Err(StoreError::Invalid(problems.join("; ")));
        }
        sqlx::query("UPDATE lti_platforms SET deployment_ids = $1 WHERE id = $2")
            .bind(lines(&ids))
            .bind(platform_id.to_string())
            .execute(&mut *tx)
            .await?;
        audit_opt(&mut tx, actor, "lti.deployment.add", platform_id, deployment_id).await?;
        tx.commit().await?;
        self.lti_platform(platform_id).await
    }

    /// Every registered platform, oldest first (an admin registers a handful).
    pub async fn lti_platforms(&self) -> Result<Vec<LtiPlatform>, StoreError> {
        let rows = sqlx::query(select_platforms!("ORDER BY created_at, id LIMIT 1000"))
            .fetch_all(&self.pool)
            .await?;
        Ok(rows.iter().map(platform_of).collect::<Result<_, _>>()?)
    }

    pub async fn lti_platform(&self, id: &str) -> Result<Option<LtiPlatform>, StoreError> {
        let row = sqlx::query(select_platforms!("WHERE id = $1"))
            .bind(id.to_string())
            .fetch_optional(&self.pool)
            .await?;
        Ok(row.as_ref().map(platform_of).transpose()?)
    }

    /// The platforms of `issuer` (with `client_id`, the one of that client id).
    pub async fn lti_platforms_of(
        &self,
        issuer: &str,
        client_id: Option<&str>,
    ) -> Result<Vec<LtiPlatform>, StoreError> {
        let rows = sqlx::query(select_platforms!(
            "WHERE issuer = $1 AND ($2 = '' OR client_id = $2) ORDER BY created_at LIMIT 50"
        ))
        .bind(issuer.to_string())
        .bind(client_id.unwrap_or("").to_string())
        .fetch_all(&self.pool)
        .await?;
        Ok(rows.iter().map(platform_of).collect::<Result<_, _>>()?)
    }

    /// The tool's signing key, `(kid, PKCS#8 PEM)`, if one was made.
    pub async fn lti_tool_key(&self) -> Result<Option<(String, String)>, StoreError> {
        let row = sqlx::query("SELECT kid, private_pem FROM lti_tool_keys WHERE slot = 'signing'")
            .fetch_optional(&self.pool)
            .await?;
        Ok(match row {
            Some(r) => Some((r.try_get("kid")?, r.try_get("private_pem")?)),
            None => None,
        })
    }

    /// Stores a signing key unless one is there already (then that one stays: replicas making a
    /// key at once all end up with the first written).
    pub async fn insert_lti_tool_key(&self, kid: &str, pem: &str) -> Result<(), StoreError> {
        sqlx::query(
            "INSERT INTO lti_tool_keys (slot, kid, private_pem, created_at) VALUES ('signing', $1, $2, $3) ON CONFLICT (slot) DO NOTHING",
        )
        .bind(kid.to_string())
        .bind(pem.to_string())
        .bind(now())
        .execute(&self.pool)
        .await?;
        Ok(())
    }

    /// Records a launch's login initiation: its state (hashed) and nonce, valid for `ttl`.
    /// Refused ([`StoreError::TooManyLaunches`]) past [`MAX_PENDING_LAUNCHES_PER_ADDRESS`] from
    /// `address` or [`MAX_PENDING_LAUNCHES`] in all, begun within `ttl`.
    pub async fn begin_lti_launch(
        &self,
        state_sha256: &str,
        nonce: &str,
        platform_id: &str,
        address: &str,
        ttl: Duration,
    ) -> Result<(), StoreError> {
        let at = now();
        let mut tx = self.begin_write().await?;
        // Every launch begun in the last LAUNCH_MINUTES counts, used or not: a launch that was
        // posted (even with a bad id_token) frees no place.
        let counts = sqlx::query(
            "SELECT CAST(COUNT(*) AS BIGINT) AS n, CAST(COALESCE(SUM(CASE WHEN client_address = $2 THEN 1 ELSE 0 END), 0) AS BIGINT) AS mine \
             FROM lti_launch_states WHERE expires_at > $1",
        )
        .bind(at.clone())
        .bind(address.to_string())
        .fetch_one(&mut *tx)
        .await?;
        let (all, mine): (i64, i64) = (counts.try_get("n")?, counts.try_get("mine")?);
        if mine >= MAX_PENDING_LAUNCHES_PER_ADDRESS || all >= MAX_PENDING_LAUNCHES {
            return Err(StoreError::TooManyLaunches);
        }
        sqlx::query(
            "INSERT INTO lti_launch_states (state_sha256, nonce, platform_id, client_address, created_at, expires_at) \
             VALUES ($1, $2, $3, $4, $5, $6)",
        )
        .bind(state_sha256.to_string())
        .bind(nonce.to_string())
        .bind(platform_id.to_string())
        .bind(address.to_string())
        .bind(at)
        .bind(from_now(ttl))
        .execute(&mut *tx)
        .await?;
        tx.commit().await?;
        Ok(())
    }

    /// Takes the launch of state `state_sha256` (once: it is marked used).
    pub async fn take_lti_launch(
        &self,
        state_sha256: &str,
    ) -> Result<Result<LaunchState, LaunchStateProblem>, StoreError> {
        let at = now();
        let mut tx = self.begin_write().await?;
        let row = sqlx::query(
            "SELECT platform_id, nonce, expires_at, used_at FROM lti_launch_states WHERE state_sha256 = $1",
        )
        .bind(state_sha256.to_string())
        .fetch_optional(&mut *tx)
        .await?;
        let Some(row) = row else {
            return Ok(Err(LaunchStateProblem::Unknown));
        };
        if row.try_get::<Option<String>, _>("used_at")?.is_some() {
            return Ok(Err(LaunchStateProblem::Used));
        }
        if row.try_get::<String, _>("expires_at")? <= at {
            return Ok(Err(LaunchStateProblem::Expired));
        }
        let marked =
            sqlx::query("UPDATE lti_launch_states SET used_at = $1 WHERE state_sha256 = $2 AND used_at IS NULL")
                .bind(at)
                .bind(state_sha256.to_string())
                .execute(&mut *tx)
                .await?;
        if marked.rows_affected() != 1 {
            return Ok(Err(LaunchStateProblem::Used));
        }
        tx.commit().await?;
        Ok(Ok(LaunchState {
            platform_id: row.try_get("platform_id")?,
            nonce: row.try_get("nonce")?,
        }))
    }

    /// The account of an LTI user, made on their first launch with the role of that launch (no
    /// password: they come through the platform). A later launch never changes the role: a
    /// learner of one course who teaches another would otherwise see their classmates' sessions
    /// as an instructor; an admin changes it. With a course, the account joins the course's
    /// cohort (made on its first launch) when the launch's role is the account's (a trainee
    /// learns in it, an instructor teaches it). Audited. None: the account is disabled.
    ///
    /// Two first launches at once (a class opening a new activity, a double-posted form) race for
    /// the same cohort, account or username: the loser tries once more, and finds the winner's.
    pub async fn provision_lti_user(&self, who: &LtiIdentity<'_>) -> Result<Option<User>, StoreError> {
        match self.provision_once(who).await {
            Err(StoreError::Db(e)) if e.as_database_error().is_some_and(|d| d.is_unique_violation()) => {
                self.provision_once(who).await
            }
            other => other,
        }
    }

    async fn provision_once(&self, who: &LtiIdentity<'_>) -> Result<Option<User>, StoreError> {
        let platform = who.platform;
        let mut tx = self.begin_write().await?;
        let linked = sqlx::query(
            "SELECT u.id, u.username, u.role, u.disabled_at FROM lti_users l JOIN users u ON u.id = l.user_id \
             WHERE l.platform_id = $1 AND l.subject = $2",
        )
        .bind(platform.id.clone())
        .bind(who.subject.to_string())
        .fetch_optional(&mut *tx)
        .await?;
        let user = match linked {
            Some(r) => {
                if r.try_get::<Option<String>, _>("disabled_at")?.is_some() {
                    return Ok(None);
                }
                Self::user_of(&r)?
            }
            None => {
                let fallback = format!("lti-{}", short_hash(&[&platform.id, who.subject]));
                let mut username = fallback.clone();
                if let Some(hint) = who.name_hint.and_then(username_from) {
                    let taken = sqlx::query("SELECT 1 AS one FROM users WHERE username = $1")
                        .bind(hint.clone())
                        .fetch_optional(&mut *tx)
                        .await?;
                    if taken.is_none() {
                        username = hint;
                    }
                }
                let id = new_id();
                // No password can match "!": the account logs in through its platform only.
                insert_user(&mut tx, &id, &username, who.role, "!lti", None).await?;
                sqlx::query("INSERT INTO lti_users (platform_id, subject, user_id) VALUES ($1, $2, $3)")
                    .bind(platform.id.clone())
                    .bind(who.subject.to_string())
                    .bind(id.clone())
                    .execute(&mut *tx)
                    .await?;
                audit_in(
                    &mut tx,
                    &id,
                    "user.add",
                    &id,
                    &format!("{username} as {} from LTI platform {}", who.role, platform.issuer),
                )
                .await?;
                User {
                    id,
                    username,
                    role: who.role,
                }
            }
        };
        if let Some((context_id, title)) = who.context.filter(|_| user.role == who.role) {
            let row = sqlx::query("SELECT cohort_id FROM lti_contexts WHERE platform_id = $1 AND context_id = $2")
                .bind(platform.id.clone())
                .bind(context_id.to_string())
                .fetch_optional(&mut *tx)
                .await?;
            let cohort_id: String = match row {
                Some(r) => r.try_get("cohort_id")?,
                None => {
                    let stem = username_from(title).unwrap_or_else(|| "course".into());
                    let name = format!(
                        "{}-{}",
                        &stem[..stem.len().min(40)],
                        short_hash(&[&platform.id, context_id])
                    );
                    let id = cohort_id_or_create(&mut tx, &name).await?;
                    sqlx::query("INSERT INTO lti_contexts (platform_id, context_id, cohort_id) VALUES ($1, $2, $3)")
                        .bind(platform.id.clone())
                        .bind(context_id.to_string())
                        .bind(id.clone())
                        .execute(&mut *tx)
                        .await?;
                    id
                }
            };
            sqlx::query("INSERT INTO cohort_members (cohort_id, user_id) VALUES ($1, $2) ON CONFLICT (cohort_id, user_id) DO NOTHING")
                .bind(cohort_id)
                .bind(user.id.clone())
                .execute(&mut *tx)
                .await?;
        }
        tx.commit().await?;
        Ok(Some(user))
    }

    /// Records that `user` launched an activity (a resource link) of exercise `scenario` at
    /// `difficulty`, whose grades go to `lineitem_url` when the platform gave one (a launch
    /// without one keeps the line item an earlier launch gave).
    #[allow(clippy::too_many_arguments)]
    pub async fn record_lti_link(
        &self,
        platform_id: &str,
        resource_link_id: &str,
        user_id: &str,
        subject: &str,
        scenario: &str,
        difficulty: &str,
        lineitem_url: Option<&str>,
    ) -> Result<(), StoreError> {
        sqlx::query(
            "INSERT INTO lti_links (platform_id, resource_link_id, user_id, subject, scenario, difficulty, lineitem_url, launched_at) \
             VALUES ($1, $2, $3, $4, $5, $6, $7, $8) ON CONFLICT (platform_id, resource_link_id, user_id) DO UPDATE SET \
             subject = $4, scenario = $5, difficulty = $6, lineitem_url = COALESCE($7, lti_links.lineitem_url), launched_at = $8",
        )
        .bind(platform_id.to_string())
        .bind(resource_link_id.to_string())
        .bind(user_id.to_string())
        .bind(subject.to_string())
        .bind(scenario.to_string())
        .bind(difficulty.to_string())
        .bind(lineitem_url.map(str::to_string))
        .bind(now())
        .execute(&self.pool)
        .await?;
        Ok(())
    }

    /// Keeps a deep linking request under its token (hashed) for `ttl`.
    pub async fn save_deep_link(
        &self,
        token_sha256: &str,
        r: &DeepLinkRequest,
        ttl: Duration,
    ) -> Result<(), StoreError> {
        sqlx::query(
            "INSERT INTO lti_deep_links (token_sha256, platform_id, deployment_id, return_url, data, user_id, expires_at) \
             VALUES ($1, $2, $3, $4, $5, $6, $7)",
        )
        .bind(token_sha256.to_string())
        .bind(r.platform_id.clone())
        .bind(r.deployment_id.clone())
        .bind(r.return_url.clone())
        .bind(r.data.clone())
        .bind(r.user_id.clone())
        .bind(from_now(ttl))
        .execute(&self.pool)
        .await?;
        Ok(())
    }

    /// Takes the deep linking request of a token (once; None when unknown, used or expired).
    pub async fn take_deep_link(&self, token_sha256: &str) -> Result<Option<DeepLinkRequest>, StoreError> {
        let at = now();
        let mut tx = self.begin_write().await?;
        let row = sqlx::query(
            "SELECT platform_id, deployment_id, return_url, data, user_id FROM lti_deep_links \
             WHERE token_sha256 = $1 AND used_at IS NULL AND expires_at > $2",
        )
        .bind(token_sha256.to_string())
        .bind(at.clone())
        .fetch_optional(&mut *tx)
        .await?;
        let Some(r) = row else { return Ok(None) };
        let marked = sqlx::query("UPDATE lti_deep_links SET used_at = $1 WHERE token_sha256 = $2 AND used_at IS NULL")
            .bind(at)
            .bind(token_sha256.to_string())
            .execute(&mut *tx)
            .await?;
        if marked.rows_affected() != 1 {
            return Ok(None);
        }
        tx.commit().await?;
        Ok(Some(DeepLinkRequest {
            platform_id: r.try_get("platform_id")?,
            deployment_id: r.try_get("deployment_id")?,
            return_url: r.try_get("return_url")?,
            data: r.try_get("data")?,
            user_id: r.try_get("user_id")?,
        }))
    }

    /// Queues, inside the score's transaction, a grade for every line item of an activity of
    /// this session's exercise that its trainee launched; `score_json(subject)` makes the body.
    pub(super) async fn queue_grades(
        tx: &mut sqlx::Transaction<'_, sqlx::Any>,
        session_id: &str,
        score_json: impl Fn(&str) -> String,
    ) -> Result<(), StoreError> {
        let links = sqlx::query(
            "SELECT l.platform_id, l.lineitem_url, l.subject FROM sessions s JOIN lti_links l \
             ON l.user_id = s.trainee_id AND l.scenario = s.scenario AND l.difficulty = s.difficulty \
             WHERE s.id = $1 AND l.lineitem_url IS NOT NULL LIMIT 100",
        )
        .bind(session_id.to_string())
        .fetch_all(&mut **tx)
        .await?;
        let at = now();
        for l in links {
            let (platform, lineitem, subject): (String, String, String) = (
                l.try_get("platform_id")?,
                l.try_get("lineitem_url")?,
                l.try_get("subject")?,
            );
            let id = short_hash(&[session_id, &platform, &lineitem]);
            // The latest session is the grade: one still waiting for an earlier session is not
            // sent after it (AGS 2.0 §3.4: a platform keeps the score of the latest timestamp).
            sqlx::query(
                "UPDATE lti_grade_outbox SET delivered_at = $1, last_error = 'superseded by a later session' \
                 WHERE platform_id = $2 AND lineitem_url = $3 AND subject = $4 AND delivered_at IS NULL",
            )
            .bind(at.clone())
            .bind(platform.clone())
            .bind(lineitem.clone())
            .bind(subject.clone())
            .execute(&mut **tx)
            .await?;
            sqlx::query(
                "INSERT INTO lti_grade_outbox (id, session_id, platform_id, lineitem_url, subject, score_json, created_at, attempts, next_attempt_at) \
                 VALUES ($1, $2, $3, $4, $5, $6, $7, 0, $7) ON CONFLICT (id) DO NOTHING",
            )
            .bind(id)
            .bind(session_id.to_string())
            .bind(platform)
            .bind(lineitem)
            .bind(subject.clone())
            .bind(score_json(&subject))
            .bind(at.clone())
            .execute(&mut **tx)
            .await?;
        }
        Ok(())
    }

    /// Up to `limit` undelivered grades whose next try is due, oldest first.
    pub async fn due_grades(&self, limit: usize) -> Result<Vec<DueGrade>, StoreError> {
        let rows = sqlx::query(
            "SELECT id, platform_id, lineitem_url, score_json, attempts FROM lti_grade_outbox \
             WHERE delivered_at IS NULL AND next_attempt_at <= $1 ORDER BY created_at, id LIMIT $2",
        )
        .bind(now())
        .bind(limit as i64)
        .fetch_all(&self.pool)
        .await?;
        rows.iter()
            .map(|r| {
                Ok(DueGrade {
                    id: r.try_get("id")?,
                    platform_id: r.try_get("platform_id")?,
                    lineitem_url: r.try_get("lineitem_url")?,
                    score_json: r.try_get("score_json")?,
                    attempts: r.try_get("attempts")?,
                })
            })
            .collect::<Result<_, sqlx::Error>>()
            .map_err(StoreError::from)
    }

    /// The platform took grade `id`, or answered for good without taking it (`note`).
    pub async fn grade_delivered(&self, id: &str, note: Option<&str>) -> Result<(), StoreError> {
        sqlx::query(
            "UPDATE lti_grade_outbox SET delivered_at = $1, attempts = attempts + 1, last_error = $3 WHERE id = $2",
        )
        .bind(now())
        .bind(id.to_string())
        .bind(note.map(str::to_string))
        .execute(&self.pool)
        .await?;
        Ok(())
    }

    /// Platform `platform_id` could not be reached (`why`): every grade of it that is due now
    /// waits `wait` (counted as a try), so that they do not fill the next rounds.
    pub async fn platform_unreachable(&self, platform_id: &str, why: &str, wait: Duration) -> Result<(), StoreError> {
        sqlx::query(
            "UPDATE lti_grade_outbox SET attempts = attempts + 1, next_attempt_at = $1, last_error = $2 \
             WHERE platform_id = $3 AND delivered_at IS NULL AND next_attempt_at <= $4",
        )
        .bind(from_now(wait))
        .bind(why.chars().take(500).collect::<String>())
        .bind(platform_id.to_string())
        .bind(now())
        .execute(&self.pool)
        .await?;
        Ok(())
    }

    /// The platform did not take grade `id` (`why`): tried again after `wait`.
    pub async fn grade_refused(&self, id: &str, why: &str, wait: Duration) -> Result<(), StoreError> {
        sqlx::query(
            "UPDATE lti_grade_outbox SET attempts = attempts + 1, next_attempt_at = $1, last_error = $2 \
             WHERE id = $3 AND delivered_at IS NULL",
        )
        .bind(from_now(wait))
        .bind(why.chars().take(500).collect::<String>())
        .bind(id.to_string())
        .execute(&self.pool)
        .await?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::super::NewSession;
    use super::*;

    fn registration() -> NewLtiPlatform {
        NewLtiPlatform {
            issuer: "https://lms.example.org".into(),
            client_id: "stylet".into(),
            deployment_ids: vec!["d1".into()],
            keyset_url: "https://lms.example.org/jwks".into(),
            auth_url: "https://lms.example.org/auth".into(),
            token_url: "https://lms.example.org/token".into(),
            instructor_roles: vec![],
        }
    }

    /// Uploads and scores a session of `trainee` ("success", beginner); its id.
    async fn scored_session(store: &Store, trainee: &str, k: usize) -> String {
        let id = store
            .insert_session(&NewSession {
                file_sha256: format!("{k:064x}"),
                size_bytes: 10,
                session_uuid: new_id(),
                trainee_id: trainee.to_string(),
                uploaded_by: trainee.to_string(),
                scenario: "success".into(),
                difficulty: "beginner".into(),
                atlas_hash: "atlas-hash".into(),
                physics_version: 2,
                duration_s: 1.0,
                recorded_at: now(),
                request_id: None,
            })
            .await
            .unwrap();
        let job = store.claim_job().await.unwrap().expect("the queued job");
        let mut report: stylet_scoring::ScoreReport =
            serde_json::from_str(include_str!("../../tests/data/report.json")).unwrap();
        report.session_id = id.clone();
        store.finish_job(&job, &report, None).await.unwrap();
        id
    }

    /// First launches at once (a class opening a new activity) make one account and one cohort;
    /// a learner's scored sessions queue grades for the line item, the later superseding the
    /// earlier one still waiting; an unreachable platform holds back its due grades; a grade
    /// answered for good is done.
    async fn launches_and_the_grade_outbox(store: Store) {
        store.register_atlas("atlas-hash", "phantom", "/nowhere").await.unwrap();
        let platform = store.add_lti_platform(&registration(), None).await.unwrap();
        let who = LtiIdentity {
            platform: &platform,
            subject: "sub-1",
            name_hint: Some("lena@uni.example"),
            role: Role::Trainee,
            context: Some(("course-7", "Interventional Radiology")),
        };
        let users = futures_util::future::join_all((0..4).map(|_| store.provision_lti_user(&who))).await;
        let ids: Vec<String> = users.into_iter().map(|u| u.unwrap().unwrap().id).collect();
        assert!(ids.iter().all(|id| *id == ids[0]), "{ids:?}");
        let (accounts, cohorts): (i64, i64) = (
            sqlx::query_scalar("SELECT COUNT(*) FROM users")
                .fetch_one(&store.pool)
                .await
                .unwrap(),
            sqlx::query_scalar("SELECT COUNT(*) FROM cohort_members")
                .fetch_one(&store.pool)
                .await
                .unwrap(),
        );
        assert_eq!((accounts, cohorts), (1, 1));
        let lena = &ids[0];
        store
            .record_lti_link(
                &platform.id,
                "rl-1",
                lena,
                "sub-1",
                "success",
                "beginner",
                Some("https://lms.example.org/li/1"),
            )
            .await
            .unwrap();
        // A launch without a line item keeps the one before.
        store
            .record_lti_link(&platform.id, "rl-1", lena, "sub-1", "success", "beginner", None)
            .await
            .unwrap();

        scored_session(&store, lena, 1).await;
        let first = store.due_grades(10).await.unwrap();
        assert_eq!(first.len(), 1, "{first:?}");
        assert_eq!(first[0].lineitem_url, "https://lms.example.org/li/1");
        assert!(
            first[0].score_json.contains("\"userId\":\"sub-1\""),
            "{}",
            first[0].score_json
        );
        scored_session(&store, lena, 2).await;
        let due = store.due_grades(10).await.unwrap();
        assert_eq!(due.len(), 1, "the earlier grade is superseded: {due:?}");
        assert_ne!(due[0].id, first[0].id);
        let note: Option<String> = sqlx::query_scalar("SELECT last_error FROM lti_grade_outbox WHERE id = $1")
            .bind(first[0].id.clone())
            .fetch_one(&store.pool)
            .await
            .unwrap();
        assert_eq!(note.as_deref(), Some("superseded by a later session"));

        store
            .platform_unreachable(&platform.id, "connection refused", Duration::from_secs(60))
            .await
            .unwrap();
        assert!(
            store.due_grades(10).await.unwrap().is_empty(),
            "the platform's grades wait"
        );
        store
            .grade_delivered(&due[0].id, Some("409: later score"))
            .await
            .unwrap();
        let (attempts, delivered): (i64, Option<String>) =
            sqlx::query_as("SELECT attempts, delivered_at FROM lti_grade_outbox WHERE id = $1")
                .bind(due[0].id.clone())
                .fetch_one(&store.pool)
                .await
                .unwrap();
        assert_eq!(attempts, 2);
        assert!(delivered.is_some());
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 4)]
    async fn launches_and_the_grade_outbox_sqlite() {
        let dir = tempfile::tempdir().unwrap();
        let url = format!("sqlite://{}?mode=rwc", dir.path().join("t.db").display());
        launches_and_the_grade_outbox(Store::open(&url).await.unwrap()).await;
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 4)]
    async fn launches_and_the_grade_outbox_postgres() {
        let url = super::super::fresh_postgres_database("lti_outbox").await;
        launches_and_the_grade_outbox(Store::open(&url).await.unwrap()).await;
    }

    #[test]
    fn usernames_come_from_hints_in_the_allowed_characters() {
        assert_eq!(username_from("Anna Müller").as_deref(), Some("anna.mller"));
        assert_eq!(username_from("anna@uni.example").as_deref(), Some("anna@uni.example"));
        assert_eq!(username_from("  ").as_deref(), None);
        assert_eq!(username_from(&"x".repeat(100)).unwrap().len(), 40);
    }

    #[test]
    fn registrations_name_every_problem() {
        let good = NewLtiPlatform {
            issuer: "https://canvas.instructure.com".into(),
            client_id: "10000000000001".into(),
            deployment_ids: vec!["1:abc".into()],
            keyset_url: "https://canvas.instructure.com/api/lti/security/jwks".into(),
            auth_url: "https://sso.canvaslms.com/api/lti/authorize_redirect".into(),
            token_url: "https://sso.canvaslms.com/login/oauth2/token".into(),
            instructor_roles: vec![],
        };
        assert!(good.check().is_empty(), "{:?}", good.check());
        let bad = NewLtiPlatform {
            issuer: "canvas".into(),
            client_id: "a b".into(),
            deployment_ids: vec![],
            keyset_url: "ftp://x".into(),
            ..good
        };
        let problems = bad.check();
        assert_eq!(problems.len(), 4, "{problems:?}");
        assert!(problems.iter().any(|p| p.contains("issuer")));
        assert!(problems.iter().any(|p| p.contains("keyset")));
        assert!(problems.iter().any(|p| p.contains("client id")));
        assert!(problems.iter().any(|p| p.contains("deployment")));
    }
}
