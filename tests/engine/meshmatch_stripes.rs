//! The signature result of MeshMatch (Chen et al. 2012, §5.2, Figure 1): where the target is
//! stretched, MeshMatch synthesizes more stripes of the source's width instead of stretching them.
//!
//! Source: a capsule along x (cylinder x ∈ [0, 4], radius 0.5) with ring stripes whose period
//! shrinks along the length, `w(x) = 0.8 − 0.125 x` (0.8 at the tail, 0.3 at the neck tip).
//! Target: the same capsule with its "neck" x ∈ [2, 4] stretched to [2, 6]. Correspondences at
//! the two ends of the stretched part. Along the target's neck, MeshMatch must keep the stripe
//! period within 25% of the source's period there, while `project` (a one-to-one map: the
//! similarity fitted to the same correspondences) stretches it by about 2×.

use crate::common;
use crate::common_geometry::stretch_beyond_two;

use crate::meshmatch_common::{
    capsule, colored_points, glb_of, measured_period, profile, run_bytes,
};

const W0: f32 = 0.8;
const K: f32 = 0.125;

/// Stripe phase (in periods) at x: ∫ dx / w(x).
fn phase(x: f32) -> f32 {
    let x = x.clamp(0.0, 4.0);
    -(1.0 / K) * ((W0 - K * x) / W0).ln()
}

/// Linear grey level of the source at x (soft-edged black and white stripes).
fn stripe(x: f32) -> f32 {
    let s = (std::f32::consts::TAU * phase(x)).sin();
    0.05 + 0.85 * (0.5 + 0.5 * (4.0 * s).tanh())
}

fn warp(x: f32) -> f32 {
    if x <= 4.0 {
        stretch_beyond_two(x)
    } else {
        x + 2.0
    }
}

#[test]
fn meshmatch_adds_stripes_where_project_stretches_them() {
    let (sp, st) = capsule(0.5, &profile(0.0, 4.0, 0.05), 64, |x| x);
    let colors: Vec<[f32; 4]> = sp
        .iter()
        .map(|p| {
            let g = stripe(p[0]);
            [g, g, g, 1.0]
        })
        .collect();
    let source = glb_of(&sp, &st, Some(&colors));
    let (tp, tt) = capsule(0.5, &profile(0.0, 4.0, 0.025), 64, warp);
    let target = glb_of(&tp, &tt, None);
    // The two ends of the stretched part, on the top line.
    let corr = serde_json::json!([
        {"source": {"point": [2.0, 0.5, 0.0]}, "target": {"point": [2.0, 0.5, 0.0]}},
        {"source": {"point": [4.0, 0.5, 0.0]}, "target": {"point": [6.0, 0.5, 0.0]}},
        {"source": {"point": [2.0, -0.5, 0.0]}, "target": {"point": [2.0, -0.5, 0.0]}},
        {"source": {"point": [4.0, -0.5, 0.0]}, "target": {"point": [6.0, -0.5, 0.0]}},
    ]);
    // Source period over its neck: 2 / (phase(4) − phase(2)).
    let source_period = 2.0 / (phase(4.0) - phase(2.0));

    let mm = run_bytes(
        ("source.glb", source.clone()),
        ("target.glb", target.clone()),
        serde_json::json!({"version": 1, "method": "meshmatch", "seed": 1,
            "correspondences": corr,
            "output": {"vertex_colors": true},
            "params": {"samples": 16384, "scale": "world", "vertex_color_samples": 60000}}),
    );
    common::assert_validator_clean(&mm.model, "meshmatch_stripes.glb");
    let mm_period = measured_period(&colored_points(&mm.model), 2.3, 5.7);

    let pj = run_bytes(
        ("source.glb", source),
        ("target.glb", target),
        serde_json::json!({"version": 1, "method": "project",
            "correspondences": corr,
            "output": {"vertex_colors": true},
            "params": {"vertex_color_samples": 60000}}),
    );
    let pj_period = measured_period(&colored_points(&pj.model), 2.3, 5.7);
    let (mm_ratio, pj_ratio) = (mm_period / source_period, pj_period / source_period);
    eprintln!(
        "source period {source_period:.3}; meshmatch {mm_period:.3} (×{mm_ratio:.2}); project {pj_period:.3} (×{pj_ratio:.2})"
    );
    assert!(
        (mm_ratio - 1.0).abs() <= 0.25,
        "meshmatch period ×{mm_ratio:.2} of the source's"
    );
    assert!(
        pj_ratio >= 1.6,
        "project period ×{pj_ratio:.2}: the baseline should stretch"
    );
    assert!(
        pj_ratio - mm_ratio >= 0.5,
        "meshmatch ×{mm_ratio:.2} vs project ×{pj_ratio:.2}"
    );
}
