//! Accounts, logins and cohorts (API tokens: `tokens.rs`).

use sqlx::Row;

use super::super::auth;
use super::User;
use super::{ROLES, Store, StoreError, audit_in, from_now, new_id, now};

/// A role, from least to most administrative; stored and sent as its lower-case name.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize, serde::Deserialize, utoipa::ToSchema,
)]
#[serde(rename_all = "lowercase")]
pub enum Role {
    Trainee,
    Instructor,
    Curriculum,
    Admin,
}

impl Role {
    pub const ALL: [Role; 4] = [Role::Trainee, Role::Instructor, Role::Curriculum, Role::Admin];

    pub fn as_str(self) -> &'static str {
        match self {
            Role::Trainee => "trainee",
            Role::Instructor => "instructor",
            Role::Curriculum => "curriculum",
            Role::Admin => "admin",
        }
    }

    /// The role of a name, or a named error listing the roles.
    pub fn parse(name: &str) -> Result<Role, StoreError> {
        Role::ALL
            .into_iter()
            .find(|r| r.as_str() == name)
            .ok_or_else(|| StoreError::Invalid(format!("unknown role '{name}' (roles: {})", ROLES.join(", "))))
    }
}

impl std::fmt::Display for Role {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl std::str::FromStr for Role {
    type Err = StoreError;
    fn from_str(s: &str) -> Result<Role, StoreError> {
        Role::parse(s)
    }
}

/// Stored as text (`users.role`, checked by the schema).
impl sqlx::Type<sqlx::Any> for Role {
    fn type_info() -> sqlx::any::AnyTypeInfo {
        <String as sqlx::Type<sqlx::Any>>::type_info()
    }
}

impl<'r> sqlx::Decode<'r, sqlx::Any> for Role {
    fn decode(value: sqlx::any::AnyValueRef<'r>) -> Result<Self, sqlx::error::BoxDynError> {
        let name = <String as sqlx::Decode<sqlx::Any>>::decode(value)?;
        Ok(Role::parse(&name)?)
    }
}

/// Why an account change was refused (each named, so that callers map it to a status and a
/// sentence once).
#[derive(Debug, thiserror::Error)]
pub enum AccountError {
    #[error("no account '{0}'")]
    NoSuchUser(String),
    #[error("'{0}' is the last active admin: make another admin first")]
    LastAdmin(String),
    #[error("admins cannot disable or demote their own account (ask another admin)")]
    OwnAccount,
    #[error("{0}")]
    Invalid(String),
    /// A bulk import with bad lines: nothing was imported.
    #[error("nothing imported: {}", .0.iter().map(ToString::to_string).collect::<Vec<_>>().join("; "))]
    Import(Vec<ImportLineError>),
    #[error(transparent)]
    Store(#[from] StoreError),
}

impl From<sqlx::Error> for AccountError {
    fn from(e: sqlx::Error) -> Self {
        AccountError::Store(e.into())
    }
}

/// A bad line of a bulk import: its number (1 = the file's first line) and why.
#[derive(Debug, Clone, PartialEq, serde::Serialize, utoipa::ToSchema)]
pub struct ImportLineError {
    /// 1 = the file's first line; 0 = the whole file.
    pub line: usize,
    pub reason: String,
}

impl std::fmt::Display for ImportLineError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "line {}: {}", self.line, self.reason)
    }
}

/// One account of a bulk import.
#[derive(Debug, Clone, PartialEq)]
pub struct ImportLine {
    pub line: usize,
    pub username: String,
    pub role: Role,
    pub cohort: Option<String>,
    pub password: String,
}

/// Most accounts one import may add (each password is hashed with argon2id, tens of ms).
pub const MAX_IMPORT_LINES: usize = 200;
/// The optional first line of an import.
pub const IMPORT_HEADER: &str = "username,role,cohort,password";

/// Usernames and cohort names: 1–64 ASCII letters, digits or `. _ - @` (so bytes are characters).
fn valid_name(name: &str) -> bool {
    let valid = |c: char| c.is_ascii_alphanumeric() || "._-@".contains(c);
    !name.is_empty() && name.len() <= 64 && name.chars().all(valid)
}

