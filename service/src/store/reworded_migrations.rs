//! Migrations whose comments were reworded after databases had applied them.
//!
//! sqlx keeps the SHA-384 of every migration it applied and refuses to start when a file no
//! longer matches (`VersionMismatch`). The files below changed only in their comments, so a
//! database that applied the earlier text is moved to the current checksum before migrating —
//! and only when its stored checksum is exactly that earlier text's, so any other difference
//! between a database and the migrations still stops the service.

use sqlx::AnyPool;
use sqlx::migrate::Migrator;

/// (version, SHA-384 in hex of the text the migration had when it shipped).
const EARLIER_TEXTS: [(i64, &str); 6] = [
    (
        3,
        "550226c2bc239a2305c056d423239df9f103037d2c427850dcd6e3cfcee4e25d2a32fe8f31aeb6643e1b80deb337a816",
    ),
    (
        4,
        "04613bb3ff23aa30b224dda7f939121c23d8008ca096e183f5a33f4c1f2968c164a08dd8b4b6e082eb0d861359c01151",
    ),
    (
        5,
        "eb1763d48f9b7a55c094d6a9b828fd91d43ee06af95419dbe107dd1fff9aa2697118ecef4c1f303ccab1d714f5dc04ce",
    ),
    (
        7,
        "eceaf73b1da31d177fa30238b188071bc1ef588c7860fea012dab763ef22a8d780589d208112d5cd0fe228481db6e614",
    ),
    (
        8,
        "411903d4af75e307fe4b5540f52e04b4996e2f63c47c6840f62950865e4a31c7a3d3b7bb0161dbb6e1e655a148ee03ee",
    ),
    (
        9,
        "a95ab8229db97ec76410cb9192c1f0d03c526b5ecc4f1f12c07f5d6be9919693b36a33138eb198afeef9ee036d32159f",
    ),
];

/// Moves the stored checksums of reworded migrations from their earlier text to the current one.
/// Does nothing on a new database.
pub(super) async fn accept(pool: &AnyPool, migrator: &Migrator, sqlite: bool) -> Result<(), sqlx::Error> {
    let exists_sql = if sqlite {
        "SELECT COUNT(*) AS n FROM sqlite_master WHERE type = 'table' AND name = '_sqlx_migrations'"
    } else {
        "SELECT COUNT(*) AS n FROM information_schema.tables WHERE table_name = '_sqlx_migrations' AND table_schema = current_schema()"
    };
    let n: i64 = sqlx::Row::try_get(&sqlx::query(exists_sql).fetch_one(pool).await?, "n")?;
    if n == 0 {
        return Ok(());
    }
    for (version, earlier_hex) in EARLIER_TEXTS {
        let Some(current) = migrator.iter().find(|m| m.version == version) else {
            continue;
        };
        sqlx::query("UPDATE _sqlx_migrations SET checksum = $1 WHERE version = $2 AND checksum = $3")
            .bind(current.checksum.to_vec())
            .bind(version)
            .bind(hex_bytes(earlier_hex))
            .execute(pool)
            .await?;
    }
    Ok(())
}

fn hex_bytes(hex: &str) -> Vec<u8> {
    (0..hex.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&hex[i..i + 2], 16).expect("EARLIER_TEXTS holds hex"))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use sha2::{Digest, Sha384};

    static MIGRATOR: Migrator = sqlx::migrate!("../migrations");

    /// The checksum sqlx stores is the SHA-384 of the file's text, so the earlier texts' hashes
    /// above are what databases migrated with them hold.
    #[test]
    fn stored_checksums_are_the_sha384_of_the_files() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../migrations");
        for m in MIGRATOR.iter() {
            let name = format!("{:04}_{}.sql", m.version, m.description.replace(' ', "_"));
            let text = std::fs::read(dir.join(&name)).unwrap();
            assert_eq!(m.checksum.as_ref(), Sha384::digest(&text).as_slice(), "{name}");
        }
        for (version, earlier) in EARLIER_TEXTS {
            let current = MIGRATOR.iter().find(|m| m.version == version).unwrap();
            assert_ne!(
                current.checksum.to_vec(),
                hex_bytes(earlier),
                "migration {version} was not reworded"
            );
        }
    }

    async fn open_a_database_migrated_with_the_earlier_texts(url: &str) {
        sqlx::any::install_default_drivers();
        let pool = AnyPool::connect(url).await.unwrap();
        MIGRATOR.run(&pool).await.unwrap();
        for (version, earlier) in EARLIER_TEXTS {
            sqlx::query("UPDATE _sqlx_migrations SET checksum = $1 WHERE version = $2")
                .bind(hex_bytes(earlier))
                .bind(version)
                .execute(&pool)
                .await
                .unwrap();
        }
        // Without the bridge sqlx refuses such a database.
        let refused = MIGRATOR.run(&pool).await.unwrap_err();
        assert!(
            matches!(refused, sqlx::migrate::MigrateError::VersionMismatch(3)),
            "{refused}"
        );
        pool.close().await;
        super::super::Store::open(url).await.unwrap();

        // Any other checksum still stops the service.
        let pool = AnyPool::connect(url).await.unwrap();
        sqlx::query("UPDATE _sqlx_migrations SET checksum = $1 WHERE version = 5")
            .bind(vec![0u8; 48])
            .execute(&pool)
            .await
            .unwrap();
        pool.close().await;
        let Err(e) = super::super::Store::open(url).await else {
            panic!("a database with an unknown checksum opened");
        };
        assert!(e.to_string().contains('5'), "{e}");
    }

    #[tokio::test]
    async fn a_database_migrated_with_the_earlier_texts_opens_on_sqlite() {
        let dir = tempfile::tempdir().unwrap();
        let url = format!("sqlite://{}?mode=rwc", dir.path().join("t.db").display());
        open_a_database_migrated_with_the_earlier_texts(&url).await;
    }

    /// On PostgreSQL, in a database of its own.
    #[tokio::test]
    async fn a_database_migrated_with_the_earlier_texts_opens_on_postgres() {
        let url = super::super::fresh_postgres_database("stylet_reworded_unit").await;
        open_a_database_migrated_with_the_earlier_texts(&url).await;
    }
}
