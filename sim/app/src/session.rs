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
    /// The trainee: each hand's tool moved by its own device (docs/simulator.md "Hands and
    /// devices"); the window gives the commands.
    Live(LiveHands),
    /// A device script (docs/scripts.md): demonstrations and tests of the whole application.
    Script(String),
}

/// The devices of a live session: the first hand's (the needle hand) and, with two hands, the
/// second hand's and what it holds at the start.
pub struct LiveHands {
    pub needle: HandDevice,
    pub probe: Option<(HandDevice, stylet_physics::HandTool)>,
}

/// What moves one hand's tool in a live session.
#[allow(clippy::large_enum_variant, reason = "two per session at most")]
pub enum HandDevice {
    /// The window's keys and mouse: the tool follows the pose they steer.
    KeysAndMouse,
    /// The first connected SpaceMouse, by rate control.
    SpaceMouse,
    /// The first connected gamepad, by rate control (with the feature `gamepad`).
    Gamepad,
    /// A raw-HID haptic device described by a profile (docs/devices.md "HID profiles"): it moves
    /// the tool and displays the force.
    Hid(stylet_devices::hid_profile::HidProfile),
    /// A force-feedback device through its vendor's API (docs/devices.md "Haptic devices"),
    /// opened when the session starts and closed (zero force) when it ends: it moves the tool
    /// and the hand feels that tool's force.
    ForceFeedback(stylet_devices::haptic::DeviceChoice, Mapping),
}

/// A hand's device, opened: what moves the tool besides the window, and what the session needs
/// to know of it.
struct OpenedHand {
    source: Option<HandSource>,
    /// The physics' device profile (its stiffness and force limits shape the tool's force).
    profile: DeviceProfile,
    /// The device in words, for the status line; `None` for the keys and mouse.
    moved_by: Option<String>,
    window_hold: Option<WindowHold>,
    hardware: Option<stylet_recorder::format::HardwareDevice>,
}

enum HandSource {
    Rate(
        Box<dyn stylet_devices::live::SixAxisSource>,
        stylet_devices::rate::RateSettings,
    ),
    Pose(Box<dyn stylet_devices::live::PoseSource>),
}

