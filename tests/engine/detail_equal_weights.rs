//! Learned metric vs equal weights through the whole `detail` method (Berkiten et al. 2017,
//! Fig. 16a; issue 13, "Tests it must have"): a case where `metric = identity` measurably puts
//! the detail in the wrong place and the learned metric does not.
//!
//! **Case.** Open strips whose profile (in the (z, y) plane, extruded along x) is a chain of
//! treads (normal +y) and risers (normal −z). Source: a tall wall at each end of the profile and
//! 3-5 tiers between them, bumps (amplitude 0.01, wavelength 0.25) on the treads only, so the
//! detail follows the normal at many heights. Target: a tread at each end of its profile and one
//! tall wall between them (a podium and a roof terrace), so its up-facing parts sit where the
//! source's profile has its bare end walls.
//!
//! **Why equal weights fail.** The strip is intrinsically a flat rectangle, so HKS, WKS and the
//! geodesic statistics (46 of the 60 z-scored columns) say only where a point is along the
//! profile: the target's treads (profile ends) look like the source's end walls, not like its
//! treads (middle). Nearest source vertex of each interior target tread under equal weights,
//! squared z-distance by group (first variant below, 0.1 spacing): to the nearest source tread,
//! HKS 23.4, WKS 30.7, geo 5.9 and normal 0.2; to the nearest bare source vertex, HKS 0.1, WKS
//! 0.6, geo 0.1 and normal 10.5. So 0 % of the target's treads find a source tread as nearest
//! neighbour with equal weights, 95 % with the normal columns alone. In the source the normal
//! explains the detail and the intrinsic columns add nothing, so the learned metric puts 75-97 %
//! of its diagonal on the normal group.
//!
//! **λ.** The detail features are standard deviations of the displacement in world units (bands
//! of about 1e-3 here), so `B̂` of the metric problem is about 1e-6 (measured max diagonal
//! 1.24e-6). With an absolute λ = 0.1 (the paper's value, ≈ 80,000 × that) the ℓ1 term wins
//! and the learned `M` is zero up to solver residue (top eigenvalue 2-3e-15, reported as
//! `zero_metric`): the synthesis then follows that residue, which weights HKS / geo (0.6 / 0.2 of
//! its diagonal) and puts *less* detail on the treads than elsewhere (tread / other ratio
//! 0.00-0.47 on the variants below, worse than `identity`). The default, `lambda_relative`
//! (λ = 0.1 of `B̂`'s largest diagonal entry; λ from 0.01 to 1.9 of it all gave ≥ 96 % of the
//! diagonal on the normal group on the first variant), learns the metric.
//!
//! Measured with λ = 1e-7 absolute (≈ 0.08 of max diag `B̂`; finest edge 0.05, 3 levels; detail
//! std on up-facing target vertices (n_y > 0.8) / on the others (n_y < 0.2); learned, then
//! identity; seconds with 2 shared cores):
//!
//! | source profile (width, phase) | target | learned std in / out, ratio | identity std in / out, ratio |
//! |---|---|---|---|
//! | R2 (T1 R1)×3 T1 R2 (2.5, 0) | T2 R7 T2 | 0.00209 / 0.00010, 22.0 | 0.00024 / 0.00020, 1.20 |
//! | R2.5 (T1 R0.8)×3 T1 R2.5 (2.0, 1.3) | T1.5 R6 T1.5 | 0.00147 / 0.00001, 155 | 0.00001 / 0.00023, 0.02 |
//! | R2 (T1.2 R1)×2 T1.2 R2 (2.2, 2.1) | T2.5 R6 T2.5 | 0.00212 / 0.00007, 29.4 | 0.00055 / 0.00029, 1.91 |
//! | R2 (T1 R1)×4 T1 R2 (2.5, 0.7) | T2 R8 T2 | 0.00228 / 0.00009, 26.4 | 0.00039 / 0.00033, 1.17 |
//!
//! (source tread std about 0.0040.) With the defaults (`lambda_relative`, λ 0.1; 16 candidates;
//! measured on main at 47e2792 and again with the z-score floor 1e-2, the learned figures the
//! same) the last three give learned 0.00160 / 0.00001 (ratio 189, normal 0.80 of the
//! diagonal), 0.00222 / 0.00001 (241, 0.93) and 0.00226 / 0.00005 (48.4, 0.96); identity
//! 0.00003 / 0.00013 (0.25), 0.00039 / 0.00026 (1.54) and 0.00028 / 0.00026 (1.07) (with the
//! floor 1e-3: 0.01, 1.21, 0.83). Before the remesher skipped moves that leave a face degenerate
//! (6e5cfc8), the learned ratios were 42.4 / 46.8 / 27.6 and identity's 0.00 / 1.40 / 1.44;
//! with 8 candidates the learned ratios were 300 / 1164 / 34.8 then. The test runs the last
//! three: about 110 s in all (learned 10-15 s each, identity 17-42 s), about 3 minutes while
//! other builds share the cores.

use crate::detail_features::metric_features::extrude_profile;
use crate::detail_method::std;
use retex::engine::control::Control;
use retex::engine::mesh::Surface;
use retex::engine::methods::detail::displacement::area_weighted_normals;
use retex::engine::methods::detail::params::{DetailParams, MetricChoice};
use retex::engine::methods::detail::pipeline::{transfer_detail, DetailTransfer};

