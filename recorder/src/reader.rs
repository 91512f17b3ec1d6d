//! Reading session files: strictly (any damage is an error), in recovery (everything intact before
//! the first damage, and what was lost), streaming (chunk by chunk in file order) and indexed (the
//! chunks of a tick range, through the summary's chunk index).
//!
//! The record walker and the record parser ([`crate::records`]) are our own and bounded by
//! [`Limits`] — a hostile file gets an error, never a huge allocation or a panic.

use std::collections::BTreeMap;
use std::io::{Read, Seek, SeekFrom};
use std::path::Path;

use crate::device_forces::{self, DeviceForceBlock, DeviceForceError, DeviceForceRecord};
use crate::format::*;
use crate::outputs::OutputCheck;
use crate::records::{self, OP_CHUNK, OP_DATA_END, OP_FOOTER, OP_HEADER, ParseError, Record};
use crate::writer::{BlockError, DecodedBlock, decode_block};

/// Hard limits against hostile files.
#[derive(Debug, Clone, Copy)]
pub struct Limits {
    pub max_file_bytes: u64,
    pub max_record_bytes: u64,
    pub max_chunk_uncompressed_bytes: u64,
    pub max_ticks: u64,
    pub max_messages: u64,
    /// Events and annotations kept in memory (ticks can be streamed; these cannot).
    pub max_notes: u64,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_file_bytes: 2 << 30,
            max_record_bytes: 64 << 20,
            max_chunk_uncompressed_bytes: 64 << 20,
            max_ticks: 200_000_000,
            max_messages: 50_000_000,
            max_notes: 1_000_000,
        }
    }
}

impl Limits {
    /// Limits for a file from outside (an upload) of `file_bytes` whose header says it ticks at
    /// `tick_rate_hz`: at most `max_duration_s` of ticks, chunks and records far smaller than the
    /// defaults (the writer's chunks hold half a second, tens of KB), messages and notes in
    /// proportion to the ticks. With [`verify_streaming`], the memory a file can make a reader
    /// use is bounded by these, whatever the file declares.
    pub fn for_upload(file_bytes: u64, tick_rate_hz: u32, max_duration_s: u64) -> Limits {
        let max_ticks = max_duration_s.saturating_mul(u64::from(tick_rate_hz));
        Limits {
            max_file_bytes: file_bytes,
            max_record_bytes: 8 << 20,
            max_chunk_uncompressed_bytes: 8 << 20,
            max_ticks,
            // Blocks, digests (every 100 ticks) and previews (every 20) come to ticks / 16.
            max_messages: max_ticks / 10 + 10_000,
            max_notes: max_ticks / 100 + 10_000,
        }
    }
}

/// Why a file cannot be read at all.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ReadError {
    #[error("{0}")]
    Io(String),
    #[error("not a Stylet session file: {0}")]
    NotASession(String),
    /// The session header is there but cannot be read (nothing else is read then).
    #[error("not a Stylet session file: {0}")]
    BadHeader(HeaderError),
    #[error("damaged session file: {0}")]
    Damaged(Damage),
}

