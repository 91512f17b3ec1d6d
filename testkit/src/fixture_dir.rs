//! Temporary directories for a test binary's `static` fixtures.
//!
//! A test binary builds its expensive fixtures (an imported CT is ≈ 300 MB) once and keeps them
//! in a `static`. Rust never drops statics, so a `tempfile::TempDir` kept there is never removed:
//! every test run used to leave its atlases in the temporary directory until the disk filled.
//! [`fixture_dir`] hands out a directory that is removed when the process exits normally (the test
//! harness ends with `exit`, which runs the handlers registered with `atexit`).

use std::path::PathBuf;
use std::sync::{Mutex, Once};

/// Directories to remove at exit.
static DIRS: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

extern "C" fn remove_fixture_dirs() {
    // At exit no test runs any more; a poisoned lock still holds the list.
    let dirs = std::mem::take(&mut *DIRS.lock().unwrap_or_else(|p| p.into_inner()));
    for dir in dirs {
        let _ = std::fs::remove_dir_all(dir);
    }
}

/// A new empty temporary directory that lives until the process exits, for a fixture held in a
/// `static`. A process killed by a signal leaves it behind (as it would a `TempDir`).
pub fn fixture_dir() -> PathBuf {
    static REGISTER: Once = Once::new();
    REGISTER.call_once(|| {
        // SAFETY: `remove_fixture_dirs` is a plain `extern "C" fn` without arguments that does not
        // unwind (it ignores every error), as `atexit` requires.
        let status = unsafe { libc::atexit(remove_fixture_dirs) };
        assert_eq!(status, 0, "atexit refused the fixture-directory clean-up");
    });
    let dir = tempfile::Builder::new()
        .prefix("stylet-fixture-")
        .tempdir()
        .expect("a temporary directory for a test fixture")
        .keep();
    DIRS.lock().unwrap_or_else(|p| p.into_inner()).push(dir.clone());
    dir
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fixture_dirs_are_distinct_empty_and_listed_for_removal() {
        let a = fixture_dir();
        let b = fixture_dir();
        assert_ne!(a, b);
        for d in [&a, &b] {
            assert!(d.is_dir());
            assert_eq!(std::fs::read_dir(d).unwrap().count(), 0);
        }
        let listed = DIRS.lock().unwrap().clone();
        assert!(listed.contains(&a) && listed.contains(&b));
    }

    /// Run as a child process by the test below: makes a fixture directory with a file in it,
    /// prints its path and lets the harness exit.
    #[test]
    fn child_makes_a_fixture_dir() {
        if std::env::var_os("STYLET_TESTKIT_CHILD").is_none() {
            return;
        }
        let d = fixture_dir();
        std::fs::create_dir(d.join("atlas")).unwrap();
        std::fs::write(d.join("atlas/ct.nii"), [0u8; 1024]).unwrap();
        println!("FIXTURE_DIR={}", d.display());
    }

    #[test]
    fn a_fixture_dir_is_removed_when_the_test_process_exits() {
        let out = std::process::Command::new(std::env::current_exe().unwrap())
            .args([
                "--exact",
                "fixture_dir::tests::child_makes_a_fixture_dir",
                "--nocapture",
            ])
            .env("STYLET_TESTKIT_CHILD", "1")
            .output()
            .unwrap();
        let stdout = String::from_utf8(out.stdout).unwrap();
        assert!(out.status.success(), "the child test failed: {stdout}");
        let dir = stdout
            .lines()
            .find_map(|l| l.strip_prefix("FIXTURE_DIR="))
            .unwrap_or_else(|| panic!("the child printed no directory: {stdout}"));
        let dir = std::path::Path::new(dir);
        assert!(dir.is_absolute());
        assert!(!dir.exists(), "{} outlived its process", dir.display());
    }
}
