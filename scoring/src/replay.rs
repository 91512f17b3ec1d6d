//! Deterministic replay (docs/metrics.md "Replay verification"): re-run a session's recorded device
//! inputs and events through `stylet_physics::Simulation` — the same code the simulator ran — and
//! check every recomputed output and state digest against the recorded ones, bit for bit.

use std::borrow::Borrow;
use std::collections::BTreeMap;
use std::sync::Arc;

use stylet_physics::glam::{DQuat, DVec3};
use stylet_physics::{DeviceProfile, Event, PunctureAtlas, SimConfig, SimError, Simulation, TickInput, TickOutput};
use stylet_recorder::format::{EventError, TickRecord};
use stylet_recorder::outputs::{OutputCheck, OutputDigest, rounded_outputs};
use stylet_recorder::reader::Session;

/// Where a replay first differs from the recording.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Divergence {
    pub tick: u64,
    /// `ticks.force_n`, `ticks.torque_nmm`, `ticks.tip_label`, `ticks.inserted_mm`,
    /// `ticks.outputs_digest` (the exact outputs of a block with rounded ones, at its last tick),
    /// `digests` or `ticks` (a gap in the recorded ticks).
    pub stream: String,
    pub recorded: String,
    pub replayed: String,
}

/// The outcome of a replay.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ReplayReport {
    /// Every recorded output and digest was reproduced bit for bit.
    pub replay_verified: bool,
    pub divergence: Option<Divergence>,
    /// Ticks replayed.
    pub ticks: u64,
    /// Digests compared.
    pub digests_checked: u64,
}

/// Why a session cannot be replayed at all.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ReplayError {
    #[error(
        "the session was recorded with physics version {recorded}; this build is version {this} and does not re-grade it"
    )]
    PhysicsVersion { recorded: u32, this: u32 },
    #[error("the session's device profile '{0}' is unknown")]
    UnknownDevice(String),
    #[error("the session has an unreadable event at tick {tick}: {source}")]
    BadEvent {
        tick: u64,
        #[source]
        source: EventError,
    },
    #[error("the simulation cannot start: {0}")]
    Simulation(#[source] SimError),
}

/// The device input of a recorded tick (pose and buttons exactly as recorded, plus its events).
pub fn tick_input(t: &TickRecord, events: Vec<Event>) -> TickInput {
    let [w, x, y, z] = t.orientation;
    TickInput {
        position_mm: DVec3::from_array(t.position_mm),
        orientation: DQuat::from_xyzw(x, y, z, w),
        buttons: t.buttons,
        events,
    }
}

fn bits3(v: &[f64; 3]) -> [u64; 3] {
    v.map(f64::to_bits)
}

/// The first recorded output of `t` that `o` does not reproduce; `rounded`: the file holds `t`'s
/// force and torque rounded ([`stylet_recorder::outputs`]), so `o`'s are rounded the same way
/// before the comparison (their exact bits are checked by the block's digest).
fn compare(t: &TickRecord, o: &TickOutput, rounded: bool) -> Option<Divergence> {
    let d = |stream: &str, recorded: String, replayed: String| {
        Some(Divergence {
            tick: t.tick,
            stream: stream.into(),
            recorded,
            replayed,
        })
    };
    let (mut f, mut m) = (o.force_n.to_array(), o.torque_nmm.to_array());
    if rounded {
        match rounded_outputs(f, m) {
            Some((rf, rm)) => (f, m) = (rf, rm),
            None => {
                return d(
                    "ticks.force_n",
                    format!("{:?} (rounded)", t.force_n),
                    format!("{f:?} (cannot be rounded)"),
                );
            }
        }
    }
    if bits3(&t.force_n) != bits3(&f) {
        return d("ticks.force_n", format!("{:?}", t.force_n), format!("{f:?}"));
    }
    if bits3(&t.torque_nmm) != bits3(&m) {
        return d("ticks.torque_nmm", format!("{:?}", t.torque_nmm), format!("{m:?}"));
    }
    if t.tip_label != o.tip_label {
        return d("ticks.tip_label", t.tip_label.to_string(), o.tip_label.to_string());
    }
    if t.inserted_mm.to_bits() != o.inserted_mm.to_bits() {
        return d(
            "ticks.inserted_mm",
            format!("{:?}", t.inserted_mm),
            format!("{:?}", o.inserted_mm),
        );
    }
    None
}

