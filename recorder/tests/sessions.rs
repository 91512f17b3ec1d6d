//! Session files: round trip, damage (cuts and bit flips at every 4 KiB boundary), hostile
//! input, queue overflow, streaming and indexed access, and the committed schema fixture.

use std::path::{Path, PathBuf};

use stylet_physics::{DeformSettings, Event, Gauge, ToolSpec};
use stylet_recorder::format::{DigestRecord, PoseError, TickRecord};
use stylet_recorder::format::{HandRecord, HardwareDevice, SecondHandHeader};
use stylet_recorder::outputs::{OutputCheck, OutputDigest, rounded_outputs};
use stylet_recorder::reader::{self, DamageKind, LimitExceeded, Limits, MessageError, Mode, VerifyError};
use stylet_recorder::{EventRecord, SessionHeader, SessionWriter, WriterOptions};

fn header() -> SessionHeader {
    SessionHeader {
        schema_version: stylet_recorder::SCHEMA_VERSION,
        session_id: "00000000-0000-4000-8000-000000000001".into(),
        trainee: "alice".into(),
        scenario: "ptcd-intercostal".into(),
        difficulty: "beginner".into(),
        atlas_id: "phantom".into(),
        atlas_hash: "ab".repeat(32),
        software_version: "stylet test".into(),
        physics_version: stylet_physics::PHYSICS_VERSION,
        tick_rate_hz: 1000,
        seed: 7,
        device: "premium".into(),
        initial_tool: ToolSpec::Needle {
            gauge: Gauge::G18,
            length_mm: 150.0,
            stylet_in: true,
        },
        wall_clock_start: "2026-11-22T12:00:00Z".into(),
        deformation: DeformSettings::on(),
        // Not the defaults, so that the round trip shows every value travels.
        contrast: stylet_physics::ContrastSettings {
            front_fraction: 0.75,
            steps_per_update: 3,
            rate_ml_per_s: 0.75,
            settle_s: 7.5,
            ..Default::default()
        },
        // Not the defaults either: every breathing value must travel.
        breathing: stylet_physics::motion::BreathingSettings {
            enabled: true,
            motion: stylet_physics::motion::SyntheticMotion {
                amplitude_mm: 17.5,
                anterior_ratio: 0.25,
                wall_mm: 14.0,
                bone_margin_mm: 2.5,
            },
            signal: stylet_physics::motion::SignalParams {
                period_s: 4.7,
                period_jitter: 0.2,
                depth_jitter: 0.05,
                power: 3,
                seed: 1_234_567_890_123,
            },
            measured: false,
        },
        hardware: Some(HardwareDevice {
            backend: "dhd".into(),
            model: "omega.3 (serial 1234)".into(),
            max_force_n: 12.0,
            max_continuous_force_n: 12.0,
        }),
        second_hand: None,
    }
}

/// A hand-like needle session: slow insertion with tremor, force growing with depth. (The
/// committed fixture holds exactly these values: keep the literal 0.70710678.)
#[allow(clippy::approx_constant)]
pub fn synthetic_ticks(n: u64, seed: u64) -> Vec<TickRecord> {
    let mut state = seed | 1;
    let mut noise = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    (0..n)
        .map(|tick| {
            let t = tick as f64 / 1000.0;
            let depth = 60.0 * (1.0 - (-(t % 60.0) / 20.0).exp());
            let tremor = 0.05 * (t * 2.0 * std::f64::consts::PI * 8.0).sin() + 0.01 * noise();
            TickRecord {
                tick,
                position_mm: [
                    150.0 - depth + tremor,
                    1.5 + 0.3 * depth + 0.5 * tremor,
                    15.9 - 0.1 * depth,
                ],
                orientation: [0.70710678, 0.0, -0.70710678 + 1e-4 * (t * 0.3).sin(), 0.0],
                buttons: (tick / 5000 % 2) as u32,
                force_n: [0.02 * depth + 0.05 * noise(), 0.01 * noise(), -0.005 * depth],
                torque_nmm: [0.0, 0.0, 0.0],
                tip_label: if depth < 3.0 {
                    2
                } else if depth < 20.0 {
                    3
                } else {
                    10
                },
                inserted_mm: depth,
                second_hand: None,
            }
        })
        .collect()
}

fn write_session(path: &Path, ticks: &[TickRecord], options: WriterOptions) -> stylet_recorder::WriteSummary {
    let w = SessionWriter::create(path, &header(), options).unwrap();
    for t in ticks {
        if t.tick % 10_000 == 5 {
            w.event_record_blocking(EventRecord::from_event(t.tick, &Event::ContrastInject { ml: 1.5 }))
                .unwrap();
        }
        w.record_raw_blocking(*t).unwrap();
        if t.tick % 100 == 99 {
            w.digest_blocking(t.tick, t.tick.wrapping_mul(0x9E37_79B9_7F4A_7C15))
                .unwrap();
        }
    }
    w.finish().unwrap()
}

/// A device force for `tick`: a smooth push, a guard flag now and then.
fn device_force(tick: u64) -> stylet_recorder::device_forces::DeviceForceRecord {
    let t = tick as f64 * 1e-3;
    stylet_recorder::device_forces::DeviceForceRecord {
        tick,
        sent_n: [0.25 * t.sin(), 0.0, 1.5 * t],
        guard: (tick / 97 % 128) as u8,
    }
}

/// A session trained on a force-feedback device keeps the force it was sent, tick by tick (to
/// the 2⁻¹⁶ N step) with the guard's flags; a session without a device has no channel for it,
/// and what is sent to its writer is refused rather than stored.
#[test]
fn device_forces_are_kept_beside_the_ticks() {
    let d = tempfile::tempdir().unwrap();
    let with_device = d.path().join("device.mcap");
    let ticks = synthetic_ticks(1300, 3);
    let w = SessionWriter::create(&with_device, &header(), WriterOptions::default()).unwrap();
    for t in &ticks {
        w.record_raw_blocking(*t).unwrap();
        assert!(w.device_force(device_force(t.tick)) || w.dropped() > 0);
    }
    w.finish().unwrap();
    let s = reader::verify(&with_device).unwrap();
    assert_eq!(s.header.schema_version, stylet_recorder::SCHEMA_VERSION);
    assert_eq!(s.device_forces.len(), 1300);
    for (r, t) in s.device_forces.iter().zip(&ticks) {
        let want = device_force(t.tick);
        assert_eq!((r.tick, r.guard), (want.tick, want.guard));
        for k in 0..3 {
            assert!((r.sent_n[k] - want.sent_n[k]).abs() <= 1.0 / 131072.0);
        }
    }
    // A recovered copy keeps them.
    let copy = d.path().join("copy.mcap");
    stylet_recorder::rewrite_recovered(&s, "device.mcap", &copy).unwrap();
    assert_eq!(reader::verify(&copy).unwrap().device_forces, s.device_forces);

    let without = d.path().join("plain.mcap");
    let plain = SessionHeader {
        hardware: None,
        ..header()
    };
    let w = SessionWriter::create(&without, &plain, WriterOptions::default()).unwrap();
    w.record_raw_blocking(ticks[0]).unwrap();
    assert!(!w.device_force(device_force(0)));
    w.finish().unwrap();
    let bytes = std::fs::read(&without).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    assert!(
        summary
            .channels
            .values()
            .all(|c| c.topic != stylet_recorder::format::TOPIC_DEVICE_FORCES)
    );
    let s = reader::verify(&without).unwrap();
    assert!(s.device_forces.is_empty() && s.header.hardware.is_none());
}

