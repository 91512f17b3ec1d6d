//! The session writer: its own thread behind a bounded queue, so the 1 kHz loop never waits for
//! the disk (docs/session-format.md "Writing and crash safety").
//!
//! - `record`, `event`, `digest`, `annotate` never block: if the queue is full the item is counted
//!   as dropped and the session is marked incomplete (with counts) — never dropped silently.
//! - The writer thread packs ticks into blocks of [`BLOCK_TICKS`] and closes an MCAP chunk (zstd,
//!   CRC) at least every second of wall time and every [`CHUNK_TICKS`] ticks, flushing it to the OS
//!   and to the disk, so a crash loses at most the last second.
//! - `finish` writes the end metadata and the summary (statistics, chunk and message indexes).

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, sync_channel};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use mcap::records::{MessageHeader, Metadata};
use serde_bytes::ByteBuf;
use stylet_physics::{Event, TickInput, TickOutput};

use crate::codec;
use crate::device_forces::{self, DeviceForceRecord};
use crate::format::*;
use crate::outputs::{self, FORCE_STEPS_PER_N, OutputCheck, OutputDigest, TORQUE_STEPS_PER_NMM};

/// Ticks per block message.
pub const BLOCK_TICKS: usize = 500;
/// Ticks per chunk at most (half a second at 1 kHz): a crash loses at most the unflushed chunk.
pub const CHUNK_TICKS: u64 = 500;
/// Longest wall time between chunk flushes.
pub const FLUSH_INTERVAL: Duration = Duration::from_millis(500);
/// Queue length (items): eight seconds of ticks at 1 kHz.
pub const QUEUE_LEN: usize = 8192;
/// Preview decimation: one preview sample every this many ticks (50 Hz at 1 kHz).
pub const PREVIEW_EVERY: u64 = 20;

/// A note as recorded: at most [`MAX_NOTE_CHARS`] characters.
fn note_text(text: &str) -> String {
    text.chars().take(MAX_NOTE_CHARS).collect()
}

/// Writer settings.
#[derive(Debug, Clone)]
pub struct WriterOptions {
    pub queue_len: usize,
    pub zstd_level: u32,
    /// Sync the file to disk at every flush (survives power loss, not only a killed process).
    pub fsync: bool,
}

impl Default for WriterOptions {
    fn default() -> Self {
        WriterOptions {
            queue_len: QUEUE_LEN,
            zstd_level: 9,
            fsync: true,
        }
    }
}

enum Item {
    Tick(TickRecord),
    /// A block read from a session file with rounded outputs, written as it was read: the same
    /// ticks, the same rounded values, the digest of the original's exact outputs.
    RoundedBlock(Vec<TickRecord>, u64),
    Event(EventRecord),
    Digest(DigestRecord),
    Annotation(AnnotationRecord),
    DeviceForce(DeviceForceRecord),
    /// The session is known to be incomplete for this reason (e.g. recovered from a cut file).
    Incomplete(String),
}

/// What `finish` reports.
#[derive(Debug, Clone, PartialEq)]
pub struct WriteSummary {
    pub path: PathBuf,
    pub ticks: u64,
    pub dropped: u64,
    pub bytes: u64,
    pub complete: bool,
}

/// Errors while writing.
#[derive(Debug, thiserror::Error)]
pub enum WriteError {
    #[error("{path}: {message}")]
    Io { path: String, message: String },
    #[error("the writer thread stopped: {0}")]
    Thread(String),
    /// [`SessionWriter::record_read_blocking`] got ticks that are not whole blocks as read.
    #[error("the ticks are not as a reader returned them: {0}")]
    NotAsRead(String),
}

/// A file handle whose `flush` also syncs to disk when asked.
struct SyncingFile {
    inner: BufWriter<File>,
    fsync: bool,
}

impl Write for SyncingFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.inner.write(buf)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()?;
        if self.fsync {
            self.inner.get_ref().sync_data()?;
        }
        Ok(())
    }
}

impl Seek for SyncingFile {
    fn seek(&mut self, pos: SeekFrom) -> std::io::Result<u64> {
        self.inner.seek(pos)
    }
}

/// What the writer thread reports: ticks written, file bytes, complete.
type Written = (u64, u64, bool);

/// Writes one message on a topic at a tick.
type WriteFn<'a> = dyn FnMut(&mut mcap::Writer<SyncingFile>, &str, u64, &[u8]) -> Result<(), WriteError> + 'a;

/// Records one session.
pub struct SessionWriter {
    tx: Option<SyncSender<Item>>,
    /// Whether the file has the device-force channel (a header naming a force-feedback device).
    device_forces: bool,
    handle: Option<JoinHandle<Result<Written, WriteError>>>,
    dropped: Arc<AtomicU64>,
    path: PathBuf,
}

