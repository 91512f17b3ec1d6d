//! Deterministic replay (docs/metrics.md "Replay verification"): re-run a session's recorded device
//! inputs and events through `stylet_physics::Simulation` — the same code the simulator ran — and
//! check every recomputed output and state digest against the recorded ones, bit for bit.

use std::borrow::Borrow;
use std::collections::BTreeMap;
use std::sync::Arc;

use stylet_physics::glam::{DQuat, DVec3};
use stylet_physics::{
    DeviceProfile, Event, HandPose, PunctureAtlas, SecondHandConfig, SimConfig, SimError, Simulation, TickInput,
    TickOutput,
};
use stylet_recorder::format::{EventError, TickRecord};
use stylet_recorder::outputs::{OutputCheck, OutputDigest, rounded_outputs};
use stylet_recorder::reader::Session;

/// Where a replay first differs from the recording.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Divergence {
    pub tick: u64,
    /// `ticks.force_n`, `ticks.torque_nmm`, `ticks.tip_label`, `ticks.inserted_mm`,
    /// `ticks.second_hand` (the second hand's force and torque, or whether it is there),
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

/// Why [`Replayer::step_to`] cannot replay to a tick. The replayer is left where it was.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum StepToError {
    /// The tick was replayed already: a replay only goes forward (to go back, start again or
    /// step on from an earlier clone).
    #[error("tick {tick} has been replayed already; the replay is at tick {next}")]
    Passed { tick: u64, next: u64 },
    /// The recording ends before the tick: it holds the ticks before `end`.
    #[error("tick {tick} is beyond the recording, which ends before tick {end}")]
    Beyond { tick: u64, end: u64 },
    /// The recorded ticks have a gap at `at` (ticks dropped while recording), before the tick: the
    /// state after the gap cannot be reproduced, so the replay reaches the ticks before `at` only.
    #[error("the recording has a gap at tick {at}, before tick {tick}")]
    Gap { tick: u64, at: u64 },
}

