//! Input devices for the simulator (DESIGN.md "Layout"): the `Device` trait and its backends —
//! scripted, replay, keyboard/mouse and HID (hidapi).
//!
//! Empty on purpose: the haptic-core issue fills it. Nothing here pretends to work yet.
