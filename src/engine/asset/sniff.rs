//! What a main file is when it is not glTF: recognized from its first bytes, so that an OBJ, an
//! image or a text file sent as the model gets "this is a Wavefront OBJ file; retex reads glTF
//! 2.0" instead of the JSON parser's "expected value at line 1 column 1".
//!
//! Only called for files that are neither a GLB (magic `glTF`) nor JSON text (first non-blank
//! byte `{`, or a byte order mark). Unrecognized binary data is left to the GLB and JSON parsers,
//! whose errors say what is wrong byte by byte.

/// A format that is not glTF 2.0, with advice on what to do with it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Foreign {
    /// What the file is, for "... is {what}", e.g. `a Wavefront OBJ file`.
    pub what: &'static str,
    /// What to do instead, for "...; {advice}".
    pub advice: &'static str,
}

const CONVERT: &str = "convert it to glTF first (e.g. Blender: File > Export > glTF 2.0)";
const CONVERT_OBJ: &str =
    "convert it to glTF first (e.g. Blender: File > Export > glTF 2.0, or `obj2gltf -i model.obj`)";
const IMAGE: &str = "a texture goes inside the model (the glTF's images), not in place of it";

/// Recognizes a main file that is another format than glTF 2.0. `None` for bytes that may be
/// glTF (GLB magic, JSON text) and for binary data of no format known here.
pub fn foreign_format(bytes: &[u8]) -> Option<Foreign> {
    let f = |what, advice| Some(Foreign { what, advice });
    let starts = |magic: &[u8]| bytes.starts_with(magic);
    if starts(b"glTF") || first_non_blank(bytes).is_some_and(|b| b == b'{' || b == 0xEF) {
        return None;
    }
    // Binary formats, by magic number.
    if starts(b"\x89PNG\r\n\x1a\n") {
        return f("a PNG image", IMAGE);
    }
    if starts(&[0xFF, 0xD8, 0xFF]) {
        return f("a JPEG image", IMAGE);
    }
    if starts(b"RIFF") && bytes.get(8..12) == Some(b"WEBP") {
        return f("a WebP image", IMAGE);
    }
    if starts(b"GIF87a") || starts(b"GIF89a") {
        return f("a GIF image", IMAGE);
    }
    if starts(b"PK\x03\x04") || starts(b"PK\x05\x06") {
        return f(
            "a zip archive",
            "unpack it and give the .glb or .gltf inside (the HTTP service accepts a zip as one part)",
        );
    }
    if starts(&[0x1F, 0x8B]) {
        return f("a gzip-compressed file", "decompress it first");
    }
    if starts(b"Kaydara FBX Binary") {
        return f("an FBX file", CONVERT);
    }
    if starts(b"BLENDER") {
        return f(
            "a Blender file",
            "export it from Blender as glTF 2.0 (File > Export > glTF 2.0)",
        );
    }
    if starts(b"PXR-USDC") {
        return f("a USD file", CONVERT);
    }
    if starts(b"%PDF") {
        return f("a PDF document", CONVERT);
    }
    if binary_stl(bytes) {
        return f("a binary STL file", CONVERT);
    }
    // Text formats, by their first meaningful line.
    let head = &bytes[..bytes.len().min(4096)];
    let text = match std::str::from_utf8(head) {
        Ok(t) => t,
        // A character cut by the 4096-byte window is fine; an invalid byte is binary data.
        Err(e) if e.error_len().is_none() => std::str::from_utf8(&head[..e.valid_up_to()]).ok()?,
        Err(_) => return None,
    };
    if text.chars().any(|c| c.is_control() && !c.is_whitespace()) {
        return None;
    }
    let lower = text.trim_start().to_ascii_lowercase();
    // JSON of another shape (an array, a number) is left to the glTF checks.
    if lower.starts_with('[') || serde_json::from_slice::<serde::de::IgnoredAny>(bytes).is_ok() {
        return None;
    }
    if lower.starts_with("ply") {
        return f("a PLY file", CONVERT);
    }
    if lower.starts_with("solid") {
        return f("an ASCII STL file", CONVERT);
    }
    if lower.starts_with("#usda") {
        return f("a USD file", CONVERT);
    }
    if lower.starts_with("; fbx") {
        return f("an FBX file", CONVERT);
    }
    if lower.starts_with('<') {
        if lower.contains("<collada") {
            return f("a COLLADA (.dae) file", CONVERT);
        }
        return f("an XML or HTML file", CONVERT);
    }
    if looks_like_obj(text) {
        return f("a Wavefront OBJ file", CONVERT_OBJ);
    }
    if lower.is_empty() {
        return f("blank (only white space)", "");
    }
    f("plain text", "")
}

fn first_non_blank(bytes: &[u8]) -> Option<u8> {
    bytes.iter().copied().find(|b| !b.is_ascii_whitespace())
}

/// 80-byte header, u32 triangle count, 50 bytes per triangle: the size gives it away.
fn binary_stl(bytes: &[u8]) -> bool {
    let Some(count) = bytes.get(80..84) else {
        return false;
    };
    let count = u32::from_le_bytes(count.try_into().expect("4 bytes")) as u64;
    count > 0 && bytes.len() as u64 == 84 + 50 * count
}

/// OBJ: lines of `v`, `vt`, `vn`, `f`, `o`, `g`, `s`, `usemtl`, `mtllib` and `#` comments; at
/// least one vertex or face line among the first ones.
fn looks_like_obj(text: &str) -> bool {
    let mut geometry = false;
    for line in text
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .take(64)
    {
        let keyword = line.split_whitespace().next().unwrap_or("");
        match keyword {
            "v" | "vt" | "vn" | "f" | "l" | "p" => geometry = true,
            "o" | "g" | "s" | "usemtl" | "mtllib" | "vp" => {}
            k if k.starts_with('#') => {}
            _ => return false,
        }
    }
    geometry
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recognizes_formats_and_leaves_gltf_alone() {
        let what = |b: &[u8]| foreign_format(b).map(|f| f.what);
        assert_eq!(what(b"glTF\x02\0\0\0"), None);
        assert_eq!(what(b"  {\"asset\":{}}"), None);
        assert_eq!(what(b"\xEF\xBB\xBF{}"), None);
        assert_eq!(what(&[0u8; 12]), None);
        assert_eq!(
            what(b"# Blender\nmtllib a.mtl\no Cube\nv 1 2 3\nf 1 2 3\n"),
            Some("a Wavefront OBJ file")
        );
        assert_eq!(what(b"\x89PNG\r\n\x1a\n\0\0\0\rIHDR"), Some("a PNG image"));
        assert_eq!(what(b"ply\nformat ascii 1.0\n"), Some("a PLY file"));
        assert_eq!(what(b"solid cube\nfacet normal"), Some("an ASCII STL file"));
        assert_eq!(what(b"hello world"), Some("plain text"));
        assert_eq!(what(b"  \n"), Some("blank (only white space)"));
        assert_eq!(what(b"[1, 2]"), None);
        assert_eq!(what(b"\xFF\xFE binary"), None);
        let mut stl = vec![0u8; 84 + 50];
        stl[80] = 1;
        assert_eq!(what(&stl), Some("a binary STL file"));
    }
}
