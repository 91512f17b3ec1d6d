//! Bounded parsing of the MCAP records a session file uses (MCAP spec, "Records").
//!
//! Our own, not the `mcap` crate's reader: that one reserves memory for a string or map from its
//! length prefix before checking the prefix against the record (fuzzing found a 2.4 GB
//! allocation from a 600-byte file). Here every length is checked against the bytes that are
//! really there, so a hostile file costs at most its own size.

use std::collections::BTreeMap;

/// The records the reader needs, borrowing from the file.
#[derive(Debug)]
pub enum Record<'a> {
    Header {
        profile: &'a str,
    },
    Footer {
        summary_start: u64,
        summary_crc: u32,
    },
    Channel {
        id: u16,
        topic: &'a str,
    },
    Message {
        channel_id: u16,
        data: &'a [u8],
    },
    Chunk(Chunk<'a>),
    ChunkIndex(ChunkIndex),
    Metadata {
        name: &'a str,
        map: BTreeMap<String, String>,
    },
    DataEnd {
        data_section_crc: u32,
    },
    /// A record the reader does not need (schemas, message indexes, statistics …).
    Other,
}

#[derive(Debug)]
pub struct Chunk<'a> {
    pub uncompressed_size: u64,
    pub uncompressed_crc: u32,
    pub compression: &'a str,
    pub records: &'a [u8],
}

#[derive(Debug, Clone, Copy)]
pub struct ChunkIndex {
    pub message_start_time: u64,
    pub message_end_time: u64,
    pub chunk_start_offset: u64,
    pub chunk_length: u64,
}

pub const OP_HEADER: u8 = 0x01;
pub const OP_FOOTER: u8 = 0x02;
pub const OP_CHANNEL: u8 = 0x04;
pub const OP_MESSAGE: u8 = 0x05;
pub const OP_CHUNK: u8 = 0x06;
pub const OP_CHUNK_INDEX: u8 = 0x08;
pub const OP_METADATA: u8 = 0x0C;
pub const OP_DATA_END: u8 = 0x0F;

/// Why a record body cannot be parsed: a length that runs past the record, or text that is not
/// UTF-8. Names the field, so a damaged file says where it is damaged.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ParseError {
    /// A length prefix (or a fixed-size field) declares more bytes than the record has left.
    #[error("{field}: {declared} bytes declared, {left} left in the record")]
    Overrun {
        field: &'static str,
        declared: u64,
        left: usize,
    },
    #[error("{field} is not UTF-8")]
    NotUtf8 { field: &'static str },
}

/// A cursor over one record body; every read checks the remaining length.
struct Body<'a> {
    b: &'a [u8],
}