impl SessionWriter {
    /// Creates the file, writes the header and starts the writer thread.
    pub fn create(path: &Path, header: &SessionHeader, options: WriterOptions) -> Result<Self, WriteError> {
        let io = |e: &dyn std::fmt::Display| WriteError::Io {
            path: path.display().to_string(),
            message: e.to_string(),
        };
        let file = File::create(path).map_err(|e| io(&e))?;
        let sink = SyncingFile {
            inner: BufWriter::with_capacity(1 << 20, file),
            fsync: options.fsync,
        };
        let mut w = mcap::WriteOptions::new()
            .profile(PROFILE)
            .library(format!("stylet-recorder {}", env!("CARGO_PKG_VERSION")))
            .compression(Some(mcap::Compression::Zstd))
            .compression_level(options.zstd_level)
            .chunk_size(None)
            .create(sink)
            .map_err(|e| io(&e))?;
        w.write_metadata(&Metadata {
            name: META_HEADER.into(),
            metadata: header.to_metadata(),
        })
        .map_err(|e| io(&e))?;
        w.flush().map_err(|e| io(&e))?;
        let mut channels = BTreeMap::new();
        let device_forces = header.hardware.is_some();
        let topics = TOPICS
            .into_iter()
            .filter(|t| device_forces || *t != TOPIC_DEVICE_FORCES);
        for topic in topics {
            let schema = w
                .add_schema(&topic.replace('/', "."), SCHEMA_ENCODING, json_schema(topic).as_bytes())
                .map_err(|e| io(&e))?;
            let id = w
                .add_channel(schema, topic, MESSAGE_ENCODING, &BTreeMap::new())
                .map_err(|e| io(&e))?;
            channels.insert(topic, id);
        }
        let (tx, rx) = sync_channel(options.queue_len.max(1));
        let dropped = Arc::new(AtomicU64::new(0));
        let thread_dropped = dropped.clone();
        let rate = header.tick_rate_hz.max(1) as u64;
        let thread_path = path.display().to_string();
        let handle = std::thread::Builder::new()
            .name("stylet-recorder".into())
            .spawn(move || run(w, rx, channels, rate, thread_dropped, thread_path))
            .map_err(|e| io(&e))?;
        Ok(SessionWriter {
            tx: Some(tx),
            device_forces,
            handle: Some(handle),
            dropped,
            path: path.to_path_buf(),
        })
    }

    fn send(&self, item: Item) -> bool {
        match self.tx.as_ref().map(|tx| tx.try_send(item).map_err(|_| ())) {
            Some(Ok(())) => true,
            Some(Err(())) | None => {
                self.dropped.fetch_add(1, Ordering::Relaxed);
                false
            }
        }
    }

    /// Records one tick (input and output) and its events. Never blocks; false if dropped.
    pub fn record(&self, input: &TickInput, output: &TickOutput) -> bool {
        for e in &input.events {
            self.event(output.tick, e);
        }
        self.send(Item::Tick(tick_record(input, output)))
    }

    /// As [`SessionWriter::record`], but waits while the queue is full: for recording offline,
    /// faster than real time (headless scripts, conversions). Never call it from the haptic loop.
    pub fn record_blocking(&self, input: &TickInput, output: &TickOutput) -> Result<(), WriteError> {
        let tx = self.tx.as_ref().ok_or_else(|| WriteError::Thread("finished".into()))?;
        let stopped = |_| WriteError::Thread("the writer thread stopped (see finish)".into());
        for e in &input.events {
            tx.send(Item::Event(EventRecord::from_event(output.tick, e)))
                .map_err(stopped)?;
        }
        tx.send(Item::Tick(tick_record(input, output))).map_err(stopped)
    }

    /// As [`SessionWriter::digest`], waiting while the queue is full (offline recording).
    pub fn digest_blocking(&self, tick: u64, digest: u64) -> Result<(), WriteError> {
        let tx = self.tx.as_ref().ok_or_else(|| WriteError::Thread("finished".into()))?;
        tx.send(Item::Digest(DigestRecord { tick, digest }))
            .map_err(|_| WriteError::Thread("the writer thread stopped".into()))
    }

    /// Records a tick given as a [`TickRecord`] (tests, conversions); never blocks.
    pub fn record_raw(&self, t: TickRecord) -> bool {
        self.send(Item::Tick(t))
    }

    /// As [`SessionWriter::record_raw`], waiting while the queue is full.
    pub fn record_raw_blocking(&self, t: TickRecord) -> Result<(), WriteError> {
        let tx = self.tx.as_ref().ok_or_else(|| WriteError::Thread("finished".into()))?;
        tx.send(Item::Tick(t))
            .map_err(|_| WriteError::Thread("the writer thread stopped".into()))
    }

