//! The replay player on the session review, in headless Chromium (SQLite and PostgreSQL): an
//! instructor opens a session, plays, seeks by the timeline and by clicking the force chart, jumps
//! to the risk hit, and the frames and the chart cursor follow; a frame equals
//! `stylet render --session … --at …` of the same tick; a trainee sees only their own sessions'
//! frames; a session still being scored answers 409. Screenshots of the player on a desktop and a
//! tablet-sized window go to `$CARGO_TARGET_TMPDIR/browser-screenshots/`.

use std::path::{Path, PathBuf};
use std::time::Duration;

use crate::common::browser::{Driver, chromium, js, log_in, until};
use crate::common::*;
use fantoccini::{Client, Locator};
use serde_json::json;

on_both_databases!(an_instructor_plays_and_seeks_the_replay => the_player, "player");

fn shots() -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR")).join("browser-screenshots");
    std::fs::create_dir_all(&d).unwrap();
    d
}

async fn shown_tick(c: &Client) -> u64 {
    js(c, "return Number(document.getElementById('player').dataset.shown)")
        .await
        .as_u64()
        .unwrap()
}

fn the_player(db: Db) {
    let tag = db.name();
    let f = Fixture::new(STYLET);
    let srv = f.serve(&db, 2);
    let base = srv.base.clone();
    let tina = login(&base, "tina");
    let upload = |who: &Auth, name: &str| upload_scored(&base, who, &f.session(name));
    let (lung, lung_row) = upload(&tina, "tina-lung");
    let tom = login(&base, "tom");
    let (tom_id, _) = upload(&tom, "tom-ok");
    let ivan = login(&base, "ivan");

    // Who may see which frames: the session's trainee and the instructors, not another trainee
    // (404, as if the session did not exist); a bad view or size is a 400 that says why.
    let frame = |id: &str, query: &str| format!("{base}/sessions/{id}/frame?{query}");
    let (status, png) = get_bytes(&frame(&lung, "view=axial&tick=2000"), &tina);
    assert_eq!(status, 200);
    assert_eq!(&png[1..4], b"PNG");
    assert_eq!(get_bytes(&frame(&lung, "view=axial&tick=2000"), &ivan).0, 200);
    assert_eq!(get_bytes(&frame(&lung, "view=axial&tick=2000"), &tom).0, 404);
    assert_eq!(get_bytes(&frame(&tom_id, "view=axial&tick=2000"), &tina).0, 404);
    let (status, body) = get_bytes(&frame(&lung, "view=ct&tick=2000"), &ivan);
    assert_eq!(status, 400);
    assert!(String::from_utf8_lossy(&body).contains("unknown view"));
    assert_eq!(get_bytes(&frame(&lung, "view=3d&tick=2000&w=5000&h=100"), &ivan).0, 400);
    assert_eq!(get_bytes(&frame(&lung, "view=3d&tick=99999999"), &ivan).0, 404);
    assert_eq!(get_bytes(&frame(&lung, "view=3d&tick=-1"), &ivan).0, 400);

    // The frame at the risk hit equals `stylet render` of the same tick, view by view.
    // The first risk hit in time (the score lists them by structure).
    let hit_s = lung_row["score"]["metrics"]["risk_hits"]
        .as_array()
        .unwrap()
        .iter()
        .map(|h| h["t_s"].as_f64().unwrap())
        .fold(f64::INFINITY, f64::min);
    let hit_tick = (hit_s * 1000.0).round() as u64;
    let (atlas_dir, lung_file) = (f.atlases().join("phantom"), f.session("tina-lung"));
    for (view, extra) in [
        ("3d", &["--tagging", "risk"][..]),
        ("axial", &[][..]),
        ("ultrasound", &[][..]),
        ("xray", &[][..]),
    ] {
        let (status, served) = get_bytes(
            &frame(&lung, &format!("view={view}&tick={hit_tick}&w=320&h=240")),
            &ivan,
        );
        assert_eq!(status, 200, "{view}");
        let png = f.dir.path().join(format!("cli-{view}.png"));
        let at = format!("{:.3}", hit_tick as f64 / 1000.0);
        let mut args = vec![
            "render",
            "--atlas",
            s(&atlas_dir),
            "--session",
            s(&lung_file),
            "--at",
            &at,
            "--view",
            view,
            "--size",
            "320x240",
            "--out",
            s(&png),
        ];
        args.extend_from_slice(extra);
        ok(&args);
        let served_png = f.dir.path().join(format!("served-{view}.png"));
        std::fs::write(&served_png, &served).unwrap();
        let a = stylet_render::image::Image::read_png(&png).unwrap();
        let b = stylet_render::image::Image::read_png(&served_png).unwrap();
        assert!(
            a == b,
            "{view}: the player's frame differs from stylet render's at tick {hit_tick}"
        );
    }
    // Without JavaScript: the review at ?tick=N shows the four views at N, the controls are
    // hidden, and every key moment is a link to the review at its tick.
    let (status, page, _) = call(
        "GET",
        &format!("{base}/sessions/{lung}?tick=4000"),
        Some(&ivan),
        None,
        false,
    );
    assert_eq!(status, 200);
    let page = page.as_str().unwrap().to_string();
    for view in ["3d", "axial", "ultrasound", "xray"] {
        assert!(
            page.contains(&format!("frame?view={view}&amp;tick=4000&amp;")),
            "{view}"
        );
    }
    assert!(
        page.contains("class=\"controls noprint\" hidden"),
        "controls hidden without the script"
    );
    assert!(page.contains(&format!("href=\"/sessions/{lung}?tick={hit_tick}#player\"")));
    // The cache answers the second time with the same bytes, and holds files on disk.
    let again = get_bytes(&frame(&lung, &format!("view=xray&tick={hit_tick}&w=320&h=240")), &ivan).1;
    assert_eq!(again, std::fs::read(f.dir.path().join("served-xray.png")).unwrap());
    assert!(f.data().join("frames").is_dir());

    let driver = Driver::start();
    let profiles = tempfile::tempdir().unwrap();
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let c = chromium(&driver, &profiles.path().join("p"), (1400, 1000), &[]).await;
        log_in(&c, &base, "ivan").await;
        c.goto(&format!("{base}/sessions/{lung}")).await.unwrap();
        until(&c, "the player starts", "document.getElementById('player').dataset.ready === '1'").await;
        // The first frames load (a real picture each).
        until(&c, "the first frames", "document.getElementById('player').dataset.shown").await;
        let widths = js(
            &c,
            "return Array.from(document.querySelectorAll('#player img')).map(i => i.naturalWidth)",
        )
        .await;
        assert_eq!(widths, json!([480, 480, 480, 480]), "every view drawn");

        // Play: the tick advances and the frames follow; pause stops it.
        let before = shown_tick(&c).await;
        c.find(Locator::Id("play")).await.unwrap().click().await.unwrap();
        until(
            &c,
            "playing moves the frames",
            &format!("Number(document.getElementById('player').dataset.shown) > {before}"),
        )
        .await;
        // While playing, the clock shows the time of the frames on screen, and the four views
        // show one time: the clock neither runs ahead of the pictures nor jumps.
        for _ in 0..30 {
            let seen = js(
                &c,
                "const p = document.getElementById('player'); \
                 return [document.getElementById('clock').textContent, p.dataset.rate, \
                 Array.from(p.querySelectorAll('img[data-view]')).map(i => i.dataset.tick || p.dataset.shown)]",
            )
            .await;
            let rate: f64 = seen[1].as_str().unwrap().parse().unwrap();
            let ticks: Vec<f64> = seen[2]
                .as_array()
                .unwrap()
                .iter()
                .map(|t| t.as_str().unwrap().parse().unwrap())
                .collect();
            assert!(ticks.iter().all(|t| *t == ticks[0]), "the views show different times: {seen}");
            assert_eq!(seen[0], json!(format!("{:.2} s", ticks[0] / rate)), "clock and frames: {seen}");
            tokio::time::sleep(std::time::Duration::from_millis(50)).await;
        }
        c.find(Locator::Id("play")).await.unwrap().click().await.unwrap();
        assert_eq!(js(&c, "return document.getElementById('player').dataset.playing").await, "0");

        // Seek by the timeline: frames, clock and the chart cursor at the new tick.
        js(
            &c,
            "const t = document.getElementById('timeline'); t.value = 4000; t.dispatchEvent(new Event('input'));",
        )
        .await;
        until(&c, "the timeline seeks", "document.getElementById('player').dataset.shown === '4000'").await;
        let srcs = js(&c, "return Array.from(document.querySelectorAll('#player img')).map(i => i.src)").await;
        for src in srcs.as_array().unwrap() {
            assert!(src.as_str().unwrap().contains("tick=4000"), "{src}");
        }
        assert_eq!(text_of(&c, "#clock").await, "4.00 s");
        assert_eq!(
            js(&c, "return document.getElementById('cursor-0').getAttribute('data-t')").await,
            "4.000"
        );

        // Click the force chart: the player goes to the time under the click (its middle).
        let chart = c.find(Locator::Css("svg.chart[data-x0]")).await.unwrap();
        let d = js(
            &c,
            "const s = document.querySelector('svg.chart[data-x0]').dataset; return [Number(s.x0), Number(s.x1), Number(s.px0), Number(s.px1)]",
        )
        .await;
        let [x0, x1, px0, px1] = [0, 1, 2, 3].map(|i| d[i].as_f64().unwrap());
        chart.click().await.unwrap();
        // The click lands on the middle of the 1100-unit-wide chart.
        let mid_t = x0 + (550.0 - px0) / (px1 - px0) * (x1 - x0);
        until(&c, "a chart click seeks", "document.getElementById('player').dataset.shown !== '4000'").await;
        let clicked = shown_tick(&c).await as f64 / 1000.0;
        assert!((clicked - mid_t).abs() < 0.05 * (x1 - x0), "clicked {clicked} s, the middle is {mid_t} s");
        let cursor_t: f64 = js(&c, "return document.getElementById('cursor-0').getAttribute('data-t')")
            .await
            .as_str()
            .unwrap()
            .parse()
            .unwrap();
        assert!((cursor_t - clicked).abs() < 1e-3);

        // Jump to the risk hit.
        let hit = c
            .find(Locator::Css("#player a.moment[data-kind='risk hit']"))
            .await
            .unwrap();
        let want = hit.attr("data-tick").await.unwrap().unwrap();
        assert_eq!(want.parse::<u64>().unwrap(), hit_tick);
        hit.click().await.unwrap();
        until(
            &c,
            "the risk-hit button seeks",
            &format!("document.getElementById('player').dataset.shown === '{want}'"),
        )
        .await;
        // Keyboard: → one second on.
        c.find(Locator::Css("body")).await.unwrap().send_keys("\u{E014}").await.unwrap();
        let next = hit_tick + 1000;
        until(
            &c,
            "the right arrow key",
            &format!("document.getElementById('player').dataset.tick === '{next}'"),
        )
        .await;
        c.find(Locator::Css("body")).await.unwrap().send_keys("\u{E012}").await.unwrap();
        until(
            &c,
            "the left arrow key",
            &format!("document.getElementById('player').dataset.shown === '{want}'"),
        )
        .await;

        // Pictures: the player on a desktop and on a tablet.
        c.set_window_size(1400, 1350).await.unwrap();
        js(&c, "document.getElementById('player').scrollIntoView()").await;
        tokio::time::sleep(Duration::from_millis(300)).await;
        std::fs::write(shots().join(format!("{tag}-player-desktop.png")), c.screenshot().await.unwrap()).unwrap();
        c.set_window_size(820, 1180).await.unwrap();
        js(&c, "document.getElementById('player').scrollIntoView()").await;
        tokio::time::sleep(Duration::from_millis(300)).await;
        std::fs::write(shots().join(format!("{tag}-player-tablet.png")), c.screenshot().await.unwrap()).unwrap();
        let overflow = js(&c, "return document.documentElement.scrollWidth > window.innerWidth").await;
        assert_eq!(overflow, json!(false), "the tablet page does not scroll sideways");
        c.close().await.unwrap();
    });

    // A session still being scored: its frames answer 409.
    rt.block_on(async {
        sqlx::any::install_default_drivers();
        let pool = sqlx::AnyPool::connect(&db.url(&f.data())).await.unwrap();
        sqlx::query("UPDATE sessions SET status = 'scoring' WHERE id = $1")
            .bind(tom_id.clone())
            .execute(&pool)
            .await
            .unwrap();
    });
    let (status, body) = get_bytes(&frame(&tom_id, "view=axial&tick=2000"), &tom);
    assert_eq!(status, 409, "{}", String::from_utf8_lossy(&body));
}

