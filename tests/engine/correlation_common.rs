//! Shared builders of the `correlation` end-to-end tests (issue 11): the procedural weathering
//! case (two different bumpy shapes, dirt = f(solid-angle curvature, occlusion, up-facing) plus
//! noise on the source), the transfer through the job pipeline, and the metrics.

use retex::engine::control::Control;
use retex::engine::geometry::occlusion::{directional_occlusion, OcclusionParams};
use retex::engine::geometry::solid_angle::{solid_angle_curvature, SolidAngleParams};
use retex::engine::mesh::Surface;
use retex::engine::rng::SplitMix64;
use retex::engine::spatial::Bvh;
use serde_json::json;

use crate::common::assert_validator_clean;
use crate::common_geometry::orient_outward;
use crate::meshmatch_common::{colored_points, glb_of, run_bytes};

/// A closed latitude–longitude shape about the y axis with radius `radius(theta, phi)`
/// (theta from +y), faces outward.
pub(crate) fn bumpy(rings: u32, segments: u32, radius: impl Fn(f64, f64) -> f64) -> Surface {
    use std::f64::consts::PI;
    let at = |th: f64, ph: f64| {
        let r = radius(th, ph);
        [
            (r * th.sin() * ph.cos()) as f32,
            (r * th.cos()) as f32,
            (r * th.sin() * ph.sin()) as f32,
        ]
    };
    let mut pos = vec![at(0.0, 0.0)];
    for i in 1..rings {
        let th = PI * i as f64 / rings as f64;
        for j in 0..segments {
            pos.push(at(th, 2.0 * PI * j as f64 / segments as f64));
        }
    }
    pos.push(at(PI, 0.0));
    let south = (pos.len() - 1) as u32;
    let ring = |i: u32, j: u32| 1 + (i - 1) * segments + j % segments;
    let mut faces = Vec::new();
    for j in 0..segments {
        faces.push([0, ring(1, j + 1), ring(1, j)]);
        faces.push([south, ring(rings - 1, j), ring(rings - 1, j + 1)]);
    }
    for i in 1..rings - 1 {
        for j in 0..segments {
            faces.push([ring(i, j), ring(i, j + 1), ring(i + 1, j)]);
            faces.push([ring(i, j + 1), ring(i + 1, j + 1), ring(i + 1, j)]);
        }
    }
    orient_outward(&pos, &mut faces);
    Surface::from_triangles(pos, faces)
}

pub(crate) fn source_shape() -> Surface {
    bumpy(72, 144, |th, ph| {
        1.0 + 0.14 * (5.0 * th).sin() * (6.0 * ph).cos()
            + 0.05 * (11.0 * th).sin() * (9.0 * ph + 1.0).cos()
    })
}

pub(crate) fn target_shape() -> Surface {
    bumpy(72, 144, |th, ph| {
        (1.0 + 0.16 * (4.0 * th).sin() * (7.0 * ph + 0.5).cos()
            + 0.05 * (9.0 * th).sin() * (12.0 * ph).cos())
            * (1.0 + 0.25 * th.cos().powi(2))
    })
}

/// The raw dirt terms per vertex: curvature at 2.5 % of the diagonal, 1 − visibility, up-facing.
pub(crate) fn dirt_terms(s: &Surface) -> Vec<[f32; 3]> {
    let c = solid_angle_curvature(
        s,
        None,
        &SolidAngleParams {
            radii: vec![0.025],
            rays: 128,
            ..Default::default()
        },
        &Control::new(),
    )
    .unwrap();
    let o = directional_occlusion(
        s,
        None,
        &OcclusionParams {
            rays: 128,
            ..Default::default()
        },
        &Control::new(),
    )
    .unwrap();
    let n = s.vertex_normals();
    (0..s.vertex_count())
        .map(|v| [c.values[v], 1.0 - o.visibility(v), n[v][1]])
        .collect()
}

/// f = z(curvature) + 0.3 z(occlusion) + z(up), z standardised with the source's statistics
/// (dirt in crevices and on up-facing parts, like moss).
pub(crate) struct Dirt {
    pub(crate) mean: [f32; 3],
    pub(crate) std: [f32; 3],
}

