//! `stylet serve` against hostile clients and failing storage (docs/security.md): each test names
//! a defence that must hold. Memory is measured as the server process's peak RSS (VmHWM).

use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::time::{Duration, Instant};

use crate::common::*;
use stylet_recorder::format::{self, TickRecord};
use stylet_recorder::{SessionEnd, SessionHeader, SessionWriter, WriterOptions};

/// Resets a process's peak RSS to its current RSS (Linux: `5` to /proc/PID/clear_refs), so that
/// the next peak measures what happens from now on, not the atlas loading at start.
fn reset_peak(pid: u32) {
    std::fs::write(format!("/proc/{pid}/clear_refs"), "5").unwrap();
}

/// The test fixture's phantom, sessions and accounts, served on SQLite with `extra` flags.
fn serve(extra: &[&str]) -> (Fixture, Server) {
    let f = Fixture::new(STYLET);
    f.users(&Db::Sqlite);
    let server = Server::start(STYLET, &f.data(), &Db::Sqlite, &f.atlases(), extra);
    (f, server)
}

fn header_of(file: &Path) -> SessionHeader {
    stylet_recorder::reader::read_header(&std::fs::read(file).unwrap()).unwrap()
}

fn still_tick(tick: u64) -> TickRecord {
    TickRecord {
        tick,
        position_mm: [150.0, 0.0, 0.0],
        orientation: [1.0, 0.0, 0.0, 0.0],
        buttons: 0,
        force_n: [0.0; 3],
        torque_nmm: [0.0; 3],
        tip_label: 1,
        inserted_mm: 0.0,
        second_hand: None,
    }
}

/// A session file written by the recorder's own writer: `header` and ticks `first..first+n`.
fn written(dir: &Path, name: &str, header: &SessionHeader, first: u64, n: u64) -> Vec<u8> {
    let path = dir.join(format!("{name}.mcap"));
    let w = SessionWriter::create(&path, header, WriterOptions::default()).unwrap();
    for t in first..first + n {
        w.record_raw_blocking(still_tick(t)).unwrap();
    }
    w.finish().unwrap();
    std::fs::read(&path).unwrap()
}

/// A hand-made session file of a few hundred KB that declares `ticks` ticks in highly
/// compressible chunks of 50 000-tick blocks (each chunk about 6 MB uncompressed), written with
/// the same MCAP library and message encoding as the recorder's writer.
fn tick_bomb_file(header: &SessionHeader, ticks: u64) -> Vec<u8> {
    const BLOCK: u64 = 50_000;
    let block: Vec<TickRecord> = (0..BLOCK).map(still_tick).collect();
    let mut encoded = stylet_recorder::writer::encode_block(&block);
    let mut w = mcap::WriteOptions::new()
        .profile(format::PROFILE)
        .compression(Some(mcap::Compression::Zstd))
        .chunk_size(Some(1))
        .create(std::io::Cursor::new(Vec::new()))
        .unwrap();
    w.write_metadata(&mcap::records::Metadata {
        name: format::META_HEADER.into(),
        metadata: header.to_metadata(),
    })
    .unwrap();
    let schema = w
        .add_schema(
            "stylet.ticks",
            format::SCHEMA_ENCODING,
            format::json_schema(format::TOPIC_TICKS).as_bytes(),
        )
        .unwrap();
    let channel = w
        .add_channel(
            schema,
            format::TOPIC_TICKS,
            format::MESSAGE_ENCODING,
            &Default::default(),
        )
        .unwrap();
    for i in 0..ticks / BLOCK {
        encoded.first_tick = i * BLOCK;
        let data = format::to_cbor(&encoded);
        let time = i * BLOCK * 1_000_000;
        w.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id: channel,
                sequence: i as u32,
                log_time: time,
                publish_time: time,
            },
            &data,
        )
        .unwrap();
    }
    let end = SessionEnd {
        ticks,
        dropped_ticks: 0,
        complete: true,
        reason: String::new(),
    };
    w.write_metadata(&mcap::records::Metadata {
        name: format::META_END.into(),
        metadata: end.to_metadata(),
    })
    .unwrap();
    w.finish().unwrap();
    w.into_inner().into_inner()
}

/// A small file declaring 20 M ticks (2.5 GB decoded) is refused — by an account that may not
/// upload it before anything is decoded, by its trainee because it exceeds the longest session
/// accepted — and the server's peak memory grows by less than 100 MB either way.
#[test]
fn a_tick_bomb_is_refused_with_bounded_memory() {
    let (f, server) = serve(&["--workers", "1"]);
    let b = &server.base;
    let bomb = tick_bomb_file(&header_of(&f.session("tina-ok")), 20_000_000);
    assert!(bomb.len() < 2 << 20, "the bomb is {} bytes", bomb.len());
    let pid = server.child.id();
    let (cora, tina) = (login(b, "cora"), login(b, "tina"));
    reset_peak(pid);
    let (_, rss0) = memory_mib(pid);
    let (status, body) = raw_post(b, "/api/sessions", Some(&cora), &bomb);
    assert_eq!(status, 403, "{body}");
    let (peak1, rss1) = memory_mib(pid);
    reset_peak(pid);
    let (status, body) = raw_post(b, "/api/sessions", Some(&tina), &bomb);
    assert_eq!(status, 422, "{body}");
    let e = body["error"].as_str().unwrap();
    assert!(e.contains("more than 1800000 ticks") && e.contains("30 minutes"), "{e}");
    let (peak2, _) = memory_mib(pid);
    println!(
        "server RSS {rss0:.0} MiB; peak during the refused upload (curriculum) {peak1:.0} MiB, during the rejected one (trainee) {peak2:.0} MiB"
    );
    assert!(peak1 - rss0 < 100.0, "{rss0} -> {peak1} MiB");
    assert!(peak2 - rss1 < 100.0, "{rss1} -> {peak2} MiB");
    assert_eq!(files_under(&f.data().join("sessions")), 0);
    let (status, _, _) = call("GET", &format!("{b}/healthz"), None, None, false);
    assert_eq!(status, 200);
}

