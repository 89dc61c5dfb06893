//! Parsers for the MCAP record bodies the reader needs (schema, channel, chunk, chunk index,
//! statistics, footer). Every length prefix is checked against the bytes that remain in the
//! record body before anything is allocated, so a flipped length cannot ask for gigabytes;
//! errors say which field of which record is bad.

use std::collections::BTreeMap;

/// A Schema record (opcode 0x03).
#[derive(Debug, Clone)]
pub(crate) struct SchemaRecord {
    pub id: u16,
    pub name: String,
    pub encoding: String,
    pub data: Vec<u8>,
}

/// A Channel record (opcode 0x04); the metadata map is skipped.
#[derive(Debug, Clone)]
pub(crate) struct ChannelRecord {
    pub id: u16,
    pub schema_id: u16,
    pub topic: String,
    pub message_encoding: String,
}

/// A Chunk record (opcode 0x06): header fields and the (compressed) records.
#[derive(Debug)]
pub(crate) struct ChunkRecord<'a> {
    pub uncompressed_size: u64,
    pub uncompressed_crc: u32,
    pub compression: String,
    pub records: &'a [u8],
}

/// A Chunk Index record (opcode 0x08).
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub(crate) struct ChunkIndex {
    pub message_start_time: u64,
    pub message_end_time: u64,
    pub chunk_start_offset: u64,
    pub chunk_length: u64,
    /// Channel id → offset of that channel's message index record.
    pub message_index_offsets: BTreeMap<u16, u64>,
    pub uncompressed_size: u64,
    /// Byte offset of this chunk index record in the file (0 until the summary parser sets it;
    /// 0 for an entry found by walking the data section).
    pub record_offset: u64,
    /// Not a chunk: a span of records stored outside chunks (read as they are).
    pub loose: bool,
}

/// A Statistics record (opcode 0x0B).
#[derive(Debug, Clone)]
pub(crate) struct Statistics {
    pub message_count: u64,
    pub channel_message_counts: BTreeMap<u16, u64>,
}

/// A Footer record (opcode 0x02).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Footer {
    pub summary_start: u64,
    pub summary_crc: u32,
}

/// Reads little-endian fields from a record body with bounds checks.
struct Body<'a> {
    record: &'static str,
    buf: &'a [u8],
    pos: usize,
}

impl<'a> Body<'a> {
    fn new(record: &'static str, buf: &'a [u8]) -> Body<'a> {
        Body {
            record,
            buf,
            pos: 0,
        }
    }

    fn take(&mut self, n: u64, field: &str) -> Result<&'a [u8], String> {
        let remaining = (self.buf.len() - self.pos) as u64;
        if n > remaining {
            return Err(format!(
                "{} record: field {field} needs {n} bytes but only {remaining} remain in the record",
                self.record
            ));
        }
        let start = self.pos;
        self.pos += n as usize;
        Ok(&self.buf[start..self.pos])
    }

    fn array<const N: usize>(&mut self, field: &str) -> Result<[u8; N], String> {
        let b = self.take(N as u64, field)?;
        b.try_into().map_err(|_| format!("{field}: short read"))
    }

    fn u16(&mut self, field: &str) -> Result<u16, String> {
        self.array::<2>(field).map(u16::from_le_bytes)
    }

    fn u32(&mut self, field: &str) -> Result<u32, String> {
        self.array::<4>(field).map(u32::from_le_bytes)
    }

    fn u64(&mut self, field: &str) -> Result<u64, String> {
        self.array::<8>(field).map(u64::from_le_bytes)
    }

    fn bytes_u32(&mut self, field: &str) -> Result<&'a [u8], String> {
        let n = self.u32(field)? as u64;
        self.take(n, field)
    }

    fn string(&mut self, field: &str) -> Result<String, String> {
        let b = self.bytes_u32(field)?;
        std::str::from_utf8(b)
            .map(str::to_string)
            .map_err(|_| format!("{} record: field {field} is not UTF-8", self.record))
    }

    /// A `map<u16, u64>` (u32 byte length, then 10-byte entries).
    fn map_u16_u64(&mut self, field: &str) -> Result<BTreeMap<u16, u64>, String> {
        let b = self.bytes_u32(field)?;
        if b.len() % 10 != 0 {
            return Err(format!(
                "{} record: map {field} of {} bytes is not a whole number of entries",
                self.record,
                b.len()
            ));
        }
        Ok(b.chunks_exact(10)
            .map(|e| {
                (
                    u16::from_le_bytes([e[0], e[1]]),
                    u64::from_le_bytes(e[2..10].try_into().unwrap_or_default()),
                )
            })
            .collect())
    }
}

pub(crate) fn schema(body: &[u8]) -> Result<SchemaRecord, String> {
    let mut b = Body::new("schema", body);
    Ok(SchemaRecord {
        id: b.u16("id")?,
        name: b.string("name")?,
        encoding: b.string("encoding")?,
        data: b.bytes_u32("data")?.to_vec(),
    })
}

