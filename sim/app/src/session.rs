//! One training session as the window runs it: the plan chosen on the start screen (patient,
//! scenario, difficulty, trainee), the running haptic loop with its recording, and the finished
//! session with its local score (the same scorer and rubric as the service: thesis §6.3,
//! docs/metrics.md) and its place in the outbox.
//!
//! Nothing here draws: the window and the tests drive it alike.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use stylet_atlas::Atlas;
use stylet_atlas::manifest::DifficultyPreset;
use stylet_devices::Device;
use stylet_devices::haptic::Hold;
use stylet_devices::haptic::pose::{HapticPose, Mapping, WindowHold};
use stylet_devices::live::{LiveDevice, LiveHandle, live_device};
use stylet_devices::script::{ScriptedDevice, parse, scripted_simulation};
use stylet_physics::glam::{DQuat, DVec3};
use stylet_physics::{DeformSettings, DeviceProfile, SimConfig, Simulation, ToolSpec};
use stylet_recorder::{Recording, SessionInfo, WriterOptions};
use stylet_render::scene::Tagging;
use stylet_render::views::SessionLabels;
use stylet_scoring::{Exercise, Rubric, ScoreReport, Scorer};

use crate::haptic::{ConsoleLine, HapticLoop, LoopError, LoopOptions, LoopReport, Snapshot, StatsView};
use crate::views::ViewSettings;

/// The difficulty levels a session is graded at (the rubric has one level per name).
pub use stylet_scoring::Difficulty;

/// Console lines a session keeps (the oldest go first).
pub const CONSOLE_LINES: usize = 500;