/// What is wrong where a file is damaged: what makes a strict read fail and a recovering read
/// stop. A file cut short (a crash, an interrupted copy) can be recovered up to the cut; a limit
/// of [`Limits`] exceeded, altered bytes and malformed records, chunks or messages are the rest.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DamageKind {
    #[error("the file ends without its summary and footer (cut short?)")]
    NoSummary,
    #[error("the file ends inside a record header")]
    EndsInRecordHeader,
    /// The file ends inside a record of this many bytes.
    #[error("the file ends inside a record of {0} bytes (cut short?)")]
    EndsInRecord(u64),
    #[error(transparent)]
    OverLimit(#[from] LimitExceeded),
    #[error("data section CRC mismatch (the file was altered)")]
    DataCrc,
    #[error("summary CRC mismatch (the file was altered)")]
    SummaryCrc,
    /// The MCAP header names another profile (shown as the file has it).
    #[error("MCAP profile '{0}' is not '{PROFILE}'")]
    Profile(String),
    #[error("bad MCAP header")]
    BadHeader,
    #[error("bad data-end record")]
    BadDataEnd,
    #[error("bad footer")]
    BadFooter,
    /// A footer with no data-end record before it: the data section's CRC was never checked (an
    /// altered data-end opcode reads as an unknown record).
    #[error("footer without a data-end record (the file was altered)")]
    NoDataEnd,
    #[error("bytes after the footer, or the closing magic is missing")]
    AfterFooter,
    /// A record inside a chunk whose header the chunk cuts off.
    #[error("record header cut off")]
    RecordHeaderCut,
    /// A record inside a chunk that is longer than what is left of the chunk.
    #[error("record runs past its chunk")]
    RecordPastChunk,
    /// A record whose fields do not fit its length.
    #[error("bad record (opcode {op:#04x}): {source}")]
    BadRecord { op: u8, source: ParseError },
    /// A channel on a topic that is not a session's (its first 64 characters).
    #[error("channel on unexpected topic '{0}'")]
    ChannelTopic(String),
    #[error(transparent)]
    End(#[from] EndError),
    #[error(transparent)]
    Chunk(#[from] ChunkError),
    #[error(transparent)]
    Message(#[from] MessageError),
}

/// A limit of [`Limits`] that a file exceeds: the reader stops there rather than use more memory.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LimitExceeded {
    #[error("record of {len} bytes exceeds the limit of {limit}")]
    Record { len: u64, limit: u64 },
    /// A record inside a chunk longer than [`Limits::max_record_bytes`].
    #[error("record of {0} bytes exceeds the limit")]
    RecordInChunk(u64),
    /// A chunk that declares more uncompressed bytes than [`Limits::max_chunk_uncompressed_bytes`].
    #[error("chunk claims {0} bytes uncompressed, over the limit")]
    Chunk(u64),
    #[error("more than {0} ticks")]
    Ticks(u64),
    #[error("more than {0} messages")]
    Messages(u64),
    #[error("more than {0} events and annotations")]
    Notes(u64),
}

/// Why a chunk's records cannot be had: a malformed chunk record, an unknown compression, bytes
/// that do not decompress to what the chunk declares, or a CRC mismatch.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ChunkError {
    #[error("bad chunk: {0}")]
    Parse(ParseError),
    /// The chunk record parsed as another kind of record.
    #[error("bad chunk")]
    NotAChunk,
    #[error("chunk compression '{0}' is not supported")]
    Compression(String),
    /// The zstd decoder cannot start (its reason).
    #[error("chunk: {0}")]
    Decoder(String),
    /// The compressed bytes are not zstd (the decoder's reason).
    #[error("chunk does not decompress: {0}")]
    Decompress(String),
    #[error("chunk decompresses to {got} bytes, not the {declared} it declares")]
    Size { got: usize, declared: u64 },
    #[error("chunk CRC mismatch")]
    Crc,
}

/// Why a message in a chunk is refused: it is on no known channel, does not decode, or holds
/// ticks, an event or text a session cannot have.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MessageError {
    #[error("message on unknown channel {0}")]
    UnknownChannel(u16),
    #[error("message on unexpected topic '{0}'")]
    UnexpectedTopic(String),
    #[error(transparent)]
    Cbor(#[from] CborError),
    #[error(transparent)]
    Block(#[from] BlockError),
    #[error(transparent)]
    DeviceForces(#[from] DeviceForceError),
    #[error(transparent)]
    Pose(#[from] PoseError),
    /// A tick block that does not start after the previous one ended.
    #[error("tick {first} after tick {last}")]
    TickOrder { first: u64, last: u64 },
    #[error(transparent)]
    TooLong(#[from] TextTooLong),
    #[error("event at tick {tick}: {source}")]
    Event { tick: u64, source: EventError },
}

/// The first damage found, where it is and what it costs.
#[derive(Debug, Clone, PartialEq)]
pub struct Damage {
    /// Byte offset of the damaged or cut record.
    pub offset: u64,
    pub what: DamageKind,
    /// Bytes from the damage to the end of the file that could not be used.
    pub lost_bytes: u64,
}

impl std::fmt::Display for Damage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "at byte {}: {} ({} bytes after it unusable)",
            self.offset, self.what, self.lost_bytes
        )
    }
}

/// A chunk's place in the file and the ticks it holds.
#[derive(Debug, Clone, PartialEq)]
pub struct ChunkInfo {
    pub offset: u64,
    pub end: u64,
    pub first_tick: Option<u64>,
    pub last_tick: Option<u64>,
}

/// A session as read.
#[derive(Debug, Clone, PartialEq)]
pub struct Session {
    pub header: SessionHeader,
    pub end: Option<SessionEnd>,
    pub ticks: Vec<TickRecord>,
    pub events: Vec<EventRecord>,
    pub digests: Vec<DigestRecord>,
    /// One per tick block with rounded outputs (codec v2), in tick order: the digest replay checks
    /// the exact outputs of the block's ticks against.
    pub output_checks: Vec<OutputCheck>,
    pub annotations: Vec<AnnotationRecord>,
    /// The force a force-feedback device was sent, per tick (sessions trained on one; metadata
    /// for the review, never replayed).
    pub device_forces: Vec<DeviceForceRecord>,
    pub chunks: Vec<ChunkInfo>,
    /// The first damage (recovery mode only; `None` for an intact file).
    pub damage: Option<Damage>,
    /// Whether the file ended with its summary and footer.
    pub finished: bool,
}

impl Session {
    pub fn duration_s(&self) -> f64 {
        self.ticks
            .last()
            .map_or(0.0, |t| (t.tick + 1) as f64 / self.header.tick_rate_hz as f64)
    }

    /// Complete: finished, intact, nothing dropped.
    pub fn complete(&self) -> bool {
        self.damage.is_none() && self.finished && self.end.as_ref().is_some_and(|e| e.complete)
    }
}

const MAGIC: &[u8; 8] = b"\x89MCAP0\r\n";

/// Reading mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mode {
    /// Any damage is an error.
    Strict,
    /// Stop at the first damage and return what came before.
    Recover,
}

/// Receives ticks block by block when streaming.
pub type TickSink<'a> = &'a mut dyn FnMut(&[TickRecord]);

struct Walk<'l> {
    limits: &'l Limits,
    /// Streaming: ticks go here block by block instead of being kept.
    sink: Option<TickSink<'l>>,
    last_tick: Option<u64>,
    channels: BTreeMap<u16, String>,
    header: Option<SessionHeader>,
    end: Option<SessionEnd>,
    ticks: Vec<TickRecord>,
    events: Vec<EventRecord>,
    digests: Vec<DigestRecord>,
    output_checks: Vec<OutputCheck>,
    annotations: Vec<AnnotationRecord>,
    device_forces: Vec<DeviceForceRecord>,
    chunks: Vec<ChunkInfo>,
    /// Ticks read so far (kept or streamed): bounded by `limits.max_ticks` before decoding.
    tick_count: u64,
    messages: u64,
    finished: bool,
    header_error: Option<HeaderError>,
}

