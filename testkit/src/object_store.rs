//! A real S3-compatible server for a test: `s3s-fs` (installed by scripts/test, named by
//! `$STYLET_S3S_FS`) on a free loopback port, its buckets folders of a temporary directory;
//! stopped when the test drops it.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

const ACCESS_KEY: &str = "stylet-test";
const SECRET_KEY: &str = "stylet-test-secret";

/// A running `s3s-fs`; killed (and waited for) on drop.
pub struct S3Server {
    child: Child,
    root: tempfile::TempDir,
    /// `http://127.0.0.1:PORT`.
    pub endpoint: String,
}

impl S3Server {
    /// Starts `s3s-fs` with one empty bucket, `bucket`.
    pub fn start(bucket: &str) -> S3Server {
        let program = std::env::var("STYLET_S3S_FS")
            .expect("STYLET_S3S_FS is not set: scripts/test installs s3s-fs (scripts/s3s-fs) and sets it");
        let root = tempfile::tempdir().unwrap();
        std::fs::create_dir(root.path().join(bucket)).unwrap();
        // A free port: taken from the kernel, then handed to s3s-fs (which has no port 0).
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let child = Command::new(&program)
            .args(["--host", "127.0.0.1", "--port", &port.to_string()])
            .args(["--access-key", ACCESS_KEY, "--secret-key", SECRET_KEY])
            .arg(root.path())
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap_or_else(|e| panic!("{program} does not start: {e}"));
        let endpoint = format!("http://127.0.0.1:{port}");
        let started = Instant::now();
        while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
            assert!(
                started.elapsed() < Duration::from_secs(20),
                "s3s-fs does not listen on {endpoint}"
            );
            std::thread::sleep(Duration::from_millis(50));
        }
        S3Server { child, root, endpoint }
    }

    /// The `AWS_*` environment a client of this server needs.
    pub fn env(&self) -> Vec<(&'static str, String)> {
        vec![
            ("AWS_ENDPOINT", self.endpoint.clone()),
            ("AWS_ALLOW_HTTP", "true".into()),
            ("AWS_REGION", "us-east-1".into()),
            ("AWS_ACCESS_KEY_ID", ACCESS_KEY.into()),
            ("AWS_SECRET_ACCESS_KEY", SECRET_KEY.into()),
        ]
    }

    /// Sets [`S3Server::env`] on `command`.
    pub fn configure(&self, command: &mut Command) {
        for (k, v) in self.env() {
            command.env(k, v);
        }
    }

    /// Where the server keeps the objects of `bucket` (`<key>` is a file under it).
    pub fn bucket_dir(&self, bucket: &str) -> PathBuf {
        self.root.path().join(bucket)
    }

    /// The keys of the objects in `bucket` under `prefix`, sorted.
    pub fn keys(&self, bucket: &str, prefix: &str) -> Vec<String> {
        let root = self.bucket_dir(bucket);
        let mut out = Vec::new();
        walk(&root, &root, &mut out);
        out.retain(|k| k.starts_with(prefix));
        out.sort();
        out
    }

    /// Stops the server (a store that does not answer).
    pub fn stop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn walk(root: &Path, dir: &Path, out: &mut Vec<String>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let path = e.path();
        if path.is_dir() {
            walk(root, &path, out);
        } else if let Ok(rel) = path.strip_prefix(root) {
            let key = rel.to_string_lossy().replace('\\', "/");
            // s3s-fs keeps its own bookkeeping beside the objects.
            if !key.split('/').any(|part| part.starts_with('.')) {
                out.push(key);
            }
        }
    }
}

impl Drop for S3Server {
    fn drop(&mut self) {
        self.stop();
    }
}