/// Replays `session` on `atlas`, calling `observe` after every tick with the input, the replayed
/// output and the simulation (for metrics). Outputs are the replayed ones, so metrics always
/// come from physics, never from what the file claims.
pub fn replay(
    session: &Session,
    atlas: Arc<PunctureAtlas>,
    observe: &mut dyn FnMut(&TickInput, &TickOutput, &Simulation),
) -> Result<ReplayReport, ReplayError> {
    let mut r = Replayer::new(session, atlas)?;
    while let Some((input, out)) = r.step() {
        observe(&input, &out, r.simulation());
    }
    Ok(r.report())
}

/// A replay one tick at a time (the scorer runs it to the end; the replay viewer steps and
/// seeks through it). Each step feeds the recorded pose, buttons and events of the next tick to
/// `Simulation::step` and checks the outputs and digests against the recording.
///
/// A clone (with a shared session, `S = Arc<Session>`) is a snapshot: it copies the simulation
/// and shares the recording, and replaying on from it gives the same ticks, bit for bit, as
/// replaying on from the original (the dashboard's player seeks from such snapshots).
#[derive(Clone)]
pub struct Replayer<S: Borrow<Session>> {
    session: S,
    sim: Simulation,
    /// Events and digests by tick, in tick order, consumed as the ticks pass.
    events: Arc<[(u64, Vec<Event>)]>,
    next_event: usize,
    digests: Arc<[(u64, u64)]>,
    next_digest: usize,
    /// The blocks with rounded outputs, in tick order, and the digest of the exact outputs
    /// replayed so far in the current one.
    output_checks: Arc<[OutputCheck]>,
    next_check: usize,
    outputs: OutputDigest,
    /// Index of the next recorded tick.
    next: usize,
    /// A gap in the recorded ticks ended the replay.
    gap: bool,
    divergence: Option<Divergence>,
    ticks: u64,
    digests_checked: u64,
}

impl<S: Borrow<Session>> Replayer<S> {
    /// Checks that the session can be replayed by this build and starts its simulation.
    pub fn new(session: S, atlas: Arc<PunctureAtlas>) -> Result<Self, ReplayError> {
        let h = &session.borrow().header;
        if h.physics_version != stylet_physics::PHYSICS_VERSION {
            return Err(ReplayError::PhysicsVersion {
                recorded: h.physics_version,
                this: stylet_physics::PHYSICS_VERSION,
            });
        }
        let device = DeviceProfile::by_name(&h.device).ok_or_else(|| ReplayError::UnknownDevice(h.device.clone()))?;
        let mut config = SimConfig::new(device, h.initial_tool);
        config.tick_rate_hz = h.tick_rate_hz;
        config.deformation = h.deformation;
        config.contrast = h.contrast;
        config.breathing = h.breathing;
        let sim = Simulation::new(atlas, config).map_err(ReplayError::Simulation)?;
        let mut events: BTreeMap<u64, Vec<Event>> = BTreeMap::new();
        for e in &session.borrow().events {
            let ev = e
                .to_event()
                .map_err(|source| ReplayError::BadEvent { tick: e.tick, source })?;
            events.entry(e.tick).or_default().push(ev);
        }
        let digests: BTreeMap<u64, u64> = session.borrow().digests.iter().map(|d| (d.tick, d.digest)).collect();
        let output_checks = session.borrow().output_checks.iter().copied().collect();
        Ok(Replayer {
            session,
            sim,
            events: events.into_iter().collect(),
            next_event: 0,
            digests: digests.into_iter().collect(),
            next_digest: 0,
            output_checks,
            next_check: 0,
            outputs: OutputDigest::default(),
            next: 0,
            gap: false,
            divergence: None,
            ticks: 0,
            digests_checked: 0,
        })
    }