fn read_u64(b: &[u8], at: usize) -> Option<u64> {
    b.get(at..at + 8)
        .map(|s| u64::from_le_bytes(s.try_into().expect("8 bytes")))
}

impl Walk<'_> {
    /// Counts an event or annotation against [`Limits::max_notes`].
    fn note(&self) -> Result<(), DamageKind> {
        if (self.events.len() + self.annotations.len()) as u64 >= self.limits.max_notes {
            return Err(LimitExceeded::Notes(self.limits.max_notes).into());
        }
        Ok(())
    }

    /// Handles one message; an error is damage.
    fn message(&mut self, channel: u16, data: &[u8]) -> Result<(), DamageKind> {
        self.messages += 1;
        if self.messages > self.limits.max_messages {
            return Err(LimitExceeded::Messages(self.limits.max_messages).into());
        }
        let topic = self
            .channels
            .get(&channel)
            .ok_or(MessageError::UnknownChannel(channel))?;
        match topic.as_str() {
            TOPIC_TICKS => {
                let block: TickBlock = from_cbor(data).map_err(MessageError::from)?;
                if self.tick_count.saturating_add(u64::from(block.count)) > self.limits.max_ticks {
                    return Err(LimitExceeded::Ticks(self.limits.max_ticks).into());
                }
                let DecodedBlock { ticks, check } = decode_block(&block).map_err(MessageError::from)?;
                check_poses_finite(&ticks).map_err(MessageError::from)?;
                if let (Some(last), Some(first)) = (self.last_tick, ticks.first())
                    && first.tick <= last
                {
                    return Err(MessageError::TickOrder {
                        first: first.tick,
                        last,
                    }
                    .into());
                }
                self.tick_count += ticks.len() as u64;
                self.last_tick = ticks.last().map(|t| t.tick);
                self.output_checks.extend(check);
                match self.sink.as_mut() {
                    Some(sink) => sink(&ticks),
                    None => self.ticks.extend(ticks),
                }
            }
            TOPIC_EVENTS => {
                self.note()?;
                let e: EventRecord = from_cbor(data).map_err(MessageError::from)?;
                // Bounded before anything else looks at them (unused fields are kept too).
                check_text("event name", &e.name, MAX_NAME_CHARS).map_err(MessageError::from)?;
                check_text("event tool", e.tool.as_deref().unwrap_or_default(), MAX_NAME_CHARS)
                    .map_err(MessageError::from)?;
                e.to_event()
                    .map_err(|source| MessageError::Event { tick: e.tick, source })?;
                self.events.push(e);
            }
            TOPIC_DIGESTS => self.digests.push(from_cbor(data).map_err(MessageError::from)?),
            TOPIC_ANNOTATIONS => {
                self.note()?;
                let a: AnnotationRecord = from_cbor(data).map_err(MessageError::from)?;
                check_text("annotation", &a.text, MAX_NOTE_CHARS).map_err(MessageError::from)?;
                self.annotations.push(a);
            }
            TOPIC_PREVIEW => {}
            TOPIC_DEVICE_FORCES => {
                let block: DeviceForceBlock = from_cbor(data).map_err(MessageError::from)?;
                if (self.device_forces.len() as u64).saturating_add(u64::from(block.count)) > self.limits.max_ticks {
                    return Err(LimitExceeded::Ticks(self.limits.max_ticks).into());
                }
                let records = device_forces::decode(&block).map_err(MessageError::from)?;
                if let (Some(last), Some(first)) = (self.device_forces.last(), records.first())
                    && first.tick <= last.tick
                {
                    return Err(MessageError::TickOrder {
                        first: first.tick,
                        last: last.tick,
                    }
                    .into());
                }
                self.device_forces.extend(records);
            }
            other => return Err(MessageError::UnexpectedTopic(other.to_string()).into()),
        }
        Ok(())
    }

    /// Handles the records inside `buf` (a chunk's content); the first error is damage.
    fn records(&mut self, buf: &[u8]) -> Result<(), DamageKind> {
        let mut pos = 0usize;
        while pos < buf.len() {
            let op = buf[pos];
            let len = read_u64(buf, pos + 1).ok_or(DamageKind::RecordHeaderCut)?;
            if len > self.limits.max_record_bytes {
                return Err(LimitExceeded::RecordInChunk(len).into());
            }
            let start = pos + 9;
            let body = buf
                .get(start..start + len as usize)
                .ok_or(DamageKind::RecordPastChunk)?;
            self.record(op, body)?;
            pos = start + len as usize;
        }
        Ok(())
    }

    fn record(&mut self, op: u8, body: &[u8]) -> Result<(), DamageKind> {
        match records::parse(op, body).map_err(|source| DamageKind::BadRecord { op, source })? {
            Record::Channel { id, topic } => {
                // Only the session's own topics: nothing else is read, so nothing else is kept.
                if !TOPICS.contains(&topic) {
                    let shown: String = topic.chars().take(MAX_NAME_CHARS).collect();
                    return Err(DamageKind::ChannelTopic(shown));
                }
                self.channels.insert(id, topic.to_string());
            }
            Record::Message { channel_id, data } => self.message(channel_id, data)?,
            Record::Metadata { name, map } if name == META_HEADER => match SessionHeader::from_metadata(&map) {
                Ok(h) => self.header = Some(h),
                Err(e) => self.header_error = Some(e),
            },
            Record::Metadata { name, map } if name == META_END => {
                self.end = Some(SessionEnd::from_metadata(&map)?);
            }
            _ => {}
        }
        Ok(())
    }

    fn chunk(&mut self, offset: u64, body: &[u8]) -> Result<(), DamageKind> {
        let Record::Chunk(c) = records::parse(OP_CHUNK, body).map_err(ChunkError::Parse)? else {
            return Err(ChunkError::NotAChunk.into());
        };
        if c.uncompressed_size > self.limits.max_chunk_uncompressed_bytes {
            return Err(LimitExceeded::Chunk(c.uncompressed_size).into());
        }
        let plain = match c.compression {
            "" => c.records.to_vec(),
            "zstd" => {
                let mut out = Vec::new();
                zstd::stream::read::Decoder::new(c.records)
                    .map_err(|e| ChunkError::Decoder(e.to_string()))?
                    .take(c.uncompressed_size + 1)
                    .read_to_end(&mut out)
                    .map_err(|e| ChunkError::Decompress(e.to_string()))?;
                out
            }
            other => return Err(ChunkError::Compression(other.to_string()).into()),
        };
        if plain.len() as u64 != c.uncompressed_size {
            return Err(ChunkError::Size {
                got: plain.len(),
                declared: c.uncompressed_size,
            }
            .into());
        }
        if c.uncompressed_crc != 0 && crc32fast::hash(&plain) != c.uncompressed_crc {
            return Err(ChunkError::Crc.into());
        }
        // All or nothing: a chunk's messages count only if the whole chunk is good.
        let saved = (
            self.ticks.len(),
            self.events.len(),
            self.digests.len(),
            self.annotations.len(),
            self.tick_count,
            self.output_checks.len(),
        );
        let first = self.ticks.len();
        if let Err(e) = self.records(&plain) {
            self.ticks.truncate(saved.0);
            self.events.truncate(saved.1);
            self.digests.truncate(saved.2);
            self.annotations.truncate(saved.3);
            self.tick_count = saved.4;
            self.output_checks.truncate(saved.5);
            return Err(e);
        }
        let added = &self.ticks[first..];
        let first_tick = added.first().map(|t| t.tick);
        self.chunks.push(ChunkInfo {
            offset,
            end: offset + 9 + body.len() as u64,
            first_tick: first_tick.or(if self.sink.is_some() { self.last_tick } else { None }),
            last_tick: if self.sink.is_some() {
                self.last_tick
            } else {
                added.last().map(|t| t.tick)
            },
        });
        Ok(())
    }
}

