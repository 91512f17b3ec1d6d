//! A real LTI 1.3 platform for a test: lti1p3platform from PyPI (scripts/lti-platform installs
//! it and scripts/test names its Python in `$STYLET_LTI_PLATFORM`), driven by
//! tests/lti-platform/lms.py on a free loopback port. Its port is chosen before it starts, so
//! that it can be registered in Stylet before Stylet (whose address it needs) starts; stopped on
//! drop.

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;

use crate::scored::workspace_dir;

/// The client id the platform gave Stylet.
pub const LTI_CLIENT_ID: &str = "stylet-tool";
/// The deployment of Stylet at the platform.
pub const LTI_DEPLOYMENT_ID: &str = "deployment-1";

/// The platform on `port`, running or not; killed (and waited for) on drop.
pub struct LtiPlatform {
    python: String,
    dir: tempfile::TempDir,
    child: Option<Child>,
    pub port: u16,
}

impl LtiPlatform {
    /// A platform on a free port, not started yet.
    pub fn new() -> LtiPlatform {
        let python = std::env::var("STYLET_LTI_PLATFORM").expect(
            "STYLET_LTI_PLATFORM is not set: scripts/test installs lti1p3platform (scripts/lti-platform) and sets it",
        );
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        LtiPlatform {
            python,
            dir: tempfile::tempdir().unwrap(),
            child: None,
            port,
        }
    }

    /// Its address, which is also its issuer.
    pub fn url(&self) -> String {
        format!("http://127.0.0.1:{}", self.port)
    }

    /// The arguments of `stylet lti add-platform` that register it (after the database ones).
    pub fn registration(&self) -> Vec<String> {
        let u = self.url();
        [
            "--issuer",
            &u,
            "--client-id",
            LTI_CLIENT_ID,
            "--deployment-id",
            LTI_DEPLOYMENT_ID,
            "--keyset-url",
            &format!("{u}/jwks"),
            "--auth-url",
            &format!("{u}/authorize"),
            "--token-url",
            &format!("{u}/token"),
        ]
        .map(str::to_string)
        .to_vec()
    }

    /// Starts it for the tool at `tool_url` and waits until it answers.
    pub fn start(&mut self, tool_url: &str) {
        let log_path = self.dir.path().join("lms.log");
        let log = std::fs::File::create(&log_path).unwrap();
        let script = workspace_dir().join("tests/lti-platform/lms.py");
        let child = Command::new(&self.python)
            .arg(script)
            .args(["--port", &self.port.to_string(), "--tool-url", tool_url])
            .args(["--client-id", LTI_CLIENT_ID, "--deployment-id", LTI_DEPLOYMENT_ID])
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .unwrap_or_else(|e| panic!("the LTI platform does not start: {e}"));
        self.child = Some(child);
        let started = Instant::now();
        while ureq::get(&format!("{}/jwks", self.url())).call().is_err() {
            assert!(
                started.elapsed() < Duration::from_secs(60),
                "the LTI platform does not answer on {}: {}",
                self.url(),
                std::fs::read_to_string(&log_path).unwrap_or_default()
            );
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// What it logged (for failure messages).
    pub fn log(&self) -> String {
        std::fs::read_to_string(self.dir.path().join("lms.log")).unwrap_or_default()
    }

    /// GET `path` as JSON.
    pub fn json(&self, path: &str) -> Value {
        ureq::get(&format!("{}{path}", self.url()))
            .call()
            .unwrap_or_else(|e| panic!("GET {path}: {e}\n{}", self.log()))
            .into_json()
            .unwrap()
    }
}

impl Default for LtiPlatform {
    fn default() -> Self {
        LtiPlatform::new()
    }
}

impl Drop for LtiPlatform {
    fn drop(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}
