//! The start screen: log in to a scoring service (an upload-only API token, kept in the user's
//! configuration folder) or work offline; choose the patient, the scenario and the difficulty;
//! start a session, or open a session file in the replay viewer.

use std::path::PathBuf;
use std::sync::mpsc::{Receiver, TryRecvError};

use eframe::egui;

use super::replay_screen::LoadingReplay;
use super::{Go, SessionScreen, Shared};
use crate::credentials::{Credentials, CredentialsError, LabMachine};
use crate::service_client::{LoginError, Pairing, ServiceClient};
use crate::session::{Difficulty, Driver, SessionPlan};
use stylet_atlas::manifest::ScenarioKind;

/// Why a login from the start screen did not leave a usable login behind.
#[derive(Debug, thiserror::Error)]
enum LoginFailure {
    #[error(transparent)]
    Service(#[from] LoginError),
    /// The service gave a token, but it cannot be written to the configuration folder.
    #[error("logged in, but the token cannot be kept: {0}")]
    NotKept(#[source] CredentialsError),
}

/// What a login, a pairing or a sign-in at a lab machine left behind.
enum Joined {
    /// An account's upload token (kept in the configuration folder unless signed in at a lab
    /// machine).
    Account(Credentials),
    /// This computer, now a lab machine of a cohort.
    Lab(LabMachine),
}

/// The start screen's fields.
pub struct StartScreen {
    pub server_url: String,
    pub username: String,
    password: String,
    /// A pairing code from the dashboard ("Pair a simulator"): for this computer, or a
    /// trainee's sign-in code at a lab machine.
    pub pairing_code: String,
    /// A login, pairing or sign-in under way on its own thread.
    login: Option<Receiver<Result<Joined, LoginFailure>>>,
    pub atlas_index: usize,
    pub scenario: String,
    pub difficulty: Difficulty,
    /// The name sessions are recorded under when offline.
    pub offline_name: String,
    pub replay_path: String,
    /// A session id on the service, to fetch and replay.
    pub fetch_id: String,
    /// The last thing that went wrong, shown until the next action.
    pub problem: Option<String>,
    /// Offer the scripted examples and grading fixtures too (instructors, demos); a trainee's
    /// picker lists the training scenarios only.
    pub show_examples: bool,
    /// The devices dialog, while it is open.
    devices: Option<super::devices::DevicesDialog>,
}

impl StartScreen {
    pub fn new(shared: &Shared) -> StartScreen {
        let (server_url, username) = shared.login.as_ref().map_or_else(
            || ("https://".to_string(), String::new()),
            |c| (c.server_url.clone(), c.username.clone()),
        );
        StartScreen {
            server_url,
            username,
            password: String::new(),
            pairing_code: String::new(),
            login: None,
            atlas_index: 0,
            scenario: String::new(),
            difficulty: Difficulty::Beginner,
            offline_name: "trainee".into(),
            show_examples: false,
            replay_path: String::new(),
            fetch_id: String::new(),
            problem: None,
            devices: None,
        }
    }

    pub fn ui(&mut self, ui: &mut egui::Ui, shared: &mut Shared) -> Option<Go> {
        self.poll_login(shared);
        if let Some(d) = &mut self.devices
            && matches!(d.ui(ui.ctx(), shared), super::devices::DialogAction::Close)
        {
            self.devices = None;
        }
        let mut go = None;
        egui::CentralPanel::default().show(ui, |ui| {
            ui.heading("Stylet — percutaneous transhepatic cholangiodrainage (PTCD)");
            ui.label("Train the puncture on a virtual patient built from a CT: palpate, scan, puncture, confirm.");
            ui.add_space(12.0);
            ui.columns(2, |cols| {
                self.account_ui(&mut cols[0], shared);
                go = self.exercise_ui(&mut cols[1], shared);
            });
            ui.add_space(12.0);
            ui.separator();
            ui.label(format!("Uploads: {}", shared.upload_status()));
            if let Some(t) = shared.tablet_line() {
                ui.label(t);
            }
            if let Some(p) = &self.problem {
                ui.colored_label(egui::Color32::from_rgb(255, 120, 100), p);
            }
        });
        go
    }

    fn account_ui(&mut self, ui: &mut egui::Ui, shared: &mut Shared) {
        ui.strong("Scoring service");
        let busy = self.login.is_some();
        match (shared.login.clone(), shared.lab.clone()) {
            (Some(c), lab) => {
                match &lab {
                    Some(lab) => ui.label(format!(
                        "Signed in as {} at this lab machine of cohort {}",
                        c.username, lab.cohort
                    )),
                    None => ui.label(format!("Logged in as {} at {}", c.username, c.server_url)),
                };
                ui.label("Sessions upload by themselves; a session waits in the outbox while the service is down.");
                ui.horizontal(|ui| {
                    if ui.button("Upload waiting sessions now").clicked() {
                        shared.upload_now();
                    }
                    let out = if lab.is_some() { "Sign out" } else { "Log out" };
                    if ui.button(out).clicked() {
                        shared.log_out();
                    }
                });
            }
            (None, Some(lab)) => {
                ui.label(format!("Lab machine of cohort {} at {}", lab.cohort, lab.server_url));
                ui.label("Trainees sign in one after another: show a sign-in code on your dashboard page \"Pair a simulator\".");
                ui.horizontal(|ui| {
                    let l = ui.label("Sign in with your code");
                    ui.text_edit_singleline(&mut self.pairing_code).labelled_by(l.id);
                    if ui.add_enabled(!busy, egui::Button::new("Sign in")).clicked() {
                        self.start_sign_in(&lab);
                    }
                    if busy {
                        ui.spinner();
                    }
                });
                if ui.button("Unpair this lab machine").clicked()
                    && let Some(dir) = &shared.options.config_dir
                {
                    LabMachine::forget(dir);
                    shared.lab = None;
                }
            }
            (None, None) => {
                egui::Grid::new("login").num_columns(2).show(ui, |ui| {
                    let l = ui.label("Server");
                    ui.text_edit_singleline(&mut self.server_url).labelled_by(l.id);
                    ui.end_row();
                    let l = ui.label("Account");
                    ui.text_edit_singleline(&mut self.username).labelled_by(l.id);
                    ui.end_row();
                    let l = ui.label("Password");
                    ui.add(egui::TextEdit::singleline(&mut self.password).password(true))
                        .labelled_by(l.id);
                    ui.end_row();
                    let l = ui.label("Pairing code");
                    ui.text_edit_singleline(&mut self.pairing_code).labelled_by(l.id);
                    ui.end_row();
                });
                ui.horizontal(|ui| {
                    if ui.add_enabled(!busy, egui::Button::new("Log in")).clicked() {
                        self.start_login(shared);
                    }
                    if ui.add_enabled(!busy, egui::Button::new("Pair")).clicked() {
                        self.start_pairing(shared);
                    }
                    if busy {
                        ui.spinner();
                        ui.label("connecting…");
                    }
                });
                ui.label(
                    "Log in with your password, or pair with a code from the dashboard's page \"Pair a simulator\".",
                );
                ui.add_space(8.0);
                ui.label("Or work offline: sessions are scored here and wait in the outbox until you log in.");
                ui.horizontal(|ui| {
                    let l = ui.label("Your name");
                    ui.text_edit_singleline(&mut self.offline_name).labelled_by(l.id);
                });
            }
        }
    }

    /// The service at the typed address, or the problem shown.
    fn client(&mut self, base: &str) -> Option<ServiceClient> {
        self.problem = None;
        match ServiceClient::new(base.trim()) {
            Ok(c) => Some(c),
            Err(e) => {
                self.problem = Some(e.to_string());
                None
            }
        }
    }

    /// Logs in on a thread of its own: the password is used once for an upload-only token and
    /// never stored.
    fn start_login(&mut self, shared: &Shared) {
        let Some(client) = self.client(&self.server_url.clone()) else {
            return;
        };
        let (username, password) = (self.username.trim().to_string(), std::mem::take(&mut self.password));
        let config_dir = shared.options.config_dir.clone();
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let result = client
                .upload_token(&username, &password, &this_computer())
                .map_err(LoginFailure::Service)
                .and_then(|token| {
                    let c = Credentials {
                        server_url: client.base().to_string(),
                        username,
                        token,
                    };
                    if let Some(dir) = config_dir {
                        c.save(&dir).map_err(LoginFailure::NotKept)?;
                    }
                    Ok(Joined::Account(c))
                });
            let _ = tx.send(result);
        });
        self.login = Some(rx);
    }

