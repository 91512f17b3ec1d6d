//! The derived-data cache (docs/atlas.md "Derived-data cache"): a load writes it, the next one
//! reads it and gets the very bits a full derivation gives; a damaged, truncated, foreign or
//! outdated cache is refused with the reason, derived again and rewritten; a cache that cannot be
//! written never fails a load.

use std::fs;
use std::path::{Path, PathBuf};

use crate::common::{tiny_manifest, tiny_volumes, write_tiny};
use stylet_atlas::cache::{CACHE_DIR, cache_file};
use stylet_atlas::phantom::{PhantomConfig, generate};
use stylet_atlas::{Atlas, CacheMode, CacheStatus, ThresholdSource};

fn small_phantom(dir: &Path) {
    let config = PhantomConfig {
        dims: [64, 64, 50],
        spacing_mm: [6.0; 3],
        ..PhantomConfig::default()
    };
    let p = generate(&config).unwrap();
    stylet_atlas::write(dir, &p.manifest, &p.ct, &p.partial).unwrap();
}

fn file_of(a: &Atlas) -> PathBuf {
    cache_file(&a.dir, &a.content_hash)
}

/// The derived data of `a` equals, bit for bit, that of a load that does not use the cache.
fn assert_same_as_derived(a: &Atlas) {
    let fresh = stylet_atlas::load_with(&a.dir, CacheMode::Off).unwrap();
    assert_eq!(fresh.cache_status(), CacheStatus::Disabled);
    assert_eq!(a.model.thresholds(), fresh.model.thresholds());
    let bits = |v: &stylet_physics::Volume<f32>| v.data().iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert!(
        bits(a.model.skin_distance()) == bits(fresh.model.skin_distance()),
        "skin map differs"
    );
    assert!(
        bits(a.model.bone_distance()) == bits(fresh.model.bone_distance()),
        "bone map differs"
    );
}

#[test]
fn a_load_writes_the_cache_and_the_next_reads_the_same_bits() {
    for (name, make) in [("phantom", small_phantom as fn(&Path)), ("tiny", write_tiny)] {
        let d = tempfile::tempdir().unwrap();
        make(d.path());
        let first = stylet_atlas::load(d.path()).unwrap();
        assert_eq!(first.cache_status(), CacheStatus::Written, "{name}");
        assert!(file_of(&first).is_file(), "{name}");
        let second = stylet_atlas::load(d.path()).unwrap();
        assert_eq!(second.cache_status(), CacheStatus::Hit, "{name}");
        assert_eq!(second.content_hash, first.content_hash);
        assert_eq!(second.threshold_source, first.threshold_source);
        assert_same_as_derived(&second);
    }
}

#[test]
fn estimated_thresholds_come_from_the_cache_too() {
    let d = tempfile::tempdir().unwrap();
    write_tiny(d.path());
    let first = stylet_atlas::load(d.path()).unwrap();
    assert_eq!(
        first.threshold_source,
        ThresholdSource::Estimated,
        "the tiny atlas has no thresholds"
    );
    assert_eq!(first.cache_status(), CacheStatus::Written);
    let second = stylet_atlas::load(d.path()).unwrap();
    assert_eq!(second.cache_status(), CacheStatus::Hit);
    assert_eq!(second.threshold_source, ThresholdSource::Estimated);
    assert_eq!(second.model.thresholds(), first.model.thresholds());
}

/// Loads, expects the cache to be refused for a reason mentioning `why`, then checks the maps
/// are right and the cache was rewritten (the next load hits).
fn assert_rebuilt(dir: &Path, why: &str) {
    let a = stylet_atlas::load(dir).unwrap();
    match &a.cache_status() {
        CacheStatus::Rebuilt { refused } => assert!(refused.contains(why), "refused for {refused:?}, expected {why:?}"),
        other => panic!("expected the cache to be rebuilt ({why}), got {other:?}"),
    }
    assert_same_as_derived(&a);
    assert_eq!(stylet_atlas::load(dir).unwrap().cache_status(), CacheStatus::Hit);
}