/// Reads a session from bytes.
pub fn read_bytes(bytes: &[u8], mode: Mode, limits: &Limits) -> Result<Session, ReadError> {
    read_bytes_with(bytes, mode, limits, None)
}

/// Reads a session from bytes; with a `sink`, ticks are handed to it block by block in file order
/// instead of being collected (streaming).
pub fn read_bytes_with<'a>(
    bytes: &[u8],
    mode: Mode,
    limits: &'a Limits,
    sink: Option<TickSink<'a>>,
) -> Result<Session, ReadError> {
    walk(&mut SliceSource(bytes), mode, limits, sink)
}

/// Reads a session from a file (or any seekable reader) one record at a time: the memory it
/// takes is one record (at most [`Limits::max_record_bytes`]) and one decompressed chunk, not
/// the file. With a `sink`, ticks are streamed as by [`read_bytes_with`], with the same result.
pub fn read_file_with<'a, R: Read + Seek>(
    file: R,
    mode: Mode,
    limits: &'a Limits,
    sink: Option<TickSink<'a>>,
) -> Result<Session, ReadError> {
    walk(&mut FileSource::new(file)?, mode, limits, sink)
}

/// Where a walk reads a file's bytes from: the whole file in memory, or a file read record by
/// record. Both give the walk the same bytes, so the same file reads the same either way.
trait Source {
    /// The file's length in bytes.
    fn len(&self) -> u64;
    /// The `n` bytes at `at`; `None` when the file ends first. `n` is bounded by the caller
    /// (a record header, or a record within [`Limits::max_record_bytes`]).
    fn bytes(&mut self, at: u64, n: u64) -> Result<Option<&[u8]>, ReadError>;
    /// CRC-32 of the bytes from `from` to `to` (within the file).
    fn crc(&mut self, from: u64, to: u64) -> Result<u32, ReadError>;
}

struct SliceSource<'b>(&'b [u8]);

impl Source for SliceSource<'_> {
    fn len(&self) -> u64 {
        self.0.len() as u64
    }

    fn bytes(&mut self, at: u64, n: u64) -> Result<Option<&[u8]>, ReadError> {
        let range = usize::try_from(at)
            .ok()
            .zip(usize::try_from(n).ok())
            .and_then(|(at, n)| Some(at..at.checked_add(n)?));
        Ok(range.and_then(|r| self.0.get(r)))
    }

    fn crc(&mut self, from: u64, to: u64) -> Result<u32, ReadError> {
        Ok(crc32fast::hash(&self.0[from as usize..to as usize]))
    }
}

