//! Every page of the dashboard under its own Content-Security-Policy, in headless Chromium: each
//! role opens every page it may see, and every button, action and link-like control on it is
//! clicked. The test fails on any CSP violation in the browser's console (ChromeDriver's log),
//! on any inline handler, `javascript:` URL or inline script in a page, and when the report's
//! Print button does not reach `window.print`. Form submissions are cancelled in the page before
//! the clicks, so no click changes data; the API checks afterwards that nothing changed. A page
//! route the sweep does not visit fails the test, so new pages are swept too.

use std::collections::BTreeSet;
use std::time::Duration;

use crate::common::browser::{Driver, chromium, js, log_in};
use crate::common::*;
use fantoccini::{Client, Locator};
use serde_json::{Value, json};

/// Routes that are not HTML pages (images, files, scripts, the PDF), so nothing to click.
const NOT_PAGES: [&str; 11] = [
    "/sessions/{id}/file",
    "/sessions/{id}/slices.png",
    "/sessions/{id}/frame",
    "/sessions/{id}/overview",
    "/sessions/{id}/hits/{n}/slices.png",
    "/reports/cohort.pdf",
    "/assets/player.js",
    "/assets/dashboard.js",
    // LTI: a platform's redirect endpoint, a key set and a script (the launch pages are POSTs,
    // opened in tests/integration/lti.rs).
    "/lti/login",
    "/lti/jwks",
    "/lti/submit.js",
];

/// The dashboard's GET routes, read from its router.
fn page_routes() -> BTreeSet<String> {
    let src = include_str!("../../dashboard/src/lib.rs");
    let mut routes = BTreeSet::new();
    let mut rest = src;
    while let Some(at) = rest.find(".route(") {
        rest = &rest[at + ".route(".len()..];
        let call: String = rest.chars().take_while(|c| *c != ')').collect();
        let path = call.split('"').nth(1).unwrap_or_default();
        if call.contains("get(") && !NOT_PAGES.contains(&path) && !path.starts_with("/assets/favicon") {
            routes.insert(path.to_string());
        }
    }
    routes
}

/// The route pattern a concrete path opens (`/sessions/42?turn=3` → `/sessions/{id}`).
fn pattern(path: &str, ids: &[(&str, &str)]) -> String {
    let mut p = path.split('?').next().unwrap().to_string();
    for (value, name) in ids {
        p = p
            .split('/')
            .map(|seg| {
                if seg == *value {
                    name.to_string()
                } else {
                    seg.to_string()
                }
            })
            .collect::<Vec<_>>()
            .join("/");
    }
    p
}