/// Header fields are bounded at the format level and checked against what the server knows;
/// sessions with no ticks or not starting at tick 0 are refused; each with a 422 and the reason,
/// nothing stored.
#[test]
fn uploads_with_bad_headers_or_ticks_are_refused_with_the_reason() {
    let (f, server) = serve(&["--workers", "1"]);
    let b = &server.base;
    let tina = login(b, "tina");
    let good = header_of(&f.session("tina-ok"));
    let dir = f.dir.path();
    let with = |change: &dyn Fn(&mut SessionHeader)| {
        let mut h = good.clone();
        change(&mut h);
        h
    };
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        (
            "a 1000-character scenario",
            written(dir, "long", &with(&|h| h.scenario = "s".repeat(1000)), 0, 100),
            "'scenario' is longer than 64 characters",
        ),
        (
            "a scenario the atlas does not declare",
            written(
                dir,
                "unknown-scenario",
                &with(&|h| h.scenario = "free-style".into()),
                0,
                100,
            ),
            "unknown scenario 'free-style'",
        ),
        (
            "an unknown difficulty",
            written(
                dir,
                "difficulty",
                &with(&|h| h.difficulty = "impossible".into()),
                0,
                100,
            ),
            "unknown difficulty 'impossible'",
        ),
        (
            "an unknown device",
            written(dir, "device", &with(&|h| h.device = "joystick".into()), 0, 100),
            "unknown device 'joystick'",
        ),
        (
            "physics version 99",
            written(dir, "physics", &with(&|h| h.physics_version = 99), 0, 100),
            "physics version 99",
        ),
        (
            "a deformation on a 129³ lattice solved every tick (a scoring worker's hour)",
            written(
                dir,
                "deformation",
                &with(&|h| {
                    h.deformation = stylet_physics::DeformSettings {
                        cells: 128,
                        every_ticks: 1,
                        latency_ticks: 1,
                        ..stylet_physics::DeformSettings::on()
                    }
                }),
                0,
                100,
            ),
            "the session's tissue deformation (128 cells, a solve every 1 ticks) costs",
        ),
        (
            "a contrast agent stepped 64 times every tick",
            written(
                dir,
                "contrast",
                &with(&|h| {
                    h.contrast = stylet_physics::ContrastSettings {
                        update_every_ticks: 1,
                        steps_per_update: 64,
                        ..Default::default()
                    }
                }),
                0,
                100,
            ),
            "the session's contrast agent (64 diffusion steps every 1 ticks) costs",
        ),
        (
            "a tick rate of 100 kHz (a hundred times the ticks allowed per minute)",
            written(dir, "rate", &with(&|h| h.tick_rate_hz = 100_000), 0, 100),
            "the session ticks at 100000 Hz; this server accepts 1000 Hz",
        ),
        ("no ticks", written(dir, "empty", &good, 0, 0), "no ticks"),
        (
            "a first tick of 2^64 - 2",
            written(dir, "late", &good, u64::MAX - 1, 1),
            "the first tick is 18446744073709551614, not 0",
        ),
    ];
    for (what, bytes, reason) in cases {
        let (status, body) = raw_post(b, "/api/sessions", Some(&tina), &bytes);
        assert_eq!(status, 422, "{what}: {body}");
        let e = body["error"].as_str().unwrap();
        assert!(e.contains(reason), "{what}: {e}");
    }
    assert_eq!(files_under(&f.data().join("sessions")), 0);
    let (_, list, _) = call("GET", &format!("{b}/api/sessions"), Some(&tina), None, false);
    assert_eq!(list["total"], 0, "{list}");
}

/// An admin deletes a session: rows, file and derived data go, the deletion is audited; nobody else
/// may.
#[test]
fn an_admin_deletes_a_session_and_everything_about_it() {
    let (f, server) = serve(&["--workers", "1"]);
    let b = &server.base;
    let (root, tina, ivan) = (login(b, "root"), login(b, "tina"), login(b, "ivan"));
    let bytes = std::fs::read(f.session("tina-lung")).unwrap();
    let (status, up) = raw_post(b, "/api/sessions", Some(&tina), &bytes);
    assert_eq!(status, 201, "{up}");
    let id = up["id"].as_str().unwrap().to_string();
    assert_eq!(wait_scored(b, &tina, &id)["status"], "scored");
    let comment = br#"{"body": "too high: the lung"}"#;
    let (status, _, _) = call(
        "POST",
        &format!("{b}/api/sessions/{id}/comments"),
        Some(&ivan),
        Some(comment),
        true,
    );
    assert_eq!(status, 201);
    assert!(files_under(&f.data().join("traces")) >= 1);
    // A frame of the replay player, kept on disk.
    let (status, png) = get_bytes(&format!("{b}/sessions/{id}/frame?view=axial&tick=100"), &root);
    assert_eq!(status, 200, "{}", String::from_utf8_lossy(&png));
    assert!(files_under(&f.data().join("frames")) >= 1);
    for (who, auth) in [("tina", &tina), ("ivan", &ivan)] {
        let (status, body, _) = call("DELETE", &format!("{b}/api/sessions/{id}"), Some(auth), None, false);
        assert_eq!(status, 403, "{who}: {body}");
    }
    // Without the login's CSRF token: refused too.
    let Auth::Cookie { token, .. } = &root else {
        unreachable!()
    };
    let no_csrf = Auth::Cookie {
        token: token.clone(),
        csrf: "wrong".into(),
    };
    let (status, _, _) = call("DELETE", &format!("{b}/api/sessions/{id}"), Some(&no_csrf), None, false);
    assert_eq!(status, 403);
    let (status, body, _) = call("DELETE", &format!("{b}/api/sessions/{id}"), Some(&root), None, false);
    assert_eq!(status, 200, "{body}");
    let (status, _, _) = call("GET", &format!("{b}/api/sessions/{id}"), Some(&root), None, false);
    assert_eq!(status, 404);
    for kind in ["sessions", "traces", "figures", "frames"] {
        assert_eq!(files_under(&f.data().join(kind)), 0, "{kind}");
    }
    let (status, _, _) = call("DELETE", &format!("{b}/api/sessions/{id}"), Some(&root), None, false);
    assert_eq!(status, 404);
    // Audited, and the same file can be uploaded again afterwards.
    let audit = tokio::runtime::Runtime::new().unwrap().block_on(async {
        sqlx::any::install_default_drivers();
        let pool = sqlx::AnyPool::connect(&Db::Sqlite.url(&f.data())).await.unwrap();
        let row: (String, String) =
            sqlx::query_as("SELECT action, detail FROM audit_log WHERE target = $1 AND action = 'session.delete'")
                .bind(id.clone())
                .fetch_one(&pool)
                .await
                .unwrap();
        row
    });
    assert_eq!(audit.0, "session.delete");
    assert!(audit.1.contains("tina") && audit.1.contains("lung-hit"), "{}", audit.1);
    let (status, again) = raw_post(b, "/api/sessions", Some(&tina), &bytes);
    assert_eq!(status, 201, "{again}");
    // The dashboard's form does the same, only with its box ticked and the login's CSRF token.
    let again = again["id"].as_str().unwrap().to_string();
    let Auth::Cookie { token, csrf } = &root else {
        unreachable!()
    };
    let agent = ureq::AgentBuilder::new().redirects(0).build();
    let form = |fields: &[(&str, &str)]| match agent
        .post(&format!("{b}/sessions/{again}/delete"))
        .set("Cookie", &format!("stylet_session={token}"))
        .send_form(fields)
    {
        Ok(r) => (r.status(), r.header("Location").unwrap_or_default().to_string()),
        Err(ureq::Error::Status(s, r)) => (s, r.header("Location").unwrap_or_default().to_string()),
        Err(e) => panic!("{e}"),
    };
    assert_eq!(form(&[("csrf", csrf), ("confirm", "")]).0, 400, "unticked");
    assert_eq!(form(&[("csrf", "wrong"), ("confirm", "yes")]).0, 403, "no CSRF token");
    assert_eq!(
        form(&[("csrf", csrf), ("confirm", "yes")]),
        (303, "/sessions".to_string())
    );
    let (status, _, _) = call("GET", &format!("{b}/api/sessions/{again}"), Some(&root), None, false);
    assert_eq!(status, 404);
}

