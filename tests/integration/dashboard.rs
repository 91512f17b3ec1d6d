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

use std::path::{Path, PathBuf};

use std::time::Duration;

use crate::common::browser::{Driver, chromium, click, log_in, type_into};
use crate::common::*;
use fantoccini::{Client, Locator};
use serde_json::{Value, json};

/// A fresh headless Chromium at desktop size.
async fn browser(driver: &Driver, profile: &Path) -> Client {
    chromium(driver, profile, (1400, 1000), &[]).await
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

/// Submits a form and waits for the page it leads to. The old page is marked first, so that an
/// element both pages have is not found on the old one while the browser is still navigating.
async fn submit_and_wait(c: &Client, form: fantoccini::elements::Form) {
    c.execute("window.__styletOldPage = true", vec![]).await.unwrap();
    form.submit().await.unwrap();
    for _ in 0..300 {
        let loaded = c
            .execute(
                "return window.__styletOldPage === undefined && document.readyState === 'complete'",
                vec![],
            )
            .await;
        if matches!(loaded, Ok(Value::Bool(true))) {
            return;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    panic!("the page the form leads to did not load within 30 s");
}

async fn log_out(c: &Client, base: &str) {
    c.goto(&format!("{base}/")).await.unwrap();
    click(c, Locator::Css("header.top form button")).await;
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

on_both_databases!(every_role_uses_the_dashboard_in_headless_chromium => every_role_uses_the_dashboard, "dashboard");

fn every_role_uses_the_dashboard(db: Db) {
    let tag = db.name();
    let f = Fixture::new(STYLET);
    let srv = f.serve(&db, 2);
    let base = srv.base.clone();
    // Data the pages show: tina's lung hit and tom's success, uploaded through the API.
    let upload = |who: &str, name: &str| {
        let auth = login(&base, who);
        upload_scored(&base, &auth, &f.session(name)).0
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
        type_into(&c, Locator::Id("session-file"), ok_file.to_str().unwrap()).await;
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
        // The rubric's metrics by their names for people, never their identifiers.
        let rubric = text_of(&c, "#rubric").await;
        assert!(rubric.contains("target not reached") && !rubric.contains("target_not_reached"), "{rubric}");
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
        submit_and_wait(&c, form).await;
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
        type_into(&c, Locator::Css("#comment-form textarea"), "Aim one rib lower next time.").await;
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
        submit_and_wait(&c, c.form(Locator::Id("report-form")).await.unwrap()).await;
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
        submit_and_wait(&c, form).await;
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
        // Atlases: the admin withdraws the phantom (the box must be ticked); it leaves the
        // catalogue, and the sessions on it still open.
        c.find(Locator::Id("nav-atlases")).await.unwrap().click().await.unwrap();
        c.wait().at_most(Duration::from_secs(20)).for_element(Locator::Id("atlases")).await.unwrap();
        assert!(text_of(&c, "#atlases").await.contains("in the catalogue"));
        shot(&c, tag, "15-admin-atlases").await;
        let form = c.form(Locator::Css("form.withdraw")).await.unwrap();
        c.find(Locator::Css("form.withdraw input[name=confirm]")).await.unwrap().click().await.unwrap();
        submit_and_wait(&c, form).await;
        c.wait().at_most(Duration::from_secs(20)).for_element(Locator::Id("atlases")).await.unwrap();
        let status = text_of(&c, "#atlases td.status").await;
        assert!(status.starts_with("withdrawn"), "{status}");
        assert!(c.find(Locator::Css("form.withdraw")).await.is_err(), "a withdrawn atlas has no Withdraw button");
        shot(&c, tag, "16-admin-atlas-withdrawn").await;
        open(&c, &base, "/atlases").await;
        assert!(c.find(Locator::Css("#catalogue tbody tr")).await.is_err(), "the catalogue still lists it");
        open(&c, &base, &format!("/sessions/{tom_ok}")).await;
        log_out(&c, &base).await;
        c.close().await.unwrap();
    });
    println!("screenshots in {}", shots().display());
}

/// A URL's status, content type and size, fetched by the browser with its login.
async fn fetch_head(c: &Client, url: &str) -> (u64, String, u64) {
    let v = c
        .execute(
            "return fetch(arguments[0]).then(r => r.arrayBuffer().then(b => [r.status, r.headers.get('content-type') || '', b.byteLength]))",
            vec![json!(url)],
        )
        .await
        .unwrap();
    (
        v[0].as_u64().unwrap(),
        v[1].as_str().unwrap().to_string(),
        v[2].as_u64().unwrap(),
    )
}

/// The natural width of an image once it has loaded (0 if it failed).
async fn image_width(c: &Client, css: &str) -> u64 {
    c.execute(
        "const i = document.querySelector(arguments[0]); \
         return new Promise(r => { if (i.complete) r(i.naturalWidth); else { i.onload = () => r(i.naturalWidth); i.onerror = () => r(0); } });",
        vec![json!(css)],
    )
    .await
    .unwrap()
    .as_u64()
    .unwrap_or(0)
}

/// A scored session's reasons in words (from the API's session row); never empty for a failure.
fn reasons_of(name: &str, row: &Value) -> Vec<String> {
    let reasons: Vec<String> = row["reasons"]
        .as_array()
        .unwrap_or_else(|| panic!("{name}: no reasons in {row}"))
        .iter()
        .map(|r| r.as_str().unwrap().to_string())
        .collect();
    assert!(!reasons.is_empty(), "{name} failed without reasons");
    reasons
}

/// Metric identifiers that must never reach text meant for people.
const IDENTIFIERS: [&str; 6] = [
    "target_not_reached",
    "target_not_confirmed",
    "risk_hits",
    "bone_contacts",
    "time_total_s",
    "max_force_n",
];

/// "Show where and why": the lung-hit review shows slices through the lung hit with the point
/// marked and the consequence from the scenario TOML; the success review shows the planned path
/// (legend) and the same guided-path deviation as `stylet score`; force peaks are named; an
/// instructor's comment at a moment is listed with its time and marked on the charts; every failed
/// session has its reasons in words on its review and on the trainee's home.
#[test]
fn the_review_shows_where_and_why_in_headless_chromium() {
    let db = Db::Sqlite;
    let f = Fixture::new(STYLET);
    let srv = f.serve(&db, 2);
    let base = srv.base.clone();
    let tina = login(&base, "tina");
    let mut rows = Vec::new();
    for name in ["tina-lung", "tina-ok", "tina-two"] {
        let (id, row) = upload_scored(&base, &tina, &f.session(name));
        rows.push((name, id, row));
    }
    let (lung, lung_row) = (&rows[0].1, &rows[0].2);
    let (ok_id, ok_row) = (&rows[1].1, &rows[1].2);
    let hits = lung_row["score"]["metrics"]["risk_hits"].as_array().unwrap().clone();
    let lung_hit = hits
        .iter()
        .position(|h| h["structure"].as_str().unwrap().contains("lung"))
        .expect("the lung-hit session hits a lung");
    // The guided metrics the CLI prints for the success session.
    let cli: Value = serde_json::from_str(&ok(&[
        "score",
        "--json",
        "--atlas",
        s(&f.atlases().join("phantom")),
        s(&f.session("tina-ok")),
    ]))
    .unwrap();
    let guided = cli["metrics"]["guided"].clone();
    assert!(guided.is_object(), "the CLI scores guided metrics: {cli}");
    assert_eq!(
        ok_row["score"]["metrics"]["guided"], guided,
        "the service's guided metrics are the CLI's"
    );
    // A comment's moment must lie within the session.
    let ivan = login(&base, "ivan");
    let (status, body, _) = call(
        "POST",
        &format!("{base}/api/sessions/{lung}/comments"),
        Some(&ivan),
        Some(json!({"body": "later", "at_s": 1.0e9}).to_string().as_bytes()),
        false,
    );
    assert_eq!(status, 400, "{body}");

    let driver = Driver::start();
    let profiles = tempfile::tempdir().unwrap();
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let c = browser(&driver, &profiles.path().join("p")).await;
        log_in(&c, &base, "ivan").await;

        // ---- the lung hit: where and why
        open(&c, &base, &format!("/sessions/{lung}")).await;
        let hit = format!("#hit-{lung_hit}");
        let consequence = text_of(&c, &format!("{hit} .consequence")).await;
        assert!(consequence.to_lowercase().contains("pneumothorax"), "{consequence}");
        let src = c
            .find(Locator::Css(&format!("{hit} img.hit-slices")))
            .await
            .unwrap()
            .attr("src")
            .await
            .unwrap()
            .unwrap();
        assert_eq!(src, format!("/sessions/{lung}/hits/{}/slices.png", lung_hit + 1));
        let (status, kind, size) = fetch_head(&c, &src).await;
        assert_eq!((status, kind.as_str()), (200, "image/png"));
        assert!(size > 10_000, "a real picture: {size} bytes");
        assert!(image_width(&c, &format!("{hit} img.hit-slices")).await > 500);
        // A hit the session does not have, and one that is no number.
        for n in [format!("{}", hits.len() + 1), "0".into(), "x".into()] {
            let (status, _, _) = fetch_head(&c, &format!("/sessions/{lung}/hits/{n}/slices.png")).await;
            assert_eq!(status, 404, "hit {n}");
        }
        // The result card: failed, with its reasons in words.
        let result = text_of(&c, "#result").await;
        assert!(result.contains("failed"), "{result}");
        let reasons = c.find_all(Locator::Css("#result #reasons li")).await.unwrap();
        assert!(!reasons.is_empty(), "no reasons: {result}");
        let page = body_text(&c).await;
        for id in IDENTIFIERS {
            assert!(!page.contains(id), "the page shows the identifier {id}");
        }
        // Force peaks named by the structure punctured.
        let force = c
            .find(Locator::Css("#force-chart svg"))
            .await
            .unwrap()
            .html(false)
            .await
            .unwrap();
        let labels: Vec<&str> = force
            .split("<text")
            .skip(1)
            .filter_map(|t| Some(t.split_once('>')?.1.split_once("</text>")?.0.trim()))
            .collect();
        for want in ["skin", "right lung"] {
            assert!(
                labels.contains(&want),
                "no {want} peak label on the force chart: {labels:?}"
            );
        }
        // A comment at a moment: listed with its time, a marker on both charts.
        type_into(
            &c,
            Locator::Css("#comment-form textarea"),
            "Here the needle enters the lung.",
        )
        .await;
        let at = hits[lung_hit]["t_s"].as_f64().unwrap();
        type_into(&c, Locator::Css("#comment-form input[name=at_s]"), &format!("{at:.2}")).await;
        click(&c, Locator::Css("#comment-form button")).await;
        let comment = wait_text(&c, "#review li.comment").await;
        assert!(
            comment.contains(&format!("[1] at {at:.2} s")) && comment.contains("enters the lung"),
            "{comment}"
        );
        for chart in ["#force-chart svg", "#depth-chart svg"] {
            let svg = c.find(Locator::Css(chart)).await.unwrap().html(false).await.unwrap();
            assert!(svg.contains("[1] comment"), "{chart} lacks the comment marker");
        }
        shot(&c, "where-why", "01-lung-hit-review").await;

        // ---- the success: planned path and deviation
        open(&c, &base, &format!("/sessions/{ok_id}")).await;
        let legend = text_of(&c, "#tip-path-legend").await;
        let path_name = guided["path"].as_str().unwrap();
        assert!(
            legend.contains(&format!("planned path '{path_name}'")) && legend.contains("needle tip path"),
            "{legend}"
        );
        assert!(image_width(&c, "#tip-path").await > 500);
        let deviation = text_of(&c, "#guided").await;
        for (key, unit) in [
            ("entry_distance_mm", " mm"),
            ("angle_error_deg", "°"),
            ("mean_deviation_mm", " mm"),
            ("max_deviation_mm", " mm"),
        ] {
            let want = format!("{:.1}{unit}", guided[key].as_f64().unwrap());
            assert!(deviation.contains(&want), "{key}: {want} not in {deviation}");
        }
        assert!(text_of(&c, "#result").await.contains("passed"));
        shot(&c, "where-why", "02-success-review").await;
        log_out(&c, &base).await;

        // ---- every failed session: its reasons in words on its review
        log_in(&c, &base, "tina").await;
        let failed: Vec<&(&str, String, Value)> = rows.iter().filter(|r| r.2["outcome"] == "failed").collect();
        assert!(!failed.is_empty(), "the lung hit fails");
        for (name, id, row) in &failed {
            let reasons = reasons_of(name, row);
            open(&c, &base, &format!("/sessions/{id}")).await;
            let card = text_of(&c, "#result").await;
            for r in &reasons {
                assert!(card.contains(r.as_str()), "{name}: review lacks '{r}': {card}");
            }
        }
        log_out(&c, &base).await;
        c.close().await.unwrap();
    });
}

/// "Reasons everywhere": every failed session of the trainee says why on the trainee's home
/// page, short (its first reason's first clause) with a link to the others on its review (the
/// review page has them all: the test above).
#[test]
fn every_failed_session_has_its_reasons_on_the_trainee_home() {
    let db = Db::Sqlite;
    let f = Fixture::new(STYLET);
    let srv = f.serve(&db, 2);
    let base = srv.base.clone();
    let tina = login(&base, "tina");
    let mut failed = Vec::new();
    for name in ["tina-lung", "tina-ok", "tina-two"] {
        let id = upload(&base, &tina, &f.session(name));
        let row = wait_scored(&base, &tina, &id);
        if row["outcome"] == "failed" {
            failed.push((name, id, reasons_of(name, &row)));
        }
    }
    assert!(!failed.is_empty(), "the lung hit fails");
    let driver = Driver::start();
    let profiles = tempfile::tempdir().unwrap();
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let c = browser(&driver, &profiles.path().join("p")).await;
        log_in(&c, &base, "tina").await;
        open(&c, &base, "/").await;
        let home = body_text(&c).await;
        let source = c.source().await.unwrap();
        shot(&c, "where-why", "03-trainee-home").await;
        for (name, id, reasons) in &failed {
            let short = stylet_dashboard::layout::short_reason(&reasons[0]);
            assert!(home.contains(&short), "{name}: the trainee home lacks '{short}'");
            if reasons.len() > 1 {
                let link = format!("href=\"/sessions/{id}#reasons\"");
                assert!(source.contains(&link), "{name}: no link to the other reasons");
                assert!(home.contains(&format!("+{} more", reasons.len() - 1)), "{name}: {home}");
            }
        }
        for id in IDENTIFIERS {
            assert!(!home.contains(id), "the home shows the identifier {id}");
        }
        log_out(&c, &base).await;
        c.close().await.unwrap();
    });
}