/// A seekable reader, read where the walk asks; `buf` holds the last record read. Reads that
/// follow one another do not seek, so a buffered reader serves them from its buffer.
struct FileSource<R> {
    file: R,
    len: u64,
    /// Where the reader is now.
    pos: u64,
    buf: Vec<u8>,
}

fn io_error(e: std::io::Error) -> ReadError {
    ReadError::Io(e.to_string())
}

impl<R: Read + Seek> FileSource<R> {
    fn new(mut file: R) -> Result<Self, ReadError> {
        let len = file.seek(SeekFrom::End(0)).map_err(io_error)?;
        Ok(FileSource {
            file,
            len,
            pos: len,
            buf: Vec::new(),
        })
    }
}

impl<R: Read + Seek> FileSource<R> {
    fn seek_to(&mut self, at: u64) -> Result<(), ReadError> {
        if at != self.pos {
            self.file.seek(SeekFrom::Start(at)).map_err(io_error)?;
            self.pos = at;
        }
        Ok(())
    }
}

impl<R: Read + Seek> Source for FileSource<R> {
    fn len(&self) -> u64 {
        self.len
    }

    fn bytes(&mut self, at: u64, n: u64) -> Result<Option<&[u8]>, ReadError> {
        let Some(end) = at.checked_add(n).filter(|&end| end <= self.len) else {
            return Ok(None);
        };
        let n = usize::try_from(end - at).map_err(|_| ReadError::Io("a record too large for memory".into()))?;
        self.buf.clear();
        self.buf.resize(n, 0);
        self.seek_to(at)?;
        self.pos = u64::MAX;
        self.file.read_exact(&mut self.buf).map_err(io_error)?;
        self.pos = end;
        Ok(Some(&self.buf))
    }

    fn crc(&mut self, from: u64, to: u64) -> Result<u32, ReadError> {
        self.seek_to(from)?;
        // Unknown until the reads below have all succeeded.
        self.pos = u64::MAX;
        let mut hasher = crc32fast::Hasher::new();
        let mut left = to - from;
        let mut block = vec![0u8; 64 << 10];
        while left > 0 {
            let n = left.min(block.len() as u64) as usize;
            self.file.read_exact(&mut block[..n]).map_err(io_error)?;
            hasher.update(&block[..n]);
            left -= n as u64;
        }
        self.pos = to;
        Ok(hasher.finalize())
    }
}

