//! Issue 14, item 2: where the geometry is unchanged the scale is kept. Two shapes, a round
//! capsule and a bar of square section (x ∈ [0, 4], black and white ring stripes of period 0.5
//! as COLOR_0), each transferred without correspondences at the default 64K samples onto the
//! same shape with x ∈ [2, 4] stretched to [2, 6], seeds 1-5. On every run the stripe period is
//! within ×0.85-1.15 of the source's on the unstretched part and ×0.8-1.2 on the stretched part
//! (the bounds), and the stripes stay rings. The shapes are those of
//! `scripts/stretched_bar.py` (`--round` and the bar), made here in f32, so the runs are not
//! bit-identical to the README's sweep (the synthesis is chaotic in its input; README "HKS units
//! and time range").
//!
//! The period is measured like `scripts/stripe_period.py`: along 16 lines of the surface
//! (x axis, 1/16 turn apart, points within 0.02 rad and radius > 0.45), the mid-grey crossings in
//! the window, interpolated, `2 (last − first) / (count − 1)`, the median of the lines. Rings:
//! the fraction of crossings with a crossing of the next line within a quarter period, at least
//! 0.95 (a swirl gives 0.76-0.91, a single U-turn 0.955). Measured at the defaults: capsule
//! ×1.02-1.05 / ×1.04-1.06, bar ×1.03-1.08 / ×1.06-1.11, rings ≥ 0.955 (the bar's seed 1 has
//! one U-turn; region flips on three levels remove it, rings 0.983, but cost the real pairs'
//! statistics: README "Region flips"). Fails with
//! the old features (each surface's HKS
//! at its own unit area, all times, no clamp: the capsule's seed 3 stretched ×1.44, the bar's
//! seeds 1 and 4 unstretched ×1.25 and ×1.18) and without the clamp alone
//! (`hks.clamp_to_source` false: the bar's seed 3 swirls, rings 0.891).

use crate::meshmatch_common::{
    capsule, colored_points, glb_of, profile, run_bytes, stripe_colors, UPDATE_PERIOD,
};

/// The source's stripes: those of the texture-update case (period 0.5).
const PERIOD: f32 = UPDATE_PERIOD;

/// The edit, x ∈ [2, 4] stretched to [2, 6]: written as the bench's (`src/cli/bench_meshmatch_pairs.rs`,
/// not reachable from tests), not as `lengthen(x, 4.0)`, whose f32 rounding differs and the
/// synthesis is chaotic in its input.
fn stretch(x: f32) -> f32 {
    if x <= 2.0 {
        x
    } else {
        x + (x.min(4.0) - 2.0)
    }
}

/// A bar of square section (half-width 0.5) along x ∈ [0, 4]: 257 rings of 4 × 64 vertices and
/// a fan at each end; `warp` moves x.
fn bar(warp: impl Fn(f32) -> f32) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    const SIDE: usize = 64;
    const RINGS: usize = 257;
    let m = 4 * SIDE;
    let lp = |side: usize, t: f32| -> (f32, f32) {
        match side {
            0 => (0.5, t),
            1 => (-t, 0.5),
            2 => (-0.5, -t),
            _ => (t, -0.5),
        }
    };
    let mut positions = Vec::with_capacity(RINGS * m + 2);
    for i in 0..RINGS {
        let x = warp(4.0 * i as f32 / (RINGS - 1) as f32);
        for j in 0..m {
            let (y, z) = lp(j / SIDE, -0.5 + (j % SIDE) as f32 / SIDE as f32);
            positions.push([x, y, z]);
        }
    }
    let mut faces = Vec::with_capacity(2 * RINGS * m);
    let id = |i: usize, j: usize| (i * m + j % m) as u32;
    for i in 0..RINGS - 1 {
        for j in 0..m {
            let (a, b, c, d) = (id(i, j), id(i, j + 1), id(i + 1, j), id(i + 1, j + 1));
            faces.push([a, c, b]);
            faces.push([b, c, d]);
        }
    }
    let (c0, c1) = (positions.len() as u32, positions.len() as u32 + 1);
    positions.push([warp(0.0), 0.0, 0.0]);
    positions.push([warp(4.0), 0.0, 0.0]);
    for j in 0..m {
        faces.push([c0, id(0, j), id(0, j + 1)]);
        faces.push([c1, id(RINGS - 1, j + 1), id(RINGS - 1, j)]);
    }
    (positions, faces)
}

/// Interpolated x of the crossings of grey level `t` along one line's points in [lo, hi].
fn crossings(line: &[(f32, f32)], lo: f32, hi: f32, t: f32) -> Vec<f32> {
    let mut pts: Vec<(f32, f32)> = line
        .iter()
        .copied()
        .filter(|p| p.0 >= lo && p.0 <= hi)
        .collect();
    pts.sort_by(|a, b| a.0.total_cmp(&b.0));
    pts.windows(2)
        .filter(|w| (w[0].1 > t) != (w[1].1 > t))
        .map(|w| w[0].0 + (t - w[0].1) / (w[1].1 - w[0].1) * (w[1].0 - w[0].0))
        .collect()
}