async fn text_of(c: &Client, css: &str) -> String {
    c.find(Locator::Css(css)).await.unwrap().text().await.unwrap()
}

/// A moment replayed from the nearest snapshot is the moment replayed from the start, at ticks
/// on, just before and just after snapshots, and at the ends.
#[test]
fn snapshots_replay_the_same_moments_as_the_whole_replay() {
    use std::sync::Arc;
    use stylet_dashboard::player::states::{MIN_SPACING_TICKS, ReplayStates};
    let f = Fixture::new(STYLET);
    let atlas = stylet_atlas::load(&f.atlases().join("phantom")).unwrap();
    let session = stylet_recorder::reader::read(&f.session("tina-lung")).unwrap();
    let states = ReplayStates::build(session.clone(), Arc::clone(&atlas.model))
        .unwrap()
        .unwrap();
    assert!(states.snapshots() > 2, "{} snapshots", states.snapshots());
    let labels = stylet_render::views::SessionLabels {
        scenario: session.header.scenario.clone(),
        difficulty: session.header.difficulty.parse().unwrap(),
        seed: session.header.seed,
    };
    let s = MIN_SPACING_TICKS;
    let wanted = [
        states.first_tick,
        s - 1,
        s,
        s + 1,
        3 * s + 17,
        states.last_tick - 1,
        states.last_tick,
    ];
    let mut replayer = stylet_scoring::Replayer::new(&session, Arc::clone(&atlas.model)).unwrap();
    let mut checked = 0;
    while let Some((input, out)) = replayer.step() {
        if wanted.contains(&out.tick) {
            let whole = stylet_render::views::Moment::of_simulation(replayer.simulation(), &input, &out, &labels);
            let from_snapshot = states.moment_at(out.tick).unwrap();
            assert_eq!(format!("{whole:?}"), format!("{from_snapshot:?}"), "tick {}", out.tick);
            checked += 1;
        }
    }
    assert_eq!(checked, wanted.len());
    assert!(states.moment_at(states.last_tick + 1).is_none());
}
