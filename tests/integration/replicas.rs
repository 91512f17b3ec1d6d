//! Several `stylet serve` replicas on one database (docs/operations.md "Several replicas"): the
//! limits that protect accounts hold across replicas and across restarts, because their state
//! lives in the database, not in a process.

use std::io::Write;
use std::net::TcpStream;
use std::time::{Duration, Instant};

use crate::common::attack::{header_prefix, junk_upload, upload_head};
use crate::common::*;

/// Replica `name` of the fixture's service on `db`, with a data directory of its own.
fn replica(f: &Fixture, db: &Db, name: &str, extra: &[&str]) -> Server {
    let data = f.dir.path().join(format!("data-{name}"));
    let mut args = vec!["--workers", "1"];
    args.extend_from_slice(extra);
    Server::start(STYLET, &data, db, &f.atlases(), &args)
}

fn login_status(base: &str, username: &str, password: &str) -> u16 {
    let body = serde_json::json!({ "username": username, "password": password }).to_string();
    call("POST", &format!("{base}/api/login"), None, Some(body.as_bytes()), true).0
}

#[test]
fn failed_logins_count_across_replicas_and_restarts() {
    let f = Fixture::new(STYLET);
    let db = Db::postgres("loginreplicas");
    f.users(&db);
    let a = replica(&f, &db, "a", &[]);
    let b = replica(&f, &db, "b", &[]);
    // Three wrong guesses at one replica, two at the other: the account's five.
    for base in [&a.base, &a.base, &a.base, &b.base, &b.base] {
        assert_eq!(login_status(base, "cora", "guess-guess"), 401);
    }
    assert_eq!(login_status(&a.base, "cora", "cora-password"), 429);
    assert_eq!(login_status(&b.base, "cora", "cora-password"), 429);
    // Another account is not held up.
    assert_eq!(login_status(&b.base, "tina", "tina-password"), 200);
    // A restarted replica forgets nothing.
    drop(a);
    let a = replica(&f, &db, "a", &[]);
    assert_eq!(login_status(&a.base, "cora", "cora-password"), 429);
    // Guesses sent at once to both replicas get five tries between them, the rest 429.
    let start = std::sync::Barrier::new(12);
    let statuses: Vec<u16> = std::thread::scope(|scope| {
        let tasks: Vec<_> = (0..12)
            .map(|i| {
                let (start, base) = (&start, if i % 2 == 0 { &a.base } else { &b.base });
                scope.spawn(move || {
                    start.wait();
                    login_status(base, "tom", &format!("guess-{i:04}"))
                })
            })
            .collect();
        tasks.into_iter().map(|t| t.join().unwrap()).collect()
    });
    assert_eq!(statuses.iter().filter(|&&s| s == 401).count(), 5, "{statuses:?}");
    assert_eq!(statuses.iter().filter(|&&s| s == 429).count(), 7, "{statuses:?}");
}

/// An upload of `tina`'s session held open at `base`: its request head and the session's header
/// sent, the rest not (so the server holds an upload slot for it until the socket closes).
fn held_upload(base: &str, auth: &Auth, head: &[u8]) -> TcpStream {
    let addr = base.strip_prefix("http://").unwrap();
    let mut s = TcpStream::connect(addr).unwrap();
    s.write_all(upload_head(addr, auth, 10 << 20).as_bytes()).unwrap();
    s.write_all(head).unwrap();
    s
}

/// Upload slots held in the database, by any replica.
fn held_slots(f: &Fixture, db: &Db) -> i64 {
    on_database(db, &f.data(), async |store| {
        sqlx::query_scalar("SELECT COUNT(*) FROM upload_slots")
            .fetch_one(&store.pool)
            .await
            .unwrap()
    })
}

#[test]
fn an_accounts_upload_cap_holds_across_replicas() {
    let f = Fixture::new(STYLET);
    let db = Db::postgres("uploadreplicas");
    f.users(&db);
    // No minimum rate, so that the held uploads stay held.
    let slow = ["--min-upload-rate", "0"];
    let a = replica(&f, &db, "a", &slow);
    let b = replica(&f, &db, "b", &slow);
    let file = std::fs::read(f.session("tina-ok")).unwrap();
    let head = header_prefix(&file);
    let (tina_a, tina_b) = (login(&a.base, "tina"), login(&b.base, "tina"));
    // One upload held at each replica: the account's two (the default cap).
    let first = held_upload(&a.base, &tina_a, &head);
    let _second = held_upload(&b.base, &tina_b, &head);
    // Each replica takes its slot before reading the body: wait until both are held (a third
    // upload racing them would take one of the two itself).
    let t0 = Instant::now();
    while held_slots(&f, &db) < 2 {
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "the held uploads did not take their slots"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    // A third, at either replica, is refused before its body is read.
    let (status, text) = junk_upload(b.base.strip_prefix("http://").unwrap(), &tina_b, &head, 1 << 20);
    assert_eq!(status, 429, "{text}");
    assert!(text.contains("2 uploads in progress"), "{text}");
    let (status, text) = junk_upload(a.base.strip_prefix("http://").unwrap(), &tina_a, &head, 1 << 20);
    assert_eq!(status, 429, "{text}");
    // Another trainee uploads meanwhile.
    let tom = login(&a.base, "tom");
    upload(&a.base, &tom, &f.session("tom-ok"));
    // The upload held at replica a ends (its client goes away): replica b takes the slot.
    drop(first);
    let t0 = Instant::now();
    loop {
        let (status, json) = raw_post(&b.base, "/api/sessions", Some(&tina_b), &file);
        if status == 201 {
            break;
        }
        assert_eq!(status, 429, "{json}");
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "the slot of the ended upload was not given back"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
}
