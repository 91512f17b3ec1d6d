//! What an upload of a session file is, between the outbox that sends finished sessions and the
//! service client that carries them: the largest file, the uploader, and the service's reply.

/// Largest session file the outbox takes, and the largest a fetch from the service reads (the
/// service's default upload limit is 64 MiB).
pub const MAX_SESSION_BYTES: u64 = 256 << 20;

/// Something that uploads a session file (the service client; tests use others).
pub trait Uploader {
    fn upload(&self, session: &[u8]) -> UploadReply;
}

/// What the service said to an upload.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum UploadReply {
    /// Stored (201) or already stored before (200): the session's id on the service.
    Accepted { id: String, new: bool },
    /// The service refused the file itself (400, 403, 413, 415, 422): uploading it again will
    /// not help. The service's reason.
    Refused { status: u16, reason: String },
    /// The token is missing, expired or revoked (401): log in again.
    Unauthorized { reason: String },
    /// The account may not upload (403 without a file problem: a disabled account, a token of
    /// the wrong scope): nothing is moved aside; the next round tries again.
    Forbidden { reason: String },
    /// The service is down, overloaded or unreachable: try again later.
    Unavailable { reason: String },
}
