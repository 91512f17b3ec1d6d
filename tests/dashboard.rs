//! The dashboard in a real browser: Debian's headless Chromium driven through ChromeDriver
//! (WebDriver, fantoccini) against `stylet serve` on loopback. Every role logs in through the
//! login form and opens its pages; a trainee uploads a session through the upload form and
//! watches its score appear; an instructor compares two sessions, comments and overrides a
//! grade; curriculum staff open the printable report and export the CSV, which is parsed; the
//! admin adds an account. Screenshots of every page are kept in
//! `$CARGO_TARGET_TMPDIR/browser-screenshots/` to be looked at.
//!
//! Needs `chromium` and `chromium-driver` (scripts/test installs them); without them the test
//! fails and says so.

mod common;

use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use common::*;
use fantoccini::{Client, ClientBuilder, Locator};
use serde_json::{Value, json};

const CHROMIUM: &str = "/usr/bin/chromium";
const CHROMEDRIVER: &str = "/usr/bin/chromedriver";

/// ChromeDriver on a free loopback port, stopped on drop.
struct Driver {
    child: Child,
    url: String,
}

impl Driver {
    fn start() -> Driver {
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
        let t0 = Instant::now();
        while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
            assert!(t0.elapsed() < Duration::from_secs(20), "chromedriver did not listen");
            std::thread::sleep(Duration::from_millis(50));
        }
        Driver {
            child,
            url: format!("http://127.0.0.1:{port}"),
        }
    }
}

