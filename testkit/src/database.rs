//! The database a test runs the service on: SQLite in its data directory, or a fresh database of
//! its own on the PostgreSQL server of `$STYLET_POSTGRES_URL`; [`crate::on_both_databases!`]
//! makes one test of each.

use std::path::Path;
use std::process::Command;
use std::sync::atomic::{AtomicU32, Ordering};

/// Which database the service uses.
pub enum Db {
    /// `stylet.db` in the service's data directory (the default of `stylet serve`).
    Sqlite,
    /// A fresh PostgreSQL database of its own, by URL.
    Postgres(String),
}

impl Db {
    /// A new, empty database on the PostgreSQL server of `$STYLET_POSTGRES_URL` (scripts/test
    /// starts it with scripts/postgres-up and sets it), named after `test`, this process and a
    /// sequence number, so tests running at the same time in one or several processes never
    /// share one. Without the variable the test fails rather than being skipped.
    pub fn postgres(test: &str) -> Db {
        static NEXT: AtomicU32 = AtomicU32::new(0);
        let admin = std::env::var("STYLET_POSTGRES_URL")
            .expect("STYLET_POSTGRES_URL is not set: scripts/test starts PostgreSQL (scripts/postgres-up) and sets it");
        let name = format!(
            "stylet_{test}_{}_{}",
            std::process::id(),
            NEXT.fetch_add(1, Ordering::Relaxed)
        );
        let run = |sql: &str| {
            let out = Command::new("psql")
                .args([admin.as_str(), "-q", "-c", sql])
                .output()
                .expect("psql runs");
            assert!(out.status.success(), "{sql}: {}", String::from_utf8_lossy(&out.stderr));
        };
        run(&format!("DROP DATABASE IF EXISTS {name}"));
        run(&format!("CREATE DATABASE {name}"));
        let base = admin.rsplit_once('/').expect("a URL with a database").0;
        Db::Postgres(format!("{base}/{name}"))
    }

    /// The database's name in test output and file names: `sqlite` or `postgres`.
    pub fn name(&self) -> &'static str {
        match self {
            Db::Sqlite => "sqlite",
            Db::Postgres(_) => "postgres",
        }
    }

    /// The arguments of a `stylet` command (`serve`, `user add`) that choose this database.
    pub fn args(&self) -> Vec<&str> {
        match self {
            Db::Sqlite => Vec::new(),
            Db::Postgres(url) => vec!["--database", url.as_str()],
        }
    }

    /// The database's URL for a service whose data directory is `data`.
    pub fn url(&self, data: &Path) -> String {
        match self {
            Db::Sqlite => format!("sqlite://{}?mode=rwc", data.join("stylet.db").display()),
            Db::Postgres(url) => url.clone(),
        }
    }
}

/// Two tests of one body, `fn body(db: Db)`: `<name>_sqlite` on SQLite and `<name>_postgres` on a
/// fresh PostgreSQL database named after `prefix` ([`Db::postgres`]).
///
/// ```ignore
/// on_both_databases!(publishing_an_atlas, "publish");
/// // a test name other than the body's:
/// on_both_databases!(the_cohort_report_pdf_holds_the_cohorts_numbers => cohort_report_pdf, "reports");
/// ```
#[macro_export]
macro_rules! on_both_databases {
    ($body:ident, $prefix:literal) => {
        $crate::on_both_databases!($body => $body, $prefix);
    };
    ($name:ident => $body:ident, $prefix:literal) => {
        $crate::pastey::paste! {
            #[test]
            fn [<$name _sqlite>]() {
                $body($crate::Db::Sqlite)
            }

            #[test]
            fn [<$name _postgres>]() {
                $body($crate::Db::postgres($prefix))
            }
        }
    };
}
