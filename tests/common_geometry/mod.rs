//! Helpers for the geometry tests: a minimal OBJ reader (positions and faces only) and a `.npy`
//! writer for exporting results to the libigl cross-check (`scripts/crosscheck_libigl.py`).

use std::io::Write;
use std::path::{Path, PathBuf};

use retex::engine::mesh::Surface;

/// The shared asset folder: `$RETEX_SHARED_ASSETS`, else `../shared/assets` next to the crate.
pub fn shared_assets_dir() -> PathBuf {
    match std::env::var("RETEX_SHARED_ASSETS") {
        Ok(dir) => PathBuf::from(dir),
        Err(_) => Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/assets"),
    }
}

/// Reads `v` and `f` records of an OBJ file (vertex order kept, polygons fan-triangulated,
/// `v/vt/vn` and negative indices handled, no welding) into a surface.
pub fn read_obj(path: &Path) -> Surface {
    let text = std::fs::read_to_string(path)
        .unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
    let mut positions = Vec::new();
    let mut faces = Vec::new();
    for line in text.lines() {
        let mut it = line.split_whitespace();
        match it.next() {
            Some("v") => {
                let p: Vec<f32> = it.take(3).map(|t| t.parse().expect("bad vertex")).collect();
                positions.push([p[0], p[1], p[2]]);
            }
            Some("f") => {
                let n = positions.len() as i64;
                let ids: Vec<u32> = it
                    .map(|t| {
                        let i: i64 = t.split('/').next().unwrap().parse().expect("bad face");
                        (if i < 0 { n + i } else { i - 1 }) as u32
                    })
                    .collect();
                for k in 1..ids.len().saturating_sub(1) {
                    faces.push([ids[0], ids[k], ids[k + 1]]);
                }
            }
            _ => {}
        }
    }
    Surface::from_triangles(positions, faces)
}

/// Writes a C-order `.npy` array of little-endian `f64` (`descr = "<f8"`) or `i64` (`"<i8"`).
fn write_npy(path: &Path, descr: &str, shape: &[usize], bytes: &[u8]) {
    let shape_txt = match shape {
        [n] => format!("({n},)"),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(|s| s.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    let mut header =
        format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape_txt}, }}");
    // Magic (6) + version (2) + header length (2) + header + '\n' must be a multiple of 64.
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut f = std::fs::File::create(path).expect("create npy");
    f.write_all(b"\x93NUMPY\x01\x00").unwrap();
    f.write_all(&(header.len() as u16).to_le_bytes()).unwrap();
    f.write_all(header.as_bytes()).unwrap();
    f.write_all(bytes).unwrap();
}

/// Writes `f64` values with the given shape.
pub fn write_f64(dir: &Path, name: &str, shape: &[usize], values: &[f64]) {
    let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
    write_npy(&dir.join(format!("{name}.npy")), "<f8", shape, &bytes);
}

/// Writes `i64` values with the given shape.
pub fn write_i64(dir: &Path, name: &str, shape: &[usize], values: &[i64]) {
    let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
    write_npy(&dir.join(format!("{name}.npy")), "<i8", shape, &bytes);
}
