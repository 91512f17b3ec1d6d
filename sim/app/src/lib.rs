//! The Stylet desktop simulator (thesis §2.1, §6.2–6.3; docs/simulator.md).
//!
//! This crate holds what the simulator is made of below its windows: the real-time haptic loop
//! ([`haptic`], paced by [`pacing`]), and the outbox that uploads finished sessions to the
//! scoring service and keeps them until the service confirms ([`outbox`]), and the views drawn
//! from the loop's snapshots at a resolution that keeps their frame budget ([`views`]). The egui
//! window builds on these.

pub mod controls;
pub mod credentials;
pub mod haptic;
pub mod outbox;
pub mod pacing;
pub mod service_client;
pub mod tablet;
pub mod views;