const USERNAME_RULE: &str = "a username is 1–64 letters, digits or . _ - @";
const COHORT_RULE: &str = "a cohort name is 1–64 letters, digits or . _ - @";
const PASSWORD_RULE: &str = "a password has 8–1024 characters";

fn valid_password(password: &str) -> bool {
    (8..=1024).contains(&password.chars().count())
}

/// Parses a bulk import, `username,role,cohort,password` per line (cohort may be empty; the
/// password is the rest of the line, commas included; an optional header line; blank lines
/// skipped). Every bad line is reported, by number, with why; existing usernames are checked by
/// [`Store::import_csv`].
pub fn parse_import(text: &str) -> Result<Vec<ImportLine>, Vec<ImportLineError>> {
    let (good, bad) = parse_lines(text);
    if bad.is_empty() { Ok(good) } else { Err(bad) }
}

/// Every line of an import: the good ones and, for the others, why not.
fn parse_lines(text: &str) -> (Vec<ImportLine>, Vec<ImportLineError>) {
    let mut out = Vec::new();
    let mut bad = Vec::new();
    let mut seen = std::collections::BTreeMap::new();
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let raw = raw.trim_end_matches('\r');
        if raw.trim().is_empty() || (line == 1 && raw.trim().eq_ignore_ascii_case(IMPORT_HEADER)) {
            continue;
        }
        let mut reject = |reason: String| bad.push(ImportLineError { line, reason });
        let fields: Vec<&str> = raw.splitn(4, ',').collect();
        if fields.len() != 4 {
            reject(format!("expected 4 fields ({IMPORT_HEADER}), found {}", fields.len()));
            continue;
        }
        let (username, role, cohort, password) = (fields[0].trim(), fields[1].trim(), fields[2].trim(), fields[3]);
        let mut reasons = Vec::new();
        if !valid_name(username) {
            reasons.push(USERNAME_RULE.to_string());
        } else if let Some(first) = seen.insert(username.to_string(), line) {
            reasons.push(format!("'{username}' is already on line {first}"));
        }
        let role = match Role::parse(role) {
            Ok(r) => Some(r),
            Err(e) => {
                reasons.push(e.to_string());
                None
            }
        };
        if !cohort.is_empty() && !valid_name(cohort) {
            reasons.push(COHORT_RULE.to_string());
        }
        if !valid_password(password) {
            reasons.push(PASSWORD_RULE.to_string());
        }
        match role {
            Some(role) if reasons.is_empty() => out.push(ImportLine {
                line,
                username: username.to_string(),
                role,
                cohort: (!cohort.is_empty()).then(|| cohort.to_string()),
                password: password.to_string(),
            }),
            _ => reject(reasons.join("; ")),
        }
    }
    if out.len() + bad.len() > MAX_IMPORT_LINES {
        return (
            Vec::new(),
            vec![ImportLineError {
                line: 0,
                reason: format!("at most {MAX_IMPORT_LINES} accounts per import"),
            }],
        );
    }
    if out.is_empty() && bad.is_empty() {
        bad.push(ImportLineError {
            line: 0,
            reason: format!("no accounts: one per line, {IMPORT_HEADER}"),
        });
    }
    (out, bad)
}

/// A change to an account ([`Store::update_user`]); None leaves that part as it is.
#[derive(Debug, Clone, Default)]
pub struct AccountChange {
    pub role: Option<Role>,
    /// The cohorts it belongs to from now on (replacing the others; created if new; empty: none).
    pub cohorts: Option<Vec<String>>,
    /// Some(true) disables (its logins and tokens are refused from now on), Some(false) enables
    /// (they work again, unless expired or revoked meanwhile).
    pub disabled: Option<bool>,
    /// A new password (argon2id); its logins are ended.
    pub password: Option<String>,
}