/// The device input of a recorded tick (pose and buttons exactly as recorded, plus its events).
pub fn tick_input(t: &TickRecord, events: Vec<Event>) -> TickInput {
    let [w, x, y, z] = t.orientation;
    TickInput {
        position_mm: DVec3::from_array(t.position_mm),
        orientation: DQuat::from_xyzw(x, y, z, w),
        buttons: t.buttons,
        events,
        second_hand: t.second_hand.map(|h| {
            let [w, x, y, z] = h.orientation;
            HandPose {
                position_mm: DVec3::from_array(h.position_mm),
                orientation: DQuat::from_xyzw(x, y, z, w),
                buttons: h.buttons,
            }
        }),
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
    // The second hand's outputs are stored exactly.
    let recorded = t.second_hand.map(|h| (bits3(&h.force_n), bits3(&h.torque_nmm)));
    let replayed = o
        .second_hand
        .map(|h| (bits3(&h.force_n.to_array()), bits3(&h.torque_nmm.to_array())));
    if recorded != replayed {
        let show = |h: Option<([u64; 3], [u64; 3])>| match h {
            Some((f, m)) => format!("{:?} N, {:?} N·mm", f.map(f64::from_bits), m.map(f64::from_bits)),
            None => "no second hand".to_string(),
        };
        return d("ticks.second_hand", show(recorded), show(replayed));
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

/// A replay one tick at a time (the scorer runs it to the end; `stylet render --at`, the
/// dashboard's player and the simulator's replay viewer replay it to a moment with
/// [`Replayer::step_to`]). Each step feeds the recorded pose, buttons and events of the next tick to
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
        if let Some(second) = &h.second_hand {
            config.second_hand = Some(SecondHandConfig {
                device: DeviceProfile::by_name(&second.device)
                    .ok_or_else(|| ReplayError::UnknownDevice(second.device.clone()))?,
                tool: second.initial_tool,
            });
        }
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

    /// Replays on until `tick` has been replayed and returns its step (input and replayed output),
    /// the same bits as stepping there one tick at a time. When the replay cannot get there (a
    /// tick replayed already, beyond the recording or after a gap in it) it replays nothing and
    /// says why.
    pub fn step_to(&mut self, tick: u64) -> Result<(TickInput, TickOutput), StepToError> {
        self.reaches(tick)?;
        while let Some(step) = self.step() {
            if step.1.tick == tick {
                return Ok(step);
            }
        }
        // Not reached: `reaches` found the recorded ticks up to `tick` following one another.
        Err(StepToError::Gap {
            tick,
            at: self.sim.tick(),
        })
    }

    /// Whether stepping on reaches `tick`: the recorded ticks from the next one to `tick` follow
    /// one another from the simulation's tick, as [`Self::step`] requires.
    fn reaches(&self, tick: u64) -> Result<(), StepToError> {
        let next = self.sim.tick();
        if tick < next {
            return Err(StepToError::Passed { tick, next });
        }
        let mut expected = next;
        for t in self.session.borrow().ticks.iter().skip(self.next) {
            if expected > tick {
                return Ok(());
            }
            if t.tick != expected {
                return Err(StepToError::Gap { tick, at: expected });
            }
            expected += 1;
        }
        if expected > tick {
            Ok(())
        } else {
            Err(StepToError::Beyond { tick, end: expected })
        }
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

#[cfg(test)]
mod tests {
    use super::*;
    use stylet_devices::script::{parse, scripted_simulation};
    use stylet_recorder::{Recording, SessionInfo, WriterOptions};

    /// A 3-second needle session with an event, recorded on a coarse phantom and read back.
    fn recorded() -> (Session, Arc<PunctureAtlas>) {
        let dir = tempfile::tempdir().unwrap();
        let p = stylet_atlas::phantom::generate(&stylet_atlas::phantom::PhantomConfig {
            dims: [64, 64, 50],
            spacing_mm: [6.0; 3],
            ..Default::default()
        })
        .unwrap();
        stylet_atlas::write(&dir.path().join("atlas"), &p.manifest, &p.ct, &p.partial).unwrap();
        let atlas = stylet_atlas::load(&dir.path().join("atlas")).unwrap();
        let script = parse(
            "stylet-script 1\ndevice premium\ntool needle gauge 18 length 150 stylet in\nend 3\n\
             at 0 along intercostal-10-11 -15\nat 2 along intercostal-10-11 40\nat 2.5 event stylet-remove\n",
        )
        .unwrap();
        let (mut sim, mut device) =
            scripted_simulation(Arc::clone(&atlas.model), &atlas.planned_paths(), &script).unwrap();
        let info = SessionInfo {
            trainee: "t",
            scenario: "step-to",
            difficulty: "beginner",
            seed: 0,
            atlas_id: &atlas.manifest.name,
            atlas_hash: &atlas.content_hash,
        };
        let path = dir.path().join("session.mcap");
        let header = stylet_recorder::recording::header(&sim, &info);
        let options = WriterOptions {
            fsync: false,
            ..Default::default()
        };
        let mut rec = Recording::start(&path, &header, false, options).unwrap();
        stylet_devices::run_headless(&mut sim, &mut device, |i, o, s| rec.tick(i, o, s));
        rec.finish().unwrap();
        (stylet_recorder::reader::read(&path).unwrap(), Arc::clone(&atlas.model))
    }

    /// What a step leaves: its input, its output and the simulation's state digest, as bits.
    fn bits(step: &(TickInput, TickOutput), sim: &Simulation) -> String {
        format!("{:?} {:?} {:016x}", step.0, step.1, sim.state_digest())
    }

    #[test]
    fn stepping_to_a_tick_gives_the_bits_of_stepping_there_one_tick_at_a_time() {
        let (session, atlas) = recorded();
        let last = session.ticks.last().unwrap().tick;
        assert_eq!(last, 2999);
        assert!(!session.events.is_empty() && !session.digests.is_empty());
        let wanted = [0, 1, 999, 1000, 2500, last];
        let mut straight = Replayer::new(&session, Arc::clone(&atlas)).unwrap();
        let mut expected = Vec::new();
        while let Some(step) = straight.step() {
            if wanted.contains(&step.1.tick) {
                expected.push(bits(&step, straight.simulation()));
            }
        }
        assert!(straight.report().replay_verified);

        let mut r = Replayer::new(&session, Arc::clone(&atlas)).unwrap();
        let mut snapshot = None;
        for (&tick, expected) in wanted.iter().zip(&expected) {
            let step = r.step_to(tick).unwrap();
            assert_eq!(&bits(&step, r.simulation()), expected, "tick {tick}");
            if tick == 999 {
                snapshot = Some(r.clone());
            }
        }
        assert_eq!(r.report(), straight.report());

        // On from a clone: the same bits as on from the original.
        let mut snapshot = snapshot.unwrap();
        let step = snapshot.step_to(2500).unwrap();
        assert_eq!(bits(&step, snapshot.simulation()), expected[4]);
    }

    #[test]
    fn a_tick_the_replay_cannot_reach_is_a_typed_error_and_replays_nothing() {
        let (mut session, atlas) = recorded();
        let mut r = Replayer::new(&session, Arc::clone(&atlas)).unwrap();
        assert_eq!(r.step_to(3000), Err(StepToError::Beyond { tick: 3000, end: 3000 }));
        assert_eq!(r.ticks(), 0);
        let ten = r.step_to(10).unwrap();
        assert_eq!(r.step_to(5), Err(StepToError::Passed { tick: 5, next: 11 }));
        assert_eq!(r.step_to(10), Err(StepToError::Passed { tick: 10, next: 11 }));
        assert_eq!(r.ticks(), 11);
        let mut straight = Replayer::new(&session, Arc::clone(&atlas)).unwrap();
        let mut at_ten = None;
        while let Some(step) = straight.step() {
            if step.1.tick == 10 {
                at_ten = Some(bits(&step, straight.simulation()));
                break;
            }
        }
        assert_eq!(Some(bits(&ten, r.simulation())), at_ten);

        // Ticks 1500 … 1599 dropped while recording.
        session.ticks.retain(|t| !(1500..1600).contains(&t.tick));
        let session = Arc::new(session);
        let mut r = Replayer::new(Arc::clone(&session), Arc::clone(&atlas)).unwrap();
        for tick in [1550, 1600, 2999, 3000] {
            assert_eq!(r.step_to(tick), Err(StepToError::Gap { tick, at: 1500 }), "tick {tick}");
            assert_eq!(r.ticks(), 0);
        }
        assert_eq!(r.step_to(1499).unwrap().1.tick, 1499);
        assert_eq!(r.step_to(1600), Err(StepToError::Gap { tick: 1600, at: 1500 }));
        assert_eq!(r.ticks(), 1500);
        assert!(r.report().replay_verified);
        // Stepping on finds the gap, as the scorer's replay does.
        assert!(r.step().is_none());
        assert_eq!(
            r.report().divergence.map(|d| (d.tick, d.stream)),
            Some((1500, "ticks".into()))
        );
        assert_eq!(r.step_to(1600), Err(StepToError::Gap { tick: 1600, at: 1500 }));
    }
}
