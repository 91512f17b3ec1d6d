//! The haptic loop (thesis §6.3; docs/simulator.md "The haptic loop"): a thread of its own ticking
//! at the simulation's rate (1 kHz): device sample → `Simulation::step` → force to the device (the
//! device receives the previous tick's output with its next sample) → recorder.
//!
//! Nothing outside the thread can make it wait. The recorder never blocks in real time (a full
//! queue marks the session incomplete); the views read [`Snapshot`]s that the loop publishes with
//! `try_lock` every few ticks, skipping a publication rather than waiting for a reader. Ticks done
//! after their deadline are counted ([`LoopStats`], shown in the status bar) and written to the
//! session as notes, which the replay ignores: pacing decides when a tick runs, never what it
//! computes.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use stylet_devices::Device;
use stylet_physics::glam::{DQuat, DVec3};
use stylet_physics::{Event, LabelId, Simulation, TickInput, TickOutput};
use stylet_recorder::device_forces::DeviceForceRecord;
use stylet_recorder::{Recording, WriteError, WriteSummary};
use stylet_render::views::{Moment, SessionLabels};
use stylet_render::xray::ContrastOverlay;
use stylet_render::xray::attenuation::DEFAULT_IODINE_MG_PER_ML;

use crate::pacing::Pacer;

/// How the loop runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LoopOptions {
    /// Real time (ticks at the simulation's rate) or as fast as the CPU allows (headless runs,
    /// tests: same ticks, same session file).
    pub paced: bool,
    /// A snapshot for the views every this many ticks (16: 62.5 Hz at 1 kHz, the
    /// views' fixed sub-rate; docs/simulator.md "The haptic loop").
    pub publish_every: u64,
}

impl Default for LoopOptions {
    fn default() -> Self {
        LoopOptions {
            paced: true,
            publish_every: 16,
        }
    }
}

/// What the views draw: the state after one tick.
#[derive(Debug, Clone)]
pub struct Snapshot {
    pub position_mm: DVec3,
    pub orientation: DQuat,
    pub output: TickOutput,
    /// The tools, the contrast medium and the session's labels at this tick.
    pub moment: Moment,
    /// What the first hand holds.
    pub tool: stylet_physics::ToolSpec,
    /// What the second hand holds (two-handed sessions).
    pub second_tool: Option<stylet_physics::HandTool>,
}

/// Counters the loop keeps for the status bar (read at any time, never locked).
#[derive(Debug, Default)]
pub struct LoopStats {
    ticks: AtomicU64,
    missed: AtomicU64,
    worst_late_ns: AtomicU64,
    skipped_periods: AtomicU64,
    skipped_publications: AtomicU64,
}

/// A copy of [`LoopStats`] at one moment.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct StatsView {
    /// Ticks simulated so far.
    pub ticks: u64,
    /// Ticks done after their deadline (paced loops only).
    pub missed: u64,
    /// The latest any tick was done past its deadline.
    pub worst_late: Duration,
    /// Periods given up when the loop was stalled for more than `pacing::MAX_BACKLOG_PERIODS`.
    pub skipped_periods: u64,
    /// Snapshots not published because a view was reading the previous one.
    pub skipped_publications: u64,
}

impl LoopStats {
    pub fn view(&self) -> StatsView {
        StatsView {
            ticks: self.ticks.load(Ordering::Relaxed),
            missed: self.missed.load(Ordering::Relaxed),
            worst_late: Duration::from_nanos(self.worst_late_ns.load(Ordering::Relaxed)),
            skipped_periods: self.skipped_periods.load(Ordering::Relaxed),
            skipped_publications: self.skipped_publications.load(Ordering::Relaxed),
        }
    }
}

/// Why the loop ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Ended {
    /// The device had no more samples (a script's end, a replay's end).
    DeviceEnded,
    /// [`HapticLoop::stop`] was called (the trainee finished or quit).
    Stopped,
}

