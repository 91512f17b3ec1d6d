//! The built `stylet` binary, run as a user or a script would run it.

use std::io::Write;
use std::path::Path;
use std::process::{Command, Output, Stdio};

use crate::Db;

/// The `stylet` binary under test. Its path is `env!("CARGO_BIN_EXE_stylet")`, which only the
/// root package's tests can read, so they hand it in (`Stylet::at`); everything here that runs
/// `stylet` takes one.
#[derive(Clone, Copy, Debug)]
pub struct Stylet {
    path: &'static str,
}

impl Stylet {
    /// The binary at `path`.
    pub const fn at(path: &'static str) -> Stylet {
        Stylet { path }
    }

    /// The binary's path.
    pub fn path(self) -> &'static Path {
        Path::new(self.path)
    }

    /// A command that runs the binary, for a test that sets its own arguments, environment or
    /// pipes.
    pub fn command(self) -> Command {
        Command::new(self.path)
    }

    /// Runs `stylet args…` to completion.
    pub fn run(self, args: &[&str]) -> Output {
        self.command().args(args).output().expect("the stylet binary runs")
    }

    /// Runs `stylet args…`, which must succeed; its standard output.
    pub fn ok(self, args: &[&str]) -> String {
        let out = self.run(args);
        assert!(
            out.status.success(),
            "stylet {args:?} failed: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8(out.stdout).unwrap()
    }

    /// Runs `stylet args…`, which must fail; its standard error.
    pub fn fails(self, args: &[&str]) -> String {
        let out = self.run(args);
        assert!(!out.status.success(), "stylet {args:?} should fail");
        String::from_utf8(out.stderr).unwrap()
    }

    /// Adds account `name` with `role` (and `cohort`) to the service's data in `data` on `db`,
    /// through `stylet user add`; its password is `<name>-password`, as [`crate::login`] expects.
    pub fn add_user(self, data: &Path, db: &Db, name: &str, role: &str, cohort: Option<&str>) {
        let mut args = vec![
            "user",
            "add",
            "--data-dir",
            s(data),
            "--username",
            name,
            "--role",
            role,
            "--password-stdin",
        ];
        args.extend(db.args());
        if let Some(c) = cohort {
            args.extend(["--cohort", c]);
        }
        let mut child = self
            .command()
            .args(&args)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .unwrap();
        child
            .stdin
            .take()
            .unwrap()
            .write_all(format!("{name}-password\n").as_bytes())
            .unwrap();
        assert!(child.wait().unwrap().success(), "user add {name}");
    }

    /// Builds a phantom atlas at `out` (`dims` "X,Y,Z" voxels of `spacing_mm`) with
    /// `stylet atlas phantom`.
    pub fn phantom_atlas(self, out: &Path, dims: &str, spacing_mm: &str) {
        self.ok(&[
            "atlas",
            "phantom",
            "--out",
            s(out),
            "--dims",
            dims,
            "--spacing",
            spacing_mm,
        ]);
    }
}

/// A path as a command-line argument (test paths are UTF-8).
pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}