/// `t` as a block with rounded outputs (codec v2) stores it.
fn as_recorded(t: &TickRecord) -> TickRecord {
    let (force_n, torque_nmm) = rounded_outputs(t.force_n, t.torque_nmm).unwrap();
    TickRecord {
        force_n,
        torque_nmm,
        ..*t
    }
}

/// Whether the ticks read (`a`) are the ticks written (`b`), bit for bit, with the forces and
/// torques rounded as the writer stores them.
fn same(a: &[TickRecord], b: &[TickRecord]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.same_bits(&as_recorded(y)))
}

/// Every bit, outputs included (files and blocks written with codec v1).
fn same_exact(a: &[TickRecord], b: &[TickRecord]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.same_bits(y))
}

/// The output checks of a session cover `ticks` block after block, and each digest is that of
/// the exact outputs written.
fn checks_pin_the_exact_outputs(checks: &[OutputCheck], ticks: &[TickRecord]) {
    let base = ticks[0].tick;
    let mut next = base;
    for c in checks {
        assert_eq!(c.first_tick, next);
        let mut d = OutputDigest::default();
        for t in &ticks[(c.first_tick - base) as usize..=(c.last_tick() - base) as usize] {
            d.add(t.force_n, t.torque_nmm);
        }
        assert_eq!(d.value(), c.digest, "block at tick {}", c.first_tick);
        next = c.last_tick() + 1;
    }
    assert_eq!(next, ticks.last().unwrap().tick + 1);
}

/// 10 minutes of 1 kHz ticks come back bit for bit; prints the size per minute.
#[test]
fn ten_minutes_round_trip() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("s.mcap");
    let ticks = synthetic_ticks(600_000, 1);
    let summary = write_session(&p, &ticks, WriterOptions::default());
    assert_eq!(summary.ticks, 600_000);
    assert!(summary.complete);
    let s = reader::verify(&p).unwrap();
    assert!(same(&s.ticks, &ticks));
    checks_pin_the_exact_outputs(&s.output_checks, &ticks);
    assert_eq!(s.header, header());
    assert_eq!(s.events.len(), 60);
    assert_eq!(
        s.events[0],
        EventRecord::from_event(5, &Event::ContrastInject { ml: 1.5 })
    );
    assert_eq!(s.digests.len(), 6000);
    assert_eq!(
        s.digests[0],
        DigestRecord {
            tick: 99,
            digest: 99u64.wrapping_mul(0x9E37_79B9_7F4A_7C15)
        }
    );
    assert!(s.complete());
    let raw = (std::mem::size_of::<f64>() * 14 + 4 + 2) as f64 * 600_000.0;
    println!(
        "10 min at 1 kHz: {:.3} MB ({:.3} MB/min), raw tick data {:.1} MB: ratio {:.1}:1",
        summary.bytes as f64 / 1e6,
        summary.bytes as f64 / 1e6 / 10.0,
        raw / 1e6,
        raw / summary.bytes as f64
    );
}

/// The expected intact prefix: the ticks of the chunks that end at or before `cut`.
fn expected_prefix(chunks: &[reader::ChunkInfo], ticks: &[TickRecord], cut: u64) -> usize {
    let last = chunks.iter().filter(|c| c.end <= cut).filter_map(|c| c.last_tick).max();
    last.map_or(0, |l| ticks.iter().position(|t| t.tick == l).unwrap() + 1)
}

/// An altered data-end opcode turns the record into an unknown one, which MCAP readers skip: the
/// data section's CRC would go unchecked. A footer with no data end before it is damage.
#[test]
fn a_file_without_its_data_end_does_not_verify() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("s.mcap");
    write_session(&p, &synthetic_ticks(2_000, 2), WriterOptions::default());
    let mut bytes = std::fs::read(&p).unwrap();
    // Walk the records after the magic to the data end (opcode 0x0f).
    let mut pos = 8;
    while bytes[pos] != 0x0f {
        pos += 9 + u64::from_le_bytes(bytes[pos + 1..pos + 9].try_into().unwrap()) as usize;
    }
    bytes[pos] ^= 0x10;
    match reader::read_bytes(&bytes, Mode::Strict, &Limits::default()) {
        Err(reader::ReadError::Damaged(d)) => assert_eq!(d.what, DamageKind::NoDataEnd),
        other => panic!("altered data end read as {:?}", other.map(|s| s.ticks.len())),
    }
    assert!(reader::verify_bytes(&bytes).is_err());
}

/// Cuts and bit flips at every 4 KiB boundary: verify names the damage, nothing panics, recover
/// returns the intact prefix.
#[test]
fn damage_at_every_4k_boundary() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("s.mcap");
    let ticks = synthetic_ticks(30_000, 2);
    write_session(&p, &ticks, WriterOptions::default());
    let bytes = std::fs::read(&p).unwrap();
    let full = reader::read_bytes(&bytes, Mode::Strict, &Limits::default()).unwrap();
    assert!(full.chunks.len() >= 30, "{} chunks", full.chunks.len());
    let mut cuts = 0;
    for off in (4096..bytes.len()).step_by(4096) {
        // Cut.
        let cut = &bytes[..off];
        let e = match stylet_recorder::reader::verify_bytes(cut) {
            Ok(_) => panic!("cut at {off} of {} bytes: the cut file verified", bytes.len()),
            Err(e) => e.to_string(),
        };
        assert!(e.contains("byte") || e.contains("cut"), "cut at {off}: {e}");
        let r = reader::read_bytes(cut, Mode::Recover, &Limits::default()).unwrap();
        let want = expected_prefix(&full.chunks, &ticks, off as u64);
        assert!(
            r.ticks.len() >= want,
            "cut at {off}: recovered {} ticks, {want} were intact",
            r.ticks.len()
        );
        assert!(
            same(&r.ticks, &ticks[..r.ticks.len()]),
            "cut at {off}: recovered ticks differ"
        );
        assert!(r.damage.is_some());
        cuts += 1;
        // Bit flip.
        let mut flipped = bytes.clone();
        flipped[off] ^= 0x10;
        let e = match stylet_recorder::reader::verify_bytes(&flipped) {
            Ok(_) => panic!("bit flip at {off} of {} bytes: the damaged file verified", bytes.len()),
            Err(e) => e,
        };
        assert!(!e.to_string().is_empty());
        if let Ok(r) = reader::read_bytes(&flipped, Mode::Recover, &Limits::default()) {
            let want = expected_prefix(&full.chunks, &ticks, off as u64);
            assert!(
                r.ticks.len() >= want,
                "flip at {off}: recovered {} ticks, {want} were intact",
                r.ticks.len()
            );
            assert!(
                same(&r.ticks, &ticks[..r.ticks.len()]),
                "flip at {off}: recovered ticks differ"
            );
        }
    }
    assert!(cuts > 10);
}

