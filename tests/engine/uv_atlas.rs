//! The UV atlas (`retex::engine::uv`): on a closed sphere, an open sheet, a torus (genus 1), two
//! components, a jittered (irregular) sphere and a cylinder, every face gets UVs in [0, 1], no
//! two triangles cover the same texel at 1024² (strict-inside rasterisation), no UV triangle is
//! flipped, every chart's L2 stretch is within the bound, seams lie only where charts meet
//! (adjacent faces in one chart share their UVs), and the result is deterministic. Degenerate and
//! non-manifold input get a clear error or the documented fallback.

use retex::engine::control::Control;
use retex::engine::mesh::primitives::{cylinder, grid, icosphere, jitter};
use retex::engine::mesh::Surface;
use retex::engine::uv::{generate, Atlas, AtlasError, AtlasParams};

/// A torus of radii `big`, `small` with `n × m` quads split in two.
pub fn torus(big: f64, small: f64, n: usize, m: usize) -> Surface {
    let mut positions = Vec::new();
    for i in 0..n {
        let a = std::f64::consts::TAU * i as f64 / n as f64;
        for j in 0..m {
            let b = std::f64::consts::TAU * j as f64 / m as f64;
            let r = big + small * b.cos();
            positions.push([
                (r * a.cos()) as f32,
                (r * a.sin()) as f32,
                (small * b.sin()) as f32,
            ]);
        }
    }
    let id = |i: usize, j: usize| ((i % n) * m + (j % m)) as u32;
    let mut faces = Vec::new();
    for i in 0..n {
        for j in 0..m {
            faces.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            faces.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    Surface::from_triangles(positions, faces)
}

/// Two disjoint copies of `s`, the second shifted along x.
fn two_of(s: &Surface, shift: f32) -> Surface {
    let n = s.positions.len() as u32;
    let mut positions = s.positions.clone();
    positions.extend(s.positions.iter().map(|p| [p[0] + shift, p[1], p[2]]));
    let mut faces = s.faces.clone();
    faces.extend(s.faces.iter().map(|f| f.map(|v| v + n)));
    Surface::from_triangles(positions, faces)
}

fn signed_area(q: [[f32; 2]; 3]) -> f64 {
    let q = q.map(|c| c.map(f64::from));
    0.5 * ((q[1][0] - q[0][0]) * (q[2][1] - q[0][1]) - (q[2][0] - q[0][0]) * (q[1][1] - q[0][1]))
}

/// Texels (centres strictly inside) covered by more than one triangle, and texels covered.
pub fn overlaps(tris: &[[[f32; 2]; 3]], size: usize) -> (usize, usize) {
    let mut count = vec![0u8; size * size];
    for t in tris {
        let p = t.map(|c| [f64::from(c[0]) * size as f64, f64::from(c[1]) * size as f64]);
        let lo = |k: usize| {
            p.iter()
                .map(|c| c[k])
                .fold(f64::MAX, f64::min)
                .floor()
                .max(0.0) as usize
        };
        let hi = |k: usize| {
            (p.iter().map(|c| c[k]).fold(f64::MIN, f64::max).ceil() as usize).min(size - 1)
        };
        let area =
            (p[1][0] - p[0][0]) * (p[2][1] - p[0][1]) - (p[2][0] - p[0][0]) * (p[1][1] - p[0][1]);
        if area.abs() < 1e-18 {
            continue;
        }
        for y in lo(1)..=hi(1) {
            for x in lo(0)..=hi(0) {
                let c = [x as f64 + 0.5, y as f64 + 0.5];
                let w = |a: [f64; 2], b: [f64; 2]| {
                    ((b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1])) / area
                };
                let eps = 1e-9;
                if w(p[1], p[2]) > eps && w(p[2], p[0]) > eps && w(p[0], p[1]) > eps {
                    count[y * size + x] = count[y * size + x].saturating_add(1);
                }
            }
        }
    }
    (
        count.iter().filter(|c| **c > 1).count(),
        count.iter().filter(|c| **c > 0).count(),
    )
}

/// Every property of the module doc; returns the atlas.
pub fn check_atlas(name: &str, s: &Surface, params: &AtlasParams) -> Atlas {
    let atlas = generate(s, params, &Control::new()).unwrap_or_else(|e| panic!("{name}: {e}"));
    let r = &atlas.report;
    let tris: Vec<[[f32; 2]; 3]> = (0..s.faces.len()).map(|f| atlas.face_uv(s, f)).collect();
    for (f, t) in tris.iter().enumerate() {
        assert!(
            t.iter().flatten().all(|c| (0.0..=1.0).contains(c)),
            "{name}: face {f} UVs {t:?} outside [0, 1]"
        );
        assert!(
            signed_area(*t) > 0.0,
            "{name}: face {f} is flipped or collapsed: {t:?}"
        );
    }
    assert_eq!(r.flipped, 0, "{name}");
    let (twice, covered) = overlaps(&tris, 1024);
    assert_eq!(
        twice, 0,
        "{name}: {twice} of {covered} texels covered twice"
    );
    for (i, c) in r.charts.iter().enumerate() {
        assert!(
            c.l2_stretch <= params.max_stretch + 1e-9,
            "{name}: chart {i} L2 stretch {} above {}",
            c.l2_stretch,
            params.max_stretch
        );
    }
    // Seams only where charts meet: across every shared edge inside one chart the UVs agree
    // (they come from one vertex table per chart), across charts the faces are in different
    // charts by definition, and every seam edge counted has faces in two charts.
    let mut seam = 0;
    let mut edges = std::collections::HashMap::new();
    for (f, fv) in s.faces.iter().enumerate() {
        for k in 0..3 {
            let key = (fv[k].min(fv[(k + 1) % 3]), fv[k].max(fv[(k + 1) % 3]));
            edges.entry(key).or_insert_with(Vec::new).push(f);
        }
    }
    for ((a, b), fs) in &edges {
        let charts: std::collections::BTreeSet<u32> =
            fs.iter().map(|f| atlas.face_chart[*f]).collect();
        if charts.len() > 1 {
            seam += 1;
            continue;
        }
        let uv_at = |f: usize, v: u32| tris[f][s.faces[f].iter().position(|x| *x == v).unwrap()];
        for f in &fs[1..] {
            assert_eq!(
                uv_at(fs[0], *a),
                uv_at(*f, *a),
                "{name}: crack inside a chart"
            );
            assert_eq!(
                uv_at(fs[0], *b),
                uv_at(*f, *b),
                "{name}: crack inside a chart"
            );
        }
    }
    assert_eq!(seam, r.seam_edges, "{name}: seam edges");
    assert!(
        r.packing_efficiency > 0.2 && r.packing_efficiency <= 1.0,
        "{name}: packing {}",
        r.packing_efficiency
    );
    let again = generate(s, params, &Control::new()).unwrap();
    assert_eq!(again, atlas, "{name}: not deterministic");
    println!(
        "{name}: {} faces, {} charts ({} single), L2 {:.3}, Linf {:.2}, angle {:.3}, density spread {:.2}, packing {:.3}, seams {:.3} ({} edges)",
        s.faces.len(),
        r.chart_count,
        r.single_triangle_charts,
        r.l2_stretch,
        r.linf_stretch,
        r.angle_distortion,
        r.texel_density_spread,
        r.packing_efficiency,
        r.seam_length,
        r.seam_edges
    );
    atlas
}

fn cases() -> Vec<(&'static str, Surface)> {
    let mut jittered = icosphere(1.0, 24);
    jitter(&mut jittered, 0.01, [true, true, true], 7);
    vec![
        ("closed sphere", icosphere(1.0, 24)),
        ("open sheet", grid(40, 30, 0.1)),
        ("torus", torus(1.0, 0.35, 96, 32)),
        ("two spheres", two_of(&icosphere(1.0, 12), 3.0)),
        ("jittered sphere", jittered),
        ("open cylinder", cylinder(0.5, 2.0, 64, 20)),
    ]
}

#[test]
fn atlases_are_valid_on_closed_open_genus_one_and_multi_component_meshes() {
    for (name, s) in cases() {
        check_atlas(name, &s, &AtlasParams::default());
    }
}

#[test]
fn the_stretch_bound_holds_for_a_sweep_of_bounds_and_cone_angles() {
    let s = torus(1.0, 0.35, 64, 24);
    let mut charts = Vec::new();
    for (stretch, cone) in [
        (1.05, 60.0),
        (1.1, 45.0),
        (1.2, 60.0),
        (1.5, 80.0),
        (2.0, 90.0),
    ] {
        let p = AtlasParams {
            max_stretch: stretch,
            max_normal_deviation: cone,
            ..AtlasParams::default()
        };
        let a = check_atlas(&format!("torus bound {stretch} cone {cone}"), &s, &p);
        charts.push(a.report.chart_count);
    }
    // A tighter bound never needs fewer charts than the loosest.
    assert!(charts[0] >= charts[4], "{charts:?}");
}

#[test]
fn a_flat_sheet_is_one_isometric_chart() {
    let s = grid(20, 20, 0.05);
    let a = check_atlas("flat sheet", &s, &AtlasParams::default());
    assert_eq!(a.report.chart_count, 1);
    assert!(
        (a.report.l2_stretch - 1.0).abs() < 1e-3,
        "{}",
        a.report.l2_stretch
    );
    assert!(a.report.texel_density_spread < 1.01);
}

/// A corrugated sheet (z = a sin(kx), slopes up to about 70°) is developable, but its normals
/// turn by more than the growth's 60° cone across each fold, so the growth cuts it into strips.
/// The merge joins them again: one chart, isometric up to LSCM's round-off, fewer seams.
#[test]
fn charts_of_a_developable_sheet_merge_into_one() {
    let mut s = grid(24, 12, 0.05);
    for p in &mut s.positions {
        p[2] = 0.08 * (f64::from(p[0]) * 35.0).sin() as f32;
    }
    let params = AtlasParams::default();
    let adj = retex::engine::uv::charts::adjacency(&s);
    let grown = retex::engine::uv::charts::grow(&adj, params.max_normal_deviation);
    assert!(grown.len() >= 3, "the growth made {} charts", grown.len());
    let a = check_atlas("corrugated sheet", &s, &params);
    assert_eq!(a.report.chart_count, 1, "grown: {}", grown.len());
    assert!(a.report.l2_stretch < 1.01, "{}", a.report.l2_stretch);
}

#[test]
fn degenerate_faces_are_a_clear_error_and_empty_input_too() {
    let mut s = grid(4, 4, 1.0);
    s.faces.push([0, 1, 2]); // collinear: grid row
    let e = generate(&s, &AtlasParams::default(), &Control::new()).unwrap_err();
    assert!(matches!(e, AtlasError::DegenerateFace { .. }), "{e}");
    assert!(e.to_string().contains("degenerate"));
    let empty = Surface::from_triangles(vec![], vec![]);
    assert_eq!(
        generate(&empty, &AtlasParams::default(), &Control::new()).unwrap_err(),
        AtlasError::Empty
    );
}

#[test]
fn non_manifold_edges_and_vertices_become_seams() {
    // Three sheets on one edge (a "book"), and two fans touching at a vertex (a bow tie).
    let positions = vec![
        [0.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [1.0, 0.5, 0.0],
        [-1.0, 0.5, 0.0],
        [0.0, 0.5, 1.0],
        [1.0, 2.0, 0.0],
        [-1.0, 2.0, 0.0],
    ];
    let faces = vec![[0, 2, 1], [0, 1, 3], [0, 1, 4], [1, 2, 5], [1, 6, 3]];
    let s = Surface::from_triangles(positions, faces);
    let a = check_atlas("non-manifold", &s, &AtlasParams::default());
    assert!(a.report.chart_count >= 2);
}

#[test]
fn too_many_charts_for_the_texture_is_a_clear_error() {
    // 9600 single-triangle charts cannot fit 16² texels with an 8-texel gutter.
    let s = icosphere(1.0, 20);
    let p = AtlasParams {
        texture_size: 16,
        gutter: 8,
        ..AtlasParams::default()
    };
    let e = generate(&s, &p, &Control::new()).unwrap_err();
    assert!(matches!(e, AtlasError::DoesNotFit { .. }), "{e}");
}

// ---- `project` onto a UV-less target through the atlas vs onto hand-made UVs ----

mod transfer {
    use crate::common::*;
    use retex::engine::asset::constraints::{Constraints, OutputFormat};
    use retex::engine::asset::edits::{Edit, PrimitiveGeometry, TextureSlot};
    use retex::engine::asset::export::export;
    use retex::engine::asset::{Asset, BlobSet};
    use retex::engine::control::Control;
    use retex::engine::pipeline::{transfer, ModelInput, TransferInput, TransferOutput};
    use serde_json::json;

    const SPOT: &str = "src_spot_keenan/spot_textured_derived.glb";
    const SPOT_REMESHED: &str = "tgt_spot_remeshed_odedstein/spot_derived.glb";

    /// Hand-made box-projection UVs: each triangle goes to the cell (3 × 2 grid) of its normal's
    /// dominant signed axis and is projected onto that axis' plane; vertices split per cell.
    /// Positions, UVs, triangles and the input vertex of each output vertex.
    type Boxed = (Vec<[f32; 3]>, Vec<[f32; 2]>, Vec<[u32; 3]>, Vec<u32>);

    fn box_uvs(prim: &retex::engine::asset::Primitive) -> Boxed {
        let (mut lo, mut hi) = ([f32::MAX; 3], [f32::MIN; 3]);
        for p in &prim.positions {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        let ext = (0..3).map(|k| hi[k] - lo[k]).fold(0.0f32, f32::max);
        let mut index = std::collections::HashMap::new();
        let (mut pos, mut uv, mut tris, mut orig) = (vec![], vec![], vec![], vec![]);
        for t in &prim.triangles {
            let w = t.map(|v| prim.positions[v as usize]);
            let e1 = [0, 1, 2].map(|k| w[1][k] - w[0][k]);
            let e2 = [0, 1, 2].map(|k| w[2][k] - w[0][k]);
            let n = [
                e1[1] * e2[2] - e1[2] * e2[1],
                e1[2] * e2[0] - e1[0] * e2[2],
                e1[0] * e2[1] - e1[1] * e2[0],
            ];
            let axis = (0..3)
                .max_by(|a, b| n[*a].abs().total_cmp(&n[*b].abs()))
                .unwrap();
            let cell = axis * 2 + usize::from(n[axis] < 0.0);
            // Plane axes chosen so that the projected triangle keeps its orientation.
            let (a, b) = match (axis, n[axis] >= 0.0) {
                (0, true) => (1, 2),
                (0, false) => (2, 1),
                (1, true) => (2, 0),
                (1, false) => (0, 2),
                (2, true) => (0, 1),
                _ => (1, 0),
            };
            let mut tri = [0u32; 3];
            for (k, v) in t.iter().enumerate() {
                tri[k] = *index.entry((*v, cell)).or_insert_with(|| {
                    let p = prim.positions[*v as usize];
                    let s = (p[a] - lo[a]) / ext;
                    let r = (p[b] - lo[b]) / ext;
                    let (cx, cy) = ((cell % 3) as f32, (cell / 3) as f32);
                    pos.push(p);
                    uv.push([(cx + 0.05 + 0.9 * s) / 3.0, (cy + 0.05 + 0.9 * r) / 2.0]);
                    orig.push(*v);
                    (pos.len() - 1) as u32
                });
            }
            tris.push(tri);
        }
        (pos, uv, tris, orig)
    }

    /// Two copies of the target: with hand-made UVs (`own`: the asset's; else box UVs) and
    /// without any UVs (same triangles in the same order).
    fn variants(path: &str, own: bool) -> (Vec<u8>, Vec<u8>) {
        let asset = load_path(&test_data(path));
        let mut with = Vec::new();
        let mut without = Vec::new();
        for (p, prim) in asset.primitives.iter().enumerate() {
            let (positions, uv, triangles, orig) = if own {
                let n = prim.positions.len() as u32;
                (
                    prim.positions.clone(),
                    prim.tex_coords[0].clone(),
                    prim.triangles.clone(),
                    (0..n).collect(),
                )
            } else {
                box_uvs(prim)
            };
            let normals = prim
                .normals
                .as_ref()
                .map(|n| orig.iter().map(|v| n[*v as usize]).collect());
            let g = PrimitiveGeometry {
                positions: positions.clone(),
                normals: normals.clone(),
                tex_coords: vec![uv],
                triangles: triangles.clone(),
                ..PrimitiveGeometry::default()
            };
            with.push(Edit::ReplacePrimitive {
                primitive: p,
                geometry: g,
            });
            let g = PrimitiveGeometry {
                positions,
                normals,
                triangles,
                ..PrimitiveGeometry::default()
            };
            without.push(Edit::ReplacePrimitive {
                primitive: p,
                geometry: g,
            });
            if let Some(m) = prim.material {
                if asset.materials[m].base_color_texture.is_some() {
                    without.push(Edit::ClearTexture {
                        material: m,
                        slot: TextureSlot::BaseColor,
                    });
                }
            }
        }
        (
            export(&asset, &with, OutputFormat::Glb).unwrap(),
            export(&asset, &without, OutputFormat::Glb).unwrap(),
        )
    }

    fn run(target: Vec<u8>, size: u32) -> TransferOutput {
        let (src_name, src) = BlobSet::from_path(&test_data(SPOT)).unwrap();
        let mut tgt = BlobSet::new();
        tgt.insert("target.glb", target);
        let c = Constraints::from_json(
            json!({"version": 1, "output": {"texture_size": size, "padding": 4}})
                .to_string()
                .as_bytes(),
        )
        .unwrap();
        let input = TransferInput::pair(
            ModelInput {
                main: &src_name,
                blobs: &src,
            },
            ModelInput {
                main: "target.glb",
                blobs: &tgt,
            },
            c,
        );
        transfer(&input, &Control::new()).unwrap()
    }

    /// Bilinear sRGB colour of primitive `p` triangle `t` at barycentric `b`.
    fn color(asset: &Asset, p: usize, t: usize, b: [f32; 3]) -> [f32; 3] {
        let prim = &asset.primitives[p];
        let tex = asset.materials[prim.material.unwrap()]
            .base_color_texture
            .unwrap();
        let img = asset.images[asset.textures[tex.texture].image.unwrap()]
            .decoded
            .as_ref()
            .unwrap();
        let tri = prim.triangles[t];
        let uv = tex_at(&prim.tex_coords[tex.tex_coord as usize], tri, b);
        let (w, h) = (img.width as f32, img.height as f32);
        let x = (uv[0] * w - 0.5).clamp(0.0, w - 1.0);
        let y = (uv[1] * h - 0.5).clamp(0.0, h - 1.0);
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (x1, y1) = (
            (x0 + 1).min(img.width as usize - 1),
            (y0 + 1).min(img.height as usize - 1),
        );
        let (fx, fy) = (x - x0 as f32, y - y0 as f32);
        let px =
            |x: usize, y: usize, k: usize| f32::from(img.pixels[y * img.width as usize + x][k]);
        [0, 1, 2].map(|k| {
            (px(x0, y0, k) * (1.0 - fx) + px(x1, y0, k) * fx) * (1.0 - fy)
                + (px(x0, y1, k) * (1.0 - fx) + px(x1, y1, k) * fx) * fy
        })
    }

    fn tex_at(uv: &[[f32; 2]], t: [u32; 3], b: [f32; 3]) -> [f32; 2] {
        [0, 1].map(|k| (0..3).map(|j| b[j] * uv[t[j] as usize][k]).sum())
    }

    fn psnr(a: &[[f32; 3]], b: &[[f32; 3]]) -> f64 {
        let mse: f64 = a
            .iter()
            .zip(b)
            .flat_map(|(x, y)| (0..3).map(move |k| f64::from(x[k] - y[k]).powi(2)))
            .sum::<f64>()
            / (3 * a.len()) as f64;
        10.0 * (255.0f64 * 255.0 / mse.max(1e-12)).log10()
    }

    /// Colours of both outputs at the same random surface points (area-weighted triangles).
    fn compare(name: &str, path: &str, own: bool, size: u32) -> (f64, f64) {
        let (with, without) = variants(path, own);
        let out_hand = run(with, size);
        let out_atlas = run(without, size);
        assert_validator_clean(&out_hand.model, &format!("{name}_hand.glb"));
        assert_validator_clean(&out_atlas.model, &format!("{name}_atlas.glb"));
        let report = &out_atlas.report.method_report["atlas"];
        assert!(report.is_object(), "{name}: no atlas report");
        let hand = load_bytes(&out_hand.model, "hand.glb");
        let atlas = load_bytes(&out_atlas.model, "atlas.glb");
        assert!(atlas
            .primitives
            .iter()
            .all(|p| p.tex_coords.len() == 1 && p.colors.is_none()));
        let mut rng = 0x9e3779b97f4a7c15u64;
        let mut next = || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            (rng >> 11) as f64 / (1u64 << 53) as f64
        };
        let (mut a, mut b) = (Vec::new(), Vec::new());
        for (p, prim) in hand.primitives.iter().enumerate() {
            let areas: Vec<f64> = prim
                .triangles
                .iter()
                .map(|t| {
                    let w = t.map(|v| prim.positions[v as usize].map(f64::from));
                    let e1 = [0, 1, 2].map(|k| w[1][k] - w[0][k]);
                    let e2 = [0, 1, 2].map(|k| w[2][k] - w[0][k]);
                    let n = [
                        e1[1] * e2[2] - e1[2] * e2[1],
                        e1[2] * e2[0] - e1[0] * e2[2],
                        e1[0] * e2[1] - e1[1] * e2[0],
                    ];
                    (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt()
                })
                .collect();
            let total: f64 = areas.iter().sum();
            for _ in 0..20_000 {
                let mut r = next() * total;
                let t = areas.iter().position(|x| {
                    r -= x;
                    r <= 0.0
                });
                let t = t.unwrap_or(areas.len() - 1);
                let (mut u, mut v) = (next() as f32, next() as f32);
                if u + v > 1.0 {
                    (u, v) = (1.0 - u, 1.0 - v);
                }
                let bary = [1.0 - u - v, u, v];
                b.push(color(&hand, p, t, bary));
                a.push(color(&atlas, p, t, bary));
            }
        }
        let mean = b
            .iter()
            .fold([0.0f32; 3], |m, c| [m[0] + c[0], m[1] + c[1], m[2] + c[2]])
            .map(|x| x / b.len() as f32);
        let baseline = psnr(&vec![mean; b.len()], &b);
        let got = psnr(&a, &b);
        println!(
            "{name}: atlas vs hand-made UVs {got:.2} dB, one-texel baseline {baseline:.2} dB; atlas {} charts, L2 {:.3}, packing {:.3}",
            report["chart_count"], report["l2_stretch"], report["packing_efficiency"]
        );
        (got, baseline)
    }

    /// Measured (see the README's atlas section): 3 cases, 1024² and 512².
    const MIN_PSNR: f64 = 28.0;

    #[test]
    fn project_through_the_atlas_matches_hand_made_uvs() {
        for (name, path, own, size) in [
            ("spot_own_uvs", SPOT, true, 1024),
            ("spot_box_uvs", SPOT, false, 1024),
            ("spot_remeshed_box_uvs", SPOT_REMESHED, false, 512),
        ] {
            let (got, baseline) = compare(name, path, own, size);
            assert!(got >= MIN_PSNR, "{name}: {got:.2} dB < {MIN_PSNR}");
            assert!(
                got >= baseline + 10.0,
                "{name}: {got:.2} dB vs baseline {baseline:.2}"
            );
        }
    }
}

// ---- Benchmark: `cargo test --release --test engine bench_uv_atlas -- --ignored --nocapture` ----

/// A GLB of a surface without UVs or normals (u32 indices).
pub fn surface_glb(s: &Surface) -> Vec<u8> {
    retex::engine::asset::export::mesh_glb(&s.positions, &s.faces).unwrap()
}

fn write_obj(s: &Surface, path: &std::path::Path) {
    use std::fmt::Write;
    let mut out = String::new();
    for p in &s.positions {
        writeln!(out, "v {} {} {}", p[0], p[1], p[2]).unwrap();
    }
    for f in &s.faces {
        writeln!(out, "f {} {} {}", f[0] + 1, f[1] + 1, f[2] + 1).unwrap();
    }
    std::fs::write(path, out).unwrap();
}

/// Atlas timings (median of 3) on spheres of 10k / 40k / 160k vertices and, when the shared
/// assets are there, on koala, skull (genus 2) and Nefertiti; writes each target as GLB and OBJ
/// under `$RETEX_BENCH_DIR` (default /tmp/retex-atlas-bench) for the CLI and xatlas runs of the
/// README.
#[test]
#[ignore = "benchmark"]
fn bench_uv_atlas() {
    let dir = std::path::PathBuf::from(
        std::env::var("RETEX_BENCH_DIR").unwrap_or_else(|_| "/tmp/retex-atlas-bench".into()),
    );
    std::fs::create_dir_all(&dir).unwrap();
    let mut cases = vec![
        ("sphere_10k".to_string(), icosphere(1.0, 32)),
        ("sphere_40k".to_string(), icosphere(1.0, 63)),
        ("sphere_160k".to_string(), icosphere(1.0, 127)),
    ];
    for (name, rel) in [
        ("koala_50k", "perf_koala_odedstein/koala.obj"),
        ("skull_50k", "perf_skull_odedstein/skull.obj"),
        (
            "nefertiti_35k",
            "tgt_nefertiti_bust_odedstein/nefertiti-lowres.obj",
        ),
    ] {
        let path = crate::common::shared_assets_dir().join(rel);
        if path.exists() {
            cases.push((name.to_string(), crate::common_geometry::read_obj(&path)));
        }
    }
    for (name, s) in &cases {
        std::fs::write(dir.join(format!("{name}.glb")), surface_glb(s)).unwrap();
        write_obj(s, &dir.join(format!("{name}.obj")));
        let mut times = Vec::new();
        let mut last = None;
        for _ in 0..3 {
            let t = std::time::Instant::now();
            let a = generate(s, &AtlasParams::default(), &Control::new());
            times.push(t.elapsed().as_secs_f64() * 1e3);
            last = Some(a);
        }
        times.sort_by(f64::total_cmp);
        match last.unwrap() {
            Ok(a) => {
                let r = &a.report;
                println!(
                    "| {name} | {} | {} | {:.0} ms | {} | {:.3} | {:.2} | {:.3} | {:.2} | {:.3} | {:.1} |",
                    s.positions.len(),
                    s.faces.len(),
                    times[1],
                    r.chart_count,
                    r.l2_stretch,
                    r.linf_stretch,
                    r.angle_distortion,
                    r.texel_density_spread,
                    r.packing_efficiency,
                    r.seam_length / s.diagonal() as f64
                );
            }
            Err(e) => println!(
                "| {name} | {} | {} | error: {e} |",
                s.positions.len(),
                s.faces.len()
            ),
        }
    }
}
