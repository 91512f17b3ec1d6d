//! Scored sessions: a phantom with sessions recorded by the example scripts, accounts to upload
//! them, and the upload that waits until the service has scored one.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use serde_json::Value;

use crate::{Auth, Db, Server, Stylet, call, fixture_dir, s};

/// The workspace's root (the atlases, scripts and docs the tests read).
pub fn workspace_dir() -> &'static Path {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
}

/// The example script `name` of the default phantom (`atlases/phantom/scripts/<name>.txt`).
pub fn phantom_script(name: &str) -> PathBuf {
    workspace_dir()
        .join("atlases/phantom/scripts")
        .join(format!("{name}.txt"))
}

/// A small phantom and two sessions of trainee `tina`, one of `tom`, and one recorded on another
/// atlas, in a temporary directory; [`Fixture::users`] adds the accounts that upload them.
pub struct Fixture {
    pub dir: tempfile::TempDir,
    stylet: Stylet,
}

impl Fixture {
    /// A copy of the sessions recorded with `stylet script run` (`tina-ok`, `tina-lung`,
    /// `tina-two`, `tom-ok` on the phantom in [`Fixture::atlases`], `tina-other-atlas` on another
    /// phantom): recorded once per test process, copied for every fixture, so each test may change
    /// its own files.
    pub fn new(stylet: Stylet) -> Fixture {
        let dir = tempfile::tempdir().unwrap();
        copy_dir(recorded(stylet), dir.path());
        Fixture { dir, stylet }
    }

    /// The server's atlas folder (it holds the phantom).
    pub fn atlases(&self) -> PathBuf {
        self.dir.path().join("atlases")
    }

    /// The session file `name`.
    pub fn session(&self, name: &str) -> PathBuf {
        self.dir.path().join(format!("{name}.mcap"))
    }

    /// The server's data folder.
    pub fn data(&self) -> PathBuf {
        self.dir.path().join("data")
    }

    /// Adds the accounts on `db`: admin `root`, instructor `ivan` (cohort c1), trainees `tina`
    /// (c1) and `tom` (c2), curriculum staff `cora`.
    pub fn users(&self, db: &Db) {
        let d = self.data();
        for (name, role, cohort) in [
            ("root", "admin", None),
            ("ivan", "instructor", Some("c1")),
            ("tina", "trainee", Some("c1")),
            ("tom", "trainee", Some("c2")),
            ("cora", "curriculum", None),
        ] {
            self.stylet.add_user(&d, db, name, role, cohort);
        }
    }

    /// The accounts of [`Fixture::users`] on `db`, and a server on them with `workers` scoring
    /// workers, serving the fixture's atlases.
    pub fn serve(&self, db: &Db, workers: u32) -> Server {
        self.users(db);
        let workers = workers.to_string();
        Server::start(self.stylet, &self.data(), db, &self.atlases(), &["--workers", &workers])
    }
}

/// The fixture's atlases and sessions, recorded on first use in a directory that lives until
/// the process exits (the recordings take seconds; the same scripts give the same sessions).
fn recorded(stylet: Stylet) -> &'static Path {
    static RECORDED: OnceLock<PathBuf> = OnceLock::new();
    RECORDED.get_or_init(|| {
        let dir = fixture_dir();
        let atlas = dir.join("atlases/phantom");
        stylet.phantom_atlas(&atlas, "160,160,130", "2.4");
        let other = dir.join("other-atlas");
        stylet.phantom_atlas(&other, "96,96,80", "4");
        for (name, script, trainee, on) in [
            ("tina-ok", "success-intercostal", "tina", &atlas),
            ("tina-lung", "lung-hit", "tina", &atlas),
            ("tina-two", "two-attempts", "tina", &atlas),
            ("tom-ok", "success-intercostal", "tom", &atlas),
            ("tina-other-atlas", "success-intercostal", "tina", &other),
        ] {
            let out = dir.join(format!("{name}.mcap"));
            stylet.ok(&[
                "script",
                "run",
                "--atlas",
                s(on),
                "--script",
                s(&phantom_script(script)),
                "--out",
                s(&out),
                "--trainee",
                trainee,
            ]);
        }
        dir
    })
}

/// Copies the files and folders of `from` into `to` (which exists).
fn copy_dir(from: &Path, to: &Path) {
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        let target = to.join(entry.file_name());
        if entry.file_type().unwrap().is_dir() {
            std::fs::create_dir(&target).unwrap();
            copy_dir(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), &target).unwrap();
        }
    }
}

/// Uploads the session file `file` as `who` (`POST /api/sessions`, which must answer 201); the
/// session's id.
pub fn upload(base: &str, who: &Auth, file: &Path) -> String {
    let body = std::fs::read(file).unwrap();
    let (status, json, _) = call("POST", &format!("{base}/api/sessions"), Some(who), Some(&body), false);
    assert_eq!(status, 201, "{}: {json}", file.display());
    json["id"].as_str().unwrap().to_string()
}

/// Uploads `file` as `who` and waits until it is scored (not failed); its id and row.
pub fn upload_scored(base: &str, who: &Auth, file: &Path) -> (String, Value) {
    let id = upload(base, who, file);
    let row = wait_scored(base, who, &id);
    assert_eq!(row["status"], "scored", "{}: {row}", file.display());
    (id, row)
}

/// Waits (up to two minutes) until session `id` is scored or failed; its row.
pub fn wait_scored(base: &str, who: &Auth, id: &str) -> Value {
    let t0 = Instant::now();
    loop {
        let (status, json, _) = call("GET", &format!("{base}/api/sessions/{id}"), Some(who), None, false);
        assert_eq!(status, 200, "{json}");
        match json["status"].as_str().unwrap() {
            "scored" | "failed" => return json,
            _ if t0.elapsed() > Duration::from_secs(120) => panic!("not scored in time: {json}"),
            _ => std::thread::sleep(Duration::from_millis(100)),
        }
    }
}
