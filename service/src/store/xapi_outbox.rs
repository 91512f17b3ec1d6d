//! The xAPI outbox (migration 0016): statements of scored sessions waiting for the Learning
//! Record Store ([`crate::xapi`]). Written with the score, marked once the LRS has them.

use std::time::Duration;

use sqlx::Row;

use super::{Store, StoreError, from_now, now};

/// A statement to write with a score: (id, verb, JSON).
pub type OutboxStatement = (String, &'static str, String);

impl Store {
    /// Adds `statements` of session `session_id` to the outbox inside `tx` (the score's
    /// transaction); a statement already there (the same id) is left as it is.
    pub(super) async fn queue_statements(
        tx: &mut sqlx::Transaction<'_, sqlx::Any>,
        session_id: &str,
        statements: &[OutboxStatement],
    ) -> Result<(), StoreError> {
        let at = now();
        for (id, verb, json) in statements {
            sqlx::query(
                "INSERT INTO xapi_outbox (statement_id, session_id, verb, statement_json, created_at, attempts, next_attempt_at) \
                 VALUES ($1, $2, $3, $4, $5, 0, $5) ON CONFLICT (statement_id) DO NOTHING",
            )
            .bind(id.clone())
            .bind(session_id.to_string())
            .bind(verb.to_string())
            .bind(json.clone())
            .bind(at.clone())
            .execute(&mut **tx)
            .await?;
        }
        Ok(())
    }

    /// Up to `limit` undelivered statements whose next try is due, oldest first: (id, JSON,
    /// tries so far).
    pub async fn due_statements(&self, limit: usize) -> Result<Vec<(String, String, i64)>, StoreError> {
        let rows = sqlx::query(
            "SELECT statement_id, statement_json, attempts FROM xapi_outbox \
             WHERE delivered_at IS NULL AND next_attempt_at <= $1 ORDER BY created_at, statement_id LIMIT $2",
        )
        .bind(now())
        .bind(limit as i64)
        .fetch_all(&self.pool)
        .await?;
        rows.iter()
            .map(|r| {
                Ok((
                    r.try_get("statement_id")?,
                    r.try_get("statement_json")?,
                    r.try_get("attempts")?,
                ))
            })
            .collect::<Result<_, sqlx::Error>>()
            .map_err(StoreError::from)
    }

    /// The LRS has statement `id`.
    pub async fn statement_delivered(&self, id: &str) -> Result<(), StoreError> {
        sqlx::query("UPDATE xapi_outbox SET delivered_at = $1, attempts = attempts + 1, last_error = NULL WHERE statement_id = $2")
            .bind(now())
            .bind(id.to_string())
            .execute(&self.pool)
            .await?;
        Ok(())
    }

    /// The LRS did not take statement `id` (`why`): tried again after `wait`.
    pub async fn statement_refused(&self, id: &str, why: &str, wait: Duration) -> Result<(), StoreError> {
        sqlx::query(
            "UPDATE xapi_outbox SET attempts = attempts + 1, next_attempt_at = $1, last_error = $2 \
             WHERE statement_id = $3 AND delivered_at IS NULL",
        )
        .bind(from_now(wait))
        .bind(why.chars().take(500).collect::<String>())
        .bind(id.to_string())
        .execute(&self.pool)
        .await?;
        Ok(())
    }
}