    /// Records ticks as a reader returned them (a read `Session`'s `ticks` and
    /// `output_checks`), waiting while the queue is full: the ticks of each block with rounded
    /// outputs are written as one block with its digest (the exact outputs are not in the file
    /// any more, so only the original digest still pins them); every other tick as
    /// [`Self::record_raw_blocking`]. For rewriting a session (recovery, tests, tools).
    pub fn record_read_blocking(&self, ticks: &[TickRecord], checks: &[OutputCheck]) -> Result<(), WriteError> {
        let tx = self.tx.as_ref().ok_or_else(|| WriteError::Thread("finished".into()))?;
        let stopped = |_| WriteError::Thread("the writer thread stopped".into());
        let mut checks = checks.iter().peekable();
        let mut i = 0;
        while i < ticks.len() {
            let tick = ticks[i].tick;
            while checks.next_if(|c| c.last_tick() < tick).is_some() {}
            match checks.peek() {
                Some(c) if c.first_tick == tick => {
                    let n = c.count as usize;
                    let block = ticks
                        .get(i..i + n)
                        .filter(|b| b.iter().zip(c.first_tick..).all(|(t, k)| t.tick == k));
                    let Some(block) = block else {
                        return Err(WriteError::NotAsRead(format!(
                            "the block of ticks {}–{} is not among the ticks given",
                            c.first_tick,
                            c.last_tick()
                        )));
                    };
                    tx.send(Item::RoundedBlock(block.to_vec(), c.digest)).map_err(stopped)?;
                    i += n;
                }
                Some(c) if c.covers(tick) => {
                    // The block's first ticks are missing: its digest cannot be checked any more.
                    return Err(WriteError::NotAsRead(format!(
                        "tick {tick} lies inside the block of ticks {}–{}, whose first ticks are not among the ticks given",
                        c.first_tick,
                        c.last_tick()
                    )));
                }
                _ => {
                    tx.send(Item::Tick(ticks[i])).map_err(stopped)?;
                    i += 1;
                }
            }
        }
        Ok(())
    }

    /// Records an event record, waiting while the queue is full (offline recording).
    pub fn event_record_blocking(&self, e: EventRecord) -> Result<(), WriteError> {
        let tx = self.tx.as_ref().ok_or_else(|| WriteError::Thread("finished".into()))?;
        tx.send(Item::Event(e))
            .map_err(|_| WriteError::Thread("the writer thread stopped".into()))
    }

    /// Records a note, waiting while the queue is full (offline recording).
    pub fn annotate_blocking(&self, tick: u64, text: &str) -> Result<(), WriteError> {
        let tx = self.tx.as_ref().ok_or_else(|| WriteError::Thread("finished".into()))?;
        tx.send(Item::Annotation(AnnotationRecord {
            tick,
            text: note_text(text),
        }))
        .map_err(|_| WriteError::Thread("the writer thread stopped".into()))
    }

    /// Records the force a force-feedback device was sent at a tick. Never blocks; false if
    /// dropped, or if the header named no device (the file then has no channel for it).
    pub fn device_force(&self, record: DeviceForceRecord) -> bool {
        self.device_forces && self.send(Item::DeviceForce(record))
    }

    /// As [`SessionWriter::device_force`], waiting while the queue is full (rewriting a file);
    /// nothing for a header without a device.
    pub fn device_force_blocking(&self, record: DeviceForceRecord) -> Result<(), WriteError> {
        if !self.device_forces {
            return Ok(());
        }
        let tx = self.tx.as_ref().ok_or_else(|| WriteError::Thread("finished".into()))?;
        tx.send(Item::DeviceForce(record))
            .map_err(|_| WriteError::Thread("the writer thread stopped".into()))
    }

    /// Records an event. Never blocks; false if dropped.
    pub fn event(&self, tick: u64, e: &Event) -> bool {
        self.send(Item::Event(EventRecord::from_event(tick, e)))
    }

    /// Records the state digest after `tick`.
    pub fn digest(&self, tick: u64, digest: u64) -> bool {
        self.send(Item::Digest(DigestRecord { tick, digest }))
    }

    /// Records a note (cut to [`MAX_NOTE_CHARS`] characters, the most a reader accepts). Never
    /// blocks; false if dropped.
    pub fn annotate(&self, tick: u64, text: &str) -> bool {
        self.send(Item::Annotation(AnnotationRecord {
            tick,
            text: note_text(text),
        }))
    }

    /// Marks the session incomplete (the end record says why); waits while the queue is full.
    pub fn mark_incomplete(&self, reason: &str) -> Result<(), WriteError> {
        let tx = self.tx.as_ref().ok_or_else(|| WriteError::Thread("finished".into()))?;
        tx.send(Item::Incomplete(reason.into()))
            .map_err(|_| WriteError::Thread("the writer thread stopped".into()))
    }

    /// Items the queue could not take so far.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }

