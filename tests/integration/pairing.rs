//! Pairing simulators with short codes (docs/integration.md "Pairing a simulator"), on SQLite and
//! PostgreSQL: a trainee's own simulator, a lab machine of a cohort on which trainees sign in in
//! turn, and what is refused — a used, expired or mistyped code, a code in the wrong place, a
//! trainee of another cohort, a revoked machine, a signed-out token, too many codes, too many
//! wrong guesses — each with what it says, and the audit trail.

use serde_json::{Value, json};

use crate::common::*;

fn post(base: &str, path: &str, auth: Option<&Auth>, body: &Value) -> (u16, Value) {
    let body = serde_json::to_vec(body).unwrap();
    let (status, json, _) = call("POST", &format!("{base}{path}"), auth, Some(&body), true);
    (status, json)
}

/// A new code of `who` for `purpose` (and `cohort`): its text.
fn code(base: &str, who: &Auth, purpose: &str, cohort: Option<&str>) -> String {
    let (status, json) = post(
        base,
        "/api/pairing/codes",
        Some(who),
        &json!({"purpose": purpose, "cohort": cohort}),
    );
    assert_eq!(status, 201, "{json}");
    let code = json["code"].as_str().unwrap().to_string();
    assert_eq!((code.len(), &code[5..6]), (11, "-"), "{code}");
    code
}

fn audited(db: &Db, f: &Fixture, action: &str) -> i64 {
    let action = action.to_string();
    on_database(db, &f.data(), async move |store| {
        sqlx::query_scalar::<_, i64>("SELECT COUNT(*) FROM audit_log WHERE action = $1")
            .bind(action)
            .fetch_one(&store.pool)
            .await
            .unwrap()
    })
}

on_both_databases!(a_simulator_and_a_lab_machine_pair_with_short_codes, "pairing");

