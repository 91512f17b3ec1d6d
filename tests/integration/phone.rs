//! Phones and tablets: at a 390 × 844 window, every page each role can open is no wider than the
//! window (`document.documentElement.scrollWidth <= window.innerWidth`: no sideways scrolling; wide
//! tables and charts scroll inside their own box), its charts' labels are at least 8.5 px tall, and
//! "Log out" is on screen. Headless Chromium through ChromeDriver, as tests/integration/dashboard.rs.
//! Full-page screenshots go to `$STYLET_SHOTS` (default `$CARGO_TARGET_TMPDIR/phone-screenshots/`) to
//! be looked at.
//!
//! To add a page: add its path to the role's list in [`pages_of`].

use std::path::{Path, PathBuf};

use crate::common::browser::{Driver, chromium, log_in};
use crate::common::*;
use fantoccini::{Client, Locator};

const PHONE: (u32, u32) = (390, 844);

async fn phone_browser(driver: &Driver, profile: &Path) -> Client {
    chromium(driver, profile, PHONE, &["--hide-scrollbars"]).await
}

fn shots() -> PathBuf {
    let d = std::env::var_os("STYLET_SHOTS")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_TARGET_TMPDIR")).join("phone-screenshots"));
    std::fs::create_dir_all(&d).unwrap();
    d
}

async fn number(c: &Client, js: &str) -> f64 {
    c.execute(js, vec![]).await.unwrap().as_f64().unwrap()
}

/// A full-page screenshot at phone width (the window grows to the page's height, then back).
async fn shot(c: &Client, name: &str) {
    c.execute("window.scrollTo(0, 0)", vec![]).await.unwrap();
    let h = number(c, "return document.documentElement.scrollHeight").await as u32;
    c.set_window_size(PHONE.0, (h + 20).clamp(PHONE.1, 6000)).await.unwrap();
    let png = c.screenshot().await.unwrap();
    std::fs::write(shots().join(format!("{name}.png")), png).unwrap();
    c.set_window_size(PHONE.0, PHONE.1).await.unwrap();
}

/// The pages each role can open (GET, HTML), with the ids of a session of tina's (`a`, `b`).
fn pages_of(role: &str, a: &str, b: &str) -> Vec<String> {
    let mut p: Vec<String> = vec![
        "/".into(),
        "/sessions".into(),
        format!("/sessions/{a}"),
        "/tokens".into(),
    ];
    let staff: Vec<String> = vec![
        "/cohorts".into(),
        "/cohorts/c1".into(),
        "/compare".into(),
        format!("/compare?a={a}&b={b}"),
        "/trainees/tina".into(),
        "/reports".into(),
        "/reports/cohort?cohort=c1".into(),
    ];
    match role {
        "trainee" => p.push("/trainees/tina".into()),
        "instructor" => {
            p.extend(staff);
            p.push("/review-queue".into());
        }
        "curriculum" => p.extend(staff),
        "admin" => {
            p.extend(staff);
            p.push("/review-queue".into());
            p.push("/admin/users".into());
        }
        _ => unreachable!(),
    }
    p
}

