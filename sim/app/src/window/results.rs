//! The results screen: the session's local score (a replay through the same physics, the same
//! scorer and rubric as the service), its reasons in plain words, and where its upload stands.

use std::sync::Arc;
use std::sync::mpsc::Receiver;

use eframe::egui;
use stylet_scoring::{Outcome, ScoreReport};

use super::replay_screen::LoadingReplay;
use super::{Go, Shared};
use crate::outbox::OutboxError;
use crate::session::{FinishedSession, ScoreFileError, SessionError};

/// Why the results screen shows no local score.
#[derive(Debug, thiserror::Error)]
pub enum NoScore {
    /// The session could not be finished properly: there is no file to score.
    #[error("{0}")]
    Unfinished(Arc<SessionError>),
    #[error(transparent)]
    Scoring(#[from] ScoreFileError),
    #[error("the scoring thread stopped")]
    ThreadStopped,
}

/// Why a finished session is not in the outbox (the file stays where it was recorded).
#[derive(Debug, thiserror::Error)]
pub enum NotQueued {
    /// The session could not be finished properly.
    #[error("{0}")]
    Unfinished(Arc<SessionError>),
    /// The outbox refused the file (unreadable, not a finished session, too large).
    #[error(transparent)]
    Add(#[from] OutboxError),
    /// The outbox could not be opened when the window started.
    #[error("{0}")]
    OutboxUnusable(Arc<OutboxError>),
    #[error("no outbox")]
    NoOutbox,
}

/// The local score: being computed, or its result.
#[allow(clippy::large_enum_variant, reason = "one per results screen")]
enum Scoring {
    Running(Receiver<Result<ScoreReport, ScoreFileError>>),
    Done(Result<ScoreReport, NoScore>),
}

pub struct ResultsScreen {
    finished: Option<FinishedSession>,
    scoring: Scoring,
    /// The session's name in the outbox, or why it could not be queued.
    queued: Result<String, NotQueued>,
    problem: Option<String>,
}

impl ResultsScreen {
    /// Queues the session for upload and scores it on a thread of its own.
    pub fn new(finished: FinishedSession, shared: &Shared) -> ResultsScreen {
        let queued = match &shared.outbox {
            Some(o) => o.add(&finished.path).map_err(NotQueued::Add),
            None => Err(shared
                .outbox_problem
                .clone()
                .map_or(NotQueued::NoOutbox, NotQueued::OutboxUnusable)),
        };
        shared.upload_now();
        let (tx, rx) = std::sync::mpsc::channel();
        let (atlas, path) = (std::sync::Arc::clone(&finished.plan.atlas), finished.path.clone());
        std::thread::spawn(move || {
            let _ = tx.send(crate::session::score_file(&atlas, &path));
        });
        ResultsScreen {
            finished: Some(finished),
            scoring: Scoring::Running(rx),
            queued,
            problem: None,
        }
    }

    /// A session that could not be finished properly.
    pub fn failed(why: SessionError) -> ResultsScreen {
        let why = Arc::new(why);
        ResultsScreen {
            finished: None,
            scoring: Scoring::Done(Err(NoScore::Unfinished(Arc::clone(&why)))),
            queued: Err(NotQueued::Unfinished(why)),
            problem: None,
        }
    }

    /// The local score, once computed.
    pub fn score(&self) -> Option<&Result<ScoreReport, NoScore>> {
        match &self.scoring {
            Scoring::Done(r) => Some(r),
            Scoring::Running(_) => None,
        }
    }

    pub fn finished(&self) -> Option<&FinishedSession> {
        self.finished.as_ref()
    }

