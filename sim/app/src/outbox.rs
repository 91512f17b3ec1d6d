//! The outbox: finished sessions waiting to be uploaded to the scoring service. A session is
//! never lost: it enters the outbox completely or not at all (copied to a temporary name, synced,
//! renamed), and leaves it only when the service has confirmed it (201, or 200 for bytes it
//! already had). A server that is down leaves everything in place for the next round; a file the
//! service refuses moves to `refused/` with the reason beside it, for the trainee to see.
//!
//! Layout: `DIR/*.mcap` waiting, oldest name first; `DIR/refused/NAME.mcap` and `NAME.txt`;
//! `DIR/.incoming-*` a copy cut short by a crash (removed when the outbox is opened; the
//! original recording is still where it was written).

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use crate::upload::{MAX_SESSION_BYTES, UploadReply, Uploader};

/// Errors of the outbox's own files.
#[derive(Debug, thiserror::Error)]
pub enum OutboxError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path} is not a finished session file: {reason}")]
    NotASession {
        path: PathBuf,
        #[source]
        reason: stylet_recorder::VerifyError,
    },
    #[error("{path} is {bytes} bytes, more than the {MAX_SESSION_BYTES} an upload may be")]
    TooLarge { path: PathBuf, bytes: u64 },
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> OutboxError + '_ {
    move |source| OutboxError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// What one upload round did.
#[derive(Debug, Default, Clone, PartialEq, Eq)]
pub struct Round {
    /// Confirmed by the service and removed: (file name, session id on the service).
    pub uploaded: Vec<(String, String)>,
    /// Refused by the service and moved to `refused/`: (file name, reason).
    pub refused: Vec<(String, String)>,
    /// Still waiting (server down, or the token needs a new login): (file name, reason).
    pub waiting: Vec<(String, String)>,
    /// The token was refused: log in again before the next round.
    pub needs_login: bool,
}

/// A directory of sessions waiting for upload. Clones share one lock, so rounds of one process
/// never run at the same time (two processes on one outbox are not supported).
#[derive(Debug, Clone)]
pub struct Outbox {
    dir: PathBuf,
    round: std::sync::Arc<std::sync::Mutex<()>>,
}

impl Outbox {
    /// Opens (creating) the outbox at `dir` and clears copies a crash cut short.
    pub fn open(dir: &Path) -> Result<Outbox, OutboxError> {
        fs::create_dir_all(dir.join("refused")).map_err(io(dir))?;
        for entry in fs::read_dir(dir).map_err(io(dir))? {
            let entry = entry.map_err(io(dir))?;
            if entry.file_name().to_string_lossy().starts_with(".incoming-") {
                let p = entry.path();
                fs::remove_file(&p).map_err(io(&p))?;
            }
        }
        Ok(Outbox {
            dir: dir.to_path_buf(),
            round: Default::default(),
        })
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Puts a finished session file in the outbox (the file itself stays where it is). Checks
    /// that it is a complete session first; returns its name in the outbox.
    pub fn add(&self, session: &Path) -> Result<String, OutboxError> {
        let bytes = fs::metadata(session).map_err(io(session))?.len();
        if bytes > MAX_SESSION_BYTES {
            return Err(OutboxError::TooLarge {
                path: session.to_path_buf(),
                bytes,
            });
        }
        let data = fs::read(session).map_err(io(session))?;
        let checked = stylet_recorder::reader::verify_bytes(&data).map_err(|reason| OutboxError::NotASession {
            path: session.to_path_buf(),
            reason,
        })?;
        // Oldest first by name: milliseconds since 1970, then the session id.
        let ms = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| d.as_millis());
        let id: String = checked
            .header
            .session_id
            .chars()
            .filter(|c| c.is_ascii_alphanumeric() || *c == '-')
            .take(64)
            .collect();
        let _round = self.round.lock();
        // A name not in use (the same millisecond and id: a suffix).
        let mut name = format!("{ms:015}-{id}.mcap");
        let mut n = 1;
        while self.dir.join(&name).exists() {
            name = format!("{ms:015}-{id}-{n}.mcap");
            n += 1;
        }
        let incoming = self.dir.join(format!(".incoming-{name}"));
        let mut f = fs::File::create(&incoming).map_err(io(&incoming))?;
        f.write_all(&data).map_err(io(&incoming))?;
        f.sync_all().map_err(io(&incoming))?;
        drop(f);
        let target = self.dir.join(&name);
        fs::rename(&incoming, &target).map_err(io(&target))?;
        sync_dir(&self.dir);
        Ok(name)
    }

