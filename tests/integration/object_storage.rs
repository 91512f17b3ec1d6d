//! Session files and review traces in S3-compatible object storage (`stylet serve --storage
//! s3://bucket/prefix`), against a real S3 server (s3s-fs, installed by scripts/test): replicas
//! with data directories of their own share the files through the store; an upload is in the
//! store before its row commits, so a replica killed between the two leaves no row pointing at a
//! missing object; player frames drawn at one replica are served by the others from the store;
//! `/readyz` says when the store does not answer.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::process::Command;
use std::time::{Duration, Instant};

use crate::common::attack::{status_of, upload_head};
use crate::common::*;

const BUCKET: &str = "stylet";
const STORAGE: &str = "s3://stylet/site-a";

/// Replica `name` of the fixture's service on `db` and the object store `s3`, with a data
/// directory of its own.
fn replica(f: &Fixture, db: &Db, s3: &S3Server, name: &str) -> Server {
    let data = f.dir.path().join(format!("data-{name}"));
    let mut command = Server::command(
        STYLET,
        "127.0.0.1:0",
        &data,
        db,
        &f.atlases(),
        &["--workers", "1", "--storage", STORAGE, "--admin-bind", "127.0.0.1:0"],
    );
    s3.configure(&mut command);
    Server::spawn(command, &data)
}

/// The status and body of a GET on the admin port (not in the API's OpenAPI document).
fn admin_get(url: &str) -> (u16, String) {
    match ureq::get(url).call() {
        Ok(r) => (r.status(), r.into_string().unwrap()),
        Err(ureq::Error::Status(code, r)) => (code, r.into_string().unwrap()),
        Err(e) => panic!("{url}: {e}"),
    }
}

fn session_key(sha: &str) -> String {
    format!("site-a/sessions/{}/{sha}.mcap", &sha[..2])
}

