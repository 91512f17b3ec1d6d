//! The root package's end-to-end tests, one module per subject, in one test binary (each test
//! binary links the whole product). `cargo test --test integration MODULE::` runs one module.
//!
//! Tests run in parallel threads of this one process, so none may change what the process shares:
//! no environment variables or working directory changed, no fixed ports or paths; fixtures built
//! once are kept in `static`s (in `common` where modules share them).

mod common;

mod accounts;
mod backup;
mod benchmark;
mod breathing;
mod cli;
mod complications;
mod csp;
mod dashboard;
mod deploy;
mod force_feedback;
mod guide_wire;
mod haptics;
mod hardening;
mod instructors;
mod lti;
mod multi_site;
mod object_storage;
mod observability;
mod pairing;
mod phone;
mod player;
mod publish;
mod render_cli;
mod render_golden;
mod replicas;
mod reports;
mod scoring;
mod service;
mod sessions;
mod simulator;
mod tokens;
mod two_hands;
mod upgrade;
mod window;
mod xapi;
