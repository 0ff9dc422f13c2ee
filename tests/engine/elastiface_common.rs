//! Builders for the `elastiface` tests: parametric meshes with UVs (spheres, tori, discs) written
//! as GLBs with an optional base-colour texture, the transfer runner, and readers of the result.
#![allow(dead_code)]

use retex::engine::asset::constraints::Constraints;
use retex::engine::asset::{Asset, BlobSet};
use retex::engine::control::Control;
use retex::engine::pipeline::{transfer, ModelInput, TransferError, TransferInput, TransferOutput};
use retex::engine::texture::encode::encode_png_srgb;
use serde_json::json;

use crate::common::{glb, load_bytes};

/// An indexed triangle mesh with optional UVs.
#[derive(Clone, Debug)]
pub struct MeshData {
    pub positions: Vec<[f32; 3]>,
    pub uvs: Option<Vec<[f32; 2]>>,
    pub indices: Vec<u32>,
}

impl MeshData {
    /// The same mesh with every position mapped.
    pub fn mapped(&self, f: impl Fn([f64; 3]) -> [f64; 3]) -> Self {
        let mut out = self.clone();
        for p in &mut out.positions {
            *p = f(p.map(f64::from)).map(|c| c as f32);
        }
        out
    }

    /// Flips every triangle if the mesh's signed volume is negative (outward normals, CCW).
    fn orient_outward(mut self) -> Self {
        let mut vol = 0.0f64;
        for t in self.indices.chunks(3) {
            let p = [t[0], t[1], t[2]].map(|i| self.positions[i as usize].map(f64::from));
            vol += p[0][0] * (p[1][1] * p[2][2] - p[1][2] * p[2][1])
                - p[0][1] * (p[1][0] * p[2][2] - p[1][2] * p[2][0])
                + p[0][2] * (p[1][0] * p[2][1] - p[1][1] * p[2][0]);
        }
        if vol < 0.0 {
            for t in self.indices.chunks_mut(3) {
                t.swap(1, 2);
            }
        }
        self
    }
}

/// A grid over (u, v) in [0,1]² with seam duplicates, mapped through `param`; `closed_u` adds
/// the seam column. Triangles are oriented by `orient` (outward for closed surfaces).
pub fn grid(nu: usize, nv: usize, param: impl Fn(f64, f64) -> [f64; 3]) -> MeshData {
    let mut positions = Vec::new();
    let mut uvs = Vec::new();
    for j in 0..=nv {
        for i in 0..=nu {
            let (u, v) = (i as f64 / nu as f64, j as f64 / nv as f64);
            positions.push(param(u, v).map(|c| c as f32));
            uvs.push([u as f32, v as f32]);
        }
    }
    let id = |i: usize, j: usize| (j * (nu + 1) + i) as u32;
    let mut indices = Vec::new();
    for j in 0..nv {
        for i in 0..nu {
            indices.extend([id(i, j), id(i, j + 1), id(i + 1, j + 1)]);
            indices.extend([id(i, j), id(i + 1, j + 1), id(i + 1, j)]);
        }
    }
    MeshData {
        positions,
        uvs: Some(uvs),
        indices,
    }
}

/// The unit sphere point at (u, v): longitude 2πu, colatitude πv.
pub fn sphere_point(u: f64, v: f64) -> [f64; 3] {
    let (t, p) = (std::f64::consts::PI * v, 2.0 * std::f64::consts::PI * u);
    [t.sin() * p.cos(), t.cos(), -t.sin() * p.sin()]
}

/// A UV sphere (`nu` × `nv` cells) whose points are `rot(sphere_point)`.
pub fn uv_sphere(nu: usize, nv: usize, rot: impl Fn([f64; 3]) -> [f64; 3]) -> MeshData {
    grid(nu, nv, |u, v| rot(sphere_point(u, v))).orient_outward()
}

/// The point of the torus with radii 1 (tube centre) and 0.4 (tube) at parameters (u, v).
pub fn torus_point(u: f64, v: f64) -> [f64; 3] {
    let (a, b) = (
        2.0 * std::f64::consts::PI * u,
        2.0 * std::f64::consts::PI * v,
    );
    let r = 1.0 + 0.4 * b.cos();
    [r * a.cos(), 0.4 * b.sin(), r * a.sin()]
}

/// A torus tessellated with `nu` × `nv` cells, the grid shifted by `phase` in (u, v).
pub fn torus(nu: usize, nv: usize, phase: (f64, f64)) -> MeshData {
    grid(nu, nv, |u, v| torus_point(u + phase.0, v + phase.1)).orient_outward()
}