/// The loop's account of a finished run.
#[derive(Debug)]
pub struct LoopReport {
    pub ended: Ended,
    pub stats: StatsView,
    /// Wall time from the first tick to the last.
    pub wall: Duration,
    /// The recording's summary, or why it could not be written completely.
    pub recording: Option<Result<WriteSummary, WriteError>>,
    /// The simulation after the last tick (for the results screen's local score).
    pub final_tick: u64,
    /// `Simulation::state_digest` after the last tick: a replay of the recording reaches it.
    pub final_digest: u64,
}

/// A line of the event console: what happened at a tick, in words.
#[derive(Debug, Clone, PartialEq)]
pub struct ConsoleLine {
    pub tick: u64,
    pub time_s: f64,
    pub text: String,
}

/// Console lines waiting for the window; more are dropped (and counted), never waited for.
pub const CONSOLE_CAPACITY: usize = 1024;

/// Errors of the loop thread itself.
#[derive(Debug, thiserror::Error)]
pub enum LoopError {
    #[error("cannot start the haptic thread: {0}")]
    Spawn(#[from] std::io::Error),
    #[error("the haptic thread stopped unexpectedly (panic): {0}")]
    Panicked(String),
}

struct Shared {
    stop: AtomicBool,
    snapshot: Mutex<Option<Snapshot>>,
    stats: LoopStats,
    dropped_console_lines: AtomicU64,
}

/// A running haptic loop. Dropping it without [`HapticLoop::join`] asks the loop to stop (the
/// recording is then finished by the loop thread on its own).
pub struct HapticLoop {
    shared: Arc<Shared>,
    handle: Option<JoinHandle<LoopReport>>,
    console: Receiver<ConsoleLine>,
}

impl Drop for HapticLoop {
    fn drop(&mut self) {
        if self.handle.is_some() {
            self.stop();
        }
    }
}

impl HapticLoop {
    /// Starts the loop on its own thread. `recording`, when given, must be in real-time mode for
    /// a paced loop (it never blocks then).
    pub fn spawn(
        sim: Simulation,
        device: Box<dyn Device + Send>,
        recording: Option<Recording>,
        labels: SessionLabels,
        options: LoopOptions,
    ) -> Result<HapticLoop, LoopError> {
        let shared = Arc::new(Shared {
            stop: AtomicBool::new(false),
            snapshot: Mutex::new(None),
            stats: LoopStats::default(),
            dropped_console_lines: AtomicU64::new(0),
        });
        let inner = Arc::clone(&shared);
        // The ducts' channel a guide wire follows is a distance transform of the whole atlas
        // (a fraction of a second): built beside the loop now, so putting a wire in later does not
        // hold up a tick. Without a thread, the first wire builds it.
        let atlas = sim.shared_atlas();
        let _ = std::thread::Builder::new()
            .name("duct-channel".into())
            .spawn(move || drop(atlas.duct_channel()));
        let (tx, console) = std::sync::mpsc::sync_channel(CONSOLE_CAPACITY);
        let handle = spawn_at_normal_priority(move || run(sim, device, recording, &labels, options, &inner, &tx))?;
        Ok(HapticLoop {
            shared,
            handle: Some(handle),
            console,
        })
    }

    /// The console lines written since the last call (never blocks the loop).
    pub fn console(&self) -> Vec<ConsoleLine> {
        self.console.try_iter().collect()
    }

    /// Console lines the loop dropped because the window did not read them in time.
    pub fn dropped_console_lines(&self) -> u64 {
        self.shared.dropped_console_lines.load(Ordering::Relaxed)
    }

    /// The latest published state (a brief lock the loop never waits on).
    pub fn snapshot(&self) -> Option<Snapshot> {
        self.shared.snapshot.lock().ok().and_then(|s| s.clone())
    }

    pub fn stats(&self) -> StatsView {
        self.shared.stats.view()
    }

    /// Asks the loop to end after its current tick.
    pub fn stop(&self) {
        self.shared.stop.store(true, Ordering::Relaxed);
    }

