//! Fuzz target: the session-file reader on arbitrary bytes. Strict and recovery reads (from
//! memory and record by record), verify, streaming, the header of a prefix and tick blocks must
//! return an error or a session — never panic, hang or allocate beyond the limits.
//! Seed corpus: recorder/tests/fixtures (see scripts/fuzz).
#![no_main]

use libfuzzer_sys::fuzz_target;
use stylet_recorder::reader::{self, Limits, Mode};

fuzz_target!(|data: &[u8]| {
    // Tight limits so the fuzzer reaches them; the defaults are checked by the unit tests.
    let limits = Limits {
        max_file_bytes: 1 << 20,
        max_record_bytes: 1 << 18,
        max_chunk_uncompressed_bytes: 1 << 20,
        max_ticks: 100_000,
        max_messages: 10_000,
        max_notes: 1_000,
    };
    let strict = reader::read_bytes(data, Mode::Strict, &limits);
    let recovered = reader::read_bytes(data, Mode::Recover, &limits);
    if let Ok(s) = &strict {
        // What reads strictly reads the same in recovery mode.
        assert_eq!(Ok(s), recovered.as_ref());
    }
    // A file read record by record reads as its bytes do.
    assert_eq!(
        reader::read_file_with(std::io::Cursor::new(data), Mode::Recover, &limits, None),
        recovered
    );
    let _ = reader::verify_bytes(data);
    let _ = reader::read_header(data);
    if let Ok(Some(h)) = reader::read_header_prefix(data) {
        assert_eq!(reader::read_header(data), Ok(h));
    }
    if let (Ok(full), Ok(streamed)) = (reader::verify_bytes(data), reader::verify_streaming(data, &Limits::default())) {
        // Streaming verification agrees with the full one on what both accept.
        assert_eq!(streamed.tick_count, full.ticks.len() as u64);
        assert_eq!(streamed.session.header, full.header);
    }
    let _ = reader::verify_streaming(data, &limits);
    let mut count = 0usize;
    let _ = reader::read_bytes_with(data, Mode::Recover, &limits, Some(&mut |b| count += b.len()));
    if let Ok(block) = stylet_recorder::format::from_cbor::<stylet_recorder::format::TickBlock>(data) {
        let _ = stylet_recorder::writer::decode_block(&block);
    }
});
