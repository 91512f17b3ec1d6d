//! Receiving a large request body (a session upload, an atlas archive) without trusting its
//! sender: chunk by chunk, never more than one chunk in memory, within its size limit, and no
//! slower than the minimum rate over any [`RATE_WINDOW_S`]-second stretch ([`MinRate`]). A sender
//! that stalls is cut off after at most that window, not after the whole body's allowance.

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::time::Duration;

use axum::body::Bytes;
use axum::http::StatusCode;
use futures_util::{Stream, StreamExt};
use sha2::Digest;
use tokio::io::AsyncWriteExt;

use super::error::{ApiError, err};

/// The stretch over which a body's rate is measured (s): every stretch this long, once the body
/// has been arriving for that long, must bring at least the minimum rate's worth of bytes.
pub const RATE_WINDOW_S: u64 = 10;

/// The minimum-rate rule of a body (see the module doc), on the clock of the time spent waiting
/// for the sender: time the server spends on its own work between chunks (writing to disk) is
/// not held against the sender. Bytes are counted in one-second buckets, so its memory is a few
/// numbers whatever the chunks.
#[derive(Debug)]
pub struct MinRate {
    /// Bytes needed in every window; 0: no minimum.
    need: u64,
    /// `(second of the waiting clock, bytes that arrived in it)`, the oldest first, at most a
    /// window's worth.
    buckets: VecDeque<(u64, u64)>,
    waited: Duration,
}

impl MinRate {
    pub fn new(min_bytes_per_s: u64) -> MinRate {
        MinRate {
            need: min_bytes_per_s.saturating_mul(RATE_WINDOW_S),
            buckets: VecDeque::new(),
            waited: Duration::ZERO,
        }
    }

    /// Bytes counted in the window that ends at second `k` (seconds `k - W .. k`).
    fn window_sum(&self, k: u64) -> u64 {
        let from = k.saturating_sub(RATE_WINDOW_S);
        self.buckets
            .iter()
            .filter(|(s, _)| (from..k).contains(s))
            .map(|(_, n)| n)
            .sum()
    }

    /// How much longer the sender may take to send its next bytes; `None`: as long as it likes
    /// (no minimum rate). The rule is checked at each whole second of waiting from the first
    /// window's end on: the first second whose window falls short ends the patience.
    pub fn patience(&self) -> Option<Duration> {
        if self.need == 0 {
            return None;
        }
        let now = self.waited.as_secs_f64();
        let mut k = (self.waited.as_secs() + 1).max(RATE_WINDOW_S);
        // Without new bytes every bucket has left the window after W + 1 seconds.
        loop {
            if self.window_sum(k) < self.need {
                return Some(Duration::from_secs_f64((k as f64 - now).max(0.0)));
            }
            k += 1;
        }
    }

    /// `n` bytes arrived after `waited` more time spent waiting for them.
    pub fn arrived(&mut self, n: u64, waited: Duration) {
        self.waited += waited;
        let second = self.waited.as_secs();
        match self.buckets.back_mut() {
            Some((s, bytes)) if *s == second => *bytes += n,
            _ => self.buckets.push_back((second, n)),
        }
        while self.buckets.front().is_some_and(|(s, _)| s + RATE_WINDOW_S < second) {
            self.buckets.pop_front();
        }
    }
}

/// The error of a body sent too slowly: 408, and the connection is closed by the deadline layer.
pub fn too_slow(min_bytes_per_s: u64) -> ApiError {
    err(
        StatusCode::REQUEST_TIMEOUT,
        format!(
            "the body arrived more slowly than {min_bytes_per_s} bytes/s over {RATE_WINDOW_S} s; send it again on a faster connection"
        ),
    )
}

/// A body's chunks, each checked against the minimum rate as it arrives.
pub struct RatedBody<S> {
    stream: S,
    rate: MinRate,
    min_bytes_per_s: u64,
    /// Bytes received so far.
    pub received: u64,
}

impl<S, E> RatedBody<S>
where
    S: Stream<Item = Result<Bytes, E>> + Unpin,
    E: std::fmt::Display,
{
    pub fn new(stream: S, min_bytes_per_s: u64) -> Self {
        RatedBody {
            stream,
            rate: MinRate::new(min_bytes_per_s),
            min_bytes_per_s,
            received: 0,
        }
    }

    /// The next chunk; `Ok(None)` at the body's end; 408 when the sender is too slow, 400 when
    /// the body breaks off.
    pub async fn next(&mut self) -> Result<Option<Bytes>, ApiError> {
        let started = tokio::time::Instant::now();
        let next = match self.rate.patience() {
            Some(patience) => tokio::time::timeout(patience, self.stream.next())
                .await
                .map_err(|_| too_slow(self.min_bytes_per_s))?,
            None => self.stream.next().await,
        };
        match next {
            None => Ok(None),
            Some(Err(e)) => Err(err(StatusCode::BAD_REQUEST, format!("the upload broke off: {e}"))),
            Some(Ok(chunk)) => {
                self.rate.arrived(chunk.len() as u64, started.elapsed());
                self.received += chunk.len() as u64;
                Ok(Some(chunk))
            }
        }
    }
}

