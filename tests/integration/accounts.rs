//! Account management against a real server on loopback (`stylet serve`), on SQLite and on a real
//! PostgreSQL server (`$STYLET_POSTGRES_URL`, started by scripts/test): disabling an account logs
//! it out everywhere at once (cookie, API token, dashboard) and keeps its sessions; enabling it
//! restores them; password resets; role and cohort changes take effect at once; bulk imports are
//! all or nothing and name every bad line (API, dashboard form, command line); the last active
//! admin and one's own account are protected; every change is audited.

use std::io::Write;
use std::process::Stdio;

use crate::common::*;
use serde_json::Value;

on_both_databases!(disabling_logs_out_everywhere_and_enabling_restores, "accounts_disable");
on_both_databases!(passwords_roles_cohorts_and_the_last_admin, "accounts_change");
on_both_databases!(imports_are_all_or_nothing_and_name_the_bad_lines, "accounts_import");

/// The accounts of [`small_server`]: an admin, an instructor of c1 and trainees tina (c1) and tom
/// (c2).
const USERS: &[(&str, &str, Option<&str>)] = &[
    ("root", "admin", None),
    ("ivan", "instructor", Some("c1")),
    ("tina", "trainee", Some("c1")),
    ("tom", "trainee", Some("c2")),
];

fn error_of(json: &Value) -> &str {
    json["error"].as_str().unwrap_or_default()
}

fn post_json(base: &str, path: &str, who: &Auth, body: &str) -> (u16, Value) {
    let (status, json, _) = call("POST", &format!("{base}{path}"), Some(who), Some(body.as_bytes()), true);
    (status, json)
}

fn patch_json(base: &str, path: &str, who: &Auth, body: &str) -> (u16, Value) {
    let (status, json, _) = call(
        "PATCH",
        &format!("{base}{path}"),
        Some(who),
        Some(body.as_bytes()),
        true,
    );
    (status, json)
}

fn get(base: &str, path: &str, who: &Auth) -> (u16, Value) {
    let (status, json, _) = call("GET", &format!("{base}{path}"), Some(who), None, false);
    (status, json)
}

/// A login with an explicit password: (status, JSON).
fn try_login(base: &str, user: &str, password: &str) -> (u16, Value) {
    let body = serde_json::json!({ "username": user, "password": password }).to_string();
    let (status, json, _) = call("POST", &format!("{base}/api/login"), None, Some(body.as_bytes()), true);
    (status, json)
}

/// A CSV import through the API: (status, JSON).
fn import_csv(base: &str, who: &Auth, csv: &str) -> (u16, Value) {
    let Auth::Cookie { token, csrf } = who else {
        unreachable!()
    };
    let res = ureq::post(&format!("{base}/api/users"))
        .set("Cookie", &format!("stylet_session={token}"))
        .set("X-CSRF-Token", csrf)
        .set("Content-Type", "text/csv")
        .send_bytes(csv.as_bytes());
    let resp = match res {
        Ok(r) => r,
        Err(ureq::Error::Status(_, r)) => r,
        Err(e) => panic!("import: {e}"),
    };
    let status = resp.status();
    (status, serde_json::from_str(&resp.into_string().unwrap()).unwrap())
}

fn csrf_of(who: &Auth) -> &str {
    match who {
        Auth::Cookie { csrf, .. } => csrf,
        Auth::Bearer(_) => unreachable!(),
    }
}

/// `stylet user …` on the server's database: (success, stdout, stderr).
fn stylet_user(data: &std::path::Path, db: &Db, args: &[&str], stdin: &str) -> (bool, String, String) {
    let mut all = vec!["user"];
    all.extend(args);
    all.extend(["--data-dir", s(data)]);
    all.extend(db.args());
    let mut child = STYLET
        .command()
        .args(&all)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    child.stdin.take().unwrap().write_all(stdin.as_bytes()).unwrap();
    let out = child.wait_with_output().unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).to_string(),
        String::from_utf8_lossy(&out.stderr).to_string(),
    )
}