/// The LTI platforms page: an admin sees the values to paste into the platform, registers a
/// platform (a bad registration is refused with every problem named and the typed values kept)
/// and adds a deployment id to it (once); it is listed there and by `stylet lti list`, with the
/// deployment `stylet lti add-deployment` added; a trainee may not open the page.
#[test]
fn the_lti_page_registers_a_platform() {
    let f = Fixture::new(STYLET);
    let db = Db::Sqlite;
    let srv = f.serve(&db, 1);
    let base = srv.base.clone();
    let driver = Driver::start();
    let profiles = tempfile::tempdir().unwrap();
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let c = browser(&driver, &profiles.path().join("tina")).await;
        log_in(&c, &base, "tina").await;
        c.goto(&format!("{base}/admin/lti")).await.unwrap();
        assert!(
            text_of(&c, "h1").await.starts_with("403"),
            "a trainee registers nothing"
        );

        let c = browser(&driver, &profiles.path().join("root")).await;
        log_in(&c, &base, "root").await;
        c.find(Locator::Id("nav-lti")).await.unwrap().click().await.unwrap();
        c.wait()
            .at_most(Duration::from_secs(20))
            .for_element(Locator::Id("lti-register"))
            .await
            .unwrap();
        assert_eq!(text_of(&c, "h1").await, "LTI platforms");
        let values = text_of(&c, "#lti-tool-values").await;
        for route in ["/lti/launch", "/lti/login", "/lti/jwks"] {
            assert!(values.contains(&format!("{base}{route}")), "{values}");
        }
        assert!(body_text(&c).await.contains("None yet."));
        let fill = |issuer: &'static str, deployments: &'static str| {
            let c = c.clone();
            async move {
                let form = c.form(Locator::Id("lti-register")).await.unwrap();
                form.set_by_name("issuer", issuer).await.unwrap();
                form.set_by_name("client_id", "Kq3xT0dBq1XvCzY").await.unwrap();
                form.set_by_name("deployment_ids", deployments).await.unwrap();
                form.set_by_name("keyset_url", "https://moodle.example.org/mod/lti/certs.php")
                    .await
                    .unwrap();
                form.set_by_name("auth_url", "https://moodle.example.org/mod/lti/auth.php")
                    .await
                    .unwrap();
                form.set_by_name("token_url", "https://moodle.example.org/mod/lti/token.php")
                    .await
                    .unwrap();
                form
            }
        };
        // A deployment id with a space and an issuer that is no URL: both named, nothing kept.
        let form = fill("moodle.example.org", "1 2").await;
        form.submit().await.unwrap();
        let error = wait_text(&c, ".lti-error").await;
        assert!(error.contains("issuer"), "{error}");
        let errors = body_text(&c).await;
        assert!(errors.contains("a deployment id must be"), "{errors}");
        assert!(
            body_text(&c).await.contains("None yet."),
            "a refused registration keeps nothing"
        );
        let kept = c
            .find(Locator::Id("lti-issuer"))
            .await
            .unwrap()
            .prop("value")
            .await
            .unwrap();
        assert_eq!(kept.as_deref(), Some("moodle.example.org"), "the typed values stay");
        let form = fill("https://moodle.example.org", "3\n7").await;
        submit_and_wait(&c, form).await;
        c.wait()
            .at_most(Duration::from_secs(20))
            .for_element(Locator::Id("lti-platforms"))
            .await
            .unwrap();
        let row = text_of(&c, "#lti-platforms tbody tr").await;
        assert!(
            row.contains("https://moodle.example.org") && row.contains("Kq3xT0dBq1XvCzY") && row.contains("3, 7"),
            "{row}"
        );
        assert!(
            row.contains("Instructor, TeachingAssistant, ContentDeveloper"),
            "the default roles: {row}"
        );
        shot(&c, "lti", "01-registration").await;
        // Another installation's deployment id, added on the row; the same one again is refused.
        for (id, error) in [("11", None), ("11", Some("registered already"))] {
            let form = c
                .form(Locator::Css("#lti-platforms form.add-deployment"))
                .await
                .unwrap();
            form.set_by_name("deployment_id", id).await.unwrap();
            match error {
                None => {
                    submit_and_wait(&c, form).await;
                    c.wait()
                        .at_most(Duration::from_secs(20))
                        .for_element(Locator::Id("lti-platforms"))
                        .await
                        .unwrap();
                    assert!(text_of(&c, "#lti-platforms tbody tr").await.contains("3, 7, 11"));
                }
                Some(words) => {
                    submit_and_wait(&c, form).await;
                    assert!(text_of(&c, ".lti-error").await.contains(words));
                }
            }
        }
        // The same issuer and client id again: refused, named.
        let form = fill("https://moodle.example.org", "9").await;
        submit_and_wait(&c, form).await;
        assert!(text_of(&c, ".lti-error").await.contains("registered already"));
        println!("screenshots in {}", shots().display());
    });
    let data = f.data();
    let mut add = vec![
        "lti",
        "add-deployment",
        "--data-dir",
        s(&data),
        "--issuer",
        "https://moodle.example.org",
        "--client-id",
        "Kq3xT0dBq1XvCzY",
        "--deployment-id",
        "12",
    ];
    add.extend(db.args());
    STYLET.ok(&add);
    let mut args = vec!["lti", "list", "--data-dir", s(&data)];
    args.extend(db.args());
    let listed = STYLET.ok(&args);
    assert!(
        listed.contains("https://moodle.example.org") && listed.contains("deployments 3,7,11,12"),
        "{listed}"
    );
}

