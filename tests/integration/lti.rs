//! Launching Stylet from a learning management system (docs/integration.md "Launching from a
//! learning management system"), against a real LTI 1.3 platform (lti1p3platform from PyPI,
//! scripts/lti-platform, driven by tests/lti-platform/lms.py), on SQLite and PostgreSQL: an
//! instructor adds an exercise by deep linking, a learner launches it (the account and the
//! course's cohort made on the way), pairs the simulator, uploads two sessions, and both grades
//! arrive at the activity's line item with the pass/fail comment; replayed, mis-addressed,
//! expired and foreign-key launches are refused with a page that says why.

use std::time::{Duration, Instant};

use serde_json::{Value, json};

use crate::common::*;

/// The value of the form input named `name` in `html`.
fn input_value(html: &str, name: &str) -> Option<String> {
    let at = html.find(&format!("name=\"{name}\""))?;
    let tag_start = html[..at].rfind('<')?;
    let tag_end = at + html[at..].find('>')?;
    let tag = &html[tag_start..tag_end];
    let v = tag.find("value=\"")? + "value=\"".len();
    let len = tag[v..].find('"')?;
    Some(tag[v..v + len].replace("&amp;", "&").replace("&quot;", "\""))
}

/// The `action` of the first form in `html`.
fn form_action(html: &str) -> String {
    let at = html.find("action=\"").expect("a form") + "action=\"".len();
    let len = html[at..].find('"').unwrap();
    html[at..at + len].replace("&amp;", "&")
}

fn agent() -> ureq::Agent {
    ureq::AgentBuilder::new().redirects(0).build()
}

/// (status, body, headers we look at) of a request; error statuses are answers too.
fn answer(r: Result<ureq::Response, ureq::Error>) -> (u16, String, Vec<(String, String)>) {
    let r = match r {
        Ok(r) => r,
        Err(ureq::Error::Status(_, r)) => r,
        Err(e) => panic!("{e}"),
    };
    let status = r.status();
    let headers = ["location", "set-cookie", "content-security-policy", "x-frame-options"]
        .iter()
        .filter_map(|h| r.header(h).map(|v| (h.to_string(), v.to_string())))
        .collect();
    (status, r.into_string().unwrap(), headers)
}

fn header<'a>(headers: &'a [(String, String)], name: &str) -> Option<&'a str> {
    headers.iter().find(|(n, _)| n == name).map(|(_, v)| v.as_str())
}

/// Follows a launch from the platform's "user opens the activity" to the form the platform posts
/// to Stylet: (id_token, state, the form's action).
fn launch_form(lms: &LtiPlatform, query: &str) -> (String, String, String) {
    let a = agent();
    let (status, body, h) = answer(a.get(&format!("{}/test/launch?{query}", lms.url())).call());
    assert_eq!(status, 302, "{body}\n{}", lms.log());
    // The platform's login initiation, to Stylet: a redirect to the platform's authentication.
    let (status, body, h) = answer(a.get(header(&h, "location").unwrap()).call());
    assert_eq!(status, 303, "{body}");
    let (status, body, _) = answer(a.get(header(&h, "location").unwrap()).call());
    assert_eq!(status, 200, "{body}\n{}", lms.log());
    (
        input_value(&body, "id_token").expect("an id_token"),
        input_value(&body, "state").expect("a state"),
        form_action(&body),
    )
}

/// Posts a launch form to Stylet: (status, page, login cookie token). Every launch page, refused
/// or not, may be shown in the platform's frame.
fn post_launch(action: &str, id_token: &str, state: &str) -> (u16, String, Option<String>) {
    let (status, body, h) = answer(
        agent()
            .post(action)
            .send_form(&[("id_token", id_token), ("state", state)]),
    );
    let csp = header(&h, "content-security-policy").unwrap_or_default();
    assert!(
        csp.contains("frame-ancestors *") && csp.contains("form-action 'self';"),
        "{status} {body} {csp}"
    );
    assert_eq!(header(&h, "x-frame-options"), None);
    let cookie = header(&h, "set-cookie").and_then(|c| {
        c.strip_prefix("stylet_session=")
            .and_then(|v| v.split(';').next())
            .map(str::to_string)
    });
    (status, body, cookie)
}

/// The whole launch: (status, page, login cookie).
fn launch(lms: &LtiPlatform, query: &str) -> (u16, String, Option<String>) {
    let (id_token, state, action) = launch_form(lms, query);
    post_launch(&action, &id_token, &state)
}

