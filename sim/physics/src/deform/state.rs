//! The deformation as simulation state with a fixed latency (results never depend on scheduling): a
//! solve launched at tick k from the state at k enters the state at tick k + latency. It runs
//! inline (replay, scripts) or on a thread of its own (the live simulator); both give the same bits
//! at the same tick, because the solve is a pure function of what it was handed at launch and the
//! haptic loop waits for it at the due tick if it is late.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex, OnceLock};
use std::time::Duration;

use glam::DVec3;

use super::field::{self, DeformField};
use super::{DeformSettings, ToolPoint};
use crate::PunctureAtlas;

/// Where a launched solve's result will appear.
#[derive(Default)]
struct Slot {
    value: Mutex<Option<Arc<DeformField>>>,
    ready: Condvar,
}

impl Slot {
    fn put(&self, f: Arc<DeformField>) {
        let mut v = self.value.lock().unwrap_or_else(|e| e.into_inner());
        *v = Some(f);
        self.ready.notify_all();
    }
    fn wait(&self) -> Arc<DeformField> {
        let mut v = self.value.lock().unwrap_or_else(|e| e.into_inner());
        loop {
            if let Some(f) = v.as_ref() {
                return Arc::clone(f);
            }
            v = self.ready.wait(v).unwrap_or_else(|e| e.into_inner());
        }
    }
}

/// Starts the threads background solves run on, if they have not started: they take the CPU
/// affinity and priority of the thread that starts them, so a haptic loop that pins itself to a
/// core of its own starts them first, from where it still may run anywhere its process may.
pub fn start_background_threads() {
    let _ = background_pool();
    let _ = Mailbox::get();
}

/// The threads background solves run on: all cores but one, which stays with the haptic loop.
/// The solve gives the same bits on any number of threads.
fn background_pool() -> &'static rayon::ThreadPool {
    static POOL: OnceLock<rayon::ThreadPool> = OnceLock::new();
    POOL.get_or_init(|| {
        let cores = std::thread::available_parallelism().map_or(2, |n| n.get());
        rayon::ThreadPoolBuilder::new()
            .num_threads(cores.saturating_sub(1).max(1))
            .thread_name(|i| format!("stylet-deform-{i}"))
            .build()
            .expect("the deformation thread pool starts")
    })
}

/// A background solve, as handed over.
type Job = Box<dyn FnOnce() + Send>;

/// How often the idle handover thread looks into its mailbox.
const POLL: Duration = Duration::from_micros(200);

/// Where the haptic thread leaves background solves, for a thread that fetches them.
///
/// Handing a job to a sleeping thread means waking it: a system call on the waker's side that
/// measured 7 µs on average and 21 µs at worst in this project's VMs, on the one haptic tick in
/// `every_ticks` that launches a solve; that tick alone kept the tick's p99 above 20 µs. So
/// the haptic thread wakes nobody: it queues the job (an uncontended lock, no allocation while
/// the queue has room) and the handover thread, polling every [`POLL`] while idle, runs it on
/// [`background_pool`]. A job starts at most about [`POLL`] after its launch, far inside its
/// `latency_ticks`; were it late, the haptic loop would wait for it at the due tick, so the
/// result and the tick it enters never depend on this timing.
struct Mailbox {
    jobs: Mutex<VecDeque<Job>>,
    /// Jobs queued and not yet fetched (read without the lock while polling).
    queued: AtomicUsize,
}

impl Mailbox {
    /// The mailbox and its thread, started on first use.
    fn get() -> &'static Mailbox {
        static MAILBOX: OnceLock<&'static Mailbox> = OnceLock::new();
        MAILBOX.get_or_init(|| {
            let mailbox: &'static Mailbox = Box::leak(Box::new(Mailbox {
                jobs: Mutex::new(VecDeque::with_capacity(4)),
                queued: AtomicUsize::new(0),
            }));
            std::thread::Builder::new()
                .name("stylet-deform-handover".into())
                .spawn(move || mailbox.serve())
                .expect("the deformation handover thread starts");
            mailbox
        })
    }

    fn post(&self, job: Job) {
        self.jobs.lock().unwrap_or_else(|e| e.into_inner()).push_back(job);
        self.queued.fetch_add(1, Ordering::Release);
    }

    fn serve(&self) -> ! {
        loop {
            if self.queued.load(Ordering::Acquire) == 0 {
                std::thread::sleep(POLL);
                continue;
            }
            let job = self.jobs.lock().unwrap_or_else(|e| e.into_inner()).pop_front();
            if let Some(job) = job {
                self.queued.fetch_sub(1, Ordering::AcqRel);
                background_pool().install(job);
            }
        }
    }
}

