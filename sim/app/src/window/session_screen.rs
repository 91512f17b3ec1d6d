//! The session screen: the views, the tools and commands, the force and depth indicators, the
//! event console and the status bar with the haptic loop's rate and missed deadlines.
//!
//! The trainee's keys, mouse and buttons become a target pose and commands for the live device
//! (`controls`); the haptic loop does the rest. A scripted session only watches.

use std::sync::Arc;
use std::time::{Duration, Instant};

use eframe::egui;
use stylet_devices::command::{ExchangeStep, dilator_on};
use stylet_devices::haptic::Hold;
use stylet_devices::rate::RatePose;
use stylet_physics::glam::{DQuat, DVec3};
use stylet_physics::needle::spec::Gauge;
use stylet_physics::seldinger::passes;
use stylet_physics::wire::spec::WireDiameter;
use stylet_physics::{Event, ToolSpec};

use super::keys::Keyboard;
use super::panes::Panes;
use super::{Go, ResultsScreen, Shared};
use crate::controls::{self, Command, ControlInput, KeypadKey};
use crate::haptic::Snapshot;
use crate::session::{Driver, RunningSession, SessionError, SessionPlan};
use crate::view_worker::ViewWorker;

/// Full scale of the force bar (N): more than a needle meets in the liver (thesis Fig. 3.12).
pub const FORCE_BAR_N: f64 = 20.0;

/// A running session on screen.
pub struct SessionScreen {
    run: Option<RunningSession>,
    worker: ViewWorker,
    pub panes: Panes,
    /// The pose the keys and mouse steer (sessions by hand).
    pose: RatePose,
    /// The device frame's orientation in the world for the controls (x right, y away, z up).
    view: DQuat,
    pedal_down: bool,
    /// The physical keys down (kept across frames).
    keyboard: Keyboard,
    /// The gauge of the needle keypad 4 takes.
    pub gauge: Gauge,
    /// A dilator has been on the wire (the drainage's next step is then the catheter).
    dilated: bool,
    last_frame: Instant,
    rate: RateMeter,
    pub show_console: bool,
    problem: Option<String>,
}

/// The loop's tick rate over the last second or so.
struct RateMeter {
    at: Instant,
    ticks: u64,
    per_s: f64,
}

impl SessionScreen {
    /// Starts a session: its haptic loop and recording, and the drawing thread.
    pub fn start(
        ctx: &egui::Context,
        plan: SessionPlan,
        driver: Driver,
        shared: &Shared,
    ) -> Result<SessionScreen, SessionError> {
        let settings = crate::views::ViewSettings {
            budget: shared.options.view_budget,
            backend: shared.options.renderer,
            ..plan.view_settings()
        };
        // Commands the tablet sent before this session are not this session's.
        let _ = shared.tablet_commands();
        let atlas = Arc::clone(&plan.atlas);
        let run = RunningSession::start(plan, driver, shared.options.paced)?;
        let repaint = ctx.clone();
        let worker = ViewWorker::start(
            atlas,
            settings,
            Box::new(move || repaint.request_repaint_after(std::time::Duration::from_millis(33))),
        )?;
        let pose = run
            .steered_by_keys()
            .and_then(|l| l.pose())
            .map_or_else(RatePose::default, |(p, q)| RatePose {
                position_mm: p,
                orientation: q,
            });
        Ok(SessionScreen {
            run: Some(run),
            worker,
            panes: Panes::default(),
            pose,
            view: DQuat::IDENTITY,
            pedal_down: false,
            keyboard: Keyboard::default(),
            gauge: Gauge::G18,
            dilated: false,
            last_frame: Instant::now(),
            rate: RateMeter {
                at: Instant::now(),
                ticks: 0,
                per_s: 0.0,
            },
            show_console: true,
            problem: None,
        })
    }

    /// Finishes the session now (the window is closing): the recording is closed and the file
    /// queued for upload, so no finished session is lost.
    pub fn finish_now(&mut self, shared: &Shared) {
        if let Some(run) = self.run.take()
            && let Ok(done) = run.finish()
            && let Some(outbox) = &shared.outbox
        {
            let _ = outbox.add(&done.path);
        }
    }

    /// The session (until it is finished).
    pub fn running(&self) -> Option<&RunningSession> {
        self.run.as_ref()
    }

