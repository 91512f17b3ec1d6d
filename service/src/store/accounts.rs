//! Accounts, logins and cohorts (API tokens: `tokens.rs`).

use sqlx::Row;

use super::super::auth;
use super::User;
use super::{ROLES, Store, StoreError, new_id, now};

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
        if !ROLES.contains(&role) {
            return Err(StoreError::Invalid(format!(
                "unknown role '{role}' (roles: {})",
                ROLES.join(", ")
            )));
        }
        // Usernames and cohort names are ASCII only, so their lengths in bytes are their lengths
        // in characters.
        let valid = |c: char| c.is_ascii_alphanumeric() || "._-@".contains(c);
        if username.is_empty() || username.len() > 64 || !username.chars().all(valid) {
            return Err(StoreError::Invalid(
                "a username is 1–64 letters, digits or . _ - @".into(),
            ));
        }
        // Characters, as documented, at both ends (a password of 1024 'é' is 2048 bytes).
        let chars = password.chars().count();
        if !(8..=1024).contains(&chars) {
            return Err(StoreError::Invalid("a password has 8–1024 characters".into()));
        }
        if let Some(c) = cohort
            && (c.is_empty() || c.len() > 64 || !c.chars().all(valid))
        {
            return Err(StoreError::Invalid(
                "a cohort name is 1–64 letters, digits or . _ - @".into(),
            ));
        }
        // argon2id takes tens of milliseconds: off the async threads.
        let owned = password.to_string();
        let hash = tokio::task::spawn_blocking(move || auth::hash_password(&owned))
            .await
            .map_err(|e| StoreError::Invalid(format!("hashing the password: {e}")))?
            .map_err(StoreError::Invalid)?;
        let id = new_id();
        let mut tx = self.begin_write().await?;
        let exists = sqlx::query("SELECT id FROM users WHERE username = $1")
            .bind(username.to_string())
            .fetch_optional(&mut *tx)
            .await?;
        if exists.is_some() {
            return Err(StoreError::Invalid(format!("user '{username}' already exists")));
        }
        sqlx::query("INSERT INTO users (id, username, role, password_hash, created_at) VALUES ($1, $2, $3, $4, $5)")
            .bind(id.clone())
            .bind(username.to_string())
            .bind(role.to_string())
            .bind(hash)
            .bind(now())
            .execute(&mut *tx)
            .await?;
        if let Some(name) = cohort {
            let row = sqlx::query("SELECT id FROM cohorts WHERE name = $1")
                .bind(name.to_string())
                .fetch_optional(&mut *tx)
                .await?;
            let cohort_id = match row {
                Some(r) => r.try_get::<String, _>("id")?,
                None => {
                    let cid = new_id();
                    sqlx::query("INSERT INTO cohorts (id, name, created_at) VALUES ($1, $2, $3)")
                        .bind(cid.clone())
                        .bind(name.to_string())
                        .bind(now())
                        .execute(&mut *tx)
                        .await?;
                    cid
                }
            };
            sqlx::query("INSERT INTO cohort_members (cohort_id, user_id) VALUES ($1, $2)")
                .bind(cohort_id)
                .bind(id.clone())
                .execute(&mut *tx)
                .await?;
        }
        tx.commit().await?;
        self.audit(actor, "user.add", Some(&id), &format!("{username} as {role}"))
            .await?;
        Ok(id)
    }

    fn user_of(row: &sqlx::any::AnyRow) -> Result<User, sqlx::Error> {
        Ok(User {
            id: row.try_get("id")?,
            username: row.try_get("username")?,
            role: row.try_get("role")?,
        })
    }

    /// The account a login names and its password hash, if any. The caller checks the password
    /// (argon2id, on the service's password threads), against a dummy hash when there is no
    /// such account, so that timing does not reveal which usernames exist.
    pub async fn login_candidate(&self, username: &str) -> Result<Option<(User, String)>, StoreError> {
        let row = sqlx::query("SELECT id, username, role, password_hash FROM users WHERE username = $1")
            .bind(username.to_string())
            .fetch_optional(&self.pool)
            .await?;
        Ok(match row {
            Some(r) => Some((Self::user_of(&r)?, r.try_get("password_hash")?)),
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

    /// Starts a login session; returns the cookie token and its CSRF token (only the token's
    /// hash is stored).
    pub async fn create_login(&self, user: &User, ttl_s: u64) -> Result<(String, String), StoreError> {
        let (token, csrf) = (auth::random_token(), auth::random_token());
        let expires =
            humantime::format_rfc3339_micros(std::time::SystemTime::now() + std::time::Duration::from_secs(ttl_s))
                .to_string();
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

    /// The user of a login token that has not expired, and the login's CSRF token.
    pub async fn user_for_login(&self, token: &str) -> Result<Option<(User, String)>, StoreError> {
        let row = sqlx::query(
            "SELECT u.id, u.username, u.role, s.csrf_token FROM auth_sessions s JOIN users u ON u.id = s.user_id \
             WHERE s.token_sha256 = $1 AND s.expires_at > $2",
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

    /// Every account with its cohorts (`;`-separated), by username.
    pub async fn users(&self) -> Result<Vec<UserRow>, StoreError> {
        let rows = sqlx::query("SELECT id, username, role, created_at FROM users ORDER BY username")
            .fetch_all(&self.pool)
            .await?;
        let members = sqlx::query(
            "SELECT m.user_id, c.name FROM cohort_members m JOIN cohorts c ON c.id = m.cohort_id ORDER BY c.name",
        )
        .fetch_all(&self.pool)
        .await?;
        let mut cohorts_of: std::collections::BTreeMap<String, Vec<String>> = Default::default();
        for m in &members {
            cohorts_of
                .entry(m.try_get("user_id")?)
                .or_default()
                .push(m.try_get("name")?);
        }
        let mut out = Vec::with_capacity(rows.len());
        for r in &rows {
            let id: String = r.try_get("id")?;
            out.push(UserRow {
                username: r.try_get("username")?,
                role: r.try_get("role")?,
                cohorts: cohorts_of.remove(&id).unwrap_or_default(),
                created_at: r.try_get("created_at")?,
            });
        }
        Ok(out)
    }
}

/// An account as admins see it (never the password hash).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct UserRow {
    pub username: String,
    pub role: String,
    pub cohorts: Vec<String>,
    pub created_at: String,
}

#[cfg(test)]
mod tests {
    use super::*;

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
