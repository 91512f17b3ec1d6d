//! The Stylet desktop simulator (thesis §2.1, §6.2–6.3; docs/simulator.md).
//!
//! The window ([`window`], egui on wgpu, feature `window`) shows the start screen, the session,
//! the results and the replay viewer. Below it: the real-time haptic loop
//! ([`haptic`], paced by [`pacing`]), and the outbox that uploads finished sessions to the
//! scoring service and keeps them until the service confirms ([`outbox`]), and the views drawn
//! from the loop's snapshots at a resolution that keeps their frame budget ([`views`]) on a thread
//! of their own ([`view_worker`]); a session from start to score ([`session`]); the replay
//! viewer's cursor ([`replay_cursor`]).

pub mod controls;
pub mod credentials;
pub mod hands;
pub mod haptic;
pub mod outbox;
pub mod pacing;
pub mod priority;
pub mod publish_client;
pub mod replay_cursor;
pub mod service_client;
pub mod session;
pub mod skin_hint;
pub mod tablet;
pub mod upload;
pub mod view_worker;
pub mod views;
#[cfg(feature = "window")]
pub mod window;
