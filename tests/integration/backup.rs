//! `stylet backup` and `stylet restore` (docs/operations.md "Backing up"): a backup taken while
//! the server runs, the service wiped, restored: every session's row, score and file identical;
//! a damaged backup or a data directory in use is refused before anything is written.

use std::path::Path;

use crate::common::*;

/// The same kind of database as `db`, new and empty.
fn another(db: &Db) -> Db {
    match db {
        Db::Sqlite => Db::Sqlite,
        Db::Postgres(_) => Db::postgres("restored"),
    }
}

/// Every session's row (with its score) and file, as a trainee of the service sees them.
fn sessions_of(base: &str, ids: &[String]) -> Vec<(serde_json::Value, Vec<u8>)> {
    let (tina, tom) = (login(base, "tina"), login(base, "tom"));
    ids.iter()
        .map(|id| {
            let who = if id.starts_with("tom:") { &tom } else { &tina };
            let id = id.trim_start_matches("tom:");
            let (status, row, _) = call("GET", &format!("{base}/api/sessions/{id}"), Some(who), None, false);
            assert_eq!(status, 200, "{row}");
            let (status, file) = get_bytes(&format!("{base}/api/sessions/{id}/file"), who);
            assert_eq!(status, 200);
            (row, file)
        })
        .collect()
}

fn args<'a>(base: &[&'a str], db: &'a Db) -> Vec<&'a str> {
    let mut v = base.to_vec();
    v.extend(db.args());
    v
}

fn backup_and_restore(db: Db) {
    let f = Fixture::new(STYLET);
    f.users(&db);
    let server = Server::start(STYLET, &f.data(), &db, &f.atlases(), &["--workers", "1"]);
    let b = &server.base;
    let (tina, tom) = (login(b, "tina"), login(b, "tom"));
    let ids = vec![
        upload_scored(b, &tina, &f.session("tina-ok")).0,
        upload_scored(b, &tina, &f.session("tina-lung")).0,
        format!("tom:{}", upload_scored(b, &tom, &f.session("tom-ok")).0),
    ];
    let before = sessions_of(b, &ids);
    // Taken while the server runs.
    let backup = f.dir.path().join("backup");
    let said = ok(&args(&["backup", "--data-dir", s(&f.data()), "--to", s(&backup)], &db));
    assert!(said.contains("backed up 3 sessions (3 scored)"), "{said}");
    drop(server);
    // A backup folder is never overwritten.
    let err = fails(&args(&["backup", "--data-dir", s(&f.data()), "--to", s(&backup)], &db));
    assert!(err.contains("exists already"), "{err}");

    // The service is gone; restored elsewhere, into a new database.
    let restored_db = another(&db);
    let data = f.dir.path().join("restored");
    let said = ok(&args(
        &[
            "restore",
            "--from",
            s(&backup),
            "--data-dir",
            s(&data),
            "--atlases",
            s(&f.atlases()),
        ],
        &restored_db,
    ));
    assert!(said.contains("restored 3 sessions (3 scored)"), "{said}");
    assert_eq!(
        said.matches("replayed, identical to its restored score").count(),
        3,
        "{said}"
    );
    let server = Server::start(STYLET, &data, &restored_db, &f.atlases(), &["--workers", "1"]);
    let after = sessions_of(&server.base, &ids);
    for ((row_before, file_before), (row_after, file_after)) in before.iter().zip(&after) {
        assert_eq!(row_before, row_after);
        assert!(row_after["score"]["grade"].is_object(), "{row_after}");
        assert!(file_before == file_after, "the file of {}", row_after["id"]);
    }
    // A data directory in use is not restored into.
    let err = fails(&args(
        &["restore", "--from", s(&backup), "--data-dir", s(&data)],
        &restored_db,
    ));
    assert!(err.contains("restore into an empty data directory"), "{err}");
}

on_both_databases!(backup_and_restore, "backup");

/// One byte changed in a backed-up session file: restore names the file and writes nothing.
#[test]
fn a_damaged_backup_is_refused_before_anything_is_written() {
    let f = Fixture::new(STYLET);
    f.users(&Db::Sqlite);
    let server = Server::start(STYLET, &f.data(), &Db::Sqlite, &f.atlases(), &["--workers", "1"]);
    let tina = login(&server.base, "tina");
    upload_scored(&server.base, &tina, &f.session("tina-ok"));
    drop(server);
    let backup = f.dir.path().join("backup");
    ok(&["backup", "--data-dir", s(&f.data()), "--to", s(&backup)]);
    let damaged = walk(&backup.join("sessions"))
        .into_iter()
        .next()
        .expect("a session file");
    let mut bytes = std::fs::read(&damaged).unwrap();
    let middle = bytes.len() / 2;
    bytes[middle] ^= 0x40;
    std::fs::write(&damaged, bytes).unwrap();
    let data = f.dir.path().join("restored");
    let err = fails(&["restore", "--from", s(&backup), "--data-dir", s(&data)]);
    let name = damaged.file_name().unwrap().to_string_lossy();
    assert!(
        err.contains("the backup is damaged") && err.contains(name.as_ref()),
        "{err}"
    );
    assert!(!data.exists() || files_under(&data) == 0, "something was written");
    assert!(!Path::new(&data).join("stylet.db").exists());
}
