//! One scenario set-up for every scripted run (the CLI, tests, benches, recordings): a parsed
//! script bound to the atlas' planned paths, and the simulation it starts, at the script's tick
//! rate. Replays do not use it: they rebuild the simulation from the session file's header.

use std::sync::Arc;

use stylet_physics::{PlannedPath, PunctureAtlas, SecondHandConfig, SimConfig, SimError, Simulation};

use super::device::BindError;
use super::{Script, ScriptedDevice};

/// Why a scripted run cannot start.
#[derive(Debug, thiserror::Error)]
pub enum SetupError {
    /// The script cannot be bound to the atlas' paths (the message names the line).
    #[error(transparent)]
    Script(#[from] BindError),
    /// The script's settings (device, tick rate, breathing) are refused by the simulation.
    #[error(transparent)]
    Simulation(#[from] SimError),
}

/// The simulation a script starts with on `atlas`, and its device bound to `paths`.
pub fn scripted_simulation(
    atlas: Arc<PunctureAtlas>,
    paths: &[PlannedPath],
    script: &Script,
) -> Result<(Simulation, ScriptedDevice), SetupError> {
    let device = ScriptedDevice::new(script, paths)?;
    let mut config = SimConfig::new(script.device, script.initial_tool);
    config.tick_rate_hz = script.rate_hz;
    config.deformation = script.deformation;
    config.breathing = script.breathing.resolve(&atlas).map_err(SimError::from)?;
    config.second_hand = script.second_hand.map(|h| SecondHandConfig {
        device: h.device,
        tool: h.initial_tool,
    });
    let sim = Simulation::new(atlas, config)?;
    Ok((sim, device))
}
