//! Rolling upgrades (docs/operations.md "Upgrading"): while replicas are upgraded one at a time,
//! a replica of the older release runs, and may restart, on the schema the newer release has
//! migrated — which only adds. Two tests: the previous release's own binary (deploy/releases,
//! built by scripts/previous-release) serving beside and after this build on the schema this
//! build migrated to; and this build playing the older release on a later release's schema.

use crate::common::*;

/// The previous release's `stylet` binary: scripts/test builds it (scripts/previous-release) and
/// sets `STYLET_PREVIOUS_RELEASE`. Without it the test fails; it is never skipped.
fn previous_release() -> Stylet {
    let path = std::env::var("STYLET_PREVIOUS_RELEASE").expect(
        "STYLET_PREVIOUS_RELEASE is not set: scripts/test builds the previous release's binary \
         (scripts/previous-release) and sets it",
    );
    Stylet::at(Box::leak(path.into_boxed_str()))
}

on_both_databases!(the_previous_release_serves_on_this_releases_schema, "previous");

/// The previous release makes the database and scores a session; this build migrates it and
/// scores another; the previous release then serves beside this build (PostgreSQL, where
/// replicas share a database) and alone after it (both databases): it lists, serves and scores on
/// the newer schema.
fn the_previous_release_serves_on_this_releases_schema(db: Db) {
    let old = previous_release();
    let version = old.ok(&["--version"]);
    let this_version = STYLET.ok(&["--version"]);
    assert_ne!(version, this_version, "the previous release's binary is this build");
    let f = Fixture::new(STYLET);
    let data = f.data();
    for (name, role, cohort) in [
        ("tina", "trainee", Some("c1")),
        ("tom", "trainee", Some("c2")),
        ("cora", "curriculum", None),
    ] {
        old.add_user(&data, &db, name, role, cohort);
    }
    let serve = |stylet: Stylet| Server::start(stylet, &data, &db, &f.atlases(), &["--workers", "1"]);

    let srv = serve(old);
    let tina = login(&srv.base, "tina");
    let (first, _) = upload_scored(&srv.base, &tina, &f.session("tina-ok"));
    drop(srv);

    let new = serve(STYLET);
    let tom = login(&new.base, "tom");
    let (second, _) = upload_scored(&new.base, &tom, &f.session("tom-ok"));
    let mut ids = vec![first, second];

    // Side by side on one database: the newer schema is already there when the old one starts.
    if matches!(db, Db::Postgres(_)) {
        let srv = serve(old);
        let tina = login(&srv.base, "tina");
        let (id, row) = upload_scored(&srv.base, &tina, &f.session("tina-lung"));
        assert_eq!(row["status"], "scored", "{id}: {row}");
        ids.push(id);
        let tom = login(&srv.base, "tom");
        let (status, row, _) = call(
            "GET",
            &format!("{}/api/sessions/{}", srv.base, ids[1]),
            Some(&tom),
            None,
            false,
        );
        assert_eq!((status, row["status"].as_str()), (200, Some("scored")), "{row}");
    }
    drop(new);

    // Alone on the newer schema (a rollback, or the last replica not yet upgraded restarting).
    let srv = serve(old);
    let b = &srv.base;
    let tina = login(b, "tina");
    let (id, row) = upload_scored(b, &tina, &f.session("tina-two"));
    assert_eq!(row["status"], "scored", "{id}: {row}");
    ids.push(id);
    let cora = login(b, "cora");
    let (status, list, _) = call("GET", &format!("{b}/api/sessions"), Some(&cora), None, false);
    assert_eq!(status, 200, "{list}");
    assert_eq!(list["total"], ids.len(), "{list}");
    for id in &ids {
        let (status, row, _) = call("GET", &format!("{b}/api/sessions/{id}"), Some(&cora), None, false);
        assert_eq!((status, row["status"].as_str()), (200, Some("scored")), "{id}: {row}");
    }
    let (status, bytes) = get_bytes(&format!("{b}/api/sessions/{}/file", ids[1]), &login(b, "tom"));
    assert_eq!(status, 200);
    assert_eq!(bytes, std::fs::read(f.session("tom-ok")).unwrap());
}

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
