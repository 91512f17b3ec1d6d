//! `stylet serve` on loopback for a test, stopped when the test drops it.

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};

use crate::{Db, Stylet, s};

/// A running `stylet serve`; killed (and waited for) on drop.
pub struct Server {
    pub child: Child,
    /// `http://127.0.0.1:PORT`, as the server printed it.
    pub base: String,
    /// The admin port's `http://127.0.0.1:PORT`, when started with `--admin-bind`.
    pub admin: Option<String>,
}

impl Server {
    /// `stylet serve` on a free loopback port with its data in `data` on `db`, the atlases in
    /// `atlases`, and `extra` arguments.
    pub fn start(stylet: Stylet, data: &Path, db: &Db, atlases: &Path, extra: &[&str]) -> Server {
        Server::start_at(stylet, "127.0.0.1:0", data, db, atlases, extra)
    }

    /// [`Server::start`] on a given address (a client may have tried it while it was down).
    pub fn start_at(stylet: Stylet, bind: &str, data: &Path, db: &Db, atlases: &Path, extra: &[&str]) -> Server {
        Server::spawn(Server::command(stylet, bind, data, db, atlases, extra), data)
    }

    /// The command line of [`Server::start_at`], not started.
    pub fn command(stylet: Stylet, bind: &str, data: &Path, db: &Db, atlases: &Path, extra: &[&str]) -> Command {
        std::fs::create_dir_all(data).unwrap();
        let mut command = stylet.command();
        command
            .args(["serve", "--bind", bind, "--data-dir", s(data), "--atlases", s(atlases)])
            .args(extra)
            .args(db.args());
        command
    }

    /// Spawns `command`, a `stylet serve` however launched, and waits for its "listening on"
    /// line. Its log (tracing, with request ids) goes to `server.log` in `data`, to be looked at
    /// after a failure.
    pub fn spawn(command: Command, data: &Path) -> Server {
        let log_path = data.join("server.log");
        let log = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(&log_path)
            .unwrap();
        Server::spawn_logging_to(command, log, &log_path)
    }

    /// Spawns `command` with its log (stderr) going to `log`, whose path `log_path` is named if
    /// it does not start.
    pub fn spawn_logging_to(mut command: Command, log: std::fs::File, log_path: &Path) -> Server {
        let mut child = command
            .stdout(Stdio::piped())
            .stderr(log)
            .spawn()
            .unwrap_or_else(|e| panic!("{:?} does not start: {e}", command.get_program()));
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        // "listening on http://A" or "listening on http://A (admin: http://B)".
        let rest = line
            .trim()
            .strip_prefix("listening on ")
            .unwrap_or_else(|| panic!("unexpected: {line:?}; see {}", log_path.display()));
        let (base, admin) = match rest.split_once(" (admin: ") {
            Some((base, admin)) => (base.to_string(), Some(admin.trim_end_matches(')').to_string())),
            None => (rest.to_string(), None),
        };
        Server { child, base, admin }
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        crate::contract::forget(&self.base);
    }
}