    pub fn ui(&mut self, ui: &mut egui::Ui, shared: &mut Shared) -> Option<Go> {
        if let Scoring::Running(rx) = &self.scoring {
            match rx.try_recv() {
                Ok(r) => self.scoring = Scoring::Done(r.map_err(NoScore::Scoring)),
                Err(std::sync::mpsc::TryRecvError::Disconnected) => {
                    self.scoring = Scoring::Done(Err(NoScore::ThreadStopped))
                }
                Err(std::sync::mpsc::TryRecvError::Empty) => {
                    ui.ctx().request_repaint_after(std::time::Duration::from_millis(50))
                }
            }
        }
        let mut go = None;
        egui::CentralPanel::default().show(ui, |ui| {
            ui.heading("Results");
            if let Some(f) = &self.finished {
                let p = &f.plan;
                ui.label(format!(
                    "{} · {} · {} · trainee {}",
                    p.atlas.manifest.name,
                    p.scenario,
                    p.difficulty.as_str(),
                    p.trainee
                ));
                let s = f.report.stats;
                ui.label(format!("{} ticks; {} missed their deadline", s.ticks, s.missed));
            }
            ui.add_space(8.0);
            match &self.scoring {
                Scoring::Running(_) => {
                    ui.horizontal(|ui| {
                        ui.spinner();
                        ui.label("Scoring: replaying the session through the physics…");
                    });
                }
                Scoring::Done(Err(e)) => {
                    ui.colored_label(egui::Color32::from_rgb(255, 120, 100), format!("No score: {e}"));
                }
                Scoring::Done(Ok(r)) => report_ui(ui, r),
            }
            ui.add_space(8.0);
            ui.separator();
            match &self.queued {
                Ok(name) => {
                    let uploaded = shared.uploaded().into_iter().find(|(n, _)| n == name);
                    match uploaded {
                        Some((_, id)) => ui.label(format!("Uploaded: the service keeps it as session {id}.")),
                        None => ui.label(format!("Upload: queued in the outbox; {}", shared.upload_status())),
                    };
                }
                Err(e) => {
                    ui.colored_label(
                        egui::Color32::from_rgb(255, 120, 100),
                        format!("Not queued for upload: {e}. The file stays where it was recorded."),
                    );
                }
            }
            ui.add_space(12.0);
            ui.horizontal(|ui| {
                if ui.button("New session").clicked() {
                    go = Some(Go::Start);
                }
                if let Some(f) = &self.finished
                    && ui.button("Replay this session").clicked()
                {
                    go = Some(Go::Loading(Box::new(LoadingReplay::start(
                        ui.ctx(),
                        std::sync::Arc::clone(&f.plan.atlas),
                        &f.path,
                    ))));
                }
            });
            if let Some(p) = &self.problem {
                ui.colored_label(egui::Color32::from_rgb(255, 120, 100), p);
            }
            if let Some(f) = &self.finished {
                ui.add_space(8.0);
                egui::CollapsingHeader::new("File and upload details").show(ui, |ui| {
                    ui.label(format!("Recorded to {}", f.path.display()));
                    if let Ok(name) = &self.queued {
                        ui.label(format!(
                            "In the outbox ({}) as {name}",
                            shared.options.outbox_dir.display()
                        ));
                    }
                });
            }
        });
        go
    }
}

/// The outcome, the score against the pass mark, the reasons and the main metrics.
fn report_ui(ui: &mut egui::Ui, r: &ScoreReport) {
    let (color, word) = match r.outcome {
        Outcome::Passed => (egui::Color32::from_rgb(90, 200, 120), "Passed"),
        Outcome::Failed => (egui::Color32::from_rgb(230, 110, 90), "Failed"),
        Outcome::NotGradeable => (egui::Color32::from_rgb(220, 180, 80), "Not gradeable"),
    };
    ui.horizontal(|ui| {
        ui.label(egui::RichText::new(word).size(28.0).color(color).strong());
        let pass = r
            .grade
            .pass_score
            .map_or_else(String::new, |p| format!(" (pass mark {p:.0})"));
        ui.label(egui::RichText::new(format!("{:.0} / 100{pass}", r.grade.score)).size(22.0));
    });
    ui.label(if r.replay_verified {
        "Replay verified: the service will compute the same score from the file."
    } else {
        "The replay differed from the recording: the service will flag this session."
    });
    if !r.reasons.is_empty() {
        ui.add_space(6.0);
        ui.strong("Why");
        for reason in &r.reasons {
            ui.label(format!("• {reason}"));
        }
    }
    ui.add_space(6.0);
    let m = &r.metrics;
    egui::Grid::new("metrics").num_columns(2).striped(true).show(ui, |ui| {
        let mut row = |k: &str, v: String| {
            ui.label(k);
            ui.label(v);
            ui.end_row();
        };
        row("Attempts", m.attempts.to_string());
        row(
            "Risk structures hit",
            match m.risk_hits.is_empty() {
                true => "none".into(),
                false => m
                    .risk_hits
                    .iter()
                    .map(|h| h.structure.clone())
                    .collect::<Vec<_>>()
                    .join(", "),
            },
        );
        row("Target reached", if m.target_reached { "yes" } else { "no" }.into());
        row(
            "Time to target",
            m.time_to_target_s.map_or_else(|| "–".into(), |t| format!("{t:.1} s")),
        );
        row(
            "Fluoroscopy",
            format!("{:.1} s, {} shots", m.fluoro_time_s, m.xray_shots),
        );
        row("Contrast in the ducts", format!("{:.1} ml", m.contrast_in_ducts_ml));
        row("Largest force", format!("{:.1} N", m.max_force_n));
        if let Some(g) = &m.live_guidance {
            // Two hands: the needle advanced under the probe's live image.
            row(
                "Needle tip in the live ultrasound",
                format!("{:.0} % of the insertion", 100.0 * g.needle_tip_visible_share),
            );
            row("Longest blind advance", format!("{:.1} s", g.longest_blind_advance_s));
            row(
                "Tip at the target",
                match g.tip_in_view_at_target_entry {
                    Some(true) => "in view",
                    Some(false) => "out of view",
                    None => "–",
                }
                .into(),
            );
        }
        // What a wrong puncture did to the patient (docs/complications.md), as the review lists it.
        for c in &m.consequences {
            let name = c.kind.name();
            row(
                &format!("{}{} ({})", name[..1].to_uppercase(), &name[1..], c.structure),
                format!(
                    "{:.1} ml by the end; punctured at {:.1} s, began at {:.1} s",
                    c.volume_ml, c.punctured_s, c.began_s
                ),
            );
        }
    });
}