    /// Replays the next recorded tick: its input and the replayed output; `None` at the end of
    /// the recording or at a gap in it (the state after a gap cannot be reproduced).
    pub fn step(&mut self) -> Option<(TickInput, TickOutput)> {
        if self.gap {
            return None;
        }
        let t = *self.session.borrow().ticks.get(self.next)?;
        if t.tick != self.sim.tick() {
            self.divergence.get_or_insert(Divergence {
                tick: self.sim.tick(),
                stream: "ticks".into(),
                recorded: format!("next recorded tick {}", t.tick),
                replayed: format!("tick {}", self.sim.tick()),
            });
            self.gap = true;
            return None;
        }
        while self.events.get(self.next_event).is_some_and(|(tick, _)| *tick < t.tick) {
            self.next_event += 1;
        }
        let events = match self.events.get(self.next_event) {
            Some((tick, e)) if *tick == t.tick => {
                self.next_event += 1;
                e.clone()
            }
            _ => Vec::new(),
        };
        let input = tick_input(&t, events);
        let out = self.sim.step(&input);
        self.ticks += 1;
        let rounded = self.check_outputs(t.tick, &out);
        if self.divergence.is_none() {
            self.divergence = compare(&t, &out, rounded);
        }
        while self
            .digests
            .get(self.next_digest)
            .is_some_and(|(tick, _)| *tick < t.tick)
        {
            self.next_digest += 1;
        }
        if let Some(&(tick, recorded)) = self.digests.get(self.next_digest)
            && tick == t.tick
        {
            self.next_digest += 1;
            self.digests_checked += 1;
            let replayed = self.sim.state_digest();
            if recorded != replayed && self.divergence.is_none() {
                self.divergence = Some(Divergence {
                    tick: t.tick,
                    stream: "digests".into(),
                    recorded: format!("{recorded:016x}"),
                    replayed: format!("{replayed:016x}"),
                });
            }
        }
        self.next += 1;
        Some((input, out))
    }

    /// Adds `out` to the digest of its block when the file rounded the outputs of `tick` (and
    /// says so), checking the digest at the block's last tick.
    fn check_outputs(&mut self, tick: u64, out: &TickOutput) -> bool {
        while self
            .output_checks
            .get(self.next_check)
            .is_some_and(|c| c.last_tick() < tick)
        {
            self.next_check += 1;
        }
        let Some(&check) = self.output_checks.get(self.next_check) else {
            return false;
        };
        if !check.covers(tick) {
            return false;
        }
        if tick == check.first_tick {
            self.outputs = OutputDigest::default();
        }
        self.outputs.add(out.force_n.to_array(), out.torque_nmm.to_array());
        if tick == check.last_tick() {
            let replayed = self.outputs.value();
            if replayed != check.digest && self.divergence.is_none() {
                self.divergence = Some(Divergence {
                    tick,
                    stream: "ticks.outputs_digest".into(),
                    recorded: format!("{:016x} (ticks {}–{tick})", check.digest, check.first_tick),
                    replayed: format!("{replayed:016x}"),
                });
            }
            self.next_check += 1;
        }
        true
    }

    /// The simulation after the last replayed tick.
    pub fn simulation(&self) -> &Simulation {
        &self.sim
    }

    pub fn session(&self) -> &Session {
        self.session.borrow()
    }

    /// The recorded tick the next [`Self::step`] replays (`None` at the end of the recording or
    /// after a gap).
    pub fn next_tick(&self) -> Option<u64> {
        if self.gap {
            return None;
        }
        self.session.borrow().ticks.get(self.next).map(|t| t.tick)
    }

    /// Ticks replayed so far.
    pub fn ticks(&self) -> u64 {
        self.ticks
    }

    /// The check so far (at the end of the recording: of the whole session).
    pub fn report(&self) -> ReplayReport {
        ReplayReport {
            replay_verified: self.divergence.is_none(),
            divergence: self.divergence.clone(),
            ticks: self.ticks,
            digests_checked: self.digests_checked,
        }
    }
}