/// The login of a launch as an API credential (the CSRF token from a page of the login).
fn auth_of(base: &str, cookie: &str) -> Auth {
    let (status, body, _) = answer(
        agent()
            .get(&format!("{base}/pair"))
            .set("Cookie", &format!("stylet_session={cookie}"))
            .call(),
    );
    assert_eq!(status, 200, "{body}");
    Auth::Cookie {
        token: cookie.to_string(),
        csrf: input_value(&body, "csrf").expect("a CSRF field"),
    }
}

fn post_json(base: &str, path: &str, auth: Option<&Auth>, body: &Value) -> (u16, Value) {
    let body = serde_json::to_vec(body).unwrap();
    let (status, json, _) = call("POST", &format!("{base}{path}"), auth, Some(&body), true);
    (status, json)
}

fn wait_for_scores(lms: &LtiPlatform, n: usize) -> Vec<Value> {
    let t0 = Instant::now();
    loop {
        let scores = lms.json("/test/scores/1").as_array().cloned().unwrap_or_default();
        if scores.len() >= n {
            return scores;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(90),
            "{n} grades at the line item within 90 s: {scores:#?}\n{}",
            lms.log()
        );
        std::thread::sleep(Duration::from_millis(250));
    }
}

const INSTRUCTOR: &str = "kind=deeplink&user=inst-1&name=Irene%20Instructor&role=Instructor&context=course-7&context_title=Interventional%20Radiology";
const LEARNER: &str = "kind=resource&resource_link=rl-1&user=learner-1&name=Lena%20Learner&email=lena%40uni.example&role=Learner&context=course-7&context_title=Interventional%20Radiology";

on_both_databases!(a_course_links_launches_and_grades_stylet, "lti");

