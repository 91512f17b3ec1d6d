//! The simulator's window (egui on wgpu; thesis §6.2–6.3, docs/simulator.md "The window"): the
//! start screen (log in or work offline; patient, scenario, difficulty), the session (views,
//! tools, indicators, console, status bar), the results (the local score and the upload) and the
//! replay viewer. Each screen is a module; this one owns what they share and switches between
//! them.
//!
//! Everything a score depends on happens in the haptic loop and the physics; the window only
//! turns the trainee's input into device commands and draws snapshots.

mod chart;
mod devices;
mod keys;
mod panes;
mod replay_screen;
mod results;
mod session_screen;
mod start;

use std::path::PathBuf;

/// The egui the window is built with (for tests driving it).
pub use eframe::egui;
use std::sync::Arc;
use std::time::Duration;

use stylet_atlas::Atlas;

use crate::credentials::Credentials;
use crate::outbox::{Backoff, Outbox, OutboxError, Retrier};
use crate::service_client::{ServiceClient, TokenUploader};

pub use panes::Layout;
pub use replay_screen::{LoadReplayError, ReplayScreen};
pub use results::{NoScore, NotQueued, ResultsScreen};
pub use session_screen::SessionScreen;
pub use start::StartScreen;

/// How the window starts.
#[derive(Debug, Clone)]
pub struct AppOptions {
    /// The patients to choose from (atlas directories); the first is preselected.
    pub atlases: Vec<PathBuf>,
    /// Where session files are written.
    pub sessions_dir: PathBuf,
    /// The outbox of finished sessions waiting for the service.
    pub outbox_dir: PathBuf,
    /// Where the login (an upload-only API token) is kept; `None`: never stored.
    pub config_dir: Option<PathBuf>,
    /// Drive sessions with this device script instead of by hand (demonstrations, tests).
    pub script: Option<PathBuf>,
    /// Real-time sessions (false: as fast as the CPU allows, for tests).
    pub paced: bool,
    /// A view's frame budget (the resolution adapts to keep it).
    pub view_budget: Duration,
    /// What draws the views (the CPU, the GPU, or the GPU when it is a real one).
    pub renderer: crate::views::Backend,
    /// Open this session file in the replay viewer at start.
    pub replay: Option<PathBuf>,
    /// Serve the tablet page here (off by default: thesis §6.2.2, docs/simulator.md).
    pub tablet: Option<std::net::SocketAddr>,
    /// Sessions by hand use the raw-HID haptic device this profile describes.
    pub hid_profile: Option<stylet_devices::hid_profile::HidProfile>,
    /// Sessions by hand use this force-feedback device (opened when a session starts).
    pub haptic_device: Option<(
        stylet_devices::haptic::DeviceChoice,
        stylet_devices::haptic::pose::Mapping,
    )>,
}

/// The screens.
pub enum Screen {
    Start(Box<StartScreen>),
    Session(Box<SessionScreen>),
    Results(Box<ResultsScreen>),
    /// A session file being replayed and scored before the viewer opens.
    Loading(Box<replay_screen::LoadingReplay>),
    Replay(Box<ReplayScreen>),
}

impl Screen {
    pub fn name(&self) -> &'static str {
        match self {
            Screen::Start(_) => "start",
            Screen::Session(_) => "session",
            Screen::Results(_) => "results",
            Screen::Loading(_) => "loading",
            Screen::Replay(_) => "replay",
        }
    }
}

