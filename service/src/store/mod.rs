//! The service's database (sqlx, `Any` driver): SQLite in WAL mode by default, PostgreSQL for
//! multi-site use. One set of migrations (`migrations/`) and one SQL dialect for both: `$n`
//! placeholders (SQLite reads them as numbered parameters), text ids and times. Booleans are read
//! back as `CAST(CASE WHEN b THEN 1 ELSE 0 END AS BIGINT)`: the `Any` driver cannot decode
//! SQLite's BOOLEAN.

use sqlx::any::{AnyPoolOptions, install_default_drivers};
use sqlx::{AnyPool, Row};

mod accounts;
mod atlases;
mod cohorts;
mod experts;
pub mod health;
mod instructors;
mod jobs;
mod login_failures;
mod lti;
mod pairing;
mod readiness;
mod reports;
mod review;
mod reworded_migrations;
mod sessions;
mod status;
mod tokens;
mod upload_slots;
mod xapi_outbox;

pub use accounts::{
    AccountChange, AccountError, IMPORT_HEADER, ImportLine, ImportLineError, MAX_IMPORT_LINES, Role, UserRow,
    parse_import,
};
pub use atlases::AtlasRow;
pub use cohorts::{CohortLine, ReportLine, ScorePoint};
pub use experts::{ExpertReference, Marked};
pub use instructors::{
    CompareSearch, DatedScore, LevelTotals, OutcomeFilter, PROGRESS_POINTS, PROGRESS_RECENT, QUEUE_PAGE, QueueReason,
    QueueScope, ReviewLine, RiskSession, SEARCH_PAGE, TraineeProgress,
};
pub use jobs::{Job, OutcomeColumns, join_reasons, split_reasons};
pub use login_failures::{CheckEnd, CheckReservation};
pub use lti::{
    DEFAULT_INSTRUCTOR_ROLES, DeepLinkRequest, DueGrade, LaunchState, LaunchStateProblem, LtiIdentity, LtiPlatform,
    MAX_PENDING_LAUNCHES, MAX_PENDING_LAUNCHES_PER_ADDRESS, NewLtiPlatform, deployment_problems,
};
pub use pairing::{LabMachine, Paired, PairingPlace, PairingPurpose, PairingRefusal};
pub use readiness::NotReady;
pub use reports::{DayCount, FAILED_READ_MAX, FailureBreakdown, FailureCause, TREND_ROWS_MAX};
pub use review::{ExportRow, ProgressPoint, TraineeSummary};
pub use sessions::{NewSession, SessionFilter, SessionLine};
pub use status::SessionStatus;
pub use tokens::{TokenAuth, TokenRow, TokenScope, TokenStatus};
pub use upload_slots::UploadSlotKey;
pub use xapi_outbox::OutboxStatement;

/// Roles, from least to most administrative.
pub const ROLES: [&str; 4] = ["trainee", "instructor", "curriculum", "admin"];

#[derive(Debug, Clone, PartialEq)]
pub struct User {
    pub id: String,
    pub username: String,
    pub role: Role,
}

/// A stored session row (`Session` in the OpenAPI document).
#[derive(Debug, Clone, PartialEq, serde::Serialize, utoipa::ToSchema)]
#[schema(as = Session)]
pub struct SessionRow {
    pub id: String,
    pub trainee: String,
    pub scenario: String,
    pub difficulty: String,
    pub status: SessionStatus,
    pub uploaded_at: String,
    /// The simulator's clock when recording started (from the file's header).
    pub recorded_at: String,
    pub duration_s: f64,
    pub error: Option<String>,
    /// The stored file's SHA-256 (its name under `DATA/sessions/`).
    pub file_sha256: String,
    pub atlas_hash: String,
    pub size_bytes: i64,
    /// The full score report (docs/metrics.md) once scored.
    #[schema(value_type = Option<Object>)]
    pub score: Option<serde_json::Value>,
    /// What the scenario practises (migrations 0005, 0012): puncture, palpation, ultrasound_survey or
    /// drainage.
    #[schema(value_type = String)]
    pub exercise: stylet_scoring::Exercise,
    /// passed, failed or not_gradeable; `None` until scored.
    #[schema(value_type = Option<String>)]
    pub outcome: Option<stylet_scoring::Outcome>,
    /// Why, in plain words (empty until scored, and for a pass that cost nothing).
    pub reasons: Vec<String>,
}

