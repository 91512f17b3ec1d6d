//! The replay viewer's cursor: a session file replayed through the same physics as the scorer
//! (`stylet_scoring::Replayer`), stepped forward as it plays and replayed again from the start
//! when the viewer seeks backward. What the views show at a tick is computed from the recorded
//! inputs, never read from the file (as in scoring, docs/metrics.md).

use std::path::Path;
use std::sync::Arc;

use stylet_atlas::Atlas;
use stylet_physics::{PunctureAtlas, TickInput, TickOutput};
use stylet_recorder::reader::Session;
use stylet_render::views::{Moment, SessionLabels};
use stylet_scoring::{ReplayError, Replayer, ReviewTrace, Rubric, ScoreReport, Scorer, StepToError};

/// Why a session cannot be opened in the viewer.
#[derive(Debug, thiserror::Error)]
pub enum OpenError {
    #[error("cannot read {path}: {reason}")]
    Unreadable {
        path: String,
        #[source]
        reason: stylet_recorder::ReadError,
    },
    /// No scorer could be built for the atlas.
    #[error("cannot score the session: {0}")]
    Scorer(#[source] stylet_scoring::ScorerError),
    #[error("cannot score the session: {0}")]
    Score(#[source] stylet_scoring::ScoreError),
    #[error(transparent)]
    Replay(#[from] ReplayError),
}

pub use stylet_scoring::trace::MomentKind;

/// A moment worth jumping to.
#[derive(Debug, Clone, PartialEq)]
pub struct KeyMoment {
    pub kind: MomentKind,
    /// The cursor position (ticks replayed) that shows it.
    pub ticks: u64,
    pub time_s: f64,
    pub label: String,
}

/// A session replayed for viewing.
pub struct ReplayCursor {
    model: Arc<PunctureAtlas>,
    session: Arc<Session>,
    replayer: Replayer<Arc<Session>>,
    last: Option<(TickInput, TickOutput)>,
    labels: SessionLabels,
    report: ScoreReport,
    trace: ReviewTrace,
    key_moments: Vec<KeyMoment>,
    /// The furthest the replay can go: the recording's end, or a gap in it (ticks dropped while
    /// recording: the state after it cannot be reproduced).
    end: u64,
}

impl ReplayCursor {
    /// Reads a session file (a cut file: its intact part), scores it with the default rubric
    /// (the trace gives the force chart and the key moments) and stands at its start.
    pub fn open(atlas: &Atlas, path: &Path) -> Result<ReplayCursor, OpenError> {
        let session = stylet_recorder::reader::recover(path).map_err(|reason| OpenError::Unreadable {
            path: path.display().to_string(),
            reason,
        })?;
        ReplayCursor::of_session(atlas, Arc::new(session))
    }

    pub fn of_session(atlas: &Atlas, session: Arc<Session>) -> Result<ReplayCursor, OpenError> {
        let scorer = Scorer::new(atlas, Rubric::default_rubric(), None).map_err(OpenError::Scorer)?;
        let (report, trace) = scorer.score_session_traced(&session).map_err(OpenError::Score)?;
        let model = Arc::clone(scorer.atlas());
        let h = &session.header;
        let labels = SessionLabels {
            scenario: h.scenario.clone(),
            difficulty: report.grade.difficulty,
            seed: h.seed,
        };
        let key_moments = key_moments(&trace, f64::from(h.tick_rate_hz), session.ticks.len() as u64);
        let replayer = Replayer::new(Arc::clone(&session), Arc::clone(&model))?;
        let end = session.ticks.len() as u64;
        Ok(ReplayCursor {
            end,
            model,
            session,
            replayer,
            last: None,
            labels,
            report,
            trace,
            key_moments,
        })
    }

    /// Ticks replayed so far (the cursor's position).
    pub fn position(&self) -> u64 {
        self.replayer.ticks()
    }

    /// Recorded ticks in the file.
    pub fn total(&self) -> u64 {
        self.session.ticks.len() as u64
    }

    /// The furthest position the replay reaches (before a gap in the recording, else its end).
    pub fn end(&self) -> u64 {
        self.end
    }

    pub fn tick_rate_hz(&self) -> u32 {
        self.session.header.tick_rate_hz
    }

    pub fn session(&self) -> &Session {
        &self.session
    }

    /// The score of the whole session (the same as `stylet score` gives).
    pub fn report(&self) -> &ScoreReport {
        &self.report
    }

    pub fn trace(&self) -> &ReviewTrace {
        &self.trace
    }

    pub fn key_moments(&self) -> &[KeyMoment] {
        &self.key_moments
    }

    /// The last replayed tick's input and output.
    pub fn last(&self) -> Option<&(TickInput, TickOutput)> {
        self.last.as_ref()
    }

    /// `Simulation::state_digest` at the cursor.
    pub fn state_digest(&self) -> u64 {
        self.replayer.simulation().state_digest()
    }

    /// Moves toward `target` ticks replayed, at most `budget` ticks of stepping; true when the
    /// cursor is there (or at the end of the recording). Backward: replays from the start.
    pub fn seek(&mut self, target: u64, budget: u64) -> Result<bool, ReplayError> {
        let target = target.min(self.end);
        if target < self.position() {
            self.replayer = Replayer::new(Arc::clone(&self.session), Arc::clone(&self.model))?;
            self.last = None;
        }
        let goal = target.min(self.position().saturating_add(budget));
        if goal <= self.position() {
            return Ok(self.position() >= target);
        }
        // Position n shows tick n − 1 (a replay starts at tick 0).
        match self.replayer.step_to(goal - 1) {
            Ok(step) => self.last = Some(step),
            // Goal − 1 is at or after the position: never behind the replay.
            Err(StepToError::Passed { .. }) => {}
            Err(StepToError::Gap { at: reach, .. } | StepToError::Beyond { end: reach, .. }) => {
                // The replay stops before the goal: it goes as far as it can, which is the end.
                if reach > self.position()
                    && let Ok(step) = self.replayer.step_to(reach - 1)
                {
                    self.last = Some(step);
                }
                self.end = self.position();
                return Ok(true);
            }
        }
        Ok(self.position() >= target)
    }

    /// The state at the cursor, as the views draw it (`None` before the first tick).
    pub fn moment(&self) -> Option<Moment> {
        let (input, out) = self.last.as_ref()?;
        Some(Moment::of_simulation(
            self.replayer.simulation(),
            input,
            out,
            &self.labels,
        ))
    }
}

/// The trace's key moments (`ReviewTrace::key_moments`) at their cursor positions.
fn key_moments(trace: &ReviewTrace, rate_hz: f64, total: u64) -> Vec<KeyMoment> {
    let at = |t_s: f64| (((t_s * rate_hz).round().max(0.0)) as u64 + 1).min(total);
    trace
        .key_moments()
        .into_iter()
        .map(|m| KeyMoment {
            kind: m.kind,
            ticks: at(m.t_s),
            time_s: m.t_s,
            label: m.label,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use stylet_devices::script::{parse, scripted_simulation};
    use stylet_recorder::{Recording, SessionInfo, WriterOptions};

    /// A coarse phantom and a 2-second needle session on it, ticks 1200 … 1299 dropped.
    fn gapped_session() -> (Atlas, Session) {
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
            "stylet-script 1\ndevice premium\ntool needle gauge 18 length 150 stylet in\nend 2\n\
             at 0 along intercostal-10-11 -15\nat 2 along intercostal-10-11 30\n",
        )
        .unwrap();
        let (mut sim, mut device) =
            scripted_simulation(Arc::clone(&atlas.model), &atlas.planned_paths(), &script).unwrap();
        let info = SessionInfo {
            trainee: "t",
            scenario: &atlas.manifest.scenarios[0].name,
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
        let mut session = stylet_recorder::reader::read(&path).unwrap();
        session.ticks.retain(|t| !(1200..1300).contains(&t.tick));
        (atlas, session)
    }

    /// The cursor steps at most the budget, goes back by replaying from the start, and finds the
    /// gap only when asked to go past it, stopping there; its state is the straight replay's.
    #[test]
    fn seeking_steps_within_the_budget_and_stops_at_a_gap() {
        let (atlas, session) = gapped_session();
        let mut straight = Replayer::new(&session, Arc::clone(&atlas.model)).unwrap();
        let digests: Vec<u64> =
            std::iter::from_fn(|| straight.step().map(|_| straight.simulation().state_digest())).collect();
        assert_eq!(digests.len(), 1200);
        let session = Arc::new(session);
        let mut c = ReplayCursor::of_session(&atlas, Arc::clone(&session)).unwrap();
        let at = |c: &ReplayCursor| (c.position(), c.end(), c.last().map(|(_, o)| o.tick), c.state_digest());

        assert_eq!(c.seek(1000, 500), Ok(false));
        assert_eq!(at(&c), (500, 1900, Some(499), digests[499]));
        assert_eq!(c.seek(1000, 500), Ok(true));
        assert_eq!(at(&c), (1000, 1900, Some(999), digests[999]));
        assert_eq!(c.seek(10, 500), Ok(true));
        assert_eq!(at(&c), (10, 1900, Some(9), digests[9]));
        // The budget runs out at the gap: the next seek finds it.
        assert_eq!(c.seek(1900, 1190), Ok(false));
        assert_eq!(at(&c), (1200, 1900, Some(1199), digests[1199]));
        assert_eq!(c.seek(1900, 500), Ok(true));
        assert_eq!(at(&c), (1200, 1200, Some(1199), digests[1199]));
        assert_eq!(c.seek(1900, 500), Ok(true));
        assert_eq!(at(&c), (1200, 1200, Some(1199), digests[1199]));

        // Past the gap within one seek's budget: up to the gap at once.
        let mut c = ReplayCursor::of_session(&atlas, session).unwrap();
        assert_eq!(c.seek(1900, 5000), Ok(true));
        assert_eq!(at(&c), (1200, 1200, Some(1199), digests[1199]));
    }
}