/// A disc of radius 1 in the xz plane (polar grid, `nr` rings × `na` sectors, the innermost
/// ring collapsed to the centre), normal +y, starting at angle `a0`.
pub fn disc(nr: usize, na: usize, a0: f64) -> MeshData {
    let mut m = grid(na, nr, |u, v| {
        let a = a0 + 2.0 * std::f64::consts::PI * u;
        [v * a.cos(), 0.0, -v * a.sin()]
    });
    let p = |i: u32| m.positions[i as usize];
    let k = 3 * (2 * na); // a triangle of the second ring (the first ones are degenerate)
    let (a, b, c) = (p(m.indices[k]), p(m.indices[k + 1]), p(m.indices[k + 2]));
    let ny = (b[2] - a[2]) * (c[0] - a[0]) - (b[0] - a[0]) * (c[2] - a[2]);
    if ny < 0.0 {
        for t in m.indices.chunks_mut(3) {
            t.swap(1, 2);
        }
    }
    m
}

/// A `w × h` texture whose texel (x, y) has linear colour `color(u, v)` at its centre.
pub fn texture_png(w: u32, h: u32, color: impl Fn(f64, f64) -> [f64; 3]) -> Vec<u8> {
    let px: Vec<[f32; 4]> = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            let c = color((x as f64 + 0.5) / w as f64, (y as f64 + 0.5) / h as f64);
            [c[0] as f32, c[1] as f32, c[2] as f32, 1.0]
        })
        .collect();
    encode_png_srgb(&px, w, h)
}

fn push_aligned(bin: &mut Vec<u8>, bytes: &[u8]) -> (usize, usize) {
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let at = bin.len();
    bin.extend_from_slice(bytes);
    (at, bytes.len())
}

/// A GLB of one mesh (one primitive, one node with `scale`), with a base-colour texture when
/// `png` is given.
pub fn mesh_glb(mesh: &MeshData, png: Option<&[u8]>, node_scale: f64) -> Vec<u8> {
    mesh_glb_with(mesh, png, node_scale, &[])
}

/// [`mesh_glb`] with extra float vertex attributes: (name, components, flat values), e.g.
/// `("COLOR_0", 4, ...)`, `("NORMAL", 3, ...)`, `("TANGENT", 4, ...)`.
pub fn mesh_glb_with(
    mesh: &MeshData,
    png: Option<&[u8]>,
    node_scale: f64,
    extra: &[(&str, usize, Vec<f32>)],
) -> Vec<u8> {
    let mut bin = Vec::new();
    let pos: Vec<u8> = mesh
        .positions
        .iter()
        .flatten()
        .flat_map(|c| c.to_le_bytes())
        .collect();
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in &mesh.positions {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let mut views = vec![];
    let mut accessors = vec![];
    let (o, l) = push_aligned(&mut bin, &pos);
    views.push(json!({"buffer": 0, "byteOffset": o, "byteLength": l, "target": 34962}));
    accessors.push(
        json!({"bufferView": 0, "componentType": 5126, "count": mesh.positions.len(),
        "type": "VEC3", "min": lo, "max": hi}),
    );
    let mut attributes = json!({"POSITION": 0});
    if let Some(uvs) = &mesh.uvs {
        let b: Vec<u8> = uvs.iter().flatten().flat_map(|c| c.to_le_bytes()).collect();
        let (o, l) = push_aligned(&mut bin, &b);
        views.push(json!({"buffer": 0, "byteOffset": o, "byteLength": l, "target": 34962}));
        accessors.push(json!({"bufferView": views.len() - 1, "componentType": 5126,
            "count": uvs.len(), "type": "VEC2"}));
        attributes["TEXCOORD_0"] = json!(accessors.len() - 1);
    }
    for (name, n, values) in extra {
        let b: Vec<u8> = values.iter().flat_map(|c| c.to_le_bytes()).collect();
        let (o, l) = push_aligned(&mut bin, &b);
        views.push(json!({"buffer": 0, "byteOffset": o, "byteLength": l, "target": 34962}));
        let kind = ["SCALAR", "VEC2", "VEC3", "VEC4"][n - 1];
        accessors.push(json!({"bufferView": views.len() - 1, "componentType": 5126,
            "count": values.len() / n, "type": kind}));
        attributes[*name] = json!(accessors.len() - 1);
    }
    let b: Vec<u8> = mesh.indices.iter().flat_map(|c| c.to_le_bytes()).collect();
    let (o, l) = push_aligned(&mut bin, &b);
    views.push(json!({"buffer": 0, "byteOffset": o, "byteLength": l, "target": 34963}));
    accessors.push(json!({"bufferView": views.len() - 1, "componentType": 5125,
        "count": mesh.indices.len(), "type": "SCALAR"}));
    let indices = accessors.len() - 1;
    let mut doc = json!({
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "scale": [node_scale, node_scale, node_scale]}],
        "meshes": [{"primitives": [{"attributes": attributes, "indices": indices, "material": 0}]}],
        "materials": [{"pbrMetallicRoughness": {"baseColorFactor": [1.0, 1.0, 1.0, 1.0]}}],
        "accessors": accessors,
    });
    if let Some(png) = png {
        let (o, l) = push_aligned(&mut bin, png);
        views.push(json!({"buffer": 0, "byteOffset": o, "byteLength": l}));
        doc["images"] = json!([{"bufferView": views.len() - 1, "mimeType": "image/png"}]);
        doc["textures"] = json!([{"source": 0}]);
        doc["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"] = json!({"index": 0});
    }
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    doc["bufferViews"] = json!(views);
    doc["buffers"] = json!([{"byteLength": bin.len()}]);
    glb(&doc, &bin)
}