    /// Pairs with a code on a thread of its own: this computer gets an upload token of the
    /// code's account, or becomes a lab machine; either is kept in the configuration folder.
    fn start_pairing(&mut self, shared: &Shared) {
        let Some(client) = self.client(&self.server_url.clone()) else {
            return;
        };
        let code = std::mem::take(&mut self.pairing_code);
        let config_dir = shared.options.config_dir.clone();
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let result = client
                .pair(&code, &this_computer())
                .map_err(LoginFailure::Service)
                .and_then(|paired| {
                    let server_url = client.base().to_string();
                    let joined = match paired {
                        Pairing::Account { username, token } => Joined::Account(Credentials {
                            server_url,
                            username,
                            token,
                        }),
                        Pairing::Lab { cohort, lab_token } => Joined::Lab(LabMachine {
                            server_url,
                            cohort,
                            lab_token,
                        }),
                    };
                    if let Some(dir) = config_dir {
                        match &joined {
                            Joined::Account(c) => c.save(&dir),
                            Joined::Lab(lab) => lab.save(&dir),
                        }
                        .map_err(LoginFailure::NotKept)?;
                    }
                    Ok(joined)
                });
            let _ = tx.send(result);
        });
        self.login = Some(rx);
    }

    /// Signs a trainee in at this lab machine with their code, on a thread of its own; their
    /// token stays in memory (the next trainee must not inherit it).
    fn start_sign_in(&mut self, lab: &LabMachine) {
        let Some(client) = self.client(&lab.server_url) else {
            return;
        };
        let (code, lab_token) = (std::mem::take(&mut self.pairing_code), lab.lab_token.clone());
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let result = client
                .lab_sign_in(&lab_token, &code)
                .map(|(username, token)| {
                    Joined::Account(Credentials {
                        server_url: client.base().to_string(),
                        username,
                        token,
                    })
                })
                .map_err(LoginFailure::Service);
            let _ = tx.send(result);
        });
        self.login = Some(rx);
    }

    fn poll_login(&mut self, shared: &mut Shared) {
        let Some(rx) = &self.login else { return };
        match rx.try_recv() {
            Ok(Ok(Joined::Account(c))) => {
                shared.logged_in(c);
                self.login = None;
            }
            Ok(Ok(Joined::Lab(lab))) => {
                shared.lab = Some(lab);
                self.login = None;
            }
            Ok(Err(e)) => {
                self.problem = Some(format!("not connected: {e}"));
                self.login = None;
            }
            Err(TryRecvError::Empty) => {}
            Err(TryRecvError::Disconnected) => self.login = None,
        }
    }

    fn exercise_ui(&mut self, ui: &mut egui::Ui, shared: &mut Shared) -> Option<Go> {
        ui.strong("Exercise");
        let atlases: Vec<PathBuf> = shared.options.atlases.clone();
        if atlases.is_empty() {
            ui.label("No patient: start with --atlas DIR (docs/simulator.md).");
            return None;
        }
        self.atlas_index = self.atlas_index.min(atlases.len() - 1);
        let dir = atlases[self.atlas_index].clone();
        let atlas = match shared.atlas(&dir) {
            Ok(a) => Some(a),
            Err(e) => {
                ui.colored_label(
                    egui::Color32::from_rgb(255, 120, 100),
                    format!("{}: {e}", dir.display()),
                );
                None
            }
        };
        // A scripted window (demos, tests) may run any scenario; a trainee is offered training.
        let all = self.show_examples || shared.options.script.is_some();
        let scenarios: Vec<(String, String)> = atlas.as_ref().map_or_else(Vec::new, |a| {
            a.manifest
                .scenarios
                .iter()
                .filter(|s| all || s.kind() == ScenarioKind::Training)
                .map(|s| (s.name.clone(), s.description.clone()))
                .collect()
        });
        if !scenarios.iter().any(|(n, _)| n == &self.scenario) {
            self.scenario = scenarios.first().map_or_else(|| "ptcd".to_string(), |s| s.0.clone());
        }
        egui::Grid::new("exercise").num_columns(2).show(ui, |ui| {
            let l = ui.label("Patient");
            egui::ComboBox::from_id_salt("patient")
                .selected_text(atlas_name(&dir))
                .show_ui(ui, |ui| {
                    for (i, d) in atlases.iter().enumerate() {
                        ui.selectable_value(&mut self.atlas_index, i, atlas_name(d));
                    }
                })
                .response
                .labelled_by(l.id);
            ui.end_row();
            let l = ui.label("Scenario");
            egui::ComboBox::from_id_salt("scenario")
                .selected_text(self.scenario.clone())
                .show_ui(ui, |ui| {
                    for (name, description) in &scenarios {
                        ui.selectable_value(&mut self.scenario, name.clone(), name)
                            .on_hover_text(description);
                    }
                })
                .response
                .labelled_by(l.id);
            ui.end_row();
            ui.label("Difficulty");
            ui.horizontal(|ui| {
                for d in Difficulty::ALL {
                    ui.selectable_value(&mut self.difficulty, d, d.as_str());
                }
            });
            ui.end_row();
        });
        if let Some((_, desc)) = scenarios.iter().find(|(n, _)| n == &self.scenario)
            && !desc.is_empty()
        {
            ui.label(desc);
        }
        ui.checkbox(&mut self.show_examples, "Also offer the examples and test scenarios");
        if let Some(a) = &atlas {
            let plan = self.plan(a, shared);
            let aids = plan.aids();
            let mut list = Vec::new();
            if aids.risk_overlay || aids.target_overlay {
                list.push("clipping with risk tagging");
            }
            if aids.needle_guide {
                list.push("needle guide in the ultrasound");
            }
            if aids.guided_path.is_some() {
                list.push("planned path");
            }
            ui.label(match list.is_empty() {
                true => "Aids: none".to_string(),
                false => format!("Aids: {}", list.join(", ")),
            });
        }
        ui.add_space(8.0);
        let mut go = None;
        let driven = shared.options.script.clone();
        if driven.is_none() {
            ui.horizontal(|ui| {
                ui.label(format!("Devices: {}", shared.hands.describe()));
                if ui.button("Devices…").clicked() {
                    self.devices = Some(super::devices::DevicesDialog::new(shared.hands));
                }
            });
            if let Some(p) = &shared.hands_problem {
                ui.colored_label(egui::Color32::from_rgb(255, 120, 100), p);
            }
        }
        let label = match (&driven, shared.hands.probe_hand, shared.hands.needle_hand) {
            (Some(_), _, _) => "Start session (scripted)".to_string(),
            (None, Some(_), _) => "Start session with two hands".to_string(),
            (None, None, crate::hands::InputDevice::KeysAndMouse) => "Start session".to_string(),
            (None, None, d) => format!("Start session with the {}", d.title()),
        };
        if ui
            .add_enabled(
                atlas.is_some() && self.devices.is_none(),
                egui::Button::new(label).min_size(egui::vec2(180.0, 32.0)),
            )
            .clicked()
            && let Some(a) = &atlas
        {
            let driver = match &driven {
                Some(path) => match std::fs::read_to_string(path) {
                    Ok(text) => Some(Driver::Script(text)),
                    Err(e) => {
                        self.problem = Some(format!("cannot read the script {}: {e}", path.display()));
                        None
                    }
                },
                None => match shared.live_driver() {
                    Ok(d) => Some(d),
                    Err(e) => {
                        self.problem = Some(format!("{e} (Devices… to choose another)"));
                        None
                    }
                },
            };
            if let Some(driver) = driver {
                match SessionScreen::start(ui.ctx(), self.plan(a, shared), driver, shared) {
                    Ok(s) => go = Some(Go::Session(Box::new(s))),
                    Err(e) => self.problem = Some(e.to_string()),
                }
            }
        }
        ui.add_space(16.0);
        ui.strong("Replay a session");
        ui.horizontal(|ui| {
            let l = ui.label("Session file");
            ui.text_edit_singleline(&mut self.replay_path).labelled_by(l.id);
            if ui.button("Open replay").clicked() {
                let path = PathBuf::from(self.replay_path.trim());
                match LoadingReplay::open_file(ui.ctx(), shared, &path) {
                    Ok(r) => go = Some(Go::Loading(Box::new(r))),
                    Err(e) => self.problem = Some(e.to_string()),
                }
            }
        });
        if shared.login.is_some() {
            ui.horizontal(|ui| {
                let l = ui.label("Session id on the service");
                ui.text_edit_singleline(&mut self.fetch_id).labelled_by(l.id);
                if ui.button("Fetch and replay").clicked() {
                    match LoadingReplay::fetch(ui.ctx(), shared, &self.fetch_id) {
                        Ok(r) => go = Some(Go::Loading(Box::new(r))),
                        Err(e) => self.problem = Some(e.to_string()),
                    }
                }
            });
        }
        go
    }

    fn plan(&self, atlas: &std::sync::Arc<stylet_atlas::Atlas>, shared: &Shared) -> SessionPlan {
        let trainee = shared
            .login
            .as_ref()
            .map_or_else(|| self.offline_name.trim().to_string(), |c| c.username.clone());
        SessionPlan {
            atlas: std::sync::Arc::clone(atlas),
            scenario: self.scenario.clone(),
            difficulty: self.difficulty,
            trainee: if trainee.is_empty() { "trainee".into() } else { trainee },
            seed: 0,
            sessions_dir: shared.options.sessions_dir.clone(),
        }
    }
}

fn atlas_name(dir: &std::path::Path) -> String {
    dir.file_name()
        .map_or_else(|| dir.display().to_string(), |n| n.to_string_lossy().into_owned())
}

/// How this computer is named on the service (its tokens' and lab machine's label).
fn this_computer() -> String {
    let host = std::env::var("HOSTNAME").unwrap_or_else(|_| "this computer".into());
    format!("stylet sim on {host}")
}