/// The id of cohort `name`, created if new.
pub(super) async fn cohort_id_or_create(
    tx: &mut sqlx::Transaction<'_, sqlx::Any>,
    name: &str,
) -> Result<String, sqlx::Error> {
    let row = sqlx::query("SELECT id FROM cohorts WHERE name = $1")
        .bind(name.to_string())
        .fetch_optional(&mut **tx)
        .await?;
    if let Some(r) = row {
        return r.try_get::<String, _>("id");
    }
    let id = new_id();
    sqlx::query("INSERT INTO cohorts (id, name, created_at) VALUES ($1, $2, $3)")
        .bind(id.clone())
        .bind(name.to_string())
        .bind(now())
        .execute(&mut **tx)
        .await?;
    Ok(id)
}

async fn hash_off_thread(passwords: Vec<String>) -> Result<Vec<String>, StoreError> {
    tokio::task::spawn_blocking(move || {
        passwords
            .iter()
            .map(|p| auth::hash_password(p))
            .collect::<Result<Vec<_>, _>>()
    })
    .await
    .map_err(StoreError::HashingTask)?
    .map_err(StoreError::PasswordHash)
}

impl Store {
    /// Adds an account (argon2id password hash); with `cohort`, also its cohort membership
    /// (the cohort is created if new).
    /// `actor`: the admin who adds it (None from the command line), for the audit log.
    pub async fn add_user(
        &self,
        username: &str,
        role: &str,
        password: &str,
        cohort: Option<&str>,
        actor: Option<&str>,
    ) -> Result<String, StoreError> {
        let role = Role::parse(role)?;
        // Usernames and cohort names are ASCII only, so their lengths in bytes are their lengths
        // in characters.
        if !valid_name(username) {
            return Err(StoreError::Invalid(USERNAME_RULE.into()));
        }
        // Characters, as documented, at both ends (a password of 1024 'é' is 2048 bytes).
        if !valid_password(password) {
            return Err(StoreError::Invalid(PASSWORD_RULE.into()));
        }
        if let Some(c) = cohort
            && !valid_name(c)
        {
            return Err(StoreError::Invalid(COHORT_RULE.into()));
        }
        // argon2id takes tens of milliseconds: off the async threads.
        let hash = hash_off_thread(vec![password.to_string()]).await?.remove(0);
        let id = new_id();
        let mut tx = self.begin_write().await?;
        let exists = sqlx::query("SELECT id FROM users WHERE username = $1")
            .bind(username.to_string())
            .fetch_optional(&mut *tx)
            .await?;
        if exists.is_some() {
            return Err(StoreError::UserExists(username.to_string()));
        }
        insert_user(&mut tx, &id, username, role, &hash, cohort).await?;
        tx.commit().await?;
        self.audit(actor, "user.add", Some(&id), &format!("{username} as {role}"))
            .await?;
        Ok(id)
    }

    /// Imports the accounts of a CSV text ([`parse_import`]'s format): every one in one
    /// transaction, or none. Every bad line is reported by number with why, usernames that
    /// exist already included. Audited (`user.import` with the count, and `user.add` per
    /// account). Returns the usernames added.
    pub async fn import_csv(&self, text: &str, actor: Option<&str>) -> Result<Vec<String>, AccountError> {
        let (lines, mut bad) = parse_lines(text);
        bad.extend(Self::taken(&lines, &mut *self.pool.acquire().await?).await?);
        if !bad.is_empty() {
            bad.sort_by_key(|b| b.line);
            return Err(AccountError::Import(bad));
        }
        // argon2id for every password before the write lock is taken.
        let hashes = hash_off_thread(lines.iter().map(|l| l.password.clone()).collect()).await?;
        let mut tx = self.begin_write().await?;
        // Again in the transaction: another admin may have added one of these meanwhile.
        let taken = Self::taken(&lines, &mut tx).await?;
        if !taken.is_empty() {
            return Err(AccountError::Import(taken));
        }
        let actor_id = actor.map(str::to_string);
        for (l, hash) in lines.iter().zip(&hashes) {
            let id = new_id();
            insert_user(&mut tx, &id, &l.username, l.role, hash, l.cohort.as_deref()).await?;
            let detail = format!("{} as {} (import)", l.username, l.role);
            audit_opt(&mut tx, actor_id.as_deref(), "user.add", &id, &detail).await?;
        }
        audit_opt(
            &mut tx,
            actor_id.as_deref(),
            "user.import",
            "",
            &format!("{} accounts", lines.len()),
        )
        .await?;
        tx.commit().await?;
        Ok(lines.iter().map(|l| l.username.clone()).collect())
    }

