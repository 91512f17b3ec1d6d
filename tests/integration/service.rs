//! The scoring service against a real server on loopback (`stylet serve`), on SQLite and on a
//! real PostgreSQL server (`$STYLET_POSTGRES_URL`, started by scripts/test): accounts from
//! `stylet user add`, login, upload, scoring by replay, who may see what, hostile uploads, and a
//! server killed with SIGKILL while jobs are queued and running.

use std::time::{Duration, Instant};

use crate::common::*;

on_both_databases!(upload_score_and_see_only_what_you_may, "upload");
on_both_databases!(review_progress_and_reports_by_role, "review");

/// Comments, overrides, progress, cohort summaries and the CSV export, and the role × route
/// matrix of every route that reads or changes a scored session.
fn review_progress_and_reports_by_role(db: Db) {
    let f = Fixture::new(STYLET);
    let srv = f.serve(&db, 2);
    let b = &srv.base;
    let tina = login(b, "tina");
    let tom = login(b, "tom");
    let upload = |who: &Auth, name: &str| {
        let id = crate::common::upload(b, who, &f.session(name));
        wait_scored(b, who, &id);
        id
    };
    let t1 = upload(&tina, "tina-ok");
    let t2 = upload(&tina, "tina-lung");
    let m1 = upload(&tom, "tom-ok");
    // The matrix: every route × every role (and no login at all) → status.
    let users = ["root", "ivan", "tina", "tom", "cora", "anonymous"];
    let auths: Vec<(&str, Auth)> = users[..5].iter().map(|u| (*u, login(b, u))).collect();
    let auth = |u: &str| auths.iter().find(|(n, _)| *n == u).map(|a| &a.1);
    let get = |u: &str, path: &str| call("GET", &format!("{b}{path}"), auth(u), None, false).0;
    let post =
        |u: &str, path: &str, body: &str| call("POST", &format!("{b}{path}"), auth(u), Some(body.as_bytes()), true).0;
    let tina_two = std::fs::read(f.session("tina-two")).unwrap();
    // A raw socket: a refusal may come before the server has read the body.
    let upload_as = |u: &str| raw_post(b, "/api/sessions", auth(u), &tina_two).0;
    let over = r#"{"score": 75, "passed": true, "reason": "lung contact was a recess artefact"}"#;
    let comment = r#"{"body": "aim one rib lower"}"#;
    let new_user = r#"{"username": "nina", "role": "trainee", "password": "nina-password", "cohort": "c1"}"#;
    // The player's frames (PNG, dashboard login; no redirect is followed: a stranger is sent to
    // the login page with a 303).
    let frame = |u: &str, id: &str| {
        let agent = ureq::AgentBuilder::new().redirects(0).build();
        let mut req = agent.get(&format!("{b}/sessions/{id}/frame?view=axial&tick=1000&w=320&h=240"));
        if let Some(Auth::Cookie { token, .. }) = auth(u) {
            req = req.set("Cookie", &format!("stylet_session={token}"));
        }
        match req.call() {
            Ok(r) => r.status(),
            Err(ureq::Error::Status(code, _)) => code,
            Err(e) => panic!("{e}"),
        }
    };
    type Row<'a> = (&'a str, Box<dyn Fn(&str) -> u16 + 'a>, [u16; 6]);
    //                                                        root ivan tina  tom cora anon
    let matrix: Vec<Row> = vec![
        (
            "GET /healthz",
            Box::new(|u: &str| get(u, "/healthz")),
            [200, 200, 200, 200, 200, 200],
        ),
        (
            "GET /api/openapi.json",
            Box::new(|u: &str| get(u, "/api/openapi.json")),
            [200, 200, 200, 200, 200, 200],
        ),
        (
            "GET tina's session",
            Box::new(|u: &str| get(u, &format!("/api/sessions/{t1}"))),
            [200, 200, 200, 404, 200, 401],
        ),
        (
            "GET tom's session",
            Box::new(|u: &str| get(u, &format!("/api/sessions/{m1}"))),
            [200, 404, 404, 200, 200, 401],
        ),
        (
            "GET a frame of tina's session (player)",
            Box::new(|u: &str| frame(u, &t1)),
            [200, 200, 200, 404, 200, 303],
        ),
        (
            "GET a frame of tom's session (player)",
            Box::new(|u: &str| frame(u, &m1)),
            [200, 404, 404, 200, 200, 303],
        ),
        (
            "GET a session that does not exist",
            Box::new(|u: &str| get(u, "/api/sessions/no-such-id")),
            [404, 404, 404, 404, 404, 401],
        ),
        (
            "GET tina's progress",
            Box::new(|u: &str| get(u, "/api/trainees/tina/progress")),
            [200, 200, 200, 404, 200, 401],
        ),
        (
            "GET cohort c1",
            Box::new(|u: &str| get(u, "/api/cohorts/c1/summary")),
            // 404, not 403, for those who may not see it: like a cohort that does not exist.
            [200, 200, 404, 404, 200, 401],
        ),
        (
            "GET cohort c2",
            Box::new(|u: &str| get(u, "/api/cohorts/c2/summary")),
            [200, 404, 404, 404, 200, 401],
        ),
        (
            "GET export",
            Box::new(|u: &str| get(u, "/api/export/sessions.csv")),
            [200, 200, 403, 403, 200, 401],
        ),
        (
            "GET sessions",
            Box::new(|u: &str| get(u, "/api/sessions")),
            [200, 200, 200, 200, 200, 401],
        ),
        (
            "GET users",
            Box::new(|u: &str| get(u, "/api/users")),
            [200, 403, 403, 403, 403, 401],
        ),
        // The first allowed upload stores the file (201); later allowed ones get its id (200).
        (
            "upload tina's session",
            Box::new(|u: &str| upload_as(u)),
            [201, 200, 200, 403, 403, 401],
        ),
        (
            "GET the atlas catalogue",
            Box::new(|u: &str| get(u, "/api/atlases")),
            [200, 200, 200, 200, 200, 401],
        ),
        // Who may publish is settled before the body is looked at (a JSON body: 415 for them).
        (
            "POST an atlas",
            Box::new(|u: &str| post(u, "/api/atlases", "{}")),
            [415, 415, 403, 403, 403, 401],
        ),
        (
            "POST token",
            Box::new(|u: &str| post(u, "/api/tokens", r#"{"label":"matrix"}"#)),
            [201, 201, 201, 201, 201, 401],
        ),
        (
            "POST user",
            Box::new(|u: &str| post(u, "/api/users", new_user)),
            [201, 403, 403, 403, 403, 401],
        ),
        (
            "GET an account",
            Box::new(|u: &str| get(u, "/api/users/tina")),
            [200, 403, 403, 403, 403, 401],
        ),
        (
            "GET an account that does not exist",
            Box::new(|u: &str| get(u, "/api/users/nobody")),
            [404, 403, 403, 403, 403, 401],
        ),
        // nina, added by the row above, is changed by admins only.
        (
            "PATCH an account's cohorts",
            Box::new(|u: &str| {
                call(
                    "PATCH",
                    &format!("{b}/api/users/nina"),
                    auth(u),
                    Some(br#"{"cohorts":["c1"]}"#),
                    true,
                )
                .0
            }),
            [200, 403, 403, 403, 403, 401],
        ),
        (
            "disable an account",
            Box::new(|u: &str| post(u, "/api/users/nina/disable", "")),
            [200, 403, 403, 403, 403, 401],
        ),
        (
            "enable an account",
            Box::new(|u: &str| post(u, "/api/users/nina/enable", "")),
            [200, 403, 403, 403, 403, 401],
        ),
        (
            "reset a password",
            Box::new(|u: &str| post(u, "/api/users/nina/password", r#"{"password":"nina-password"}"#)),
            [200, 403, 403, 403, 403, 401],
        ),
        (
            "disable oneself",
            Box::new(|u: &str| post(u, &format!("/api/users/{u}/disable"), "")),
            [409, 403, 403, 403, 403, 401],
        ),
        (
            "import accounts (CSV)",
            Box::new(|u: &str| {
                let mut req = ureq::post(&format!("{b}/api/users")).set("Content-Type", "text/csv");
                if let Some(Auth::Cookie { token, csrf }) = auth(u) {
                    req = req
                        .set("Cookie", &format!("stylet_session={token}"))
                        .set("X-CSRF-Token", csrf);
                }
                match req.send_string("zoe,trainee,c1,zoe-password\n") {
                    Ok(r) => r.status(),
                    Err(ureq::Error::Status(code, _)) => code,
                    Err(e) => panic!("{e}"),
                }
            }),
            [201, 403, 403, 403, 403, 401],
        ),
        (
            "comment on tina's",
            Box::new(|u: &str| post(u, &format!("/api/sessions/{t2}/comments"), comment)),
            [201, 201, 403, 404, 403, 401],
        ),
        (
            "comment on tom's",
            Box::new(|u: &str| post(u, &format!("/api/sessions/{m1}/comments"), comment)),
            [201, 404, 404, 403, 403, 401],
        ),
        (
            "override tina's",
            Box::new(|u: &str| post(u, &format!("/api/sessions/{t2}/override"), over)),
            [201, 201, 403, 404, 403, 401],
        ),
        (
            "override tom's",
            Box::new(|u: &str| post(u, &format!("/api/sessions/{m1}/override"), over)),
            [201, 404, 404, 403, 403, 401],
        ),
        // The expert benchmark: its reviewers mark and unmark; whoever sees a session reads it.
        (
            "mark tina's as an expert reference",
            Box::new(|u: &str| post(u, &format!("/api/sessions/{t1}/expert"), "")),
            [201, 201, 403, 404, 403, 401],
        ),
        (
            "mark tom's as an expert reference",
            Box::new(|u: &str| post(u, &format!("/api/sessions/{m1}/expert"), "")),
            [201, 404, 404, 403, 403, 401],
        ),
        (
            "GET the benchmark of tina's",
            Box::new(|u: &str| get(u, &format!("/api/sessions/{t1}/benchmark"))),
            [200, 200, 200, 404, 200, 401],
        ),
        (
            "GET the benchmark of tom's",
            Box::new(|u: &str| get(u, &format!("/api/sessions/{m1}/benchmark"))),
            [200, 404, 404, 200, 200, 401],
        ),
        (
            "unmark tina's",
            Box::new(|u: &str| call("DELETE", &format!("{b}/api/sessions/{t1}/expert"), auth(u), None, false).0),
            [200, 200, 403, 404, 403, 401],
        ),
        (
            "unmark tom's",
            Box::new(|u: &str| call("DELETE", &format!("{b}/api/sessions/{m1}/expert"), auth(u), None, false).0),
            [200, 404, 404, 403, 403, 401],
        ),
    ];
    for (what, f, want) in &matrix {
        for (k, u) in users.iter().enumerate() {
            assert_eq!(f(u), want[k], "{what} as {u}");
        }
    }
    // The account the admin added can log in, and is listed with its cohort.
    login(b, "nina");
    let (_, listed, _) = call("GET", &format!("{b}/api/users"), auth("root"), None, false);
    let nina = listed["users"]
        .as_array()
        .unwrap()
        .iter()
        .find(|u| u["username"] == "nina")
        .unwrap();
    assert_eq!(
        (nina["role"].as_str(), nina["cohorts"][0].as_str()),
        (Some("trainee"), Some("c1"))
    );
    assert!(nina.get("password_hash").is_none());
    for (body, want) in [
        (new_user, 409),
        (
            r#"{"username": "x y", "role": "trainee", "password": "long-enough"}"#,
            400,
        ),
        (
            r#"{"username": "xavier", "role": "janitor", "password": "long-enough"}"#,
            400,
        ),
        (r#"{"username": "xavier", "role": "trainee", "password": "short"}"#, 400),
        ("{}", 400),
    ] {
        assert_eq!(post("root", "/api/users", body), want, "{body}");
    }
    // The session the matrix uploaded is scored like any other; tina now has three.
    let (_, listed, _) = call("GET", &format!("{b}/api/sessions"), auth("tina"), None, false);
    let ids: Vec<&str> = listed["sessions"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| s["id"].as_str().unwrap())
        .collect();
    assert_eq!(ids.len(), 3, "{listed}");
    for id in ids {
        assert_eq!(wait_scored(b, auth("tina").unwrap(), id)["status"], "scored");
    }

    // What the review holds: the comments and the override with its reason and author.
    let (_, s2, _) = call("GET", &format!("{b}/api/sessions/{t2}"), Some(&tina), None, false);
    let review = &s2["review"];
    assert_eq!(review["comments"].as_array().unwrap().len(), 2, "{review}");
    assert_eq!(review["overrides"][0]["author"], "root");
    assert_eq!(review["overrides"][1]["reason"], "lung contact was a recess artefact");
    // Bad overrides are refused with a reason.
    for body in [
        r#"{"score": 120, "passed": true, "reason": "x"}"#,
        r#"{"score": 50, "passed": true, "reason": "  "}"#,
        "nonsense",
    ] {
        assert_eq!(
            post("ivan", &format!("/api/sessions/{t2}/override"), body),
            400,
            "{body}"
        );
    }

    // Progress: tina's two beginner sessions in order; the override shows.
    let (_, p, _) = call(
        "GET",
        &format!("{b}/api/trainees/tina/progress"),
        Some(&tina),
        None,
        false,
    );
    let series = p["progress"]["beginner"].as_array().unwrap();
    assert_eq!(series.len(), 3, "{p}");
    assert_eq!(
        (series[0]["session_id"].as_str(), series[0]["passed"].as_bool()),
        (Some(t1.as_str()), Some(true))
    );
    assert_eq!(
        (series[1]["score"].as_f64(), series[1]["overridden"].as_bool()),
        (Some(75.0), Some(true))
    );
    assert!(p["progress"]["expert"].as_array().unwrap().is_empty());

    // Cohort summary: tina in c1 with 3 sessions, all passed after the override (nina: none yet).
    let (_, c, _) = call("GET", &format!("{b}/api/cohorts/c1/summary"), auth("ivan"), None, false);
    let t = c["trainees"]
        .as_array()
        .unwrap()
        .iter()
        .find(|t| t["username"] == "tina")
        .unwrap();
    assert_eq!(
        (t["sessions"].as_i64(), t["scored"].as_i64(), t["passed"].as_i64()),
        (Some(3), Some(3), Some(3)),
        "{c}"
    );
    let nina = c["trainees"]
        .as_array()
        .unwrap()
        .iter()
        .find(|t| t["username"] == "nina")
        .unwrap();
    assert_eq!(
        (nina["sessions"].as_i64(), nina["passed"].as_i64()),
        (Some(0), Some(0)),
        "{c}"
    );

    // The export: curriculum sees all four sessions, the instructor only tina's three.
    let csv = |u: &str| {
        let resp = ureq::get(&format!("{b}/api/export/sessions.csv"))
            .set(
                "Cookie",
                &match auth(u) {
                    Some(Auth::Cookie { token, .. }) => format!("stylet_session={token}"),
                    _ => unreachable!(),
                },
            )
            .call()
            .unwrap();
        assert!(resp.content_type().starts_with("text/csv"));
        resp.into_string().unwrap()
    };
    let all = csv("cora");
    let mut lines = all.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    assert_eq!(header[..3], ["session_id", "trainee", "cohorts"]);
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), 4);
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let t2_row = rows.iter().find(|r| r[0] == t2).unwrap();
    assert_eq!(
        (t2_row[col("score")], t2_row[col("passed")], t2_row[col("overridden")]),
        ("75", "true", "true")
    );
    assert_eq!(t2_row[col("cohorts")], "c1");
    assert_eq!(csv("ivan").lines().count(), 1 + 3);
}

on_both_databases!(a_killed_server_resumes_its_jobs_and_scores_each_session_once, "crash");

fn upload_score_and_see_only_what_you_may(db: Db) {
    let f = Fixture::new(STYLET);
    f.users(&db);
    let srv = Server::start(
        STYLET,
        &f.data(),
        &db,
        &f.atlases(),
        // Eight parallel uploads of one file by one account below: room for all of them at once.
        &[
            "--max-upload-bytes",
            "2000000",
            "--workers",
            "2",
            "--max-uploads-per-account",
            "8",
        ],
    );
    let b = &srv.base;
    assert_eq!(call("GET", &format!("{b}/healthz"), None, None, false).0, 200);
    let (status, json, _) = call(
        "POST",
        &format!("{b}/api/login"),
        None,
        Some(br#"{"username":"tina","password":"nope-nope"}"#),
        true,
    );
    assert_eq!(status, 401, "{json}");
    assert!(json["error"].as_str().unwrap().contains("wrong username or password"));

    let tina = login(b, "tina");
    let file = std::fs::read(f.session("tina-ok")).unwrap();
    let (status, first, _) = call("POST", &format!("{b}/api/sessions"), Some(&tina), Some(&file), false);
    assert_eq!(status, 201, "{first}");
    assert_eq!(first["status"], "queued");
    let id = first["id"].as_str().unwrap().to_string();
    // The same bytes again: 200 and the same id.
    let (status, again, _) = call("POST", &format!("{b}/api/sessions"), Some(&tina), Some(&file), false);
    assert_eq!((status, again["id"].as_str()), (200, Some(id.as_str())));
    let scored = wait_scored(b, &tina, &id);
    assert_eq!(scored["status"], "scored", "{scored}");
    assert_eq!(scored["score"]["replay_verified"], true);
    assert_eq!(scored["score"]["grade"]["passed"], true);
    assert_eq!(scored["score"]["metrics"]["target_reached"], true);

    // Who sees it: tina, her instructor, curriculum staff, the admin; not tom, not anonymous.
    let url = format!("{b}/api/sessions/{id}");
    for (user, want) in [("ivan", 200), ("cora", 200), ("root", 200), ("tom", 404)] {
        let c = login(b, user);
        assert_eq!(call("GET", &url, Some(&c), None, false).0, want, "{user}");
        let (_, list, _) = call("GET", &format!("{b}/api/sessions"), Some(&c), None, false);
        let n = list["sessions"].as_array().unwrap().len();
        assert_eq!(n, usize::from(want == 200), "{user} lists {n}");
    }
    assert_eq!(call("GET", &url, None, None, false).0, 401);
    let forged = Auth::Cookie {
        token: "forged-token".into(),
        csrf: String::new(),
    };
    assert_eq!(call("GET", &url, Some(&forged), None, false).0, 401);
    assert_eq!(
        call("GET", &url, Some(&Auth::Bearer("forged".into())), None, false).0,
        401
    );

    // Uploads that must be refused, each with a reason, leaving no file and no row behind.
    let files_before = files_under(&f.data().join("sessions"));
    let tom = login(b, "tom");
    let ivan = login(b, "ivan");
    let cora = login(b, "cora");
    let lung = std::fs::read(f.session("tina-lung")).unwrap();
    let mut flipped = lung.clone();
    let mid = flipped.len() / 2;
    flipped[mid] ^= 0x20;
    let mut bomb = b"\x89MCAP0\r\n".to_vec();
    bomb.extend(std::iter::repeat_n(0u8, 64));
    let no_csrf = match &tina {
        Auth::Cookie { token, .. } => Auth::Cookie {
            token: token.clone(),
            csrf: "wrong".into(),
        },
        Auth::Bearer(_) => unreachable!(),
    };
    let cases: Vec<(&str, &Auth, Vec<u8>, u16, &str)> = vec![
        (
            "cookie without the CSRF token",
            &no_csrf,
            lung.clone(),
            403,
            "X-CSRF-Token",
        ),
        ("tom uploads tina's session", &tom, lung.clone(), 403, "may not upload"),
        ("curriculum uploads", &cora, lung.clone(), 403, "may not upload"),
        (
            "truncated",
            &tina,
            lung[..lung.len() / 2].to_vec(),
            422,
            "not a valid session file",
        ),
        ("bit flip", &tina, flipped, 422, "not a valid session file"),
        (
            "random bytes",
            &tina,
            (0..5000u32).map(|i| (i.wrapping_mul(2654435761) >> 13) as u8).collect(),
            422,
            "not a valid session file",
        ),
        ("header only", &tina, bomb, 422, "not a valid session file"),
        (
            "decompression bomb that declares its size",
            &tina,
            zstd_bomb(&lung, None),
            422,
            "over the limit",
        ),
        (
            "decompression bomb that lies about its size",
            &tina,
            zstd_bomb(&lung, Some(1000)),
            422,
            "not the 1000 it declares",
        ),
        ("empty", &tina, Vec::new(), 400, "empty"),
        (
            "another atlas",
            &tina,
            std::fs::read(f.session("tina-other-atlas")).unwrap(),
            422,
            "does not know",
        ),
    ];
    for (what, cookie, body, want, reason) in cases {
        // Raw socket: a refusal may come before the server has read the whole body.
        let (status, json) = raw_post(b, "/api/sessions", Some(cookie), &body);
        assert_eq!(status, want, "{what}: {json}");
        assert!(
            json["error"].as_str().unwrap_or_default().contains(reason),
            "{what}: {json}"
        );
        assert_eq!(
            call("GET", &format!("{b}/healthz"), None, None, false).0,
            200,
            "{what}: server down"
        );
    }
    // Over the size limit: answered 413 from the declared length, before the body is read (a
    // raw socket, because the server does not wait for the rest of the body).
    let (status, json) = raw_post(b, "/api/sessions", Some(&tina), &vec![0u8; 2_500_000]);
    assert_eq!(status, 413, "{json}");
    assert!(json["error"].as_str().unwrap().contains("limit"), "{json}");
    assert_eq!(call("GET", &format!("{b}/healthz"), None, None, false).0, 200);
    assert_eq!(
        files_under(&f.data().join("sessions")),
        files_before,
        "a refused upload left a file"
    );
    let (_, list, _) = call("GET", &format!("{b}/api/sessions"), Some(&cora), None, false);
    assert_eq!(
        list["sessions"].as_array().unwrap().len(),
        1,
        "a refused upload left a row"
    );

    // An instructor may upload for a trainee of their cohort.
    let (status, json, _) = call("POST", &format!("{b}/api/sessions"), Some(&ivan), Some(&lung), false);
    assert_eq!(status, 201, "{json}");
    let scored = wait_scored(b, &ivan, json["id"].as_str().unwrap());
    assert_eq!(scored["score"]["grade"]["passed"], false);
    assert!(
        scored["score"]["metrics"]["risk_hits"][0]["structure"]
            .as_str()
            .unwrap()
            .contains("lung"),
        "{scored}"
    );

    // The desktop app: an API token, then uploads with it (no cookie, no CSRF token).
    let (status, json, _) = call(
        "POST",
        &format!("{b}/api/tokens"),
        Some(&tina),
        Some(br#"{"label":"sim-1"}"#),
        true,
    );
    assert_eq!(status, 201, "{json}");
    let bearer = Auth::Bearer(json["token"].as_str().unwrap().to_string());
    // Eight uploads of the same new bytes at once (a simulator retrying): one 201, the others
    // 200 with the same id; one row, one stored file, scored.
    let two = std::fs::read(f.session("tina-two")).unwrap();
    let start = std::sync::Barrier::new(8);
    let answers: Vec<(u16, serde_json::Value)> = std::thread::scope(|scope| {
        let tasks: Vec<_> = (0..8)
            .map(|_| {
                scope.spawn(|| {
                    start.wait();
                    let (status, json, _) =
                        call("POST", &format!("{b}/api/sessions"), Some(&bearer), Some(&two), false);
                    (status, json)
                })
            })
            .collect();
        tasks.into_iter().map(|t| t.join().unwrap()).collect()
    });
    let mut statuses: Vec<u16> = answers.iter().map(|(st, _)| *st).collect();
    statuses.sort();
    assert_eq!(statuses, [200, 200, 200, 200, 200, 200, 200, 201], "{answers:?}");
    let two_id = answers[0].1["id"].as_str().unwrap().to_string();
    assert!(answers.iter().all(|(_, j)| j["id"] == two_id.as_str()), "{answers:?}");
    assert_eq!(wait_scored(b, &bearer, &two_id)["status"], "scored");
    let stored = walk(&f.data().join("sessions"));
    assert_eq!(stored.len(), files_before + 2, "{stored:?}");
    assert!(
        stored.iter().all(|p| p.extension().is_some_and(|e| e == "mcap")),
        "{stored:?}"
    );

    // The OpenAPI document names every route; every response carries a request id.
    let (status, doc, _) = call("GET", &format!("{b}/api/openapi.json"), None, None, false);
    assert_eq!(status, 200);
    for path in [
        "/healthz",
        "/api/login",
        "/api/logout",
        "/api/tokens",
        "/api/atlases",
        "/api/sessions",
        "/api/sessions/{id}",
        "/api/sessions/{id}/expert",
        "/api/sessions/{id}/benchmark",
    ] {
        assert!(doc["paths"].get(path).is_some(), "openapi lacks {path}");
    }
    openapi_lists_every_route_with_its_statuses(b, &doc);
    let resp = ureq::get(&format!("{b}/healthz"))
        .set("X-Request-Id", "abc-123")
        .call()
        .unwrap();
    assert_eq!(resp.header("X-Request-Id"), Some("abc-123"));
    assert!(
        ureq::get(&format!("{b}/healthz"))
            .call()
            .unwrap()
            .header("X-Request-Id")
            .is_some_and(|v| v.len() == 36)
    );

    // Guessing passwords: five failures, then 429 even for the right password, for a while.
    for _ in 0..5 {
        let (status, _, _) = call(
            "POST",
            &format!("{b}/api/login"),
            None,
            Some(br#"{"username":"cora","password":"guess-guess"}"#),
            true,
        );
        assert_eq!(status, 401);
    }
    let (status, json, _) = call(
        "POST",
        &format!("{b}/api/login"),
        None,
        Some(br#"{"username":"cora","password":"cora-password"}"#),
        true,
    );
    assert_eq!(status, 429, "{json}");
    assert!(json["error"].as_str().unwrap().contains("too many failed logins"));
    // Guesses sent in parallel get no more tries: five 401 at most, the rest 429.
    let start = std::sync::Barrier::new(12);
    let statuses: Vec<u16> = std::thread::scope(|scope| {
        let tasks: Vec<_> = (0..12)
            .map(|i| {
                let start = &start;
                scope.spawn(move || {
                    start.wait();
                    let body = format!(r#"{{"username":"tom","password":"guess-{i:04}"}}"#);
                    call("POST", &format!("{b}/api/login"), None, Some(body.as_bytes()), true).0
                })
            })
            .collect();
        tasks.into_iter().map(|t| t.join().unwrap()).collect()
    });
    let tried = statuses.iter().filter(|&&st| st == 401).count();
    assert_eq!(tried, 5, "{statuses:?}");
    assert_eq!(statuses.iter().filter(|&&st| st == 429).count(), 7, "{statuses:?}");
    // Login CSRF: a login a browser marks as sent from another site, or one that is not JSON
    // (an HTML form can post text/plain that parses as JSON), starts no login.
    let right = br#"{"username":"tina","password":"tina-password"}"#;
    let cross = ureq::post(&format!("{b}/api/login"))
        .set("Content-Type", "application/json")
        .set("Sec-Fetch-Site", "cross-site")
        .send_bytes(right);
    match cross {
        Err(ureq::Error::Status(403, resp)) => {
            assert!(resp.header("Set-Cookie").is_none());
            assert!(resp.into_string().unwrap().contains("other sites"));
        }
        other => panic!("cross-site login: {other:?}"),
    }
    let (status, json, cookie) = call("POST", &format!("{b}/api/login"), None, Some(right), false);
    assert_eq!((status, cookie), (415, None), "{json}");
    assert!(json["error"].as_str().unwrap().contains("application/json"));

    // Logging out ends the login.
    let (status, _, _) = call("POST", &format!("{b}/api/logout"), Some(&tina), Some(b""), false);
    assert_eq!(status, 200);
    assert_eq!(call("GET", &url, Some(&tina), None, false).0, 401);
}

fn a_killed_server_resumes_its_jobs_and_scores_each_session_once(db: Db) {
    let f = Fixture::new(STYLET);
    f.users(&db);
    // A long session (5 minutes of needle work) keeps the single worker busy long enough to be
    // killed mid-replay; the others wait in the queue behind it.
    let mut long = String::from("stylet-script 1\nend 300\nat 0 along intercostal-10-11 -10\n");
    for k in 0..29 {
        long += &format!(
            "at {} along intercostal-10-11 60\nat {} along intercostal-10-11 40\n",
            10 * k + 5,
            10 * k + 10
        );
    }
    long += "at 300 along intercostal-10-11 -10\n";
    let script = f.dir.path().join("long.txt");
    std::fs::write(&script, long).unwrap();
    let atlas = f.atlases().join("phantom");
    ok(&[
        "script",
        "run",
        "--atlas",
        s(&atlas),
        "--script",
        s(&script),
        "--out",
        s(&f.session("tina-long")),
        "--trainee",
        "tina",
        // A scenario the atlas declares (the server refuses others).
        "--scenario",
        "success-intercostal",
    ]);
    let names = ["tina-long", "tina-ok", "tina-lung", "tina-two"];
    let ids: Vec<String> = {
        let mut srv = Server::start(STYLET, &f.data(), &db, &f.atlases(), &["--workers", "1"]);
        let tina = login(&srv.base, "tina");
        let ids: Vec<String> = names
            .iter()
            .map(|n| {
                let body = std::fs::read(f.session(n)).unwrap();
                let (status, json, _) = call(
                    "POST",
                    &format!("{}/api/sessions", srv.base),
                    Some(&tina),
                    Some(&body),
                    false,
                );
                assert_eq!(status, 201, "{json}");
                json["id"].as_str().unwrap().to_string()
            })
            .collect();
        // Kill it while the long session is being scored and the rest are queued.
        let t0 = Instant::now();
        loop {
            let (_, json, _) = call(
                "GET",
                &format!("{}/api/sessions/{}", srv.base, ids[0]),
                Some(&tina),
                None,
                false,
            );
            if json["status"] == "scoring" {
                break;
            }
            assert!(
                json["status"] == "queued" && t0.elapsed() < Duration::from_secs(60),
                "{json}"
            );
            std::thread::sleep(Duration::from_millis(5));
        }
        srv.child.kill().unwrap(); // SIGKILL
        srv.child.wait().unwrap();
        ids
    };
    let srv = Server::start(STYLET, &f.data(), &db, &f.atlases(), &["--workers", "2"]);
    let tina = login(&srv.base, "tina");
    for id in &ids {
        let r = wait_scored(&srv.base, &tina, id);
        assert_eq!(r["status"], "scored", "{r}");
        assert_eq!(r["score"]["replay_verified"], true);
    }
    drop(srv);
    // Exactly one score per session and every job done once, straight from the database.
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let store = stylet_service::Store::open(&db.url(&f.data())).await.unwrap();
        for id in &ids {
            assert_eq!(store.score_count(id).await.unwrap(), 1, "{id}");
        }
        // Rows scored before migration 0002 get their summary columns filled at the next start.
        let lung_id = ids[2].clone();
        let summary = |store: stylet_service::Store| {
            let id = lung_id.clone();
            async move {
            let row = sqlx::query("SELECT final_score, final_passed, attempts, risk_hits, replay_verified FROM sessions WHERE id = $1")
                .bind(id)
                .fetch_one(&store.pool)
                .await
                .unwrap();
            use sqlx::Row;
            (
                row.try_get::<Option<f64>, _>(0).unwrap(),
                row.try_get::<Option<i64>, _>(1).unwrap(),
                row.try_get::<Option<i64>, _>(2).unwrap(),
                row.try_get::<Option<i64>, _>(3).unwrap(),
                row.try_get::<Option<i64>, _>(4).unwrap(),
            )
            }
        };
        let before = summary(store.clone()).await;
        assert_eq!((before.1, before.2, before.4), (Some(0), Some(1), Some(1)), "tina-lung: failed, 1 attempt, verified");
        assert!(before.3.is_some_and(|n| n >= 1), "tina-lung hits the lung: {before:?}");
        sqlx::query("UPDATE sessions SET final_score = NULL, final_passed = NULL, attempts = NULL, risk_hits = NULL, replay_verified = NULL")
            .execute(&store.pool)
            .await
            .unwrap();
        store.pool.close().await;
        let store = stylet_service::Store::open(&db.url(&f.data())).await.unwrap();
        assert_eq!(summary(store).await, before);
    });
}

/// Every route the server serves is in its OpenAPI document, with the statuses it can answer:
/// its own and those of the layers around it (408 past the deadline; 503 past the request cap,
/// not `/healthz`; 401 and 429 where a login is needed), uploads their caps' 429 and 503 and
/// their 413 and 422. The list here is written from docs/api.md, not from the document. And the
/// check every test applies to the server's answers (tests/common/contract.rs) refuses an
/// undocumented status and a body that does not match its schema.
fn openapi_lists_every_route_with_its_statuses(b: &str, doc: &serde_json::Value) {
    const LOGIN: &[u16] = &[401, 408, 429, 503];
    let routes: &[(&str, &str, &[u16])] = &[
        ("get", "/healthz", &[200, 408, 503]),
        ("get", "/api/openapi.json", &[200, 408, 503]),
        ("post", "/api/login", &[200, 400, 401, 403, 408, 413, 415, 429, 503]),
        ("post", "/api/logout", &[200, 403, 408, 503]),
        ("post", "/api/tokens", &[201, 400, 403, 409, 413]),
        ("get", "/api/tokens", &[200, 403]),
        ("post", "/api/tokens/{id}/revoke", &[200, 403, 404]),
        ("post", "/api/tokens/current/revoke", &[200, 401]),
        ("post", "/api/pairing/codes", &[201, 400, 403, 404, 409]),
        ("post", "/api/pair", &[201, 400, 403, 404, 409, 429]),
        ("post", "/api/lab/sign-in", &[201, 401, 403, 404, 409, 429]),
        ("get", "/api/lab/machines", &[200, 403]),
        ("post", "/api/lab/machines/{id}/revoke", &[200, 403, 404]),
        ("get", "/api/users", &[200, 403]),
        ("post", "/api/users", &[201, 400, 403, 409, 413, 422]),
        ("get", "/api/users/{username}", &[200, 403, 404]),
        ("patch", "/api/users/{username}", &[200, 400, 403, 404, 409, 413]),
        ("post", "/api/users/{username}/disable", &[200, 403, 404, 409]),
        ("post", "/api/users/{username}/enable", &[200, 403, 404]),
        ("post", "/api/users/{username}/password", &[200, 400, 403, 404, 413]),
        ("get", "/api/atlases", &[200, 403]),
        (
            "post",
            "/api/atlases",
            &[200, 201, 400, 403, 409, 411, 413, 415, 422, 429, 503],
        ),
        ("delete", "/api/atlases/{hash}", &[200, 403, 404, 409]),
        ("post", "/api/sessions", &[200, 201, 400, 403, 413, 422, 429, 503]),
        ("get", "/api/sessions", &[200, 400, 403]),
        ("get", "/api/sessions/{id}", &[200, 404]),
        ("delete", "/api/sessions/{id}", &[200, 403, 404]),
        ("get", "/api/sessions/{id}/file", &[200, 404]),
        ("post", "/api/sessions/{id}/override", &[201, 400, 403, 404, 413]),
        ("post", "/api/sessions/{id}/comments", &[201, 400, 403, 404, 413]),
        ("post", "/api/sessions/{id}/expert", &[201, 403, 404, 409]),
        ("delete", "/api/sessions/{id}/expert", &[200, 403, 404]),
        ("get", "/api/sessions/{id}/benchmark", &[200, 403, 404]),
        ("get", "/api/trainees/{username}/progress", &[200, 403, 404]),
        ("get", "/api/cohorts/{name}/summary", &[200, 400, 403, 404]),
        ("get", "/api/export/sessions.csv", &[200, 400, 403]),
        // The player's frames, which its script fetches: pages, not the JSON API (no 401: a
        // login redirect).
        ("get", "/sessions/{id}/frame", &[200, 303, 400, 404, 408, 409, 429, 503]),
        (
            "get",
            "/sessions/{id}/overview",
            &[200, 303, 400, 404, 408, 409, 429, 503],
        ),
        // The LTI tool's public keys, which platforms fetch.
        ("get", "/lti/jwks", &[200, 500]),
    ];
    let mut documented = 0;
    for (path, item) in doc["paths"].as_object().unwrap() {
        documented += item.as_object().unwrap().len();
        for method in item.as_object().unwrap().keys() {
            assert!(
                routes.iter().any(|(m, p, _)| m == method && p == path),
                "the document has {method} {path}, which docs/api.md does not list"
            );
        }
    }
    assert_eq!(documented, routes.len(), "routes documented");
    for (method, path, statuses) in routes {
        let op = &doc["paths"][path][method];
        assert!(op.is_object(), "openapi lacks {method} {path}");
        let needs_login = op["security"].as_array().is_some_and(|s| !s.is_empty()) && path.starts_with("/api/");
        let login: &[u16] = if needs_login { LOGIN } else { &[] };
        for status in statuses.iter().chain(login) {
            assert!(
                op["responses"][status.to_string()].is_object(),
                "{method} {path}: no {status} in {:?}",
                op["responses"].as_object().map(|r| r.keys().collect::<Vec<_>>())
            );
        }
        // Every documented route is served: a request to it is not answered "no such route".
        let url = format!(
            "{b}{}",
            path.replace("{id}", "x")
                .replace("{username}", "x")
                .replace("{name}", "x")
                .replace("{hash}", "x")
        );
        let resp = match ureq::request(&method.to_uppercase(), &url).call() {
            Ok(r) => r,
            Err(ureq::Error::Status(_, r)) => r,
            Err(e) => panic!("{method} {url}: {e}"),
        };
        let status = resp.status();
        let body = resp.into_string().unwrap_or_default();
        // The framework's own answers for a route it does not have: 405, or 404 "not found".
        assert_ne!(status, 405, "{method} {path} is not served");
        assert!(
            status != 404 || !body.contains("\"not found\""),
            "{method} {path} is not served: {body}"
        );
    }
    // The check every test applies refuses an undocumented status and a body off its schema.
    let refused = |status: u16, body: &'static str| {
        std::panic::catch_unwind(|| {
            crate::common::contract::check(
                b,
                "GET",
                &format!("{b}/healthz"),
                status,
                Some("application/json"),
                body,
            )
        })
        .is_err()
    };
    assert!(!refused(200, r#"{"status":"ok"}"#), "a documented answer");
    assert!(refused(418, r#"{"error":"teapot"}"#), "an undocumented status");
    assert!(refused(200, r#"{"status":5}"#), "a body off its schema");
    assert!(
        refused(503, r#"{"message":"no error field"}"#),
        "an error without its field"
    );
}

/// Bounded load on loopback ($STYLET_LOAD_SECONDS, default 20 s): 50 readers of the API and 5
/// uploaders of distinct session files against one server (SQLite), half the time calm, half
/// under attack (one trainee's junk uploads without pause, 300 slow-header connections). Zero
/// 5xx, zero lost uploads, another account logs in during the attack; prints throughput, p50/p99
/// latencies, `/healthz` on new connections and the server's peak memory (reported, never
/// asserted).
#[test]
fn bounded_load_on_loopback() {
    let seconds: u64 = std::env::var("STYLET_LOAD_SECONDS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(20);
    let f = Fixture::new(STYLET);
    let db = Db::Sqlite;
    f.users(&db);
    // Distinct bytes for every upload: the same recorded ticks under new session ids.
    // Each uploader sends one session per second (a busy simulator), so there are enough files.
    let files: Vec<Vec<u8>> = (0..5 * seconds as usize + 10)
        .map(|k| restamped_session(&f, "tina-ok", None, &f.dir.path().join(format!("load-{k}.mcap"))))
        .collect();
    let srv = Server::start(STYLET, &f.data(), &db, &f.atlases(), &["--workers", "2"]);
    let b = srv.base.clone();
    let seed_id = {
        let tina = login(&b, "tina");
        let (status, json, _) = call(
            "POST",
            &format!("{b}/api/sessions"),
            Some(&tina),
            Some(&files[0]),
            false,
        );
        assert_eq!(status, 201, "{json}");
        json["id"].as_str().unwrap().to_string()
    };
    let files = std::sync::Arc::new(files);
    let next_file = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(1));
    let mut accepted = Vec::new();
    for (phase, attacked) in [("calm", false), ("under attack", true)] {
        let run = load_phase(&b, &f, &srv, &seed_id, &files, &next_file, seconds / 2, attacked);
        run.report(phase);
        assert_eq!(run.server_errors, 0, "{phase}: 5xx under load");
        assert!(run.reads.iter().all(|r| r.0 == 200), "{phase}: a read failed");
        assert!(
            run.uploads.iter().all(|r| r.0 == 201),
            "{phase}: an upload was refused: {:?}",
            run.uploads.iter().find(|r| r.0 != 201)
        );
        if attacked {
            assert_eq!(run.other_login, Some(200), "another account's login during the attack");
        }
        accepted.extend(run.uploads.into_iter().map(|u| u.2));
    }
    // Zero lost uploads: every accepted id is there (and gets scored).
    let cora = login(&b, "cora");
    let mut stored = std::collections::BTreeSet::new();
    for page in 1.. {
        let (_, list, _) = call(
            "GET",
            &format!("{b}/api/sessions?page={page}"),
            Some(&cora),
            None,
            false,
        );
        let lines = list["sessions"].as_array().unwrap();
        if lines.is_empty() {
            assert_eq!(list["total"].as_u64(), Some(stored.len() as u64));
            break;
        }
        stored.extend(lines.iter().map(|s| s["id"].as_str().unwrap().to_string()));
    }
    for id in &accepted {
        assert!(stored.contains(id.as_deref().unwrap()), "upload {id:?} lost");
    }
    // The attacker's sessions (tom) are junk: none was stored.
    assert_eq!(stored.len(), accepted.len() + 1);
    let last = accepted.last().cloned().flatten().unwrap_or(seed_id);
    assert_eq!(wait_scored(&b, &cora, &last)["status"], "scored");
}

/// An upload of the load test: (status, latency, session id).
type Upload = (u16, Duration, Option<String>);

/// What one phase of the load test saw.
struct LoadRun {
    wall_s: f64,
    /// (status, latency) of every read.
    reads: Vec<(u16, Duration)>,
    /// Every upload (after its retries).
    uploads: Vec<Upload>,
    /// Uploads retried after a 429 (the account's two at once) with its Retry-After.
    retried: usize,
    server_errors: usize,
    /// `/healthz` on new connections (ms, sorted).
    healthz_ms: Vec<f64>,
    /// The server's peak and final RSS in the phase (MiB).
    rss_mib: (f64, f64),
    /// The attacker's answers by status.
    attacker: std::collections::BTreeMap<u16, usize>,
    /// Another account's login during the attack.
    other_login: Option<u16>,
}

impl LoadRun {
    fn report(&self, phase: &str) {
        let pct = |mut v: Vec<Duration>, q: f64| {
            v.sort();
            v.get(((v.len() as f64 - 1.0) * q).round() as usize)
                .map_or(0.0, |d| d.as_secs_f64() * 1e3)
        };
        let read_lat: Vec<Duration> = self.reads.iter().map(|r| r.1).collect();
        let up_lat: Vec<Duration> = self.uploads.iter().map(|r| r.1).collect();
        let h = &self.healthz_ms;
        println!(
            "load {phase}, {:.0} s: {} reads ({:.0}/s), p50 {:.1} ms, p99 {:.1} ms; {} uploads ({:.1}/s, {} retried after 429),              p50 {:.1} ms, p99 {:.1} ms; /healthz p50 {:.1} ms, p99 {:.1} ms ({} probes); server RSS peak {:.0} MiB, end {:.0} MiB;              attacker's answers {:?}",
            self.wall_s,
            self.reads.len(),
            self.reads.len() as f64 / self.wall_s,
            pct(read_lat.clone(), 0.5),
            pct(read_lat, 0.99),
            self.uploads.len(),
            self.uploads.len() as f64 / self.wall_s,
            self.retried,
            pct(up_lat.clone(), 0.5),
            pct(up_lat, 0.99),
            h.get(h.len() / 2).copied().unwrap_or(0.0),
            h.get(((h.len() as f64 - 1.0) * 0.99).round() as usize)
                .copied()
                .unwrap_or(0.0),
            h.len(),
            self.rss_mib.0,
            self.rss_mib.1,
            self.attacker
        );
    }
}

/// One phase of the load test: 50 readers and 5 uploaders for `seconds`; `attacked`: meanwhile
/// the trainee tom sends junk uploads (16 MiB behind a valid header) from 8 threads without
/// pause, and 300 anonymous connections send their headers a byte a second.
#[allow(clippy::too_many_arguments)]
fn load_phase(
    b: &str,
    f: &Fixture,
    srv: &Server,
    seed_id: &str,
    files: &std::sync::Arc<Vec<Vec<u8>>>,
    next_file: &std::sync::Arc<std::sync::atomic::AtomicUsize>,
    seconds: u64,
    attacked: bool,
) -> LoadRun {
    use crate::common::attack::*;
    use std::sync::atomic::{AtomicBool, Ordering};
    let pid = srv.child.id();
    std::fs::write(format!("/proc/{pid}/clear_refs"), "5").unwrap();
    let addr = b.strip_prefix("http://").unwrap().to_string();
    let deadline = Instant::now() + Duration::from_secs(seconds);
    let started = Instant::now();
    let stop = std::sync::Arc::new(AtomicBool::new(false));
    let probe = probe_healthz(addr.clone(), stop.clone());
    let junk_head = header_prefix(&std::fs::read(f.session("tom-ok")).unwrap());
    let (reads, uploads, attacker, other_login) = std::thread::scope(|scope| {
        let mut attackers = Vec::new();
        if attacked {
            let tom = std::sync::Arc::new(login(b, "tom"));
            for _ in 0..8 {
                let (addr, tom, head) = (addr.clone(), tom.clone(), junk_head.clone());
                attackers.push(scope.spawn(move || {
                    let mut seen = Vec::new();
                    while Instant::now() < deadline {
                        seen.push(junk_upload(&addr, &tom, &head, 16 << 20).0);
                    }
                    seen
                }));
            }
            let addr = addr.clone();
            attackers.push(scope.spawn(move || {
                let mut loris: Vec<std::net::TcpStream> = Vec::new();
                while Instant::now() < deadline {
                    loris.retain_mut(|s| std::io::Write::write_all(s, b"G").is_ok());
                    while loris.len() < 300 {
                        match std::net::TcpStream::connect(&addr) {
                            Ok(s) => loris.push(s),
                            Err(_) => break,
                        }
                    }
                    std::thread::sleep(Duration::from_secs(1));
                }
                Vec::new()
            }));
        }
        let readers: Vec<_> = (0..50)
            .map(|k| {
                let (b, seed_id) = (b.to_string(), seed_id.to_string());
                scope.spawn(move || {
                    let who = ["tina", "ivan", "cora"][k % 3];
                    let auth = login(&b, who);
                    let paths = [
                        "/api/sessions".to_string(),
                        format!("/api/sessions/{seed_id}"),
                        "/healthz".into(),
                        "/api/trainees/tina/progress".into(),
                    ];
                    let mut out = Vec::new();
                    let mut i = k;
                    while Instant::now() < deadline {
                        let t = Instant::now();
                        let (status, _, _) = call(
                            "GET",
                            &format!("{b}{}", paths[i % paths.len()]),
                            Some(&auth),
                            None,
                            false,
                        );
                        out.push((status, t.elapsed()));
                        i += 1;
                    }
                    out
                })
            })
            .collect();
        let uploaders: Vec<_> = (0..5)
            .map(|_| {
                let (b, files, next_file) = (b.to_string(), files.clone(), next_file.clone());
                scope.spawn(move || {
                    let auth = login(&b, "tina");
                    let mut out = Vec::new();
                    let mut retried = 0;
                    while Instant::now() < deadline {
                        let k = next_file.fetch_add(1, Ordering::Relaxed);
                        if k >= files.len() {
                            break;
                        }
                        let t = Instant::now();
                        // Like the simulator's outbox: a 429 (two uploads of this account
                        // already arriving) is sent again after its Retry-After.
                        let (status, json) = loop {
                            let (status, json, _) = call(
                                "POST",
                                &format!("{b}/api/sessions"),
                                Some(&auth),
                                Some(&files[k]),
                                false,
                            );
                            if status != 429 {
                                break (status, json);
                            }
                            retried += 1;
                            std::thread::sleep(Duration::from_secs(5));
                        };
                        out.push((status, t.elapsed(), json["id"].as_str().map(str::to_string)));
                        std::thread::sleep(Duration::from_secs(1).saturating_sub(t.elapsed()));
                    }
                    (out, retried)
                })
            })
            .collect();
        std::thread::sleep(Duration::from_secs(seconds / 2));
        let other_login = attacked.then(|| {
            let body = br#"{"username":"ivan","password":"ivan-password"}"#;
            call("POST", &format!("{b}/api/login"), None, Some(body), true).0
        });
        let reads: Vec<(u16, Duration)> = readers.into_iter().flat_map(|h| h.join().unwrap()).collect();
        let uploads: Vec<(Vec<Upload>, usize)> = uploaders.into_iter().map(|h| h.join().unwrap()).collect();
        let mut attacker = std::collections::BTreeMap::<u16, usize>::new();
        for h in attackers {
            for status in h.join().unwrap() {
                *attacker.entry(status).or_default() += 1;
            }
        }
        (reads, uploads, attacker, other_login)
    });
    stop.store(true, Ordering::Relaxed);
    let healthz_ms = probe.join().unwrap();
    let wall_s = started.elapsed().as_secs_f64();
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    let field = |name: &str| -> f64 {
        let line = status.lines().find(|l| l.starts_with(name)).unwrap();
        line.split_whitespace().nth(1).unwrap().parse::<f64>().unwrap() / 1024.0
    };
    let retried = uploads.iter().map(|u| u.1).sum();
    let uploads: Vec<_> = uploads.into_iter().flat_map(|u| u.0).collect();
    let server_errors = reads.iter().filter(|r| r.0 >= 500).count() + uploads.iter().filter(|r| r.0 >= 500).count();
    LoadRun {
        wall_s,
        reads,
        uploads,
        retried,
        server_errors,
        healthz_ms,
        rss_mib: (field("VmHWM:"), field("VmRSS:")),
        attacker,
        other_login,
    }
}

/// `file` with its first MCAP chunk replaced by 256 MiB of zeros compressed with zstd (about
/// 10 KB), declaring `claim` bytes uncompressed (default: the true size).
fn zstd_bomb(file: &[u8], claim: Option<u64>) -> Vec<u8> {
    let plain: u64 = 256 << 20;
    let mut enc = zstd::stream::Encoder::new(Vec::new(), 3).unwrap();
    std::io::copy(&mut std::io::Read::take(std::io::repeat(0), plain), &mut enc).unwrap();
    let packed = enc.finish().unwrap();
    assert!(packed.len() < 100_000, "{} bytes", packed.len());
    let mut body = Vec::new();
    body.extend(0u64.to_le_bytes()); // message start time
    body.extend(0u64.to_le_bytes()); // message end time
    body.extend(claim.unwrap_or(plain).to_le_bytes());
    body.extend(0u32.to_le_bytes()); // no CRC
    body.extend(4u32.to_le_bytes());
    body.extend(b"zstd");
    body.extend((packed.len() as u64).to_le_bytes());
    body.extend(&packed);
    // Walk the records (magic, then op u8 + length u64 + body) to the first chunk (op 0x06).
    let mut at = 8;
    loop {
        let op = file[at];
        let len = u64::from_le_bytes(file[at + 1..at + 9].try_into().unwrap()) as usize;
        if op == 0x06 {
            let mut out = file[..at].to_vec();
            out.push(0x06);
            out.extend((body.len() as u64).to_le_bytes());
            out.extend(&body);
            out.extend(&file[at + 9 + len..]);
            return out;
        }
        at += 9 + len;
    }
}
