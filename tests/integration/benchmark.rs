//! The expert benchmark against a real server (SQLite and PostgreSQL): an instructor marks sessions
//! as expert references of a scenario and unmarks them (both audited, repeats not); the benchmark's
//! figures are the mean and sample spread of the references' metrics; a session scored once the
//! scenario has enough references is graded against them by the rubric's relative deductions
//! (recorded in its grade), one scored before is not; the review page shows the session against the
//! benchmark and marks through its form; a session that failed its grade is refused as a reference
//! and its review offers no button. (Which sessions cannot be references is a unit test of
//! `stylet_service::experts`.)

use std::path::Path;

use crate::common::browser::{Driver, chromium, js, log_in, until};
use crate::common::*;
use fantoccini::Locator;
use serde_json::Value;

on_both_databases!(experts_mark_and_the_benchmark_grades, "benchmark");

const SCENARIO: &str = "success-intercostal";

/// An expert's puncture of the phantom's target duct from a skin entry `dy_mm` beside the
/// planned entry of path intercostal-10-11 (152.6, 1.5, 15.9 mm): the same 20 s as the shipped
/// success script, by another line (the corridor has a width).
fn beside_the_planned_path(f: &Fixture, dy_mm: f64) -> String {
    let aim = format!("aim 152.6 {} 15.9  50.5 30 7.5", 1.5 + dy_mm);
    let text = format!(
        "stylet-script 1\ndevice premium\ntool needle gauge 18 length 150 stylet in\nend 20\n\n\
         at 0 {aim} -15\nat 1 {aim} -15\nat 11 {aim} 111\nat 11.5 event stylet-remove\n\
         at 12 event xray-on\nat 12.2 event contrast-inject 2\nat 13.5 event xray-off\n\
         at 14 event stylet-insert\nat 14 {aim} 111\nat 19.5 {aim} -15\n"
    );
    let path = f.dir.path().join(format!("beside-{dy_mm}.txt"));
    std::fs::write(&path, text).unwrap();
    path.display().to_string()
}

/// Records `script` (a shipped phantom script's name, or a script file) as scenario
/// [`SCENARIO`] at `difficulty`.
fn record(f: &Fixture, name: &str, script: &str, trainee: &str, difficulty: &str, seed: u64) -> std::path::PathBuf {
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("atlases/phantom/scripts")
        .join(format!("{script}.txt"));
    let script = if shipped.is_file() {
        shipped
    } else {
        Path::new(script).to_path_buf()
    };
    let out = f.dir.path().join(format!("{name}.mcap"));
    ok(&[
        "script",
        "run",
        "--atlas",
        s(&f.atlases().join("phantom")),
        "--script",
        s(&script),
        "--out",
        s(&out),
        "--trainee",
        trainee,
        "--scenario",
        SCENARIO,
        "--difficulty",
        difficulty,
        "--seed",
        &seed.to_string(),
    ]);
    out
}

/// The audit rows of `action`: (actor username, target).
fn audits(db: &Db, data: &Path, action: &str) -> Vec<(String, String)> {
    on_database(db, data, async |store| {
        let rows = sqlx::query(
            "SELECT u.username, a.target FROM audit_log a JOIN users u ON u.id = a.actor_id \
             WHERE a.action = $1 ORDER BY a.at, a.id",
        )
        .bind(action.to_string())
        .fetch_all(&store.pool)
        .await
        .unwrap();
        use sqlx::Row;
        rows.iter()
            .map(|r| (r.get::<String, _>("username"), r.get::<String, _>("target")))
            .collect()
    })
}

fn mean_and_sample_spread(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
    (mean, var.sqrt())
}