/// Why the store refused or failed a request: the database, a value it does not accept, or a
/// change that clashes with what is stored (each named, so that callers map it to a status once).
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    #[error("database: {0}")]
    Db(sqlx::Error),
    #[error("migrations: {0}")]
    Migrate(#[from] sqlx::migrate::MigrateError),
    #[error("{0}")]
    Invalid(String),
    /// An account of that username exists already.
    #[error("user '{0}' already exists")]
    UserExists(String),
    /// The account holds the most active API tokens allowed.
    #[error("{username} has {active} active API tokens, the most allowed; revoke one first")]
    TooManyTokens { username: String, active: i64 },
    /// The account holds the most unused pairing codes allowed.
    #[error("you have {active} unused pairing codes, the most allowed; use one or wait until they expire")]
    TooManyPairingCodes { active: i64 },
    /// A platform of that issuer and client id is registered already.
    #[error("an LTI platform with issuer {issuer} and client id {client_id} is registered already")]
    LtiPlatformExists { issuer: String, client_id: String },
    /// Too many LTI launches were begun lately (from this address, or in all).
    #[error("too many LTI launches were begun in the last minutes; try again in a few minutes")]
    TooManyLaunches,
    /// argon2 could not hash a password.
    #[error("{0}")]
    PasswordHash(argon2::password_hash::Error),
    /// The thread hashing passwords panicked or was cancelled.
    #[error("hashing the password: {0}")]
    HashingTask(#[source] tokio::task::JoinError),
}

impl From<sqlx::Error> for StoreError {
    /// Every database error passes here: storage failures are noted ([`health`]).
    fn from(e: sqlx::Error) -> Self {
        health::note(&e);
        StoreError::Db(e)
    }
}

impl StoreError {
    /// Whether the request may succeed later (503; the worker tries again): the storage failed
    /// (read-only, I/O, full), or no connection could be had in time (while the disk is
    /// read-only, new SQLite connections are refused).
    pub fn is_transient(&self) -> bool {
        matches!(self, StoreError::Db(e) if health::is_storage_failure(e) || matches!(e, sqlx::Error::PoolTimedOut))
    }

    /// Whether the disk under the database is full.
    pub fn is_disk_full(&self) -> bool {
        matches!(self, StoreError::Db(e) if health::is_disk_full(e))
    }
}

/// A time as the database keeps times: RFC 3339 UTC with microseconds, equal-length strings that
/// sort in time order.
pub fn at(t: std::time::SystemTime) -> String {
    humantime::format_rfc3339_micros(t).to_string()
}

/// Now, in the format of [`at`].
pub fn now() -> String {
    at(std::time::SystemTime::now())
}

/// The time `after` from now, in the format of [`at`] (expiries, leases, back-offs).
pub fn from_now(after: std::time::Duration) -> String {
    at(std::time::SystemTime::now() + after)
}

/// A query whose text was built from constants and `$n` placeholders only (filters assembled at
/// run time), with `binds` bound to `$1…` in order. Values never enter the text.
pub(crate) fn bound_query(
    sql: String,
    binds: Vec<String>,
) -> sqlx::query::Query<'static, sqlx::Any, sqlx::any::AnyArguments> {
    binds
        .into_iter()
        .fold(sqlx::query(sqlx::AssertSqlSafe(sql)), |query, b| query.bind(b))
}

/// An audit record written in the transaction of the change it records.
pub(super) async fn audit_in(
    tx: &mut sqlx::Transaction<'_, sqlx::Any>,
    actor_id: &str,
    action: &str,
    target: &str,
    detail: &str,
) -> Result<(), StoreError> {
    sqlx::query("INSERT INTO audit_log (id, at, actor_id, action, target, detail) VALUES ($1, $2, $3, $4, $5, $6)")
        .bind(new_id())
        .bind(now())
        .bind(actor_id.to_string())
        .bind(action.to_string())
        .bind(target.to_string())
        .bind(detail.to_string())
        .execute(&mut **tx)
        .await?;
    Ok(())
}

