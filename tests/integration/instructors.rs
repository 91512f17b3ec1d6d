//! Instructors' tools end to end (`stylet serve` on loopback, pages fetched over HTTP with a login
//! cookie): the "needs review" queue lists a failed session with a risk hit and drops it once it
//! is commented (an override drops one too); trainees and curriculum staff have no queue; the
//! trainee progress page shows the trainee's sessions, scores over time and risk hits, and is
//! not shown to other trainees nor to an instructor of another cohort (404, like a trainee who
//! does not exist); the comparison search finds sessions by trainee and outcome, and the
//! comparison of two sessions draws force against insertion depth aligned at skin entry.
//! On SQLite and PostgreSQL (the queue's and the search's SQL run on both).

use crate::common::*;
use serde_json::Value;

/// Status and HTML of a page.
fn page(base: &str, auth: &Auth, path: &str) -> (u16, String) {
    let (status, body, _) = call("GET", &format!("{base}{path}"), Some(auth), None, false);
    match body {
        Value::String(html) => (status, html),
        other => (status, other.to_string()),
    }
}

/// The table row of the page that links to session `id` (empty if none).
fn row_of(html: &str, id: &str) -> String {
    html.split("<tr")
        .find(|r| r.contains(&format!("/sessions/{id}\"")))
        .map(|r| r.split("</tr>").next().unwrap_or("").to_string())
        .unwrap_or_default()
}

/// The inside of the element with this id (up to its table/div end), for narrowing asserts.
fn element(html: &str, id: &str) -> String {
    let start = html
        .find(&format!("id=\"{id}\""))
        .unwrap_or_else(|| panic!("no #{id} in the page"));
    let rest = &html[start..];
    let end = rest
        .find("</table>")
        .or_else(|| rest.find("</div>"))
        .unwrap_or(rest.len());
    rest[..end].to_string()
}

on_both_databases!(instructors_tools, "instructors");

