//! One scenario set-up for every scripted run (the CLI, tests, benches, recordings): a parsed
//! script bound to the atlas' planned paths, and the simulation it starts, at the script's tick
//! rate. Replays do not use it: they rebuild the simulation from the session file's header.

use std::sync::Arc;

use stylet_physics::{PlannedPath, PunctureAtlas, SimConfig, Simulation};

use super::{Script, ScriptedDevice};

/// Why a scripted run cannot start.
#[derive(Debug, thiserror::Error)]
pub enum SetupError {
    /// The script names a path the atlas does not have (the message names the line).
    #[error("{0}")]
    Script(String),
    /// The script's device or tick rate is refused by the simulation.
    #[error("{0}")]
    Simulation(String),
}

/// The simulation a script starts with on `atlas`, and its device bound to `paths`.
pub fn scripted_simulation(
    atlas: Arc<PunctureAtlas>,
    paths: &[PlannedPath],
    script: &Script,
) -> Result<(Simulation, ScriptedDevice), SetupError> {
    let device = ScriptedDevice::new(script, paths).map_err(SetupError::Script)?;
    let mut config = SimConfig::new(script.device, script.initial_tool);
    config.tick_rate_hz = script.rate_hz;
    config.deformation = script.deformation;
    config.breathing = script.breathing.resolve(&atlas).map_err(SetupError::Simulation)?;
    let sim = Simulation::new(atlas, config).map_err(SetupError::Simulation)?;
    Ok((sim, device))
}
