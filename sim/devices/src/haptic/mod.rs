//! Force-feedback devices (docs/devices.md "Haptic devices"): one interface over the vendors' APIs,
//! loaded at run time so a binary built without any SDK runs everywhere and finds a device where
//! its SDK is installed. Each backend runs the device's servo loop (the vendor's scheduler, or a
//! thread of its own) and exchanges poses and forces with the simulation through [`mailbox`]es
//! that never block it; every force passes the [`safety`] guard on its way to the hand.

pub mod check;
pub mod dhd;
pub mod haply;
pub mod library;
pub mod mailbox;
pub mod openhaptics;
pub mod pose;
pub mod safety;
mod servo;
mod servo_thread;

use std::path::PathBuf;

use stylet_physics::glam::{DMat3, DVec3};

pub use safety::{Computed, ForceGuard, GuardCounts, Guarded, Hold, Limits, SafetyLimits};

/// The vendor API a device is reached through.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Backend {
    /// 3D Systems OpenHaptics HD API: Touch, Touch X, Phantom Premium.
    OpenHaptics,
    /// Force Dimension DHD: omega, sigma, delta, Novint Falcon.
    Dhd,
    /// Haply Inverse3 through the Inverse Service's WebSocket API.
    Haply,
}

impl Backend {
    pub fn name(self) -> &'static str {
        match self {
            Backend::OpenHaptics => "openhaptics",
            Backend::Dhd => "dhd",
            Backend::Haply => "haply",
        }
    }
}

impl std::fmt::Display for Backend {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// What an open device says about itself.
#[derive(Debug, Clone, PartialEq)]
pub struct DeviceInfo {
    pub backend: Backend,
    /// The vendor's model name ("Touch", "omega.6", …).
    pub model: String,
    /// Nominal peak force (N), read from the device.
    pub max_force_n: f64,
    /// Nominal continuous force (N), read from the device.
    pub max_continuous_force_n: f64,
    /// Whether the device senses the stylus' orientation (six-DOF sensing).
    pub senses_orientation: bool,
}

/// One servo tick as the simulation sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ServoReading {
    /// Servo ticks since the device opened.
    pub tick: u64,
    /// Seconds since the device opened, on the servo loop's clock.
    pub time_s: f64,
    /// The stylus tip in the device's frame (mm).
    pub position_mm: DVec3,
    /// The stylus' orientation in the device's frame, when sensed.
    pub rotation: Option<DMat3>,
    /// Button bits (bit 0: the first button).
    pub buttons: u32,
    /// The force this tick, as computed and as sent, and what the guard did.
    pub force: Guarded,
}

/// A device's calibration as it reports it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Calibration {
    /// The device needs the trainee's hand (OpenHaptics: the stylus in its inkwell); forces are
    /// held at zero meanwhile.
    pub needs_manual_input: bool,
    /// Calibrations Stylet asked the device for since it opened.
    pub updates: u64,
}

/// A device's running totals.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ServoCounts {
    pub ticks: u64,
    /// Recoverable device errors (warm motors, exceeded force or velocity): counted, shown.
    pub recoverable_errors: u64,
    pub guard: GuardCounts,
}

/// An open force-feedback device. Dropping it (or [`HapticDevice::close`]) commands zero force
/// and stops its servo loop.
pub trait HapticDevice: Send {
    fn info(&self) -> &DeviceInfo;
    /// The newest servo tick, if any (never waits for the servo loop).
    fn reading(&self) -> Option<ServoReading>;
    /// The simulation's newest force for the hand (N, device frame), stamped when it arrives so
    /// the servo loop's watchdog sees a stall.
    fn set_force(&self, force_n: DVec3);
    /// Holds forces at zero (paused, window out of focus) or lets them flow again (they engage
    /// afresh and ramp in).
    fn set_hold(&self, hold: Hold);
    fn counts(&self) -> ServoCounts;
    /// The 99th percentile of the servo loop's tick intervals so far (ms).
    fn interval_p99_ms(&self) -> f64;
    /// Why force output stopped, when a device error stopped it.
    fn fault(&self) -> Option<HapticError>;
    /// The device's calibration, for devices that report one (OpenHaptics).
    fn calibration(&self) -> Calibration {
        Calibration::default()
    }
    /// Zero force, then the servo loop stopped and the device released.
    fn close(self: Box<Self>) -> Result<ServoCounts, HapticError>;
}

/// Why a device could not be opened or stopped.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum HapticError {
    #[error("{backend}: no vendor library found (tried {}); install the vendor's SDK or name the library with --device-library", list(.tried))]
    LibraryNotFound { backend: Backend, tried: Vec<PathBuf> },
    #[error("{backend}: {path}: {reason}")]
    Library {
        backend: Backend,
        path: PathBuf,
        reason: String,
    },
    #[error("{backend}: {operation} failed: {message} (error {code:#06x})")]
    Device {
        backend: Backend,
        operation: &'static str,
        code: u32,
        message: String,
    },
    #[error("{backend}: {url}: {reason}")]
    Service {
        backend: Backend,
        url: String,
        reason: String,
    },
    #[error("{backend}: the device reports a nominal maximum force of {max_force_n} N, which cannot be right")]
    BadLimits { backend: Backend, max_force_n: f64 },
}

fn list(paths: &[PathBuf]) -> String {
    paths
        .iter()
        .map(|p| p.display().to_string())
        .collect::<Vec<_>>()
        .join(", ")
}

/// Which force-feedback device to open, and where its vendor library or service is.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeviceChoice {
    pub backend: Backend,
    /// The vendor library (OpenHaptics, DHD); default: its usual names and install paths.
    pub library: Option<PathBuf>,
    /// Haply's Inverse Service; default [`haply::DEFAULT_URL`].
    pub url: Option<String>,
}

impl DeviceChoice {
    /// Opens the device; its servo loop runs when this returns.
    pub fn open(&self) -> Result<Box<dyn HapticDevice>, HapticError> {
        Ok(match self.backend {
            Backend::OpenHaptics => Box::new(openhaptics::OpenHaptics::open(self.library.as_deref())?),
            Backend::Dhd => Box::new(dhd::Dhd::open(self.library.as_deref())?),
            Backend::Haply => Box::new(haply::Haply::open(self.url.as_deref())?),
        })
    }

    /// Finds the vendor library or the service without opening the device: where it is.
    pub fn find(&self) -> Result<String, HapticError> {
        let spec = match self.backend {
            Backend::OpenHaptics => &openhaptics::LIBRARY,
            Backend::Dhd => &dhd::LIBRARY,
            Backend::Haply => {
                let url = self.url.as_deref().unwrap_or(haply::DEFAULT_URL);
                return haply::service_listening(url).map(|()| url.to_string());
            }
        };
        library::load(spec, self.library.as_deref()).map(|(_, path)| path.display().to_string())
    }
}