    /// The lines whose username exists already.
    async fn taken(lines: &[ImportLine], conn: &mut sqlx::AnyConnection) -> Result<Vec<ImportLineError>, sqlx::Error> {
        let mut taken = Vec::new();
        for l in lines {
            let exists = sqlx::query("SELECT id FROM users WHERE username = $1")
                .bind(l.username.clone())
                .fetch_optional(&mut *conn)
                .await?;
            if exists.is_some() {
                taken.push(ImportLineError {
                    line: l.line,
                    reason: format!("user '{}' already exists", l.username),
                });
            }
        }
        Ok(taken)
    }

    /// Changes an account in one transaction, audited per part (`user.role`, `user.cohorts`,
    /// `user.disable`, `user.enable`, `user.passwd`). `actor`: the admin (None from the command
    /// line). Refused, with nothing changed: an unknown account, an admin disabling or demoting
    /// themselves ([`AccountError::OwnAccount`]), and leaving no active admin
    /// ([`AccountError::LastAdmin`]). A new password ends the account's logins.
    pub async fn update_user(
        &self,
        username: &str,
        change: &AccountChange,
        actor: Option<&User>,
    ) -> Result<UserRow, AccountError> {
        if let Some(p) = &change.password
            && !valid_password(p)
        {
            return Err(AccountError::Invalid(PASSWORD_RULE.into()));
        }
        if let Some(cohorts) = &change.cohorts
            && let Some(bad) = cohorts.iter().find(|c| !valid_name(c))
        {
            return Err(AccountError::Invalid(format!("{COHORT_RULE} (not '{bad}')")));
        }
        let hash = match &change.password {
            Some(p) => Some(hash_off_thread(vec![p.clone()]).await?.remove(0)),
            None => None,
        };
        let mut tx = self.begin_write().await?;
        let row = sqlx::query("SELECT id, role, disabled_at FROM users WHERE username = $1")
            .bind(username.to_string())
            .fetch_optional(&mut *tx)
            .await?
            .ok_or_else(|| AccountError::NoSuchUser(username.to_string()))?;
        let id: String = row.try_get("id")?;
        let role: Role = row.try_get("role")?;
        let was_disabled = row.try_get::<Option<String>, _>("disabled_at")?.is_some();
        let loses_admin = role == Role::Admin
            && !was_disabled
            && (change.disabled == Some(true) || change.role.is_some_and(|r| r != Role::Admin));
        if loses_admin {
            if actor.is_some_and(|a| a.id == id) {
                return Err(AccountError::OwnAccount);
            }
            let others = sqlx::query(
                "SELECT COUNT(*) AS n FROM users WHERE role = 'admin' AND disabled_at IS NULL AND id <> $1",
            )
            .bind(id.clone())
            .fetch_one(&mut *tx)
            .await?
            .try_get::<i64, _>("n")?;
            if others == 0 {
                return Err(AccountError::LastAdmin(username.to_string()));
            }
        }
        if actor.is_some_and(|a| a.id == id) && change.disabled == Some(true) {
            return Err(AccountError::OwnAccount);
        }
        let actor_id = actor.map(|a| a.id.clone());
        let audit = async |tx: &mut sqlx::Transaction<'static, sqlx::Any>, action: &str, detail: String| {
            audit_opt(tx, actor_id.as_deref(), action, &id, &detail).await
        };
        if let Some(new_role) = change.role
            && new_role != role
        {
            sqlx::query("UPDATE users SET role = $1 WHERE id = $2")
                .bind(new_role.as_str().to_string())
                .bind(id.clone())
                .execute(&mut *tx)
                .await?;
            audit(&mut tx, "user.role", format!("{username}: {role} → {new_role}")).await?;
        }
        if let Some(cohorts) = &change.cohorts {
            sqlx::query("DELETE FROM cohort_members WHERE user_id = $1")
                .bind(id.clone())
                .execute(&mut *tx)
                .await?;
            let mut names: Vec<&String> = cohorts.iter().collect();
            names.sort();
            names.dedup();
            for name in &names {
                let cid = cohort_id_or_create(&mut tx, name).await?;
                sqlx::query("INSERT INTO cohort_members (cohort_id, user_id) VALUES ($1, $2)")
                    .bind(cid)
                    .bind(id.clone())
                    .execute(&mut *tx)
                    .await?;
            }
            let list = names.iter().map(|n| n.as_str()).collect::<Vec<_>>().join(", ");
            audit(&mut tx, "user.cohorts", format!("{username}: [{list}]")).await?;
        }
        if let Some(hash) = hash {
            sqlx::query("UPDATE users SET password_hash = $1 WHERE id = $2")
                .bind(hash)
                .bind(id.clone())
                .execute(&mut *tx)
                .await?;
            end_logins(&mut tx, &id).await?;
            audit(&mut tx, "user.passwd", format!("{username}: password reset")).await?;
        }
        match change.disabled {
            Some(true) if !was_disabled => {
                sqlx::query("UPDATE users SET disabled_at = $1 WHERE id = $2")
                    .bind(now())
                    .bind(id.clone())
                    .execute(&mut *tx)
                    .await?;
                // Its logins and tokens stay stored but are refused on every request while it is
                // disabled (the look-ups check the account); enabling it lets them work again.
                audit(&mut tx, "user.disable", username.to_string()).await?;
            }
            Some(false) if was_disabled => {
                sqlx::query("UPDATE users SET disabled_at = NULL WHERE id = $1")
                    .bind(id.clone())
                    .execute(&mut *tx)
                    .await?;
                audit(&mut tx, "user.enable", username.to_string()).await?;
            }
            _ => {}
        }
        tx.commit().await?;
        self.user_row(username)
            .await?
            .ok_or_else(|| AccountError::NoSuchUser(username.to_string()))
    }

    pub(super) fn user_of(row: &sqlx::any::AnyRow) -> Result<User, sqlx::Error> {
        Ok(User {
            id: row.try_get("id")?,
            username: row.try_get("username")?,
            role: row.try_get("role")?,
        })
    }

    /// The account a login names, its password hash and whether it is disabled, if any. The
    /// caller checks the password (argon2id, on the service's password threads), against a dummy
    /// hash when there is no such account, so that timing does not reveal which usernames exist.
    pub async fn login_candidate(&self, username: &str) -> Result<Option<(User, String, bool)>, StoreError> {
        let row = sqlx::query("SELECT id, username, role, password_hash, disabled_at FROM users WHERE username = $1")
            .bind(username.to_string())
            .fetch_optional(&self.pool)
            .await?;
        Ok(match row {
            Some(r) => Some((
                Self::user_of(&r)?,
                r.try_get("password_hash")?,
                r.try_get::<Option<String>, _>("disabled_at")?.is_some(),
            )),
            None => None,
        })
    }

    pub async fn user_by_name(&self, username: &str) -> Result<Option<User>, StoreError> {
        let row = sqlx::query("SELECT id, username, role FROM users WHERE username = $1")
            .bind(username.to_string())
            .fetch_optional(&self.pool)
            .await?;
        Ok(row.as_ref().map(Self::user_of).transpose()?)
    }

    /// The account named `username` and whether it is disabled.
    pub async fn account_by_name(&self, username: &str) -> Result<Option<(User, bool)>, StoreError> {
        let row = sqlx::query("SELECT id, username, role, disabled_at FROM users WHERE username = $1")
            .bind(username.to_string())
            .fetch_optional(&self.pool)
            .await?;
        Ok(row
            .as_ref()
            .map(|r| {
                Ok::<_, sqlx::Error>((
                    Self::user_of(r)?,
                    r.try_get::<Option<String>, _>("disabled_at")?.is_some(),
                ))
            })
            .transpose()?)
    }

    /// Starts a login session; returns the cookie token and its CSRF token (only the token's
    /// hash is stored).
    pub async fn create_login(&self, user: &User, ttl_s: u64) -> Result<(String, String), StoreError> {
        let (token, csrf) = (auth::random_token(), auth::random_token());
        let expires = from_now(std::time::Duration::from_secs(ttl_s));
        sqlx::query("INSERT INTO auth_sessions (token_sha256, user_id, csrf_token, created_at, expires_at) VALUES ($1, $2, $3, $4, $5)")
            .bind(auth::sha256_hex(&token))
            .bind(user.id.clone())
            .bind(csrf.clone())
            .bind(now())
            .bind(expires)
            .execute(&self.pool)
            .await?;
        self.audit(Some(&user.id), "login", None, "").await?;
        Ok((token, csrf))
    }

    /// The user of a login token that has not expired, and the login's CSRF token. Looked up on
    /// every request: a disabled account's logins are refused from the moment it is disabled.
    pub async fn user_for_login(&self, token: &str) -> Result<Option<(User, String)>, StoreError> {
        let row = sqlx::query(
            "SELECT u.id, u.username, u.role, s.csrf_token FROM auth_sessions s JOIN users u ON u.id = s.user_id \
             WHERE s.token_sha256 = $1 AND s.expires_at > $2 AND u.disabled_at IS NULL",
        )
        .bind(auth::sha256_hex(token))
        .bind(now())
        .fetch_optional(&self.pool)
        .await?;
        Ok(match row {
            Some(r) => Some((Self::user_of(&r)?, r.try_get("csrf_token")?)),
            None => None,
        })
    }

    pub async fn end_login(&self, token: &str) -> Result<(), StoreError> {
        sqlx::query("DELETE FROM auth_sessions WHERE token_sha256 = $1")
            .bind(auth::sha256_hex(token))
            .execute(&self.pool)
            .await?;
        Ok(())
    }

    /// Whether `instructor` teaches `trainee` (they share a cohort).
    pub async fn teaches(&self, instructor_id: &str, trainee_id: &str) -> Result<bool, StoreError> {
        let row = sqlx::query(
            "SELECT 1 AS one FROM cohort_members a JOIN cohort_members b ON a.cohort_id = b.cohort_id \
             WHERE a.user_id = $1 AND b.user_id = $2",
        )
        .bind(instructor_id.to_string())
        .bind(trainee_id.to_string())
        .fetch_optional(&self.pool)
        .await?;
        Ok(row.is_some())
    }

    /// The ids of the cohorts `user` belongs to or teaches, and whether a cohort by that name exists.
    pub async fn cohort_id(&self, name: &str) -> Result<Option<String>, StoreError> {
        let row = sqlx::query("SELECT id FROM cohorts WHERE name = $1")
            .bind(name.to_string())
            .fetch_optional(&self.pool)
            .await?;
        Ok(row.map(|r| r.try_get("id")).transpose()?)
    }

    pub async fn in_cohort(&self, user_id: &str, cohort_id: &str) -> Result<bool, StoreError> {
        let row = sqlx::query("SELECT 1 AS one FROM cohort_members WHERE user_id = $1 AND cohort_id = $2")
            .bind(user_id.to_string())
            .bind(cohort_id.to_string())
            .fetch_optional(&self.pool)
            .await?;
        Ok(row.is_some())
    }

    /// Every account with its cohorts, by username (bounded by `MAX_USERS_LISTED`; admin
    /// pages and the API page through [`Store::users_page`]).
    pub async fn users(&self) -> Result<Vec<UserRow>, StoreError> {
        Ok(self.users_page(None, 0, MAX_USERS_LISTED).await?.0)
    }

    /// A page of accounts by username, those whose name contains `search` if given, and how many
    /// match in all.
    pub async fn users_page(
        &self,
        search: Option<&str>,
        offset: i64,
        limit: i64,
    ) -> Result<(Vec<UserRow>, i64), StoreError> {
        // LIKE's wildcards in the search are taken literally.
        let pattern = search.map(|q| {
            let escaped: String = q
                .chars()
                .flat_map(|c| match c {
                    '%' | '_' | '!' => vec!['!', c],
                    c => vec![c],
                })
                .collect();
            format!("%{escaped}%")
        });
        let filter = if pattern.is_some() {
            "WHERE username LIKE $1 ESCAPE '!'"
        } else {
            ""
        };
        let binds: Vec<String> = pattern.into_iter().collect();
        let total: i64 = super::bound_query(format!("SELECT COUNT(*) AS n FROM users {filter}"), binds.clone())
            .fetch_one(&self.pool)
            .await?
            .try_get("n")?;
        let rows = super::bound_query(
            format!(
                "SELECT id, username, role, created_at, disabled_at FROM users {filter} ORDER BY username \
                 LIMIT {} OFFSET {}",
                limit.clamp(0, MAX_USERS_LISTED),
                offset.max(0)
            ),
            binds,
        )
        .fetch_all(&self.pool)
        .await?;
        let mut out = Vec::with_capacity(rows.len());
        for r in &rows {
            out.push(self.user_row_of(r).await?);
        }
        Ok((out, total))
    }

    /// One account as admins see it.
    pub async fn user_row(&self, username: &str) -> Result<Option<UserRow>, StoreError> {
        let row = sqlx::query("SELECT id, username, role, created_at, disabled_at FROM users WHERE username = $1")
            .bind(username.to_string())
            .fetch_optional(&self.pool)
            .await?;
        match row {
            Some(r) => Ok(Some(self.user_row_of(&r).await?)),
            None => Ok(None),
        }
    }

    async fn user_row_of(&self, r: &sqlx::any::AnyRow) -> Result<UserRow, StoreError> {
        let id: String = r.try_get("id")?;
        let cohorts = sqlx::query(
            "SELECT c.name FROM cohort_members m JOIN cohorts c ON c.id = m.cohort_id WHERE m.user_id = $1 ORDER BY c.name",
        )
        .bind(id)
        .fetch_all(&self.pool)
        .await?
        .iter()
        .map(|m| m.try_get("name"))
        .collect::<Result<_, _>>()?;
        Ok(UserRow {
            username: r.try_get("username")?,
            role: r.try_get("role")?,
            cohorts,
            created_at: r.try_get("created_at")?,
            disabled_at: r.try_get("disabled_at")?,
        })
    }
}