/// An open strip: its profile in the (z, y) plane is a chain of treads (`'T'`, along +z, normal
/// +y) and risers (`'R'`, along +y, normal −z) of the given lengths, sampled every `h` and
/// extruded over `width` along x. Returns the surface and whether each vertex is strictly inside
/// a tread.
fn strip(segments: &[(char, f64)], width: f64, h: f64) -> (Surface, Vec<bool>) {
    let mut profile: Vec<([f64; 2], bool)> = vec![([0.0, 0.0], false)];
    let (mut z, mut y) = (0.0, 0.0);
    for &(kind, len) in segments {
        let n = (len / h).round() as usize;
        for i in 1..=n {
            let t = len * i as f64 / n as f64;
            match kind {
                'T' => profile.push(([z + t, y], i < n)),
                _ => profile.push(([z, y + t], false)),
            }
        }
        match kind {
            'T' => z += len,
            _ => y += len,
        }
    }
    extrude_profile(&profile, width, h)
}

/// `"R2 T1 …"` → segments.
fn profile(spec: &str) -> Vec<(char, f64)> {
    spec.split_whitespace()
        .map(|t| (t.chars().next().unwrap(), t[1..].parse().unwrap()))
        .collect()
}

/// Bumps (amplitude 0.01, wavelength 0.25) along +y on the tread vertices.
fn tread_bumps(s: &Surface, tread: &[bool], phase: f64) -> Surface {
    let w = std::f64::consts::TAU / 0.25;
    let mut out = s.clone();
    for (p, t) in out.positions.iter_mut().zip(tread) {
        if *t {
            let d = 0.01 * (w * p[0] as f64 + phase).sin() * (w * p[2] as f64).sin();
            p[1] += d as f32;
        }
    }
    out
}

/// Detail std on the finest target level's up-facing vertices (normal y > 0.8) and on the
/// others (normal y < 0.2; corners in between are left out).
fn inside_outside(out: &DetailTransfer) -> (f64, f64) {
    let normals = area_weighted_normals(&out.surface);
    let (mut up, mut other) = (Vec::new(), Vec::new());
    for (n, d) in normals.iter().zip(&out.displacement) {
        if n[1] > 0.8 {
            up.push(*d);
        } else if n[1] < 0.2 {
            other.push(*d);
        }
    }
    (std(&up), std(&other))
}

#[test]
#[ignore = "about 2 minutes in release on 2 cores (equal weights synthesise with all 60 \
            feature columns); runs in CI with --include-ignored"]
fn learned_metric_follows_the_normal_where_equal_weights_follow_position() {
    // (source profile, width, bump phase, target profile); thresholds from the variants in the
    // module doc (min learned ratio 22.0 at λ 1e-7 absolute, 27.6 relative; max identity ratio
    // 1.91; min learned / identity tread std 3.9; min normal share of the learned diagonal
    // 0.75 absolute, 0.80 relative).
    let variants = [
        (
            "R2.5 T1 R0.8 T1 R0.8 T1 R0.8 T1 R2.5",
            2.0,
            1.3,
            "T1.5 R6 T1.5",
        ),
        ("R2 T1.2 R1 T1.2 R1 T1.2 R2", 2.2, 2.1, "T2.5 R6 T2.5"),
        ("R2 T1 R1 T1 R1 T1 R1 T1 R1 T1 R2", 2.5, 0.7, "T2 R8 T2"),
    ];
    let control = Control::new();
    for (src, width, phase, tgt) in variants {
        let (base, tread) = strip(&profile(src), width, 0.05);
        let detailed = tread_bumps(&base, &tread, phase);
        let (target, _) = strip(&profile(tgt), width, 0.05);
        let mut results = Vec::new();
        for metric in [MetricChoice::Learned, MetricChoice::Identity] {
            let t0 = std::time::Instant::now();
            let mut p = DetailParams {
                levels: 3,
                metric,
                ..DetailParams::default()
            }
            .pipeline(1.0, 1.0);
            p.hierarchy.finest_edge_length = Some(0.05);
            let out = transfer_detail(&detailed, Some(&base), &target, &p, &control).unwrap();
            let (inside, outside) = inside_outside(&out);
            let normal = out
                .report
                .metric
                .diagonal_by_group
                .iter()
                .find(|(g, _)| g == "normal")
                .map_or(0.0, |(_, m)| *m);
            println!(
                "[{src}] -> [{tgt}], width {width}, {metric:?}: up-facing std {inside:.5}, other \
                 {outside:.5}, ratio {:.2}; rank {}, diagonal by group {:?}; {:.1} s",
                inside / outside.max(1e-12),
                out.report.metric.rank,
                out.report
                    .metric
                    .diagonal_by_group
                    .iter()
                    .map(|(g, m)| format!("{g} {m:.2}"))
                    .collect::<Vec<_>>(),
                t0.elapsed().as_secs_f64()
            );
            assert!(
                !out.report.metric.zero_metric,
                "[{src}] {metric:?}: the learned metric is zero"
            );
            results.push((inside, outside, normal));
        }
        let (l_in, l_out, l_normal) = results[0];
        let (i_in, i_out, _) = results[1];
        let (l_ratio, i_ratio) = (l_in / l_out.max(1e-12), i_in / i_out.max(1e-12));
        assert!(
            l_normal > 0.5,
            "[{src}]: the learned metric puts only {l_normal} of its diagonal on the normals"
        );
        assert!(
            l_in > 0.001 && l_ratio > 10.0,
            "[{src}]: learned metric, up-facing {l_in}, other {l_out}"
        );
        assert!(
            i_ratio < 3.0,
            "[{src}]: equal weights put the detail on the up-facing parts ({i_in} / {i_out})"
        );
        assert!(
            l_in > 2.0 * i_in && l_ratio > 5.0 * i_ratio,
            "[{src}]: learned {l_in} ({l_ratio}) vs identity {i_in} ({i_ratio})"
        );
    }
}