impl<'a> Body<'a> {
    fn take(&mut self, n: u64, what: &'static str) -> Result<&'a [u8], ParseError> {
        if n > self.b.len() as u64 {
            return Err(ParseError::Overrun {
                field: what,
                declared: n,
                left: self.b.len(),
            });
        }
        let (head, rest) = self.b.split_at(n as usize);
        self.b = rest;
        Ok(head)
    }
    fn u16(&mut self, what: &'static str) -> Result<u16, ParseError> {
        Ok(u16::from_le_bytes(self.take(2, what)?.try_into().expect("2 bytes")))
    }
    fn u32(&mut self, what: &'static str) -> Result<u32, ParseError> {
        Ok(u32::from_le_bytes(self.take(4, what)?.try_into().expect("4 bytes")))
    }
    fn u64(&mut self, what: &'static str) -> Result<u64, ParseError> {
        Ok(u64::from_le_bytes(self.take(8, what)?.try_into().expect("8 bytes")))
    }
    fn str(&mut self, what: &'static str) -> Result<&'a str, ParseError> {
        let n = self.u32(what)?;
        std::str::from_utf8(self.take(n as u64, what)?).map_err(|_| ParseError::NotUtf8 { field: what })
    }
    fn map(&mut self, what: &'static str) -> Result<BTreeMap<String, String>, ParseError> {
        let n = self.u32(what)?;
        let mut inner = Body {
            b: self.take(n as u64, what)?,
        };
        let mut m = BTreeMap::new();
        while !inner.b.is_empty() {
            let k = inner.str(what)?;
            let v = inner.str(what)?;
            m.insert(k.to_string(), v.to_string());
        }
        Ok(m)
    }
}

/// Parses a record body of opcode `op`; names the field that does not fit.
pub fn parse(op: u8, body: &[u8]) -> Result<Record<'_>, ParseError> {
    let mut r = Body { b: body };
    Ok(match op {
        OP_HEADER => Record::Header {
            profile: r.str("header profile")?,
        },
        OP_FOOTER => {
            let summary_start = r.u64("footer")?;
            r.u64("footer")?;
            Record::Footer {
                summary_start,
                summary_crc: r.u32("footer")?,
            }
        }
        OP_CHANNEL => {
            let id = r.u16("channel")?;
            r.u16("channel")?;
            Record::Channel {
                id,
                topic: r.str("channel topic")?,
            }
        }
        OP_MESSAGE => {
            let channel_id = r.u16("message")?;
            r.take(4 + 8 + 8, "message header")?;
            Record::Message { channel_id, data: r.b }
        }
        OP_CHUNK => {
            r.take(16, "chunk times")?;
            let uncompressed_size = r.u64("chunk")?;
            let uncompressed_crc = r.u32("chunk")?;
            let compression = r.str("chunk compression")?;
            let n = r.u64("chunk records")?;
            Record::Chunk(Chunk {
                uncompressed_size,
                uncompressed_crc,
                compression,
                records: r.take(n, "chunk records")?,
            })
        }
        OP_CHUNK_INDEX => Record::ChunkIndex(ChunkIndex {
            message_start_time: r.u64("chunk index")?,
            message_end_time: r.u64("chunk index")?,
            chunk_start_offset: r.u64("chunk index")?,
            chunk_length: r.u64("chunk index")?,
        }),
        OP_METADATA => {
            let name = r.str("metadata name")?;
            Record::Metadata {
                name,
                map: r.map("metadata")?,
            }
        }
        OP_DATA_END => Record::DataEnd {
            data_section_crc: r.u32("data end")?,
        },
        _ => Record::Other,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lengths_beyond_the_record_are_refused_without_allocating() {
        // A metadata record whose name claims 4 GiB.
        let mut body = u32::MAX.to_le_bytes().to_vec();
        body.extend_from_slice(b"abc");
        let e = parse(OP_METADATA, &body).unwrap_err();
        assert!(
            matches!(
                e,
                ParseError::Overrun {
                    declared: 4294967295,
                    ..
                }
            ),
            "{e}"
        );
        assert!(e.to_string().contains("4294967295 bytes declared"), "{e}");
        // A map claiming more bytes than there are.
        let mut body = 1u32.to_le_bytes().to_vec();
        body.push(b'n');
        body.extend_from_slice(&1000u32.to_le_bytes());
        assert!(parse(OP_METADATA, &body).is_err());
        assert!(parse(OP_CHUNK, &[0; 20]).is_err());
        assert!(parse(OP_FOOTER, &[0; 19]).is_err());
    }

    #[test]
    fn parses_what_the_writer_writes() {
        let mut body = 3u32.to_le_bytes().to_vec();
        body.extend_from_slice(b"abc");
        let map = [1u32.to_le_bytes().as_slice(), b"k", 1u32.to_le_bytes().as_slice(), b"v"].concat();
        body.extend_from_slice(&(map.len() as u32).to_le_bytes());
        body.extend_from_slice(&map);
        match parse(OP_METADATA, &body).unwrap() {
            Record::Metadata { name, map } => {
                assert_eq!(name, "abc");
                assert_eq!(map["k"], "v");
            }
            r => panic!("{r:?}"),
        }
    }
}