#[test]
fn hostile_and_garbage_files_are_refused_with_reasons() {
    let lim = Limits::default();
    assert!(
        reader::read_bytes(b"", Mode::Recover, &lim)
            .unwrap_err()
            .to_string()
            .contains("magic")
    );
    assert!(
        reader::read_bytes(b"hello world, not mcap", Mode::Recover, &lim)
            .unwrap_err()
            .to_string()
            .contains("magic")
    );
    // A record claiming 2^60 bytes right after the magic.
    let mut evil = b"\x89MCAP0\r\n".to_vec();
    evil.push(0x01);
    evil.extend_from_slice(&(1u64 << 60).to_le_bytes());
    let e = reader::read_bytes(&evil, Mode::Recover, &lim).unwrap_err().to_string();
    assert!(e.contains("limit"), "{e}");
    // A chunk claiming 1 TiB uncompressed.
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("s.mcap");
    write_session(&p, &synthetic_ticks(3000, 3), WriterOptions::default());
    let mut bytes = std::fs::read(&p).unwrap();
    let s = reader::read_bytes(&bytes, Mode::Strict, &lim).unwrap();
    let c = s.chunks[0].offset as usize;
    bytes[c + 9 + 16..c + 9 + 24].copy_from_slice(&(1u64 << 40).to_le_bytes());
    let r = reader::read_bytes(&bytes, Mode::Recover, &lim).unwrap();
    let what = r.damage.unwrap().what;
    assert_eq!(what, DamageKind::OverLimit(LimitExceeded::Chunk(1 << 40)));
    assert!(what.to_string().contains("over the limit"), "{what}");
    // Tight limits are honoured.
    let tight = Limits {
        max_ticks: 1000,
        ..Limits::default()
    };
    let r = reader::read_bytes(&std::fs::read(&p).unwrap(), Mode::Recover, &tight).unwrap();
    let what = r.damage.unwrap().what;
    assert_eq!(what, DamageKind::OverLimit(LimitExceeded::Ticks(1000)));
    assert!(what.to_string().contains("more than 1000 ticks"), "{what}");
}

/// A queue that overflows marks the session incomplete with counts.
#[test]
fn a_full_queue_marks_the_session_incomplete() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("s.mcap");
    let w = SessionWriter::create(
        &p,
        &header(),
        WriterOptions {
            queue_len: 4,
            ..WriterOptions::default()
        },
    )
    .unwrap();
    let mut refused = 0;
    for t in synthetic_ticks(20_000, 4) {
        if !w.record_raw(t) {
            refused += 1;
        }
    }
    let summary = w.finish().unwrap();
    assert!(refused > 0 && summary.dropped == refused && !summary.complete);
    let s = reader::read(&p).unwrap();
    let end = s.end.clone().unwrap();
    assert!(!end.complete && end.dropped_ticks == refused, "{end:?}");
    assert!(s.annotations.iter().any(|a| a.text.contains("queue full")));
    let e = reader::verify(&p).unwrap_err();
    assert!(matches!(e, VerifyError::Incomplete(_)), "{e}");
    assert!(e.to_string().contains("incomplete"), "{e}");
}

#[test]
fn streaming_and_indexed_access() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("s.mcap");
    let ticks = synthetic_ticks(12_345, 5);
    write_session(&p, &ticks, WriterOptions::default());
    let mut streamed = Vec::new();
    let mut blocks = 0;
    let s = reader::stream_ticks(&p, &mut |b: &[TickRecord]| {
        blocks += 1;
        streamed.extend_from_slice(b);
    })
    .unwrap();
    assert!(s.ticks.is_empty() && blocks >= 12_345 / 500);
    assert!(same(&streamed, &ticks));
    // Streaming keeps the blocks' output checks (a few bytes per 500 ticks).
    checks_pin_the_exact_outputs(&s.output_checks, &ticks);
    let range = reader::read_tick_range(&p, 1234, 5678).unwrap();
    assert!(same(&range, &ticks[1234..=5678]));
    let tail = reader::read_tick_range(&p, 12_000, 20_000).unwrap();
    assert!(same(&tail, &ticks[12_000..]));
}

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures").join(name)
}

/// The committed schema-version-1 file still reads, with its exact content (every output bit:
/// version 1 had no rounded blocks). Frozen: it was written by the version-1 writer.
#[test]
fn schema_v1_fixture_reads() {
    let path = fixture("session-v1.mcap");
    let ticks = synthetic_ticks(1500, 6);
    let s = reader::verify(&path).unwrap();
    assert_eq!(s.header.schema_version, 1);
    assert_eq!(s.header.trainee, "alice");
    // Written before the world model was recorded: no deformation.
    assert_eq!(s.header.deformation, DeformSettings::off());
    assert!(same_exact(&s.ticks, &ticks));
    assert!(s.output_checks.is_empty());
    assert_eq!(s.digests.len(), 15);
}

/// The committed schema-version-2 file reads: rounded outputs and the digests of the exact ones.
/// Frozen: it was written by the version-2 writer.
#[test]
fn schema_v2_fixture_reads() {
    let path = fixture("session-v2.mcap");
    let ticks = synthetic_ticks(1500, 6);
    let s = reader::verify(&path).unwrap();
    assert_eq!(s.header.schema_version, 2);
    assert_eq!(s.header.trainee, "alice");
    assert!(same(&s.ticks, &ticks));
    assert_eq!(s.output_checks.len(), 3);
    checks_pin_the_exact_outputs(&s.output_checks, &ticks);
    assert_eq!(s.digests.len(), 15);
    assert!(s.header.hardware.is_none() && s.device_forces.is_empty());
}

/// The committed schema-version-3 file reads: a session trained on a force-feedback device, its
/// header naming the device and the force it was sent beside every tick.
/// (Regenerate it only when adding a new schema version:
/// `STYLET_WRITE_FIXTURE=1 cargo test -p stylet-recorder fixture`.)
#[test]
fn schema_v3_fixture_reads() {
    let path = fixture("session-v3.mcap");
    let ticks = synthetic_ticks(1500, 6);
    if std::env::var("STYLET_WRITE_FIXTURE").is_ok() {
        let w = SessionWriter::create(&path, &header(), WriterOptions::default()).unwrap();
        for t in &ticks {
            w.record_raw_blocking(*t).unwrap();
            w.device_force_blocking(device_force(t.tick)).unwrap();
            if t.tick % 100 == 99 {
                w.digest_blocking(t.tick, t.tick.wrapping_mul(0x9E37_79B9_7F4A_7C15))
                    .unwrap();
            }
        }
        w.finish().unwrap();
    }
    let s = reader::verify(&path).unwrap();
    assert_eq!(s.header.schema_version, 3);
    assert_eq!(s.header.hardware, header().hardware);
    assert!(same(&s.ticks, &ticks));
    assert_eq!(s.digests.len(), 15);
    assert_eq!(s.device_forces.len(), 1500);
    for r in &s.device_forces {
        let want = device_force(r.tick);
        assert_eq!(r.guard, want.guard);
        assert!((0..3).all(|k| (r.sent_n[k] - want.sent_n[k]).abs() <= 1.0 / 131072.0));
    }
}

/// A convex probe in the second hand over the ticks of [`synthetic_ticks`]: it is picked up at tick
/// `from` (the ticks before have no second hand), pressed and swept, its force exact to the bit.
fn with_second_hand(mut ticks: Vec<TickRecord>, from: u64) -> Vec<TickRecord> {
    for t in &mut ticks {
        let s = t.tick as f64 * 1e-3;
        t.second_hand = (t.tick >= from).then(|| HandRecord {
            position_mm: [180.0 - 0.2 * s, 20.0 + 3.0 * (0.5 * s).sin(), 40.0],
            orientation: [0.5, 0.5, -0.5, 0.5 + 1e-5 * s.cos()],
            buttons: (t.tick / 700 % 2) as u32,
            force_n: [1.0 + 0.1 * (3.0 * s).sin(), 0.013 * s, -0.2],
            torque_nmm: [0.0, 2.0 * s.cos(), 0.0],
        });
    }
    ticks
}