/// The audit log's (action, actor username or "-", target username or "", detail), oldest first.
fn audit_rows(db: &Db, data: &std::path::Path) -> Vec<(String, String, String, String)> {
    on_database(db, data, async |store| {
        let rows = sqlx::query(
            "SELECT a.action, COALESCE(u.username, '-') AS actor, COALESCE(t.username, '') AS target, \
             COALESCE(a.detail, '') AS detail FROM audit_log a \
             LEFT JOIN users u ON u.id = a.actor_id LEFT JOIN users t ON t.id = a.target \
             ORDER BY a.at, a.id",
        )
        .fetch_all(&store.pool)
        .await
        .unwrap();
        use sqlx::Row;
        rows.iter()
            .map(|r| {
                (
                    r.get::<String, _>("action"),
                    r.get::<String, _>("actor"),
                    r.get::<String, _>("target"),
                    r.get::<String, _>("detail"),
                )
            })
            .collect()
    })
}

fn has_audit(rows: &[(String, String, String, String)], action: &str, actor: &str, target: &str) -> bool {
    rows.iter()
        .any(|(a, by, t, _)| a == action && by == actor && t == target)
}

/// Disabling refuses the account's login cookie, its API token and its dashboard pages on the
/// very next request, and a new login; its sessions stay. Enabling restores cookie and token.
fn disabling_logs_out_everywhere_and_enabling_restores(db: Db) {
    let f = Fixture::new(STYLET);
    let srv = f.serve(&db, 1);
    let b = &srv.base;
    let root = login(b, "root");
    let tina = login(b, "tina");
    let (status, made) = post_json(b, "/api/tokens", &tina, r#"{"label":"lab PC","scope":"full"}"#);
    assert_eq!(status, 201, "{made}");
    let token = Auth::Bearer(made["token"].as_str().unwrap().to_string());
    let session = upload(b, &tina, &f.session("tina-ok"));
    wait_scored(b, &tina, &session);
    assert_eq!(get(b, "/api/sessions", &tina).0, 200);
    assert_eq!(get(b, "/api/sessions", &token).0, 200);
    assert_eq!(page(b, "/", &tina, None).status, 200);

    let (status, row) = post_json(b, "/api/users/tina/disable", &root, "");
    assert_eq!(status, 200, "{row}");
    assert!(row["disabled_at"].is_string(), "{row}");
    // At once, everywhere.
    let (status, json) = get(b, "/api/sessions", &tina);
    assert_eq!(status, 401, "{json}");
    let (status, json) = get(b, &format!("/api/sessions/{session}"), &token);
    assert_eq!(status, 401, "{json}");
    assert!(error_of(&json).contains("disabled"), "{json}");
    let Page { status, location, .. } = page(b, "/", &tina, None);
    assert!(status == 303 || status == 302 || status == 307, "{status}");
    assert!(location.starts_with("/login"), "{location}");
    let (status, json) = try_login(b, "tina", "tina-password");
    assert_eq!(status, 403, "{json}");
    assert!(error_of(&json).contains("disabled"), "{json}");
    // A wrong password tells nothing about the account.
    let (status, json) = try_login(b, "tina", "not-her-password");
    assert_eq!(status, 401, "{json}");
    // Its sessions stay: the admin still sees and lists it, the account is listed as disabled.
    assert_eq!(get(b, &format!("/api/sessions/{session}"), &root).0, 200);
    let (_, listed) = get(b, "/api/users?q=tin", &root);
    assert_eq!(listed["total"], 1, "{listed}");
    assert!(listed["users"][0]["disabled_at"].is_string(), "{listed}");
    // Disabling twice changes nothing; the admin page shows it.
    assert_eq!(post_json(b, "/api/users/tina/disable", &root, "").0, 200);
    let Page { status, body: html, .. } = page(b, "/admin/users?q=tina", &root, None);
    assert_eq!(status, 200);
    assert!(html.contains("disabled since"), "{html}");

    // Enabling restores the same cookie and token.
    let (status, row) = post_json(b, "/api/users/tina/enable", &root, "");
    assert_eq!(status, 200, "{row}");
    assert!(row["disabled_at"].is_null(), "{row}");
    assert_eq!(get(b, "/api/sessions", &tina).0, 200);
    assert_eq!(get(b, &format!("/api/sessions/{session}"), &token).0, 200);
    assert_eq!(page(b, "/", &tina, None).status, 200);

    // The dashboard's form does the same, with the CSRF token only.
    let path = "/admin/users/tina/status";
    let Page { status, body: html, .. } = page(b, path, &root, Some(&[("csrf", "wrong"), ("action", "disable")]));
    assert_eq!(status, 403, "{html}");
    assert_eq!(get(b, "/api/sessions", &tina).0, 200);
    let Page { status, location, .. } = page(b, path, &root, Some(&[("csrf", csrf_of(&root)), ("action", "disable")]));
    assert_eq!((status, location.as_str()), (303, "/admin/users?q=tina"));
    assert_eq!(get(b, "/api/sessions", &tina).0, 401);
    assert_eq!(get(b, "/api/sessions", &token).0, 401);
    let Page { status, .. } = page(b, path, &root, Some(&[("csrf", csrf_of(&root)), ("action", "enable")]));
    assert_eq!(status, 303);
    assert_eq!(get(b, "/api/sessions", &tina).0, 200);

    // Unknown accounts: 404; non-admins: 403 (also a full token of a trainee).
    assert_eq!(post_json(b, "/api/users/nobody/disable", &root, "").0, 404);
    assert_eq!(post_json(b, "/api/users/tom/disable", &tina, "").0, 403);
    assert_eq!(post_json(b, "/api/users/tom/disable", &token, "").0, 403);

    let audit = audit_rows(&db, &f.data());
    assert!(has_audit(&audit, "user.disable", "root", "tina"), "{audit:?}");
    assert!(has_audit(&audit, "user.enable", "root", "tina"), "{audit:?}");
    // Repeats are not audited twice: two disables took effect (API, form), two enables.
    let count = |action: &str| audit.iter().filter(|r| r.0 == action && r.2 == "tina").count();
    assert_eq!((count("user.disable"), count("user.enable")), (2, 2), "{audit:?}");
}

/// Password resets end the account's logins and the old password; role and cohort changes take
/// effect on the next request; the last active admin and one's own account cannot be disabled or
/// demoted (API, dashboard and command line); all audited.
fn passwords_roles_cohorts_and_the_last_admin(db: Db) {
    let (dir, srv) = small_server(&db, USERS);
    let data = dir.path().join("data");
    let b = &srv.base;
    let root = login(b, "root");
    let ivan = login(b, "ivan");
    let tom = login(b, "tom");

    // Password reset.
    let (status, json) = post_json(b, "/api/users/tom/password", &root, r#"{"password":"short"}"#);
    assert_eq!(status, 400, "{json}");
    assert!(error_of(&json).contains("8–1024"), "{json}");
    let (status, json) = post_json(b, "/api/users/tom/password", &root, r#"{"password":"a new long one"}"#);
    assert_eq!(status, 200, "{json}");
    assert_eq!(get(b, "/api/sessions", &tom).0, 401, "the old login ended");
    assert_eq!(try_login(b, "tom", "tom-password").0, 401);
    assert_eq!(try_login(b, "tom", "a new long one").0, 200);
    // From the command line, the password on standard input.
    let (ok_, out, err) = stylet_user(&data, &db, &["passwd", "tom", "--password-stdin"], "tom-password\n");
    assert!(ok_, "{out}{err}");
    assert_eq!(try_login(b, "tom", "a new long one").0, 401);
    let tom = login(b, "tom");

    // Cohorts: ivan teaches c1, tom is in c2 → tom's progress is not ivan's to see, until tom
    // joins c1.
    assert_eq!(get(b, "/api/trainees/tom/progress", &ivan).0, 404);
    let (status, row) = patch_json(b, "/api/users/tom", &root, r#"{"cohorts":["c1","c2"]}"#);
    assert_eq!(status, 200, "{row}");
    assert_eq!(row["cohorts"], serde_json::json!(["c1", "c2"]), "{row}");
    assert_eq!(get(b, "/api/trainees/tom/progress", &ivan).0, 200);
    let (status, json) = patch_json(b, "/api/users/tom", &root, r#"{"cohorts":["bad name"]}"#);
    assert_eq!(status, 400, "{json}");
    let (status, json) = patch_json(b, "/api/users/tom", &root, r#"{"role":"janitor"}"#);
    assert_eq!(status, 400, "{json}");

    // Role: tom becomes curriculum staff, with the same login.
    assert_eq!(get(b, "/api/export/sessions.csv", &tom).0, 403);
    let (status, row) = patch_json(b, "/api/users/tom", &root, r#"{"role":"curriculum"}"#);
    assert_eq!(status, 200, "{row}");
    assert_eq!(row["role"], "curriculum");
    assert_eq!(get(b, "/api/export/sessions.csv", &tom).0, 200);
    // The dashboard's form: role and cohorts together.
    let Page { status, body: html, .. } = page(
        b,
        "/admin/users/tom/set",
        &root,
        Some(&[("csrf", csrf_of(&root)), ("role", "trainee"), ("cohorts", "c2")]),
    );
    assert_eq!(status, 303, "{html}");
    let (_, row) = get(b, "/api/users/tom", &root);
    assert_eq!(
        (row["role"].as_str(), row["cohorts"].clone()),
        (Some("trainee"), serde_json::json!(["c2"]))
    );
    assert_eq!(get(b, "/api/export/sessions.csv", &tom).0, 403);
    assert_eq!(get(b, "/api/trainees/tom/progress", &ivan).0, 404);
    // And the command line.
    let (ok_, out, err) = stylet_user(&data, &db, &["set", "tom", "--cohorts", "c1"], "");
    assert!(ok_, "{out}{err}");
    assert!(out.contains("tom: trainee, cohorts [c1], active"), "{out}");
    assert_eq!(get(b, "/api/trainees/tom/progress", &ivan).0, 200);

    // The last active admin, and one's own account.
    for (path, body) in [
        ("/api/users/root/disable", ""),
        ("/api/users/root", r#"{"role":"instructor"}"#),
    ] {
        let (status, json) = if body.is_empty() {
            post_json(b, path, &root, body)
        } else {
            patch_json(b, path, &root, body)
        };
        assert_eq!(status, 409, "{path}: {json}");
        assert!(error_of(&json).contains("own account"), "{json}");
    }
    let Page { status, body: html, .. } = page(
        b,
        "/admin/users/root/status",
        &root,
        Some(&[("csrf", csrf_of(&root)), ("action", "disable")]),
    );
    assert_eq!(status, 409, "{html}");
    assert!(html.contains("own account"), "{html}");
    // From the command line (no acting admin): root is the last active admin.
    for args in [&["disable", "root"][..], &["set", "root", "--role", "trainee"][..]] {
        let (ok_, out, err) = stylet_user(&data, &db, args, "");
        assert!(!ok_, "{args:?}: {out}");
        assert!(err.contains("last active admin"), "{args:?}: {err}");
    }
    // With a second admin, either may be disabled by the other; a disabled admin does not count.
    let (status, json) = post_json(
        b,
        "/api/users",
        &root,
        r#"{"username":"ada","role":"admin","password":"ada-password"}"#,
    );
    assert_eq!(status, 201, "{json}");
    let ada = login(b, "ada");
    assert_eq!(post_json(b, "/api/users/root/disable", &ada, "").0, 200);
    assert_eq!(get(b, "/api/users", &root).0, 401);
    let (ok_, _, err) = stylet_user(&data, &db, &["disable", "ada"], "");
    assert!(!ok_ && err.contains("last active admin"), "{err}");
    let (ok_, out, err) = stylet_user(&data, &db, &["enable", "root"], "");
    assert!(ok_, "{out}{err}");
    assert_eq!(get(b, "/api/users", &root).0, 200);
    let (status, row) = patch_json(b, "/api/users/ada", &root, r#"{"role":"instructor"}"#);
    assert_eq!(status, 200, "{row}");
    assert_eq!(get(b, "/api/users", &ada).0, 403, "demoted at once");
    let (ok_, out, _) = stylet_user(&data, &db, &["list", "--search", "ada"], "");
    assert!(
        ok_ && out.contains("ada") && out.contains("instructor") && !out.contains("root"),
        "{out}"
    );

    let audit = audit_rows(&db, &data);
    for (action, actor, target) in [
        ("user.passwd", "root", "tom"),
        ("user.passwd", "-", "tom"),
        ("user.cohorts", "root", "tom"),
        ("user.cohorts", "-", "tom"),
        ("user.role", "root", "tom"),
        ("user.add", "root", "ada"),
        ("user.disable", "ada", "root"),
        ("user.enable", "-", "root"),
        ("user.role", "root", "ada"),
    ] {
        assert!(
            has_audit(&audit, action, actor, target),
            "{action} by {actor} of {target}: {audit:?}"
        );
    }
    // Refusals change nothing and are not recorded as changes.
    assert!(!has_audit(&audit, "user.disable", "root", "root"), "{audit:?}");
    let role = audit.iter().find(|r| r.0 == "user.role" && r.2 == "ada").unwrap();
    assert_eq!(role.3, "ada: admin → instructor");
}

/// A CSV with bad lines imports nothing and names each bad line with why, through the API, the
/// dashboard's form and the command line; a good one imports every account, audited.
fn imports_are_all_or_nothing_and_name_the_bad_lines(db: Db) {
    let (dir, srv) = small_server(&db, USERS);
    let data = dir.path().join("data");
    let b = &srv.base;
    let root = login(b, "root");
    let tina = login(b, "tina");
    let count = || get(b, "/api/users", &root).1["total"].as_i64().unwrap();
    let before = count();

    let bad = "username,role,cohort,password\n\
               nora,trainee,c1,nora-password\n\
               otto,janitor,c1,otto-password\n\
               pia,trainee,c1,short\n\
               tina,trainee,c1,tina-password\n\
               nora,instructor,,nora-password\n";
    let (status, json) = import_csv(b, &root, bad);
    assert_eq!(status, 422, "{json}");
    let lines: Vec<(i64, String)> = json["lines"]
        .as_array()
        .unwrap()
        .iter()
        .map(|l| (l["line"].as_i64().unwrap(), l["reason"].as_str().unwrap().to_string()))
        .collect();
    assert_eq!(lines.iter().map(|l| l.0).collect::<Vec<_>>(), [3, 4, 5, 6], "{json}");
    assert!(lines[0].1.contains("unknown role 'janitor'"), "{json}");
    assert!(lines[1].1.contains("8–1024 characters"), "{json}");
    assert!(lines[2].1.contains("user 'tina' already exists"), "{json}");
    assert!(lines[3].1.contains("already on line 2"), "{json}");
    assert!(error_of(&json).starts_with("nothing imported"), "{json}");
    assert_eq!(count(), before, "nothing imported");
    assert_eq!(try_login(b, "nora", "nora-password").0, 401);
    // Lines that parse but name existing accounts are refused too, all at once.
    let (status, json) = import_csv(
        b,
        &root,
        "nora,trainee,c1,nora-password\ntina,trainee,c1,tina-password\n",
    );
    assert_eq!(status, 422, "{json}");
    assert_eq!(json["lines"][0]["line"], 2, "{json}");
    assert!(
        json["lines"][0]["reason"].as_str().unwrap().contains("already exists"),
        "{json}"
    );
    assert_eq!(json["lines"].as_array().unwrap().len(), 1, "{json}");
    assert_eq!(count(), before);
    // Only admins.
    assert_eq!(import_csv(b, &tina, "nora,trainee,c1,nora-password\n").0, 403);

    // The dashboard's form shows every bad line in words.
    let Page { status, body: html, .. } = page(
        b,
        "/admin/users/import",
        &root,
        Some(&[("csrf", csrf_of(&root)), ("csv", bad)]),
    );
    assert_eq!(status, 422, "{html}");
    assert!(html.contains("Nothing was imported"), "{html}");
    for l in [
        "line 3: unknown role",
        "line 4: a password has 8–1024 characters",
        "line 6:",
    ] {
        assert!(html.contains(l), "{l}: {html}");
    }
    assert_eq!(count(), before);

    // The command line: a bad file imports nothing and names the line.
    let file = dir.path().join("accounts.csv");
    std::fs::write(&file, bad).unwrap();
    let (ok_, out, err) = stylet_user(&data, &db, &["import", s(&file)], "");
    assert!(!ok_, "{out}");
    assert!(
        err.contains("line 3: unknown role 'janitor'") && err.contains("line 6:"),
        "{err}"
    );
    assert!(err.contains("nothing imported"), "{err}");
    assert_eq!(count(), before);

    // Good files: through the API, then the command line (from standard input).
    let (status, json) = import_csv(
        b,
        &root,
        "nora,trainee,c1,nora-password\r\n\r\notto,instructor,,otto, with comma\n",
    );
    assert_eq!(status, 201, "{json}");
    assert_eq!(json["imported"], serde_json::json!(["nora", "otto"]));
    assert_eq!(try_login(b, "nora", "nora-password").0, 200);
    assert_eq!(try_login(b, "otto", "otto, with comma").0, 200);
    let (_, nora) = get(b, "/api/users/nora", &root);
    assert_eq!(
        (nora["role"].as_str(), nora["cohorts"].clone()),
        (Some("trainee"), serde_json::json!(["c1"]))
    );
    let (ok_, out, err) = stylet_user(&data, &db, &["import", "-"], "pia,curriculum,,pia-password\n");
    assert!(ok_, "{out}{err}");
    assert!(out.contains("imported 1 accounts: pia"), "{out}");
    assert_eq!(try_login(b, "pia", "pia-password").0, 200);
    assert_eq!(count(), before + 3);

    // The OpenAPI document describes every account route.
    let (_, doc, _) = call("GET", &format!("{b}/api/openapi.json"), None, None, false);
    for (path, method) in [
        ("/api/users", "get"),
        ("/api/users", "post"),
        ("/api/users/{username}", "get"),
        ("/api/users/{username}", "patch"),
        ("/api/users/{username}/disable", "post"),
        ("/api/users/{username}/enable", "post"),
        ("/api/users/{username}/password", "post"),
    ] {
        assert!(doc["paths"][path][method].is_object(), "openapi lacks {method} {path}");
    }
    assert!(doc["paths"]["/api/users"]["post"]["responses"]["422"].is_object());

    let audit = audit_rows(&db, &data);
    assert!(has_audit(&audit, "user.import", "root", ""), "{audit:?}");
    assert!(has_audit(&audit, "user.add", "root", "nora"), "{audit:?}");
    assert!(has_audit(&audit, "user.add", "root", "otto"), "{audit:?}");
    assert!(has_audit(&audit, "user.import", "-", ""), "{audit:?}");
    // Refused imports wrote nothing.
    assert_eq!(audit.iter().filter(|r| r.0 == "user.import").count(), 2, "{audit:?}");
}
