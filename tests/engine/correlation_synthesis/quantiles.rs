//! Weighted quantiles: exact transfer, weights, blending of inverse CDFs.

use super::normal;
use retex::engine::methods::correlation::quantiles::{match_to, Quantiles};
use retex::engine::rng::SplitMix64;

#[test]
fn quantiles_match_to_reproduces_the_target_exactly() {
    for seed in 0..5u64 {
        let mut rng = SplitMix64::new(seed);
        let n = 1000 + 37 * seed as usize;
        let target: Vec<f32> = (0..n).map(|_| normal(&mut rng).exp()).collect();
        let mut x: Vec<f32> = (0..n).map(|_| rng.unit_f32() * 5.0 - 1.0).collect();
        let order_before = {
            let mut i: Vec<usize> = (0..n).collect();
            i.sort_by(|&a, &b| x[a].total_cmp(&x[b]));
            i
        };
        match_to(&mut x, None, &Quantiles::new(&target, None));
        let mut sx = x.clone();
        sx.sort_by(f32::total_cmp);
        let mut st = target.clone();
        st.sort_by(f32::total_cmp);
        let err = sx
            .iter()
            .zip(&st)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f32::max);
        assert!(err < 1e-5, "seed {seed}: {err}");
        // Ranks are kept.
        assert!(order_before.windows(2).all(|w| x[w[0]] <= x[w[1]]));
    }
    // Ties are broken stably (all-equal input spreads over the target).
    let mut x = vec![1.0f32; 4];
    match_to(&mut x, None, &Quantiles::new(&[1.0, 2.0, 3.0, 4.0], None));
    assert_eq!(x, vec![1.0, 2.0, 3.0, 4.0]);
}

#[test]
fn quantiles_respect_weights() {
    // Values 0..n; the first half weighs 3, the second 1. Target uniform on [0, 1]: the weighted
    // median must land on 0.5 and the first half (75% of the weight) fill [0, 0.75].
    let n = 2000;
    let x0: Vec<f32> = (0..n).map(|i| i as f32).collect();
    let w: Vec<f32> = (0..n).map(|i| if i < n / 2 { 3.0 } else { 1.0 }).collect();
    let target: Vec<f32> = (0..10_000).map(|i| (i as f32 + 0.5) / 10_000.0).collect();
    let mut x = x0.clone();
    match_to(&mut x, Some(&w), &Quantiles::new(&target, None));
    let edge = x[n / 2 - 1];
    assert!((edge - 0.75).abs() < 2e-3, "first half ends at {edge}");
    let wm: f32 = x.iter().zip(&w).map(|(a, b)| a * b).sum::<f32>() / w.iter().sum::<f32>();
    assert!((wm - 0.5).abs() < 2e-3, "weighted mean {wm}");
    // Zero weight: ignored for the distribution.
    let q = Quantiles::new(&[0.0, 1.0, 100.0], Some(&[1.0, 1.0, 0.0]));
    assert_eq!(q.len(), 2);
    assert!(q.value_at(1.0) <= 1.0);
    // Weighted distribution: the mean follows the weights.
    let q = Quantiles::new(&x0, Some(&w));
    let m = q.mean();
    let expect = x0.iter().zip(&w).map(|(a, b)| a * b).sum::<f32>() / w.iter().sum::<f32>();
    assert!((m - expect).abs() < 0.01 * n as f32, "mean {m} vs {expect}");
}

#[test]
fn quantiles_blend_of_shifted_distributions_is_the_mid_shift() {
    for seed in 0..4u64 {
        let mut rng = SplitMix64::new(100 + seed);
        // Small sizes blend on the union of knots, large ones on the fixed grid.
        let n = if seed % 2 == 0 { 500 } else { 3000 };
        let base: Vec<f32> = (0..n).map(|_| normal(&mut rng)).collect();
        // `a` holds every value twice (another knot count, the same distribution).
        let a: Vec<f32> = base.iter().chain(&base).map(|x| x - 2.0).collect();
        let b: Vec<f32> = base.iter().map(|x| 3.0 * x + 4.0).collect();
        let (qa, qb) = (Quantiles::new(&a, None), Quantiles::new(&b, None));
        let q0 = Quantiles::new(&base, None);
        for (wa, wb) in [(1.0f32, 1.0f32), (3.0, 1.0), (0.2, 0.8)] {
            let m = Quantiles::blend(&[(&qa, wa), (&qb, wb)]);
            let (ta, tb) = (wa / (wa + wb), wb / (wa + wb));
            for k in 1..20 {
                let u = k as f32 / 20.0;
                // The mean of the inverse CDFs: scale ta·1 + tb·3, shift ta·(-2) + tb·4.
                let expect = (ta + 3.0 * tb) * q0.value_at(u) + (-2.0 * ta + 4.0 * tb);
                let got = m.value_at(u);
                assert!(
                    (got - expect).abs() < 0.1,
                    "seed {seed} w {wa}/{wb} u {u}: {got} vs {expect}"
                );
            }
        }
        // Empty / zero-weight parts are ignored.
        let e = Quantiles::new(&[], None);
        let m = Quantiles::blend(&[(&qa, 1.0), (&e, 1.0), (&qb, 0.0)]);
        assert_eq!(m, qa);
        assert!(Quantiles::blend(&[]).is_empty());
    }
}
