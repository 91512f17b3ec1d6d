//! Pairing codes and lab machines (migration 0015): short codes, stored as SHA-256, made by a
//! logged-in account for one purpose, valid for minutes and used once; and lab machines, simulators
//! paired to a cohort on which its trainees sign in one after another. Using a code and making
//! what it yields (an API token, a lab machine) is one transaction, audited in it: a code is
//! never used up without its token, and a token never made without its code used up.

use std::time::Duration;

use sqlx::Row;

use super::super::auth;
use super::{Role, Store, StoreError, TokenRow, TokenScope, User, audit_in, from_now, new_id, now};

/// What a pairing code is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum PairingPurpose {
    /// A trainee's (or anyone's) own simulator gets an upload token of the account.
    Simulator,
    /// A simulator in a skills lab becomes a lab machine of a cohort.
    Lab,
    /// A trainee signs in at a lab machine of their cohort.
    SignIn,
}

impl PairingPurpose {
    pub const ALL: [PairingPurpose; 3] = [PairingPurpose::Simulator, PairingPurpose::Lab, PairingPurpose::SignIn];

    /// The name in the database, the API and forms.
    pub fn as_str(self) -> &'static str {
        match self {
            PairingPurpose::Simulator => "simulator",
            PairingPurpose::Lab => "lab",
            PairingPurpose::SignIn => "sign_in",
        }
    }

    pub fn parse(name: &str) -> Option<PairingPurpose> {
        PairingPurpose::ALL.into_iter().find(|p| p.as_str() == name)
    }

    /// What the code does, for people.
    pub fn words(self) -> &'static str {
        match self {
            PairingPurpose::Simulator => "pairs a simulator with your account",
            PairingPurpose::Lab => "pairs a lab machine with a cohort",
            PairingPurpose::SignIn => "signs you in at a lab machine",
        }
    }
}

/// A lab machine as instructors and admins see it (never its token).
#[derive(Debug, Clone, PartialEq, serde::Serialize, utoipa::ToSchema)]
pub struct LabMachine {
    pub id: String,
    pub label: String,
    /// The cohort's name.
    pub cohort: String,
    #[serde(skip)]
    pub cohort_id: String,
    /// Who paired it.
    pub paired_by: String,
    pub created_at: String,
    pub expires_at: String,
    pub revoked_at: Option<String>,
    /// Whether it may sign trainees in now.
    pub active: bool,
}

/// What a used code yielded.
#[derive(Debug, Clone, PartialEq)]
pub enum Paired {
    /// An upload token of `row.username` (a simulator pairing, or a sign-in at a lab machine).
    Token { token: String, row: TokenRow },
    /// A lab machine and its token.
    Lab { token: String, machine: LabMachine },
}

/// Why a code yielded nothing (nothing was written; the code stays as it was).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PairingRefusal {
    /// No such code, or expired, or used: all alike to whoever presents it.
    Unknown,
    /// A good code presented where another purpose's codes go.
    WrongPlace(PairingPurpose),
    /// A sign-in code of a trainee not in the lab machine's cohort.
    NotInCohort,
    /// The code's account is disabled.
    AccountDisabled,
}

/// Where a code is presented.
#[derive(Debug, Clone, Copy)]
pub enum PairingPlace<'a> {
    /// A simulator pairing itself (`POST /api/pair`): simulator and lab codes.
    Simulator {
        label: &'a str,
        token_days: u32,
        max_tokens: usize,
    },
    /// A lab machine signing a trainee in: sign-in codes of its cohort's trainees.
    Lab {
        machine: &'a LabMachine,
        sign_in: Duration,
        max_tokens: usize,
    },
}

const MACHINE_COLUMNS: &str = "l.id, l.label, c.name AS cohort, l.cohort_id, u.username AS paired_by, \
     l.created_at, l.expires_at, l.revoked_at";

/// The lab machines' rows matching `condition` (constant SQL; values are bound).
fn machine_where(condition: &str) -> String {
    format!(
        "SELECT {MACHINE_COLUMNS} FROM lab_machines l JOIN cohorts c ON c.id = l.cohort_id \
         JOIN users u ON u.id = l.paired_by WHERE {condition}"
    )
}