/// Runs a transfer between two GLBs in memory.
pub fn run_glbs(
    source: &[u8],
    target: &[u8],
    constraints: serde_json::Value,
) -> Result<TransferOutput, TransferError> {
    let c = Constraints::from_json(constraints.to_string().as_bytes())?;
    let mut sb = BlobSet::new();
    sb.insert("source.glb", source.to_vec());
    let mut tb = BlobSet::new();
    tb.insert("target.glb", target.to_vec());
    let input = TransferInput::pair(
        ModelInput {
            main: "source.glb",
            blobs: &sb,
        },
        ModelInput {
            main: "target.glb",
            blobs: &tb,
        },
        c,
    );
    transfer(&input, &Control::new())
}

/// The output model as an asset.
pub fn output_asset(out: &TransferOutput) -> Asset {
    load_bytes(&out.model, "out.glb")
}

/// Linear → sRGB 8-bit.
pub fn srgb8(c: f64) -> u8 {
    let c = c.clamp(0.0, 1.0);
    let s = if c <= 0.003_130_8 {
        12.92 * c
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    };
    (s * 255.0).round() as u8
}

/// The stage timings of a transfer (recorded by `Control`), as `name ms` pairs for a log line.
pub fn stage_timings(timings: &[retex::engine::control::StageTiming]) -> String {
    timings
        .iter()
        .map(|t| format!("{} {:.0} ms", t.stage, t.ms))
        .collect::<Vec<_>>()
        .join(", ")
}

// The stretched-sphere pair shared by the engine and service input/blend tests: a UV-sphere
// template onto an independently tessellated, turned sphere stretched per axis, whose colour at a
// target point is `sphere_color(q)` of the unit-sphere point `q` it came from.

/// `p / |p|`.
pub fn normalize(p: [f64; 3]) -> [f64; 3] {
    let l = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
    p.map(|c| c / l)
}

/// Turn of the target's tessellation (0.5 rad about z, then 0.3 rad about x).
pub fn turn(p: [f64; 3]) -> [f64; 3] {
    let (s, c) = 0.5f64.sin_cos();
    let q = [c * p[0] - s * p[1], s * p[0] + c * p[1], p[2]];
    let (s, c) = 0.3f64.sin_cos();
    [q[0], c * q[1] - s * q[2], s * q[1] + c * q[2]]
}

/// Linear colour of the unit-sphere point `q`.
pub fn sphere_color(q: [f64; 3]) -> [f64; 3] {
    [
        0.5 + 0.4 * (2.5 * q[0] + 1.0).sin(),
        0.5 + 0.4 * (2.0 * q[1]).sin(),
        0.5 + 0.4 * (3.0 * q[2]).cos(),
    ]
}

/// The first `n` (≤ 10) landmarks on the unit sphere: the six axis points, then four diagonals.
pub fn sphere_landmarks(n: usize) -> Vec<[f64; 3]> {
    let mut out = vec![
        [1.0, 0.0, 0.0],
        [-1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, 0.0, 1.0],
        [0.0, 0.0, -1.0],
    ];
    for s in [
        [1.0, 1.0, 1.0],
        [-1.0, 1.0, -1.0],
        [1.0, -1.0, -1.0],
        [-1.0, -1.0, 1.0],
    ] {
        out.push(normalize(s));
    }
    out.truncate(n);
    out
}

/// Elastiface constraints with the first `n` landmarks mapped by `stretch` (128² texture,
/// 4 texels of padding).
pub fn sphere_constraints(stretch: [f64; 3], n: usize) -> serde_json::Value {
    let corr: Vec<serde_json::Value> = sphere_landmarks(n)
        .iter()
        .map(|p| {
            let q = [0, 1, 2].map(|k| p[k] * stretch[k]);
            json!({"source": {"point": p}, "target": {"point": q}})
        })
        .collect();
    json!({"version": 1, "method": "elastiface", "correspondences": corr,
        "output": {"texture_size": 128, "padding": 4}})
}

