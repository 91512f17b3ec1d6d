//! Recording a running simulation into a session file: the path the desktop app will use too.

use std::path::Path;

use anyhow::Context;
use stylet_physics::{Simulation, TickInput, TickOutput};
use stylet_recorder::{SessionHeader, SessionWriter, WriteSummary, WriterOptions};

/// A state digest every this many ticks (and at every tick with events), so a replay can find the
/// first tick where it diverges.
pub const DIGEST_EVERY: u64 = 100;

/// Who and what a recorded session is about.
pub struct SessionInfo<'a> {
    pub trainee: &'a str,
    pub scenario: &'a str,
    pub difficulty: &'a str,
    pub seed: u64,
}

/// The header for a session about to start on `sim`.
pub fn header(atlas: &stylet_atlas::Atlas, sim: &Simulation, info: &SessionInfo) -> SessionHeader {
    SessionHeader {
        schema_version: stylet_recorder::SCHEMA_VERSION,
        session_id: stylet_recorder::new_session_id(),
        trainee: info.trainee.to_string(),
        scenario: info.scenario.to_string(),
        difficulty: info.difficulty.to_string(),
        atlas_id: atlas.manifest.name.clone(),
        atlas_hash: atlas.content_hash.clone(),
        software_version: format!("stylet {}", env!("CARGO_PKG_VERSION")),
        physics_version: stylet_physics::PHYSICS_VERSION,
        tick_rate_hz: sim.tick_rate_hz(),
        seed: info.seed,
        device: sim.device().name.to_string(),
        initial_tool: *sim.tool_spec(),
        wall_clock_start: stylet_recorder::wall_clock_now(),
    }
}

/// A session being recorded.
pub struct Recording {
    writer: SessionWriter,
    /// Real-time loop: never block (a full queue marks the session incomplete). Offline: wait.
    realtime: bool,
    error: Option<anyhow::Error>,
}

impl Recording {
    pub fn start(path: &Path, header: &SessionHeader, realtime: bool) -> anyhow::Result<Self> {
        let writer = SessionWriter::create(path, header, WriterOptions::default())
            .with_context(|| format!("cannot record to {}", path.display()))?;
        Ok(Recording {
            writer,
            realtime,
            error: None,
        })
    }

    /// Records one tick, and the state digest after it when due.
    pub fn tick(&mut self, input: &TickInput, output: &TickOutput, sim: &Simulation) {
        let digest_due = output.tick % DIGEST_EVERY == DIGEST_EVERY - 1 || !input.events.is_empty();
        if self.realtime {
            self.writer.record(input, output);
            if digest_due {
                self.writer.digest(output.tick, sim.state_digest());
            }
        } else if self.error.is_none() {
            let r = self.writer.record_blocking(input, output).and_then(|()| {
                if digest_due {
                    self.writer.digest_blocking(output.tick, sim.state_digest())
                } else {
                    Ok(())
                }
            });
            if let Err(e) = r {
                self.error = Some(e.into());
            }
        }
    }

    /// Ends the session (summary, indexes); an error if anything could not be written.
    pub fn finish(self) -> anyhow::Result<WriteSummary> {
        let summary = self.writer.finish()?;
        match self.error {
            Some(e) => Err(e.context("recording the session")),
            None => Ok(summary),
        }
    }
}
