//! Counted slots, in all and per account: how many uploads are being received, how many requests
//! an account has in flight. A slot is held by a guard and given back when the guard is dropped,
//! however the request ends. Taking one never waits: past a cap the caller is refused at once
//! (429 for the account's own cap, 503 for the server's), with `Retry-After`.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use axum::http::StatusCode;

// The wait a refusal here asks for, also under this module's path (the dashboard's error pages).
pub use super::error::RETRY_AFTER_S;
use super::error::{ApiError, err};

/// Slots of one kind.
#[derive(Debug)]
pub struct Slots {
    /// What is counted, in words, for the refusals ("uploads", "requests").
    what: &'static str,
    total_max: usize,
    per_account_max: usize,
    held: Mutex<Held>,
}

#[derive(Debug, Default)]
struct Held {
    total: usize,
    by_account: HashMap<String, usize>,
}

/// Why a slot was not given.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refused {
    /// The account holds its most.
    Account,
    /// The server holds its most.
    Server,
}

impl Slots {
    pub fn new(what: &'static str, total_max: usize, per_account_max: usize) -> Arc<Slots> {
        Arc::new(Slots {
            what,
            total_max: total_max.max(1),
            per_account_max: per_account_max.max(1),
            held: Mutex::new(Held::default()),
        })
    }

    fn held(&self) -> std::sync::MutexGuard<'_, Held> {
        // The counts are changed in one step each: a poisoned lock still holds sound numbers.
        self.held.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// A slot for `account` (an account id), or why not.
    pub fn try_take(self: &Arc<Self>, account: &str) -> Result<Slot, Refused> {
        let mut held = self.held();
        let mine = held.by_account.get(account).copied().unwrap_or(0);
        if mine >= self.per_account_max {
            return Err(Refused::Account);
        }
        if held.total >= self.total_max {
            return Err(Refused::Server);
        }
        held.total += 1;
        held.by_account.insert(account.to_string(), mine + 1);
        Ok(Slot {
            slots: self.clone(),
            account: account.to_string(),
        })
    }

    /// [`Slots::try_take`], refusals as API errors: 429 (the account's cap) or 503 (the
    /// server's), both with `Retry-After`.
    pub fn take(self: &Arc<Self>, account: &str) -> Result<Slot, ApiError> {
        self.try_take(account).map_err(|r| {
            tracing::info!(what = self.what, account, refused = ?r, "refused: the cap is reached");
            self.refusal(r)
        })
    }

    fn refusal(&self, r: Refused) -> ApiError {
        match r {
            Refused::Account => ApiError::Throttled {
                message: format!(
                    "you have {} {} in progress, the most one account may; wait for one to finish",
                    self.per_account_max, self.what
                ),
                retry_after_s: RETRY_AFTER_S,
            },
            Refused::Server => err(
                StatusCode::SERVICE_UNAVAILABLE,
                format!(
                    "the server is handling as many {} as it can; try again shortly",
                    self.what
                ),
            ),
        }
    }

    /// Slots held now, in all.
    pub fn in_use(&self) -> usize {
        self.held().total
    }
}

/// A held slot; dropping it gives it back.
#[derive(Debug)]
pub struct Slot {
    slots: Arc<Slots>,
    account: String,
}

impl Drop for Slot {
    fn drop(&mut self) {
        let mut held = self.slots.held();
        held.total = held.total.saturating_sub(1);
        if let Some(n) = held.by_account.get_mut(&self.account) {
            *n -= 1;
            if *n == 0 {
                held.by_account.remove(&self.account);
            }
        }
    }
}

/// A request's place for its account's in-flight slot: put into the request's extensions by the
/// server's `in_flight` layer before the handler runs, filled by the extractor that learns the
/// request's account ([`InFlight::hold`]), given back when the request has been answered. (An
/// extractor cannot keep the slot in the request itself: a handler that takes the body consumes
/// the request, and its extensions, before it runs.)
#[derive(Debug, Clone, Default)]
pub struct InFlight(Arc<Mutex<Option<Slot>>>);

impl InFlight {
    /// Takes a slot of `slots` for `account` unless this request holds one already.
    pub fn hold(&self, slots: &Arc<Slots>, account: &str) -> Result<(), ApiError> {
        let mut held = self.0.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        if held.is_none() {
            *held = Some(slots.take(account)?);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn caps_hold_per_account_and_in_all_and_slots_come_back() {
        let slots = Slots::new("uploads", 3, 2);
        let a1 = slots.try_take("a").unwrap();
        let _a2 = slots.try_take("a").unwrap();
        assert_eq!(slots.try_take("a").unwrap_err(), Refused::Account);
        let _b1 = slots.try_take("b").unwrap();
        assert_eq!(slots.try_take("c").unwrap_err(), Refused::Server);
        assert_eq!(slots.in_use(), 3);
        drop(a1);
        assert_eq!(slots.in_use(), 2);
        let _c1 = slots.try_take("c").unwrap();
        // Accounts with nothing held are forgotten: the map holds only accounts in flight.
        drop(_c1);
        assert!(!slots.held().by_account.contains_key("c"));
    }
}