    /// Every pane shows the loop's latest state.
    pub fn views_current(&self) -> bool {
        self.worker.is_current()
    }

    pub fn ui(&mut self, ui: &mut egui::Ui, shared: &mut Shared) -> Option<Go> {
        let run = self.run.as_mut()?;
        let snapshot = run.snapshot();
        self.dilated |= snapshot.as_ref().is_some_and(|s| dilator_on(&s.output));
        let over = run.is_over();
        let mut finish = false;
        let dt = self.last_frame.elapsed().as_secs_f64().min(0.1);
        self.last_frame = Instant::now();
        let stats = run.stats();
        if self.rate.at.elapsed() >= Duration::from_secs(1) {
            let secs = self.rate.at.elapsed().as_secs_f64();
            self.rate.per_s = (stats.ticks - self.rate.ticks) as f64 / secs;
            self.rate = RateMeter {
                at: Instant::now(),
                ticks: stats.ticks,
                per_s: self.rate.per_s,
            };
        }
        let plan = run.plan.clone();
        let time_s = snapshot.as_ref().map_or(0.0, |s| s.output.time_s);

        egui::Panel::top("session-top").show(ui, |ui| {
            ui.horizontal(|ui| {
                ui.strong(format!(
                    "{} · {} · {}",
                    plan.atlas.manifest.name,
                    plan.scenario,
                    plan.difficulty.as_str()
                ));
                ui.label(format!("trainee {}", plan.trainee));
                if let Some(m) = hands_line(run) {
                    ui.label(m);
                }
                if let Some(t) = shared.tablet_line() {
                    ui.label(t);
                }
                ui.label(format!("t = {time_s:.1} s"));
                ui.separator();
                let combo = egui::ComboBox::from_id_salt("layout")
                    .selected_text(self.panes.layout.name())
                    .show_ui(ui, |ui| {
                        for l in super::Layout::ALL {
                            ui.selectable_value(&mut self.panes.layout, l, l.name());
                        }
                    });
                super::name_widget(&combo.response, egui::Role::ComboBox, "layout");
                ui.checkbox(&mut self.show_console, "console");
                ui.checkbox(&mut self.panes.show_timings, "frame times");
                if ui
                    .button(if over { "See the results" } else { "Finish (Enter)" })
                    .clicked()
                {
                    finish = true;
                }
            });
        });

        // Status bar first (bottom-most), then the console above it.
        egui::Panel::bottom("session-status").show(ui, |ui| {
            ui.horizontal_wrapped(|ui| {
                // First what the trainee needs: how far the tool is from the skin, or how deep.
                if let Some(s) = snapshot.as_ref() {
                    let hint = crate::skin_hint::skin_hint(tool_name(s), &s.output, &plan.atlas.model);
                    ui.strong(hint);
                    ui.separator();
                    if s.output.second_hand.is_some()
                        && let Some(tool) = s.second_tool
                    {
                        let word = match tool {
                            stylet_physics::HandTool::Finger => "finger",
                            stylet_physics::HandTool::Probe(_) => "probe",
                        };
                        let view = stylet_devices::two_hands::second_hand_view(&s.output);
                        let hint = crate::skin_hint::skin_hint(word, &view, &plan.atlas.model);
                        ui.strong(format!("probe hand: {hint}"));
                        ui.separator();
                    }
                }
                let missed_pct = 100.0 * stats.missed as f64 / stats.ticks.max(1) as f64;
                if over {
                    ui.label(format!(
                        "haptic loop ended after {} ticks; {} missed their deadline ({missed_pct:.1} %)",
                        stats.ticks, stats.missed
                    ));
                } else {
                    let rate = if self.panes.show_timings {
                        format!("{:.0} ticks/s", self.rate.per_s)
                    } else {
                        "running".into()
                    };
                    ui.label(format!(
                        "haptic loop {rate}; {} of {} ticks missed their deadline ({missed_pct:.2} %), worst {:.1} ms late",
                        stats.missed,
                        stats.ticks,
                        stats.worst_late.as_secs_f64() * 1e3
                    ));
                }
                if self.panes.show_timings {
                    if let Some(by) = self.worker.drawn_by() {
                        ui.separator();
                        ui.label(format!("views: {by}"));
                    }
                    for (kind, ms, scale) in self.panes.timings.iter().flatten() {
                        ui.separator();
                        ui.label(format!("{} {ms:.0} ms ({:.0} fps, scale {scale:.2})", kind.title(), 1e3 / ms.max(1e-3)));
                    }
                }
                let dropped = run.dropped_console_lines();
                if dropped > 0 {
                    ui.separator();
                    ui.label(format!("{dropped} console lines dropped"));
                }
                ui.separator();
                ui.label(format!("uploads: {}", shared.upload_status()));
            });
        });
        let console: Vec<String> = run
            .console()
            .iter()
            .map(|l| format!("{:8.3} s  {}", l.time_s, l.text))
            .collect();
        if self.show_console {
            egui::Panel::bottom("session-console")
                .resizable(true)
                .default_size(110.0)
                .show(ui, |ui| {
                    egui::ScrollArea::vertical().stick_to_bottom(true).show(ui, |ui| {
                        if console.is_empty() {
                            ui.weak(
                                "Events appear here: tools, stylet, X-ray, contrast, structures the needle enters.",
                            );
                        }
                        for line in &console {
                            ui.monospace(line);
                        }
                    });
                });
        }

        let mut commands: Vec<Command> = Vec::new();
        let mut second_tool = None;
        let mut pedal = self.pedal_down;
        egui::Panel::left("session-tools")
            .resizable(false)
            .exact_size(260.0)
            .show(ui, |ui| {
                // Two hands' indicators may not fit a small window: the panel scrolls.
                egui::ScrollArea::vertical().show(ui, |ui| {
                    tools_ui(ui, &mut commands, &mut pedal, &mut self.gauge);
                    if run.probe_live().is_some() {
                        ui.add_space(6.0);
                        probe_hand_ui(ui, &mut second_tool);
                    }
                    ui.separator();
                    indicators_ui(ui, snapshot.as_ref(), &plan);
                    drainage_ui(ui, snapshot.as_ref(), self.dilated);
                    if let Some(p) = &self.problem {
                        ui.colored_label(egui::Color32::from_rgb(255, 120, 100), p);
                    }
                    if over && run.live().is_none() {
                        ui.separator();
                        ui.label("The script has ended. Press “See the results” for the score.");
                    }
                });
            });

        let mut pictures = Vec::new();
        egui::CentralPanel::default().show(ui, |ui| {
            pictures = self.panes.ui(ui, &self.worker, snapshot.as_ref().map(|s| &s.moment));
        });

        // Keys (unless a text field has them) and the pointer over the pictures.
        let typing = ui.ctx().egui_wants_keyboard_input();
        let keyboard = &mut self.keyboard;
        let (input, keypad, pedal_key) = ui.input(|i| read_controls(i, keyboard, &pictures, typing));
        for k in keypad {
            match controls::keypad(k) {
                Some(Command::Finish) => finish = true,
                Some(Command::NextLayout) => self.panes.layout = self.panes.layout.next(),
                Some(c) => commands.push(c),
                None => {}
            }
        }
        pedal |= pedal_key;
        commands.extend(shared.tablet_commands());
        // The needle of keypad 4 (and the tablet's) has the gauge chosen in the tools panel, and
        // the exchange's wire is one that needle takes.
        for c in commands.iter_mut() {
            match c {
                Command::Tool(ToolSpec::Needle { gauge, .. }) => *gauge = self.gauge,
                Command::NextStep { wire } => *wire = wire_for(self.gauge),
                _ => {}
            }
        }
        let (from_tablet, commands): (Vec<Command>, Vec<Command>) = commands
            .into_iter()
            .partition(|c| matches!(c, Command::Finish | Command::NextLayout));
        for c in from_tablet {
            match c {
                Command::Finish => finish = true,
                _ => self.panes.layout = self.panes.layout.next(),
            }
        }
        // A force-feedback device pushes only while the window has the focus.
        let focused = ui.ctx().input(|i| i.focused);
        run.hold_forces(if focused { Hold::None } else { Hold::FocusLost });
        // The keys and mouse steer the hand no device of its own moves (if any); the devices
        // that move a tool by rate control move it in the window's view.
        if let Some(steered) = run.steered_by_keys() {
            controls::apply(&input, self.view, &mut self.pose, dt);
            steered.set_pose(self.pose.position_mm, self.pose.orientation);
        }
        for hand in [run.live(), run.probe_live()].into_iter().flatten() {
            hand.set_view(self.view);
        }
        // The commands are the needle hand's (its tool, the stylet, contrast, X-ray); the probe
        // hand's tool changes travel with them.
        if let Some(live) = run.live() {
            if pedal != self.pedal_down {
                live.send(if pedal { Event::XrayOn } else { Event::XrayOff });
            }
            if let Some(tool) = second_tool {
                live.send(Event::SecondTool(tool));
            }
            for c in commands {
                live.command(c);
            }
        }
        self.pedal_down = pedal;

        if !over {
            // 30 frames a second: the snapshots come at 62.5 Hz, the views far slower, and on
            // software rendering every window frame costs the loop's cores.
            ui.ctx().request_repaint_after(Duration::from_millis(33));
        }
        if finish {
            let run = self.run.take()?;
            return match run.finish() {
                Ok(done) => Some(Go::Results(Box::new(ResultsScreen::new(done, shared)))),
                Err(e) => Some(Go::Results(Box::new(ResultsScreen::failed(e)))),
            };
        }
        None
    }
}

