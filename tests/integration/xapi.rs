//! Learning records to a real Learning Record Store (docs/integration.md "Learning records
//! (xAPI)"), on SQLite and PostgreSQL: Ralph (from PyPI, scripts/ralph) is down while two sessions
//! are scored — the statements wait in the database's outbox and are retried — and once it is up
//! they are all there, with the right verbs, results and ids, each once; sent again, the LRS
//! still holds each once.

use std::time::{Duration, Instant};

use serde_json::Value;

use crate::common::*;

const PUBLIC_URL: &str = "https://stylet.example.org";

fn outbox(db: &Db, f: &Fixture) -> (i64, i64, i64) {
    on_database(db, &f.data(), async |store| {
        let row: (i64, i64, i64) = sqlx::query_as(
            "SELECT COUNT(*), CAST(COALESCE(SUM(CASE WHEN delivered_at IS NULL THEN 1 ELSE 0 END), 0) AS BIGINT), \
             CAST(COALESCE(MIN(attempts), 0) AS BIGINT) FROM xapi_outbox",
        )
        .fetch_one(&store.pool)
        .await
        .unwrap();
        row
    })
}

fn wait_until(what: &str, seconds: u64, mut done: impl FnMut() -> bool) {
    let t0 = Instant::now();
    while !done() {
        assert!(t0.elapsed() < Duration::from_secs(seconds), "{what} within {seconds} s");
        std::thread::sleep(Duration::from_millis(200));
    }
}

on_both_databases!(statements_reach_the_lrs_after_it_was_down, "xapi");

fn statements_reach_the_lrs_after_it_was_down(db: Db) {
    let f = Fixture::new(STYLET);
    f.users(&db);
    let mut lrs = Lrs::new();
    let mut command = Server::command(
        STYLET,
        "127.0.0.1:0",
        &f.data(),
        &db,
        &f.atlases(),
        &[
            "--workers",
            "1",
            "--lrs-url",
            &lrs.url(),
            "--lrs-username",
            LRS_USERNAME,
            "--public-url",
            PUBLIC_URL,
        ],
    );
    command.env("STYLET_LRS_PASSWORD", LRS_PASSWORD);
    let srv = Server::spawn(command, &f.data());
    let b = &srv.base;
    let tina = login(b, "tina");
    let (passed, row) = upload_scored(b, &tina, &f.session("tina-ok"));
    assert_eq!(row["score"]["grade"]["passed"], true, "{row}");
    let (failed, row) = upload_scored(b, &tina, &f.session("tina-lung"));
    assert_eq!(row["score"]["grade"]["passed"], false, "{row}");

    // The LRS is down: six statements wait, each tried at least once.
    wait_until("every statement tried", 30, || {
        let (all, pending, tries) = outbox(&db, &f);
        all == 6 && pending == 6 && tries >= 1
    });

    // Up again: every statement arrives, once.
    lrs.start();
    wait_until("every statement delivered", 90, || outbox(&db, &f).1 == 0);
    let statements = lrs.statements();
    assert_eq!(statements.len(), 6, "{statements:#?}");
    let of = |session: &str, verb: &str| -> Value {
        let id = stylet_service::xapi::statement_id(
            session,
            match verb {
                "attempted" => stylet_service::xapi::Verb::Attempted,
                "completed" => stylet_service::xapi::Verb::Completed,
                "passed" => stylet_service::xapi::Verb::Passed,
                _ => stylet_service::xapi::Verb::Failed,
            },
        );
        statements
            .iter()
            .find(|s| s["id"] == id.as_str())
            .unwrap_or_else(|| panic!("no {verb} statement of {session}: {statements:#?}"))
            .clone()
    };
    for (session, outcome) in [(&passed, "passed"), (&failed, "failed")] {
        for verb in ["attempted", "completed", outcome] {
            let s = of(session, verb);
            assert_eq!(s["verb"]["id"], format!("http://adlnet.gov/expapi/verbs/{verb}"));
            assert_eq!(s["actor"]["account"]["name"], "tina");
            assert_eq!(s["actor"]["account"]["homePage"], PUBLIC_URL);
            let activity = s["object"]["id"].as_str().unwrap();
            assert!(
                activity.starts_with(&format!("{PUBLIC_URL}/xapi/activities/")),
                "{activity}"
            );
            let ext = |name: &str| s["context"]["extensions"][format!("{PUBLIC_URL}/xapi/extensions/{name}")].clone();
            assert_eq!(ext("session-id"), session.as_str());
            if verb != "attempted" {
                let result = &s["result"];
                assert_eq!(result["success"], outcome == "passed", "{result}");
                assert!(result["score"]["scaled"].as_f64().unwrap() <= 1.0, "{result}");
                assert!(result["duration"].as_str().unwrap().starts_with("PT"), "{result}");
                let metric = |name: &str| result["extensions"][format!("{PUBLIC_URL}/xapi/extensions/{name}")].clone();
                assert!(metric("attempts").as_u64().unwrap() >= 1, "{result}");
                assert!(metric("max_force_n").as_f64().is_some(), "{result}");
            } else {
                assert!(s["result"].is_null(), "{s}");
            }
        }
    }
    let lung_reasons = &of(&failed, "failed")["result"]["extensions"][format!("{PUBLIC_URL}/xapi/extensions/reasons")];
    assert!(!lung_reasons.as_array().unwrap().is_empty(), "{lung_reasons}");

    // Sent again (a replica that died before marking them): still one of each at the LRS.
    on_database(&db, &f.data(), async |store| {
        sqlx::query("UPDATE xapi_outbox SET delivered_at = NULL, next_attempt_at = '2000-01-01T00:00:00.000000Z'")
            .execute(&store.pool)
            .await
            .unwrap();
    });
    wait_until("the statements sent again", 60, || outbox(&db, &f).1 == 0);
    assert_eq!(lrs.statements().len(), 6);
    drop(srv);
}
