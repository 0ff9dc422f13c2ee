//! The fuzz harness's mutator (see `fuzz.rs`): deterministic, seeded, and aware of the formats it
//! feeds so that most mutants get past the first parser and reach the checks behind it.
//!
//! - bytes: bit flips, interesting bytes, "interesting" integers over aligned little-endian words
//!   (GLB lengths, chunk sizes), range deletion and duplication, dictionary tokens, splicing with
//!   a second seed, truncation;
//! - JSON (glTF, constraints): the document is parsed and its tree edited (a number replaced by
//!   one that breaks index or length arithmetic, a key removed, a key from elsewhere in the
//!   document inserted, an array element removed or duplicated, a node replaced by a value of
//!   another type), then written back; a text that does not parse gets byte mutations;
//! - GLB: the JSON chunk edited as JSON, the BIN chunk as bytes, or the whole file as bytes, with
//!   the container's lengths rewritten unless the whole file was mutated;
//! - PNG: byte mutations followed by recomputed chunk CRCs, so that the decoder does not refuse
//!   every mutant at the first checksum.

use retex::engine::rng::SplitMix64;
use serde_json::Value;

/// Integers that break length and index arithmetic.
const INTERESTING_U32: [u32; 12] = [
    0,
    1,
    2,
    3,
    4,
    0x7F,
    0xFFFF,
    0x1_0000,
    0x7FFF_FFFF,
    0x8000_0000,
    0xFFFF_FFFE,
    0xFFFF_FFFF,
];

/// Numbers written over numbers in text formats.
const INTERESTING_NUMBERS: [&str; 14] = [
    "0",
    "-1",
    "1",
    "2",
    "3",
    "255",
    "65536",
    "16384",
    "4294967295",
    "4294967296",
    "18446744073709551616",
    "1e308",
    "-1e308",
    "0.5",
];

/// Largest mutated input (keeps one iteration cheap).
const MAX_LEN: usize = 4 << 20;

/// A seeded mutator.
pub struct Mutator {
    rng: SplitMix64,
    dictionary: Vec<Vec<u8>>,
}

/// How a campaign's inputs are mutated.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// Any bytes.
    Bytes,
    /// A JSON document.
    Json,
    /// A binary glTF container.
    Glb,
    /// A PNG image (a JPEG or anything else gets byte mutations).
    Png,
}

impl Mutator {
    /// A mutator drawing from `seed`, inserting `dictionary` tokens among its mutations.
    pub fn new(seed: u64, dictionary: &[&str]) -> Self {
        Self {
            rng: SplitMix64::new(seed),
            dictionary: dictionary.iter().map(|t| t.as_bytes().to_vec()).collect(),
        }
    }

    /// A uniform integer in `0..n` (0 when `n` is 0).
    pub fn below(&mut self, n: usize) -> usize {
        self.rng.below(n.max(1) as u64) as usize
    }

    /// A mutant of `input` for `format`; `other` is a second seed to splice from.
    pub fn mutate_as(&mut self, format: Format, input: &[u8], other: &[u8]) -> Vec<u8> {
        match format {
            Format::Bytes => self.mutate(input, other),
            Format::Json => {
                if self.below(5) == 0 {
                    self.mutate(input, other)
                } else {
                    self.mutate_json(input)
                        .unwrap_or_else(|| self.mutate(input, other))
                }
            }
            Format::Glb => self.mutate_glb(input, other),
            Format::Png => {
                let mut out = self.mutate(input, other);
                fix_png_crcs(&mut out);
                out
            }
        }
    }

    /// One to four stacked byte mutations of `input`; `other` is a second seed to splice from.
    pub fn mutate(&mut self, input: &[u8], other: &[u8]) -> Vec<u8> {
        let mut out = input.to_vec();
        let count = 1 + self.below(4);
        for _ in 0..count {
            self.mutate_once(&mut out, other);
        }
        out.truncate(MAX_LEN);
        out
    }

