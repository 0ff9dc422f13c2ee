//! The GLB binary container (glTF 2.0 §4.4 "Binary glTF Layout"), parsed by hand so that every
//! lie in it is a typed error rather than a panic or a huge allocation.
//!
//! Enforced (§4.4.2 header, §4.4.3 chunks): the 12-byte header is present; magic is `glTF`;
//! version is 2; the header's total length equals the data length; every chunk header (8 bytes)
//! and chunk body lies inside the data; chunk lengths are multiples of 4 (so chunks stay 4-byte
//! aligned); the first chunk is JSON; there is at most one BIN chunk and it comes after the JSON
//! chunk. Chunks of unknown type are skipped, as the specification requires. Parsing borrows
//! slices of the input and allocates nothing.

/// The GLB magic, `glTF` in ASCII.
pub const MAGIC: [u8; 4] = *b"glTF";
/// Chunk type of the JSON chunk (`JSON` in ASCII, little endian).
pub const CHUNK_JSON: u32 = 0x4E4F_534A;
/// Chunk type of the binary buffer chunk (`BIN\0` in ASCII, little endian).
pub const CHUNK_BIN: u32 = 0x004E_4942;

/// What is wrong with a GLB container. Offsets are byte offsets in the file.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum GlbError {
    /// Fewer than 12 bytes.
    #[error("file has {len} bytes, too short for the 12-byte glb header")]
    TruncatedHeader {
        /// File length.
        len: u64,
    },
    /// The first four bytes are not `glTF`.
    #[error("magic is {found:02x?}, expected \"glTF\"")]
    BadMagic {
        /// The first four bytes.
        found: [u8; 4],
    },
    /// The version field is not 2.
    #[error("version {version} is not supported: only glb version 2 is")]
    UnsupportedVersion {
        /// The version field.
        version: u32,
    },
    /// The header's length field disagrees with the data.
    #[error("header declares {declared} bytes but the file has {actual}")]
    LengthMismatch {
        /// Length from the header.
        declared: u64,
        /// Actual data length.
        actual: u64,
    },
    /// A chunk header runs past the end of the data.
    #[error("chunk {chunk} header at offset {offset} runs past the end of the file ({len} bytes)")]
    TruncatedChunkHeader {
        /// Chunk number (0-based).
        chunk: usize,
        /// Offset of the chunk header.
        offset: u64,
        /// File length.
        len: u64,
    },
    /// A chunk body runs past the end of the data.
    #[error(
        "chunk {chunk} at offset {offset} declares {length} bytes but only {available} remain"
    )]
    TruncatedChunkData {
        /// Chunk number.
        chunk: usize,
        /// Offset of the chunk body.
        offset: u64,
        /// Declared chunk length.
        length: u64,
        /// Bytes left in the file.
        available: u64,
    },
    /// A chunk length that is not a multiple of 4.
    #[error("chunk {chunk} length {length} is not a multiple of 4")]
    UnalignedChunk {
        /// Chunk number.
        chunk: usize,
        /// Declared chunk length.
        length: u64,
    },
    /// The first chunk is not JSON (or there is no chunk at all).
    #[error("the first chunk must be json, found type {found:#010x}")]
    FirstChunkNotJson {
        /// Chunk type found (0 when there is no chunk).
        found: u32,
    },
    /// A second JSON or BIN chunk.
    #[error("chunk {chunk} is a second chunk of type {chunk_type:#010x}")]
    DuplicateChunk {
        /// Chunk number.
        chunk: usize,
        /// Its type.
        chunk_type: u32,
    },
}

/// A parsed GLB container: slices into the input.
#[derive(Debug, Clone, Copy)]
pub struct Glb<'a> {
    /// The JSON chunk, trailing padding (spaces, NULs) removed.
    pub json: &'a [u8],
    /// The BIN chunk, if any (including its up to 3 padding bytes).
    pub bin: Option<&'a [u8]>,
}

/// Whether `data` starts with the GLB magic.
pub fn is_glb(data: &[u8]) -> bool {
    data.len() >= 4 && data[..4] == MAGIC
}

fn read_u32(data: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([data[at], data[at + 1], data[at + 2], data[at + 3]])
}

