//! The E-step's fan comparison shortcuts (MeshMatch, Chen et al. 2012 §4.2): rings written
//! twice so a rotation is one contiguous slice, and the rotation-free lower bound from per-ring
//! means and residual norms that prunes a candidate before any rotation is tried. Both must
//! leave every match exactly as the plain comparison finds it.

use retex::engine::geometry::fans::FanShape;
use retex::engine::methods::meshmatch::matcher::{PatchSpace, Rotations};
use retex::engine::rng::SplitMix64;

const SHAPE: FanShape = FanShape {
    rings: 3,
    spokes: 18,
    dim: 3,
};

/// `count` fans: random colours, and every fourth fan a rotated, slightly perturbed copy of an
/// earlier one (the near matches where pruning is tightest).
fn fans(count: usize, seed: u64) -> Vec<f32> {
    let mut rng = SplitMix64::new(seed);
    let n = SHAPE.len();
    let mut data = vec![0.0f32; count * n];
    for f in 0..count {
        if f >= 4 && f % 4 == 0 {
            let from = rng.below(f as u64) as usize;
            let k = rng.below(SHAPE.spokes as u64) as usize;
            let row = SHAPE.spokes * SHAPE.dim;
            for ring in 0..SHAPE.rings {
                for i in 0..row {
                    let j = (i + k * SHAPE.dim) % row;
                    let noise = 0.02 * (rng.unit_f32() - 0.5);
                    data[f * n + ring * row + i] = data[from * n + ring * row + j] + noise;
                }
            }
        } else {
            // A per-fan tint plus texture, so means and contrasts both vary.
            let tint: Vec<f32> = (0..3).map(|_| rng.unit_f32()).collect();
            let contrast = rng.unit_f32();
            for (i, x) in data[f * n..(f + 1) * n].iter_mut().enumerate() {
                *x = tint[i % 3] + contrast * (rng.unit_f32() - 0.5);
            }
        }
    }
    data
}

fn fan(data: &[f32], f: usize) -> &[f32] {
    &data[f * SHAPE.len()..(f + 1) * SHAPE.len()]
}

#[test]
fn doubled_rings_give_the_plain_distance_for_every_rotation_and_bound() {
    let data = fans(40, 7);
    let mut doubled = vec![0.0f32; SHAPE.doubled_len()];
    for a in 0..40 {
        let b = (a * 7 + 3) % 40;
        SHAPE.double_rings(fan(&data, b), &mut doubled);
        for k in 0..SHAPE.spokes {
            let plain = SHAPE.distance(fan(&data, a), fan(&data, b), k);
            let fast = SHAPE.distance_below_doubled(fan(&data, a), &doubled, k, f32::INFINITY, &[]);
            assert!(
                (plain - fast).abs() <= 1e-5 * plain.max(1.0),
                "fans {a}, {b}, rotation {k}: {plain} vs {fast}"
            );
            // Stopped early: at least the bound, never below it.
            let bound = 0.5 * plain;
            let partial = SHAPE.distance_below_doubled(fan(&data, a), &doubled, k, bound, &[]);
            assert!(partial >= bound * (1.0 - 1e-6), "{partial} below {bound}");
        }
    }
}

#[test]
fn rotation_free_bound_is_below_every_rotation_and_exact_on_constant_rings() {
    let data = fans(200, 11);
    let stats = SHAPE.ring_stats(&data);
    let m = SHAPE.stats_len();
    let mut tight = 0.0f32;
    for a in 0..200 {
        for b in [(a + 1) % 200, (a * 13 + 5) % 200, a / 4 * 4] {
            let lower = SHAPE.rotation_free_bound(
                &stats[a * m..(a + 1) * m],
                &stats[b * m..(b + 1) * m],
                &[],
            );
            let best = (0..SHAPE.spokes)
                .map(|k| SHAPE.distance(fan(&data, a), fan(&data, b), k))
                .fold(f32::INFINITY, f32::min);
            assert!(
                lower <= best * (1.0 + 1e-5) + 1e-6,
                "fans {a}, {b}: bound {lower} above the best rotation's {best}"
            );
            if best > 1e-3 {
                tight = tight.max(lower / best);
            }
        }
    }
    // The bound is informative, not zero: on differently tinted fans it reaches most of the
    // distance.
    assert!(
        tight > 0.5,
        "the bound reaches at most {tight} of the distance"
    );
    // Constant rings: the residuals vanish and the bound is the distance itself.
    let flat: Vec<f32> = (0..2 * SHAPE.len())
        .map(|i| {
            let (f, ring, c) = (i / SHAPE.len(), i / 54 % 3, i % 3);
            0.1 * (f + 1) as f32 * (ring + c + 1) as f32
        })
        .collect();
    let s = SHAPE.ring_stats(&flat);
    let lower = SHAPE.rotation_free_bound(&s[..m], &s[m..], &[]);
    let d = SHAPE.distance(fan(&flat, 0), fan(&flat, 1), 5);
    assert!((lower - d).abs() <= 1e-4 * d, "{lower} vs {d}");
}