/// The pairing page (docs/integration.md "Pairing a simulator") in Chromium: a trainee shows a
/// pairing code, which pairs a simulator (through the API, as the simulator does), and a
/// sign-in code; an instructor pairs a lab machine of a cohort, sees it listed and revokes it.
#[test]
fn the_pairing_page_shows_codes_that_pair_and_lists_lab_machines() {
    let f = Fixture::new(STYLET);
    let db = Db::Sqlite;
    let srv = f.serve(&db, 1);
    let base = srv.base.clone();
    let pair = |code: &str, label: &str| {
        let body = json!({"code": code, "label": label}).to_string();
        let (status, json, _) = call("POST", &format!("{base}/api/pair"), None, Some(body.as_bytes()), true);
        assert_eq!(status, 201, "{json}");
        json
    };
    let driver = Driver::start();
    let profiles = tempfile::tempdir().unwrap();
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let c = browser(&driver, &profiles.path().join("tina")).await;
        log_in(&c, &base, "tina").await;
        assert_eq!(open(&c, &base, "/pair").await, "Pair a simulator");
        assert!(
            c.find(Locator::Css("#pair-lab")).await.is_err(),
            "a trainee pairs no lab machine"
        );
        let form = c.form(Locator::Css("#pair-simulator")).await.unwrap();
        submit_and_wait(&c, form).await;
        let code = wait_text(&c, "#pairing-code").await;
        assert_eq!((code.len(), &code[5..6]), (11, "-"), "{code}");
        assert!(
            text_of(&c, "#pairing-box")
                .await
                .contains("pairs a simulator with your account")
        );
        shot(&c, "pairing", "01-trainee-code").await;
        let paired = pair(&code, "tina's laptop");
        assert_eq!(
            (paired["kind"].as_str(), paired["username"].as_str()),
            (Some("simulator"), Some("tina"))
        );
        let form = c.form(Locator::Css("#pair-sign-in")).await.unwrap();
        submit_and_wait(&c, form).await;
        assert!(
            text_of(&c, "#pairing-box")
                .await
                .contains("signs you in at a lab machine")
        );

        let c = browser(&driver, &profiles.path().join("ivan")).await;
        log_in(&c, &base, "ivan").await;
        open(&c, &base, "/pair").await;
        assert!(body_text(&c).await.contains("No lab machines yet."));
        let form = c.form(Locator::Css("#pair-lab")).await.unwrap();
        submit_and_wait(&c, form).await;
        let box_text = text_of(&c, "#pairing-box").await;
        assert!(box_text.contains("pairs a lab machine with a cohort c1"), "{box_text}");
        shot(&c, "pairing", "02-instructor-lab-code").await;
        let lab = pair(&text_of(&c, "#pairing-code").await, "skills lab, bay 2");
        assert_eq!(lab["cohort"], "c1", "{lab}");
        open(&c, &base, "/pair").await;
        let row = text_of(&c, "#lab-machines tbody tr").await;
        assert!(
            row.contains("skills lab, bay 2") && row.contains("ivan") && row.contains("active"),
            "{row}"
        );
        shot(&c, "pairing", "03-lab-machines").await;
        let form = c.form(Locator::Css("#lab-machines tbody tr form")).await.unwrap();
        submit_and_wait(&c, form).await;
        assert!(text_of(&c, "#lab-machines tbody tr").await.contains("revoked"));
        println!("screenshots in {}", shots().display());
    });
}
