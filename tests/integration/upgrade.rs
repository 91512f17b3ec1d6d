//! Rolling upgrades (docs/operations.md "Upgrading"): while replicas are upgraded one at a time,
//! a replica of the older release runs, and may restart, on the schema the newer release has
//! migrated — which only adds. Here this build plays the older release: a later release's
//! migration (a new table, new nullable columns on the tables this build reads and writes,
//! recorded as sqlx records it) is applied to its database, and this build starts on it, serves
//! what it stored before, and stores and scores a new upload.

use crate::common::*;

on_both_databases!(an_older_replica_keeps_serving_on_a_newer_releases_schema, "upgrade");

fn an_older_replica_keeps_serving_on_a_newer_releases_schema(db: Db) {
    let f = Fixture::new(STYLET);
    let srv = f.serve(&db, 1);
    let tina = login(&srv.base, "tina");
    let (first, _) = upload_scored(&srv.base, &tina, &f.session("tina-ok"));
    drop(srv);

    // A later release's migration, applied by one of its replicas: additions only.
    on_database(&db, &f.data(), async |store| {
        for sql in [
            "CREATE TABLE later_release_notes (id TEXT PRIMARY KEY, note TEXT NOT NULL)",
            "ALTER TABLE sessions ADD COLUMN later_release_note TEXT",
            "ALTER TABLE scores ADD COLUMN later_release_figure DOUBLE PRECISION",
            "ALTER TABLE scoring_jobs ADD COLUMN later_release_flag BOOLEAN",
        ] {
            sqlx::query(sqlx::AssertSqlSafe(sql))
                .execute(&store.pool)
                .await
                .unwrap();
        }
        sqlx::query(
            "INSERT INTO _sqlx_migrations (version, description, success, checksum, execution_time) \
             VALUES ($1, $2, TRUE, $3, 1)",
        )
        .bind(9001_i64)
        .bind("later release notes")
        .bind(vec![7u8; 48])
        .execute(&store.pool)
        .await
        .unwrap();
    });

    // This build starts on it, says it is ready, and serves.
    let srv = Server::start(
        STYLET,
        &f.data(),
        &db,
        &f.atlases(),
        &["--workers", "1", "--admin-bind", "127.0.0.1:0"],
    );
    let b = &srv.base;
    let ready = ureq::get(&format!("{}/readyz", srv.admin.as_ref().unwrap())).call();
    assert_eq!(ready.map(|r| r.status()).ok(), Some(200));
    let tina = login(b, "tina");
    let (status, row, _) = call("GET", &format!("{b}/api/sessions/{first}"), Some(&tina), None, false);
    assert_eq!((status, row["status"].as_str()), (200, Some("scored")), "{row}");
    let (status, bytes) = get_bytes(&format!("{b}/api/sessions/{first}/file"), &tina);
    assert_eq!(status, 200);
    assert_eq!(bytes, std::fs::read(f.session("tina-ok")).unwrap());
    let tom = login(b, "tom");
    let (second, row) = upload_scored(b, &tom, &f.session("tom-ok"));
    assert_eq!(row["status"], "scored", "{second}: {row}");
    let cora = login(b, "cora");
    let (status, list, _) = call("GET", &format!("{b}/api/sessions"), Some(&cora), None, false);
    assert_eq!(status, 200, "{list}");
    assert_eq!(list["total"], 2, "{list}");
}
