//! Helpers of the MeshMatch tests: procedural capsules with stripes, GLB writing and reading,
//! running a transfer from bytes.
#![allow(dead_code)]

use retex::engine::asset::constraints::Constraints;
use retex::engine::asset::BlobSet;
use retex::engine::control::Control;
use retex::engine::pipeline::{transfer, ModelInput, TransferInput, TransferOutput};

/// Builds a GLB of one primitive: positions, triangles and optional COLOR_0 (linear RGBA), with a
/// plain white material.
pub fn glb_of(
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    colors: Option<&[[f32; 4]]>,
) -> Vec<u8> {
    let mut bin = Vec::new();
    for p in positions {
        for x in p {
            bin.extend_from_slice(&x.to_le_bytes());
        }
    }
    let pos_len = bin.len();
    for t in triangles {
        for i in t {
            bin.extend_from_slice(&i.to_le_bytes());
        }
    }
    let idx_len = bin.len() - pos_len;
    let col_off = bin.len();
    if let Some(c) = colors {
        for p in c {
            for x in p {
                bin.extend_from_slice(&x.to_le_bytes());
            }
        }
    }
    let col_len = bin.len() - col_off;
    let (mut lo, mut hi) = ([f32::MAX; 3], [f32::MIN; 3]);
    for p in positions {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let mut attributes = serde_json::json!({"POSITION": 0});
    let mut accessors = vec![
        serde_json::json!({"bufferView": 0, "componentType": 5126, "count": positions.len(), "type": "VEC3", "min": lo, "max": hi}),
        serde_json::json!({"bufferView": 1, "componentType": 5125, "count": triangles.len() * 3, "type": "SCALAR"}),
    ];
    let mut views = vec![
        serde_json::json!({"buffer": 0, "byteOffset": 0, "byteLength": pos_len, "target": 34962}),
        serde_json::json!({"buffer": 0, "byteOffset": pos_len, "byteLength": idx_len, "target": 34963}),
    ];
    if colors.is_some() {
        attributes["COLOR_0"] = 2.into();
        accessors.push(serde_json::json!({"bufferView": 2, "componentType": 5126, "count": positions.len(), "type": "VEC4"}));
        views.push(serde_json::json!({"buffer": 0, "byteOffset": col_off, "byteLength": col_len, "target": 34962}));
    }
    let json = serde_json::json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "materials": [{"pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, 1], "metallicFactor": 0}}],
        "meshes": [{"primitives": [{"attributes": attributes, "indices": 1, "material": 0}]}],
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": bin.len()}],
    });
    crate::common::glb(&json, &bin)
}

/// Runs a transfer between two models given as bytes.
pub fn run_bytes(
    source: (&str, Vec<u8>),
    target: (&str, Vec<u8>),
    constraints: serde_json::Value,
) -> TransferOutput {
    let mut sb = BlobSet::new();
    sb.insert(source.0, source.1);
    let mut tb = BlobSet::new();
    tb.insert(target.0, target.1);
    let c: Constraints = serde_json::from_value(constraints).unwrap();
    transfer(
        &TransferInput::pair(
            ModelInput {
                main: source.0,
                blobs: &sb,
            },
            ModelInput {
                main: target.0,
                blobs: &tb,
            },
            c,
        ),
        &Control::new(),
    )
    .unwrap()
}

/// A capsule along +x: a cylinder of `radius` over the profile's x range with hemispherical caps,
/// `around` segments around; `profile` lists the x of the cylinder's rings (increasing). `warp`
/// moves x afterwards (the stretched target).
pub fn capsule(
    radius: f32,
    profile: &[f32],
    around: usize,
    warp: impl Fn(f32) -> f32,
) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let cap_rings = 8;
    let (x0, x1) = (profile[0], *profile.last().unwrap());
    // Rings as (x, ring radius), from the left pole to the right pole (poles excluded).
    let mut rings: Vec<(f32, f32)> = Vec::new();
    for k in 1..cap_rings {
        let a = std::f32::consts::FRAC_PI_2 * k as f32 / cap_rings as f32;
        rings.push((x0 - radius * a.cos(), radius * a.sin()));
    }
    for &x in profile {
        rings.push((x, radius));
    }
    for k in (1..cap_rings).rev() {
        let a = std::f32::consts::FRAC_PI_2 * k as f32 / cap_rings as f32;
        rings.push((x1 + radius * a.cos(), radius * a.sin()));
    }
    let mut positions = vec![[warp(x0 - radius), 0.0, 0.0]];
    for &(x, r) in &rings {
        for j in 0..around {
            let t = std::f32::consts::TAU * j as f32 / around as f32;
            positions.push([warp(x), r * t.cos(), r * t.sin()]);
        }
    }
    positions.push([warp(x1 + radius), 0.0, 0.0]);
    let last = positions.len() as u32 - 1;
    let at = |ring: usize, j: usize| (1 + ring * around + j % around) as u32;
    let mut tris = Vec::new();
    for j in 0..around {
        tris.push([0, at(0, j + 1), at(0, j)]);
    }
    for ring in 0..rings.len() - 1 {
        for j in 0..around {
            let (a, b, c, d) = (
                at(ring, j),
                at(ring, j + 1),
                at(ring + 1, j),
                at(ring + 1, j + 1),
            );
            tris.push([a, b, d]);
            tris.push([a, d, c]);
        }
    }
    let r = rings.len() - 1;
    for j in 0..around {
        tris.push([last, at(r, j), at(r, j + 1)]);
    }
    (positions, tris)
}

/// Reads POSITION and COLOR_0 (as linear RGB) of every primitive of an output GLB, in world space
/// (the test assets have identity nodes).
pub fn colored_points(glb: &[u8]) -> Vec<([f32; 3], [f32; 3])> {
    let asset = crate::common::load_bytes(glb, "out.glb");
    let mut out = Vec::new();
    for p in &asset.primitives {
        if let Some(c) = &p.colors {
            for (x, col) in p.positions.iter().zip(c) {
                out.push((*x, [col[0], col[1], col[2]]));
            }
        }
    }
    out
}