fn experts_mark_and_the_benchmark_grades(db: Db) {
    let tag = db.name();
    let f = Fixture::new(STYLET);
    f.users(&db);
    add_user(&f.data(), &db, "eve", "trainee", Some("c1"));
    let srv = Server::start(STYLET, &f.data(), &db, &f.atlases(), &["--workers", "2"]);
    let b = &srv.base;
    let olga = {
        add_user(&f.data(), &db, "olga", "instructor", Some("c2"));
        login(b, "olga")
    };
    let (ivan, tina, eve, cora, tom) = (
        login(b, "ivan"),
        login(b, "tina"),
        login(b, "eve"),
        login(b, "cora"),
        login(b, "tom"),
    );
    let upload = |who: &Auth, file: &Path| upload_scored(b, who, file);
    let expert = |who: &Auth, method: &str, id: &str| {
        call(method, &format!("{b}/api/sessions/{id}/expert"), Some(who), None, false).0
    };
    let bench = |who: &Auth, id: &str| {
        let (status, json, _) = call(
            "GET",
            &format!("{b}/api/sessions/{id}/benchmark"),
            Some(who),
            None,
            false,
        );
        assert_eq!(status, 200, "{json}");
        json
    };

    // A review page as `who` sees it.
    let page = |who: &Auth, id: &str| {
        let (status, html, _) = call("GET", &format!("{b}/sessions/{id}"), Some(who), None, false);
        assert_eq!(status, 200);
        html.as_str().unwrap().to_string()
    };
    // Three expert sessions by eve: two by lines 4 mm either side of the planned path, one with
    // a first attempt withdrawn (its final approach follows the planned path); 20, 20 and 34 s.
    // Only a passed session can be a reference: they are recorded at beginner level, which they
    // pass without ultrasound and with a second attempt (at advanced the second attempt and the
    // missing palpation and ultrasound cost 35 points, at expert the rules refuse them); the
    // benchmark is the scenario's whatever level its references were graded at.
    let experts: Vec<(String, Value)> = [
        (beside_the_planned_path(&f, -4.0), 1),
        ("two-attempts".to_string(), 2),
        (beside_the_planned_path(&f, 4.0), 3),
    ]
    .iter()
    .enumerate()
    .map(|(k, (script, seed))| upload(&eve, &record(&f, &format!("eve-{k}"), script, "eve", "beginner", *seed)))
    .collect();
    for (_, row) in &experts {
        assert_eq!(
            row["outcome"], "passed",
            "an expert's session fails: {}",
            row["reasons"]
        );
    }
    let ids: Vec<&str> = experts.iter().map(|(id, _)| id.as_str()).collect();
    assert_eq!(bench(&ivan, ids[0])["experts"], 0);

    // Who may mark: the trainee's instructor and admins; not the trainee, curriculum staff,
    // another trainee or another cohort's instructor (not found for a stranger's session).
    assert_eq!(expert(&tina, "POST", ids[0]), 404, "tina may not see eve's session");
    assert_eq!(expert(&eve, "POST", ids[0]), 403, "a trainee does not mark herself");
    assert_eq!(expert(&cora, "POST", ids[0]), 403);
    assert_eq!(expert(&tom, "POST", ids[0]), 404);
    assert_eq!(expert(&olga, "POST", ids[0]), 404);
    assert_eq!(expert(&ivan, "POST", ids[0]), 201);
    assert_eq!(expert(&ivan, "POST", ids[0]), 201, "marking again changes nothing");
    assert_eq!(expert(&ivan, "POST", ids[1]), 201);

    // A session scored with two references is not graded against them (the rubric wants 3).
    let (before, row) = upload(&tina, &record(&f, "tina-slow-0", "two-attempts", "tina", "expert", 5));
    let g = &row["score"]["grade"]["benchmark"];
    assert_eq!(
        (g["experts"].as_u64(), g["applied"].as_bool()),
        (Some(2), Some(false)),
        "{g}"
    );
    // Two references are two people's metrics, not a benchmark: a trainee sees how many, not
    // their figures; staff see them.
    let two = bench(&tina, &before);
    assert_eq!(two["experts"], 2);
    assert!(two["metrics"].as_array().unwrap().is_empty() && two["comparison"].as_array().unwrap().is_empty());
    assert!(page(&tina, &before).contains("its benchmark is shown from 3 on"));
    assert!(!bench(&ivan, &before)["metrics"].as_array().unwrap().is_empty());
    // That session failed its grade (two attempts at expert level): it cannot be a reference,
    // and its review says why instead of offering the button.
    assert_eq!(row["outcome"], "failed", "{}", row["reasons"]);
    assert_eq!(expert(&ivan, "POST", &before), 409);
    let refused = page(&ivan, &before);
    assert!(
        refused.contains("id=\"expert-form-none\"") && !refused.contains("Mark as expert reference"),
        "the review of a failed session offers it as a reference"
    );

    assert_eq!(expert(&ivan, "POST", ids[2]), 201);
    let all = bench(&ivan, ids[0]);
    assert_eq!(all["experts"], 3, "{all}");
    assert_eq!(all["expert"], true);
    assert_eq!(all["references"].as_array().unwrap().len(), 3);
    // Another cohort's instructor, on a session of their own trainee, learns the figures and how
    // many references there are, not whose.
    let (toms, _) = upload(&tom, &record(&f, "tom-0", "success-intercostal", "tom", "expert", 9));
    let theirs = bench(&olga, &toms);
    assert_eq!(theirs["experts"], 3);
    assert!(theirs["references"].as_array().unwrap().is_empty(), "{theirs}");
    let olgas_review = page(&olga, &toms);
    assert!(olgas_review.contains("3 of other cohorts") && !olgas_review.contains("eve ("));
    // The figures are the mean and sample spread of the references' metrics.
    // A rubric metric's value in a stored report (`tissue_damage_mm2` is in `needle_motion`).
    let metric_of = |row: &Value, m: &str| {
        let metrics: stylet_scoring::Metrics = serde_json::from_value(row["score"]["metrics"].clone()).unwrap();
        stylet_scoring::rubric::metric_value(&metrics, m)
            .unwrap_or_else(|| panic!("no {m} in {}", row["score"]["metrics"]))
    };
    for m in ["time_total_s", "fluoro_time_s", "shaft_sweep_mm2", "max_force_n"] {
        let values: Vec<f64> = experts.iter().map(|(_, r)| metric_of(r, m)).collect();
        let (mean, spread) = mean_and_sample_spread(&values);
        let fig = all["metrics"]
            .as_array()
            .unwrap()
            .iter()
            .find(|x| x["metric"] == m)
            .unwrap();
        assert!(
            (fig["mean"].as_f64().unwrap() - mean).abs() < 1e-9,
            "{m}: {fig} vs {mean}"
        );
        assert!(
            (fig["spread"].as_f64().unwrap() - spread).abs() < 1e-9,
            "{m}: {fig} vs {spread}"
        );
    }
    let times: Vec<f64> = experts.iter().map(|(_, r)| metric_of(r, "time_total_s")).collect();
    assert!(
        mean_and_sample_spread(&times).1 > 0.0,
        "the references differ: {times:?}"
    );
    // A trainee sees the figures of her session's scenario, not whose sessions they are.
    let hers = bench(&tina, &before);
    assert_eq!(hers["experts"], 3);
    assert!(hers.get("references").is_none(), "{hers}");
    assert!(
        hers["comparison"]
            .as_array()
            .unwrap()
            .iter()
            .any(|c| c["metric"] == "time_total_s")
    );

    // Scored now, a slower session (the whole PTCD workflow) is graded against the three: the
    // rubric's relative deductions (expert level: mean + 1 spread) as the benchmark gives them.
    let (after, row) = upload(&tina, &record(&f, "tina-slow-1", "complete-ptcd", "tina", "expert", 6));
    let grade = &row["score"]["grade"];
    assert_eq!(grade["benchmark"]["experts"], 3, "{grade}");
    assert_eq!(grade["benchmark"]["applied"], true);
    // The grade records what it was measured against: the references and every relative
    // metric's figures (also those that cost nothing).
    let mut recorded: Vec<&str> = grade["benchmark"]["references"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    let mut marked = ids.clone();
    recorded.sort_unstable();
    marked.sort_unstable();
    assert_eq!(recorded, marked);
    assert_eq!(grade["benchmark"]["figures"].as_array().unwrap().len(), 4, "{grade}");
    // Beside the grade, the skill estimate against the three: the whole workflow is slower than
    // the experts, so it lies above their level; the review shows it. With two references there
    // was none.
    let skill = &row["score"]["skill"];
    assert_eq!(skill["experts"], 3, "{skill}");
    let zs: Vec<f64> = skill["metrics"]
        .as_array()
        .unwrap()
        .iter()
        .map(|z| z["z"].as_f64().unwrap())
        .collect();
    let mean = zs.iter().sum::<f64>() / zs.len() as f64;
    assert!((skill["z_mean"].as_f64().unwrap() - mean).abs() < 1e-12, "{skill}");
    assert!(
        skill["metrics"]
            .as_array()
            .unwrap()
            .iter()
            .any(|z| z["metric"] == "time_total_s" && z["z"].as_f64().unwrap() > 0.0),
        "{skill}"
    );
    assert!(page(&tina, &after).contains("id=\"skill\""));
    assert!(!page(&tina, &before).contains("id=\"skill\""));
    // Curriculum staff find it in the sessions CSV (column `skill_z`, empty where there was
    // none) and, averaged per trainee and level, in the cohort report.
    let (status, csv, _) = call("GET", &format!("{b}/api/export/sessions.csv"), Some(&cora), None, false);
    assert_eq!(status, 200);
    let csv = csv.as_str().unwrap().to_string();
    let head: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    let col = head.iter().position(|h| *h == "skill_z").unwrap();
    let cell = |id: &str| {
        let line = csv.lines().find(|l| l.starts_with(id)).unwrap();
        // The skill column is the last, after the quoted reasons: count from the end.
        let from_end = head.len() - 1 - col;
        line.rsplit(',').nth(from_end).unwrap().to_string()
    };
    let z = skill["z_mean"].as_f64().unwrap();
    assert_eq!(cell(&after).parse::<f64>().unwrap(), z, "{csv}");
    assert_eq!(cell(&before), "", "{csv}");
    let (status, report, _) = call(
        "GET",
        &format!("{b}/reports/cohort?cohort=c1"),
        Some(&cora),
        None,
        false,
    );
    assert_eq!(status, 200);
    let report = report.as_str().unwrap();
    assert!(
        report.contains("Skill vs experts") && report.contains(&format!("{z:+.1}")),
        "{report}"
    );
    let rubric = stylet_scoring::Rubric::default_rubric();
    let level = rubric
        .level(stylet_scoring::Exercise::Puncture, stylet_scoring::Difficulty::Expert)
        .unwrap();
    assert!(!level.relative.is_empty());
    let mut relative_points = 0.0;
    for d in &level.relative {
        let fig = all["metrics"]
            .as_array()
            .unwrap()
            .iter()
            .find(|x| x["metric"] == d.metric)
            .unwrap();
        let free = fig["mean"].as_f64().unwrap() + d.spreads * fig["spread"].as_f64().unwrap();
        let v = metric_of(&row, &d.metric);
        let want = ((v - free).max(0.0) * d.points).min(d.max_points.unwrap_or(f64::INFINITY));
        let got = grade["deductions"]
            .as_array()
            .unwrap()
            .iter()
            .find(|a| a["metric"] == d.metric && a.get("relative").is_some())
            .map_or(0.0, |a| a["points"].as_f64().unwrap());
        assert!((got - want).abs() < 1e-9, "{}: {got} vs {want} ({grade})", d.metric);
        relative_points += got;
    }
    assert!(
        relative_points > 0.0,
        "the whole workflow takes longer than the experts: {grade}"
    );
    // The same recording graded without the benchmark scores higher by exactly those points
    // (before rounding to 0.01).
    let plain = rubric
        .grade(
            &serde_json::from_value(row["score"]["metrics"].clone()).unwrap(),
            stylet_scoring::Exercise::Puncture,
            stylet_scoring::Difficulty::Expert,
        )
        .unwrap();
    assert!(
        (plain.score - grade["score"].as_f64().unwrap() - relative_points).abs() < 0.011,
        "{} vs {grade}",
        plain.score
    );
    // The reasons say where the free amount came from.
    let reasons = row["reasons"].as_array().unwrap();
    assert!(
        reasons
            .iter()
            .any(|r| r.as_str().unwrap().contains("the experts' mean + 1 spread")),
        "{reasons:?}"
    );

    // The whole workflow passes at expert level: its review offers it as a reference.
    assert_eq!(row["outcome"], "passed", "{}", row["reasons"]);
    let review = page(&ivan, &after);
    for want in [
        "id=\"benchmark-table\"",
        "data-metric=\"time_total_s\"",
        "Graded against the expert benchmark: 3 expert references",
        "per unit above the expert mean + 1 spread",
        "Mark as expert reference",
        "id=\"expert-references\"",
    ] {
        assert!(review.contains(want), "the review lacks {want}");
    }
    assert!(page(&ivan, &before).contains("it had 2 when this session was scored"));
    // Without JavaScript the overview turns by links: ?turn=N shows frame N, its arrows link to
    // the neighbours.
    let turned = page(&ivan, &format!("{after}?turn=3"));
    assert!(
        turned.contains(&format!("/sessions/{after}/overview?frame=3&amp;e=")),
        "frame 3 shown"
    );
    for n in [2, 4] {
        assert!(
            turned.contains(&format!("href=\"/sessions/{after}?turn={n}#overview\"")),
            "link to {n}"
        );
    }
    let trainee_view = page(&tina, &after);
    assert!(trainee_view.contains("id=\"benchmark-table\""));
    assert!(!trainee_view.contains("id=\"expert-references\"") && !trainee_view.contains("id=\"expert-form\""));
    assert!(page(&ivan, ids[2]).contains("This session is an expert reference"));

    // The 3D overview's turntable: a frame per 30°, drawn with the corridor of the three; the
    // tip-path slices with it too. Written for a person to look at.
    let png = |who: &Auth, path: &str| get_bytes(&format!("{b}{path}"), who);
    let shots = Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join("browser-screenshots")
        .join(tag);
    std::fs::create_dir_all(&shots).unwrap();
    let mut frames = Vec::new();
    for frame in [0, 3] {
        let (status, body) = png(&ivan, &format!("/sessions/{after}/overview?frame={frame}"));
        assert_eq!(status, 200);
        let file = shots.join(format!("overview-{frame}.png"));
        std::fs::write(&file, &body).unwrap();
        let img = stylet_render::image::Image::read_png(&file).unwrap();
        assert_eq!((img.width, img.height), (480, 360));
        frames.push(img);
    }
    assert_ne!(frames[0].rgba, frames[1].rgba, "the turntable turns");
    assert_eq!(png(&ivan, &format!("/sessions/{after}/overview?frame=12")).0, 400);
    assert_eq!(png(&tom, &format!("/sessions/{after}/overview?frame=0")).0, 404);
    assert_eq!(png(&tina, &format!("/sessions/{after}/overview?frame=0")).0, 200);
    let (status, slices) = png(&ivan, &format!("/sessions/{after}/slices.png"));
    assert_eq!(status, 200);
    std::fs::write(shots.join("slices-with-corridor.png"), &slices).unwrap();

    // In the browser: the turntable turns by its arrow and by dragging; pictures of the overview
    // and of the benchmark for a person to look at.
    turn_the_overview(b, &after, &shots);

    // Unmarking by the dashboard's form (CSRF-checked) and by the API; repeats change nothing.
    let Auth::Cookie { token, csrf } = &ivan else {
        unreachable!()
    };
    let form = |id: &str, body: String| {
        let agent = ureq::AgentBuilder::new().redirects(0).build();
        match agent
            .post(&format!("{b}/sessions/{id}/expert"))
            .set("Cookie", &format!("stylet_session={token}"))
            .set("Content-Type", "application/x-www-form-urlencoded")
            .send_string(&body)
        {
            Ok(r) => r.status(),
            Err(ureq::Error::Status(code, _)) => code,
            Err(e) => panic!("{e}"),
        }
    };
    assert_eq!(form(ids[2], "csrf=wrong&expert=no".into()), 403);
    assert_eq!(form(ids[2], format!("csrf={csrf}&expert=maybe")), 400);
    assert_eq!(form(ids[2], format!("csrf={csrf}&expert=no")), 303);
    assert_eq!(expert(&ivan, "DELETE", ids[1]), 200);
    assert_eq!(expert(&ivan, "DELETE", ids[1]), 200);
    assert_eq!(expert(&cora, "DELETE", ids[0]), 403);
    assert_eq!(bench(&ivan, ids[0])["experts"], 1);
    assert!(!page(&ivan, ids[2]).contains("This session is an expert reference"));
    // Marked again through the form.
    assert_eq!(form(ids[2], format!("csrf={csrf}&expert=yes")), 303);
    assert_eq!(bench(&ivan, ids[0])["experts"], 2);

    // The audit log: three marks, two unmarks and one mark again, each once, by ivan.
    let marks = audits(&db, &f.data(), "expert.mark");
    let unmarks = audits(&db, &f.data(), "expert.unmark");
    let targets = |rows: &[(String, String)]| rows.iter().map(|(_, t)| t.clone()).collect::<Vec<_>>();
    assert_eq!(targets(&marks), [ids[0], ids[1], ids[2], ids[2]]);
    assert_eq!(targets(&unmarks), [ids[2], ids[1]]);
    assert!(marks.iter().chain(&unmarks).all(|(who, _)| who == "ivan"));
}

fn turn_the_overview(base: &str, id: &str, shots: &Path) {
    let driver = Driver::start();
    let profiles = tempfile::tempdir().unwrap();
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let c = chromium(&driver, &profiles.path().join("p"), (1400, 1000), &[]).await;
        log_in(&c, base, "ivan").await;
        c.goto(&format!("{base}/sessions/{id}")).await.unwrap();
        until(&c, "the overview's script", "document.getElementById('overview').dataset.ready === '1'").await;
        until(&c, "the first frame", "document.getElementById('overview').dataset.shown === '0'").await;
        c.find(Locator::Id("turn-right")).await.unwrap().click().await.unwrap();
        until(&c, "the arrow turns it", "document.getElementById('overview').dataset.shown === '1'").await;
        let src = js(&c, "return document.getElementById('overview-frame').src").await;
        assert!(src.as_str().unwrap().contains("frame=1&"), "{src}");
        // Dragging 85 px to the right turns it back two frames (the picture follows the hand).
        js(
            &c,
            "const i = document.getElementById('overview-frame'); const r = i.getBoundingClientRect(); \
             const at = (t, x) => i.dispatchEvent(new PointerEvent(t, {pointerId: 7, clientX: x, clientY: r.top + 50, bubbles: true})); \
             at('pointerdown', r.left + 100); at('pointermove', r.left + 185); at('pointerup', r.left + 185);",
        )
        .await;
        until(&c, "dragging turns it", "document.getElementById('overview').dataset.shown === '11'").await;
        c.find(Locator::Id("turn-right")).await.unwrap().click().await.unwrap();
        until(&c, "round the turntable", "document.getElementById('overview').dataset.shown === '0'").await;
        for (section, name) in [("overview", "overview"), ("benchmark", "benchmark")] {
            // From the section's heading.
            js(
                &c,
                &format!("document.getElementById('{section}').previousElementSibling.scrollIntoView()"),
            )
            .await;
            tokio::time::sleep(std::time::Duration::from_millis(300)).await;
            std::fs::write(shots.join(format!("review-{name}.png")), c.screenshot().await.unwrap()).unwrap();
        }
        // The grade's cards with the skill estimate beside the score.
        js(&c, "document.getElementById('grade').scrollIntoView()").await;
        tokio::time::sleep(std::time::Duration::from_millis(300)).await;
        std::fs::write(shots.join("review-grade.png"), c.screenshot().await.unwrap()).unwrap();
        c.close().await.unwrap();
    });
}