/// Names that do not exist get the same answer as names the caller may not see.
#[test]
fn names_that_do_not_exist_answer_like_names_one_may_not_see() {
    let (f, server) = serve(&["--workers", "1"]);
    let b = &server.base;
    let (tina, ivan) = (login(b, "tina"), login(b, "ivan"));
    let get = |auth: &Auth, path: &str| call("GET", &format!("{b}{path}"), Some(auth), None, false);
    // Filters: an account that exists but is not visible, and one that does not exist.
    for (existing, missing) in [
        ("/api/sessions?trainee=root", "/api/sessions?trainee=nosuchuser"),
        ("/api/sessions?cohort=c2", "/api/sessions?cohort=nosuchcohort"),
        (
            "/api/export/sessions.csv?trainee=tom",
            "/api/export/sessions.csv?trainee=nosuchuser",
        ),
    ] {
        let who = if existing.contains("export") { &ivan } else { &tina };
        let (s1, v1, _) = get(who, existing);
        let (s2, v2, _) = get(who, missing);
        assert_eq!((s1, s2), (200, 200), "{existing}: {v1} / {missing}: {v2}");
        assert_eq!(v1, v2, "{existing} vs {missing}");
    }
    // Cohort summaries: not yours and does not exist are both 404.
    let (s1, _, _) = get(&ivan, "/api/cohorts/c2/summary");
    let (s2, _, _) = get(&ivan, "/api/cohorts/nosuchcohort/summary");
    assert_eq!((s1, s2), (404, 404));
    // Uploads naming another trainee: the same 403 whether or not the account exists.
    let good = header_of(&f.session("tina-ok"));
    let dir = f.dir.path();
    for (uploader, auth) in [("tina", &tina), ("ivan", &ivan)] {
        let mut answers = Vec::new();
        for trainee in ["tom", "nosuchuser"] {
            let mut h = good.clone();
            h.trainee = trainee.into();
            let bytes = written(dir, &format!("{uploader}-{trainee}"), &h, 0, 10);
            let (status, body) = raw_post(b, "/api/sessions", Some(auth), &bytes);
            let e = body["error"].as_str().unwrap().replace(trainee, "X");
            answers.push((status, e));
        }
        assert_eq!(answers[0], answers[1], "{uploader}");
        assert_eq!(answers[0].0, 403, "{uploader}: {:?}", answers[0]);
    }
}

/// Failed logins with long, distinct usernames are refused before anything is kept, and the
/// server's memory stays flat.
#[test]
fn failed_logins_with_long_usernames_keep_memory_flat() {
    let (_f, server) = serve(&["--workers", "1"]);
    let b = &server.base;
    let pid = server.child.id();
    reset_peak(pid);
    let (_, rss0) = memory_mib(pid);
    // 600 distinct 60 KB usernames: 36 MB if each were remembered.
    for i in 0..600 {
        let name = format!("{i:06}{}", "x".repeat(60_000));
        let body = serde_json::to_vec(&serde_json::json!({ "username": name, "password": "wrong password" })).unwrap();
        let (status, v, _) = call("POST", &format!("{b}/api/login"), None, Some(&body), true);
        assert_eq!(status, 401, "{v}");
    }
    let (_, rss1) = memory_mib(pid);
    println!("server RSS {rss0:.1} -> {rss1:.1} MiB after 600 failed logins with 60 KB usernames");
    assert!(rss1 - rss0 < 16.0, "{rss0} -> {rss1} MiB");
    // A login body over the limit is refused before it is read, as JSON.
    let big = serde_json::to_vec(&serde_json::json!({ "username": "x".repeat(3 << 20), "password": "p" })).unwrap();
    let (status, v) = raw_post(b, "/api/login", None, &big);
    assert_eq!(status, 413, "{v}");
    assert!(v["error"].is_string(), "{v}");
    // The real account still logs in.
    login(b, "tina");
}

/// Password checks run on their own threads with a bounded queue: a flood of wrong passwords beyond
/// it gets 503 with Retry-After, and other routes keep answering meanwhile. Prints /healthz latency
/// during the flood (no threshold: machines differ).
#[test]
fn a_login_flood_is_queued_or_refused_and_other_routes_keep_answering() {
    let (_f, server) = serve(&["--workers", "1", "--password-threads", "1", "--password-queue", "4"]);
    let b = server.base.clone();
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let flooders: Vec<_> = (0..32)
        .map(|i| {
            let (b, stop) = (b.clone(), stop.clone());
            std::thread::spawn(move || {
                let mut seen = std::collections::BTreeMap::<u16, u32>::new();
                let body = format!(r#"{{"username":"user{i}","password":"wrong password"}}"#);
                while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                    let resp = ureq::post(&format!("{b}/api/login"))
                        .set("Content-Type", "application/json")
                        .send_bytes(body.as_bytes());
                    let (status, retry) = match resp {
                        Ok(r) => (r.status(), r.header("Retry-After").map(str::to_string)),
                        Err(ureq::Error::Status(s, r)) => (s, r.header("Retry-After").map(str::to_string)),
                        Err(e) => panic!("{e}"),
                    };
                    if status == 503 {
                        assert_eq!(retry.as_deref(), Some("1"));
                    }
                    *seen.entry(status).or_default() += 1;
                }
                seen
            })
        })
        .collect();
    std::thread::sleep(Duration::from_millis(500));
    let mut healthz_ms = Vec::new();
    for _ in 0..100 {
        let t0 = Instant::now();
        let (status, _, _) = call("GET", &format!("{b}/healthz"), None, None, false);
        assert_eq!(status, 200);
        healthz_ms.push(t0.elapsed().as_secs_f64() * 1e3);
        std::thread::sleep(Duration::from_millis(20));
    }
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let mut totals = std::collections::BTreeMap::<u16, u32>::new();
    for t in flooders {
        for (k, v) in t.join().unwrap() {
            *totals.entry(k).or_default() += v;
        }
    }
    healthz_ms.sort_by(f64::total_cmp);
    println!(
        "32-way wrong-password flood: answers {totals:?}; /healthz p50 {:.1} ms, p99 {:.1} ms",
        healthz_ms[50], healthz_ms[98]
    );
    assert!(totals.get(&503).copied().unwrap_or(0) > 0, "{totals:?}");
    assert!(totals.get(&401).copied().unwrap_or(0) > 0, "{totals:?}");
    // 429 once an account name has failed five times.
    assert_eq!(
        totals.keys().filter(|k| ![401, 429, 503].contains(*k)).count(),
        0,
        "{totals:?}"
    );
}