fn a_simulator_and_a_lab_machine_pair_with_short_codes(db: Db) {
    let f = Fixture::new(STYLET);
    let srv = f.serve(&db, 1);
    let b = &srv.base;
    let tina = login(b, "tina");

    // A trainee's own simulator: the code, typed in lower case without its dash, gives an upload
    // token of the trainee, which uploads and is scored.
    let typed = code(b, &tina, "simulator", None).replace('-', "").to_lowercase();
    let (status, paired) = post(b, "/api/pair", None, &json!({"code": typed, "label": "tina's laptop"}));
    assert_eq!(status, 201, "{paired}");
    assert_eq!(
        (paired["kind"].as_str(), paired["username"].as_str()),
        (Some("simulator"), Some("tina"))
    );
    let sim = Auth::Bearer(paired["token"].as_str().unwrap().to_string());
    let (_, row) = upload_scored(b, &sim, &f.session("tina-ok"));
    assert_eq!(row["trainee"], "tina", "{row}");
    // It is an upload token: it may not read the account's tokens.
    assert_eq!(call("GET", &format!("{b}/api/tokens"), Some(&sim), None, false).0, 403);
    // Used once.
    let (status, again) = post(b, "/api/pair", None, &json!({"code": typed, "label": "x"}));
    assert_eq!(status, 404, "{again}");
    assert!(again["error"].as_str().unwrap().contains("expired"), "{again}");
    // Codes are made from a login only, not with a token.
    let (status, json) = post(b, "/api/pairing/codes", Some(&sim), &json!({"purpose": "simulator"}));
    assert_eq!(status, 403, "{json}");

    // An expired code is refused like a wrong one.
    let late = code(b, &tina, "simulator", None);
    on_database(&db, &f.data(), async |store| {
        sqlx::query("UPDATE pairing_codes SET expires_at = '2000-01-01T00:00:00.000000Z' WHERE used_at IS NULL")
            .execute(&store.pool)
            .await
            .unwrap();
    });
    assert_eq!(post(b, "/api/pair", None, &json!({"code": late, "label": "x"})).0, 404);

    // A lab machine: an instructor of c1 pairs it; a trainee or another cohort's cannot.
    let ivan = login(b, "ivan");
    let (status, json) = post(
        b,
        "/api/pairing/codes",
        Some(&ivan),
        &json!({"purpose": "lab", "cohort": "c2"}),
    );
    assert_eq!(status, 403, "{json}");
    let (status, json) = post(
        b,
        "/api/pairing/codes",
        Some(&tina),
        &json!({"purpose": "lab", "cohort": "c1"}),
    );
    assert_eq!(status, 403, "{json}");
    let lab_code = code(b, &ivan, "lab", Some("c1"));
    let (status, lab) = post(
        b,
        "/api/pair",
        None,
        &json!({"code": lab_code, "label": "skills lab 2, bay 1"}),
    );
    assert_eq!(status, 201, "{lab}");
    assert_eq!(
        (lab["kind"].as_str(), lab["cohort"].as_str()),
        (Some("lab"), Some("c1")),
        "{lab}"
    );
    let machine = Auth::Bearer(lab["lab_token"].as_str().unwrap().to_string());
    // A lab token is no API token.
    assert_eq!(
        call("POST", &format!("{b}/api/sessions"), Some(&machine), Some(b"x"), false).0,
        401
    );

    // Trainees sign in in turn with their own codes: tina (c1) is signed in; tom (c2) is not,
    // and his code stays usable.
    let sign_in = code(b, &tina, "sign_in", None);
    let (status, signed) = post(b, "/api/lab/sign-in", Some(&machine), &json!({"code": sign_in}));
    assert_eq!(status, 201, "{signed}");
    assert_eq!(signed["username"], "tina");
    let at_lab = Auth::Bearer(signed["token"].as_str().unwrap().to_string());
    let (_, row) = upload_scored(b, &at_lab, &f.session("tina-lung"));
    assert_eq!(row["trainee"], "tina", "{row}");
    let tom = login(b, "tom");
    let toms = code(b, &tom, "sign_in", None);
    let (status, json) = post(b, "/api/lab/sign-in", Some(&machine), &json!({"code": toms}));
    assert_eq!(status, 403, "{json}");
    assert!(json["error"].as_str().unwrap().contains("another cohort"), "{json}");
    // Codes in the wrong place: a sign-in code at /api/pair, a simulator code at a lab machine.
    let (status, json) = post(b, "/api/pair", None, &json!({"code": toms, "label": "x"}));
    assert_eq!(status, 409, "{json}");
    assert!(json["error"].as_str().unwrap().contains("lab machine"), "{json}");
    let own = code(b, &tina, "simulator", None);
    assert_eq!(
        post(b, "/api/lab/sign-in", Some(&machine), &json!({"code": own})).0,
        409
    );
    // Only trainees make sign-in codes.
    assert_eq!(
        post(b, "/api/pairing/codes", Some(&ivan), &json!({"purpose": "sign_in"})).0,
        403
    );

    // Signing out revokes the trainee's token at the machine.
    let (status, json, _) = call(
        "POST",
        &format!("{b}/api/tokens/current/revoke"),
        Some(&at_lab),
        None,
        false,
    );
    assert_eq!(status, 200, "{json}");
    let (status, json, _) = call("GET", &format!("{b}/api/sessions"), Some(&at_lab), None, false);
    assert_eq!(status, 401, "{json}");

    // The instructor sees the machine and revokes it; it signs nobody in after.
    let (status, list, _) = call("GET", &format!("{b}/api/lab/machines"), Some(&ivan), None, false);
    assert_eq!(status, 200, "{list}");
    assert_eq!(list["machines"].as_array().unwrap().len(), 1, "{list}");
    assert_eq!(list["machines"][0]["label"], "skills lab 2, bay 1");
    assert_eq!(
        call("GET", &format!("{b}/api/lab/machines"), Some(&tina), None, false).1["machines"],
        json!([])
    );
    let id = list["machines"][0]["id"].as_str().unwrap();
    // Nobody but the cohort's instructors and admins may revoke it, nor learn that it exists.
    for who in [&tina, &login(b, "cora")] {
        let (status, json) = post(b, &format!("/api/lab/machines/{id}/revoke"), Some(who), &json!({}));
        assert_eq!(status, 404, "{json}");
    }
    let (status, json) = post(b, &format!("/api/lab/machines/{id}/revoke"), Some(&ivan), &json!({}));
    assert_eq!((status, json["active"].as_bool()), (200, Some(false)), "{json}");
    let later = code(b, &tina, "sign_in", None);
    let (status, json) = post(b, "/api/lab/sign-in", Some(&machine), &json!({"code": later}));
    assert_eq!(status, 401, "{json}");

    // At most five unused codes an account.
    let cora = login(b, "cora");
    for _ in 0..5 {
        code(b, &cora, "simulator", None);
    }
    let (status, json) = post(b, "/api/pairing/codes", Some(&cora), &json!({"purpose": "simulator"}));
    assert_eq!(status, 409, "{json}");

    // Audited: each code made, each pairing, the sign-in, the sign-out and the revocation.
    assert_eq!(audited(&db, &f, "pairing.code"), 12);
    assert_eq!(audited(&db, &f, "pairing.simulator"), 1);
    assert_eq!(audited(&db, &f, "lab.pair"), 1);
    assert_eq!(audited(&db, &f, "lab.sign_in"), 1);
    assert_eq!(audited(&db, &f, "lab.revoke"), 1);
    assert!(audited(&db, &f, "token.revoke") >= 1);
}

on_both_databases!(wrong_codes_are_limited_per_address, "pairing_guess");

/// Twenty wrong codes from one address in the window, then 429 for the next — a good code too —
/// with Retry-After; a malformed code counts as wrong.
fn wrong_codes_are_limited_per_address(db: Db) {
    let f = Fixture::new(STYLET);
    let srv = f.serve(&db, 1);
    let b = &srv.base;
    let tina = login(b, "tina");
    let good = code(b, &tina, "simulator", None);
    for i in 0..20 {
        let guess = if i % 2 == 0 { "00000-00000" } else { "not a code" };
        let (status, json) = post(b, "/api/pair", None, &json!({"code": guess, "label": "x"}));
        assert_eq!(status, 404, "guess {i}: {json}");
    }
    let body = serde_json::to_vec(&json!({"code": good, "label": "x"})).unwrap();
    let resp = ureq::post(&format!("{b}/api/pair"))
        .set("Content-Type", "application/json")
        .send_bytes(&body);
    let Err(ureq::Error::Status(429, resp)) = resp else {
        panic!("a good code after 20 wrong ones from this address: {resp:?}")
    };
    let wait: u64 = resp.header("Retry-After").unwrap().parse().unwrap();
    assert!((1..=301).contains(&wait), "{wait}");
    assert!(resp.into_string().unwrap().contains("too many wrong pairing codes"));
}
