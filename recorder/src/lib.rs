//! Session files: format, writer that never blocks the haptic loop, reader and recovery.
//!
//! Empty on purpose: the session-recorder issue fills it. Nothing here pretends to work yet.
