//! Issue 14 item 2: `scale: match_extents`, and so the default `auto` (the smaller of it and
//! `match_area`), keeps the source's units when the target is the source stretched along one
//! axis (the unedited part keeps its pattern size), and still follows a uniform change of size;
//! `match_area` (the old default) scales a stretched target's pattern up by √(area ratio).
//! Read from the report's `source_scale` of whole transfers.

use crate::common_geometry::stretch_beyond_two;
use crate::meshmatch_common::{capsule, glb_of, run_bytes};

fn source_scale(source: &[u8], target: &[u8], scale: &str) -> f64 {
    let out = run_bytes(
        ("source.glb", source.to_vec()),
        ("target.glb", target.to_vec()),
        serde_json::json!({"version": 1, "method": "meshmatch", "seed": 1,
            "output": {"vertex_colors": true},
            "params": {"samples": 1024, "scale": scale}}),
    );
    out.report.method_report["source_scale"].as_f64().unwrap()
}

#[test]
fn extents_scale_keeps_units_on_a_stretch_and_follows_a_uniform_resize() {
    let profile: Vec<f32> = (0..=80).map(|i| i as f32 * 0.05).collect();
    let (sp, st) = capsule(0.5, &profile, 48, |x| x);
    let colors: Vec<[f32; 4]> = sp
        .iter()
        .map(|p| {
            let g = if (p[0] / 0.5).rem_euclid(1.0) < 0.5 {
                0.1
            } else {
                0.9
            };
            [g, g, g, 1.0]
        })
        .collect();
    let source = glb_of(&sp, &st, Some(&colors));
    // The far half stretched 2×: length 5 → 7 with the caps, area × about 1.4.
    let (tp, tt) = capsule(0.5, &profile, 48, stretch_beyond_two);
    let stretched = glb_of(&tp, &tt, None);
    let extents = source_scale(&source, &stretched, "match_extents");
    let area = source_scale(&source, &stretched, "match_area");
    println!("stretched target: match_extents {extents:.4}, match_area {area:.4}");
    assert!((extents - 1.0).abs() < 0.02, "match_extents {extents}");
    assert!(area > 1.15, "match_area {area}");
    // The default, auto, is the smaller of the two.
    let out = run_bytes(
        ("source.glb", source.clone()),
        ("target.glb", stretched),
        serde_json::json!({"version": 1, "method": "meshmatch", "seed": 1,
            "params": {"samples": 1024}}),
    );
    let default = out.report.method_report["source_scale"].as_f64().unwrap();
    assert!(
        (default - extents.min(area)).abs() < 1e-9,
        "default {default}"
    );
    assert!((default - 1.0).abs() < 0.02, "default {default}");
    // The whole capsule 3× larger: every mode measures 3.
    let big: Vec<[f32; 3]> = sp.iter().map(|p| p.map(|c| 3.0 * c)).collect();
    let scaled = glb_of(&big, &st, None);
    for mode in ["match_extents", "match_area", "auto"] {
        let s = source_scale(&source, &scaled, mode);
        assert!((s - 3.0).abs() < 0.03, "{mode} {s}");
    }
}
