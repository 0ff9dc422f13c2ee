//! The `detail` method's detail features (Berkiten et al. 2017, §3.2.1): a steerable pyramid's
//! 17 sub-band standard deviations. An oriented sinusoid puts its energy in the band of its own
//! orientation and scale; the masks tile the spectrum (energy is conserved).

use retex::engine::methods::detail::steerable::{
    SteerableError, SteerablePyramid, FEATURES, ORIENTATIONS, SCALES,
};

fn sinusoid(n: usize, cx: f64, cy: f64) -> Vec<f64> {
    (0..n * n)
        .map(|i| {
            let (x, y) = ((i % n) as f64, (i / n) as f64);
            (std::f64::consts::TAU * (cx * x + cy * y) / n as f64 + 0.4).sin()
        })
        .collect()
}

#[test]
fn oriented_sinusoid_lands_in_its_band() {
    let n = 64;
    let p = SteerablePyramid::new(n).unwrap();
    for s in 0..SCALES {
        // Band s peaks at ρ = 2^-(s+1) of Nyquist: n/2 · 2^-(s+1) cycles per grid.
        let c = (n as f64 / 2.0) / 2f64.powi(s as i32 + 1);
        for k in 0..ORIENTATIONS {
            // Integer cycles along both axes (periodic grid) at angle πk/4.
            let (cx, cy) = match k {
                0 => (c, 0.0),
                1 => ((c / 2f64.sqrt()).round(), (c / 2f64.sqrt()).round()),
                2 => (0.0, c),
                _ => (-(c / 2f64.sqrt()).round(), (c / 2f64.sqrt()).round()),
            };
            let dev = p.band_deviations(&sinusoid(n, cx, cy)).unwrap();
            let energy: Vec<f64> = dev.iter().map(|d| d * d).collect();
            let total: f64 = energy.iter().sum();
            let want = s * ORIENTATIONS + k;
            let best = (0..FEATURES)
                .max_by(|&a, &b| energy[a].total_cmp(&energy[b]))
                .unwrap();
            println!(
                "scale {s} orientation {k} ({cx}, {cy}): band {best}, share {:.3}",
                energy[want] / total
            );
            assert_eq!(best, want, "energy in band {best}, expected {want}");
            assert!(energy[want] > 0.5 * total);
        }
    }
    // The high-pass residual takes a wave near Nyquist.
    let dev = p.band_deviations(&sinusoid(n, 30.0, 0.0)).unwrap();
    let energy: Vec<f64> = dev.iter().map(|d| d * d).collect();
    let best = (0..FEATURES)
        .max_by(|&a, &b| energy[a].total_cmp(&energy[b]))
        .unwrap();
    assert_eq!(best, FEATURES - 1);
}

#[test]
fn masks_tile_the_spectrum() {
    // Σ bands² + low-pass² = 1 per frequency, so for white noise the band energies plus the
    // low-pass part sum to the signal energy; check that the 17 bands take all but the low part.
    let n = 32;
    let p = SteerablePyramid::new(n).unwrap();
    let mut state = 12345u64;
    let grid: Vec<f64> = (0..n * n)
        .map(|_| {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 11) as f64 / (1u64 << 53) as f64) - 0.5
        })
        .collect();
    let mean = grid.iter().sum::<f64>() / grid.len() as f64;
    let var = grid.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / grid.len() as f64;
    let bands = p.bands(&grid).unwrap();
    let band_energy: f64 = bands
        .iter()
        .map(|b| b.iter().map(|x| x * x).sum::<f64>() / b.len() as f64)
        .sum();
    // The low-pass residual below ρ = 1/32 holds a few DFT bins out of n²: under 2 %.
    println!("band energy / variance = {:.4}", band_energy / var);
    assert!(band_energy / var > 0.97 && band_energy / var < 1.0 + 1e-9);
}

#[test]
fn bad_grids_are_errors() {
    assert!(matches!(
        SteerablePyramid::new(4),
        Err(SteerableError::Shape { .. })
    ));
    let p = SteerablePyramid::new(16).unwrap();
    assert!(matches!(
        p.band_deviations(&[0.0; 10]),
        Err(SteerableError::Shape { .. })
    ));
    let mut g = vec![0.0; 256];
    g[3] = f64::NAN;
    assert_eq!(p.band_deviations(&g), Err(SteerableError::NonFinite(3)));
    // A constant grid has no band energy.
    let d = p.band_deviations(&[2.5; 256]).unwrap();
    assert!(d.iter().all(|&x| x < 1e-12));
}
