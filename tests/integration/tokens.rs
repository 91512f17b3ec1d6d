//! API tokens and login origins against a real server on loopback (`stylet serve`), on SQLite and
//! on a real PostgreSQL server (`$STYLET_POSTGRES_URL`, started by scripts/test): token scopes,
//! expiry and revocation, no tokens made by tokens, lists without secrets, the dashboard's tokens
//! page, and logins sent from another origin.

use crate::common::*;
use serde_json::Value;

on_both_databases!(api_tokens_scopes_expiry_and_revocation, "tokens");
on_both_databases!(tokens_page_creates_lists_and_revokes, "tokens_page");
on_both_databases!(logins_from_other_origins_are_refused, "origins");

/// The accounts of [`small_server`]: an admin and two trainees.
const USERS: &[(&str, &str, Option<&str>)] = &[
    ("root", "admin", None),
    ("tina", "trainee", Some("c1")),
    ("tom", "trainee", Some("c2")),
];

/// Asserts that a token's row expires `days` after its creation.
fn assert_lasts_days(row: &Value, days: u64) {
    let t = |k: &str| humantime::parse_rfc3339(row[k].as_str().unwrap_or_else(|| panic!("{k}: {row}"))).unwrap();
    let lasts = t("expires_at").duration_since(t("created_at")).unwrap().as_secs_f64();
    assert!((lasts - days as f64 * 86_400.0).abs() < 5.0, "{row}");
}

fn error_of(json: &Value) -> &str {
    json["error"].as_str().unwrap_or_default()
}

