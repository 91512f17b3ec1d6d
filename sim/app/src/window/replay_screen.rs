//! The replay viewer for instructors and trainees: a session file replayed through the physics
//! (the same code as the scorer), played, paused and scrubbed at 0.25–8×, every view drawn again
//! from the replay, the force chart with a cursor, and jumps to the key moments.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::mpsc::{Receiver, TryRecvError};
use std::time::{Duration, Instant};

use eframe::egui;
use stylet_atlas::Atlas;

use super::chart::{force_chart, moment_color};
use super::panes::Panes;
use super::{Go, Shared};
use crate::replay_cursor::{OpenError, ReplayCursor};
use crate::service_client::{AddressError, FetchError};
use crate::view_worker::ViewWorker;
use crate::views::ViewSettings;

/// The speeds a replay plays at.
pub const SPEEDS: [f64; 6] = [0.25, 0.5, 1.0, 2.0, 4.0, 8.0];

/// The longest a frame spends replaying ticks (the rest of a long jump continues next frame).
const REPLAY_PER_FRAME: Duration = Duration::from_millis(30);

pub struct ReplayScreen {
    cursor: ReplayCursor,
    worker: ViewWorker,
    pub panes: Panes,
    path: PathBuf,
    pub playing: bool,
    pub speed: f64,
    /// Where the cursor should be (ticks replayed); it catches up frame by frame.
    target: f64,
    last_frame: Instant,
    problem: Option<String>,
}