    /// Names of the sessions waiting, oldest first.
    pub fn pending(&self) -> Result<Vec<String>, OutboxError> {
        let mut names: Vec<String> = fs::read_dir(&self.dir)
            .map_err(io(&self.dir))?
            .filter_map(Result::ok)
            .filter(|e| e.file_type().is_ok_and(|t| t.is_file()))
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| n.ends_with(".mcap") && !n.starts_with('.'))
            .collect();
        names.sort();
        Ok(names)
    }

    /// Names of the sessions the service refused, with its reasons.
    pub fn refused(&self) -> Result<Vec<(String, String)>, OutboxError> {
        let dir = self.dir.join("refused");
        let mut out = Vec::new();
        for name in (Outbox {
            dir: dir.clone(),
            round: Default::default(),
        })
        .pending()?
        {
            let reason = fs::read_to_string(dir.join(format!("{name}.txt"))).unwrap_or_default();
            out.push((name, reason.trim().to_string()));
        }
        Ok(out)
    }

    /// Tries to upload every waiting session, oldest first. Stops at the first sign that the
    /// service is unavailable or the account may not upload (the rest wait for the next round).
    /// A file that cannot be read is reported and skipped; the others go on.
    pub fn upload_all(&self, uploader: &dyn Uploader) -> Result<Round, OutboxError> {
        self.upload_all_until(uploader, &|| false)
    }

    /// [`Self::upload_all`], checking `stop` before each file (a closing window).
    pub fn upload_all_until(&self, uploader: &dyn Uploader, stop: &dyn Fn() -> bool) -> Result<Round, OutboxError> {
        let _round = self.round.lock();
        let mut round = Round::default();
        let mut halt: Option<String> = None;
        for name in self.pending()? {
            if halt.is_none() && stop() {
                halt = Some("the simulator is closing: will retry".into());
            }
            if let Some(reason) = &halt {
                round.waiting.push((name, reason.clone()));
                continue;
            }
            let path = self.dir.join(&name);
            // Files placed here by hand are bounded like those `add` takes.
            if let Ok(m) = fs::metadata(&path)
                && m.len() > MAX_SESSION_BYTES
            {
                round.waiting.push((
                    name,
                    format!(
                        "{} bytes, more than the {MAX_SESSION_BYTES} an upload may be: not sent",
                        m.len()
                    ),
                ));
                continue;
            }
            let data = match fs::read(&path) {
                Ok(d) => d,
                // Gone since the listing: nothing to do.
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => continue,
                Err(e) => {
                    round.waiting.push((name, format!("cannot read it ({e}): will retry")));
                    continue;
                }
            };
            match uploader.upload(&data) {
                UploadReply::Accepted { id, .. } => {
                    match fs::remove_file(&path) {
                        Ok(()) => {}
                        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                        // Confirmed but still here: the next round sends it again and the
                        // service recognises it (200, same id).
                        Err(e) => {
                            round
                                .waiting
                                .push((name.clone(), format!("uploaded, but cannot be removed ({e})")));
                        }
                    }
                    round.uploaded.push((name, id));
                }
                UploadReply::Refused { status, reason } => {
                    let why = format!("refused by the server ({status}): {reason}");
                    let target = self.dir.join("refused").join(&name);
                    let note = self.dir.join("refused").join(format!("{name}.txt"));
                    match fs::write(&note, format!("{why}\n")).and_then(|()| fs::rename(&path, &target)) {
                        Ok(()) => round.refused.push((name, why)),
                        Err(e) => round.waiting.push((name, format!("{why}; cannot move it aside ({e})"))),
                    }
                }
                UploadReply::Unauthorized { reason } => {
                    round.needs_login = true;
                    let why = format!("the server refused the token ({reason}): log in again");
                    round.waiting.push((name, why.clone()));
                    halt = Some(why);
                }
                // This account may not upload this file (a session of another trainee, a disabled
                // account): it waits for a login that may, and the others still go.
                UploadReply::Forbidden { reason } => {
                    let why = format!("this login may not upload it ({reason}): it waits");
                    round.waiting.push((name, why));
                }
                UploadReply::Unavailable { reason } => {
                    let why = format!("the server is unavailable ({reason}): will retry");
                    round.waiting.push((name, why.clone()));
                    halt = Some(why);
                }
            }
        }
        sync_dir(&self.dir);
        Ok(round)
    }
}

/// How long the retrier waits between rounds while the service is unavailable: `first`, then
/// twice as long each time, at most `max`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Backoff {
    pub first: std::time::Duration,
    pub max: std::time::Duration,
}

impl Default for Backoff {
    fn default() -> Self {
        Backoff {
            first: std::time::Duration::from_secs(1),
            max: std::time::Duration::from_secs(60),
        }
    }
}