/// Slow clients are cut off: headers not finished in time, bodies sent too slowly, connections left
/// idle; and at most --max-connections are served at once.
#[test]
fn slow_and_idle_connections_are_closed() {
    let (_f, server) = serve(&[
        "--workers",
        "1",
        "--header-timeout-s",
        "2",
        "--request-timeout-s",
        "2",
        "--min-upload-rate",
        "1000000",
        // Thirteen slow uploads from one account: each must be cut off by the deadline.
        "--max-uploads-per-account",
        "64",
        "--max-connections",
        "64",
    ]);
    let b = &server.base;
    let addr = b.strip_prefix("http://").unwrap().to_string();
    let tina = login(b, "tina");
    let Auth::Cookie { token, csrf } = &tina else {
        unreachable!()
    };
    let started = Instant::now();
    let mut sockets: Vec<(&str, TcpStream)> = Vec::new();
    for i in 0..50 {
        let mut s = TcpStream::connect(&addr).unwrap();
        let kind = match i % 4 {
            0 => {
                // Slow headers: a request line, then nothing more.
                s.write_all(b"GET /healthz HTTP/1.1\r\nHost: x\r\n").unwrap();
                "slow headers"
            }
            1 => {
                // A slow upload body: 10 MB announced, a few bytes sent.
                let head = format!(
                    "POST /api/sessions HTTP/1.1\r\nHost: x\r\nCookie: stylet_session={token}\r\nX-CSRF-Token: {csrf}\r\n\
                     Content-Type: application/octet-stream\r\nContent-Length: 10000000\r\n\r\n"
                );
                s.write_all(head.as_bytes()).unwrap();
                s.write_all(&[0x89, b'M', b'C']).unwrap();
                "slow body"
            }
            2 => {
                // A login announcing a huge body: no upload allowance, the request timeout holds.
                s.write_all(b"POST /api/login HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nContent-Length: 60000\r\n\r\n{")
                    .unwrap();
                "slow login body"
            }
            _ => "idle",
        };
        s.set_read_timeout(Some(Duration::from_secs(30))).unwrap();
        sockets.push((kind, s));
    }
    // Each socket read on a thread of its own, so that each one's closing time is its own.
    let readers: Vec<_> = sockets
        .into_iter()
        .map(|(kind, mut s)| {
            std::thread::spawn(move || {
                let mut buf = Vec::new();
                // The server closes it (EOF, possibly after an answer) before our 30 s read timeout.
                let r = s.read_to_end(&mut buf).map_err(|e| e.kind());
                (kind, r, started.elapsed(), String::from_utf8_lossy(&buf).to_string())
            })
        })
        .collect();
    for reader in readers {
        let (kind, r, waited, text) = reader.join().unwrap();
        assert!(
            r.is_ok() || r == Err(std::io::ErrorKind::ConnectionReset),
            "{kind}: {r:?} after {waited:?}"
        );
        assert!(waited < Duration::from_secs(20), "{kind}: open for {waited:?}");
        if kind != "slow body" {
            // 2 s timeouts, no allowance for a body's size outside uploads (those get 12 s here).
            assert!(waited < Duration::from_secs(8), "{kind}: open for {waited:?}");
        }
        if kind == "slow body" {
            assert!(text.is_empty() || text.starts_with("HTTP/1.1 408"), "{kind}: {text}");
        }
    }
    let (status, _, _) = call("GET", &format!("{b}/healthz"), None, None, false);
    assert_eq!(status, 200);
}