/// The tool and command buttons (the keypad's keys in brackets).
fn tools_ui(ui: &mut egui::Ui, commands: &mut Vec<Command>, pedal: &mut bool, gauge: &mut Gauge) {
    ui.strong("Tools");
    for (digit, label) in [(1, "Finger (palpation)"), (2, "Linear probe"), (3, "Convex probe")] {
        if ui.button(format!("[{digit}] {label}")).clicked()
            && let Some(c) = controls::keypad(KeypadKey::Digit(digit))
        {
            commands.push(c);
        }
    }
    ui.horizontal(|ui| {
        if ui.button("[4] Needle, 150 mm").clicked()
            && let Some(c) = controls::keypad(KeypadKey::Digit(4))
        {
            commands.push(c);
        }
        let combo = egui::ComboBox::from_id_salt("gauge")
            .selected_text(format!("{} G", gauge.number()))
            .width(60.0)
            .show_ui(ui, |ui| {
                for g in Gauge::ALL {
                    ui.selectable_value(gauge, g, format!("{} G", g.number()));
                }
            });
        super::name_widget(&combo.response, egui::Role::ComboBox, "needle gauge");
    });
    ui.add_space(6.0);
    ui.strong("Commands");
    for (digit, label) in [
        (5, "Stylet out / in"),
        (6, "Inject 1 ml contrast"),
        (7, "Fluoroscopy on / off"),
        (8, "One X-ray shot"),
        (9, "Breath hold / release"),
    ] {
        if ui.button(format!("[{digit}] {label}")).clicked()
            && let Some(c) = controls::keypad(KeypadKey::Digit(digit))
        {
            commands.push(c);
        }
    }
    if ui.button("[+] Drainage: next step").clicked()
        && let Some(c) = controls::keypad(KeypadKey::Plus)
    {
        commands.push(c);
    }
    let pedal_button = ui.add(egui::Button::new("X-ray pedal (hold, or hold X)").sense(egui::Sense::click_and_drag()));
    *pedal = pedal_button.is_pointer_button_down_on();
}