#[derive(Default)]
struct RetrierState {
    /// Replaced by [`Retrier::set_uploader`] (a new login).
    uploader: Option<std::sync::Arc<dyn Uploader + Send + Sync>>,
    stop: bool,
    wake: bool,
    /// The latest round, or why it could not run (shared: every caller gets the same error).
    last: Option<Result<Round, std::sync::Arc<OutboxError>>>,
    /// Every upload the service confirmed since the start: (file name, session id).
    uploaded: Vec<(String, String)>,
}

/// Uploads the outbox in the background: a round at start, after every [`Retrier::wake`] (a
/// session was added), and while sessions wait, again after a growing pause ([`Backoff`]).
pub struct Retrier {
    state: std::sync::Arc<(std::sync::Mutex<RetrierState>, std::sync::Condvar)>,
    stopping: std::sync::Arc<std::sync::atomic::AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Retrier {
    pub fn start(
        outbox: Outbox,
        uploader: std::sync::Arc<dyn Uploader + Send + Sync>,
        backoff: Backoff,
    ) -> Result<Retrier, OutboxError> {
        let state = std::sync::Arc::new((
            std::sync::Mutex::new(RetrierState {
                uploader: Some(uploader),
                ..Default::default()
            }),
            std::sync::Condvar::new(),
        ));
        let stopping = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let shared = std::sync::Arc::clone(&state);
        let stop_flag = std::sync::Arc::clone(&stopping);
        let thread = std::thread::Builder::new()
            .name("stylet-outbox".into())
            .spawn(move || {
                let (lock, cvar) = &*shared;
                let mut pause = backoff.first;
                loop {
                    let Some(uploader) = lock.lock().ok().and_then(|st| st.uploader.clone()) else {
                        return;
                    };
                    let stop = || stop_flag.load(std::sync::atomic::Ordering::Relaxed);
                    let round = outbox.upload_all_until(&*uploader, &stop);
                    let waiting = match &round {
                        Ok(r) => !r.waiting.is_empty(),
                        Err(_) => true,
                    };
                    let Ok(mut st) = lock.lock() else { return };
                    if let Ok(r) = &round {
                        st.uploaded.extend(r.uploaded.iter().cloned());
                    }
                    st.last = Some(round.map_err(std::sync::Arc::new));
                    // Wait: for a wake-up only when nothing waits; else at most the pause.
                    let deadline = std::time::Instant::now() + if waiting { pause } else { backoff.max };
                    while !st.stop && !st.wake {
                        let now = std::time::Instant::now();
                        if now >= deadline {
                            break;
                        }
                        st = match cvar.wait_timeout(st, deadline - now) {
                            Ok((g, _)) => g,
                            Err(_) => return,
                        };
                    }
                    if st.stop {
                        return;
                    }
                    if st.wake {
                        st.wake = false;
                        pause = backoff.first;
                    } else if waiting {
                        pause = (pause * 2).min(backoff.max);
                    }
                }
            })
            .map_err(|source| OutboxError::Io {
                path: PathBuf::from("(outbox thread)"),
                source,
            })?;
        Ok(Retrier {
            state,
            stopping,
            thread: Some(thread),
        })
    }

    /// Uploads with `uploader` from now on (a new login's token) and starts a round.
    pub fn set_uploader(&self, uploader: std::sync::Arc<dyn Uploader + Send + Sync>) {
        if let Ok(mut st) = self.state.0.lock() {
            st.uploader = Some(uploader);
        }
        self.wake();
    }

    /// Starts a round now (call after adding a session).
    pub fn wake(&self) {
        let (lock, cvar) = &*self.state;
        if let Ok(mut st) = lock.lock() {
            st.wake = true;
            cvar.notify_all();
        }
    }

    /// Every upload the service confirmed since the retrier started.
    pub fn uploaded(&self) -> Vec<(String, String)> {
        self.state.0.lock().map(|st| st.uploaded.clone()).unwrap_or_default()
    }

    /// What the latest round did (for the window's status line).
    pub fn last_round(&self) -> Option<Result<Round, std::sync::Arc<OutboxError>>> {
        self.state.0.lock().ok().and_then(|st| st.last.clone())
    }
}

impl Drop for Retrier {
    /// Stops after the file being sent (at most one upload's time limits).
    fn drop(&mut self) {
        self.stopping.store(true, std::sync::atomic::Ordering::Relaxed);
        let (lock, cvar) = &*self.state;
        if let Ok(mut st) = lock.lock() {
            st.stop = true;
            cvar.notify_all();
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Makes a rename or removal in `dir` durable (best effort where directories cannot be synced).
fn sync_dir(dir: &Path) {
    if let Ok(d) = fs::File::open(dir) {
        let _ = d.sync_all();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::cell::RefCell;

    /// Answers from a list, recording what it was sent.
    struct Scripted {
        replies: RefCell<Vec<UploadReply>>,
        sent: RefCell<Vec<usize>>,
    }

    impl Uploader for Scripted {
        fn upload(&self, session: &[u8]) -> UploadReply {
            self.sent.borrow_mut().push(session.len());
            self.replies.borrow_mut().remove(0)
        }
    }

    #[test]
    fn a_file_this_login_may_not_upload_waits_without_holding_up_the_others() {
        let dir = tempfile::tempdir().unwrap();
        let outbox = Outbox::open(&dir.path().join("outbox")).unwrap();
        for n in ["001-a.mcap", "002-b.mcap"] {
            fs::write(outbox.dir().join(n), n).unwrap();
        }
        let uploader = Scripted {
            replies: RefCell::new(vec![
                UploadReply::Forbidden {
                    reason: "tina may not upload sessions of trainee 'trainee'".into(),
                },
                UploadReply::Accepted {
                    id: "s2".into(),
                    new: true,
                },
            ]),
            sent: RefCell::new(Vec::new()),
        };
        let round = outbox.upload_all(&uploader).unwrap();
        assert_eq!(round.uploaded, vec![("002-b.mcap".to_string(), "s2".to_string())]);
        assert_eq!(round.waiting.len(), 1);
        assert!(round.waiting[0].1.contains("may not upload"), "{round:?}");
        assert_eq!(outbox.pending().unwrap(), vec!["001-a.mcap"]);
        assert!(outbox.refused().unwrap().is_empty());
    }

    #[test]
    fn files_that_are_not_sessions_never_enter() {
        let dir = tempfile::tempdir().unwrap();
        let outbox = Outbox::open(&dir.path().join("outbox")).unwrap();
        let junk = dir.path().join("junk.mcap");
        fs::write(&junk, b"not a session").unwrap();
        let e = outbox.add(&junk).unwrap_err();
        assert!(matches!(e, OutboxError::NotASession { .. }), "{e}");
        assert!(outbox.pending().unwrap().is_empty());
        let e = outbox.add(&dir.path().join("missing.mcap")).unwrap_err();
        assert!(e.to_string().contains("missing.mcap"), "{e}");
    }

    #[test]
    fn a_copy_cut_short_by_a_crash_is_cleared_and_never_uploaded() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("outbox");
        fs::create_dir_all(&path).unwrap();
        fs::write(path.join(".incoming-000-x.mcap"), b"half a file").unwrap();
        let outbox = Outbox::open(&path).unwrap();
        assert!(!path.join(".incoming-000-x.mcap").exists());
        let uploader = Scripted {
            replies: RefCell::new(Vec::new()),
            sent: RefCell::new(Vec::new()),
        };
        assert_eq!(outbox.upload_all(&uploader).unwrap(), Round::default());
        assert!(uploader.sent.borrow().is_empty());
    }

    #[test]
    fn rounds_keep_what_was_not_confirmed_and_file_refusals_with_the_reason() {
        let dir = tempfile::tempdir().unwrap();
        let outbox = Outbox::open(&dir.path().join("outbox")).unwrap();
        // Three waiting "sessions" (placed directly; `add` is tested with real files elsewhere).
        for n in ["001-a.mcap", "002-b.mcap", "003-c.mcap"] {
            fs::write(outbox.dir().join(n), n).unwrap();
        }
        let uploader = Scripted {
            replies: RefCell::new(vec![
                UploadReply::Accepted {
                    id: "s1".into(),
                    new: true,
                },
                UploadReply::Refused {
                    status: 422,
                    reason: "unknown atlas 'x'".into(),
                },
                UploadReply::Unavailable {
                    reason: "connection refused".into(),
                },
            ]),
            sent: RefCell::new(Vec::new()),
        };
        let round = outbox.upload_all(&uploader).unwrap();
        assert_eq!(round.uploaded, vec![("001-a.mcap".to_string(), "s1".to_string())]);
        assert_eq!(round.refused.len(), 1);
        assert_eq!(round.waiting.len(), 1);
        assert_eq!(outbox.pending().unwrap(), vec!["003-c.mcap"]);
        let refused = outbox.refused().unwrap();
        assert_eq!(refused[0].0, "002-b.mcap");
        assert!(refused[0].1.contains("unknown atlas 'x'"), "{refused:?}");
        // An unauthorised token stops the round: nothing else is tried.
        fs::write(outbox.dir().join("004-d.mcap"), "d").unwrap();
        let uploader = Scripted {
            replies: RefCell::new(vec![UploadReply::Unauthorized {
                reason: "the API token has expired".into(),
            }]),
            sent: RefCell::new(Vec::new()),
        };
        let round = outbox.upload_all(&uploader).unwrap();
        assert!(round.needs_login);
        assert_eq!(uploader.sent.borrow().len(), 1);
        assert_eq!(round.waiting.len(), 2);
        assert_eq!(outbox.pending().unwrap().len(), 2);
    }
}