/// The second hand of a two-handed session as its header records it.
fn two_handed_header() -> SessionHeader {
    SessionHeader {
        second_hand: Some(SecondHandHeader {
            device: "touch".into(),
            initial_tool: Some(stylet_physics::HandTool::Probe(stylet_physics::ProbeKind::Convex)),
        }),
        ..header()
    }
}

/// A two-handed session keeps both devices' poses and forces in every tick, bit for bit, with a
/// second hand that appears in the middle of a block; its header names the second device and
/// tool, and its `tool2` events read back as the events they were.
#[test]
fn two_handed_ticks_keep_both_hands_to_the_bit() {
    let d = tempfile::tempdir().unwrap();
    let path = d.path().join("two.mcap");
    let ticks = with_second_hand(synthetic_ticks(1300, 5), 730);
    let w = SessionWriter::create(&path, &two_handed_header(), WriterOptions::default()).unwrap();
    let events = [
        (100, Event::SecondTool(None)),
        (200, Event::SecondTool(Some(stylet_physics::HandTool::Finger))),
        (
            300,
            Event::SecondTool(Some(stylet_physics::HandTool::Probe(stylet_physics::ProbeKind::Linear))),
        ),
    ];
    for t in &ticks {
        for (tick, e) in &events {
            if *tick == t.tick {
                w.event_record_blocking(EventRecord::from_event(t.tick, e)).unwrap();
            }
        }
        w.record_raw_blocking(*t).unwrap();
    }
    w.finish().unwrap();
    let s = reader::verify(&path).unwrap();
    assert_eq!(s.header.second_hand, two_handed_header().second_hand);
    assert!(same(&s.ticks, &ticks));
    assert!(s.ticks[729].second_hand.is_none() && s.ticks[730].second_hand.is_some());
    let read: Vec<Event> = s.events.iter().map(|e| e.to_event().unwrap()).collect();
    assert_eq!(read, events.map(|(_, e)| e));
    // A one-handed block carries no second-hand columns; a two-handed one all of them.
    let blocks: Vec<_> = (0..3)
        .map(|b| stylet_recorder::writer::encode_block(&ticks[b * 500..(b * 500 + 500).min(1300)]))
        .collect();
    assert!(!blocks[0].columns.contains_key("hand2"));
    assert!(blocks[1].columns.contains_key("hand2") && blocks[1].columns.contains_key("hand2_force_z_n"));
}

/// A damaged second-hand column is named: a presence flag other than 0 or 1, a column missing.
/// A needle for the second hand and an unknown second-hand tool are refused.
#[test]
fn damaged_second_hand_columns_and_tools_are_named() {
    use stylet_recorder::writer::{decode_block, encode_block};
    let ticks = with_second_hand(synthetic_ticks(20, 2), 5);
    let mut b = encode_block(&ticks);
    assert!(decode_block(&b).is_ok());
    let mut flags = b.columns["hand2"].to_vec();
    flags[7] ^= 0x2;
    b.columns.insert("hand2".into(), serde_bytes::ByteBuf::from(flags));
    assert_eq!(
        decode_block(&b).unwrap_err().to_string(),
        "column 'hand2' holds a value other than 0 or 1"
    );
    let mut b = encode_block(&ticks);
    b.columns.remove("hand2_q_y");
    assert_eq!(
        decode_block(&b).unwrap_err().to_string(),
        "block lacks column 'hand2_q_y'"
    );
    let mut e = EventRecord::from_event(1, &Event::SecondTool(None));
    e.tool = Some("needle".into());
    assert_eq!(
        e.to_event().unwrap_err().to_string(),
        "the second hand holds a finger or a probe, not 'needle'"
    );
    e.tool = Some("scalpel".into());
    assert_eq!(e.to_event().unwrap_err().to_string(), "unknown tool 'scalpel'");
    let mut m = two_handed_header().to_metadata();
    m.insert("hand2.tool".into(), "needle".into());
    assert!(SessionHeader::from_metadata(&m).is_err());
    m.remove("hand2.tool");
    assert_eq!(
        SessionHeader::from_metadata(&m).unwrap_err().to_string(),
        "session header lacks 'hand2.tool'"
    );
}

/// The committed schema-version-4 file reads: a two-handed session, the second hand picked up
/// in the middle of a block. (Regenerate it only when adding a new schema version:
/// `STYLET_WRITE_FIXTURE=1 cargo test -p stylet-recorder fixture`.)
#[test]
fn schema_v4_fixture_reads() {
    let path = fixture("session-v4.mcap");
    let ticks = with_second_hand(synthetic_ticks(1200, 8), 650);
    if std::env::var("STYLET_WRITE_FIXTURE").is_ok() {
        let w = SessionWriter::create(&path, &two_handed_header(), WriterOptions::default()).unwrap();
        w.event_record_blocking(EventRecord::from_event(
            650,
            &Event::SecondTool(Some(stylet_physics::HandTool::Probe(stylet_physics::ProbeKind::Convex))),
        ))
        .unwrap();
        for t in &ticks {
            w.record_raw_blocking(*t).unwrap();
            if t.tick % 100 == 99 {
                w.digest_blocking(t.tick, t.tick.wrapping_mul(0x9E37_79B9_7F4A_7C15))
                    .unwrap();
            }
        }
        w.finish().unwrap();
    }
    let s = reader::verify(&path).unwrap();
    assert_eq!(s.header.schema_version, 4);
    assert_eq!(s.header.second_hand, two_handed_header().second_hand);
    assert!(same(&s.ticks, &ticks));
    assert_eq!(s.events.len(), 1);
    assert_eq!(s.digests.len(), 12);
}

/// A block whose outputs cannot be rounded exactly (here a NaN force) is stored with every bit
/// (codec v1); the blocks around it still round theirs.
#[test]
fn outputs_that_cannot_be_rounded_are_stored_exactly() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("s.mcap");
    let mut ticks = synthetic_ticks(1500, 3);
    ticks[700].force_n[1] = f64::from_bits(f64::NAN.to_bits() | 0x5);
    ticks[701].torque_nmm[2] = 1e300;
    write_session(&p, &ticks, WriterOptions::default());
    let s = reader::verify(&p).unwrap();
    assert_eq!(s.output_checks.len(), 2);
    let exact = s
        .ticks
        .iter()
        .filter(|t| !s.output_checks.iter().any(|c| c.covers(t.tick)));
    let exact: Vec<TickRecord> = exact.copied().collect();
    assert!(exact.iter().any(|t| t.tick == 700));
    let first = exact[0].tick as usize;
    assert!(same_exact(&exact, &ticks[first..first + exact.len()]));
    assert_eq!(s.ticks[700].force_n[1].to_bits(), ticks[700].force_n[1].to_bits());
    for c in &s.output_checks {
        let range = c.first_tick as usize..=c.last_tick() as usize;
        assert!(same(&s.ticks[range.clone()], &ticks[range.clone()]));
        checks_pin_the_exact_outputs(std::slice::from_ref(c), &ticks[range]);
    }

    // Written again from what was read (as `session recover` does), the file says the same:
    // the same ticks and the original digests of the exact outputs.
    let again = d.path().join("again.mcap");
    let w = SessionWriter::create(&again, &s.header, WriterOptions::default()).unwrap();
    w.record_read_blocking(&s.ticks, &s.output_checks).unwrap();
    w.finish().unwrap();
    let s2 = reader::verify(&again).unwrap();
    assert!(same_exact(&s2.ticks, &s.ticks));
    assert_eq!(s2.output_checks, s.output_checks);

    // Part of a rounded block cannot be written again: its digest would no longer hold.
    let part = d.path().join("part.mcap");
    let w = SessionWriter::create(&part, &s.header, WriterOptions::default()).unwrap();
    let e = w.record_read_blocking(&s.ticks[10..], &s.output_checks).unwrap_err();
    assert!(
        e.to_string().contains("tick 10 lies inside the block of ticks 0–"),
        "{e}"
    );
    let e = w.record_read_blocking(&s.ticks[..10], &s.output_checks).unwrap_err();
    assert!(e.to_string().contains("ticks 0–"), "{e}");
}