    fn mutate_once(&mut self, out: &mut Vec<u8>, other: &[u8]) {
        let len = out.len();
        match self.below(10) {
            0 if len > 0 => {
                let i = self.below(len);
                out[i] ^= 1 << self.below(8);
            }
            1 if len > 0 => {
                let i = self.below(len);
                out[i] = [0u8, 0xFF, 0x7F, 0x80, b'"', b'{', b'-', b'9'][self.below(8)];
            }
            2 if len >= 4 => {
                // An aligned little-endian word: GLB lengths, chunk sizes, accessor offsets.
                let i = self.below(len / 4) * 4;
                let v = match self.below(4) {
                    0 => len as u32,
                    1 => (len as u32).wrapping_add(4),
                    _ => INTERESTING_U32[self.below(INTERESTING_U32.len())],
                };
                out[i..i + 4].copy_from_slice(&v.to_le_bytes());
            }
            3 if len > 0 => {
                let start = self.below(len);
                let n = 1 + self.below((len - start).min(256));
                out.drain(start..start + n);
            }
            4 if len > 0 => {
                let start = self.below(len);
                let n = 1 + self.below((len - start).min(256));
                let chunk = out[start..start + n].to_vec();
                let at = self.below(len + 1);
                out.splice(at..at, chunk);
            }
            5 if !self.dictionary.is_empty() => {
                let pick = self.below(self.dictionary.len());
                let token = self.dictionary[pick].clone();
                let at = self.below(len + 1);
                out.splice(at..at, token);
            }
            6 => self.replace_number(out),
            7 if !other.is_empty() => {
                let cut = self.below(len + 1);
                let from = self.below(other.len());
                out.truncate(cut);
                out.extend_from_slice(&other[from..]);
            }
            8 if len > 0 => {
                let keep = self.below(len);
                out.truncate(keep);
            }
            _ if len > 0 => {
                let start = self.below(len);
                let n = 1 + self.below((len - start).min(16));
                for b in &mut out[start..start + n] {
                    *b = self.rng.next_u64() as u8;
                }
            }
            _ => out.push(self.rng.next_u64() as u8),
        }
    }

    /// Replaces a run of ASCII digits (a number in JSON) with an interesting number.
    fn replace_number(&mut self, out: &mut Vec<u8>) {
        let digits: Vec<usize> = (0..out.len())
            .filter(|&i| out[i].is_ascii_digit())
            .collect();
        if digits.is_empty() {
            return;
        }
        let mut start = digits[self.below(digits.len())];
        while start > 0 && out[start - 1].is_ascii_digit() {
            start -= 1;
        }
        let mut end = start;
        while end < out.len() && (out[end].is_ascii_digit() || out[end] == b'.') {
            end += 1;
        }
        let number = INTERESTING_NUMBERS[self.below(INTERESTING_NUMBERS.len())];
        out.splice(start..end, number.bytes());
    }

    /// One to three tree edits of a JSON document; `None` when `text` is not JSON.
    pub fn mutate_json(&mut self, text: &[u8]) -> Option<Vec<u8>> {
        let mut doc: Value = serde_json::from_slice(text).ok()?;
        let mut keys = Vec::new();
        collect_keys(&doc, &mut keys);
        for _ in 0..1 + self.below(3) {
            let nodes = count_nodes(&doc);
            let mut k = self.below(nodes);
            let replacement = self.interesting_value();
            let key = keys.get(self.below(keys.len())).cloned();
            let (pick, choice) = (self.rng.next_u64() as usize, self.below(4));
            let Some(node) = nth_node(&mut doc, &mut k) else {
                continue;
            };
            edit_node(node, pick, choice, replacement, key);
        }
        serde_json::to_vec(&doc).ok()
    }

    /// A value that breaks index, length or type assumptions.
    fn interesting_value(&mut self) -> Value {
        let n = INTERESTING_NUMBERS[self.below(INTERESTING_NUMBERS.len())];
        match self.below(8) {
            0 => Value::Null,
            1 => Value::Array(Vec::new()),
            2 => Value::Object(Default::default()),
            3 => Value::String(
                ["", "VEC3", "SCALAR", "../x", "data:,", "image/png"][self.below(6)].into(),
            ),
            4 => Value::Bool(true),
            _ => serde_json::from_str(n).unwrap_or(Value::Null),
        }
    }

    /// A GLB mutant: its JSON chunk edited as JSON, its BIN chunk as bytes (lengths rewritten),
    /// or the raw file as bytes.
    pub fn mutate_glb(&mut self, input: &[u8], other: &[u8]) -> Vec<u8> {
        let Some((json, bin)) = glb_chunks(input) else {
            return self.mutate(input, other);
        };
        match self.below(10) {
            0..=5 => {
                let json = self
                    .mutate_json(json)
                    .unwrap_or_else(|| self.mutate(json, &[]));
                glb_from(&json, bin)
            }
            6..=7 => {
                let bin = self.mutate(bin, &[]);
                glb_from(json, &bin)
            }
            _ => self.mutate(input, other),
        }
    }
}