pub(crate) fn channel(body: &[u8]) -> Result<ChannelRecord, String> {
    let mut b = Body::new("channel", body);
    Ok(ChannelRecord {
        id: b.u16("id")?,
        schema_id: b.u16("schema_id")?,
        topic: b.string("topic")?,
        message_encoding: b.string("message_encoding")?,
    })
}

pub(crate) fn chunk(body: &[u8]) -> Result<ChunkRecord<'_>, String> {
    let mut b = Body::new("chunk", body);
    let _message_start_time = b.u64("message_start_time")?;
    let _message_end_time = b.u64("message_end_time")?;
    let uncompressed_size = b.u64("uncompressed_size")?;
    let uncompressed_crc = b.u32("uncompressed_crc")?;
    let compression = b.string("compression")?;
    let len = b.u64("records")?;
    Ok(ChunkRecord {
        uncompressed_size,
        uncompressed_crc,
        compression,
        records: b.take(len, "records")?,
    })
}

pub(crate) fn chunk_index(body: &[u8]) -> Result<ChunkIndex, String> {
    let mut b = Body::new("chunk index", body);
    Ok(ChunkIndex {
        message_start_time: b.u64("message_start_time")?,
        message_end_time: b.u64("message_end_time")?,
        chunk_start_offset: b.u64("chunk_start_offset")?,
        chunk_length: b.u64("chunk_length")?,
        message_index_offsets: b.map_u16_u64("message_index_offsets")?,
        uncompressed_size: {
            let _length = b.u64("message_index_length")?;
            let _compression = (b.string("compression")?, b.u64("compressed_size")?);
            b.u64("uncompressed_size")?
        },
        record_offset: 0,
        loose: false,
    })
}

pub(crate) fn statistics(body: &[u8]) -> Result<Statistics, String> {
    let mut b = Body::new("statistics", body);
    let message_count = b.u64("message_count")?;
    let _schema_count = b.u16("schema_count")?;
    let _channel_count = b.u32("channel_count")?;
    let _attachment_count = b.u32("attachment_count")?;
    let _metadata_count = b.u32("metadata_count")?;
    let _chunk_count = b.u32("chunk_count")?;
    let _message_start_time = b.u64("message_start_time")?;
    let _message_end_time = b.u64("message_end_time")?;
    let channel_message_counts = b.map_u16_u64("channel_message_counts")?;
    Ok(Statistics {
        message_count,
        channel_message_counts,
    })
}

pub(crate) fn footer(body: &[u8]) -> Result<Footer, String> {
    let mut b = Body::new("footer", body);
    let summary_start = b.u64("summary_start")?;
    let _summary_offset_start = b.u64("summary_offset_start")?;
    let summary_crc = b.u32("summary_crc")?;
    Ok(Footer {
        summary_start,
        summary_crc,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_length_prefix_longer_than_the_record_is_refused_before_allocating() {
        // Schema: id 1, name of claimed length 0xFFFF_FFF0 in a 12-byte body.
        let mut body = 1u16.to_le_bytes().to_vec();
        body.extend(0xFFFF_FFF0u32.to_le_bytes());
        body.extend(b"abcdef");
        let e = schema(&body).unwrap_err();
        assert!(
            e.contains("field name needs 4294967280 bytes but only 6 remain"),
            "{e}"
        );
        // A map whose byte length is not a multiple of its entry size.
        let mut body = vec![0u8; 8 * 4];
        body.extend(3u32.to_le_bytes());
        body.extend([0u8; 3]);
        let e = chunk_index(&body).unwrap_err();
        assert!(e.contains("not a whole number of entries"), "{e}");
    }

    #[test]
    fn schema_and_channel_round_trip() {
        let mut body = 7u16.to_le_bytes().to_vec();
        for s in ["pkg/msg/T", "ros2msg"] {
            body.extend((s.len() as u32).to_le_bytes());
            body.extend(s.as_bytes());
        }
        body.extend(3u32.to_le_bytes());
        body.extend(b"x y");
        let s = schema(&body).unwrap();
        assert_eq!(
            (s.id, s.name.as_str(), s.encoding.as_str(), &s.data[..]),
            (7, "pkg/msg/T", "ros2msg", &b"x y"[..])
        );
        let mut body = 2u16.to_le_bytes().to_vec();
        body.extend(7u16.to_le_bytes());
        for s in ["/t", "cdr"] {
            body.extend((s.len() as u32).to_le_bytes());
            body.extend(s.as_bytes());
        }
        body.extend(0u32.to_le_bytes());
        let c = channel(&body).unwrap();
        assert_eq!(
            (
                c.id,
                c.schema_id,
                c.topic.as_str(),
                c.message_encoding.as_str()
            ),
            (2, 7, "/t", "cdr")
        );
    }
}
