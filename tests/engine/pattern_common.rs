//! Measures of a `pattern` output read back from the file (issue 12's tests): coverage, flipped
//! faces, texel density and anisotropy from each face's UV Jacobian, seam error across UV
//! discontinuities normalised by random placement, and the baselines (planar, cube,
//! random-per-patch) measured the same way.
#![allow(dead_code)]

use retex::engine::asset::constraints::Constraints;
use retex::engine::asset::{Asset, BlobSet};
use retex::engine::control::Control;
use retex::engine::pipeline::{transfer, ImageInput, ModelInput, TransferInput, TransferOutput};
use retex::engine::rng::SplitMix64;

use crate::elastiface_common::{mesh_glb, texture_png, MeshData};

/// A tileable colour pattern (integer frequencies), `size`², with structure at several scales.
pub fn tile_png(size: u32) -> Vec<u8> {
    use std::f64::consts::TAU;
    texture_png(size, size, |u, v| {
        [
            0.5 + 0.35 * (TAU * (2.0 * u + v)).sin() + 0.1 * (TAU * 5.0 * v).sin(),
            0.5 + 0.35 * (TAU * 3.0 * v).sin() * (TAU * u).cos(),
            0.5 + 0.35 * (TAU * (u - 2.0 * v)).cos() + 0.1 * (TAU * 4.0 * u).cos(),
        ]
    })
}

/// An anisotropic tileable pattern: stripes along x with a weak modulation.
pub fn stripes_png(size: u32) -> Vec<u8> {
    use std::f64::consts::TAU;
    texture_png(size, size, |u, v| {
        let s = 0.5 + 0.45 * (TAU * 4.0 * v).sin();
        [s, 0.3 + 0.2 * (TAU * u).cos(), 1.0 - s]
    })
}

