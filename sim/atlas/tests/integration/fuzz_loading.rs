//! Property-based fuzzing of the atlas loading paths: `atlas.toml` parsing and NIfTI reading never
//! panic, whatever the bytes; they return Ok or an error naming the file.

use std::fs;
use std::path::Path;
use std::sync::OnceLock;

use crate::common::write_tiny;
use proptest::prelude::*;
use stylet_atlas::nifti_io::{read_ct, read_labels};
use stylet_atlas::store::parse_manifest;

/// A valid manifest, a raw `.nii` CT and a `.nii.gz` label map to mutate.
struct Seeds {
    manifest: String,
    ct_nii: Vec<u8>,
    labels_gz: Vec<u8>,
}

fn seeds() -> &'static Seeds {
    static S: OnceLock<Seeds> = OnceLock::new();
    S.get_or_init(|| {
        let d = tempfile::tempdir().unwrap();
        write_tiny(d.path());
        let (ct, _) = crate::common::tiny_volumes();
        let raw = d.path().join("ct.nii");
        stylet_atlas::nifti_io::write_ct(&raw, &ct, "seed").unwrap();
        Seeds {
            manifest: fs::read_to_string(d.path().join("atlas.toml")).unwrap(),
            ct_nii: fs::read(&raw).unwrap(),
            labels_gz: fs::read(d.path().join("labels.nii.gz")).unwrap(),
        }
    })
}

/// Byte-level mutations: overwrite, delete or insert at random places, or truncate.
#[derive(Debug, Clone)]
enum Mutation {
    Set(usize, u8),
    Delete(usize),
    Insert(usize, u8),
    Truncate(usize),
}

fn mutations() -> impl Strategy<Value = Vec<Mutation>> {
    let one = prop_oneof![
        (any::<usize>(), any::<u8>()).prop_map(|(i, b)| Mutation::Set(i, b)),
        any::<usize>().prop_map(Mutation::Delete),
        (any::<usize>(), any::<u8>()).prop_map(|(i, b)| Mutation::Insert(i, b)),
        any::<usize>().prop_map(Mutation::Truncate),
    ];
    prop::collection::vec(one, 1..8)
}

/// Mutations biased to the first `hot` bytes (a NIfTI header is 348 bytes).
fn apply(bytes: &[u8], muts: &[Mutation], hot: usize) -> Vec<u8> {
    let mut b = bytes.to_vec();
    for m in muts {
        if b.is_empty() {
            break;
        }
        let at = |i: usize| {
            if i.is_multiple_of(2) {
                (i / 2) % hot.min(b.len())
            } else {
                (i / 2) % b.len()
            }
        };
        match *m {
            Mutation::Set(i, v) => {
                let k = at(i);
                b[k] = v;
            }
            Mutation::Delete(i) => {
                let k = at(i);
                b.remove(k);
            }
            Mutation::Insert(i, v) => {
                let k = at(i);
                b.insert(k, v);
            }
            Mutation::Truncate(i) => {
                let k = i % (b.len() + 1);
                b.truncate(k);
            }
        }
    }
    b
}

fn check_error_names(path: &Path, r: Result<impl Sized, stylet_atlas::AtlasError>) {
    if let Err(e) = r {
        let msg = e.to_string();
        assert!(
            msg.contains(&path.display().to_string()),
            "error {msg:?} does not name {}",
            path.display()
        );
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 1024, ..ProptestConfig::default() })]

    #[test]
    fn manifest_parsing_never_panics_on_arbitrary_text(text in "\\PC{0,400}") {
        let _ = parse_manifest(&text);
    }

    #[test]
    fn manifest_parsing_never_panics_on_mutated_manifests(muts in mutations()) {
        let bytes = apply(seeds().manifest.as_bytes(), &muts, usize::MAX);
        if let Ok(text) = String::from_utf8(bytes) {
            let _ = parse_manifest(&text);
        }
    }

    #[test]
    fn nifti_reading_never_panics_on_mutated_raw_files(muts in mutations()) {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("ct.nii");
        fs::write(&p, apply(&seeds().ct_nii, &muts, 352)).unwrap();
        check_error_names(&p, read_ct(&p));
        check_error_names(&p, read_labels(&p));
    }

    #[test]
    fn nifti_reading_never_panics_on_mutated_gzip_files(muts in mutations()) {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("labels.nii.gz");
        fs::write(&p, apply(&seeds().labels_gz, &muts, 64)).unwrap();
        check_error_names(&p, read_labels(&p));
        check_error_names(&p, read_ct(&p));
    }

    #[test]
    fn nifti_reading_never_panics_on_random_bytes(bytes in prop::collection::vec(any::<u8>(), 0..2048)) {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("x.nii");
        fs::write(&p, &bytes).unwrap();
        check_error_names(&p, read_ct(&p));
    }

    /// Whole-directory loading with a mutated manifest or a mutated volume.
    #[test]
    fn atlas_loading_never_panics(muts in mutations(), which in 0usize..3) {
        let d = tempfile::tempdir().unwrap();
        write_tiny(d.path());
        let s = seeds();
        match which {
            0 => fs::write(d.path().join("atlas.toml"), apply(s.manifest.as_bytes(), &muts, usize::MAX)).unwrap(),
            1 => fs::write(d.path().join("labels.nii.gz"), apply(&s.labels_gz, &muts, 64)).unwrap(),
            _ => fs::write(d.path().join("ct.nii.gz"), apply(&s.ct_nii, &muts, 352)).unwrap(),
        }
        let _ = stylet_atlas::load(d.path());
    }
}