/// Errors of starting and finishing a session.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    #[error("the script cannot drive this patient: {0}")]
    Script(String),
    #[error("the simulation cannot start: {0}")]
    Simulation(stylet_physics::SimError),
    #[error("the device cannot be used: {0}")]
    Device(String),
    #[error("cannot record the session to {path}: {reason}")]
    Record { path: PathBuf, reason: String },
    #[error(transparent)]
    Loop(#[from] LoopError),
    #[error("cannot start a thread: {0}")]
    Thread(#[from] std::io::Error),
    #[error("the recording of {path} failed: {reason}")]
    Recording { path: PathBuf, reason: String },
}

/// What the trainee chose on the start screen.
#[derive(Clone)]
pub struct SessionPlan {
    pub atlas: Arc<Atlas>,
    pub scenario: String,
    pub difficulty: Difficulty,
    /// The account username the session is recorded for (offline: a local name).
    pub trainee: String,
    /// Seed of the session's random generators (speckle), recorded in the header.
    pub seed: u64,
    /// Where session files are written.
    pub sessions_dir: PathBuf,
}

impl SessionPlan {
    /// The aids of the difficulty level, as the atlas declares them (`[difficulty.*]`).
    pub fn aids(&self) -> &DifficultyPreset {
        self.atlas.manifest.difficulty.of(self.difficulty)
    }

    /// The breathing of the session: the scenario's `breathes` with the atlas' motion and the
    /// session's seed (its cycles), off otherwise. Refused when the scenario breathes and the
    /// atlas has no motion.
    pub fn breathing(&self) -> Result<stylet_physics::motion::BreathingSettings, SessionError> {
        let breathes = self
            .atlas
            .manifest
            .scenarios
            .iter()
            .any(|s| s.name == self.scenario && s.breathes);
        stylet_physics::motion::BreathingRequest {
            enabled: breathes,
            amplitude_mm: None,
            signal: stylet_physics::motion::SignalParams {
                seed: self.seed,
                ..Default::default()
            },
        }
        .resolve(&self.atlas.model)
        .map_err(|e| SessionError::Simulation(e.into()))
    }

    /// What the scenario practises (decides the rubric).
    pub fn exercise(&self) -> Exercise {
        self.atlas
            .manifest
            .scenarios
            .iter()
            .find(|s| s.name == self.scenario)
            .map(|s| s.exercise)
            .unwrap_or_default()
    }

    /// The views' settings for the level: risk tagging with its clipping plane where the level
    /// highlights risk structures (thesis eq. 3.2.4), none otherwise.
    pub fn view_settings(&self) -> ViewSettings {
        let aids = self.aids();
        ViewSettings {
            tagging: if aids.risk_overlay || aids.target_overlay {
                Tagging::Risk
            } else {
                Tagging::Off
            },
            ..ViewSettings::default()
        }
    }

    /// The planned path the level shows (the guided mode), if any.
    pub fn guided_path(&self) -> Option<stylet_physics::PlannedPath> {
        let name = self.aids().guided_path.as_ref()?;
        self.atlas.planned_paths().into_iter().find(|p| &p.name == name)
    }

    pub fn labels(&self) -> SessionLabels {
        SessionLabels {
            scenario: self.scenario.clone(),
            difficulty: self.difficulty,
            seed: self.seed,
        }
    }
}

/// Who moves the tools.
#[allow(clippy::large_enum_variant, reason = "one per session, made once when it starts")]
pub enum Driver {
    /// The trainee, through the window (keyboard, mouse, SpaceMouse, tablet).
    Hands,
    /// A device script (docs/scripts.md): demonstrations and tests of the whole application.
    Script(String),
    /// A raw-HID haptic device described by a profile (docs/devices.md "HID profiles"): it moves
    /// the tool and displays the force; the window gives commands.
    HidDevice(stylet_devices::hid_profile::HidProfile),
    /// A force-feedback device through its vendor's API (docs/devices.md "Haptic devices"),
    /// opened when the session starts and closed (zero force) when it ends: it moves the tool
    /// and the trainee feels the force; the window gives commands.
    HapticDevice(stylet_devices::haptic::DeviceChoice, Mapping),
}

/// The physics' device profile for a force-feedback device: the Phantom Premium's (8.5 N,
/// 3.5 N/mm) for devices that reach its force, else the Touch's (3.3 N, 1.02 N/mm), the
/// conservative choice. The device's own limits are then enforced by its force guard.
pub fn physics_profile_for(info: &stylet_devices::haptic::DeviceInfo) -> DeviceProfile {
    if info.max_force_n >= DeviceProfile::PREMIUM.max_force_n {
        DeviceProfile::PREMIUM
    } else {
        DeviceProfile::TOUCH
    }
}

/// How far outside the skin a session by hand starts (mm): a few seconds of the wheel (1 mm a
/// notch), not minutes.
pub const START_STANDOFF_MM: f64 = 30.0;

/// How far from the entry an expert starts, along the skin (mm): near the entry window, not on it.
pub const EXPERT_OFFSET_MM: f64 = 10.0;

/// Where the tool starts for a session by hand: [`START_STANDOFF_MM`] outside the skin entry of
/// the path the atlas guides along. With the planned path among the level's aids (beginner), on
/// that path and aimed along it; without (advanced, expert), over the entry and aimed straight
/// into the skin, so the trainee finds the angle, and an expert [`EXPERT_OFFSET_MM`] to the side,
/// so they also find the window. Without planned paths, above the volume's centre pointing down.
/// The pose is the first tick's, recorded like every other: replay does not depend on it.
pub fn start_pose(plan: &SessionPlan) -> (DVec3, DQuat) {
    let atlas = &plan.atlas;
    let orient = |d| stylet_devices::script::device::orientation(d, None);
    let path = atlas
        .guided_path()
        .map(|p| (DVec3::from_array(p.entry_mm), DVec3::from_array(p.target_mm)));
    if let Some((entry, target)) = path
        && let Some(dir) = (target - entry).try_normalize()
    {
        if plan.aids().guided_path.is_some() {
            return (entry - dir * START_STANDOFF_MM, orient(dir));
        }
        // D_skin grows inward: its gradient at the entry is the inward normal.
        let inward = atlas
            .model
            .skin_distance()
            .gradient(entry, 0.0)
            .try_normalize()
            .filter(|n| n.dot(dir) > 0.0)
            .unwrap_or(dir);
        let over = if plan.difficulty == stylet_atlas::Difficulty::Expert {
            let lean = dir - inward * dir.dot(inward);
            let side = inward
                .cross(lean)
                .try_normalize()
                .unwrap_or_else(|| inward.any_orthonormal_vector());
            entry + side * EXPERT_OFFSET_MM
        } else {
            entry
        };
        return (over - inward * START_STANDOFF_MM, orient(inward));
    }
    let (lo, hi) = atlas.model.ct().grid().world_bounds();
    let top = (lo + hi) * 0.5 + DVec3::new(0.0, (hi.y - lo.y) * 0.5, 0.0);
    let to_skin = atlas
        .model
        .skin_distance_along(top, DVec3::NEG_Y, hi.y - lo.y)
        .unwrap_or(0.0);
    (
        top + DVec3::NEG_Y * (to_skin - START_STANDOFF_MM).max(0.0),
        orient(DVec3::NEG_Y),
    )
}

/// The live device moved by a connected SpaceMouse, else by a gamepad (with the feature
/// `gamepad`), else unchanged; and the name of what moves it.
fn with_six_axis_source(device: LiveDevice) -> (LiveDevice, Option<String>) {
    use stylet_devices::rate::RateSettings;
    if let Ok(sm) = stylet_devices::hid::HidSpaceMouse::open_first() {
        let name = sm.model.name.to_string();
        return (device.with_source(Box::new(sm), RateSettings::SPACEMOUSE), Some(name));
    }
    #[cfg(feature = "gamepad")]
    if let Ok(pad) = stylet_devices::gilrs_pad::GilrsGamepad::open_first() {
        let name = format!("gamepad {}", pad.name);
        return (device.with_source(Box::new(pad), RateSettings::GAMEPAD), Some(name));
    }
    (device, None)
}

/// A session in progress.
pub struct RunningSession {
    pub plan: SessionPlan,
    haptic: HapticLoop,
    live: Option<LiveHandle>,
    /// The device moving the tool besides the window (a SpaceMouse's model, a HID profile's
    /// name), if any.
    moved_by: Option<String>,
    /// Holds a force-feedback device's forces at zero (window out of focus).
    window_hold: Option<WindowHold>,
    path: PathBuf,
    started: Instant,
    console: std::collections::VecDeque<ConsoleLine>,
}

impl RunningSession {
    /// Starts the haptic loop and its recording to a new file in the plan's sessions folder.
    /// `paced`: real time (the window); unpaced runs as fast as the CPU allows (tests).
    pub fn start(plan: SessionPlan, driver: Driver, paced: bool) -> Result<RunningSession, SessionError> {
        let atlas = &plan.atlas;
        let model = Arc::clone(&atlas.model);
        let mut moved_by = None;
        let mut window_hold = None;
        let mut hardware = None;
        let (sim, device, live): (Simulation, Box<dyn Device + Send>, Option<LiveHandle>) = match driver {
            Driver::Hands => {
                let mut config = SimConfig::new(DeviceProfile::IDEAL, ToolSpec::Finger);
                // A trainee's tissue yields (recorded in the header, replayed by scoring), solved
                // off the haptic thread; the bits are the same (fixed latency).
                config.deformation = DeformSettings::on();
                config.deform_in_background = true;
                config.breathing = plan.breathing()?;
                let sim = Simulation::new(model, config).map_err(SessionError::Simulation)?;
                let (position, orientation) = start_pose(&plan);
                let (device, handle) = live_device(position, orientation, sim.tick_rate_hz());
                // A connected SpaceMouse (else a gamepad) moves the tool by rate control; the
                // keys and mouse then only give commands.
                let (device, by) = with_six_axis_source(device);
                moved_by = by;
                (sim, Box::new(device), Some(handle))
            }
            Driver::HidDevice(profile) => {
                let mut config = SimConfig::new(profile.physics_profile(), ToolSpec::Finger);
                config.deformation = DeformSettings::on();
                config.deform_in_background = true;
                config.breathing = plan.breathing()?;
                let sim = Simulation::new(model, config).map_err(SessionError::Simulation)?;
                let (position, orientation) = start_pose(&plan);
                let (device, handle) = live_device(position, orientation, sim.tick_rate_hz());
                let name = profile.name.clone();
                let arm =
                    stylet_devices::hid::HidProfileDevice::open(profile).map_err(|e| SessionError::Device(e.0))?;
                moved_by = Some(name);
                (sim, Box::new(device.with_pose_source(Box::new(arm))), Some(handle))
            }
            Driver::HapticDevice(choice, mapping) => {
                let device = choice.open().map_err(|e| SessionError::Device(e.to_string()))?;
                let mut config = SimConfig::new(physics_profile_for(device.info()), ToolSpec::Finger);
                config.deformation = DeformSettings::on();
                config.deform_in_background = true;
                config.breathing = plan.breathing()?;
                let sim = Simulation::new(model, config).map_err(SessionError::Simulation)?;
                let (position, orientation) = start_pose(&plan);
                let (live, handle) = live_device(position, orientation, sim.tick_rate_hz());
                let info = device.info();
                moved_by = Some(format!("{} ({})", info.model, info.backend));
                hardware = Some(stylet_recorder::format::HardwareDevice {
                    backend: info.backend.name().to_string(),
                    // Within the header's text limit, whatever the vendor's library says.
                    model: info
                        .model
                        .chars()
                        .take(stylet_recorder::format::MAX_TEXT_CHARS)
                        .collect(),
                    max_force_n: info.max_force_n,
                    max_continuous_force_n: info.max_continuous_force_n,
                });
                let pose = HapticPose::new(device, mapping);
                window_hold = Some(pose.window_hold());
                (sim, Box::new(live.with_pose_source(Box::new(pose))), Some(handle))
            }
            Driver::Script(text) => {
                let script = parse(&text).map_err(|e| SessionError::Script(e.to_string()))?;
                let (sim, device): (Simulation, ScriptedDevice) =
                    scripted_simulation(model, &atlas.planned_paths(), &script)
                        .map_err(|e| SessionError::Script(e.to_string()))?;
                (sim, Box::new(device), None)
            }
        };
        let path = new_session_path(&plan.sessions_dir, &plan.scenario);
        let info = SessionInfo {
            trainee: &plan.trainee,
            scenario: &plan.scenario,
            difficulty: plan.difficulty.as_str(),
            seed: plan.seed,
            atlas_id: &atlas.manifest.name,
            atlas_hash: &atlas.content_hash,
        };
        let mut header = stylet_recorder::recording::header(&sim, &info);
        header.hardware = hardware;
        std::fs::create_dir_all(&plan.sessions_dir).map_err(|e| SessionError::Record {
            path: plan.sessions_dir.clone(),
            reason: e.to_string(),
        })?;
        let recording =
            Recording::start(&path, &header, paced, WriterOptions::default()).map_err(|e| SessionError::Record {
                path: path.clone(),
                reason: e.to_string(),
            })?;
        let options = LoopOptions {
            paced,
            ..LoopOptions::default()
        };
        let haptic = HapticLoop::spawn(sim, device, Some(recording), plan.labels(), options)?;
        Ok(RunningSession {
            plan,
            haptic,
            live,
            moved_by,
            window_hold,
            path,
            started: Instant::now(),
            console: std::collections::VecDeque::new(),
        })
    }

    /// The latest state the loop published.
    pub fn snapshot(&self) -> Option<Snapshot> {
        self.haptic.snapshot()
    }

    pub fn stats(&self) -> StatsView {
        self.haptic.stats()
    }

    /// The window's end of the device (sessions by hand).
    pub fn live(&self) -> Option<&LiveHandle> {
        self.live.as_ref()
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The device moving the tool besides the window (a SpaceMouse found at the start, a HID
    /// profile's device), if any.
    pub fn moved_by(&self) -> Option<&str> {
        self.moved_by.as_deref()
    }

    /// Holds a force-feedback device's forces at zero while the window is out of focus (or
    /// lets them ramp in again); nothing for other drivers.
    pub fn hold_forces(&self, hold: Hold) {
        if let Some(h) = &self.window_hold {
            h.set(hold);
        }
    }

    pub fn started(&self) -> Instant {
        self.started
    }

    /// Takes the loop's new console lines; returns the session's recent ones, oldest first.
    pub fn console(&mut self) -> &std::collections::VecDeque<ConsoleLine> {
        for line in self.haptic.console() {
            if self.console.len() == CONSOLE_LINES {
                self.console.pop_front();
            }
            self.console.push_back(line);
        }
        &self.console
    }

    /// Console lines the loop could not hand over in time.
    pub fn dropped_console_lines(&self) -> u64 {
        self.haptic.dropped_console_lines()
    }

    /// The device has nothing more to say (a script's end).
    pub fn is_over(&self) -> bool {
        self.haptic.is_finished()
    }

    /// Ends the session: the device finishes (by hand, after what is queued) or the loop is
    /// stopped, the recording is closed, and the file is checked complete.
    pub fn finish(self) -> Result<FinishedSession, SessionError> {
        match &self.live {
            Some(live) => live.finish(),
            None => self.haptic.stop(),
        }
        let report = self.haptic.join()?;
        if let Some(Err(e)) = &report.recording {
            return Err(SessionError::Recording {
                path: self.path,
                reason: e.to_string(),
            });
        }
        Ok(FinishedSession {
            plan: self.plan,
            path: self.path,
            report,
        })
    }
}

/// A session that ended, its file closed.
pub struct FinishedSession {
    pub plan: SessionPlan,
    pub path: PathBuf,
    pub report: LoopReport,
}

impl FinishedSession {
    /// Scores the file as the service will: a replay through the same physics, the default
    /// rubric, reasons in plain words.
    pub fn score(&self) -> Result<ScoreReport, ScoreFileError> {
        score_file(&self.plan.atlas, &self.path)
    }
}

/// Why a session file got no local score: no scorer could be built for its atlas, or the file
/// itself could not be scored (unreadable, another atlas, a replay that fails, no grade level).
#[derive(Debug, thiserror::Error)]
pub enum ScoreFileError {
    #[error(transparent)]
    Scorer(#[from] stylet_scoring::ScorerError),
    #[error(transparent)]
    Score(#[from] stylet_scoring::ScoreError),
}

/// Scores a session file on its atlas with the default rubric.
pub fn score_file(atlas: &Atlas, path: &Path) -> Result<ScoreReport, ScoreFileError> {
    let scorer = Scorer::new(atlas, Rubric::default_rubric(), None)?;
    Ok(scorer.score_file(path)?)
}

/// A new file name in `dir`: the time and the scenario, never one that exists.
fn new_session_path(dir: &Path, scenario: &str) -> PathBuf {
    let stamp = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis());
    let safe: String = scenario
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() || c == '-' { c } else { '_' })
        .take(40)
        .collect();
    let mut n = 0u32;
    loop {
        let name = match n {
            0 => format!("{stamp}-{safe}.mcap"),
            n => format!("{stamp}-{safe}-{n}.mcap"),
        };
        let p = dir.join(name);
        if !p.exists() {
            return p;
        }
        n += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A beginner starts on the planned path, aimed along it; an advanced trainee over its entry,
    /// aimed into the skin; an expert beside the entry: all a few centimetres out.
    #[test]
    fn a_session_by_hand_starts_a_few_centimetres_outside_the_entry() {
        let dir = tempfile::tempdir().unwrap();
        let p = stylet_atlas::phantom::generate(&stylet_atlas::phantom::PhantomConfig {
            dims: [64, 64, 50],
            spacing_mm: [6.0; 3],
            ..Default::default()
        })
        .unwrap();
        stylet_atlas::write(dir.path(), &p.manifest, &p.ct, &p.partial).unwrap();
        let atlas = Arc::new(stylet_atlas::load(dir.path()).unwrap());
        let g = atlas.guided_path().unwrap();
        let (entry, target) = (DVec3::from_array(g.entry_mm), DVec3::from_array(g.target_mm));
        let path_dir = (target - entry).normalize();
        let plan = |difficulty| SessionPlan {
            atlas: Arc::clone(&atlas),
            scenario: atlas.manifest.scenarios[0].name.clone(),
            difficulty,
            trainee: "t".into(),
            seed: 1,
            sessions_dir: dir.path().join("sessions"),
        };
        for level in [Difficulty::Beginner, Difficulty::Advanced, Difficulty::Expert] {
            let (p, q) = start_pose(&plan(level));
            let axis = q * DVec3::Z;
            let to_skin = atlas
                .model
                .skin_distance_along(p, axis, 300.0)
                .expect("the tool points at the skin");
            assert!((20.0..=40.0).contains(&to_skin), "{level:?}: {to_skin} mm to the skin");
            let off_entry = distance_to_line(entry, p, axis);
            match level {
                Difficulty::Beginner => {
                    assert!(axis.dot(path_dir) > 0.9999, "beginner: aimed along the path");
                    assert!(off_entry < 0.5, "beginner: on the path, {off_entry} mm off");
                }
                Difficulty::Advanced => assert!(off_entry < 0.5, "advanced: over the entry, {off_entry} mm off"),
                _ => assert!(
                    (EXPERT_OFFSET_MM - 0.5..=EXPERT_OFFSET_MM + 0.5).contains(&off_entry),
                    "expert: near the entry, {off_entry} mm off"
                ),
            }
        }
    }

    /// Distance of `p` from the line through `a` along the unit vector `d`.
    fn distance_to_line(p: DVec3, a: DVec3, d: DVec3) -> f64 {
        let v = p - a;
        (v - d * v.dot(d)).length()
    }

    /// A scenario that breathes gives its sessions the atlas' motion with the session's seed; the
    /// others stay still; an atlas without motion refuses a breathing scenario by name.
    #[test]
    fn the_scenario_decides_whether_the_patient_breathes() {
        let dir = tempfile::tempdir().unwrap();
        let mut p = stylet_atlas::phantom::generate(&stylet_atlas::phantom::PhantomConfig {
            dims: [64, 64, 50],
            spacing_mm: [6.0; 3],
            ..Default::default()
        })
        .unwrap();
        p.manifest.scenarios[0].breathes = true;
        let breathing_scenario = p.manifest.scenarios[0].name.clone();
        let still_scenario = p.manifest.scenarios[1].name.clone();
        stylet_atlas::write(dir.path(), &p.manifest, &p.ct, &p.partial).unwrap();
        let atlas = Arc::new(stylet_atlas::load(dir.path()).unwrap());
        let plan = |scenario: &str, atlas: &Arc<Atlas>| SessionPlan {
            atlas: Arc::clone(atlas),
            scenario: scenario.into(),
            difficulty: Difficulty::Beginner,
            trainee: "t".into(),
            seed: 42,
            sessions_dir: dir.path().join("sessions"),
        };
        let b = plan(&breathing_scenario, &atlas).breathing().unwrap();
        assert!(b.enabled && !b.measured);
        assert_eq!((b.signal.seed, b.motion.amplitude_mm), (42, 12.0));
        assert!(!plan(&still_scenario, &atlas).breathing().unwrap().enabled);
        p.manifest.breathing = Some(stylet_atlas::manifest::BreathingToml::attached(false));
        let still_dir = dir.path().join("still");
        stylet_atlas::write(&still_dir, &p.manifest, &p.ct, &p.partial).unwrap();
        let still = Arc::new(stylet_atlas::load(&still_dir).unwrap());
        let e = plan(&breathing_scenario, &still).breathing().unwrap_err();
        assert!(e.to_string().contains("no breathing motion"), "{e}");
    }
}