/// The record walk shared by every reader of a whole file (see the module doc).
fn walk<'a>(
    src: &mut dyn Source,
    mode: Mode,
    limits: &'a Limits,
    sink: Option<TickSink<'a>>,
) -> Result<Session, ReadError> {
    let file_len = src.len();
    if file_len > limits.max_file_bytes {
        return Err(ReadError::NotASession(format!(
            "{file_len} bytes exceed the limit of {}",
            limits.max_file_bytes
        )));
    }
    if src.bytes(0, 8)? != Some(MAGIC.as_slice()) {
        return Err(ReadError::NotASession("it does not start with the MCAP magic".into()));
    }
    let mut w = Walk {
        limits,
        sink,
        last_tick: None,
        channels: BTreeMap::new(),
        header: None,
        end: None,
        ticks: Vec::new(),
        events: Vec::new(),
        digests: Vec::new(),
        output_checks: Vec::new(),
        annotations: Vec::new(),
        device_forces: Vec::new(),
        chunks: Vec::new(),
        tick_count: 0,
        messages: 0,
        finished: false,
        header_error: None,
    };
    let mut pos = 8u64;
    let mut damage: Option<Damage> = None;
    let mut in_summary = false;
    let mut profile_ok = false;
    let damaged = |offset: u64, what: DamageKind| Damage {
        offset,
        what,
        lost_bytes: file_len - offset,
    };
    loop {
        if pos == file_len {
            damage = Some(damaged(pos, DamageKind::NoSummary));
            break;
        }
        let Some(head) = src.bytes(pos, 9)? else {
            damage = Some(damaged(pos, DamageKind::EndsInRecordHeader));
            break;
        };
        let op = head[0];
        let len = read_u64(head, 1).expect("9 bytes");
        if len > limits.max_record_bytes {
            damage = Some(damaged(
                pos,
                LimitExceeded::Record {
                    len,
                    limit: limits.max_record_bytes,
                }
                .into(),
            ));
            break;
        }
        let start = pos + 9;
        let Some(body) = src.bytes(start, len)? else {
            damage = Some(damaged(pos, DamageKind::EndsInRecord(len)));
            break;
        };
        let result = match op {
            OP_HEADER => match records::parse(op, body) {
                Ok(Record::Header { profile }) if profile == PROFILE => {
                    profile_ok = true;
                    Ok(())
                }
                Ok(Record::Header { profile }) => Err(DamageKind::Profile(profile.to_string())),
                _ => Err(DamageKind::BadHeader),
            },
            OP_CHUNK => w.chunk(pos, body),
            OP_DATA_END => {
                // Fields first: the CRC reads the file again, after the record's bytes.
                let data_section_crc = match records::parse(op, body) {
                    Ok(Record::DataEnd { data_section_crc }) => Some(data_section_crc),
                    _ => None,
                };
                match data_section_crc {
                    Some(crc) => {
                        in_summary = true;
                        if crc != 0 && crc != src.crc(0, pos)? {
                            Err(DamageKind::DataCrc)
                        } else {
                            Ok(())
                        }
                    }
                    None => Err(DamageKind::BadDataEnd),
                }
            }
            OP_FOOTER => {
                let footer = match records::parse(op, body) {
                    Ok(Record::Footer {
                        summary_start,
                        summary_crc,
                    }) => Some((summary_start, summary_crc)),
                    _ => None,
                };
                match footer {
                    Some((summary_start, summary_crc)) => {
                        // The CRC covers the summary section through the footer's fields before the CRC.
                        let crc_end = start + 8 + 8;
                        let summary_ok = summary_crc == 0
                            || (summary_start > 0
                                && summary_start <= pos
                                && crc_end <= file_len
                                && src.crc(summary_start, crc_end)? == summary_crc);
                        if !in_summary {
                            Err(DamageKind::NoDataEnd)
                        } else if !summary_ok {
                            Err(DamageKind::SummaryCrc)
                        } else if start + len + 8 != file_len || src.bytes(file_len - 8, 8)? != Some(MAGIC.as_slice()) {
                            Err(DamageKind::AfterFooter)
                        } else {
                            w.finished = true;
                            Ok(())
                        }
                    }
                    None => Err(DamageKind::BadFooter),
                }
            }
            _ if in_summary => Ok(()),
            _ => w.record(op, body),
        };
        if let Err(what) = result {
            damage = Some(damaged(pos, what));
            break;
        }
        if !profile_ok {
            return Err(ReadError::NotASession(
                "the first record is not a Stylet session header".into(),
            ));
        }
        if w.finished {
            break;
        }
        pos = start + len;
    }
    let header = match (w.header.take(), w.header_error.take()) {
        (Some(h), _) => h,
        (None, Some(e)) => return Err(ReadError::BadHeader(e)),
        (None, None) => {
            return Err(match damage {
                Some(d) => ReadError::Damaged(d),
                None => ReadError::NotASession("no session header".into()),
            });
        }
    };
    if !(OLDEST_SCHEMA_VERSION..=SCHEMA_VERSION).contains(&header.schema_version) {
        return Err(ReadError::NotASession(format!(
            "schema version {} (this Stylet reads {OLDEST_SCHEMA_VERSION} to {SCHEMA_VERSION})",
            header.schema_version,
        )));
    }
    if let (Mode::Strict, Some(d)) = (mode, &damage) {
        return Err(ReadError::Damaged(d.clone()));
    }
    Ok(Session {
        header,
        end: w.end,
        ticks: w.ticks,
        events: w.events,
        digests: w.digests,
        output_checks: w.output_checks,
        annotations: w.annotations,
        device_forces: w.device_forces,
        chunks: w.chunks,
        damage,
        finished: w.finished,
    })
}

fn load(path: &Path, limits: &Limits) -> Result<Vec<u8>, ReadError> {
    let io = |e: std::io::Error| ReadError::Io(format!("{}: {e}", path.display()));
    let meta = std::fs::metadata(path).map_err(io)?;
    if meta.len() > limits.max_file_bytes {
        return Err(ReadError::NotASession(format!(
            "{}: {} bytes exceed the limit",
            path.display(),
            meta.len()
        )));
    }
    std::fs::read(path).map_err(io)
}

/// Reads an intact session file.
pub fn read(path: &Path) -> Result<Session, ReadError> {
    read_bytes(&load(path, &Limits::default())?, Mode::Strict, &Limits::default())
}

/// Reads what is intact of a damaged or cut file (`damage` says what was lost).
pub fn recover(path: &Path) -> Result<Session, ReadError> {
    read_bytes(&load(path, &Limits::default())?, Mode::Recover, &Limits::default())
}

/// Why a file fails `stylet session verify`: it does not read strictly, or it reads but is not a
/// whole session (unfinished, incomplete, ticks missing or out of place). Only a file that passes
/// is graded or uploaded.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum VerifyError {
    #[error(transparent)]
    Read(#[from] ReadError),
    #[error("the file has no summary and footer")]
    Unfinished,
    #[error("the session has no end record")]
    NoEnd,
    /// The end record says the session is incomplete, and why.
    #[error("the session is incomplete: {0}")]
    Incomplete(String),
    #[error("the session has no ticks")]
    NoTicks,
    #[error("the first tick is {0}, not 0")]
    FirstTick(u64),
    #[error("the end record counts {declared} ticks, the file holds {held}")]
    TickCount { declared: u64, held: u64 },
    #[error("ticks jump from {from} to {to}")]
    Jump { from: u64, to: u64 },
    #[error("a digest at tick {tick} after the last tick {last}")]
    DigestAfterEnd { tick: u64, last: u64 },
    #[error("an event at tick {tick} after the last tick {last}")]
    EventAfterEnd { tick: u64, last: u64 },
}

/// The checks of `stylet session verify`: intact, finished, nothing dropped, ticks from 0 and
/// contiguous, digests and events inside the recorded ticks. `Ok` carries the session.
pub fn verify_bytes(bytes: &[u8]) -> Result<Session, VerifyError> {
    let s = read_bytes(bytes, Mode::Strict, &Limits::default())?;
    let jump = s
        .ticks
        .windows(2)
        .find(|w| w[1].tick != w[0].tick + 1)
        .map(|w| (w[0].tick, w[1].tick));
    let span = s.ticks.first().zip(s.ticks.last()).map(|(a, b)| (a.tick, b.tick));
    check_verified(&s, s.ticks.len() as u64, span, jump)?;
    Ok(s)
}