/// Most bytes a received body's file holds on their way to the disk.
const WRITE_BUFFER_BYTES: usize = 128 << 10;

/// A temporary file a body is received into, removed when dropped unless kept.
pub struct TempFile {
    pub path: PathBuf,
    file: Option<tokio::fs::File>,
    sha: sha2::Sha256,
    pub bytes: u64,
}

impl TempFile {
    /// A new file `DIR/<random>.partial` (the directory is made if needed).
    pub async fn create(dir: &Path) -> Result<TempFile, ApiError> {
        let path = dir.join(format!("{}.partial", super::store::new_id()));
        let mut file = async {
            tokio::fs::create_dir_all(dir).await?;
            tokio::fs::File::create_new(&path).await
        }
        .await
        .map_err(|e| storage_error(&path, &e))?;
        // tokio buffers a write of up to 2 MiB on its way to the blocking pool: one chunk is
        // enough, and keeps an upload's memory at about that.
        file.set_max_buf_size(WRITE_BUFFER_BYTES);
        Ok(TempFile {
            path,
            file: Some(file),
            sha: sha2::Sha256::new(),
            bytes: 0,
        })
    }

    /// Appends `data`, and counts it into the file's SHA-256.
    pub async fn write(&mut self, data: &[u8]) -> Result<(), ApiError> {
        let file = self.file.as_mut().expect("written before finish");
        file.write_all(data).await.map_err(|e| storage_error(&self.path, &e))?;
        self.sha.update(data);
        self.bytes += data.len() as u64;
        Ok(())
    }

    /// Flushes and closes the file; returns its SHA-256 (hex).
    pub async fn finish(&mut self) -> Result<String, ApiError> {
        if let Some(mut file) = self.file.take() {
            file.flush().await.map_err(|e| storage_error(&self.path, &e))?;
        }
        let digest = std::mem::take(&mut self.sha).finalize();
        Ok(digest.iter().map(|b| format!("{b:02x}")).collect())
    }

    /// Moves the file to `dest` (same file system: a rename, never half a file there) and keeps it.
    pub async fn persist(mut self, dest: &Path) -> Result<(), ApiError> {
        self.file.take();
        let moved = async {
            if let Some(dir) = dest.parent() {
                tokio::fs::create_dir_all(dir).await?;
            }
            tokio::fs::rename(&self.path, dest).await
        }
        .await;
        moved.map_err(|e| storage_error(dest, &e))?;
        self.path = PathBuf::new();
        Ok(())
    }
}

impl Drop for TempFile {
    fn drop(&mut self) {
        if !self.path.as_os_str().is_empty() {
            let _ = std::fs::remove_file(&self.path);
        }
    }
}

/// A file the server cannot write: 503 with Retry-After (a full or read-only disk passes), the
/// cause logged, not shown.
pub fn storage_error(path: &Path, e: &std::io::Error) -> ApiError {
    tracing::error!(error = %e, file = %path.display(), "cannot write a received body");
    if e.kind() == std::io::ErrorKind::StorageFull {
        ApiError::Unavailable("the server's disk is full; try again later".into())
    } else {
        ApiError::Unavailable("the server cannot store the upload right now; try again later".into())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn secs(s: f64) -> Duration {
        Duration::from_secs_f64(s)
    }

    #[test]
    fn a_steady_sender_at_the_minimum_rate_is_never_cut_off() {
        // 100 bytes/s needed: 100 bytes every second for a minute.
        let mut r = MinRate::new(100);
        for _ in 0..60 {
            let p = r.patience().unwrap();
            assert!(p >= secs(1.0), "{p:?}");
            r.arrived(100, secs(1.0));
        }
    }

    #[test]
    fn a_sender_that_stalls_after_a_fast_start_is_cut_off_within_a_window() {
        let mut r = MinRate::new(100);
        // Everything but the last byte in the first second, then silence.
        r.arrived(1_000_000, secs(0.5));
        let p = r.patience().unwrap();
        // The window ending at second 11 no longer holds the burst of second 0.
        assert!(p > secs(9.0) && p <= secs(11.0), "{p:?}");
    }

    #[test]
    fn a_trickle_below_the_rate_is_cut_off_at_the_first_window() {
        // 64 bytes every 2 s against 32 KiB/s.
        let mut r = MinRate::new(32 << 10);
        let mut waited = Duration::ZERO;
        loop {
            let p = r.patience().unwrap();
            if p <= secs(2.0) {
                waited += p;
                break;
            }
            r.arrived(64, secs(2.0));
            waited += secs(2.0);
        }
        assert!(waited <= secs(RATE_WINDOW_S as f64), "{waited:?}");
    }

    #[test]
    fn no_minimum_rate_means_no_patience_limit() {
        assert_eq!(MinRate::new(0).patience(), None);
    }
}
