//! The admin port (`--admin-bind`): `/metrics` counts what a client did, `/livez` and `/readyz`
//! say what they should, and the JSON logs carry the upload's request id into its scoring job.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use crate::common::*;

/// A scrape, parsed: `(name, labels) → value` for every sample line.
type Samples = Vec<(String, BTreeMap<String, String>, f64)>;

fn scrape(admin: &str) -> Samples {
    let resp = ureq::get(&format!("{admin}/metrics")).call().unwrap();
    assert!(resp.content_type().starts_with("text/plain"), "{}", resp.content_type());
    let text = resp.into_string().unwrap();
    text.lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let (series, value) = l.rsplit_once(' ').unwrap_or_else(|| panic!("a sample line: {l}"));
            let (name, labels) = match series.split_once('{') {
                Some((name, rest)) => {
                    let labels = rest
                        .trim_end_matches('}')
                        .split("\",")
                        .filter(|kv| !kv.is_empty())
                        .map(|kv| {
                            let (k, v) = kv.split_once("=\"").unwrap_or_else(|| panic!("a label: {kv} in {l}"));
                            (k.to_string(), v.trim_end_matches('"').to_string())
                        })
                        .collect();
                    (name.to_string(), labels)
                }
                None => (series.to_string(), BTreeMap::new()),
            };
            (name, labels, value.parse().unwrap_or_else(|_| panic!("a number: {l}")))
        })
        .collect()
}

/// The sum of the samples named `name` whose labels include `labels`.
fn value(samples: &Samples, name: &str, labels: &[(&str, &str)]) -> f64 {
    samples
        .iter()
        .filter(|(n, l, _)| n == name && labels.iter().all(|(k, v)| l.get(*k).map(String::as_str) == Some(*v)))
        .map(|(_, _, v)| v)
        .sum()
}

fn status(url: &str) -> (u16, String) {
    match ureq::get(url).call() {
        Ok(r) => (r.status(), r.into_string().unwrap()),
        Err(ureq::Error::Status(code, r)) => (code, r.into_string().unwrap()),
        Err(e) => panic!("{url}: {e}"),
    }
}

