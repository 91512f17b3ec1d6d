//! The simulator's login to a scoring service: the server's address, the account and an
//! upload-only API token, kept in the OS configuration directory (`$XDG_CONFIG_HOME/stylet` or
//! `~/.config/stylet` on Linux) in a file only the user may read (mode 0600). The password is
//! never stored.

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

/// File name of the credentials in the configuration directory.
pub const FILE_NAME: &str = "credentials.json";

#[derive(Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Credentials {
    pub server_url: String,
    pub username: String,
    /// An API token of scope `upload` (docs/api.md "API tokens").
    pub token: String,
}

impl std::fmt::Debug for Credentials {
    /// Never prints the token.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Credentials")
            .field("server_url", &self.server_url)
            .field("username", &self.username)
            .field("token", &"…")
            .finish()
    }
}

#[derive(Debug, thiserror::Error)]
pub enum CredentialsError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path} is not a Stylet credentials file: {reason}")]
    Invalid { path: PathBuf, reason: String },
    #[error("{path} may be read by other users (mode {mode:o}); it must be 600. Log in again to rewrite it")]
    Exposed { path: PathBuf, mode: u32 },
    #[error("no configuration directory (set HOME or XDG_CONFIG_HOME)")]
    NoConfigDir,
}

/// Stylet's configuration directory.
pub fn config_dir() -> Result<PathBuf, CredentialsError> {
    dirs::config_dir()
        .map(|d| d.join("stylet"))
        .ok_or(CredentialsError::NoConfigDir)
}

impl Credentials {
    /// Writes the credentials to `dir/credentials.json`, readable by the user only; replaces an
    /// older file atomically.
    pub fn save(&self, dir: &Path) -> Result<PathBuf, CredentialsError> {
        save_private(dir, FILE_NAME, self)
    }

    /// Reads `dir/credentials.json`; `None` when there is none (not logged in). Refuses a file
    /// others may read.
    pub fn load(dir: &Path) -> Result<Option<Credentials>, CredentialsError> {
        load_private(dir, FILE_NAME)
    }
}

/// File name of a lab machine's pairing in the configuration directory.
pub const LAB_FILE_NAME: &str = "lab-machine.json";

/// This computer as a lab machine of a cohort (paired with a lab code): trainees of the cohort
/// sign in on it in turn with their own codes; their tokens are kept in memory only.
#[derive(Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LabMachine {
    pub server_url: String,
    pub cohort: String,
    /// The lab token: it may only exchange sign-in codes (docs/integration.md).
    pub lab_token: String,
}

impl std::fmt::Debug for LabMachine {
    /// Never prints the token.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LabMachine")
            .field("server_url", &self.server_url)
            .field("cohort", &self.cohort)
            .field("lab_token", &"…")
            .finish()
    }
}

impl LabMachine {
    /// Writes `dir/lab-machine.json`, readable by the user only.
    pub fn save(&self, dir: &Path) -> Result<PathBuf, CredentialsError> {
        save_private(dir, LAB_FILE_NAME, self)
    }

    /// Reads `dir/lab-machine.json`; `None` when this is no lab machine.
    pub fn load(dir: &Path) -> Result<Option<LabMachine>, CredentialsError> {
        load_private(dir, LAB_FILE_NAME)
    }

    /// Makes this computer an ordinary simulator again.
    pub fn forget(dir: &Path) {
        let _ = fs::remove_file(dir.join(LAB_FILE_NAME));
    }
}

/// Writes `value` as JSON to `dir/name`, readable by the user only (mode 0600); replaces an
/// older file atomically.
fn save_private(dir: &Path, name: &str, value: &impl Serialize) -> Result<PathBuf, CredentialsError> {
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| CredentialsError::Io { path, source }
    };
    fs::create_dir_all(dir).map_err(io(dir))?;
    let path = dir.join(name);
    let tmp = dir.join(format!(".{name}.tmp"));
    let _ = fs::remove_file(&tmp);
    let mut options = fs::OpenOptions::new();
    options.write(true).create_new(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        options.mode(0o600);
    }
    let mut f = options.open(&tmp).map_err(io(&tmp))?;
    let json = serde_json::to_vec_pretty(value).expect("plain strings serialise");
    f.write_all(&json).map_err(io(&tmp))?;
    f.sync_all().map_err(io(&tmp))?;
    fs::rename(&tmp, &path).map_err(io(&path))?;
    Ok(path)
}

/// Reads the JSON file `dir/name`; `None` when there is none. Refuses a file others may read.
fn load_private<T: serde::de::DeserializeOwned>(dir: &Path, name: &str) -> Result<Option<T>, CredentialsError> {
    let path = dir.join(name);
    let meta = match fs::metadata(&path) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(source) => return Err(CredentialsError::Io { path, source }),
    };
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        let mode = meta.permissions().mode() & 0o777;
        if mode & 0o077 != 0 {
            return Err(CredentialsError::Exposed { path, mode });
        }
    }
    if meta.len() > 64 * 1024 {
        return Err(CredentialsError::Invalid {
            path,
            reason: "larger than 64 KiB".into(),
        });
    }
    let text = fs::read(&path).map_err(|source| CredentialsError::Io {
        path: path.clone(),
        source,
    })?;
    serde_json::from_slice(&text)
        .map(Some)
        .map_err(|e| CredentialsError::Invalid {
            path,
            reason: e.to_string(),
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn credentials_are_kept_for_the_user_only() {
        let dir = tempfile::tempdir().unwrap();
        let c = Credentials {
            server_url: "https://stylet.example.org".into(),
            username: "tina".into(),
            token: "ab".repeat(32),
        };
        assert_eq!(Credentials::load(dir.path()).unwrap(), None);
        let path = c.save(dir.path()).unwrap();
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            assert_eq!(fs::metadata(&path).unwrap().permissions().mode() & 0o777, 0o600);
            assert_eq!(Credentials::load(dir.path()).unwrap(), Some(c.clone()));
            fs::set_permissions(&path, fs::Permissions::from_mode(0o644)).unwrap();
            let e = Credentials::load(dir.path()).unwrap_err();
            assert!(e.to_string().contains("must be 600"), "{e}");
            // Saving again rewrites it private.
            c.save(dir.path()).unwrap();
            assert_eq!(fs::metadata(&path).unwrap().permissions().mode() & 0o777, 0o600);
        }
        fs::write(&path, "{\"server_url\": 1}").unwrap();
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            fs::set_permissions(&path, fs::Permissions::from_mode(0o600)).unwrap();
        }
        let e = Credentials::load(dir.path()).unwrap_err();
        assert!(e.to_string().contains("not a Stylet credentials file"), "{e}");
    }

    #[test]
    fn a_lab_machines_pairing_is_kept_private_and_forgotten() {
        let dir = tempfile::tempdir().unwrap();
        let lab = LabMachine {
            server_url: "https://stylet.example.org".into(),
            cohort: "c1".into(),
            lab_token: "cd".repeat(32),
        };
        assert_eq!(LabMachine::load(dir.path()).unwrap(), None);
        let path = lab.save(dir.path()).unwrap();
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            assert_eq!(fs::metadata(&path).unwrap().permissions().mode() & 0o777, 0o600);
        }
        assert_eq!(LabMachine::load(dir.path()).unwrap(), Some(lab.clone()));
        assert!(!format!("{lab:?}").contains("cdcd"));
        // A lab machine's file is not an account's credentials, nor the other way round.
        assert_eq!(Credentials::load(dir.path()).unwrap(), None);
        LabMachine::forget(dir.path());
        assert_eq!(LabMachine::load(dir.path()).unwrap(), None);
    }
}
