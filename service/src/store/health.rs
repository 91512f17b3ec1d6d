//! Storage failures and recovery from them. When the disk under the database turns read-only or
//! fails, SQLite keeps failing on connections opened meanwhile (they open read-only) even after
//! the disk is writable again. So: every storage failure is noted; connections that existed at
//! a failure are closed when returned to the pool, or when they would be handed out after
//! idling through it, rather than reused; a new SQLite connection
//! must be able to write before the pool hands it out; and the health check writes, so that
//! `/healthz` says 503 while writes fail.

use std::sync::OnceLock;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use super::{Store, StoreError, now};

/// When the last storage failure happened, as milliseconds after [`epoch`] (0: never).
static LAST_FAILURE_MS: AtomicU64 = AtomicU64::new(0);

fn epoch() -> Instant {
    static EPOCH: OnceLock<Instant> = OnceLock::new();
    *EPOCH.get_or_init(Instant::now)
}

/// Whether `e` says the storage itself failed (read-only, I/O, full, cannot open), as opposed to
/// a constraint or a bad query. SQLite result codes (the primary code is the low byte of the
/// extended one) and PostgreSQL SQLSTATE classes 53 (resources), 58 (system) and 25006 (read-only
/// transaction).
pub fn is_storage_failure(e: &sqlx::Error) -> bool {
    match e {
        sqlx::Error::Io(_) => true,
        sqlx::Error::Database(d) => is_storage_code(&d.code().unwrap_or_default()),
        _ => false,
    }
}

/// Whether a database error code says the storage failed. PostgreSQL SQLSTATEs have five
/// characters (often all digits); SQLite's extended result codes at most four digits.
fn is_storage_code(code: &str) -> bool {
    if code.len() == 5 {
        return code.starts_with("53") || code.starts_with("58") || code == "25006";
    }
    // SQLITE_READONLY 8, SQLITE_IOERR 10, SQLITE_FULL 13, SQLITE_CANTOPEN 14 (primary codes are
    // the low byte of the extended ones).
    code.parse::<u32>().is_ok_and(|n| matches!(n & 0xff, 8 | 10 | 13 | 14))
}

/// Whether `e` says the disk is full (SQLITE_FULL; PostgreSQL 53100 disk_full).
pub fn is_disk_full(e: &sqlx::Error) -> bool {
    match e {
        sqlx::Error::Io(io) => io.kind() == std::io::ErrorKind::StorageFull,
        sqlx::Error::Database(d) => {
            let code = d.code().unwrap_or_default();
            code == "53100" || (code.len() < 5 && code.parse::<u32>().is_ok_and(|n| n & 0xff == 13))
        }
        _ => false,
    }
}

/// Notes `e` if it is a storage failure (every database error passes here, see [`StoreError`]).
pub fn note(e: &sqlx::Error) {
    if is_storage_failure(e) {
        let ms = epoch().elapsed().as_millis() as u64;
        LAST_FAILURE_MS.store(ms.max(1), Ordering::Release);
        tracing::warn!(error = %e, "storage failure: connections in use now will be replaced");
    }
}

/// Whether a pooled connection of this age saw a storage failure in its lifetime (then it is
/// closed on release, not reused).
pub fn outlived_failure(age: Duration) -> bool {
    let last = LAST_FAILURE_MS.load(Ordering::Acquire);
    if last == 0 {
        return false;
    }
    let born = epoch().elapsed().saturating_sub(age);
    Duration::from_millis(last) >= born
}

/// Whether the health check may reuse its last answer (it writes, so at most once a second).
const HEALTH_CACHE: Duration = Duration::from_secs(1);

/// The last health check: when and whether writes worked.
#[derive(Debug, Default)]
pub struct Health {
    last: std::sync::Mutex<Option<(Instant, bool)>>,
}

impl Health {
    /// The answer of `probe` (writes that must work), run at most once a second.
    pub async fn check(&self, probe: impl std::future::Future<Output = bool>) -> bool {
        if let Some((at, ok)) = *self.last.lock().expect("not poisoned")
            && at.elapsed() < HEALTH_CACHE
        {
            return ok;
        }
        let ok = probe.await;
        *self.last.lock().expect("not poisoned") = Some((Instant::now(), ok));
        ok
    }
}

impl Store {
    /// A write in a transaction, as every writer does (`BEGIN IMMEDIATE` on SQLite).
    pub async fn probe_write(&self) -> Result<(), StoreError> {
        let mut tx = self.begin_write().await?;
        sqlx::query("UPDATE service_health SET checked_at = $1 WHERE id = 1")
            .bind(now())
            .execute(&mut *tx)
            .await?;
        tx.commit().await?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn storage_failures_are_told_from_other_errors_on_both_databases() {
        // SQLite: READONLY, READONLY_DBMOVED (1032), IOERR_WRITE (778), FULL, CANTOPEN.
        for code in ["8", "1032", "778", "13", "14"] {
            assert!(is_storage_code(code), "{code}");
        }
        // SQLite: CONSTRAINT_UNIQUE (2067), BUSY (5), ERROR (1).
        for code in ["2067", "5", "1"] {
            assert!(!is_storage_code(code), "{code}");
        }
        // PostgreSQL: disk full, I/O error, read-only transaction; not: unique violation, syntax.
        for code in ["53100", "58030", "25006"] {
            assert!(is_storage_code(code), "{code}");
        }
        for code in ["23505", "42601", "40001"] {
            assert!(!is_storage_code(code), "{code}");
        }
    }

    #[test]
    fn connections_older_than_a_failure_are_not_reused() {
        // A connection 10 s old saw a failure noted just now; one opened after it did not.
        LAST_FAILURE_MS.store(epoch().elapsed().as_millis() as u64 + 1, Ordering::Release);
        assert!(outlived_failure(Duration::from_secs(10)));
        std::thread::sleep(Duration::from_millis(20));
        assert!(!outlived_failure(Duration::from_millis(5)));
    }
}
