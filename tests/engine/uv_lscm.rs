//! LSCM as the atlas solves it (`retex::engine::uv::param::lscm`: a nested-dissection order and
//! no u–v terms on interior edges, which cancel) against what it must equal: on a flat chart the
//! planar layout itself up to a similarity (the conformal energy is zero there), and on curved
//! charts the minimiser of the full least-squares system of Lévy et al. 2002 eq. 3, assembled
//! here independently with every u–v term and solved densely. Charts are large enough to be
//! dissected at several levels (the dissection keeps parts of at most 64 vertices whole).

use retex::engine::mesh::Surface;
use retex::engine::uv::param::{chart_vertices, lscm};

/// A disc of `rings × segments` plus a centre vertex, mapped by `place(ρ, θ)`, ρ in [0, 1], the
/// inner rings' radii and every angle moved by up to `±amplitude / 2` of their spacing
/// (deterministic; 0 gives the regular disc). Shared with `uv_arap`.
pub(crate) fn disc(
    rings: usize,
    segments: usize,
    amplitude: f64,
    place: impl Fn(f64, f64) -> [f64; 3],
) -> Surface {
    let mut positions = vec![place(0.0, 0.0).map(|c| c as f32)];
    let mut seed = 12_345u64;
    let mut jitter = || {
        seed = seed
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        ((seed >> 33) as f64 / (1u64 << 31) as f64) - 0.5
    };
    for i in 1..=rings {
        for j in 0..segments {
            let rho =
                (i as f64 + amplitude * jitter() * f64::from(u8::from(i < rings))) / rings as f64;
            let theta = std::f64::consts::TAU * (j as f64 + amplitude * jitter()) / segments as f64;
            positions.push(place(rho, theta).map(|c| c as f32));
        }
    }
    let id = |i: usize, j: usize| (1 + (i - 1) * segments + j % segments) as u32;
    let mut faces = Vec::new();
    for j in 0..segments {
        faces.push([0, id(1, j), id(1, j + 1)]);
    }
    for i in 1..rings {
        for j in 0..segments {
            faces.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            faces.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    Surface::from_triangles(positions, faces)
}

/// Largest distance between `a` and the best similarity image of `b` (complex least squares:
/// a ≈ s·b + t with s, t complex), relative to `a`'s extent.
fn similarity_residual(a: &[[f64; 2]], b: &[[f64; 2]]) -> f64 {
    let n = a.len() as f64;
    let ma = a
        .iter()
        .fold([0.0; 2], |m, p| [m[0] + p[0] / n, m[1] + p[1] / n]);
    let mb = b
        .iter()
        .fold([0.0; 2], |m, p| [m[0] + p[0] / n, m[1] + p[1] / n]);
    let (mut re, mut im, mut nb) = (0.0, 0.0, 0.0);
    for (p, q) in a.iter().zip(b) {
        let (x, y) = (p[0] - ma[0], p[1] - ma[1]);
        let (u, v) = (q[0] - mb[0], q[1] - mb[1]);
        // Σ (x + iy)·conj(u + iv)
        re += x * u + y * v;
        im += y * u - x * v;
        nb += u * u + v * v;
    }
    let (sr, si) = (re / nb, im / nb);
    let extent = a
        .iter()
        .map(|p| ((p[0] - ma[0]).powi(2) + (p[1] - ma[1]).powi(2)).sqrt())
        .fold(0.0f64, f64::max);
    a.iter()
        .zip(b)
        .map(|(p, q)| {
            let (u, v) = (q[0] - mb[0], q[1] - mb[1]);
            let fit = [ma[0] + sr * u - si * v, ma[1] + si * u + sr * v];
            ((p[0] - fit[0]).powi(2) + (p[1] - fit[1]).powi(2)).sqrt()
        })
        .fold(0.0f64, f64::max)
        / extent
}

/// The pins `lscm` documents: the vertex farthest from the first, the one farthest from that
/// (ties to the lower index), and their distance.
fn pins(s: &Surface) -> (usize, usize, f64) {
    let dist = |a: usize, b: usize| {
        let (p, q) = (s.positions[a], s.positions[b]);
        (0..3)
            .map(|k| (f64::from(p[k]) - f64::from(q[k])).powi(2))
            .sum::<f64>()
    };
    let far = |from: usize| {
        (0..s.positions.len()).fold(0, |best, i| {
            if dist(i, from) > dist(best, from) {
                i
            } else {
                best
            }
        })
    };
    let a = far(0);
    let b = far(a);
    (a, b, dist(a, b).sqrt())
}

/// The full LSCM system (Lévy et al. 2002 eq. 3: per triangle, in its own plane, the residual
/// `∇v − rot90(∇u)` weighted by √area), every u–v term kept, with `lscm`'s pins at (0, 0) and
/// (d, 0), solved by a dense Cholesky factorisation written here. (On a curved chart the
/// minimiser depends on the pins beyond a similarity, so they must be the same.)
fn dense_reference(s: &Surface) -> Vec<[f64; 2]> {
    let n = s.positions.len();
    let (pa, pb, d) = pins(s);
    let free: Vec<Option<usize>> = (0..2 * n)
        .scan(0usize, |next, k| {
            let v = k / 2;
            Some(if v == pa || v == pb {
                None
            } else {
                *next += 1;
                Some(*next - 1)
            })
        })
        .collect();
    let fixed = move |k: usize| -> f64 {
        if k == 2 * pb {
            d
        } else {
            0.0
        }
    };
    let m = 2 * n - 4;
    let mut a = vec![0.0f64; m * m];
    let mut rhs = vec![0.0f64; m];
    for f in &s.faces {
        let p = f.map(|v| s.positions[v as usize].map(f64::from));
        let e1 = [p[1][0] - p[0][0], p[1][1] - p[0][1], p[1][2] - p[0][2]];
        let e2 = [p[2][0] - p[0][0], p[2][1] - p[0][1], p[2][2] - p[0][2]];
        let l1 = (e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2]).sqrt();
        let x = e1.map(|c| c / l1);
        let nrm = [
            e1[1] * e2[2] - e1[2] * e2[1],
            e1[2] * e2[0] - e1[0] * e2[2],
            e1[0] * e2[1] - e1[1] * e2[0],
        ];
        let area = 0.5 * (nrm[0] * nrm[0] + nrm[1] * nrm[1] + nrm[2] * nrm[2]).sqrt();
        let y0 = [
            nrm[1] * x[2] - nrm[2] * x[1],
            nrm[2] * x[0] - nrm[0] * x[2],
            nrm[0] * x[1] - nrm[1] * x[0],
        ];
        let ly = (y0[0] * y0[0] + y0[1] * y0[1] + y0[2] * y0[2]).sqrt();
        let q = [
            [0.0, 0.0],
            [l1, 0.0],
            [
                e2[0] * x[0] + e2[1] * x[1] + e2[2] * x[2],
                (e2[0] * y0[0] + e2[1] * y0[1] + e2[2] * y0[2]) / ly,
            ],
        ];
        // ∇φ_j = rot90(q_{j+2} − q_{j+1}) / (2A), rot90(x, y) = (−y, x).
        let g: Vec<[f64; 2]> = (0..3)
            .map(|j| {
                let (b, c) = (q[(j + 1) % 3], q[(j + 2) % 3]);
                [-(c[1] - b[1]) / (2.0 * area), (c[0] - b[0]) / (2.0 * area)]
            })
            .collect();
        let w = area.sqrt();
        for c in 0..2 {
            let mut row = Vec::new();
            for j in 0..3 {
                let v = f[j] as usize;
                let rot = if c == 0 { -g[j][1] } else { g[j][0] };
                row.push((2 * v, -rot * w));
                row.push((2 * v + 1, g[j][c] * w));
            }
            let b: f64 = row
                .iter()
                .filter(|(k, _)| free[*k].is_none())
                .map(|(k, coef)| -coef * fixed(*k))
                .sum();
            for (i, ci) in &row {
                let Some(fi) = free[*i] else { continue };
                rhs[fi] += ci * b;
                for (j, cj) in &row {
                    if let Some(fj) = free[*j] {
                        a[fi * m + fj] += ci * cj;
                    }
                }
            }
        }
    }
    // Dense Cholesky A = L Lᵀ in place (lower triangle), then two triangular solves.
    for j in 0..m {
        let mut d = a[j * m + j];
        for k in 0..j {
            d -= a[j * m + k] * a[j * m + k];
        }
        assert!(d > 0.0, "reference system not positive definite");
        let d = d.sqrt();
        a[j * m + j] = d;
        for i in j + 1..m {
            let mut s = a[i * m + j];
            for k in 0..j {
                s -= a[i * m + k] * a[j * m + k];
            }
            a[i * m + j] = s / d;
        }
    }
    let mut y = rhs;
    for i in 0..m {
        for k in 0..i {
            y[i] -= a[i * m + k] * y[k];
        }
        y[i] /= a[i * m + i];
    }
    for i in (0..m).rev() {
        for k in i + 1..m {
            y[i] -= a[k * m + i] * y[k];
        }
        y[i] /= a[i * m + i];
    }
    (0..n)
        .map(|v| {
            let value = |k: usize| free[k].map_or_else(|| fixed(k), |f| y[f]);
            [value(2 * v), value(2 * v + 1)]
        })
        .collect()
}

/// A map from the disc's polar coordinates into 3-D.
type Placement = Box<dyn Fn(f64, f64) -> [f64; 3]>;

fn solve(s: &Surface) -> Vec<[f64; 2]> {
    let faces: Vec<u32> = (0..s.faces.len() as u32).collect();
    let vertices = chart_vertices(s, &faces);
    assert_eq!(vertices.len(), s.positions.len());
    lscm(s, &faces, &vertices).expect("LSCM solves")
}

#[test]
fn a_flat_chart_comes_back_as_its_own_layout_up_to_a_similarity() {
    // A tilted plane in 3-D, 40 rings × 90 segments: 3,601 vertices, 7,110 faces.
    let (u, v) = ([0.6f64, 0.0, 0.8], [0.0f64, 1.0, 0.0]);
    let s = disc(40, 90, 0.3, |rho, theta| {
        let (a, b) = (2.0 * rho * theta.cos(), 1.3 * rho * theta.sin());
        [
            a * u[0] + b * v[0],
            a * u[1] + b * v[1] + 5.0,
            a * u[2] + b * v[2],
        ]
    });
    let planar: Vec<[f64; 2]> = s
        .positions
        .iter()
        .map(|p| {
            let p = p.map(f64::from);
            [
                p[0] * u[0] + p[1] * u[1] + p[2] * u[2],
                p[0] * v[0] + (p[1] - 5.0) * v[1] + p[2] * v[2],
            ]
        })
        .collect();
    let residual = similarity_residual(&planar, &solve(&s));
    assert!(
        residual < 1e-5,
        "flat chart off a similarity by {residual:.2e} of its size"
    );
}

#[test]
fn curved_charts_match_the_full_system_with_every_u_v_term() {
    let cases: [(&str, Placement); 3] = [
        (
            "cap 70°",
            Box::new(|rho: f64, theta: f64| {
                let phi = 70f64.to_radians() * rho;
                [phi.sin() * theta.cos(), phi.sin() * theta.sin(), phi.cos()]
            }),
        ),
        (
            "saddle",
            Box::new(|rho: f64, theta: f64| {
                let (x, y) = (rho * theta.cos(), 0.7 * rho * theta.sin());
                [x, y, 0.6 * (x * x - y * y)]
            }),
        ),
        (
            "cone",
            Box::new(|rho: f64, theta: f64| {
                [rho * theta.cos(), rho * theta.sin(), 0.8 * (1.0 - rho)]
            }),
        ),
    ];
    for (name, place) in cases {
        // 12 rings × 30 segments: 361 vertices (718 unknowns), dissected at several levels.
        let s = disc(12, 30, 0.3, place);
        let reference = dense_reference(&s);
        let ours = solve(&s);
        let extent = reference
            .iter()
            .map(|p| p[0].hypot(p[1]))
            .fold(0.0f64, f64::max);
        let residual = reference
            .iter()
            .zip(&ours)
            .map(|(p, q)| (p[0] - q[0]).hypot(p[1] - q[1]))
            .fold(0.0f64, f64::max)
            / extent;
        assert!(
            residual < 1e-6,
            "{name}: off the full system by {residual:.2e} of its size"
        );
        // And the comparison can fail: the planar layout of the cap is no similarity of it.
        let flat: Vec<[f64; 2]> = s
            .positions
            .iter()
            .map(|p| [f64::from(p[0]), f64::from(p[1])])
            .collect();
        let naive = similarity_residual(&reference, &flat);
        assert!(
            naive > 1e-3,
            "{name}: the test cannot tell layouts apart ({naive:.2e})"
        );
    }
}
