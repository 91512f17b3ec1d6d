//! The atlases table (migrations 0001, 0009): every atlas the service has known, and who
//! published the ones that came through `POST /api/atlases`. Publishing is audited in the same
//! transaction as the row it writes.

use sqlx::Row;

use super::{Store, StoreError, User, audit_in, now};

/// A row of the atlases table.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct AtlasRow {
    pub content_hash: String,
    pub name: String,
    pub registered_at: String,
    /// The publisher's username; `None` for an atlas of the configured directory.
    pub published_by: Option<String>,
    pub published_at: Option<String>,
    /// When an admin withdrew it from the catalogue (`None`: it takes sessions).
    pub withdrawn_at: Option<String>,
    /// Sessions stored on the atlas.
    pub sessions: i64,
}

impl Store {
    /// Records a publication of the atlas `hash`: its row (new, or an existing row of the same
    /// content gets its publisher if it had none) and the audit record `atlas.publish`, in one
    /// transaction. `detail` says what was checked.
    pub async fn publish_atlas(
        &self,
        hash: &str,
        name: &str,
        dir: &str,
        actor: &User,
        detail: &str,
    ) -> Result<(), StoreError> {
        let mut tx = self.begin_write().await?;
        let at = now();
        let known = sqlx::query("SELECT content_hash FROM atlases WHERE content_hash = $1")
            .bind(hash.to_string())
            .fetch_optional(&mut *tx)
            .await?;
        if known.is_none() {
            sqlx::query(
                "INSERT INTO atlases (content_hash, name, dir, registered_at, published_by, published_at) \
                 VALUES ($1, $2, $3, $4, $5, $6)",
            )
            .bind(hash.to_string())
            .bind(name.to_string())
            .bind(dir.to_string())
            .bind(at.clone())
            .bind(actor.id.clone())
            .bind(at.clone())
            .execute(&mut *tx)
            .await?;
        } else {
            sqlx::query(
                "UPDATE atlases SET dir = $1, published_by = $2, published_at = $3 \
                 WHERE content_hash = $4 AND published_by IS NULL",
            )
            .bind(dir.to_string())
            .bind(actor.id.clone())
            .bind(at.clone())
            .bind(hash.to_string())
            .execute(&mut *tx)
            .await?;
            // Published again after it was withdrawn: it takes sessions again.
            sqlx::query("UPDATE atlases SET withdrawn_at = NULL, withdrawn_by = NULL WHERE content_hash = $1")
                .bind(hash.to_string())
                .execute(&mut *tx)
                .await?;
        }
        audit_in(&mut tx, &actor.id, "atlas.publish", hash, detail).await?;
        tx.commit().await?;
        Ok(())
    }

    /// Withdraws the atlas `hash` from the catalogue (audited `atlas.withdraw` with `detail`, in
    /// the same transaction). `false`: no such atlas, or it was withdrawn already (nothing
    /// written).
    pub async fn withdraw_atlas(&self, hash: &str, actor: &User, detail: &str) -> Result<bool, StoreError> {
        let mut tx = self.begin_write().await?;
        let changed = sqlx::query(
            "UPDATE atlases SET withdrawn_at = $1, withdrawn_by = $2 WHERE content_hash = $3 AND withdrawn_at IS NULL",
        )
        .bind(now())
        .bind(actor.id.clone())
        .bind(hash.to_string())
        .execute(&mut *tx)
        .await?
        .rows_affected();
        if changed == 0 {
            return Ok(false);
        }
        audit_in(&mut tx, &actor.id, "atlas.withdraw", hash, detail).await?;
        tx.commit().await?;
        Ok(true)
    }

    /// Every atlas row, by name then hash, with its publisher and its stored sessions.
    pub async fn atlas_rows(&self) -> Result<Vec<AtlasRow>, StoreError> {
        let rows = sqlx::query(
            "SELECT a.content_hash, a.name, a.registered_at, u.username AS published_by, a.published_at, a.withdrawn_at, \
             (SELECT COUNT(*) FROM sessions s WHERE s.atlas_hash = a.content_hash) AS sessions \
             FROM atlases a LEFT JOIN users u ON u.id = a.published_by ORDER BY a.name, a.content_hash",
        )
        .fetch_all(&self.pool)
        .await?;
        rows.iter()
            .map(|r| {
                Ok(AtlasRow {
                    content_hash: r.try_get("content_hash")?,
                    name: r.try_get("name")?,
                    registered_at: r.try_get("registered_at")?,
                    published_by: r.try_get("published_by")?,
                    published_at: r.try_get("published_at")?,
                    withdrawn_at: r.try_get("withdrawn_at")?,
                    sessions: r.try_get("sessions")?,
                })
            })
            .collect()
    }
}