/// What the screens share: the options, loaded patients, the login and the outbox.
pub struct Shared {
    pub options: AppOptions,
    atlases: Vec<(PathBuf, Arc<Atlas>)>,
    pub login: Option<Credentials>,
    /// This computer as a lab machine of a cohort, when paired as one: `login` is then the
    /// trainee signed in on it, if any.
    pub lab: Option<crate::credentials::LabMachine>,
    pub outbox: Option<Outbox>,
    /// Why the outbox cannot be used (shown on every screen).
    pub outbox_problem: Option<Arc<OutboxError>>,
    retrier: Option<Retrier>,
    /// The tablet page and the commands it sends, when it is on.
    tablet: Option<(
        crate::tablet::TabletPage,
        std::sync::mpsc::Receiver<crate::controls::Command>,
    )>,
    tablet_problem: Option<String>,
    /// The devices this machine offers (found when the window opened).
    pub available: crate::hands::Available,
    /// Which device moves which hand (remembered on this machine).
    pub hands: crate::hands::HandAssignment,
    /// Why the remembered assignment was not read or could not be kept.
    pub hands_problem: Option<String>,
}

impl Shared {
    fn new(options: AppOptions) -> Shared {
        let login = options
            .config_dir
            .as_deref()
            .and_then(|d| Credentials::load(d).ok().flatten());
        let lab = options
            .config_dir
            .as_deref()
            .and_then(|d| crate::credentials::LabMachine::load(d).ok().flatten());
        let (outbox, outbox_problem) = match Outbox::open(&options.outbox_dir) {
            Ok(o) => (Some(o), None),
            Err(e) => (None, Some(Arc::new(e))),
        };
        let (mut tablet, mut tablet_problem) = (None, None);
        if let Some(addr) = options.tablet {
            let (tx, rx) = std::sync::mpsc::channel();
            match crate::tablet::TabletPage::start(addr, tx) {
                Ok(page) => tablet = Some((page, rx)),
                Err(e) => tablet_problem = Some(e.to_string()),
            }
        }
        let available = Shared::probe_devices(&options);
        let remembered = match options.config_dir.as_deref() {
            Some(dir) => crate::hands::HandAssignment::load(dir),
            None => Ok(None),
        };
        let (hands, hands_problem) = match remembered {
            Ok(Some(h)) => (h, None),
            Ok(None) => (crate::hands::HandAssignment::default_for(&available), None),
            Err(e) => (
                crate::hands::HandAssignment::default_for(&available),
                Some(format!("the devices chosen before are not used: {e}")),
            ),
        };
        let mut shared = Shared {
            available,
            hands,
            hands_problem,
            options,
            atlases: Vec::new(),
            login: None,
            lab,
            outbox,
            outbox_problem,
            retrier: None,
            tablet,
            tablet_problem,
        };
        if let Some(c) = login {
            shared.logged_in(c);
        }
        shared
    }

    /// A patient, loaded once and kept.
    pub fn atlas(&mut self, dir: &std::path::Path) -> Result<Arc<Atlas>, stylet_atlas::AtlasError> {
        if let Some((_, a)) = self.atlases.iter().find(|(d, _)| d == dir) {
            return Ok(Arc::clone(a));
        }
        let a = Arc::new(stylet_atlas::load(dir)?);
        self.atlases.push((dir.to_path_buf(), Arc::clone(&a)));
        Ok(a)
    }

    /// Uses a login from now on: the outbox uploads with its token (a retrier in the
    /// background, started on the first login).
    pub fn logged_in(&mut self, c: Credentials) {
        if let Ok(client) = ServiceClient::new(&c.server_url) {
            let uploader = Arc::new(TokenUploader {
                client,
                token: c.token.clone(),
            });
            match (&self.retrier, &self.outbox) {
                (Some(r), _) => r.set_uploader(uploader),
                (None, Some(outbox)) => match Outbox::open(outbox.dir()) {
                    Ok(o) => match Retrier::start(o, uploader, Backoff::default()) {
                        Ok(r) => self.retrier = Some(r),
                        Err(e) => self.outbox_problem = Some(Arc::new(e)),
                    },
                    Err(e) => self.outbox_problem = Some(Arc::new(e)),
                },
                (None, None) => {}
            }
        }
        self.login = Some(c);
    }