#[test]
fn metrics_count_what_clients_did_and_readiness_follows_the_database() {
    let f = Fixture::new(STYLET);
    f.users(&Db::Sqlite);
    let server = Server::start(
        STYLET,
        &f.data(),
        &Db::Sqlite,
        &f.atlases(),
        &["--workers", "1", "--admin-bind", "127.0.0.1:0", "--log-format", "json"],
    );
    let (b, admin) = (&server.base, server.admin.clone().expect("the admin port's address"));
    assert_eq!(status(&format!("{admin}/livez")).0, 200);
    assert_eq!(
        status(&format!("{admin}/readyz")),
        (200, r#"{"status":"ready"}"#.into())
    );
    // Not on the public port.
    assert_eq!(call("GET", &format!("{b}/metrics"), None, None, false).0, 404);

    // Two wrong logins, one right.
    for _ in 0..2 {
        let body = br#"{"username":"cora","password":"guess-guess"}"#;
        assert_eq!(call("POST", &format!("{b}/api/login"), None, Some(body), true).0, 401);
    }
    let tina = login(b, "tina");
    let Auth::Cookie { token, csrf } = &tina else {
        unreachable!()
    };
    // One session stored (under a request id of the client's), the same bytes again, one refused.
    let file = std::fs::read(f.session("tina-ok")).unwrap();
    let resp = ureq::post(&format!("{b}/api/sessions"))
        .set("Cookie", &format!("stylet_session={token}"))
        .set("X-CSRF-Token", csrf)
        .set("X-Request-Id", "upload-from-the-test")
        .set("Content-Type", "application/octet-stream")
        .send_bytes(&file)
        .unwrap();
    assert_eq!(resp.status(), 201);
    let id = resp.into_json::<serde_json::Value>().unwrap()["id"]
        .as_str()
        .unwrap()
        .to_string();
    assert_eq!(
        call("POST", &format!("{b}/api/sessions"), Some(&tina), Some(&file), false).0,
        200
    );
    assert_eq!(raw_post(b, "/api/sessions", Some(&tina), b"not a session file").0, 422);
    // Polled until scored: each poll is one GET of the route `/api/sessions/{id}`.
    let (mut polls, t0) = (0, Instant::now());
    loop {
        let (code, row, _) = call("GET", &format!("{b}/api/sessions/{id}"), Some(&tina), None, false);
        polls += 1;
        assert_eq!(code, 200, "{row}");
        if row["status"] == "scored" {
            break;
        }
        assert!(t0.elapsed() < Duration::from_secs(120), "not scored: {row}");
        std::thread::sleep(Duration::from_millis(100));
    }
    for _ in 0..3 {
        assert_eq!(
            call("GET", &format!("{b}/api/sessions"), Some(&tina), None, false).0,
            200
        );
    }

    let m = scrape(&admin);
    let logins = |result| value(&m, "stylet_logins_total", &[("result", result)]);
    assert_eq!(
        (logins("wrong"), logins("success"), logins("throttled")),
        (2.0, 1.0, 0.0)
    );
    let uploads = |result| value(&m, "stylet_uploads_total", &[("result", result)]);
    assert_eq!(
        (uploads("stored"), uploads("duplicate"), uploads("refused")),
        (1.0, 1.0, 1.0)
    );
    assert_eq!(value(&m, "stylet_upload_bytes_total", &[]), file.len() as f64);
    let requests = |method, route, code| {
        value(
            &m,
            "http_server_request_duration_seconds_count",
            &[
                ("http_request_method", method),
                ("http_route", route),
                ("http_response_status_code", code),
            ],
        )
    };
    assert_eq!(requests("GET", "/api/sessions/{id}", "200"), f64::from(polls));
    assert_eq!(requests("GET", "/api/sessions", "200"), 3.0);
    assert_eq!(requests("POST", "/api/login", "401"), 2.0);
    assert_eq!(requests("POST", "/api/sessions", "201"), 1.0);
    assert_eq!(requests("POST", "/api/sessions", "422"), 1.0);
    // The public port's 404 for /metrics, under no route.
    assert_eq!(requests("GET", "", "404"), 1.0);
    // The one job, scored; its ticks replayed at a measured speed.
    assert_eq!(value(&m, "stylet_scoring_jobs_total", &[("outcome", "scored")]), 1.0);
    assert_eq!(
        value(
            &m,
            "stylet_scoring_job_duration_seconds_count",
            &[("outcome", "scored")]
        ),
        1.0
    );
    let ticks = stylet_recorder::reader::read(&f.session("tina-ok"))
        .unwrap()
        .ticks
        .len();
    assert_eq!(value(&m, "stylet_replay_ticks_total", &[]), ticks as f64);
    assert_eq!(value(&m, "stylet_replay_ticks_per_second_count", &[]), 1.0);
    assert!(value(&m, "stylet_replay_ticks_per_second_sum", &[]) > 1000.0, "{m:?}");
    assert_eq!(value(&m, "stylet_scoring_queue_depth", &[]), 0.0);
    assert!(value(&m, "stylet_atlas_cache_lookups_total", &[]) >= 1.0);

    // JSON logs: one object per line; the job's "scored" line names the upload's request id.
    let log = std::fs::read_to_string(f.data().join("server.log")).unwrap();
    let lines: Vec<serde_json::Value> = log
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("not a JSON log line ({e}): {l}")))
        .collect();
    let scored = lines
        .iter()
        .find(|l| l["fields"]["message"] == "scored")
        .unwrap_or_else(|| panic!("no 'scored' line: {log}"));
    assert_eq!(scored["span"]["request"], "upload-from-the-test", "{scored}");
    assert_eq!(scored["span"]["session"], id.as_str(), "{scored}");

    // A database that lacks a migration of this build (restored from an older backup, or being
    // migrated by another replica): not ready, saying which.
    let last = on_database(&Db::Sqlite, &f.data(), async |store| {
        let last: i64 = sqlx::query_scalar("SELECT MAX(version) FROM _sqlx_migrations")
            .fetch_one(&store.pool)
            .await
            .unwrap();
        sqlx::query("DELETE FROM _sqlx_migrations WHERE version = $1")
            .bind(last)
            .execute(&store.pool)
            .await
            .unwrap();
        last
    });
    let (code, text) = status(&format!("{admin}/readyz"));
    assert_eq!(code, 503, "{text}");
    assert!(text.contains(&format!("[{last}]")), "{text}");
    assert_eq!(status(&format!("{admin}/livez")).0, 200, "alive all the same");
}
