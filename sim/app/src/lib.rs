//! The egui/eframe desktop simulator (viewports, tools, workflow, recording, replay viewer).
//!
//! Empty on purpose: a later issue fills it. Nothing here pretends to work yet.
