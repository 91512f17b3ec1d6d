//! The client side of publishing an atlas (`stylet atlas publish`; docs/api.md "Atlases"): the
//! atlas is checked here first (its validation record must vouch for its current content, so a
//! stale atlas is not uploaded only to be refused), packed as one tar archive of exactly the
//! files the service accepts, and streamed to `POST /api/atlases`.

use std::io::{Seek, SeekFrom};
use std::path::Path;

use serde_json::Value;
use stylet_atlas::store::{MANIFEST_FILE, content_hash, parse_manifest};
use stylet_atlas::validation::{self, SCRIPTS_DIR, VALIDATION_FILE};

use crate::service_client::ServiceClient;

/// Why an atlas was not published.
#[derive(Debug, thiserror::Error)]
pub enum PublishError {
    /// The atlas folder cannot be published as it is (nothing was sent).
    #[error("{0}")]
    Atlas(String),
    /// The service refused it, with its reason.
    #[error("the service refused the atlas ({status}): {reason}")]
    Refused { status: u16, reason: String },
    #[error("the service cannot be reached or broke off: {0}")]
    Unavailable(String),
}

/// What the service said to a publication that went through.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Published {
    pub content_hash: String,
    pub name: String,
    /// False: the service had this atlas already.
    pub new: bool,
    /// The service's own smoke test, one line per script.
    pub smoke: Vec<String>,
}

/// How far a publication got, for a progress display.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PublishProgress {
    /// Checked and packed: the archive's size.
    Packed { bytes: u64 },
    /// Bytes of the archive sent so far.
    Sent { bytes: u64, total: u64 },
    /// All sent: the service is checking the atlas and running its smoke test.
    Checking,
}

/// A reader that reports how much of the archive has been read (sent).
struct Reporting<'a, R> {
    inner: R,
    sent: u64,
    total: u64,
    progress: &'a dyn Fn(PublishProgress),
}

impl<R: std::io::Read> std::io::Read for Reporting<'_, R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        if n > 0 {
            self.sent += n as u64;
            (self.progress)(PublishProgress::Sent {
                bytes: self.sent,
                total: self.total,
            });
            if self.sent == self.total {
                (self.progress)(PublishProgress::Checking);
            }
        }
        Ok(n)
    }
}

/// The packed archive, in a temporary file removed when dropped.
pub struct Packed {
    pub file: std::fs::File,
    pub bytes: u64,
    pub content_hash: String,
    pub name: String,
}

/// Checks the atlas in `dir` (its manifest, its content hash against its validation record) and
/// packs `atlas.toml`, `validation.toml`, the two volumes, the record's scripts and the measured
/// breathing motion (`motion/`), if any.
pub fn pack(dir: &Path) -> Result<Packed, PublishError> {
    let fail = |m: String| PublishError::Atlas(format!("{}: {m}", dir.display()));
    let manifest_text =
        std::fs::read_to_string(dir.join(MANIFEST_FILE)).map_err(|e| fail(format!("{MANIFEST_FILE}: {e}")))?;
    let manifest = parse_manifest(&manifest_text).map_err(|e| fail(format!("{MANIFEST_FILE}: {e}")))?;
    let hash = content_hash(dir, &manifest).map_err(|e| PublishError::Atlas(e.to_string()))?;
    let record = validation::read_record(dir)
        .map_err(|e| PublishError::Atlas(e.to_string()))?
        .ok_or(validation::NotValidated::Missing)
        .and_then(|r| r.vouches_for(&hash).map(|()| r))
        .map_err(|e| fail(format!("not validated: {e}")))?;
    let file = tempfile::tempfile().map_err(|e| fail(format!("cannot make a temporary file: {e}")))?;
    let mut tar = tar::Builder::new(file);
    let mut add = |name: &str| {
        tar.append_path_with_name(dir.join(name), name)
            .map_err(|e| fail(format!("{name}: {e}")))
    };
    add(MANIFEST_FILE)?;
    add(VALIDATION_FILE)?;
    add(&manifest.volumes.ct)?;
    add(&manifest.volumes.labels)?;
    for s in &record.smoke {
        add(&format!("{SCRIPTS_DIR}/{}", s.script))?;
    }
    // Measured breathing motion: the files travel under the names atlas.toml gives them, which
    // the content hash covers; the service takes them from motion/ only.
    for name in manifest.breathing_or_default().measured_files() {
        if !name.starts_with("motion/") || name.matches('/').count() != 1 {
            return Err(fail(format!(
                "{MANIFEST_FILE} names the breathing file {name} outside motion/; attach it with stylet atlas attach-motion"
            )));
        }
        add(name)?;
    }
    let mut file = tar.into_inner().map_err(|e| fail(format!("packing: {e}")))?;
    let bytes = file.seek(SeekFrom::End(0)).map_err(|e| fail(e.to_string()))?;
    file.seek(SeekFrom::Start(0)).map_err(|e| fail(e.to_string()))?;
    Ok(Packed {
        file,
        bytes,
        content_hash: hash,
        name: manifest.name,
    })
}