/// The browser's console since the last call (ChromeDriver's log, enabled by
/// `goog:loggingPrefs`; not part of WebDriver, so read from ChromeDriver directly).
async fn console(driver: &Driver, c: &Client) -> Vec<String> {
    let id = c.session_id().await.unwrap().expect("a WebDriver session");
    let body = ureq::post(&format!("{}/session/{id}/se/log", driver.url))
        .set("Content-Type", "application/json")
        .send_string(r#"{"type":"browser"}"#)
        .expect("ChromeDriver's browser log")
        .into_string()
        .unwrap();
    let v: Value = serde_json::from_str(&body).unwrap();
    v["value"]
        .as_array()
        .map(|a| {
            a.iter()
                .filter_map(|e| e["message"].as_str().map(str::to_string))
                .collect()
        })
        .unwrap_or_default()
}

async fn assert_no_violation(driver: &Driver, c: &Client, what: &str) {
    let bad: Vec<String> = console(driver, c)
        .await
        .into_iter()
        .filter(|m| m.contains("Content Security Policy"))
        .collect();
    assert!(bad.is_empty(), "{what}: CSP violations: {bad:#?}");
}

/// Inline handlers, `javascript:` URLs and inline scripts in the page (a click sweep cannot fire
/// `onchange` and the like, and Chromium reports a blocked handler only when it runs).
const INLINE_SCAN: &str = r#"
var bad = [];
document.querySelectorAll('*').forEach(function (el) {
  for (var a of el.attributes) {
    if (/^on/i.test(a.name)) bad.push(el.tagName + '[' + a.name + ']');
    if (/^\s*javascript:/i.test(a.value)) bad.push(el.tagName + '[' + a.name + '=javascript:]');
  }
});
document.querySelectorAll('script:not([src])').forEach(function () { bad.push('inline script'); });
return bad;
"#;

/// Marks the page, cancels every form submission (the handlers still run, so a blocked inline
/// one is still reported) and stands in for window.print.
const STUBS: &str = r#"
window.__probe = true; window.__printed = 0;
window.print = function () { window.__printed++; };
window.confirm = function () { return true; }; window.alert = function () {};
document.addEventListener('submit', function (e) { e.preventDefault(); }, true);
HTMLFormElement.prototype.submit = function () {};
"#;

const CLICKABLE: &str = "button, input[type=submit], input[type=button], [data-action], #overview a.turn";

/// Opens `path`, checks it, then clicks every visible control on it; returns how often
/// window.print ran.
async fn sweep(driver: &Driver, c: &Client, base: &str, who: &str, path: &str) -> u64 {
    let what = format!("{who} {path}");
    let open = || async {
        c.goto(&format!("{base}{path}")).await.unwrap();
        let h1 = c.find(Locator::Css("h1")).await.unwrap().text().await.unwrap();
        assert!(!h1.starts_with(['4', '5']), "{what}: error page {h1}");
        let inline = js(c, INLINE_SCAN).await;
        assert_eq!(inline, json!([]), "{what}: inline script in the page");
        js(c, STUBS).await;
    };
    open().await;
    assert_no_violation(driver, c, &what).await;
    let mut printed = 0;
    let mut i = 0;
    loop {
        let all = c.find_all(Locator::Css(CLICKABLE)).await.unwrap();
        let Some(el) = all.get(i) else { break };
        i += 1;
        if !el.is_displayed().await.unwrap_or(false) || !el.is_enabled().await.unwrap_or(false) {
            continue;
        }
        let label = el.html(false).await.unwrap_or_default();
        // A control under another element cannot be clicked by a person either.
        if el.click().await.is_err() {
            continue;
        }
        tokio::time::sleep(Duration::from_millis(150)).await;
        assert_no_violation(driver, c, &format!("{what}, clicking {label}")).await;
        if js(c, "return window.__probe === true").await != json!(true) {
            // The click opened another page: back to this one, from the next control on.
            open().await;
        } else {
            printed += js(c, "return window.__printed").await.as_u64().unwrap_or(0);
            js(c, "window.__printed = 0").await;
        }
    }
    // Still logged in: no click got through to Log out.
    if who != "nobody" {
        c.find(Locator::Css("header.top .who"))
            .await
            .unwrap_or_else(|_| panic!("{what}: logged out by the sweep"));
    }
    printed
}

#[test]
fn every_button_of_every_page_works_under_the_content_security_policy() {
    let f = Fixture::new(STYLET);
    let srv = f.serve(&Db::Sqlite, 2);
    let base = srv.base.clone();
    let upload = |who: &str, name: &str| upload_scored(&base, &login(&base, who), &f.session(name)).0;
    let lung = upload("tina", "tina-lung");
    let ok = upload("tina", "tina-ok");
    let tom = upload("tom", "tom-ok");
    for who in ["tina", "ivan"] {
        let (status, v) = api(&base, "POST", "/api/tokens", who, Some(json!({"label": "sweep"})));
        assert_eq!(status, 201, "{who} creates a token: {v}");
    }
    let catalogue = atlases(&base);
    let s = |id: &str| format!("/sessions/{id}");
    let compare = format!("/compare?s={lung}&s={ok}");
    let common = vec![
        "/".to_string(),
        "/sessions".into(),
        s(&lung),
        format!("{}?turn=3", s(&lung)),
        "/atlases".into(),
        compare.clone(),
        "/trainees/tina".into(),
        "/tokens".into(),
        "/pair".into(),
    ];
    let staff: Vec<String> = [
        "/cohorts",
        "/cohorts/c1",
        "/compare",
        "/reports",
        "/reports/cohort?cohort=c1",
    ]
    .iter()
    .map(|p| p.to_string())
    .collect();
    let plan: Vec<(&str, Vec<String>)> = vec![
        ("nobody", vec!["/login".into()]),
        ("tina", common.clone()),
        (
            "ivan",
            [
                common.clone(),
                staff.clone(),
                vec!["/review-queue".into(), "/review-queue?only=flagged".into()],
            ]
            .concat(),
        ),
        ("cora", [common.clone(), staff.clone()].concat()),
        (
            "root",
            [
                common,
                staff,
                vec![
                    "/review-queue".into(),
                    s(&tom),
                    "/admin/users".into(),
                    "/admin/users?q=t".into(),
                    "/admin/atlases".into(),
                    "/admin/lti".into(),
                ],
            ]
            .concat(),
        ),
    ];

    // Every page route is swept by some role.
    let ids = [
        (lung.as_str(), "{id}"),
        (tom.as_str(), "{id}"),
        ("c1", "{name}"),
        ("tina", "{username}"),
    ];
    let visited: BTreeSet<String> = plan
        .iter()
        .flat_map(|(_, paths)| paths.iter().map(|p| pattern(p, &ids)))
        .collect();
    let missed: Vec<String> = page_routes().into_iter().filter(|r| !visited.contains(r)).collect();
    assert!(missed.is_empty(), "pages the sweep does not open: {missed:?}");

    let driver = Driver::start();
    let profiles = tempfile::tempdir().unwrap();
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        for (who, paths) in &plan {
            let c = chromium(&driver, &profiles.path().join(who), (1280, 900), &[]).await;
            if *who != "nobody" {
                log_in(&c, &base, who).await;
            }
            for path in paths {
                let printed = sweep(&driver, &c, &base, who, path).await;
                if path.starts_with("/reports/cohort") {
                    assert_eq!(printed, 1, "{who} {path}: the Print button prints");
                } else {
                    assert_eq!(printed, 0, "{who} {path}: nothing else prints");
                }
            }
            c.close().await.unwrap();
        }
    });

    // The cancelled submissions changed nothing: every account still logs in (`api` does),
    // no session was deleted, no atlas withdrawn, no token revoked.
    let (_, sessions) = api(&base, "GET", "/api/sessions", "root", None);
    assert_eq!(sessions["total"], json!(3), "the sweep deleted no session: {sessions}");
    assert_eq!(atlases(&base), catalogue, "the sweep withdrew no atlas");
    for who in ["tina", "ivan"] {
        let (_, tokens) = api(&base, "GET", "/api/tokens", who, None);
        let rows = tokens["tokens"].as_array().cloned().unwrap_or_default();
        assert!(
            rows.iter().any(|t| t["label"] == "sweep" && t["revoked_at"].is_null()),
            "{who}'s token is not revoked: {tokens}"
        );
    }
}

/// A JSON API call as `who` (logged in with the fixture's password): status and body.
fn api(base: &str, method: &str, path: &str, who: &str, body: Option<Value>) -> (u16, Value) {
    let body = body.map(|b| b.to_string());
    let (status, v, _) = call(
        method,
        &format!("{base}{path}"),
        Some(&login(base, who)),
        body.as_deref().map(str::as_bytes),
        true,
    );
    (status, v)
}

/// The atlas catalogue as the admin sees it (it changes when an atlas is withdrawn).
fn atlases(base: &str) -> Value {
    let (status, v) = api(base, "GET", "/api/atlases", "root", None);
    assert_eq!(status, 200, "{v}");
    v
}