fn machine_row(r: &sqlx::any::AnyRow, now: &str) -> Result<LabMachine, StoreError> {
    let expires_at: String = r.try_get("expires_at")?;
    let revoked_at: Option<String> = r.try_get("revoked_at")?;
    Ok(LabMachine {
        id: r.try_get("id")?,
        label: r.try_get("label")?,
        cohort: r.try_get("cohort")?,
        cohort_id: r.try_get("cohort_id")?,
        paired_by: r.try_get("paired_by")?,
        created_at: r.try_get("created_at")?,
        active: revoked_at.is_none() && expires_at.as_str() > now,
        expires_at,
        revoked_at,
    })
}

impl Store {
    /// Stores the pairing code `code` (normalised) of `user` for `purpose` (a lab code: for
    /// `cohort_id`), valid for `ttl`, unless the account holds `max_active` unused codes already.
    /// Returns its expiry. Audited (`pairing.code`).
    pub async fn create_pairing_code(
        &self,
        user: &User,
        code: &str,
        purpose: PairingPurpose,
        cohort_id: Option<&str>,
        ttl: Duration,
        max_active: usize,
    ) -> Result<String, StoreError> {
        let created_at = now();
        let expires_at = from_now(ttl);
        let mut tx = self.begin_write().await?;
        if !self.sqlite {
            sqlx::query("SELECT id FROM users WHERE id = $1 FOR UPDATE")
                .bind(user.id.clone())
                .fetch_optional(&mut *tx)
                .await?;
        }
        let active: i64 = sqlx::query(
            "SELECT COUNT(*) AS n FROM pairing_codes WHERE user_id = $1 AND used_at IS NULL AND expires_at > $2",
        )
        .bind(user.id.clone())
        .bind(created_at.clone())
        .fetch_one(&mut *tx)
        .await?
        .try_get("n")?;
        if active >= max_active as i64 {
            tx.rollback().await?;
            return Err(StoreError::TooManyPairingCodes { active });
        }
        sqlx::query(
            "INSERT INTO pairing_codes (code_sha256, purpose, user_id, cohort_id, created_at, expires_at, used_at) \
             VALUES ($1, $2, $3, $4, $5, $6, NULL)",
        )
        .bind(auth::sha256_hex(code))
        .bind(purpose.as_str().to_string())
        .bind(user.id.clone())
        .bind(cohort_id.map(str::to_string))
        .bind(created_at)
        .bind(expires_at.clone())
        .execute(&mut *tx)
        .await?;
        let detail = match cohort_id {
            Some(c) => format!("cohort {c}, expires {expires_at}"),
            None => format!("expires {expires_at}"),
        };
        audit_in(&mut tx, &user.id, "pairing.code", purpose.as_str(), &detail).await?;
        tx.commit().await?;
        Ok(expires_at)
    }