#[test]
fn every_page_fits_a_phone_for_every_role() {
    let db = Db::Sqlite;
    let f = Fixture::new(STYLET);
    let srv = f.serve(&db, 2);
    let base = srv.base.clone();
    let tina = login(&base, "tina");
    let mut ids = Vec::new();
    for name in ["tina-lung", "tina-ok"] {
        ids.push(upload_scored(&base, &tina, &f.session(name)).0);
    }
    let driver = Driver::start();
    let profiles = tempfile::tempdir().unwrap();
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let mut too_wide = Vec::new();
        let mut small_chart_text = Vec::new();
        for (user, role) in [
            ("tina", "trainee"),
            ("ivan", "instructor"),
            ("cora", "curriculum"),
            ("root", "admin"),
        ] {
            let c = phone_browser(&driver, &profiles.path().join(user)).await;
            c.set_window_size(PHONE.0, PHONE.1).await.unwrap();
            c.goto(&format!("{base}/login")).await.unwrap();
            let inner = number(&c, "return window.innerWidth").await;
            assert_eq!(inner, f64::from(PHONE.0), "the window's inner width is the phone's");
            if role == "trainee" {
                let w = number(&c, "return document.documentElement.scrollWidth").await;
                assert!(w <= inner, "/login is {w} px wide at {inner} px");
            }
            log_in(&c, &base, user).await;
            for path in pages_of(role, &ids[0], &ids[1]) {
                c.goto(&format!("{base}{path}")).await.unwrap();
                let h1 = c.find(Locator::Css("h1")).await.unwrap().text().await.unwrap();
                assert!(
                    !["400", "403", "404", "409", "500"]
                        .iter()
                        .any(|code| h1.starts_with(code)),
                    "{user} {path}: error page {h1}"
                );
                let width = number(&c, "return document.documentElement.scrollWidth").await;
                if width > inner {
                    // Name the elements that stick out (the innermost few), to say what to fix.
                    let culprits = c
                        .execute(
                            "const w = window.innerWidth; return [...document.querySelectorAll('body *')] \
                             .filter(e => { for (let a = e.parentElement; a; a = a.parentElement) \
                               { if (getComputedStyle(a).overflowX !== 'visible') return false; } return true; }) \
                             .filter(e => e.getBoundingClientRect().right > w + 0.5 && \
                               ![...e.children].some(k => k.getBoundingClientRect().right > w + 0.5)) \
                             .slice(0, 5).map(e => e.tagName.toLowerCase() + (e.id ? '#' + e.id : '') + \
                               (e.className && typeof e.className === 'string' ? '.' + e.className.split(' ').join('.') : '') + \
                               ' ' + Math.round(e.getBoundingClientRect().right) + 'px').join(', ')",
                            vec![],
                        )
                        .await
                        .unwrap();
                    too_wide.push(format!("{role} {path}: {width} px ({})", culprits.as_str().unwrap_or("")));
                    shot(
                        &c,
                        &format!("too-wide-{role}-{}", path.replace(['/', '?', '=', '&'], "_")),
                    )
                    .await;
                }
                // Chart text is readable: the axis labels (plotters' size 16, an SVG font-size of
                // 16 / 1.24 units) are at least 8.5 px on screen.
                let smallest = number(
                    &c,
                    "const px = [...document.querySelectorAll('svg.chart')] \
                       .map(s => s.getBoundingClientRect().width / s.viewBox.baseVal.width * 16 / 1.24); \
                     return px.length ? Math.min(...px) : 1e9",
                )
                .await;
                if smallest < 8.5 {
                    small_chart_text.push(format!("{role} {path}: chart labels {smallest:.1} px"));
                }
                // "Log out" is on screen, not past the right edge.
                let right = number(
                    &c,
                    "const b = document.querySelector('header.top form button'); \
                     const r = b.getBoundingClientRect(); return r.width > 0 ? r.right : 1e9",
                )
                .await;
                assert!(right <= inner, "{role} {path}: Log out ends at {right} px of {inner}");
            }
            if role == "curriculum" {
                c.goto(&format!("{base}/reports/cohort?cohort=c1")).await.unwrap();
                shot(&c, "phone-curriculum-report").await;
                c.goto(&format!("{base}/cohorts/c1")).await.unwrap();
                shot(&c, "phone-curriculum-cohort").await;
            }
            if role == "trainee" {
                c.goto(&format!("{base}/sessions/{}", ids[0])).await.unwrap();
                shot(&c, "phone-trainee-review").await;
            }
            c.close().await.unwrap();
        }
        assert!(too_wide.is_empty(), "pages wider than a phone: {too_wide:#?}");
        assert!(
            small_chart_text.is_empty(),
            "chart text too small to read on a phone: {small_chart_text:#?}"
        );
    });
}
