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
use stylet_scoring::{ReplayError, Replayer, ReviewTrace, Rubric, ScoreReport, Scorer};

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
        let mut left = budget;
        while self.position() < target && left > 0 {
            match self.replayer.step() {
                Some(step) => self.last = Some(step),
                None => {
                    self.end = self.position();
                    return Ok(true);
                }
            }
            left -= 1;
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
