//! Stylet session files (docs/session-format.md): every tick's device input and output, events,
//! state digests and notes in an MCAP file with zstd-compressed, CRC-checked chunks that survives
//! a crash (everything older than a second is recoverable) and opens in MCAP tools.
//!
//! [`writer`] records without ever blocking the haptic loop; [`reader`] reads strictly, streams,
//! seeks by tick through the index, and recovers cut or damaged files; [`format`](mod@format) defines the
//! header, channels and messages; [`codec`] the compressible tick columns; [`outputs`] the rounded
//! forces and torques and the digest that pins their exact bits.

pub mod codec;
pub mod device_forces;
pub mod format;
pub mod outputs;
pub mod reader;
pub mod recording;
pub mod records;
pub mod repair;
pub mod writer;

pub use format::{EventRecord, SCHEMA_VERSION, SessionEnd, SessionHeader, TickRecord};
pub use reader::{
    Damage, DamageKind, Limits, Mode, ReadError, Session, VerifyError, read, read_bytes, recover, verify,
};
pub use recording::{Recording, SessionInfo};
pub use repair::rewrite_recovered;
pub use writer::{SessionWriter, WriteError, WriteSummary, WriterOptions};

/// A new random session id (UUID v4).
pub fn new_session_id() -> String {
    uuid::Uuid::new_v4().to_string()
}

/// Now, RFC 3339 UTC, for the header's wall-clock start (metadata only).
pub fn wall_clock_now() -> String {
    humantime::format_rfc3339_seconds(std::time::SystemTime::now()).to_string()
}
