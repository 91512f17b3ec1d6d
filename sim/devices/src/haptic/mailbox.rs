//! The newest value, handed between the simulation and a device's servo loop without ever blocking
//! the servo loop: the servo side only *tries* the lock and keeps its previous value when the other
//! side holds it (for the few nanoseconds of a copy), so a stalled or descheduled simulation
//! thread cannot delay a servo tick.

use std::sync::Mutex;

/// One slot holding the newest `T`.
#[derive(Debug, Default)]
pub struct Mailbox<T: Copy> {
    slot: Mutex<Option<T>>,
}

impl<T: Copy> Mailbox<T> {
    pub fn new() -> Self {
        Mailbox { slot: Mutex::new(None) }
    }

    /// Replaces the value, waiting for the lock (the simulation's side; the servo loop holds it
    /// only for a copy).
    pub fn put(&self, value: T) {
        let mut slot = self.slot.lock().unwrap_or_else(|e| e.into_inner());
        *slot = Some(value);
    }

    /// Replaces the value if the lock is free at once (the servo loop's side); `false` when it
    /// was not (the value is dropped: the next tick brings a newer one).
    pub fn try_put(&self, value: T) -> bool {
        match self.slot.try_lock() {
            Ok(mut slot) => {
                *slot = Some(value);
                true
            }
            Err(std::sync::TryLockError::Poisoned(e)) => {
                *e.into_inner() = Some(value);
                true
            }
            Err(std::sync::TryLockError::WouldBlock) => false,
        }
    }

    /// The newest value, waiting for the lock (the simulation's side).
    pub fn latest(&self) -> Option<T> {
        *self.slot.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The newest value if the lock is free at once, else `previous` (the servo loop's side).
    pub fn try_latest(&self, previous: Option<T>) -> Option<T> {
        match self.slot.try_lock() {
            Ok(slot) => slot.or(previous),
            Err(std::sync::TryLockError::Poisoned(e)) => e.into_inner().or(previous),
            Err(std::sync::TryLockError::WouldBlock) => previous,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_servo_side_keeps_its_previous_value_while_the_lock_is_held() {
        let m = Mailbox::new();
        assert_eq!(m.try_latest(None), None);
        m.put(1u32);
        assert_eq!(m.try_latest(None), Some(1));
        let held = m.slot.lock().unwrap();
        assert_eq!(m.try_latest(Some(7)), Some(7), "never waits");
        assert!(!m.try_put(2));
        drop(held);
        assert!(m.try_put(3));
        assert_eq!(m.latest(), Some(3));
    }
}
