//! The headless browser of the dashboard's end-to-end tests: ChromeDriver on loopback, a fresh
//! Chromium per test with its own profile, and the login form.

use std::net::TcpListener;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use fantoccini::{Client, ClientBuilder, Locator};
use serde_json::{Value, json};

pub const CHROMIUM: &str = "/usr/bin/chromium";
pub const CHROMEDRIVER: &str = "/usr/bin/chromedriver";

/// ChromeDriver on a free loopback port, stopped on drop.
pub struct Driver {
    child: Child,
    pub url: String,
}

impl Driver {
    pub fn start() -> Driver {
        for bin in [CHROMIUM, CHROMEDRIVER] {
            assert!(
                Path::new(bin).is_file(),
                "{bin} is missing: scripts/test installs the Debian packages chromium and chromium-driver"
            );
        }
        let port = TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
        let child = Command::new(CHROMEDRIVER)
            .arg(format!("--port={port}"))
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("chromedriver starts");
        // Listening is not ready: a session requested before ChromeDriver says so in /status
        // can have its connection reset.
        let t0 = Instant::now();
        while !ready(port) {
            assert!(
                t0.elapsed() < Duration::from_secs(20),
                "chromedriver did not become ready"
            );
            std::thread::sleep(Duration::from_millis(50));
        }
        Driver {
            child,
            url: format!("http://127.0.0.1:{port}"),
        }
    }
}

/// Whether ChromeDriver on `port` answers /status with `"ready": true`.
fn ready(port: u16) -> bool {
    use std::io::{Read, Write};
    let Ok(mut s) = std::net::TcpStream::connect(("127.0.0.1", port)) else {
        return false;
    };
    let _ = s.set_read_timeout(Some(Duration::from_secs(2)));
    if s.write_all(b"GET /status HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n")
        .is_err()
    {
        return false;
    }
    let mut body = String::new();
    let _ = s.read_to_string(&mut body);
    body.replace(' ', "").contains("\"ready\":true")
}

impl Drop for Driver {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A fresh headless Chromium (its own profile, no network but loopback) with a window of
/// `size` (CSS pixels) and any `extra` switches.
pub async fn chromium(driver: &Driver, profile: &Path, size: (u32, u32), extra: &[&str]) -> Client {
    let mut args: Vec<String> = [
        "--headless=new",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--disable-dev-shm-usage",
    ]
    .iter()
    .chain(extra)
    .map(|a| a.to_string())
    .collect();
    args.push(format!("--window-size={},{}", size.0, size.1));
    args.push(format!("--user-data-dir={}", profile.display()));
    let caps = json!({
        "browserName": "chrome",
        "goog:chromeOptions": { "binary": CHROMIUM, "args": args },
        // The console, for tests that read it (ChromeDriver's log endpoint).
        "goog:loggingPrefs": { "browser": "ALL" }
    });
    let Value::Object(caps) = caps else { unreachable!() };
    // A session request can still meet a reset connection on a loaded machine: retry a few
    // times before failing the test with the last error.
    let mut last = None;
    for attempt in 0..3 {
        if attempt > 0 {
            tokio::time::sleep(Duration::from_millis(500)).await;
        }
        match ClientBuilder::new(hyper_util::client::legacy::connect::HttpConnector::new())
            .capabilities(caps.clone())
            .connect(&driver.url)
            .await
        {
            Ok(c) => return c,
            Err(e) => last = Some(e),
        }
    }
    panic!("a Chromium session: {:?}", last.expect("three attempts were made"))
}

/// Logs `user` in through the login form (password `<user>-password`, as the fixtures set).
pub async fn log_in(c: &Client, base: &str, user: &str) {
    c.goto(&format!("{base}/login")).await.unwrap();
    type_into(c, Locator::Id("username"), user).await;
    type_into(c, Locator::Id("password"), &format!("{user}-password")).await;
    click(c, Locator::Css("form.login button[type=submit]")).await;
    c.wait()
        .at_most(Duration::from_secs(20))
        .for_element(Locator::Css("header.top .who"))
        .await
        .unwrap_or_else(|e| panic!("{user} is not logged in: {e}"));
}

/// Clicks the element `at` (which must be on the page).
pub async fn click(c: &Client, at: Locator<'_>) {
    c.find(at).await.unwrap().click().await.unwrap();
}

/// Types `text` into the element `at` (which must be on the page).
pub async fn type_into(c: &Client, at: Locator<'_>, text: &str) {
    c.find(at).await.unwrap().send_keys(text).await.unwrap();
}

/// Runs a script in the page and returns its value.
pub async fn js(c: &Client, script: &str) -> Value {
    c.execute(script, vec![]).await.unwrap()
}

/// Waits until `script` (an expression) is true in the page.
pub async fn until(c: &Client, what: &str, script: &str) {
    for _ in 0..300 {
        if js(c, &format!("return !!({script})")).await == json!(true) {
            return;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    panic!("{what}: `{script}` never became true");
}
