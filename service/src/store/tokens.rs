//! API tokens (the desktop simulator's credentials; migration 0003): random 256-bit values stored
//! only as SHA-256, each with an id, a scope, an expiry and a revocation time. Creating and
//! revoking are audited in the same transaction as the change.

use std::time::Duration;

use sqlx::Row;

use super::super::auth;
use super::{Store, StoreError, User, audit_in, from_now, new_id, now};

/// What an API token may do. A token lives in a config file on a training PC; the narrow scope
/// keeps a stolen simulator token from reading the account's other data.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum TokenScope {
    /// Upload sessions and read the status of the sessions the account may see (the simulator).
    #[default]
    Upload,
    /// What the account may do through the API (scripts), except making more tokens.
    Full,
}

impl TokenScope {
    pub const ALL: [TokenScope; 2] = [TokenScope::Upload, TokenScope::Full];

    /// The name in the database, the API and forms.
    pub fn as_str(self) -> &'static str {
        match self {
            TokenScope::Upload => "upload",
            TokenScope::Full => "full",
        }
    }

    pub fn parse(name: &str) -> Option<TokenScope> {
        TokenScope::ALL.into_iter().find(|s| s.as_str() == name)
    }
}

/// Whether a token still authenticates, at the time it was read.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum TokenStatus {
    Active,
    Expired,
    Revoked,
}

impl TokenStatus {
    /// Revoked first (an admin's act), then the clock; no expiry (never written since
    /// migration 0003) counts as expired.
    fn of(expires_at: Option<&str>, revoked_at: Option<&str>, now: &str) -> TokenStatus {
        match (revoked_at, expires_at) {
            (Some(_), _) => TokenStatus::Revoked,
            (None, Some(e)) if e > now => TokenStatus::Active,
            _ => TokenStatus::Expired,
        }
    }

    pub fn as_str(self) -> &'static str {
        match self {
            TokenStatus::Active => "active",
            TokenStatus::Expired => "expired",
            TokenStatus::Revoked => "revoked",
        }
    }
}

/// A token as its owner or an admin sees it: never the token, never its hash (`ApiToken` in the
/// OpenAPI document).
#[derive(Debug, Clone, PartialEq, serde::Serialize, utoipa::ToSchema)]
#[schema(as = ApiToken)]
pub struct TokenRow {
    pub id: String,
    /// The owner.
    pub username: String,
    #[serde(skip)]
    pub user_id: String,
    pub label: String,
    pub scope: TokenScope,
    pub created_at: String,
    pub expires_at: Option<String>,
    pub revoked_at: Option<String>,
    /// The token's last four hex digits, to tell tokens apart (none for tokens from before
    /// migration 0003).
    pub last4: Option<String>,
    pub status: TokenStatus,
}

/// The account and scope of a presented token that matches a stored one, and whether it is
/// still good.
#[derive(Debug, Clone, PartialEq)]
pub struct TokenAuth {
    pub user: User,
    pub scope: TokenScope,
    pub status: TokenStatus,
    /// Its owner's account is disabled: refused like a revoked token while it is.
    pub account_disabled: bool,
}

const ROW_COLUMNS: &str =
    "t.id, u.username, t.user_id, t.label, t.scope, t.created_at, t.expires_at, t.revoked_at, t.last4";

fn scope_of(name: &str) -> Result<TokenScope, StoreError> {
    TokenScope::parse(name).ok_or_else(|| StoreError::Invalid(format!("stored token scope '{name}' is unknown")))
}

fn token_row(r: &sqlx::any::AnyRow, now: &str) -> Result<TokenRow, StoreError> {
    let expires_at: Option<String> = r.try_get("expires_at")?;
    let revoked_at: Option<String> = r.try_get("revoked_at")?;
    Ok(TokenRow {
        id: r.try_get("id")?,
        username: r.try_get("username")?,
        user_id: r.try_get("user_id")?,
        label: r.try_get("label")?,
        scope: scope_of(&r.try_get::<String, _>("scope")?)?,
        created_at: r.try_get("created_at")?,
        status: TokenStatus::of(expires_at.as_deref(), revoked_at.as_deref(), now),
        expires_at,
        revoked_at,
        last4: r.try_get("last4")?,
    })
}

