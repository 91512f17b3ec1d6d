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

/// The environment variable that, set to 1, keeps the haptic loop off a core of its own.
pub const SHARE_CORES: &str = "STYLET_SHARE_CORES";

/// The core the haptic loop keeps to itself, once the window has reserved one
/// ([`reserve_a_core_for_the_haptic_loop`]).
static HAPTIC_CORE: std::sync::OnceLock<usize> = std::sync::OnceLock::new();

/// On a machine with more than one core, keeps the last core the process may use for the haptic
/// loop: the calling thread (the window), and every thread it starts later (drawing, the software
/// renderer's, the spawner of the haptic loop), is restricted to the other cores; the loop pins
/// itself to the kept one ([`pin_the_haptic_loop`]). Returns the kept core; `None` with one core,
/// where affinity cannot be set, or when `STYLET_SHARE_CORES=1` asks for the cores to be shared
/// (to compare, or on a machine where a pinned loop fares worse): then everything shares the
/// cores, under priorities alone.
pub fn reserve_a_core_for_the_haptic_loop() -> Option<usize> {
    if let Some(core) = HAPTIC_CORE.get() {
        return Some(*core);
    }
    if std::env::var_os(SHARE_CORES).is_some_and(|v| v == "1") {
        return None;
    }
    let allowed = allowed_cores();
    let (&haptic, others) = allowed.split_last()?;
    if others.is_empty() || !pin_this_thread(others) {
        return None;
    }
    Some(*HAPTIC_CORE.get_or_init(|| haptic))
}

/// Pins the calling thread (the haptic loop) to the core kept for it, if one was; returns it.
pub fn pin_the_haptic_loop() -> Option<usize> {
    let core = *HAPTIC_CORE.get()?;
    pin_this_thread(&[core]).then_some(core)
}

/// The cores this thread may run on (Linux; elsewhere none known).
pub fn allowed_cores() -> Vec<usize> {
    #[cfg(target_os = "linux")]
    {
        // SAFETY: `set` is a plain bit mask of the size passed; sched_getaffinity(0, …) writes
        // the calling thread's mask into it and nothing else.
        unsafe {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            if libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut set) != 0 {
                return Vec::new();
            }
            (0..libc::CPU_SETSIZE as usize)
                .filter(|&c| libc::CPU_ISSET(c, &set))
                .collect()
        }
    }
    #[cfg(not(target_os = "linux"))]
    {
        Vec::new()
    }
}

/// Restricts the calling thread, and the threads it starts afterwards (which inherit it), to
/// `cores` (Linux; elsewhere nothing happens). Returns whether it took effect.
pub fn pin_this_thread(cores: &[usize]) -> bool {
    #[cfg(target_os = "linux")]
    {
        if cores.is_empty() || cores.iter().any(|&c| c >= libc::CPU_SETSIZE as usize) {
            return false;
        }
        // SAFETY: `set` is a plain bit mask; CPU_SET writes bits below CPU_SETSIZE (checked above);
        // sched_setaffinity(0, …) changes the calling thread's mask only.
        unsafe {
            let mut set: libc::cpu_set_t = std::mem::zeroed();
            for &c in cores {
                libc::CPU_SET(c, &mut set);
            }
            libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) == 0
        }
    }
    #[cfg(not(target_os = "linux"))]
    {
        let _ = cores;
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A thread pinned to one of its cores runs there, and threads it starts inherit the pin.
    #[test]
    fn a_pinned_thread_and_its_children_stay_on_their_cores() {
        let allowed = allowed_cores();
        if cfg!(target_os = "linux") {
            assert!(!allowed.is_empty(), "the affinity mask is readable");
        }
        let Some(&last) = allowed.last() else { return };
        let (mine, child) = std::thread::spawn(move || {
            assert!(pin_this_thread(&[last]));
            let child = std::thread::spawn(allowed_cores).join().unwrap();
            (allowed_cores(), child)
        })
        .join()
        .unwrap();
        assert_eq!(mine, [last]);
        assert_eq!(child, [last], "a thread started after the pin inherits it");
        assert!(!pin_this_thread(&[]));
        // This thread was not touched.
        assert_eq!(allowed_cores(), allowed);
    }
}