/// Most accounts one list returns (pages hold fewer).
pub const MAX_USERS_LISTED: i64 = 1000;

/// Inserts an account row (and its cohort membership, the cohort created if new).
pub(super) async fn insert_user(
    tx: &mut sqlx::Transaction<'static, sqlx::Any>,
    id: &str,
    username: &str,
    role: Role,
    hash: &str,
    cohort: Option<&str>,
) -> Result<(), sqlx::Error> {
    sqlx::query("INSERT INTO users (id, username, role, password_hash, created_at) VALUES ($1, $2, $3, $4, $5)")
        .bind(id.to_string())
        .bind(username.to_string())
        .bind(role.as_str().to_string())
        .bind(hash.to_string())
        .bind(now())
        .execute(&mut **tx)
        .await?;
    if let Some(name) = cohort {
        let cohort_id = cohort_id_or_create(tx, name).await?;
        sqlx::query("INSERT INTO cohort_members (cohort_id, user_id) VALUES ($1, $2)")
            .bind(cohort_id)
            .bind(id.to_string())
            .execute(&mut **tx)
            .await?;
    }
    Ok(())
}

/// Ends every login of an account (a password reset).
async fn end_logins(tx: &mut sqlx::Transaction<'static, sqlx::Any>, user_id: &str) -> Result<(), sqlx::Error> {
    sqlx::query("DELETE FROM auth_sessions WHERE user_id = $1")
        .bind(user_id.to_string())
        .execute(&mut **tx)
        .await?;
    Ok(())
}