/// A session checked by [`verify_streaming`]: everything but its ticks, which were checked one
/// block at a time and not kept.
#[derive(Debug, Clone, PartialEq)]
pub struct Verified {
    /// The session, with `ticks` empty.
    pub session: Session,
    pub tick_count: u64,
}

impl Verified {
    /// Recorded length (ticks from 0 are contiguous, so the count gives it).
    pub fn duration_s(&self) -> f64 {
        self.tick_count as f64 / f64::from(self.session.header.tick_rate_hz)
    }
}

/// The checks of [`verify_bytes`] with memory bounded independently of the tick count: ticks are
/// decoded one block at a time, checked and dropped; `limits` (e.g. `max_ticks` from the longest
/// session accepted) are checked before each block is decoded.
pub fn verify_streaming(bytes: &[u8], limits: &Limits) -> Result<Verified, VerifyError> {
    verify_with(|sink| read_bytes_with(bytes, Mode::Strict, limits, Some(sink)))
}

/// [`verify_streaming`] of a file read record by record: its memory is bounded by `limits`
/// whatever the file's size (one record, one decompressed chunk, one tick block). For files from
/// outside (uploads, received to disk first).
pub fn verify_file_streaming<R: Read + Seek>(file: R, limits: &Limits) -> Result<Verified, VerifyError> {
    verify_with(|sink| read_file_with(file, Mode::Strict, limits, Some(sink)))
}

