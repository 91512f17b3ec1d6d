//! Helpers shared by the end-to-end tests of the service and the dashboard: `stylet` runs,
//! accounts, a server on loopback, HTTP calls, a small phantom with recorded sessions.
#![allow(dead_code)]

pub mod attack;
pub mod browser;
pub mod contract;
pub mod dicom_labels;

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;

pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

pub fn ok(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_stylet")).args(args).output().unwrap();
    assert!(
        out.status.success(),
        "stylet {args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

pub fn add_user(data: &Path, db: &Db, name: &str, role: &str, cohort: Option<&str>) {
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
    let mut child = Command::new(env!("CARGO_BIN_EXE_stylet"))
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

/// Which database the server uses.
pub enum Db {
    Sqlite,
    /// A fresh PostgreSQL database of its own.
    Postgres(String),
}

impl Db {
    pub fn postgres(test: &str) -> Db {
        let admin = std::env::var("STYLET_POSTGRES_URL")
            .expect("STYLET_POSTGRES_URL is not set: scripts/test starts PostgreSQL (scripts/postgres-up) and sets it");
        let name = format!("stylet_{test}_{}", std::process::id());
        let run = |sql: &str| {
            let out = Command::new("psql")
                .args([admin.as_str(), "-q", "-c", sql])
                .output()
                .expect("psql runs");
            assert!(out.status.success(), "{sql}: {}", String::from_utf8_lossy(&out.stderr));
        };
        run(&format!("DROP DATABASE IF EXISTS {name}"));
        run(&format!("CREATE DATABASE {name}"));
        let base = admin.rsplit_once('/').expect("a URL with a database").0;
        Db::Postgres(format!("{base}/{name}"))
    }
    pub fn args(&self) -> Vec<&str> {
        match self {
            Db::Sqlite => Vec::new(),
            Db::Postgres(url) => vec!["--database", url.as_str()],
        }
    }
    pub fn url(&self, data: &Path) -> String {
        match self {
            Db::Sqlite => format!("sqlite://{}?mode=rwc", data.join("stylet.db").display()),
            Db::Postgres(url) => url.clone(),
        }
    }
}

pub struct Server {
    pub child: Child,
    pub base: String,
}

impl Server {
    pub fn start(data: &Path, db: &Db, atlases: &Path, extra: &[&str]) -> Server {
        Server::start_at("127.0.0.1:0", data, db, atlases, extra)
    }

    /// [`Server::start`] on a given address (a client may have tried it while it was down).
    pub fn start_at(bind: &str, data: &Path, db: &Db, atlases: &Path, extra: &[&str]) -> Server {
        std::fs::create_dir_all(data).unwrap();
        let log = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(data.join("server.log"))
            .unwrap();
        let mut child = Command::new(env!("CARGO_BIN_EXE_stylet"))
            .args(["serve", "--bind", bind, "--data-dir", s(data), "--atlases", s(atlases)])
            .args(extra)
            .args(db.args())
            .stdout(Stdio::piped())
            // The server's log (tracing, with request ids) stays beside its data for a look after a failure.
            .stderr(log)
            .spawn()
            .unwrap();
        let mut line = String::new();
        BufReader::new(child.stdout.take().unwrap())
            .read_line(&mut line)
            .unwrap();
        let base = line
            .trim()
            .strip_prefix("listening on ")
            .unwrap_or_else(|| panic!("unexpected: {line}"))
            .to_string();
        Server { child, base }
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// How a test client authenticates.
pub enum Auth {
    /// The login cookie and the login's CSRF token (sent with POSTs).
    Cookie {
        token: String,
        csrf: String,
    },
    Bearer(String),
}

/// (status, JSON body, Set-Cookie token) of a request.
pub fn call(
    method: &str,
    url: &str,
    auth: Option<&Auth>,
    body: Option<&[u8]>,
    json: bool,
) -> (u16, Value, Option<String>) {
    let mut req = ureq::request(method, url);
    match auth {
        Some(Auth::Cookie { token, csrf }) => {
            req = req.set("Cookie", &format!("stylet_session={token}"));
            if method != "GET" {
                req = req.set("X-CSRF-Token", csrf);
            }
        }
        Some(Auth::Bearer(t)) => req = req.set("Authorization", &format!("Bearer {t}")),
        None => {}
    }
    let res = match body {
        Some(b) => req
            .set(
                "Content-Type",
                if json {
                    "application/json"
                } else {
                    "application/octet-stream"
                },
            )
            .send_bytes(b),
        None => req.call(),
    };
    let resp = match res {
        Ok(r) => r,
        Err(ureq::Error::Status(_, r)) => r,
        Err(e) => panic!("{method} {url}: {e}"),
    };
    let status = resp.status();
    let token = resp
        .header("Set-Cookie")
        .and_then(|c| c.strip_prefix("stylet_session="))
        .and_then(|c| c.split(';').next())
        .map(str::to_string);
    let content_type = resp.header("Content-Type").map(str::to_string);
    let text = resp.into_string().unwrap();
    if let Some(base) = base_of(url) {
        contract::check(base, method, url, status, content_type.as_deref(), &text);
    }
    (
        status,
        serde_json::from_str(&text).unwrap_or(Value::String(text)),
        token,
    )
}

/// `http://host:port` of a URL.
fn base_of(url: &str) -> Option<&str> {
    let after = url.strip_prefix("http://")?;
    let end = after.find('/').map_or(url.len(), |i| i + "http://".len());
    Some(&url[..end])
}

pub fn login(base: &str, user: &str) -> Auth {
    let body = format!(r#"{{"username":"{user}","password":"{user}-password"}}"#);
    let (status, json, token) = call("POST", &format!("{base}/api/login"), None, Some(body.as_bytes()), true);
    assert_eq!(status, 200, "{json}");
    Auth::Cookie {
        token: token.unwrap(),
        csrf: json["csrf_token"].as_str().unwrap().to_string(),
    }
}

/// A POST over a raw socket that ignores write errors (the server may answer and close before
/// the whole body is sent); returns status and JSON body.
pub fn raw_post(base: &str, path: &str, auth: Option<&Auth>, body: &[u8]) -> (u16, Value) {
    raw_post_as(base, path, auth, "application/octet-stream", body)
}

/// [`raw_post`] with another `Content-Type`.
pub fn raw_post_as(base: &str, path: &str, auth: Option<&Auth>, content_type: &str, body: &[u8]) -> (u16, Value) {
    use std::io::Read;
    let addr = base.strip_prefix("http://").unwrap();
    let mut sock = std::net::TcpStream::connect(addr).unwrap();
    let credentials = match auth {
        Some(Auth::Cookie { token, csrf }) => format!("Cookie: stylet_session={token}\r\nX-CSRF-Token: {csrf}\r\n"),
        Some(Auth::Bearer(t)) => format!("Authorization: Bearer {t}\r\n"),
        None => String::new(),
    };
    let head = format!(
        "POST {path} HTTP/1.1\r\nHost: {addr}\r\n{credentials}\
         Content-Type: {content_type}\r\nContent-Length: {}\r\nConnection: close\r\n\r\n",
        body.len()
    );
    sock.write_all(head.as_bytes()).unwrap();
    let _ = sock.write_all(body);
    let mut resp = Vec::new();
    let _ = sock.read_to_end(&mut resp);
    let text = String::from_utf8_lossy(&resp).to_string();
    let status = text.split_whitespace().nth(1).and_then(|c| c.parse().ok()).unwrap_or(0);
    let (head, body) = text.split_once("\r\n\r\n").unwrap_or((&text, ""));
    if status != 0 {
        let content_type = head
            .lines()
            .find_map(|l| {
                l.split_once(':')
                    .filter(|(k, _)| k.eq_ignore_ascii_case("content-type"))
            })
            .map(|(_, v)| v.trim().to_string());
        contract::check(
            base,
            "POST",
            &format!("{base}{path}"),
            status,
            content_type.as_deref(),
            body,
        );
    }
    let json = serde_json::from_str(body).unwrap_or(Value::String(text.clone()));
    (status, json)
}

/// `file` with its first MCAP chunk replaced by 256 MiB of zeros compressed with zstd (about
/// 10 KB), declaring `claim` bytes uncompressed (default: the true size).
pub fn zstd_bomb(file: &[u8], claim: Option<u64>) -> Vec<u8> {
    let plain: u64 = 256 << 20;
    let mut enc = zstd::stream::Encoder::new(Vec::new(), 3).unwrap();
    std::io::copy(&mut std::io::Read::take(std::io::repeat(0), plain), &mut enc).unwrap();
    let packed = enc.finish().unwrap();
    assert!(packed.len() < 100_000, "{} bytes", packed.len());
    let mut body = Vec::new();
    body.extend(0u64.to_le_bytes()); // message start time
    body.extend(0u64.to_le_bytes()); // message end time
    body.extend(claim.unwrap_or(plain).to_le_bytes());
    body.extend(0u32.to_le_bytes()); // no CRC
    body.extend(4u32.to_le_bytes());
    body.extend(b"zstd");
    body.extend((packed.len() as u64).to_le_bytes());
    body.extend(&packed);
    // Walk the records (magic, then op u8 + length u64 + body) to the first chunk (op 0x06).
    let mut at = 8;
    loop {
        let op = file[at];
        let len = u64::from_le_bytes(file[at + 1..at + 9].try_into().unwrap()) as usize;
        if op == 0x06 {
            let mut out = file[..at].to_vec();
            out.push(0x06);
            out.extend((body.len() as u64).to_le_bytes());
            out.extend(&body);
            out.extend(&file[at + 9 + len..]);
            return out;
        }
        at += 9 + len;
    }
}

pub fn files_under(dir: &Path) -> usize {
    walk(dir).len()
}

pub fn walk(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    if let Ok(rd) = std::fs::read_dir(dir) {
        for e in rd.flatten() {
            let p = e.path();
            if p.is_dir() { out.extend(walk(&p)) } else { out.push(p) }
        }
    }
    out
}

/// A small phantom and two sessions of trainee `tina`, one of `tom`, and one recorded on another
/// atlas.
pub struct Fixture {
    pub dir: tempfile::TempDir,
}

/// Builds a phantom atlas at `out` (`dims` "X,Y,Z" voxels of `spacing_mm`).
pub fn phantom_atlas(out: &Path, dims: &str, spacing_mm: &str) {
    ok(&[
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

impl Fixture {
    pub fn new() -> Fixture {
        let dir = tempfile::tempdir().unwrap();
        let f = Fixture { dir };
        let atlas = f.atlases().join("phantom");
        phantom_atlas(&atlas, "160,160,130", "2.4");
        let other = f.dir.path().join("other-atlas");
        phantom_atlas(&other, "96,96,80", "4");
        let scripts = Path::new(env!("CARGO_MANIFEST_DIR")).join("atlases/phantom/scripts");
        for (name, script, trainee, on) in [
            ("tina-ok", "success-intercostal", "tina", &atlas),
            ("tina-lung", "lung-hit", "tina", &atlas),
            ("tina-two", "two-attempts", "tina", &atlas),
            ("tom-ok", "success-intercostal", "tom", &atlas),
            ("tina-other-atlas", "success-intercostal", "tina", &other),
        ] {
            let sc = scripts.join(format!("{script}.txt"));
            let out = f.session(name);
            ok(&[
                "script",
                "run",
                "--atlas",
                s(on),
                "--script",
                s(&sc),
                "--out",
                s(&out),
                "--trainee",
                trainee,
            ]);
        }
        f
    }
    pub fn atlases(&self) -> PathBuf {
        self.dir.path().join("atlases")
    }
    pub fn session(&self, name: &str) -> PathBuf {
        self.dir.path().join(format!("{name}.mcap"))
    }
    pub fn data(&self) -> PathBuf {
        self.dir.path().join("data")
    }
    pub fn users(&self, db: &Db) {
        let d = self.data();
        add_user(&d, db, "root", "admin", None);
        add_user(&d, db, "ivan", "instructor", Some("c1"));
        add_user(&d, db, "tina", "trainee", Some("c1"));
        add_user(&d, db, "tom", "trainee", Some("c2"));
        add_user(&d, db, "cora", "curriculum", None);
    }
}

pub fn wait_scored(base: &str, cookie: &Auth, id: &str) -> Value {
    let t0 = Instant::now();
    loop {
        let (status, json, _) = call("GET", &format!("{base}/api/sessions/{id}"), Some(cookie), None, false);
        assert_eq!(status, 200, "{json}");
        match json["status"].as_str().unwrap() {
            "scored" | "failed" => return json,
            _ if t0.elapsed() > Duration::from_secs(120) => panic!("not scored in time: {json}"),
            _ => std::thread::sleep(Duration::from_millis(100)),
        }
    }
}