/// An audit row in a transaction, by an admin or (None) the command line.
pub(super) async fn audit_opt(
    tx: &mut sqlx::Transaction<'static, sqlx::Any>,
    actor_id: Option<&str>,
    action: &str,
    target: &str,
    detail: &str,
) -> Result<(), StoreError> {
    match actor_id {
        Some(a) => audit_in(tx, a, action, target, detail).await,
        None => {
            sqlx::query(
                "INSERT INTO audit_log (id, at, actor_id, action, target, detail) VALUES ($1, $2, NULL, $3, $4, $5)",
            )
            .bind(new_id())
            .bind(now())
            .bind(action.to_string())
            .bind(target.to_string())
            .bind(detail.to_string())
            .execute(&mut **tx)
            .await?;
            Ok(())
        }
    }
}

/// An account as admins see it (never the password hash).
/// An account as the API lists it (`Account` in the OpenAPI document).
#[derive(Debug, Clone, PartialEq, serde::Serialize, utoipa::ToSchema)]
#[schema(as = Account)]
pub struct UserRow {
    pub username: String,
    pub role: Role,
    pub cohorts: Vec<String>,
    pub created_at: String,
    /// When it was disabled (None: active).
    pub disabled_at: Option<String>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn roles_by_name() {
        for r in Role::ALL {
            assert_eq!(Role::parse(r.as_str()).unwrap(), r);
            assert_eq!(serde_json::to_value(r).unwrap(), r.as_str());
        }
        assert_eq!(Role::ALL.map(Role::as_str), ROLES);
        assert!(
            Role::parse("janitor")
                .unwrap_err()
                .to_string()
                .contains("unknown role 'janitor'")
        );
    }