#[derive(Clone)]
enum Result {
    /// No tool condition: u = 0 everywhere, nothing to solve.
    Undeformed,
    Solving(Arc<Slot>),
}

#[derive(Clone)]
struct Pending {
    due_tick: u64,
    result: Result,
}

/// The deformation part of a simulation's state.
#[derive(Clone)]
pub struct DeformState {
    settings: DeformSettings,
    /// The field in effect (None until the first solve enters).
    field: Option<Arc<DeformField>>,
    pending: Option<Pending>,
    background: bool,
    /// A field that left the state and is to be freed by the next background solve (freeing a
    /// 65³ field returns megabytes to the system: tens of µs the haptic thread must not pay,
    /// and a job of its own would cost it a thread wake-up).
    retired: Option<Arc<DeformField>>,
}

impl DeformState {
    pub fn new(settings: DeformSettings, background: bool) -> Self {
        if background {
            Mailbox::get();
        }
        DeformState {
            settings,
            field: None,
            pending: None,
            background,
            retired: None,
        }
    }
    /// Whether solves run in the background (the live simulator) or inline (replay, scripts).
    /// Switching on starts the handover thread now, not on the first launch's haptic tick.
    pub fn set_background(&mut self, background: bool) {
        if background {
            Mailbox::get();
        }
        self.background = background;
    }
    pub fn settings(&self) -> &DeformSettings {
        &self.settings
    }
    /// The field in effect at this tick.
    pub fn field(&self) -> Option<&Arc<DeformField>> {
        self.field.as_ref()
    }

    /// Enters a pending result whose due tick has come (waiting for it if still running).
    pub fn enter_due(&mut self, tick: u64) {
        if let Some(p) = &self.pending
            && p.due_tick <= tick
        {
            let entering = match &p.result {
                Result::Undeformed => None,
                Result::Solving(slot) => Some(slot.wait()),
            };
            let left = std::mem::replace(&mut self.field, entering);
            self.pending = None;
            if self.background && left.is_some() {
                self.retired = left;
            }
        }
    }

    /// Whether a solve is due to start at `tick`.
    pub fn launch_due(&self, tick: u64) -> bool {
        self.settings.enabled && tick.is_multiple_of(u64::from(self.settings.every_ticks))
    }

    /// Starts the solve for the tool state at `tick`; its result enters at tick + latency.
    pub fn launch(&mut self, atlas: &Arc<PunctureAtlas>, tick: u64, centre: DVec3, points: Vec<ToolPoint>) {
        let settings = self.settings;
        let due_tick = tick + u64::from(settings.latency_ticks);
        if points.is_empty() {
            self.pending = Some(Pending {
                due_tick,
                result: Result::Undeformed,
            });
            return;
        }
        let slot = Arc::new(Slot::default());
        let prev = self.field.clone();
        if self.background {
            let (atlas, slot) = (Arc::clone(atlas), Arc::clone(&slot));
            let retired = self.retired.take();
            Mailbox::get().post(Box::new(move || {
                drop(retired);
                let f = field::solve(&atlas, &settings, prev.as_deref(), centre, &points);
                slot.put(Arc::new(f));
            }));
        } else {
            slot.put(Arc::new(field::solve(
                atlas,
                &settings,
                prev.as_deref(),
                centre,
                &points,
            )));
        }
        self.pending = Some(Pending {
            due_tick,
            result: Result::Solving(slot),
        });
    }

    /// Feeds the state's bits to `h`: the field's digest and the pending solve's due tick.
    pub fn digest_into(&self, mut h: impl FnMut(u64)) {
        h(self.field.as_ref().map_or(0, |f| f.digest()));
        h(self.pending.as_ref().map_or(u64::MAX, |p| p.due_tick));
        h(self
            .pending
            .as_ref()
            .map_or(2, |p| u64::from(matches!(p.result, Result::Undeformed))));
    }
}