    /// Forgets the login (the stored token is deleted; queued sessions stay queued). At a lab
    /// machine the trainee's token is revoked on the service too (in the background; it expires
    /// by itself at the end of the lab day if the service cannot be reached).
    pub fn log_out(&mut self) {
        if let Some(dir) = &self.options.config_dir {
            let _ = std::fs::remove_file(dir.join(crate::credentials::FILE_NAME));
        }
        if let (Some(c), Some(_)) = (self.login.take(), &self.lab)
            && let Ok(client) = ServiceClient::new(&c.server_url)
        {
            std::thread::spawn(move || {
                if let Err(e) = client.sign_out(&c.token) {
                    eprintln!("stylet: signing out at the service failed ({e}); the token expires by itself");
                }
            });
        }
        self.login = None;
        // The retrier finishes the file it is sending before it stops: not on the window's thread.
        if let Some(r) = self.retrier.take() {
            std::thread::spawn(move || drop(r));
        }
    }

    /// Commands the tablet sent since the last call.
    pub fn tablet_commands(&self) -> Vec<crate::controls::Command> {
        self.tablet
            .as_ref()
            .map_or_else(Vec::new, |(_, rx)| rx.try_iter().collect())
    }

    /// Where the tablet page is and its pairing code (it changes), or why it is not there.
    pub fn tablet_line(&self) -> Option<String> {
        match (&self.tablet, &self.tablet_problem) {
            (Some((page, _)), _) => Some(format!(
                "tablet page: http://{} code {}",
                self.options.tablet.map_or_else(String::new, |a| a.to_string()),
                page.code()
            )),
            (None, Some(e)) => Some(format!("no tablet page: {e}")),
            (None, None) => None,
        }
    }

    /// Asks the retrier to try the outbox now.
    pub fn upload_now(&self) {
        if let Some(r) = &self.retrier {
            r.wake();
        }
    }

    /// The outbox names and service ids of the sessions uploaded since the window opened.
    pub fn uploaded(&self) -> Vec<(String, String)> {
        self.retrier.as_ref().map_or_else(Vec::new, |r| r.uploaded())
    }

    /// Sessions waiting for the service, and those the service refused (with its reason).
    pub fn outbox_counts(&self) -> (usize, usize) {
        self.outbox.as_ref().map_or((0, 0), |o| {
            (o.pending().map_or(0, |p| p.len()), o.refused().map_or(0, |r| r.len()))
        })
    }

    /// What the retrier's last round did, in words.
    pub fn upload_status(&self) -> String {
        let (pending, refused) = self.outbox_counts();
        let mut s = match (&self.login, pending) {
            (None, 0) => "offline; no session waiting".to_string(),
            (None, n) => format!("offline; {n} session(s) wait for a login"),
            (Some(c), 0) => format!("{} at {}: every session uploaded", c.username, c.server_url),
            (Some(c), n) => format!("{} at {}: {n} session(s) waiting", c.username, c.server_url),
        };
        if refused > 0 {
            s.push_str(&format!("; {refused} refused by the service"));
        }
        if let Some(Err(e)) = self.retrier.as_ref().and_then(|r| r.last_round()) {
            s.push_str(&format!("; last try: {e}"));
        }
        if let Some(p) = &self.outbox_problem {
            s.push_str(&format!("; outbox unusable: {p}"));
        }
        s
    }
}

/// The application: one screen at a time.
pub struct StyletApp {
    pub screen: Screen,
    pub shared: Shared,
    /// The start screen as it was left (its choices, a login under way), shown again on return.
    last_start: Option<Box<StartScreen>>,
}

/// What a screen asks for at the end of its frame.
pub enum Go {
    Start,
    Session(Box<SessionScreen>),
    Results(Box<ResultsScreen>),
    Loading(Box<replay_screen::LoadingReplay>),
    Replay(Box<ReplayScreen>),
}