/// The distance of ring `ring` alone at rotation `k`.
fn ring_distance(a: &[f32], b: &[f32], ring: usize, k: usize) -> f32 {
    let row = SHAPE.spokes * SHAPE.dim;
    let one = FanShape { rings: 1, ..SHAPE };
    one.distance(
        &a[ring * row..(ring + 1) * row],
        &b[ring * row..(ring + 1) * row],
        k,
    )
}

/// Pruning by the bound changes no evaluation: the same best rotation and distance, or the
/// same refusal, for every candidate and every search bound, with uniform and with area ring
/// weights; and the weighted evaluation is the best rotation of `Σ_r w_r d_r`.
#[test]
fn pruned_evaluation_matches_the_plain_one() {
    let (nt, ns) = (60, 120);
    let (target, source) = (fans(nt, 21), fans(ns, 22));
    let (ts, ss) = (SHAPE.ring_stats(&target), SHAPE.ring_stats(&source));
    let area = SHAPE.area_ring_weights();
    assert_eq!(area, vec![0.5, 1.0, 1.5]);
    for weights in [Vec::new(), area] {
        let plain = PatchSpace {
            fan: SHAPE,
            target_fans: &target,
            source_fans: &source,
            target_shape: &[],
            source_shape: &[],
            shape_dim: 0,
            source_allowed: None,
            exclude: None,
            target_ring_stats: &[],
            source_ring_stats: &[],
            source_penalty: &[],
            ring_weights: &weights,
        };
        let pruned = PatchSpace {
            target_ring_stats: &ts,
            source_ring_stats: &ss,
            ..plain
        };
        let (mut refused, mut found, mut pruned_away) = (0, 0, 0);
        for t in 0..nt {
            for s in 0..ns {
                let full = plain.evaluate(t, s, Rotations::All, f32::INFINITY).unwrap();
                let (a, b) = (fan(&target, t), fan(&source, s));
                let expected = (0..SHAPE.spokes)
                    .map(|k| {
                        (0..SHAPE.rings)
                            .map(|r| {
                                weights.get(r).copied().unwrap_or(1.0) * ring_distance(a, b, r, k)
                            })
                            .sum::<f32>()
                    })
                    .fold(f32::INFINITY, f32::min);
                assert!(
                    (full.1 - expected).abs() <= 1e-4 * expected.max(1.0),
                    "target {t}, source {s}: {} vs {expected}",
                    full.1
                );
                for bound in [0.5 * full.1, full.1 * 0.999, full.1 * 1.001, 2.0 * full.1] {
                    let a = plain.evaluate(t, s, Rotations::All, bound);
                    let b = pruned.evaluate(t, s, Rotations::All, bound);
                    assert_eq!(a, b, "target {t}, source {s}, bound {bound}");
                    match a {
                        Some(_) => found += 1,
                        None => refused += 1,
                    }
                    let m = SHAPE.stats_len();
                    let lower = SHAPE.rotation_free_bound(
                        &ts[t * m..(t + 1) * m],
                        &ss[s * m..(s + 1) * m],
                        &weights,
                    );
                    pruned_away += (a.is_none() && lower * 0.999 >= bound) as usize;
                }
            }
        }
        assert!(
            found > 1000 && refused > 1000,
            "found {found}, refused {refused}"
        );
        // The shortcut is exercised: a good share of the refusals never compare a ring.
        assert!(
            pruned_away * 5 > refused,
            "{pruned_away} of {refused} refusals pruned"
        );
    }
}
