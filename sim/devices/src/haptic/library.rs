//! Finding a vendor's library at run time: the path the user gives (`--device-library`), else the
//! library's names in the directories of `LD_LIBRARY_PATH` and the usual install locations; a
//! versioned name (`libHD.so.3.4.0`, as OpenHaptics installs it) counts too.

use std::path::{Path, PathBuf};

use super::{Backend, HapticError};

/// Where and under which names a vendor installs its library.
#[derive(Debug, Clone, Copy)]
pub struct LibrarySpec {
    pub backend: Backend,
    /// File names tried as they are ("libHD.so"), and as prefixes of versioned names
    /// ("libHD.so.3.4.0").
    pub names: &'static [&'static str],
    /// Install directories tried after `LD_LIBRARY_PATH`.
    pub dirs: &'static [&'static str],
}

/// The candidate files for `spec`, in the order they are tried: `explicit` alone when given.
pub fn candidates(spec: &LibrarySpec, explicit: Option<&Path>) -> Vec<PathBuf> {
    if let Some(p) = explicit {
        return vec![p.to_path_buf()];
    }
    let mut dirs: Vec<PathBuf> = std::env::var_os("LD_LIBRARY_PATH")
        .map(|v| std::env::split_paths(&v).collect())
        .unwrap_or_default();
    dirs.extend(spec.dirs.iter().map(PathBuf::from));
    let mut out = Vec::new();
    for dir in dirs {
        for name in spec.names {
            let exact = dir.join(name);
            if !out.contains(&exact) {
                out.push(exact);
            }
            // Versioned names, newest last by name order.
            if let Ok(entries) = std::fs::read_dir(&dir) {
                let mut versioned: Vec<PathBuf> = entries
                    .filter_map(|e| e.ok())
                    .map(|e| e.path())
                    .filter(|p| {
                        p.file_name()
                            .and_then(|f| f.to_str())
                            .is_some_and(|f| f.len() > name.len() && f.starts_with(&format!("{name}.")))
                    })
                    .collect();
                versioned.sort();
                for p in versioned.into_iter().rev() {
                    if !out.contains(&p) {
                        out.push(p);
                    }
                }
            }
        }
    }
    out
}

/// Loads the first candidate that exists and loads; the error names every path tried.
pub fn load(spec: &LibrarySpec, explicit: Option<&Path>) -> Result<(libloading::Library, PathBuf), HapticError> {
    let tried = candidates(spec, explicit);
    let mut last_failure = None;
    for path in &tried {
        if !path.is_file() {
            continue;
        }
        // SAFETY: loading a vendor library runs its initialisers; that is what using its SDK
        // means. Only files at the vendor's names (or the one the user named) are loaded.
        match unsafe { libloading::Library::new(path) } {
            Ok(lib) => return Ok((lib, path.clone())),
            Err(e) => last_failure = Some((path.clone(), e.to_string())),
        }
    }
    match last_failure {
        Some((path, reason)) => Err(HapticError::Library {
            backend: spec.backend,
            path,
            reason,
        }),
        None => Err(HapticError::LibraryNotFound {
            backend: spec.backend,
            tried,
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SPEC: LibrarySpec = LibrarySpec {
        backend: Backend::OpenHaptics,
        names: &["libHD.so"],
        dirs: &[],
    };

    #[test]
    fn a_missing_library_names_every_path_tried() {
        let e = load(&SPEC, Some(Path::new("/nonexistent/libHD.so"))).unwrap_err();
        assert_eq!(
            e.to_string(),
            "openhaptics: no vendor library found (tried /nonexistent/libHD.so); install the vendor's SDK \
             or name the library with --device-library"
        );
    }

    #[test]
    fn a_file_that_is_no_library_is_named_with_the_loader_reason() {
        let d = tempfile::tempdir().unwrap();
        let fake = d.path().join("libHD.so");
        std::fs::write(&fake, b"not an ELF file").unwrap();
        let e = load(&SPEC, Some(&fake)).unwrap_err().to_string();
        assert!(e.starts_with(&format!("openhaptics: {}: ", fake.display())), "{e}");
    }

    #[test]
    fn versioned_names_are_found_beside_the_plain_one() {
        let d = tempfile::tempdir().unwrap();
        for f in ["libHD.so.3.4.0", "libHD.so.3.0.0", "libHDU.so", "other.so"] {
            std::fs::write(d.path().join(f), b"").unwrap();
        }
        let dir: &'static str = Box::leak(d.path().to_str().unwrap().to_string().into_boxed_str());
        let spec = LibrarySpec {
            dirs: Box::leak(vec![dir].into_boxed_slice()),
            ..SPEC
        };
        let c = candidates(&spec, None);
        let here: Vec<&Path> = c
            .iter()
            .filter(|p| p.starts_with(d.path()))
            .map(PathBuf::as_path)
            .collect();
        assert_eq!(
            here,
            vec![
                d.path().join("libHD.so").as_path(),
                d.path().join("libHD.so.3.4.0").as_path(),
                d.path().join("libHD.so.3.0.0").as_path(),
            ]
        );
    }
}
