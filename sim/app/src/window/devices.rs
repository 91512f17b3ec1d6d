//! The devices dialog of the start screen: which device moves the needle hand, which (if any)
//! the probe hand and what that hand holds at the start (docs/simulator.md "Hands and devices").
//! The choice is remembered on this machine (`hands::HandAssignment::save`).

use eframe::egui;

use super::Shared;
use crate::hands::{Available, HandAssignment, InputDevice, SecondHandTool};
use crate::session::{Driver, HandDevice, LiveHands};

/// The dialog's draft, until it is saved or cancelled.
pub struct DevicesDialog {
    pub draft: HandAssignment,
}

/// What the dialog's frame decided.
pub enum DialogAction {
    Keep,
    Close,
}

/// A device's entry in a picker: its kind and, where known, the machine's name for it.
fn entry(available: &Available, device: InputDevice) -> String {
    match (device, available.name(device)) {
        (InputDevice::KeysAndMouse, _) => device.title().to_string(),
        (_, Ok(name)) => format!("{} ({name})", device.title()),
        (_, Err(_)) => format!("{} (not available)", device.title()),
    }
}

/// A picker of the devices, the unavailable ones greyed out with the reason.
fn device_picker(
    ui: &mut egui::Ui,
    id: &str,
    label: egui::Id,
    available: &Available,
    value: &mut Option<InputDevice>,
    none: Option<&str>,
) {
    let selected = value.map_or_else(|| none.unwrap_or("").to_string(), |d| entry(available, d));
    let combo = egui::ComboBox::from_id_salt(id)
        .selected_text(selected)
        .width(280.0)
        .show_ui(ui, |ui| {
            if let Some(none) = none {
                ui.selectable_value(value, None, none);
            }
            for d in InputDevice::ALL {
                let usable = available.name(d);
                let r = ui.add_enabled(
                    usable.is_ok(),
                    egui::Button::selectable(*value == Some(d), entry(available, d)),
                );
                let r = match &usable {
                    Err(e) => r.on_disabled_hover_text(e.to_string()),
                    Ok(_) => r,
                };
                if r.clicked() {
                    *value = Some(d);
                }
            }
        });
    combo.response.labelled_by(label);
}

impl DevicesDialog {
    pub fn new(current: HandAssignment) -> DevicesDialog {
        DevicesDialog { draft: current }
    }

    pub fn ui(&mut self, ctx: &egui::Context, shared: &mut Shared) -> DialogAction {
        let mut action = DialogAction::Keep;
        let modal = egui::Modal::new(egui::Id::unique("hands-and-devices")).show(ctx, |ui| {
            ui.set_max_width(560.0);
            ui.heading("Hands and devices");
            ui.label(
                "The needle hand holds the needle (and the tools the keypad selects). With a second \
                     device, the other hand holds the ultrasound probe at the same time: scan and \
                     puncture under live guidance. Each hand feels its own tool's force.",
            );
            ui.add_space(6.0);
            let available = shared.available.clone();
            egui::Grid::new("hands").num_columns(2).show(ui, |ui| {
                let l = ui.label("Needle hand");
                let mut needle = Some(self.draft.needle_hand);
                device_picker(ui, "needle-hand", l.id, &available, &mut needle, None);
                self.draft.needle_hand = needle.unwrap_or(InputDevice::KeysAndMouse);
                ui.end_row();
                let l = ui.label("Probe hand");
                device_picker(
                    ui,
                    "probe-hand",
                    l.id,
                    &available,
                    &mut self.draft.probe_hand,
                    Some("none: one hand, tools in turn"),
                );
                ui.end_row();
                let l = ui.label("Probe hand holds");
                ui.add_enabled_ui(self.draft.probe_hand.is_some(), |ui| {
                    let combo = egui::ComboBox::from_id_salt("probe-hand-tool")
                        .selected_text(self.draft.probe_hand_tool.title())
                        .show_ui(ui, |ui| {
                            for t in SecondHandTool::ALL {
                                ui.selectable_value(&mut self.draft.probe_hand_tool, t, t.title());
                            }
                        });
                    combo.response.labelled_by(l.id);
                });
                ui.end_row();
            });
            if self.draft.keys_steer().is_none() {
                ui.label("The keys and mouse then only give commands (tools, stylet, contrast, X-ray).");
            }
            let check = self.draft.check(&available);
            if let Err(e) = &check {
                ui.colored_label(egui::Color32::from_rgb(255, 120, 100), e.to_string());
            }
            ui.add_space(6.0);
            ui.horizontal(|ui| {
                if ui
                    .add_enabled(check.is_ok(), egui::Button::new("Use these devices"))
                    .clicked()
                {
                    shared.set_hands(self.draft);
                    action = DialogAction::Close;
                }
                if ui.button("Cancel").clicked() {
                    action = DialogAction::Close;
                }
            });
            if shared.options.config_dir.is_some() {
                ui.weak(format!(
                    "Remembered on this computer ({} in Stylet's configuration folder).",
                    crate::hands::FILE_NAME
                ));
            }
        });
        // Escape cancels (a click beside it does not: the click that opened it would close it).
        if modal.is_top_modal && ctx.input(|i| i.key_pressed(egui::Key::Escape)) {
            action = DialogAction::Close;
        }
        action
    }
}

impl Shared {
    /// The devices this window was started with and found, by name.
    pub fn probe_devices(options: &super::AppOptions) -> Available {
        Available::probe(
            options
                .haptic_device
                .as_ref()
                .map(|(d, _)| format!("{} device", d.backend)),
            options.hid_profile.as_ref().map(|p| p.name.clone()),
        )
    }

    /// Uses an assignment from now on and remembers it on this machine (where it cannot be
    /// written, it is used until the window closes and the reason is shown).
    pub fn set_hands(&mut self, hands: HandAssignment) {
        self.hands = hands;
        self.hands_problem = match &self.options.config_dir {
            Some(dir) => hands.save(dir).err().map(|e| format!("not remembered: {e}")),
            None => None,
        };
    }

    /// The live session's devices for the current assignment, or why it cannot be used.
    pub fn live_driver(&self) -> Result<Driver, crate::hands::AssignmentError> {
        self.hands.check(&self.available)?;
        let device = |d: InputDevice| -> Result<HandDevice, crate::hands::AssignmentError> {
            let unavailable = || crate::hands::AssignmentError::Unavailable {
                device: d,
                reason: "the window was not started with it".into(),
            };
            Ok(match d {
                InputDevice::KeysAndMouse => HandDevice::KeysAndMouse,
                InputDevice::SpaceMouse => HandDevice::SpaceMouse,
                InputDevice::Gamepad => HandDevice::Gamepad,
                InputDevice::ForceFeedback => {
                    let (choice, mapping) = self.options.haptic_device.as_ref().ok_or_else(unavailable)?;
                    HandDevice::ForceFeedback(choice.clone(), *mapping)
                }
                InputDevice::HidProfile => HandDevice::Hid(self.options.hid_profile.clone().ok_or_else(unavailable)?),
            })
        };
        let probe = match self.hands.probe_hand {
            Some(d) => Some((device(d)?, self.hands.probe_hand_tool.hand_tool())),
            None => None,
        };
        Ok(Driver::Live(LiveHands {
            needle: device(self.hands.needle_hand)?,
            probe,
        }))
    }
}
