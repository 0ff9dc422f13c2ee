//! The capsule primitive (`retex::engine::mesh::primitives::capsule`) and the vertex-coloured GLB
//! writer (`retex::engine::asset::export::colored_mesh_glb`) that the MeshMatch tests and
//! `retex bench --method meshmatch` build their striped inputs from.

use crate::common;

use std::collections::HashMap;

use retex::engine::asset::export::colored_mesh_glb;
use retex::engine::mesh::primitives::capsule;

/// Signed volume enclosed by the faces (positive when they wind outwards).
fn signed_volume(positions: &[[f32; 3]], faces: &[[u32; 3]]) -> f64 {
    faces
        .iter()
        .map(|f| {
            let [a, b, c] = f.map(|v| positions[v as usize].map(f64::from));
            (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
                + a[2] * (b[0] * c[1] - b[1] * c[0]))
                / 6.0
        })
        .sum()
}

#[test]
fn capsule_is_closed_outward_and_of_the_documented_size() {
    let (radius, length, around) = (0.5f32, 4.0f32, 48usize);
    let profile: Vec<f32> = (0..=40).map(|i| length * i as f32 / 40.0).collect();
    let s = capsule(radius, &profile, around, |x| x);
    assert_eq!(s.positions.len(), 2 + around * (profile.len() + 14));
    // Every directed edge once, and its reverse once: closed, consistently oriented.
    let mut directed: HashMap<(u32, u32), usize> = HashMap::new();
    for f in &s.faces {
        for k in 0..3 {
            *directed.entry((f[k], f[(k + 1) % 3])).or_default() += 1;
        }
    }
    for (&(a, b), &n) in &directed {
        assert_eq!(n, 1, "edge {a}-{b} used {n} times in one direction");
        assert_eq!(directed.get(&(b, a)), Some(&1), "edge {a}-{b} is a border");
    }
    // Volume of a cylinder plus a sphere, within the polygonal approximation (48 segments,
    // 8 cap rings: about 1% below).
    let r = radius as f64;
    let exact =
        std::f64::consts::PI * r * r * length as f64 + 4.0 / 3.0 * std::f64::consts::PI * r.powi(3);
    let v = signed_volume(&s.positions, &s.faces);
    assert!(
        v > 0.97 * exact && v < exact,
        "volume {v}, analytic {exact}"
    );
    // The warp moves x only, with the same connectivity.
    let stretched = capsule(radius, &profile, around, |x| 2.0 * x);
    assert_eq!(stretched.faces, s.faces);
    let v2 = signed_volume(&stretched.positions, &stretched.faces);
    assert!((v2 / v - 2.0).abs() < 1e-3, "stretched volume ×{}", v2 / v);
}

#[test]
fn colored_capsule_glb_is_valid_and_keeps_its_colours() {
    let profile: Vec<f32> = (0..=20).map(|i| i as f32 / 10.0).collect();
    let s = capsule(0.5, &profile, 24, |x| x);
    let colors: Vec<[f32; 4]> = s
        .positions
        .iter()
        .map(|p| [(p[0] / 3.0).clamp(0.0, 1.0), 0.5, 0.25, 1.0])
        .collect();
    let glb = colored_mesh_glb(&s.positions, &s.faces, Some(&colors)).unwrap();
    common::assert_validator_clean(&glb, "primitives_colored_capsule.glb");
    let bare = colored_mesh_glb(&s.positions, &s.faces, None).unwrap();
    common::assert_validator_clean(&bare, "primitives_bare_capsule.glb");
    // The COLOR_0 floats are the last bytes of the binary chunk, in vertex order.
    let tail = &glb[glb.len() - colors.len() * 16..];
    let read: Vec<f32> = tail
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    let want: Vec<f32> = colors.iter().flatten().copied().collect();
    assert_eq!(read, want);
}