/// The guide wire a needle of `gauge` takes: 0.035″ where it passes (the wire an 8 F drain goes
/// over), else 0.018″.
fn wire_for(gauge: Gauge) -> WireDiameter {
    if passes(gauge, WireDiameter::In035) {
        WireDiameter::In035
    } else {
        WireDiameter::In018
    }
}

/// The drainage (Seldinger exchange): where it stands and the step keypad + takes next.
fn drainage_ui(ui: &mut egui::Ui, snapshot: Option<&Snapshot>, dilated: bool) {
    let Some(o) = snapshot.map(|s| &s.output) else {
        return;
    };
    let next = ExchangeStep::next(o, dilated);
    if o.wire.is_none() && next.is_none() {
        return;
    }
    ui.add_space(6.0);
    ui.strong("Drainage");
    egui::Grid::new("drainage").num_columns(2).show(ui, |ui| {
        if let Some(w) = &o.wire {
            ui.label("Wire in the ducts");
            ui.label(if w.wire_in {
                format!("{:.0} mm", w.in_ducts_mm)
            } else {
                "out".into()
            });
            ui.end_row();
            if w.access_lost {
                ui.label("Access");
                ui.colored_label(egui::Color32::from_rgb(255, 120, 100), "lost");
                ui.end_row();
            }
            if let Some(t) = &w.over_wire {
                ui.label("On the wire");
                ui.label(format!(
                    "{} F {} ({:.0} mm in)",
                    t.size_fr,
                    t.kind.name(),
                    t.inserted_mm
                ));
                ui.end_row();
            }
            if let Some(c) = &w.catheter {
                ui.label("Catheter");
                ui.label(format!(
                    "{} of {} holes in the ducts, pigtail {}",
                    c.holes_in_ducts,
                    stylet_physics::seldinger::pigtail::DRAINAGE_HOLES,
                    if c.pigtail_in_ducts { "in the duct" } else { "outside" }
                ));
                ui.end_row();
            }
        }
        ui.label("Next [+ or N]");
        ui.label(next.map_or("—", ExchangeStep::label));
        ui.end_row();
    });
}