#[test]
fn replicas_share_session_files_and_traces_through_the_object_store() {
    let f = Fixture::new(STYLET);
    let db = Db::postgres("objectstore");
    let mut s3 = S3Server::start(BUCKET);
    f.users(&db);
    let a = replica(&f, &db, &s3, "a");
    let b = replica(&f, &db, &s3, "b");
    let tina = login(&a.base, "tina");
    let file = std::fs::read(f.session("tina-ok")).unwrap();
    let (id, _) = upload_scored(&a.base, &tina, &f.session("tina-ok"));
    let sha = psql(&db, &format!("SELECT file_sha256 FROM sessions WHERE id = '{id}'"));

    // The file is in the store, byte for byte; so is the trace of its scoring replay.
    let stored = std::fs::read(s3.bucket_dir(BUCKET).join(session_key(&sha))).unwrap();
    assert_eq!(stored, file);
    let traces = s3.keys(BUCKET, "site-a/traces/");
    assert_eq!(traces, vec![format!("site-a/traces/{}/{sha}.json.zst", &sha[..2])]);

    // Replica b has no copy of it, fetches it from the store and serves the same bytes.
    let b_copy = f
        .dir
        .path()
        .join("data-b")
        .join(format!("sessions/{}/{sha}.mcap", &sha[..2]));
    assert!(!b_copy.exists());
    let tina_b = login(&b.base, "tina");
    let (status, bytes) = get_bytes(&format!("{}/api/sessions/{id}/file", b.base), &tina_b);
    assert_eq!(status, 200);
    assert_eq!(bytes, file);
    assert!(b_copy.is_file());

    // A player frame drawn at a is shared through the store, and b serves the store's copy
    // instead of drawing it: replaced in the store, b serves the replacement.
    let frame = |base: &str| format!("{base}/sessions/{id}/frame?view=axial&tick=2000");
    let (status, drawn) = get_bytes(&frame(&a.base), &tina);
    assert_eq!(status, 200);
    assert!(drawn.starts_with(b"\x89PNG"));
    let frames = format!("site-a/frames/{}/{sha}/", &sha[..2]);
    let started = Instant::now();
    while s3.keys(BUCKET, &frames).is_empty() {
        assert!(
            started.elapsed() < Duration::from_secs(20),
            "the frame never reached the store"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    let keys = s3.keys(BUCKET, &frames);
    assert_eq!(keys.len(), 1, "{keys:?}");
    let stored_frame = s3.bucket_dir(BUCKET).join(&keys[0]);
    assert_eq!(std::fs::read(&stored_frame).unwrap(), drawn);
    let replacement = b"the store's copy of the frame".to_vec();
    std::fs::write(&stored_frame, &replacement).unwrap();
    let (status, served) = get_bytes(&frame(&b.base), &tina_b);
    assert_eq!(status, 200);
    assert_eq!(served, replacement, "b drew the frame instead of taking the shared one");

    // Deleted at b: gone from the store as well, its frames with it.
    let root = login(&b.base, "root");
    let (status, json, _) = call(
        "DELETE",
        &format!("{}/api/sessions/{id}", b.base),
        Some(&root),
        None,
        false,
    );
    assert_eq!(status, 200, "{json}");
    assert_eq!(s3.keys(BUCKET, "site-a/"), Vec::<String>::new());

    // A store that does not answer: not ready, and an upload is refused (503) without a row.
    let admin = a.admin.clone().unwrap();
    assert_eq!(admin_get(&format!("{admin}/readyz")).0, 200);
    s3.stop();
    let (status, text) = admin_get(&format!("{admin}/readyz"));
    assert_eq!(status, 503, "{text}");
    assert!(text.contains("object storage"), "{text}");
    let body = std::fs::read(f.session("tom-ok")).unwrap();
    let tom = login(&a.base, "tom");
    let (status, json, _) = call(
        "POST",
        &format!("{}/api/sessions", a.base),
        Some(&tom),
        Some(&body),
        false,
    );
    assert_eq!(status, 503, "{json}");
    assert_eq!(psql(&db, "SELECT COUNT(*) FROM sessions"), "0");
}

/// The replica is killed after the file reached the store and before its row committed (held
/// back by a lock on the sessions table): the client got no answer, no row names the object,
/// and the same upload to the restarted replica is stored and scored.
#[test]
fn a_replica_killed_between_the_object_and_its_row_leaves_no_row_without_its_object() {
    let f = Fixture::new(STYLET);
    let db = Db::postgres("objectkill");
    let s3 = S3Server::start(BUCKET);
    f.users(&db);
    let mut a = replica(&f, &db, &s3, "a");
    let tina = login(&a.base, "tina");
    let file = std::fs::read(f.session("tina-ok")).unwrap();

    // Inserts into sessions wait behind this lock; reads go on.
    let mut lock = Command::new("psql")
        .args([
            db.url(std::path::Path::new("")).as_str(),
            "-q",
            "-c",
            "BEGIN; LOCK TABLE sessions IN EXCLUSIVE MODE; SELECT pg_sleep(60); COMMIT;",
        ])
        // Its end (terminated below) is expected: not test output.
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("psql runs");
    let held = Instant::now();
    while psql(
        &db,
        "SELECT COUNT(*) FROM pg_locks l JOIN pg_class c ON l.relation = c.oid \
         WHERE c.relname = 'sessions' AND l.mode = 'ExclusiveLock' AND l.granted",
    ) != "1"
    {
        assert!(held.elapsed() < Duration::from_secs(20), "the lock was not taken");
        std::thread::sleep(Duration::from_millis(50));
    }

    let addr = a.base.strip_prefix("http://").unwrap().to_string();
    let head = upload_head(&addr, &tina, file.len() as u64);
    let body = file.clone();
    let upload = std::thread::spawn(move || {
        let mut s = TcpStream::connect(&addr).unwrap();
        s.write_all(head.as_bytes()).unwrap();
        let _ = s.write_all(&body);
        let mut answer = Vec::new();
        let _ = s.read_to_end(&mut answer);
        status_of(&answer)
    });
    let waited = Instant::now();
    let key = loop {
        if let Some(key) = s3.keys(BUCKET, "site-a/sessions/").pop() {
            break key;
        }
        assert!(
            waited.elapsed() < Duration::from_secs(30),
            "the upload never reached the store"
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    assert_eq!(std::fs::read(s3.bucket_dir(BUCKET).join(&key)).unwrap(), file);
    // The object is there and the row waits for the lock: kill the replica now.
    a.child.kill().unwrap();
    a.child.wait().unwrap();
    let (status, text) = upload.join().unwrap();
    assert_eq!(status, 0, "the killed replica answered: {text}");
    // The lock's session ends (its client going away would not end pg_sleep).
    psql(
        &db,
        "SELECT pg_terminate_backend(pid) FROM pg_stat_activity \
         WHERE query LIKE '%LOCK TABLE sessions%' AND pid <> pg_backend_pid()",
    );
    let _ = lock.wait();

    assert_eq!(psql(&db, "SELECT COUNT(*) FROM sessions"), "0");
    drop(a);
    let a = replica(&f, &db, &s3, "a");
    let tina = login(&a.base, "tina");
    let (id, _) = upload_scored(&a.base, &tina, &f.session("tina-ok"));
    // Every row's object is in the store.
    let rows = psql(&db, "SELECT file_sha256 FROM sessions");
    assert_eq!(session_key(&rows), key, "{id}");
    for sha in rows.lines() {
        assert!(s3.keys(BUCKET, &session_key(sha)).contains(&session_key(sha)));
    }
}

/// An atlas published at one replica is put into the store before its row; a replica started
/// before the publication fetches it when a session on it arrives, checks it and scores the
/// session.
#[test]
fn an_atlas_published_at_one_replica_is_fetched_by_another() {
    let f = Fixture::new(STYLET);
    let db = Db::postgres("objectatlas");
    let s3 = S3Server::start(BUCKET);
    f.users(&db);
    let a = replica(&f, &db, &s3, "a");
    let b = replica(&f, &db, &s3, "b");
    let other = f.dir.path().join("other-atlas");
    let out = ok(&["atlas", "validate", s(&other)]);
    assert!(out.contains("is validated"), "{out}");
    let ivan = login(&a.base, "ivan");
    let (status, made, _) = call(
        "POST",
        &format!("{}/api/tokens", a.base),
        Some(&ivan),
        Some(br#"{"label":"publishing","scope":"full"}"#),
        true,
    );
    assert_eq!(status, 201, "{made}");
    let published = STYLET
        .command()
        .args(["atlas", "publish", s(&other), "--server", &a.base])
        .env("STYLET_TOKEN", made["token"].as_str().unwrap())
        .output()
        .unwrap();
    assert!(
        published.status.success(),
        "{}",
        String::from_utf8_lossy(&published.stderr)
    );
    let hash = psql(&db, "SELECT content_hash FROM atlases WHERE published_at IS NOT NULL");
    assert_eq!(hash.len(), 64, "{hash}");

    // Its files, and no derived-data cache, are in the store.
    let keys = s3.keys(BUCKET, &format!("site-a/atlases/{hash}/"));
    assert!(keys.iter().any(|k| k.ends_with("/atlas.toml")), "{keys:?}");
    assert!(!keys.iter().any(|k| k.contains(".stylet-cache")), "{keys:?}");
    let b_copy = f.dir.path().join("data-b/atlases").join(&hash);
    assert!(!b_copy.exists());

    // Replica b takes a session on it at once and scores it.
    let tina = login(&b.base, "tina");
    let (_, row) = upload_scored(&b.base, &tina, &f.session("tina-other-atlas"));
    assert_eq!(row["atlas_hash"], hash.as_str(), "{row}");
    assert!(b_copy.join("atlas.toml").is_file());
}

/// `stylet backup` of a service on the store, from a host with an empty data directory (every
/// file fetched from the store), into an `s3://` prefix; then `stylet restore` from that prefix
/// into a new database and another storage prefix: the files are there byte for byte, and the
/// restored scores replay identically. A second backup into the same prefix is refused.
#[test]
fn a_service_on_object_storage_is_backed_up_and_restored_into_another_prefix() {
    let f = Fixture::new(STYLET);
    let db = Db::postgres("objectbackup");
    let s3 = S3Server::start(BUCKET);
    f.users(&db);
    let a = replica(&f, &db, &s3, "a");
    let tina = login(&a.base, "tina");
    upload_scored(&a.base, &tina, &f.session("tina-ok"));
    upload_scored(&a.base, &tina, &f.session("tina-lung"));
    drop(a);
    let run = |args: &[&str], succeeds: bool| {
        let mut command = STYLET.command();
        command.args(args);
        s3.configure(&mut command);
        let out = command.output().unwrap();
        let said = String::from_utf8_lossy(&out.stdout).into_owned() + &String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.success(), succeeds, "{args:?}: {said}");
        said
    };
    let elsewhere = f.dir.path().join("backup-host");
    std::fs::create_dir(&elsewhere).unwrap();
    let url = db.url(&elsewhere);
    let backup = "s3://stylet/backups/monday";
    let backup_args = [
        "backup",
        "--data-dir",
        s(&elsewhere),
        "--database",
        &url,
        "--storage",
        STORAGE,
        "--to",
        backup,
    ];
    let said = run(&backup_args, true);
    assert!(said.contains("backed up 2 sessions (2 scored)"), "{said}");
    let held = s3.keys(BUCKET, "backups/monday/");
    assert!(held.contains(&"backups/monday/manifest.json".to_string()), "{held:?}");
    assert_eq!(
        held.iter()
            .filter(|k| k.starts_with("backups/monday/sessions/"))
            .count(),
        2,
        "{held:?}"
    );
    // The staging folder is gone; the prefix is not written twice.
    let staged: Vec<_> = std::fs::read_dir(&elsewhere)
        .unwrap()
        .flatten()
        .map(|e| e.file_name())
        .collect();
    assert!(
        !staged
            .iter()
            .any(|n| n.to_string_lossy().starts_with(".backup-staging")),
        "{staged:?}"
    );
    let said = run(&backup_args, false);
    assert!(said.contains("exists already"), "{said}");

    let restored_db = Db::postgres("objectrestored");
    let data = f.dir.path().join("restored");
    let restored_url = restored_db.url(&data);
    let said = run(
        &[
            "restore",
            "--from",
            backup,
            "--data-dir",
            s(&data),
            "--database",
            &restored_url,
            "--storage",
            "s3://stylet/site-b",
            "--atlases",
            s(&f.atlases()),
        ],
        true,
    );
    assert!(said.contains("restored 2 sessions (2 scored)"), "{said}");
    assert_eq!(
        said.matches("replayed, identical to its restored score").count(),
        2,
        "{said}"
    );
    assert!(!data.join(".restore-staging").exists());
    // Every session and score as it was.
    let rows = "SELECT s.id, s.file_sha256, s.status, c.score, c.passed, c.report_json \
                FROM sessions s JOIN scores c ON c.session_id = s.id ORDER BY s.id";
    let original = psql(&db, rows);
    assert_eq!(original.lines().count(), 2, "{original}");
    assert_eq!(psql(&restored_db, rows), original);
    let before: Vec<String> = s3.keys(BUCKET, "site-a/sessions/");
    let after: Vec<String> = s3.keys(BUCKET, "site-b/sessions/");
    assert_eq!(before.len(), 2);
    assert_eq!(
        after,
        before
            .iter()
            .map(|k| k.replacen("site-a", "site-b", 1))
            .collect::<Vec<_>>()
    );
    for (b, a) in before.iter().zip(&after) {
        let dir = s3.bucket_dir(BUCKET);
        assert_eq!(std::fs::read(dir.join(b)).unwrap(), std::fs::read(dir.join(a)).unwrap());
    }
    // A prefix without a manifest is not a backup.
    let err = run(
        &[
            "restore",
            "--from",
            "s3://stylet/site-a",
            "--data-dir",
            s(&f.dir.path().join("r2")),
            "--database",
            &restored_url,
        ],
        false,
    );
    assert!(err.contains("not a backup"), "{err}");
}
