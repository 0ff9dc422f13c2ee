//! The `correlation` method's building blocks owned by helper syn (Mertens et al. 2006): the
//! surface pyramid (§3.1, [`pyramid`]), weighted quantiles and exact quantile transfer (§4, §5.2,
//! [`quantiles`]), and the parametric synthesis with its k-means, feathering and statistics (§5.2,
//! [`parametric`]). Meshes are made in code.
//! `cargo test --release --test engine correlation_synthesis::`

use retex::engine::mesh::primitives::icosphere;
use retex::engine::mesh::Surface;
use retex::engine::rng::SplitMix64;

mod parametric;
mod pyramid;
mod quantiles;

// ---------------------------------------------------------------------------------------------
// Fixtures

/// A standard normal draw (Box-Muller).
pub(super) fn normal(rng: &mut SplitMix64) -> f32 {
    let u1 = rng.unit_f64().max(1e-12);
    let u2 = rng.unit_f64();
    ((-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()) as f32
}

/// A sphere of radius 1 with radial bumps of relative height `bump` and angular frequency `freq`.
pub(super) fn bumpy_sphere(bump: f32, freq: f32) -> Surface {
    let mut s = icosphere(1.0, 12);
    for p in &mut s.positions {
        let r = 1.0 + bump * (freq * p[0]).sin() * (freq * p[1]).sin() * (freq * p[2]).cos();
        *p = p.map(|c| c * r);
    }
    s
}

/// A torus (major radius 1, minor 0.35) with bumps, `nu × nv` quads.
pub(super) fn bumpy_torus(nu: usize, nv: usize, bump: f32) -> Surface {
    let mut pos = Vec::with_capacity(nu * nv);
    for i in 0..nu {
        for j in 0..nv {
            let (u, v) = (
                std::f32::consts::TAU * i as f32 / nu as f32,
                std::f32::consts::TAU * j as f32 / nv as f32,
            );
            let r = 0.35 * (1.0 + bump * (5.0 * u).sin() * (3.0 * v).cos());
            pos.push([
                (1.0 + r * v.cos()) * u.cos(),
                (1.0 + r * v.cos()) * u.sin(),
                r * v.sin(),
            ]);
        }
    }
    let id = |i: usize, j: usize| ((i % nu) * nv + (j % nv)) as u32;
    let mut faces = Vec::with_capacity(2 * nu * nv);
    for i in 0..nu {
        for j in 0..nv {
            faces.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            faces.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    Surface::from_triangles(pos, faces)
}

pub(super) fn shapes() -> Vec<(&'static str, Surface)> {
    vec![
        ("sphere", icosphere(1.0, 10)),
        ("bumpy sphere", bumpy_sphere(0.15, 4.0)),
        ("bumpy torus", bumpy_torus(48, 16, 0.3)),
    ]
}

pub(super) fn percentile(mut v: Vec<f32>, p: f32) -> f32 {
    v.sort_by(f32::total_cmp);
    v[((v.len() - 1) as f32 * p).round() as usize]
}