/// Tokens expire, can be revoked (logout does not touch them), cannot make more tokens, and an
/// upload-scoped token uploads and reads its session's status and nothing else.
fn api_tokens_scopes_expiry_and_revocation(db: Db) {
    let f = Fixture::new(STYLET);
    let srv = f.serve(&db, 1);
    let b = &srv.base;
    let url = |p: &str| format!("{b}{p}");
    let tina = login(b, "tina");
    let make = |who: &Auth, body: &str| call("POST", &url("/api/tokens"), Some(who), Some(body.as_bytes()), true);

    // The default: scope upload, 90 days, the secret once, its last four digits.
    let (status, made, _) = make(&tina, r#"{"label":"sim PC 3"}"#);
    assert_eq!(status, 201, "{made}");
    let upload_secret = made["token"].as_str().unwrap().to_string();
    assert!(
        upload_secret.len() == 64 && upload_secret.bytes().all(|c| c.is_ascii_hexdigit()),
        "{made}"
    );
    assert_eq!(
        (&made["scope"], &made["status"], &made["username"], &made["last4"]),
        (
            &Value::from("upload"),
            &Value::from("active"),
            &Value::from("tina"),
            &Value::from(&upload_secret[60..])
        ),
        "{made}"
    );
    assert_lasts_days(&made, 90);
    let upload_id = made["id"].as_str().unwrap().to_string();
    let up = Auth::Bearer(upload_secret.clone());

    // It uploads, and reads that session's status...
    let file = std::fs::read(f.session("tina-ok")).unwrap();
    let (status, json, _) = call("POST", &url("/api/sessions"), Some(&up), Some(&file), false);
    assert_eq!(status, 201, "{json}");
    let id = json["id"].as_str().unwrap().to_string();
    let (status, json, _) = call("GET", &url(&format!("/api/sessions/{id}")), Some(&up), None, false);
    assert_eq!((status, json["id"].as_str()), (200, Some(id.as_str())), "{json}");
    // ... not a session its account may not see...
    let tom = login(b, "tom");
    let (status, json, _) = call(
        "POST",
        &url("/api/sessions"),
        Some(&tom),
        Some(&std::fs::read(f.session("tom-ok")).unwrap()),
        false,
    );
    assert_eq!(status, 201, "{json}");
    let toms = json["id"].as_str().unwrap().to_string();
    assert_eq!(
        call("GET", &url(&format!("/api/sessions/{toms}")), Some(&up), None, false).0,
        404
    );
    // ... and nothing else: 403 with the reason.
    let comment = format!("/api/sessions/{id}/comments");
    let revoke_own = format!("/api/tokens/{upload_id}/revoke");
    let refused: [(&str, &str, Option<&str>); 9] = [
        ("GET", "/api/sessions", None),
        ("GET", "/api/export/sessions.csv", None),
        ("GET", "/api/users", None),
        ("GET", "/api/trainees/tina/progress", None),
        ("GET", "/api/cohorts/c1/summary", None),
        ("GET", "/api/tokens", None),
        ("POST", &comment, Some(r#"{"body":"x"}"#)),
        ("POST", &revoke_own, Some("")),
        (
            "POST",
            "/api/users",
            Some(r#"{"username":"eve","role":"admin","password":"eve-password"}"#),
        ),
    ];
    for (method, path, body) in refused {
        let (status, json, _) = call(method, &url(path), Some(&up), body.map(str::as_bytes), true);
        assert_eq!(status, 403, "{method} {path}: {json}");
        assert!(error_of(&json).contains("scope 'upload'"), "{method} {path}: {json}");
    }

    // A full token has the account's rights, no more: a trainee's token exports nothing.
    let (status, made, _) = make(&tina, r#"{"label":"script","scope":"full","expires_in_days":7}"#);
    assert_eq!((status, made["scope"].as_str()), (201, Some("full")), "{made}");
    assert_lasts_days(&made, 7);
    let full_id = made["id"].as_str().unwrap().to_string();
    let full_secret = made["token"].as_str().unwrap().to_string();
    let full = Auth::Bearer(full_secret.clone());
    let (status, listed, _) = call("GET", &url("/api/sessions"), Some(&full), None, false);
    assert_eq!((status, listed["total"].as_i64()), (200, Some(1)), "{listed}");
    assert_eq!(
        call("GET", &url("/api/trainees/tina/progress"), Some(&full), None, false).0,
        200
    );
    assert_eq!(
        call("GET", &url("/api/export/sessions.csv"), Some(&full), None, false).0,
        403
    );

    // No token makes tokens, whatever its scope.
    for (what, token) in [("upload", &up), ("full", &full)] {
        let (status, json, _) = make(token, r#"{"label":"minted","scope":"full"}"#);
        assert_eq!(status, 403, "{what}: {json}");
        assert!(error_of(&json).contains("cannot create API tokens"), "{what}: {json}");
    }
    // Nor a cookie without its CSRF token, nor nobody.
    let Auth::Cookie { token: cookie, .. } = &tina else {
        unreachable!()
    };
    let no_csrf = Auth::Cookie {
        token: cookie.clone(),
        csrf: "wrong".into(),
    };
    assert_eq!(make(&no_csrf, r#"{"label":"x"}"#).0, 403);
    assert_eq!(
        call("POST", &url("/api/tokens"), None, Some(b"{\"label\":\"x\"}"), true).0,
        401
    );
    assert_eq!(call("GET", &url("/api/tokens"), None, None, false).0, 401);
    // Bad requests say what is wrong; labels are counted in characters.
    let e = |n: usize| "é".repeat(n);
    for (body, reason) in [
        (r#"{"label":"  "}"#.to_string(), "label is 1–100 characters"),
        (format!(r#"{{"label":"{}"}}"#, e(101)), "label is 1–100 characters"),
        (r#"{"label":"x","scope":"admin"}"#.into(), "unknown variant"),
        (r#"{"label":"x","expires_in_days":0}"#.into(), "1–90 days"),
        (r#"{"label":"x","expires_in_days":91}"#.into(), "1–90 days"),
        (r#"{"label":"x","expires_in_days":-1}"#.into(), "expected"),
        (r#"{"label":"x","expires":3}"#.into(), "unknown field"),
    ] {
        let (status, json, _) = make(&tina, &body);
        assert_eq!(status, 400, "{body}: {json}");
        assert!(error_of(&json).contains(reason), "{body}: {json}");
    }
    let (status, json, _) = make(&tina, &format!(r#"{{"label":"{}"}}"#, e(100)));
    assert_eq!(status, 201, "{json}");

    // The list: what each token is, never the token.
    let (status, list, _) = call("GET", &url("/api/tokens"), Some(&tina), None, false);
    assert_eq!(status, 200, "{list}");
    let rows = list["tokens"].as_array().unwrap();
    assert_eq!(rows.len(), 3, "{list}");
    let text = list.to_string();
    assert!(!text.contains(&upload_secret) && !text.contains(&full_secret), "{text}");
    for row in rows {
        for key in ["id", "label", "scope", "created_at", "expires_at", "last4", "status"] {
            assert!(row.get(key).is_some(), "{key}: {row}");
        }
        assert!(row.get("token").is_none() && row.get("token_sha256").is_none(), "{row}");
    }
    let (_, list, _) = call("GET", &url("/api/tokens"), Some(&full), None, false);
    assert_eq!(
        list["tokens"].as_array().unwrap().len(),
        3,
        "a full token lists them too: {list}"
    );
    let (_, list, _) = call("GET", &url("/api/tokens"), Some(&tom), None, false);
    assert_eq!(list["tokens"], serde_json::json!([]), "tom sees none of tina's");
    let root = login(b, "root");
    let (_, list, _) = call("GET", &url("/api/tokens"), Some(&root), None, false);
    let everyone = list["tokens"].as_array().unwrap();
    assert!(
        everyone.len() == 3 && everyone.iter().all(|t| t["username"] == "tina"),
        "an admin sees everyone's: {list}"
    );

    // Logging out ends the login, not the tokens.
    assert_eq!(call("POST", &url("/api/logout"), Some(&tina), Some(b""), true).0, 200);
    assert_eq!(call("GET", &url("/api/sessions"), Some(&tina), None, false).0, 401);
    assert_eq!(
        call("GET", &url(&format!("/api/sessions/{id}")), Some(&up), None, false).0,
        200
    );
    assert_eq!(call("GET", &url("/api/sessions"), Some(&full), None, false).0, 200);

    // Revoking: not another's (404, as for a token that does not exist), then the owner's.
    let tina = login(b, "tina");
    let revoke = |who: &Auth, token_id: &str| {
        call(
            "POST",
            &url(&format!("/api/tokens/{token_id}/revoke")),
            Some(who),
            Some(b""),
            true,
        )
    };
    assert_eq!(revoke(&tom, &upload_id).0, 404);
    assert_eq!(revoke(&tina, "no-such-token").0, 404);
    assert_eq!(
        call("GET", &url(&format!("/api/sessions/{id}")), Some(&up), None, false).0,
        200
    );
    let (status, revoked, _) = revoke(&tina, &upload_id);
    assert_eq!(
        (status, revoked["status"].as_str()),
        (200, Some("revoked")),
        "{revoked}"
    );
    let (status, json, _) = call("GET", &url(&format!("/api/sessions/{id}")), Some(&up), None, false);
    assert_eq!(status, 401, "{json}");
    assert!(error_of(&json).contains("revoked"), "{json}");
    let two = std::fs::read(f.session("tina-two")).unwrap();
    assert_eq!(raw_post(b, "/api/sessions", Some(&up), &two).0, 401);
    // Revoking twice changes nothing; an admin revokes anyone's.
    let (status, again, _) = revoke(&tina, &upload_id);
    assert_eq!((status, &again["revoked_at"]), (200, &revoked["revoked_at"]), "{again}");
    assert_eq!(revoke(&root, &full_id).0, 200);
    assert_eq!(call("GET", &url("/api/sessions"), Some(&full), None, false).0, 401);

    // Expiry: a token whose time is up is refused (401) and listed as expired.
    let (_, made, _) = make(&tina, r#"{"label":"soon","expires_in_days":1}"#);
    let soon_id = made["id"].as_str().unwrap().to_string();
    let soon = Auth::Bearer(made["token"].as_str().unwrap().to_string());
    assert_eq!(
        call("GET", &url(&format!("/api/sessions/{id}")), Some(&soon), None, false).0,
        200
    );
    on_database(&db, &f.data(), async |store| {
        sqlx::query("UPDATE api_tokens SET expires_at = $1 WHERE id = $2")
            .bind("2020-01-01T00:00:00.000000Z".to_string())
            .bind(soon_id.clone())
            .execute(&store.pool)
            .await
            .unwrap();
    });
    let (status, json, _) = call("GET", &url(&format!("/api/sessions/{id}")), Some(&soon), None, false);
    assert_eq!(status, 401, "{json}");
    assert!(error_of(&json).contains("expired"), "{json}");
    let (_, list, _) = call("GET", &url("/api/tokens"), Some(&tina), None, false);
    let status_of = |token_id: &str| {
        list["tokens"]
            .as_array()
            .unwrap()
            .iter()
            .find(|t| t["id"] == token_id)
            .map(|t| t["status"].as_str().unwrap().to_string())
    };
    assert_eq!(status_of(&soon_id).as_deref(), Some("expired"), "{list}");
    assert_eq!(status_of(&upload_id).as_deref(), Some("revoked"), "{list}");
    assert_eq!(status_of(&full_id).as_deref(), Some("revoked"), "{list}");

    // The OpenAPI document describes the token routes.
    let (_, doc, _) = call("GET", &url("/api/openapi.json"), None, None, false);
    for (path, method) in [
        ("/api/tokens", "post"),
        ("/api/tokens", "get"),
        ("/api/tokens/{id}/revoke", "post"),
    ] {
        assert!(
            doc["paths"][path].get(method).is_some(),
            "openapi lacks {method} {path}"
        );
    }
    assert!(doc["components"]["schemas"].get("ApiToken").is_some());

    // Audited: four tokens made, two revoked (the second by the admin).
    let audit = on_database(&db, &f.data(), async |store| {
        use sqlx::Row;
        let rows = sqlx::query(
            "SELECT a.action, a.target, u.username FROM audit_log a JOIN users u ON u.id = a.actor_id \
             WHERE a.action LIKE 'token.%' ORDER BY a.at",
        )
        .fetch_all(&store.pool)
        .await
        .unwrap();
        rows.iter()
            .map(|r| {
                (
                    r.get::<String, _>("action"),
                    r.get::<String, _>("target"),
                    r.get::<String, _>("username"),
                )
            })
            .collect::<Vec<_>>()
    });
    let count = |action: &str| audit.iter().filter(|a| a.0 == action).count();
    assert_eq!((count("token.create"), count("token.revoke")), (4, 2), "{audit:?}");
    assert!(
        audit.contains(&("token.revoke".into(), full_id.clone(), "root".into())),
        "{audit:?}"
    );
}

/// The dashboard's tokens page: create (the secret shown once, not kept by caches), list (never
/// the secret), revoke; forms need the login's CSRF token.
fn tokens_page_creates_lists_and_revokes(db: Db) {
    let (_dir, srv) = small_server(&db, USERS);
    let b = &srv.base;
    let tina = login(b, "tina");
    let Auth::Cookie { csrf, .. } = &tina else {
        unreachable!()
    };
    let Page { status, body: html, .. } = page(b, "/tokens", &tina, None);
    assert_eq!(status, 200, "{html}");
    assert!(
        html.contains(r#"href="/tokens""#) && html.contains(r#"id="create-token""#),
        "{html}"
    );
    assert!(html.contains("No tokens yet."), "{html}");

    let form = |csrf: &str, scope: &str, days: &str| {
        page(
            b,
            "/tokens",
            &tina,
            Some(&[
                ("csrf", csrf),
                ("label", "PC 3 <lab>"),
                ("scope", scope),
                ("days", days),
            ]),
        )
    };
    let Page { status, body: html, .. } = form("wrong", "full", "30");
    assert_eq!(status, 403, "{html}");
    for (scope, days, reason) in [
        ("root", "30", "unknown scope"),
        ("full", "500", "1–90 days"),
        ("full", "x", "whole number"),
    ] {
        let Page { status, body: html, .. } = form(csrf, scope, days);
        assert_eq!(status, 400, "{scope} {days}: {html}");
        assert!(html.contains(reason) && !html.contains("new-token"), "{html}");
    }
    let Page {
        status,
        cache_control: cache,
        body: html,
        ..
    } = form(csrf, "full", "30");
    assert_eq!((status, cache.as_str()), (200, "no-store"), "{html}");
    let secret = html
        .split(r#"<code id="new-token">"#)
        .nth(1)
        .and_then(|rest| rest.split('<').next())
        .unwrap_or_else(|| panic!("no token shown: {html}"))
        .to_string();
    assert_eq!(secret.len(), 64, "{secret}");
    assert!(html.contains("PC 3 &lt;lab&gt;"), "{html}");

    // The token works; the list (API and page) shows it without the secret.
    let bearer = Auth::Bearer(secret.clone());
    let (status, list, _) = call("GET", &format!("{b}/api/tokens"), Some(&bearer), None, false);
    assert_eq!(status, 200, "{list}");
    let row = &list["tokens"][0];
    assert_eq!(
        (row["scope"].as_str(), row["label"].as_str()),
        (Some("full"), Some("PC 3 <lab>"))
    );
    assert_lasts_days(row, 30);
    let token_id = row["id"].as_str().unwrap().to_string();
    let Page { body: html, .. } = page(b, "/tokens", &tina, None);
    assert!(!html.contains(&secret), "{html}");
    assert!(html.contains(&format!("…{}", &secret[60..])), "{html}");
    // Another trainee's page lists nothing of hers and cannot revoke it.
    let tom = login(b, "tom");
    let Auth::Cookie { csrf: tom_csrf, .. } = &tom else {
        unreachable!()
    };
    let Page { body: html, .. } = page(b, "/tokens", &tom, None);
    assert!(!html.contains(&token_id), "{html}");
    let revoke_path = format!("/tokens/{token_id}/revoke");
    assert_eq!(page(b, &revoke_path, &tom, Some(&[("csrf", tom_csrf)])).status, 404);
    assert_eq!(page(b, &revoke_path, &tina, Some(&[("csrf", "wrong")])).status, 403);
    assert_eq!(
        call("GET", &format!("{b}/api/tokens"), Some(&bearer), None, false).0,
        200
    );

    let Page { status, location, .. } = page(b, &revoke_path, &tina, Some(&[("csrf", csrf)]));
    assert_eq!((status, location.as_str()), (303, "/tokens"));
    assert_eq!(
        call("GET", &format!("{b}/api/tokens"), Some(&bearer), None, false).0,
        401
    );
    let Page { body: html, .. } = page(b, "/tokens", &tina, None);
    assert!(html.contains("revoked") && !html.contains(&revoke_path), "{html}");
}

/// (status, Set-Cookie, body) of a login with extra headers: JSON (`/api/login`) or the
/// dashboard's form (`/login`); redirects are not followed.
fn login_with(base: &str, form: bool, headers: &[(&str, &str)]) -> (u16, Option<String>, String) {
    let agent = ureq::AgentBuilder::new().redirects(0).build();
    let mut req = agent.post(&format!("{base}{}", if form { "/login" } else { "/api/login" }));
    for (k, v) in headers {
        req = req.set(k, v);
    }
    let res = if form {
        req.send_form(&[
            ("username", "tina"),
            ("password", "tina-password"),
            ("next", "/sessions"),
        ])
    } else {
        req.set("Content-Type", "application/json")
            .send_bytes(br#"{"username":"tina","password":"tina-password"}"#)
    };
    let resp = match res {
        Ok(r) => r,
        Err(ureq::Error::Status(_, r)) => r,
        Err(e) => panic!("login: {e}"),
    };
    let cookie = resp.header("Set-Cookie").map(str::to_string);
    (resp.status(), cookie, resp.into_string().unwrap())
}

/// Login CSRF without `Sec-Fetch-Site`: a login whose `Origin` (or, without one, `Referer`) is
/// another site is refused with 403 and sets no cookie, on the JSON API and the login form; this
/// server's own pages and clients that send neither still log in.
fn logins_from_other_origins_are_refused(db: Db) {
    let (_dir, srv) = small_server(&db, USERS);
    let b = srv.base.as_str();
    let other_port = format!(
        "http://127.0.0.1:{}",
        srv.base.rsplit(':').next().unwrap().parse::<u16>().unwrap() ^ 1
    );
    let other_sites: [(&str, &str); 5] = [
        ("Origin", "http://evil.example"),
        ("Origin", "null"),
        ("Origin", other_port.as_str()),
        ("Referer", "http://evil.example/innocent-page"),
        ("Referer", "https://evil.example/?back=http://127.0.0.1/"),
    ];
    for header in other_sites {
        for form in [false, true] {
            let (status, cookie, body) = login_with(b, form, &[header]);
            assert_eq!(status, 403, "{header:?} form={form}: {body}");
            assert_eq!(cookie, None, "{header:?} form={form}: a cookie was set");
            assert!(body.contains("other site") || body.contains("another site"), "{body}");
        }
    }
    let login_page = format!("{b}/login");
    for headers in [vec![("Origin", b)], vec![("Referer", login_page.as_str())], vec![]] {
        let (status, cookie, body) = login_with(b, false, &headers);
        assert_eq!(status, 200, "{headers:?}: {body}");
        assert!(cookie.is_some_and(|c| c.starts_with("stylet_session=")), "{headers:?}");
        let (status, cookie, body) = login_with(b, true, &headers);
        assert_eq!(status, 303, "{headers:?}: {body}");
        assert!(cookie.is_some_and(|c| c.starts_with("stylet_session=")), "{headers:?}");
    }
}

/// An account holds at most 20 active tokens: the rows one login can make are bounded; revoking
/// one makes room.
#[test]
fn an_account_holds_a_bounded_number_of_active_tokens() {
    let db = Db::Sqlite;
    let (_dir, server) = small_server(&db, USERS);
    let b = &server.base;
    let tina = login(b, "tina");
    let make = || {
        call(
            "POST",
            &format!("{b}/api/tokens"),
            Some(&tina),
            Some(br#"{"label":"desk"}"#),
            true,
        )
    };
    let mut first = None;
    for i in 0..20 {
        let (status, v, _) = make();
        assert_eq!(status, 201, "token {i}: {v}");
        first.get_or_insert(v["id"].as_str().unwrap().to_string());
    }
    let (status, v, _) = make();
    assert_eq!(status, 409, "{v}");
    assert!(error_of(&v).contains("revoke one first"), "{v}");
    let id = first.unwrap();
    let (status, v, _) = call(
        "POST",
        &format!("{b}/api/tokens/{id}/revoke"),
        Some(&tina),
        Some(b""),
        true,
    );
    assert_eq!(status, 200, "{v}");
    assert_eq!(make().0, 201);
}
