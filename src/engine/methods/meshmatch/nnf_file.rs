//! The nearest-neighbour field artifact `nnf.bin` of a MeshMatch job (Chen et al. 2012, §4: "the
//! output is a new synthesized texture … along with an approximate nearest neighbor field that
//! associates an orientation and vertex of M_S with every vertex of M_T").
//!
//! Layout, all little-endian:
//!
//! | bytes | content |
//! |---|---|
//! | 8 | magic `RTXNNF01` |
//! | 4 | `u32` target sample count `T` |
//! | 4 | `u32` source sample count `S` |
//! | 4 | `u32` spokes `A` (rotation unit: 360°/A) |
//! | 4 | `f32` scale applied to the source before matching |
//! | 12·T | target sample positions, `f32 x, y, z`, target world space |
//! | 12·S | source sample positions, `f32 x, y, z`, source world space (unscaled) |
//! | 10·T | per target sample: `u32` source sample, `u16` rotation (spokes), `f32` dissimilarity |
//!
//! Target spoke `j` matches source spoke `j + rotation (mod A)`, i.e. the source patch is rotated
//! by `rotation · 360°/A` counter-clockwise about its normal relative to the target's frame.

use super::matcher::Nnf;

/// Magic bytes.
pub const MAGIC: &[u8; 8] = b"RTXNNF01";

/// A decoded `nnf.bin`.
#[derive(Clone, Debug, PartialEq)]
pub struct NnfFile {
    /// Spokes `A`.
    pub spokes: u32,
    /// Source scale used while matching.
    pub source_scale: f32,
    /// Target sample positions.
    pub target_positions: Vec<[f32; 3]>,
    /// Source sample positions (unscaled).
    pub source_positions: Vec<[f32; 3]>,
    /// The field.
    pub nnf: Nnf,
}

impl NnfFile {
    /// Encodes the file.
    pub fn encode(&self) -> Vec<u8> {
        let t = self.target_positions.len();
        let s = self.source_positions.len();
        let mut out = Vec::with_capacity(24 + 12 * (t + s) + 10 * t);
        out.extend_from_slice(MAGIC);
        out.extend_from_slice(&(t as u32).to_le_bytes());
        out.extend_from_slice(&(s as u32).to_le_bytes());
        out.extend_from_slice(&self.spokes.to_le_bytes());
        out.extend_from_slice(&self.source_scale.to_le_bytes());
        for p in self.target_positions.iter().chain(&self.source_positions) {
            for x in p {
                out.extend_from_slice(&x.to_le_bytes());
            }
        }
        for i in 0..t {
            out.extend_from_slice(&self.nnf.source[i].to_le_bytes());
            out.extend_from_slice(&self.nnf.rotation[i].to_le_bytes());
            out.extend_from_slice(&self.nnf.distance[i].to_le_bytes());
        }
        out
    }

    /// Decodes a file; `None` when it is malformed.
    pub fn decode(bytes: &[u8]) -> Option<Self> {
        let mut at = 0usize;
        let mut take = |n: usize| -> Option<&[u8]> {
            let s = bytes.get(at..at.checked_add(n)?)?;
            at += n;
            Some(s)
        };
        if take(8)? != MAGIC {
            return None;
        }
        let u32_at = |b: &[u8]| u32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        let t = u32_at(take(4)?) as usize;
        let s = u32_at(take(4)?) as usize;
        let spokes = u32_at(take(4)?);
        let source_scale = f32::from_bits(u32_at(take(4)?));
        let expected = 24u64 + 12 * (t as u64 + s as u64) + 10 * t as u64;
        if bytes.len() as u64 != expected {
            return None;
        }
        let mut points = |n: usize| -> Option<Vec<[f32; 3]>> {
            (0..n)
                .map(|_| {
                    let b = take(12)?;
                    Some(std::array::from_fn(|k| {
                        f32::from_bits(u32_at(&b[4 * k..4 * k + 4]))
                    }))
                })
                .collect()
        };
        let target_positions = points(t)?;
        let source_positions = points(s)?;
        let mut nnf = Nnf::default();
        for _ in 0..t {
            let b = take(10)?;
            nnf.source.push(u32_at(&b[0..4]));
            nnf.rotation.push(u16::from_le_bytes([b[4], b[5]]));
            nnf.distance.push(f32::from_bits(u32_at(&b[6..10])));
        }
        Some(NnfFile {
            spokes,
            source_scale,
            target_positions,
            source_positions,
            nnf,
        })
    }
}
