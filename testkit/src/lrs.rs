//! A real xAPI Learning Record Store for a test: Ralph (scripts/ralph installs it and scripts/test
//! names its Python in `$STYLET_RALPH`), served by uvicorn on a free loopback port, its statements
//! in a temporary folder (Ralph's filesystem backend), one HTTP Basic account. Made before it is
//! started, so that a service can be pointed at an LRS that is down; stopped on drop.

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use base64::Engine as _;
use base64::engine::general_purpose::STANDARD;
use serde_json::Value;

/// The LRS account the service sends with.
pub const LRS_USERNAME: &str = "stylet";
/// Its password.
pub const LRS_PASSWORD: &str = "stylet-lrs-secret";

/// Ralph on `port`, running or not; killed (and waited for) on drop.
pub struct Lrs {
    python: String,
    dir: tempfile::TempDir,
    child: Option<Child>,
    pub port: u16,
}

impl Lrs {
    /// An LRS with its account written, on a free port, not started yet.
    pub fn new() -> Lrs {
        let python = std::env::var("STYLET_RALPH")
            .expect("STYLET_RALPH is not set: scripts/test installs Ralph (scripts/ralph) and sets it");
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir(dir.path().join("statements")).unwrap();
        let out = Command::new(&python)
            .args([
                "-m",
                "ralph",
                "auth",
                "-u",
                LRS_USERNAME,
                "-p",
                LRS_PASSWORD,
                "-s",
                "all",
            ])
            .args(["-M", "mailto:stylet@example.org", "-w"])
            .env("RALPH_AUTH_FILE", dir.path().join("auth.json"))
            .env("RALPH_RUNSERVER_BACKEND", "fs")
            .output()
            .unwrap_or_else(|e| panic!("{python} does not run: {e}"));
        assert!(
            out.status.success(),
            "ralph auth: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        Lrs {
            python,
            dir,
            child: None,
            port,
        }
    }

    /// The xAPI endpoint, `http://127.0.0.1:PORT/xAPI`.
    pub fn url(&self) -> String {
        format!("http://127.0.0.1:{}/xAPI", self.port)
    }

    /// Starts the server and waits until it answers.
    pub fn start(&mut self) {
        let log = std::fs::File::create(self.dir.path().join("ralph.log")).unwrap();
        let child = Command::new(&self.python)
            .args(["-m", "uvicorn", "ralph.api:app", "--host", "127.0.0.1", "--port"])
            .arg(self.port.to_string())
            .env("RALPH_AUTH_FILE", self.dir.path().join("auth.json"))
            .env("RALPH_RUNSERVER_BACKEND", "fs")
            .env(
                "RALPH_BACKENDS__LRS__FS__DEFAULT_DIRECTORY_PATH",
                self.dir.path().join("statements"),
            )
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .unwrap_or_else(|e| panic!("Ralph does not start: {e}"));
        self.child = Some(child);
        let started = Instant::now();
        while ureq::get(&format!("http://127.0.0.1:{}/__lbheartbeat__", self.port))
            .call()
            .is_err()
        {
            assert!(
                started.elapsed() < Duration::from_secs(60),
                "Ralph does not answer on {}: {}",
                self.url(),
                std::fs::read_to_string(self.dir.path().join("ralph.log")).unwrap_or_default()
            );
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// Every statement the LRS holds (at most 500), as it serves them.
    pub fn statements(&self) -> Vec<Value> {
        let auth = format!("{LRS_USERNAME}:{LRS_PASSWORD}");
        let r = ureq::get(&format!("{}/statements?limit=500", self.url()))
            .set("X-Experience-API-Version", "1.0.3")
            .set("Authorization", &format!("Basic {}", STANDARD.encode(auth)))
            .call()
            .unwrap_or_else(|e| panic!("GET statements: {e}"));
        let body: Value = r.into_json().unwrap();
        body["statements"].as_array().cloned().unwrap_or_default()
    }

    /// Stops the server (an LRS that does not answer).
    pub fn stop(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

impl Default for Lrs {
    fn default() -> Self {
        Lrs::new()
    }
}

impl Drop for Lrs {
    fn drop(&mut self) {
        self.stop();
    }
}