    pub fn is_finished(&self) -> bool {
        self.handle.as_ref().is_none_or(|h| h.is_finished())
    }

    /// Waits for the loop to end (call [`Self::stop`] first unless the device ends by itself).
    pub fn join(mut self) -> Result<LoopReport, LoopError> {
        let handle = self.handle.take().expect("joined once");
        handle.join().map_err(|p| {
            let why = p
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_else(|| "no message".into());
            LoopError::Panicked(why)
        })
    }
}

type Job = Box<dyn FnOnce() + Send>;

/// A thread of normal priority that starts the haptic loops, once the window has lowered its own.
static SPAWNER: std::sync::OnceLock<Mutex<std::sync::mpsc::Sender<Job>>> = std::sync::OnceLock::new();

/// Keeps a thread of normal priority that starts every later haptic loop. The window calls this
/// before it lowers its own thread's priority (which the threads it starts would inherit, and
/// which an unprivileged process cannot raise again), so that the loop outranks the window and
/// its software renderer on a machine with few cores.
pub fn keep_a_normal_priority_spawner() -> Result<(), std::io::Error> {
    if SPAWNER.get().is_some() {
        return Ok(());
    }
    let (tx, rx) = std::sync::mpsc::channel::<Job>();
    std::thread::Builder::new()
        .name("stylet-spawner".into())
        .spawn(move || {
            for job in rx {
                job();
            }
        })?;
    let _ = SPAWNER.set(Mutex::new(tx));
    Ok(())
}

/// Runs `f` on the normal-priority spawner when there is one (else here), so that the threads
/// it starts run at normal priority: the haptic loop, the recorder's writer.
pub fn at_normal_priority<T: Send + 'static>(f: impl FnOnce() -> T + Send + 'static) -> Result<T, std::io::Error> {
    let Some(spawner) = SPAWNER.get() else {
        return Ok(f());
    };
    let (tx, rx) = std::sync::mpsc::channel();
    let job: Job = Box::new(move || {
        let _ = tx.send(f());
    });
    let sent = spawner.lock().map(|s| s.send(job).is_ok()).unwrap_or(false);
    match (sent, rx.recv()) {
        (true, Ok(t)) => Ok(t),
        _ => Err(std::io::Error::other("the normal-priority spawner thread is gone")),
    }
}

/// Starts the loop's thread, from the normal-priority spawner when there is one.
fn spawn_at_normal_priority(
    f: impl FnOnce() -> LoopReport + Send + 'static,
) -> Result<JoinHandle<LoopReport>, std::io::Error> {
    at_normal_priority(move || std::thread::Builder::new().name("stylet-haptic".into()).spawn(f))?
}

