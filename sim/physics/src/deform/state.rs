//! The deformation as simulation state with a fixed latency (issue: results never depend on
//! scheduling): a solve launched at tick k from the state at k enters the state at tick
//! k + latency. It runs inline (replay, scripts) or on a thread of its own (the live simulator);
//! both give the same bits at the same tick, because the solve is a pure function of what it was
//! handed at launch and the haptic loop waits for it at the due tick if it is late.

use std::sync::{Arc, Condvar, Mutex};

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

/// The threads background solves run on: all cores but one, which stays with the haptic loop
/// (handing a job to a pool costs the haptic thread far less than starting a thread). The solve
/// gives the same bits on any number of threads.
fn background_pool() -> &'static rayon::ThreadPool {
    static POOL: std::sync::OnceLock<rayon::ThreadPool> = std::sync::OnceLock::new();
    POOL.get_or_init(|| {
        let cores = std::thread::available_parallelism().map_or(2, |n| n.get());
        rayon::ThreadPoolBuilder::new()
            .num_threads(cores.saturating_sub(1).max(1))
            .thread_name(|i| format!("stylet-deform-{i}"))
            .build()
            .expect("the deformation thread pool starts")
    })
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
        DeformState {
            settings,
            field: None,
            pending: None,
            background,
            retired: None,
        }
    }
    pub fn set_background(&mut self, background: bool) {
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
            background_pool().spawn(move || {
                drop(retired);
                let f = field::solve(&atlas, &settings, prev.as_deref(), centre, &points);
                slot.put(Arc::new(f));
            });
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