impl Dirt {
    pub(crate) fn fit(t: &[[f32; 3]]) -> Dirt {
        let n = t.len() as f32;
        let mean: [f32; 3] = std::array::from_fn(|k| t.iter().map(|x| x[k]).sum::<f32>() / n);
        let std = std::array::from_fn(|k| {
            (t.iter().map(|x| (x[k] - mean[k]).powi(2)).sum::<f32>() / n)
                .sqrt()
                .max(1e-6)
        });
        Dirt { mean, std }
    }

    pub(crate) fn f(&self, t: [f32; 3]) -> f32 {
        let z: [f32; 3] = std::array::from_fn(|k| (t[k] - self.mean[k]) / self.std[k]);
        z[0] + 0.3 * z[1] + z[2]
    }
}

pub(crate) fn luminance(c: [f32; 3]) -> f32 {
    0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
}

pub(crate) fn pearson(a: &[f32], b: &[f32]) -> f64 {
    let n = a.len() as f64;
    let ma = a.iter().map(|x| f64::from(*x)).sum::<f64>() / n;
    let mb = b.iter().map(|x| f64::from(*x)).sum::<f64>() / n;
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        let (dx, dy) = (f64::from(*x) - ma, f64::from(*y) - mb);
        sab += dx * dy;
        saa += dx * dx;
        sbb += dy * dy;
    }
    if saa == 0.0 || sbb == 0.0 {
        return 0.0;
    }
    sab / (saa * sbb).sqrt()
}

pub(crate) const CLEAN: [f32; 3] = [0.78, 0.68, 0.5];
pub(crate) const DIRTY: [f32; 3] = [0.12, 0.1, 0.07];

/// Source colours: clean → dirty by a sigmoid of f, plus per-vertex noise.
pub(crate) fn weathered(f: &[f32], seed: u64) -> Vec<[f32; 4]> {
    let mut rng = SplitMix64::new(seed);
    f.iter()
        .map(|&x| {
            let s = 1.0 / (1.0 + (-1.5 * x).exp());
            let mut c = [0.0, 0.0, 0.0, 1.0];
            for k in 0..3 {
                let noise = 0.05 * (rng.unit_f32() * 2.0 - 1.0);
                c[k] = (CLEAN[k] + (DIRTY[k] - CLEAN[k]) * s + noise).clamp(0.0, 1.0);
            }
            c
        })
        .collect()
}

/// Per-vertex values of `s` at points near it (closest point, barycentric).
pub(crate) fn at_points(s: &Surface, values: &[f32], points: &[[f32; 3]]) -> Vec<f32> {
    let bvh = Bvh::build(&s.positions, &s.faces);
    points
        .iter()
        .map(|p| {
            let h = bvh.closest_point(*p, f32::INFINITY).unwrap();
            let f = s.faces[h.face as usize];
            (0..3).map(|k| h.bary[k] * values[f[k] as usize]).sum()
        })
        .collect()
}

/// Area shares of the output in the source's luminance terciles.
pub(crate) fn tercile_shares(source_lum: &[f32], out_lum: &[f32]) -> [f64; 3] {
    let mut sorted = source_lum.to_vec();
    sorted.sort_by(f32::total_cmp);
    let (a, b) = (sorted[sorted.len() / 3], sorted[2 * sorted.len() / 3]);
    let mut count = [0usize; 3];
    for l in out_lum {
        count[if *l < a {
            0
        } else if *l < b {
            1
        } else {
            2
        }] += 1;
    }
    count.map(|c| c as f64 / out_lum.len() as f64)
}

pub(crate) struct Case {
    pub(crate) source: Surface,
    pub(crate) target: Surface,
    pub(crate) source_glb: Vec<u8>,
    pub(crate) target_glb: Vec<u8>,
    pub(crate) source_f: Vec<f32>,
    pub(crate) target_f: Vec<f32>,
    pub(crate) source_colors: Vec<[f32; 4]>,
}

/// The second procedural case's source: vertical ribs over an equatorial bulge.
pub(crate) fn ribbed_source_shape() -> Surface {
    bumpy(72, 144, |th, ph| {
        1.0 + 0.1 * (8.0 * ph).cos() * th.sin().powi(2)
            + 0.08 * (3.0 * th).cos()
            + 0.04 * (13.0 * th).sin() * (5.0 * ph + 0.7).cos()
    })
}

/// The second procedural case's target: an oblate shape with diagonal waves.
pub(crate) fn oblate_target_shape() -> Surface {
    bumpy(72, 144, |th, ph| {
        (1.0 + 0.13 * (6.0 * th + 3.0 * ph).sin() * th.sin()
            + 0.05 * (10.0 * th).cos() * (8.0 * ph).sin())
            * (1.0 - 0.2 * th.cos().powi(2))
    })
}

