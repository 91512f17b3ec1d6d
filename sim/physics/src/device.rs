//! Haptic device profiles: what the hardware can display (thesis §3.5.3; docs/scripts.md
//! "Devices").
//!
//! The maximum force and torque clamp every output; the stable stiffness k_max bounds the change of
//! the friction force per tick (eq. 3.5.5) and sets the base spring κ (eq. 3.5.7); the rotational
//! spring k_q = −(k_q0 + k_q_per_cm · inserted length in cm) of eq. 3.5.8 is in N·mm/rad.

/// A haptic device's display limits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeviceProfile {
    pub name: &'static str,
    /// Largest force the device displays (N); outputs are clamped to it.
    pub max_force_n: f64,
    /// Largest torque (N·mm); 0 for 3-DOF devices, which display no torque.
    pub max_torque_nmm: f64,
    /// Highest stiffness the device renders stably (N/mm): k_max of eq. 3.5.5.
    pub k_max_n_per_mm: f64,
    /// Base spring κ of eq. 3.5.7 (N/mm): as stiff as the device stays stable with.
    pub base_kappa_n_per_mm: f64,
    /// k_q0 of eq. 3.5.8 (N·mm/rad).
    pub torque_k0_nmm_per_rad: f64,
    /// Growth of k_q per cm of inserted needle (N·mm/rad/cm).
    pub torque_k_per_cm: f64,
}

impl DeviceProfile {
    /// 3D Systems (Geomagic) Touch: 3-DOF force, 3.3 N peak, stiffness 1.02–2.31 N/mm (maker's
    /// data sheet; the lowest axis is taken).
    pub const TOUCH: DeviceProfile = DeviceProfile {
        name: "touch",
        max_force_n: 3.3,
        max_torque_nmm: 0.0,
        k_max_n_per_mm: 1.02,
        base_kappa_n_per_mm: 0.5,
        torque_k0_nmm_per_rad: 300.0,
        torque_k_per_cm: 50.0,
    };

    /// Phantom Premium 1.5 6-DOF (the thesis' workbench): 8.5 N peak force, 515 N·mm peak
    /// torque, stiffness 3.5 N/mm (maker's data sheet).
    pub const PREMIUM: DeviceProfile = DeviceProfile {
        name: "premium",
        max_force_n: 8.5,
        max_torque_nmm: 515.0,
        k_max_n_per_mm: 3.5,
        base_kappa_n_per_mm: 1.5,
        torque_k0_nmm_per_rad: 300.0,
        torque_k_per_cm: 50.0,
    };

    /// An ideal device for headless experiments and tests: large limits, so the physics is seen
    /// unclipped.
    pub const IDEAL: DeviceProfile = DeviceProfile {
        name: "ideal",
        max_force_n: 100.0,
        max_torque_nmm: 5000.0,
        k_max_n_per_mm: 10.0,
        base_kappa_n_per_mm: 2.0,
        torque_k0_nmm_per_rad: 300.0,
        torque_k_per_cm: 50.0,
    };

    pub const ALL: [DeviceProfile; 3] = [DeviceProfile::TOUCH, DeviceProfile::PREMIUM, DeviceProfile::IDEAL];

    pub fn by_name(name: &str) -> Option<DeviceProfile> {
        DeviceProfile::ALL.into_iter().find(|d| d.name == name)
    }

    /// Whether the device displays torque (6-DOF output).
    pub fn has_torque(&self) -> bool {
        self.max_torque_nmm > 0.0
    }
}