pub fn new_id() -> String {
    stylet_recorder::new_session_id()
}

/// Whether an SQLite connection can really write. SQLite opens a file it cannot write read-only,
/// silently, and such a connection stays read-only; `BEGIN IMMEDIATE` alone is no test, for it
/// succeeds on such a connection once the file is writable again (a connection opened just before
/// a read-only window ends). Writing the header's `user_version` back to its own value, rolled
/// back, fails on it.
pub(crate) async fn check_sqlite_writable(conn: &mut sqlx::AnyConnection) -> Result<(), sqlx::Error> {
    let version: i64 = sqlx::query_scalar("PRAGMA user_version").fetch_one(&mut *conn).await?;
    sqlx::query("BEGIN IMMEDIATE").execute(&mut *conn).await?;
    let wrote = sqlx::query(sqlx::AssertSqlSafe(format!("PRAGMA user_version = {version}")))
        .execute(&mut *conn)
        .await;
    let rolled_back = sqlx::query("ROLLBACK").execute(&mut *conn).await;
    wrote?;
    rolled_back?;
    Ok(())
}

/// The migrations of this build (`migrations/`), applied at start.
pub(crate) static MIGRATOR: sqlx::migrate::Migrator = sqlx::migrate!("../migrations");

/// The migrations as a replica runs them at start: the ones this build knows, and applied
/// migrations it does not know tolerated — a newer release's, during a rolling upgrade, which
/// only add (docs/operations.md "Upgrading"), so this older replica keeps working (and can
/// restart) on the newer schema.
fn upgrading_migrator() -> sqlx::migrate::Migrator {
    let mut migrator = sqlx::migrate!("../migrations");
    migrator.set_ignore_missing(true);
    migrator
}

#[derive(Clone)]
pub struct Store {
    pub pool: AnyPool,
    sqlite: bool,
    /// Who this process is among the replicas on the database: the holder of its job leases.
    replica: std::sync::Arc<str>,
    /// How long a claimed job stays this replica's without a renewal.
    job_lease: std::time::Duration,
}

