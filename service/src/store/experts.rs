//! Expert references (migration 0008): the sessions a scenario's expert benchmark is computed
//! from. Marking and unmarking are audited in the same transaction.

use sqlx::Row;

use super::{Store, StoreError, User, audit_in, now};

/// A session marked as an expert reference.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ExpertReference {
    pub session_id: String,
    /// The trainee account the session was recorded under.
    pub trainee: String,
    pub marked_by: String,
    pub marked_at: String,
    /// The session file (its review trace holds the path for the expert corridor).
    #[serde(skip)]
    pub file_sha256: String,
}

/// What marking did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Marked {
    /// The session is now a reference.
    Now,
    /// It was one already (nothing changed, nothing audited).
    Already,
    /// The scenario has [`stylet_scoring::benchmark::MAX_EXPERTS`] references already.
    Full,
}

impl Store {
    /// Marks a scored session as an expert reference of its scenario (on its atlas), audited.
    pub async fn mark_expert(&self, session_id: &str, actor: &User) -> Result<Marked, StoreError> {
        let mut tx = self.begin_write().await?;
        let row = sqlx::query("SELECT atlas_hash, scenario FROM sessions WHERE id = $1")
            .bind(session_id.to_string())
            .fetch_optional(&mut *tx)
            .await?;
        let Some(row) = row else {
            tx.rollback().await?;
            return Err(StoreError::Invalid(format!("no session {session_id}")));
        };
        let (atlas_hash, scenario): (String, String) = (row.try_get("atlas_hash")?, row.try_get("scenario")?);
        let already = sqlx::query("SELECT 1 AS one FROM expert_references WHERE session_id = $1")
            .bind(session_id.to_string())
            .fetch_optional(&mut *tx)
            .await?;
        if already.is_some() {
            tx.rollback().await?;
            return Ok(Marked::Already);
        }
        let count: i64 =
            sqlx::query("SELECT COUNT(*) AS n FROM expert_references WHERE atlas_hash = $1 AND scenario = $2")
                .bind(atlas_hash.clone())
                .bind(scenario.clone())
                .fetch_one(&mut *tx)
                .await?
                .try_get("n")?;
        if count as usize >= stylet_scoring::benchmark::MAX_EXPERTS {
            tx.rollback().await?;
            return Ok(Marked::Full);
        }
        // Two marks of one session at once (PostgreSQL reads committed rows only): the second
        // inserts nothing and changes nothing.
        let inserted = sqlx::query(
            "INSERT INTO expert_references (session_id, atlas_hash, scenario, marked_by, marked_at) VALUES ($1, $2, $3, $4, $5) \
             ON CONFLICT (session_id) DO NOTHING",
        )
        .bind(session_id.to_string())
        .bind(atlas_hash)
        .bind(scenario.clone())
        .bind(actor.id.clone())
        .bind(now())
        .execute(&mut *tx)
        .await?
        .rows_affected();
        if inserted == 0 {
            tx.rollback().await?;
            return Ok(Marked::Already);
        }
        audit_in(
            &mut tx,
            &actor.id,
            "expert.mark",
            session_id,
            &format!("expert reference of scenario '{scenario}'"),
        )
        .await?;
        tx.commit().await?;
        Ok(Marked::Now)
    }

    /// Takes the mark off a session, audited; `false` if it had none (nothing audited).
    pub async fn unmark_expert(&self, session_id: &str, actor: &User) -> Result<bool, StoreError> {
        let mut tx = self.begin_write().await?;
        let removed = sqlx::query("DELETE FROM expert_references WHERE session_id = $1")
            .bind(session_id.to_string())
            .execute(&mut *tx)
            .await?
            .rows_affected();
        if removed == 0 {
            tx.rollback().await?;
            return Ok(false);
        }
        audit_in(
            &mut tx,
            &actor.id,
            "expert.unmark",
            session_id,
            "no longer an expert reference",
        )
        .await?;
        tx.commit().await?;
        Ok(true)
    }

    /// The expert references of a scenario on an atlas with their stored score reports (JSON), in
    /// session-id order; at most [`stylet_scoring::benchmark::MAX_EXPERTS`].
    pub async fn expert_references(
        &self,
        atlas_hash: &str,
        scenario: &str,
    ) -> Result<Vec<(ExpertReference, Option<String>)>, StoreError> {
        self.expert_rows(
            "e.atlas_hash = $1 AND e.scenario = $2",
            vec![atlas_hash.to_string(), scenario.to_string()],
        )
        .await
    }

    async fn expert_rows(
        &self,
        condition: &str,
        binds: Vec<String>,
    ) -> Result<Vec<(ExpertReference, Option<String>)>, StoreError> {
        let q = format!(
            "SELECT e.session_id, t.username AS trainee, m.username AS marked_by, e.marked_at, s.file_sha256, sc.report_json \
             FROM expert_references e JOIN sessions s ON s.id = e.session_id \
             JOIN users t ON t.id = s.trainee_id JOIN users m ON m.id = e.marked_by \
             LEFT JOIN scores sc ON sc.session_id = e.session_id \
             WHERE {condition} ORDER BY e.session_id LIMIT {}",
            stylet_scoring::benchmark::MAX_EXPERTS
        );
        let rows = super::bound_query(q, binds).fetch_all(&self.pool).await?;
        rows.iter()
            .map(|r| {
                Ok((
                    ExpertReference {
                        session_id: r.try_get("session_id")?,
                        trainee: r.try_get("trainee")?,
                        marked_by: r.try_get("marked_by")?,
                        marked_at: r.try_get("marked_at")?,
                        file_sha256: r.try_get("file_sha256")?,
                    },
                    r.try_get("report_json")?,
                ))
            })
            .collect::<Result<_, sqlx::Error>>()
            .map_err(StoreError::from)
    }
}