impl StyletApp {
    pub fn new(ctx: &egui::Context, options: AppOptions) -> StyletApp {
        ctx.set_visuals(egui::Visuals::dark());
        let replay = options.replay.clone();
        let mut shared = Shared::new(options);
        let mut screen = Screen::Start(Box::new(StartScreen::new(&shared)));
        if let Some(path) = replay {
            match replay_screen::LoadingReplay::open_file(ctx, &mut shared, &path) {
                Ok(r) => screen = Screen::Loading(Box::new(r)),
                Err(e) => {
                    if let Screen::Start(s) = &mut screen {
                        s.problem = Some(e.to_string());
                    }
                }
            }
        }
        StyletApp {
            screen,
            shared,
            last_start: None,
        }
    }

    /// Draws the current screen and switches when it asks.
    pub fn show(&mut self, ui: &mut egui::Ui) {
        if !matches!(self.screen, Screen::Session(_)) {
            // Tablet presses outside a session are not kept for the next one.
            let _ = self.shared.tablet_commands();
        }
        let go = match &mut self.screen {
            Screen::Start(s) => s.ui(ui, &mut self.shared),
            Screen::Session(s) => s.ui(ui, &mut self.shared),
            Screen::Results(s) => s.ui(ui, &mut self.shared),
            Screen::Loading(s) => s.ui(ui, &mut self.shared),
            Screen::Replay(s) => s.ui(ui, &mut self.shared),
        };
        if let Some(go) = go {
            let next = match go {
                Go::Start => Screen::Start(
                    self.last_start
                        .take()
                        .unwrap_or_else(|| Box::new(StartScreen::new(&self.shared))),
                ),
                Go::Session(s) => Screen::Session(s),
                Go::Results(r) => Screen::Results(r),
                Go::Loading(l) => Screen::Loading(l),
                Go::Replay(r) => Screen::Replay(r),
            };
            if let Screen::Start(mut old) = std::mem::replace(&mut self.screen, next) {
                old.problem = None;
                self.last_start = Some(old);
            }
            ui.ctx().request_repaint();
        }
    }

    /// The window is closing: a session under way is finished and queued, not cut off.
    pub fn close(&mut self) {
        if let Screen::Session(s) = &mut self.screen {
            s.finish_now(&self.shared);
        }
    }
}

impl eframe::App for StyletApp {
    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        self.show(ui);
    }

    fn on_exit(&mut self) {
        self.close();
    }
}

/// Errors of the window itself.
#[derive(Debug, thiserror::Error)]
pub enum WindowError {
    #[error("cannot open the window: {0}")]
    Window(String),
}

/// Names a widget that has no visible label, for screen readers and tests.
pub(crate) fn name_widget(r: &egui::Response, role: egui::Role, name: &str) {
    r.widget_info(|| egui::WidgetInfo::labeled(role, r.enabled(), name));
}

/// The window thread's niceness (the drawing threads take `priority::DRAWING_NICENESS`).
pub const WINDOW_NICENESS: i32 = 10;

/// Opens the window and runs until it is closed.
pub fn run(options: AppOptions) -> Result<(), WindowError> {
    // The haptic loops start from a thread of normal priority; the window (and the software
    // renderer's threads it starts, on machines without a GPU) then yields to them.
    // Where the machine has more than one core, the haptic loop keeps one to itself: the window
    // and every thread it starts (drawing, the software renderer's) run on the others.
    crate::priority::reserve_a_core_for_the_haptic_loop();
    crate::haptic::keep_a_normal_priority_spawner().map_err(|e| WindowError::Window(e.to_string()))?;
    crate::priority::lower_this_thread(WINDOW_NICENESS);
    let native = eframe::NativeOptions {
        viewport: egui::ViewportBuilder::default()
            .with_title("Stylet — PTCD training")
            .with_inner_size([1280.0, 800.0]),
        ..Default::default()
    };
    eframe::run_native(
        "stylet",
        native,
        Box::new(move |cc| Ok(Box::new(StyletApp::new(&cc.egui_ctx, options)))),
    )
    .map_err(|e| WindowError::Window(e.to_string()))
}