/// The procedural weathering case on the first pair of shapes (see the module docs).
pub(crate) fn case(seed: u64) -> Case {
    case_on(source_shape(), target_shape(), seed)
}

/// The same weathering on the second pair of shapes (ribbed source, oblate target).
pub(crate) fn case_b(seed: u64) -> Case {
    case_on(ribbed_source_shape(), oblate_target_shape(), seed)
}

/// The weathering case on any source and target shape.
pub(crate) fn case_on(source: Surface, target: Surface, seed: u64) -> Case {
    let ts = dirt_terms(&source);
    let dirt = Dirt::fit(&ts);
    let source_f: Vec<f32> = ts.iter().map(|t| dirt.f(*t)).collect();
    let target_f: Vec<f32> = dirt_terms(&target).iter().map(|t| dirt.f(*t)).collect();
    let source_colors = weathered(&source_f, seed);
    Case {
        source_glb: glb_of(&source.positions, &source.faces, Some(&source_colors)),
        target_glb: glb_of(&target.positions, &target.faces, None),
        source,
        target,
        source_f,
        target_f,
        source_colors,
    }
}

/// Output points, their colours, the method report.
pub(crate) type Transferred = (Vec<[f32; 3]>, Vec<[f32; 3]>, serde_json::Value);

pub(crate) fn transfer(c: &Case, params: serde_json::Value, seed: u64) -> Transferred {
    transfer_named(c, params, seed, None)
}

/// [`transfer`]; with `name` and `RETEX_CORRELATION_DUMP=<dir>` set, the output is also written
/// to `<dir>/<name>.glb` (for `retex preview`).
pub(crate) fn transfer_named(
    c: &Case,
    params: serde_json::Value,
    seed: u64,
    name: Option<&str>,
) -> Transferred {
    let mut p = json!({"samples": 32768, "vertex_color_samples": 20000});
    for (k, v) in params.as_object().unwrap() {
        p[k] = v.clone();
    }
    let out = run_bytes(
        ("s.glb", c.source_glb.clone()),
        ("t.glb", c.target_glb.clone()),
        // `uv: keep`: these tests read the COLOR_0 of the refined copy, not the generated atlas.
        json!({"version": 1, "method": "correlation", "seed": seed, "output": {"uv": "keep"}, "params": p}),
    );
    assert_validator_clean(&out.model, "correlation.glb");
    if let (Some(name), Some(dir)) = (name, std::env::var_os("RETEX_CORRELATION_DUMP")) {
        let path = std::path::Path::new(&dir).join(format!("{name}.glb"));
        std::fs::write(&path, &out.model).unwrap();
    }
    let pts = colored_points(&out.model);
    assert!(pts.len() > 10_000, "{} coloured points", pts.len());
    (
        pts.iter().map(|p| p.0).collect(),
        pts.iter().map(|p| p.1).collect(),
        out.report.method_report,
    )
}

/// Mean squared difference between each point's luminance and the mean of the points within
/// `radius` (a uniform grid): the output's high-frequency energy.
pub(crate) fn high_frequency_energy(points: &[[f32; 3]], colors: &[[f32; 3]], radius: f32) -> f64 {
    use std::collections::HashMap;
    let key = |p: [f32; 3]| p.map(|x| (x / radius).floor() as i32);
    let mut grid: HashMap<[i32; 3], Vec<usize>> = HashMap::new();
    for (i, p) in points.iter().enumerate() {
        grid.entry(key(*p)).or_default().push(i);
    }
    let lum: Vec<f32> = colors.iter().map(|c| luminance(*c)).collect();
    let mut total = 0.0f64;
    for (i, p) in points.iter().enumerate() {
        let k = key(*p);
        let (mut sum, mut n) = (0.0f32, 0u32);
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    if let Some(cell) = grid.get(&[k[0] + dx, k[1] + dy, k[2] + dz]) {
                        for &j in cell {
                            let q = points[j];
                            let d2: f32 = (0..3).map(|a| (p[a] - q[a]).powi(2)).sum();
                            if d2 <= radius * radius {
                                sum += lum[j];
                                n += 1;
                            }
                        }
                    }
                }
            }
        }
        total += f64::from(lum[i] - sum / n.max(1) as f32).powi(2);
    }
    total / points.len() as f64
}
