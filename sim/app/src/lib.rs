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

/// Values shared by the unit tests.
#[cfg(test)]
mod tests_support {
    use stylet_physics::TickOutput;
    use stylet_physics::glam::DVec3;

    /// A tick output with nothing happening (stylet in, X-ray off).
    pub fn output() -> TickOutput {
        TickOutput {
            tick: 0,
            time_s: 0.0,
            force_n: DVec3::ZERO,
            torque_nmm: DVec3::ZERO,
            components: Default::default(),
            insertion_dir: DVec3::Z,
            tip_label: 0,
            inserted_mm: 0.0,
            tip_mm: DVec3::ZERO,
            tip_depth_mm: 0.0,
            contacts: 0,
            indentation_mm: 0.0,
            stylet_in: true,
            xray_on: false,
            breath_hold: false,
            contrast_ml: 0.0,
            contrast_in_ducts_ml: 0.0,
            extravasated_ml: 0.0,
            contrast_extent_mm: 0.0,
        }
    }
}
