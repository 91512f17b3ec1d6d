//! Thread priorities: the threads that draw run at a lower priority than the haptic loop, so that
//! on a machine with few cores the scheduler gives the loop its core first (the loop's deadlines
//! are 1 ms apart; a view is fine a few milliseconds later).

/// The niceness drawing threads take (0 is normal, 19 the lowest priority).
pub const DRAWING_NICENESS: i32 = 15;

/// Lowers the calling thread's priority to `niceness` (Linux: per thread). Raising a priority
/// needs privileges and is never attempted. Returns whether it took effect.
pub fn lower_this_thread(niceness: i32) -> bool {
    #[cfg(target_os = "linux")]
    {
        // SAFETY: gettid and setpriority have no memory-safety preconditions; setpriority with
        // PRIO_PROCESS and a thread id changes that thread's niceness only.
        unsafe {
            let tid = libc::gettid();
            let current = libc::getpriority(libc::PRIO_PROCESS, tid as libc::id_t);
            if current >= niceness {
                return true;
            }
            libc::setpriority(libc::PRIO_PROCESS, tid as libc::id_t, niceness) == 0
        }
    }
    #[cfg(not(target_os = "linux"))]
    {
        let _ = niceness;
        false
    }
}