/// Inputs the fuzzer once broke the reader with (scripts/fuzz): each now gives a clear error.
#[test]
fn fuzzer_findings_stay_fixed() {
    let dir = fixture("fuzz");
    let mut n = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        let bytes = std::fs::read(&path).unwrap();
        for mode in [Mode::Strict, Mode::Recover] {
            match reader::read_bytes(&bytes, mode, &Limits::default()) {
                Ok(s) => assert!(mode == Mode::Recover && s.damage.is_some(), "{}", path.display()),
                Err(e) => assert!(!e.to_string().is_empty()),
            }
        }
        assert!(reader::verify_bytes(&bytes).is_err());
        n += 1;
    }
    assert!(n >= 1);
}

/// A tick with a non-finite pose is damage (replay would feed NaN into the physics): verify and
/// strict reading refuse the file, recovery stops before the chunk that holds it.
#[test]
fn non_finite_poses_are_damage() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("s.mcap");
    let mut ticks = synthetic_ticks(3000, 8);
    ticks[1700].position_mm[2] = f64::NAN;
    let summary = write_session(&p, &ticks, WriterOptions::default());
    assert!(summary.complete && summary.ticks == 3000);
    let bytes = std::fs::read(&p).unwrap();
    let e = reader::verify_bytes(&bytes).unwrap_err().to_string();
    assert!(e.contains("tick 1700: position") && e.contains("not finite"), "{e}");
    let e = reader::read_bytes(&bytes, Mode::Strict, &Limits::default()).unwrap_err();
    assert!(matches!(e, reader::ReadError::Damaged(_)), "{e}");
    let r = reader::read_bytes(&bytes, Mode::Recover, &Limits::default()).unwrap();
    assert!(
        matches!(
            r.damage.as_ref().unwrap().what,
            DamageKind::Message(MessageError::Pose(PoseError::Position { tick: 1700, .. }))
        ),
        "{:?}",
        r.damage
    );
    assert!(r.damage.as_ref().unwrap().what.to_string().contains("tick 1700"));
    assert!(!r.ticks.is_empty() && r.ticks.len() <= 1700, "{} ticks", r.ticks.len());
    assert!(same(&r.ticks, &ticks[..r.ticks.len()]));
    assert!(!r.complete());
}

#[test]
fn pose_checks_name_the_tick() {
    use stylet_recorder::format::check_poses_finite;
    let mut ticks = synthetic_ticks(4, 9);
    assert_eq!(check_poses_finite(&ticks), Ok(()));
    ticks[2].position_mm[1] = f64::INFINITY;
    let e = check_poses_finite(&ticks).unwrap_err().to_string();
    assert!(e.starts_with("tick 2: position") && e.contains("not finite"), "{e}");
    ticks[2] = synthetic_ticks(4, 9)[2];
    ticks[1].orientation[3] = f64::NAN;
    let e = check_poses_finite(&ticks).unwrap_err().to_string();
    assert!(e.starts_with("tick 1: orientation") && e.contains("not finite"), "{e}");
    ticks[1].orientation = [0.0, -0.0, 0.0, 0.0];
    let e = check_poses_finite(&ticks).unwrap_err();
    assert_eq!(e, PoseError::ZeroOrientation { tick: 1 });
    assert_eq!(e.to_string(), "tick 1: orientation is all zero");
}

