//! Helpers for the geometry tests: a minimal OBJ reader (positions and faces only), a `.npy`
//! writer for exporting results to the libigl cross-check (`scripts/crosscheck_libigl.py`), face
//! orientation for the star-shaped test shapes, and the axial warp of the stretched capsules.

use std::io::Write;
use std::path::Path;

use retex::engine::geometry::curvature::{principal_curvatures, CurvatureParams};
use retex::engine::geometry::laplacian::{cotan_laplacian, mass_matrix, LaplacianParams, MassKind};
use retex::engine::mesh::primitives::{icosphere, jitter};
use retex::engine::mesh::Surface;
use retex::engine::rng::SplitMix64;

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

/// Deterministic values in [-1, 1).
pub fn random_vec(n: usize, seed: u64) -> Vec<f64> {
    let mut rng = SplitMix64::new(seed);
    (0..n).map(|_| rng.signed_unit_f64()).collect()
}

/// A sphere of radius `r` whose vertices were jittered and pushed back onto the sphere:
/// irregular valences kept, triangle shapes irregular (some obtuse).
pub fn jittered_sphere(r: f64, frequency: usize, amount: f64) -> Surface {
    let mut s = icosphere(r, frequency);
    jitter(&mut s, amount, [true; 3], 7);
    for p in &mut s.positions {
        let l = p.iter().map(|c| (*c as f64).powi(2)).sum::<f64>().sqrt();
        *p = p.map(|c| (c as f64 * r / l) as f32);
    }
    s
}

/// Great-circle distance between two points on the sphere of radius `r` about the origin.
pub fn great_circle(p: [f32; 3], q: [f32; 3], r: f64) -> f64 {
    let d: f64 = (0..3).map(|k| p[k] as f64 * q[k] as f64).sum::<f64>() / (r * r);
    r * d.clamp(-1.0, 1.0).acos()
}

/// Mean of `|got - want| / want` over entries with `want > min_dist`.
pub fn mean_relative_error(got: &[f64], want: &[f64], min_dist: f64) -> f64 {
    let (mut sum, mut count) = (0.0, 0usize);
    for (g, w) in got.iter().zip(want) {
        if *w > min_dist {
            sum += (g - w).abs() / w;
            count += 1;
        }
    }
    sum / count as f64
}

/// Writes V, F, L triplets, both masses and curvatures of an icosphere, Spot (`tests/data`) and
/// the low-resolution koala (shared assets) (see `scripts/crosscheck_libigl.py`) into
/// `$RETEX_CROSSCHECK_DIR` (default `target/crosscheck_libigl`).
pub fn export_for_libigl() {
    let out = std::env::var("RETEX_CROSSCHECK_DIR")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|_| {
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("target/crosscheck_libigl")
        });
    let meshes = [
        ("icosphere", icosphere(1.0, 12)),
        (
            "spot",
            read_obj(&crate::common::test_data(
                "src_spot_keenan/spot_triangulated.obj",
            )),
        ),
        (
            "koala_low",
            read_obj(&crate::common::shared_asset(
                "perf_koala_odedstein/koala_low_resolution.obj",
            )),
        ),
    ];
    for (name, s) in meshes {
        let dir = out.join(name);
        std::fs::create_dir_all(&dir).unwrap();
        let (n, m) = (s.vertex_count(), s.face_count());
        let v: Vec<f64> = s.positions.iter().flatten().map(|&c| c as f64).collect();
        let f: Vec<i64> = s.faces.iter().flatten().map(|&i| i as i64).collect();
        write_f64(&dir, "V", &[n, 3], &v);
        write_i64(&dir, "F", &[m, 3], &f);
        let lap = cotan_laplacian(&s, &LaplacianParams::default()).unwrap();
        let t = lap.stiffness.triplets();
        write_i64(
            &dir,
            "L_rows",
            &[t.len()],
            &t.iter().map(|e| e.0 as i64).collect::<Vec<_>>(),
        );
        write_i64(
            &dir,
            "L_cols",
            &[t.len()],
            &t.iter().map(|e| e.1 as i64).collect::<Vec<_>>(),
        );
        write_f64(
            &dir,
            "L_vals",
            &[t.len()],
            &t.iter().map(|e| e.2).collect::<Vec<_>>(),
        );
        for (kind, file) in [
            (MassKind::MixedVoronoi, "M_voronoi"),
            (MassKind::Barycentric, "M_barycentric"),
        ] {
            write_f64(&dir, file, &[n], &mass_matrix(&s, kind).unwrap());
        }
        let c = principal_curvatures(&s, &CurvatureParams::default()).unwrap();
        write_f64(&dir, "k_max", &[n], &c.k_max);
        write_f64(&dir, "k_min", &[n], &c.k_min);
        let flat = |d: &[[f64; 3]]| d.iter().flatten().copied().collect::<Vec<_>>();
        write_f64(&dir, "dir_max", &[n, 3], &flat(&c.dir_max));
        write_f64(&dir, "dir_min", &[n, 3], &flat(&c.dir_min));
        write_f64(&dir, "normals", &[n, 3], &flat(&c.normals));
        eprintln!(
            "exported {name}: {n} vertices, {m} faces -> {}",
            dir.display()
        );
    }
}

/// Orients every face so that its normal points away from the origin (star-shaped shapes):
/// the triple product `a · (b × c)` must be positive.
pub fn orient_outward(positions: &[[f32; 3]], faces: &mut [[u32; 3]]) {
    for f in faces.iter_mut() {
        let [a, b, c] = f.map(|v| positions[v as usize].map(f64::from));
        let bc = [
            b[1] * c[2] - b[2] * c[1],
            b[2] * c[0] - b[0] * c[2],
            b[0] * c[1] - b[1] * c[0],
        ];
        if a[0] * bc[0] + a[1] * bc[1] + a[2] * bc[2] < 0.0 {
            f.swap(1, 2);
        }
    }
}

/// The axial warp of the stretched capsules (meshmatch's stripe and scale tests, detail's ring
/// test): x ≤ 2 stays, the part beyond x = 2 is stretched 2× (x = 4 goes to 6).
pub fn stretch_beyond_two(x: f32) -> f32 {
    if x <= 2.0 {
        x
    } else {
        2.0 + 2.0 * (x - 2.0)
    }
}