/// Why a session cannot be opened in the replay viewer: the file, the service it is fetched
/// from, the patient it was recorded on, or the replay and drawing themselves.
#[derive(Debug, thiserror::Error)]
pub enum LoadReplayError {
    #[error("cannot read {}: {source}", path.display())]
    Unreadable {
        path: PathBuf,
        #[source]
        source: stylet_recorder::ReadError,
    },
    #[error("log in to fetch sessions from the service")]
    NotLoggedIn,
    /// The login's server address is not one the client may use.
    #[error(transparent)]
    Address(#[from] AddressError),
    #[error(transparent)]
    Fetch(#[from] FetchError),
    #[error("the fetched file {} cannot be read: {source}", path.display())]
    FetchedUnreadable {
        path: PathBuf,
        #[source]
        source: stylet_recorder::ReadError,
    },
    /// None of the window's atlases has the session's atlas hash.
    #[error(
        "the session {} was recorded on patient '{atlas_id}', which is not among this window's patients",
        path.display()
    )]
    UnknownPatient { path: PathBuf, atlas_id: String },
    #[error(transparent)]
    Open(#[from] OpenError),
    #[error("cannot start drawing: {0}")]
    Drawing(#[source] std::io::Error),
    #[error("the fetching thread stopped")]
    FetchThreadStopped,
    #[error("the replay thread stopped")]
    ReplayThreadStopped,
}

/// A session file being replayed and scored on a thread of its own (a long session takes
/// seconds); the viewer opens when it is done.
pub struct LoadingReplay {
    atlas: Option<Arc<Atlas>>,
    path: PathBuf,
    /// A file being fetched from the service first (its path and contents when it is here).
    fetching: Option<Receiver<Result<(PathBuf, stylet_recorder::reader::Session), LoadReplayError>>>,
    rx: Option<Receiver<Result<ReplayCursor, OpenError>>>,
    problem: Option<String>,
}

impl LoadingReplay {
    /// Opens a file, finding its patient among the window's atlases by the session's atlas hash.
    pub fn open_file(ctx: &egui::Context, shared: &mut Shared, path: &Path) -> Result<LoadingReplay, LoadReplayError> {
        let session = stylet_recorder::reader::recover(path).map_err(|source| LoadReplayError::Unreadable {
            path: path.to_path_buf(),
            source,
        })?;
        LoadingReplay::of_session(ctx, shared, path, session)
    }

    /// Fetches session `id` from the service (with the login's token) into the sessions folder,
    /// then replays it.
    pub fn fetch(ctx: &egui::Context, shared: &Shared, id: &str) -> Result<LoadingReplay, LoadReplayError> {
        let login = shared.login.clone().ok_or(LoadReplayError::NotLoggedIn)?;
        let client = crate::service_client::ServiceClient::new(&login.server_url)?;
        let (tx, rx) = std::sync::mpsc::channel();
        let (id, dir, repaint) = (id.trim().to_string(), shared.options.sessions_dir.clone(), ctx.clone());
        let shown = dir.join(format!("fetched-{id}.mcap"));
        std::thread::spawn(move || {
            let r = client
                .fetch_session(&login.token, &id, &dir)
                .map_err(LoadReplayError::Fetch)
                .and_then(|path| match stylet_recorder::reader::recover(&path) {
                    Ok(s) => Ok((path, s)),
                    Err(source) => Err(LoadReplayError::FetchedUnreadable { path, source }),
                });
            let _ = tx.send(r);
            repaint.request_repaint();
        });
        Ok(LoadingReplay {
            atlas: None,
            path: shown,
            fetching: Some(rx),
            rx: None,
            problem: None,
        })
    }

    fn of_session(
        ctx: &egui::Context,
        shared: &mut Shared,
        path: &Path,
        session: stylet_recorder::reader::Session,
    ) -> Result<LoadingReplay, LoadReplayError> {
        let want = session.header.atlas_hash.clone();
        let dirs = shared.options.atlases.clone();
        for dir in &dirs {
            // A patient that cannot be loaded is not this session's; the others may be.
            let Ok(atlas) = shared.atlas(dir) else { continue };
            if atlas.content_hash == want {
                return Ok(LoadingReplay::with_session(ctx, atlas, path, session));
            }
        }
        Err(LoadReplayError::UnknownPatient {
            path: path.to_path_buf(),
            atlas_id: session.header.atlas_id,
        })
    }

    /// Replays a file recorded on `atlas`.
    pub fn start(ctx: &egui::Context, atlas: Arc<Atlas>, path: &Path) -> LoadingReplay {
        let p = path.to_path_buf();
        LoadingReplay::replaying(ctx, atlas, path, move |a| ReplayCursor::open(a, &p))
    }

    fn with_session(
        ctx: &egui::Context,
        atlas: Arc<Atlas>,
        path: &Path,
        session: stylet_recorder::reader::Session,
    ) -> LoadingReplay {
        LoadingReplay::replaying(ctx, atlas, path, move |a| {
            ReplayCursor::of_session(a, Arc::new(session))
        })
    }

    /// Builds the cursor with `open` on a thread of its own (it replays and scores the file).
    fn replaying(
        ctx: &egui::Context,
        atlas: Arc<Atlas>,
        path: &Path,
        open: impl FnOnce(&Atlas) -> Result<ReplayCursor, crate::replay_cursor::OpenError> + Send + 'static,
    ) -> LoadingReplay {
        let (tx, rx) = std::sync::mpsc::channel();
        let (a, repaint) = (Arc::clone(&atlas), ctx.clone());
        std::thread::spawn(move || {
            let _ = tx.send(open(&a));
            repaint.request_repaint();
        });
        LoadingReplay {
            atlas: Some(atlas),
            path: path.to_path_buf(),
            fetching: None,
            rx: Some(rx),
            problem: None,
        }
    }

    /// What went wrong, if loading failed.
    pub fn problem(&self) -> Option<&str> {
        self.problem.as_deref()
    }

    pub fn ui(&mut self, ui: &mut egui::Ui, shared: &mut Shared) -> Option<Go> {
        if let (None, Some(rx)) = (&self.problem, &self.fetching) {
            match rx.try_recv() {
                Ok(Ok((path, session))) => match LoadingReplay::of_session(ui.ctx(), shared, &path, session) {
                    Ok(next) => *self = next,
                    Err(e) => self.problem = Some(e.to_string()),
                },
                Ok(Err(e)) => self.problem = Some(e.to_string()),
                Err(TryRecvError::Disconnected) => self.problem = Some(LoadReplayError::FetchThreadStopped.to_string()),
                Err(TryRecvError::Empty) => ui.ctx().request_repaint_after(Duration::from_millis(100)),
            }
        }
        if let (None, Some(rx), Some(atlas)) = (&self.problem, &self.rx, &self.atlas) {
            match rx.try_recv() {
                Ok(Ok(cursor)) => match ReplayScreen::new(ui.ctx(), shared, Arc::clone(atlas), &self.path, cursor) {
                    Ok(r) => return Some(Go::Replay(Box::new(r))),
                    Err(e) => self.problem = Some(e.to_string()),
                },
                Ok(Err(e)) => self.problem = Some(e.to_string()),
                Err(TryRecvError::Disconnected) => {
                    self.problem = Some(LoadReplayError::ReplayThreadStopped.to_string())
                }
                Err(TryRecvError::Empty) => ui.ctx().request_repaint_after(Duration::from_millis(100)),
            }
        }
        let mut go = None;
        egui::CentralPanel::default().show(ui, |ui| {
            ui.heading("Replay");
            ui.label(self.path.display().to_string());
            match &self.problem {
                None => {
                    ui.horizontal(|ui| {
                        ui.spinner();
                        ui.label(match self.fetching {
                            Some(_) => "Fetching the session from the service…",
                            None => "Replaying the session through the physics to score it and find its key moments…",
                        });
                    });
                }
                Some(p) => {
                    ui.colored_label(egui::Color32::from_rgb(255, 120, 100), p);
                }
            }
            if ui.button("Back").clicked() {
                go = Some(Go::Start);
            }
        });
        go
    }
}

impl ReplayScreen {
    fn new(
        ctx: &egui::Context,
        shared: &Shared,
        atlas: Arc<Atlas>,
        path: &Path,
        cursor: ReplayCursor,
    ) -> Result<ReplayScreen, LoadReplayError> {
        let repaint = ctx.clone();
        // Instructors see inside: risk tagging with the clipping plane through the tool.
        let settings = ViewSettings {
            budget: shared.options.view_budget,
            backend: shared.options.renderer,
            tagging: stylet_render::scene::Tagging::Risk,
            ..ViewSettings::default()
        };
        let worker = ViewWorker::start(
            atlas,
            settings,
            Box::new(move || repaint.request_repaint_after(Duration::from_millis(33))),
        )
        .map_err(LoadReplayError::Drawing)?;
        Ok(ReplayScreen {
            cursor,
            worker,
            panes: Panes::default(),
            path: path.to_path_buf(),
            playing: false,
            speed: 1.0,
            // The first tick: the patient is shown at once.
            target: 1.0,
            last_frame: Instant::now(),
            problem: None,
        })
    }

    pub fn cursor(&self) -> &ReplayCursor {
        &self.cursor
    }

    /// Jumps to `ticks` replayed (the cursor catches up over the next frames).
    pub fn jump_to(&mut self, ticks: u64) {
        self.target = ticks.clamp(1, self.cursor.end().max(1)) as f64;
    }

    /// The cursor is where it was asked to be and every pane shows it.
    pub fn settled(&self) -> bool {
        self.cursor.position() as f64 >= self.target.floor() && self.worker.is_current()
    }

    pub fn ui(&mut self, ui: &mut egui::Ui, _shared: &mut Shared) -> Option<Go> {
        let rate = f64::from(self.cursor.tick_rate_hz());
        // A gap in the recording ends the replay there.
        let total = self.cursor.end().max(1);
        self.target = self.target.min(total as f64);
        let dt = self.last_frame.elapsed().as_secs_f64().min(0.1);
        self.last_frame = Instant::now();
        if self.playing {
            self.target = (self.target + dt * self.speed * rate).min(total as f64);
            if self.target >= total as f64 {
                self.playing = false;
            }
        }
        let t0 = Instant::now();
        while (self.cursor.position() as f64) < self.target.floor() || (self.cursor.position() as f64) > self.target {
            match self.cursor.seek(self.target as u64, 500) {
                Ok(true) => break,
                Ok(false) => {}
                Err(e) => {
                    self.problem = Some(e.to_string());
                    self.playing = false;
                    break;
                }
            }
            if t0.elapsed() > REPLAY_PER_FRAME {
                break;
            }
        }
        let total = self.cursor.end().max(1);
        self.target = self.target.min(total as f64);
        let mut go = None;
        let position = self.cursor.position();
        let now_s = position as f64 / rate;
        let duration_s = self.cursor.total() as f64 / rate;
        let report = self.cursor.report().clone();
        let h = self.cursor.session().header.clone();

        egui::Panel::top("replay-top").show(ui, |ui| {
            ui.horizontal(|ui| {
                if ui.button("Back").clicked() {
                    go = Some(Go::Start);
                }
                ui.strong(format!(
                    "Replay: {} · {} · trainee {}",
                    h.scenario, h.difficulty, h.trainee
                ))
                .on_hover_text(self.path.display().to_string());
                ui.label(format!(
                    "{} {:.0}/100{}",
                    report.outcome.label(),
                    report.grade.score,
                    if report.replay_verified {
                        ", replay verified"
                    } else {
                        ", replay DIFFERED"
                    }
                ));
                let combo = egui::ComboBox::from_id_salt("replay-layout")
                    .selected_text(self.panes.layout.name())
                    .show_ui(ui, |ui| {
                        for l in super::Layout::ALL {
                            ui.selectable_value(&mut self.panes.layout, l, l.name());
                        }
                    });
                super::name_widget(&combo.response, egui::Role::ComboBox, "layout");
            });
            ui.horizontal(|ui| {
                if ui.button("|< Start").clicked() {
                    self.target = 1.0;
                }
                let label = if self.playing { "Pause" } else { "Play" };
                if ui.button(label).clicked() {
                    if !self.playing && position >= total {
                        self.target = 1.0;
                    }
                    self.playing = !self.playing;
                }
                let combo = egui::ComboBox::from_id_salt("speed")
                    .selected_text(format!("{}×", self.speed))
                    .width(60.0)
                    .show_ui(ui, |ui| {
                        for s in SPEEDS {
                            ui.selectable_value(&mut self.speed, s, format!("{s}×"));
                        }
                    });
                super::name_widget(&combo.response, egui::Role::ComboBox, "replay speed");
                // On ticks, shown in seconds: a slider that rounds what it shows never moves the
                // cursor by itself.
                let mut ticks = self.target.round() as u64;
                let slider = egui::Slider::new(&mut ticks, 1..=total.max(1))
                    .custom_formatter(move |v, _| format!("{:.3} s", v / rate))
                    .custom_parser(move |text| {
                        text.trim()
                            .trim_end_matches('s')
                            .trim()
                            .parse::<f64>()
                            .ok()
                            .map(|t| (t * rate).round())
                    })
                    .text(format!("of {duration_s:.1} s"));
                ui.spacing_mut().slider_width = (ui.available_width() - 180.0).max(120.0);
                if ui.add(slider).changed() {
                    self.target = ticks as f64;
                    self.playing = false;
                }
            });
            ui.horizontal_wrapped(|ui| {
                ui.label("Jump to:");
                for m in self.cursor.key_moments().to_vec() {
                    let text =
                        egui::RichText::new(format!("{} ({:.1} s)", m.label, m.time_s)).color(moment_color(m.kind));
                    if ui.button(text).clicked() {
                        self.target = m.ticks as f64;
                        self.playing = false;
                    }
                }
                if self.cursor.key_moments().is_empty() {
                    ui.weak("no key moments (the needle never entered)");
                }
            });
        });

        egui::Panel::bottom("replay-chart").exact_size(170.0).show(ui, |ui| {
            let size = egui::vec2(ui.available_width(), 150.0);
            let trace = self.cursor.trace().clone();
            let moments = self.cursor.key_moments().to_vec();
            if let Some(t) = force_chart(ui, size, &trace, &moments, now_s, duration_s) {
                // Position n shows tick n − 1 (at n − 1 periods).
                self.target = ((t * rate).round() + 1.0).clamp(1.0, total as f64);
                self.playing = false;
            }
            if self.cursor.end() < self.cursor.total() {
                ui.colored_label(
                    egui::Color32::from_rgb(220, 180, 80),
                    format!(
                        "The recording has a gap at {:.3} s (ticks were dropped while recording): the replay stops there.",
                        self.cursor.end() as f64 / rate
                    ),
                );
            }
            if let Some(p) = &self.problem {
                ui.colored_label(egui::Color32::from_rgb(255, 120, 100), p);
            }
        });

        let moment = self.cursor.moment();
        egui::CentralPanel::default().show(ui, |ui| {
            self.panes.ui(ui, &self.worker, moment.as_ref());
        });
        if self.playing || (self.cursor.position() as f64) < self.target.floor() {
            ui.ctx().request_repaint_after(Duration::from_millis(16));
        }
        go
    }
}