impl Store {
    /// A new API token for `user`, valid for `ttl`: the token (returned once; only its SHA-256
    /// is stored) and its row. Audited (`token.create`).
    pub async fn create_api_token(
        &self,
        user: &User,
        label: &str,
        scope: TokenScope,
        ttl: Duration,
        max_active: usize,
    ) -> Result<(String, TokenRow), StoreError> {
        let mut tx = self.begin_write().await?;
        let made = self
            .insert_api_token(&mut tx, user, label, scope, ttl, max_active)
            .await;
        match made {
            Ok(made) => {
                tx.commit().await?;
                Ok(made)
            }
            Err(e) => {
                tx.rollback().await?;
                Err(e)
            }
        }
    }

    /// [`Store::create_api_token`] inside the writing transaction `tx` (a pairing makes its
    /// token in the transaction that uses its code up).
    pub(super) async fn insert_api_token(
        &self,
        tx: &mut sqlx::Transaction<'_, sqlx::Any>,
        user: &User,
        label: &str,
        scope: TokenScope,
        ttl: Duration,
        max_active: usize,
    ) -> Result<(String, TokenRow), StoreError> {
        let token = auth::random_token();
        let id = new_id();
        let created_at = now();
        let expires_at = from_now(ttl);
        let last4 = token[token.len() - 4..].to_string();
        // Counted in the writing transaction, so parallel requests cannot pass the cap together
        // (SQLite: BEGIN IMMEDIATE serialises writers; PostgreSQL: the account's row is locked).
        if !self.sqlite {
            sqlx::query("SELECT id FROM users WHERE id = $1 FOR UPDATE")
                .bind(user.id.clone())
                .fetch_optional(&mut **tx)
                .await?;
        }
        let active: i64 = sqlx::query(
            "SELECT COUNT(*) AS n FROM api_tokens WHERE user_id = $1 AND revoked_at IS NULL AND expires_at > $2",
        )
        .bind(user.id.clone())
        .bind(created_at.clone())
        .fetch_one(&mut **tx)
        .await?
        .try_get("n")?;
        if active >= max_active as i64 {
            return Err(StoreError::TooManyTokens {
                username: user.username.clone(),
                active,
            });
        }
        sqlx::query(
            "INSERT INTO api_tokens (token_sha256, user_id, label, created_at, id, scope, expires_at, revoked_at, last4) \
             VALUES ($1, $2, $3, $4, $5, $6, $7, NULL, $8)",
        )
        .bind(auth::sha256_hex(&token))
        .bind(user.id.clone())
        .bind(label.to_string())
        .bind(created_at.clone())
        .bind(id.clone())
        .bind(scope.as_str().to_string())
        .bind(expires_at.clone())
        .bind(last4.clone())
        .execute(&mut **tx)
        .await?;
        audit_in(
            tx,
            &user.id,
            "token.create",
            &id,
            &format!("{label} (scope {}, expires {expires_at})", scope.as_str()),
        )
        .await?;
        let row = TokenRow {
            id,
            username: user.username.clone(),
            user_id: user.id.clone(),
            label: label.to_string(),
            scope,
            created_at,
            expires_at: Some(expires_at),
            revoked_at: None,
            last4: Some(last4),
            status: TokenStatus::Active,
        };
        Ok((token, row))
    }