impl Store {
    /// A transaction that writes. On SQLite it starts `BEGIN IMMEDIATE`, taking the write lock
    /// (waiting up to the busy timeout): a deferred transaction that reads first fails at once
    /// with "database is locked" when it comes to write after another connection has written.
    pub(crate) async fn begin_write(&self) -> Result<sqlx::Transaction<'static, sqlx::Any>, sqlx::Error> {
        if self.sqlite {
            self.pool.begin_with("BEGIN IMMEDIATE").await
        } else {
            self.pool.begin().await
        }
    }

    /// How long a request waits for a database connection before it gets 503 (try later). Well
    /// under the request timeout (30 s by default): while the disk is read-only every new SQLite
    /// connection is refused and the pool keeps trying until this deadline, and the client should
    /// hear "the storage failed, try again", not a 408 from the request deadline winning the race.
    pub const ACQUIRE_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(10);

    /// How long a claimed scoring job stays its replica's without a renewal (the worker renews it
    /// every third of that while it replays): a replica that dies loses its jobs this long after.
    pub const JOB_LEASE: std::time::Duration = std::time::Duration::from_secs(60);

    /// The same store acting as replica `id` (a stable name: the server keeps its own in its data
    /// directory, so that a restart takes back at once what its previous run held).
    pub fn with_replica(mut self, id: &str) -> Store {
        self.replica = id.into();
        self
    }

    /// The same store with leases of `lease` (tests use short ones).
    pub fn with_job_lease(mut self, lease: std::time::Duration) -> Store {
        self.job_lease = lease;
        self
    }

    /// This replica's name.
    pub fn replica(&self) -> &str {
        &self.replica
    }

    /// The length of the job leases it takes.
    pub fn job_lease(&self) -> std::time::Duration {
        self.job_lease
    }

    /// Connects, sets SQLite to WAL, applies the migrations.
    pub async fn open(url: &str) -> Result<Store, StoreError> {
        install_default_drivers();
        let sqlite = url.starts_with("sqlite:");
        let pool = AnyPoolOptions::new()
            .max_connections(8)
            .acquire_timeout(Self::ACQUIRE_TIMEOUT)
            .after_connect(move |conn, _| {
                Box::pin(async move {
                    if sqlite {
                        sqlx::query("PRAGMA busy_timeout = 10000").execute(&mut *conn).await?;
                        sqlx::query("PRAGMA foreign_keys = ON").execute(&mut *conn).await?;
                        // SQLite opens a file it cannot write read-only, silently, and the
                        // connection stays so: refuse it, so that a data directory that was
                        // read-only for a while leaves no such connection in the pool.
                        if let Err(e) = check_sqlite_writable(conn).await {
                            health::note(&e);
                            return Err(e);
                        }
                    }
                    Ok(())
                })
            })
            // A connection that existed when the storage failed is closed, not reused: when it
            // is returned, and when it would be handed out after idling through the failure
            // (else each such idle connection fails one request after the disk recovered).
            .after_release(|_, meta| Box::pin(async move { Ok(!health::outlived_failure(meta.age)) }))
            .before_acquire(|_, meta| Box::pin(async move { Ok(!health::outlived_failure(meta.age)) }))
            // And none lives forever.
            .max_lifetime(std::time::Duration::from_secs(30 * 60))
            .connect(url)
            .await?;
        if sqlite {
            sqlx::query("PRAGMA journal_mode = WAL").execute(&pool).await?;
        }
        reworded_migrations::accept(&pool, &MIGRATOR, sqlite).await?;
        upgrading_migrator().run(&pool).await?;
        let store = Store {
            pool,
            sqlite,
            replica: new_id().into(),
            job_lease: Self::JOB_LEASE,
        };
        store.fill_session_summaries().await?;
        store.fill_session_reasons().await?;
        Ok(store)
    }

    /// Fills the summary columns of migration 0002 for sessions scored before it (once; later
    /// scores and overrides write them as they happen).
    async fn fill_session_summaries(&self) -> Result<(), StoreError> {
        let rows = sqlx::query(
            "SELECT s.id, sc.report_json FROM sessions s JOIN scores sc ON sc.session_id = s.id WHERE s.attempts IS NULL",
        )
        .fetch_all(&self.pool)
        .await?;
        for r in rows {
            let id: String = r.try_get("id")?;
            let report: serde_json::Value = serde_json::from_str(&r.try_get::<String, _>("report_json")?)
                .map_err(|e| StoreError::Invalid(format!("stored report of session {id}: {e}")))?;
            let summary = jobs::Summary::from_json(&report)
                .ok_or_else(|| StoreError::Invalid(format!("stored report of session {id} lacks grade or metrics")))?;
            let mut tx = self.begin_write().await?;
            jobs::write_summary(&mut tx, &id, &summary).await?;
            if let Some((score, passed)) = review::latest_override(&mut tx, &id).await? {
                review::write_final_grade(&mut tx, &id, score, passed).await?;
            }
            tx.commit().await?;
        }
        Ok(())
    }

    async fn audit(
        &self,
        actor: Option<&str>,
        action: &str,
        target: Option<&str>,
        detail: &str,
    ) -> Result<(), StoreError> {
        sqlx::query("INSERT INTO audit_log (id, at, actor_id, action, target, detail) VALUES ($1, $2, $3, $4, $5, $6)")
            .bind(new_id())
            .bind(now())
            .bind(actor.map(str::to_string))
            .bind(action.to_string())
            .bind(target.map(str::to_string))
            .bind(detail.to_string())
            .execute(&self.pool)
            .await?;
        Ok(())
    }
    pub async fn register_atlas(&self, hash: &str, name: &str, dir: &str) -> Result<(), StoreError> {
        let known = sqlx::query("SELECT content_hash FROM atlases WHERE content_hash = $1")
            .bind(hash.to_string())
            .fetch_optional(&self.pool)
            .await?;
        if known.is_none() {
            sqlx::query("INSERT INTO atlases (content_hash, name, dir, registered_at) VALUES ($1, $2, $3, $4)")
                .bind(hash.to_string())
                .bind(name.to_string())
                .bind(dir.to_string())
                .bind(now())
                .execute(&self.pool)
                .await?;
        }
        Ok(())
    }

    /// Count of scores per session (tests: exactly once).
    pub async fn score_count(&self, session_id: &str) -> Result<i64, StoreError> {
        let row = sqlx::query("SELECT COUNT(*) AS n FROM scores WHERE session_id = $1")
            .bind(session_id.to_string())
            .fetch_one(&self.pool)
            .await?;
        Ok(row.try_get("n")?)
    }
}

