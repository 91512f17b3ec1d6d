//! Failed logins per account name, in the database: every replica sees the same count, and a
//! restart forgets none.
//!
//! A password check of an account starts only while the account's failures in the current
//! window plus its checks in progress (on any replica) stay under the limit, reserved by one
//! conditional upsert (atomic on SQLite and PostgreSQL alike). So guesses sent at once, to one
//! replica or to several, get no more checks than the limit, and each check that ends adds a
//! failure or, on success, forgets them — the behaviour of checking one account's logins one
//! after another, without holding a lock while argon2 runs. Someone else's login in progress
//! only makes a check wait for it ([`CheckReservation::Wait`]), never refuses it. The window
//! starts at an account's first check and is not moved by later ones (a flood of refused
//! guesses cannot keep an account locked beyond it); [`Store::purge_expired`] deletes the
//! windows that have passed.

use std::time::{Duration, SystemTime};

use sqlx::Row;

use super::{Store, StoreError, at};

/// Whether a password check of an account may start.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CheckReservation {
    /// It may: end it with [`Store::end_login_check`].
    Granted,
    /// The account has had as many failures as allowed; the window ends this much from now.
    Refused { window_left: Duration },
    /// Checks in progress (on any replica) may still use up the allowance: try again shortly.
    Wait,
}

/// How a reserved check ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CheckEnd {
    /// The password matched: the account's failures are forgotten.
    Matched,
    /// It did not: one more failure.
    Failed,
    /// Its request went away before the answer (nobody learnt anything): just given back.
    Abandoned,
}

impl Store {
    /// Reserves a password check of `account` (the lower-cased username) under a limit of
    /// `allowed` failures per `window`.
    pub async fn reserve_login_check(
        &self,
        account: &str,
        allowed: u32,
        window: Duration,
    ) -> Result<CheckReservation, StoreError> {
        let now = SystemTime::now();
        let cutoff = at(now - window);
        let granted = sqlx::query(
            "INSERT INTO login_failures (account, failures, pending, window_from) VALUES ($1, 0, 1, $2) \
             ON CONFLICT (account) DO UPDATE SET \
               failures = CASE WHEN login_failures.window_from < $3 THEN 0 ELSE login_failures.failures END, \
               pending = CASE WHEN login_failures.window_from < $3 THEN 1 ELSE login_failures.pending + 1 END, \
               window_from = CASE WHEN login_failures.window_from < $3 THEN $2 ELSE login_failures.window_from END \
             WHERE login_failures.window_from < $3 OR login_failures.failures + login_failures.pending < $4 \
             RETURNING failures",
        )
        .bind(account.to_string())
        .bind(at(now))
        .bind(cutoff)
        .bind(i64::from(allowed))
        .fetch_optional(&self.pool)
        .await?;
        if granted.is_some() {
            return Ok(CheckReservation::Granted);
        }
        let row = sqlx::query("SELECT failures, window_from FROM login_failures WHERE account = $1")
            .bind(account.to_string())
            .fetch_optional(&self.pool)
            .await?;
        let Some(row) = row else {
            // Deleted meanwhile (its window passed): try again.
            return Ok(CheckReservation::Wait);
        };
        let failures: i64 = row.try_get("failures")?;
        if failures < i64::from(allowed) {
            return Ok(CheckReservation::Wait);
        }
        let from: String = row.try_get("window_from")?;
        let from = humantime::parse_rfc3339(&from)
            .map_err(|e| StoreError::Invalid(format!("login_failures.window_from {from:?}: {e}")))?;
        Ok(CheckReservation::Refused {
            window_left: (from + window).duration_since(now).unwrap_or_default(),
        })
    }

    /// Ends a check [`Store::reserve_login_check`] granted.
    pub async fn end_login_check(&self, account: &str, end: CheckEnd) -> Result<(), StoreError> {
        let failures = match end {
            CheckEnd::Matched => "0",
            CheckEnd::Failed => "failures + 1",
            CheckEnd::Abandoned => "failures",
        };
        sqlx::query(sqlx::AssertSqlSafe(format!(
            "UPDATE login_failures SET failures = {failures}, \
             pending = CASE WHEN pending > 0 THEN pending - 1 ELSE 0 END WHERE account = $1"
        )))
        .bind(account.to_string())
        .execute(&self.pool)
        .await?;
        Ok(())
    }