/// Parses and checks a GLB container.
///
/// # Errors
/// A [`GlbError`] naming the first lie found.
pub fn parse(data: &[u8]) -> Result<Glb<'_>, GlbError> {
    let len = data.len() as u64;
    if data.len() < 12 {
        return Err(GlbError::TruncatedHeader { len });
    }
    let magic = [data[0], data[1], data[2], data[3]];
    if magic != MAGIC {
        return Err(GlbError::BadMagic { found: magic });
    }
    let version = read_u32(data, 4);
    if version != 2 {
        return Err(GlbError::UnsupportedVersion { version });
    }
    let declared = read_u32(data, 8) as u64;
    if declared != len {
        return Err(GlbError::LengthMismatch {
            declared,
            actual: len,
        });
    }
    let mut json: Option<&[u8]> = None;
    let mut bin: Option<&[u8]> = None;
    let mut offset = 12usize;
    let mut chunk = 0usize;
    while offset < data.len() {
        if data.len() - offset < 8 {
            return Err(GlbError::TruncatedChunkHeader {
                chunk,
                offset: offset as u64,
                len,
            });
        }
        let length = read_u32(data, offset) as u64;
        let chunk_type = read_u32(data, offset + 4);
        let body = offset + 8;
        let available = (data.len() - body) as u64;
        if length > available {
            return Err(GlbError::TruncatedChunkData {
                chunk,
                offset: body as u64,
                length,
                available,
            });
        }
        if !length.is_multiple_of(4) {
            return Err(GlbError::UnalignedChunk { chunk, length });
        }
        // length <= available <= usize::MAX, so the cast is exact.
        let slice = &data[body..body + length as usize];
        if chunk == 0 && chunk_type != CHUNK_JSON {
            return Err(GlbError::FirstChunkNotJson { found: chunk_type });
        }
        match chunk_type {
            CHUNK_JSON if json.is_some() => {
                return Err(GlbError::DuplicateChunk { chunk, chunk_type })
            }
            CHUNK_JSON => json = Some(slice),
            CHUNK_BIN if bin.is_some() => {
                return Err(GlbError::DuplicateChunk { chunk, chunk_type })
            }
            CHUNK_BIN => bin = Some(slice),
            _ => {} // unknown chunk types are ignored (§4.4.3.1)
        }
        offset = body + length as usize;
        chunk += 1;
    }
    let json = json.ok_or(GlbError::FirstChunkNotJson { found: 0 })?;
    let end = json
        .iter()
        .rposition(|&b| b != b' ' && b != 0)
        .map_or(0, |i| i + 1);
    Ok(Glb {
        json: &json[..end],
        bin,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn glb(chunks: &[(u32, &[u8])]) -> Vec<u8> {
        let mut out = Vec::new();
        out.extend_from_slice(&MAGIC);
        out.extend_from_slice(&2u32.to_le_bytes());
        out.extend_from_slice(&0u32.to_le_bytes());
        for (ty, body) in chunks {
            out.extend_from_slice(&(body.len() as u32).to_le_bytes());
            out.extend_from_slice(&ty.to_le_bytes());
            out.extend_from_slice(body);
        }
        let n = out.len() as u32;
        out[8..12].copy_from_slice(&n.to_le_bytes());
        out
    }

    #[test]
    fn parses_json_and_bin_and_trims_padding() {
        let data = glb(&[(CHUNK_JSON, b"{}  "), (CHUNK_BIN, &[1, 2, 3, 4])]);
        let g = parse(&data).unwrap();
        assert_eq!(g.json, b"{}");
        assert_eq!(g.bin, Some(&[1u8, 2, 3, 4][..]));
    }

    #[test]
    fn every_lie_is_an_error() {
        assert_eq!(
            parse(b"").unwrap_err(),
            GlbError::TruncatedHeader { len: 0 }
        );
        assert!(matches!(
            parse(b"glTF\x01\0\0\0\x0c\0\0\0"),
            Err(GlbError::UnsupportedVersion { version: 1 })
        ));
        let mut d = glb(&[(CHUNK_JSON, b"{}  ")]);
        d[8] += 4;
        assert!(matches!(parse(&d), Err(GlbError::LengthMismatch { .. })));
        let mut d = glb(&[(CHUNK_JSON, b"{}  ")]);
        d[12] = 200;
        assert!(matches!(
            parse(&d),
            Err(GlbError::TruncatedChunkData { chunk: 0, .. })
        ));
        let mut d = glb(&[(CHUNK_JSON, b"{}  ")]);
        d[12..16].copy_from_slice(&u32::MAX.to_le_bytes());
        assert!(matches!(
            parse(&d),
            Err(GlbError::TruncatedChunkData { .. })
        ));
        let d = glb(&[(CHUNK_BIN, b"abcd")]);
        assert!(matches!(parse(&d), Err(GlbError::FirstChunkNotJson { .. })));
        let d = glb(&[
            (CHUNK_JSON, b"{}  "),
            (CHUNK_BIN, b"abcd"),
            (CHUNK_BIN, b"abcd"),
        ]);
        assert!(matches!(
            parse(&d),
            Err(GlbError::DuplicateChunk { chunk: 2, .. })
        ));
        let d = glb(&[(CHUNK_JSON, b"{} ")]);
        assert!(matches!(parse(&d), Err(GlbError::UnalignedChunk { .. })));
        let mut d = glb(&[(CHUNK_JSON, b"{}  ")]);
        d.extend_from_slice(&[0, 0, 0]);
        let n = d.len() as u32;
        d[8..12].copy_from_slice(&n.to_le_bytes());
        assert!(matches!(
            parse(&d),
            Err(GlbError::TruncatedChunkHeader { chunk: 1, .. })
        ));
    }
}
