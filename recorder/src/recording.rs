//! Recording a running simulation: the one path the desktop app, `stylet script run --out` and
//! the benchmarks use. Ticks, their events and a state digest every [`DIGEST_EVERY`] ticks and
//! at every tick with events.

use std::path::Path;

use stylet_physics::{Simulation, TickInput, TickOutput};

use crate::format::SessionHeader;
use crate::writer::{SessionWriter, WriteError, WriteSummary, WriterOptions};

/// A state digest every this many ticks (and at every tick with events), so a replay can find the
/// first tick where it diverges.
pub const DIGEST_EVERY: u64 = 100;

/// Who and what a recorded session is about.
pub struct SessionInfo<'a> {
    /// The trainee's account username on the scoring service.
    pub trainee: &'a str,
    pub scenario: &'a str,
    pub difficulty: &'a str,
    pub seed: u64,
    pub atlas_id: &'a str,
    pub atlas_hash: &'a str,
}

/// The header of a session about to start on `sim` (new session id, wall clock now).
pub fn header(sim: &Simulation, info: &SessionInfo) -> SessionHeader {
    SessionHeader {
        schema_version: crate::SCHEMA_VERSION,
        session_id: crate::new_session_id(),
        trainee: info.trainee.to_string(),
        scenario: info.scenario.to_string(),
        difficulty: info.difficulty.to_string(),
        atlas_id: info.atlas_id.to_string(),
        atlas_hash: info.atlas_hash.to_string(),
        software_version: format!("stylet {}", env!("CARGO_PKG_VERSION")),
        physics_version: stylet_physics::PHYSICS_VERSION,
        tick_rate_hz: sim.tick_rate_hz(),
        seed: info.seed,
        device: sim.device().name.to_string(),
        initial_tool: *sim.tool_spec(),
        wall_clock_start: crate::wall_clock_now(),
        deformation: sim.config().deformation,
        contrast: sim.config().contrast,
        breathing: sim.config().breathing,
        hardware: None,
        second_hand: sim.config().second_hand.map(|h| crate::format::SecondHandHeader {
            device: h.device.name.to_string(),
            initial_tool: h.tool,
        }),
    }
}

/// A session being recorded.
pub struct Recording {
    writer: SessionWriter,
    /// Real-time loop: never block (a full queue marks the session incomplete). Offline: wait.
    realtime: bool,
    error: Option<WriteError>,
}

impl Recording {
    pub fn start(
        path: &Path,
        header: &SessionHeader,
        realtime: bool,
        options: WriterOptions,
    ) -> Result<Self, WriteError> {
        Ok(Recording {
            writer: SessionWriter::create(path, header, options)?,
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
                self.error = Some(e);
            }
        }
    }

    /// Records the force a force-feedback device was sent at a tick (metadata; the replay ignores
    /// it). Never blocks (a full queue drops it); nothing when the header names no device.
    pub fn device_force(&self, record: crate::device_forces::DeviceForceRecord) {
        self.writer.device_force(record);
    }

    /// Records a note at `tick` (metadata such as the haptic loop's missed deadlines; the replay
    /// ignores notes). Never blocks in real time (a full queue drops it).
    pub fn note(&self, tick: u64, text: &str) {
        if self.realtime {
            self.writer.annotate(tick, text);
        } else {
            // Offline: an error here shows again at `finish`.
            let _ = self.writer.annotate_blocking(tick, text);
        }
    }

    /// Ends the session (summary, indexes); an error if anything could not be written.
    pub fn finish(self) -> Result<WriteSummary, WriteError> {
        let summary = self.writer.finish()?;
        match self.error {
            Some(e) => Err(e),
            None => Ok(summary),
        }
    }
}