fn count_nodes(v: &Value) -> usize {
    1 + match v {
        Value::Array(a) => a.iter().map(count_nodes).sum(),
        Value::Object(o) => o.values().map(count_nodes).sum(),
        _ => 0,
    }
}

fn collect_keys(v: &Value, keys: &mut Vec<String>) {
    match v {
        Value::Array(a) => a.iter().for_each(|x| collect_keys(x, keys)),
        Value::Object(o) => {
            for (k, x) in o {
                if !keys.contains(k) {
                    keys.push(k.clone());
                }
                collect_keys(x, keys);
            }
        }
        _ => {}
    }
}

/// The `k`-th node of `v` in pre-order.
fn nth_node<'a>(v: &'a mut Value, k: &mut usize) -> Option<&'a mut Value> {
    if *k == 0 {
        return Some(v);
    }
    *k -= 1;
    match v {
        Value::Array(a) => {
            for x in a.iter_mut() {
                if let Some(found) = nth_node(x, k) {
                    return Some(found);
                }
            }
            None
        }
        Value::Object(o) => {
            for x in o.values_mut() {
                if let Some(found) = nth_node(x, k) {
                    return Some(found);
                }
            }
            None
        }
        _ => None,
    }
}

/// One edit of `node`: containers lose, duplicate or gain a child; scalars are replaced.
fn edit_node(
    node: &mut Value,
    pick: usize,
    choice: usize,
    replacement: Value,
    key: Option<String>,
) {
    match node {
        Value::Array(a) if !a.is_empty() && choice < 3 => {
            let i = pick % a.len();
            match choice {
                0 => {
                    a.remove(i);
                }
                1 => {
                    let copy = a[i].clone();
                    a.push(copy);
                }
                _ => a[i] = replacement,
            }
        }
        Value::Object(o) if !o.is_empty() && choice < 3 => {
            let name = o.keys().nth(pick % o.len()).cloned().unwrap_or_default();
            match choice {
                0 => {
                    o.remove(&name);
                }
                1 => {
                    o.insert(key.unwrap_or(name), replacement);
                }
                _ => {
                    o.insert(name, replacement);
                }
            }
        }
        _ => *node = replacement,
    }
}

/// The JSON and BIN chunks of a well-formed GLB (BIN may be empty).
fn glb_chunks(data: &[u8]) -> Option<(&[u8], &[u8])> {
    let word = |at: usize| -> Option<usize> {
        Some(u32::from_le_bytes(data.get(at..at + 4)?.try_into().ok()?) as usize)
    };
    if data.get(..4)? != b"glTF" || data.get(16..20)? != b"JSON" {
        return None;
    }
    let json_len = word(12)?;
    let json = data.get(20..20 + json_len)?;
    let rest = 20 + json_len;
    let bin = match word(rest) {
        Some(n) if data.get(rest + 4..rest + 8) == Some(b"BIN\0") => {
            data.get(rest + 8..rest + 8 + n)?
        }
        _ => &[],
    };
    Some((json, bin))
}

/// A GLB of the given chunks with correct lengths and padding.
fn glb_from(json: &[u8], bin: &[u8]) -> Vec<u8> {
    let mut text = json.to_vec();
    while !text.len().is_multiple_of(4) {
        text.push(b' ');
    }
    let mut bin = bin.to_vec();
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let total = 12 + 8 + text.len() + if bin.is_empty() { 0 } else { 8 + bin.len() };
    let mut out = b"glTF".to_vec();
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(text.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&text);
    if !bin.is_empty() {
        out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(&bin);
    }
    out
}

/// Rewrites the CRC of every whole chunk of a PNG (a no-op for other data).
fn fix_png_crcs(data: &mut [u8]) {
    if !data.starts_with(b"\x89PNG\r\n\x1a\n") {
        return;
    }
    let mut at = 8;
    while at + 12 <= data.len() {
        let len = u32::from_be_bytes(data[at..at + 4].try_into().unwrap()) as usize;
        let Some(end) = (at + 8).checked_add(len).filter(|&e| e + 4 <= data.len()) else {
            return;
        };
        let crc = super::png_crc32(&data[at + 4..end]);
        data[end..end + 4].copy_from_slice(&crc.to_be_bytes());
        at = end + 4;
    }
}
