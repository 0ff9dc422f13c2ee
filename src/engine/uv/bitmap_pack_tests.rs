//! Tests of [`super`]: irregular charts (L-shapes, annuli, thin diagonal strips, C-shaped arcs)
//! packed without overlap and tighter than their boxes; covers conservative in every turn.
use super::super::pack::{pack, pack_boxes};
use super::*;
use crate::engine::rng::SplitMix64;

/// Points and counter-clockwise triangles of a chart, moved so that its box starts at 0.
type Mesh = (Vec<[f64; 2]>, Vec<[u32; 3]>);

fn quads(rows: usize, cols: usize, at: impl Fn(usize, usize) -> [f64; 2]) -> Mesh {
    let points = (0..=rows)
        .flat_map(|j| (0..=cols).map(move |i| (i, j)))
        .map(|(i, j)| at(i, j))
        .collect();
    let id = |i: usize, j: usize| (j * (cols + 1) + i) as u32;
    let mut triangles = Vec::new();
    for j in 0..rows {
        for i in 0..cols {
            triangles.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            triangles.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    (points, triangles)
}

/// An L (two arms of a 6 × 6 grid, `t` cells thick), an annulus, a thin diagonal strip or a
/// C-shaped arc, `size` across.
fn shape(kind: u64, size: f64, rng: &mut SplitMix64) -> Mesh {
    let mut mesh = match kind {
        0 => {
            let t = 1 + rng.below(3) as usize;
            let (points, tris) = quads(6, 6, |i, j| [i as f64, j as f64]);
            let keep = |t3: &[u32; 3]| {
                let c = t3.map(|v| points[v as usize]);
                let (x, y) = (
                    (c[0][0] + c[1][0] + c[2][0]) / 3.0,
                    (c[0][1] + c[1][1] + c[2][1]) / 3.0,
                );
                x < t as f64 || y < t as f64
            };
            let tris = tris.into_iter().filter(keep).collect();
            (points, tris)
        }
        1 | 3 => {
            let inner = 0.4 + 0.4 * rng.unit_f64();
            let sweep = if kind == 1 {
                std::f64::consts::TAU
            } else {
                4.0
            };
            let n = 32;
            let mut m = quads(1, n, |i, j| {
                let a = sweep * i as f64 / n as f64;
                let r = if j == 0 { inner } else { 1.0 };
                [r * a.cos(), r * a.sin()]
            });
            if kind == 1 {
                // Close the ring: the last column is the first.
                for t in &mut m.1 {
                    for v in t.iter_mut() {
                        if *v as usize % (n + 1) == n {
                            *v -= n as u32;
                        }
                    }
                }
            }
            m
        }
        _ => {
            let width = 0.03 + 0.05 * rng.unit_f64();
            quads(1, 12, |i, j| {
                let t = i as f64 / 12.0;
                let off = (j as f64 - 0.5) * width;
                [t - off, t + off]
            })
        }
    };
    for t in &mut mesh.1 {
        let c = t.map(|v| mesh.0[v as usize]);
        if (c[1][0] - c[0][0]) * (c[2][1] - c[0][1]) < (c[2][0] - c[0][0]) * (c[1][1] - c[0][1]) {
            t.swap(1, 2);
        }
    }
    let lo = mesh
        .0
        .iter()
        .fold([f64::MAX; 2], |m, p| [m[0].min(p[0]), m[1].min(p[1])]);
    let hi = mesh
        .0
        .iter()
        .fold([f64::MIN; 2], |m, p| [m[0].max(p[0]), m[1].max(p[1])]);
    let s = size / (hi[0] - lo[0]).max(hi[1] - lo[1]);
    for p in &mut mesh.0 {
        *p = [(p[0] - lo[0]) * s, (p[1] - lo[1]) * s];
    }
    mesh
}

fn charts(seed: u64, n: usize) -> Vec<Mesh> {
    let mut rng = SplitMix64::new(seed);
    (0..n)
        .map(|i| {
            let size = 0.2 + 0.8 * rng.unit_f64();
            shape(i as u64 % 4, size, &mut rng)
        })
        .collect()
}

fn outlines(meshes: &[Mesh]) -> Vec<Outline<'_>> {
    meshes
        .iter()
        .map(|(points, triangles)| Outline {
            points,
            triangles: triangles.clone(),
            size: points
                .iter()
                .fold([0.0f64; 2], |m, p| [m[0].max(p[0]), m[1].max(p[1])]),
        })
        .collect()
}

/// Texels whose centre lies within `d` of two charts' triangles (placed), and whether every
/// placed triangle is inside the texture with positive area.
fn conflicts(charts: &[Outline], places: &[Placement], scale: f64, size: usize, d: f64) -> usize {
    let mut owner = vec![u32::MAX; size * size];
    let mut conflicts = 0;
    for (c, (chart, place)) in charts.iter().zip(places).enumerate() {
        for t in &chart.triangles {
            let p = t.map(|v| place.apply(chart.points[v as usize], scale));
            let cross = |a: [f64; 2], b: [f64; 2], q: [f64; 2]| {
                (b[0] - a[0]) * (q[1] - a[1]) - (q[0] - a[0]) * (b[1] - a[1])
            };
            assert!(cross(p[0], p[1], p[2]) > 0.0, "a turn flipped a triangle");
            for q in p {
                assert!((0.0..=size as f64).contains(&q[0]) && (0.0..=size as f64).contains(&q[1]));
            }
            let seg = |a: [f64; 2], b: [f64; 2], q: [f64; 2]| {
                let e = [b[0] - a[0], b[1] - a[1]];
                let u = (((q[0] - a[0]) * e[0] + (q[1] - a[1]) * e[1])
                    / (e[0] * e[0] + e[1] * e[1]))
                    .clamp(0.0, 1.0);
                ((a[0] + u * e[0] - q[0]).powi(2) + (a[1] + u * e[1] - q[1]).powi(2)).sqrt()
            };
            let lo = |k: usize| {
                (p.iter().map(|q| q[k]).fold(f64::MAX, f64::min) - d)
                    .floor()
                    .max(0.0) as usize
            };
            let hi = |k: usize| {
                ((p.iter().map(|q| q[k]).fold(f64::MIN, f64::max) + d).ceil() as usize)
                    .min(size - 1)
            };
            for y in lo(1)..=hi(1) {
                for x in lo(0)..=hi(0) {
                    let q = [x as f64 + 0.5, y as f64 + 0.5];
                    let inside = (0..3).all(|k| cross(p[k], p[(k + 1) % 3], q) >= 0.0);
                    let near = inside || (0..3).any(|k| seg(p[k], p[(k + 1) % 3], q) <= d);
                    let o = &mut owner[y * size + x];
                    if near {
                        if *o != u32::MAX && *o != c as u32 {
                            conflicts += 1;
                        }
                        *o = c as u32;
                    }
                }
            }
        }
    }
    conflicts
}

/// L-shapes, annuli, thin diagonal strips and C-shaped arcs (60 charts, sizes over a factor
/// of 5): no texel centre within half the gutter of two charts, every chart inside the
/// texture and unflipped, the same result twice, and a packing efficiency well above the
/// skyline packing of the same charts' boxes.
#[test]
fn outlines_of_irregular_charts_pack_without_overlap_and_tighter_than_boxes() {
    for (seed, texture, gutter) in [
        (1u64, 1024u32, 4u32),
        (2, 1024, 2),
        (3, 2048, 4),
        (4, 2048, 8),
    ] {
        let meshes = charts(seed, 60);
        let charts = outlines(&meshes);
        let area: f64 = charts.iter().map(Outline::area).sum();
        let sizes: Vec<[f64; 2]> = charts.iter().map(|c| c.size).collect();
        let efficiency = |s: f64| s * s * area / f64::from(texture).powi(2);
        let (box_scale, _) = pack_boxes(&sizes, texture, gutter).expect("boxes fit");
        let (scale, places) = pack(&charts, texture, gutter).expect("fits");
        let (e_box, e) = (efficiency(box_scale), efficiency(scale));
        println!("seed {seed}, {texture}², gutter {gutter}: boxes {e_box:.3}, outlines {e:.3}");
        assert!(
            e > 1.25 * e_box,
            "seed {seed}: outlines {e:.3} vs boxes {e_box:.3}"
        );
        assert_eq!(
            pack(&charts, texture, gutter),
            Some((scale, places.clone()))
        );
        let n = conflicts(
            &charts,
            &places,
            scale,
            texture as usize,
            0.5 * f64::from(gutter),
        );
        assert_eq!(
            n, 0,
            "seed {seed}: {n} texels within half the gutter of two charts"
        );
    }
}

/// A chart's cover contains every cell within `r` of its triangles: sampled points of each
/// triangle, moved by up to `r` in the max norm, fall in covered cells, for every turn.
#[test]
fn covers_are_conservative_in_every_turn() {
    let meshes = charts(9, 12);
    let charts = outlines(&meshes);
    let (scale, cell, r) = (97.3, 4.0, 2.5);
    for chart in &charts {
        let cover = Cover::new(&boundary(chart), scale, cell, r);
        for (k, (shape, shift)) in cover.shapes.iter().enumerate() {
            let place = Placement {
                offset: *shift,
                quarter: k as u8,
            };
            for t in &chart.triangles {
                let p = t.map(|v| place.apply(chart.points[v as usize], scale));
                for (u, v) in [(0.2, 0.3), (1.0, 0.0), (0.0, 1.0), (0.0, 0.0), (0.5, 0.5)] {
                    let q =
                        [0, 1].map(|i| p[0][i] + u * (p[1][i] - p[0][i]) + v * (p[2][i] - p[0][i]));
                    // Just inside the distance (cells at exactly `r` may be left out).
                    let e = r - 1e-6;
                    for d in [[-e, -e], [e, e], [-e, e], [e, -e], [0.0, e]] {
                        let (x, y) = (
                            ((q[0] + d[0]) / cell).floor() as usize,
                            ((q[1] + d[1]) / cell).floor() as usize,
                        );
                        let covered =
                            y < shape.h && shape.row(y).iter().any(|(a, b)| (*a..*b).contains(&x));
                        assert!(
                            covered,
                            "turn {k}: cell ({x}, {y}) of a chart point not covered"
                        );
                    }
                }
            }
        }
    }
}