/// (unstretched period ratio, stretched period ratio, rings) of an output's COLOR_0.
fn stripe_figures(points: &[([f32; 3], [f32; 3])]) -> (f32, f32, f32) {
    let grey_of = |c: [f32; 3]| (c[0] + c[1] + c[2]) / 3.0;
    let (lo_g, hi_g) = points.iter().fold((f32::MAX, f32::MIN), |(a, b), p| {
        (a.min(grey_of(p.1)), b.max(grey_of(p.1)))
    });
    let windows = [(0.2f32, 1.8f32), (2.4, 5.6)];
    let mut ratios = [Vec::new(), Vec::new()];
    let mut lines = Vec::new();
    for k in 0..16 {
        let th = -std::f32::consts::PI + std::f32::consts::TAU * k as f32 / 16.0;
        let line: Vec<(f32, f32)> = points
            .iter()
            .filter(|(p, _)| {
                let d = (p[2].atan2(p[1]) - th + std::f32::consts::PI)
                    .rem_euclid(std::f32::consts::TAU)
                    - std::f32::consts::PI;
                d.abs() < 0.02 && p[1].hypot(p[2]) > 0.45
            })
            .map(|(p, c)| (p[0], grey_of(*c)))
            .collect();
        for (w, &(lo, hi)) in windows.iter().enumerate() {
            let in_window: Vec<f32> = line
                .iter()
                .filter(|p| p.0 >= lo && p.0 <= hi)
                .map(|p| p.1)
                .collect();
            let (a, b) = in_window
                .iter()
                .fold((f32::MAX, f32::MIN), |(a, b), &g| (a.min(g), b.max(g)));
            let xs = crossings(&line, lo, hi, 0.5 * (a + b));
            let period = if xs.len() < 2 {
                2.0 * (hi - lo)
            } else {
                2.0 * (xs[xs.len() - 1] - xs[0]) / (xs.len() - 1) as f32
            };
            ratios[w].push(period / PERIOD);
        }
        let t = 0.5 * (lo_g + hi_g);
        let all: Vec<f32> = windows
            .iter()
            .flat_map(|&(lo, hi)| crossings(&line, lo, hi, t))
            .collect();
        lines.push(all);
    }
    let median = |v: &mut Vec<f32>| {
        v.sort_by(f32::total_cmp);
        0.5 * (v[7] + v[8])
    };
    let (mut paired, mut total) = (0usize, 0usize);
    for k in 0..16 {
        let next = &lines[(k + 1) % 16];
        for &c in &lines[k] {
            total += 1;
            paired += usize::from(next.iter().any(|&d| (d - c).abs() < 0.125));
        }
    }
    let [mut u, mut s] = ratios;
    (
        median(&mut u),
        median(&mut s),
        paired as f32 / total.max(1) as f32,
    )
}

fn source_and_target(shape: &str) -> (Vec<u8>, Vec<u8>) {
    let make = |warp: fn(f32) -> f32| match shape {
        "capsule" => capsule(0.5, &profile(0.0, 4.0, 4.0 / 256.0), 256, warp),
        _ => bar(warp),
    };
    let (sp, sf) = make(|x| x);
    let colors = stripe_colors(&sp);
    let (tp, tf) = make(stretch);
    (glb_of(&sp, &sf, Some(&colors)), glb_of(&tp, &tf, None))
}

#[test]
fn stripes_keep_their_period_where_the_shape_is_unchanged() {
    let mut failures = Vec::new();
    for shape in ["capsule", "bar"] {
        let (source, target) = source_and_target(shape);
        for seed in 1..=5u64 {
            let out = run_bytes(
                ("source.glb", source.clone()),
                ("target.glb", target.clone()),
                serde_json::json!({"version": 1, "method": "meshmatch", "seed": seed,
                    "output": {"vertex_colors": true}}),
            );
            let (unstretched, stretched, rings) = stripe_figures(&colored_points(&out.model));
            eprintln!(
                "{shape} seed {seed}: unstretched ×{unstretched:.2}, stretched ×{stretched:.2}, rings {rings:.3}"
            );
            if !((0.85..=1.15).contains(&unstretched)
                && (0.8..=1.2).contains(&stretched)
                && rings >= 0.95)
            {
                failures.push(format!(
                    "{shape} seed {seed}: ×{unstretched:.2} / ×{stretched:.2}, rings {rings:.3}"
                ));
            }
        }
    }
    assert!(
        failures.is_empty(),
        "period outside ×0.85-1.15 (unstretched) / ×0.8-1.2 (stretched) or rings < 0.95: {failures:?}"
    );
}
