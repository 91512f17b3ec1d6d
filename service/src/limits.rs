//! The service's limits and timeouts, each with its default (docs/security.md lists them with the
//! `stylet serve` flag that changes each). Every request, upload and connection is bounded by
//! these before any expensive work is done for it.

use std::time::Duration;

/// Limits and timeouts of a running service.
#[derive(Debug, Clone)]
pub struct Limits {
    /// Longest session accepted for upload (s): bounds the ticks a file may hold, so the memory
    /// and time of its verification and replay.
    pub max_session_s: u64,
    /// Largest request body other than a session upload (bytes): logins, comments, forms.
    pub max_json_body_bytes: usize,
    /// Time a client has to send a request's headers; also how long a keep-alive connection may
    /// wait for its next request.
    pub header_timeout: Duration,
    /// Longest time for a request other than an upload, body included.
    pub request_timeout: Duration,
    /// Slowest body accepted for an upload or a publication (bytes per second): every
    /// [`crate::intake::RATE_WINDOW_S`]-second stretch of it must bring this rate's worth, and
    /// the whole upload may take `request_timeout` plus its size at this rate.
    pub min_upload_bytes_per_s: u64,
    /// Connections open at once, whatever they are doing (sending headers, idle between
    /// requests, being served); more wait in the kernel's backlog. Bounded by the process's
    /// file descriptors at start.
    pub max_connections: usize,
    /// Connections open at once from one address; past it a new one is closed at once.
    pub max_connections_per_address: usize,
    /// Requests being served at once (from their complete headers to their answer); past it:
    /// 503 with `Retry-After`. `/healthz` is never refused. Connections still sending their
    /// headers hold no such slot.
    pub max_requests: usize,
    /// Requests one account may have in flight at once; past it: 429 with `Retry-After`.
    pub max_requests_per_account: usize,
    /// Uploads (sessions and atlas archives) being received at once, in all (503 past it) and per
    /// account (429 past it).
    pub max_uploads: usize,
    pub max_uploads_per_account: usize,
    /// Free disk space an upload must leave in the data directory's file system (bytes): an
    /// upload that would leave less is refused with 503 and `Retry-After` before its body is
    /// read, so that the database, deletions and the scores still have room.
    pub min_free_disk_bytes: u64,
    /// Password checks (argon2id) run at once, on threads of their own.
    pub password_threads: usize,
    /// Password checks waiting for a thread; more get 503 with Retry-After.
    pub password_queue: usize,
    /// Largest atlas upload (`POST /api/atlases`, the archive's bytes).
    pub max_atlas_bytes: u64,
    /// Most atlases the catalogue offers (withdrawn ones do not count): a publication past it is
    /// refused (409).
    pub max_atlases: usize,
    /// Memory the loaded atlases may take (bytes, estimated from their volumes): the least
    /// recently used are let go past it and loaded again from disk when needed.
    pub atlas_cache_bytes: u64,
    /// Most voxels a published atlas may hold, its CT and measured breathing fields counted
    /// (`stylet_atlas::store::voxel_count`): checked from the headers before the atlas is
    /// loaded, it bounds the memory the atlas takes when loaded and its derived-data cache
    /// on disk (a compressed archive far under `max_atlas_bytes` can describe a huge grid).
    pub max_atlas_voxels: u64,
    /// Time a publication gets for its checks (loading the atlas, its smoke test), beyond its
    /// upload time.
    pub atlas_check_timeout: Duration,
    /// With object storage: bytes of session files this replica keeps as local copies (the
    /// store has them all); past it the least recently used are deleted
    /// ([`crate::local_copies`]).
    pub local_copies_bytes: u64,
    /// Reverse proxies whose `X-Forwarded-For` names the client (the pairing codes' failure
    /// limit per client address); none by default: the connection's peer is the client.
    pub trusted_proxies: Vec<ipnet::IpNet>,
}

impl Default for Limits {
    fn default() -> Self {
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        Limits {
            max_session_s: 30 * 60,
            max_json_body_bytes: 64 << 10,
            header_timeout: Duration::from_secs(10),
            request_timeout: Duration::from_secs(30),
            min_upload_bytes_per_s: 32 << 10,
            max_connections: 4096,
            max_connections_per_address: 1024,
            max_requests: 512,
            max_requests_per_account: 64,
            max_uploads: 32,
            max_uploads_per_account: 2,
            min_free_disk_bytes: 256 << 20,
            password_threads: (cores / 2).max(1),
            password_queue: 32,
            max_atlas_bytes: 1 << 30,
            max_atlases: 32,
            atlas_cache_bytes: 4 << 30,
            // 512 × 512 × 256.
            max_atlas_voxels: 1 << 26,
            atlas_check_timeout: Duration::from_secs(300),
            local_copies_bytes: 16 << 30,
            trusted_proxies: Vec::new(),
        }
    }
}

impl Limits {
    /// How long an upload of `bytes` may take, body included.
    pub fn upload_timeout(&self, bytes: u64) -> Duration {
        self.request_timeout + Duration::from_secs(bytes / self.min_upload_bytes_per_s.max(1))
    }
}