/// Past --max-connections, further connections wait (in the kernel's backlog) until a served one is
/// closed.
#[test]
fn connections_past_the_cap_wait_for_a_free_slot() {
    let (_f, server) = serve(&["--workers", "1", "--header-timeout-s", "3", "--max-connections", "4"]);
    let addr = server.base.strip_prefix("http://").unwrap().to_string();
    let idle: Vec<TcpStream> = (0..4).map(|_| TcpStream::connect(&addr).unwrap()).collect();
    std::thread::sleep(Duration::from_millis(300));
    let t0 = Instant::now();
    let mut s = TcpStream::connect(&addr).unwrap();
    s.write_all(b"GET /healthz HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
        .unwrap();
    let mut answer = String::new();
    s.read_to_string(&mut answer).unwrap();
    let waited = t0.elapsed();
    assert!(answer.starts_with("HTTP/1.1 200"), "{answer}");
    // Served only once the header timeout had closed the four idle connections.
    assert!(
        waited >= Duration::from_secs(2),
        "answered after {waited:?}: the cap did not hold"
    );
    drop(idle);
}

/// Errors the framework writes (bad query, body over the limit, unknown route) are JSON like every
/// API error, and every answer carries the security headers.
#[test]
fn framework_errors_are_json_and_every_answer_has_security_headers() {
    let (_f, server) = serve(&["--workers", "1"]);
    let b = &server.base;
    let tina = login(b, "tina");
    for (path, status) in [
        ("/api/sessions?page=abc", 400),
        ("/api/no-such-route", 404),
        ("/api/sessions?from=yesterday", 400),
    ] {
        let (got, v, _) = call("GET", &format!("{b}{path}"), Some(&tina), None, false);
        assert_eq!(got, status, "{path}: {v}");
        assert!(v["error"].as_str().is_some_and(|e| !e.is_empty()), "{path}: {v}");
    }
    let (got, v, _) = call(
        "POST",
        &format!("{b}/api/sessions/x/comments"),
        Some(&tina),
        Some(b"{not json"),
        true,
    );
    assert_eq!(got, 400, "{v}");
    for path in ["/login", "/healthz", "/api/sessions", "/"] {
        let resp = match ureq::get(&format!("{b}{path}")).call() {
            Ok(r) => r,
            Err(ureq::Error::Status(_, r)) => r,
            Err(e) => panic!("{e}"),
        };
        let csp = resp.header("Content-Security-Policy").unwrap_or_default().to_string();
        assert!(
            csp.contains("frame-ancestors 'none'") && csp.contains("default-src 'self'"),
            "{path}: {csp}"
        );
        assert_eq!(resp.header("X-Frame-Options"), Some("DENY"), "{path}");
        assert_eq!(resp.header("X-Content-Type-Options"), Some("nosniff"), "{path}");
    }
}

/// Runs `stylet serve` as the unprivileged user `nobody` (so that file permissions bind it: the
/// tests run as root, whom a read-only mode does not stop).
fn start_unprivileged(data: &Path, atlases: &Path) -> Server {
    let mut setpriv = std::process::Command::new("setpriv");
    setpriv
        .args(["--reuid=65534", "--regid=65534", "--clear-groups", "--"])
        .arg(STYLET.path())
        .args(["serve", "--bind", "127.0.0.1:0", "--workers", "1"])
        .args(["--data-dir", s(data), "--atlases", s(atlases)]);
    Server::spawn(setpriv, data)
}

fn chmod_r(dir: &Path, writable: bool) {
    let mode = if writable { "u+w" } else { "a-w" };
    let out = std::process::Command::new("chmod")
        .args(["-R", mode, s(dir)])
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
}

/// After the data directory was read-only for a while, the service recovers by itself: /healthz
/// says 503 during the window and 200 after it, every login and comment works again, and a session
/// whose score could not be stored during the window is scored, not left `scoring` for ever.
#[test]
fn the_service_recovers_after_its_data_directory_was_read_only() {
    let f = Fixture::new(STYLET);
    let db = Db::Sqlite;
    f.users(&db);
    let data = f.data();
    // The server runs as nobody: it needs to reach its data and atlases.
    let chown = std::process::Command::new("chown")
        .args(["-R", "65534:65534", s(&data)])
        .status()
        .unwrap();
    assert!(chown.success());
    let chmod = std::process::Command::new("chmod")
        .args(["a+rx", s(f.dir.path())])
        .status()
        .unwrap();
    assert!(chmod.success());
    let server = start_unprivileged(&data, &f.atlases());
    let b = &server.base;
    let (tina, ivan) = (login(b, "tina"), login(b, "ivan"));
    let upload = |name: &str| {
        let (status, v) = raw_post(
            b,
            "/api/sessions",
            Some(&tina),
            &std::fs::read(f.session(name)).unwrap(),
        );
        assert_eq!(status, 201, "{v}");
        v["id"].as_str().unwrap().to_string()
    };
    let first = upload("tina-ok");
    assert_eq!(wait_scored(b, &tina, &first)["status"], "scored");
    // The window: a session is being scored when the directory turns read-only.
    let during = upload("tina-lung");
    chmod_r(&data, false);
    let t0 = Instant::now();
    loop {
        let (status, v, _) = call("GET", &format!("{b}/healthz"), None, None, false);
        if status == 503 {
            assert!(v["error"].as_str().unwrap().contains("cannot be written"), "{v}");
            break;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "healthz still {status} during the read-only window"
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    // Traffic during the window: parallel logins and comments open new connections, which SQLite
    // opens read-only. Whatever they answer, the server must not die, and it answers before the
    // request deadline (no 408): a request waits for a connection at most Store::ACQUIRE_TIMEOUT.
    let during_window: Vec<_> = (0..16)
        .map(|i| {
            let b = b.clone();
            std::thread::spawn(move || {
                // Names of no account: the real ones must not be locked by these failures.
                let body = format!(r#"{{"username":"someone{i}","password":"x-password"}}"#);
                call("POST", &format!("{b}/api/login"), None, Some(body.as_bytes()), true).0
            })
        })
        .collect();
    for t in during_window {
        let status = t.join().unwrap();
        assert!([401, 429, 500, 503].contains(&status), "{status}");
    }
    let comment = br#"{"body": "written during the window"}"#;
    let (status, _, _) = call(
        "POST",
        &format!("{b}/api/sessions/{first}/comments"),
        Some(&ivan),
        Some(comment),
        true,
    );
    assert_ne!(status, 0);
    std::thread::sleep(Duration::from_secs(2));
    chmod_r(&data, true);
    // After the window: healthy within seconds, and everything works, every time.
    let t1 = Instant::now();
    loop {
        let (status, _, _) = call("GET", &format!("{b}/healthz"), None, None, false);
        if status == 200 {
            break;
        }
        assert!(
            t1.elapsed() < Duration::from_secs(30),
            "healthz still {status} after the window"
        );
        std::thread::sleep(Duration::from_millis(200));
    }
    let mut failures = Vec::new();
    for i in 0..40 {
        let user = if i % 2 == 0 { "tina" } else { "ivan" };
        let body = format!(r#"{{"username":"{user}","password":"{user}-password"}}"#);
        let (status, v, _) = call("POST", &format!("{b}/api/login"), None, Some(body.as_bytes()), true);
        if status != 200 {
            failures.push(format!("login {i}: {status} {v}"));
        }
        let comment = format!(r#"{{"body": "comment {i} after the window"}}"#);
        let (status, v, _) = call(
            "POST",
            &format!("{b}/api/sessions/{first}/comments"),
            Some(&ivan),
            Some(comment.as_bytes()),
            true,
        );
        if status != 201 {
            failures.push(format!("comment {i}: {status} {v}"));
        }
    }
    if !failures.is_empty() {
        let log = std::fs::read_to_string(data.join("server.log")).unwrap_or_default();
        let tail: Vec<&str> = log
            .lines()
            .rev()
            .take(60)
            .collect::<Vec<_>>()
            .into_iter()
            .rev()
            .collect();
        panic!("{failures:#?}\nserver log, last lines:\n{}", tail.join("\n"));
    }
    let scored = wait_scored(b, &tina, &during);
    assert_eq!(scored["status"], "scored", "{scored}");
    let after = upload("tina-two");
    assert_eq!(wait_scored(b, &tina, &after)["status"], "scored");
}

// ---------------------------------------------------------------------------------------------
// One account, or a stranger, trying to exhaust memory and connections: each test names a bound
// that must hold.
// ---------------------------------------------------------------------------------------------

use crate::common::attack::*;

/// Another account logs in and uploads while an attack runs.
fn tom_logs_in_and_uploads(b: &str, f: &Fixture) -> u16 {
    // Within 10 s each, or the attack has starved the server: status 0.
    let agent = ureq::AgentBuilder::new().timeout(Duration::from_secs(10)).build();
    let login = agent
        .post(&format!("{b}/api/login"))
        .set("Content-Type", "application/json")
        .send_bytes(br#"{"username":"tom","password":"tom-password"}"#);
    let Ok(answer) = login else {
        return 0;
    };
    let cookie = answer.header("Set-Cookie").unwrap_or_default().to_string();
    let token = cookie
        .strip_prefix("stylet_session=")
        .and_then(|c| c.split(';').next())
        .unwrap_or_default()
        .to_string();
    let body: serde_json::Value = answer
        .into_string()
        .ok()
        .and_then(|t| serde_json::from_str(&t).ok())
        .unwrap_or_default();
    let csrf = body["csrf_token"].as_str().unwrap_or_default();
    let upload = agent
        .post(&format!("{b}/api/sessions"))
        .set("Cookie", &format!("stylet_session={token}"))
        .set("X-CSRF-Token", csrf)
        .set("Content-Type", "application/octet-stream")
        .send_bytes(&std::fs::read(f.session("tom-ok")).unwrap());
    match upload {
        Ok(r) => r.status(),
        Err(ureq::Error::Status(s, _)) => s,
        Err(_) => 0,
    }
}

/// Uploads are authorised from their first bytes and streamed to disk, and one account may send
/// only a few at once. 100 concurrent 64 MiB uploads of junk behind a valid header from one
/// trainee: the first few are received (to disk) and refused (422), the rest get 429 with
/// Retry-After before their body is read; with the caps raised so that 32 are received at once, the
/// server's memory still grows by a fraction of one upload. Another trainee logs in and uploads
/// meanwhile. (Without these bounds 4–7 GB grow and stay.)
#[test]
fn concurrent_junk_uploads_are_capped_and_streamed_with_bounded_memory() {
    more_files();
    let f = Fixture::new(STYLET);
    let file = std::fs::read(f.session("tina-ok")).unwrap();
    let head = header_prefix(&file);
    const SIZE: u64 = 64 << 20;
    for (label, extra, uploads) in [
        ("default caps", &["--workers", "1"][..], 100),
        (
            "caps raised to 64",
            &[
                "--workers",
                "1",
                "--max-uploads",
                "64",
                "--max-uploads-per-account",
                "64",
            ][..],
            32,
        ),
    ] {
        let data = f.dir.path().join(format!("data-{}", label.replace(' ', "-")));
        add_user(&data, &Db::Sqlite, "tina", "trainee", Some("c1"));
        add_user(&data, &Db::Sqlite, "tom", "trainee", Some("c2"));
        let server = Server::start(STYLET, &data, &Db::Sqlite, &f.atlases(), extra);
        let b = server.base.clone();
        let addr = b.strip_prefix("http://").unwrap().to_string();
        let pid = server.child.id();
        let tina = login(&b, "tina");
        std::thread::sleep(Duration::from_millis(300));
        reset_peak(pid);
        let (_, rss0) = memory_mib(pid);
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let probe = probe_healthz(addr.clone(), stop.clone());
        let tina = std::sync::Arc::new(tina);
        let started = Instant::now();
        let answers: Vec<(u16, String)> = std::thread::scope(|scope| {
            let senders: Vec<_> = (0..uploads)
                .map(|_| {
                    let (addr, tina, head) = (&addr, tina.clone(), &head);
                    scope.spawn(move || junk_upload(addr, &tina, head, SIZE))
                })
                .collect();
            std::thread::sleep(Duration::from_millis(500));
            let other = tom_logs_in_and_uploads(&b, &f);
            assert_eq!(other, 201, "{label}: another trainee's upload during the attack");
            senders.into_iter().map(|h| h.join().unwrap()).collect()
        });
        let took = started.elapsed();
        stop.store(true, std::sync::atomic::Ordering::Relaxed);
        let healthz = probe.join().unwrap();
        let (peak, _) = memory_mib(pid);
        std::thread::sleep(Duration::from_secs(5));
        let (_, settled) = memory_mib(pid);
        let mut counts = std::collections::BTreeMap::<u16, usize>::new();
        for (status, text) in &answers {
            *counts.entry(*status).or_default() += 1;
            assert!([422, 429].contains(status), "{label}: {text}");
            if *status == 429 {
                assert!(text.to_lowercase().contains("retry-after: 5"), "{label}: {text}");
            }
        }
        println!(
            "{label}: {uploads} concurrent 64 MiB junk uploads from one trainee in {:.1} s: answers {counts:?}; \
             server RSS {rss0:.0} MiB, peak {peak:.0} MiB (+{:.0}), 5 s later {settled:.0} MiB; \
             /healthz p50 {:.1} ms, p99 {:.1} ms, max {:.1} ms ({} probes)",
            took.as_secs_f64(),
            peak - rss0,
            healthz[healthz.len() / 2],
            p99(&healthz),
            healthz[healthz.len() - 1],
            healthz.len()
        );
        assert!(counts.get(&422).copied().unwrap_or(0) >= 1, "{label}: {counts:?}");
        if uploads > 64 {
            assert!(counts.get(&429).copied().unwrap_or(0) >= 1, "{label}: {counts:?}");
        }
        // Received to disk one chunk at a time: a fraction of one upload's size, however many.
        assert!(peak - rss0 < 64.0, "{label}: {rss0:.0} -> {peak:.0} MiB");
        assert!(
            settled - rss0 < 64.0,
            "{label}: {rss0:.0} -> {settled:.0} MiB after 5 s"
        );
        if uploads > 64 {
            // The default caps keep the server answering (with the caps raised, the figures are
            // reported above).
            assert!(p99(&healthz) < 1000.0, "{label}: /healthz p99 {:.0} ms", p99(&healthz));
        }
        // Nothing of the refused uploads is left; tom's session is the one file.
        assert_eq!(
            files_under(&data.join("sessions")),
            1,
            "{:?}",
            walk(&data.join("sessions"))
        );
    }
}

/// One trainee opening 600 slow uploads (64 B every 2 s) holds at most its two upload slots, and
/// those only until the minimum rate fails (10 s), not for half an hour; then 600 anonymous
/// connections sending their headers a byte a second hold no serving capacity. `/healthz` answers
/// within a second throughout and another trainee logs in and uploads. (Without the minimum rate
/// the 512-connection cap fills and `/healthz` takes 9.7 s or never answers.)
#[test]
fn slow_uploads_and_slow_headers_cannot_starve_the_server() {
    more_files();
    let (f, server) = serve(&["--workers", "1"]);
    let b = server.base.clone();
    let addr = b.strip_prefix("http://").unwrap().to_string();
    let tina = login(&b, "tina");
    let head = upload_head(&addr, &tina, 64 << 20);
    let first = header_prefix(&std::fs::read(f.session("tina-ok")).unwrap());
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let probe = probe_healthz(addr.clone(), stop.clone());

    // 600 slow uploads from one account.
    let started = Instant::now();
    let mut slow: Vec<(TcpStream, Vec<u8>, Option<Duration>)> = (0..600)
        .map(|_| {
            let mut s = TcpStream::connect(&addr).unwrap();
            s.write_all(head.as_bytes()).unwrap();
            let _ = s.write_all(&first[..64]);
            s.set_nonblocking(true).unwrap();
            (s, Vec::new(), None)
        })
        .collect();
    let mut sent_at = Instant::now();
    let mut offset = 64;
    let mut tom_upload = None;
    while started.elapsed() < Duration::from_secs(25) && slow.iter().any(|c| c.2.is_none()) {
        if sent_at.elapsed() >= Duration::from_secs(2) {
            for (s, _, done) in slow.iter_mut().filter(|c| c.2.is_none()) {
                let chunk = first.get(offset..offset + 64).unwrap_or(&[0u8; 64]);
                let _ = s.write_all(chunk);
                let _ = done;
            }
            offset += 64;
            sent_at = Instant::now();
        }
        for (s, answer, done) in slow.iter_mut().filter(|c| c.2.is_none()) {
            let mut buf = [0u8; 4096];
            match s.read(&mut buf) {
                Ok(0) => *done = Some(started.elapsed()),
                Ok(n) => answer.extend_from_slice(&buf[..n]),
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {}
                Err(_) => *done = Some(started.elapsed()),
            }
        }
        if tom_upload.is_none() && started.elapsed() > Duration::from_secs(3) {
            tom_upload = Some(tom_logs_in_and_uploads(&b, &f));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    // Past the account's two upload slots an upload is refused at once with 429 (its requests in
    // flight, counted per credential before the login is looked up, or its uploads) — never 503:
    // the burst cannot fill the server's `--max-requests`. A refusal holds nothing: every one
    // comes before the slots' holders are cut off.
    let mut counts = std::collections::BTreeMap::<u16, usize>::new();
    let mut slowest_408 = Duration::ZERO;
    let mut first_408 = Duration::MAX;
    let mut last_refusal = Duration::ZERO;
    for (_, answer, done) in &slow {
        let (status, text) = status_of(answer);
        *counts.entry(status).or_default() += 1;
        assert!(
            [408, 429].contains(&status),
            "a slow upload answered {status} (0: nothing): {text}"
        );
        let done = done.unwrap_or_else(|| panic!("a slow upload was still open after 25 s: {text}"));
        if status == 408 {
            slowest_408 = slowest_408.max(done);
            first_408 = first_408.min(done);
        } else {
            last_refusal = last_refusal.max(done);
        }
    }
    assert!(
        last_refusal < first_408,
        "a refusal came at {last_refusal:?}, after a slot's holder was cut off at {first_408:?}: {counts:?}"
    );
    assert_eq!(
        tom_upload,
        Some(201),
        "another trainee's upload during the slow uploads"
    );
    assert_eq!(counts.get(&408).copied(), Some(2), "{counts:?}");
    // Cut off by the minimum rate over 10 s, not after the upload's whole allowance (34 min).
    assert!(slowest_408 < Duration::from_secs(20), "{slowest_408:?}");
    drop(slow);

    // 600 anonymous connections sending their headers a byte a second.
    let t_loris = Instant::now();
    let mut loris: Vec<TcpStream> = (0..600)
        .map(|_| {
            let mut s = TcpStream::connect(&addr).unwrap();
            s.write_all(b"G").unwrap();
            s
        })
        .collect();
    let mut sent = 1;
    let request = b"GET /healthz HTTP/1.1\r\nHost: x\r\n";
    let mut tom_during_loris = None;
    while t_loris.elapsed() < Duration::from_secs(8) {
        std::thread::sleep(Duration::from_secs(1));
        for s in &mut loris {
            let _ = s.write_all(&request[sent % request.len()..sent % request.len() + 1]);
        }
        sent += 1;
        if tom_during_loris.is_none() {
            tom_during_loris = Some(tom_logs_in_and_uploads(&b, &f));
        }
    }
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let healthz = probe.join().unwrap();
    drop(loris);
    println!(
        "600 slow uploads from one trainee: answers {counts:?}, the slots' holders cut off after {:.1} s; \
         then 600 slow-header connections for 8 s; /healthz throughout: p50 {:.1} ms, p99 {:.1} ms, max {:.1} ms ({} probes)",
        slowest_408.as_secs_f64(),
        healthz[healthz.len() / 2],
        p99(&healthz),
        healthz[healthz.len() - 1],
        healthz.len()
    );
    // tom's second upload is the same file: 200, already stored.
    assert_eq!(tom_during_loris, Some(200), "another trainee during the slow headers");
    assert!(p99(&healthz) < 1000.0, "/healthz p99 {:.0} ms", p99(&healthz));
}

/// A filesystem of `mib` MiB (tmpfs), unmounted when dropped: a disk that can really fill up.
struct SmallDisk {
    path: std::path::PathBuf,
    _dir: tempfile::TempDir,
}

impl SmallDisk {
    fn new(mib: u32) -> SmallDisk {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("disk");
        std::fs::create_dir(&path).unwrap();
        let out = std::process::Command::new("mount")
            .args(["-t", "tmpfs", "-o", &format!("size={mib}m"), "tmpfs", s(&path)])
            .output()
            .expect("mount (util-linux) runs");
        assert!(
            out.status.success(),
            "cannot mount a tmpfs (the tests run as root): {}",
            String::from_utf8_lossy(&out.stderr)
        );
        SmallDisk { path, _dir: dir }
    }

    /// Fills what is left of the disk with a file; returns its path.
    fn fill(&self) -> std::path::PathBuf {
        let filler = self.path.join("filler");
        let mut f = std::fs::File::create(&filler).unwrap();
        let block = vec![1u8; 64 << 10];
        while f.write_all(&block).is_ok() {}
        let mut rest = [1u8; 1];
        while f.write_all(&rest).is_ok() {
            rest[0] = 1;
        }
        filler
    }
}

impl Drop for SmallDisk {
    fn drop(&mut self) {
        let _ = std::process::Command::new("umount")
            .args(["-l", s(&self.path)])
            .status();
    }
}

/// A log that cannot be written (its disk is full: here `/dev/full`, where every write fails with
/// ENOSPC) loses log lines, never answers: every request is still served. (The logger's own
/// fallback, a message to stderr, would panic on the same failure and drop the connection.)
#[test]
fn a_log_on_a_full_disk_loses_lines_not_answers() {
    let f = Fixture::new(STYLET);
    f.users(&Db::Sqlite);
    let data = f.data();
    let full = std::fs::OpenOptions::new().write(true).open("/dev/full").unwrap();
    let command = Server::command(STYLET, "127.0.0.1:0", &data, &Db::Sqlite, &f.atlases(), &[]);
    let server = Server::spawn_logging_to(command, full, Path::new("/dev/full"));
    let b = &server.base;
    for _ in 0..3 {
        let tina = login(b, "tina");
        let (status, json, _) = call("GET", &format!("{b}/api/sessions"), Some(&tina), None, false);
        assert_eq!(status, 200, "{json}");
    }
}

/// A full disk: an upload is refused with 503 and Retry-After (not 500) before its body is read,
/// and an admin can still delete a session to make room: the files go first, so the database has
/// room for its journal. Once there is room again, uploads work.
#[test]
fn a_full_disk_answers_503_and_an_admin_can_still_delete() {
    let f = Fixture::new(STYLET);
    let disk = SmallDisk::new(48);
    let data = disk.path.join("data");
    let db = Db::Sqlite;
    add_user(&data, &db, "root", "admin", None);
    add_user(&data, &db, "tina", "trainee", Some("c1"));
    let server = Server::start(
        STYLET,
        &data,
        &db,
        &f.atlases(),
        &["--workers", "1", "--min-free-disk-bytes", "1000000"],
    );
    let b = &server.base;
    let (root, tina) = (login(b, "root"), login(b, "tina"));
    let upload = |name: &str| {
        raw_post(
            b,
            "/api/sessions",
            Some(&tina),
            &std::fs::read(f.session(name)).unwrap(),
        )
    };
    let (status, first) = upload("tina-ok");
    assert_eq!(status, 201, "{first}");
    let id = first["id"].as_str().unwrap().to_string();
    assert_eq!(wait_scored(b, &tina, &id)["status"], "scored");
    let filler = disk.fill();
    let before = stylet_service::disk::free_bytes(&data).unwrap();
    // Full: refused before the body is read, and told to try again.
    let file = std::fs::read(f.session("tina-lung")).unwrap();
    let addr = b.strip_prefix("http://").unwrap();
    let mut s = TcpStream::connect(addr).unwrap();
    s.write_all(upload_head(addr, &tina, file.len() as u64).as_bytes())
        .unwrap();
    let _ = s.write_all(&file);
    let mut answer = Vec::new();
    let _ = s.read_to_end(&mut answer);
    let (status, text) = status_of(&answer);
    assert_eq!(status, 503, "{text}");
    assert!(
        text.to_lowercase().contains("retry-after: 1") && text.contains("disk"),
        "{text}"
    );
    assert_eq!(files_under(&data.join("sessions").join(".incoming")), 0);
    // The admin deletes the session on the full disk (on a connection of its own: a pooled one
    // may have been closed by the server meanwhile).
    let Auth::Cookie { token, csrf } = &root else {
        unreachable!()
    };
    let deleted = ureq::AgentBuilder::new()
        .timeout(Duration::from_secs(30))
        .build()
        .delete(&format!("{b}/api/sessions/{id}"))
        .set("Cookie", &format!("stylet_session={token}"))
        .set("X-CSRF-Token", csrf)
        .call();
    let log = || std::fs::read_to_string(data.join("server.log")).unwrap_or_default();
    let (status, body) = match deleted {
        Ok(r) => (r.status(), r.into_string().unwrap_or_default()),
        Err(ureq::Error::Status(s, r)) => (s, r.into_string().unwrap_or_default()),
        Err(e) => panic!("the deletion got no answer ({e}); server log:\n{}", log()),
    };
    println!("full disk ({before} bytes free): upload 503; admin deletion {status} {body}");
    assert_eq!(status, 200, "{body}\nserver log:\n{}", log());
    let (status, _, _) = call("GET", &format!("{b}/api/sessions/{id}"), Some(&root), None, false);
    assert_eq!(status, 404);
    // Room again: uploads work.
    std::fs::remove_file(filler).unwrap();
    let (status, again) = upload("tina-lung");
    assert_eq!(status, 201, "{again}");
    drop(server);
}

/// An instructor cannot upload for a trainee of their cohort whose account is disabled (nor can an
/// admin); enabled again, the upload works.
#[test]
fn nobody_uploads_for_a_disabled_trainee() {
    let (f, server) = serve(&["--workers", "1"]);
    let b = &server.base;
    let (root, ivan) = (login(b, "root"), login(b, "ivan"));
    let bytes = std::fs::read(f.session("tina-ok")).unwrap();
    let (status, body, _) = call("POST", &format!("{b}/api/users/tina/disable"), Some(&root), None, false);
    assert_eq!(status, 200, "{body}");
    for (who, auth) in [("ivan", &ivan), ("root", &root)] {
        let (status, body) = raw_post(b, "/api/sessions", Some(auth), &bytes);
        assert_eq!(status, 403, "{who}: {body}");
        assert!(body["error"].as_str().unwrap().contains("disabled"), "{who}: {body}");
    }
    assert_eq!(files_under(&f.data().join("sessions")), 0);
    let (status, _, _) = call("POST", &format!("{b}/api/users/tina/enable"), Some(&root), None, false);
    assert_eq!(status, 200);
    let (status, body) = raw_post(b, "/api/sessions", Some(&ivan), &bytes);
    assert_eq!(status, 201, "{body}");
}

/// An upload-scoped token cannot log its account out (nor can a full one: tokens do not log in);
/// the account's login keeps working.
#[test]
fn api_tokens_cannot_log_the_account_out() {
    let (_f, server) = serve(&["--workers", "1"]);
    let b = &server.base;
    let tina = login(b, "tina");
    for scope in ["upload", "full"] {
        let body = format!(r#"{{"label":"lab pc","scope":"{scope}"}}"#);
        let (status, made, _) = call(
            "POST",
            &format!("{b}/api/tokens"),
            Some(&tina),
            Some(body.as_bytes()),
            true,
        );
        assert_eq!(status, 201, "{made}");
        let token = Auth::Bearer(made["token"].as_str().unwrap().to_string());
        let (status, body, _) = call("POST", &format!("{b}/api/logout"), Some(&token), None, false);
        assert_eq!(status, 403, "{scope}: {body}");
        // Sent with the account's cookie too: still refused, and the login stays.
        let Auth::Cookie { token: cookie, .. } = &tina else {
            unreachable!()
        };
        let resp = ureq::post(&format!("{b}/api/logout"))
            .set("Authorization", &format!("Bearer {}", made["token"].as_str().unwrap()))
            .set("Cookie", &format!("stylet_session={cookie}"))
            .call();
        assert!(matches!(resp, Err(ureq::Error::Status(403, _))), "{scope}");
        let (status, _, _) = call("GET", &format!("{b}/api/sessions"), Some(&tina), None, false);
        assert_eq!(status, 200, "{scope}: the login was ended");
    }
}

/// Loaded atlases are held in a cache bounded by bytes. Four atlases of 3.3 M voxels (copies of the
/// phantom under other names, so four contents): a server whose cache may hold all of them keeps
/// them resident; one whose cache holds one keeps about one, yet scores a session on an atlas it
/// let go of (loaded again from disk). (Without the bound every atlas stays resident, 1.2 GB each
/// at 512² × 256.)
#[test]
fn loaded_atlases_are_held_in_a_cache_bounded_by_bytes() {
    let f = Fixture::new(STYLET);
    f.users(&Db::Sqlite);
    let phantom = f.atlases().join("phantom");
    for k in 2..=4 {
        let copy = f.atlases().join(format!("phantom-{k}"));
        std::fs::create_dir_all(&copy).unwrap();
        for name in ["ct.nii.gz", "labels.nii.gz"] {
            std::fs::copy(phantom.join(name), copy.join(name)).unwrap();
        }
        let manifest = std::fs::read_to_string(phantom.join("atlas.toml")).unwrap();
        std::fs::write(
            copy.join("atlas.toml"),
            manifest.replacen("description = \"", &format!("description = \"Copy {k}. "), 1),
        )
        .unwrap();
    }
    let mut rss = Vec::new();
    for (label, budget) in [("all four", "8000000000"), ("one", "1")] {
        let data = f.dir.path().join(format!("data-{budget}"));
        add_user(&data, &Db::Sqlite, "tina", "trainee", Some("c1"));
        let server = Server::start(
            STYLET,
            &data,
            &Db::Sqlite,
            &f.atlases(),
            &["--workers", "1", "--atlas-cache-bytes", budget],
        );
        std::thread::sleep(Duration::from_secs(1));
        let (_, resident) = memory_mib(server.child.id());
        println!("4 atlases of 3.3 M voxels, a cache for {label}: server RSS {resident:.0} MiB");
        rss.push(resident);
        if budget == "1" {
            // The phantom was loaded first and let go of; a session on it is still scored.
            let b = &server.base;
            let tina = login(b, "tina");
            let (status, up) = raw_post(
                b,
                "/api/sessions",
                Some(&tina),
                &std::fs::read(f.session("tina-ok")).unwrap(),
            );
            assert_eq!(status, 201, "{up}");
            let scored = wait_scored(b, &tina, up["id"].as_str().unwrap());
            assert_eq!(scored["status"], "scored", "{scored}");
        }
    }
    // One phantom and its scorer hold about 3.3 M voxels × 18 bytes = 57 MiB.
    assert!(
        rss[0] - rss[1] > 100.0,
        "RSS with room for four {:.0} MiB, for one {:.0} MiB",
        rss[0],
        rss[1]
    );
}

/// SIGTERM: the server stops accepting connections, says "not ready" on its admin port, answers
/// the request in flight (a login whose body was half sent when the signal came), gives back its
/// scoring jobs' leases and exits 0.
#[test]
fn sigterm_finishes_the_request_in_flight_and_stops() {
    let (f, mut server) = serve(&["--admin-bind", "127.0.0.1:0"]);
    let admin = server.admin.clone().expect("the admin port");
    let readyz = || match ureq::get(&format!("{admin}/readyz")).call() {
        Ok(r) => (r.status(), r.into_string().unwrap()),
        Err(ureq::Error::Status(code, r)) => (code, r.into_string().unwrap()),
        Err(e) => panic!("{admin}/readyz: {e}"),
    };
    assert_eq!(readyz().0, 200);
    let addr = server.base.strip_prefix("http://").unwrap().to_string();
    let body = r#"{"username":"tina","password":"not her password"}"#;
    let mut s = TcpStream::connect(&addr).unwrap();
    write!(
        s,
        "POST /api/login HTTP/1.1\r\nHost: {addr}\r\nContent-Type: application/json\r\nContent-Length: {}\r\n\r\n{}",
        body.len(),
        &body[..10]
    )
    .unwrap();
    std::thread::sleep(Duration::from_millis(300));
    let term = std::process::Command::new("kill")
        .args(["-TERM", &server.child.id().to_string()])
        .status()
        .unwrap();
    assert!(term.success());
    // No new connections once it stops accepting.
    let t0 = Instant::now();
    while TcpStream::connect(&addr).is_ok() {
        assert!(t0.elapsed() < Duration::from_secs(10), "still accepting connections");
        std::thread::sleep(Duration::from_millis(50));
    }
    // While it finishes, the admin port tells the load balancer to send nothing more.
    let (code, text) = readyz();
    assert_eq!(code, 503, "{text}");
    assert!(text.contains("stopping"), "{text}");
    s.write_all(&body.as_bytes()[10..]).unwrap();
    let mut answer = String::new();
    s.read_to_string(&mut answer).unwrap();
    assert!(answer.starts_with("HTTP/1.1 401"), "{answer}");
    let t0 = Instant::now();
    let status = loop {
        if let Some(status) = server.child.try_wait().unwrap() {
            break status;
        }
        assert!(t0.elapsed() < Duration::from_secs(30), "still running after SIGTERM");
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(status.success(), "{status:?}");
    let log = std::fs::read_to_string(f.data().join("server.log")).unwrap();
    assert!(
        log.contains("no new connections") && log.contains("stopped") && log.contains("released"),
        "{log}"
    );
}
