//! Uploads in progress per account, in the database, so that the per-account cap holds across
//! replicas. An account has slots `0..cap`; an upload takes the first free one (no row, or a row
//! whose lease ran out) with one conditional upsert — the primary key `(account, slot)` makes two
//! holders of one slot impossible on SQLite and PostgreSQL alike — renews its lease while it
//! runs, and deletes its row when it ends. A replica that dies leaves its rows to expire; a
//! restart deletes its own at once ([`Store::release_own_upload_slots`]).

use sqlx::Row;

use super::{Store, StoreError, from_now, new_id, now};

/// An upload slot held in the database.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct UploadSlotKey {
    pub account: String,
    pub slot: i64,
    /// This hold's own id: a slot taken over after its lease ran out is not given back by the
    /// upload that lost it.
    pub holder: String,
}

impl Store {
    /// How long an upload slot stays held without a renewal (the holder renews it every third).
    pub const UPLOAD_SLOT_LEASE: std::time::Duration = std::time::Duration::from_secs(60);

    /// Takes a free upload slot of `account`'s `cap`, or `None` when all are held.
    pub async fn take_upload_slot(&self, account: &str, cap: usize) -> Result<Option<UploadSlotKey>, StoreError> {
        let holder = new_id();
        for slot in 0..cap.max(1) as i64 {
            let taken = sqlx::query(
                "INSERT INTO upload_slots (account, slot, holder, replica, lease_until) VALUES ($1, $2, $3, $4, $5) \
                 ON CONFLICT (account, slot) DO UPDATE SET holder = excluded.holder, replica = excluded.replica, \
                   lease_until = excluded.lease_until \
                 WHERE upload_slots.lease_until < $6 \
                 RETURNING slot",
            )
            .bind(account.to_string())
            .bind(slot)
            .bind(holder.clone())
            .bind(self.replica.to_string())
            .bind(from_now(Self::UPLOAD_SLOT_LEASE))
            .bind(now())
            .fetch_optional(&self.pool)
            .await?;
            if let Some(row) = taken {
                return Ok(Some(UploadSlotKey {
                    account: account.to_string(),
                    slot: row.try_get("slot")?,
                    holder,
                }));
            }
        }
        Ok(None)
    }

    /// Extends the slot's lease; false when it is no longer this hold's.
    pub async fn renew_upload_slot(&self, key: &UploadSlotKey) -> Result<bool, StoreError> {
        let r =
            sqlx::query("UPDATE upload_slots SET lease_until = $1 WHERE account = $2 AND slot = $3 AND holder = $4")
                .bind(from_now(Self::UPLOAD_SLOT_LEASE))
                .bind(key.account.clone())
                .bind(key.slot)
                .bind(key.holder.clone())
                .execute(&self.pool)
                .await?;
        Ok(r.rows_affected() == 1)
    }

    /// Gives the slot back (nothing if it is no longer this hold's).
    pub async fn release_upload_slot(&self, key: &UploadSlotKey) -> Result<(), StoreError> {
        sqlx::query("DELETE FROM upload_slots WHERE account = $1 AND slot = $2 AND holder = $3")
            .bind(key.account.clone())
            .bind(key.slot)
            .bind(key.holder.clone())
            .execute(&self.pool)
            .await?;
        Ok(())
    }

    /// Gives back every upload slot this replica holds (at start, after a crash, and when it
    /// stops): its uploads ended with its previous run.
    pub async fn release_own_upload_slots(&self) -> Result<u64, StoreError> {
        let r = sqlx::query("DELETE FROM upload_slots WHERE replica = $1")
            .bind(self.replica.to_string())
            .execute(&self.pool)
            .await?;
        Ok(r.rows_affected())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two replicas share an account's cap: what one holds the other cannot take, until it is
    /// given back, or its lease runs out, or its replica restarts.
    async fn replicas_share_the_upload_cap(url: &str) {
        let a = Store::open(url).await.unwrap().with_replica("a");
        let b = Store::open(url).await.unwrap().with_replica("b");
        let a1 = a.take_upload_slot("tom", 2).await.unwrap().expect("a first slot");
        let b1 = b.take_upload_slot("tom", 2).await.unwrap().expect("a second slot");
        assert_ne!(a1.slot, b1.slot);
        assert_eq!(a.take_upload_slot("tom", 2).await.unwrap(), None);
        assert_eq!(b.take_upload_slot("tom", 2).await.unwrap(), None);
        // Another account is not held up.
        assert!(b.take_upload_slot("cora", 2).await.unwrap().is_some());
        // Given back: taken again, by the other replica.
        a.release_upload_slot(&a1).await.unwrap();
        let b2 = b
            .take_upload_slot("tom", 2)
            .await
            .unwrap()
            .expect("the slot given back");
        assert_eq!(b2.slot, a1.slot);
        // Many at once from both replicas: exactly the cap's number succeed.
        b.release_upload_slot(&b1).await.unwrap();
        b.release_upload_slot(&b2).await.unwrap();
        let taken = futures_util::future::join_all((0..10).map(|i| {
            let s = if i % 2 == 0 { a.clone() } else { b.clone() };
            async move { s.take_upload_slot("ivan", 3).await.unwrap() }
        }))
        .await;
        assert_eq!(taken.iter().flatten().count(), 3, "{taken:?}");
        // Replicas that restart give back what their previous runs held.
        let released = a.release_own_upload_slots().await.unwrap() + b.release_own_upload_slots().await.unwrap();
        assert_eq!(released, 4, "ivan's 3 and cora's 1");
        // A lease that ran out (its replica died) is taken over; the old hold can neither renew
        // nor give back the slot now held by another.
        let dead = a.take_upload_slot("tina", 1).await.unwrap().unwrap();
        sqlx::query("UPDATE upload_slots SET lease_until = $1")
            .bind(now())
            .execute(&a.pool)
            .await
            .unwrap();
        tokio::time::sleep(std::time::Duration::from_millis(5)).await;
        let live = b.take_upload_slot("tina", 1).await.unwrap().expect("the expired slot");
        assert!(!a.renew_upload_slot(&dead).await.unwrap());
        a.release_upload_slot(&dead).await.unwrap();
        assert!(b.renew_upload_slot(&live).await.unwrap(), "still the live hold's");
        assert_eq!(a.take_upload_slot("tina", 1).await.unwrap(), None);
    }

    #[tokio::test]
    async fn replicas_share_the_upload_cap_sqlite() {
        let dir = tempfile::tempdir().unwrap();
        let url = format!("sqlite://{}?mode=rwc", dir.path().join("t.db").display());
        replicas_share_the_upload_cap(&url).await;
    }

    #[tokio::test]
    async fn replicas_share_the_upload_cap_postgres() {
        let url = super::super::fresh_postgres_database("uploadslots").await;
        replicas_share_the_upload_cap(&url).await;
    }
}
