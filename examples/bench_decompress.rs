//! Bare decompression of an MCAP file: the floor for any command that reads it.
//!
//! Walks the file's top-level records with a buffered reader (no index, no message decoding) and
//! zstd/lz4-free decompresses every zstd chunk on one core, so docs/scale.md can state each command's
//! reading time as a multiple of this figure (issue: "time still within ~2× of bare decompression").
//!
//! ```text
//! cargo run --example bench_decompress -- FILE.mcap [FILE.mcap …]
//! ```

use std::fs::File;
use std::io::{BufReader, Read};
use std::time::Instant;

use anyhow::{Context, Result, bail};

/// MCAP opcode of a chunk record.
const OP_CHUNK: u8 = 0x06;

fn u64_at(b: &[u8], at: usize) -> Result<u64> {
    let s = b.get(at..at + 8).context("chunk record too short")?;
    Ok(u64::from_le_bytes(s.try_into()?))
}

fn u32_at(b: &[u8], at: usize) -> Result<u32> {
    let s = b.get(at..at + 4).context("chunk record too short")?;
    Ok(u32::from_le_bytes(s.try_into()?))
}

/// Decompresses every chunk of `path`; returns (chunks, compressed bytes, decompressed bytes).
fn decompress_all(path: &str) -> Result<(usize, u64, u64)> {
    let mut r = BufReader::with_capacity(1 << 20, File::open(path).context(path.to_string())?);
    let mut magic = [0u8; 8];
    r.read_exact(&mut magic)?;
    if &magic != b"\x89MCAP0\r\n" {
        bail!("{path}: not an MCAP file");
    }
    let mut dec = zstd::bulk::Decompressor::new()?;
    let (mut chunks, mut packed, mut unpacked) = (0usize, 0u64, 0u64);
    let mut body = Vec::new();
    let mut out = Vec::new();
    loop {
        let mut head = [0u8; 9];
        if r.read_exact(&mut head).is_err() {
            break; // the footer magic is shorter than a record header
        }
        let len = u64::from_le_bytes(head[1..9].try_into()?) as usize;
        body.resize(len, 0);
        r.read_exact(&mut body)
            .with_context(|| format!("{path}: record truncated"))?;
        if head[0] != OP_CHUNK {
            continue;
        }
        // start u64, end u64, uncompressed_size u64, crc u32, compression string, records u64+bytes
        let size = u64_at(&body, 16)? as usize;
        let clen = u32_at(&body, 28)? as usize;
        let compression = body.get(32..32 + clen).context("chunk compression")?;
        let rec_len = u64_at(&body, 32 + clen)? as usize;
        let records = body
            .get(40 + clen..40 + clen + rec_len)
            .context("chunk records")?;
        match compression {
            b"zstd" => {
                out.clear();
                out.reserve(size);
                let n = dec.decompress_to_buffer(records, &mut out)?;
                unpacked += n as u64;
            }
            b"" => unpacked += rec_len as u64,
            other => bail!(
                "{path}: compression {:?} not measured",
                String::from_utf8_lossy(other)
            ),
        }
        chunks += 1;
        packed += rec_len as u64;
    }
    Ok((chunks, packed, unpacked))
}

fn main() -> Result<()> {
    let files: Vec<String> = std::env::args().skip(1).collect();
    if files.is_empty() {
        bail!("usage: bench_decompress FILE.mcap [FILE.mcap …]");
    }
    println!("| file | chunks | compressed | decompressed | wall [s] |");
    println!("|---|---|---|---|---|");
    for f in &files {
        let t0 = Instant::now();
        let (chunks, packed, unpacked) = decompress_all(f)?;
        println!(
            "| {f} | {chunks} | {:.0} MB | {:.0} MB | {:.2} |",
            packed as f64 / 1e6,
            unpacked as f64 / 1e6,
            t0.elapsed().as_secs_f64()
        );
    }
    Ok(())
}
