//! `stylet`: the command-line entry point. Subcommands only; the work lives in the library crates.
// clap turns the argument structs' doc comments into `--help` text, which is plain text: a bare
// URL or a placeholder like <structure> is meant literally there, not as Markdown.
#![allow(rustdoc::bare_urls, rustdoc::invalid_html_tags)]

mod cli;

use std::process::ExitCode;

use clap::Parser;

fn main() -> ExitCode {
    let args = cli::Cli::parse();
    match cli::run(args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
