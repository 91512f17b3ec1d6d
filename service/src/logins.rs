//! What keeps logins from taking the service down: password checks (argon2id, tens of
//! milliseconds of CPU each) run on a few threads of their own with a bounded queue, so a flood
//! of logins waits or gets 503 while every other route keeps its latency; and the memory of
//! recent failures per account is bounded in entries and in time.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use tokio::sync::Semaphore;

/// The queue of password checks is full: answer 503 with Retry-After.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("too many logins at once; try again in a second")]
pub struct Busy;

/// Runs password checks on at most `threads` blocking threads, with at most `queue` waiting.
pub struct PasswordPool {
    run: Arc<Semaphore>,
    admitted: Arc<AtomicUsize>,
    capacity: usize,
}

/// Gives an admission back when a check ends (or its request is dropped).
struct Admission(Arc<AtomicUsize>);

impl Drop for Admission {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::AcqRel);
    }
}

impl PasswordPool {
    pub fn new(threads: usize, queue: usize) -> PasswordPool {
        let threads = threads.max(1);
        PasswordPool {
            run: Arc::new(Semaphore::new(threads)),
            admitted: Arc::new(AtomicUsize::new(0)),
            capacity: threads + queue,
        }
    }

    /// Whether `password` matches the argon2id `hash`; [`Busy`] at once when the queue is full.
    pub async fn verify(&self, password: &str, hash: &str) -> Result<bool, Busy> {
        if self.admitted.fetch_add(1, Ordering::AcqRel) >= self.capacity {
            self.admitted.fetch_sub(1, Ordering::AcqRel);
            return Err(Busy);
        }
        let admission = Admission(self.admitted.clone());
        let permit = self.run.clone().acquire_owned().await.map_err(|_| Busy)?;
        let (password, hash) = (password.to_string(), hash.to_string());
        // The permit and the admission go with the thread: a request dropped while its hash runs
        // still counts until the hash ends, so the threads are never oversubscribed.
        tokio::task::spawn_blocking(move || {
            let _held = (permit, admission);
            super::auth::verify_password(&password, &hash)
        })
        .await
        .map_err(|_| Busy)
    }
}

/// One account's recent failed logins. Its lock is held while a password is checked, so that
/// guesses sent in parallel are checked one after another, each seeing the failures before it.
pub type AccountFailures = Arc<tokio::sync::Mutex<Vec<Instant>>>;

/// Recent failed logins per account name, bounded: entries whose failures are all older than
/// the window are dropped, and past `max_accounts` the entries least recently failed go first.
pub struct FailedLogins {
    accounts: std::sync::Mutex<BTreeMap<String, AccountFailures>>,
    max_accounts: usize,
    window: Duration,
}

impl FailedLogins {
    pub fn new(max_accounts: usize, window: Duration) -> FailedLogins {
        FailedLogins {
            accounts: Default::default(),
            max_accounts: max_accounts.max(1),
            window,
        }
    }

    /// The failures of `account` (lower-cased by the caller), created if new.
    pub fn of(&self, account: &str) -> AccountFailures {
        let mut map = self.accounts.lock().expect("not poisoned");
        if let Some(f) = map.get(account) {
            return f.clone();
        }
        if map.len() >= self.max_accounts {
            self.prune(&mut map);
        }
        let f = AccountFailures::default();
        map.insert(account.to_string(), f.clone());
        f
    }

    /// How many accounts are remembered (tests, metrics).
    pub fn len(&self) -> usize {
        self.accounts.lock().expect("not poisoned").len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Drops the entries nobody is using whose failures have expired; if that is not enough to
    /// get below three quarters of the cap, the least recently failed ones too.
    fn prune(&self, map: &mut BTreeMap<String, AccountFailures>) {
        let now = Instant::now();
        // An entry in use (a login is checking it) has another handle and is kept.
        let last_failure = |f: &AccountFailures| -> Option<Option<Instant>> {
            if Arc::strong_count(f) > 1 {
                return None;
            }
            f.try_lock().ok().map(|v| v.last().copied())
        };
        map.retain(|_, f| match last_failure(f) {
            Some(last) => last.is_some_and(|t| now.duration_since(t) < self.window),
            None => true,
        });
        let target = self.max_accounts * 3 / 4;
        if map.len() <= target {
            return;
        }
        let mut by_age: Vec<(Instant, String)> = map
            .iter()
            .filter_map(|(k, f)| Some((last_failure(f)??, k.clone())))
            .collect();
        by_age.sort();
        for (_, k) in by_age.into_iter().take(map.len() - target) {
            map.remove(&k);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn failed_logins_stay_bounded() {
        let f = FailedLogins::new(100, Duration::from_secs(300));
        for i in 0..10_000 {
            let a = f.of(&format!("user{i}"));
            a.lock().await.push(Instant::now());
        }
        assert!(f.len() <= 100, "{}", f.len());
        // The newest failures are remembered.
        assert_eq!(f.of("user9999").lock().await.len(), 1);
    }

    #[tokio::test]
    async fn expired_failures_are_forgotten_first() {
        let f = FailedLogins::new(10, Duration::from_millis(1));
        for i in 0..10 {
            f.of(&format!("old{i}")).lock().await.push(Instant::now());
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
        f.of("new");
        assert_eq!(f.len(), 1);
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn a_full_password_queue_answers_busy_at_once() {
        let hash = super::super::auth::hash_password("right password").unwrap();
        let pool = Arc::new(PasswordPool::new(1, 2));
        let tasks: Vec<_> = (0..12)
            .map(|_| {
                let (pool, hash) = (pool.clone(), hash.clone());
                tokio::spawn(async move { pool.verify("wrong password", &hash).await })
            })
            .collect();
        let mut busy = 0;
        for t in tasks {
            match t.await.unwrap() {
                Ok(matched) => assert!(!matched),
                Err(Busy) => busy += 1,
            }
        }
        assert!(busy >= 9, "{busy} of 12 refused with a queue of 2 behind 1 thread");
        assert_eq!(pool.verify("right password", &hash).await, Ok(true));
    }
}
