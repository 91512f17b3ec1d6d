//! Command-line interface: argument parsing and dispatch.

/// `println!` that ends the program quietly when stdout is closed (`stylet … | head`).
macro_rules! sayf {
    ($($arg:tt)*) => { $crate::cli::say(&format!($($arg)*)) };
}

mod atlas;
mod backup;
mod demo;
mod device;
mod lti;
mod render;
mod score;
mod script;
mod serve;
mod session;
mod sim;
mod user;

use clap::{Parser, Subcommand};

#[derive(Debug, Parser)]
#[command(
    name = "stylet",
    version,
    about = "Stylet: needle-puncture training on virtual patients built from CT"
)]
pub struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Build, import and inspect puncture atlases.
    #[command(subcommand)]
    Atlas(atlas::AtlasCommand),
    /// Run device scripts on an atlas, headless (docs/scripts.md).
    #[command(subcommand)]
    Script(script::ScriptCommand),
    /// Replay session files through the physics and grade them (docs/metrics.md).
    Score(score::ScoreArgs),
    /// Run the scoring service: JSON API, uploads, scoring by replay (docs/api.md).
    Serve(Box<serve::ServeArgs>),
    /// Manage service accounts.
    #[command(subcommand)]
    User(user::UserCommand),
    /// Register learning management systems that launch Stylet (LTI 1.3).
    #[command(subcommand)]
    Lti(lti::LtiCommand),
    /// Back up the service: its database and the files it names, with a manifest of hashes.
    Backup(backup::BackupArgs),
    /// Restore a backup into an empty data directory and database, checking every hash, then
    /// replay a sample of its sessions.
    Restore(backup::RestoreArgs),
    /// Inspect, verify, export and recover session files (docs/session-format.md).
    #[command(subcommand)]
    Session(session::SessionCommand),
    /// Draw an atlas, or a recorded session at a moment, as a PNG (docs/rendering.md).
    Render(render::RenderArgs),
    /// The desktop simulator: its window, or its haptic loop headless (docs/simulator.md).
    Sim(sim::SimArgs),
    /// Run the demo on the embedded default: build the phantom atlas and print its summary.
    Demo(demo::DemoArgs),
    /// List the force-feedback devices' libraries this machine has, and why not (docs/devices.md).
    Devices,
    /// Check a force-feedback device headless (docs/devices.md "Haptic devices").
    #[command(subcommand)]
    Device(device::DeviceCommand),
}

pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Atlas(cmd) => atlas::run(cmd),
        Command::Script(cmd) => script::run(cmd),
        Command::Session(cmd) => session::run(cmd),
        Command::Score(args) => score::run(args),
        Command::Serve(args) => serve::serve(*args),
        Command::User(cmd) => user::run(cmd),
        Command::Lti(cmd) => lti::run(cmd),
        Command::Backup(args) => backup::backup(args),
        Command::Restore(args) => backup::restore(args),
        Command::Render(args) => render::run(args),
        Command::Sim(args) => sim::run(args),
        Command::Demo(args) => demo::run(args),
        Command::Devices => device::list(),
        Command::Device(cmd) => device::run(cmd),
    }
}

/// Prints a line; exits quietly if the reader went away (broken pipe) instead of panicking.
pub fn say(line: &str) {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    if let Err(e) = writeln!(out, "{line}") {
        if e.kind() == std::io::ErrorKind::BrokenPipe {
            std::process::exit(0);
        }
        eprintln!("error: cannot write to stdout: {e}");
        std::process::exit(1);
    }
}
