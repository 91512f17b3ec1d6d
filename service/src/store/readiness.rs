//! What the admin port's `/readyz` and `/metrics` ask the database: can it answer, are this
//! build's migrations all applied, how many scoring jobs wait.

use super::{Store, StoreError};

/// Why a replica is not ready to serve, as far as the database is concerned.
#[derive(Debug, thiserror::Error)]
pub enum NotReady {
    #[error("the database does not answer: {0}")]
    Unreachable(#[from] StoreError),
    /// The database lacks migrations this build has (another replica is migrating it, or it was
    /// restored from an older backup).
    #[error("the database lacks migration(s) {0:?} of this build")]
    Behind(Vec<i64>),
}

impl Store {
    /// Whether the database answers and holds every migration of this build.
    pub async fn readiness(&self) -> Result<(), NotReady> {
        let applied: Vec<i64> =
            sqlx::query_scalar("SELECT version FROM _sqlx_migrations WHERE success = TRUE ORDER BY version")
                .fetch_all(&self.pool)
                .await
                .map_err(StoreError::from)?;
        let missing: Vec<i64> = super::MIGRATOR
            .iter()
            .map(|m| m.version)
            .filter(|v| applied.binary_search(v).is_err())
            .collect();
        if missing.is_empty() {
            Ok(())
        } else {
            Err(NotReady::Behind(missing))
        }
    }

    /// Scoring jobs queued (waiting for a replica), on the whole database.
    pub async fn queued_jobs(&self) -> Result<i64, StoreError> {
        Ok(
            sqlx::query_scalar("SELECT COUNT(*) FROM scoring_jobs WHERE state = 'queued'")
                .fetch_one(&self.pool)
                .await?,
        )
    }
}