/// Header fields are bounded at the format level (a 60 MB scenario was once accepted and
/// listed), numbers are not truncated (schema version 2^32 + 1 once read as 1), times are times.
#[test]
fn header_fields_are_bounded_and_exact() {
    let good = header().to_metadata();
    assert_eq!(SessionHeader::from_metadata(&good).unwrap(), header());
    let with = |k: &str, v: String| {
        let mut m = good.clone();
        m.insert(k.into(), v);
        SessionHeader::from_metadata(&m).unwrap_err().to_string()
    };
    assert!(with("scenario", "s".repeat(65)).contains("'scenario' is longer than 64 characters"));
    assert!(with("trainee", "a b".into()).contains("'trainee' must be"));
    assert!(with("schema_version", "4294967297".into()).contains("'schema_version' is out of range"));
    assert!(with("physics_version", "4294967298".into()).contains("'physics_version' is out of range"));
    assert!(with("wall_clock_start", "yesterday".into()).contains("RFC 3339"));
    assert!(with("atlas_id", "é".repeat(257)).contains("longer than 256 characters"));
    // The world model: every deformation setting is checked as the simulation checks it.
    assert!(with("world.deformation.cells", "7".into()).contains("deformation cells 7"));
    assert!(with("world.deformation.regulariser", "chainmail".into()).contains("'chainmail' is unknown"));
    assert!(with("world.deformation.enabled", "2".into()).contains("must be 0 or 1"));
    assert!(with("world.deformation.latency_ticks", "101".into()).contains("latency_ticks 101"));
    // The force-feedback device: optional, but whole and sane when there.
    assert!(with("hardware.backend", "two words".into()).contains("'hardware.backend' must be"));
    assert!(with("hardware.max_force_n", "NaN".into()).contains("'hardware.max_force_n' is out of range"));
    assert!(with("hardware.max_continuous_force_n", "1e9".into()).contains("is out of range"));
    assert!(with("hardware.model", "m".repeat(257)).contains("longer than 256 characters"));
    let mut m = good.clone();
    m.remove("hardware.model");
    assert!(
        SessionHeader::from_metadata(&m)
            .unwrap_err()
            .to_string()
            .contains("lacks 'hardware.model'")
    );
    let mut m = good.clone();
    m.retain(|k, _| !k.starts_with("hardware."));
    assert_eq!(SessionHeader::from_metadata(&m).unwrap().hardware, None);
    let mut m = good.clone();
    m.remove("world.deformation.spacing_mm_bits");
    assert!(
        SessionHeader::from_metadata(&m)
            .unwrap_err()
            .to_string()
            .contains("lacks 'world.deformation.spacing_mm_bits'")
    );
    // And every contrast setting; a file without any (written before they were recorded) ran
    // the defaults and reads so.
    assert!(
        with(
            "world.contrast.front_fraction_bits",
            format!("{:016x}", 1.5f64.to_bits())
        )
        .contains("contrast front_fraction 1.5")
    );
    assert!(with("world.contrast.tau_bits", format!("{:016x}", 0.5f64.to_bits())).contains("contrast tau 0.5"));
    assert!(with("world.contrast.settle_s_bits", "zz".into()).contains("'world.contrast.settle_s_bits' is not hex"));
    let mut m = good.clone();
    m.remove("world.contrast.rate_ml_per_s_bits");
    assert!(
        SessionHeader::from_metadata(&m)
            .unwrap_err()
            .to_string()
            .contains("lacks 'world.contrast.rate_ml_per_s_bits'")
    );
    let mut m = good.clone();
    m.retain(|k, _| !k.starts_with("world.contrast."));
    assert_eq!(
        SessionHeader::from_metadata(&m).unwrap().contrast,
        stylet_physics::ContrastSettings::default()
    );
    // A file of physics version 9 (a diffusion grid, no filling front) reads with the default
    // front and its other settings.
    let mut m = good.clone();
    m.remove("world.contrast.front_fraction_bits");
    m.insert("world.contrast.grid_nodes".into(), "64".into());
    let old = SessionHeader::from_metadata(&m).unwrap().contrast;
    assert_eq!(
        old.front_fraction,
        stylet_physics::ContrastSettings::default().front_fraction
    );
    assert_eq!(old.steps_per_update, 3);
    // Breathing: bad values named; a file without it did not breathe; measured fields travel.
    assert!(with("world.breathing.model", "4d-ct".into()).contains("'world.breathing.model' '4d-ct' is unknown"));
    let mut m = good.clone();
    m.insert("world.breathing.model".into(), "measured".into());
    let h = SessionHeader::from_metadata(&m).unwrap();
    assert!(h.breathing.measured);
    assert_eq!(h.to_metadata()["world.breathing.model"], "measured");
    assert!(with("world.breathing.enabled", "2".into()).contains("'world.breathing.enabled' must be 0 or 1"));
    assert!(with("world.breathing.seed", "-1".into()).contains("'world.breathing.seed' is not a number"));
    assert!(
        with(
            "world.breathing.amplitude_mm_bits",
            format!("{:016x}", 90.0f64.to_bits())
        )
        .contains("breathing amplitude (mm) 90")
    );
    assert!(with("world.breathing.power", "9".into()).contains("power n = 9"));
    let mut m = good.clone();
    m.remove("world.breathing.period_s_bits");
    assert!(
        SessionHeader::from_metadata(&m)
            .unwrap_err()
            .to_string()
            .contains("lacks 'world.breathing.period_s_bits'")
    );
    let mut m = good.clone();
    m.retain(|k, _| !k.starts_with("world.breathing."));
    assert_eq!(
        SessionHeader::from_metadata(&m).unwrap().breathing,
        stylet_physics::motion::BreathingSettings::default()
    );
    let diffusion = SessionHeader {
        deformation: DeformSettings {
            regulariser: stylet_physics::Regulariser::Diffusion,
            ..DeformSettings::off()
        },
        ..header()
    };
    assert_eq!(
        SessionHeader::from_metadata(&diffusion.to_metadata()).unwrap(),
        diffusion
    );
    // Characters, not bytes: 64 two-byte characters are too many for a name only because they
    // are not ASCII; 256 of them are a valid atlas name.
    let mut m = good.clone();
    m.insert("atlas_id".into(), "é".repeat(256));
    assert!(SessionHeader::from_metadata(&m).is_ok());
}

/// Streaming verification gives what the full one gives without keeping the ticks, and checks
/// the tick limit before decoding a block.
#[test]
fn streaming_verification_bounds_the_ticks() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("s.mcap");
    let ticks = synthetic_ticks(3000, 3);
    write_session(&p, &ticks, WriterOptions::default());
    let bytes = std::fs::read(&p).unwrap();
    let full = reader::verify_bytes(&bytes).unwrap();
    let streamed = reader::verify_streaming(&bytes, &Limits::default()).unwrap();
    assert_eq!(streamed.tick_count, 3000);
    assert!(streamed.session.ticks.is_empty());
    assert_eq!(streamed.session.header, full.header);
    assert_eq!(streamed.session.digests, full.digests);
    assert_eq!(streamed.duration_s(), full.duration_s());
    assert_eq!(reader::read_header(&bytes).unwrap(), full.header);
    let short = Limits {
        max_ticks: 1000,
        ..Limits::default()
    };
    let e = reader::verify_streaming(&bytes, &short).unwrap_err().to_string();
    assert!(e.contains("more than 1000 ticks"), "{e}");
    // Upload limits follow the longest session accepted: 2 s at 1 kHz.
    let e = reader::verify_streaming(&bytes, &Limits::for_upload(bytes.len() as u64, 1000, 2))
        .unwrap_err()
        .to_string();
    assert!(e.contains("more than 2000 ticks"), "{e}");
    assert!(reader::verify_streaming(&bytes, &Limits::for_upload(bytes.len() as u64, 1000, 3)).is_ok());
}

/// Strings a reader keeps are bounded even where the event's kind does not use them: an
/// `xray-on` event carrying an 8 KB `tool` is damage, not 8 KB kept per event.
#[test]
fn unused_event_fields_are_bounded_too() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("s.mcap");
    let w = SessionWriter::create(&p, &header(), WriterOptions::default()).unwrap();
    let mut e = EventRecord::from_event(3, &Event::XrayOn);
    e.tool = Some("x".repeat(8192));
    w.event_record_blocking(e).unwrap();
    for t in synthetic_ticks(100, 1) {
        w.record_raw_blocking(t).unwrap();
    }
    w.finish().unwrap();
    let bytes = std::fs::read(&p).unwrap();
    let err = reader::verify_bytes(&bytes).unwrap_err().to_string();
    assert!(err.contains("'event tool' is longer than 64 characters"), "{err}");
    assert!(reader::verify_streaming(&bytes, &Limits::default()).is_err());
}

/// A file read record by record (as the service reads uploads it has received to disk) reads
/// exactly as the same bytes in memory: intact, cut at every 4 KiB boundary and with a bit
/// flipped there, strictly and in recovery, and verified by streaming.
#[test]
fn files_read_record_by_record_read_as_the_bytes_do() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("s.mcap");
    let ticks = synthetic_ticks(20_000, 2);
    write_session(&p, &ticks, WriterOptions::default());
    let bytes = std::fs::read(&p).unwrap();
    let limits = Limits::default();
    let from_file = |b: &[u8], mode: Mode| reader::read_file_with(std::io::Cursor::new(b), mode, &limits, None);
    let whole = from_file(&bytes, Mode::Strict).unwrap();
    assert_eq!(whole, reader::read_bytes(&bytes, Mode::Strict, &limits).unwrap());
    assert_eq!(whole.ticks.len(), 20_000);
    let streamed = reader::verify_file_streaming(std::fs::File::open(&p).unwrap(), &limits).unwrap();
    assert_eq!(streamed, reader::verify_streaming(&bytes, &limits).unwrap());
    let mut variants = 0;
    for off in (4096..bytes.len()).step_by(4096) {
        let mut flipped = bytes.clone();
        flipped[off] ^= 0x10;
        for damaged in [&bytes[..off], &flipped[..]] {
            for mode in [Mode::Strict, Mode::Recover] {
                assert_eq!(
                    from_file(damaged, mode),
                    reader::read_bytes(damaged, mode, &limits),
                    "{} bytes, {mode:?}",
                    damaged.len()
                );
            }
            assert_eq!(
                reader::verify_file_streaming(std::io::Cursor::new(damaged), &limits),
                reader::verify_streaming(damaged, &limits)
            );
            variants += 1;
        }
    }
    assert!(variants > 20, "{variants}");
    // Not a session at all, and nothing.
    for junk in [&b"PK\x03\x04 not a session"[..], b""] {
        assert_eq!(
            from_file(junk, Mode::Strict),
            reader::read_bytes(junk, Mode::Strict, &limits)
        );
        assert!(from_file(junk, Mode::Strict).is_err());
    }
}