    /// Deletes what has expired: logins past their expiry, login windows older than
    /// `login_window`, upload slots whose lease ran out, pairing codes past their expiry, and xAPI statements
    /// delivered more than 30 days ago. Returns the rows deleted.
    pub async fn purge_expired(&self, login_window: Duration) -> Result<u64, StoreError> {
        let now = SystemTime::now();
        let mut deleted = 0;
        for (sql, before) in [
            ("DELETE FROM auth_sessions WHERE expires_at <= $1", now),
            ("DELETE FROM login_failures WHERE window_from < $1", now - login_window),
            ("DELETE FROM upload_slots WHERE lease_until < $1", now),
            ("DELETE FROM pairing_codes WHERE expires_at < $1", now),
            // The LRS holds them; the outbox keeps a month of them to look into.
            (
                "DELETE FROM xapi_outbox WHERE delivered_at < $1",
                now - Duration::from_secs(30 * 86_400),
            ),
            // An hour after expiry a replayed launch is unknown rather than "already used"; the
            // table holds at most the launch cap's rows per 10 minutes, for 70 minutes.
            (
                "DELETE FROM lti_launch_states WHERE expires_at < $1",
                now - Duration::from_secs(3600),
            ),
            ("DELETE FROM lti_deep_links WHERE expires_at < $1", now),
            (
                "DELETE FROM lti_grade_outbox WHERE delivered_at < $1",
                now - Duration::from_secs(30 * 86_400),
            ),
        ] {
            deleted += sqlx::query(sql)
                .bind(at(before))
                .execute(&self.pool)
                .await?
                .rows_affected();
        }
        Ok(deleted)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const WINDOW: Duration = Duration::from_secs(300);

    /// Two replicas (two stores on one database) share one account's allowance: checks reserved
    /// at once from both never exceed it, failures lock the account at both, a match forgets
    /// them, a window that passed starts again, and housekeeping deletes passed windows.
    async fn replicas_share_the_allowance(url: &str) {
        let a = Store::open(url).await.unwrap().with_replica("a");
        let b = Store::open(url).await.unwrap().with_replica("b");
        let reserve = |s: &Store, account: &'static str| {
            let s = s.clone();
            async move { s.reserve_login_check(account, 5, WINDOW).await.unwrap() }
        };
        // Twelve at once from both replicas: five granted, the rest wait (none refused: no
        // failure yet).
        let got =
            futures_util::future::join_all((0..12).map(|i| reserve(if i % 2 == 0 { &a } else { &b }, "tom"))).await;
        assert_eq!(
            got.iter().filter(|r| **r == CheckReservation::Granted).count(),
            5,
            "{got:?}"
        );
        assert_eq!(
            got.iter().filter(|r| **r == CheckReservation::Wait).count(),
            7,
            "{got:?}"
        );
        // Two of the five fail and one is abandoned: two failures and two checks in progress
        // leave one place, and no refusal yet.
        a.end_login_check("tom", CheckEnd::Failed).await.unwrap();
        b.end_login_check("tom", CheckEnd::Failed).await.unwrap();
        a.end_login_check("tom", CheckEnd::Abandoned).await.unwrap();
        assert_eq!(reserve(&b, "tom").await, CheckReservation::Granted);
        assert_eq!(reserve(&a, "tom").await, CheckReservation::Wait);
        // The other three checks fail: five failures, refused at both replicas until the
        // window ends.
        for _ in 0..3 {
            b.end_login_check("tom", CheckEnd::Failed).await.unwrap();
        }
        for s in [&a, &b] {
            match reserve(s, "tom").await {
                CheckReservation::Refused { window_left } => {
                    assert!(
                        window_left > Duration::from_secs(290) && window_left <= WINDOW,
                        "{window_left:?}"
                    )
                }
                other => panic!("{other:?}"),
            }
        }
        // Another account has its own allowance.
        assert_eq!(reserve(&a, "cora").await, CheckReservation::Granted);
        a.end_login_check("cora", CheckEnd::Failed).await.unwrap();
        // A match forgets the failures.
        assert_eq!(reserve(&b, "cora").await, CheckReservation::Granted);
        b.end_login_check("cora", CheckEnd::Matched).await.unwrap();
        let cora: i64 = sqlx::query_scalar("SELECT failures FROM login_failures WHERE account = 'cora'")
            .fetch_one(&a.pool)
            .await
            .unwrap();
        assert_eq!(cora, 0);
        // A window that has passed starts again, failures and checks in progress alike.
        let short = Duration::from_millis(50);
        for _ in 0..5 {
            assert_eq!(
                a.reserve_login_check("ivan", 5, short).await.unwrap(),
                CheckReservation::Granted
            );
            a.end_login_check("ivan", CheckEnd::Failed).await.unwrap();
        }
        assert!(matches!(
            b.reserve_login_check("ivan", 5, short).await.unwrap(),
            CheckReservation::Refused { .. }
        ));
        tokio::time::sleep(Duration::from_millis(80)).await;
        assert_eq!(
            b.reserve_login_check("ivan", 5, short).await.unwrap(),
            CheckReservation::Granted
        );
        // Housekeeping deletes the windows that passed and keeps the others.
        sqlx::query("UPDATE login_failures SET window_from = $1 WHERE account = 'tom'")
            .bind(at(SystemTime::now() - WINDOW - Duration::from_secs(1)))
            .execute(&a.pool)
            .await
            .unwrap();
        a.purge_expired(WINDOW).await.unwrap();
        let left: Vec<String> = sqlx::query_scalar("SELECT account FROM login_failures ORDER BY account")
            .fetch_all(&a.pool)
            .await
            .unwrap();
        assert_eq!(
            left,
            vec!["cora".to_string(), "ivan".to_string()],
            "tom's window passed"
        );
    }

    #[tokio::test]
    async fn replicas_share_the_allowance_sqlite() {
        let dir = tempfile::tempdir().unwrap();
        let url = format!("sqlite://{}?mode=rwc", dir.path().join("t.db").display());
        replicas_share_the_allowance(&url).await;
    }

    #[tokio::test]
    async fn replicas_share_the_allowance_postgres() {
        let url = super::super::fresh_postgres_database("loginfail").await;
        replicas_share_the_allowance(&url).await;
    }
}