fn instructors_tools(db: Db) {
    let f = Fixture::new(STYLET);
    let srv = f.serve(&db, 2);
    let base = srv.base.clone();
    let (tina, tom, ivan, cora, root) = (
        login(&base, "tina"),
        login(&base, "tom"),
        login(&base, "ivan"),
        login(&base, "cora"),
        login(&base, "root"),
    );
    let upload = |auth: &Auth, name: &str| upload_scored(&base, auth, &f.session(name)).0;
    let lung = upload(&tina, "tina-lung");
    let ok = upload(&tina, "tina-ok");
    let two = upload(&tina, "tina-two");
    let tom_ok = upload(&tom, "tom-ok");

    // ---- the review queue
    let (status, queue) = page(&base, &ivan, "/review-queue");
    assert_eq!(status, 200, "{queue}");
    let lung_row = row_of(&queue, &lung);
    assert!(lung_row.contains("risk structure hit"), "{lung_row}");
    assert!(
        lung_row.contains("failed") && lung_row.contains("not yet commented"),
        "{lung_row}"
    );
    assert!(
        lung_row.contains("/trainees/tina"),
        "the trainee links to their progress: {lung_row}"
    );
    // Passed and uncommented: in the queue, for no other reason.
    let ok_row = row_of(&queue, &ok);
    assert!(
        ok_row.contains("not yet commented") && !ok_row.contains("risk structure hit"),
        "{ok_row}"
    );
    // Another cohort's session is not ivan's to review.
    assert!(!queue.contains(&tom_ok), "tom is not in ivan's cohorts");
    // Newest first.
    let at = |id: &str| queue.find(&format!("/sessions/{id}\"")).unwrap();
    assert!(at(&two) < at(&ok) && at(&ok) < at(&lung), "newest first");
    // Only the flagged ones.
    let (_, flagged) = page(&base, &ivan, "/review-queue?only=flagged");
    assert!(flagged.contains(&lung), "the lung hit is flagged");
    assert!(
        !flagged.contains(&format!("/sessions/{ok}\"")),
        "a clean pass is not flagged"
    );
    let (status, _) = page(&base, &ivan, "/review-queue?only=everything");
    assert_eq!(status, 400);
    // The instructor's home says how many wait and links there; so does the navigation.
    let (_, home) = page(&base, &ivan, "/");
    assert!(
        home.contains("id=\"home-review-queue\"") && home.contains("3 sessions need review"),
        "{home}"
    );
    assert!(home.contains("id=\"nav-review-queue\""));

    // A comment takes the lung hit off the queue; an override takes tina-two off.
    let (status, json, _) = call(
        "POST",
        &format!("{base}/api/sessions/{lung}/comments"),
        Some(&ivan),
        Some(br#"{"body":"Aim one rib lower next time."}"#),
        true,
    );
    assert!(status == 200 || status == 201, "{status} {json}");
    let (status, json, _) = call(
        "POST",
        &format!("{base}/api/sessions/{two}/override"),
        Some(&ivan),
        Some(br#"{"score":85,"passed":true,"reason":"second attempt was a deliberate redirection"}"#),
        true,
    );
    assert!(status == 200 || status == 201, "{status} {json}");
    let (_, queue) = page(&base, &ivan, "/review-queue");
    assert!(
        !queue.contains(&format!("/sessions/{lung}\"")),
        "a commented session leaves the queue"
    );
    assert!(
        !queue.contains(&format!("/sessions/{two}\"")),
        "an overridden session leaves the queue"
    );
    assert!(queue.contains(&format!("/sessions/{ok}\"")));
    let (_, flagged) = page(&base, &ivan, "/review-queue?only=flagged");
    assert!(flagged.contains("Nothing to review"), "{flagged}");
    // The admin sees every cohort's queue.
    let (status, all) = page(&base, &root, "/review-queue");
    assert_eq!(status, 200);
    assert!(all.contains(&tom_ok) && all.contains(&ok));
    // Trainees and curriculum staff have no queue.
    for who in [&tina, &cora] {
        let (status, html) = page(&base, who, "/review-queue");
        assert_eq!(status, 403, "{html}");
        assert!(!html.contains(&ok));
    }

    // ---- the trainee progress page
    let (status, progress) = page(&base, &tina, "/trainees/tina");
    assert_eq!(status, 200, "{progress}");
    for id in [&lung, &ok, &two] {
        assert!(
            progress.contains(&format!("/sessions/{id}\"")),
            "tina's session {id} is listed"
        );
    }
    assert!(!progress.contains(&tom_ok));
    let chart = element(&progress, "progress-chart");
    for want in [
        "upload date (UTC)",
        "score (0–100)",
        "beginner",
        "Scores of tina over time",
    ] {
        assert!(chart.contains(want), "the progress chart lacks {want}");
    }
    let today = humantime::format_rfc3339_seconds(std::time::SystemTime::now()).to_string()[..10].to_string();
    let risk = element(&progress, "risk-sessions");
    assert!(
        risk.contains(&format!("/sessions/{lung}\"")) && risk.contains("lung"),
        "{risk}"
    );
    // The override shows as the final grade, marked.
    assert!(row_of(&progress, &two).contains("overridden"));
    assert!(progress.contains("My progress"), "the trainee's navigation links here");
    assert!(chart.contains(&today[..7]), "dates on the x axis ({today})");
    // Who else may look: her instructor, curriculum, admin; not another trainee, not an
    // instructor of another cohort, and a name that is not a trainee answers the same 404.
    for who in [&ivan, &cora, &root] {
        let (status, html) = page(&base, who, "/trainees/tina");
        assert_eq!(status, 200, "{html}");
        assert!(html.contains(&format!("/sessions/{lung}\"")));
    }
    let (status, html) = page(&base, &tom, "/trainees/tina");
    assert_eq!(status, 404);
    assert!(!html.contains(&lung));
    for path in ["/trainees/tom", "/trainees/nobody", "/trainees/ivan"] {
        assert_eq!(page(&base, &ivan, path).0, 404, "{path}");
    }
    assert_eq!(page(&base, &tina, "/trainees/tom").0, 404);
    assert_eq!(page(&base, &cora, "/trainees/tom").0, 200);

    // ---- comparison: search, then two sessions against depth
    let (status, search) = page(&base, &ivan, "/compare?trainee=tina");
    assert_eq!(status, 200, "{search}");
    let results = element(&search, "search-results");
    for id in [&lung, &ok, &two] {
        assert!(results.contains(&format!("value=\"{id}\"")), "search finds {id}");
    }
    assert!(!search.contains(&tom_ok));
    let (_, risky) = page(&base, &ivan, "/compare?trainee=tina&outcome=risk-hit");
    let results = element(&risky, "search-results");
    assert!(
        results.contains(&lung) && !results.contains(&ok) && !results.contains(&two),
        "{results}"
    );
    let (_, none) = page(
        &base,
        &ivan,
        &format!("/compare?trainee=tina&from={today}&to=2000-01-01"),
    );
    assert!(none.contains("No scored session matches"));
    assert_eq!(page(&base, &ivan, "/compare?outcome=great").0, 400);
    assert_eq!(page(&base, &ivan, "/compare?from=yesterday").0, 400);
    let (status, compared) = page(&base, &ivan, &format!("/compare?s={lung}&s={ok}&trainee=tina"));
    assert_eq!(status, 200, "{compared}");
    let chart = element(&compared, "compare-chart");
    for want in [
        "insertion depth: needle length inside the body (mm), 0 = skin entry",
        "force along the needle (N)",
        "total — A tina lung-hit",
        "total — B tina success-intercostal",
        "cutting — A tina",
        "skin entry",
    ] {
        assert!(chart.contains(want), "the comparison lacks {want}");
    }
    let table = element(&compared, "compared");
    assert!(table.contains("Deepest insertion (mm)") && table.contains(&lung) && table.contains(&ok));
    // The ticked sessions stay ticked (no second checkbox for them in the results).
    assert!(element(&compared, "ticked").contains(&format!("value=\"{lung}\" checked")));
    // The old two-session link still works; five sessions are too many; others' sessions are 404.
    assert_eq!(page(&base, &cora, &format!("/compare?a={lung}&b={tom_ok}")).0, 200);
    let five = [&lung, &ok, &two, &tom_ok, &lung]
        .iter()
        .enumerate()
        .map(|(k, id)| format!("s={id}{}", if k == 4 { "x" } else { "" }))
        .collect::<Vec<_>>()
        .join("&");
    assert_eq!(page(&base, &cora, &format!("/compare?{five}")).0, 400);
    assert_eq!(page(&base, &tina, &format!("/compare?s={ok}&s={tom_ok}")).0, 404);
    assert_eq!(page(&base, &ivan, &format!("/compare?s={ok}&s={tom_ok}")).0, 404);
    // A trainee compares and searches their own sessions only.
    let (status, own) = page(&base, &tina, "/compare");
    assert_eq!(status, 200);
    assert!(own.contains(&lung) && !own.contains(&tom_ok));
}