/// Runs a streaming read with a sink that counts the ticks and finds their span and first jump,
/// then the checks of [`verify_bytes`].
fn verify_with(read: impl FnOnce(TickSink<'_>) -> Result<Session, ReadError>) -> Result<Verified, VerifyError> {
    let mut count = 0u64;
    let mut span: Option<(u64, u64)> = None;
    let mut jump: Option<(u64, u64)> = None;
    let mut on_block = |block: &[TickRecord]| {
        for t in block {
            match span {
                Some((_, last)) if jump.is_none() && t.tick != last + 1 => jump = Some((last, t.tick)),
                _ => {}
            }
            span = Some((span.map_or(t.tick, |s| s.0), t.tick));
        }
        count += block.len() as u64;
    };
    let s = read(&mut on_block)?;
    check_verified(&s, count, span, jump)?;
    Ok(Verified {
        session: s,
        tick_count: count,
    })
}

/// The checks shared by both verifications, on the session, its ticks' count and span, and the
/// first jump between ticks (if any).
fn check_verified(
    s: &Session,
    count: u64,
    span: Option<(u64, u64)>,
    jump: Option<(u64, u64)>,
) -> Result<(), VerifyError> {
    if !s.finished {
        return Err(VerifyError::Unfinished);
    }
    let end = s.end.as_ref().ok_or(VerifyError::NoEnd)?;
    if !end.complete {
        return Err(VerifyError::Incomplete(end.reason.clone()));
    }
    let Some((first, last)) = span else {
        return Err(VerifyError::NoTicks);
    };
    if first != 0 {
        return Err(VerifyError::FirstTick(first));
    }
    if end.ticks != count {
        return Err(VerifyError::TickCount {
            declared: end.ticks,
            held: count,
        });
    }
    if let Some((from, to)) = jump {
        return Err(VerifyError::Jump { from, to });
    }
    if let Some(d) = s.digests.iter().find(|d| d.tick > last) {
        return Err(VerifyError::DigestAfterEnd { tick: d.tick, last });
    }
    if let Some(e) = s.events.iter().find(|e| e.tick > last) {
        return Err(VerifyError::EventAfterEnd { tick: e.tick, last });
    }
    Ok(())
}

/// [`verify_bytes`] of a file on disk.
pub fn verify(path: &Path) -> Result<Session, VerifyError> {
    verify_bytes(&load(path, &Limits::default())?)
}

/// Streaming access: hands the ticks to `on_block` block by block in file order without keeping
/// them; stops at the first damage (returned). The returned session has no ticks.
pub fn stream_ticks(path: &Path, on_block: &mut dyn FnMut(&[TickRecord])) -> Result<Session, ReadError> {
    let limits = Limits::default();
    let bytes = load(path, &limits)?;
    read_bytes_with(&bytes, Mode::Recover, &limits, Some(on_block))
}

/// Indexed access: the ticks from `first` to `last` (inclusive), reading only the chunks the
/// summary's chunk index says cover them. Needs a finished file.
pub fn read_tick_range(path: &Path, first: u64, last: u64) -> Result<Vec<TickRecord>, ReadError> {
    let limits = Limits::default();
    let bytes = load(path, &limits)?;
    let header = read_header(&bytes)?;
    let (channels, chunk_indexes) = summary(&bytes)?;
    let rate = header.tick_rate_hz as u64;
    let ns = |tick: u64| tick.saturating_mul(1_000_000_000) / rate;
    let (lo, hi) = (ns(first), ns(last));
    let mut w = Walk {
        limits: &limits,
        sink: None,
        last_tick: None,
        channels,
        header: None,
        end: None,
        ticks: Vec::new(),
        events: Vec::new(),
        digests: Vec::new(),
        output_checks: Vec::new(),
        annotations: Vec::new(),
        device_forces: Vec::new(),
        chunks: Vec::new(),
        tick_count: 0,
        messages: 0,
        finished: false,
        header_error: None,
    };
    for ci in &chunk_indexes {
        // A block starting before `first` may still hold it: widen by one block.
        let block_ns = ns(crate::writer::BLOCK_TICKS as u64);
        if ci.message_end_time.saturating_add(block_ns) < lo || ci.message_start_time > hi {
            continue;
        }
        let start = usize::try_from(ci.chunk_start_offset).unwrap_or(usize::MAX);
        let rec = usize::try_from(ci.chunk_length)
            .ok()
            .and_then(|len| bytes.get(start..start.checked_add(len)?))
            .ok_or_else(|| ReadError::NotASession("chunk index points outside the file".into()))?;
        if rec.len() < 9 || rec[0] != OP_CHUNK {
            return Err(ReadError::NotASession("chunk index does not point at a chunk".into()));
        }
        w.chunk(start as u64, &rec[9..]).map_err(|what| {
            ReadError::Damaged(Damage {
                offset: start as u64,
                what,
                lost_bytes: 0,
            })
        })?;
    }
    w.ticks.retain(|t| t.tick >= first && t.tick <= last);
    Ok(w.ticks)
}

/// The channels and chunk indexes of a finished file's summary section.
fn summary(bytes: &[u8]) -> Result<(BTreeMap<u16, String>, Vec<records::ChunkIndex>), ReadError> {
    let bad = |what: &str| ReadError::NotASession(format!("summary: {what}"));
    // Footer: opcode, length 20, summary start, summary offset start, CRC; then the magic.
    let footer_at = bytes
        .len()
        .checked_sub(8 + 9 + 20)
        .ok_or_else(|| bad("file too short"))?;
    if bytes[footer_at] != OP_FOOTER || &bytes[bytes.len() - 8..] != MAGIC {
        return Err(bad("no footer (the file is not finished)"));
    }
    let Ok(Record::Footer {
        summary_start,
        summary_crc,
    }) = records::parse(OP_FOOTER, &bytes[footer_at + 9..bytes.len() - 8])
    else {
        return Err(bad("bad footer"));
    };
    let mut pos = usize::try_from(summary_start)
        .ok()
        .filter(|&s| s >= 8 && s <= footer_at)
        .ok_or_else(|| bad("no summary section"))?;
    // The index is trusted only if the summary is intact (its CRC runs through the footer's fields).
    if summary_crc == 0 || crc32fast::hash(&bytes[pos..footer_at + 9 + 16]) != summary_crc {
        return Err(bad("CRC mismatch (the file was altered)"));
    }
    let (mut channels, mut indexes) = (BTreeMap::new(), Vec::new());
    while pos < footer_at {
        let op = bytes[pos];
        let len = read_u64(bytes, pos + 1).ok_or_else(|| bad("record header cut off"))?;
        let body = usize::try_from(len)
            .ok()
            .and_then(|l| bytes.get(pos + 9..(pos + 9).checked_add(l)?))
            .filter(|b| pos + 9 + b.len() <= footer_at)
            .ok_or_else(|| bad("record runs past the footer"))?;
        match records::parse(op, body).map_err(|e| bad(&e.to_string()))? {
            Record::Channel { id, topic } => {
                channels.insert(id, topic.to_string());
            }
            Record::ChunkIndex(ci) => indexes.push(ci),
            _ => {}
        }
        pos += 9 + body.len();
    }
    Ok((channels, indexes))
}

/// The session header alone: the metadata record right after the MCAP header (bounded: the first
/// few records only, nothing decompressed). Lets a service decide who may send a file, and with
/// which limits to read it, before reading it.
pub fn read_header(bytes: &[u8]) -> Result<SessionHeader, ReadError> {
    read_header_prefix(bytes)?
        .ok_or_else(|| ReadError::NotASession("no session header at the start of the file".into()))
}

/// [`read_header`] of the first bytes of a file that is still arriving: `Ok(None)` while the
/// bytes end before the header record does (send more), an error as soon as they cannot start a
/// session file.
pub fn read_header_prefix(bytes: &[u8]) -> Result<Option<SessionHeader>, ReadError> {
    let magic_seen = &bytes[..bytes.len().min(8)];
    if magic_seen != &MAGIC[..magic_seen.len()] {
        return Err(ReadError::NotASession("it does not start with the MCAP magic".into()));
    }
    if bytes.len() < 8 {
        return Ok(None);
    }
    let mut pos = 8usize;
    for _ in 0..4 {
        let (Some(&op), Some(len)) = (bytes.get(pos), read_u64(bytes, pos + 1)) else {
            return Ok(None);
        };
        let Some(body) = usize::try_from(len)
            .ok()
            .and_then(|l| bytes.get(pos + 9..(pos + 9).checked_add(l)?))
        else {
            return Ok(None);
        };
        if let Ok(Record::Metadata { name, map }) = records::parse(op, body)
            && name == META_HEADER
        {
            return SessionHeader::from_metadata(&map)
                .map(Some)
                .map_err(ReadError::BadHeader);
        }
        pos += 9 + body.len();
    }
    Err(ReadError::NotASession(
        "no session header at the start of the file".into(),
    ))
}