    /// The account, scope and status of a presented token; None when no token has that hash.
    pub async fn api_token(&self, token: &str) -> Result<Option<TokenAuth>, StoreError> {
        let row = sqlx::query(
            "SELECT u.id, u.username, u.role, u.disabled_at, t.scope, t.expires_at, t.revoked_at \
             FROM api_tokens t JOIN users u ON u.id = t.user_id WHERE t.token_sha256 = $1",
        )
        .bind(auth::sha256_hex(token))
        .fetch_optional(&self.pool)
        .await?;
        let Some(r) = row else { return Ok(None) };
        let expires_at: Option<String> = r.try_get("expires_at")?;
        let revoked_at: Option<String> = r.try_get("revoked_at")?;
        Ok(Some(TokenAuth {
            user: User {
                id: r.try_get("id")?,
                username: r.try_get("username")?,
                role: r.try_get("role")?,
            },
            scope: scope_of(&r.try_get::<String, _>("scope")?)?,
            status: TokenStatus::of(expires_at.as_deref(), revoked_at.as_deref(), &now()),
            account_disabled: r.try_get::<Option<String>, _>("disabled_at")?.is_some(),
        }))
    }

    /// Tokens, newest first: `owner`'s (a user id), or everyone's with None (admins).
    pub async fn api_tokens(&self, owner: Option<&str>) -> Result<Vec<TokenRow>, StoreError> {
        let rows = match owner {
            Some(user_id) => {
                sqlx::query(sqlx::AssertSqlSafe(format!(
                    "SELECT {ROW_COLUMNS} FROM api_tokens t JOIN users u ON u.id = t.user_id \
                     WHERE t.user_id = $1 ORDER BY t.created_at DESC, t.id"
                )))
                .bind(user_id.to_string())
                .fetch_all(&self.pool)
                .await?
            }
            None => {
                sqlx::query(sqlx::AssertSqlSafe(format!(
                    "SELECT {ROW_COLUMNS} FROM api_tokens t JOIN users u ON u.id = t.user_id \
                     ORDER BY t.created_at DESC, t.id"
                )))
                .fetch_all(&self.pool)
                .await?
            }
        };
        let now = now();
        rows.iter().map(|r| token_row(r, &now)).collect()
    }

    /// One token by id.
    pub async fn api_token_by_id(&self, id: &str) -> Result<Option<TokenRow>, StoreError> {
        let row = sqlx::query(sqlx::AssertSqlSafe(format!(
            "SELECT {ROW_COLUMNS} FROM api_tokens t JOIN users u ON u.id = t.user_id WHERE t.id = $1"
        )))
        .bind(id.to_string())
        .fetch_optional(&self.pool)
        .await?;
        row.map(|r| token_row(&r, &now())).transpose()
    }