#[test]
fn a_damaged_cache_is_detected_and_rebuilt() {
    let d = tempfile::tempdir().unwrap();
    small_phantom(d.path());
    let a = stylet_atlas::load(d.path()).unwrap();
    assert_eq!(a.cache_status(), CacheStatus::Written);
    let path = file_of(&a);
    let len = fs::metadata(&path).unwrap().len() as usize;

    // One flipped bit in the middle of each map, then in the last byte.
    for at in [len / 3, 2 * len / 3, len - 1] {
        let mut bytes = fs::read(&path).unwrap();
        bytes[at] ^= 0x10;
        fs::write(&path, &bytes).unwrap();
        assert_rebuilt(d.path(), "damaged");
    }
    // Truncated, and lengthened.
    let bytes = fs::read(&path).unwrap();
    fs::write(&path, &bytes[..len - 4]).unwrap();
    assert_rebuilt(d.path(), "bytes");
    fs::write(&path, [bytes.as_slice(), &[0u8; 4]].concat()).unwrap();
    assert_rebuilt(d.path(), "bytes");
    // Another file's magic, another physics version.
    let mut other = bytes.clone();
    other[0] = b'X';
    fs::write(&path, &other).unwrap();
    assert_rebuilt(d.path(), "magic");
    let mut other = bytes.clone();
    other[20] ^= 0xff;
    fs::write(&path, &other).unwrap();
    assert_rebuilt(d.path(), "physics version");
    // Not a file at all.
    fs::remove_file(&path).unwrap();
    fs::create_dir(&path).unwrap();
    let a = stylet_atlas::load(d.path()).unwrap();
    assert!(
        matches!(a.cache_status(), CacheStatus::NotWritten { .. }),
        "{:?}",
        a.cache_status()
    );
    assert_same_as_derived(&a);
}

#[test]
fn dropping_a_deriving_load_waits_for_its_cache_write() {
    // The write runs on its own thread; the last clone of the atlas waits for it, so the next
    // load reads a whole file even when nobody asked for the status.
    let d = tempfile::tempdir().unwrap();
    small_phantom(d.path());
    let first = stylet_atlas::load(d.path()).unwrap();
    let clone = first.clone();
    drop(first);
    drop(clone);
    let leftovers: Vec<_> = fs::read_dir(d.path().join(CACHE_DIR))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".partial"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
    let second = stylet_atlas::load(d.path()).unwrap();
    assert_eq!(second.cache_status(), CacheStatus::Hit);
    assert_same_as_derived(&second);
}

#[test]
fn a_cache_of_other_content_is_not_used_and_is_replaced() {
    let d = tempfile::tempdir().unwrap();
    small_phantom(d.path());
    let before = stylet_atlas::load(d.path()).unwrap();
    assert_eq!(before.cache_status(), CacheStatus::Written);
    // The same volumes under an edited manifest: other content, so the old cache must not serve
    // it, and is removed once the new one is written.
    let manifest = d.path().join("atlas.toml");
    let text = fs::read_to_string(&manifest).unwrap();
    fs::write(&manifest, format!("# edited\n{text}")).unwrap();
    let after = stylet_atlas::load(d.path()).unwrap();
    assert_ne!(after.content_hash, before.content_hash);
    assert_eq!(after.cache_status(), CacheStatus::Written);
    assert!(!file_of(&before).exists(), "the cache of the old content is left");
    assert!(file_of(&after).is_file());
    // A cache file copied under the name of other content is refused by its header.
    fs::copy(file_of(&after), file_of(&before)).unwrap();
    fs::write(&manifest, &text).unwrap();
    assert_rebuilt(d.path(), "other atlas content");
}

#[test]
fn a_cache_that_cannot_be_written_never_fails_a_load() {
    let d = tempfile::tempdir().unwrap();
    let (ct, labels) = tiny_volumes();
    stylet_atlas::write(d.path(), &tiny_manifest(), &ct, &labels).unwrap();
    fs::write(d.path().join(CACHE_DIR), b"a file where the cache folder would be").unwrap();
    for _ in 0..2 {
        let a = stylet_atlas::load(d.path()).unwrap();
        match &a.cache_status() {
            CacheStatus::NotWritten { error } => assert!(error.contains(CACHE_DIR), "{error}"),
            other => panic!("{other:?}"),
        }
        assert_same_as_derived(&a);
    }
}
