//! Command-line interface: argument parsing and dispatch.

mod atlas;
mod demo;

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
    /// Run the demo on the embedded default: build the phantom atlas and print its summary.
    Demo(demo::DemoArgs),
}

pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Atlas(cmd) => atlas::run(cmd),
        Command::Demo(args) => demo::run(args),
    }
}