/// The header of a file still arriving: "send more" until its record is complete, then the
/// header; an error at once when the first bytes cannot begin a session file.
#[test]
fn the_header_is_read_from_the_first_bytes_of_a_file() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("s.mcap");
    write_session(&p, &synthetic_ticks(100, 1), WriterOptions::default());
    let bytes = std::fs::read(&p).unwrap();
    let full = reader::read_header(&bytes).unwrap();
    let needed = (0..=bytes.len())
        .find(|&n| reader::read_header_prefix(&bytes[..n]).unwrap().is_some())
        .unwrap();
    assert!(needed < 4096, "the header needs the first {needed} bytes");
    for n in 0..needed {
        assert_eq!(reader::read_header_prefix(&bytes[..n]), Ok(None), "{n} bytes");
    }
    assert_eq!(reader::read_header_prefix(&bytes[..needed]), Ok(Some(full.clone())));
    assert_eq!(reader::read_header_prefix(&bytes), Ok(Some(full)));
    for junk in [&b"P"[..], b"\x89MCAQ", b"PK\x03\x04 a zip archive"] {
        assert!(reader::read_header_prefix(junk).is_err(), "{junk:?}");
    }
}

/// The JSON form of a CBOR message by RFC 8949 §6.1: byte strings as base64url without padding,
/// non-finite floats as null, tags dropped.
fn cbor_as_json(v: &ciborium::Value) -> serde_json::Value {
    use base64::Engine;
    use ciborium::Value as C;
    use serde_json::Value as J;
    match v {
        C::Integer(i) => {
            let i = i128::from(*i);
            match u64::try_from(i) {
                Ok(u) => J::from(u),
                Err(_) => J::from(i64::try_from(i).expect("CBOR integers fit i64 or u64 here")),
            }
        }
        C::Bytes(b) => J::String(base64::engine::general_purpose::URL_SAFE_NO_PAD.encode(b)),
        C::Float(f) => serde_json::Number::from_f64(*f).map_or(J::Null, J::Number),
        C::Text(t) => J::String(t.clone()),
        C::Bool(b) => J::Bool(*b),
        C::Null => J::Null,
        C::Tag(_, inner) => cbor_as_json(inner),
        C::Array(items) => J::Array(items.iter().map(cbor_as_json).collect()),
        C::Map(entries) => J::Object(
            entries
                .iter()
                .map(|(k, v)| (k.as_text().expect("text keys").to_string(), cbor_as_json(v)))
                .collect(),
        ),
        other => panic!("unexpected CBOR value {other:?}"),
    }
}

/// The schema of a property, following a local `$ref`.
fn resolve<'a>(schema: &'a serde_json::Value, root: &'a serde_json::Value) -> &'a serde_json::Value {
    match schema.get("$ref").and_then(|r| r.as_str()) {
        Some(r) => root
            .pointer(r.trim_start_matches('#'))
            .unwrap_or_else(|| panic!("unresolved {r}")),
        None => schema,
    }
}

/// JSON cannot tell a byte string from a text string: every string the schema marks as encoded
/// binary must be a CBOR byte string, and every other string a text string.
fn strings_are_what_the_schema_says(
    v: &ciborium::Value,
    schema: &serde_json::Value,
    root: &serde_json::Value,
    at: &str,
) {
    let schema = resolve(schema, root);
    match v {
        ciborium::Value::Map(entries) => {
            for (k, value) in entries {
                let key = k.as_text().unwrap();
                if let Some(sub) = schema.get("properties").and_then(|p| p.get(key)) {
                    strings_are_what_the_schema_says(value, sub, root, &format!("{at}/{key}"));
                }
            }
        }
        ciborium::Value::Array(items) => {
            if let Some(sub) = schema.get("items") {
                for (i, item) in items.iter().enumerate() {
                    strings_are_what_the_schema_says(item, sub, root, &format!("{at}/{i}"));
                }
            }
        }
        ciborium::Value::Bytes(_) => assert!(
            schema.get("contentEncoding").is_some(),
            "{at}: a byte string the schema calls text"
        ),
        ciborium::Value::Text(_) => assert!(
            schema.get("contentEncoding").is_none(),
            "{at}: text the schema calls bytes"
        ),
        _ => {}
    }
}

/// Checks every message of `path` against the published schema of its topic; returns the
/// number of messages per topic.
fn check_against_schemas(path: &Path) -> std::collections::BTreeMap<String, usize> {
    use stylet_recorder::format;
    let bytes = std::fs::read(path).unwrap();
    let mut counts = std::collections::BTreeMap::new();
    let mut schemas = boon::Schemas::new();
    let mut compiled = std::collections::BTreeMap::new();
    for topic in [
        format::TOPIC_TICKS,
        format::TOPIC_EVENTS,
        format::TOPIC_DIGESTS,
        format::TOPIC_ANNOTATIONS,
        format::TOPIC_PREVIEW,
        format::TOPIC_DEVICE_FORCES,
    ] {
        let doc: serde_json::Value = serde_json::from_str(format::json_schema(topic)).unwrap();
        let mut compiler = boon::Compiler::new();
        let url = format!("urn:stylet{}", topic.replace('/', ":"));
        compiler.add_resource(&url, doc.clone()).unwrap();
        let index = compiler.compile(&url, &mut schemas).unwrap();
        compiled.insert(topic.to_string(), (index, doc));
    }
    for message in mcap::MessageStream::new(&bytes).unwrap() {
        let message = message.unwrap();
        let topic = message.channel.topic.clone();
        let (index, doc) = compiled.get(&topic).unwrap_or_else(|| panic!("unknown topic {topic}"));
        let value: ciborium::Value = ciborium::de::from_reader(&message.data[..]).unwrap();
        let json = cbor_as_json(&value);
        if let Err(e) = schemas.validate(&json, *index) {
            panic!(
                "{}: a {topic} message at {} ns breaks its schema: {e:#}",
                path.display(),
                message.log_time
            );
        }
        strings_are_what_the_schema_says(&value, doc, doc, &topic);
        *counts.entry(topic).or_insert(0) += 1;
    }
    counts
}