    /// Revokes a token (from now on it is refused) by `actor`; audited (`token.revoke`).
    /// Revoking a revoked token changes nothing. Returns the token's row, or None for an
    /// unknown id.
    pub async fn revoke_api_token(&self, id: &str, actor: &User) -> Result<Option<TokenRow>, StoreError> {
        let mut tx = self.begin_write().await?;
        let at = now();
        let changed = sqlx::query("UPDATE api_tokens SET revoked_at = $1 WHERE id = $2 AND revoked_at IS NULL")
            .bind(at.clone())
            .bind(id.to_string())
            .execute(&mut *tx)
            .await?
            .rows_affected();
        if changed > 0 {
            audit_in(&mut tx, &actor.id, "token.revoke", id, "").await?;
        }
        tx.commit().await?;
        self.api_token_by_id(id).await
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scopes_and_statuses_by_name() {
        for s in TokenScope::ALL {
            assert_eq!(TokenScope::parse(s.as_str()), Some(s));
        }
        assert_eq!(TokenScope::parse("admin"), None);
        assert_eq!(TokenScope::default(), TokenScope::Upload);
        let now = "2026-05-01T00:00:00.000000Z";
        let later = Some("2026-05-02T00:00:00.000000Z");
        let earlier = Some("2026-04-30T00:00:00.000000Z");
        assert_eq!(TokenStatus::of(later, None, now), TokenStatus::Active);
        assert_eq!(TokenStatus::of(earlier, None, now), TokenStatus::Expired);
        assert_eq!(TokenStatus::of(Some(now), None, now), TokenStatus::Expired);
        assert_eq!(TokenStatus::of(None, None, now), TokenStatus::Expired);
        assert_eq!(TokenStatus::of(later, Some(now), now), TokenStatus::Revoked);
    }

    /// Tokens issued before migration 0003 (no expiry, every right, possibly minted by another
    /// token) stop working when it is applied: listed as expired, scope `full`, with an id.
    async fn tokens_from_before_0003_are_closed(url: &str) {
        sqlx::any::install_default_drivers();
        let pool = sqlx::AnyPool::connect(url).await.unwrap();
        sqlx::migrate!("../migrations").run_to(2, &pool).await.unwrap();
        sqlx::query("INSERT INTO users (id, username, role, password_hash, created_at) VALUES ('u1', 'tina', 'trainee', 'x', '2025-01-01T00:00:00.000000Z')")
            .execute(&pool)
            .await
            .unwrap();
        let token = auth::random_token();
        sqlx::query("INSERT INTO api_tokens (token_sha256, user_id, label, created_at) VALUES ($1, 'u1', 'old sim', '2025-01-02T00:00:00.000000Z')")
            .bind(auth::sha256_hex(&token))
            .execute(&pool)
            .await
            .unwrap();
        pool.close().await;
        let store = Store::open(url).await.unwrap();
        let found = store.api_token(&token).await.unwrap().unwrap();
        assert_eq!((found.scope, found.status), (TokenScope::Full, TokenStatus::Expired));
        let listed = store.api_tokens(Some("u1")).await.unwrap();
        assert_eq!(listed.len(), 1);
        let old = &listed[0];
        assert!(old.id.starts_with("legacy-") && old.id.len() == 23, "{}", old.id);
        assert_eq!(old.expires_at.as_deref(), Some("2025-01-02T00:00:00.000000Z"));
        assert_eq!((old.status, old.last4.as_deref()), (TokenStatus::Expired, None));
        // A token made now has the narrow scope unless asked, an expiry, and works.
        let user = store.user_by_name("tina").await.unwrap().unwrap();
        let (new, row) = store
            .create_api_token(&user, "sim", TokenScope::default(), Duration::from_secs(60), 20)
            .await
            .unwrap();
        let found = store.api_token(&new).await.unwrap().unwrap();
        assert_eq!((found.scope, found.status), (TokenScope::Upload, TokenStatus::Active));
        assert_eq!(row.last4.as_deref(), Some(&new[60..]));
        store.revoke_api_token(&row.id, &user).await.unwrap();
        let again = store.revoke_api_token(&row.id, &user).await.unwrap().unwrap();
        assert_eq!(again.status, TokenStatus::Revoked);
        assert_eq!(
            store.api_token(&new).await.unwrap().unwrap().status,
            TokenStatus::Revoked
        );
        let audited: i64 = sqlx::query_scalar(
            "SELECT COUNT(*) FROM audit_log WHERE target = $1 AND action IN ('token.create', 'token.revoke')",
        )
        .bind(row.id.clone())
        .fetch_one(&store.pool)
        .await
        .unwrap();
        assert_eq!(audited, 2, "one create, one revoke (revoking twice is one revocation)");
    }

    #[tokio::test]
    async fn tokens_from_before_0003_are_closed_sqlite() {
        let dir = tempfile::tempdir().unwrap();
        tokens_from_before_0003_are_closed(&format!("sqlite://{}?mode=rwc", dir.path().join("t.db").display())).await;
    }

    /// On PostgreSQL (scripts/test starts it and sets `$STYLET_POSTGRES_URL`), in a database of
    /// its own. Without it the test fails: it is never skipped silently.
    #[tokio::test]
    async fn tokens_from_before_0003_are_closed_postgres() {
        let url = crate::store::fresh_postgres_database("stylet_tokens_unit").await;
        tokens_from_before_0003_are_closed(&url).await;
    }
}