    #[test]
    fn imports_name_every_bad_line() {
        let text =
            "username,role,cohort,password\nann,trainee,c1,ann-password\n\nbo b,admin,,x\nann,trainee,,ann-password\n";
        let bad = parse_import(text).unwrap_err();
        assert_eq!(bad.iter().map(|b| b.line).collect::<Vec<_>>(), [4, 5]);
        assert!(
            bad[0].reason.contains("username") && bad[0].reason.contains("8–1024"),
            "{bad:?}"
        );
        assert!(bad[1].reason.contains("already on line 2"), "{bad:?}");
        let good = parse_import("cy,instructor,,pass, with, commas\r\n").unwrap();
        assert_eq!(good[0].password, "pass, with, commas");
        assert_eq!((good[0].role, good[0].cohort.as_deref()), (Role::Instructor, None));
        assert_eq!(parse_import("").unwrap_err()[0].line, 0);
        assert_eq!(parse_import(IMPORT_HEADER).unwrap_err()[0].line, 0);
        let many: String = (0..=MAX_IMPORT_LINES)
            .map(|i| format!("u{i},trainee,,password{i}\n"))
            .collect();
        assert!(parse_import(&many).unwrap_err()[0].reason.contains("at most"));
    }

    /// Password lengths are documented in characters: 1024 'é' (2048 bytes) are allowed.
    #[tokio::test]
    async fn password_lengths_count_characters() {
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open(&format!("sqlite://{}?mode=rwc", dir.path().join("t.db").display()))
            .await
            .unwrap();
        store
            .add_user("long", "trainee", &"é".repeat(1024), None, None)
            .await
            .unwrap();
        for (name, password) in [("longer", "é".repeat(1025)), ("short", "é".repeat(7))] {
            match store.add_user(name, "trainee", &password, None, None).await {
                Err(StoreError::Invalid(m)) => assert!(m.contains("8–1024 characters"), "{m}"),
                other => panic!("{name}: {other:?}"),
            }
        }
    }
}