/// The published schemas describe exactly what is written: every message of a session with every
/// kind of message (all events, both tick codecs, an annotation, previews) validates against its
/// topic's schema, byte strings are declared as byte strings, and the file carries these schemas.
/// The committed sessions (schema versions 1 to 4, physics fixtures) validate too.
#[test]
fn sessions_match_their_published_schemas() {
    use stylet_recorder::format;
    let d = tempfile::tempdir().unwrap();
    let path = d.path().join("s.mcap");
    // A second hand from tick 600 on: its columns in the last two blocks.
    let mut ticks = with_second_hand(synthetic_ticks(1200, 9), 600);
    // One block that cannot round its outputs: codec v1, without a digest.
    ticks[700].force_n[1] = f64::NAN;
    let events = [
        Event::SelectTool(ToolSpec::Finger),
        Event::SelectTool(ToolSpec::Probe(stylet_physics::ProbeKind::Convex)),
        Event::SelectTool(ToolSpec::Needle {
            gauge: Gauge::G22,
            length_mm: 200.0,
            stylet_in: true,
        }),
        Event::StyletRemove,
        Event::ContrastInject { ml: 2.5 },
        Event::StyletInsert,
        Event::XrayOn,
        Event::XrayOff,
        Event::BreathHold,
        Event::BreathRelease,
        Event::SecondTool(Some(stylet_physics::HandTool::Probe(stylet_physics::ProbeKind::Linear))),
        Event::SecondTool(None),
    ];
    let w = SessionWriter::create(&path, &two_handed_header(), WriterOptions::default()).unwrap();
    for t in &ticks {
        if let Some(e) = events.get(t.tick as usize / 100).filter(|_| t.tick % 100 == 50) {
            w.event_record_blocking(EventRecord::from_event(t.tick, e)).unwrap();
        }
        w.record_raw_blocking(*t).unwrap();
        w.device_force_blocking(device_force(t.tick)).unwrap();
        if t.tick % 100 == 99 {
            w.digest_blocking(t.tick, u64::MAX - t.tick).unwrap();
        }
    }
    w.annotate_blocking(1199, "the instructor's remark").unwrap();
    w.finish().unwrap();

    let counts = check_against_schemas(&path);
    assert_eq!(counts.get(format::TOPIC_EVENTS), Some(&events.len()));
    assert_eq!(counts.get(format::TOPIC_TICKS), Some(&3));
    assert_eq!(counts.get(format::TOPIC_DIGESTS), Some(&12));
    assert_eq!(counts.get(format::TOPIC_ANNOTATIONS), Some(&1));
    assert_eq!(counts.get(format::TOPIC_PREVIEW), Some(&60));
    assert!(counts.get(format::TOPIC_DEVICE_FORCES).is_some_and(|&n| n >= 3));
    let s = reader::verify(&path).unwrap();
    assert_eq!(s.output_checks.len(), 2, "one block in each codec or more");
    assert_eq!(s.device_forces.len(), 1200);

    // The file carries the published schemas.
    let bytes = std::fs::read(&path).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    for channel in summary.channels.values() {
        let schema = channel.schema.as_ref().unwrap();
        assert_eq!(schema.encoding, format::SCHEMA_ENCODING);
        assert_eq!(
            std::str::from_utf8(&schema.data).unwrap(),
            format::json_schema(&channel.topic)
        );
    }

    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let mut committed = vec![
        fixture("session-v1.mcap"),
        fixture("session-v2.mcap"),
        fixture("session-v3.mcap"),
        fixture("session-v4.mcap"),
    ];
    for entry in std::fs::read_dir(root.join("tests/fixtures/physics-v13")).unwrap() {
        let p = entry.unwrap().path();
        if p.extension().is_some_and(|e| e == "mcap") {
            committed.push(p);
        }
    }
    assert!(committed.len() >= 6);
    for p in committed {
        let counts = check_against_schemas(&p);
        assert!(
            counts.get(format::TOPIC_TICKS).is_some_and(|&n| n > 0),
            "{}",
            p.display()
        );
    }
}

/// The check above can fail: the schema text of an older writer, which called the columns text,
/// is caught, and so is a column the schema does not declare.
#[test]
fn the_schema_check_catches_bytes_called_text_and_undeclared_columns() {
    let block = stylet_recorder::writer::encode_block(&synthetic_ticks(10, 1));
    let value: ciborium::Value = ciborium::de::from_reader(&stylet_recorder::format::to_cbor(&block)[..]).unwrap();
    let old: serde_json::Value = serde_json::from_str(
        r#"{"type":"object","properties":{"columns":{"type":"object","additionalProperties":{"type":"string"},"properties":{"q_w":{"type":"string"}}}}}"#,
    )
    .unwrap();
    let caught = std::panic::catch_unwind(|| strings_are_what_the_schema_says(&value, &old, &old, "ticks"));
    assert!(caught.is_err());

    let mut extra = block.clone();
    extra
        .columns
        .insert("force_n".into(), serde_bytes::ByteBuf::from(vec![0u8; 80]));
    let doc: serde_json::Value = serde_json::from_str(stylet_recorder::format::json_schema(
        stylet_recorder::format::TOPIC_TICKS,
    ))
    .unwrap();
    let mut schemas = boon::Schemas::new();
    let mut compiler = boon::Compiler::new();
    compiler.add_resource("urn:ticks", doc).unwrap();
    let index = compiler.compile("urn:ticks", &mut schemas).unwrap();
    let json = |b: &stylet_recorder::format::TickBlock| {
        let v: ciborium::Value = ciborium::de::from_reader(&stylet_recorder::format::to_cbor(b)[..]).unwrap();
        cbor_as_json(&v)
    };
    assert!(schemas.validate(&json(&block), index).is_ok());
    assert!(schemas.validate(&json(&extra), index).is_err());
}

/// The Seldinger exchange's events read back as they were written; a `wire-in` without its wire
/// or with a wire that is not one is named.
#[test]
fn the_exchange_events_round_trip_and_a_bad_wire_is_named() {
    use stylet_physics::wire::{WireDiameter, WireTip};
    let events = [
        Event::WireIn {
            diameter: WireDiameter::In035,
            tip: WireTip::J,
        },
        Event::WireIn {
            diameter: WireDiameter::In018,
            tip: WireTip::Straight,
        },
        Event::NeedleOut,
        Event::WireOut,
        Event::DilatorIn { size_fr: 10 },
        Event::DilatorOut,
        Event::CatheterIn { size_fr: 8 },
    ];
    for e in &events {
        let r = EventRecord::from_event(7, e);
        assert_eq!(&r.to_event().unwrap(), e);
    }
    assert_eq!(EventRecord::from_event(7, &events[0]).wire.as_deref(), Some("0.035 j"));
    let mut r = EventRecord::from_event(7, &events[0]);
    r.wire = None;
    assert_eq!(r.to_event().unwrap_err().to_string(), "wire-in event without its wire");
    for bad in ["0.038 j", "0.035", "0.035 j extra", "0.035 J"] {
        r.wire = Some(bad.into());
        assert_eq!(
            r.to_event().unwrap_err().to_string(),
            format!("wire '{bad}' is not \"<0.018|0.035> <j|straight>\"")
        );
    }
    // A dilator or catheter without its size, or of a size it does not come in.
    let mut r = EventRecord::from_event(7, &Event::CatheterIn { size_fr: 10 });
    assert_eq!(r.size_fr, Some(10));
    r.size_fr = None;
    assert_eq!(
        r.to_event().unwrap_err().to_string(),
        "catheter-in event without its size"
    );
    for (name, size) in [("catheter-in", 12), ("dilator-in", 7), ("dilator-in", 300)] {
        r.name = name.into();
        r.size_fr = Some(size);
        let tool = name.trim_end_matches("-in");
        assert_eq!(
            r.to_event().unwrap_err().to_string(),
            format!("there is no {size} F {tool}")
        );
    }
}