/// A new, empty PostgreSQL database for one unit test, named `{prefix}_{process id}`, on the
/// server of `$STYLET_POSTGRES_URL` (scripts/test starts it and sets it); its URL. Without that
/// variable the test fails rather than being skipped.
#[cfg(test)]
pub(crate) async fn fresh_postgres_database(prefix: &str) -> String {
    let admin = std::env::var("STYLET_POSTGRES_URL")
        .expect("STYLET_POSTGRES_URL is not set: scripts/test starts PostgreSQL (scripts/postgres-up) and sets it");
    sqlx::any::install_default_drivers();
    let name = format!("{prefix}_{}", std::process::id());
    let pool = sqlx::AnyPool::connect(&admin).await.unwrap();
    for sql in [
        format!("DROP DATABASE IF EXISTS {name}"),
        format!("CREATE DATABASE {name}"),
    ] {
        sqlx::query(sqlx::AssertSqlSafe(sql)).execute(&pool).await.unwrap();
    }
    pool.close().await;
    let base = admin.rsplit_once('/').expect("a URL with a database").0;
    format!("{base}/{name}")
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Writers that read before they write (adding an account checks the name, then the cohort)
    /// must wait for each other on SQLite, not fail with "database is locked".
    #[tokio::test(flavor = "multi_thread", worker_threads = 4)]
    async fn concurrent_writers_all_succeed_on_sqlite() {
        let dir = tempfile::tempdir().unwrap();
        let store = Store::open(&format!("sqlite://{}?mode=rwc", dir.path().join("t.db").display()))
            .await
            .unwrap();
        let tasks: Vec<_> = (0..24)
            .map(|i| {
                let store = store.clone();
                tokio::spawn(async move {
                    let cohort = format!("c{}", i % 3);
                    store
                        .add_user(&format!("user{i}"), "trainee", "a long password", Some(&cohort), None)
                        .await
                })
            })
            .collect();
        for (i, t) in tasks.into_iter().enumerate() {
            if let Err(e) = t.await.unwrap() {
                panic!("user{i}: {e}");
            }
        }
        assert_eq!(store.users().await.unwrap().len(), 24);
    }

    /// A connection SQLite opened read-only is refused even while the file is writable (the race
    /// at the end of a read-only window: opened during it, checked after it), and a normal one
    /// passes without changing the database.
    #[tokio::test]
    async fn a_read_only_sqlite_connection_fails_the_write_check() {
        use sqlx::Connection;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.db");
        let store = Store::open(&format!("sqlite://{}?mode=rwc", path.display()))
            .await
            .unwrap();
        let mut ro = sqlx::AnyConnection::connect(&format!("sqlite://{}?mode=ro", path.display()))
            .await
            .unwrap();
        // `BEGIN IMMEDIATE` alone succeeds on it: the old check let it through.
        sqlx::query("BEGIN IMMEDIATE").execute(&mut ro).await.unwrap();
        sqlx::query("ROLLBACK").execute(&mut ro).await.unwrap();
        let e = check_sqlite_writable(&mut ro).await.unwrap_err();
        assert!(health::is_storage_failure(&e), "{e}");
        let mut rw = sqlx::AnyConnection::connect(&format!("sqlite://{}", path.display()))
            .await
            .unwrap();
        check_sqlite_writable(&mut rw).await.unwrap();
        let v: i64 = sqlx::query_scalar("PRAGMA user_version")
            .fetch_one(&mut rw)
            .await
            .unwrap();
        assert_eq!(v, 0);
        store.probe_write().await.unwrap();
    }
}
