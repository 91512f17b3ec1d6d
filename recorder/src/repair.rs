//! Rewriting what was recovered from a damaged or cut file as a finished, indexed session file
//! that says it is incomplete and why (`stylet session recover`).

use std::path::Path;

use crate::reader::Session;
use crate::writer::{SessionWriter, WriteError, WriteSummary, WriterOptions};

/// Writes `session` (as returned by [`crate::reader::recover`]) to `out`, atomically: a temporary
/// file beside it is renamed into place only when complete. `source` names the damaged file in
/// the note written into the new one.
pub fn rewrite_recovered(session: &Session, source: &str, out: &Path) -> Result<WriteSummary, WriteError> {
    let io = |e: std::io::Error| WriteError::Io {
        path: out.display().to_string(),
        message: e.to_string(),
    };
    let file_name = out
        .file_name()
        .map_or_else(|| "session".into(), |n| n.to_string_lossy().into_owned());
    let tmp = out.with_file_name(format!(".{file_name}.partial"));
    let result = (|| {
        let w = SessionWriter::create(&tmp, &session.header, WriterOptions::default())?;
        for a in &session.annotations {
            w.annotate_blocking(a.tick, &a.text)?;
        }
        for e in &session.events {
            w.event_record_blocking(e.clone())?;
        }
        for d in &session.digests {
            w.digest_blocking(d.tick, d.digest)?;
        }
        for f in &session.device_forces {
            w.device_force_blocking(*f)?;
        }
        w.record_read_blocking(&session.ticks, &session.output_checks)?;
        let mut reasons = Vec::new();
        if let Some(d) = &session.damage {
            reasons.push(format!("recovered from {source}, damaged {d}"));
        }
        match &session.end {
            Some(e) if !e.complete => reasons.push(format!("the original was incomplete: {}", e.reason)),
            Some(_) => {}
            None => reasons.push("the original has no end record (recording was interrupted)".into()),
        }
        let last = session.ticks.last().map_or(0, |t| t.tick);
        for r in &reasons {
            w.annotate_blocking(last, r)?;
        }
        if !reasons.is_empty() {
            w.mark_incomplete(&reasons.join("; "))?;
        }
        w.finish()
    })();
    match result {
        Ok(mut summary) => {
            std::fs::rename(&tmp, out).map_err(io)?;
            summary.path = out.to_path_buf();
            Ok(summary)
        }
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            Err(e)
        }
    }
}