/// The target: a turned, finer UV sphere stretched by `stretch`, with its unit points.
pub fn stretched_sphere(stretch: [f64; 3]) -> (MeshData, Vec<[f64; 3]>) {
    let unit = uv_sphere(64, 32, turn);
    let q = unit
        .positions
        .iter()
        .map(|p| normalize(p.map(f64::from)))
        .collect();
    (unit.mapped(|p| [0, 1, 2].map(|k| p[k] * stretch[k])), q)
}

/// PSNR (dB, 8-bit sRGB) of `got` against `want` (linear colours).
pub fn psnr(got: &[[f64; 3]], want: &[[f64; 3]]) -> f64 {
    let mut se = 0.0;
    for (g, w) in got.iter().zip(want) {
        for d in 0..3 {
            se += (srgb8(g[d]) as f64 - srgb8(w[d]) as f64).powi(2);
        }
    }
    10.0 * (255.0f64.powi(2) / (se / (3 * got.len()) as f64)).log10()
}

/// The mean colour repeated: the constant baseline.
pub fn constant(want: &[[f64; 3]]) -> Vec<[f64; 3]> {
    let mut m = [0.0; 3];
    for w in want {
        for d in 0..3 {
            m[d] += w[d] / want.len() as f64;
        }
    }
    vec![m; want.len()]
}

/// sRGB 8-bit → linear.
pub fn linear(c: u8) -> f64 {
    let s = c as f64 / 255.0;
    if s <= 0.04045 {
        s / 12.92
    } else {
        ((s + 0.055) / 1.055).powf(2.4)
    }
}

/// The bounding-box diagonal of world positions.
pub fn diagonal(x: &[[f64; 3]]) -> f64 {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in x {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt()
}

/// The Lee Perry-Smith head's vertices of the `upper_lip` and `lower_lip` landmarks
/// (`tests/data/elastiface/head_to_deformed.json`, pairs 9 and 10).
pub const HEAD_LIP_VERTICES: [usize; 2] = [2539, 2920];

/// Mean map errors (over the target's diagonal) of the head's lip region: the vertices within
/// 4 % of the head's diagonal of the midpoint of [`HEAD_LIP_VERTICES`].
#[derive(Debug)]
pub struct LipErrors {
    /// Every vertex of the region (the mouth bag's inside too).
    pub all: f64,
    /// The front-facing ones (head normal z > 0.3: the visible lips and skin around them).
    pub front: f64,
    /// Front-facing, above the midpoint (the upper lip).
    pub upper: f64,
    /// Front-facing, below the midpoint (the lower lip).
    pub lower: f64,
}

/// [`LipErrors`] of `fitted` against the known answer `truth` (vertex i ↦ `truth[i]`); the
/// region is chosen on the head's own positions `head` (y up, the face toward +z).
pub fn lip_errors(
    head: &[[f64; 3]],
    tris: &[[u32; 3]],
    fitted: &[[f64; 3]],
    truth: &[[f64; 3]],
    diag: f64,
) -> LipErrors {
    use retex::engine::math::{cross, length, sub};
    let head_diag = diagonal(head);
    let [u, l] = HEAD_LIP_VERTICES.map(|v| head[v]);
    let mid: [f64; 3] = std::array::from_fn(|k| 0.5 * (u[k] + l[k]));
    let mut normal = vec![[0.0f64; 3]; head.len()];
    for t in tris {
        let [a, b, c] = t.map(|v| head[v as usize]);
        let n = cross(sub(b, a), sub(c, a));
        for v in t {
            for k in 0..3 {
                normal[*v as usize][k] += n[k];
            }
        }
    }
    let mut sums = [(0.0, 0usize); 4];
    for i in 0..head.len() {
        if length(sub(head[i], mid)) > 0.04 * head_diag {
            continue;
        }
        let e = length(sub(fitted[i], truth[i])) / diag;
        let front = normal[i][2] / length(normal[i]).max(1e-300) > 0.3;
        let upper = head[i][1] > mid[1];
        for (slot, on) in [
            (0, true),
            (1, front),
            (2, front && upper),
            (3, front && !upper),
        ] {
            if on {
                sums[slot].0 += e;
                sums[slot].1 += 1;
            }
        }
    }
    let [all, front, upper, lower] = sums.map(|(s, n)| s / n.max(1) as f64);
    assert!(
        sums[3].1 > 0 && sums[2].1 > 0,
        "an empty lip region: {sums:?}"
    );
    LipErrors {
        all,
        front,
        upper,
        lower,
    }
}
