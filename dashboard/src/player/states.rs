//! Replay states for the player: a session replayed once through the scorer's physics
//! (`stylet_scoring::Replayer`), keeping snapshots along the way, so that a frame at any tick
//! replays only from the nearest snapshot before it, not from the start (as in scoring,
//! docs/metrics.md: what the player shows is computed from the recorded inputs, never read from
//! the file).
//!
//! A snapshot is a clone of the replayer: the simulation's state, the recording shared. Stepping
//! on from it gives the same ticks, bit for bit, as stepping on from the start.

use std::sync::Arc;

use stylet_physics::PunctureAtlas;
use stylet_recorder::reader::Session;
use stylet_render::views::{Moment, SessionLabels};
use stylet_scoring::{ReplayError, Replayer, UnknownDifficulty};

/// Why a session cannot be replayed for the player: its header names no difficulty level (its
/// views' aids), or the replay refuses it.
#[derive(Debug, thiserror::Error)]
pub enum StatesError {
    #[error(transparent)]
    Difficulty(#[from] UnknownDifficulty),
    #[error(transparent)]
    Replay(#[from] ReplayError),
}

/// Most snapshots kept of one session: their spacing grows with the session's length (ten minutes
/// at 1 kHz: one every 9 375 ticks, about 10 ms to replay).
pub const MAX_SNAPSHOTS: u64 = 64;
/// Fewest recorded ticks between two snapshots (0.5 s at 1 kHz: replaying that is a few ms).
pub const MIN_SPACING_TICKS: u64 = 500;

/// One session's snapshots.
pub struct ReplayStates {
    labels: SessionLabels,
    /// (the recorded tick the snapshot replays next, the snapshot), in tick order.
    snapshots: Vec<(u64, Replayer<Arc<Session>>)>,
    /// The first and last ticks that can be shown (the replay stops at a gap in the recording).
    pub first_tick: u64,
    pub last_tick: u64,
    pub tick_rate_hz: u32,
}

impl ReplayStates {
    /// Replays the whole session once, keeping a snapshot every `max(MIN_SPACING_TICKS,
    /// ticks / MAX_SNAPSHOTS)` ticks. `None` when the session has no tick to show.
    pub fn build(session: Session, atlas: Arc<PunctureAtlas>) -> Result<Option<ReplayStates>, StatesError> {
        let h = &session.header;
        let labels = SessionLabels {
            scenario: h.scenario.clone(),
            difficulty: h.difficulty.parse()?,
            seed: h.seed,
        };
        let tick_rate_hz = h.tick_rate_hz;
        let spacing = MIN_SPACING_TICKS.max((session.ticks.len() as u64).div_ceil(MAX_SNAPSHOTS));
        let mut replayer = Replayer::new(Arc::new(session), atlas)?;
        let mut snapshots = Vec::new();
        let (mut first, mut last) = (None, None);
        loop {
            if replayer.ticks() % spacing == 0
                && let Some(next) = replayer.next_tick()
            {
                snapshots.push((next, replayer.clone()));
            }
            let Some((_, out)) = replayer.step() else { break };
            first.get_or_insert(out.tick);
            last = Some(out.tick);
        }
        Ok(first.zip(last).map(|(first_tick, last_tick)| ReplayStates {
            labels,
            snapshots,
            first_tick,
            last_tick,
            tick_rate_hz,
        }))
    }

    /// The session's state after `tick`, replayed from the nearest snapshot before it; `None`
    /// for a tick the recording does not hold.
    pub fn moment_at(&self, tick: u64) -> Option<Moment> {
        let i = self.snapshots.partition_point(|(next, _)| *next <= tick);
        let mut replayer = self.snapshots.get(i.checked_sub(1)?)?.1.clone();
        let (input, out) = replayer.step_to(tick).ok()?;
        Some(Moment::of_simulation(replayer.simulation(), &input, &out, &self.labels))
    }

    /// Snapshots kept.
    pub fn snapshots(&self) -> usize {
        self.snapshots.len()
    }
}