impl Drop for Driver {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A fresh headless Chromium (its own profile, no network but loopback).
async fn browser(driver: &Driver, profile: &Path) -> Client {
    let args = [
        "--headless=new",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--disable-dev-shm-usage",
        "--window-size=1400,1000",
    ];
    let mut args: Vec<String> = args.iter().map(|a| a.to_string()).collect();
    args.push(format!("--user-data-dir={}", profile.display()));
    let caps = json!({
        "browserName": "chrome",
        "goog:chromeOptions": { "binary": CHROMIUM, "args": args }
    });
    let Value::Object(caps) = caps else { unreachable!() };
    ClientBuilder::new(hyper_util::client::legacy::connect::HttpConnector::new())
        .capabilities(caps)
        .connect(&driver.url)
        .await
        .expect("a Chromium session")
}

/// Where screenshots go.
fn shots() -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR")).join("browser-screenshots");
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A screenshot of the whole page (the window grows to the page's height first).
async fn shot(c: &Client, tag: &str, name: &str) {
    c.execute("window.scrollTo(0, 0)", vec![]).await.unwrap();
    let h = c
        .execute("return document.documentElement.scrollHeight", vec![])
        .await
        .unwrap()
        .as_u64()
        .unwrap_or(1000);
    c.set_window_size(1400, (h as u32 + 40).clamp(600, 8000)).await.unwrap();
    let png = c.screenshot().await.unwrap();
    std::fs::write(shots().join(format!("{tag}-{name}.png")), png).unwrap();
    c.set_window_size(1400, 1000).await.unwrap();
}

async fn text_of(c: &Client, css: &str) -> String {
    c.find(Locator::Css(css))
        .await
        .unwrap_or_else(|e| panic!("no {css}: {e}"))
        .text()
        .await
        .unwrap()
}

/// The text of an element that appears once the page a click started has loaded.
async fn wait_text(c: &Client, css: &str) -> String {
    c.wait()
        .at_most(Duration::from_secs(30))
        .for_element(Locator::Css(css))
        .await
        .unwrap_or_else(|e| panic!("{css} did not appear: {e}"))
        .text()
        .await
        .unwrap()
}

async fn body_text(c: &Client) -> String {
    text_of(c, "body").await
}

/// The HTTP status of the current page is not visible to WebDriver; error pages say it in
/// their first heading, so every page opened is checked not to be one.
async fn open(c: &Client, base: &str, path: &str) -> String {
    c.goto(&format!("{base}{path}")).await.unwrap();
    let h1 = text_of(c, "h1").await;
    for code in ["400", "401", "403", "404", "409", "413", "422", "500"] {
        assert!(!h1.starts_with(code), "{path}: error page {h1}: {}", body_text(c).await);
    }
    h1
}

async fn log_in(c: &Client, base: &str, user: &str) {
    c.goto(&format!("{base}/login")).await.unwrap();
    c.find(Locator::Id("username"))
        .await
        .unwrap()
        .send_keys(user)
        .await
        .unwrap();
    c.find(Locator::Id("password"))
        .await
        .unwrap()
        .send_keys(&format!("{user}-password"))
        .await
        .unwrap();
    c.find(Locator::Css("form.login button[type=submit]"))
        .await
        .unwrap()
        .click()
        .await
        .unwrap();
    c.wait()
        .at_most(Duration::from_secs(20))
        .for_element(Locator::Css("header.top .who"))
        .await
        .unwrap_or_else(|e| panic!("{user} is not logged in: {e}"));
}

async fn log_out(c: &Client, base: &str) {
    c.goto(&format!("{base}/")).await.unwrap();
    c.find(Locator::Css("header.top form button"))
        .await
        .unwrap()
        .click()
        .await
        .unwrap();
    c.wait()
        .at_most(Duration::from_secs(20))
        .for_element(Locator::Css("form.login"))
        .await
        .unwrap();
}

/// Splits one CSV line (RFC 4180 quotes).
fn csv_fields(line: &str) -> Vec<String> {
    let (mut out, mut cur, mut quoted, mut chars) = (Vec::new(), String::new(), false, line.chars().peekable());
    while let Some(ch) = chars.next() {
        match (ch, quoted) {
            ('"', true) if chars.peek() == Some(&'"') => {
                cur.push('"');
                chars.next();
            }
            ('"', _) => quoted = !quoted,
            (',', false) => out.push(std::mem::take(&mut cur)),
            (c, _) => cur.push(c),
        }
    }
    out.push(cur);
    out
}

#[test]
fn every_role_uses_the_dashboard_in_headless_chromium_sqlite() {
    every_role_uses_the_dashboard(Db::Sqlite, "sqlite");
}

#[test]
fn every_role_uses_the_dashboard_in_headless_chromium_postgres() {
    every_role_uses_the_dashboard(Db::postgres("dashboard"), "postgres");
}

fn every_role_uses_the_dashboard(db: Db, tag: &'static str) {
    let f = Fixture::new();
    f.users(&db);
    let srv = Server::start(&f.data(), &db, &f.atlases(), &["--workers", "2"]);
    let base = srv.base.clone();
    // Data the pages show: tina's lung hit and tom's success, uploaded through the API.
    let upload = |who: &str, name: &str| {
        let auth = login(&base, who);
        let body = std::fs::read(f.session(name)).unwrap();
        let (status, json, _) = call("POST", &format!("{base}/api/sessions"), Some(&auth), Some(&body), false);
        assert_eq!(status, 201, "{json}");
        let id = json["id"].as_str().unwrap().to_string();
        assert_eq!(wait_scored(&base, &auth, &id)["status"], "scored");
        id
    };
    let lung = upload("tina", "tina-lung");
    let tom_ok = upload("tom", "tom-ok");
    let driver = Driver::start();
    let profiles = tempfile::tempdir().unwrap();
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let c = browser(&driver, &profiles.path().join("p1")).await;

        // Not logged in: every page leads to the login form.
        c.goto(&format!("{base}/sessions/{lung}")).await.unwrap();
        c.find(Locator::Css("form.login")).await.expect("the login form");
        assert!(c.current_url().await.unwrap().as_str().contains("/login?next="));
        shot(&c, tag, "01-login").await;
        // A wrong password says so.
        c.find(Locator::Id("username")).await.unwrap().send_keys("tina").await.unwrap();
        c.find(Locator::Id("password")).await.unwrap().send_keys("not-her-password").await.unwrap();
        c.find(Locator::Css("form.login button")).await.unwrap().click().await.unwrap();
        assert!(wait_text(&c, "p.error").await.contains("wrong username or password"));
        // Login CSRF: a page on another site posts the right password; the browser is not logged in.
        c.goto(&format!(
            "data:text/html,<form id=f method=post action='{base}/login'><input name=username value=tina>\
             <input name=password value=tina-password></form><script>document.getElementById('f').submit()</script>"
        ))
        .await
        .unwrap();
        let refused = wait_text(&c, "p.error").await;
        assert!(refused.contains("sent from another site"), "{refused}");
        assert!(text_of(&c, "h1").await.starts_with("403"));
        c.goto(&format!("{base}/")).await.unwrap();
        c.find(Locator::Css("form.login")).await.expect("still logged out");

        // ---- trainee
        log_in(&c, &base, "tina").await;
        let h1 = open(&c, &base, "/").await;
        assert_eq!(h1, "My training — tina");
        assert!(text_of(&c, "#suggestion").await.contains("beginner"));
        // Upload through the form, then watch the score appear (the page refreshes itself).
        let ok_file = f.session("tina-ok");
        c.find(Locator::Id("session-file"))
            .await
            .unwrap()
            .send_keys(ok_file.to_str().unwrap())
            .await
            .unwrap();
        c.find(Locator::Css("#upload button")).await.unwrap().click().await.unwrap();
        let grade = c
            .wait()
            .at_most(Duration::from_secs(120))
            .for_element(Locator::Id("grade"))
            .await
            .expect("the score appears on the session page");
        let grade_text = grade.text().await.unwrap();
        assert!(grade_text.contains("passed"), "{grade_text}");
        assert!(text_of(&c, "#replay").await.contains("replay verified"));
        let review_url = c.current_url().await.unwrap();
        let own_id = review_url.path().rsplit('/').next().unwrap().to_string();
        // The charts carry their series and axis titles; the slices image loaded.
        let force = c.find(Locator::Css("#force-chart svg")).await.unwrap().html(false).await.unwrap();
        for want in ["force along the needle (N)", "time (s)", "cutting", "friction", "base", "stylet removed", "target reached"] {
            assert!(force.contains(want), "force chart lacks {want}");
        }
        let depth = c.find(Locator::Css("#depth-chart svg")).await.unwrap().html(false).await.unwrap();
        assert!(depth.contains("depth (mm)") && depth.contains("inserted length"));
        let img = c
            .execute(
                "const i = document.getElementById('tip-path'); \
                 return new Promise(r => { if (i.complete) r(i.naturalWidth); else i.onload = () => r(i.naturalWidth); });",
                vec![],
            )
            .await
            .unwrap();
        assert!(img.as_u64().unwrap_or(0) > 500, "tip-path image: {img}");
        assert!(text_of(&c, "#risk-hits").await.contains("No risk structure"));
        assert!(text_of(&c, "#rubric").await.contains("target_not_reached"));
        shot(&c, tag, "02-trainee-session-review").await;
        // The download is the uploaded file, byte for byte.
        let size = c
            .execute(
                "return fetch(document.getElementById('download').href).then(r => r.arrayBuffer()).then(b => b.byteLength)",
                vec![],
            )
            .await
            .unwrap();
        assert_eq!(size.as_u64(), Some(std::fs::metadata(&ok_file).unwrap().len()));
        // A hostile upload through the form: refused with the reason, nothing stored.
        let cut = f.dir.path().join("cut.mcap");
        let bytes = std::fs::read(&ok_file).unwrap();
        std::fs::write(&cut, &bytes[..bytes.len() / 3]).unwrap();
        open(&c, &base, "/").await;
        c.find(Locator::Id("session-file")).await.unwrap().send_keys(cut.to_str().unwrap()).await.unwrap();
        c.find(Locator::Css("#upload button")).await.unwrap().click().await.unwrap();
        let refused = wait_text(&c, "#upload-error").await;
        assert!(refused.contains("not a valid session file"), "{refused}");
        shot(&c, tag, "03-trainee-upload-refused").await;
        // Home: progress chart and both sessions.
        open(&c, &base, "/").await;
        let home = c.source().await.unwrap();
        assert!(home.contains("Scores of tina by difficulty") && home.contains("score (0–100)"));
        assert_eq!(c.find_all(Locator::Css("table.sessions tbody tr")).await.unwrap().len(), 2);
        shot(&c, tag, "04-trainee-home").await;
        open(&c, &base, "/sessions").await;
        shot(&c, tag, "05-trainee-sessions").await;
        // What a trainee may not see.
        c.goto(&format!("{base}/sessions/{tom_ok}")).await.unwrap();
        assert!(text_of(&c, "h1").await.starts_with("404"));
        c.goto(&format!("{base}/cohorts/c1")).await.unwrap();
        // A cohort one may not see answers like one that does not exist.
        assert!(text_of(&c, "h1").await.starts_with("404"));
        log_out(&c, &base).await;

        // ---- instructor
        log_in(&c, &base, "ivan").await;
        assert!(open(&c, &base, "/").await.starts_with("Instructor"));
        assert!(text_of(&c, "table.cohorts").await.contains("c1"));
        shot(&c, tag, "06-instructor-home").await;
        open(&c, &base, "/cohorts/c1").await;
        let trainees = text_of(&c, "#trainees").await;
        assert!(trainees.contains("tina") && !trainees.contains("tom"), "{trainees}");
        assert_eq!(c.find_all(Locator::Css("#trainees svg.spark")).await.unwrap().len(), 1);
        // Filters: beginner sessions from today on.
        let today = humantime::format_rfc3339_seconds(std::time::SystemTime::now()).to_string()[..10].to_string();
        let form = c.form(Locator::Css("form.filters")).await.unwrap();
        form.set_by_name("difficulty", "beginner").await.unwrap();
        c.execute(&format!("document.querySelector('form.filters input[name=from]').value = '{today}'"), vec![])
            .await
            .unwrap();
        form.submit().await.unwrap();
        c.wait().at_most(Duration::from_secs(20)).for_element(Locator::Id("trainees")).await.unwrap();
        let url = c.current_url().await.unwrap();
        assert!(url.as_str().contains("difficulty=beginner") && url.as_str().contains(&today), "{url}");
        assert_eq!(c.find_all(Locator::Css("table.sessions tbody tr")).await.unwrap().len(), 2);
        shot(&c, tag, "07-instructor-cohort").await;
        // Two sessions' force curves on one chart.
        c.find(Locator::Css("#compare button")).await.unwrap().click().await.unwrap();
        let chart = c
            .wait()
            .at_most(Duration::from_secs(30))
            .for_element(Locator::Css("#compare-chart svg"))
            .await
            .unwrap()
            .html(false)
            .await
            .unwrap();
        for want in ["total — A tina", "total — B tina", "cutting — A tina", "force along the needle (N)"] {
            assert!(chart.contains(want), "comparison lacks {want}");
        }
        shot(&c, tag, "08-instructor-compare").await;
        // Comment on and override tina's lung hit.
        open(&c, &base, &format!("/sessions/{lung}")).await;
        assert!(text_of(&c, "#risk-hits").await.contains("lung"));
        c.find(Locator::Css("#comment-form textarea"))
            .await
            .unwrap()
            .send_keys("Aim one rib lower next time.")
            .await
            .unwrap();
        c.find(Locator::Css("#comment-form button")).await.unwrap().click().await.unwrap();
        c.wait().at_most(Duration::from_secs(20)).for_element(Locator::Css("#review li.comment")).await.unwrap();
        let form = c.form(Locator::Id("override-form")).await.unwrap();
        form.set_by_name("score", "75").await.unwrap();
        form.set_by_name("reason", "the lung contact was a recess artefact").await.unwrap();
        c.find(Locator::Css("#override-form select")).await.unwrap().select_by_value("true").await.unwrap();
        c.find(Locator::Css("#override-form button")).await.unwrap().click().await.unwrap();
        c.wait().at_most(Duration::from_secs(20)).for_element(Locator::Css("#review li.override")).await.unwrap();
        let g = text_of(&c, "#grade").await;
        assert!(g.contains("75.0") && g.contains("overridden") && g.contains("computed"), "{g}");
        assert!(text_of(&c, "#review").await.contains("recess artefact"));
        shot(&c, tag, "09-instructor-review-override").await;
        for path in ["/sessions", "/cohorts", "/reports", "/reports/cohort?cohort=c1"] {
            open(&c, &base, path).await;
        }
        c.goto(&format!("{base}/cohorts/c2")).await.unwrap();
        // Another instructor's cohort answers like one that does not exist.
        assert!(text_of(&c, "h1").await.starts_with("404"), "another instructor's cohort");
        log_out(&c, &base).await;

        // ---- curriculum
        log_in(&c, &base, "cora").await;
        open(&c, &base, "/").await;
        shot(&c, tag, "10-curriculum-home").await;
        open(&c, &base, "/reports").await;
        shot(&c, tag, "11-curriculum-reports").await;
        c.form(Locator::Id("report-form")).await.unwrap().submit().await.unwrap();
        c.wait().at_most(Duration::from_secs(20)).for_element(Locator::Id("report-lines")).await.unwrap();
        assert!(text_of(&c, "#report-title").await.starts_with("Cohort c1"));
        let lines = text_of(&c, "#report-lines").await;
        assert!(lines.contains("tina") && lines.contains("beginner"), "{lines}");
        shot(&c, tag, "12-curriculum-report-c1").await;
        open(&c, &base, "/sessions").await;
        // The export, fetched by the browser through the page's link, parsed here.
        let csv = c
            .execute(
                "return fetch(document.getElementById('export-csv').href).then(r => r.text())",
                vec![],
            )
            .await
            .unwrap();
        let csv = csv.as_str().unwrap();
        let mut rows = csv.lines().map(csv_fields);
        let header = rows.next().unwrap();
        let documented = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/api.md")).unwrap();
        for column in &header {
            assert!(documented.contains(&format!("| `{column}`")) || documented.contains(&format!("`{column}`,")), "column {column} is not documented in docs/api.md");
        }
        let rows: Vec<Vec<String>> = rows.collect();
        assert_eq!(rows.len(), 3, "{csv}");
        let col = |name: &str| header.iter().position(|h| h == name).unwrap();
        for r in &rows {
            assert_eq!(r.len(), header.len(), "{r:?}");
            assert_eq!(r[col("replay_verified")], "true");
        }
        let lung_row = rows.iter().find(|r| r[col("session_id")] == lung).unwrap();
        assert_eq!(
            (lung_row[col("score")].as_str(), lung_row[col("passed")].as_str(), lung_row[col("overridden")].as_str()),
            ("75", "true", "true")
        );
        assert_eq!(lung_row[col("risk_hits")].parse::<u32>().map(|n| n >= 1), Ok(true));
        let own_row = rows.iter().find(|r| r[col("session_id")] == own_id).unwrap();
        assert_eq!(own_row[col("trainee")], "tina");
        assert_eq!(own_row[col("cohorts")], "c1");
        for path in ["/cohorts", "/cohorts/c1", "/cohorts/c2", &format!("/compare?a={lung}&b={own_id}")] {
            open(&c, &base, path).await;
        }
        // Curriculum staff read but do not change: no review forms, no accounts.
        c.goto(&format!("{base}/admin/users")).await.unwrap();
        assert!(text_of(&c, "h1").await.starts_with("403"));
        open(&c, &base, &format!("/sessions/{lung}")).await;
        assert!(c.find(Locator::Id("override-form")).await.is_err());
        log_out(&c, &base).await;

        // ---- admin
        log_in(&c, &base, "root").await;
        open(&c, &base, "/").await;
        shot(&c, tag, "13-admin-home").await;
        open(&c, &base, "/admin/users").await;
        let form = c.form(Locator::Id("add-user")).await.unwrap();
        form.set_by_name("username", "nora").await.unwrap();
        form.set_by_name("cohort", "c1").await.unwrap();
        form.set_by_name("password", "nora-password").await.unwrap();
        form.submit().await.unwrap();
        c.wait().at_most(Duration::from_secs(20)).for_element(Locator::Id("users")).await.unwrap();
        assert!(text_of(&c, "#users").await.contains("nora"));
        // A second time: refused with the reason.
        let form = c.form(Locator::Id("add-user")).await.unwrap();
        form.set_by_name("username", "nora").await.unwrap();
        form.set_by_name("password", "nora-password").await.unwrap();
        form.submit().await.unwrap();
        assert!(wait_text(&c, "#add-user-error").await.contains("already exists"));
        shot(&c, tag, "14-admin-accounts").await;
        for path in ["/sessions", "/cohorts", "/cohorts/c2", "/reports", &format!("/sessions/{tom_ok}")] {
            open(&c, &base, path).await;
        }
        log_out(&c, &base).await;
        c.close().await.unwrap();
    });
    println!("screenshots in {}", shots().display());
}