/// The force and depth indicators, the tool, and what the tip is in.
fn indicators_ui(ui: &mut egui::Ui, snapshot: Option<&Snapshot>, plan: &SessionPlan) {
    ui.strong("Indicators");
    let Some(s) = snapshot else {
        ui.weak("waiting for the first tick…");
        return;
    };
    let o = &s.output;
    let force = o.force_n.length();
    let color = if force > 0.75 * FORCE_BAR_N {
        egui::Color32::from_rgb(220, 80, 60)
    } else {
        egui::Color32::from_rgb(80, 160, 220)
    };
    ui.label("Force on the hand");
    ui.add(
        egui::ProgressBar::new((force / FORCE_BAR_N).clamp(0.0, 1.0) as f32)
            .fill(color)
            .text(format!("{force:.2} N")),
    );
    let tool = tool_name(s);
    egui::Grid::new("indicators").num_columns(2).show(ui, |ui| {
        ui.label("Tool");
        ui.label(tool);
        ui.end_row();
        if matches!(s.tool, ToolSpec::Needle { .. }) {
            ui.label("Along the needle");
            ui.label(format!("{:.2} N", -o.force_n.dot(o.insertion_dir)));
            ui.end_row();
            ui.label("Inserted");
            ui.label(format!("{:.1} mm", o.inserted_mm.max(0.0)));
            ui.end_row();
            ui.label("Tip under the skin");
            ui.label(format!("{:.1} mm", o.tip_depth_mm.max(0.0)));
            ui.end_row();
            ui.label("Tip in");
            let name = plan.atlas.model.label_table().name_of(o.tip_label).to_string();
            ui.label(if o.inserted_mm > 0.0 { name } else { "air".into() });
            ui.end_row();
            ui.label("Stylet");
            ui.label(if o.stylet_in { "in" } else { "out" });
            ui.end_row();
        } else {
            ui.label("Indentation");
            ui.label(format!("{:.1} mm", o.indentation_mm));
            ui.end_row();
        }
        ui.label("X-ray");
        ui.label(if o.xray_on { "ON" } else { "off" });
        ui.end_row();
        ui.label("Breathing");
        ui.label(if o.breath_hold { "held" } else { "free" });
        ui.end_row();
        ui.label("Contrast injected");
        ui.label(format!("{:.1} ml", o.contrast_ml));
        ui.end_row();
        ui.label("… in the ducts");
        ui.label(format!("{:.1} ml", o.contrast_in_ducts_ml));
        ui.end_row();
    });
    if let Some(path) = plan.guided_path()
        && let Some(dir) = path.direction()
    {
        let tip = if o.inserted_mm > 0.0 { o.tip_mm } else { s.position_mm };
        let off = distance_to_line(tip, path.entry_mm, dir);
        ui.label(format!("Planned path '{}': {off:.1} mm off", path.name));
    }
    if let Some(h) = &o.second_hand {
        // Two hands: the probe hand's tool, the force on it and its contact with the skin.
        ui.add_space(6.0);
        ui.strong("Probe hand");
        let force = h.force_n.length();
        ui.add(
            egui::ProgressBar::new((force / FORCE_BAR_N).clamp(0.0, 1.0) as f32)
                .fill(egui::Color32::from_rgb(80, 160, 220))
                .text(format!("{force:.2} N")),
        );
        egui::Grid::new("probe-hand").num_columns(2).show(ui, |ui| {
            ui.label("Tool");
            ui.label(second_tool_name(s.second_tool));
            ui.end_row();
            ui.label("On the skin");
            ui.label(match (h.holding, h.contacts) {
                (false, _) => "—".to_string(),
                (true, 0) => "not touching".to_string(),
                (true, n) => format!("{n} nodes, {:.1} mm deep", h.indentation_mm),
            });
            ui.end_row();
        });
    }
}