    /// Ends the session: drains the queue, writes the end metadata and the summary.
    pub fn finish(mut self) -> Result<WriteSummary, WriteError> {
        drop(self.tx.take());
        let handle = self.handle.take().expect("finish runs once");
        let (ticks, bytes, complete) = handle.join().map_err(|_| WriteError::Thread("panicked".into()))??;
        let dropped = self.dropped();
        Ok(WriteSummary {
            path: self.path.clone(),
            ticks,
            dropped,
            bytes,
            complete,
        })
    }
}

impl Drop for SessionWriter {
    fn drop(&mut self) {
        // Dropped without finish (e.g. the caller panicked): still close the file properly.
        drop(self.tx.take());
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

fn tick_record(input: &TickInput, output: &TickOutput) -> TickRecord {
    let q = input.orientation;
    TickRecord {
        tick: output.tick,
        position_mm: input.position_mm.to_array(),
        orientation: [q.w, q.x, q.y, q.z],
        buttons: input.buttons,
        force_n: output.force_n.to_array(),
        torque_nmm: output.torque_nmm.to_array(),
        tip_label: output.tip_label,
        inserted_mm: output.inserted_mm,
        second_hand: output.second_hand.map(|h| {
            // The pose as the device reported it (the physics' holds its last valid one).
            let (position_mm, orientation, buttons) = match &input.second_hand {
                Some(p) => (p.position_mm, p.orientation, p.buttons),
                None => (h.position_mm, h.orientation, 0),
            };
            HandRecord {
                position_mm: position_mm.to_array(),
                orientation: [orientation.w, orientation.x, orientation.y, orientation.z],
                buttons,
                force_n: h.force_n.to_array(),
                torque_nmm: h.torque_nmm.to_array(),
            }
        }),
    }
}

/// The writer thread.
fn run(
    mut w: mcap::Writer<SyncingFile>,
    rx: Receiver<Item>,
    channels: BTreeMap<&'static str, u16>,
    rate: u64,
    dropped: Arc<AtomicU64>,
    path: String,
) -> Result<Written, WriteError> {
    let io = |e: &dyn std::fmt::Display| WriteError::Io {
        path: path.clone(),
        message: e.to_string(),
    };
    let mut seq: BTreeMap<u16, u32> = BTreeMap::new();
    let ns = |tick: u64| tick.saturating_mul(1_000_000_000) / rate;
    let mut write =
        |w: &mut mcap::Writer<SyncingFile>, topic: &str, tick: u64, data: &[u8]| -> Result<(), WriteError> {
            let channel_id = channels[topic];
            let s = seq.entry(channel_id).or_insert(0);
            *s += 1;
            let header = MessageHeader {
                channel_id,
                sequence: *s,
                log_time: ns(tick),
                publish_time: ns(tick),
            };
            w.write_to_known_channel(&header, data).map_err(|e| io(&e))
        };
    let mut block: Vec<TickRecord> = Vec::with_capacity(BLOCK_TICKS);
    let mut forces: Vec<DeviceForceRecord> = Vec::with_capacity(device_forces::BLOCK_TICKS);

    let mut ticks = 0u64;
    let mut since_flush = 0u64;
    let mut last_flush = Instant::now();
    let mut reported_drops = 0u64;
    let mut incomplete: Option<String> = None;
    loop {
        let timeout = FLUSH_INTERVAL.saturating_sub(last_flush.elapsed());
        let item = rx.recv_timeout(timeout);
        let ended = matches!(item, Err(RecvTimeoutError::Disconnected));
        match item {
            Ok(Item::RoundedBlock(read, digest)) => {
                write_block(&mut write, &mut w, &block)?;
                block.clear();
                for t in read.iter().filter(|t| t.tick % PREVIEW_EVERY == 0) {
                    write(&mut w, TOPIC_PREVIEW, t.tick, &to_cbor(&preview(t, rate)))?;
                }
                let b = encode_rounded_block(&read, digest).ok_or_else(|| {
                    WriteError::Thread(format!(
                        "the block at tick {} does not hold rounded outputs",
                        read.first().map_or(0, |t| t.tick)
                    ))
                })?;
                write(&mut w, TOPIC_TICKS, b.first_tick, &to_cbor(&b))?;
                ticks += read.len() as u64;
                since_flush += read.len() as u64;
            }
            Ok(Item::Tick(t)) => {
                if block.last().is_some_and(|b| b.tick + 1 != t.tick) {
                    write_block(&mut write, &mut w, &block)?;
                    block.clear();
                }
                if t.tick % PREVIEW_EVERY == 0 {
                    write(&mut w, TOPIC_PREVIEW, t.tick, &to_cbor(&preview(&t, rate)))?;
                }
                block.push(t);
                ticks += 1;
                since_flush += 1;
                if block.len() == BLOCK_TICKS {
                    write_block(&mut write, &mut w, &block)?;
                    block.clear();
                }
            }
            Ok(Item::Event(e)) => write(&mut w, TOPIC_EVENTS, e.tick, &to_cbor(&e))?,
            Ok(Item::Digest(d)) => write(&mut w, TOPIC_DIGESTS, d.tick, &to_cbor(&d))?,
            Ok(Item::Annotation(a)) => write(&mut w, TOPIC_ANNOTATIONS, a.tick, &to_cbor(&a))?,
            Ok(Item::DeviceForce(f)) => {
                if forces.last().is_some_and(|l| l.tick + 1 != f.tick) {
                    write_forces(&mut write, &mut w, &mut forces)?;
                }
                forces.push(f);
                if forces.len() == device_forces::BLOCK_TICKS {
                    write_forces(&mut write, &mut w, &mut forces)?;
                }
            }
            Ok(Item::Incomplete(reason)) => incomplete = Some(reason),
            Err(_) => {}
        }
        let now_dropped = dropped.load(Ordering::Relaxed);
        if now_dropped > reported_drops {
            let tick = block.last().map_or(0, |b| b.tick);
            let text = format!(
                "queue full: {} items dropped so far; the session is incomplete",
                now_dropped
            );
            write(
                &mut w,
                TOPIC_ANNOTATIONS,
                tick,
                &to_cbor(&AnnotationRecord { tick, text }),
            )?;
            reported_drops = now_dropped;
        }
        if ended || since_flush >= CHUNK_TICKS || last_flush.elapsed() >= FLUSH_INTERVAL {
            write_block(&mut write, &mut w, &block)?;
            block.clear();
            write_forces(&mut write, &mut w, &mut forces)?;
            w.flush().map_err(|e| io(&e))?;
            since_flush = 0;
            last_flush = Instant::now();
        }
        if ended {
            break;
        }
    }
    let dropped_now = dropped.load(Ordering::Relaxed);
    let mut reasons: Vec<String> = incomplete.into_iter().collect();
    if dropped_now > 0 {
        reasons.push(format!("{dropped_now} items dropped: queue full"));
    }
    let end = SessionEnd {
        ticks,
        dropped_ticks: dropped_now,
        complete: reasons.is_empty(),
        reason: if reasons.is_empty() {
            "finished".into()
        } else {
            reasons.join("; ")
        },
    };
    w.write_metadata(&Metadata {
        name: META_END.into(),
        metadata: end.to_metadata(),
    })
    .map_err(|e| io(&e))?;
    w.finish().map_err(|e| io(&e))?;
    let mut sink = w.into_inner();
    sink.flush().map_err(|e| io(&e))?;
    let bytes = sink.inner.get_ref().metadata().map_err(|e| io(&e))?.len();
    Ok((ticks, bytes, end.complete))
}

/// The preview sample of a tick (f32, for plotting in MCAP tools).
fn preview(t: &TickRecord, rate: u64) -> PreviewRecord {
    let f = t.force_n;
    PreviewRecord {
        tick: t.tick,
        t_s: (t.tick as f64 / rate as f64) as f32,
        position_mm: t.position_mm.map(|v| v as f32),
        force_n: f.map(|v| v as f32),
        force_magnitude_n: (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]).sqrt() as f32,
        tip_label: t.tip_label,
        inserted_mm: t.inserted_mm as f32,
    }
}

/// Writes the device forces gathered so far as one block, and clears them.
fn write_forces(
    write: &mut WriteFn,
    w: &mut mcap::Writer<SyncingFile>,
    forces: &mut Vec<DeviceForceRecord>,
) -> Result<(), WriteError> {
    if forces.is_empty() {
        return Ok(());
    }
    let b = device_forces::encode(forces);
    forces.clear();
    write(w, TOPIC_DEVICE_FORCES, b.first_tick, &to_cbor(&b))
}

fn write_block(write: &mut WriteFn, w: &mut mcap::Writer<SyncingFile>, block: &[TickRecord]) -> Result<(), WriteError> {
    if block.is_empty() {
        return Ok(());
    }
    let b = encode_block(block);
    write(w, TOPIC_TICKS, block[0].tick, &to_cbor(&b))
}

/// Columns of a block of consecutive ticks: codec v2 (rounded forces and torques, the digest of
/// their exact bits) when every output rounds exactly, else codec v1 (every bit stored).
pub fn encode_block(block: &[TickRecord]) -> TickBlock {
    let mut columns = BTreeMap::new();
    let mut f = |name: &str, get: &dyn Fn(&TickRecord) -> f64| {
        let v: Vec<f64> = block.iter().map(get).collect();
        columns.insert(name.to_string(), ByteBuf::from(codec::encode_f64(&v)));
    };
    f("pos_x_mm", &|t| t.position_mm[0]);
    f("pos_y_mm", &|t| t.position_mm[1]);
    f("pos_z_mm", &|t| t.position_mm[2]);
    f("q_w", &|t| t.orientation[0]);
    f("q_x", &|t| t.orientation[1]);
    f("q_y", &|t| t.orientation[2]);
    f("q_z", &|t| t.orientation[3]);
    f("inserted_mm", &|t| t.inserted_mm);
    let rounded = output_steps(block);
    let outputs_digest = match &rounded {
        Some(steps) => {
            for (name, column) in OUTPUT_COLUMNS.iter().zip(steps) {
                columns.insert(name.to_string(), ByteBuf::from(codec::encode_i64(column)));
            }
            let mut d = OutputDigest::default();
            for t in block {
                d.add(t.force_n, t.torque_nmm);
            }
            Some(d.value())
        }
        None => {
            for (a, name) in OUTPUT_COLUMNS.iter().enumerate() {
                f(name, &|t| output(t, a));
            }
            None
        }
    };
    let buttons: Vec<u64> = block.iter().map(|t| t.buttons as u64).collect();
    columns.insert("buttons".into(), ByteBuf::from(codec::encode(&buttons, 4)));
    let labels: Vec<u64> = block.iter().map(|t| t.tip_label as u64).collect();
    columns.insert("tip_label".into(), ByteBuf::from(codec::encode(&labels, 2)));
    if block.iter().any(|t| t.second_hand.is_some()) {
        encode_second_hand(block, &mut columns);
    }
    TickBlock {
        first_tick: block[0].tick,
        count: block.len() as u32,
        codec: if rounded.is_some() {
            COLUMN_CODEC_ROUNDED
        } else {
            COLUMN_CODEC
        }
        .into(),
        columns,
        outputs_digest,
    }
}

/// The second hand's columns (exact in both codecs; zero where a tick has no second hand).
fn encode_second_hand(block: &[TickRecord], columns: &mut BTreeMap<String, ByteBuf>) {
    let present: Vec<u64> = block.iter().map(|t| u64::from(t.second_hand.is_some())).collect();
    columns.insert(HAND2_PRESENT.into(), ByteBuf::from(codec::encode(&present, 1)));
    for (a, name) in HAND2_F64_COLUMNS.iter().enumerate() {
        let v: Vec<f64> = block
            .iter()
            .map(|t| t.second_hand.map_or(0.0, |h| hand_value(&h, a)))
            .collect();
        columns.insert(name.to_string(), ByteBuf::from(codec::encode_f64(&v)));
    }
    let buttons: Vec<u64> = block
        .iter()
        .map(|t| t.second_hand.map_or(0, |h| h.buttons.into()))
        .collect();
    columns.insert(HAND2_BUTTONS.into(), ByteBuf::from(codec::encode(&buttons, 4)));
}

/// The second hand's presence column (u8: 1 where the tick has a second hand).
const HAND2_PRESENT: &str = "hand2";
const HAND2_BUTTONS: &str = "hand2_buttons";
/// The second hand's real columns: position, orientation (w, x, y, z), force, torque.
const HAND2_F64_COLUMNS: [&str; 13] = [
    "hand2_pos_x_mm",
    "hand2_pos_y_mm",
    "hand2_pos_z_mm",
    "hand2_q_w",
    "hand2_q_x",
    "hand2_q_y",
    "hand2_q_z",
    "hand2_force_x_n",
    "hand2_force_y_n",
    "hand2_force_z_n",
    "hand2_torque_x_nmm",
    "hand2_torque_y_nmm",
    "hand2_torque_z_nmm",
];

/// Real column `a` of [`HAND2_F64_COLUMNS`] of a second hand.
fn hand_value(h: &HandRecord, a: usize) -> f64 {
    match a {
        0..3 => h.position_mm[a],
        3..7 => h.orientation[a - 3],
        7..10 => h.force_n[a - 7],
        _ => h.torque_nmm[a - 10],
    }
}

/// A block read back from a file with rounded outputs, encoded again with the `digest` it was
/// read with (the exact outputs are gone). `None` if a value is not a rounded output or the
/// ticks are not consecutive.
fn encode_rounded_block(block: &[TickRecord], digest: u64) -> Option<TickBlock> {
    let first = block.first()?.tick;
    let consecutive = block.iter().zip(first..).all(|(t, k)| t.tick == k);
    let rounded = block
        .iter()
        .all(|t| outputs::rounded_outputs(t.force_n, t.torque_nmm) == Some((t.force_n, t.torque_nmm)));
    if !consecutive || !rounded {
        return None;
    }
    let mut b = encode_block(block);
    b.outputs_digest = Some(digest);
    Some(b)
}

/// The output columns: force (N) then torque (N·mm), x, y, z.
const OUTPUT_COLUMNS: [&str; 6] = [
    "force_x_n",
    "force_y_n",
    "force_z_n",
    "torque_x_nmm",
    "torque_y_nmm",
    "torque_z_nmm",
];

/// Steps per unit of output column `a` ([`OUTPUT_COLUMNS`]).
fn steps_per_unit(a: usize) -> f64 {
    if a < 3 { FORCE_STEPS_PER_N } else { TORQUE_STEPS_PER_NMM }
}

/// Output column `a` of a tick.
fn output(t: &TickRecord, a: usize) -> f64 {
    if a < 3 { t.force_n[a] } else { t.torque_nmm[a - 3] }
}

/// The block's outputs in steps, column by column, or `None` if one cannot be rounded exactly.
fn output_steps(block: &[TickRecord]) -> Option<Vec<Vec<i64>>> {
    (0..OUTPUT_COLUMNS.len())
        .map(|a| {
            block
                .iter()
                .map(|t| outputs::steps(output(t, a), steps_per_unit(a)))
                .collect()
        })
        .collect()
}

/// A decoded tick block: its ticks and, for a codec-v2 block, what its rounded outputs promise.
#[derive(Debug, Clone, PartialEq)]
pub struct DecodedBlock {
    /// The ticks; in a codec-v2 block their forces and torques are the rounded values.
    pub ticks: Vec<TickRecord>,
    pub check: Option<OutputCheck>,
}

/// Why a tick block cannot be decoded: its codec and digest disagree, its tick count or numbers
/// are impossible, or a column is missing or malformed. A reader treats it as damage.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum BlockError {
    /// An exact-codec block that carries an outputs digest.
    #[error("a '{COLUMN_CODEC}' block with an outputs digest")]
    UnexpectedDigest,
    /// A rounded-codec block without the digest of its exact outputs.
    #[error("a '{COLUMN_CODEC_ROUNDED}' block without its outputs digest")]
    MissingDigest,
    /// The codec name (at most 64 characters of it).
    #[error("unknown column codec '{0}'")]
    UnknownCodec(String),
    #[error("block of {0} ticks")]
    TickCount(usize),
    #[error("block tick numbers overflow")]
    TickOverflow,
    #[error("block lacks column '{0}'")]
    MissingColumn(&'static str),
    #[error("column '{column}' has {bytes} bytes, not {expected}")]
    ColumnLength {
        column: &'static str,
        bytes: usize,
        expected: usize,
    },
    /// A flag column holding a value other than 0 or 1.
    #[error("column '{0}' holds a value other than 0 or 1")]
    NotAFlag(&'static str),
    /// A rounded output column holds a step count that no exact value rounds to.
    #[error("column '{0}' holds a step count out of range")]
    StepOutOfRange(&'static str),
}

/// The ticks of a block; names the first problem.
pub fn decode_block(b: &TickBlock) -> Result<DecodedBlock, BlockError> {
    let rounded = match (b.codec.as_str(), b.outputs_digest) {
        (COLUMN_CODEC, None) => false,
        (COLUMN_CODEC_ROUNDED, Some(_)) => true,
        (COLUMN_CODEC, Some(_)) => return Err(BlockError::UnexpectedDigest),
        (COLUMN_CODEC_ROUNDED, None) => return Err(BlockError::MissingDigest),
        (other, _) => {
            let shown: String = other.chars().take(64).collect();
            return Err(BlockError::UnknownCodec(shown));
        }
    };
    let n = b.count as usize;
    if n == 0 || n > 100_000 {
        return Err(BlockError::TickCount(n));
    }
    if b.first_tick.checked_add(n as u64).is_none() {
        return Err(BlockError::TickOverflow);
    }
    let bytes_of = |name: &'static str| b.columns.get(name).ok_or(BlockError::MissingColumn(name));
    let wrong_length = |name: &'static str, bytes: &ByteBuf, width: usize| BlockError::ColumnLength {
        column: name,
        bytes: bytes.len(),
        expected: n * width,
    };
    let col = |name: &'static str, width: usize| -> Result<Vec<u64>, BlockError> {
        let bytes = bytes_of(name)?;
        codec::decode(bytes, width, n).ok_or_else(|| wrong_length(name, bytes, width))
    };
    let fc = |name: &'static str| -> Result<Vec<f64>, BlockError> {
        let bytes = bytes_of(name)?;
        codec::decode_f64(bytes, n).ok_or_else(|| wrong_length(name, bytes, 8))
    };
    let out = |a: usize| -> Result<Vec<f64>, BlockError> {
        let name = OUTPUT_COLUMNS[a];
        if !rounded {
            return fc(name);
        }
        let bytes = bytes_of(name)?;
        let steps = codec::decode_i64(bytes, n).ok_or_else(|| wrong_length(name, bytes, 8))?;
        let per = steps_per_unit(a);
        steps
            .into_iter()
            .map(|s| {
                // Counts beyond 2⁵³ were never written (and would not be exact).
                let v = outputs::from_steps(s, per);
                (outputs::steps(v, per) == Some(s))
                    .then_some(v)
                    .ok_or(BlockError::StepOutOfRange(name))
            })
            .collect()
    };
    let (px, py, pz) = (fc("pos_x_mm")?, fc("pos_y_mm")?, fc("pos_z_mm")?);
    let (qw, qx, qy, qz) = (fc("q_w")?, fc("q_x")?, fc("q_y")?, fc("q_z")?);
    let (fx, fy, fz) = (out(0)?, out(1)?, out(2)?);
    let (tx, ty, tz) = (out(3)?, out(4)?, out(5)?);
    let ins = fc("inserted_mm")?;
    let buttons = col("buttons", 4)?;
    let labels = col("tip_label", 2)?;
    let hands: Vec<Option<HandRecord>> = if b.columns.contains_key(HAND2_PRESENT) {
        let present = col(HAND2_PRESENT, 1)?;
        let reals = HAND2_F64_COLUMNS
            .iter()
            .map(|name| fc(name))
            .collect::<Result<Vec<_>, _>>()?;
        let hand_buttons = col(HAND2_BUTTONS, 4)?;
        (0..n)
            .map(|i| match present[i] {
                0 => Ok(None),
                1 => {
                    let r = |a: usize| reals[a][i];
                    Ok(Some(HandRecord {
                        position_mm: [r(0), r(1), r(2)],
                        orientation: [r(3), r(4), r(5), r(6)],
                        buttons: hand_buttons[i] as u32,
                        force_n: [r(7), r(8), r(9)],
                        torque_nmm: [r(10), r(11), r(12)],
                    }))
                }
                _ => Err(BlockError::NotAFlag(HAND2_PRESENT)),
            })
            .collect::<Result<_, _>>()?
    } else {
        vec![None; n]
    };
    let ticks = (0..n)
        .map(|i| TickRecord {
            tick: b.first_tick + i as u64,
            position_mm: [px[i], py[i], pz[i]],
            orientation: [qw[i], qx[i], qy[i], qz[i]],
            buttons: buttons[i] as u32,
            force_n: [fx[i], fy[i], fz[i]],
            torque_nmm: [tx[i], ty[i], tz[i]],
            tip_label: labels[i] as u16,
            inserted_mm: ins[i],
            second_hand: hands[i],
        })
        .collect();
    Ok(DecodedBlock {
        ticks,
        check: b.outputs_digest.map(|digest| OutputCheck {
            first_tick: b.first_tick,
            count: b.count,
            digest,
        }),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ticks(n: u64) -> Vec<TickRecord> {
        (0..n)
            .map(|tick| {
                let t = tick as f64 * 1e-3;
                TickRecord {
                    tick,
                    position_mm: [t, 2.0 * t, 3.0],
                    orientation: [1.0, 0.0, 0.0, 0.0],
                    buttons: 0,
                    force_n: [0.1 + t.sin(), -0.3 * t, 0.0],
                    torque_nmm: [t.cos(), 0.0, 1e-7 * t],
                    tip_label: 1,
                    inserted_mm: 0.0,
                    second_hand: None,
                }
            })
            .collect()
    }

    /// A block with rounded outputs states so twice (codec and digest); each mismatch, a missing
    /// column and a step count beyond 2⁵³ is named.
    #[test]
    fn rounded_blocks_are_checked_when_decoded() {
        let block = encode_block(&ticks(50));
        assert_eq!(block.codec, COLUMN_CODEC_ROUNDED);
        let decoded = decode_block(&block).unwrap();
        assert_eq!(decoded.check.map(|c| (c.first_tick, c.count)), Some((0, 50)));

        let mut no_digest = block.clone();
        no_digest.outputs_digest = None;
        let e = decode_block(&no_digest).unwrap_err();
        assert_eq!(e, BlockError::MissingDigest);
        assert!(e.to_string().contains("without its outputs digest"), "{e}");

        let mut exact_with_digest = encode_block(&{
            let mut t = ticks(50);
            t[3].force_n[0] = f64::INFINITY;
            t
        });
        assert_eq!(exact_with_digest.codec, COLUMN_CODEC);
        assert!(decode_block(&exact_with_digest).unwrap().check.is_none());
        exact_with_digest.outputs_digest = Some(1);
        let e = decode_block(&exact_with_digest).unwrap_err();
        assert_eq!(e, BlockError::UnexpectedDigest);
        assert!(e.to_string().contains("with an outputs digest"), "{e}");

        let mut missing = block.clone();
        missing.columns.remove("torque_y_nmm");
        let e = decode_block(&missing).unwrap_err();
        assert_eq!(e, BlockError::MissingColumn("torque_y_nmm"));
        assert!(e.to_string().contains("lacks column 'torque_y_nmm'"), "{e}");

        let mut huge = block.clone();
        let mut steps = vec![0i64; 50];
        steps[7] = 1 << 60;
        huge.columns
            .insert("force_z_n".into(), ByteBuf::from(codec::encode_i64(&steps)));
        let e = decode_block(&huge).unwrap_err();
        assert_eq!(e, BlockError::StepOutOfRange("force_z_n"));
        assert!(
            e.to_string().contains("'force_z_n' holds a step count out of range"),
            "{e}"
        );
    }
}