impl HandDevice {
    /// Opens the device (a force-feedback device's servo loop runs from here on, at zero force
    /// until the session's forces ramp in).
    fn open(self) -> Result<OpenedHand, SessionError> {
        use stylet_devices::rate::RateSettings;
        let device_error = |e: &dyn std::fmt::Display| SessionError::Device(e.to_string());
        let mut hand = OpenedHand {
            source: None,
            profile: DeviceProfile::IDEAL,
            moved_by: None,
            window_hold: None,
            hardware: None,
        };
        match self {
            HandDevice::KeysAndMouse => {}
            HandDevice::SpaceMouse => {
                let sm = stylet_devices::hid::HidSpaceMouse::open_first().map_err(|e| device_error(&e))?;
                hand.moved_by = Some(sm.model.name.to_string());
                hand.source = Some(HandSource::Rate(Box::new(sm), RateSettings::SPACEMOUSE));
            }
            #[cfg(feature = "gamepad")]
            HandDevice::Gamepad => {
                let pad = stylet_devices::gilrs_pad::GilrsGamepad::open_first().map_err(|e| device_error(&e))?;
                hand.moved_by = Some(format!("gamepad {}", pad.name));
                hand.source = Some(HandSource::Rate(Box::new(pad), RateSettings::GAMEPAD));
            }
            #[cfg(not(feature = "gamepad"))]
            HandDevice::Gamepad => {
                return Err(SessionError::Device(
                    "this build has no gamepad support (build with the feature `gamepad`)".into(),
                ));
            }
            HandDevice::Hid(profile) => {
                hand.profile = profile.physics_profile();
                hand.moved_by = Some(profile.name.clone());
                let arm =
                    stylet_devices::hid::HidProfileDevice::open(profile).map_err(|e| SessionError::Device(e.0))?;
                hand.source = Some(HandSource::Pose(Box::new(arm)));
            }
            HandDevice::ForceFeedback(choice, mapping) => {
                let device = choice.open().map_err(|e| device_error(&e))?;
                let info = device.info();
                hand.profile = physics_profile_for(info);
                hand.moved_by = Some(format!("{} ({})", info.model, info.backend));
                hand.hardware = Some(stylet_recorder::format::HardwareDevice {
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
                hand.window_hold = Some(pose.window_hold());
                hand.source = Some(HandSource::Pose(Box::new(pose)));
            }
        }
        Ok(hand)
    }
}

impl OpenedHand {
    /// The hand's live device starting at a pose, and the window's handle to it.
    fn live(&mut self, (position, orientation): (DVec3, DQuat), rate_hz: u32) -> (LiveDevice, LiveHandle) {
        let (device, handle) = live_device(position, orientation, rate_hz);
        let device = match self.source.take() {
            None => device,
            Some(HandSource::Rate(source, settings)) => device.with_source(source, settings),
            Some(HandSource::Pose(source)) => device.with_pose_source(source),
        };
        (device, handle)
    }
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

/// The skin entry of the path the atlas guides along, seen from outside: the path's direction,
/// the skin's inward normal there, and the side across the path's lean.
struct EntryFrame {
    entry: DVec3,
    dir: DVec3,
    inward: DVec3,
    side: DVec3,
}

impl EntryFrame {
    fn of(atlas: &Atlas) -> Option<EntryFrame> {
        let p = atlas.guided_path()?;
        let entry = DVec3::from_array(p.entry_mm);
        let dir = (DVec3::from_array(p.target_mm) - entry).try_normalize()?;
        // D_skin grows inward: its gradient at the entry is the inward normal.
        let inward = atlas
            .model
            .skin_distance()
            .gradient(entry, 0.0)
            .try_normalize()
            .filter(|n| n.dot(dir) > 0.0)
            .unwrap_or(dir);
        let lean = dir - inward * dir.dot(inward);
        let side = inward
            .cross(lean)
            .try_normalize()
            .unwrap_or_else(|| inward.any_orthonormal_vector());
        Some(EntryFrame {
            entry,
            dir,
            inward,
            side,
        })
    }

    /// [`START_STANDOFF_MM`] outside the skin at `over`, aimed straight into it.
    fn aimed_in_from(&self, over: DVec3) -> (DVec3, DQuat) {
        (over - self.inward * START_STANDOFF_MM, orient(self.inward))
    }
}

/// A tool's orientation pointing along `dir`.
fn orient(dir: DVec3) -> DQuat {
    stylet_devices::script::device::orientation(dir, None)
}

/// Where the tool starts for a session by hand: [`START_STANDOFF_MM`] outside the skin entry of
/// the path the atlas guides along. With the planned path among the level's aids (beginner), on
/// that path and aimed along it; without (advanced, expert), over the entry and aimed straight
/// into the skin, so the trainee finds the angle, and an expert [`EXPERT_OFFSET_MM`] to the side,
/// so they also find the window. Without planned paths, above the volume's centre pointing down.
/// The pose is the first tick's, recorded like every other: replay does not depend on it.
pub fn start_pose(plan: &SessionPlan) -> (DVec3, DQuat) {
    let atlas = &plan.atlas;
    if let Some(f) = EntryFrame::of(atlas) {
        if plan.aids().guided_path.is_some() {
            return (f.entry - f.dir * START_STANDOFF_MM, orient(f.dir));
        }
        return match plan.difficulty {
            stylet_atlas::Difficulty::Expert => f.aimed_in_from(f.entry + f.side * EXPERT_OFFSET_MM),
            _ => f.aimed_in_from(f.entry),
        };
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

/// How far beside the needle's entry the second hand's tool starts (mm): clear of the needle,
/// close enough to find the path in the image.
pub const PROBE_OFFSET_MM: f64 = 40.0;

/// Where the second hand's tool starts: [`START_STANDOFF_MM`] outside the skin,
/// [`PROBE_OFFSET_MM`] beside the entry of the path the atlas guides along (across the path's
/// lean, so the needle has its side), aimed straight into the skin. Without planned paths, beside
/// where the first hand starts. Recorded like every pose: replay does not depend on it.
pub fn probe_start_pose(plan: &SessionPlan) -> (DVec3, DQuat) {
    match EntryFrame::of(&plan.atlas) {
        Some(f) => f.aimed_in_from(f.entry + f.side * PROBE_OFFSET_MM),
        None => {
            let (p, q) = start_pose(plan);
            (p + DVec3::X * PROBE_OFFSET_MM, q)
        }
    }
}

/// What a live session keeps of its hands' devices.
#[derive(Default)]
struct HandsInUse {
    live: Option<LiveHandle>,
    probe_live: Option<LiveHandle>,
    moved_by: Option<String>,
    probe_moved_by: Option<String>,
    window_holds: Vec<WindowHold>,
    hardware: Option<stylet_recorder::format::HardwareDevice>,
}

/// A session in progress.
pub struct RunningSession {
    pub plan: SessionPlan,
    haptic: HapticLoop,
    /// The first hand's device (sessions by hand): the window's commands go to it.
    live: Option<LiveHandle>,
    /// The second hand's device (two-handed sessions by hand).
    probe_live: Option<LiveHandle>,
    /// The device moving the first hand's tool besides the window (a SpaceMouse's model, a HID
    /// profile's name), if any.
    moved_by: Option<String>,
    /// The same for the second hand.
    probe_moved_by: Option<String>,
    /// Hold the force-feedback devices' forces at zero (window out of focus).
    window_holds: Vec<WindowHold>,
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
        let mut hands = HandsInUse::default();
        let (sim, device): (Simulation, Box<dyn Device + Send>) = match driver {
            Driver::Live(devices) => {
                // Opened before the simulation: a force-feedback device's limits choose the
                // physics' device profile. A device that fails closes those already opened.
                let mut needle = devices.needle.open()?;
                let mut probe = match devices.probe {
                    Some((device, tool)) => Some((device.open()?, tool)),
                    None => None,
                };
                let mut config = SimConfig::new(needle.profile, ToolSpec::Finger);
                // A trainee's tissue yields (recorded in the header, replayed by scoring), solved
                // off the haptic thread; the bits are the same (fixed latency).
                config.deformation = DeformSettings::on();
                config.deform_in_background = true;
                config.breathing = plan.breathing()?;
                config.second_hand = probe.as_ref().map(|(hand, tool)| stylet_physics::SecondHandConfig {
                    device: hand.profile,
                    tool: Some(*tool),
                });
                let sim = Simulation::new(model, config).map_err(SessionError::Simulation)?;
                let rate_hz = sim.tick_rate_hz();
                let (first, handle) = needle.live(start_pose(&plan), rate_hz);
                hands.live = Some(handle);
                hands.moved_by = needle.moved_by.take();
                hands.window_holds.extend(needle.window_hold.take());
                hands.hardware = needle.hardware.take();
                let device: Box<dyn Device + Send> = match probe.as_mut() {
                    None => Box::new(first),
                    Some((hand, _)) => {
                        let (second, handle) = hand.live(probe_start_pose(&plan), rate_hz);
                        hands.probe_live = Some(handle);
                        hands.probe_moved_by = hand.moved_by.take();
                        hands.window_holds.extend(hand.window_hold.take());
                        Box::new(stylet_devices::two_hands::TwoHands::new(
                            Box::new(first),
                            Box::new(second),
                        ))
                    }
                };
                (sim, device)
            }
            Driver::Script(text) => {
                let script = parse(&text).map_err(|e| SessionError::Script(e.to_string()))?;
                let (sim, device): (Simulation, ScriptedDevice) =
                    scripted_simulation(model, &atlas.planned_paths(), &script)
                        .map_err(|e| SessionError::Script(e.to_string()))?;
                (sim, Box::new(device))
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
        // The needle hand's force-feedback device: the one whose sent forces the file records.
        header.hardware = hands.hardware.take();
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
            live: hands.live,
            probe_live: hands.probe_live,
            moved_by: hands.moved_by,
            probe_moved_by: hands.probe_moved_by,
            window_holds: hands.window_holds,
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

    /// The second hand's device (two-handed sessions by hand).
    pub fn probe_live(&self) -> Option<&LiveHandle> {
        self.probe_live.as_ref()
    }

    /// The handle the window's keys and mouse steer: the hand whose tool no device of its own
    /// moves (the first hand's first), if any.
    pub fn steered_by_keys(&self) -> Option<&LiveHandle> {
        match (
            &self.live,
            self.moved_by.is_none(),
            &self.probe_live,
            self.probe_moved_by.is_none(),
        ) {
            (Some(l), true, _, _) => Some(l),
            (_, _, Some(p), true) => Some(p),
            _ => None,
        }
    }

    /// The device moving the first hand's tool besides the window (a SpaceMouse, a HID
    /// profile's device, a force-feedback device), if any.
    pub fn moved_by(&self) -> Option<&str> {
        self.moved_by.as_deref()
    }

    /// The device moving the second hand's tool besides the window, if any.
    pub fn probe_moved_by(&self) -> Option<&str> {
        self.probe_moved_by.as_deref()
    }

    /// Holds the force-feedback devices' forces at zero while the window is out of focus (or
    /// lets them ramp in again); nothing for other devices.
    pub fn hold_forces(&self, hold: Hold) {
        for h in &self.window_holds {
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
        if let Some(probe) = &self.probe_live {
            probe.finish();
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

    /// A coarse phantom (64 × 64 × 50 voxels of 6 mm) written to and loaded from `dir`.
    fn small_phantom(dir: &Path) -> Arc<Atlas> {
        let p = stylet_atlas::phantom::generate(&stylet_atlas::phantom::PhantomConfig {
            dims: [64, 64, 50],
            spacing_mm: [6.0; 3],
            ..Default::default()
        })
        .unwrap();
        stylet_atlas::write(dir, &p.manifest, &p.ct, &p.partial).unwrap();
        Arc::new(stylet_atlas::load(dir).unwrap())
    }

    /// A beginner starts on the planned path, aimed along it; an advanced trainee over its entry,
    /// aimed into the skin; an expert beside the entry: all a few centimetres out.
    #[test]
    fn a_session_by_hand_starts_a_few_centimetres_outside_the_entry() {
        let dir = tempfile::tempdir().unwrap();
        let atlas = small_phantom(dir.path());
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

    /// The second hand's probe starts a few centimetres outside the skin, beside the entry (clear
    /// of the needle), aimed into the skin.
    #[test]
    fn the_probe_hand_starts_beside_the_entry_aimed_into_the_skin() {
        let dir = tempfile::tempdir().unwrap();
        let atlas = small_phantom(dir.path());
        let entry = DVec3::from_array(atlas.guided_path().unwrap().entry_mm);
        let plan = SessionPlan {
            atlas: Arc::clone(&atlas),
            scenario: atlas.manifest.scenarios[0].name.clone(),
            difficulty: Difficulty::Beginner,
            trainee: "t".into(),
            seed: 1,
            sessions_dir: dir.path().join("sessions"),
        };
        let (p, q) = probe_start_pose(&plan);
        let axis = q * DVec3::Z;
        let to_skin = atlas
            .model
            .skin_distance_along(p, axis, 300.0)
            .expect("the probe points at the skin");
        assert!((20.0..=40.0).contains(&to_skin), "{to_skin} mm to the skin");
        let beside = distance_to_line(entry, p, axis);
        assert!(
            (PROBE_OFFSET_MM - 0.5..=PROBE_OFFSET_MM + 0.5).contains(&beside),
            "{beside} mm beside the entry"
        );
        let (needle, _) = start_pose(&plan);
        assert!((needle - p).length() > 30.0, "clear of the needle's start");
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