fn run(
    mut sim: Simulation,
    mut device: Box<dyn Device + Send>,
    mut recording: Option<Recording>,
    labels: &SessionLabels,
    options: LoopOptions,
    shared: &Shared,
    console: &SyncSender<ConsoleLine>,
) -> LoopReport {
    if options.paced {
        // The deformation's solver threads start here, before the pin, so that they run on the
        // other cores; then this thread takes the core the window kept for it, if it did.
        stylet_physics::deform::start_background_threads();
        crate::priority::pin_the_haptic_loop();
    }
    let mut contrast = ContrastCache::default();
    let rate = sim.tick_rate_hz();
    let mut pacer = options.paced.then(|| Pacer::new(rate, sim.tick()));
    let publish_every = options.publish_every.max(1);
    let stats = &shared.stats;
    let started = Instant::now();
    let mut last: Option<TickOutput> = None;
    let mut last_input: Option<TickInput> = None;
    // Misses within the current second, for the session notes.
    let (mut window_missed, mut window_worst) = (0u64, Duration::ZERO);
    let ended = loop {
        if shared.stop.load(Ordering::Relaxed) {
            break Ended::Stopped;
        }
        let tick = sim.tick();
        if let Some(p) = &pacer {
            p.wait_until_due(tick);
        }
        let Some(input) = device.next(tick, last.as_ref()) else {
            break Ended::DeviceEnded;
        };
        let out = sim.step(&input);
        let notes = device.notes();
        if let Some(r) = recording.as_ref() {
            for text in &notes {
                r.note(out.tick, text);
            }
            if let Some(g) = device.device_force() {
                r.device_force(DeviceForceRecord {
                    tick: out.tick,
                    sent_n: g.sent_n.to_array(),
                    guard: guard_flags(&g.limits),
                });
            }
        }
        for text in happenings(&sim, &input, &out, last.as_ref()).into_iter().chain(notes) {
            let line = ConsoleLine {
                tick: out.tick,
                time_s: out.time_s,
                text,
            };
            if let Err(TrySendError::Full(_)) = console.try_send(line) {
                shared.dropped_console_lines.fetch_add(1, Ordering::Relaxed);
            }
        }
        if let Some(r) = recording.as_mut() {
            r.tick(&input, &out, &sim);
        }
        if out.tick.is_multiple_of(publish_every) {
            publish(shared, snapshot_of(&sim, &input, &out, labels, &mut contrast));
        }
        stats.ticks.fetch_add(1, Ordering::Relaxed);
        if let Some(p) = pacer.as_mut() {
            let timing = p.done(tick);
            if !timing.late.is_zero() {
                stats.missed.fetch_add(1, Ordering::Relaxed);
                stats
                    .worst_late_ns
                    .fetch_max(timing.late.as_nanos() as u64, Ordering::Relaxed);
                stats
                    .skipped_periods
                    .fetch_add(timing.skipped_periods, Ordering::Relaxed);
                window_missed += 1;
                window_worst = window_worst.max(timing.late);
            }
            if (tick + 1).is_multiple_of(u64::from(rate)) && window_missed > 0 {
                if let Some(r) = recording.as_ref() {
                    r.note(
                        tick,
                        &format!(
                            "haptic loop: {window_missed} of the last {rate} ticks missed their deadline (worst {:.2} ms late)",
                            window_worst.as_secs_f64() * 1e3
                        ),
                    );
                }
                (window_missed, window_worst) = (0, Duration::ZERO);
            }
        }
        last = Some(out);
        last_input = Some(input);
    };
    let wall = started.elapsed();
    // The final state is always published (the loop no longer races anyone for it), so the
    // window shows where the session ended, not up to 15 ticks before.
    if let (Some(out), Some(input)) = (last.as_ref(), last_input.as_ref()) {
        let last = snapshot_of(&sim, input, out, labels, &mut contrast);
        if let Ok(mut slot) = shared.snapshot.lock() {
            *slot = Some(last);
        }
    }
    let view = stats.view();
    if let (Some(r), true) = (recording.as_ref(), options.paced) {
        r.note(
            sim.tick(),
            &format!(
                "haptic loop: {} ticks in {:.3} s, {} missed their deadline (worst {:.2} ms late), {} periods skipped",
                view.ticks,
                wall.as_secs_f64(),
                view.missed,
                view.worst_late.as_secs_f64() * 1e3,
                view.skipped_periods
            ),
        );
    }
    LoopReport {
        ended,
        stats: view,
        wall,
        recording: recording.map(Recording::finish),
        final_tick: sim.tick(),
        final_digest: sim.state_digest(),
    }
}

/// The force guard's decisions as the session stores them.
fn guard_flags(l: &stylet_devices::haptic::Limits) -> u8 {
    use stylet_recorder::device_forces::guard;
    [
        (l.held, guard::HELD),
        (l.watchdog, guard::WATCHDOG),
        (l.waiting, guard::WAITING),
        (l.not_finite, guard::NOT_FINITE),
        (l.ramping, guard::RAMPING),
        (l.clamped, guard::CLAMPED),
        (l.continuous, guard::CONTINUOUS),
    ]
    .into_iter()
    .filter(|(on, _)| *on)
    .fold(0, |bits, (_, bit)| bits | bit)
}