/// The probe hand's tool buttons (two-handed sessions).
fn probe_hand_ui(ui: &mut egui::Ui, tool: &mut Option<Option<stylet_physics::HandTool>>) {
    use stylet_physics::{HandTool, ProbeKind};
    ui.strong("Probe hand");
    ui.horizontal_wrapped(|ui| {
        for (label, t) in [
            ("Convex probe", Some(HandTool::Probe(ProbeKind::Convex))),
            ("Linear probe", Some(HandTool::Probe(ProbeKind::Linear))),
            ("Finger", Some(HandTool::Finger)),
            ("Put down", None),
        ] {
            let r = ui.button(label);
            super::name_widget(&r, egui::Role::Button, &format!("probe hand: {label}"));
            if r.clicked() {
                *tool = Some(t);
            }
        }
    });
}

/// Which device moves which hand, for the top bar; `None` for one hand on the keys and mouse.
fn hands_line(run: &crate::session::RunningSession) -> Option<String> {
    let keys = "keys and mouse";
    match (run.probe_live(), run.moved_by()) {
        (None, None) => None,
        (None, Some(m)) => Some(format!("moving with: {m}")),
        (Some(_), m) => Some(format!(
            "needle hand: {} · probe hand: {}",
            m.unwrap_or(keys),
            run.probe_moved_by().unwrap_or(keys)
        )),
    }
}

/// The second hand's tool in words.
fn second_tool_name(tool: Option<stylet_physics::HandTool>) -> &'static str {
    use stylet_physics::{HandTool, ProbeKind};
    match tool {
        Some(HandTool::Probe(ProbeKind::Convex)) => "convex probe",
        Some(HandTool::Probe(ProbeKind::Linear)) => "linear probe",
        Some(HandTool::Finger) => "finger",
        None => "none",
    }
}

/// The first hand's tool at the snapshot.
fn tool_name(s: &Snapshot) -> &'static str {
    match s.tool {
        ToolSpec::Needle { .. } => "needle",
        ToolSpec::Probe(_) => "probe",
        ToolSpec::Finger => "finger",
    }
}

/// Distance of `p` from the line through `a` along the unit vector `d`.
fn distance_to_line(p: DVec3, a: DVec3, d: DVec3) -> f64 {
    let v = p - a;
    (v - d * v.dot(d)).length()
}

/// Reads one frame of controls: the keys (every event of the frame, by physical key), drags and
/// wheel over the pictures.
fn read_controls(
    i: &egui::InputState,
    keyboard: &mut Keyboard,
    pictures: &[egui::Response],
    typing: bool,
) -> (ControlInput, Vec<KeypadKey>, bool) {
    let keys = keyboard.frame(&i.events, typing, i.modifiers.shift);
    let mut input = ControlInput {
        held: keys.held,
        ..ControlInput::default()
    };
    for r in pictures {
        if r.dragged_by(egui::PointerButton::Primary) {
            let d = r.drag_delta();
            input.drag_px = [f64::from(d.x), f64::from(d.y)];
        }
        if r.dragged_by(egui::PointerButton::Secondary) {
            let d = r.drag_delta();
            input.aim_px = [f64::from(d.x), f64::from(d.y)];
        }
        if r.hovered() {
            for e in &i.events {
                if let egui::Event::MouseWheel { unit, delta, .. } = e {
                    input.wheel_notches += match unit {
                        egui::MouseWheelUnit::Line => f64::from(delta.y),
                        egui::MouseWheelUnit::Point => f64::from(delta.y) / 50.0,
                        egui::MouseWheelUnit::Page => f64::from(delta.y) * 10.0,
                    };
                }
            }
        }
    }
    (input, keys.commands, keys.pedal)
}