fn a_course_links_launches_and_grades_stylet(db: Db) {
    let f = Fixture::new(STYLET);
    f.users(&db);
    let mut lms = LtiPlatform::new();
    let mut args: Vec<String> = ["lti", "add-platform", "--data-dir", s(&f.data())]
        .map(str::to_string)
        .to_vec();
    args.extend(db.args().iter().map(|a| a.to_string()));
    args.extend(lms.registration());
    let said = STYLET.ok(&args.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(said.contains("registered"), "{said}");
    let srv = Server::start(STYLET, &f.data(), &db, &f.atlases(), &["--workers", "1"]);
    let b = &srv.base;
    lms.start(b);

    // The tool's key set is public.
    let (status, jwks, _) = call("GET", &format!("{b}/lti/jwks"), None, None, false);
    assert_eq!(status, 200, "{jwks}");
    assert_eq!(jwks["keys"][0]["kty"], "RSA", "{jwks}");

    // The instructor adds an exercise to the course (deep linking).
    let (status, picker, cookie) = launch(&lms, INSTRUCTOR);
    assert_eq!(status, 200, "{picker}");
    assert!(cookie.is_some(), "the instructor is logged in");
    assert!(picker.contains("Add a Stylet exercise"), "{picker}");
    assert!(
        picker.contains("value=\"success-intercostal/beginner\""),
        "training scenarios are offered: {picker}"
    );
    assert!(
        !picker.contains("value=\"lung-hit/"),
        "grading fixtures are not: {picker}"
    );
    let token = input_value(&picker, "token").unwrap();
    let (status, sending, h) = answer(agent().post(&format!("{b}/lti/deep-link")).send_form(&[
        ("token", &token),
        ("exercise", "success-intercostal/beginner"),
        ("title", "PTCD puncture, beginner"),
    ]));
    assert_eq!(status, 200, "{sending}");
    let csp = header(&h, "content-security-policy").unwrap();
    assert!(csp.contains(&format!("form-action 'self' {};", lms.url())), "{csp}");
    assert!(csp.contains("frame-ancestors *"), "{csp}");
    let return_url = form_action(&sending);
    assert_eq!(return_url, format!("{}/deep-link-return", lms.url()));
    let jwt = input_value(&sending, "JWT").unwrap();
    let (status, added, _) = answer(agent().post(&return_url).send_form(&[("JWT", &jwt)]));
    assert_eq!(
        status,
        200,
        "the platform takes the signed response: {added}\n{}",
        lms.log()
    );
    assert!(added.contains("PTCD puncture, beginner"), "{added}");
    // Sent once: the same choice again is refused.
    let (status, again, _) = answer(
        agent()
            .post(&format!("{b}/lti/deep-link"))
            .send_form(&[("token", &token), ("exercise", "success-intercostal/beginner")]),
    );
    assert_eq!(status, 400, "{again}");
    let items = lms.json("/test/content-items");
    assert_eq!(items.as_array().unwrap().len(), 1, "{items}");
    assert_eq!(
        items[0]["custom"],
        json!({"scenario": "success-intercostal", "level": "beginner"})
    );
    assert_eq!(items[0]["line_item"]["scoreMaximum"], 100);

    // A learner opens the activity: an account, in the course's cohort, logged in.
    let (status, landing, cookie) = launch(&lms, LEARNER);
    assert_eq!(status, 200, "{landing}");
    assert!(landing.contains("lena@uni.example"), "{landing}");
    assert!(landing.contains("success-intercostal"), "{landing}");
    assert!(landing.contains("gradebook"), "{landing}");
    let lena = auth_of(b, &cookie.unwrap());
    let (accounts, same_cohort) = on_database(&db, &f.data(), async |store| {
        let accounts: Vec<(String, String)> =
            sqlx::query_as("SELECT username, role FROM users WHERE password_hash = '!lti' ORDER BY username")
                .fetch_all(&store.pool)
                .await
                .unwrap();
        let shared: i64 = sqlx::query_scalar(
            "SELECT COUNT(*) FROM cohort_members a JOIN cohort_members b ON a.cohort_id = b.cohort_id \
             JOIN users ua ON ua.id = a.user_id JOIN users ub ON ub.id = b.user_id \
             WHERE ua.username = 'lena@uni.example' AND ub.role = 'instructor' AND ub.password_hash = '!lti'",
        )
        .fetch_one(&store.pool)
        .await
        .unwrap();
        (accounts, shared)
    });
    assert_eq!(
        accounts,
        vec![
            ("irene.instructor".to_string(), "instructor".to_string()),
            ("lena@uni.example".to_string(), "trainee".to_string())
        ]
    );
    assert_eq!(same_cohort, 1, "the instructor teaches the course's cohort");
    // No password logs in to an account made by a launch.
    let (status, _, _) = call(
        "POST",
        &format!("{b}/api/login"),
        None,
        Some(br#"{"username":"lena@uni.example","password":"!lti"}"#),
        true,
    );
    assert_eq!(status, 401);

    // She pairs her simulator and uploads two sessions of the exercise.
    let (status, code) = post_json(b, "/api/pairing/codes", Some(&lena), &json!({"purpose": "simulator"}));
    assert_eq!(status, 201, "{code}");
    let (status, paired) = post_json(
        b,
        "/api/pair",
        None,
        &json!({"code": code["code"], "label": "lena's laptop"}),
    );
    assert_eq!(status, 201, "{paired}");
    let sim = Auth::Bearer(paired["token"].as_str().unwrap().to_string());
    let atlas = f.atlases().join("phantom");
    let record = |script: &str, out: &str| {
        let out = f.dir.path().join(out);
        STYLET.ok(&[
            "script",
            "run",
            "--atlas",
            s(&atlas),
            "--script",
            s(&phantom_script(script)),
            "--scenario",
            "success-intercostal",
            "--out",
            s(&out),
            "--trainee",
            "lena@uni.example",
        ]);
        out
    };
    let (_, passed) = upload_scored(b, &sim, &record("success-intercostal", "lena-ok.mcap"));
    assert_eq!(passed["score"]["grade"]["passed"], true, "{passed}");
    let scores = wait_for_scores(&lms, 1);
    assert_eq!(scores[0]["userId"], "learner-1");
    assert_eq!(scores[0]["scoreMaximum"], 100);
    assert_eq!(scores[0]["gradingProgress"], "FullyGraded");
    assert_eq!(scores[0]["activityProgress"], "Completed");
    assert_eq!(scores[0]["comment"], "Passed.");
    let given = scores[0]["scoreGiven"].as_f64().unwrap();
    assert!(
        (given - passed["score"]["grade"]["score"].as_f64().unwrap()).abs() < 1e-9,
        "{scores:#?} {passed}"
    );
    let (_, failed) = upload_scored(b, &sim, &record("lung-hit", "lena-lung.mcap"));
    assert_eq!(failed["score"]["grade"]["passed"], false, "{failed}");
    let scores = wait_for_scores(&lms, 2);
    let comment = scores[1]["comment"].as_str().unwrap();
    assert!(comment.starts_with("Not passed: "), "{comment}");
    assert!(
        !comment.contains(".;") && !comment.ends_with(".."),
        "one full stop: {comment}"
    );
    assert!(
        comment.to_lowercase().contains("lung"),
        "the reasons are named: {comment}"
    );

    // Refused launches, each with a page that says why.
    let (id_token, state, action) = launch_form(&lms, LEARNER);
    assert_eq!(post_launch(&action, &id_token, &state).0, 200);
    let (status, page, cookie) = post_launch(&action, &id_token, &state);
    assert_eq!(status, 400, "a replayed launch: {page}");
    assert!(page.contains("already used"), "{page}");
    assert!(cookie.is_none());
    for (tamper, status, words) in [
        ("wrong_aud", 401, "another tool"),
        ("expired", 401, "expired"),
        ("unknown_key", 401, "does not hold the key"),
    ] {
        let (got, page, cookie) = launch(&lms, &format!("{LEARNER}&tamper={tamper}"));
        assert_eq!(got, status, "{tamper}: {page}");
        assert!(page.contains(words), "{tamper}: {page}");
        assert!(cookie.is_none(), "{tamper}: no login");
    }
    // A learner cannot add exercises; a launch from an unregistered platform is refused.
    let (status, page, cookie) = launch(&lms, &LEARNER.replace("kind=resource", "kind=deeplink"));
    assert_eq!(status, 403, "{page}");
    assert!(cookie.is_none(), "a refused launch logs nobody in");
    // A learner who teaches another course stays a trainee (an account keeps the role of its
    // first launch) and does not join that course's cohort: no instructor's view of classmates.
    let other_course = LEARNER
        .replace("kind=resource", "kind=deeplink")
        .replace("role=Learner", "role=Instructor")
        .replace("context=course-7", "context=course-9");
    let (status, page, _) = launch(&lms, &other_course);
    assert_eq!(status, 403, "{page}");
    assert!(page.contains("keeps the role of its first launch"), "{page}");
    let (role, cohorts) = on_database(&db, &f.data(), async |store| {
        let role: String = sqlx::query_scalar("SELECT role FROM users WHERE username = 'lena@uni.example'")
            .fetch_one(&store.pool)
            .await
            .unwrap();
        let cohorts: i64 = sqlx::query_scalar(
            "SELECT COUNT(*) FROM cohort_members m JOIN users u ON u.id = m.user_id WHERE u.username = 'lena@uni.example'",
        )
        .fetch_one(&store.pool)
        .await
        .unwrap();
        (role, cohorts)
    });
    assert_eq!((role.as_str(), cohorts), ("trainee", 1));
    // Anyone may post an error to the launch URL: the page does not repeat their words.
    let (status, page, _) = answer(agent().post(&format!("{b}/lti/launch")).send_form(&[
        ("error", "login_required"),
        ("error_description", "Your account is locked: call 555-0100"),
    ]));
    assert_eq!(status, 400, "{page}");
    assert!(!page.contains("555-0100"), "{page}");
    // The platform may be asked to post to Stylet's launch URL only, at the address it was reached at.
    let (status, page, _) = answer(
        agent()
            .get(&format!(
                "{b}/lti/login?iss={}&login_hint=x&target_link_uri={}",
                encode(&lms.url()),
                encode("https://evil.example/lti/launch")
            ))
            .call(),
    );
    assert_eq!(status, 400, "{page}");
    assert!(page.contains("not Stylet's launch URL"), "{page}");
    let (status, page, _) = answer(
        agent()
            .get(&format!(
                "{b}/lti/login?iss=https%3A%2F%2Fevil.example&login_hint=x&target_link_uri={}",
                encode(&format!("{b}/lti/launch"))
            ))
            .call(),
    );
    assert_eq!(status, 400, "{page}");
    assert!(page.contains("is registered in Stylet"), "{page}");
    drop(srv);
}

fn encode(s: &str) -> String {
    s.bytes()
        .map(|b| match b {
            b'A'..=b'Z' | b'a'..=b'z' | b'0'..=b'9' | b'-' | b'_' | b'.' | b'~' => (b as char).to_string(),
            _ => format!("%{b:02X}"),
        })
        .collect()
}