/// A sheet folded along x = 0 by `angle` radians: points (s, t) of the unit-free rectangle
/// [−1, 1] × [0, 1] map isometrically (its exact unfolding is (s, t)).
pub fn folded_sheet(n: usize, angle: f64) -> MeshData {
    let mut positions = Vec::new();
    for j in 0..=n {
        for i in 0..=2 * n {
            let s = -1.0 + i as f64 / n as f64;
            let t = j as f64 / n as f64;
            let p = if s <= 0.0 {
                [s, 0.0, t]
            } else {
                [s * angle.cos(), s * angle.sin(), t]
            };
            positions.push(p.map(|c| c as f32));
        }
    }
    let w = 2 * n + 1;
    let id = |i: usize, j: usize| (j * w + i) as u32;
    let mut indices = Vec::new();
    for j in 0..n {
        for i in 0..2 * n {
            indices.extend([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
            indices.extend([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
        }
    }
    MeshData {
        positions,
        uvs: None,
        indices,
    }
}

/// Runs `pattern` on a mesh with a PNG pattern.
pub fn run_pattern(mesh: &MeshData, png: &[u8], params: serde_json::Value) -> TransferOutput {
    run_pattern_seeded(mesh, png, params, 3)
}

/// [`run_pattern`] with a job seed.
pub fn run_pattern_seeded(
    mesh: &MeshData,
    png: &[u8],
    params: serde_json::Value,
    seed: u64,
) -> TransferOutput {
    let target = mesh_glb(
        &MeshData {
            uvs: None,
            ..mesh.clone()
        },
        None,
        1.0,
    );
    run_pattern_glb(&target, png, params, seed)
}

/// Runs `pattern` on a GLB.
pub fn run_pattern_glb(
    target: &[u8],
    png: &[u8],
    params: serde_json::Value,
    seed: u64,
) -> TransferOutput {
    let c = serde_json::json!({"version": 1, "method": "pattern", "seed": seed, "params": params});
    let constraints = Constraints::from_json(c.to_string().as_bytes()).unwrap();
    let mut tb = BlobSet::new();
    tb.insert("target.glb", target.to_vec());
    let input = TransferInput::new(
        ModelInput {
            main: "target.glb",
            blobs: &tb,
        },
        constraints,
    )
    .with_pattern(ImageInput {
        name: "tile.png",
        bytes: png,
    });
    transfer(&input, &Control::new()).unwrap()
}

/// A textured triangle soup: world positions and UVs per corner.
#[derive(Clone, Debug, Default)]
pub struct UvMesh {
    pub positions: Vec<[[f64; 3]; 3]>,
    pub uvs: Vec<[[f64; 2]; 3]>,
    /// Output vertex ids per corner (equal ids = same UV, no seam).
    pub ids: Vec<[u32; 3]>,
    /// Welded position key per corner.
    pub keys: Vec<[u64; 3]>,
}

fn key(p: [f64; 3]) -> u64 {
    let q = p.map(|c| ((c * 1e5).round() as i64) as u64);
    q[0].wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ q[1].wrapping_mul(0xC2B2_AE3D_27D4_EB4F) ^ q[2]
}

/// The first primitive of an output asset (world = local: the test meshes have unit nodes).
pub fn uv_mesh(asset: &Asset) -> UvMesh {
    let prim = &asset.primitives[0];
    let uv = &prim.tex_coords[0];
    let mut m = UvMesh::default();
    for t in &prim.triangles {
        let p = t.map(|v| prim.positions[v as usize].map(f64::from));
        m.positions.push(p);
        m.uvs.push(t.map(|v| uv[v as usize].map(f64::from)));
        m.ids.push(*t);
        m.keys.push(p.map(key));
    }
    m
}

/// The same triangles with UVs from `f(position)` per corner and one vertex id per position.
pub fn with_uvs(mesh: &MeshData, f: impl Fn([f64; 3], usize) -> [f64; 2]) -> UvMesh {
    let mut m = UvMesh::default();
    for (ti, t) in mesh.indices.chunks(3).enumerate() {
        let p = [t[0], t[1], t[2]].map(|v| mesh.positions[v as usize].map(f64::from));
        m.uvs.push(p.map(|q| f(q, ti)));
        m.positions.push(p);
        m.ids.push([t[0], t[1], t[2]]);
        m.keys.push(p.map(key));
    }
    m
}

/// Decoded pattern, linear-ish RGB in [0, 1] (sRGB values / 255; the metric only compares).
pub struct Image {
    pub w: usize,
    pub h: usize,
    pub px: Vec<[f32; 3]>,
}

impl Image {
    pub fn decode(bytes: &[u8]) -> Self {
        let img = image::load_from_memory(bytes).unwrap().to_rgb8();
        let (w, h) = (img.width() as usize, img.height() as usize);
        let px = img
            .pixels()
            .map(|p| p.0.map(|c| f32::from(c) / 255.0))
            .collect();
        Self { w, h, px }
    }

    /// Bilinear, wrapped (REPEAT).
    pub fn sample(&self, uv: [f64; 2]) -> [f32; 3] {
        let x = uv[0] * self.w as f64 - 0.5;
        let y = uv[1] * self.h as f64 - 0.5;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = ((x - x0) as f32, (y - y0) as f32);
        let at = |i: f64, j: f64| {
            let i = (i as i64).rem_euclid(self.w as i64) as usize;
            let j = (j as i64).rem_euclid(self.h as i64) as usize;
            self.px[j * self.w + i]
        };
        let (a, b, c, d) = (
            at(x0, y0),
            at(x0 + 1.0, y0),
            at(x0, y0 + 1.0),
            at(x0 + 1.0, y0 + 1.0),
        );
        [0, 1, 2].map(|k| {
            (a[k] * (1.0 - fx) + b[k] * fx) * (1.0 - fy) + (c[k] * (1.0 - fx) + d[k] * fx) * fy
        })
    }

    /// Mean squared colour difference of two random pixels.
    pub fn random_pair_error(&self) -> f64 {
        let mut rng = SplitMix64::new(11);
        let mut s = 0.0;
        for _ in 0..20_000 {
            let a = self.sample([rng.unit_f64(), rng.unit_f64()]);
            let b = self.sample([rng.unit_f64(), rng.unit_f64()]);
            s += (0..3)
                .map(|k| f64::from((a[k] - b[k]).powi(2)))
                .sum::<f64>();
        }
        s / 20_000.0
    }
}

/// Figures of one UV layout.
#[derive(Clone, Debug, Default)]
pub struct Measures {
    /// Triangles with a non-positive (or non-finite) UV area when seen in image orientation.
    pub flipped: usize,
    /// Texel density (px per world unit, geometric mean of the singular values) / requested,
    /// area-weighted 10th, 50th and 90th percentiles.
    pub density: [f64; 3],
    /// Anisotropy σ1/σ2, area-weighted 50th and 90th percentiles.
    pub anisotropy: [f64; 2],
    /// Mean colour difference across seam edges / random-pair difference.
    pub seam: f64,
    /// Seam length / total interior edge length.
    pub seam_fraction: f64,
}

fn percentile(mut v: Vec<(f64, f64)>, q: f64) -> f64 {
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    let total: f64 = v.iter().map(|x| x.1).sum();
    let mut acc = 0.0;
    for (x, w) in &v {
        acc += w;
        if acc >= q * total {
            return *x;
        }
    }
    v.last().map_or(0.0, |x| x.0)
}

/// Measures a layout against the requested px per world unit (`image.w / scale`).
pub fn measure(m: &UvMesh, image: &Image, px_per_world: f64) -> Measures {
    let mut out = Measures::default();
    let mut dens = Vec::new();
    let mut aniso = Vec::new();
    for (p, uv) in m.positions.iter().zip(&m.uvs) {
        let e1 = [0, 1, 2].map(|k| p[1][k] - p[0][k]);
        let e2 = [0, 1, 2].map(|k| p[2][k] - p[0][k]);
        let l1 = e1.iter().map(|x| x * x).sum::<f64>().sqrt();
        let x = e1.map(|c| c / l1);
        let n = [
            e1[1] * e2[2] - e1[2] * e2[1],
            e1[2] * e2[0] - e1[0] * e2[2],
            e1[0] * e2[1] - e1[1] * e2[0],
        ];
        let area = 0.5 * n.iter().map(|x| x * x).sum::<f64>().sqrt();
        if area < 1e-12 * l1 * l1 || area == 0.0 {
            // A degenerate input triangle (e.g. at a UV sphere's pole) has no texture to judge.
            continue;
        }
        let nn = n.map(|c| c / (2.0 * area));
        let y = [
            nn[1] * x[2] - nn[2] * x[1],
            nn[2] * x[0] - nn[0] * x[2],
            nn[0] * x[1] - nn[1] * x[0],
        ];
        let q1 = [l1, 0.0];
        let q2 = [
            e2.iter().zip(&x).map(|(a, b)| a * b).sum::<f64>(),
            e2.iter().zip(&y).map(|(a, b)| a * b).sum::<f64>(),
        ];
        // UV in pixels with y up (image v down flipped) so a front face keeps its orientation.
        let t = |k: usize| [uv[k][0] * image.w as f64, -uv[k][1] * image.h as f64];
        let (t0, t1, t2) = (t(0), t(1), t(2));
        let d1 = [t1[0] - t0[0], t1[1] - t0[1]];
        let d2 = [t2[0] - t0[0], t2[1] - t0[1]];
        // J · [q1 q2] = [d1 d2].
        let det = q1[0] * q2[1] - q2[0] * q1[1];
        let inv = [[q2[1] / det, -q2[0] / det], [-q1[1] / det, q1[0] / det]];
        let j = [
            [
                d1[0] * inv[0][0] + d2[0] * inv[1][0],
                d1[0] * inv[0][1] + d2[0] * inv[1][1],
            ],
            [
                d1[1] * inv[0][0] + d2[1] * inv[1][0],
                d1[1] * inv[0][1] + d2[1] * inv[1][1],
            ],
        ];
        let jdet = j[0][0] * j[1][1] - j[0][1] * j[1][0];
        if !(jdet.is_finite() && jdet > 0.0) {
            out.flipped += 1;
        }
        let fro = j.iter().flatten().map(|x| x * x).sum::<f64>();
        let disc = (fro * fro - 4.0 * jdet * jdet).max(0.0).sqrt();
        let s1 = ((fro + disc) / 2.0).sqrt();
        let s2 = ((fro - disc) / 2.0).max(0.0).sqrt();
        dens.push(((s1 * s2).sqrt() / px_per_world, area));
        aniso.push((if s2 > 0.0 { s1 / s2 } else { f64::INFINITY }, area));
    }
    out.density = [0.1, 0.5, 0.9].map(|q| percentile(dens.clone(), q));
    out.anisotropy = [0.5, 0.9].map(|q| percentile(aniso.clone(), q));
    let (seam, frac) = seam_error(m, image);
    out.seam = seam;
    out.seam_fraction = frac;
    out
}

/// Mean colour difference across edges whose two faces give different UVs, normalised by the
/// random-pair difference; and the seam share of the interior edge length.
fn seam_error(m: &UvMesh, image: &Image) -> (f64, f64) {
    use std::collections::HashMap;
    let mut edges: HashMap<(u64, u64), Vec<(usize, usize)>> = HashMap::new();
    for (f, k) in m.keys.iter().enumerate() {
        for e in 0..3 {
            let (a, b) = (k[e], k[(e + 1) % 3]);
            edges.entry((a.min(b), a.max(b))).or_default().push((f, e));
        }
    }
    let (mut sum, mut seam_len, mut total_len) = (0.0, 0.0, 0.0);
    for ((ka, _), sides) in edges {
        if sides.len() != 2 {
            continue;
        }
        let (f, e) = sides[0];
        let (g, d) = sides[1];
        let p = &m.positions[f];
        let len = (0..3)
            .map(|k| (p[e][k] - p[(e + 1) % 3][k]).powi(2))
            .sum::<f64>()
            .sqrt();
        total_len += len;
        // Corners of both faces at the edge's two ends, in a common order.
        let ends = |f: usize, e: usize| {
            let (a, b) = (e, (e + 1) % 3);
            if m.keys[f][a] == ka {
                ((m.ids[f][a], m.uvs[f][a]), (m.ids[f][b], m.uvs[f][b]))
            } else {
                ((m.ids[f][b], m.uvs[f][b]), (m.ids[f][a], m.uvs[f][a]))
            }
        };
        let (fa, fb) = ends(f, e);
        let (ga, gb) = ends(g, d);
        if fa.0 == ga.0 && fb.0 == gb.0 {
            continue;
        }
        seam_len += len;
        for t in [0.25, 0.5, 0.75] {
            let lerp =
                |a: [f64; 2], b: [f64; 2]| [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])];
            let c1 = image.sample(lerp(fa.1, fb.1));
            let c2 = image.sample(lerp(ga.1, gb.1));
            sum += len / 3.0
                * (0..3)
                    .map(|k| f64::from((c1[k] - c2[k]).powi(2)))
                    .sum::<f64>();
        }
    }
    let seam = if seam_len > 0.0 {
        sum / seam_len / image.random_pair_error()
    } else {
        0.0
    };
    (seam, seam_len / total_len.max(1e-300))
}

/// The output's patches (faces joined through shared output vertices) each moved by a random
/// rotation and translation: the random-per-cluster baseline with the method's own clusters.
pub fn randomised_patches(m: &UvMesh, seed: u64) -> UvMesh {
    let n = m.ids.iter().flatten().max().map_or(0, |x| *x as usize + 1);
    let mut parent: Vec<usize> = (0..n).collect();
    fn find(p: &mut [usize], mut x: usize) -> usize {
        while p[x] != x {
            p[x] = p[p[x]];
            x = p[x];
        }
        x
    }
    for t in &m.ids {
        let a = find(&mut parent, t[0] as usize);
        for v in &t[1..] {
            let b = find(&mut parent, *v as usize);
            parent[b] = a;
        }
    }
    let mut out = m.clone();
    for (f, t) in m.ids.iter().enumerate() {
        let root = find(&mut parent, t[0] as usize) as u64;
        let mut rng = SplitMix64::new(seed ^ root.wrapping_mul(0x9E37_79B9_7F4A_7C15));
        let th = rng.unit_f64() * std::f64::consts::TAU;
        let (dx, dy) = (rng.unit_f64(), rng.unit_f64());
        let (s, c) = th.sin_cos();
        out.uvs[f] = m.uvs[f].map(|u| [c * u[0] - s * u[1] + dx, s * u[0] + c * u[1] + dy]);
    }
    out
}

/// Planar projection onto x / −y at `scale` world units per image width.
pub fn planar(mesh: &MeshData, scale: f64) -> UvMesh {
    with_uvs(mesh, |p, _| [p[0] / scale, -p[1] / scale])
}

/// Planar projection onto x / z (along y) at `scale` world units per image width.
pub fn planar_xz(mesh: &MeshData, scale: f64) -> UvMesh {
    with_uvs(mesh, |p, _| [p[0] / scale, p[2] / scale])
}

/// Cube projection: each face projected along its dominant normal axis (a seam where that
/// axis changes), oriented so front faces are not mirrored.
pub fn cube(mesh: &MeshData, scale: f64) -> UvMesh {
    let normals: Vec<[f64; 3]> = mesh
        .indices
        .chunks(3)
        .map(|t| {
            let p = [t[0], t[1], t[2]].map(|v| mesh.positions[v as usize].map(f64::from));
            let e1 = [0, 1, 2].map(|k| p[1][k] - p[0][k]);
            let e2 = [0, 1, 2].map(|k| p[2][k] - p[0][k]);
            [
                e1[1] * e2[2] - e1[2] * e2[1],
                e1[2] * e2[0] - e1[0] * e2[2],
                e1[0] * e2[1] - e1[1] * e2[0],
            ]
        })
        .collect();
    let mut m = with_uvs(mesh, |p, f| {
        let n = normals[f];
        let a = (0..3)
            .max_by(|i, j| n[*i].abs().total_cmp(&n[*j].abs()))
            .unwrap();
        let s = n[a].signum();
        let (u, v) = match a {
            0 => (-s * p[2], p[1]),
            1 => (p[0], -s * p[2]),
            _ => (s * p[0], p[1]),
        };
        [u / scale, -v / scale]
    });
    // One vertex id per (position, axis): seams where the axis changes.
    for (f, ids) in m.ids.iter_mut().enumerate() {
        let n = normals[f];
        let a = (0..3)
            .max_by(|i, j| n[*i].abs().total_cmp(&n[*j].abs()))
            .unwrap() as u32;
        let s = u32::from(n[a as usize] > 0.0);
        *ids = ids.map(|v| v * 6 + a * 2 + s);
    }
    m
}

/// Orientation coherence across seams for a pattern whose stripes run along the image's u axis
/// ([`stripes_png`]): per face, the 3-D direction that the UV map sends to (1, 0) (the first
/// column of `E Δ⁻¹`, `E` the face's edge vectors, `Δ` its UV edges); across every seam edge
/// (the two faces' output vertices differ), the angle between the two faces' stripe axes, each
/// measured from the shared edge in its own face's plane (so the dihedral bend does not count)
/// and compared modulo 180° (a stripe is an axis). Returns the edge-length-weighted mean angle in
/// degrees (random axes score 45) and the number of seam edges.
pub fn stripe_seam_angle(m: &UvMesh) -> (f64, usize) {
    use std::collections::HashMap;
    let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let dot = |a: [f64; 3], b: [f64; 3]| a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    let cross = |a: [f64; 3], b: [f64; 3]| {
        [
            a[1] * b[2] - a[2] * b[1],
            a[2] * b[0] - a[0] * b[2],
            a[0] * b[1] - a[1] * b[0],
        ]
    };
    // Stripe direction and unit normal per face (None when the UV map is degenerate).
    let frames: Vec<Option<([f64; 3], [f64; 3])>> = (0..m.positions.len())
        .map(|f| {
            let p = m.positions[f];
            let u = m.uvs[f];
            let (e1, e2) = (sub(p[1], p[0]), sub(p[2], p[0]));
            let (a, b) = (
                [u[1][0] - u[0][0], u[1][1] - u[0][1]],
                [u[2][0] - u[0][0], u[2][1] - u[0][1]],
            );
            let det = a[0] * b[1] - b[0] * a[1];
            let n = cross(e1, e2);
            let nl = dot(n, n).sqrt();
            if det.abs() < 1e-300 || nl < 1e-300 {
                return None;
            }
            // Δ⁻¹ · (1, 0) = (b[1], −a[1]) / det; direction = E · that.
            let (x, y) = (b[1] / det, -a[1] / det);
            let d = [0, 1, 2].map(|k| e1[k] * x + e2[k] * y);
            Some((d, n.map(|c| c / nl)))
        })
        .collect();
    let mut edges: HashMap<(u64, u64), Vec<(usize, usize)>> = HashMap::new();
    for (f, k) in m.keys.iter().enumerate() {
        for e in 0..3 {
            let (a, b) = (k[e], k[(e + 1) % 3]);
            edges.entry((a.min(b), a.max(b))).or_default().push((f, e));
        }
    }
    let (mut sum, mut total, mut count) = (0.0, 0.0, 0usize);
    for ((ka, _), sides) in edges {
        if sides.len() != 2 {
            continue;
        }
        let (f, e) = sides[0];
        let (g, d) = sides[1];
        let corner = |f: usize, e: usize, key: u64| {
            let a = if m.keys[f][e] == key { e } else { (e + 1) % 3 };
            m.ids[f][a]
        };
        let other = |f: usize, e: usize| {
            if m.keys[f][e] == ka {
                (e + 1) % 3
            } else {
                e
            }
        };
        let same_a = corner(f, e, ka) == corner(g, d, ka);
        let same_b = m.ids[f][other(f, e)] == m.ids[g][other(g, d)];
        if same_a && same_b {
            continue;
        }
        let (Some((df, nf)), Some((dg, ng))) = (frames[f], frames[g]) else {
            continue;
        };
        let p = m.positions[f];
        let edge = sub(p[(e + 1) % 3], p[e]);
        let len = dot(edge, edge).sqrt();
        if len < 1e-300 {
            continue;
        }
        let angle = |d: [f64; 3], n: [f64; 3]| dot(d, cross(n, edge)).atan2(dot(d, edge));
        let diff = (angle(df, nf) - angle(dg, ng)).rem_euclid(std::f64::consts::PI);
        let diff = diff.min(std::f64::consts::PI - diff);
        sum += len * diff.to_degrees();
        total += len;
        count += 1;
    }
    (if total > 0.0 { sum / total } else { 0.0 }, count)
}
