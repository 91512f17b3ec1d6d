//! `stylet devices` and `stylet device check`: which force-feedback devices this machine can
//! reach, and a headless check of one (docs/devices.md "Haptic devices").

use std::path::PathBuf;

use anyhow::bail;
use clap::{Args, Subcommand, ValueEnum};
use stylet_devices::haptic::check::run_wall;
use stylet_devices::haptic::{Backend, DeviceChoice, HapticDevice, library};
use stylet_devices::haptic::{dhd, haply, openhaptics};

/// A force-feedback backend, as the command line names it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum BackendArg {
    Openhaptics,
    Dhd,
    Haply,
}

impl BackendArg {
    fn backend(self) -> Backend {
        match self {
            BackendArg::Openhaptics => Backend::OpenHaptics,
            BackendArg::Dhd => Backend::Dhd,
            BackendArg::Haply => Backend::Haply,
        }
    }
}

#[derive(Debug, Subcommand)]
pub enum DeviceCommand {
    /// Open a device, render a virtual wall (the plane z = 0, 0.5 N/mm into +z below it) and
    /// report the servo rate, the stylus' range, the largest force and the guard's counts.
    Check(CheckArgs),
}

#[derive(Debug, Args)]
pub struct CheckArgs {
    #[arg(long, value_enum)]
    pub backend: BackendArg,
    /// The vendor library (default: its usual names and install paths).
    #[arg(long)]
    pub device_library: Option<PathBuf>,
    /// Haply's Inverse Service (default ws://localhost:10001).
    #[arg(long)]
    pub device_url: Option<String>,
    /// How long to render the wall (s, 0.1 … 600).
    #[arg(long, default_value_t = 10.0)]
    pub seconds: f64,
}

/// Opens a device of `backend`.
pub fn open(
    backend: BackendArg,
    library_path: Option<&std::path::Path>,
    url: Option<&str>,
) -> anyhow::Result<Box<dyn HapticDevice>> {
    Ok(choice(backend, library_path, url)?.open()?)
}

/// The device the flags name; a flag for another backend is refused.
pub fn choice(
    backend: BackendArg,
    library_path: Option<&std::path::Path>,
    url: Option<&str>,
) -> anyhow::Result<DeviceChoice> {
    match backend {
        BackendArg::Openhaptics | BackendArg::Dhd if url.is_some() => {
            bail!(
                "--device-url is for haply; {} is found by --device-library",
                backend.backend()
            )
        }
        BackendArg::Haply if library_path.is_some() => {
            bail!("--device-library is for openhaptics and dhd; haply is reached by --device-url")
        }
        _ => Ok(DeviceChoice {
            backend: backend.backend(),
            library: library_path.map(Into::into),
            url: url.map(Into::into),
        }),
    }
}

pub fn check(a: CheckArgs) -> anyhow::Result<()> {
    if !(0.1..=600.0).contains(&a.seconds) {
        bail!("--seconds takes 0.1 … 600, not {}", a.seconds);
    }
    let device = open(a.backend, a.device_library.as_deref(), a.device_url.as_deref())?;
    sayf!(
        "opened {} ({}): nominal {:.2} N peak, {:.2} N continuous; rendering the wall for {} s",
        device.info().model,
        device.info().backend,
        device.info().max_force_n,
        device.info().max_continuous_force_n,
        a.seconds
    );
    let report = run_wall(device, a.seconds)?;
    for line in report.lines() {
        sayf!("{line}");
    }
    Ok(())
}

pub fn run(cmd: DeviceCommand) -> anyhow::Result<()> {
    match cmd {
        DeviceCommand::Check(a) => check(a),
    }
}

/// `stylet devices`: each backend's library, found or why not.
pub fn list() -> anyhow::Result<()> {
    for (backend, spec) in [
        (Backend::OpenHaptics, &openhaptics::LIBRARY),
        (Backend::Dhd, &dhd::LIBRARY),
    ] {
        match library::load(spec, None) {
            Ok((_, path)) => sayf!(
                "{backend}: library {} (`stylet device check --backend {backend}` opens the device)",
                path.display()
            ),
            Err(e) => sayf!("{e}"),
        }
    }
    match haply::service_listening(haply::DEFAULT_URL) {
        Ok(()) => sayf!(
            "haply: the Inverse Service listens at {} (`stylet device check --backend haply` opens the device)",
            haply::DEFAULT_URL
        ),
        Err(e) => sayf!("{e}"),
    }
    Ok(())
}
