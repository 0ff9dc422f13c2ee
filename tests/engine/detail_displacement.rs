//! The `detail` method's displacement map (Berkiten et al. 2017, Fig. 4): on a base sphere with
//! a known analytic bump field on the detailed sphere, the recovered signed displacement matches
//! the field; a base smoothed from the detailed surface keeps the bumps in the displacement.

use retex::engine::math::to_f64;
use retex::engine::mesh::primitives::icosphere;
use retex::engine::mesh::Surface;
use retex::engine::methods::detail::displacement::{
    displacement, smooth_base, BaseParams, DisplacementError, DisplacementParams,
};

/// The bump field on the unit sphere: amplitude `a`, wavelength about 2π/k around the sphere.
fn bumps(p: [f64; 3], a: f64, k: f64) -> f64 {
    a * (k * p[0]).sin() * (k * p[1]).sin() * (k * p[2] + 0.3).sin()
}

/// The unit sphere displaced radially by the bump field.
fn bumpy_sphere(frequency: usize, a: f64, k: f64) -> Surface {
    let mut s = icosphere(1.0, frequency);
    for p in &mut s.positions {
        let q = to_f64(*p);
        let r = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt();
        let u = q.map(|x| x / r);
        let h = 1.0 + bumps(u, a, k);
        *p = u.map(|x| (x * h) as f32);
    }
    s
}

fn rms(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x * x, n + 1));
    (s / n as f64).sqrt()
}

#[test]
fn recovers_an_analytic_bump_field_on_a_sphere() {
    for (a, k, sign) in [(0.03, 6.0, 1.0), (0.02, 9.0, 1.0), (0.03, 6.0, -1.0)] {
        let base = icosphere(1.0, 20);
        let detailed = bumpy_sphere(80, sign * a, k);
        let d = displacement(&base, &detailed, &DisplacementParams::default()).unwrap();
        assert_eq!(d.missing, 0);
        let truth: Vec<f64> = base
            .positions
            .iter()
            .map(|p| {
                let q = to_f64(*p);
                let r = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt();
                bumps(q.map(|x| x / r), sign * a, k)
            })
            .collect();
        let err = rms(d.values.iter().zip(&truth).map(|(x, y)| x - y));
        let max = d
            .values
            .iter()
            .zip(&truth)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f64::max);
        // Baseline: the constant 0 (no detail) has the field's RMS as its error.
        let base_err = rms(truth.iter().copied());
        println!(
            "a {a} k {k} sign {sign}: rms err {err:.2e} max {max:.2e} (zero baseline {base_err:.2e})"
        );
        // The detailed sphere is a polyhedron of edge ≈ 0.04: its chord error (≈ 2e-4) and the
        // bumps' curvature between its vertices bound the error; stated tolerance 5 % of the
        // amplitude RMS, 15 % max.
        assert!(err < 0.05 * a, "rms error {err}");
        assert!(max < 0.15 * a, "max error {max}");
        assert!(err < 0.1 * base_err);
    }
}

#[test]
fn smoothed_base_keeps_the_bumps_in_the_displacement() {
    let (a, k) = (0.03, 9.0);
    let detailed = bumpy_sphere(48, a, k);
    // σ = 0.25 on bumps of wavelength 2π/9 ≈ 0.7 keeps exp(−2π²σ²/λ²) ≈ 8 % of them.
    let params = BaseParams {
        sigma: Some(0.25),
        ..Default::default()
    };
    let base = smooth_base(&detailed, &params).unwrap();
    // The base is smooth: its radial deviation is a fraction of the bumps'.
    let radial = |s: &Surface| {
        rms(s.positions.iter().map(|p| {
            let q = to_f64(*p);
            (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt() - 1.0
        }))
    };
    let (rd, rb) = (radial(&detailed), radial(&base));
    println!("radial rms: detailed {rd:.4}, base {rb:.4}");
    assert!(rb < 0.35 * rd, "base not smooth: {rb} vs {rd}");
    let d = displacement(&base, &detailed, &DisplacementParams::default()).unwrap();
    assert_eq!(d.missing, 0);
    // Displacement + base radius reproduces the detailed radius (the base's own deviation is
    // put back), and correlates with the bump field.
    let truth: Vec<f64> = detailed
        .positions
        .iter()
        .map(|p| {
            let q = to_f64(*p);
            let r = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt();
            bumps(q.map(|x| x / r), a, k)
        })
        .collect();
    let n = truth.len() as f64;
    let (mx, my) = (
        d.values.iter().sum::<f64>() / n,
        truth.iter().sum::<f64>() / n,
    );
    let cov: f64 = d
        .values
        .iter()
        .zip(&truth)
        .map(|(x, y)| (x - mx) * (y - my))
        .sum();
    let vx: f64 = d.values.iter().map(|x| (x - mx).powi(2)).sum();
    let vy: f64 = truth.iter().map(|y| (y - my).powi(2)).sum();
    let corr = cov / (vx * vy).sqrt();
    println!("correlation with the field {corr:.3}, mean displacement {mx:.2e}");
    assert!(corr > 0.9);
    // Volume preservation: no constant offset of the order of the bumps.
    assert!(mx.abs() < 0.1 * a, "mean displacement {mx}");
}

#[test]
fn missing_hits_and_bad_input() {
    let base = icosphere(1.0, 8);
    let far = icosphere(2.0, 8);
    let d = displacement(
        &base,
        &far,
        &DisplacementParams {
            max_distance: Some(0.5),
        },
    )
    .unwrap();
    assert_eq!(d.missing, base.positions.len());
    assert!(d.values.iter().all(|&v| v == 0.0));
    let d = displacement(
        &base,
        &far,
        &DisplacementParams {
            max_distance: Some(1.5),
        },
    )
    .unwrap();
    assert_eq!(d.missing, 0);
    let mean = d.values.iter().sum::<f64>() / d.values.len() as f64;
    assert!((mean - 1.0).abs() < 0.02, "mean {mean}");
    let empty = Surface::from_triangles(vec![], vec![]);
    assert!(matches!(
        displacement(&empty, &far, &DisplacementParams::default()),
        Err(DisplacementError::Empty(_))
    ));
    assert!(matches!(
        displacement(
            &base,
            &far,
            &DisplacementParams {
                max_distance: Some(-1.0)
            }
        ),
        Err(DisplacementError::Param(_))
    ));
    assert!(smooth_base(&empty, &BaseParams::default()).is_err());
}