fn reason_of(resp: ureq::Response) -> String {
    let status = resp.status();
    resp.into_string()
        .ok()
        .and_then(|b| serde_json::from_str::<Value>(&b).ok())
        .and_then(|v| v["error"].as_str().map(str::to_string))
        .unwrap_or_else(|| format!("HTTP {status}"))
}

/// What the service said to a withdrawal.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Withdrawn {
    pub content_hash: String,
    pub name: String,
}

impl ServiceClient {
    /// Withdraws the atlas `content_hash` from the service's catalogue with an admin's `full` API
    /// token (`DELETE /api/atlases/{hash}`): it takes no new sessions; those recorded on it stay.
    pub fn unpublish_atlas(&self, token: &str, content_hash: &str) -> Result<Withdrawn, PublishError> {
        let agent = ureq::AgentBuilder::new()
            .timeout_connect(std::time::Duration::from_secs(5))
            .timeout(std::time::Duration::from_secs(60))
            .build();
        let resp = agent
            .delete(&format!("{}/api/atlases/{content_hash}", self.base()))
            .set("Authorization", &format!("Bearer {token}"))
            .call();
        match resp {
            Ok(r) => {
                let body: Value = r
                    .into_string()
                    .ok()
                    .and_then(|b| serde_json::from_str(&b).ok())
                    .ok_or_else(|| PublishError::Unavailable("the service's answer was not understood".into()))?;
                Ok(Withdrawn {
                    content_hash: body["content_hash"].as_str().unwrap_or_default().to_string(),
                    name: body["name"].as_str().unwrap_or_default().to_string(),
                })
            }
            Err(ureq::Error::Status(status, r)) => Err(PublishError::Refused {
                status,
                reason: reason_of(r),
            }),
            Err(ureq::Error::Transport(t)) => Err(PublishError::Unavailable(t.to_string())),
        }
    }

    /// Publishes the atlas in `dir` with an admin's or instructor's `full` API token.
    pub fn publish_atlas(&self, token: &str, dir: &Path) -> Result<Published, PublishError> {
        self.publish_atlas_with(token, dir, &|_| {})
    }

    /// [`Self::publish_atlas`], telling `progress` how far it got.
    pub fn publish_atlas_with(
        &self,
        token: &str,
        dir: &Path,
        progress: &dyn Fn(PublishProgress),
    ) -> Result<Published, PublishError> {
        let packed = pack(dir)?;
        progress(PublishProgress::Packed { bytes: packed.bytes });
        match self.post_archive(token, Some((&packed, progress))) {
            Err(PublishError::Unavailable(reason)) => {
                // The service refuses a caller (or a size) before it reads the body, and the
                // refusal is then often lost under a broken pipe: ask again without a body.
                match self.post_archive(token, None) {
                    Err(refused @ PublishError::Refused { status: 401 | 403, .. }) => Err(refused),
                    _ if reason.contains("Broken pipe") || reason.contains("reset") => {
                        Err(PublishError::Unavailable(format!(
                            "{reason} (the archive is {} bytes: the service may accept less, see `stylet serve --max-atlas-bytes`)",
                            packed.bytes
                        )))
                    }
                    _ => Err(PublishError::Unavailable(reason)),
                }
            }
            other => other,
        }
    }

    fn post_archive(
        &self,
        token: &str,
        packed: Option<(&Packed, &dyn Fn(PublishProgress))>,
    ) -> Result<Published, PublishError> {
        // The service loads the atlas and runs its smoke test before it answers (up to its
        // `atlas_check_timeout`, 5 minutes by default): wait that long for the answer.
        let agent = ureq::AgentBuilder::new()
            .timeout_connect(std::time::Duration::from_secs(5))
            .timeout_write(std::time::Duration::from_secs(60))
            .timeout_read(std::time::Duration::from_secs(330))
            .build();
        let req = agent
            .post(&format!("{}/api/atlases", self.base()))
            .set("Authorization", &format!("Bearer {token}"))
            .set("Content-Type", "application/x-tar");
        let resp = match packed {
            Some((p, progress)) => {
                let file = p.file.try_clone().map_err(|e| PublishError::Atlas(e.to_string()))?;
                let reader = Reporting {
                    inner: file,
                    sent: 0,
                    total: p.bytes,
                    progress,
                };
                req.set("Content-Length", &p.bytes.to_string()).send(reader)
            }
            None => req.send_bytes(&[]),
        };
        match resp {
            Ok(r) => {
                let new = r.status() == 201;
                let body: Value = r
                    .into_string()
                    .ok()
                    .and_then(|b| serde_json::from_str(&b).ok())
                    .ok_or_else(|| PublishError::Unavailable("the service's answer was not understood".into()))?;
                Ok(Published {
                    content_hash: body["content_hash"].as_str().unwrap_or_default().to_string(),
                    name: body["name"].as_str().unwrap_or_default().to_string(),
                    new,
                    smoke: body["smoke"]
                        .as_array()
                        .map(|a| a.iter().filter_map(|s| s.as_str().map(str::to_string)).collect())
                        .unwrap_or_default(),
                })
            }
            Err(ureq::Error::Status(status, r)) => Err(PublishError::Refused {
                status,
                reason: reason_of(r),
            }),
            Err(ureq::Error::Transport(t)) => Err(PublishError::Unavailable(t.to_string())),
        }
    }
}