/// What a tick did that a trainee or instructor wants to read: the device's events and the tip
/// entering another structure.
fn happenings(sim: &Simulation, input: &TickInput, out: &TickOutput, last: Option<&TickOutput>) -> Vec<String> {
    let mut lines: Vec<String> = input.events.iter().map(event_text).collect();
    let entered = out.inserted_mm > 0.0 && last.is_none_or(|l| l.tip_label != out.tip_label || l.inserted_mm <= 0.0);
    if entered {
        lines.push(format!("needle tip in {}", label_name(sim, out.tip_label)));
    }
    lines
}

/// An event in words.
pub fn event_text(e: &Event) -> String {
    match e {
        Event::SelectTool(t) => format!("tool: {}", t.name()),
        Event::SecondTool(Some(t)) => format!("second hand: {}", t.tool_spec().name()),
        Event::SecondTool(None) => "second hand: empty".into(),
        Event::StyletRemove => "stylet out".into(),
        Event::StyletInsert => "stylet in".into(),
        Event::XrayOn => "fluoroscopy on".into(),
        Event::XrayOff => "fluoroscopy off".into(),
        Event::ContrastInject { ml } => format!("contrast injected: {ml} ml"),
        Event::BreathHold => "breath hold".into(),
        Event::BreathRelease => "breathing again".into(),
        Event::WireIn { diameter, tip } => format!("guide wire in: {}\" {}", diameter.name(), tip.name()),
        Event::NeedleOut => "needle out over the wire".into(),
        Event::WireOut => "guide wire out".into(),
        Event::DilatorIn { size_fr } => format!("dilator in: {size_fr} F"),
        Event::DilatorOut => "dilator out".into(),
        Event::CatheterIn { size_fr } => format!("drainage catheter in: {size_fr} F"),
    }
}

/// A label's name in the atlas' table ("unnamed structure" if the table does not know it).
pub fn label_name(sim: &Simulation, id: LabelId) -> String {
    sim.atlas().label_table().name_of(id).to_string()
}

/// The contrast overlay of the latest publication, rebuilt only when the contrast changed and
/// shared, not copied, by the publications in between.
#[derive(Default)]
struct ContrastCache {
    key: Option<[u64; 3]>,
    overlay: Option<Arc<ContrastOverlay>>,
}

impl ContrastCache {
    fn get(&mut self, sim: &Simulation, out: &TickOutput) -> Option<Arc<ContrastOverlay>> {
        let key = [
            out.contrast_in_ducts_ml.to_bits(),
            out.extravasated_ml.to_bits(),
            out.contrast_extent_mm.to_bits(),
        ];
        if self.key != Some(key) {
            let dims = sim.atlas().ct().grid().dims();
            self.overlay = ContrastOverlay::from_agent(sim.contrast(), dims, DEFAULT_IODINE_MG_PER_ML).map(Arc::new);
            self.key = Some(key);
        }
        self.overlay.clone()
    }
}

/// The state after the tick that turned `input` into `out`, as the views draw it.
fn snapshot_of(
    sim: &Simulation,
    input: &TickInput,
    out: &TickOutput,
    labels: &SessionLabels,
    contrast: &mut ContrastCache,
) -> Snapshot {
    Snapshot {
        position_mm: input.position_mm,
        orientation: input.orientation,
        output: *out,
        moment: Moment::with_contrast(sim, input, out, labels, contrast.get(sim, out)),
        tool: *sim.tool_spec(),
        second_tool: sim.second_hand().and_then(|h| h.tool_spec()),
    }
}

/// Publishes the state after a tick unless a view is reading the previous one. The snapshot is
/// built before the lock is tried, so a view never waits for the building either.
fn publish(shared: &Shared, snapshot: Snapshot) {
    match shared.snapshot.try_lock() {
        Ok(mut slot) => *slot = Some(snapshot),
        Err(_) => {
            shared.stats.skipped_publications.fetch_add(1, Ordering::Relaxed);
        }
    }
}