    /// Uses the code `code` (normalised) at `place`: makes what it yields and marks it used, in
    /// one transaction; or says why not, writing nothing.
    pub async fn use_pairing_code(
        &self,
        code: &str,
        place: PairingPlace<'_>,
    ) -> Result<Result<Paired, PairingRefusal>, StoreError> {
        let hash = auth::sha256_hex(code);
        let at = now();
        let mut tx = self.begin_write().await?;
        let lock = if self.sqlite { "" } else { " FOR UPDATE OF p" };
        let row = sqlx::query(sqlx::AssertSqlSafe(format!(
            "SELECT p.purpose, p.cohort_id, u.id, u.username, u.role, u.disabled_at FROM pairing_codes p \
             JOIN users u ON u.id = p.user_id \
             WHERE p.code_sha256 = $1 AND p.used_at IS NULL AND p.expires_at > $2{lock}"
        )))
        .bind(hash.clone())
        .bind(at.clone())
        .fetch_optional(&mut *tx)
        .await?;
        let refuse = async |tx: sqlx::Transaction<'_, sqlx::Any>, why| {
            tx.rollback().await?;
            Ok::<_, StoreError>(Err(why))
        };
        let Some(r) = row else {
            return refuse(tx, PairingRefusal::Unknown).await;
        };
        let purpose_name: String = r.try_get("purpose")?;
        let purpose = PairingPurpose::parse(&purpose_name)
            .ok_or_else(|| StoreError::Invalid(format!("stored pairing purpose '{purpose_name}' is unknown")))?;
        let user = User {
            id: r.try_get("id")?,
            username: r.try_get("username")?,
            role: r.try_get("role")?,
        };
        if r.try_get::<Option<String>, _>("disabled_at")?.is_some() {
            return refuse(tx, PairingRefusal::AccountDisabled).await;
        }
        let cohort_id: Option<String> = r.try_get("cohort_id")?;
        let paired = match (purpose, place) {
            (
                PairingPurpose::Simulator,
                PairingPlace::Simulator {
                    label,
                    token_days,
                    max_tokens,
                },
            ) => {
                let ttl = Duration::from_secs(u64::from(token_days) * 86_400);
                let (token, row) = self
                    .insert_api_token(&mut tx, &user, label, TokenScope::Upload, ttl, max_tokens)
                    .await?;
                audit_in(&mut tx, &user.id, "pairing.simulator", &row.id, label).await?;
                Paired::Token { token, row }
            }
            (PairingPurpose::Lab, PairingPlace::Simulator { label, .. }) => {
                let Some(cohort_id) = cohort_id else {
                    return Err(StoreError::Invalid("a lab pairing code without a cohort".into()));
                };
                let (token, machine) = self.insert_lab_machine(&mut tx, &user, &cohort_id, label).await?;
                Paired::Lab { token, machine }
            }
            (
                PairingPurpose::SignIn,
                PairingPlace::Lab {
                    machine,
                    sign_in,
                    max_tokens,
                },
            ) => {
                let member = sqlx::query("SELECT 1 AS one FROM cohort_members WHERE user_id = $1 AND cohort_id = $2")
                    .bind(user.id.clone())
                    .bind(machine.cohort_id.clone())
                    .fetch_optional(&mut *tx)
                    .await?;
                if member.is_none() || user.role != Role::Trainee {
                    return refuse(tx, PairingRefusal::NotInCohort).await;
                }
                let label = format!("lab machine {}", machine.label);
                let (token, row) = self
                    .insert_api_token(&mut tx, &user, &label, TokenScope::Upload, sign_in, max_tokens)
                    .await?;
                audit_in(&mut tx, &user.id, "lab.sign_in", &machine.id, &row.id).await?;
                Paired::Token { token, row }
            }
            (purpose, _) => return refuse(tx, PairingRefusal::WrongPlace(purpose)).await,
        };
        let used = sqlx::query("UPDATE pairing_codes SET used_at = $1 WHERE code_sha256 = $2 AND used_at IS NULL")
            .bind(at)
            .bind(hash)
            .execute(&mut *tx)
            .await?
            .rows_affected();
        if used != 1 {
            return refuse(tx, PairingRefusal::Unknown).await;
        }
        tx.commit().await?;
        Ok(Ok(paired))
    }

    /// Most days a lab machine stays paired (then an instructor pairs it again).
    pub const LAB_MACHINE_DAYS: u64 = 365;

    async fn insert_lab_machine(
        &self,
        tx: &mut sqlx::Transaction<'_, sqlx::Any>,
        by: &User,
        cohort_id: &str,
        label: &str,
    ) -> Result<(String, LabMachine), StoreError> {
        let token = auth::random_token();
        let id = new_id();
        let created_at = now();
        let expires_at = from_now(Duration::from_secs(Self::LAB_MACHINE_DAYS * 86_400));
        sqlx::query(
            "INSERT INTO lab_machines (id, token_sha256, cohort_id, label, paired_by, created_at, expires_at, revoked_at) \
             VALUES ($1, $2, $3, $4, $5, $6, $7, NULL)",
        )
        .bind(id.clone())
        .bind(auth::sha256_hex(&token))
        .bind(cohort_id.to_string())
        .bind(label.to_string())
        .bind(by.id.clone())
        .bind(created_at)
        .bind(expires_at)
        .execute(&mut **tx)
        .await?;
        audit_in(tx, &by.id, "lab.pair", &id, label).await?;
        let row = sqlx::query(sqlx::AssertSqlSafe(machine_where("l.id = $1")))
            .bind(id)
            .fetch_one(&mut **tx)
            .await?;
        Ok((token, machine_row(&row, &now())?))
    }

    /// The lab machine whose token is `token`, active or not; None for no such token.
    pub async fn lab_machine(&self, token: &str) -> Result<Option<LabMachine>, StoreError> {
        let row = sqlx::query(sqlx::AssertSqlSafe(machine_where("l.token_sha256 = $1")))
            .bind(auth::sha256_hex(token))
            .fetch_optional(&self.pool)
            .await?;
        row.map(|r| machine_row(&r, &now())).transpose()
    }

    /// Lab machine `id`, active or not; None for no such machine.
    pub async fn lab_machine_by_id(&self, id: &str) -> Result<Option<LabMachine>, StoreError> {
        let row = sqlx::query(sqlx::AssertSqlSafe(machine_where("l.id = $1")))
            .bind(id.to_string())
            .fetch_optional(&self.pool)
            .await?;
        row.map(|r| machine_row(&r, &now())).transpose()
    }

    /// The lab machines `viewer` may see and revoke, newest first: an admin's, all; an
    /// instructor's, those of their cohorts; nobody else's.
    pub async fn lab_machines(&self, viewer: &User) -> Result<Vec<LabMachine>, StoreError> {
        let filter = match viewer.role {
            Role::Admin => "",
            Role::Instructor => "WHERE l.cohort_id IN (SELECT cohort_id FROM cohort_members WHERE user_id = $1) ",
            Role::Trainee | Role::Curriculum => return Ok(Vec::new()),
        };
        let mut query = sqlx::query(sqlx::AssertSqlSafe(format!(
            "SELECT {MACHINE_COLUMNS} FROM lab_machines l JOIN cohorts c ON c.id = l.cohort_id \
             JOIN users u ON u.id = l.paired_by {filter}ORDER BY l.created_at DESC, l.id LIMIT 500"
        )));
        if viewer.role == Role::Instructor {
            query = query.bind(viewer.id.clone());
        }
        let rows = query.fetch_all(&self.pool).await?;
        let now = now();
        rows.iter().map(|r| machine_row(r, &now)).collect()
    }

    /// Revokes lab machine `id` by `actor` (audited `lab.revoke`); revoking twice changes
    /// nothing. The machine's row, or None for no such machine.
    pub async fn revoke_lab_machine(&self, id: &str, actor: &User) -> Result<Option<LabMachine>, StoreError> {
        let mut tx = self.begin_write().await?;
        let changed = sqlx::query("UPDATE lab_machines SET revoked_at = $1 WHERE id = $2 AND revoked_at IS NULL")
            .bind(now())
            .bind(id.to_string())
            .execute(&mut *tx)
            .await?
            .rows_affected();
        if changed > 0 {
            audit_in(&mut tx, &actor.id, "lab.revoke", id, "").await?;
        }
        tx.commit().await?;
        self.lab_machine_by_id(id).await
    }

    /// Revokes the API token `token` itself (a simulator signing out), audited as its owner's
    /// `token.revoke`. The token's id, or None for no such token.
    pub async fn revoke_presented_token(&self, token: &str) -> Result<Option<String>, StoreError> {
        let row = sqlx::query("SELECT id, user_id FROM api_tokens WHERE token_sha256 = $1")
            .bind(auth::sha256_hex(token))
            .fetch_optional(&self.pool)
            .await?;
        let Some(r) = row else { return Ok(None) };
        let (id, user_id): (String, String) = (r.try_get("id")?, r.try_get("user_id")?);
        let mut tx = self.begin_write().await?;
        let changed = sqlx::query("UPDATE api_tokens SET revoked_at = $1 WHERE id = $2 AND revoked_at IS NULL")
            .bind(now())
            .bind(id.clone())
            .execute(&mut *tx)
            .await?
            .rows_affected();
        if changed > 0 {
            audit_in(&mut tx, &user_id, "token.revoke", &id, "signed out").await?;
        }
        tx.commit().await?;
        Ok(Some(id))
    }
}
